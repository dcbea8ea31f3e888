"""The roughness map's pattern, read off how the flash highlight follows the albedo (``ebr estimate``'s
roughness map for a near flash / no-flash pair fitted as a dielectric).

The flash-profile fit (:mod:`.flashfit`) reads one roughness per capture, so its map cannot beat the
material's own constant. Real surfaces carry their roughness in their albedo, as they carry their
relief (:mod:`.shading_normals`): grout, rust, pores and worn paths are rougher or smoother than the
faces around them: of the 55 real material sets of the training split, 26 have it correlated with
the log-albedo by |r| ≥ 0.7 (at 256²; ``ebr bench roughness``), 18 negatively (``acg_Tiles011``
−0.94), 8 positively (``acg_Bricks020`` +0.97). This module models the map as

    r(x) = r_fit + k · u(x),      u = log ρ̂ − mean(log ρ̂),

(ρ̂ the estimate's grey diffuse map) and reads the one number ``k`` off the flash shot. With the
flat-normal notation of :mod:`.flashfit` (``g = F / G`` the flash-only image over the unit-albedo
diffuse shading, ``lobe(θ; r)`` the GGX term, ``p(x)`` the no-flash shot over its mean, the albedo
share), the residual of the fitted profile is, to first order in ``k``,

    e(x) = g(x) − L · p(x) − lobe(θ(x); r_fit) ≈ k · u(x) · ∂lobe/∂r(θ(x); r_fit) + γ · u(x) + c_ring,

with ``u`` read off the no-flash shot (``log p``: independent of the flash's specular, which the
estimate's diffuse map still partly carries near the highlight) and ``γ · u`` the share of the
albedo pattern the no-flash shot misreads (its relief shading, its environment reflection). The
lobe's slope in ``r`` changes sign across the frame (a smoother pixel is brighter at the mirror
point, darker away from it) while ``γ`` does not, which separates the two. Each ring of equal view
angle is centred (the profile's own misfit is a function of θ alone) and trimmed (the middle 80 %
of its residuals, as the profile's rings), weighted by the inverse of its residual variance, and
``(k, γ)`` solved by least squares over all rings (:func:`read_roughness_pattern`).

The reading is skipped where it has nothing to read: above ``MAX_ROUGHNESS`` the lobe is nearly
flat over the near frame's 0–30° and its slope in ``r`` is lost in the albedo (a limit of 0.8 made
the second validation set's roughness maps worse, not better); ``|k|`` is capped at ``MAX_SLOPE``.
A metal (no diffuse), a capture whose profile misfits (the network's roughness map is kept) and a
flash-only capture keep the fit's map.

The gain. On noise-free synthetic captures (``tests/test_roughness_pattern.py``'s, a true slope of
±0.1 at roughness 0.3–0.5) the reading is 0.065–0.094, with photo noise 0.034–0.07: the no-flash
shot's noise in ``u`` dilutes the regression. The map therefore takes ``GAIN`` × the capped reading.
GAIN, MAX_SLOPE and MAX_ROUGHNESS were chosen on the validation captures (training materials and
maps; ``configs/data_real_val.toml``, 24, and ``configs/data_real_val2.toml``, 48), measured with the
pipeline's maps by ``ebr bench roughness`` (``docs/bench/roughness.md``: the constant against the
pattern per capture, and the roughness RMSE over a grid of gains).

Known failure: a sample whose roughness varies widely can make the flash fit's relief reading
(:mod:`.flashfit`, "Relief") take the sharp lobe of a two-lobe profile for the material's; the
residual of that profile then holds little of the pattern (a synthetic blotchy sample of roughness
0.45 ± 0.05 read 0.36 and a slope of 0.005 for a true −0.12).

Cost: one lobe table and a least-squares fit at most 256² (larger photos are area-averaged to it),
the map one pass over the diffuse map: measured (2026-12-07, two cores) 0.07 s for a 256² capture,
0.10 s for a 1024² one (the map 0.02 s of it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from ..errors import InputError
from ..floors import ROUGHNESS_MIN
from ..geometry import DEFAULT_FLASH_INTENSITY, NEAR_DISTANCE, view_directions
from .flashfit import (
    FIT_SIZE,
    FOOTPRINT_ROUGHNESS,
    NOFLASH_MIN,
    TRIM,
    FlashFit,
    _footprint_cos,
    _LobeTable,
    area_shots,
    flat_shading,
    ring_index,
    shrink_factor,
)

__all__ = ["RoughnessPattern", "read_roughness_pattern"]

MAX_ROUGHNESS = 0.7  # above it the lobe's slope in r is too small to read (module docstring)
MAX_SLOPE = 0.15  # |k| read is capped here (roughness per unit of log-albedo) ...
GAIN = 2.0  # ... and the map takes GAIN × the capped k (the reading is diluted: module docstring)
BINS = 32  # rings of equal pixel count over cos θ, as the profile's
SHARE_FLOOR = 0.02  # the no-flash albedo share p is floored here before its log
ALBEDO_FLOOR = 0.01  # the diffuse map's grey level is floored here before its log
DERIVATIVE_STEP = 0.02  # the lobe's slope in r: a central difference of this step
MIN_RING_PIXELS = 20  # a ring with fewer usable pixels is left out


@dataclass(frozen=True)
class RoughnessPattern:
    """What :func:`read_roughness_pattern` found: ``slope`` k (roughness per unit log-albedo, after
    the cap; 0 when not applied), ``read`` the least-squares k before the cap, ``stderr`` its
    standard error, ``albedo_term`` γ, ``applied`` and, when not, ``reason``."""

    slope: float
    read: float | None = None
    stderr: float | None = None
    albedo_term: float | None = None
    applied: bool = False
    reason: str = ""

    def at_gain(self, gain: float) -> RoughnessPattern:
        """The pattern with ``gain`` × the capped reading as its slope (the default is GAIN; ``ebr
        bench roughness`` scores a grid of gains); one not applied is returned as it is."""
        if not self.applied or self.read is None:
            return self
        return replace(self, slope=gain * float(np.clip(self.read, -MAX_SLOPE, MAX_SLOPE)))

    @classmethod
    def from_json(cls, record: dict | None) -> RoughnessPattern | None:
        """The pattern of an ``estimate.json`` record (:meth:`to_json`), None for None."""
        if record is None:
            return None
        return cls(
            float(record["slope"]),
            record.get("read"),
            record.get("stderr"),
            record.get("albedo_term"),
            bool(record["applied"]),
            record.get("reason", ""),
        )

    def roughness_map(self, roughness: float, diffuse: np.ndarray) -> np.ndarray:
        """(H, W) float32: ``roughness + k · u`` with ``u`` the grey log of ``diffuse`` (H, W, 3) less
        its mean, clipped to [ROUGHNESS_MIN, 1]."""
        d = np.asarray(diffuse, np.float64)
        if d.ndim != 3 or d.shape[-1] != 3:
            raise InputError(f"roughness pattern: the diffuse map is {d.shape}; expected (H, W, 3)")
        u = np.log(np.maximum(d.mean(-1), ALBEDO_FLOOR))
        u -= u.mean()
        return np.clip(roughness + self.slope * u, ROUGHNESS_MIN, 1.0).astype(np.float32)

    def to_json(self) -> dict:
        out = {"applied": self.applied, "slope": round(self.slope, 4)}
        if self.read is not None:
            out.update(read=round(self.read, 4), stderr=float(f"{self.stderr:.3g}"))
            out["albedo_term"] = round(self.albedo_term, 4)
        if self.reason:
            out["reason"] = self.reason
        return out


def _skip(reason: str) -> RoughnessPattern:
    return RoughnessPattern(0.0, applied=False, reason=reason)


def read_roughness_pattern(
    fit: FlashFit,
    flash: np.ndarray,
    noflash: np.ndarray,
    *,
    to_radiance: float = 1.0,
    intensity: float = DEFAULT_FLASH_INTENSITY,
    camera=(0.0, 0.0, NEAR_DISTANCE),
    saturated: np.ndarray | None = None,
) -> RoughnessPattern:
    """Read ``k`` of the roughness pattern (module docstring) off a near pair that ``fit`` was fitted
    to: ``flash``, ``noflash`` (H, W, 3) linear photo values, ``to_radiance``, ``intensity``,
    ``camera`` and ``saturated`` (H, W) bool as given to :func:`~.flashfit.fit_flash`."""
    flash = np.asarray(flash, np.float64)
    noflash = np.asarray(noflash, np.float64)
    if flash.ndim != 3 or flash.shape[-1] != 3 or noflash.shape != flash.shape:
        raise InputError(
            f"roughness pattern: flash {flash.shape} and noflash {noflash.shape} must be the same (H, W, 3)"
        )
    if fit.metal:
        return _skip("metal")
    if fit.roughness > MAX_ROUGHNESS:
        return _skip(f"roughness {fit.roughness:.3g} > {MAX_ROUGHNESS:g}")
    h, w, _ = flash.shape
    sat = np.zeros((h, w), bool) if saturated is None else np.asarray(saturated, bool).reshape(h, w)
    f = shrink_factor(h, w, FIT_SIZE)  # read at the flash fit's size
    if f > 1:
        flash, noflash, sat = area_shots(f, flash, noflash, sat)
        h, w = flash.shape[:2]
    cos = np.ascontiguousarray(view_directions(h, w, camera)[..., 2]).reshape(-1)
    shade = flat_shading(cos, float(camera[2]), intensity)
    g = (flash - noflash).mean(-1).reshape(-1) * to_radiance / shade
    nf = noflash.mean(-1).reshape(-1)
    ok = ~sat.reshape(-1) & np.isfinite(g) & (nf > 0)
    if int(ok.sum()) < BINS * MIN_RING_PIXELS or float(nf[ok].mean()) <= NOFLASH_MIN:
        return _skip("no-flash shot too dark or too few unsaturated pixels")
    p = nf / nf[ok].mean()
    u = np.log(np.maximum(p, SHARE_FLOOR))
    cos_t = torch.from_numpy(cos)
    table = _LobeTable(cos_t, _footprint_cos(h, w, camera) if fit.roughness < FOOTPRINT_ROUGHNESS else None)
    r0 = float(fit.roughness)
    lo, hi = max(r0 - DERIVATIVE_STEP, ROUGHNESS_MIN), min(r0 + DERIVATIVE_STEP, 1.0)
    slope = ((table(hi, fit.f0) - table(lo, fit.f0)) / (hi - lo)).numpy()
    e = g - float(np.mean(fit.level)) * p - table(r0, fit.f0).numpy()

    ring = ring_index(cos_t, BINS).numpy()
    rows_a, rows_y, rows_w = [], [], []
    for k in range(BINS):
        inside = (ring == k) & ok
        if int(inside.sum()) < MIN_RING_PIXELS:
            continue
        ek = e[inside]
        q_lo, q_hi = np.quantile(ek, [TRIM, 1.0 - TRIM])
        keep = (ek >= q_lo) & (ek <= q_hi)
        uk, ek, dk = u[inside][keep], ek[keep], slope[inside][keep]
        uk = uk - uk.mean()
        ek = ek - ek.mean()
        x1 = uk * dk
        x1 = x1 - x1.mean()
        var = float(ek.var())
        if var <= 0.0:
            continue
        rows_a.append(np.stack([x1, uk], 1))
        rows_y.append(ek)
        rows_w.append(np.full(len(ek), 1.0 / var))
    if len(rows_a) < 3:
        return _skip("too few usable rings")
    a, y, wt = np.concatenate(rows_a), np.concatenate(rows_y), np.concatenate(rows_w)
    normal = a.T @ (a * wt[:, None])
    try:
        cov = np.linalg.inv(normal)
    except np.linalg.LinAlgError:
        return _skip("the albedo pattern does not separate from the lobe's slope")
    k, gamma = cov @ (a * wt[:, None]).T @ y
    res = y - a @ np.array([k, gamma])
    s2 = float((wt * res * res).sum() / max(len(y) - 2, 1))
    stderr = math.sqrt(max(float(cov[0, 0]) * s2, 0.0))
    return RoughnessPattern(0.0, float(k), stderr, float(gamma), applied=True).at_gain(GAIN)
