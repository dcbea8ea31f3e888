"""Tiles with overlap blending for the full-resolution estimate (its bilinear upsampling is
:func:`ebr_mitsuba.imageio.upsample_bilinear_fast`).

When one network pass over the whole working image would take too much memory,
:mod:`.fullres` covers the N×N image with T×T tiles whose origins step by at most T − overlap
(:func:`tile_starts`; the last tile is flush with the far edge). Each tile's maps are weighted by
a separable raised-cosine ramp over the ``overlap`` pixels at its ends (:func:`ramp`, weight 1
inside, never 0), accumulated, and divided by the summed weight: seams fade over ``overlap``
pixels. Normals are averaged as vectors and renormalised. Every tile is estimated with the true
geometry of its pixels and the capture's lighting (see :mod:`.fullres`), not as a capture of its
own.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

DEFAULT_OVERLAP = 32


def tile_starts(n: int, tile: int, overlap: int) -> list[int]:
    """Origins of the tiles covering [0, n) with at least ``overlap`` pixels of overlap."""
    if tile > n:
        raise InputError(f"tiling: tile {tile} is larger than the image {n}")
    if not 0 <= overlap < tile:
        raise InputError(f"tiling: overlap {overlap}: give a value in [0, {tile - 1}]")
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


__all__ = ["DEFAULT_OVERLAP", "ramp", "tile_starts"]
