"""The EBREnv networks (docs/conventions.md#pipeline, steps 1 and 4): the lighting net and the
material cascade.

Every network is a :class:`~.nafnet.NAFNet`; radiance inputs enter through
:func:`~.transforms.log_input` (``log(max(x,0) + ε)``, ``ε = log_eps``), outputs leave through the
constraints of :mod:`.transforms`. Losses are not computed here (see :mod:`.losses`).

**Lighting net** (:class:`LightingNet`, step 1)::

    shots (B, 3S, H, W)  ──log──▶ NAFNet ──▶ log radiance (B, 3N+3, H, W)
                                           ──exp(15·tanh(·/15))──▶ exemplars (B, N, 3, H, W),
                                                                flash_only (B, 3, H, W)

``S = 2`` shots ``(flash, no-flash)`` in ``near`` mode, ``S = 4`` ``(flash, no-flash, far flash,
far no-flash)`` in ``near-far`` mode; ``N = num_exemplars`` environment exemplars (uniform
material, roughness per exemplar index: docs/conventions.md#exemplars).

**Cascade** (:class:`Cascade`, step 4; steps 2–3, SG extraction and exemplar selection, run in
Dr.Jit in between and hand in the selected exemplars)::

    diffuse net   : log(no-flash), log(flash-only), log(K env exemplars)  → normal, diffuse
    specular image: flash-only − render_diffuse_flash(normal, diffuse)
    specular net  : signed_log(specular image), log(flash-only), log(M point exemplars)
                                                                          → specular, roughness
    refinement net: maps (10 ch), log(photos), log(photos) − log(render_photos(maps))
                                                                          → Δ raw maps

The refinement adds its output to the *raw* (pre-activation) map channels of the first stage, so
it learns a correction. Ablations (:class:`CascadeConfig`): ``use_exemplars=False`` drops every
exemplar input ("without exemplars"); ``use_cascade=False`` replaces the diffuse and specular
nets by one joint net (no-flash, flash-only[, env and point exemplars] → all maps; no specular
image) ("without cascade"); ``use_refinement=False`` returns the first-stage maps.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import torch
from torch import nn

from ..errors import ConfigError, InputError
from ..typedconfig import check, config, from_dict, option
from .maps import NUM_MAP_CHANNELS, Maps
from .nafnet import PAPER_SIZE, SIZE_PRESETS, NAFNet, NAFNetSize
from .transforms import LOG_EPS, log_input, signed_log, soft_clamp_log, unit_interval, unit_normal

CAPTURE_MODES = {"near": 2, "near-far": 4}

RenderDiffuseFlash = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
"""``(normal (B,3,H,W), diffuse (B,3,H,W)) -> flash-only diffuse radiance (B,3,H,W)``."""
RenderPhotos = Callable[[Maps], torch.Tensor]
"""``maps -> renders (B, 3P, H, W)`` of the ``P`` photos (same order as ``photos``) under the
flash and the extracted SGs."""


def _check_image(name: str, x: torch.Tensor, channels: int, like: torch.Tensor | None = None):
    if x.ndim != 4 or x.shape[1] != channels:
        raise InputError(f"{name} has shape {tuple(x.shape)}; expected (B, {channels}, H, W)")
    if like is not None and (x.shape[0] != like.shape[0] or x.shape[2:] != like.shape[2:]):
        raise InputError(f"{name} has shape {tuple(x.shape)}; batch and H×W must match {tuple(like.shape)}")


def _check_stack(name: str, x: torch.Tensor, count: int, like: torch.Tensor) -> torch.Tensor:
    """(B, count, 3, H, W) → (B, 3·count, H, W)."""
    b, _, h, w = like.shape
    if x is None or x.ndim != 5 or tuple(x.shape) != (b, count, 3, h, w):
        got = None if x is None else tuple(x.shape)
        raise InputError(f"{name} has shape {got}; expected ({b}, {count}, 3, {h}, {w})")
    return x.reshape(b, 3 * count, h, w)


@config
class LightingNetConfig:
    """Options of :class:`LightingNet`."""

    size: NAFNetSize = option(
        PAPER_SIZE,
        "network size (preset name or table in files)",
        presets=SIZE_PRESETS,
        preset_kind="network size",
    )
    capture: str = option("near", "near (2 shots) or near-far (4 shots)", choices=tuple(CAPTURE_MODES))
    num_exemplars: int = option(4, "environment exemplars predicted (N)", minimum=1)
    log_eps: float = option(LOG_EPS, "ε of the input transform log(x + ε)", above=0)

    @property
    def num_shots(self) -> int:
        return CAPTURE_MODES[self.capture]

    @classmethod
    def from_dict(cls, data: Mapping, where: str = "lighting", *, key: str = "") -> LightingNetConfig:
        return from_dict(cls, data, where, key=key)


@dataclass
class LightingOutput:
    """What :class:`LightingNet` returns (radiance ≥ 0 and its log, ``log_* = log radiance``)."""

    exemplars: torch.Tensor  # (B, N, 3, H, W)
    flash_only: torch.Tensor  # (B, 3, H, W)
    log_exemplars: torch.Tensor  # (B, N, 3, H, W), soft-clamped log radiance
    log_flash_only: torch.Tensor  # (B, 3, H, W)


class LightingNet(nn.Module):
    """Shots → environment exemplars and the flash-only image (see the module docstring).

    ``forward(shots)``: ``shots`` (B, 3S, H, W) = the S shots of the capture mode concatenated on
    channels, linear radiance. Returns a :class:`LightingOutput`.
    """

    def __init__(self, config: LightingNetConfig | None = None):
        super().__init__()
        self.config = config or LightingNetConfig()
        c = self.config
        self.net = NAFNet(3 * c.num_shots, 3 * c.num_exemplars + 3, c.size)

    def forward(self, shots: torch.Tensor) -> LightingOutput:
        c = self.config
        _check_image("LightingNet shots", shots, 3 * c.num_shots)
        raw = self.net(log_input(shots, c.log_eps))
        b, _, h, w = raw.shape
        log_all = soft_clamp_log(raw)
        log_ex = log_all[:, : 3 * c.num_exemplars].reshape(b, c.num_exemplars, 3, h, w)
        log_fo = log_all[:, 3 * c.num_exemplars :]
        return LightingOutput(torch.exp(log_ex), torch.exp(log_fo), log_ex, log_fo)


@config
class CascadeConfig:
    """Options of :class:`Cascade`."""

    size: NAFNetSize = option(
        PAPER_SIZE, "size of every net of the cascade", presets=SIZE_PRESETS, preset_kind="network size"
    )
    num_env_exemplars: int = option(
        3, "selected environment exemplars K (adaptive one + fixed low and high roughness)", minimum=0
    )
    num_point_exemplars: int = option(3, "selected point-light exemplars M", minimum=0)
    num_photos: int = option(2, "photos P given to the refinement (flash, no-flash)", minimum=1)
    use_exemplars: bool = option(True, "false: ablation 'without exemplars'")
    use_cascade: bool = option(
        True, "false: ablation 'without cascade' (one joint net instead of diffuse → specular)"
    )
    use_refinement: bool = option(True, "false: no refinement net")
    log_eps: float = option(LOG_EPS, "ε of the log input transforms", above=0)

    def __post_init__(self):
        check(self)
        for name in ("num_env_exemplars", "num_point_exemplars"):
            if getattr(self, name) < (1 if self.use_exemplars else 0):
                raise ConfigError(f"CascadeConfig: {name}: must be >= 1 when use_exemplars is true")

    @classmethod
    def from_dict(cls, data: Mapping, where: str = "cascade", *, key: str = "") -> CascadeConfig:
        return from_dict(cls, data, where, key=key)


@dataclass
class CascadeOutput:
    """What :class:`Cascade` returns.

    ``maps``: final maps; ``coarse``: first-stage maps (before refinement; the same object as
    ``maps`` when refinement is off); ``specular_image``: (B, 3, H, W) or None without cascade;
    ``rendered_photos``: (B, 3P, H, W) renders used for the refinement residuals, or None.
    """

    maps: Maps
    coarse: Maps
    specular_image: torch.Tensor | None
    rendered_photos: torch.Tensor | None


class Cascade(nn.Module):
    """Diffuse net → specular net → refinement net (see the module docstring)."""

    def __init__(self, config: CascadeConfig | None = None):
        super().__init__()
        self.config = config or CascadeConfig()
        c = self.config
        env_ch = 3 * c.num_env_exemplars if c.use_exemplars else 0
        point_ch = 3 * c.num_point_exemplars if c.use_exemplars else 0
        if c.use_cascade:
            self.diffuse_net = NAFNet(6 + env_ch, 6, c.size)  # → normal (3), diffuse (3)
            self.specular_net = NAFNet(6 + point_ch, 4, c.size)  # → specular (3), roughness (1)
            self.joint_net = None
        else:
            self.diffuse_net = self.specular_net = None
            self.joint_net = NAFNet(6 + env_ch + point_ch, NUM_MAP_CHANNELS, c.size)
        photo_ch = 3 * c.num_photos
        self.refinement_net = (
            NAFNet(NUM_MAP_CHANNELS + 2 * photo_ch, NUM_MAP_CHANNELS, c.size) if c.use_refinement else None
        )

    def forward(
        self,
        noflash: torch.Tensor,
        flash_only: torch.Tensor,
        env_exemplars: torch.Tensor | None = None,
        point_exemplars: torch.Tensor | None = None,
        *,
        render_diffuse_flash: RenderDiffuseFlash | None = None,
        photos: torch.Tensor | None = None,
        render_photos: RenderPhotos | None = None,
        refine: bool = True,
    ) -> CascadeOutput:
        """Estimate the maps.

        ========================  ====================  =============================================
        argument                  shape                 meaning
        ========================  ====================  =============================================
        ``noflash``               (B, 3, H, W)          no-flash photo, linear
        ``flash_only``            (B, 3, H, W)          flash-only image (lighting net or flash − no-flash)
        ``env_exemplars``         (B, K, 3, H, W)       selected environment exemplars (if used)
        ``point_exemplars``       (B, M, 3, H, W)       selected point-light exemplars (if used)
        ``render_diffuse_flash``  callable              ``(normal, diffuse) → (B, 3, H, W)``; needed
                                                        with the cascade (e.g. :func:`.torch_brdf.
                                                        near_flash_diffuse` or a ``dr.wrap``-ed renderer)
        ``photos``                (B, 3P, H, W)         photos for the refinement (flash, no-flash)
        ``render_photos``         callable              ``maps → (B, 3P, H, W)`` under flash + SGs
        ``refine``                bool                  False: the first stage alone (the refinement
                                                        net is not run; ``photos`` and
                                                        ``render_photos`` are not needed)
        ========================  ====================  =============================================
        """
        c = self.config
        eps = c.log_eps
        _check_image("noflash", noflash, 3)
        _check_image("flash_only", flash_only, 3, noflash)
        env_in = point_in = None
        if c.use_exemplars:
            env = _check_stack("env_exemplars", env_exemplars, c.num_env_exemplars, noflash)
            point = _check_stack("point_exemplars", point_exemplars, c.num_point_exemplars, noflash)
            env_in, point_in = log_input(env, eps), log_input(point, eps)
        log_nf = log_input(noflash, eps)
        log_fo = log_input(flash_only, eps)
        specular_image = None
        if c.use_cascade:
            if render_diffuse_flash is None:
                raise InputError(
                    "Cascade: render_diffuse_flash is required with use_cascade=True; pass "
                    "ebr_mitsuba.nets.torch_brdf.near_flash_diffuse() or a Dr.Jit renderer"
                )
            diffuse_in = torch.cat([log_nf, log_fo] + ([env_in] if env_in is not None else []), dim=1)
            raw_nd = self.diffuse_net(diffuse_in)
            diffuse_render = render_diffuse_flash(unit_normal(raw_nd[:, :3]), unit_interval(raw_nd[:, 3:]))
            _check_image("render_diffuse_flash output", diffuse_render, 3, noflash)
            specular_image = flash_only - diffuse_render
            specular_in = torch.cat(
                [signed_log(specular_image, eps), log_fo] + ([point_in] if point_in is not None else []),
                dim=1,
            )
            raw_sr = self.specular_net(specular_in)
            raw = torch.cat([raw_nd, raw_sr], dim=1)
        else:
            parts = [log_nf, log_fo] + ([env_in, point_in] if env_in is not None else [])
            raw = self.joint_net(torch.cat(parts, dim=1))
        coarse = Maps.from_raw(raw)
        if self.refinement_net is None or not refine:
            return CascadeOutput(coarse, coarse, specular_image, None)
        if photos is None or render_photos is None:
            raise InputError("Cascade: photos and render_photos are required with use_refinement=True")
        _check_image("photos", photos, 3 * c.num_photos, noflash)
        rendered = render_photos(coarse)
        _check_image("render_photos output", rendered, 3 * c.num_photos, noflash)
        log_photos = log_input(photos, eps)
        residual = log_photos - log_input(rendered, eps)
        delta = self.refinement_net(torch.cat([coarse.stack(), log_photos, residual], dim=1))
        return CascadeOutput(Maps.from_raw(raw + delta), coarse, specular_image, rendered)
