"""Quad-tree subdivision of an exemplar by variance (the first step of SG extraction).

A square node of the image (level ℓ covers ``H/2^ℓ × W/2^ℓ`` pixels) is split into four while

* its luminance standard deviation exceeds ``threshold ×`` the image's mean luminance, and
* ``ℓ < max_level`` and the children are at least ``min_size`` pixels wide.

Leaves are where one lobe explains the light: flat regions stay large (broad lobes), highlights
end in small leaves (sharp lobes). Per-node statistics come from summed-area tables (O(1) per
node).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..colour import LUMINANCE


@dataclass(frozen=True)
class Patch:
    """A quad-tree leaf: ``level``, top-left pixel (``row``, ``col``), size (``height``, ``width``)
    in pixels, and the mean RGB radiance over it."""

    level: int
    row: int
    col: int
    height: int
    width: int
    mean: tuple

    @property
    def centre(self) -> tuple[float, float]:
        """(row, col) of the centre in pixel units (0.5 = centre of pixel 0)."""
        return self.row + 0.5 * self.height, self.col + 0.5 * self.width


def _sat(x: np.ndarray) -> np.ndarray:
    s = np.zeros((x.shape[0] + 1, x.shape[1] + 1) + x.shape[2:])
    s[1:, 1:] = np.cumsum(np.cumsum(x, axis=0), axis=1)
    return s


def quadtree(image: np.ndarray, threshold: float, max_level: int, min_size: int = 2) -> list[Patch]:
    """Leaves of the variance quad-tree of ``image`` (H, W, 3) (module docstring), in
    depth-first order."""
    image = np.asarray(image, np.float64)
    h, w = image.shape[:2]
    lum = image @ LUMINANCE
    s1, s2, srgb = _sat(lum), _sat(lum * lum), _sat(image)
    limit = threshold * max(float(lum.mean()), 1e-300)

    def box(s, r0, c0, r1, c1):
        return s[r1, c1] - s[r0, c1] - s[r1, c0] + s[r0, c0]

    leaves: list[Patch] = []
    stack = [(0, 0, 0, h, w)]
    while stack:
        level, r0, c0, r1, c1 = stack.pop()
        n = (r1 - r0) * (c1 - c0)
        mean = box(s1, r0, c0, r1, c1) / n
        var = max(box(s2, r0, c0, r1, c1) / n - mean * mean, 0.0)
        hm, wm = (r0 + r1) // 2, (c0 + c1) // 2
        can_split = level < max_level and min(hm - r0, r1 - hm, wm - c0, c1 - wm) >= min_size
        if can_split and np.sqrt(var) > limit:
            for rr0, rr1 in ((hm, r1), (r0, hm)):
                for cc0, cc1 in ((wm, c1), (c0, wm)):
                    stack.append((level + 1, rr0, cc0, rr1, cc1))
            continue
        rgb = box(srgb, r0, c0, r1, c1) / n
        leaves.append(Patch(level, r0, c0, r1 - r0, c1 - c0, tuple(float(v) for v in rgb)))
    return leaves
