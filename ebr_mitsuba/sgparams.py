"""Spherical-Gaussian lobes as unconstrained parameters for gradient descent, and back.

The SG optimisers (``ebr extract-sg``'s Adam stage, ``ebr fit-env``, the lobes of the test-time
refinement, :mod:`ebr_mitsuba.estimate.refine`) work on

=================  =====================================  ==================================================
parameter          from a lobe (:func:`encode`)           back to a lobe (:func:`decode`, :func:`dr_decode`)
=================  =====================================  ==================================================
``axis``           ξ as a free 3-vector (float32)         normalised where it is used
``log_sharpness``  log clamp(λ, λ_min, λ_max)             exp(clamp(·, log λ_min, log λ_max))
``log_amplitude``  log max(μ, AMPLITUDE_FLOOR)            exp(·), so μ > 0 always
=================  =====================================  ==================================================

The clamp policy: λ ∈ [λ_min, λ_max] = [0.5, 2·10⁴] (:data:`SHARPNESS_MIN`, :data:`SHARPNESS_MAX`,
the range the extraction's initial lobes are clipped to, :mod:`ebr_mitsuba.extract.init`), μ
floored at 1e-12 before the log. ``bounded=False`` drops the λ clamp on both sides: ``ebr fit-env`` fits an
environment map directly and has always run unclamped; its lobes leave those bounds (measured on
the maps of ``shared/data/envmaps`` and three of ``envmaps_extra``, 8 and 32 lobes: λ from 0.06 to
3·10⁴), so clamping it would change its fits. The refinement (``--refine-lobes``) runs unbounded
too: it starts from the lobes it is given (extracted or read from an env.json) and has always
left their sharpness free.
"""

from __future__ import annotations

import math

import numpy as np

SHARPNESS_MIN = 0.5
SHARPNESS_MAX = 2.0e4
LOG_SHARPNESS_MIN = math.log(SHARPNESS_MIN)
LOG_SHARPNESS_MAX = math.log(SHARPNESS_MAX)
AMPLITUDE_FLOOR = 1e-12


def encode(axis, sharpness, amplitude, *, bounded: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lobes (axis (K, 3), sharpness (K,), amplitude (K, 3)) → float32 ``(axis, log λ, log μ)``.

    log λ is taken in the precision of ``sharpness`` (float32 stays float32, anything else float64),
    log μ in float64."""
    lam = np.asarray(sharpness)
    lam = lam if lam.dtype == np.float32 else lam.astype(np.float64)
    if bounded:
        lam = np.clip(lam, SHARPNESS_MIN, SHARPNESS_MAX)
    return (
        np.asarray(axis, np.float32),
        np.log(lam).astype(np.float32),
        np.log(np.maximum(np.asarray(amplitude, np.float64), AMPLITUDE_FLOOR)).astype(np.float32),
    )


def decode(log_sharpness, log_amplitude, *, bounded: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """numpy ``(log λ, log μ)`` → float64 ``(λ, μ)`` (any shapes)."""
    s = np.asarray(log_sharpness, np.float64)
    if bounded:
        s = np.clip(s, LOG_SHARPNESS_MIN, LOG_SHARPNESS_MAX)
    return np.exp(s), np.exp(np.asarray(log_amplitude, np.float64))


def dr_decode(log_sharpness, log_amplitude, *, bounded: bool = True):
    """Dr.Jit ``(log λ, log μ)`` → ``(λ, μ)``, differentiable (the clamp's gradient is zero outside
    the bounds)."""
    import drjit as dr

    if bounded:
        log_sharpness = dr.clip(log_sharpness, LOG_SHARPNESS_MIN, LOG_SHARPNESS_MAX)
    return dr.exp(log_sharpness), dr.exp(log_amplitude)


__all__ = [
    "AMPLITUDE_FLOOR",
    "LOG_SHARPNESS_MAX",
    "LOG_SHARPNESS_MIN",
    "SHARPNESS_MAX",
    "SHARPNESS_MIN",
    "decode",
    "dr_decode",
    "encode",
]
