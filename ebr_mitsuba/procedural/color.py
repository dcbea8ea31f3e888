"""Vectorised RGB ↔ HSV conversion (numpy), used for palettes and colour jitter.

Arrays are (…, 3), any float dtype, RGB in [0, 1]; hue in [0, 1) (fraction of the full circle),
saturation and value in [0, 1]. Works on linear RGB as on any other RGB: the conversion is a
re-parametrisation, not a colour-space change.
"""

from __future__ import annotations

import numpy as np


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """(…, 3) RGB → (…, 3) HSV (float64)."""
    c = np.asarray(rgb, dtype=np.float64)
    r, g, b = c[..., 0], c[..., 1], c[..., 2]
    maxc = c.max(axis=-1)
    minc = c.min(axis=-1)
    delta = maxc - minc
    safe = np.where(delta > 0, delta, 1.0)
    h = np.where(maxc == r, (g - b) / safe, np.where(maxc == g, 2.0 + (b - r) / safe, 4.0 + (r - g) / safe))
    h = np.where(delta > 0, (h / 6.0) % 1.0, 0.0)
    s = np.where(maxc > 0, delta / np.where(maxc > 0, maxc, 1.0), 0.0)
    return np.stack([h, s, maxc], axis=-1)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """(…, 3) HSV → (…, 3) RGB (float64)."""
    c = np.asarray(hsv, dtype=np.float64)
    h, s, v = c[..., 0] % 1.0, c[..., 1], c[..., 2]
    k = (np.array([5.0, 3.0, 1.0]) + h[..., None] * 6.0) % 6.0
    return v[..., None] - v[..., None] * s[..., None] * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
