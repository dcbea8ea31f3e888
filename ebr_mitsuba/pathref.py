"""Path-traced reference radiance along arbitrary rays, with its Monte-Carlo standard error.

Validation and benchmarks compare the fast renderer, point by point, against Mitsuba's own
integrators. Rendering an image would tie the comparison to a camera; instead each query is a ray
(origin, unit direction) and the integrator's ``sample()`` is called on ``P × spp`` rays at once.

Shapes: ``origins`` and ``directions`` are (P, 3) numpy arrays; results are (P, 3) float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Estimate:
    """Mean radiance per query (P, 3) and its standard error (P, 3)."""

    mean: np.ndarray
    stderr: np.ndarray
    spp: int

    def relative_noise(self) -> float:
        """RMS standard error relative to the RMS signal (what an RMSE against this can resolve)."""
        sig = float(np.sqrt(np.mean(self.mean**2)))
        return float(np.sqrt(np.mean(self.stderr**2))) / max(sig, 1e-12)


def trace(
    scene,
    origins: np.ndarray,
    directions: np.ndarray,
    spp: int = 256,
    seed: int = 0,
    integrator: dict | None = None,
    batch_rays: int = 1 << 22,
) -> Estimate:
    """Radiance arriving at ``origins`` from ``directions`` (i.e. leaving the surface towards the
    origin), estimated with ``spp`` independent paths per query by ``integrator`` (default: ``path``
    with ``max_depth=3``, enough for a lone plane)."""
    import drjit as dr
    import mitsuba as mi

    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    integ = mi.load_dict(integrator or {"type": "path", "max_depth": 3})
    p_total = origins.shape[0]
    per_batch = max(1, batch_rays // spp)
    sums = np.zeros((p_total, 3))
    sq = np.zeros((p_total, 3))
    for b, start in enumerate(range(0, p_total, per_batch)):
        stop = min(p_total, start + per_batch)
        p = stop - start
        n = p * spp
        idx = dr.arange(mi.UInt32, n) // spp
        o = [dr.gather(mi.Float, mi.Float(origins[start:stop, k].astype(np.float32)), idx) for k in range(3)]
        d = [
            dr.gather(mi.Float, mi.Float(directions[start:stop, k].astype(np.float32)), idx) for k in range(3)
        ]
        ray = mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(seed * 7919 + b, n)
        radiance, _, _ = integ.sample(scene, sampler, ray, None, True)
        radiance = dr.select(dr.isfinite(radiance), radiance, 0.0)
        acc = dr.zeros(mi.Color3f, p)
        acc2 = dr.zeros(mi.Color3f, p)
        dr.scatter_reduce(dr.ReduceOp.Add, acc, radiance, idx)
        dr.scatter_reduce(dr.ReduceOp.Add, acc2, radiance * radiance, idx)
        sums[start:stop] = np.array(acc, dtype=np.float64).T
        sq[start:stop] = np.array(acc2, dtype=np.float64).T
    mean = sums / spp
    var = np.maximum(sq / spp - mean**2, 0.0) * spp / max(spp - 1, 1)
    return Estimate(mean=mean, stderr=np.sqrt(var / spp), spp=spp)
