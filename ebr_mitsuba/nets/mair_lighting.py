"""Per-pixel spherical-Gaussian incident lighting (MAIR's "incident direct lighting", S_D SGs per pixel).

At pixel p the incident radiance from direction ω (world, z-up, the SG form of
docs/conventions.md#spherical-gaussians) is ::

    L_p(ω) = Σ_s μ_s(p) · η_s · exp(λ_s(p) (ξ_s(p)·ω − 1))

=================  =================  ===========================================================
field              shape              meaning
=================  =================  ===========================================================
``axis``           (B, S, 3, H, W)    ξ: unit lobe axes, world frame, ``ξ_z > 0`` (the plane hides
                                      the lower hemisphere)
``sharpness``      (B, S, 1, H, W)    λ ∈ [λ_min, λ_max] (``MAIRConfig.sharpness_range``)
``visibility``     (B, S, 1, H, W)    μ ∈ [0, 1]: how much of lobe s reaches p (occlusion)
``intensity``      (B, S, 3)          η: global RGB intensity of lobe s (one per image), ≥ 0
=================  =================  ===========================================================

The SGs model the unknown environment; the flash of each view is a known point light (its
position and intensity are in ``capture.json``) and is rendered separately by the re-render loss.

For the MAIR losses (:mod:`.losses`): g4 compares :meth:`PixelSGLighting.radiance_image` at a
fixed direction set (:func:`hemisphere_directions`) with the true incident radiance there through
``scale_invariant_log_mse``; g5 is ``entropy_regulariser(lighting.visibility_distribution(),
dim=1)``, the binary entropy ``−μ log μ − (1 − μ) log(1 − μ)`` that pushes visibility to 0 or 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError
from ..sgenv import SGEnvironment


def hemisphere_directions(rows: int = 8, cols: int = 16, dtype=torch.float32, device=None) -> torch.Tensor:
    """Cell centres of a ``rows × cols`` (θ, φ) grid over the upper hemisphere, ``(rows·cols, 3)``.

    Row r has polar angle ``θ = (r + ½) π / (2·rows)`` from +z, column c azimuth
    ``φ = (c + ½) 2π / cols`` from +x towards +y (MAIR evaluates its per-pixel SG lighting on an
    8 × 16 hemisphere grid). Row-major order.
    """
    if rows < 1 or cols < 1:
        raise InputError(f"hemisphere_directions: rows and cols must be ≥ 1, got {rows}×{cols}")
    theta = (torch.arange(rows, dtype=torch.float64) + 0.5) * (math.pi / (2 * rows))
    phi = (torch.arange(cols, dtype=torch.float64) + 0.5) * (2 * math.pi / cols)
    t, p = torch.meshgrid(theta, phi, indexing="ij")
    d = torch.stack([torch.sin(t) * torch.cos(p), torch.sin(t) * torch.sin(p), torch.cos(t)], dim=-1)
    return d.reshape(-1, 3).to(dtype=dtype, device=device)


@dataclass
class PixelSGLighting:
    """S SGs of incident lighting per pixel (see the module docstring for the fields' shapes)."""

    axis: torch.Tensor
    sharpness: torch.Tensor
    visibility: torch.Tensor
    intensity: torch.Tensor

    def __post_init__(self):
        a = self.axis
        if a.ndim != 5 or a.shape[2] != 3:
            raise InputError(f"PixelSGLighting: axis has shape {tuple(a.shape)}; expected (B, S, 3, H, W)")
        b, s, _, h, w = a.shape
        for name in ("sharpness", "visibility"):
            shape = tuple(getattr(self, name).shape)
            if shape != (b, s, 1, h, w):
                raise InputError(
                    f"PixelSGLighting: {name} has shape {shape}; expected ({b}, {s}, 1, {h}, {w})"
                )
        if tuple(self.intensity.shape) != (b, s, 3):
            raise InputError(
                f"PixelSGLighting: intensity has shape {tuple(self.intensity.shape)}; expected ({b}, {s}, 3)"
            )

    @property
    def num_sgs(self) -> int:
        return int(self.axis.shape[1])

    @property
    def amplitude(self) -> torch.Tensor:
        """Per-pixel RGB amplitude ``μ_s(p) η_s``, ``(B, S, 3, H, W)``."""
        return self.visibility * self.intensity[..., None, None]

    def radiance(self, directions: torch.Tensor) -> torch.Tensor:
        """Incident radiance ``L_p(ω_d)`` at D world directions ``(D, 3)`` (unit): ``(B, D, 3, H, W)``."""
        if directions.ndim != 2 or directions.shape[1] != 3:
            raise InputError(
                f"PixelSGLighting.radiance: directions have shape {tuple(directions.shape)}; expected (D, 3)"
            )
        d = directions.to(self.axis)
        cos = torch.einsum("dc,bschw->bdshw", d, self.axis)  # (B, D, S, H, W)
        lobes = torch.exp(self.sharpness[:, None, :, 0] * (cos - 1.0))  # (B, D, S, H, W)
        return torch.einsum("bdshw,bschw->bdchw", lobes, self.amplitude)

    def radiance_image(self, directions: torch.Tensor) -> torch.Tensor:
        """:meth:`radiance` in image layout ``(B, 3D, H, W)`` (direction-major), for the g4 loss."""
        r = self.radiance(directions)
        return r.reshape(r.shape[0], -1, *r.shape[-2:])

    def visibility_distribution(self) -> torch.Tensor:
        """``(μ, 1 − μ)`` stacked on dim 1, ``(B, 2, S, H, W)``: the input of the g5 entropy loss."""
        mu = self.visibility[:, :, 0]
        return torch.stack([mu, 1.0 - mu], dim=1)

    def detach(self) -> PixelSGLighting:
        return PixelSGLighting(
            self.axis.detach(), self.sharpness.detach(), self.visibility.detach(), self.intensity.detach()
        )

    def pixel_environment(
        self, index: int = 0, row: int | None = None, col: int | None = None
    ) -> SGEnvironment:
        """The S lobes at one pixel (default: the centre) of batch element ``index`` as an
        :class:`~ebr_mitsuba.sgenv.SGEnvironment` (``env.json``), amplitude ``μ η``."""
        h, w = self.axis.shape[-2:]
        row = h // 2 if row is None else row
        col = w // 2 if col is None else col
        if not (0 <= row < h and 0 <= col < w):
            raise InputError(f"PixelSGLighting.pixel_environment: pixel ({row}, {col}) outside {h}×{w}")

        def at(t):
            return t[index, :, :, row, col].detach().to("cpu", torch.float64).numpy()

        return SGEnvironment(at(self.axis), at(self.sharpness)[:, 0], np.asarray(at(self.amplitude)))
