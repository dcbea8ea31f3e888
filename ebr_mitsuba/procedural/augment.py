"""SVBRDF augmentation for training (as in the dual-loss estimator's data pipeline), numpy only.

Every operation keeps the map set physically consistent:

* geometric operations move all maps together and turn the normals with the map: a map rotated by
  θ counter-clockwise (as displayed: row 0 on top, world +y) gets its normals' (x, y) rotated by θ
  too; a mirror flips the matching normal component;
* scaling keeps the normals as they are (a uniform 3-D scale of the surface: heights scale with
  the texture, slopes do not change);
* resampling interpolates normals in slope space (``∇h``, see :mod:`.normals`), as does blending;
* colour jitter touches the diffuse map only and keeps it in [0, 1].

The random driver :func:`augment` takes an explicit ``np.random.Generator`` and always makes the
same number of draws, so a (material, generator state, settings) triple gives one result.

==============================  ======================================================================
function                        operation
==============================  ======================================================================
``rotate90(m, k)``              exact rotation by k·90° counter-clockwise
``mirror(m, axis)``             flip left↔right (``"x"``) or top↔bottom (``"y"``)
``rotate_scale_crop(m, ...)``   rotate by any angle, magnify by ``zoom``, crop around ``center``
                                (bilinear; the rotated crop must lie inside the source)
``jitter_diffuse(d, ...)``      hue shift, saturation, brightness and contrast of the diffuse map
``random_mask(rng, size)``      a soft, tileable blend mask from fBm
``blend(a, b, mask)``           per-pixel mix of two materials (normals in slope space)
``augment(m, rng, other)``      the random combination of the above, see :class:`AugmentSettings`
==============================  ======================================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from ..colour import LUMINANCE
from ..errors import InputError
from ..svbrdf import SVBRDF
from .color import hsv_to_rgb, rgb_to_hsv
from .noise import fbm, grid, smoothstep
from .normals import normals_to_slopes, slopes_to_normals


def _with(m: SVBRDF, normal, diffuse, specular, roughness, tag: str) -> SVBRDF:
    return SVBRDF(
        normal=normal,
        diffuse=np.clip(diffuse, 0.0, 1.0),
        specular=np.clip(specular, 0.0, 1.0),
        roughness=np.clip(roughness, 0.0, 1.0),
        source=f"{m.source}+{tag}",
    )


def _rotate_xy(n: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    x, y = n[..., 0], n[..., 1]
    return np.stack([c * x - s * y, s * x + c * y, n[..., 2]], axis=-1)


def rotate90(m: SVBRDF, k: int) -> SVBRDF:
    """Rotate all maps by ``k``·90° counter-clockwise (as displayed), normals with them."""
    k = int(k) % 4
    if k == 0:
        return m
    rot = [np.rot90(a, k, axes=(0, 1)) for a in (m.normal, m.diffuse, m.specular, m.roughness)]
    n = rot[0]
    nx, ny = n[..., 0], n[..., 1]
    turned = {1: (-ny, nx), 2: (-nx, -ny), 3: (ny, -nx)}[k]
    normal = np.stack([turned[0], turned[1], n[..., 2]], axis=-1)
    return _with(m, normal, rot[1], rot[2], rot[3], f"rot{90 * k}")


def mirror(m: SVBRDF, axis: str = "x") -> SVBRDF:
    """Mirror left↔right (``axis="x"``: x → −x, n_x → −n_x) or top↔bottom (``"y"``)."""
    if axis not in ("x", "y"):
        raise InputError(f"mirror: axis {axis!r} must be 'x' or 'y'")
    ax = 1 if axis == "x" else 0
    maps = [np.flip(a, axis=ax) for a in (m.normal, m.diffuse, m.specular, m.roughness)]
    normal = maps[0].copy()
    normal[..., 0 if axis == "x" else 1] *= -1.0
    return _with(m, normal, maps[1], maps[2], maps[3], f"mirror{axis}")


def _bilinear(img: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    r = np.clip(rows, 0.0, h - 1.0)
    c = np.clip(cols, 0.0, w - 1.0)
    r0 = np.minimum(np.floor(r).astype(np.int64), h - 1)
    c0 = np.minimum(np.floor(c).astype(np.int64), w - 1)
    r1 = np.minimum(r0 + 1, h - 1)
    c1 = np.minimum(c0 + 1, w - 1)
    fr = (r - r0)[..., None] if img.ndim == 3 else r - r0
    fc = (c - c0)[..., None] if img.ndim == 3 else c - c0
    top = img[r0, c0] * (1 - fc) + img[r0, c1] * fc
    bottom = img[r1, c0] * (1 - fc) + img[r1, c1] * fc
    return top * (1 - fr) + bottom * fr


def rotate_scale_crop(
    m: SVBRDF, angle: float, zoom: float = 1.0, center=(0.0, 0.0), size: int | None = None
) -> SVBRDF:
    """Rotate by ``angle`` (radians, counter-clockwise), magnify by ``zoom`` and crop.

    The output (``size``², default the input's size) covers the world square [-1, 1]²; output
    point p shows the source at ``q = R(−angle)·p / zoom + center``. The rotated crop must lie in
    the source: ``|center_x|, |center_y| ≤ 1 − (|cos| + |sin|)/zoom``. Maps are interpolated
    bilinearly (normals in slope space), then the normals' (x, y) turn by ``angle``.
    """
    hs, ws = m.shape
    size = hs if size is None else int(size)
    c, s = math.cos(angle), math.sin(angle)
    extent = (abs(c) + abs(s)) / zoom
    cx, cy = (float(v) for v in center)
    if zoom <= 0 or max(abs(cx), abs(cy)) + extent > 1.0 + 1e-9:
        raise InputError(
            f"rotate_scale_crop: angle {angle:.4g} rad at zoom {zoom:.4g} around "
            f"({cx:.3g}, {cy:.3g}) reaches outside the source; raise zoom to at least "
            f"{(abs(c) + abs(s)) / max(1e-9, 1 - max(abs(cx), abs(cy))):.4g}"
        )
    u, v = grid(size)
    px = 2.0 * u - 1.0
    py = 1.0 - 2.0 * v
    qx = (c * px + s * py) / zoom + cx  # R(−angle)·p / zoom + center
    qy = (-s * px + c * py) / zoom + cy
    cols = (qx + 1.0) * ws / 2.0 - 0.5
    rows = (1.0 - qy) * hs / 2.0 - 0.5
    slopes = _bilinear(normals_to_slopes(m.normal), rows, cols)
    gx, gy = slopes[..., 0], slopes[..., 1]
    turned = np.stack([c * gx - s * gy, s * gx + c * gy], axis=-1)
    diffuse = _bilinear(m.diffuse.astype(np.float64), rows, cols)
    specular = _bilinear(m.specular.astype(np.float64), rows, cols)
    rough = _bilinear(m.roughness.astype(np.float64), rows, cols)
    return _with(
        m, slopes_to_normals(turned), diffuse, specular, rough, f"rot{math.degrees(angle):.3g}zoom{zoom:.3g}"
    )


def jitter_diffuse(
    diffuse: np.ndarray,
    hue: float = 0.0,
    saturation: float = 1.0,
    brightness: float = 1.0,
    contrast: float = 1.0,
) -> np.ndarray:
    """Colour-jittered diffuse map (H, W, 3) float32 in [0, 1].

    ``hue``: shift as a fraction of the hue circle; ``saturation`` and ``brightness``: factors
    on HSV saturation and value; ``contrast``: factor on the distance from the map's mean
    luminance. Identity at (0, 1, 1, 1).
    """
    hsv = rgb_to_hsv(np.clip(diffuse, 0.0, 1.0))
    hsv[..., 0] = (hsv[..., 0] + hue) % 1.0
    hsv[..., 1] = np.clip(hsv[..., 1] * saturation, 0.0, 1.0)
    hsv[..., 2] = hsv[..., 2] * brightness
    rgb = hsv_to_rgb(hsv)
    mean = float((rgb @ LUMINANCE).mean())
    return np.clip(mean + contrast * (rgb - mean), 0.0, 1.0).astype(np.float32)


def random_mask(
    rng: np.random.Generator, size: int, coverage: float = 0.5, softness: float = 0.05, freq: int = 3
) -> np.ndarray:
    """Soft, tileable mask (size, size) in [0, 1]: fBm thresholded so that about ``coverage`` of
    the pixels are ≥ 0.5; ``softness`` is the transition width in noise units."""
    u, v = grid(size)
    noise = fbm(u, v, rng, freq=freq, octaves=5, max_freq=size / 2)
    level = float(np.quantile(noise, 1.0 - coverage))
    return smoothstep(level - softness, level + softness, noise)


def blend(a: SVBRDF, b: SVBRDF, mask: np.ndarray) -> SVBRDF:
    """``(1 − mask)·a + mask·b`` per pixel; ``mask`` (H, W) in [0, 1]. Normals are mixed as slopes
    ``(−n_x/n_z, −n_y/n_z)`` (the gradients of the two height fields), then renormalised."""
    if a.shape != b.shape:
        raise InputError(f"blend: materials are {a.shape} and {b.shape}; resample them to one size")
    w = np.clip(np.asarray(mask, dtype=np.float64), 0.0, 1.0)
    if w.shape != a.shape:
        raise InputError(f"blend: mask has shape {w.shape}; expected {a.shape}")
    w3 = w[..., None]
    slopes = (1 - w3) * normals_to_slopes(a.normal) + w3 * normals_to_slopes(b.normal)
    return SVBRDF(
        normal=slopes_to_normals(slopes),
        diffuse=(1 - w3) * a.diffuse + w3 * b.diffuse,
        specular=(1 - w3) * a.specular + w3 * b.specular,
        roughness=(1 - w) * a.roughness + w * b.roughness,
        source=f"blend({a.source},{b.source})",
    )


@dataclass(frozen=True)
class AugmentSettings:
    """Settings of :func:`augment` (defaults follow common SVBRDF-training practice).

    ================  =========  ====================================================================
    field             default    meaning
    ================  =========  ====================================================================
    rotate90          True       random multiple of 90°
    mirror            True       mirror left↔right with probability ½
    max_angle         15.0       small-angle rotation, degrees, uniform in ±max_angle
    zoom              (1, 2)     magnification range, on top of the minimum the rotation needs
    hue               0.05       hue shift, uniform in ±hue (fraction of the circle)
    saturation        0.3        saturation factor uniform in [1 − s, 1 + s]
    brightness        0.3        value factor uniform in [1 − b, 1 + b]
    contrast          0.2        contrast factor uniform in [1 − c, 1 + c]
    blend             0.5        probability of blending with ``other`` when it is given
    mask_coverage     (0.2, .8)  range of the blend mask's coverage
    ================  =========  ====================================================================
    """

    rotate90: bool = True
    mirror: bool = True
    max_angle: float = 15.0
    zoom: tuple[float, float] = (1.0, 2.0)
    hue: float = 0.05
    saturation: float = 0.3
    brightness: float = 0.3
    contrast: float = 0.2
    blend: float = 0.5
    mask_coverage: tuple[float, float] = (0.2, 0.8)

    def __post_init__(self):
        lo, hi = self.zoom
        if not 1.0 <= lo <= hi:
            raise InputError(f"AugmentSettings: zoom {self.zoom} must satisfy 1 <= low <= high")
        if not 0.0 <= self.max_angle <= 45.0:
            raise InputError(f"AugmentSettings: max_angle {self.max_angle} must be in [0, 45] degrees")
        for name in ("saturation", "brightness", "contrast"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise InputError(f"AugmentSettings: {name} {getattr(self, name)} must be in [0, 1)")
        if not 0.0 <= self.hue <= 0.5 or not 0.0 <= self.blend <= 1.0:
            raise InputError("AugmentSettings: hue must be in [0, 0.5] and blend in [0, 1]")
        clo, chi = self.mask_coverage
        if not 0.0 < clo <= chi < 1.0:
            raise InputError(
                f"AugmentSettings: mask_coverage {self.mask_coverage} must satisfy 0 < low <= high < 1"
            )

    @classmethod
    def none(cls) -> AugmentSettings:
        """Settings that change nothing (for tests and ablations)."""
        return cls(
            rotate90=False,
            mirror=False,
            max_angle=0.0,
            zoom=(1.0, 1.0),
            hue=0.0,
            saturation=0.0,
            brightness=0.0,
            contrast=0.0,
            blend=0.0,
        )

    def replace(self, **changes) -> AugmentSettings:
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise InputError(
                f"AugmentSettings: unknown field(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )
        return replace(self, **changes)


def augment(
    m: SVBRDF, rng: np.random.Generator, other: SVBRDF | None = None, settings: AugmentSettings | None = None
) -> SVBRDF:
    """One random augmentation of ``m`` (same size): optional blend with ``other``, 90° rotation,
    mirror, small rotation + zoom + crop, diffuse colour jitter (see :class:`AugmentSettings`)."""
    st = settings or AugmentSettings()
    size = m.shape[0]
    # draws: always the same count and order
    do_blend = rng.uniform() < st.blend
    coverage = rng.uniform(*st.mask_coverage)
    mask = random_mask(rng, size, coverage=coverage)
    k = int(rng.integers(4))
    flip = rng.uniform() < 0.5
    angle = math.radians(rng.uniform(-st.max_angle, st.max_angle))
    zoom = rng.uniform(*st.zoom) * (abs(math.cos(angle)) + abs(math.sin(angle)))
    slack = max(0.0, 1.0 - (abs(math.cos(angle)) + abs(math.sin(angle))) / zoom)
    center = rng.uniform(-slack, slack, size=2)
    hue = rng.uniform(-st.hue, st.hue)
    sat = rng.uniform(1 - st.saturation, 1 + st.saturation)
    bright = rng.uniform(1 - st.brightness, 1 + st.brightness)
    contrast = rng.uniform(1 - st.contrast, 1 + st.contrast)

    if other is not None and do_blend:
        m = blend(m, other, mask)
    if st.rotate90:
        m = rotate90(m, k)
    if st.mirror and flip:
        m = mirror(m, "x")
    if angle != 0.0 or zoom != 1.0:
        m = rotate_scale_crop(m, angle, zoom, center)
    if (hue, sat, bright, contrast) != (0.0, 1.0, 1.0, 1.0):
        m = SVBRDF(
            m.normal,
            jitter_diffuse(m.diffuse, hue, sat, bright, contrast),
            m.specular,
            m.roughness,
            source=f"{m.source}+jitter",
        )
    return m
