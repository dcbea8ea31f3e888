"""Slow, obvious float64 numpy reference for the BRDF, the SG integrals and environment shading.

Nothing here imports Dr.Jit: this module is the independent yardstick that the Dr.Jit core
(:mod:`ebr_mitsuba.brdf`, :mod:`ebr_mitsuba.sg`, :mod:`ebr_mitsuba.stable`) and the renderers are
tested against. It is written for clarity, not speed (a Python loop over points, dense grids).

Conventions (``docs/conventions.md``)
-----------------------
* All directions are unit 3-vectors (``(..., 3)`` arrays) in the tangent frame of the sample,
  which for the planar sample is also the world frame: geometric normal ``+z``, tangent ``+x``.
  ``normal`` is the shading (normal-mapped) normal, ``view`` points from the surface to the camera,
  ``l``/``ω`` point from the surface to the light.
* BRDF ``f(l, v) = d/π + D(h) F(v·h) G₁(l) G₁(v) / (4 (n·l)(n·v))`` in its *textbook* form:
  ``D = α² / (π ((n·h)² (α² − 1) + 1)²)`` (fine in float64), ``G₁(c) = 2c / (c + √(α² + (1 − α²)c²))``,
  Schlick ``F = s + (1 − s)(1 − v·h)⁵`` (``fresnel="none"``: ``F = s``), ``α = r²`` with ``r``
  clamped to ``[0.03, 1]``. Zero where ``n·l ≤ 0``, ``n·v ≤ 0``, ``l_z ≤ 0`` or ``v_z ≤ 0``.
  ``n``, ``l`` and ``v`` are renormalised in float64 first (the GGX peak at α² = 8·10⁻⁷ is
  sensitive to the 10⁻⁷ norm error of float32 inputs).
* Spherical Gaussian ``G(ω) = μ exp(λ (ξ·ω − 1))``. The SG functions evaluate this formula with the
  axis exactly as given (a float32 axis is not exactly unit; ``ξ = |ξ| ξ̂`` is folded into
  ``λ' = λ|ξ|`` and ``μ' = μ e^{λ(|ξ| − 1)}``), so a float32 implementation fed the same numbers is
  compared against the same function.

Quadratures
-----------
Every rule is a product grid of *rings* (a polar variable with Gauss–Legendre panels, an azimuth
φ). A clipping plane ``c·ω > 0`` restricted to a ring is a trigonometric polynomial in φ whose
roots are solved exactly; the nodes of a clipped ring go on its visible arcs (Gauss–Legendre), and
the polar panels are split at the rings tangent to a clipping circle, so the clamps
``max(n·ω, 0)`` and ``[ω_z > 0]`` are grid boundaries, never kinks or jumps inside a cell.

* :func:`vmf_rule`: rings about the lobe axis; polar variable = the vMF inverse CDF
  ``cos θ = 1 + log1p(u·expm1(−2λ))/λ`` (the far half in ``s = 1 − u``, graded towards the
  antipode), so ``G dω = μ (1 − e^{−2λ})/λ du dφ`` and λ = 10⁻⁸ … 10⁶ are resolved alike.
* :func:`polar_rule`: plain ``θ`` on geometric panels ``[0, θ₀], [θ₀, 2θ₀], …, π``; used for
  :func:`sg_integral` (where the vMF warp would reproduce the closed form by construction).
* :func:`ggx_rule`: half vectors on rings about ``n`` warped by the GGX CDF
  ``tan²θ_h = α² u/(1 − u)`` (graded towards ``u → 1``), mapped to ``l = 2(v·h)h − v``.
* :func:`hemisphere_rule`: uniform in ``cos θ`` about ``+z``.
* :func:`integration_rule` (used by :func:`render_env`): all of the above, clipped to
  ``{ω_z > 0, n·ω > 0}``, combined by a partition of unity ``w_s = h_s / Σ h`` with
  ``h_s = C·P_s²·p_s`` for the lobe and GGX grids (``p_s`` the grid's density, ``P_s`` its peak,
  ``C = 10¹²``) and ``h = 1/(2π)`` for the hemisphere grid. The ``P_s²`` factor lets a narrow
  strategy keep its own tails down to ``(P_broad/P_narrow)²`` of its peak: with the plain balance
  heuristic the broad grid had to resolve the tails of the narrow lobe and the error stalled
  at 1e-4 … 1e-2.

Measured accuracy (float64; relative difference to the same rule refined)
--------------------------------------------------------------------------
* :func:`sg_inner_product`, :func:`sg_cosine_signed`, :func:`sg_irradiance` (above, straddling
  and below the horizon), λ = 10⁻⁴ … 10⁶: ≤ 1e-9 (against the closed forms where they exist:
  ≤ 1e-10); :func:`sg_integral` ≤ 1e-12.
* :func:`render_env` at the default ``n = 16`` (against ``n = 48``): ≤ 1e-5 on broad and sharp
  lobes (λ = 10⁻³ … 10⁴) with roughness 0 … 1, views from normal incidence to 89°, normals tilted
  up to 88° and a λ = 10⁴ lobe just below the horizon (only its tail visible); the exception is a
  sharp lobe lying in the far tail of a much sharper GGX peak (λ = 10⁴ lobe 0.5 rad from an
  r = 0 mirror direction): ≤ 5e-5, because the GGX grid claims the lobe's outer tail. ``n = 8``
  gives ≤ 5e-4. Cost: 0.05 … 0.3 s per point and lobe-count dependent (sharp clipped lobes and
  tilted normals cost most).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from .floors import ROUGHNESS_MIN

INV_PI = 1.0 / math.pi
TWO_PI = 2.0 * math.pi

__all__ = [
    "brdf_eval",
    "sg_eval",
    "sg_integral",
    "sg_inner_product",
    "sg_cosine_signed",
    "sg_irradiance",
    "vmf_pdf",
    "vmf_rule",
    "polar_rule",
    "ggx_rule",
    "hemisphere_rule",
    "integration_rule",
    "render_env",
    "render_point",
]


# -- small helpers ------------------------------------------------------------------------------
def _f64(x) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


def _normalize(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sum(a * b, axis=-1)


@lru_cache(maxsize=64)
def _gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [-1, 1]."""
    return np.polynomial.legendre.leggauss(n)


def _gl01(n: int, lo: float = 0.0, hi: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    x, w = _gauss_legendre(n)
    half = 0.5 * (hi - lo)
    return lo + half * (x + 1.0), half * w


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit ``axis`` (3,) to an orthonormal frame."""
    x, y, z = axis
    sign = math.copysign(1.0, z)
    a = -1.0 / (sign + z)
    b = x * y * a
    return (np.array([1.0 + sign * x * x * a, sign * b, -sign * x]), np.array([b, sign + y * y * a, -y]))


def _rgb(x) -> np.ndarray:
    """An RGB array ``(..., 3)``; a scalar becomes grey."""
    x = _f64(x)
    return np.full(3, float(x)) if x.ndim == 0 else x


def _alpha(roughness) -> np.ndarray:
    r = np.clip(_f64(roughness), ROUGHNESS_MIN, 1.0)
    return r * r


def _lobe_params(axis, sharpness, amplitude):
    """``(ξ̂, λ', μ')`` with ``μ exp(λ(ξ·ω − 1)) = μ' exp(λ'(ξ̂·ω − 1))`` for a non-unit ``ξ``."""
    axis = _f64(axis)
    norm = float(np.linalg.norm(axis))
    lam = float(sharpness)
    return axis / norm, lam * norm, _f64(amplitude) * math.exp(lam * (norm - 1.0))


# -- BRDF ---------------------------------------------------------------------------------------
def ggx_d(cos_h, alpha) -> np.ndarray:
    """Textbook GGX ``D = α² / (π ((n·h)²(α² − 1) + 1)²)`` for ``n·h > 0`` (zero otherwise)."""
    a2 = alpha * alpha
    den = cos_h * cos_h * (a2 - 1.0) + 1.0
    return np.where(cos_h > 0.0, a2 / (math.pi * den * den), 0.0)


def smith_g1(c, alpha) -> np.ndarray:
    """Exact Smith–GGX masking ``G₁(c) = 2c / (c + √(α² + (1 − α²)c²))`` for ``c > 0``."""
    a2 = alpha * alpha
    c = np.maximum(c, 0.0)
    return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c))


def brdf_eval(n, l, v, diffuse, specular, roughness, fresnel: str = "schlick") -> np.ndarray:
    """``f(l, v)`` (no cosine), shape ``(..., 3)``.

    ``n``, ``l``, ``v``: ``(..., 3)`` directions (renormalised here); ``diffuse``, ``specular``:
    ``(..., 3)`` RGB or broadcastable scalars; ``roughness``: ``(...)``. All broadcast together.
    """
    if fresnel not in ("schlick", "none"):
        raise ValueError(f"unknown fresnel mode {fresnel!r}; use 'schlick' or 'none'")
    n, l, v = _f64(n), _f64(l), _f64(v)
    valid = (_dot(n, l) > 0.0) & (_dot(n, v) > 0.0) & (l[..., 2] > 0.0) & (v[..., 2] > 0.0)
    n, l, v = _normalize(n), _normalize(l), _normalize(v)
    alpha = _alpha(roughness)
    hv = l + v
    h = hv / np.maximum(np.linalg.norm(hv, axis=-1, keepdims=True), 1e-300)
    cl = np.where(valid, _dot(n, l), 1.0)
    cv = np.where(valid, _dot(n, v), 1.0)
    d = ggx_d(_dot(n, h), alpha)
    g = smith_g1(cl, alpha) * smith_g1(cv, alpha)
    s = _rgb(specular)
    if fresnel == "schlick":
        f = s + (1.0 - s) * ((1.0 - _dot(v, h)) ** 5)[..., None]
    else:
        f = s + 0.0 * _dot(v, h)[..., None]
    spec = f * (d * g / (4.0 * cl * cv))[..., None]
    out = _rgb(diffuse) * INV_PI + spec
    return np.where(valid[..., None], out, 0.0)


# -- quadrature rules ---------------------------------------------------------------------------
# A ring is a one-parameter family of directions ω(φ), φ ∈ [0, 2π). A clipping constraint g(ω) > 0
# restricted to a ring is a trigonometric polynomial of degree ≤ 2 in φ, stored as its
# coefficients (a0, a1, b1, a2, b2): g = a0 + a1 cos φ + b1 sin φ + a2 cos 2φ + b2 sin 2φ.
def _trig_eval(c: np.ndarray, phi: np.ndarray) -> np.ndarray:
    return c[0] + c[1] * np.cos(phi) + c[2] * np.sin(phi) + c[3] * np.cos(2 * phi) + c[4] * np.sin(2 * phi)


def _trig_roots(c: np.ndarray) -> list[float]:
    """Real roots in φ of one trigonometric polynomial (at most 4)."""
    a0, a1, b1, a2, b2 = (float(x) for x in c)
    scale = abs(a0) + abs(a1) + abs(b1) + abs(a2) + abs(b2)
    if scale == 0.0:
        return []
    if abs(a2) + abs(b2) <= 1e-13 * scale:
        rho = math.hypot(a1, b1)
        if rho <= abs(a0):
            return []
        phi0 = math.atan2(b1, a1)
        beta = math.acos(-a0 / rho)
        return [phi0 - beta, phi0 + beta]
    # z = e^{iφ}: z²·g(φ) is a polynomial of degree 4 in z; its unit-modulus roots are the zeros.
    poly = [(a2 - 1j * b2) / 2, (a1 - 1j * b1) / 2, a0, (a1 + 1j * b1) / 2, (a2 + 1j * b2) / 2]
    roots = np.roots(poly)
    return [float(np.angle(r)) for r in roots if abs(abs(r) - 1.0) < 1e-7]


def _ring_arcs(coefs: np.ndarray, n_phi: int):
    """Azimuthal nodes of rings clipped to ``all constraints > 0``.

    ``coefs``: (R, M, 5). Unclipped rings get ``n_phi`` uniform (trapezoid) nodes, clipped ones
    ``n_phi`` Gauss–Legendre nodes on every visible arc, so the clip is a grid boundary.
    Returns ``(ring (N,), phi (N,), q (N,))`` with ``Σ q`` per ring = visible arc length.
    """
    xg, wg = _gauss_legendre(n_phi)
    uni = TWO_PI * (np.arange(n_phi) + 0.5) / n_phi
    rings, phis, qs = [], [], []
    for r in range(coefs.shape[0]):
        roots = sorted(x % TWO_PI for c in coefs[r] for x in _trig_roots(c))
        if not roots:
            if all(_trig_eval(c, 0.0) > 0.0 for c in coefs[r]):
                rings.append(np.full(n_phi, r))
                phis.append(uni)
                qs.append(np.full(n_phi, TWO_PI / n_phi))
            continue
        edges = roots + [roots[0] + TWO_PI]
        for lo, hi in zip(edges[:-1], edges[1:]):
            if hi - lo < 1e-15:
                continue
            mid = 0.5 * (lo + hi)
            if all(_trig_eval(c, mid) > 0.0 for c in coefs[r]):
                half = 0.5 * (hi - lo)
                rings.append(np.full(n_phi, r))
                phis.append(mid + half * xg)
                qs.append(half * wg)
    if not rings:
        return np.zeros(0, dtype=int), np.zeros(0), np.zeros(0)
    return np.concatenate(rings), np.concatenate(phis), np.concatenate(qs)


def _circle_constraints(axis, e1, e2, t, st, clips) -> np.ndarray:
    """Coefficients (R, M, 5) of ``c·ω`` on the circles ``ω = t·axis + st (e1 cos φ + e2 sin φ)``."""
    out = np.zeros((t.size, len(clips), 5))
    for m, c in enumerate(clips):
        out[:, m, 0] = float(c @ axis) * t
        out[:, m, 1] = float(c @ e1) * st
        out[:, m, 2] = float(c @ e2) * st
    return out


def _graded(edges: set, x: float, limit: float = 0.5) -> None:
    """Add ``x, 4x, 16x, … < limit``: panels graded away from a pole at 0 (a square-root
    singularity of the ring geometry), so a break close to the pole (or a clipping circle through
    it, x = 0) stays resolved."""
    x = max(x, 1e-14)  # a break at the pole itself: grade from 1e-14
    while x < limit:
        edges.add(x)
        x *= 4.0


def _vmf_panels(lam: float, em: float, breaks_t) -> list[tuple[str, float, float]]:
    """Gauss–Legendre panels of the vMF variable for :func:`vmf_rule`.

    ``u ∈ [0, 1]`` is the vMF CDF measured from the axis; its far half is parametrised by
    ``s = 1 − u`` so the antipodal tail keeps full precision. ``s`` is graded geometrically
    (``s = 16⁻ᵏ``) down to ``e^{−2λ}`` (where ``cos θ`` has reached −1) because ``cos θ(s)`` has a
    logarithmic endpoint behaviour there; ``breaks_t`` adds edges at given ``cos θ`` values (where
    the clipped rings become tangent to a clipping circle), graded away from the nearer pole.
    """
    u_edges = {0.0, 0.5}
    s_edges = {0.0, 0.5}
    k_max = min(int(math.ceil(2.0 * lam / math.log(16.0))) + 1, 14)
    for k in range(1, k_max + 1):
        s_edges.add(16.0**-k)
    for tb in breaks_t:
        u = math.expm1(lam * (tb - 1.0)) / em  # e^{λ(t−1)} = 1 + u·em
        if u <= 0.5:
            _graded(u_edges, u)
        else:
            _graded(s_edges, (math.exp(lam * (tb - 1.0)) - math.exp(-2.0 * lam)) / -em)
    u_e = sorted(u_edges)
    s_e = sorted(s_edges)
    return [("u", lo, hi) for lo, hi in zip(u_e[:-1], u_e[1:]) if hi - lo > 1e-15] + [
        ("s", lo, hi) for lo, hi in zip(s_e[:-1], s_e[1:]) if hi - lo > 1e-300
    ]


def _tangent_heights(axis, clips) -> list[float]:
    """``cos θ`` about ``axis`` of the rings tangent to the great circles ``c·ω = 0``."""
    out = []
    for c in clips:
        cz = float(axis @ c)
        st = math.sqrt(max(1.0 - cz * cz, 0.0))
        out += [st, -st]  # ±1 when the circle passes through a pole: graded towards it
    return out


def vmf_rule(axis, sharpness, n_u: int = 32, n_phi: int = 64, clips=()):
    """Product grid for ``∫ h(ω) dω`` warped by the vMF lobe ``(axis, sharpness)``.

    ``n_u`` Gauss–Legendre nodes per panel of the polar variable (see :func:`_vmf_panels`),
    ``n_phi`` azimuthal nodes per ring or per visible arc. ``clips``: unit vectors ``c``; the rule
    covers only ``c·ω > 0`` for all of them. Returns ``(dirs (N, 3), primary (N,), dw (N,))`` with
    ``Σ h(ω_i) dw_i ≈ ∫ h dω``; ``primary`` are the weights in the (u, φ/2π) unit square
    (``dw = primary / vmf_pdf``). ``axis`` need not be unit.
    """
    xi = _normalize(_f64(axis))
    lam = float(sharpness) * float(np.linalg.norm(_f64(axis)))
    e1, e2 = _frame(xi)
    em = math.expm1(-2.0 * lam)  # in (-1, 0)
    e2l = math.exp(-2.0 * lam)
    clips = [_normalize(_f64(c)) for c in clips]
    rs, gs, qus = [], [], []
    for var, lo, hi in _vmf_panels(lam, em, _tangent_heights(xi, clips)):
        x, q = _gl01(n_u, lo, hi)
        g = 1.0 + x * em if var == "u" else e2l - x * em  # e^{λ(cos θ − 1)}
        if var == "u" or e2l > 0.5:  # g near 1: log1p of g − 1 = em·u keeps the digits
            r = np.log1p((x if var == "u" else 1.0 - x) * em) / lam
        else:  # g far from 1: log(g) itself is exact to an ulp, down to g ~ 1e-300
            r = np.log(g) / lam
        rs.append(r)
        gs.append(g)
        qus.append(q)
    r = np.maximum(np.concatenate(rs), -2.0)  # cos θ − 1
    g = np.concatenate(gs)
    qu = np.concatenate(qus)
    t = 1.0 + r
    st = np.sqrt(np.maximum(-r * (r + 2.0), 0.0))
    jac = -em / (lam * g)  # |d cos θ / du|
    ring, phi, qphi = _ring_arcs(_circle_constraints(xi, e1, e2, t, st, clips), n_phi)
    sin_t = st[ring]
    dirs = e1 * (sin_t * np.cos(phi))[:, None] + e2 * (sin_t * np.sin(phi))[:, None] + xi * t[ring][:, None]
    primary = qu[ring] * qphi / TWO_PI
    return dirs, primary, qu[ring] * qphi * jac[ring]


def polar_rule(axis, sharpness, n_theta: int = 32, n_phi: int = 64):
    """Polar grid about ``axis`` on geometric panels ``θ ∈ [0, θ₀], [θ₀, 2θ₀], …, π`` with
    ``θ₀ = min(π, 0.1/√λ)``, Gauss–Legendre per panel. Returns ``(dirs (N, 3), dw (N,))``."""
    xi = _normalize(_f64(axis))
    lam = max(float(sharpness), 1e-12)
    e1, e2 = _frame(xi)
    edges = [0.0]
    th = min(math.pi, 0.1 / math.sqrt(lam))
    while th < math.pi:
        edges.append(th)
        th *= 2.0
    edges.append(math.pi)
    thetas, qs = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        x, q = _gl01(n_theta, lo, hi)
        thetas.append(x)
        qs.append(q * np.sin(x))
    theta = np.concatenate(thetas)[:, None]
    q = np.concatenate(qs)[:, None]
    phi = (TWO_PI * (np.arange(n_phi) + 0.5) / n_phi)[None, :]
    dirs = (
        e1 * (np.sin(theta) * np.cos(phi))[..., None]
        + e2 * (np.sin(theta) * np.sin(phi))[..., None]
        + xi * np.broadcast_to(np.cos(theta), (theta.size, n_phi))[..., None]
    )
    dw = np.broadcast_to(q * (TWO_PI / n_phi), dirs.shape[:2])
    return dirs.reshape(-1, 3), dw.reshape(-1)


def _ggx_ring_constraints(n, e1, e2, v, ch, sh, clips) -> np.ndarray:
    """Coefficients (R, M, 5) of ``c·l`` on the rings ``h = ch·n + sh (e1 cos φ + e2 sin φ)``,
    ``l = 2(v·h)h − v``: with ``v·h = A + P cos φ + Q sin φ`` and ``c·h = C + R cos φ + S sin φ``,
    ``c·l = 2(v·h)(c·h) − c·v`` is a trigonometric polynomial of degree 2."""
    A, P, Q = ch * float(v @ n), sh * float(v @ e1), sh * float(v @ e2)
    coefs = np.zeros((ch.size, len(clips), 5))
    for m, c in enumerate(clips):
        C, R, S = ch * float(c @ n), sh * float(c @ e1), sh * float(c @ e2)
        coefs[:, m] = np.stack(
            [
                2 * A * C + P * R + Q * S - float(c @ v),
                2 * (A * R + C * P),
                2 * (A * S + C * Q),
                P * R - Q * S,
                P * S + Q * R,
            ],
            axis=-1,
        )
    return coefs


def _ggx_tangencies(n, e1, e2, v, alpha, clips) -> list[float]:
    """``θ_h`` of the rings tangent to (or, in degenerate cases, lying on) a clipping curve: where
    the number of sign changes of a constraint along the ring, or its sign at φ = 0, changes
    (scanned on a log-spaced θ_h grid, then bisected)."""
    phi = TWO_PI * np.arange(512) / 512

    def counts(theta):
        """Per ring and constraint: sign changes along the ring, and the sign at φ = 0 (a ring
        can also switch from fully visible to fully hidden, e.g. for v = n)."""
        coefs = _ggx_ring_constraints(n, e1, e2, v, np.cos(theta), np.sin(theta), clips)
        g = _trig_eval(np.moveaxis(coefs, -1, 0)[..., None], phi)  # (R, M, 512)
        changes = np.sum(np.sign(g) != np.sign(np.roll(g, 1, axis=-1)), axis=-1)  # (R, M)
        return np.concatenate([changes, g[..., 0] > 0.0], axis=-1)

    theta = np.concatenate([[0.0], np.geomspace(1e-3 * alpha, math.pi / 2 - 1e-9, 2000)])
    cnt = counts(theta)
    out = []
    for i in np.nonzero(np.any(cnt[1:] != cnt[:-1], axis=-1))[0]:
        lo, hi = theta[i], theta[i + 1]
        c_lo = cnt[i]
        for _ in range(50):
            mid = 0.5 * (lo + hi)
            if np.array_equal(counts(np.array([mid]))[0], c_lo):
                lo = mid
            else:
                hi = mid
        out.append(0.5 * (lo + hi))
    return out


def ggx_rule(normal, view, roughness, n_u: int = 16, n_phi: int = 64, clips=()):
    """Grid of light directions ``l = 2(v·h)h − v`` with ``h`` warped by the GGX CDF about ``normal``
    (``tan²θ_h = α² u/(1 − u)``).

    ``n_u`` Gauss–Legendre nodes per panel of ``u``: ``[0, ½]``, then ``w = 1 − u`` graded
    geometrically (``w = ½·4⁻ᵏ``) down to ``10⁻¹⁴α²`` (``u → 1`` is where ``h`` meets the horizon of
    ``n``: a wide solid angle of ``l`` for small α). ``clips``: unit vectors ``c``; on every ring of
    ``h`` the constraint ``c·l > 0`` is a trigonometric polynomial of degree 2 in φ, solved exactly,
    and ``n_phi`` nodes go on each visible arc; panels are split at rings tangent to a clipping
    curve. Returns ``(dirs (N, 3), primary (N,))``; the density of ``l`` is :func:`ggx_l_pdf`.
    """
    n = _normalize(_f64(normal))
    v = _normalize(_f64(view))
    clips = [_normalize(_f64(c)) for c in clips]
    alpha = float(_alpha(roughness))
    a2 = alpha * alpha
    e1, e2 = _frame(n)
    u_edges = {0.0, 0.5}
    w_edges = {0.0, 0.5}
    w = 0.5
    while w > 1e-14 * a2:
        w /= 4.0
        w_edges.add(w)
    for th in _ggx_tangencies(n, e1, e2, v, alpha, clips) if clips else []:
        c2, s2 = math.cos(th) ** 2, math.sin(th) ** 2
        wb = a2 * c2 / (a2 * c2 + s2)
        if wb >= 0.5:
            _graded(u_edges, s2 / (a2 * c2 + s2))
        else:
            w_edges.add(wb)
    u_e, w_e = sorted(u_edges), sorted(w_edges)
    panels = [("u", lo, hi) for lo, hi in zip(u_e[:-1], u_e[1:]) if hi - lo > 1e-15] + [
        ("w", lo, hi) for lo, hi in zip(w_e[:-1], w_e[1:]) if hi - lo > 1e-300
    ]
    cos_l, sin_l, q_l = [], [], []
    for var, lo, hi in panels:
        x, q = _gl01(n_u, lo, hi)
        u, w = (x, 1.0 - x) if var == "u" else (1.0 - x, x)
        den = w + a2 * u
        cos_l.append(np.sqrt(w / den))
        sin_l.append(np.sqrt(a2 * u / den))
        q_l.append(q)
    ch = np.concatenate(cos_l)
    sh = np.concatenate(sin_l)
    qu = np.concatenate(q_l)
    ring, phi, qphi = _ring_arcs(_ggx_ring_constraints(n, e1, e2, v, ch, sh, clips), n_phi)
    h = (
        e1 * (sh[ring] * np.cos(phi))[:, None]
        + e2 * (sh[ring] * np.sin(phi))[:, None]
        + n * ch[ring][:, None]
    )
    l = 2.0 * _dot(h, v)[:, None] * h - v
    return l, qu[ring] * qphi / TWO_PI


def ggx_l_pdf(normal, view, roughness, w) -> np.ndarray:
    """Solid-angle density of :func:`ggx_rule`'s directions: ``D(h)(n·h)/(4 |v·h|)`` with ``h`` the
    half vector of ``(w, view)`` flipped into the hemisphere of ``normal``. ``w``: (N, 3)."""
    n = _normalize(_f64(normal))
    v = _normalize(_f64(view))
    alpha = float(_alpha(roughness))
    hv = _f64(w) + v
    h = hv / np.maximum(np.linalg.norm(hv, axis=-1, keepdims=True), 1e-300)
    ch = _dot(h, n)
    h = np.where((ch < 0.0)[..., None], -h, h)
    ch = np.abs(ch)
    vh = np.maximum(np.abs(_dot(v, h)), 1e-300)
    return ggx_d(ch, alpha) * ch / (4.0 * vh)


def hemisphere_rule(n_u: int = 16, n_phi: int = 64, clips=()):
    """Uniform grid on the upper hemisphere ``ω_z > 0``: Gauss–Legendre in ``cos θ`` on panels split
    where rings touch the clipping circles (graded away from the zenith), ``n_phi`` nodes per ring
    or visible arc. Returns ``(dirs (N, 3), primary (N,))``; the density is ``1/(2π)``."""
    z = np.array([0.0, 0.0, 1.0])
    clips = [_normalize(_f64(c)) for c in clips]
    edges = {0.0, 1.0}
    for tb in _tangent_heights(z, clips):
        if 0.0 <= tb <= 1.0:
            _graded(edges, 1.0 - tb, 1.0)
    edges = sorted(1.0 - e for e in edges)
    ts, qs = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        if hi - lo > 1e-15:
            x, q = _gl01(n_u, lo, hi)
            ts.append(x)
            qs.append(q)
    t = np.concatenate(ts)
    qt = np.concatenate(qs)
    st = np.sqrt(1.0 - t * t)
    ring, phi, qphi = _ring_arcs(
        _circle_constraints(z, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), t, st, clips), n_phi
    )
    dirs = np.stack([st[ring] * np.cos(phi), st[ring] * np.sin(phi), t[ring]], axis=-1)
    return dirs, qt[ring] * qphi / TWO_PI


CLAIM = 1e12


def integration_rule(normal, view, roughness, env=None, n: int = 16):
    """Nodes and weights for ``∫ F(ω) dω`` over ``{ω_z > 0, n·ω > 0}`` at one shading point,
    resolving the GGX lobe of ``(normal, view, roughness)`` and every lobe of ``env`` (an
    :class:`SGEnvironment` or None).

    Strategies: one clipped :func:`vmf_rule` per lobe, a clipped :func:`ggx_rule` and a clipped
    :func:`hemisphere_rule`, ``n`` nodes per panel and ``4n`` per ring/arc. Partition of unity
    ``w_s = h_s / Σ h`` with ``h_s = c_s·p_s``: ``c_s = CLAIM·P_s²`` (``P_s`` the peak of the
    density ``p_s``) for the lobe and GGX grids, ``c_s = 1`` for the hemisphere grid, which thus
    only takes what no importance grid reaches. Node ``i`` of strategy ``s`` (primary weight
    ``a_i``) gets ``dw_i = a_i c_s / Σ h``. Returns ``(dirs (N, 3), dw (N,))``.
    """
    nrm = _normalize(_f64(normal))
    v = _normalize(_f64(view))
    clips = [np.array([0.0, 0.0, 1.0]), nrm]
    dirs_list, prim_list, claims, lobes = [], [], [], []
    if env is not None:
        for k in range(env.num_lobes):
            xi, lam, _ = _lobe_params(env.axis[k], env.sharpness[k], 1.0)
            d, p, _ = vmf_rule(xi, lam, n_u=n, n_phi=4 * n, clips=clips)
            dirs_list.append(d)
            prim_list.append(p)
            claims.append(CLAIM * float(vmf_pdf(xi, lam, xi)) ** 2)
            lobes.append((xi, lam, claims[-1]))
    d, p = ggx_rule(nrm, v, roughness, n_u=n, n_phi=4 * n, clips=clips)
    dirs_list.append(d)
    prim_list.append(p)
    ggx_peak = 1.0 / (4.0 * math.pi * float(_alpha(roughness)) ** 2 * max(float(nrm @ v), 1e-6))
    claims.append(CLAIM * ggx_peak**2)
    d, p = hemisphere_rule(n_u=n, n_phi=4 * n, clips=clips[1:])
    dirs_list.append(d)
    prim_list.append(p)
    claims.append(1.0)
    dirs = np.concatenate(dirs_list)
    hsum = claims[-2] * ggx_l_pdf(nrm, v, roughness, dirs) + 1.0 / TWO_PI
    for xi, lam, c in lobes:
        hsum = hsum + c * vmf_pdf(xi, lam, dirs)
    scale = np.concatenate([np.full(len(d), c) for d, c in zip(dirs_list, claims)])
    return dirs, np.concatenate(prim_list) * scale / hsum


# -- spherical Gaussians ------------------------------------------------------------------------
def _times_amplitude(val: np.ndarray, amplitude) -> np.ndarray:
    """``val (...)`` times an amplitude that is a scalar (result ``(...)``) or RGB ``(..., 3)``."""
    amp = _f64(amplitude)
    return val * amp if amp.ndim == 0 else val[..., None] * amp


def sg_eval(axis, sharpness, amplitude, w) -> np.ndarray:
    """``μ exp(λ(ξ·w − 1))``; ``axis``/``w`` (..., 3), ``sharpness`` (...); ``amplitude`` scalar
    or RGB (..., 3) (the same convention for every SG function here)."""
    g = np.exp(_f64(sharpness) * (_dot(_f64(axis), _f64(w)) - 1.0))
    return _times_amplitude(g, amplitude)


def vmf_pdf(axis, sharpness, w) -> np.ndarray:
    """vMF density ``λ/(2π(1 − e^{−2λ})) exp(λ(ξ·w − 1))`` (closed form, float64, numpy expm1)."""
    lam = _f64(sharpness)
    return lam / (TWO_PI * -np.expm1(-2.0 * lam)) * np.exp(lam * (_dot(_f64(axis), _f64(w)) - 1.0))


def _per_lobe(fn, *arrays, vec=()):
    """Broadcast the leading dims of the arguments and call ``fn`` per element (a Python loop)."""
    shaped = []
    for i, a in enumerate(arrays):
        a = _f64(a)
        shaped.append(a if i in vec else a[..., None])
    shape = np.broadcast_shapes(*[a.shape[:-1] for a in shaped])
    flat = [np.broadcast_to(a, shape + a.shape[-1:]).reshape(-1, a.shape[-1]) for a in shaped]
    res = [fn(*[f[i] if j in vec else f[i][0] for j, f in enumerate(flat)]) for i in range(flat[0].shape[0])]
    res = np.array(res, dtype=np.float64)
    return res.reshape(shape + res.shape[1:])


def sg_integral(sharpness, amplitude, n_theta: int = 48) -> np.ndarray:
    """``∫ G dω`` over the sphere by :func:`polar_rule` quadrature; ``(...)``, or ``(..., 3)``
    for RGB amplitudes (last axis 3)."""
    z = np.array([0.0, 0.0, 1.0])

    def one(lam):
        d, dw = polar_rule(z, lam, n_theta=n_theta, n_phi=4)
        return float(np.sum(np.exp(lam * (d[:, 2] - 1.0)) * dw))

    return _times_amplitude(np.vectorize(one)(_f64(sharpness)), amplitude)


def sg_inner_product(
    axis1, sharpness1, amplitude1, axis2, sharpness2, amplitude2, n_u: int = 48, n_phi: int = 160
) -> np.ndarray:
    """``∫ G₁ G₂ dω`` by a :func:`vmf_rule` placed on the product's geometry (axis ``λ₁ξ₁ + λ₂ξ₂``
    normalised, sharpness its length; the sharper lobe if that length is below 1e-3). Only the
    node placement uses it: the integrand ``G₁ G₂`` is evaluated directly in float64, so the
    amplitude of the product (the cancelling exponent) is measured, not assumed."""

    def one(a1, l1, a2, l2):
        x1, lp1, m1 = _lobe_params(a1, l1, 1.0)
        x2, lp2, m2 = _lobe_params(a2, l2, 1.0)
        um = lp1 * x1 + lp2 * x2
        lm = float(np.linalg.norm(um))
        axis, lam = (um, lm) if lm > 1e-3 else ((x1, lp1) if lp1 >= lp2 else (x2, lp2))
        d, _, dw = vmf_rule(axis, lam / np.linalg.norm(axis), n_u=n_u, n_phi=n_phi)
        g = np.exp(lp1 * (d @ x1 - 1.0) + lp2 * (d @ x2 - 1.0))
        return float(m1 * m2 * np.sum(g * dw))

    val = _per_lobe(one, axis1, sharpness1, axis2, sharpness2, vec=(0, 2))
    return _times_amplitude(val, _f64(amplitude1) * _f64(amplitude2))


def _cosine_integral(axis, sharpness, amplitude, normal, clamped: bool, n_u: int, n_phi: int):
    def one(a, lam, nrm):
        xi, lp, m = _lobe_params(a, lam, 1.0)
        nn = _normalize(nrm)
        d, _, dw = vmf_rule(xi, lp, n_u=n_u, n_phi=n_phi, clips=[nn] if clamped else ())
        g = np.exp(lp * (d @ xi - 1.0))
        return float(m * np.sum(g * (d @ nn) * dw))

    return _times_amplitude(_per_lobe(one, axis, sharpness, normal, vec=(0, 2)), amplitude)


def sg_cosine_signed(axis, sharpness, amplitude, normal, n_u: int = 48, n_phi: int = 64) -> np.ndarray:
    """``∫ G(ω) (n·ω) dω`` over the whole sphere (signed cosine), by :func:`vmf_rule` quadrature."""
    return _cosine_integral(axis, sharpness, amplitude, normal, False, n_u, n_phi)


def sg_irradiance(axis, sharpness, amplitude, normal, n_u: int = 48, n_phi: int = 64) -> np.ndarray:
    """``∫ G(ω) max(n·ω, 0) dω`` (clamped cosine) by :func:`vmf_rule` quadrature clipped to
    ``n·ω > 0`` (the clamp is a grid boundary, so the rule converges fast in every configuration)."""
    return _cosine_integral(axis, sharpness, amplitude, normal, True, n_u, n_phi)


# -- shading ------------------------------------------------------------------------------------
def _points(normal, view, diffuse, specular, roughness):
    normal = np.atleast_2d(_f64(normal))
    view = np.atleast_2d(_f64(view))
    p = max(normal.shape[0], view.shape[0])
    normal = np.broadcast_to(normal, (p, 3))
    view = np.broadcast_to(view, (p, 3))
    diffuse = np.broadcast_to(_rgb(diffuse), (p, 3))
    specular = np.broadcast_to(_rgb(specular), (p, 3))
    roughness = np.broadcast_to(_f64(roughness).reshape(-1), (p,))
    return p, normal, view, diffuse, specular, roughness


def render_env(
    env, normal, view, diffuse, specular, roughness, n: int = 16, fresnel: str = "schlick"
) -> np.ndarray:
    """Outgoing radiance ``∫ L(ω) f(ω, v) max(n·ω, 0) [ω_z > 0] dω`` at P points, ``(P, 3)``.

    ``env``: :class:`ebr_mitsuba.SGEnvironment` (world = tangent frame, z-up); ``normal``,
    ``view``: (P, 3) or (3,); ``diffuse``, ``specular``: (P, 3), (3,) or scalar; ``roughness``: (P,)
    or scalar. Quadrature: :func:`integration_rule` (``n`` nodes per panel, ``4n`` per arc).
    """
    p, normal, view, diffuse, specular, roughness = _points(normal, view, diffuse, specular, roughness)
    out = np.zeros((p, 3))
    if env.num_lobes == 0:
        return out
    axes = env.axis.astype(np.float64)
    lam = env.sharpness.astype(np.float64)
    amp = env.amplitude.astype(np.float64)
    for i in range(p):
        dirs, dw = integration_rule(normal[i], view[i], roughness[i], env=env, n=n)
        radiance = np.exp(lam[None, :] * (dirs @ axes.T - 1.0)) @ amp  # (N, 3)
        f = brdf_eval(normal[i], dirs, view[i], diffuse[i], specular[i], roughness[i], fresnel)
        cos = np.maximum(dirs @ _normalize(normal[i]), 0.0)
        out[i] = np.sum(radiance * f * (cos * dw)[:, None], axis=0)
    return out


def render_point(
    normal, view, position, light_pos, intensity, diffuse, specular, roughness, fresnel: str = "schlick"
) -> np.ndarray:
    """Radiance from an isotropic point light, ``f(l, v) I max(n·l, 0) / d²`` (exact), ``(P, 3)``.

    ``position``: (P, 3) surface points (world); ``light_pos``: (3,) or (P, 3); ``intensity``:
    scalar or RGB (3,) radiant intensity; other arguments as in :func:`render_env`.
    """
    p, normal, view, diffuse, specular, roughness = _points(normal, view, diffuse, specular, roughness)
    pos = np.broadcast_to(_f64(position), (p, 3))
    to_light = _f64(light_pos) - pos
    d2 = np.sum(to_light * to_light, axis=-1)
    l = to_light / np.sqrt(d2)[:, None]
    f = brdf_eval(normal, l, view, diffuse, specular, roughness, fresnel)
    cos = np.maximum(_dot(_normalize(normal), l), 0.0)
    return f * (_f64(intensity) * (cos / d2)[:, None])
