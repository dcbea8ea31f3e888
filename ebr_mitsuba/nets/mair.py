"""MAIR (Choi et al., CVPR 2023) adapted to the planar 3×3 multi-view capture (``ebr capture --setup
multi-view``): normal net, per-pixel SG lighting net, SpecNet, MVANet, RefineNet and the
:class:`MAIRModel` that composes them.

**Inputs live in the sample grid.** MAIR warps its views onto the reference view by depth; here
the sample is the plane z = 0, so every view is resampled onto the pixel grid of
``docs/conventions.md`` ("Geometry and pixel grid"): pixel (i, j) of every view shows the same
surface point ``p_ij``. The fast renderer's multi-view shots already are such *texture-space*
images (:mod:`ebr_mitsuba.render.fast`); camera images are rectified by projecting ``p_ij`` into
the camera. The view of camera ``c`` then differs from the others only in its per-pixel direction
``v_ij = normalise(c − p_ij)`` (:func:`view_direction_maps`) and in which pixels it saw
(:func:`in_frame_weights`, the per-view weights w).

Data flow (B batch, N views — 9 for the 3×3 grid, any N ≥ 1 works —, S = S_D SGs per pixel)::

    views (B,N,3,H,W), v (B,N,3,H,W), w (B,N,1,H,W)
      │
      ├─ NormalNet : ViewEncoder(log views, v; pooled over views by w) → NAFNet → n (B,3,H,W)
      ├─ SVSGNet   : ViewEncoder ‖ n → NAFNet → ξ, λ, μ per pixel, η per image (PixelSGLighting)
      ├─ SpecNet   : MLP(ξ, log λ, μ, log η, v, n, n·ξ, n·v, n·h, v·h) summed over the S SGs
      │              → specular features (B,N,F_s,H,W)
      ├─ MVANet    : tokens (log view, specular features, v, n) per view and pixel → attention
      │              across the N views (weights w as a log-bias) → fused (B,F_b,H,W)
      └─ RefineNet : U-Net (GroupNorm) on fused ‖ weighted mean log view ‖ n
                     → diffuse, specular, roughness  ⇒ Maps(n, diffuse, specular, roughness)

Every view is treated alike: the per-view encoders, SpecNet and the per-view MVANet tokens are
shared across views and every fusion is a weighted pooling or an attention, so permuting the
views (with their directions and weights) permutes the per-view outputs and leaves the maps and
the lighting unchanged. ``MAIRConfig(fusion="mean")`` is the ablation without cross-view
attention (per-view MLP blocks, then the weighted mean). A centre-view-only model is the same
model fed N = 1 view.

Files: view geometry and weights in :mod:`.mair_views`, MVANet in :mod:`.mair_fusion`, the
per-pixel SG lighting type in :mod:`.mair_lighting`, sizes in :mod:`.mair_config` (presets
``tiny``, ``small``, ``paper``; ``python -m ebr_mitsuba.nets.mair_params`` prints their parameter counts).
Losses are not computed here (MAIR's g1–g5 are in :mod:`.losses`; see ``docs/mair.md`` for which
output feeds which loss).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import InputError
from .mair_config import MAIRConfig, UNetSize
from .mair_fusion import AttentionBlock, AttentionPool, MLPBlock, MVANet, MVAOutput, mlp_layers
from .mair_lighting import PixelSGLighting
from .mair_views import (
    check_inputs,
    in_frame_weights,
    multiview_shots,
    normalised_weights,
    view_direction_maps,
)
from .maps import Maps
from .nafnet import NAFBlock, NAFNet, NAFNetSize, parameter_count
from .transforms import LOG_EPS, log_input, soft_clamp_log, unit_interval, unit_normal

__all__ = [
    "ViewEncoder",
    "NormalNet",
    "SVSGNet",
    "SpecNet",
    "RefineNet",
    "MAIRModel",
    "MAIROutput",
    "MVANet",
    "MVAOutput",
    "AttentionBlock",
    "AttentionPool",
    "MLPBlock",
    "PixelSGLighting",
    "view_direction_maps",
    "in_frame_weights",
    "multiview_shots",
    "stage_parameter_counts",
]


# ------------------------------------------------------------------------------- image stages


class ViewEncoder(nn.Module):
    """Shared per-view encoder pooled over the views (weighted mean and variance).

    ===========  ================  ==========================================================
    argument     shape             meaning
    ===========  ================  ==========================================================
    views        (B, N, 3, H, W)   linear radiance, sample grid
    directions   (B, N, 3, H, W)   view directions v
    weights      (B, N, 1, H, W)   per-view weights w ≥ 0, or None (uniform)
    → output     (B, 2·F_e, H, W)  ``[Σ p_k f_k, Σ p_k (f_k − mean)²]``, ``f_k`` = conv3×3 + NAF
                                   block of ``(log(view_k + ε), v_k)``
    ===========  ================  ==========================================================
    """

    def __init__(self, width: int, log_eps: float = LOG_EPS):
        super().__init__()
        self.width, self.log_eps = width, log_eps
        self.intro = nn.Conv2d(6, width, 3, padding=1)
        self.block = NAFBlock(width)

    def forward(self, views, directions, weights=None) -> torch.Tensor:
        b, n, _, h, w = views.shape
        x = torch.cat([log_input(views, self.log_eps), directions], dim=2).reshape(b * n, 6, h, w)
        f = self.block(self.intro(x)).reshape(b, n, self.width, h, w)
        p = normalised_weights(weights, views)
        mean = (p * f).sum(dim=1)
        var = (p * (f - mean[:, None]).square()).sum(dim=1)
        return torch.cat([mean, var], dim=1)


class NormalNet(nn.Module):
    """Views → unit normals. ``forward(views, directions, weights=None) → (B, 3, H, W)``.

    ==================  ==========  ==================================================
    parameter           type        meaning
    ==================  ==========  ==================================================
    ``encoder_width``   int         F_e of the :class:`ViewEncoder`
    ``size``            NAFNetSize  backbone ``NAFNet(2·F_e → 3)``
    ``log_eps``         float       ε of the log input
    ==================  ==========  ==================================================

    Output: tangent-space (= world, on the plane) unit normals with ``n_z > 0``
    (:func:`~.transforms.unit_normal`); inputs as :class:`ViewEncoder`.
    """

    def __init__(self, encoder_width: int, size: NAFNetSize, log_eps: float = LOG_EPS):
        super().__init__()
        self.encoder = ViewEncoder(encoder_width, log_eps)
        self.net = NAFNet(2 * encoder_width, 3, size)

    def forward(self, views, directions, weights=None) -> torch.Tensor:
        return unit_normal(self.net(self.encoder(views, directions, weights)))


class SVSGNet(nn.Module):
    """Views + normals → per-pixel SG incident lighting (:class:`~.mair_lighting.PixelSGLighting`).

    ``forward(views, directions, normal, weights=None)``; ``normal`` (B, 3, H, W), the rest as
    :class:`ViewEncoder`. One ``NAFNet(2·F_e + 3 → 8·S)`` predicts per pixel and SG: 3 axis
    channels (→ :func:`~.transforms.unit_normal`, so ``ξ_z > 0``), 1 sharpness
    (``λ = λ_min (λ_max/λ_min)^sigmoid``), 1 visibility (``μ = sigmoid``) and 3 intensity channels
    whose spatial mean gives the global ``η = exp(15 tanh(·/15))`` (one RGB value per SG and image).

    ====================  ================  ==================================
    parameter             type              meaning
    ====================  ================  ==================================
    ``encoder_width``     int               F_e of the :class:`ViewEncoder`
    ``size``              NAFNetSize        backbone size
    ``num_sgs``           int               S (S_D = 3 in MAIR)
    ``sharpness_range``   (float, float)    λ_min, λ_max
    ``log_eps``           float             ε of the log input
    ====================  ================  ==================================
    """

    def __init__(
        self,
        encoder_width: int,
        size: NAFNetSize,
        num_sgs: int = 3,
        sharpness_range=(1.0, 2000.0),
        log_eps: float = LOG_EPS,
    ):
        super().__init__()
        self.num_sgs = num_sgs
        self.log_lambda = (math.log(sharpness_range[0]), math.log(sharpness_range[1]))
        self.encoder = ViewEncoder(encoder_width, log_eps)
        self.net = NAFNet(2 * encoder_width + 3, 8 * num_sgs, size)

    def forward(self, views, directions, normal, weights=None) -> PixelSGLighting:
        s = self.num_sgs
        raw = self.net(torch.cat([self.encoder(views, directions, weights), normal], dim=1))
        b, _, h, w = raw.shape
        axis = unit_normal(raw[:, : 3 * s].reshape(b * s, 3, h, w)).reshape(b, s, 3, h, w)
        lo, hi = self.log_lambda
        sharpness = torch.exp(lo + (hi - lo) * torch.sigmoid(raw[:, 3 * s : 4 * s])).reshape(b, s, 1, h, w)
        visibility = unit_interval(raw[:, 4 * s : 5 * s]).reshape(b, s, 1, h, w)
        intensity = torch.exp(soft_clamp_log(raw[:, 5 * s :].mean(dim=(2, 3)))).reshape(b, s, 3)
        return PixelSGLighting(axis, sharpness, visibility, intensity)


# -------------------------------------------------------------------------- per-pixel stages

SPEC_INPUTS = 18  # ξ 3, log λ 1, μ 1, log η 3, v 3, n 3, n·ξ, n·v, n·h, v·h


class SpecNet(nn.Module):
    """Per-view specular features from the SG lighting, the view direction and the normal.

    ==========  =================  =====================================================
    argument    shape              meaning
    ==========  =================  =====================================================
    lighting    PixelSGLighting    S SGs per pixel
    directions  (B, N, 3, H, W)    view directions v
    normal      (B, 3, H, W)       unit normals n
    → output    (B, N, F_s, H, W)  ``Σ_s MLP(ξ_s, log λ_s, μ_s, log(η_s + ε), v, n, n·ξ_s,
                                   n·v, n·h_s, v·h_s)`` with ``h_s = normalise(ξ_s + v)``
    ==========  =================  =====================================================

    Parameters: ``hidden`` width, ``layers`` hidden layers (GELU), ``features`` F_s. The dot
    products are the microfacet cues MAIR's "microfacet" variant feeds its MLP; the raw vectors
    are there too, so the MLP can learn anything they miss.
    """

    def __init__(self, hidden: int = 32, layers: int = 2, features: int = 16, log_eps: float = LOG_EPS):
        super().__init__()
        self.log_eps = log_eps
        self.mlp = mlp_layers([SPEC_INPUTS] + [hidden] * layers + [features])

    def forward(
        self, lighting: PixelSGLighting, directions: torch.Tensor, normal: torch.Tensor
    ) -> torch.Tensor:
        b, n, _, h, w = directions.shape
        s = lighting.num_sgs
        shape = (b, n, h, w, s)
        xi = lighting.axis.permute(0, 3, 4, 1, 2)[:, None]  # (B, 1, H, W, S, 3)
        lam = torch.log(lighting.sharpness).permute(0, 3, 4, 1, 2)[:, None]  # (B, 1, H, W, S, 1)
        mu = lighting.visibility.permute(0, 3, 4, 1, 2)[:, None]
        eta = torch.log(lighting.intensity + self.log_eps)[:, None, None, None]  # (B, 1, 1, 1, S, 3)
        v = directions.permute(0, 1, 3, 4, 2)[:, :, :, :, None]  # (B, N, H, W, 1, 3)
        nrm = normal.permute(0, 2, 3, 1)[:, None, :, :, None]  # (B, 1, H, W, 1, 3)
        half = F.normalize(xi + v, dim=-1, eps=1e-6)

        def dot(a, c):
            return (a * c).sum(dim=-1, keepdim=True).expand(*shape, 1)

        feats = [t.expand(*shape, t.shape[-1]) for t in (xi, lam, mu, eta, v, nrm)]
        feats += [dot(nrm, xi), dot(nrm, v), dot(nrm, half), dot(v, half)]
        out = self.mlp(torch.cat(feats, dim=-1)).sum(dim=4)  # (B, N, H, W, F_s)
        return out.permute(0, 1, 4, 2, 3)


class _ConvUnit(nn.Sequential):
    def __init__(self, cin: int, cout: int, groups: int):
        super().__init__(
            nn.Conv2d(cin, cout, 3, padding=1), nn.GroupNorm(math.gcd(groups, cout), cout), nn.GELU()
        )


def _stage(cin: int, cout: int, size: UNetSize) -> nn.Sequential:
    return nn.Sequential(*[_ConvUnit(cin if i == 0 else cout, cout, size.groups) for i in range(size.depth)])


class RefineNet(nn.Module):
    """U-Net with GroupNorm: fused features + normals → diffuse, specular, roughness (as :class:`Maps`).

    ==========  ================  =====================================================
    argument    shape             meaning
    ==========  ================  =====================================================
    features    (B, C_f, H, W)    fused MVANet features (and any per-pixel context)
    normal      (B, 3, H, W)      unit normals (input, and passed through to the maps)
    → output    Maps              ``normal``; ``diffuse``, ``specular`` (B, 3, H, W) and
                                  ``roughness`` (B, 1, H, W) in [0, 1] (sigmoid)
    ==========  ================  =====================================================

    Per level (:class:`~.mair_config.UNetSize` ``widths``): ``depth`` × (conv3×3 → GroupNorm →
    GELU); 2×2 average pooling down, a stride-2 transposed conv up, skips concatenated; a 1×1
    conv to the 7 raw channels. Inputs of any size are padded (edge replication) to a multiple of
    ``2^(levels−1)`` and cropped back. Parameters: ``in_channels`` = C_f, ``size``.
    """

    def __init__(self, in_channels: int, size: UNetSize):
        super().__init__()
        self.in_channels, self.size = in_channels, size
        widths = size.widths
        self.encoders = nn.ModuleList(
            [_stage(in_channels + 3, widths[0], size)]
            + [_stage(a, b, size) for a, b in zip(widths[:-1], widths[1:])]
        )
        self.ups = nn.ModuleList(
            [nn.ConvTranspose2d(b, a, 2, stride=2) for a, b in zip(widths[:-1], widths[1:])]
        )
        self.decoders = nn.ModuleList([_stage(2 * a, a, size) for a in widths[:-1]])
        self.ending = nn.Conv2d(widths[0], 7, 1)

    def forward(self, features: torch.Tensor, normal: torch.Tensor) -> Maps:
        if features.ndim != 4 or features.shape[1] != self.in_channels:
            raise InputError(
                f"RefineNet: features have shape {tuple(features.shape)}; expected "
                f"(B, {self.in_channels}, H, W)"
            )
        height, width = features.shape[-2:]
        x = torch.cat([features, normal], dim=1)
        multiple = 2 ** (self.size.levels - 1)
        pad_h, pad_w = (-height) % multiple, (-width) % multiple
        if pad_h or pad_w:
            x = F.pad(x, (0, pad_w, 0, pad_h), mode="replicate")
        skips = []
        for i, encoder in enumerate(self.encoders):
            x = encoder(x if i == 0 else F.avg_pool2d(x, 2))
            skips.append(x)
        for up, decoder, skip in zip(reversed(self.ups), reversed(self.decoders), reversed(skips[:-1])):
            x = decoder(torch.cat([up(x), skip], dim=1))
        raw = self.ending(x)[..., :height, :width]
        return Maps(normal, unit_interval(raw[:, :3]), unit_interval(raw[:, 3:6]), unit_interval(raw[:, 6:7]))


# ------------------------------------------------------------------------------------- model


@dataclass
class MAIROutput:
    """What :class:`MAIRModel` returns.

    ``maps``: :class:`Maps` (B, ·, H, W); ``lighting``: :class:`PixelSGLighting`;
    ``spec_features``: SpecNet output (B, N, F_s, H, W); ``fusion``: :class:`MVAOutput`.
    """

    maps: Maps
    lighting: PixelSGLighting
    spec_features: torch.Tensor
    fusion: MVAOutput


class MAIRModel(nn.Module):
    """The MAIR stages composed (see the module docstring); options in :class:`MAIRConfig`.

    ``forward(views, directions, weights=None) → MAIROutput``:

    ============  ================================  ===============================================
    argument      shape                             meaning
    ============  ================================  ===============================================
    views         (B, N, 3, H, W)                   linear radiance in the sample grid (N = 9 for
                                                    the 3×3 capture, any N ≥ 1 accepted)
    directions    (B, N, 3, H, W) or (N, 3, H, W)   per-pixel view directions
                                                    (:func:`view_direction_maps`)
    weights       (B, N, 1, H, W) or (N, 1, H, W)   per-view weights w ≥ 0 (:func:`in_frame_weights`
                                                    for rectified camera images), None: uniform
    ============  ================================  ===============================================

    The MVANet tokens are ``[log(view + ε), SpecNet features, v, n]``; RefineNet gets the fused
    features and the w-weighted mean of the log views. :data:`STAGES` names the modules MAIR trains
    in turn (normal, then lighting, then the BRDF nets); :meth:`stage_parameters` gives one
    stage's parameters to an optimiser.
    """

    STAGES = {
        "normal": ("normal_net",),
        "lighting": ("lighting_net",),
        "brdf": ("spec_net", "mva_net", "refine_net"),
    }

    def __init__(self, config: MAIRConfig | None = None):
        super().__init__()
        self.config = c = config or MAIRConfig()
        s = c.size
        self.normal_net = NormalNet(s.encoder_width, s.normal, c.log_eps)
        self.lighting_net = SVSGNet(s.encoder_width, s.lighting, c.num_sgs, c.sharpness_range, c.log_eps)
        self.spec_net = SpecNet(s.spec_hidden, s.spec_layers, s.spec_features, c.log_eps)
        self.mva_net = MVANet(
            3 + s.spec_features + 6, s.mva_dim, s.mva_heads, s.mva_depth, s.mva_mlp, s.brdf_features, c.fusion
        )
        self.refine_net = RefineNet(s.brdf_features + 3, s.refine)

    def stage_parameters(self, stage: str) -> list[nn.Parameter]:
        if stage not in self.STAGES:
            raise InputError(f"MAIRModel: unknown stage {stage!r}; use one of {', '.join(self.STAGES)}")
        return [p for name in self.STAGES[stage] for p in getattr(self, name).parameters()]

    def forward(
        self, views: torch.Tensor, directions: torch.Tensor, weights: torch.Tensor | None = None
    ) -> MAIROutput:
        directions, weights = check_inputs(views, directions, weights)
        b, n, _, h, w = views.shape
        normal = self.normal_net(views, directions, weights)
        lighting = self.lighting_net(views, directions, normal, weights)
        spec = self.spec_net(lighting, directions, normal)
        log_views = log_input(views, self.config.log_eps)
        tokens = torch.cat([log_views, spec, directions, normal[:, None].expand(b, n, 3, h, w)], dim=2)
        fusion = self.mva_net(tokens, weights)
        mean_log_view = (normalised_weights(weights, views) * log_views).sum(dim=1)
        maps = self.refine_net(torch.cat([fusion.fused, mean_log_view], dim=1), normal)
        return MAIROutput(maps, lighting, spec, fusion)


def stage_parameter_counts(config: MAIRConfig) -> dict[str, int]:
    """Trainable parameters per stage module and in total (``"total"``)."""
    model = MAIRModel(config)
    names = [name for group in MAIRModel.STAGES.values() for name in group]
    counts = {name: parameter_count(getattr(model, name)) for name in names}
    counts["total"] = parameter_count(model)
    return counts
