"""The forward model of SG extraction: the fast renderer's exemplars, at chosen pixels.

:func:`ebr_mitsuba.exemplar.images.exemplar_images` renders every pixel of every exemplar. Extraction
iterates on a random subset of the full-resolution pixels instead (``g²`` per exemplar per
iteration), so this module builds the *same* shading points as ``exemplar_images`` (uniform
exemplar material, flat normal, view vector ``normalize(camera − p)`` from
:func:`ebr_mitsuba.render.points.grid_positions`) for the selected pixels only, and evaluates them
with the renderer's own environment term (:func:`ebr_mitsuba.render.fast.environment`). At all
pixels it equals ``exemplar_images`` exactly (tested).

Pixel indices are flat over the exemplar stack: ``index = i·H·W + row·W + col`` for exemplar i.
Every per-call value (camera, indices, quadrature seed) is data or opaque: one kernel serves all
iterations.

``mode="sg"`` is the renderer's :func:`ebr_mitsuba.render.env_sg.sg_environment`, whose
evaluation order and gather mode keep each Adam step's reverse pass in one kernel over the
(pixel, lobe) pairs (see its docstring; ``tests/test_extract_speed.py`` checks the kernel count).
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..exemplar import EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR
from ..geometry import Shot
from ..render.fast import environment
from ..render.inputs import DrLobes, RenderOptions
from ..render.points import ShadingPoints, grid_positions, opaque_point, view_vectors


@dataclass
class ExemplarGeometry:
    """Per-pixel geometry of an exemplar stack: N exemplars of H×W pixels seen from ``shot``."""

    roughness: np.ndarray  # (N,) float32
    height: int
    width: int
    shot: Shot

    def __post_init__(self):
        self._positions, _ = grid_positions(self.height, self.width)
        self._view = view_vectors(self._positions, opaque_point(self.shot.camera))
        self._roughness = mi.Float(np.asarray(self.roughness, np.float32))

    @property
    def count(self) -> int:
        return int(len(self.roughness))

    @property
    def pixels(self) -> int:
        return self.height * self.width

    @property
    def view(self) -> mi.Vector3f:
        """View vectors of the H·W pixels."""
        return self._view

    @property
    def roughness_array(self) -> mi.Float:
        return self._roughness

    def points(
        self, index: mi.UInt32, view: mi.Vector3f | None = None, roughness: mi.Float | None = None
    ) -> ShadingPoints:
        """Shading points of the flat pixel indices ``index`` (module docstring); ``view`` and
        ``roughness`` override the stored arrays (a frozen function passes them as arguments)."""
        view = self._view if view is None else view
        roughness = self._roughness if roughness is None else roughness
        n_pix = self.pixels
        img = index // n_pix
        q = index - img * n_pix
        count = dr.width(index)
        return ShadingPoints(
            n=mi.Vector3f(0.0, 0.0, 1.0) + dr.zeros(mi.Vector3f, count),
            v=dr.gather(mi.Vector3f, view, q),
            diffuse=mi.Color3f(EXEMPLAR_DIFFUSE) + dr.zeros(mi.Color3f, count),
            specular=mi.Color3f(EXEMPLAR_SPECULAR) + dr.zeros(mi.Color3f, count),
            roughness=dr.gather(mi.Float, roughness, img),
            pixel=q,
            count=count,
            flat_normal=True,
        )

    def render(self, lobes: DrLobes, index: mi.UInt32, options: RenderOptions) -> mi.Color3f:
        """Exemplar radiance at the flat pixel indices ``index`` (differentiable w.r.t. ``lobes``)."""
        return self.render_with(lobes, index, options, self._view, self._roughness)

    def render_with(
        self, lobes: DrLobes, index: mi.UInt32, options: RenderOptions, view: mi.Vector3f, roughness: mi.Float
    ) -> mi.Color3f:
        """:meth:`render` with explicit view and roughness arrays."""
        return self.render_points(self.points(index, view, roughness), lobes, options)

    def render_points(self, points: ShadingPoints, lobes: DrLobes, options: RenderOptions) -> mi.Color3f:
        """:meth:`render` at shading points from :meth:`points`."""
        if lobes.num_lobes == 0:
            return dr.zeros(mi.Color3f, points.count)
        return environment(points, lobes, options)

    def all_indices(self) -> mi.UInt32:
        return dr.arange(mi.UInt32, self.count * self.pixels)

    def render_numpy(self, lobes: DrLobes, options: RenderOptions) -> np.ndarray:
        """Every pixel: (N, H, W, 3) float32, no gradients."""
        with dr.suspend_grad():
            img = self.render(lobes, self.all_indices(), options)
            arr = np.asarray(img.numpy(), dtype=np.float32)  # (3, N·H·W)
        return np.ascontiguousarray(arr.T.reshape(self.count, self.height, self.width, 3))

    def mirror_axes(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Mirror reflections (M, 3) of the view direction at fractional pixel centres
        (``rows``, ``cols`` in pixel units, 0.5 = centre of pixel 0): the environment direction a
        smooth exemplar shows there (flat normal +z: (−v_x, −v_y, v_z))."""
        x = -1.0 + 2.0 * np.asarray(cols, np.float64) / self.width
        y = 1.0 - 2.0 * np.asarray(rows, np.float64) / self.height
        cam = np.asarray(self.shot.camera, np.float64)
        v = np.stack([cam[0] - x, cam[1] - y, np.full_like(x, cam[2])], axis=-1)
        v /= np.linalg.norm(v, axis=-1, keepdims=True)
        return np.stack([-v[:, 0], -v[:, 1], v[:, 2]], axis=-1)


def stratified_indices(
    rng: np.random.Generator, n_img: int, height: int, width: int, grid: int
) -> np.ndarray:
    """One random pixel in each cell of a ``grid × grid`` partition of every exemplar (uint32
    flat indices, ``n_img · g'²`` with ``g' = min(grid, H, W)``)."""
    gh, gw = min(grid, height), min(grid, width)
    r0 = (np.arange(gh) * height) // gh
    r1 = ((np.arange(gh) + 1) * height) // gh
    c0 = (np.arange(gw) * width) // gw
    c1 = ((np.arange(gw) + 1) * width) // gw
    rows = r0[None, :, None] + (rng.random((n_img, gh, gw)) * (r1 - r0)[None, :, None]).astype(np.int64)
    cols = c0[None, None, :] + (rng.random((n_img, gh, gw)) * (c1 - c0)[None, None, :]).astype(np.int64)
    img = np.arange(n_img)[:, None, None]
    return (img * height * width + rows * width + cols).reshape(-1).astype(np.uint32)


def centre_indices(n_img: int, height: int, width: int, grid: int) -> np.ndarray:
    """The pixel nearest the centre of each cell of a ``grid × grid`` partition (uint32 flat)."""
    gh, gw = min(grid, height), min(grid, width)
    rows = ((np.arange(gh) + 0.5) * height / gh).astype(np.int64)
    cols = ((np.arange(gw) + 0.5) * width / gw).astype(np.int64)
    img = np.arange(n_img)[:, None, None]
    return (
        (img * height * width + rows[None, :, None] * width + cols[None, None, :])
        .reshape(-1)
        .astype(np.uint32)
    )
