"""Spherical-Gaussian math in Dr.Jit: the one implementation used by the ``sgenvmap`` emitter, the
fast renderer and SG extraction.

Convention (``docs/conventions.md``, "Spherical Gaussians"): ``G(ω) = μ · exp(λ (ξ·ω − 1))`` with
amplitude μ (RGB, ≥ 0), unit axis ξ (world, z-up) and sharpness λ > 0. Every function takes Dr.Jit
arrays (any backend): axes and directions as 3-vectors, λ as a float array, μ as a 3-vector (or a
float array).

Stable forms used throughout: ``exp(λ(cos − 1))``; integrals via ``−expm1(−2λ)/λ``; products with the
exponent ``−λ₁λ₂‖ξ₁−ξ₂‖²/(λₘ+λ₁+λ₂)``; vMF sampling ``cos θ = 1 + log1p(u·expm1(−2λ))/λ``.
"""

from __future__ import annotations

import math

import drjit as dr
import numpy as np

from .stable import expm1, log1p, one_minus_exp_neg2_over, safe_rsqrt_norm

TWO_PI = 2.0 * math.pi
FOUR_PI = 4.0 * math.pi


def sg_eval(axis, sharpness, amplitude, w):
    """Value of the lobe in direction ``w`` (unit): ``μ exp(λ(ξ·w − 1))``.

    ``ξ·w − 1`` is computed as ``−‖ξ − w‖²/2`` (equal for unit vectors, no cancellation near the
    axis, which matters for λ ≥ 1e4)."""
    return amplitude * dr.exp(sharpness * _cos_minus_one(axis, w))


def _cos_minus_one(axis, w):
    return -0.5 * dr.squared_norm(axis - w)


def sg_integral(sharpness, amplitude):
    """∫ G dω over the sphere: ``2π μ (1 − e^{−2λ})/λ`` (→ 4πμ as λ → 0)."""
    return amplitude * (TWO_PI * one_minus_exp_neg2_over(sharpness))


def sg_product(axis1, sharpness1, amplitude1, axis2, sharpness2, amplitude2):
    """Product of two lobes, itself a lobe: returns ``(axis, sharpness, amplitude)``.

    The amplitude uses the cancellation-free exponent ``λₘ − λ₁ − λ₂ = −λ₁λ₂‖ξ₁−ξ₂‖²/(λₘ+λ₁+λ₂)``.
    """
    um = sharpness1 * axis1 + sharpness2 * axis2
    lm = dr.safe_sqrt(dr.squared_norm(um))  # finite gradient when λ₁ξ₁ + λ₂ξ₂ = 0
    d = axis1 - axis2
    expo = -sharpness1 * sharpness2 * dr.squared_norm(d) / dr.maximum(lm + sharpness1 + sharpness2, 1e-30)
    axis = safe_rsqrt_norm(um)
    return axis, lm, amplitude1 * amplitude2 * dr.exp(expo)


def sg_inner_product(axis1, sharpness1, amplitude1, axis2, sharpness2, amplitude2):
    """∫ G₁ G₂ dω over the sphere (stable for any λ)."""
    _, lm, amp = sg_product(axis1, sharpness1, amplitude1, axis2, sharpness2, amplitude2)
    return amp * (TWO_PI * one_minus_exp_neg2_over(lm))


def sg_cosine_signed(axis, sharpness, amplitude, n):
    """∫ G(ω) (n·ω) dω over the whole sphere (signed cosine), closed form.

    ``= (n·ξ) · 2π [ (1 + e^{−2λ})/λ − (1 − e^{−2λ})/λ² ]``; below λ = 0.15 its Taylor series
    ``2λ/3 − 2λ²/3 + 2λ³/5 − 8λ⁴/45 + 4λ⁵/63`` replaces the cancelling difference.
    """
    lam = sharpness
    lam_s = dr.maximum(lam, 0.15)
    e = dr.exp(-2.0 * lam_s)
    om = -expm1(-2.0 * lam_s)  # 1 - e^{-2λ}
    big = (1.0 + e) / lam_s - om / (lam_s * lam_s)
    small = lam * (
        2.0 / 3.0 + lam * (-2.0 / 3.0 + lam * (2.0 / 5.0 + lam * (-8.0 / 45.0 + lam * (4.0 / 63.0))))
    )  # noqa: E501
    val = dr.select(lam < 0.15, small, big)
    return amplitude * (TWO_PI * dr.dot(n, axis) * val)


_GL_CACHE: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def gauss_legendre01(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [0, 1]."""
    if n not in _GL_CACHE:
        x, w = np.polynomial.legendre.leggauss(n)
        _GL_CACHE[n] = ((x + 1.0) / 2.0, w / 2.0)
    return _GL_CACHE[n]


def _clamped_cos_azimuth_integral(a, b):
    """∫₀^{2π} max(a + b cos φ, 0) dφ for b ≥ 0."""
    inside = dr.abs(a) < b
    q = dr.clip(a / dr.select(inside, b, 1.0), -1.0 + 1e-6, 1.0 - 1e-6)
    val_in = 2.0 * (a * dr.acos(-q) + b * dr.safe_sqrt(1.0 - q * q))
    val_out = TWO_PI * dr.maximum(a, 0.0)
    return dr.select(inside, val_in, val_out)


def sg_irradiance(axis, sharpness, amplitude, n, n_nodes: int = 8):
    """Diffuse irradiance ∫ G(ω) max(n·ω, 0) dω (clamped cosine).

    The azimuthal integral about ξ is closed form; the remaining 1-D integral over the lobe's
    polar variable t = ξ·ω runs in the vMF inverse-CDF variable u (so λ = 1e-4 and λ = 1e6 are
    equally well resolved). The azimuthal integral has kinks where the horizon of ``n`` touches
    the circle of constant t, at t = ±sin∠(n, ξ); the u-range is split there into three pieces,
    each integrated with ``n_nodes`` Gauss–Legendre nodes, so the integrand is smooth on each piece.
    Exact (to quadrature accuracy) whether the lobe is above, straddling or below the horizon.
    """
    c = dr.clip(dr.dot(n, axis), -1.0, 1.0)
    s = dr.safe_sqrt(1.0 - c * c)
    lam = dr.maximum(sharpness, 1e-6)
    em = expm1(-2.0 * lam)
    z = one_minus_exp_neg2_over(lam)

    def u_of_t(t):  # vMF CDF measured from the axis: u = expm1(λ(t − 1)) / expm1(−2λ)
        return dr.clip(expm1(lam * (t - 1.0)) / em, 0.0, 1.0)

    u_a = u_of_t(s)
    u_b = u_of_t(-s)
    nodes, weights = gauss_legendre01(n_nodes)
    acc = 0.0
    for lo, hi in ((0.0, u_a), (u_a, u_b), (u_b, 1.0)):
        width = hi - lo
        for x, wgt in zip(nodes.tolist(), weights.tolist()):
            u = lo + width * x
            t = dr.clip(1.0 + log1p(u * em) / lam, -1.0, 1.0)
            h = _clamped_cos_azimuth_integral(c * t, s * dr.safe_sqrt(1.0 - t * t))
            acc = acc + (wgt * width) * h
    return amplitude * (z * acc)


def coordinate_frame(n):
    """Orthonormal ``(s, t)`` with ``s × t = n`` for a unit ``n`` (Duff et al. 2017, branch-free)."""
    sign = dr.copysign(1.0, n.z)
    a = -1.0 / (sign + n.z)
    b = n.x * n.y * a
    V = type(n)
    s = V(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x)
    t = V(b, sign + n.y * n.y * a, -n.y)
    return s, t


def vmf_sample(axis, sharpness, sample):
    """Sample the normalised lobe (von Mises–Fisher) from a 2-D uniform ``sample``; returns ``ω``.

    ``cos θ = 1 + log1p(u · expm1(−2λ))/λ``, ``sin θ = sqrt(−r(r+2))`` with ``r = cos θ − 1``.
    """
    lam = dr.maximum(sharpness, 1e-6)
    r = dr.maximum(log1p(sample.x * expm1(-2.0 * lam)) / lam, -2.0)
    cos_t = 1.0 + r
    sin_t = dr.safe_sqrt(-r * (r + 2.0))
    phi = TWO_PI * sample.y
    sp, cp = dr.sincos(phi)
    s, t = coordinate_frame(axis)
    return s * (sin_t * cp) + t * (sin_t * sp) + axis * cos_t


def vmf_pdf(axis, sharpness, w):
    """Solid-angle density of :func:`vmf_sample`: ``λ/(2π(1 − e^{−2λ})) · exp(λ(ξ·ω − 1))``."""
    lam = dr.maximum(sharpness, 1e-6)
    return dr.exp(lam * _cos_minus_one(axis, w)) / (TWO_PI * one_minus_exp_neg2_over(lam))
