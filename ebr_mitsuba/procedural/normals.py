"""Tangent-space normals from height fields, and the slope-space form used to blend normals.

Conventions (``docs/conventions.md``, "Geometry and pixel grid"): the sample is [-1, 1]² (2 world
units wide), row 0 of an (H, W) map is the top (world +y), column 0 the left (world −x); normals are
OpenGL (+Y up) tangent-space unit vectors. A height field ``h`` (H, W) in world units gives

    n ∝ (−∂h/∂x, −∂h/∂y, 1),   ∂h/∂x = Δh/Δcolumn · W/2,   ∂h/∂y = −Δh/Δrow · H/2

(the minus sign: rows grow downwards, towards −y). The slope form of a normal is
``s = (−n_x/n_z, −n_y/n_z) = ∇h``; slopes of a height field add and interpolate linearly, which is
why blending and resampling happen in slope space.
"""

from __future__ import annotations

import numpy as np

#: Smallest n_z accepted when converting to slopes (≈ 89.9° tilt); keeps slopes finite.
MIN_NZ = 1e-3


def height_gradient(height: np.ndarray, wrap: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """World-space gradient ``(∂h/∂x, ∂h/∂y)`` of an (H, W) height field in world units.

    Central differences; ``wrap=True`` treats the field as periodic (tileable maps), otherwise the
    borders use one-sided differences (``np.gradient``).
    """
    h = np.asarray(height, dtype=np.float64)
    if h.ndim != 2:
        raise ValueError(f"height_gradient: height has shape {h.shape}; expected (H, W)")
    rows, cols = h.shape
    dx = 2.0 / cols
    dy = 2.0 / rows
    if wrap:
        dh_dcol = (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1)) * 0.5
        dh_drow = (np.roll(h, -1, axis=0) - np.roll(h, 1, axis=0)) * 0.5
    else:
        dh_dcol = np.gradient(h, axis=1) if cols > 1 else np.zeros_like(h)
        dh_drow = np.gradient(h, axis=0) if rows > 1 else np.zeros_like(h)
    return dh_dcol / dx, -dh_drow / dy


def normals_from_height(height: np.ndarray, wrap: bool = False) -> np.ndarray:
    """Unit tangent-space normals (H, W, 3) float32 of an (H, W) height field in world units."""
    gx, gy = height_gradient(height, wrap=wrap)
    return slopes_to_normals(np.stack([gx, gy], axis=-1))


def normals_to_slopes(normal: np.ndarray) -> np.ndarray:
    """(…, 3) unit normals → (…, 2) slopes ``(−n_x/n_z, −n_y/n_z)`` (n_z clamped to ≥ MIN_NZ)."""
    n = np.asarray(normal, dtype=np.float64)
    nz = np.maximum(n[..., 2], MIN_NZ)
    return np.stack([-n[..., 0] / nz, -n[..., 1] / nz], axis=-1)


def slopes_to_normals(slopes: np.ndarray) -> np.ndarray:
    """(…, 2) slopes → (…, 3) unit normals float32 with n_z > 0."""
    s = np.asarray(slopes, dtype=np.float64)
    n = np.stack([-s[..., 0], -s[..., 1], np.ones(s.shape[:-1])], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n.astype(np.float32)
