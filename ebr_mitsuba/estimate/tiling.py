"""Tiles with overlap blending, and the bilinear upsampling of the full-resolution estimate.

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


def upsample_bilinear(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(h, w[, c]) → (H, W[, c]) float32 by separable linear interpolation between pixel centres
    (edges clamped): ``torch.nn.functional.interpolate`` (bilinear, ``align_corners=False``), the
    same values as :func:`upsample_bilinear_reference` (tested) in a fraction of the time."""
    import torch
    import torch.nn.functional as F

    a = np.asarray(image, np.float32)
    t = torch.from_numpy(np.ascontiguousarray(a if a.ndim == 3 else a[..., None])).permute(2, 0, 1)[None]
    with torch.no_grad():
        out = F.interpolate(t, size=(int(size[0]), int(size[1])), mode="bilinear", align_corners=False)
    out = out[0].permute(1, 2, 0).numpy()
    return np.ascontiguousarray(out if a.ndim == 3 else out[..., 0])


def upsample_bilinear_reference(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(h, w[, c]) → (H, W[, c]) by separable linear interpolation between pixel centres (edges
    clamped), in numpy float64: the reference of :func:`upsample_bilinear`."""
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


__all__ = ["DEFAULT_OVERLAP", "ramp", "tile_starts", "upsample_bilinear", "upsample_bilinear_reference"]
