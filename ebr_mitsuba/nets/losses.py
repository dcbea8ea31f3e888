"""Training losses (pure functions; weights are arguments, never hidden in a model).

Shapes: images and maps in image layout ``(B, C, H, W)``; masks ``(B, 1, H, W)`` (or broadcastable)
with weights in [0, 1] (usually 0/1); scalars are 0-d tensors. Map sets are :class:`~.maps.Maps`.

* :func:`parameter_l1` — per-map mean absolute error and their weighted sum;
* :func:`sample_view_light_pairs` + :func:`rendering_loss` — the dual-loss rendering term:
  L1 between ``log(x + 1)`` of renders of the predicted and the true maps under random
  view/light pairs, half of them with a forced highlight;
* MAIR multi-view losses: :func:`masked_angular_l1`, :func:`masked_mse`,
  :func:`least_squares_scale`, :func:`scale_invariant_mse`, :func:`scale_invariant_log_mse`,
  :func:`entropy_regulariser`, :func:`multiview_rerender_loss`.

The network input log transforms live in :mod:`.transforms` (re-exported here).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields

import torch

from ..errors import ConfigError, InputError
from .maps import MAP_LAYOUT, Maps
from .transforms import log_input, log_ratio, signed_log

__all__ = [
    "MapWeights",
    "parameter_l1",
    "ViewLightPairs",
    "sample_view_light_pairs",
    "rendering_loss",
    "masked_angular_l1",
    "masked_mse",
    "least_squares_scale",
    "scale_invariant_mse",
    "scale_invariant_log_mse",
    "entropy_regulariser",
    "multiview_rerender_loss",
    "log_input",
    "log_ratio",
    "signed_log",
    "RENDER_DISTANCE",
]

# light/camera distance of the rendering loss and the re-render metric (docs/conventions.md, "Metrics")
RENDER_DISTANCE = 2.14

Mask = torch.Tensor | None
RenderFn = Callable[[Maps, torch.Tensor, torch.Tensor], torch.Tensor]
"""``(maps, camera (B, 3), light (B, 3)) -> radiance (B, 3, H, W)``, e.g.
``lambda m, cam, light: torch_brdf.render_point_light(m, light, intensity, cam)``."""


@dataclass(frozen=True)
class MapWeights:
    """Weights of the per-map terms of :func:`parameter_l1` (all 1 by default)."""

    normal: float = 1.0
    diffuse: float = 1.0
    specular: float = 1.0
    roughness: float = 1.0

    def __post_init__(self):
        for f in fields(self):
            if getattr(self, f.name) < 0:
                raise ConfigError(f"MapWeights: {f.name} weight must be ≥ 0, got {getattr(self, f.name)}")


def parameter_l1(pred: Maps, target: Maps, weights: MapWeights | None = None) -> tuple[torch.Tensor, dict]:
    """``L = Σ_m w_m · mean|pred_m − target_m|`` over m ∈ {normal, diffuse, specular, roughness}.

    ``weights`` defaults to :class:`MapWeights` (all 1).
    Returns ``(L, {map name: mean |error|})`` (each a 0-d tensor). Normals are compared as vectors
    in [-1, 1] (the L1 of the (n+1)/2 encoding is half of it).
    """
    weights = weights or MapWeights()
    per_map = {name: (getattr(pred, name) - getattr(target, name)).abs().mean() for name, _ in MAP_LAYOUT}
    total = sum(getattr(weights, name) * value for name, value in per_map.items())
    return total, per_map


@dataclass
class ViewLightPairs:
    """Random camera/light positions for :func:`rendering_loss`.

    ``cameras``, ``lights``: (B, K, 3) world positions; ``highlight``: (K,) bool, True for the
    forced-highlight pairs; ``points``: (B, K, 3) the surface point of each forced highlight
    (the origin for the other pairs).
    """

    cameras: torch.Tensor
    lights: torch.Tensor
    highlight: torch.Tensor
    points: torch.Tensor

    @property
    def count(self) -> int:
        return int(self.highlight.shape[0])


def _cosine_hemisphere(shape, generator, dtype, device) -> torch.Tensor:
    """Cosine-weighted directions about +z, ``(*shape, 3)``: ``(√u cos φ, √u sin φ, √(1−u))``."""
    u = torch.rand(*shape, 2, generator=generator, dtype=dtype, device=device)
    r = torch.sqrt(u[..., 0])
    phi = 2.0 * math.pi * u[..., 1]
    z = torch.sqrt((1.0 - u[..., 0]).clamp_min(0.0))
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], dim=-1)


def sample_view_light_pairs(
    batch: int,
    generator: torch.Generator,
    count: int = 10,
    highlights: int = 5,
    distance: float = RENDER_DISTANCE,
    dtype=torch.float32,
    device=None,
) -> ViewLightPairs:
    """Draw ``count`` view/light pairs per batch element; the last ``highlights`` force a highlight.

    Ordinary pair: camera ``= distance · ω_v``, light ``= distance · ω_l`` with independent
    cosine-hemisphere directions ``ω`` about +z (positions relative to the sample centre).
    Forced-highlight pair: camera ``= distance · ω_v``; a surface point ``p`` uniform on the sample
    ``[-1,1]² × {0}``; ``v = normalise(camera − p)``; the light sits at ``p + distance · l`` with
    ``l = (−v_x, −v_y, v_z)``, the mirror of ``v`` about the **geometric** normal +z at ``p``, so
    the half vector at ``p`` is +z and a near-flat sample shows its highlight at ``p``. (Mirroring
    about the shading normal could put the light below the horizon.)

    All randomness comes from ``generator`` (seed it for reproducible losses).
    """
    if not 0 <= highlights <= count or count < 1:
        raise ConfigError(
            f"sample_view_light_pairs: need 0 ≤ highlights ≤ count and count ≥ 1, got "
            f"highlights={highlights}, count={count}"
        )
    plain = count - highlights
    cameras = distance * _cosine_hemisphere((batch, count), generator, dtype, device)
    lights = distance * _cosine_hemisphere((batch, count), generator, dtype, device)
    xy = 2.0 * torch.rand(batch, count, 2, generator=generator, dtype=dtype, device=device) - 1.0
    points = torch.cat([xy, torch.zeros_like(xy[..., :1])], dim=-1)
    v = cameras - points
    v = v / torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    mirrored = points + distance * torch.cat([-v[..., :2], v[..., 2:]], dim=-1)
    highlight = torch.arange(count, device=device) >= plain
    lights = torch.where(highlight[None, :, None], mirrored, lights)
    points = torch.where(highlight[None, :, None], points, torch.zeros_like(points))
    return ViewLightPairs(cameras, lights, highlight, points)


def rendering_loss(pred: Maps, target: Maps, pairs: ViewLightPairs, render: RenderFn) -> torch.Tensor:
    """``L = 1/K Σ_k mean| log(1 + R(pred; c_k, l_k)) − log(1 + R(target; c_k, l_k)) |``.

    ``render(maps, camera (B, 3), light (B, 3)) -> (B, 3, H, W)`` is passed in (torch renderer or a
    ``dr.wrap``-ed Dr.Jit one); the target renders carry no gradient.
    """
    total = pred.normal.new_zeros(())
    for k in range(pairs.count):
        cam, light = pairs.cameras[:, k], pairs.lights[:, k]
        with torch.no_grad():
            ref = torch.log1p(render(target, cam, light).clamp_min(0.0))
        est = torch.log1p(render(pred, cam, light).clamp_min(0.0))
        total = total + (est - ref).abs().mean()
    return total / pairs.count


def _mask_like(mask: Mask, x: torch.Tensor) -> torch.Tensor:
    if mask is None:
        return torch.ones_like(x[:, :1])
    if (
        mask.ndim != 4
        or mask.shape[0] != x.shape[0]
        or mask.shape[2:] != x.shape[2:]
        or mask.shape[1] not in (1, x.shape[1])
    ):
        raise InputError(
            f"mask has shape {tuple(mask.shape)}; expected ({x.shape[0]}, 1, {x.shape[2]}, {x.shape[3]})"
        )
    return mask.to(x.dtype)


def masked_angular_l1(pred: torch.Tensor, target: torch.Tensor, mask: Mask = None) -> torch.Tensor:
    """Mean angle (radians) between normals over the mask:
    ``Σ m·atan2(‖n̂ × n‖, n̂·n) / Σ m``.

    ``pred``, ``target``: (B, 3, H, W), need not be unit (the angle is scale-free); ``atan2`` keeps
    value and gradient finite near 0 and π where ``acos`` is not (``‖n̂ × n‖`` gets 1e-12 under the
    root, so equal normals give 1e-6 rad per unit length², not 0).
    """
    m = _mask_like(mask, pred)[:, :1]
    cross = torch.linalg.cross(pred, target, dim=1)
    sin = torch.sqrt(cross.square().sum(dim=1, keepdim=True) + 1e-12)
    cos = (pred * target).sum(dim=1, keepdim=True)
    angle = torch.atan2(sin, cos)
    return (m * angle).sum() / m.sum().clamp_min(1e-8)


def masked_mse(pred: torch.Tensor, target: torch.Tensor, mask: Mask = None) -> torch.Tensor:
    """``Σ m (ŷ − y)² / (C · Σ m)`` over all pixels, channels and the batch."""
    m = _mask_like(mask, pred)
    err = m * (pred - target).square()
    denom = m.expand_as(pred).sum()
    return err.sum() / denom.clamp_min(1e-8)


def least_squares_scale(pred: torch.Tensor, target: torch.Tensor, mask: Mask = None) -> torch.Tensor:
    """Per-sample ``τ = argmin_τ Σ m (τŷ − y)² = Σ m ŷ y / Σ m ŷ²`` (closed form), shape (B, 1, 1, 1)."""
    m = _mask_like(mask, pred)
    num = (m * pred * target).sum(dim=(1, 2, 3), keepdim=True)
    den = (m * pred * pred).sum(dim=(1, 2, 3), keepdim=True)
    return num / den.clamp_min(1e-12)


def scale_invariant_mse(pred: torch.Tensor, target: torch.Tensor, mask: Mask = None) -> torch.Tensor:
    """``masked_mse(τ ŷ, y)`` with the per-sample least-squares scale τ (zero when ``y = c ŷ``)."""
    tau = least_squares_scale(pred, target, mask)
    return masked_mse(tau * pred, target, mask)


def scale_invariant_log_mse(pred: torch.Tensor, target: torch.Tensor, mask: Mask = None) -> torch.Tensor:
    """``masked_mse(log(τ ŷ + 1), log(y + 1))`` with τ from :func:`least_squares_scale`.

    Inputs are non-negative (radiance, albedo), so τ ≥ 0 and the logs are defined.
    """
    tau = least_squares_scale(pred, target, mask)
    return masked_mse(torch.log1p((tau * pred).clamp_min(0.0)), torch.log1p(target.clamp_min(0.0)), mask)


def entropy_regulariser(
    weights: torch.Tensor, dim: int = 1, mask: Mask = None, eps: float = 1e-12
) -> torch.Tensor:
    """Mean Shannon entropy ``H = −Σ_k p_k log p_k`` of ``p = w / Σ_k w`` along ``dim``.

    ``weights``: non-negative, e.g. (B, K, H, W) per-pixel mixture or attention weights over K
    items; ``mask``: broadcastable to the weights with ``dim`` reduced (e.g. (B, 1, H, W)).
    Minimising it makes each distribution peaked (uniform over K gives ``log K``, one-hot 0).
    """
    w = weights.clamp_min(0.0)
    p = w / w.sum(dim=dim, keepdim=True).clamp_min(eps)
    ent = -(p * torch.log(p.clamp_min(eps))).sum(dim=dim, keepdim=True)
    if mask is None:
        return ent.mean()
    m = mask.to(ent.dtype).expand_as(ent)
    return (m * ent).sum() / m.sum().clamp_min(1e-8)


def multiview_rerender_loss(
    views: torch.Tensor,
    diffuse: torch.Tensor,
    specular: torch.Tensor,
    weights: torch.Tensor | None = None,
    ridge: float = 1e-6,
) -> tuple[torch.Tensor, torch.Tensor]:
    """MAIR's re-render loss ``Σ_k w_k ‖I_k − τ_d Ĩ_d,k − τ_s Ĩ_s,k‖² / (3 Σ_k w_k)``.

    ``views`` I, ``diffuse`` Ĩ_d and ``specular`` Ĩ_s: (B, N, 3, H, W) (N views); ``weights`` w:
    (B, N, 1, H, W) or None (all 1). Per sample, ``(τ_d, τ_s)`` minimise the weighted squared error
    (the 2×2 normal equations in closed form, ``ridge`` × their trace added to the diagonal so that a
    render without specular part stays solvable); gradients flow through τ as through
    :func:`least_squares_scale`. Returns ``(loss, τ (B, 2))``.
    """
    if views.ndim != 5 or diffuse.shape != views.shape or specular.shape != views.shape:
        raise InputError(
            f"multiview_rerender_loss: views {tuple(views.shape)}, diffuse {tuple(diffuse.shape)} and "
            f"specular {tuple(specular.shape)} must all be (B, N, 3, H, W)"
        )
    w = torch.ones_like(views[:, :, :1]) if weights is None else weights.to(views.dtype)
    dims = (1, 2, 3, 4)
    a = (w * diffuse * diffuse).sum(dims)
    b = (w * diffuse * specular).sum(dims)
    c = (w * specular * specular).sum(dims)
    y_d = (w * diffuse * views).sum(dims)
    y_s = (w * specular * views).sum(dims)
    eps = ridge * (a + c) + 1e-12
    a, c = a + eps, c + eps
    det = a * c - b * b
    tau_d = (c * y_d - b * y_s) / det
    tau_s = (a * y_s - b * y_d) / det
    shape = (-1, 1, 1, 1, 1)
    fit = tau_d.view(shape) * diffuse + tau_s.view(shape) * specular
    w = w.expand_as(views[:, :, :1])
    loss = masked_mse(fit.flatten(0, 1), views.flatten(0, 1), w.flatten(0, 1))
    return loss, torch.stack([tau_d, tau_s], dim=1)
