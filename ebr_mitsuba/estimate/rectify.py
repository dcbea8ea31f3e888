"""Rectification: a camera image of the planar sample resampled onto the sample's pixel grid.

Pixel (i, j) of the sample grid (``docs/conventions.md``, "Geometry and pixel grid") shows the
surface point ``p_ij = (−1 + (2j+1)/W, 1 − (2i+1)/H, 0)`` of the plane z = 0. A camera image of
the sample (a Mitsuba capture, a photograph) from a pinhole camera at ``camera`` looking at
``target`` with ``up`` and horizontal field of view ``fov`` is rectified by projecting every
``p_ij`` into that camera and sampling the image bilinearly there (:func:`rectify`). Points
outside the camera's frame (or behind it) get in-frame weight 0 and the value of the nearest edge
pixel; so do the points interpolated from a camera pixel that straddles the sample's edge (it
mixes in what lies beyond the sample: the outermost ring of an oblique view). The weight is 1
elsewhere. The camera frame is Mitsuba's ``look_at`` frame: image right is ``forward × up``,
image up is ``right × forward``; pixel centres at ``(j + ½) / w`` of the frame (as
:func:`ebr_mitsuba.nets.mair_views.in_frame_weights` assumes for the 3×3 grid, whose weights are
the frame test alone).

For a camera that is already in the sample grid (the near camera: centred, fronto-parallel,
framing exactly [−1, 1]²) at the grid's size, rectification returns the image itself.

Pure numpy: no torch, no Mitsuba.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..geometry import pixel_positions


def camera_frame(camera, target, up) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(origin, forward, right, up)`` of a look-at camera (unit vectors, world frame)."""
    c = np.asarray(camera, np.float64)
    f = np.asarray(target, np.float64) - c
    norm = np.linalg.norm(f)
    if not norm > 0:
        raise InputError(f"camera at {list(camera)} looks at itself (target {list(target)})")
    f /= norm
    r = np.cross(f, np.asarray(up, np.float64))
    if not np.linalg.norm(r) > 1e-9:
        raise InputError(f"camera at {list(camera)}: up {list(up)} is parallel to the view direction")
    r /= np.linalg.norm(r)
    return c, f, r, np.cross(r, f)


def project(points: np.ndarray, camera, target, up, fov: float, image_size: tuple[int, int]):
    """Continuous pixel coordinates ``(x, y)`` (columns, rows; pixel centres at k + ½) of world
    ``points`` (…, 3) in an ``image_size`` = (h, w) image, and the mask of points inside the frame."""
    h, w = image_size
    c, f, r, u = camera_frame(camera, target, up)
    d = np.asarray(points, np.float64) - c
    depth = d @ f
    half_x = math.tan(math.radians(float(fov)) / 2)
    half_y = half_x * h / w
    safe = np.where(depth > 1e-12, depth, 1.0)
    nx = (d @ r) / (safe * half_x)  # −1 … 1 across the frame
    ny = (d @ u) / (safe * half_y)
    x = (nx + 1.0) * 0.5 * w
    y = (1.0 - ny) * 0.5 * h
    inside = (depth > 1e-12) & (np.abs(nx) <= 1.0) & (np.abs(ny) <= 1.0)
    return x, y, inside


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``image`` (h, w, C) sampled at continuous pixel coordinates (pixel centres at k + ½),
    clamped to the edge pixels' centres."""
    h, w = image.shape[:2]
    fx = np.clip(x - 0.5, 0.0, w - 1.0)
    fy = np.clip(y - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(fx).astype(np.int64), w - 2) if w > 1 else np.zeros(fx.shape, np.int64)
    y0 = np.minimum(np.floor(fy).astype(np.int64), h - 2) if h > 1 else np.zeros(fy.shape, np.int64)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    tx, ty = (fx - x0)[..., None], (fy - y0)[..., None]
    top = image[y0, x0] * (1 - tx) + image[y0, x1] * tx
    bottom = image[y1, x0] * (1 - tx) + image[y1, x1] * tx
    return top * (1 - ty) + bottom * ty


def on_sample_pixels(camera, target, up, fov: float, image_size: tuple[int, int]) -> np.ndarray:
    """(h, w) bool: camera pixels whose whole footprint lies on the sample square [−1, 1]² of the
    plane z = 0 (all four corners' rays meet the plane inside it)."""
    h, w = image_size
    c, f, r, u = camera_frame(camera, target, up)
    half_x = math.tan(math.radians(float(fov)) / 2)
    half_y = half_x * h / w
    nx = (2.0 * np.arange(w + 1) / w - 1.0) * half_x
    ny = (1.0 - 2.0 * np.arange(h + 1) / h) * half_y
    d = f + nx[None, :, None] * r + ny[:, None, None] * u  # (h+1, w+1, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -c[2] / d[..., 2]
    p = c + t[..., None] * d
    ok = (d[..., 2] < 0) & (t > 0) & (np.abs(p[..., 0]) <= 1 + 1e-6) & (np.abs(p[..., 1]) <= 1 + 1e-6)
    return ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & ok[1:, 1:]


def rectify(
    image: np.ndarray, camera, target, up, fov: float, size: int | tuple[int, int], sample_only: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """``image`` (h, w, C) of a camera (module docstring) on the sample grid of ``size`` (int:
    square, or (H, W)): ``(rectified (H, W, C) float32, in-frame weight (H, W) float32 in {0, 1})``.

    The weight is 1 where the grid point lies in the camera's frame and (``sample_only``) every
    camera pixel it is interpolated from saw the sample alone (:func:`on_sample_pixels`): a camera
    pixel straddling the sample's edge mixes in whatever lies beyond it."""
    hh, ww = (size, size) if isinstance(size, int) else size
    a = np.asarray(image, np.float32)
    if a.ndim == 2:
        a = a[..., None]
    x, y, inside = project(pixel_positions(hh, ww), camera, target, up, fov, a.shape[:2])
    out = bilinear(a.astype(np.float64), x, y).astype(np.float32)
    if sample_only:
        clean = on_sample_pixels(camera, target, up, fov, a.shape[:2]).astype(np.float64)[..., None]
        inside &= bilinear(clean, x, y)[..., 0] >= 1.0 - 1e-9
    return out, inside.astype(np.float32)


__all__ = ["bilinear", "camera_frame", "on_sample_pixels", "project", "rectify"]
