"""Densification: new lobes where an MS-SSIM error map shows under-represented light.

For each exemplar i the current model ŷ_i and the target y_i are tone-mapped to [0, 1) by
``x / (x + mean(y_i))`` and compared with :func:`ebr_mitsuba.extract.msssim.ms_ssim_error`; the
score of a pixel is that error times the *missing* light ``lum(max(y − ŷ, 0)) / mean lum(y_i)``
(light the model lacks, not light it has too much of: that is the optimiser's job). The highest
scores above ``threshold`` over all exemplars, at least ``H/8`` pixels apart within an exemplar,
get one new lobe each (at most ``count``): axis the mirror direction at that pixel, sharpness
``min(λ_w(r_i)/2, λ₃)`` (the exemplar's own resolution limit, at most the level-3 table value)
and amplitude ``missing / (F₀ · λ_w/(λ_w + λ))`` as in the initialisation.
"""

from __future__ import annotations

import numpy as np

from ..colour import LUMINANCE
from ..exemplar import EXEMPLAR_SPECULAR
from .forward import ExemplarGeometry
from .init import brdf_sharpness, level_sharpness, span_angle
from .msssim import ms_ssim_error


def error_maps(model: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Score maps (N, H, W) (module docstring) of ``model`` and ``targets`` (N, H, W, 3)."""
    out = np.zeros(targets.shape[:3])
    for i, (yh, y) in enumerate(zip(model, targets)):
        mean = max(float(y.mean()), 1e-30)
        err = ms_ssim_error(yh / (yh + mean), y / (y + mean), data_range=1.0)
        missing = np.maximum(y - yh, 0.0) @ LUMINANCE / max(float((y @ LUMINANCE).mean()), 1e-30)
        out[i] = err * missing
    return out


def densify_lobes(
    model: np.ndarray, targets: np.ndarray, geometry: ExemplarGeometry, count: int, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """New lobes (axis (M, 3), sharpness (M,), amplitude (M, 3)), M ≤ ``count``."""
    empty = (np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))
    if count <= 0:
        return empty
    scores = error_maps(model, targets)
    n, h, w = scores.shape
    radius = max(h // 8, 1)
    theta0 = span_angle(geometry)
    axes, sharp, amps = [], [], []
    s = scores.copy()
    while len(axes) < count:
        flat = int(np.argmax(s))
        i, row, col = np.unravel_index(flat, s.shape)
        if not s[i, row, col] > threshold:
            break
        s[i, max(row - radius, 0) : row + radius + 1, max(col - radius, 0) : col + radius + 1] = -1.0
        lam_w = brdf_sharpness(float(geometry.roughness[i]))
        lam = float(min(0.5 * lam_w, level_sharpness(3, theta0)))
        lam = max(lam, 0.5)
        missing = np.maximum(targets[i, row, col] - model[i, row, col], 0.0)
        axes.append(geometry.mirror_axes(np.array([row + 0.5]), np.array([col + 0.5]))[0])
        sharp.append(lam)
        amps.append(missing / (EXEMPLAR_SPECULAR * lam_w / (lam_w + lam)))
    if not axes:
        return empty
    return np.array(axes), np.array(sharp), np.array(amps)
