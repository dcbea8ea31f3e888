"""The cascade's two renderers, built the same way for training and inference.

* ``render_diffuse_flash(normal, diffuse)`` (specular image = flash-only − this):
  :func:`ebr_mitsuba.nets.torch_brdf.near_flash_diffuse` at the data set's nominal flash intensity.
  The photos' exposure is unknown at inference, so no exposure is applied (the network sees the
  residual exposure factor, ±0.5 EV in the shipped training data, in its inputs and learns it).
* ``render_photos(maps) -> (B, 3P, H, W)`` (the refinement's residuals), photos in the order
  (flash, no-flash[, far flash, far no-flash]):

  ``flash = k · R_point(maps, I = 1) + R_env(maps, lobes)``, ``no-flash = R_env(maps, lobes)``

  where ``R_env`` is the Dr.Jit closed-form SG render through ``dr.wrap``
  (:func:`ebr_mitsuba.nets.drwrap.render_maps`; gradients reach the maps), ``R_point`` the exact
  torch point-light render, and ``k`` per sample the least-squares flash scale
  ``k = Σ f·r / Σ r²`` of the flash-only image ``f`` against ``r = R_point(maps, I = 1)``
  (:func:`flash_scale`, no gradient): it absorbs flash intensity × exposure, which photos do not
  record. The lobes are in the photos' units: the ground truth × exposure × white balance in
  stage 1 (:func:`photo_unit_lobes`), the SGs extracted from the (photo-unit) exemplars in stage 2
  and at inference.

  Near-far (P = 4): the far pair is rendered from the far camera (``far_shot``) with its own ``k``,
  fitted to the far flash-only image :func:`far_flash_only` = ``max(far flash − far no-flash, 0)``
  of the photos (no network predicts it), in training as at inference.

Full-resolution inference (:mod:`ebr_mitsuba.estimate.fullres`) runs the cascade over an image
finer than the grid, or over a tile of one: ``window = (row0, col0, full_h, full_w)`` says which
block of the full sample grid the maps are, and both renderers then shade each pixel at its true
position (docs/conventions.md, "Geometry and pixel grid": view and light directions of the full
frame, not of a frame the size of the tile), through the Dr.Jit renderer (flash terms included:
the torch mirror was 5× slower at megapixels); ``scales = (k_near, k_far)`` fixes the flash
scales (fitted once per capture) instead of fitting them to each pass (required with a window).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from ..errors import InputError
from ..geometry import far_shot, near_shot
from ..nets import Maps
from ..nets import torch_brdf as tb


def photo_unit_lobes(lobes: Sequence[torch.Tensor], gains: torch.Tensor) -> list[torch.Tensor]:
    """Lobes (K_b, 7) with the amplitudes multiplied by per-sample RGB gains (B, 3)."""
    out = []
    for b, lb in enumerate(lobes):
        lb = lb.clone()
        lb[:, 4:7] = lb[:, 4:7] * gains[b].to(lb.dtype)
        out.append(lb)
    return out


def _point(maps: Maps, far: bool) -> torch.Tensor:
    shot = far_shot(True) if far else near_shot(True)
    return tb.render_point_light(maps, shot.flash, 1.0, shot.camera)


def _flash_render(maps: Maps, far: bool, intensity: float, options) -> torch.Tensor:
    """``intensity · R_point(maps)`` through the Dr.Jit renderer (the flash term alone; its window
    in ``options``): the full-resolution path, where the torch mirror is several times slower."""
    import dataclasses

    from ..nets.drwrap import render_maps

    shot = dataclasses.replace(
        far_shot(True) if far else near_shot(True), flash_intensity=float(intensity), env=False
    )
    return render_maps(maps, None, shot, options)


@torch.no_grad()
def flash_scale(maps: Maps, flash_only: torch.Tensor, far: bool = False) -> torch.Tensor:
    """Per-sample least-squares ``k`` (B,) with ``k · R_point(maps, I = 1) ≈ flash_only`` (≥ 0)."""
    r = _point(maps.detach(), far)
    num = (r * flash_only).sum(dim=(1, 2, 3))
    den = (r * r).sum(dim=(1, 2, 3)).clamp_min(1e-12)
    return (num / den).clamp_min(0.0)


def far_flash_only(far_flash: torch.Tensor, far_noflash: torch.Tensor) -> torch.Tensor:
    """The far flash-only image of a near-far capture from its photos (any matching shapes):
    ``max(max(far flash, 0) − max(far no-flash, 0), 0)``, as :func:`.predict.predict` forms it."""
    return (far_flash.clamp_min(0.0) - far_noflash.clamp_min(0.0)).clamp_min(0.0)


def _window_options(options, window):
    import dataclasses

    from ..render import RenderOptions

    options = options or RenderOptions()
    if window is not None:
        options = dataclasses.replace(options, window=tuple(int(v) for v in window))
    return options


def diffuse_flash_renderer(intensity: float, window=None, options=None) -> Callable:
    """``render_diffuse_flash(normal, diffuse)``: the near flash's diffuse render. With a
    ``window`` (full-resolution inference) through the Dr.Jit renderer at the block's true pixel
    positions (specular 0 and Fresnel off: exactly ``d/π · cos · I/d²``); else the torch mirror."""
    if window is None:
        return tb.near_flash_diffuse(intensity)
    import dataclasses

    opts = dataclasses.replace(_window_options(options, window), fresnel="none")

    def render_diffuse_flash(normal: torch.Tensor, diffuse: torch.Tensor) -> torch.Tensor:
        zeros = torch.zeros_like(diffuse)
        maps = Maps(normal, diffuse, zeros, zeros[:, :1])
        return _flash_render(maps, False, intensity, opts)

    return render_diffuse_flash


def photo_renderer(
    lobes: Sequence[torch.Tensor | None],
    flash_only: torch.Tensor,
    far_flash_only: torch.Tensor | None = None,
    num_photos: int = 2,
    *,
    window=None,
    scales: tuple | None = None,
    options=None,
) -> Callable[[Maps], torch.Tensor]:
    """``render_photos`` for :class:`ebr_mitsuba.nets.Cascade` (see the module docstring).

    ``lobes``: per sample (K_b, 7) in photo units (None / K = 0: no environment); ``flash_only``
    (B, 3, H, W): the flash-only image the flash scale is fitted to (``far_flash_only`` for the far
    pair when ``num_photos`` = 4). ``window``, ``scales``: see the module docstring;
    ``options``: :class:`ebr_mitsuba.render.RenderOptions` of the environment render (its window
    is set from ``window``).
    """
    from ..nets.drwrap import render_maps

    options = _window_options(options, window)
    if window is not None and scales is None:
        raise InputError("photo_renderer: a window (part of a larger image) needs the capture's flash scales")

    def render_photos(maps: Maps) -> torch.Tensor:
        out = []
        for far in (False, True) if num_photos == 4 else (False,):
            env = render_maps(maps, lobes, far_shot(False) if far else near_shot(False), options)
            if scales is not None and scales[int(far)] is not None:
                flash = _flash_render(maps, far, scales[int(far)], options)
            else:
                k = flash_scale(maps, far_flash_only if far else flash_only, far)
                flash = k[:, None, None, None] * _point(maps, far)
            out += [flash + env, env]
        return torch.cat(out, dim=1)

    return render_photos


def cascade_forward(
    cascade,
    noflash: torch.Tensor,
    flash_only: torch.Tensor,
    env_exemplars: torch.Tensor | None,
    point_exemplars: torch.Tensor | None,
    photos: torch.Tensor,
    lobes: Sequence[torch.Tensor | None],
    flash_intensity: float,
    far_flash_only: torch.Tensor | None = None,
    *,
    window=None,
    scales: tuple | None = None,
    options=None,
):
    """Run :class:`ebr_mitsuba.nets.Cascade` with the renderers of this module (training and
    inference call this one function). Shapes as in :meth:`Cascade.forward`; ``lobes`` per sample
    in photo units; ``photos`` (B, 3P, H, W) in the order of the module docstring;
    ``far_flash_only`` (B, 3, H, W): :func:`far_flash_only` of the far pair, needed when P = 4.
    ``window``, ``scales``, ``options``: full-resolution inference (module docstring,
    :func:`photo_renderer`)."""
    c = cascade.config if not hasattr(cascade, "module") else cascade.module.config
    if c.num_photos == 4 and c.use_refinement and far_flash_only is None:
        raise InputError(
            "cascade_forward: a near-far cascade needs far_flash_only (far flash − far no-flash)"
        )
    return cascade(
        noflash,
        flash_only,
        env_exemplars if c.use_exemplars else None,
        point_exemplars if c.use_exemplars else None,
        render_diffuse_flash=diffuse_flash_renderer(flash_intensity, window, options),
        photos=photos,
        render_photos=photo_renderer(
            lobes, flash_only, far_flash_only, c.num_photos, window=window, scales=scales, options=options
        ),
    )


__all__ = [
    "cascade_forward",
    "diffuse_flash_renderer",
    "far_flash_only",
    "flash_scale",
    "photo_renderer",
    "photo_unit_lobes",
]
