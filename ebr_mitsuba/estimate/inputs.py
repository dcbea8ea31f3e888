"""The photos of an estimate: reading, exposure matching and the input checks.

:func:`load_inputs` reads the shots of one capture, brings them to one exposure and checks them.
Every image is a linear float32 (H, W, 3) numpy array, row 0 at the top
(docs/conventions.md#geometry-and-pixel-grid).

================  ===========================================================================
shot              meaning
================  ===========================================================================
``flash``         near shot, flash on (required)
``noflash``       near shot, flash off; absent: flash-only capture (a dark room), no lighting
``far_flash``     far shot, flash on (optional; needs ``far_noflash`` and ``noflash``)
``far_noflash``   far shot, flash off
================  ===========================================================================

Formats: EXR (linear radiance), PNG (8/16 bit) and JPEG, decoded from sRGB
(:func:`ebr_mitsuba.imageio.read_image`); a grey image is replicated to RGB.

Exposure. Every shot is scaled to the flash shot's exposure. When all shots carry EXIF exposure
time t, ISO S and f-number N, shot k is multiplied by ``H_flash / H_k`` with ``H = t·S/N²``.
Otherwise ``exposure_ratio`` (= exposure of the no-flash shots ÷ exposure of the flash shots)
divides the no-flash shots; without either, equal exposure is assumed (a warning for photos).
``exposure_ratio`` given while EXIF is complete overrides it (and says so).

Checks (an :class:`~ebr_mitsuba.errors.InputError` with one line, or a warning in the report):

==============  ===============================================================================
check           rule
==============  ===============================================================================
size            all shots the same size (error); shorter side below ``MIN_INPUT_SIZE`` (32) pixels
                (error: nothing to estimate); a non-square frame is centre-cropped (warning)
values          NaN/Inf (error, from the readers); negative EXR values clipped (warning)
flash           the flash shot brighter than the no-flash shot on average (error: swapped? without
                EXIF or ``exposure_ratio`` the message suggests ``--exposure-ratio``)
alignment       shift between the flash and no-flash shot of a pair (:func:`estimate_shift`:
                correlation of the gradients of the blurred log luminance, which survive the
                change of lighting) and its confidence (:class:`ShiftEstimate`: peak ratio and
                texture-to-noise of both shots); above max(``max_shift`` × width, 2) pixels an
                error when confident (:attr:`ShiftEstimate.confident`), else a warning that
                alignment could not be verified (dark, noisy or flat shots); above 1 pixel a
                warning
saturation      pixels at the top code of an 8/16-bit file (linear ≥ ``LDR_SATURATION``) or
                at/above ``saturation_level`` in an EXR; more than ``MAX_SATURATED`` of the
                frame is an error, more than ``WARN_SATURATED`` a warning; the mask is kept
highlight       peak of a paraboloid fitted to the flash-only image's log luminance; when the
                fit explains at least ``HIGHLIGHT_MIN_R2`` of the variance, a peak farther than
                ``HIGHLIGHT_WARN`` half-widths from the centre, or no peak: a warning
field of view   ``fov`` in [``MIN_FOV``, ``MAX_FOV``] degrees (error outside); more than
                ``FOV_WARN`` degrees from the model's 45°: a warning
==============  ===============================================================================
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..colour import LUMINANCE
from ..errors import InputError
from ..geometry import NEAR_FOV
from ..imageio import EXR_SUFFIXES, HDR_SUFFIXES, IMAGE_SUFFIXES, box_mean, read_image, resize_area
from .resample import MIN_INPUT_SIZE

SHOT_NAMES = ("flash", "noflash", "far_flash", "far_noflash")
CAPTURE_JSON = "capture.json"  # the record 'ebr capture' writes beside its shots
CAPTURE_FORMAT = "ebr-capture/1"
DEFAULT_FOV = NEAR_FOV
MIN_FOV, MAX_FOV, FOV_WARN = 10.0, 120.0, 5.0
DEFAULT_MAX_SHIFT = 0.02  # fraction of the frame width
MIN_SHIFT_LIMIT = 2.0  # pixels: the shift limit never goes below this
LDR_SATURATION = 0.95  # linear value ≈ sRGB code 250/255
MAX_SATURATED, WARN_SATURATED = 0.5, 0.005
HIGHLIGHT_WARN = 0.5  # half-widths from the centre
HIGHLIGHT_MIN_R2 = 0.3  # below: the texture dominates the falloff, no verdict
PEAK_TIE = 0.8  # correlation peaks this close to the best count as ties
# A shift refuses the shots only when its peak is trusted (ShiftEstimate.confident): this far
# above any rival, or this many noise σ and this many times the best value near no shift.
MIN_PEAK_RATIO, MIN_PEAK_Z, MIN_ALIGNED_RATIO = 2.0, 10.0, 3.0
LOW_TEXTURE_NOISE = 0.5  # below: a shot's texture is lost in its noise (dark or noisy), said so
_ALIGN_SIZE = 256  # alignment is estimated on at most this many pixels per side

# EXIF tags (in the Exif IFD 0x8769).
_EXIF_IFD, _EXPOSURE_TIME, _FNUMBER, _ISO, _ORIENTATION = 0x8769, 0x829A, 0x829D, 0x8827, 0x0112


@dataclass
class Inputs:
    """The checked shots of one capture, at one exposure (that of the flash shot).

    ``images`` maps shot names (:data:`SHOT_NAMES`) to (H, W, 3) float32 arrays; ``saturated``
    is the (H, W) bool mask of pixels clipped in any shot; ``exposure`` per shot the factor
    applied and where it came from; ``shifts`` per pair the estimated (dy, dx) in pixels and
    ``alignment`` per pair that estimate with its confidence (:meth:`ShiftEstimate.to_json`);
    ``highlight`` the flash highlight's fit (:func:`highlight_position`); ``warnings`` the
    problems found that did not stop the estimate.
    """

    images: dict[str, np.ndarray]
    paths: dict[str, str]
    saturated: np.ndarray
    fov: float
    exposure: dict[str, dict] = field(default_factory=dict)
    shifts: dict[str, list[float]] = field(default_factory=dict)
    alignment: dict[str, dict] = field(default_factory=dict)
    highlight: dict | None = None
    source_size: tuple[int, int] = (0, 0)
    warnings: list[str] = field(default_factory=list)
    clip_level: float | None = None  # the flash shot's saturation level in these units (None: unknown)

    @property
    def size(self) -> tuple[int, int]:
        h, w = self.images["flash"].shape[:2]
        return int(h), int(w)

    @property
    def flash_only(self) -> bool:
        """True for a flash-only capture (no no-flash shot: no lighting estimation)."""
        return "noflash" not in self.images

    @property
    def has_far(self) -> bool:
        return "far_flash" in self.images

    def flash_only_image(self, far: bool = False) -> np.ndarray:
        """The image lit by the flash alone: flash − no-flash (≥ 0), or the flash shot itself in
        a flash-only capture; (H, W, 3)."""
        on, off = ("far_flash", "far_noflash") if far else ("flash", "noflash")
        if off not in self.images:
            return self.images[on]
        return np.maximum(self.images[on] - self.images[off], 0.0).astype(np.float32)

    def resampled(self, size: tuple[int, int]) -> Inputs:
        """These inputs area-resampled to ``size = (h, w)``; the saturation mask marks an output
        pixel whose footprint touches a saturated input pixel."""
        if tuple(size) == self.size:
            return self
        images = {k: resize_area(v, size) for k, v in self.images.items()}
        mask = resize_area(self.saturated.astype(np.float32)[..., None], size)[..., 0] > 0
        return replace(self, images=images, saturated=mask)

    def scaled(self, factor: float) -> Inputs:
        """The shots × ``factor`` (to the reference exposure: ``docs/conventions.md``, "Exposure")."""
        f = np.float32(factor)
        clip = None if self.clip_level is None else self.clip_level * float(factor)
        return replace(
            self, images={k: (v * f).astype(np.float32) for k, v in self.images.items()}, clip_level=clip
        )

    def to_json(self) -> dict:
        return {
            "paths": self.paths,
            "size": list(self.size),
            "source_size": list(self.source_size),
            "fov": self.fov,
            "flash_only": self.flash_only,
            "exposure": self.exposure,
            "shifts": self.shifts,
            "alignment": self.alignment,
            "highlight": self.highlight,
            "saturated_fraction": float(self.saturated.mean()),
            "warnings": list(self.warnings),
        }


# -- reading ----------------------------------------------------------------------------------------


def _rational(value) -> float | None:
    try:
        if isinstance(value, tuple):  # (numerator, denominator)
            value = value[0] / value[1]
        value = float(value[0] if isinstance(value, (list, tuple)) else value)
    except (TypeError, ValueError, ZeroDivisionError, IndexError):
        return None
    return value if math.isfinite(value) and value > 0 else None


def read_exif(path: str | Path) -> dict:
    """EXIF exposure time [s], ISO and f-number of a PNG/JPEG (keys present only when found),
    plus ``orientation`` (1 = upright) when tagged. EXR/HDR files carry none: ``{}``."""
    path = Path(path)
    if path.suffix.lower() in EXR_SUFFIXES + HDR_SUFFIXES:
        return {}
    from PIL import Image

    try:
        with Image.open(path) as im:
            exif = im.getexif()
    except (OSError, ValueError, SyntaxError):
        return {}  # the image reader reports unreadable files
    sub = exif.get_ifd(_EXIF_IFD)
    out = {}
    for key, tag in (("exposure_time", _EXPOSURE_TIME), ("f_number", _FNUMBER), ("iso", _ISO)):
        value = _rational(sub.get(tag, exif.get(tag)))
        if value is not None:
            out[key] = value
    if _ORIENTATION in exif:
        out["orientation"] = int(exif[_ORIENTATION])
    return out


def read_shot(path: str | Path, name: str) -> tuple[np.ndarray, float | None]:
    """One shot as linear (H, W, 3) float32 and the linear level at which it saturates (None:
    unknown, an EXR). Errors name ``--<name>`` and the file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise InputError(
            f"--{name.replace('_', '-')} {path}: unsupported image type "
            f"{suffix or '(no suffix)'!r}; use {', '.join(IMAGE_SUFFIXES)}"
        )
    image = read_image(path, "srgb")
    if image.shape[2] == 1:
        image = np.repeat(image, 3, axis=2)
    elif image.shape[2] != 3:
        raise InputError(f"{path}: has {image.shape[2]} channels; give an RGB or grey image")
    return np.ascontiguousarray(image, dtype=np.float32), (
        None if suffix in EXR_SUFFIXES + HDR_SUFFIXES else LDR_SATURATION
    )


# -- checks -----------------------------------------------------------------------------------------


def luminance(image: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance (H, W) of a linear (H, W, 3) image."""
    return image @ LUMINANCE.astype(np.float32)


def centre_crop(image: np.ndarray) -> np.ndarray:
    """The centred square of a (H, W, …) frame (the sample fills the square)."""
    h, w = image.shape[:2]
    s = min(h, w)
    i, j = (h - s) // 2, (w - s) // 2
    return image[i : i + s, j : j + s]


def _clip_level(levels: dict, default_level: float | None, exposure: dict) -> float | None:
    """The flash shot's saturation level after its exposure factor (None: not known)."""
    level = levels["flash"] if levels.get("flash") is not None else default_level
    return None if level is None else float(level) * float(exposure["flash"]["factor"])


def saturation_mask(images: dict[str, np.ndarray], levels: dict, default_level: float | None) -> np.ndarray:
    """(H, W) True where any shot reaches its saturation level (``levels[name]``, else
    ``default_level``; None: never saturated) in any channel, on the values as stored."""
    saturated = np.zeros(next(iter(images.values())).shape[:2], bool)
    for k, img in images.items():
        level = levels[k] if levels[k] is not None else default_level
        if level is not None:
            saturated |= np.any(img >= level, axis=-1)
    return saturated


def saturation_masks(images: dict[str, np.ndarray], levels: dict, default_level: float | None) -> dict:
    """:func:`saturation_mask` of each shot on its own: name → (H, W) bool."""
    return {k: saturation_mask({k: v}, {k: levels[k]}, default_level) for k, v in images.items()}


def check_saturation_level(level: float | None) -> None:
    """An :class:`InputError` unless ``level`` (``--saturation-level``) is None or finite and > 0."""
    if level is not None and not (math.isfinite(level) and level > 0):
        raise InputError(f"--saturation-level {level}: give a finite value > 0")


def clip_negatives(images: dict[str, np.ndarray], warnings: list[str]) -> None:
    """Negative pixel values set to 0 in place of each shot (a warning when they are more than
    rounding: below −1e-3 × the shot's maximum)."""
    for k, img in images.items():
        if float(img.min()) < 0:
            if float(img.min()) < -1e-3 * max(float(img.max()), 1e-12):
                warnings.append(f"{k}: negative pixel values clipped to 0")
            images[k] = np.maximum(img, 0.0)


def _blur3(a: np.ndarray) -> np.ndarray:
    """[1, 2, 1]/4 separable blur with edge replication."""
    p = np.pad(a, 1, mode="edge")
    a = (p[:-2] + 2 * p[1:-1] + p[2:]) / 4
    return (a[:, :-2] + 2 * a[:, 1:-1] + a[:, 2:]) / 4


_LAPLACE = ((1, -2, 1), (-2, 4, -2), (1, -2, 1))  # its response to white noise σ has std 6σ
_BLUR_NOISE = 70.0 / 256.0  # std factor of white noise through _blur3 twice (2-D)


def _log_luminance(img: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Log luminance at ``size`` with a floor of 1% of the mean (exposure-invariant)."""
    lum = resize_area(luminance(img)[..., None], size)[..., 0].astype(np.float64)
    return np.log(lum + 0.01 * max(float(lum.mean()), 0.0) + 1e-30)


def texture_to_noise(log_lum: np.ndarray) -> float:
    """How far the texture stands above the pixel noise in a log-luminance image (H, W): the RMS
    of its detail at the alignment's scale (blurred twice, minus a 1/16-width local mean) over
    that of white noise of the image's noise level (robust: median absolute Laplacian), minus the
    noise's own share; 0 for pure noise or a flat image, ≳ 1 where edges are visible."""
    h, w = log_lum.shape
    p = np.pad(log_lum, 1, mode="edge")
    lap = sum(k * p[i : i + h, j : j + w] for i, row in enumerate(_LAPLACE) for j, k in enumerate(row))
    noise = float(np.median(np.abs(lap))) / 0.6745 / 6.0
    smooth = _blur3(_blur3(log_lum))
    detail = float((smooth - box_mean(smooth, max(2, min(h, w) // 16))).std())
    ratio = detail / max(_BLUR_NOISE * noise, 1e-12)
    return float(math.sqrt(max(ratio * ratio - 1.0, 0.0)))


@dataclass(frozen=True)
class ShiftEstimate:
    """Translation of one shot against another and how far to trust it.

    ==================  ==========================================================================
    field               meaning
    ==================  ==========================================================================
    ``dy``, ``dx``      the shift in pixels of the full images
    ``peak_ratio``      the chosen correlation peak ÷ the highest value outside its 5×5
                        neighbourhood (≈ 1 for noise, flat or periodic textures)
    ``peak_z``          the peak in noise units (robust σ of the correlation surface: 1.4826 ×
                        median absolute deviation); noise alone reaches about 5
    ``aligned_z``       the highest value within ``limit`` pixels of no shift (outside the
                        peak's neighbourhood), in the same units: the support for "aligned"
    ``prominence``      the peak ÷ the RMS of the surface
    ``texture``         per image the texture-to-noise ratio (:func:`texture_to_noise`)
    ==================  ==========================================================================
    """

    dy: float
    dx: float
    peak_ratio: float
    peak_z: float
    aligned_z: float
    prominence: float
    texture: tuple[float, float]

    @property
    def distance(self) -> float:
        return math.hypot(self.dy, self.dx)

    @property
    def confident(self) -> bool:
        """Whether the peak can be trusted, so that a shift beyond the limit may refuse the shots:
        one distinct peak (``peak_ratio`` ≥ ``MIN_PEAK_RATIO``), or a strong one (``peak_z`` ≥
        ``MIN_PEAK_Z``) far above anything near no shift (≥ ``MIN_ALIGNED_RATIO`` × ``aligned_z``;
        a periodic texture repeats its peak a period away, but not near zero). Dark, noisy, flat
        shots and lighting-dependent patterns give neither: on 96 aligned synthetic captures
        (64²–128², 16–128 spp, night to studio maps) ratios stayed ≤ 1.5 and the one ``peak_z``
        above 10 had an ``aligned_z`` of 9."""
        if self.peak_ratio >= MIN_PEAK_RATIO:
            return True
        return self.peak_z >= MIN_PEAK_Z and self.peak_z >= MIN_ALIGNED_RATIO * max(self.aligned_z, 1.0)

    def describe(self) -> str:
        return (
            f"peak ratio {self.peak_ratio:.2f} (trusted from {MIN_PEAK_RATIO:g}), peak "
            f"{self.peak_z:.1f}σ vs {self.aligned_z:.1f}σ near no shift, texture-to-noise "
            f"{self.texture[0]:.2f} / {self.texture[1]:.2f}"
        )

    def to_json(self) -> dict:
        return {
            "dy": self.dy,
            "dx": self.dx,
            "peak_ratio": round(self.peak_ratio, 3),
            "peak_z": round(self.peak_z, 2),
            "aligned_z": round(self.aligned_z, 2),
            "prominence": round(self.prominence, 2),
            "texture_to_noise": [round(t, 3) for t in self.texture],
            "confident": self.confident,
        }


def estimate_shift(a: np.ndarray, b: np.ndarray, limit: float = MIN_SHIFT_LIMIT) -> ShiftEstimate:
    """Translation (dy, dx) in pixels of ``b`` relative to ``a`` (both (H, W, 3), same size) and
    its confidence (:class:`ShiftEstimate`; ``limit``: the radius in pixels counted as aligned).

    Phase correlation of the log-luminance gradients, which survive the change of lighting
    between a flash and a no-flash shot. Every frequency counts alike, so in a dark or noisy shot
    the peak drowns in noise and rivals of nearly its height appear elsewhere: the confidence
    says so (:attr:`ShiftEstimate.confident`)."""
    h, w = a.shape[:2]
    scale = max(1, int(math.ceil(max(h, w) / _ALIGN_SIZE)))
    size = (max(8, h // scale), max(8, w // scale))
    logs = [_log_luminance(img, size) for img in (a, b)]
    win = np.outer(np.hanning(size[0]), np.hanning(size[1]))

    def features(lum):
        lum = _blur3(_blur3(lum))  # suppress pixel noise (render noise, sensor noise, JPEG blocks)
        gy, gx = np.gradient(lum)
        return (gx - gx.mean() + 1j * (gy - gy.mean())) * win

    # The signed gradient of log luminance is the albedo's edge pattern, unchanged by smooth
    # changes of lighting; as one complex field it keeps the edge polarity (half the ambiguity
    # of gradient magnitudes on periodic textures).
    fa, fb = np.fft.fft2(features(logs[0])), np.fft.fft2(features(logs[1]))
    cross = fb * np.conj(fa)
    corr = np.real(np.fft.ifft2(cross / (np.abs(cross) + 1e-12)))
    # Signed shift of every cell; among the peaks (local maxima, cyclic 3×3) within PEAK_TIE of
    # the best (periodic textures such as a checkerboard correlate equally at every period), the
    # smallest shift wins.
    sy_all = np.where(np.arange(size[0]) > size[0] // 2, np.arange(size[0]) - size[0], np.arange(size[0]))
    sx_all = np.where(np.arange(size[1]) > size[1] // 2, np.arange(size[1]) - size[1], np.arange(size[1]))
    neighbours = np.max(
        [np.roll(corr, (u, v), axis=(0, 1)) for u in (-1, 0, 1) for v in (-1, 0, 1) if u or v], axis=0
    )
    cand = np.argwhere((corr >= PEAK_TIE * corr.max()) & (corr >= neighbours))
    dist = np.hypot(sy_all[cand[:, 0]], sx_all[cand[:, 1]])
    i, j = cand[int(np.argmin(dist))]
    dy, dx = int(sy_all[i]), int(sx_all[j])
    # Confidence: the peak against its best rival outside its 5×5 neighbourhood (cyclic), and in
    # noise units against the best value within ``limit`` of no shift.
    ry = np.abs((sy_all - dy + size[0] // 2) % size[0] - size[0] // 2)
    rx = np.abs((sx_all - dx + size[1] // 2) % size[1] - size[1] // 2)
    outside = (ry[:, None] > 2) | (rx[None, :] > 2)
    peak = float(corr[i, j])
    rival = float(corr[outside].max())
    peak_ratio = peak / rival if rival > 0 else float("inf")
    sy, sx = h / size[0], w / size[1]
    near = np.hypot(sy_all[:, None] * sy, sx_all[None, :] * sx) <= limit
    med = float(np.median(corr))
    sigma = 1.4826 * float(np.median(np.abs(corr - med))) + 1e-12
    aligned = corr[near & outside]
    aligned_z = (float(aligned.max()) - med) / sigma if aligned.size else 0.0
    prominence = float(corr.max() / (corr.std() + 1e-12))
    return ShiftEstimate(
        float(dy * sy),
        float(dx * sx),
        float(peak_ratio),
        (peak - med) / sigma,
        aligned_z,
        prominence,
        (texture_to_noise(logs[0]), texture_to_noise(logs[1])),
    )


def highlight_position(flash_only: np.ndarray) -> dict:
    """Centre of the flash lobe: the peak of a paraboloid fitted to the log luminance of the
    flash-only image on a 16×16 grid. Returns {"position": [x, y] in half-widths from the frame
    centre (x right, y up), or None when the fit has no maximum; "fit_r2": the share of the log
    luminance variance the fit explains}. Below ``HIGHLIGHT_MIN_R2`` the texture dominates the
    falloff and the position means little."""
    n = 16
    lum = resize_area(luminance(flash_only)[..., None], (n, n))[..., 0]
    if not np.any(lum > 0):
        return {"position": None, "fit_r2": 0.0}
    logl = np.log(np.maximum(lum, lum[lum > 0].min() * 0.5)).reshape(-1)
    c = (np.arange(n) + 0.5) / n * 2 - 1
    x, y = np.meshgrid(c, -c)
    design = np.stack([np.ones_like(x), x, y, x * x + y * y], axis=-1).reshape(-1, 4)
    coef, *_ = np.linalg.lstsq(design, logl, rcond=None)
    var = float(logl.var())
    r2 = float(1 - (logl - design @ coef).var() / var) if var > 0 else 0.0
    if coef[3] >= -1e-3:
        return {"position": None, "fit_r2": r2}
    return {"position": [float(-coef[1] / (2 * coef[3])), float(-coef[2] / (2 * coef[3]))], "fit_r2": r2}


def _check_pair(
    images, on: str, off: str, max_shift: float, warnings: list[str], paths, exposure: dict | None = None
) -> ShiftEstimate:
    a, b = images[on], images[off]
    mean_on, mean_off = float(luminance(a).mean()), float(luminance(b).mean())
    if mean_on <= mean_off:
        sources = {(exposure or {}).get(k, {}).get("source") for k in (on, off)}
        hint = "swapped files, or the flash did not fire"
        if sources <= {"assumed equal", None}:  # no EXIF and no --exposure-ratio
            hint += (
                f", or the no-flash shot was exposed longer: without EXIF exposure give "
                f"--exposure-ratio R (no-flash exposure ÷ flash exposure; here R > "
                f"{mean_off / max(mean_on, 1e-30):.3g} for the flash shot to be the brighter)"
            )
        raise InputError(
            f"--{on.replace('_', '-')} {paths[on]} is not brighter than "
            f"--{off.replace('_', '-')} {paths[off]} (mean {mean_on:.4g} vs {mean_off:.4g} at "
            f"one exposure); {hint}"
        )
    limit = max(max_shift * a.shape[1], MIN_SHIFT_LIMIT)
    est = estimate_shift(a, b, limit)
    dy, dx = est.dy, est.dx
    dist = est.distance
    if dist > limit and est.confident:
        raise InputError(
            f"--{off.replace('_', '-')} {paths[off]} is shifted by ({dx:+.0f}, {dy:+.0f}) pixels "
            f"against {paths[on]} (limit {limit:.1f} px: --max-shift {max_shift} x width, "
            f"at least {MIN_SHIFT_LIMIT:g}; {est.describe()}); "
            f"align the shots or use a tripod"
        )
    if dist > 1.0 and not est.confident:
        dark = f"; the {off} shot is dark or noisy" if est.texture[1] < LOW_TEXTURE_NOISE else ""
        warnings.append(
            f"{on}/{off}: alignment could not be verified (best guess ({dx:+.0f}, {dy:+.0f}) px, "
            f"low confidence: {est.describe()}{dark}); keep the camera still between the shots"
        )
    elif dist > 1.0:
        warnings.append(
            f"{on}/{off}: shots are offset by ({dx:+.1f}, {dy:+.1f}) pixels; the estimate "
            f"blurs detail of that size"
        )
    elif est.prominence < 5.0:
        warnings.append(
            f"{on}/{off}: alignment could not be verified (flat texture); keep the camera "
            f"still between the shots"
        )
    return est


def _exposures(
    raw_paths: dict[str, str], exposure_ratio: float | None, ldr: bool, warnings: list[str]
) -> dict[str, dict]:
    """Per shot: the factor bringing it to the flash shot's exposure and its source."""
    exif = {k: read_exif(p) for k, p in raw_paths.items()}
    for k, e in exif.items():
        if e.get("orientation", 1) != 1:
            warnings.append(
                f"{k}: EXIF orientation {e['orientation']} is ignored; the image is used as "
                f"stored (rotate it upright if the maps look turned)"
            )
    complete = all({"exposure_time", "iso", "f_number"} <= set(e) for e in exif.values())
    out = {}
    if exposure_ratio is not None:
        if complete and len(exif) > 1:
            warnings.append("--exposure-ratio overrides the EXIF exposure of the shots")
        for k in raw_paths:
            factor = 1.0 / exposure_ratio if "noflash" in k else 1.0
            out[k] = {"factor": factor, "source": "--exposure-ratio"}
        return out
    if complete and len(exif) > 1:
        h = {k: e["exposure_time"] * e["iso"] / e["f_number"] ** 2 for k, e in exif.items()}
        for k in raw_paths:
            out[k] = {"factor": h["flash"] / h[k], "source": "exif", **exif[k]}
        return out
    if ldr and len(raw_paths) > 1:
        warnings.append("no EXIF exposure in the photos and no --exposure-ratio: equal exposure assumed")
    return {k: {"factor": 1.0, "source": "assumed equal"} for k in raw_paths}


def check_fov(fov: float) -> float:
    fov = float(fov)
    if not (math.isfinite(fov) and MIN_FOV <= fov <= MAX_FOV):
        raise InputError(
            f"--fov {fov}: the horizontal field of view must be in [{MIN_FOV:g}, {MAX_FOV:g}] "
            f"degrees (45 for the capture guide's framing)"
        )
    return fov


def load_inputs(
    flash,
    noflash=None,
    far_flash=None,
    far_noflash=None,
    *,
    exposure_ratio: float | None = None,
    fov: float = DEFAULT_FOV,
    max_shift: float = DEFAULT_MAX_SHIFT,
    saturation_level: float | None = None,
    progress=None,
) -> Inputs:
    """Read, exposure-match and check the shots of a capture (see the module docstring).

    Paths may be ``str`` or ``Path``; ``noflash=None`` is a flash-only capture. Raises
    :class:`InputError` (one line) for every refused input; warnings go into ``Inputs.warnings``.
    ``progress(done, total, what)``: after each shot is read and after the checks.
    """
    report = progress or (lambda done, total, what: None)
    fov = check_fov(fov)
    if not (math.isfinite(max_shift) and 0 <= max_shift <= 0.5):
        raise InputError(f"--max-shift {max_shift}: give a fraction of the width in [0, 0.5]")
    if exposure_ratio is not None and not (math.isfinite(exposure_ratio) and exposure_ratio > 0):
        raise InputError(
            f"--exposure-ratio {exposure_ratio}: give a finite value > 0 (no-flash exposure ÷ flash exposure)"
        )
    check_saturation_level(saturation_level)
    check_shot_flags(flash, noflash, far_flash, far_noflash, exposure_ratio)
    raw_paths = {
        k: str(p) for k, p in zip(SHOT_NAMES, (flash, noflash, far_flash, far_noflash)) if p is not None
    }
    warnings: list[str] = []
    images, levels = {}, {}
    total = len(raw_paths) + 1
    for i, (k, p) in enumerate(raw_paths.items()):
        report(i, total, f"reading {k}")
        images[k], levels[k] = read_shot(p, k)
    report(len(raw_paths), total, "checks")
    shapes = {k: v.shape[:2] for k, v in images.items()}
    if len(set(shapes.values())) > 1:
        desc = ", ".join(f"{raw_paths[k]} is {s[1]}x{s[0]}" for k, s in shapes.items())
        raise InputError(f"shots differ in size ({desc}); give shots of one size from one camera")
    source_size = shapes["flash"]
    if min(source_size) < MIN_INPUT_SIZE:
        raise InputError(
            f"{raw_paths['flash']} is {source_size[1]}x{source_size[0]} pixels; ebr estimate needs at "
            f"least {MIN_INPUT_SIZE} pixels on the shorter side (the sample should fill the frame)"
        )
    if source_size[0] != source_size[1]:
        warnings.append(
            f"frame {source_size[1]}x{source_size[0]} is not square: centre-cropped to the sample square"
        )
        images = {k: np.ascontiguousarray(centre_crop(v)) for k, v in images.items()}

    # Saturation, on the values as stored (before exposure scaling).
    saturated = saturation_mask(images, levels, saturation_level)
    frac = float(saturated.mean())
    if frac > MAX_SATURATED:
        raise InputError(
            f"{frac:.0%} of the pixels are saturated (clipped) in {raw_paths['flash']}"
            f"{' or its pair' if len(images) > 1 else ''}; lower the exposure and retake"
        )
    if frac > WARN_SATURATED:
        warnings.append(
            f"{frac:.1%} of the pixels are saturated; they are left out of the refinement and the errors"
        )
    clip_negatives(images, warnings)

    ldr = any(levels[k] is not None for k in images)
    exposure = _exposures(raw_paths, exposure_ratio, ldr, warnings)
    images = {k: (v * np.float32(exposure[k]["factor"])).astype(np.float32) for k, v in images.items()}

    inputs = Inputs(
        images=images,
        paths=raw_paths,
        saturated=saturated,
        fov=fov,
        exposure=exposure,
        source_size=(int(source_size[0]), int(source_size[1])),
        warnings=warnings,
        clip_level=_clip_level(levels, saturation_level, exposure),
    )
    if abs(fov - NEAR_FOV) > FOV_WARN:
        warnings.append(
            f"--fov {fov:g}: the network was trained at {NEAR_FOV:g} degrees; expect a bias in "
            f"normals and roughness"
        )
    pairs = ([("near", "flash", "noflash")] if not inputs.flash_only else []) + (
        [("far", "far_flash", "far_noflash")] if inputs.has_far else []
    )
    for pair, on, off in pairs:
        est = _check_pair(images, on, off, max_shift, warnings, raw_paths, exposure)
        inputs.shifts[pair] = [est.dy, est.dx]
        inputs.alignment[pair] = est.to_json()
    inputs.highlight = highlight_position(inputs.flash_only_image())
    pos, r2 = inputs.highlight["position"], inputs.highlight["fit_r2"]
    if r2 < HIGHLIGHT_MIN_R2:
        pass  # texture dominates the falloff: no verdict (the report says so)
    elif pos is None:
        warnings.append(
            "no flash highlight found in the flash shot; the flash should sit beside the lens "
            "and the camera face the sample"
        )
    elif math.hypot(*pos) > HIGHLIGHT_WARN:
        warnings.append(
            f"the flash highlight is off centre (x {pos[0]:+.2f}, y {pos[1]:+.2f} half-widths); hold "
            f"the phone parallel to the sample"
        )
    report(total, total, "done")
    return inputs


def check_shot_flags(flash, noflash, far_flash, far_noflash, exposure_ratio=None) -> None:
    """Refuse conflicting combinations of shot options before anything is read."""
    if flash is None:
        raise InputError("--flash is required: the photo taken with the flash")
    if (far_flash is None) != (far_noflash is None):
        given = "--far-flash" if far_flash is not None else "--far-noflash"
        missing = "--far-noflash" if far_flash is not None else "--far-flash"
        raise InputError(f"{given} needs {missing}: the far pair comes as two shots")
    if far_flash is not None and noflash is None:
        raise InputError("--far-flash/--far-noflash need --noflash: a flash-only capture is one near shot")
    if noflash is None and exposure_ratio is not None:
        raise InputError("--exposure-ratio needs --noflash: it scales the no-flash shots")
    given = [str(Path(p).resolve()) for p in (flash, noflash, far_flash, far_noflash) if p is not None]
    if len(set(given)) != len(given):
        raise InputError("the same file is given for two shots; give one file per shot")


def read_shots_of_one_size(
    shots: list[tuple[str, str]], flag: str, one_size: str, small: str = ""
) -> tuple[dict[str, np.ndarray], dict[str, float | None], tuple[int, int]]:
    """The ``(name, path)`` shots of a capture read in order (:func:`read_shot`, errors naming
    ``--flag``): images and saturation levels by name, and their (h, w). An :class:`InputError`
    ``--flag: …`` when a shot's size differs from the first's (ending in the advice ``one_size``) or
    the shorter side is under :data:`MIN_INPUT_SIZE` pixels (followed by ``small``)."""
    images, levels = {}, {}
    for name, path in shots:
        images[name], levels[name] = read_shot(path, flag)
    first_path = shots[0][1]
    h, w = images[shots[0][0]].shape[:2]
    for name, path in shots:
        hk, wk = images[name].shape[:2]
        if (hk, wk) != (h, w):
            raise InputError(f"--{flag}: {path} is {wk}x{hk} but {first_path} is {w}x{h}; {one_size}")
    if min(h, w) < MIN_INPUT_SIZE:
        raise InputError(
            f"--{flag}: {first_path} is {w}x{h} pixels; ebr estimate needs at least {MIN_INPUT_SIZE} "
            f"pixels on the shorter side{small}"
        )
    return images, levels, (h, w)


def read_capture_record(
    path: Path,
    unreadable: str,
    foreign: str,
    fmt: str = CAPTURE_FORMAT,
    what: str = "an 'ebr capture' record",
) -> dict:
    """The ``ebr capture`` record (``capture.json``) at ``path`` — or another JSON record of format
    ``fmt`` (``what`` it is, for the message); an :class:`InputError` naming it when it is not
    readable JSON (advice ``unreadable``) or not such a record (advice ``foreign``)."""
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not readable JSON ({str(exc)[:80]}); {unreadable}") from None
    if not isinstance(meta, dict) or meta.get("format") != fmt:
        raise InputError(f"{path}: not {what} (no format '{fmt}'); {foreign}")
    return meta


def capture_vector(value, where: str, fix: str = "") -> tuple[float, float, float]:
    """``value`` (a position or direction of a capture record) as three finite floats; an
    :class:`InputError` at ``where`` otherwise, ending in the advice ``fix`` when given."""
    try:
        v = tuple(float(c) for c in value)
    except (TypeError, ValueError):
        v = ()
    if len(v) != 3 or not all(math.isfinite(c) for c in v):
        advice = f"; {fix}" if fix else ""
        raise InputError(f"{where}: expected [x, y, z], got {value!r}{advice}")
    return v


__all__ = [
    "CAPTURE_FORMAT",
    "CAPTURE_JSON",
    "capture_vector",
    "read_capture_record",
    "read_shots_of_one_size",
    "Inputs",
    "centre_crop",
    "clip_negatives",
    "saturation_mask",
    "saturation_masks",
    "check_saturation_level",
    "SHOT_NAMES",
    "DEFAULT_FOV",
    "DEFAULT_MAX_SHIFT",
    "load_inputs",
    "read_shot",
    "read_exif",
    "estimate_shift",
    "ShiftEstimate",
    "texture_to_noise",
    "highlight_position",
    "luminance",
    "check_fov",
    "check_shot_flags",
]
