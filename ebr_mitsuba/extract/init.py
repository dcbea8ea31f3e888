"""Initial lobes of SG extraction: one per quad-tree patch (or random, for the ablation).

Per leaf of :func:`ebr_mitsuba.extract.quadtree.quadtree` of exemplar i (roughness r_i):

* **axis** — the mirror reflection of the view direction at the patch centre (the environment
  direction a smooth exemplar shows there);
* **sharpness** — from the per-level table ``λ_ℓ = 8 ln 2 / θ_ℓ²`` (a lobe whose half-maximum
  width equals the patch's angular width ``θ_ℓ = θ₀ / 2^ℓ``, θ₀ the angle the whole exemplar spans
  in mirror directions, 45° for the near shot), de-blurred by the exemplar's GGX lobe
  (``λ_w = 1/(2α²)``, α = r²): ``λ = 1/(1/λ_ℓ − 1/λ_w)``, at most ``4 λ_ℓ``. Levels with
  ``λ_ℓ > λ_w/2`` are finer than the exemplar can show and are not split into;
* **amplitude** — from the patch's mean pixel value: ``(mean − D_i) / (F₀ · λ_w/(λ_w + λ))``,
  ``D_i`` the exemplar's 1st-percentile radiance (its diffuse floor), F₀ = 0.2 (the peak of a
  lobe of sharpness λ reflected by a GGX lobe of sharpness λ_w at normal view).

Fill lobes (:func:`fill_lobes`: ``n`` Fibonacci directions of the upper hemisphere, each with
λ = 3, 30 and 300) stand for the light the mirror directions never show (a sun 45°
from the zenith reaches the exemplars only through the diffuse term and the tails of the rough
lobes). They are added after merging, get their amplitudes from the closed-form solve, and the
ones it leaves empty are pruned.
"""

from __future__ import annotations

import math

import numpy as np

from ..exemplar import EXEMPLAR_SPECULAR
from ..floors import ROUGHNESS_MIN
from ..sgparams import SHARPNESS_MAX, SHARPNESS_MIN
from .forward import ExemplarGeometry
from .quadtree import quadtree

FILL_SHARPNESS = (3.0, 30.0, 300.0)
LN2 = math.log(2.0)


def brdf_sharpness(roughness: float) -> float:
    """Sharpness of the GGX lobe reflected at normal view, ``1/(2α²)``, α = clamp(r, ROUGHNESS_MIN, 1)²."""
    alpha = min(max(float(roughness), ROUGHNESS_MIN), 1.0) ** 2
    return 1.0 / (2.0 * alpha * alpha)


def span_angle(geometry: ExemplarGeometry) -> float:
    """Angle between the mirror directions at the left and right edges of the middle row."""
    h, w = geometry.height, geometry.width
    a = geometry.mirror_axes(np.array([h / 2.0, h / 2.0]), np.array([0.0, float(w)]))
    return float(np.arccos(np.clip(a[0] @ a[1], -1.0, 1.0)))


def level_sharpness(level: int, theta0: float) -> float:
    """The per-level table ``8 ln 2 / (θ₀/2^ℓ)²``."""
    return 8.0 * LN2 / (theta0 / 2.0**level) ** 2


def fibonacci_hemisphere(n: int) -> np.ndarray:
    """``n`` nearly uniform unit vectors (n, 3) with z > 0."""
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - i / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def fill_lobes(n: int, level: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``3n`` fill lobes (module docstring) of amplitude ``level``."""
    if n <= 0:
        return np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    axis = fibonacci_hemisphere(n)
    axes = np.concatenate([axis] * len(FILL_SHARPNESS))
    sharp = np.repeat(np.asarray(FILL_SHARPNESS), n)
    return axes, sharp, np.full((len(sharp), 3), max(level, 1e-12))


def quadtree_lobes(
    images: np.ndarray, geometry: ExemplarGeometry, threshold: float, max_level: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Initial lobes (axis (K, 3), sharpness (K,), amplitude (K, 3)) of the exemplar stack
    ``images`` (N, H, W, 3) (module docstring)."""
    theta0 = span_angle(geometry)
    axes, sharp, amps = [], [], []
    for img, r in zip(images, geometry.roughness):
        lam_w = brdf_sharpness(r)
        deepest = 0
        while deepest < max_level and level_sharpness(deepest + 1, theta0) <= 0.5 * lam_w:
            deepest += 1
        floor = np.percentile(img.reshape(-1, 3), 1.0, axis=0)
        patches = quadtree(img, threshold, deepest)
        rows = np.array([p.centre[0] for p in patches])
        cols = np.array([p.centre[1] for p in patches])
        mirror = geometry.mirror_axes(rows, cols)
        for p, axis in zip(patches, mirror):
            lam_l = level_sharpness(p.level, theta0)
            lam = 1.0 / max(1.0 / lam_l - 1.0 / lam_w, 1.0 / (4.0 * lam_l))
            lam = float(np.clip(lam, SHARPNESS_MIN, SHARPNESS_MAX))
            spec = np.maximum(np.asarray(p.mean) - floor, 0.0)
            amp = spec / (EXEMPLAR_SPECULAR * lam_w / (lam_w + lam))
            axes.append(axis)
            sharp.append(lam)
            amps.append(amp)
    axis = np.asarray(axes).reshape(-1, 3)
    sharp_a = np.asarray(sharp, np.float64)
    amp_a = np.asarray(amps).reshape(-1, 3)
    keep = amp_a.max(axis=1, initial=0.0) > 1e-6 * max(float(amp_a.max(initial=0.0)), 1e-30)
    return axis[keep], sharp_a[keep], amp_a[keep]


def random_lobes(
    count: int, level: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``count`` lobes with uniform random upper-hemisphere axes, log-uniform λ in [2, 2000] and
    amplitude ``level`` (the ablation's random initialisation)."""
    z = rng.random(count)
    phi = 2.0 * math.pi * rng.random(count)
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    axis = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    sharp = np.exp(rng.uniform(math.log(2.0), math.log(2000.0), count))
    return axis, sharp, np.full((count, 3), max(level, 1e-12))
