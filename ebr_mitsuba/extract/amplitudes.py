"""Closed-form amplitudes: exemplars are linear in the lobe amplitudes, so with axes and
sharpness fixed the best non-negative amplitudes solve a small non-negative least-squares problem.

The exemplar material is grey (diffuse 0.1, specular 0.2 on every channel), so channel c of an
exemplar is ``Σ_k μ_kc B_k`` with ``B_k`` the (grey) render of lobe k at unit amplitude: one basis
serves the three channels. :func:`lobe_basis` renders it at chosen pixels, three lobes per call
(lobe j of a call gets the unit colour e_j, so each channel holds one lobe's image).
:func:`nnls` solves ``min ‖A x − b‖²``, ``x ≥ 0`` with the Lawson–Hanson active-set method
on the normal equations (K ≤ a few hundred; numpy only).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..render.inputs import DrLobes, RenderOptions
from .forward import ExemplarGeometry


def lobe_basis(
    geometry: ExemplarGeometry,
    axis: np.ndarray,
    sharpness: np.ndarray,
    index: np.ndarray,
    options: RenderOptions,
) -> np.ndarray:
    """Unit-amplitude renders (K, P) float64 of lobes (``axis`` (K, 3), ``sharpness`` (K,)) at
    the flat pixel ``index`` (P,)."""
    k = int(len(sharpness))
    out = np.zeros((k, len(index)))
    idx = mi.UInt32(np.asarray(index, np.uint32))
    eye = np.eye(3, dtype=np.float32)
    with dr.suspend_grad():
        for start in range(0, k, 3):
            stop = min(start + 3, k)
            m = stop - start
            lobes = DrLobes.from_numpy(axis[start:stop], sharpness[start:stop], eye[:m])
            img = np.asarray(geometry.render(lobes, idx, options).numpy(), np.float64)  # (3, P)
            out[start:stop] = img[:m]
    return out


def _nnls_column(gram: np.ndarray, h: np.ndarray, max_iter: int) -> np.ndarray:
    """Lawson–Hanson active-set NNLS on the normal equations ``G x = h``, ``x ≥ 0``."""
    k = gram.shape[0]
    x = np.zeros(k)
    passive = np.zeros(k, dtype=bool)
    tol = 1e-12 * max(float(np.abs(h).max(initial=0.0)), 1e-300)
    for _ in range(max_iter):
        w = h - gram @ x
        cand = np.where(~passive & (w > tol))[0]
        if cand.size == 0:
            break
        passive[cand[np.argmax(w[cand])]] = True
        while True:
            idx = np.where(passive)[0]
            z = np.zeros(k)
            z[idx] = np.linalg.solve(gram[np.ix_(idx, idx)], h[idx])
            if np.all(z[idx] > 0):
                x = z
                break
            neg = idx[z[idx] <= 0]
            step = np.min(x[neg] / np.maximum(x[neg] - z[neg], 1e-300))
            x = x + step * (z - x)
            passive &= x > 1e-15 * max(float(x.max(initial=0.0)), 1e-300)
            x[~passive] = 0.0
            if not passive.any():
                break
    return x


def nnls(a: np.ndarray, b: np.ndarray, ridge: float = 1e-9) -> np.ndarray:
    """Non-negative least squares ``argmin_{x ≥ 0} ‖a x − b‖²`` for ``a`` (P, K) and ``b`` (P,)
    or (P, C) (one solve per column); returns (K,) or (K, C). Lawson–Hanson active set on
    ``G = aᵀa + ridge·tr(G)/K·I`` (the tiny ridge keeps every sub-system solvable)."""
    a = np.asarray(a, np.float64)
    b2 = np.asarray(b, np.float64)
    squeeze = b2.ndim == 1
    if squeeze:
        b2 = b2[:, None]
    k = a.shape[1]
    gram = a.T @ a
    scale = np.trace(gram) / max(k, 1)
    x = np.zeros((k, b2.shape[1]))
    if np.isfinite(scale) and scale > 0:
        gram = gram + ridge * scale * np.eye(k)
        h = a.T @ b2
        for c in range(b2.shape[1]):
            x[:, c] = _nnls_column(gram, h[:, c], 3 * k + 10)
    return x[:, 0] if squeeze else x


def solve_amplitudes(
    geometry: ExemplarGeometry,
    targets: np.ndarray,
    row_weight: np.ndarray,
    axis: np.ndarray,
    sharpness: np.ndarray,
    index: np.ndarray,
    options: RenderOptions,
    basis: np.ndarray | None = None,
    channel_scale: np.ndarray | None = None,
) -> np.ndarray:
    """Best non-negative amplitudes (K, 3) for fixed axes and sharpness: weighted least squares
    over the pixels ``index`` of ``targets`` ((N·H·W, 3) flat, the stack's pixels), each pixel's
    row scaled by ``row_weight`` (P,); ``channel_scale`` (P, 3) multiplies the model per pixel and
    channel (then each channel is its own solve)."""
    if basis is None:
        basis = lobe_basis(geometry, axis, sharpness, index, options)
    b = targets[index] * row_weight[:, None]
    if channel_scale is None:
        return nnls((basis * row_weight[None, :]).T, b)
    return np.stack(
        [nnls((basis * (row_weight * channel_scale[:, c])[None, :]).T, b[:, c]) for c in range(3)], axis=1
    )
