"""Pruning lobes the exemplars do not need.

Lobe k's contribution is ``c_k = ‖μ_k ⊗ B_k‖ / ‖y‖`` over a fixed pixel grid of the exemplar stack
(``B_k`` its unit-amplitude render, :func:`ebr_mitsuba.extract.amplitudes.lobe_basis`, weighted
per exemplar like the loss): the relative size of the change its removal makes. Lobes with
``c_k < threshold`` are dropped (lobes below the horizon, duplicates the optimiser emptied).
"""

from __future__ import annotations

import numpy as np


def contributions(
    basis: np.ndarray, amplitude: np.ndarray, targets: np.ndarray, row_weight: np.ndarray
) -> np.ndarray:
    """``c_k`` (K,) from the basis (K, P), amplitudes (K, 3), targets at the pixels (P, 3) and the
    per-pixel weights (P,)."""
    w2 = row_weight**2
    norm = np.sqrt(max(float((w2[:, None] * targets**2).sum()), 1e-300))
    per = np.sqrt((basis**2 * w2[None, :]).sum(1) * (amplitude**2).sum(1))
    return per / norm


def prune_mask(
    basis: np.ndarray, amplitude: np.ndarray, targets: np.ndarray, row_weight: np.ndarray, threshold: float
) -> np.ndarray:
    """Boolean mask (K,) of the lobes to keep (at least the strongest one when any contributes)."""
    c = contributions(basis, amplitude, targets, row_weight)
    keep = np.isfinite(c) & (c >= threshold)
    if not keep.any() and c.size and np.isfinite(c).any() and np.nanmax(c) > 0:
        keep[int(np.nanargmax(c))] = True
    return keep
