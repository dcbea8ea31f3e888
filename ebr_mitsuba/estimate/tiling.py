"""Tiled inference with overlap blending, for inputs larger than the network grid.

A square working image of size N > G (the grid) is covered by G×G tiles whose origins step by
G − overlap (the last tile is flush with the far edge). Each tile's maps are weighted by a
separable raised-cosine ramp over the ``overlap`` pixels at its inner edges (weight 1 inside,
never 0), accumulated, and divided by the summed weight: seams fade over ``overlap`` pixels.
Normals are averaged as vectors and renormalised.

Caveat: the network assumes the full capture geometry (the flash highlight at the frame centre);
a tile shows part of the sample with the highlight off-centre, so a tile's low frequencies (its
overall albedo, specular level and roughness) are unreliable — measured on the real flash-only
photos, tiles alone doubled the re-render error. The lighting therefore comes from one global pass
at the grid resolution, and :func:`merge_detail` keeps that pass's low frequencies and takes only
the detail above the grid's frequency from the tiles (see docs/estimate.md).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..errors import InputError
from ..svbrdf import SVBRDF

DEFAULT_OVERLAP = 32


def tile_starts(n: int, tile: int, overlap: int) -> list[int]:
    """Origins of the tiles covering [0, n) with at least ``overlap`` pixels of overlap."""
    if tile > n:
        raise InputError(f"tiling: tile {tile} is larger than the image {n}")
    if not 0 <= overlap < tile:
        raise InputError(f"--tile-overlap {overlap}: give a value in [0, {tile - 1}]")
    if tile == n:
        return [0]
    step = tile - overlap
    starts = list(range(0, n - tile, step))
    starts.append(n - tile)
    return starts


def ramp(tile: int, overlap: int) -> np.ndarray:
    """1-D blending weight (tile,): raised cosine from ~0 to 1 over ``overlap`` pixels at both
    ends, 1 in between; strictly positive."""
    w = np.ones(tile, np.float64)
    if overlap > 0:
        t = (np.arange(overlap) + 0.5) / overlap
        up = 0.5 - 0.5 * np.cos(np.pi * t)
        w[:overlap] = up
        w[tile - overlap :] = up[::-1]
    return np.maximum(w, 1e-3)


def tiled_maps(
    predict_tile: Callable[[dict[str, np.ndarray]], SVBRDF],
    images: dict[str, np.ndarray],
    tile: int,
    overlap: int = DEFAULT_OVERLAP,
    progress=None,
) -> SVBRDF:
    """Maps of the whole (N, N) working images from per-tile predictions.

    ``images``: shot name → (N, N, 3); ``predict_tile(crops)`` gets the same names with
    (tile, tile, 3) crops and returns an :class:`SVBRDF` of that size. ``progress``: optional
    callable(done, total).
    """
    n = next(iter(images.values())).shape[0]
    starts = tile_starts(n, tile, overlap)
    w1 = ramp(tile, overlap)
    weight2d = np.outer(w1, w1)[..., None]
    acc = {
        k: np.zeros((n, n, c), np.float64)
        for k, c in (("normal", 3), ("diffuse", 3), ("specular", 3), ("roughness", 1))
    }
    wsum = np.zeros((n, n, 1), np.float64)
    boxes = [(i, j) for i in starts for j in starts]
    for done, (i, j) in enumerate(boxes):
        crops = {k: np.ascontiguousarray(v[i : i + tile, j : j + tile]) for k, v in images.items()}
        maps = predict_tile(crops)
        if maps.shape != (tile, tile):
            raise RuntimeError(f"tiling: the model returned {maps.shape} maps for a {tile}x{tile} tile")
        sl = (slice(i, i + tile), slice(j, j + tile))
        for k in ("normal", "diffuse", "specular"):
            acc[k][sl] += weight2d * getattr(maps, k)
        acc["roughness"][sl] += weight2d * maps.roughness[..., None]
        wsum[sl] += weight2d
        if progress is not None:
            progress(done + 1, len(boxes))
    out = {k: (v / wsum).astype(np.float32) for k, v in acc.items()}
    return SVBRDF(
        normal=out["normal"],
        diffuse=out["diffuse"],
        specular=out["specular"],
        roughness=out["roughness"][..., 0],
        source="tiled",
    )


def upsample_bilinear(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(h, w[, c]) → (H, W[, c]) by separable linear interpolation between pixel centres (edges
    clamped): the smooth ``up`` of :func:`merge_detail`."""
    h, w = image.shape[:2]
    ys = np.clip((np.arange(size[0]) + 0.5) * h / size[0] - 0.5, 0, h - 1)
    xs = np.clip((np.arange(size[1]) + 0.5) * w / size[1] - 0.5, 0, w - 1)
    y0, x0 = np.floor(ys).astype(int), np.floor(xs).astype(int)
    y1, x1 = np.minimum(y0 + 1, h - 1), np.minimum(x0 + 1, w - 1)
    fy, fx = ys - y0, xs - x0
    if image.ndim == 3:
        fy, fx = fy[:, None, None], fx[None, :, None]
    else:
        fy, fx = fy[:, None], fx[None, :]
    rows = image[y0] * (1 - fy) + image[y1] * fy
    return rows[:, x0] * (1 - fx) + rows[:, x1] * fx


def merge_detail(global_maps: SVBRDF, tiled: SVBRDF) -> SVBRDF:
    """Global low frequencies + tile detail: ``up(global) + (tiled − up(down(tiled)))``.

    ``global_maps``: (G, G) maps of the whole capture at the network grid; ``tiled``: (N, N) maps
    of :func:`tiled_maps`. ``down`` is the area average, ``up`` bilinear (the same ``up`` for both
    terms, so a tiled map with no detail above the grid's frequency gives back the global maps). Values
    are clipped to [0, 1]; normals are combined as vectors, renormalised and kept in the upper
    hemisphere.
    """
    from ..materials import resample_svbrdf

    n, g = tiled.shape, global_maps.shape
    down = resample_svbrdf(tiled, g)

    def detail(name: str) -> np.ndarray:
        a, b, t = (np.asarray(getattr(m, name), np.float64) for m in (global_maps, down, tiled))
        return upsample_bilinear(a - b, n) + t

    normal = detail("normal")
    normal[..., 2] = np.maximum(normal[..., 2], 1e-3)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return SVBRDF(
        normal=normal.astype(np.float32),
        diffuse=np.clip(detail("diffuse"), 0, 1).astype(np.float32),
        specular=np.clip(detail("specular"), 0, 1).astype(np.float32),
        roughness=np.clip(detail("roughness"), 0, 1).astype(np.float32),
        source="global + tile detail",
    )


__all__ = ["DEFAULT_OVERLAP", "merge_detail", "ramp", "tile_starts", "tiled_maps", "upsample_bilinear"]
