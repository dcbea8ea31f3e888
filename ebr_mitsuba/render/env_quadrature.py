"""Fixed-pattern quadrature of the environment term (``mode="quadrature"``).

Estimates ``∫ f(l, v) L(l) max(n·l, 0) dl`` over ``l_z > 0`` (the plane occludes the lower
hemisphere) with ``L(ω) = Σ_k G_k(ω)`` and ``spp`` directions per point, multi-sample MIS with
the balance heuristic between

* **BRDF sampling** (``n_b = ⌈spp/2⌉`` directions): :func:`ebr_mitsuba.brdf.brdf_sample`, density
  ``p_b`` = :func:`ebr_mitsuba.brdf.brdf_pdf`;
* **lobe sampling** (``n_l = ⌊spp/2⌋``): pick lobe k with probability ``π_k`` ∝ luminance(μ_k) ·
  ``sg_irradiance(ξ_k, λ_k, 1, +z)`` (the lobe's irradiance on the sample plane: the
  ``sg_integral``·luminance energy, weighted by how much of it is above the horizon, so lobes
  under the plane are never picked), then :func:`ebr_mitsuba.sg.vmf_sample`; density
  ``p_l = Σ_k π_k vmf_pdf_k`` (written ``π_k G_k/∫G_k`` with unit amplitude, so L and p_l share one
  exponential per lobe). When no lobe lights the plane (largest energy below the smallest normal
  float32), ``π_k = 1/K``. The energies are divided by their detached maximum before they are
  normalised, so tiny amplitudes (1e-38 … 1e-19) give finite π and finite gradients.

The pattern is deterministic: sample i of a strategy uses the 3-D Kronecker (R₃, generalised
golden ratio) point ``frac(o + i·a)``, Cranley–Patterson-rotated per pixel by ``o`` = TEA hash
of (pixel index, strategy, dimension, seed). Same inputs, same image, on every call.

**Gradients.** Directions are detached. The sampling densities ``q_s`` come from a *guide*
(detached copies of the parameters by default) and the estimator is

``Σ_s Σ_i w_s(l_i) g(l_i) / (n_s q_s(l_i))``, ``w_s = n_s p_s / (n_b p_b + n_l p_l)``,

with ``g = f L cos`` and the balance weights ``w_s`` computed from the *attached* parameters. At
the guide its value is the usual balance-heuristic estimate; its gradient flows through f, L and
the MIS weights and is unbiased (the weight derivatives sum to zero over strategies). With an
explicit, fixed guide the estimator is a smooth deterministic function of the parameters, so
finite differences match AD (used by the tests).

Memory: the (point × direction) lanes run in chunks of at most ``max_lanes``; the lobe sum is a
symbolic ``dr.while_loop`` (reverse-mode differentiable as a sum-style loop).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..brdf import brdf_eval_cos, brdf_pdf, brdf_sample, luminance
from ..sg import sg_eval, sg_integral, sg_irradiance, vmf_sample
from .env_sg import unit_axes
from .inputs import DrLobes
from .points import ShadingPoints

# R₃ sequence: a_d = 1/g^d with g the real root of x⁴ = x + 1 (Roberts 2018), as 0.32 fixed point.
_G3 = 1.2207440846057596
_R3 = tuple(int(round((1.0 / _G3 ** (d + 1)) % 1.0 * 2.0**32)) & 0xFFFFFFFF for d in range(3))
_ONE_MINUS = 1.0 - 2.0**-24
_TINY = 1.1754944e-38  # smallest normal float32
BRDF, LOBE = 0, 1


def strategy_counts(spp: int) -> tuple[int, int]:
    """(BRDF-sampled, lobe-sampled) directions per point."""
    return (spp + 1) // 2, spp // 2


def pattern(pixel: mi.UInt32, index: mi.UInt32, strategy: int, seed: mi.UInt32) -> list:
    """Three uniforms in [0, 1) for sample ``index`` of ``strategy`` at ``pixel`` (deterministic)."""
    out = []
    for d in range(3):
        offset = mi.sample_tea_float32(pixel, seed + (strategy * 3 + d))
        frac = mi.Float((index * _R3[d]) >> 8) * 2.0**-24  # exact frac(i·a_d)
        u = offset + frac
        u = dr.select(u >= 1.0, u - 1.0, u)
        out.append(dr.minimum(u, _ONE_MINUS))
    return out


class _LobeTables:
    """Per-lobe arrays (K lanes) used inside the per-direction lobe loop."""

    def __init__(self, lobes: DrLobes):
        self.k = lobes.num_lobes
        self.axis = unit_axes(lobes)
        self.sharpness = lobes.sharpness
        self.amplitude = lobes.amplitude
        up = mi.Vector3f(0.0, 0.0, 1.0)
        energy = luminance(lobes.amplitude) * sg_irradiance(self.axis, lobes.sharpness, 1.0, up, 8)
        energy = dr.maximum(dr.select(dr.isfinite(energy), energy, 0.0), 0.0)
        # π = energy/Σenergy is scale-free: divide by the (detached) largest energy first, so the
        # sum lies in [1, K] and neither the value nor its derivative (1/Σ − e/Σ²: Σ² underflows
        # for amplitudes below ~1e-19) leaves float32. Below the smallest normal float (1.2e-38)
        # no lobe lights the plane: π = 1/K, constant.
        peak = dr.detach(dr.max(energy))
        lit = peak >= _TINY
        scaled = energy * dr.select(lit, dr.rcp(dr.select(lit, peak, 1.0)), 0.0)
        self.pmf = dr.select(lit, scaled / dr.select(lit, dr.sum(scaled), 1.0), 1.0 / self.k)
        # vmf_pdf = G/∫G for a unit-amplitude lobe: π_k/∫G_k per lobe, so that the loop shares one
        # exponential between L and p_l (λ clamped as in vmf_sample/vmf_pdf).
        self.pdf_scale = self.pmf / sg_integral(dr.maximum(lobes.sharpness, 1e-6), 1.0)

    def sample_index(self, u: mi.Float) -> mi.UInt32:
        cdf = dr.detach(dr.cumsum(self.pmf))
        cdf = cdf / dr.gather(mi.Float, cdf, mi.UInt32(self.k - 1))
        return dr.binary_search(0, self.k - 1, lambda i: dr.gather(mi.Float, cdf, i) <= u)


def _lobe_sums(tables: _LobeTables, l: mi.Vector3f, guide: _LobeTables | None):
    """``L(l)`` (RGB), ``p_l(l)`` and (with an explicit guide) the guide's ``q_l(l)``."""
    zero = dr.zeros(mi.Float, dr.width(l))

    def body(k, radiance, pdf, qpdf):
        unit = sg_eval(
            dr.gather(mi.Vector3f, tables.axis, k), dr.gather(mi.Float, tables.sharpness, k), 1.0, l
        )
        radiance = radiance + dr.gather(mi.Color3f, tables.amplitude, k) * unit
        pdf = pdf + dr.gather(mi.Float, tables.pdf_scale, k) * unit
        if guide is not None:
            g_unit = sg_eval(
                dr.gather(mi.Vector3f, guide.axis, k), dr.gather(mi.Float, guide.sharpness, k), 1.0, l
            )
            qpdf = qpdf + dr.gather(mi.Float, guide.pdf_scale, k) * g_unit
        return k + 1, radiance, pdf, qpdf

    _, radiance, pdf, qpdf = dr.while_loop(
        (dr.zeros(mi.UInt32, dr.width(l)), dr.zeros(mi.Color3f, dr.width(l)), zero, mi.Float(zero)),
        lambda k, *_: k < tables.k,
        body,
        labels=("k", "radiance", "pdf", "qpdf"),
        label="ebr_lobe_sum",
        max_iterations=-1,
    )
    return radiance, pdf, qpdf


def _chunk(
    points: ShadingPoints,
    guide_points: ShadingPoints,
    tables: _LobeTables,
    guide_tables: _LobeTables | None,
    strategy: int,
    first: int,
    count: int,
    spp: int,
    fresnel: str,
    seed: mi.UInt32,
) -> mi.Color3f:
    """Contribution of samples ``first … first+count−1`` of one strategy, summed per point."""
    n_pts = points.count
    n_b, n_l = strategy_counts(spp)
    e = dr.arange(mi.UInt32, n_pts * count)
    j = e // n_pts
    q = e - j * n_pts
    index = dr.opaque(mi.UInt32, first) + j
    u0, u1, u2 = pattern(dr.gather(mi.UInt32, points.pixel, q), index, strategy, seed)

    explicit_guide = guide_tables is not None
    sampler = guide_tables if explicit_guide else tables
    with dr.suspend_grad():
        gn = dr.gather(mi.Vector3f, guide_points.n, q)
        gv = dr.gather(mi.Vector3f, guide_points.v, q)
        if strategy == BRDF:
            l, q_own, _ = brdf_sample(
                gn,
                gv,
                dr.gather(mi.Color3f, guide_points.diffuse, q),
                dr.gather(mi.Color3f, guide_points.specular, q),
                dr.gather(mi.Float, guide_points.roughness, q),
                u0,
                mi.Point2f(u1, u2),
            )
        else:
            kk = sampler.sample_index(u0)
            l = vmf_sample(
                dr.gather(mi.Vector3f, sampler.axis, kk),
                dr.gather(mi.Float, sampler.sharpness, kk),
                mi.Point2f(u1, u2),
            )
            q_own = None
    l = dr.detach(l)

    n = dr.gather(mi.Vector3f, points.n, q)
    v = dr.gather(mi.Vector3f, points.v, q)
    d = dr.gather(mi.Color3f, points.diffuse, q)
    s = dr.gather(mi.Color3f, points.specular, q)
    r = dr.gather(mi.Float, points.roughness, q)
    fcos = brdf_eval_cos(n, l, v, d, s, r, fresnel)
    p_b = brdf_pdf(n, l, v, d, s, r)
    radiance, p_l, q_l = _lobe_sums(tables, l, guide_tables)
    if strategy == BRDF:
        p_own = p_b
    else:
        p_own = p_l
        q_own = q_l if explicit_guide else dr.detach(p_l)
    denom = n_b * p_b + n_l * p_l
    ok = (q_own > 0.0) & (denom > 0.0) & (l.z > 0.0)
    ratio = p_own / dr.select(ok, q_own * denom, 1.0)
    value = dr.select(ok, fcos * radiance * ratio, 0.0)
    value = dr.select(dr.isfinite(value.x) & dr.isfinite(value.y) & dr.isfinite(value.z), value, 0.0)
    acc = dr.zeros(mi.Color3f, n_pts)
    dr.scatter_reduce(dr.ReduceOp.Add, acc, value, q)
    return acc


def quadrature_environment(
    points: ShadingPoints,
    lobes: DrLobes,
    *,
    spp: int = 64,
    fresnel: str = "schlick",
    max_lanes: int = 1 << 21,
    seed: int = 0,
    guide: tuple[ShadingPoints, DrLobes] | None = None,
) -> mi.Color3f:
    """Environment radiance towards ``v`` at every point (``points.count`` lanes), estimated.

    ``guide``: the (points, lobes) the directions are drawn from; default detached copies of
    ``points`` and ``lobes``. Its points must be the same geometry (count and pixel order).
    """
    count = points.count
    if lobes.num_lobes == 0:
        return dr.zeros(mi.Color3f, count)
    tables = _LobeTables(lobes)
    if guide is None:
        guide_points, guide_tables = points.detach(), None
    else:
        guide_points = guide[0].detach()
        guide_tables = _LobeTables(guide[1].detach())
    seed_op = dr.opaque(mi.UInt32, 8 * seed)
    per_chunk = max(1, max_lanes // count)
    total = dr.zeros(mi.Color3f, count)
    for strategy, n_s in zip((BRDF, LOBE), strategy_counts(spp)):
        for first in range(0, n_s, per_chunk):
            total = total + _chunk(
                points,
                guide_points,
                tables,
                guide_tables,
                strategy,
                first,
                min(per_chunk, n_s - first),
                spp,
                fresnel,
                seed_op,
            )
    return total
