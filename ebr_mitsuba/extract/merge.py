"""Merging similar lobes (the second step of SG extraction).

Two lobes are *similar* when their axes are closer than ``angle / √λ_max`` radians (a fraction of
the sharper lobe's width) and their sharpness values differ by less than the factor ``ratio``.
Lobes are visited by decreasing energy ``E = lum(μ) · ∫G`` and each joins the first similar lobe
already kept. A merged lobe keeps the energy-weighted mean axis and log-sharpness and the summed
energy (per channel: ``μ = Σ_j μ_j ∫G_j / ∫G``), so its integral — what a rough material sees —
is preserved. While more than ``budget`` lobes remain, the criterion is widened (×1.5 on both) and
the pass repeated; after 12 widenings the most energetic ``budget`` lobes are kept.
"""

from __future__ import annotations

import math

import numpy as np

from ..colour import LUMINANCE


def sg_integrals(sharpness: np.ndarray) -> np.ndarray:
    lam = np.asarray(sharpness, np.float64)
    return 2.0 * np.pi * (-np.expm1(-2.0 * lam)) / lam


def energies(sharpness: np.ndarray, amplitude: np.ndarray) -> np.ndarray:
    return (np.asarray(amplitude, np.float64) @ LUMINANCE) * sg_integrals(sharpness)


def _merge_pass(axis, sharp, amp, angle, ratio):
    integ = sg_integrals(sharp)
    energy = np.maximum(amp @ LUMINANCE, 0.0) * integ
    order = np.argsort(-energy, kind="stable")
    groups: list[list[int]] = []
    lams = [float(v) for v in sharp]  # Python floats: the scalar loop below runs ~10⁵ times
    for i in order:
        for g in groups:
            j = g[0]
            lam_max = max(lams[i], lams[j])
            cos = min(max(float(axis[i] @ axis[j]), -1.0), 1.0)
            if math.acos(cos) < angle / math.sqrt(lam_max) and lam_max < ratio * min(lams[i], lams[j]):
                g.append(i)
                break
        else:
            groups.append([i])
    out_a, out_s, out_m = [], [], []
    for g in groups:
        w = np.maximum(energy[g], 0.0)
        w = w / w.sum() if w.sum() > 0 else np.full(len(g), 1.0 / len(g))
        a = (w[:, None] * axis[g]).sum(0)
        norm = np.linalg.norm(a)
        a = axis[g[0]] if norm < 1e-9 else a / norm
        lam = float(np.exp((w * np.log(sharp[g])).sum()))
        m = (amp[g] * integ[g][:, None]).sum(0) / sg_integrals(np.array([lam]))[0]
        out_a.append(a)
        out_s.append(lam)
        out_m.append(m)
    return np.array(out_a).reshape(-1, 3), np.array(out_s), np.array(out_m).reshape(-1, 3)


def merge_lobes(
    axis: np.ndarray,
    sharpness: np.ndarray,
    amplitude: np.ndarray,
    budget: int,
    angle: float = 1.5,
    ratio: float = 4.0,
):
    """Merge similar lobes (module docstring); returns at most ``budget`` lobes
    (axis (K, 3), sharpness (K,), amplitude (K, 3))."""
    axis = np.asarray(axis, np.float64).reshape(-1, 3)
    sharp = np.asarray(sharpness, np.float64).reshape(-1)
    amp = np.asarray(amplitude, np.float64).reshape(-1, 3)
    a, s, m = _merge_pass(axis, sharp, amp, angle, ratio)
    widen = 0
    while len(s) > budget and widen < 12:
        angle, ratio, widen = angle * 1.5, ratio * 1.5, widen + 1
        a, s, m = _merge_pass(a, s, m, angle, ratio)
    return keep_strongest(a, s, m, budget)


def keep_strongest(axis, sharpness, amplitude, budget: int):
    """The ``budget`` lobes of largest energy (all of them when there are fewer)."""
    if len(sharpness) <= budget:
        return axis, sharpness, amplitude
    order = np.argsort(-energies(sharpness, amplitude), kind="stable")[:budget]
    return axis[order], sharpness[order], amplitude[order]
