"""The five-light estimate (``ebr estimate --lights``): five photos from one fixed camera, each lit
by one point light at a known position, in; SVBRDF maps, re-renders and a report out.

The network is the dual-loss estimator (:class:`ebr_mitsuba.nets.DualLossNet`, a checkpoint of
``ebr train`` with ``kind = "dualloss"``). :func:`run_fivelight` writes the same kind of output
directory as :func:`ebr_mitsuba.estimate.pipeline.run_estimate`, with the same writers
(:mod:`.outputs`, :mod:`.report`) and the same atomic directory: complete or not at all, an
earlier estimate directory replaced, anything else refused.

**Inputs** (``lights``, :func:`resolve_lights`):

==========================  ====================================================================
given                       light positions (and intensities)
==========================  ====================================================================
one directory with          the shot records of ``capture.json`` (``ebr capture --setup
``capture.json``            five-light``): for each of its five shots the file, the light
                            position (``flash``), its intensity (``flash_intensity``), the camera
                            and field of view; the photos in the record order
one directory without it    ``light0`` … ``light4`` (``.exr``, ``.png``, ``.jpg``, …) in it, at
                            the positions of :data:`ebr_mitsuba.geometry.FIVE_LIGHT_POSITIONS`
five photo files            a five-light ``capture.json`` beside the first one when it names all
                            five files (the photos then in its order); otherwise the files in
                            the order given, at :data:`~ebr_mitsuba.geometry.FIVE_LIGHT_POSITIONS`
==========================  ====================================================================

The camera is the near camera of ``docs/conventions.md`` ("Geometry"): at (0, 0, 2.414), 45°,
the frame exactly the sample square. Refused with one line (exit 2) and nothing written: another
count than five, a missing or unreadable file, the same file twice, photos of different sizes or
under 32 pixels, a ``capture.json`` of another setup in a directory, a shot record without a
light position (or one not above the sample), a camera that does not frame the sample square,
more than half of the pixels saturated, a checkpoint of another kind or light count, and no
checkpoint while no dual-loss model is shipped (:func:`model_path`).

**Exposure.** The photos are brought to the first one's exposure by their EXIF exposure (time ×
ISO / f-number², when every photo has it; else equal exposure, a warning for PNG/JPEG). The
network was trained at the *reference exposure* (``docs/conventions.md``, "Exposure": a pixel
value is radiance with each light at :data:`~ebr_mitsuba.geometry.DEFAULT_FLASH_INTENSITY`):
when the lights' intensities in photo units are known (``light_intensity``, else
``capture.json``), photo k is multiplied by ``DEFAULT_FLASH_INTENSITY / I_k`` before the network
sees it; else the photos are taken as they are and one intensity for all five lights is fitted
by least squares of the maps' renders to the photos (``"source": "fitted"``). Everything written
is in the photos' units.

**Resolution.** The working size follows :func:`.resample.working_size` (the model grid for
photos up to it, the photos' size up to ``max_size``, ``max_size`` above it with a warning). The
network runs at its grid (the photos area-averaged to it, its maps area-resampled to the working
size): run on a 256² capture, the 128² shipped model saw the sample at twice the scale it was
trained at, and its maps were twice as far off (mean per-map RMSE 0.1375 against 0.0659 on the
five-light test split, ``docs/fivelight.md``). The photometric fit runs at the working size.

**The fit** (default; ``--no-flash-fit``: the network's maps). After the network, the photos
themselves are fitted (:mod:`.photometric`): the photo of the light at the camera is a flash-only
image, so the flash-profile fit of the flash / no-flash estimate reads the roughness and
specular F₀ off it; photometric stereo over the five photos, minus that lobe, gives the normal and
the albedo of every pixel; the roughness is then refined by the five photos' residual. Scored
against the network alone in ``docs/fivelight.md``.

**Checks in the report.** Saturation (as :mod:`.inputs`), and the highlight of the light at the
camera (light 0 of the five-light setup) as the flash highlight of a flash/no-flash capture. Light
positions more than :data:`POSITION_WARN` from those the model was trained with are a warning.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import InputError
from ..fsutil import atomic_dir
from ..geometry import DEFAULT_FLASH_INTENSITY, FIVE_LIGHT_POSITIONS, NEAR_DISTANCE, NEAR_FOV, Shot
from ..imageio import IMAGE_SUFFIXES, resize_area
from ..materials import resample_svbrdf
from ..svbrdf import SVBRDF
from ..typedconfig import config, option
from . import outputs
from .inputs import (
    CAPTURE_JSON,
    HIGHLIGHT_MIN_R2,
    HIGHLIGHT_WARN,
    MAX_SATURATED,
    WARN_SATURATED,
    capture_vector,
    centre_crop,
    check_saturation_level,
    clip_negatives,
    highlight_position,
    read_capture_record,
    read_exif,
    read_shots_of_one_size,
    saturation_masks,
)
from .options import (
    checkpoint_option,
    flash_fit_option,
    intensity_option,
    max_size_option,
    out_option,
    saturation_option,
)
from .resample import model_grid, working_size

LIGHT_COUNT = 5
LIGHT_NAMES = tuple(f"light{k}" for k in range(LIGHT_COUNT))
SETUP = "five-light"
SHIPPED_DUALLOSS_MODEL = "dualloss_small.pt"
POSITION_WARN = 0.05  # world units (the sample is 2 wide) from the training light positions
_FIX = "give five photos (one per light) or a directory of 'ebr capture --setup five-light'"


@config(error=InputError, cli=True)
class FiveLightConfig:
    """Everything a five-light estimate needs: the options of ``ebr estimate --lights`` (flags,
    defaults and help generated from these fields; ``--out``, ``--checkpoint``,
    ``--flash-intensity``, ``--saturation-level`` and ``--max-size`` are the flags of the same
    :class:`~ebr_mitsuba.estimate.pipeline.EstimateConfig` fields). ``lights``: five photo paths
    or one directory (module docstring)."""

    lights: tuple[str, ...] = option(
        meaning="five photos lit by five known point lights (light0..light4), or one directory of "
        "'ebr capture --setup five-light'; instead of --flash",
        flag="--lights",
        metavar="L",
        nargs="+",
    )
    out: str = out_option()
    checkpoint: str | None = checkpoint_option("dual-loss model checkpoint", "the shipped model")
    light_intensity: float | None = intensity_option(
        "the intensity of every light in W/sr at the photos' exposure"
    )
    saturation_level: float | None = saturation_option()
    max_size: int = max_size_option("larger photos are downsampled to it")
    flash_fit: bool = flash_fit_option(
        "normals and albedo by photometric stereo, roughness and specular from the light at the "
        "camera (estimate/photometric.py); --no-flash-fit keeps the network's maps"
    )


FIVELIGHT_FLAGS = tuple(f.name for f in dataclasses.fields(FiveLightConfig))  # all set by flags


@dataclass(frozen=True)
class LightShot:
    """One photo of a five-light capture: its file, its light and the camera."""

    name: str
    path: str
    position: tuple[float, float, float]
    intensity: float | None = None  # W/sr in photo units; None: unknown
    camera: tuple[float, float, float] = (0.0, 0.0, NEAR_DISTANCE)
    fov: float = NEAR_FOV

    def shot(self, intensity: float) -> Shot:
        """The fast renderer's shot: this light alone (no environment) at ``intensity``."""
        return Shot(self.name, self.camera, self.fov, self.position, float(intensity), env=False)


@dataclass(frozen=True)
class LightSetup:
    """The five shots in the network's order and where their geometry came from."""

    shots: tuple[LightShot, ...]
    geometry: str


# -- the model --------------------------------------------------------------------------------------


def shipped_model_path() -> Path:
    """Where a shipped dual-loss model lives (:mod:`ebr_mitsuba.models`; it may be absent)."""
    return Path(str(resources.files("ebr_mitsuba.models").joinpath(SHIPPED_DUALLOSS_MODEL)))


def model_path(checkpoint: str | None) -> Path:
    """``checkpoint``, or the shipped dual-loss model; :class:`InputError` when neither exists."""
    if checkpoint is not None:
        path = Path(checkpoint)
        if not path.is_file():
            raise InputError(
                f"--checkpoint {checkpoint}: no such file; give a checkpoint of 'ebr train' "
                f'with kind = "dualloss"'
            )
        return path
    path = shipped_model_path()
    if not path.is_file():
        raise InputError(
            "--lights needs a five-light (dual-loss) model and none is shipped with this installation; "
            "pass --checkpoint RUN/model.pt (from 'ebr train' with kind = \"dualloss\", e.g. "
            "configs/dualloss.toml)"
        )
    return path


def load_dualloss(path: str | Path):
    """The dual-loss model in ``path`` (networks in eval mode); refuses other kinds and nets that
    do not read five images."""
    from ..model.predict import load_model

    bundle = load_model(path, expect_kind="dualloss")
    n = bundle.dualloss.config.num_lights
    if n != LIGHT_COUNT:
        raise InputError(f"{path}: a dual-loss model of {n} lights; --lights needs one of {LIGHT_COUNT}")
    return bundle


def predict(bundle, images: list[np.ndarray]) -> SVBRDF:
    """The network's maps for five (H, W, 3) photos at the reference exposure, in light order
    (the model's :class:`~ebr_mitsuba.model.predict.DualLossPredictor`)."""
    from ..model.predict import DualLossPredictor

    maps = DualLossPredictor(bundle).predict_lights(images).maps
    return dataclasses.replace(maps, source="ebr estimate --lights (dual-loss network)")


# -- the light geometry ------------------------------------------------------------------------------


def read_capture_json(path: Path) -> dict:
    """The ``capture.json`` at ``path`` (an ``ebr capture`` record); :class:`InputError` naming
    it when it is unreadable or foreign."""
    return read_capture_record(path, "fix or remove it", "fix or remove it")


def _shots_from_capture(meta: dict, where: Path, folder: Path) -> list[LightShot]:
    """The shot records of a five-light ``capture.json`` as :class:`LightShot`s, in record order."""
    records = meta.get("shots")
    if not isinstance(records, list) or len(records) != LIGHT_COUNT:
        n = len(records) if isinstance(records, list) else 0
        raise InputError(f"{where}: {n} shot records; a five-light capture has {LIGHT_COUNT}")
    shots = []
    for k, rec in enumerate(records):
        if not isinstance(rec, dict) or not isinstance(rec.get("file"), str):
            raise InputError(f"{where}: shot record {k} has no 'file'; fix or remove {CAPTURE_JSON}")
        name = str(rec.get("name") or f"light{k}")
        if rec.get("flash") is None:
            raise InputError(
                f"{where}: shot {name} has no light position ('flash': [x, y, z]); add it, or remove "
                f"{CAPTURE_JSON} to use the default five-light geometry"
            )
        position = capture_vector(rec["flash"], f"{where}: shot {name} light position")
        if position[2] <= 0:
            raise InputError(
                f"{where}: shot {name} light position {list(position)} is not above the "
                f"sample (z must be > 0)"
            )
        camera = capture_vector(rec.get("camera", [0.0, 0.0, NEAR_DISTANCE]), f"{where}: shot {name} camera")
        fov = float(rec.get("fov", NEAR_FOV))
        intensity = rec.get("flash_intensity")
        intensity = float(intensity) if isinstance(intensity, (int, float)) else None
        if intensity is not None and not (math.isfinite(intensity) and intensity > 0):
            raise InputError(f"{where}: shot {name} flash_intensity {intensity}: give a finite value > 0")
        shot = LightShot(name, str(folder / rec["file"]), position, intensity, camera, fov)
        if not shot.shot(1.0).in_sample_grid():
            raise InputError(
                f"{where}: shot {name}'s camera does not frame the sample square; a "
                f"five-light estimate needs the near camera of docs/conventions.md"
            )
        shots.append(shot)
    return shots


def _default_shots(paths: list[str]) -> list[LightShot]:
    return [LightShot(name, p, pos) for name, p, pos in zip(LIGHT_NAMES, paths, FIVE_LIGHT_POSITIONS)]


def _find_in_dir(folder: Path) -> list[str]:
    found = []
    for name in LIGHT_NAMES:
        hits = sorted(p for p in folder.iterdir() if p.stem == name and p.suffix.lower() in IMAGE_SUFFIXES)
        if len(hits) != 1:
            what = "no" if not hits else f"{len(hits)} ({', '.join(p.name for p in hits)})"
            raise InputError(
                f"--lights {folder}: no {CAPTURE_JSON} and {what} {name} photo ({name}.exr, .png, .jpg); "
                f"{_FIX}"
            )
        found.append(str(hits[0]))
    return found


def resolve_lights(lights) -> tuple[LightSetup, list[str]]:
    """The five shots of ``lights`` (module docstring, "Inputs") and warnings about them."""
    paths = [str(p) for p in lights]
    warnings: list[str] = []
    if len(paths) == 1 and Path(paths[0]).is_dir():
        folder = Path(paths[0])
        meta_path = folder / CAPTURE_JSON
        if meta_path.is_file():
            meta = read_capture_json(meta_path)
            if meta.get("setup") != SETUP:
                raise InputError(
                    f"{meta_path}: a '{meta.get('setup')}' capture; --lights needs a five-light one "
                    f"(for a flash/no-flash capture use --flash and --noflash)"
                )
            setup = LightSetup(tuple(_shots_from_capture(meta, meta_path, folder)), str(meta_path))
        else:
            setup = LightSetup(tuple(_default_shots(_find_in_dir(folder))), "default five-light geometry")
    elif len(paths) == LIGHT_COUNT:
        setup = _from_files(paths, warnings)
    else:
        raise InputError(
            f"--lights: {len(paths)} path{'s' if len(paths) != 1 else ''} given; give five photos (one per "
            f"light, light0 … light4) or one directory of 'ebr capture --setup five-light'"
        )
    for shot in setup.shots:
        p = Path(shot.path)
        if p.is_dir():
            raise InputError(f"--lights {p}: a directory; {_FIX}")
        if not p.is_file():
            raise InputError(f"--lights {p}: no such file; {_FIX}")
    resolved = [str(Path(s.path).resolve()) for s in setup.shots]
    if len(set(resolved)) != len(resolved):
        raise InputError("--lights: the same file is given for two lights; give one photo per light")
    for k, shot in enumerate(setup.shots):
        d = math.dist(shot.position, FIVE_LIGHT_POSITIONS[k])
        if d > POSITION_WARN:
            warnings.append(
                f"{shot.name}: light at {list(shot.position)}, {d:.2f} from the position the model was "
                f"trained with ({list(FIVE_LIGHT_POSITIONS[k])}); expect a bias"
            )
    return setup, warnings


def _from_files(paths: list[str], warnings: list[str]) -> LightSetup:
    meta_path = Path(paths[0]).resolve().parent / CAPTURE_JSON
    if not meta_path.is_file():
        return LightSetup(tuple(_default_shots(paths)), "default five-light geometry")
    meta = read_capture_json(meta_path)
    if meta.get("setup") != SETUP:
        warnings.append(
            f"{meta_path} is a '{meta.get('setup')}' capture: ignored, the default five-light geometry used"
        )
        return LightSetup(tuple(_default_shots(paths)), "default five-light geometry")
    shots = _shots_from_capture(meta, meta_path, meta_path.parent)
    by_file = {Path(s.path).name: s for s in shots}
    given = {Path(p).name: p for p in paths}
    if len(given) != len(paths):
        raise InputError(
            f"--lights: two photos share a file name; {meta_path} names each light's photo by "
            f"its file name, so give the five photos of that capture"
        )
    missing = [name for name in given if name not in by_file]
    if missing:
        raise InputError(
            f"{meta_path}: names no light position for {missing[0]}; give the photos of that capture, "
            f"or move the photos away from it to use the default five-light geometry"
        )
    ordered = [
        LightShot(s.name, given[Path(s.path).name], s.position, s.intensity, s.camera, s.fov) for s in shots
    ]
    if [Path(s.path).name for s in ordered] != list(given):
        warnings.append(f"the photos are used in the light order of {meta_path}, not in the order given")
    return LightSetup(tuple(ordered), str(meta_path))


# -- the photos ---------------------------------------------------------------------------------------


@dataclass
class LightPhotos:
    """The five photos at the first one's exposure, (H, W, 3) float32 each, square; ``saturated``
    the (H, W) mask of pixels clipped in any photo, ``masks`` each photo's own."""

    images: dict[str, np.ndarray]
    saturated: np.ndarray
    exposure: dict[str, dict]
    source_size: tuple[int, int]
    masks: dict[str, np.ndarray]

    @property
    def size(self) -> int:
        return int(next(iter(self.images.values())).shape[0])

    def resampled(self, size: int) -> LightPhotos:
        if size == self.size:
            return self
        images = {k: resize_area(v, (size, size)) for k, v in self.images.items()}

        def shrink(m: np.ndarray) -> np.ndarray:  # a pixel touching a clipped one is clipped
            return resize_area(m.astype(np.float32)[..., None], (size, size))[..., 0] > 0

        masks = {k: shrink(m) for k, m in self.masks.items()}
        return LightPhotos(images, shrink(self.saturated), self.exposure, self.source_size, masks)


def load_photos(setup: LightSetup, saturation_level: float | None, warnings: list[str]) -> LightPhotos:
    """Read, check and exposure-match the five photos (module docstring)."""
    check_saturation_level(saturation_level)
    paths = {s.name: s.path for s in setup.shots}
    images, levels, (h, w) = read_shots_of_one_size(
        list(paths.items()),
        "lights",
        "give five photos of one size from one fixed camera",
        " (the sample should fill the frame)",
    )
    if h != w:
        warnings.append(f"frame {w}x{h} is not square: centre-cropped to the sample square")
        images = {k: np.ascontiguousarray(centre_crop(v)) for k, v in images.items()}
    masks = saturation_masks(images, levels, saturation_level)
    saturated = np.logical_or.reduce(list(masks.values()))
    frac = float(saturated.mean())
    if frac > MAX_SATURATED:
        raise InputError(
            f"--lights: {frac:.0%} of the pixels are saturated (clipped) in the photos; lower "
            f"the exposure and retake"
        )
    if frac > WARN_SATURATED:
        warnings.append(f"{frac:.1%} of the pixels are saturated; they are left out of the errors")
    clip_negatives(images, warnings)
    exposure = _exposures(paths, any(v is not None for v in levels.values()), warnings)
    images = {k: (v * np.float32(exposure[k]["factor"])).astype(np.float32) for k, v in images.items()}
    return LightPhotos(images, saturated, exposure, (int(h), int(w)), masks)


def _exposures(paths: dict[str, str], ldr: bool, warnings: list[str]) -> dict[str, dict]:
    """Per photo: the factor bringing it to the first photo's exposure (EXIF), and its source."""
    exif = {k: read_exif(p) for k, p in paths.items()}
    if all({"exposure_time", "iso", "f_number"} <= set(e) for e in exif.values()):
        h = {k: e["exposure_time"] * e["iso"] / e["f_number"] ** 2 for k, e in exif.items()}
        first = next(iter(h.values()))
        return {k: {"factor": first / h[k], "source": "exif", **exif[k]} for k in paths}
    if ldr:
        warnings.append("no EXIF exposure in the photos: equal exposure assumed")
    return {k: {"factor": 1.0, "source": "assumed equal"} for k in paths}


def _highlight(setup: LightSetup, photos: LightPhotos, warnings: list[str]) -> dict | None:
    """The highlight check of the light at the camera (light 0 of the setup), None without one."""
    at_camera = [s for s in setup.shots if math.dist(s.position, s.camera) < 1e-3]
    if not at_camera:
        return None
    shot = at_camera[0]
    hl = highlight_position(photos.images[shot.name])
    pos, r2 = hl["position"], hl["fit_r2"]
    if r2 >= HIGHLIGHT_MIN_R2 and pos is None:
        warnings.append(
            f"{shot.name}: no highlight of the light at the camera found; the camera should face the sample"
        )
    elif r2 >= HIGHLIGHT_MIN_R2 and math.hypot(*pos) > HIGHLIGHT_WARN:
        warnings.append(
            f"{shot.name}: the highlight of the light at the camera is off centre (x "
            f"{pos[0]:+.2f}, y {pos[1]:+.2f} half-widths); face the camera to the sample"
        )
    return hl


# -- intensities and re-renders -------------------------------------------------------------------------


def _known_intensities(cfg: FiveLightConfig, setup: LightSetup) -> dict[str, tuple[float, str]] | None:
    """Per light: (intensity in photo units, source) when every one is known, else None."""
    if cfg.light_intensity is not None:
        value = float(cfg.light_intensity)
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"--flash-intensity {value}: give a finite value > 0")
        return {s.name: (value, "--flash-intensity") for s in setup.shots}
    if all(s.intensity is not None for s in setup.shots):
        return {s.name: (float(s.intensity), "capture.json") for s in setup.shots}
    return None


def _fit_intensity(maps: SVBRDF, setup: LightSetup, photos: LightPhotos) -> float:
    """One least-squares intensity for all five lights (the photos' units)."""
    from .refine import rerender_shots

    units = rerender_shots(maps, None, [s.shot(1.0) for s in setup.shots])
    m = ~photos.saturated
    num = sum(
        float(np.sum(u[m].astype(np.float64) * photos.images[s.name][m])) for s, u in zip(setup.shots, units)
    )
    den = sum(float(np.sum(u[m].astype(np.float64) ** 2)) for u in units)
    if not (den > 0 and num > 0):
        raise InputError(
            "--lights: the photos show no light from the point lights; check the files, or "
            "give --flash-intensity"
        )
    return num / den


# -- the job ---------------------------------------------------------------------------------------------


def run_fivelight(
    cfg: FiveLightConfig,
    *,
    log: Callable[[str], None] | None = None,
    bundle=None,
) -> dict:
    """Run the five-light estimate of ``cfg``; return the summary (also ``estimate.json``).

    ``log(msg)``: stage messages (stderr in the command). ``bundle``: the dual-loss model already
    loaded (None: from ``cfg.checkpoint``, else the shipped one)."""
    from .pipeline import ESTIMATE_FORMAT
    from .refine import ShotTarget, rerender_errors

    log = log or (lambda msg: None)
    stage = outputs.Stages(cfg.out)  # the clock; --out checked
    out, timings, t0 = stage.out, stage.timings, stage.t_start
    path = model_path(cfg.checkpoint) if bundle is None else None
    setup, warnings = resolve_lights(cfg.lights)
    photos = load_photos(setup, cfg.saturation_level, warnings)
    highlight = _highlight(setup, photos, warnings)
    known = _known_intensities(cfg, setup)
    stage("inputs", t0)
    for w in warnings:
        log(f"warning: {w}")

    t0 = time.perf_counter()
    if bundle is None:
        bundle = load_dualloss(path)
    grid = model_grid(bundle)
    n = photos.size
    work = working_size(n, grid, cfg.max_size)
    if n > work:
        warnings.append(
            f"the photos are {n}x{n} pixels: estimating at {work}x{work} (the working size "
            f"limit, --max-size {cfg.max_size}); give --max-size {n} for the full size"
        )
        log(f"warning: {warnings[-1]}")
    stage("model", t0)

    t0 = time.perf_counter()
    log(f"estimating the maps from {LIGHT_COUNT} lights at {work}x{work} (model grid {grid}x{grid})")
    work_photos = photos.resampled(work)
    # the network sees the reference exposure (module docstring, "Exposure")
    to_reference = {s.name: DEFAULT_FLASH_INTENSITY / known[s.name][0] if known else 1.0 for s in setup.shots}
    net_input = [work_photos.images[s.name] * np.float32(to_reference[s.name]) for s in setup.shots]
    if work != grid:  # the network sees the sample at the scale it was trained at (module docstring)
        maps = resample_svbrdf(predict(bundle, [resize_area(x, (grid, grid)) for x in net_input]), work)
    else:
        maps = predict(bundle, net_input)
    if maps.shape != (work, work):
        raise RuntimeError(f"the network returned {maps.shape} maps for a {work}x{work} image")
    stage("maps", t0)

    fit = None
    if cfg.flash_fit:
        from .photometric import fit_photometric

        t0 = time.perf_counter()
        log("fitting the photos: photometric stereo; roughness and specular from the light at the camera")
        fit = fit_photometric(  # the network's input is at the reference exposure: every light at
            net_input,  # DEFAULT_FLASH_INTENSITY (module docstring, "Exposure")
            [s.position for s in setup.shots],
            [DEFAULT_FLASH_INTENSITY] * LIGHT_COUNT,
            maps,
            camera=setup.shots[0].camera,
            saturated=[work_photos.masks[s.name] for s in setup.shots],
        )
        maps = fit.maps
        stage("flash fit", t0)

    t0 = time.perf_counter()
    log(f"re-rendering the {LIGHT_COUNT} shots at {work}x{work}")
    if known is None:
        fitted = _fit_intensity(maps, setup, work_photos)
        intensities = {s.name: (fitted, "fitted") for s in setup.shots}
    else:
        intensities = known
    mask = ~work_photos.saturated
    targets = [
        ShotTarget(s.shot(intensities[s.name][0]), work_photos.images[s.name], mask) for s in setup.shots
    ]
    errors, renders = rerender_errors(maps, None, targets)
    stage("rerender", t0)

    paths = {s.name: s.path for s in setup.shots}
    summary = {
        "format": ESTIMATE_FORMAT,
        "version": __version__,
        "out": str(out),
        "capture": SETUP,
        "model": {"kind": "dualloss", "checkpoint": str(path) if path is not None else None},
        "inputs": {
            "paths": paths,
            "size": [work, work],
            "source_size": list(photos.source_size),
            "fov": setup.shots[0].fov,
            "flash_only": False,
            "exposure": photos.exposure,
            "shifts": {},
            "alignment": {},
            "highlight": highlight,
            "saturated_fraction": float(photos.saturated.mean()),
            "warnings": list(warnings),
            "lights": {s.name: list(s.position) for s in setup.shots},
            "geometry": setup.geometry,
        },
        "model_grid": grid,
        "resolution": work,
        "tiles": 1,
        "tile": work,
        "ensemble": [work],
        "render_mode": "sg",  # no environment: the point lights alone
        "flash": {k: {"intensity": float(v), "source": src} for k, (v, src) in intensities.items()},
        "exposure": {
            "to_reference": to_reference,
            "source": known[setup.shots[0].name][1] if known else "none (the reference exposure assumed)",
        },
        "lobes": 0,
        "rerender_error": {"network": errors, "refined": None},
        "refine": None,
        "prediction_timings": {"network": timings["maps"]},
        "flash_fit": None if fit is None else fit.to_json(),
        "warnings": list(warnings),
        "timings": timings,
    }

    t0 = time.perf_counter()
    log(f"writing {out}")
    with atomic_dir(out) as tmp:
        source = "ebr estimate --lights (five-light, dual-loss network" + (
            ", photometric fit)" if fit else ")"
        )
        files = outputs.write_maps(maps, tmp / "maps", source)
        files += outputs.write_shots(tmp, work_photos.images, renders)
        reference = intensities[setup.shots[0].name][0]
        files += outputs.write_novel(maps, None, reference, tmp, float(setup.shots[0].camera[2]))
        stage("outputs", t0)
        outputs.write_report_and_summary(tmp, summary, files, stage)
    return summary


__all__ = [
    "FIVELIGHT_FLAGS",
    "FiveLightConfig",
    "LIGHT_COUNT",
    "LightSetup",
    "LightShot",
    "load_dualloss",
    "model_path",
    "predict",
    "resolve_lights",
    "run_fivelight",
    "shipped_model_path",
]
