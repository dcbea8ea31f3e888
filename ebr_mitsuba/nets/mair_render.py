"""Re-renders of MAIR's outputs for the multi-view re-render loss (torch, differentiable).

Each view k of the 3×3 capture is lit by the environment and by its own flash, co-located with
its camera. From the predicted maps and per-pixel SG lighting (:class:`.mair_lighting.PixelSGLighting`)
:func:`multiview_renders` gives, per view, the diffuse part ``Ĩ_d,k`` and the specular part
``Ĩ_s,k`` of the re-render, with the one BRDF of :mod:`.torch_brdf`:

* **environment**: each SG lobe s of pixel p acts as a directional light from its axis ``ξ_s(p)``
  carrying the lobe's integral ``μ_s η_s · 2π/λ_s (1 − e^{−2λ_s})`` (exact for sharp lobes, the
  usual point-light reading of an SG otherwise; no quadrature, so it costs S BRDF evaluations per
  view and pixel);
* **flash**: an isotropic point light of the data set's flash intensity at the camera,
  ``f(v, v) (n·v) I / ‖c_k − p‖²``.

The MAIR loss (:func:`.losses.multiview_rerender_loss`) fits the scales ``τ_d``, ``τ_s`` by least
squares, so a global error of the lighting's intensity is not blamed on the maps.
"""

from __future__ import annotations

import math

import torch

from ..errors import InputError
from . import torch_brdf as tb
from .mair_lighting import PixelSGLighting
from .maps import Maps


def sg_integral(sharpness: torch.Tensor) -> torch.Tensor:
    """``∫ exp(λ(ξ·ω − 1)) dω = 2π/λ (1 − e^{−2λ})`` over the sphere, elementwise."""
    return (2.0 * math.pi) * (-torch.expm1(-2.0 * sharpness)) / sharpness


def multiview_renders(
    maps: Maps,
    lighting: PixelSGLighting,
    directions: torch.Tensor,
    cameras: torch.Tensor,
    flash_intensity: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Diffuse and specular re-renders of every view, each ``(B, N, 3, H, W)``.

    ===============  ====================  ==================================================
    argument         shape                 meaning
    ===============  ====================  ==================================================
    maps             Maps (B, ·, H, W)     predicted normal, diffuse, specular, roughness
    lighting         PixelSGLighting       per-pixel SGs (S lobes, B images)
    directions       (N, 3, H, W) or       view directions v of each pixel
                     (B, N, 3, H, W)       (:func:`.mair_views.view_direction_maps`)
    cameras          (N, 3)                camera (= flash) positions, world
    flash_intensity  float                 W/sr of each view's flash (reference exposure)
    ===============  ====================  ==================================================
    """
    b, _, h, w = maps.normal.shape
    if directions.ndim == 4:
        directions = directions[None]
    n_views = directions.shape[1]
    if tuple(cameras.shape) != (n_views, 3):
        raise InputError(
            f"multiview_renders: cameras have shape {tuple(cameras.shape)}; expected ({n_views}, 3)"
        )
    like = maps.normal
    # channel-last, dims (B, N, S, H, W, 3)
    n = tb.perturbed_normal(maps.normal.permute(0, 2, 3, 1))[:, None, None]
    dif = maps.diffuse.permute(0, 2, 3, 1)[:, None, None]
    spec = maps.specular.permute(0, 2, 3, 1)[:, None, None]
    rough = maps.roughness[:, 0][:, None, None]
    v = directions.to(like).permute(0, 1, 3, 4, 2)[:, :, None]
    light = lighting.axis.permute(0, 1, 3, 4, 2)[:, None]
    power = (lighting.amplitude * sg_integral(lighting.sharpness)).permute(0, 1, 3, 4, 2)[:, None]
    cos_l = (n * light).sum(dim=-1, keepdim=True).clamp_min(0.0)
    env_d = (tb.diffuse_eval_cos(n, light, v, dif) * power).sum(dim=2)
    env_s = (tb.specular_term(n, light, v, spec, rough) * cos_l * power).sum(dim=2)
    # the flash of view k at its camera: l = v
    p = tb.grid_positions(h, w, like.device, like.dtype)
    to_cam = cameras.to(like)[:, None, None, :] - p[None]  # (N, H, W, 3)
    scale = flash_intensity / (to_cam * to_cam).sum(dim=-1, keepdim=True)  # (N, H, W, 1)
    n0, v0 = n[:, :, 0], v[:, :, 0]
    cos_v = (n0 * v0).sum(dim=-1, keepdim=True).clamp_min(0.0)
    flash_d = tb.diffuse_eval_cos(n0, v0, v0, dif[:, :, 0]) * scale
    flash_s = tb.specular_term(n0, v0, v0, spec[:, :, 0], rough[:, :, 0]) * cos_v * scale
    diffuse = (env_d + flash_d).expand(b, n_views, h, w, 3).permute(0, 1, 4, 2, 3)
    specular = (env_s + flash_s).expand(b, n_views, h, w, 3).permute(0, 1, 4, 2, 3)
    return diffuse, specular


__all__ = ["multiview_renders", "sg_integral"]
