"""Structural similarity (SSIM) and multi-scale SSIM of linear images, in numpy.

Wang et al. 2004 (SSIM) and 2003 (MS-SSIM) with the usual constants: an 11-tap Gaussian window
of σ = 1.5 (separable, "valid" part only, so no padding bias at the borders), ``K1 = 0.01``,
``K2 = 0.03``, and five MS-SSIM scales with weights
``(0.0448, 0.2856, 0.3001, 0.2363, 0.1333)`` (2× box down-sampling between scales).

===================  ===============================================================================
function             what
===================  ===============================================================================
``ssim(a, b)``       mean SSIM of two (H, W, 3) (or (H, W)) images → float in [−1, 1]; the
                     function other modules import (adaptive exemplar selection compares renders
                     with the no-flash photo with it)
``ssim_map``         the per-pixel SSIM (H − 10, W − 10) averaged over channels, and its contrast-
                     structure part
``ms_ssim(a, b)``    multi-scale SSIM → float
``ms_ssim_error``    a per-pixel (H, W) *error* map ``1 − MS-SSIM`` (each scale's map up-sampled to
                     full size, combined with the MS-SSIM weights as a weighted geometric mean):
                     where the extraction's densification adds lobes
===================  ===============================================================================

``data_range`` (the L of ``C1 = (K1 L)²``, ``C2 = (K2 L)²``): by default the larger of the two
images' maxima (floor 1e-12), so that two HDR images of the same scale compare like their
[0, 1]-normalised versions. Pass a fixed value to compare with a known range (e.g. 1.0 for
sRGB-encoded, clipped images as the metrics of ``docs/conventions.md`` do). Images are compared as
given (linear); encode them first for a perceptual comparison. Images smaller than the window (H or
W < 11) are an :class:`~ebr_mitsuba.errors.InputError`.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

WINDOW = 11
SIGMA = 1.5
K1 = 0.01
K2 = 0.03
MS_WEIGHTS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)


def _gaussian_taps(size: int = WINDOW, sigma: float = SIGMA) -> np.ndarray:
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2.0
    g = np.exp(-0.5 * (x / sigma) ** 2)
    return g / g.sum()


_TAPS = _gaussian_taps()


def _filter_valid(x: np.ndarray) -> np.ndarray:
    """Separable Gaussian filter over the first two axes, 'valid' output (H − 10, W − 10, ...)."""
    n = _TAPS.size
    rows = np.lib.stride_tricks.sliding_window_view(x, n, axis=0)  # (H-10, W, ..., n)
    x = np.tensordot(rows, _TAPS, axes=([-1], [0]))
    cols = np.lib.stride_tricks.sliding_window_view(x, n, axis=1)
    return np.tensordot(cols, _TAPS, axes=([-1], [0]))


def _as_pair(a, b, what: str) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise InputError(f"{what}: images of shapes {a.shape} and {b.shape}; give two images of one shape")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    if a.ndim != 3:
        raise InputError(f"{what}: images of shape {a.shape}; expected (H, W) or (H, W, C)")
    if a.shape[0] < WINDOW or a.shape[1] < WINDOW:
        raise InputError(
            f"{what}: images of {a.shape[1]}x{a.shape[0]} pixels are smaller than the "
            f"{WINDOW}x{WINDOW} SSIM window; give larger images"
        )
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise InputError(f"{what}: NaN or Inf pixels; give finite images")
    return a, b


def _range(a: np.ndarray, b: np.ndarray, data_range: float | None) -> float:
    if data_range is None:
        return max(float(a.max(initial=0.0)), float(b.max(initial=0.0)), 1e-12)
    if not (np.isfinite(data_range) and data_range > 0):
        raise InputError(f"ssim: data_range must be a finite value > 0 (got {data_range!r})")
    return float(data_range)


def _ssim_parts(a: np.ndarray, b: np.ndarray, L: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel (valid) SSIM and contrast-structure maps, averaged over channels."""
    c1 = (K1 * L) ** 2
    c2 = (K2 * L) ** 2
    mu_a = _filter_valid(a)
    mu_b = _filter_valid(b)
    var_a = np.maximum(_filter_valid(a * a) - mu_a**2, 0.0)
    var_b = np.maximum(_filter_valid(b * b) - mu_b**2, 0.0)
    cov = _filter_valid(a * b) - mu_a * mu_b
    cs = (2.0 * cov + c2) / (var_a + var_b + c2)
    lum = (2.0 * mu_a * mu_b + c1) / (mu_a**2 + mu_b**2 + c1)
    return (lum * cs).mean(axis=-1), cs.mean(axis=-1)


def ssim_map(a, b, data_range: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(SSIM, contrast-structure) maps of shape (H − 10, W − 10), channel means."""
    a, b = _as_pair(a, b, "ssim_map")
    return _ssim_parts(a, b, _range(a, b, data_range))


def ssim(a, b, data_range: float | None = None) -> float:
    """Mean SSIM of images ``a`` and ``b`` ((H, W, 3) or (H, W), same shape, H, W ≥ 11)."""
    a, b = _as_pair(a, b, "ssim")
    s, _ = _ssim_parts(a, b, _range(a, b, data_range))
    return float(s.mean())


def _band(n: int) -> np.ndarray:
    """(n − 10, n) matrix of the 'valid' Gaussian filter along one axis."""
    m = np.zeros((n - _TAPS.size + 1, n))
    for i in range(m.shape[0]):
        m[i, i : i + _TAPS.size] = _TAPS
    return m


def ssim_many(a, b, data_range: float) -> np.ndarray:
    """Mean SSIM of each pair of a stack, ``a``, ``b``: (N, H, W, C); the value of :func:`ssim`
    per pair (float64), with the separable Gaussian filter as two banded matrix products per
    image (BLAS), so the 30 pairs of the re-render metric cost a fraction of 30 :func:`ssim` calls."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 4:
        raise InputError(f"ssim_many: stacks of shapes {a.shape} and {b.shape}; give two (N, H, W, C) stacks")
    for x, y in zip(a, b):  # the same checks as ssim
        _as_pair(x, y, "ssim_many")
    if not (np.isfinite(data_range) and data_range > 0):
        raise InputError(f"ssim_many: data_range must be a finite value > 0 (got {data_range!r})")
    n, h, w, c = a.shape
    rows, cols = _band(h), _band(w).T
    ta = a.transpose(0, 3, 1, 2)  # (N, C, H, W)
    tb = b.transpose(0, 3, 1, 2)

    def filt(x):
        return rows @ x @ cols

    c1, c2 = (K1 * data_range) ** 2, (K2 * data_range) ** 2
    mu_a, mu_b = filt(ta), filt(tb)
    var_a = np.maximum(filt(ta * ta) - mu_a**2, 0.0)
    var_b = np.maximum(filt(tb * tb) - mu_b**2, 0.0)
    cov = filt(ta * tb) - mu_a * mu_b
    cs = (2.0 * cov + c2) / (var_a + var_b + c2)
    lum = (2.0 * mu_a * mu_b + c1) / (mu_a**2 + mu_b**2 + c1)
    return (lum * cs).mean(axis=1).mean(axis=(1, 2))


def _downsample2(x: np.ndarray) -> np.ndarray:
    h, w = (x.shape[0] // 2) * 2, (x.shape[1] // 2) * 2
    x = x[:h, :w]
    return 0.25 * (x[0::2, 0::2] + x[1::2, 0::2] + x[0::2, 1::2] + x[1::2, 1::2])


def _scales(a: np.ndarray, b: np.ndarray) -> int:
    n, h, w = 1, a.shape[0], a.shape[1]
    while n < len(MS_WEIGHTS) and min(h // 2, w // 2) >= WINDOW:
        h, w, n = h // 2, w // 2, n + 1
    return n


def _ms_maps(a: np.ndarray, b: np.ndarray, L: float):
    """Per-scale maps: contrast-structure at every scale but the last, full SSIM at the last."""
    n = _scales(a, b)
    weights = np.asarray(MS_WEIGHTS[:n], dtype=np.float64)
    weights = weights / weights.sum()
    maps = []
    for level in range(n):
        s, cs = _ssim_parts(a, b, L)
        maps.append(s if level == n - 1 else cs)
        if level < n - 1:
            a, b = _downsample2(a), _downsample2(b)
    return maps, weights


def ms_ssim(a, b, data_range: float | None = None) -> float:
    """Multi-scale SSIM (as many of the five scales as the image size allows, weights
    renormalised); negative per-scale means are clamped to 0 before the weighted product."""
    a, b = _as_pair(a, b, "ms_ssim")
    maps, weights = _ms_maps(a, b, _range(a, b, data_range))
    values = np.array([max(float(m.mean()), 0.0) for m in maps])
    return float(np.prod(values**weights))


def _upsample_to(m: np.ndarray, h: int, w: int) -> np.ndarray:
    """Nearest-neighbour resize of a valid-region map to (h, w) (centred: the valid region of an
    11-tap window starts 5 pixels in)."""
    rows = np.clip(
        np.round((np.arange(h) + 0.5) / h * (m.shape[0] + 10) - 5.5).astype(int), 0, m.shape[0] - 1
    )
    cols = np.clip(
        np.round((np.arange(w) + 0.5) / w * (m.shape[1] + 10) - 5.5).astype(int), 0, m.shape[1] - 1
    )
    return m[np.ix_(rows, cols)]


def ms_ssim_error(a, b, data_range: float | None = None) -> np.ndarray:
    """Per-pixel error map ``1 − MS-SSIM`` (H, W) in [0, 1] (module docstring)."""
    a, b = _as_pair(a, b, "ms_ssim_error")
    h, w = a.shape[:2]
    maps, weights = _ms_maps(a, b, _range(a, b, data_range))
    log_sim = np.zeros((h, w))
    for m, wt in zip(maps, weights):
        log_sim += wt * np.log(np.clip(_upsample_to(m, h, w), 1e-6, 1.0))
    return 1.0 - np.exp(log_sim)


__all__ = ["ssim", "ssim_map", "ms_ssim", "ms_ssim_error"]
