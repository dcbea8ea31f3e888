"""Vectorised, seamlessly tileable noise on the unit square (numpy only).

Every function takes texture coordinates ``u`` (left → right) and ``v`` (top → bottom) as float64
arrays of one shape (usually (H, W), from :func:`grid`) and an explicit ``np.random.Generator``; it
returns a float64 array of the same shape. Lattice frequencies are integers and lattice indices
wrap, so every pattern is periodic with period 1 in ``u`` and ``v``: a material tiles seamlessly.

Resolution independence: random lattices are drawn for every octave whatever the resolution, and
octaves finer than the pixel grid (``max_freq``) are skipped rather than left out of the draw, so
the same seed gives the same pattern at 64² and 256² (the smaller one without the finest detail).

==================  =====================================================================
function            meaning
==================  =====================================================================
``grid``            pixel-centre coordinates ``(u, v)`` of an H×W image, each (H, W)
``value_noise``     smooth random values on an integer lattice, in [-1, 1]
``gradient_noise``  Perlin gradient noise, roughly in [-1, 1], zero on lattice points
``fbm``             fractal sum of octaves of gradient (or value) noise, normalised to ≈ [-1, 1]
``worley``          cellular noise: distances to the nearest and second-nearest feature point
                    (in cell units) and the nearest cell's index
``smoothstep``      Hermite step 0 → 1 between two edges (numpy twin of GLSL's)
==================  =====================================================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def grid(height: int, width: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre texture coordinates: ``u = (j + ½)/W``, ``v = (i + ½)/H``, each (H, W).

    Row 0 (``v`` small) is the top of the image, i.e. world +y (``docs/conventions.md``, "Geometry
    and pixel grid").
    """
    width = height if width is None else width
    u = (np.arange(width, dtype=np.float64) + 0.5) / width
    v = (np.arange(height, dtype=np.float64) + 0.5) / height
    return np.broadcast_to(u[None, :], (height, width)), np.broadcast_to(v[:, None], (height, width))


def smoothstep(edge0, edge1, x):
    """0 below ``edge0``, 1 above ``edge1``, Hermite ``t²(3 − 2t)`` in between."""
    t = np.clip((np.asarray(x, dtype=np.float64) - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _quintic(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


def _freq2(freq) -> tuple[int, int]:
    if np.ndim(freq) == 0:
        f = int(freq)
        return f, f
    fu, fv = freq
    return int(fu), int(fv)


def _cells(u, v, fu: int, fv: int):
    x = u * fu
    y = v * fv
    i0 = np.floor(x)
    j0 = np.floor(y)
    tx = x - i0
    ty = y - j0
    i0 = i0.astype(np.int64) % fu
    j0 = j0.astype(np.int64) % fv
    return i0, (i0 + 1) % fu, j0, (j0 + 1) % fv, tx, ty


def value_noise(u, v, freq, rng: np.random.Generator) -> np.ndarray:
    """Value noise with ``freq`` (int or (fu, fv)) lattice cells per unit; values in [-1, 1]."""
    fu, fv = _freq2(freq)
    lattice = rng.uniform(-1.0, 1.0, size=(fv, fu))
    return _value_eval(u, v, lattice)


def _value_eval(u, v, lattice):
    fv, fu = lattice.shape
    i0, i1, j0, j1, tx, ty = _cells(u, v, fu, fv)
    sx, sy = _quintic(tx), _quintic(ty)
    a = lattice[j0, i0] + sx * (lattice[j0, i1] - lattice[j0, i0])
    b = lattice[j1, i0] + sx * (lattice[j1, i1] - lattice[j1, i0])
    return a + sy * (b - a)


def gradient_noise(u, v, freq, rng: np.random.Generator) -> np.ndarray:
    """Perlin gradient noise with ``freq`` (int or (fu, fv)) lattice cells per unit.

    Unit gradients at lattice points, quintic fade; scaled by √2 so the range is about [-1, 1].
    """
    fu, fv = _freq2(freq)
    angle = rng.uniform(0.0, 2.0 * np.pi, size=(fv, fu))
    return _gradient_eval(u, v, np.cos(angle), np.sin(angle))


def _gradient_eval(u, v, gx, gy):
    fv, fu = gx.shape
    i0, i1, j0, j1, tx, ty = _cells(u, v, fu, fv)
    n00 = gx[j0, i0] * tx + gy[j0, i0] * ty
    n10 = gx[j0, i1] * (tx - 1.0) + gy[j0, i1] * ty
    n01 = gx[j1, i0] * tx + gy[j1, i0] * (ty - 1.0)
    n11 = gx[j1, i1] * (tx - 1.0) + gy[j1, i1] * (ty - 1.0)
    sx, sy = _quintic(tx), _quintic(ty)
    a = n00 + sx * (n10 - n00)
    b = n01 + sx * (n11 - n01)
    return np.sqrt(2.0) * (a + sy * (b - a))


def fbm(
    u,
    v,
    rng: np.random.Generator,
    freq=4,
    octaves: int = 5,
    gain: float = 0.5,
    lacunarity: int = 2,
    kind: str = "gradient",
    max_freq: float | None = None,
) -> np.ndarray:
    """Fractal Brownian motion: ``Σ_o gainᵒ · noise(freq·lacunarityᵒ)`` / ``Σ_o gainᵒ``.

    ``freq`` is an int or (fu, fv) (anisotropic: e.g. (2, 64) gives streaks along ``u``);
    ``kind`` is ``"gradient"`` or ``"value"``. Octaves whose larger frequency exceeds ``max_freq``
    (typically half the image size) are skipped after their lattice is drawn (see the module
    docstring). Result roughly in [-1, 1].
    """
    fu, fv = _freq2(freq)
    total = np.zeros(np.shape(u), dtype=np.float64)
    norm = 0.0
    amp = 1.0
    for _ in range(octaves):
        if kind == "gradient":
            angle = rng.uniform(0.0, 2.0 * np.pi, size=(fv, fu))
        elif kind == "value":
            lattice = rng.uniform(-1.0, 1.0, size=(fv, fu))
        else:
            raise ValueError(f"fbm: unknown noise kind {kind!r}; use 'gradient' or 'value'")
        if max_freq is None or max(fu, fv) <= max_freq:
            if kind == "gradient":
                total += amp * _gradient_eval(u, v, np.cos(angle), np.sin(angle))
            else:
                total += amp * _value_eval(u, v, lattice)
        norm += amp
        amp *= gain
        fu *= lacunarity
        fv *= lacunarity
    return total / norm


@dataclass(frozen=True)
class Cells:
    """Result of :func:`worley` (all (H, W); distances in units of one cell)."""

    f1: np.ndarray  #: distance to the nearest feature point
    f2: np.ndarray  #: distance to the second-nearest feature point
    cell: np.ndarray  #: flat index (row·cells_u + column) of the nearest point's cell, int64


def worley(u, v, cells, rng: np.random.Generator, jitter: float = 1.0) -> Cells:
    """Periodic cellular (Worley) noise with one feature point per cell of a ``cells`` grid.

    ``cells`` is an int or (cu, cv); ``jitter`` in [0, 1] moves the points off the cell centres
    (0: a regular grid). F2 − F1 is the distance to the cell border, up to a factor ≈ 2.
    """
    cu, cv = _freq2(cells)
    points = 0.5 + jitter * (rng.random((cv, cu, 2)) - 0.5)
    x = u * cu
    y = v * cv
    ci = np.floor(x).astype(np.int64)
    cj = np.floor(y).astype(np.int64)
    fx = x - ci
    fy = y - cj
    dists = []
    ids = []
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            ni = (ci + di) % cu
            nj = (cj + dj) % cv
            px = di + points[nj, ni, 0]
            py = dj + points[nj, ni, 1]
            dists.append(np.hypot(px - fx, py - fy))
            ids.append(nj * cu + ni)
    d = np.stack(dists)
    order = np.argsort(d, axis=0, kind="stable")[:2]
    f1 = np.take_along_axis(d, order[0:1], axis=0)[0]
    f2 = np.take_along_axis(d, order[1:2], axis=0)[0]
    cell = np.take_along_axis(np.stack(ids), order[0:1], axis=0)[0]
    return Cells(f1=f1, f2=f2, cell=cell)
