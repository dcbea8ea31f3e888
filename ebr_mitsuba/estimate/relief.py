"""Relief that leaves the albedo alone, read off the flash / no-flash ratio (``ebr estimate``'s
shading normals, :mod:`.shading_normals`, "Relief off the albedo").

:mod:`.shading_normals` explains the log ratio ``y = log F − log N − log(l_z / d²)`` of a near pair
by relief that follows the albedo (``δ = c · u``). What it leaves, the residual ``r``, still holds
the shading of every other relief: per pixel, to first order in the slopes ``δ = (n_x/n_z,
n_y/n_z)``,

    r(x) ≈ a(x) · δ(x) + noise,      a(x) = v(x) − e,

with ``v(x) = l_t / l_z = −(x, y) / D`` (the flash's tilt towards the pixel, known; ``D`` the camera
height) and ``e = ∇ log E`` the no-flash irradiance's gradient over normals (the sky gradient,
unknown and constant over the sample). One pixel gives the slope's component along ``a(x)`` only;
the rest comes from two assumptions that hold for most real surfaces:

* **The sky gradient, by likelihood.** With the slopes' components independent, of one variance
  ``s²`` whatever their direction, ``r(x)`` has the variance ``s² |v(x) − e|² + σ²`` (``σ²`` the
  pixel noise, the ratio's variance less its covariance with its neighbours: the noise is white,
  the relief is not). Its spread across the frame therefore points at ``e``: ``e`` is the maximum
  of the Gaussian likelihood of ``r`` (maximised over ``s²`` for each ``e``) over a grid
  (:data:`SKY_RANGE`, coarse then fine; :func:`sky_gradient`); ``s²`` is then read by moments,
  ``(mean r² − σ²) / mean |a|²``. Measured against the gradient of the true environment on the
  validation captures (``configs/data_real_val.toml``, 24), it has the right direction where the
  sample has relief (a glazed tile (−2.9, −1.8) for (−2.4, −2.9), a rusty painted metal
  (−1.1, −0.1) for (−2.5, −1.6)), comes out near 0 where it has none, and is about half the true
  length; the lighting network's own lobes gave directions no better than chance
  ((0.1, −0.2) for that tile): with them the normals got worse (validation normal RMSE 0.0472 →
  0.0496).
* **Integrable slopes.** ``δ = −∇h`` for a height field h, which links the component one pixel
  sees to its neighbours'. The slopes are the minimum of

      Σ_x (r − a · δ(h))² / σ²  +  smooth · Σ |∇h|² / s²

  over h (central differences in the data term, forward ones in the prior; conjugate gradients,
  :data:`ITERATIONS`). Without the integrability (each pixel's posterior mean along ``a(x)``
  alone) the validation normal RMSE was 0.0434 against 0.0419 with it.

Tried and not adopted (2026-12-07): turning the lighting network's lobes about the vertical so that
their irradiance gradient points along the ``e`` read here (when ``|e|`` ≥ 0.3), for ``ebr
insert``. On ``ebr bench insert``'s diffuse spheres (composited, ratio to the noise floor) three
insertions got better (a procedural leather 6.4 → 5.2×, two barks 9.1 → 7.8× and 9.1 → 8.9×), one
worse (a procedural tile set 1.7 → 2.6×), the others unchanged: ``e`` is about half the true
length, and one gradient does not place a light.

Also tried (2026-12-07): half the noise variance (as if the neighbour-based estimate counted fine
relief as noise: per capture the relief's least-squares gain against the truth is largest where
the reading is smallest). The slopes grow and the normals get worse on all three validation sets
of ``ebr bench normals`` at every relief gain from 0.15 to 1: at best 0.04546 / 0.04169 / 0.04263
against 0.04227 / 0.03813 / 0.04220 with the estimate as it is.

What it cannot see: relief under a sky whose gradient is parallel to the flash's everywhere (then
one component is all any pixel sees), relief finer than the pixel noise allows, and the slopes'
low frequencies (``r`` is high-passed with the ratio).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SKY_RANGE = 3.0  # the sky gradient is searched in [-SKY_RANGE, SKY_RANGE]² (|e| of a bright sun: 2–3)
SKY_COARSE = 0.5  # step of the coarse grid; the fine grid steps by a quarter of it around the best
VARIANCES = np.geomspace(1e-4, 1.0, 25)  # slope variances s² the likelihood is maximised over
ITERATIONS = 80  # conjugate-gradient steps of the height solve
SUBSAMPLE = 4  # the likelihood reads every SUBSAMPLE-th pixel along each axis


@dataclass
class Relief:
    """What :func:`read_relief` found: ``slopes`` (H, W, 2) float32 δ = (n_x/n_z, n_y/n_z);
    ``sky_gradient`` (2,) e; ``slope_variance`` s² (per component); ``noise`` σ² (the ratio's
    pixel noise variance)."""

    slopes: np.ndarray
    sky_gradient: np.ndarray
    slope_variance: float
    noise: float

    def to_json(self) -> dict:
        return {
            "sky_gradient": [round(float(x), 3) for x in self.sky_gradient],
            "slope_rms": round(float(np.sqrt(self.slope_variance)), 4),
            "noise_rms": round(float(np.sqrt(self.noise)), 4),
        }


def noise_variance(r: np.ndarray, valid: np.ndarray) -> float:
    """The white part of an (H, W) map's variance over ``valid`` pixels: its mean square less the
    mean product of horizontally and vertically neighbouring pixels (floored at 1e-8)."""
    m = valid.astype(np.float64)
    r = np.where(valid, r, 0.0)
    lag0 = float((r * r).sum() / max(m.sum(), 1.0))
    pairs_x = m[:, 1:] * m[:, :-1]
    pairs_y = m[1:] * m[:-1]
    lag1_x = (r[:, 1:] * r[:, :-1] * pairs_x).sum() / max(pairs_x.sum(), 1.0)
    lag1_y = (r[1:] * r[:-1] * pairs_y).sum() / max(pairs_y.sum(), 1.0)
    return max(lag0 - 0.5 * float(lag1_x + lag1_y), 1e-8)


def _likelihood(r2: np.ndarray, vx: np.ndarray, vy: np.ndarray, noise: float, e) -> tuple[float, float]:
    """(best mean log-likelihood over :data:`VARIANCES`, its s²) of squared residuals ``r2`` for the
    sky gradient ``e``."""
    a2 = (vx - e[0]) ** 2 + (vy - e[1]) ** 2
    v = VARIANCES[:, None] * a2[None, :] + noise
    ll = -0.5 * np.mean(r2[None, :] / v + np.log(v), axis=1)
    k = int(np.argmax(ll))
    return float(ll[k]), float(VARIANCES[k])


def sky_gradient(
    r: np.ndarray, valid: np.ndarray, vx: np.ndarray, vy: np.ndarray, noise: float
) -> np.ndarray:
    """e (2,): the maximum-likelihood sky gradient of the residual ``r`` (H, W) over ``valid``
    pixels, ``vx``/``vy`` (H, W) the flash tilt (module docstring)."""
    sub = (slice(None, None, SUBSAMPLE), slice(None, None, SUBSAMPLE))
    keep = valid[sub]
    r2, x, y = (r[sub][keep]) ** 2, vx[sub][keep], vy[sub][keep]
    coarse = np.arange(-SKY_RANGE, SKY_RANGE + 1e-9, SKY_COARSE)
    best = max((_likelihood(r2, x, y, noise, (a, b))[0], a, b) for a in coarse for b in coarse)
    fine = np.arange(-2, 3) * (SKY_COARSE / 4)
    best = max(
        (_likelihood(r2, x, y, noise, (best[1] + a, best[2] + b))[0], best[1] + a, best[2] + b)
        for a in fine
        for b in fine
    )
    return np.array(best[1:], np.float64)


def _slopes(h: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """δ = −∇h by central differences (x right along columns, y up against rows; 0 at the border)."""
    dx = np.zeros_like(h)
    dy = np.zeros_like(h)
    dx[:, 1:-1] = -(h[:, 2:] - h[:, :-2]) * 0.5 * scale
    dy[1:-1, :] = (h[2:, :] - h[:-2, :]) * 0.5 * scale
    return dx, dy


def _slopes_adjoint(px: np.ndarray, py: np.ndarray, scale: float) -> np.ndarray:
    h = np.zeros_like(px)
    h[:, 2:] -= px[:, 1:-1] * 0.5 * scale
    h[:, :-2] += px[:, 1:-1] * 0.5 * scale
    h[2:, :] += py[1:-1, :] * 0.5 * scale
    h[:-2, :] -= py[1:-1, :] * 0.5 * scale
    return h


def _smoothness(h: np.ndarray, scale: float) -> np.ndarray:
    """Fᵀ F h for F the forward differences (the prior's normal operator, a graph Laplacian)."""
    out = np.zeros_like(h)
    fx = (h[:, 1:] - h[:, :-1]) * scale * scale
    fy = (h[1:, :] - h[:-1, :]) * scale * scale
    out[:, 1:] += fx
    out[:, :-1] -= fx
    out[1:, :] += fy
    out[:-1, :] -= fy
    return out


def solve_slopes(
    r: np.ndarray,
    valid: np.ndarray,
    ax: np.ndarray,
    ay: np.ndarray,
    noise: float,
    slope_variance: float,
    smooth: float,
    iterations: int = ITERATIONS,
) -> np.ndarray:
    """(H, W, 2) slopes of the height field minimising the module docstring's energy for the
    residual ``r`` and the per-pixel directions ``a = (ax, ay)`` (all (H, W); the sample is 2
    wide)."""
    scale = r.shape[1] / 2.0
    m = valid.astype(np.float64) / noise
    prior = smooth / max(slope_variance, 1e-12)

    def normal_op(h):
        dx, dy = _slopes(h, scale)
        w = (ax * dx + ay * dy) * m
        return _slopes_adjoint(ax * w, ay * w, scale) + prior * _smoothness(h, scale)

    rw = np.where(valid, r, 0.0) * m
    b = _slopes_adjoint(ax * rw, ay * rw, scale)
    h = np.zeros_like(r, dtype=np.float64)
    res = b.copy()
    p = res.copy()
    rs = float((res * res).sum())
    stop = 1e-12 * max(rs, 1e-300)
    for _ in range(iterations):
        if rs <= stop:
            break
        ap = normal_op(p)
        alpha = rs / float((p * ap).sum())
        h += alpha * p
        res -= alpha * ap
        rs_new = float((res * res).sum())
        p = res + (rs_new / rs) * p
        rs = rs_new
    dx, dy = _slopes(h, scale)
    return np.stack([dx, dy], -1).astype(np.float32)


def read_relief(r: np.ndarray, valid: np.ndarray, vx: np.ndarray, vy: np.ndarray, smooth: float) -> Relief:
    """The relief of a residual log ratio ``r`` (H, W; high-passed, ``valid`` pixels read) whose
    flash tilt is ``(vx, vy)`` (H, W): sky gradient, slope variance and noise, then the slopes
    (module docstring)."""
    noise = noise_variance(r, valid)
    e = sky_gradient(r, valid, vx, vy, noise)
    # the slope variance by moments: the residual's variance less the noise, over the mean |a|²
    a2 = (vx - e[0]) ** 2 + (vy - e[1]) ** 2
    s2 = max((float(np.mean(r[valid] ** 2)) - noise) / max(float(np.mean(a2[valid])), 1e-12), 1e-12)
    slopes = solve_slopes(r, valid, vx - e[0], vy - e[1], noise, s2, smooth)
    return Relief(slopes, e, s2, noise)


__all__ = ["Relief", "noise_variance", "read_relief", "sky_gradient", "solve_slopes"]
