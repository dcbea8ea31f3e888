"""Two-Shot-style baseline: fixed Fibonacci axes, one shared sharpness, amplitudes only.

``count`` (24) axes on a Fibonacci sphere, every lobe with the same sharpness, and non-negative
amplitudes solved in closed form (:func:`ebr_mitsuba.extract.amplitudes.nnls`) against the
exemplars, with the loss's per-exemplar weighting (λ_i/‖y_i‖). The unit-lobe basis is rendered
with the fast renderer's quadrature (``spp`` directions: the closed form's bias for rough
exemplars would go straight into the amplitudes), on a 48² pixel grid per exemplar. The shared
sharpness is the best of ``sharpness`` (by the weighted residual): the baseline is given its
best setting, not a guessed one.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from ..envfit import fibonacci_sphere
from ..geometry import Shot, near_shot
from ..sgenv import SGEnvironment
from .pipeline import AMPLITUDE_GRID, ExtractResult, check_exemplars, to_environment

BASELINE_LOBES = 24
BASELINE_SHARPNESS = (2.0, 4.0, 8.0, 16.0, 32.0)


def fibonacci_nnls(
    exemplars: np.ndarray,
    roughness: Sequence[float],
    *,
    count: int = BASELINE_LOBES,
    sharpness: Sequence[float] = BASELINE_SHARPNESS,
    spp: int = 64,
    shot: Shot | None = None,
) -> ExtractResult:
    """The baseline (module docstring); returns an :class:`ExtractResult` (0 iterations; its
    ``rel_rmse_exemplars`` is measured at the solve's pixel grid with the quadrature basis)."""
    from ..render.inputs import RenderOptions
    from ..variant import ensure_variant
    from .amplitudes import lobe_basis, nnls
    from .forward import ExemplarGeometry, centre_indices

    t0 = time.perf_counter()
    images, r = check_exemplars(exemplars, roughness)
    scale = float(images.mean())
    if not scale > 1e-30:
        return ExtractResult(SGEnvironment.empty(), 0, time.perf_counter() - t0, 0.0, [], {})
    ensure_variant()
    n, h, w, _ = images.shape
    y = (images / scale).reshape(-1, 3)
    geometry = ExemplarGeometry(r.astype(np.float32), h, w, shot or near_shot(False))
    index = centre_indices(n, h, w, AMPLITUDE_GRID)
    per = y.reshape(n, -1, 3)
    rms = np.sqrt((per**2).sum(-1).mean(1))
    row_w = (1.0 / np.maximum(rms, 1e-30))[index // (h * w)]
    axis = fibonacci_sphere(count)
    options = RenderOptions(mode="quadrature", spp=spp)
    best = None
    for lam in sharpness:
        basis = lobe_basis(geometry, axis, np.full(count, float(lam)), index, options)
        a = (basis * row_w[None, :]).T
        b = y[index] * row_w[:, None]
        amp = nnls(a, b)
        res = float(np.linalg.norm(a @ amp - b))
        if best is None or res < best[0]:
            best = (res, float(lam), amp, basis)
    _, lam, amp, basis = best
    model = basis.T @ amp
    err = float(np.linalg.norm(model - y[index]) / max(np.linalg.norm(y[index]), 1e-300))
    env = to_environment((axis, np.full(count, lam), amp), scale)
    return ExtractResult(env, 0, time.perf_counter() - t0, err, [], {"solve": time.perf_counter() - t0})
