"""Equirectangular environment maps in Mitsuba's ``envmap`` convention, in our z-up world.

The one direction ↔ uv convention of the toolkit (``docs/conventions.md``, "Spherical Gaussians"; tested
against Mitsuba's own ``envmap.eval`` in ``tests/test_io.py``):

* **Mitsuba's envmap frame** (y-up): uv = (u, v) ∈ [0, 1]², φ = 2πu, θ = πv, direction
  ``(sin φ sin θ, cos θ, −cos φ sin θ)``; row 0 (v = 0) is the zenith +Y.
* **Texel positions**: column j sits at its centre u = (j + 0.5)/W (the map wraps around in u);
  row i sits at v = i/(H − 1) ("align corners": row 0 is exactly the zenith, row H − 1 exactly
  the nadir). Mitsuba interpolates bilinearly between these positions.
* **World frame** (ours, z-up): the envmap emitter's ``to_world`` is a +90° rotation about x,
  ``(x, y, z)_map → (x, −z, y)_world``, so the map's zenith is our +z. In world terms:
  u = 0 looks along +y, u = 0.25 along +x, u = 0.5 along −y, u = 0.75 along −x
  (world azimuth atan2(y, x) = π/2 − 2πu); v is the polar angle from +z over π.

=====================================  =========================================================
function                               what it gives
=====================================  =========================================================
``map_to_world`` / ``world_to_map``    the rotation between Mitsuba's envmap frame and the world
``envmap_to_world()``                  that rotation as ``mi.ScalarTransform4f`` (``to_world``)
``uv_to_direction`` / ``direction_to_uv``  the helper pair (world directions, (…, 3) ↔ (…, 2))
``texel_uv(H, W)``                     (H, W, 2) uv of the texel positions
``equirect_directions(H, W)``          (H, W, 3) world directions of the texel positions
``equirect_solid_angles(H, W)``        (H, W) solid angle of each texel's cell, sums to 4π
``EquirectMap`` / ``load_equirect``    a validated linear (H, W, 3) float32 map (.hdr / .exr)
``sg_to_equirect(env, H, W)``          an :class:`SGEnvironment` rasterised at the texel positions
``envmap_emitter_dict(map, scale)``    a Mitsuba ``envmap`` emitter dict in the z-up world
=====================================  =========================================================

Direction arrays are float64 numpy (geometry); image data is float32 (H, W, 3) linear RGB.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .imageio import EXR_SUFFIXES, HDR_SUFFIXES, read_image
from .sgenv import SGEnvironment

#: 4×4 ``to_world`` of an envmap in our z-up world: map (x, y, z) → world (x, −z, y).
ENVMAP_TO_WORLD = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


# -- the frame rotation -------------------------------------------------------------------------


def map_to_world(d: np.ndarray) -> np.ndarray:
    """Directions (…, 3) in Mitsuba's y-up envmap frame → our z-up world: (x, y, z) → (x, −z, y)."""
    d = np.asarray(d, dtype=np.float64)
    return np.stack([d[..., 0], -d[..., 2], d[..., 1]], axis=-1)


def world_to_map(d: np.ndarray) -> np.ndarray:
    """World directions (…, 3) → Mitsuba's envmap frame: (x, y, z) → (x, z, −y)."""
    d = np.asarray(d, dtype=np.float64)
    return np.stack([d[..., 0], d[..., 2], -d[..., 1]], axis=-1)


def envmap_to_world():
    """``mi.ScalarTransform4f`` to give an ``envmap`` emitter as ``to_world`` in our z-up world
    (exact entries, no trigonometric round-off). Needs a Mitsuba variant (set here if none)."""
    import mitsuba as mi

    from .variant import ensure_variant

    ensure_variant()
    return mi.ScalarTransform4f(ENVMAP_TO_WORLD.tolist())


# -- the direction ↔ uv helper pair ----------------------------------------------------------------


def uv_to_direction(uv: np.ndarray) -> np.ndarray:
    """uv (…, 2) in Mitsuba's envmap convention → unit world directions (…, 3), z-up."""
    uv = np.asarray(uv, dtype=np.float64)
    phi = 2.0 * math.pi * uv[..., 0]
    theta = math.pi * uv[..., 1]
    sin_t = np.sin(theta)
    local = np.stack([np.sin(phi) * sin_t, np.cos(theta), -np.cos(phi) * sin_t], axis=-1)
    return map_to_world(local)


def direction_to_uv(d: np.ndarray) -> np.ndarray:
    """World directions (…, 3) (normalised here) → uv (…, 2), u ∈ [0, 1), v ∈ [0, 1].

    Exact inverse of :func:`uv_to_direction` except at the poles, where u is arbitrary.
    """
    local = world_to_map(d)
    local = local / np.linalg.norm(local, axis=-1, keepdims=True)
    u = np.arctan2(local[..., 0], -local[..., 2]) / (2.0 * math.pi)
    u = u - np.floor(u)
    u = np.where(u >= 1.0, 0.0, u)  # -tiny + 1 rounds to 1.0
    v = np.arccos(np.clip(local[..., 1], -1.0, 1.0)) / math.pi
    return np.stack([u, v], axis=-1)


def _check_size(height: int, width: int) -> tuple[int, int]:
    h, w = int(height), int(width)
    if h < 2 or w < 1:
        raise ValueError(f"equirectangular size {w}x{h}: need H >= 2 rows (the poles) and W >= 1")
    return h, w


def texel_uv(height: int, width: int) -> np.ndarray:
    """uv (H, W, 2) of the texel positions: u = (j + 0.5)/W, v = i/(H − 1)."""
    h, w = _check_size(height, width)
    u = (np.arange(w, dtype=np.float64) + 0.5) / w
    v = np.arange(h, dtype=np.float64) / (h - 1)
    return np.stack(np.meshgrid(u, v, indexing="xy"), axis=-1)


def equirect_directions(height: int, width: int) -> np.ndarray:
    """World (z-up) unit directions (H, W, 3) of the texel positions of an H×W map."""
    return uv_to_direction(texel_uv(height, width))


def equirect_solid_angles(height: int, width: int) -> np.ndarray:
    """Solid angle (H, W) of each texel's cell; the cells tile the sphere (sum = 4π).

    Row i sits at θ_i = π·i/(H − 1) and owns θ ∈ [θ_i − Δ/2, θ_i + Δ/2] ∩ [0, π], Δ = π/(H − 1):
    the first and last rows own half-height polar caps. Every column spans 2π/W in φ.
    """
    h, w = _check_size(height, width)
    delta = math.pi / (h - 1)
    theta = np.arange(h, dtype=np.float64) * delta
    lo = np.clip(theta - delta / 2, 0.0, math.pi)
    hi = np.clip(theta + delta / 2, 0.0, math.pi)
    band = (np.cos(lo) - np.cos(hi)) * (2.0 * math.pi / w)
    return np.repeat(band[:, None], w, axis=1)


# -- maps -----------------------------------------------------------------------------------------

# Negative texels down to this fraction of the mean radiance are compression noise, clipped at 0.
NEGATIVE_TOLERANCE = 0.01


@dataclass(frozen=True)
class EquirectMap:
    """An equirectangular radiance map: ``data`` (H, W, 3) float32 linear RGB ≥ 0, W = 2H.

    ``source`` names where it came from (a path, or ``"<memory>"``) for error messages.
    """

    data: np.ndarray
    source: str = "<memory>"

    def __post_init__(self):
        d = np.asarray(self.data, dtype=np.float32)
        src = self.source
        if d.ndim != 3 or d.shape[2] != 3:
            raise InputError(f"{src}: environment map has shape {d.shape}; expected (H, W, 3) RGB")
        h, w, _ = d.shape
        if h < 2 or w != 2 * h:
            raise InputError(
                f"{src}: environment map is {w}x{h}; an equirectangular map is 2:1 "
                f"(W = 2H, H >= 2): convert it to a latitude-longitude map"
            )
        if not np.all(np.isfinite(d)):
            raise InputError(f"{src}: environment map has NaN or Inf texels; fix or regenerate it")
        lo = float(d.min())
        if lo < 0:
            # Lossy EXR codecs (DWAB, half floats) leave a few texels slightly below zero: those
            # within NEGATIVE_TOLERANCE of the map's mean radiance are clipped; larger ones refused.
            mean = float(np.abs(d).mean())
            if -lo > NEGATIVE_TOLERANCE * mean:
                raise InputError(
                    f"{src}: environment map has negative radiance (min {lo:.4g}, mean "
                    f"{mean:.4g}); clip it at 0"
                )
            d = np.maximum(d, 0.0)
        object.__setattr__(self, "data", np.ascontiguousarray(d))

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.data.shape[0]), int(self.data.shape[1])

    def solid_angles(self) -> np.ndarray:
        """(H, W) per-texel solid angles (see :func:`equirect_solid_angles`)."""
        return equirect_solid_angles(*self.shape)

    def eval(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (…, 3) float64 in world directions (…, 3), interpolated as Mitsuba's
        ``envmap`` does (bilinear, wrapping in u, clamped in v): a numpy reference."""
        h, w = self.shape
        uv = direction_to_uv(directions)
        x = uv[..., 0] * w - 0.5
        y = np.clip(uv[..., 1] * (h - 1), 0.0, h - 1)
        x0 = np.floor(x)
        y0 = np.minimum(np.floor(y), h - 2)
        fx = (x - x0)[..., None]
        fy = (y - y0)[..., None]
        i0 = y0.astype(np.int64)
        j0 = x0.astype(np.int64) % w
        j1 = (j0 + 1) % w
        d = self.data.astype(np.float64)
        top = d[i0, j0] * (1 - fx) + d[i0, j1] * fx
        bottom = d[i0 + 1, j0] * (1 - fx) + d[i0 + 1, j1] * fx
        return top * (1 - fy) + bottom * fy


def load_equirect(path: str | os.PathLike) -> EquirectMap:
    """Read an equirectangular ``.hdr`` or ``.exr`` (y-up file, Mitsuba's convention) as an
    :class:`EquirectMap`; LDR files are refused (they do not hold radiance)."""
    path = Path(path)
    if path.suffix.lower() not in EXR_SUFFIXES + HDR_SUFFIXES:
        raise InputError(
            f"{path}: an environment map must be a linear .exr or .hdr file (LDR images do not hold radiance)"
        )
    data = read_image(path, "linear", expect_channels=3)
    return EquirectMap(data, source=str(path))


def sg_to_equirect(env: SGEnvironment, height: int, width: int, rows_per_chunk: int = 64) -> np.ndarray:
    """Rasterise ``env`` at the texel positions of an H×W map: (H, W, 3) float32.

    A Mitsuba ``envmap`` built from the result with :func:`envmap_emitter_dict` reproduces the SG
    environment up to bilinear interpolation error (exact at the texel positions).
    """
    dirs = equirect_directions(height, width)
    out = np.empty(dirs.shape, dtype=np.float32)
    for start in range(0, dirs.shape[0], rows_per_chunk):  # bounds the (rows, W, K) temporary
        out[start : start + rows_per_chunk] = env.eval(dirs[start : start + rows_per_chunk])
    return out


def envmap_emitter_dict(source, scale: float = 1.0) -> dict:
    """Mitsuba ``envmap`` emitter dict for :func:`mi.load_dict`, oriented for our z-up world.

    ``source``: a path (``.hdr``/``.exr``, read with :func:`load_equirect`), an
    :class:`EquirectMap`, or an (H, W, 3) array (validated like a file). The data goes in as a
    float32 RGB ``mi.Bitmap`` (``'bitmap'`` property); ``to_world`` is :func:`envmap_to_world`.
    """
    import mitsuba as mi

    scale = float(scale)
    if not (math.isfinite(scale) and scale >= 0):
        raise InputError(f"envmap scale is {scale}; give a finite value >= 0")
    if isinstance(source, EquirectMap):
        emap = source
    elif isinstance(source, (str, os.PathLike)):
        emap = load_equirect(source)
    else:
        emap = EquirectMap(np.asarray(source), source="<memory>")
    to_world = envmap_to_world()  # also selects the variant that mi.Bitmap/load_dict need
    bitmap = mi.Bitmap(emap.data, pixel_format=mi.Bitmap.PixelFormat.RGB)
    return {"type": "envmap", "bitmap": bitmap, "scale": scale, "to_world": to_world}
