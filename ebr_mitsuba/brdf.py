"""The SVBRDF of ``docs/conventions.md`` ("BRDF"), written once in Dr.Jit.

``f(l, v) = d/π + D(h) F(v·h) G(l, v) / (4 (n·l)(n·v))`` with

* ``α = r²``, ``r`` clamped to ``[ROUGHNESS_MIN, 1]`` inside the BRDF only;
* ``D`` = GGX, evaluated as ``α² / (π (‖n×h‖² + α² (n·h)²)²)`` (finite for α → 0);
* ``G`` = separable exact Smith–GGX ``G₁(l) G₁(v)``, folded with ``1/(4 (n·l)(n·v))`` into
  ``1 / ((c_l + √(α² + (1−α²)c_l²)) (c_v + √(α² + (1−α²)c_v²)))`` (finite at grazing angles);
* ``F`` = Schlick with ``F₀ = s`` (RGB): ``s + (1 − s)(1 − v·h)⁵``; ``fresnel="none"`` uses
  ``F = s`` (to compare with Mitsuba's ``roughconductor(material='none')``).

All vectors are in the *tangent frame* of the surface: geometric normal ``+z``, ``n`` the shading
(normal-mapped) normal. Back-facing shading (``n·l ≤ 0``, ``n·v ≤ 0``) and directions below the
geometric surface (``l_z ≤ 0``, ``v_z ≤ 0``) give zero. Functions take Dr.Jit arrays of any
backend: directions as 3-vectors, ``d``/``s`` as RGB 3-vectors, ``r`` as a float array.

Sampling mixes GGX visible-normal sampling (Dupuy & Benyoub 2023 spherical caps) with cosine
sampling, the specular probability following the specular/diffuse luminance ratio.
"""

from __future__ import annotations

import math

import drjit as dr

from .colour import LUMINANCE_WEIGHTS
from .floors import GGX_D_FLOOR, NORMAL_Z_MIN, ROUGHNESS_MIN, SMITH_FLOOR
from .sg import coordinate_frame

INV_PI = 1.0 / math.pi
FRESNEL_MODES = ("schlick", "none")


def alpha_from_roughness(r):
    """GGX α = r², with r clamped to [ROUGHNESS_MIN, 1]."""
    rc = dr.clip(r, ROUGHNESS_MIN, 1.0)
    return rc * rc


def luminance(c):
    wr, wg, wb = LUMINANCE_WEIGHTS
    return wr * c.x + wg * c.y + wb * c.z


def ggx_d(n, h, alpha):
    """GGX normal distribution D(h) about ``n`` (unit ``n``, ``h``)."""
    c = dr.dot(n, h)
    x = dr.cross(n, h)
    a2 = alpha * alpha
    den = dr.squared_norm(x) + a2 * c * c
    return dr.select(c > 0.0, a2 * INV_PI / dr.maximum(den * den, GGX_D_FLOOR), 0.0)


def _lambda_term(c, alpha):
    a2 = alpha * alpha
    return c + dr.safe_sqrt(a2 + (1.0 - a2) * c * c)


def smith_vis(cl, cv, alpha):
    """G₁(l)G₁(v) / (4 (n·l)(n·v)) for exact separable Smith–GGX (stable at grazing angles)."""
    return 1.0 / dr.maximum(_lambda_term(cl, alpha) * _lambda_term(cv, alpha), SMITH_FLOOR)


def smith_g1(c, alpha):
    """Exact Smith–GGX masking G₁ = 2c / (c + √(α² + (1−α²)c²))."""
    return 2.0 * c / dr.maximum(_lambda_term(c, alpha), SMITH_FLOOR)


def fresnel_schlick(f0, cos_vh):
    m = dr.clip(1.0 - cos_vh, 0.0, 1.0)
    m2 = m * m
    return f0 + (1.0 - f0) * (m2 * m2 * m)


def _valid(n, l, v):
    return (dr.dot(n, l) > 0.0) & (dr.dot(n, v) > 0.0) & (l.z > 0.0) & (v.z > 0.0)


def specular_term(n, l, v, specular, roughness, fresnel: str = "schlick"):
    """Specular part ``D F G / (4 (n·l)(n·v))`` (no cosine), zero where back-facing."""
    alpha = alpha_from_roughness(roughness)
    h = dr.normalize(l + v)
    cl = dr.dot(n, l)
    cv = dr.dot(n, v)
    d = ggx_d(n, h, alpha)
    vis = smith_vis(dr.maximum(cl, 0.0), dr.maximum(cv, 0.0), alpha)
    if fresnel == "schlick":
        f = fresnel_schlick(specular, dr.dot(v, h))
    elif fresnel == "none":
        f = specular
    else:
        raise ValueError(f"unknown fresnel mode {fresnel!r}; use one of {FRESNEL_MODES}")
    return dr.select(_valid(n, l, v), f * (d * vis), 0.0)


def brdf_eval(n, l, v, diffuse, specular, roughness, fresnel: str = "schlick"):
    """f(l, v) (RGB, without the cosine)."""
    spec = specular_term(n, l, v, specular, roughness, fresnel)
    return dr.select(_valid(n, l, v), diffuse * INV_PI + spec, 0.0)


def brdf_eval_cos(n, l, v, diffuse, specular, roughness, fresnel: str = "schlick"):
    """f(l, v) · max(n·l, 0): the integrand's BRDF part (what Mitsuba's ``BSDF.eval`` returns)."""
    return brdf_eval(n, l, v, diffuse, specular, roughness, fresnel) * dr.maximum(dr.dot(n, l), 0.0)


def specular_probability(diffuse, specular):
    """Probability of picking the GGX lobe when sampling: luminance ratio, kept in [0.1, 0.9]
    unless one part is exactly zero."""
    ls = luminance(specular)
    ld = luminance(diffuse)
    p = ls / dr.maximum(ls + ld, 1e-12)
    p = dr.clip(p, 0.1, 0.9)
    p = dr.select(ld <= 0.0, 1.0, p)
    p = dr.select(ls <= 0.0, 0.0, p)
    return dr.select((ls <= 0.0) & (ld <= 0.0), 0.5, p)


def _to_local(s, t, n, w):
    return type(w)(dr.dot(w, s), dr.dot(w, t), dr.dot(w, n))


def _from_local(s, t, n, w):
    return s * w.x + t * w.y + n * w.z


def _cosine_hemisphere(sample):
    """Concentric-disk cosine sampling in a local frame (z up)."""
    x = 2.0 * sample.x - 1.0
    y = 2.0 * sample.y - 1.0
    use_x = dr.abs(x) > dr.abs(y)
    r = dr.select(use_x, x, y)
    phi = dr.select(
        use_x,
        (math.pi / 4.0) * y / dr.select(x == 0.0, 1.0, x),
        (math.pi / 2.0) - (math.pi / 4.0) * x / dr.select(y == 0.0, 1.0, y),
    )
    sp, cp = dr.sincos(phi)
    px = r * cp
    py = r * sp
    pz = dr.safe_sqrt(1.0 - px * px - py * py)
    return px, py, pz


def vndf_pdf(n, l, v, alpha):
    """Solid-angle pdf of a reflected direction ``l`` under visible-normal sampling:
    ``D(h) G₁(v) / (4 (n·v)) = D(h) / (2 (c_v + √(α² + (1−α²)c_v²)))``."""
    h = dr.normalize(l + v)
    cv = dr.maximum(dr.dot(n, v), 0.0)
    val = ggx_d(n, h, alpha) / (2.0 * dr.maximum(_lambda_term(cv, alpha), SMITH_FLOOR))
    return dr.select((dr.dot(n, v) > 0.0) & (dr.dot(n, l) > 0.0), val, 0.0)


def brdf_pdf(n, l, v, diffuse, specular, roughness):
    """Solid-angle pdf of :func:`brdf_sample` for direction ``l`` (zero where the sample is invalid)."""
    alpha = alpha_from_roughness(roughness)
    ps = specular_probability(diffuse, specular)
    cl = dr.dot(n, l)
    pdf = ps * vndf_pdf(n, l, v, alpha) + (1.0 - ps) * dr.maximum(cl, 0.0) * INV_PI
    return dr.select((cl > 0.0) & (l.z > 0.0) & (dr.dot(n, v) > 0.0) & (v.z > 0.0), pdf, 0.0)


def brdf_sample(n, v, diffuse, specular, roughness, sample1, sample2, fresnel: str = "schlick"):
    """Sample ``l`` given ``v``: returns ``(l, pdf, weight)`` with ``weight = f·cos/pdf`` (RGB).

    ``sample1`` (float) picks the lobe, ``sample2`` (2-vector) places the direction.
    """
    alpha = alpha_from_roughness(roughness)
    ps = specular_probability(diffuse, specular)
    s, t = coordinate_frame(n)
    vl = _to_local(s, t, n, v)
    # Visible-normal sampling with spherical caps (Dupuy & Benyoub 2023).
    V = type(v)
    wi_std = dr.normalize(V(alpha * vl.x, alpha * vl.y, vl.z))
    phi = 2.0 * math.pi * sample2.x
    z = (1.0 - sample2.y) * (1.0 + wi_std.z) - wi_std.z
    sin_t = dr.safe_sqrt(1.0 - z * z)
    sp, cp = dr.sincos(phi)
    hs = V(sin_t * cp + wi_std.x, sin_t * sp + wi_std.y, z + wi_std.z)
    h_loc = dr.normalize(V(alpha * hs.x, alpha * hs.y, dr.maximum(hs.z, 0.0)))
    l_spec_loc = 2.0 * dr.dot(vl, h_loc) * h_loc - vl
    px, py, pz = _cosine_hemisphere(sample2)
    l_diff_loc = V(px, py, pz)
    use_spec = sample1 < ps
    l_loc = dr.select(use_spec, l_spec_loc, l_diff_loc)
    l = dr.normalize(_from_local(s, t, n, l_loc))
    pdf = brdf_pdf(n, l, v, diffuse, specular, roughness)
    f = brdf_eval_cos(n, l, v, diffuse, specular, roughness, fresnel)
    weight = dr.select(pdf > 0.0, f / dr.maximum(pdf, 1e-30), 0.0)
    return l, pdf, weight


def perturbed_normal(normal_map_value):
    """Unit shading normal from a tangent-space normal-map value; the z component is clamped from
    below (NORMAL_Z_MIN) before normalising so exactly tangent normals stay finite."""
    V = type(normal_map_value)
    nz = dr.maximum(normal_map_value.z, NORMAL_Z_MIN)
    return dr.normalize(V(normal_map_value.x, normal_map_value.y, nz))
