"""The sample's tilt read off a glossy capture's clipped highlight (``ebr estimate``'s normals for a
metal or a glossy sample, where the shading normals do not apply).

With the flash beside the lens (``docs/conventions.md``, "Geometry") the highlight sits where the
surface faces the camera: on a flat sample exactly below it, at the frame's centre. A sample whose
mean normal is tilted by the slopes ``s = (n_x, n_y) / n_z`` moves it to ``p = −D · s`` (``D`` the
camera height, ``p`` in the sample's units, the frame 2 wide). For a sharp lobe the held-out-light
re-render hangs on that tilt far more than on any map: a normal map stored in 8 bits cannot hold
0, its flat 128/255 is a tilt of 0.0039 per axis (0.3°, 1.2 pixels at 256² on the near frame), and
a polished copper (acg_Metal034, roughness 0.074) whose estimate has its highlight 1.2 pixels off
scores a held-out re-render of 15 against the truth's maps.

The reading. A glossy capture's exposure clips the tip of the lobe: the flash shot's saturated
pixels around the frame's centre are a disc centred on the highlight. The tilt is read off that
disc's centroid (the connected saturated pixels of the flash shot that hold the saturated pixel
nearest the centre, on the flash fit's area-averaged grid, :data:`~.flashfit.FIT_SIZE`),
``s = −centroid / D``. It is used only where it can be trusted:

* the flash-fitted roughness is at most :data:`MAX_ROUGHNESS` (a lobe sharp enough for its clipped
  tip to be the highlight, not the brightest texture);
* the disc holds at least :data:`MIN_SHARE` of the pixels;
* the tilt is at most :data:`MAX_TILT` (0.01, 0.57°): what the conventions' camera straight above
  the sample allows. A disc further off is not the lobe's tip over a flat sample: a glazed tile set
  whose tiles are tilted one by one (acg_Tiles074: read 0.031 for a mean tilt of 0.004), a relief
  (acg_Tiles011: 0.020–0.030 for 0.003), a highlight merged with a reflection (acg_Metal055A:
  0.017 for 0.005), a procedural wood (0.018 for 0).

Where it is used the normal map is flat, tilted by ``s`` (:func:`tilted_normals`), in place of the
network's normals: their detail is noise on these samples (normal RMSE higher than the flat
tilt's on every validation capture read). Measured on the validation captures that keep the
network's normals and have a disc (``configs/data_real_val.toml``, ``configs/data_real_val2.toml``,
``configs/data_proc_val.toml``; training materials and maps, or new procedural draws; never the
test split) by :mod:`ebr_mitsuba.bench.tilt` (``ebr bench tilt``, ``docs/bench/tilt.md``; 2026-12-08):
of the 96 captures 23 keep the network's normals and the tilt was applied in 8 (three of the
copper, a wood floor, four procedural metals); their held-out re-render went 6.17 (the network's
normals) / 5.97 (flat) → 4.65 (tilted), the copper's 15.1 → 10.4, 15.5 → 10.0 and 15.8 → 14.0,
the normal RMSE 0.00366 / 0.00353 → 0.00322; lower in 6 of the 8, higher in 2 by under 0.003. The
rejections are the captures listed under :data:`MAX_TILT`; the reading's error against the true
mean tilt was 0.001–0.006 per axis (median 0.0024).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..geometry import pixel_positions

MAX_ROUGHNESS = 0.35  # the flash fit's roughness above which the saturated pixels are not a lobe's tip
MAX_TILT = 0.01  # largest slope read (module docstring); beyond it the disc is not the lobe's tip
MIN_SHARE = 50 / 256**2  # smallest disc, as a share of the pixels (50 at 256²)


@dataclass(frozen=True)
class HighlightTilt:
    """A reading of the highlight: ``slope`` (2,) the mean normal's (n_x, n_y) / n_z; ``centroid``
    (2,) the disc's centre in the sample's units (x right, y up; the frame 2 wide); ``pixels`` the
    disc's pixel count and ``size`` the grid it was read on; ``applied`` whether it passed the
    checks, ``reason`` why not."""

    slope: np.ndarray
    centroid: np.ndarray
    pixels: int
    size: tuple[int, int]
    applied: bool
    reason: str = ""

    @property
    def degrees(self) -> float:
        return float(np.degrees(np.arctan(np.hypot(*self.slope))))

    def to_json(self) -> dict:
        out = {
            "applied": self.applied,
            "slope": [round(float(v), 5) for v in self.slope],
            "degrees": round(self.degrees, 3),
            "pixels": int(self.pixels),
            "grid": list(self.size),
        }
        if self.reason:
            out["reason"] = self.reason
        return out


def central_component(mask: np.ndarray, radius: float) -> np.ndarray | None:
    """The 4-connected pixels of ``mask`` (H, W) bool that hold its pixel nearest the frame's centre,
    if that pixel lies within ``radius`` pixels of it (else None)."""
    mask = np.asarray(mask, bool)
    if mask.ndim != 2:
        raise InputError(f"highlight tilt: the saturation mask has shape {mask.shape}; expected (H, W)")
    h, w = mask.shape
    yy, xx = np.mgrid[0:h, 0:w]
    d2 = (yy - (h - 1) / 2.0) ** 2 + (xx - (w - 1) / 2.0) ** 2
    near = np.where(mask, d2, np.inf)
    k = int(np.argmin(near))
    if not np.isfinite(near.flat[k]) or near.flat[k] > radius**2:
        return None
    comp = np.zeros_like(mask)
    comp.flat[k] = True
    count = 1
    while True:  # grow by one pixel per step inside the mask until it stops
        grown = comp.copy()
        grown[1:] |= comp[:-1]
        grown[:-1] |= comp[1:]
        grown[:, 1:] |= comp[:, :-1]
        grown[:, :-1] |= comp[:, 1:]
        grown &= mask
        n = int(grown.sum())
        if n == count:
            return comp
        comp, count = grown, n


def read_highlight_tilt(saturated: np.ndarray, camera_height: float, roughness: float) -> HighlightTilt:
    """The tilt of the sample's mean normal read off the flash shot's clipped highlight (module
    docstring): ``saturated`` (H, W) bool, the flash shot's saturated pixels on the sample grid
    (larger grids are area-reduced to the flash fit's size, a saturated pixel saturating its
    block); ``camera_height`` the near camera's height; ``roughness`` the flash fit's."""
    from .flashfit import FIT_SIZE, area_mask, shrink_factor

    if camera_height <= 0:
        raise InputError(f"highlight tilt: camera height {camera_height}; expected > 0")
    sat = np.asarray(saturated, bool)
    if sat.ndim != 2:
        raise InputError(f"highlight tilt: the saturation mask has shape {sat.shape}; expected (H, W)")
    f = shrink_factor(*sat.shape, FIT_SIZE)
    if f > 1:
        sat = area_mask(sat, f)
    h, w = sat.shape
    zero = np.zeros(2)
    if roughness > MAX_ROUGHNESS:
        return HighlightTilt(zero, zero, 0, (h, w), False, f"roughness {roughness:.2f} > {MAX_ROUGHNESS}")
    pixel = 2.0 / max(h, w)  # one pixel in the sample's units
    comp = central_component(sat, MAX_TILT * camera_height / pixel + 1.0)
    if comp is None:
        return HighlightTilt(zero, zero, 0, (h, w), False, "no clipped highlight at the centre")
    n = int(comp.sum())
    centroid = pixel_positions(h, w)[comp][:, :2].mean(axis=0)
    slope = -centroid / camera_height
    if n < MIN_SHARE * h * w:
        return HighlightTilt(slope, centroid, n, (h, w), False, f"highlight of {n} pixels, too small")
    if float(np.hypot(*slope)) > MAX_TILT:
        return HighlightTilt(
            slope, centroid, n, (h, w), False, f"tilt {np.hypot(*slope):.4f} > {MAX_TILT}: not the lobe's tip"
        )
    return HighlightTilt(slope, centroid, n, (h, w), True)


def tilted_normals(shape: tuple[int, int], slope) -> np.ndarray:
    """A flat normal map (H, W, 3) float32 tilted by ``slope`` (2,) = (n_x, n_y) / n_z."""
    s = np.asarray(slope, np.float64)
    n = np.array([s[0], s[1], 1.0]) / np.sqrt(1.0 + s[0] ** 2 + s[1] ** 2)
    return np.broadcast_to(n.astype(np.float32), (*shape, 3)).copy()


__all__ = [
    "MAX_ROUGHNESS",
    "MAX_TILT",
    "MIN_SHARE",
    "HighlightTilt",
    "central_component",
    "read_highlight_tilt",
    "tilted_normals",
]
