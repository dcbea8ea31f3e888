"""Shading points of the fast renderer: one per pixel of the sample grid
(:func:`ebr_mitsuba.geometry.pixel_positions`).

Pixel (row i, column j) of an H×W image shades the surface point
``p = (−1 + (2j+1)/W, 1 − (2i+1)/H, 0)``. On this plane the tangent frame is the world frame
(geometric normal +z), so normals, view and light directions need no change of frame.
``v = normalize(camera − p)`` per pixel, which is exactly the pinhole view for the sample-grid
shots and a *texture-space* view for any other camera position.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi

from ..brdf import perturbed_normal
from .inputs import DrMaps


@dataclass
class ShadingPoints:
    """Per-point shading inputs (all arrays of ``count`` lanes).

    ``pixel`` is the pixel index within its image (row-major), used to seed the quadrature
    pattern; ``flat_normal`` says (statically) that every ``n`` is +z, which lets the closed form
    compute the diffuse irradiance once per lobe.
    """

    n: mi.Vector3f
    v: mi.Vector3f
    diffuse: mi.Color3f
    specular: mi.Color3f
    roughness: mi.Float
    pixel: mi.UInt32
    count: int
    flat_normal: bool = False

    def detach(self) -> ShadingPoints:
        return ShadingPoints(
            dr.detach(self.n),
            dr.detach(self.v),
            dr.detach(self.diffuse),
            dr.detach(self.specular),
            dr.detach(self.roughness),
            self.pixel,
            self.count,
            self.flat_normal,
        )


def opaque_point(xyz) -> mi.Vector3f:
    """A 3-vector whose value is not baked into kernels (no recompilation when it changes)."""
    return mi.Vector3f(*(dr.opaque(mi.Float, float(c)) for c in xyz))


def check_window(window, height: int, width: int) -> tuple[int, int, int, int] | None:
    """Validate a window ``(row0, col0, full_h, full_w)`` for an ``height``×``width`` image."""
    if window is None:
        return None
    from ..errors import InputError

    try:
        r0, c0, fh, fw = (int(v) for v in window)
    except (TypeError, ValueError):
        raise InputError(f"render window {window!r}: give (row0, col0, full_height, full_width)") from None
    if not (0 <= r0 and 0 <= c0 and r0 + height <= fh and c0 + width <= fw):
        raise InputError(
            f"render window {window!r}: a {height}x{width} block at row {r0}, column {c0} "
            f"does not fit a {fh}x{fw} grid"
        )
    return r0, c0, fh, fw


def grid_positions(height: int, width: int, window=None) -> tuple[mi.Vector3f, mi.UInt32]:
    """Surface points (H·W lanes, row-major) and their pixel indices (full-grid indices with a
    ``window``, see the module docstring)."""
    idx = dr.arange(mi.UInt32, height * width)
    row = idx // width
    col = idx - row * width
    window = check_window(window, height, width)
    if window is None:
        x = -1.0 + (2.0 * mi.Float(col) + 1.0) / width
        y = 1.0 - (2.0 * mi.Float(row) + 1.0) / height
        return mi.Vector3f(x, y, 0.0), idx
    r0, c0, fh, fw = window
    row = row + dr.opaque(mi.UInt32, r0)
    col = col + dr.opaque(mi.UInt32, c0)
    fh_f, fw_f = dr.opaque(mi.Float, float(fh)), dr.opaque(mi.Float, float(fw))
    x = -1.0 + (2.0 * mi.Float(col) + 1.0) / fw_f
    y = 1.0 - (2.0 * mi.Float(row) + 1.0) / fh_f
    return mi.Vector3f(x, y, 0.0), row * dr.opaque(mi.UInt32, fw) + col


def view_vectors(positions: mi.Vector3f, camera: mi.Vector3f) -> mi.Vector3f:
    return dr.normalize(camera - positions)


def points_from_maps(maps: DrMaps, camera: mi.Vector3f, window=None) -> tuple[ShadingPoints, mi.Vector3f]:
    """Shading points of every pixel of ``maps`` seen from ``camera`` (the block ``window`` of a
    larger grid when given); also returns the positions."""
    h, w = maps.shape
    pos, idx = grid_positions(h, w, window)
    n = perturbed_normal(dr.unravel(mi.Vector3f, maps.normal.array))
    d = dr.unravel(mi.Color3f, maps.diffuse.array)
    s = dr.unravel(mi.Color3f, maps.specular.array)
    r = maps.roughness.array
    return ShadingPoints(n, view_vectors(pos, camera), d, s, r, idx, h * w), pos
