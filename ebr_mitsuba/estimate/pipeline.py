"""The estimate job: photos in, maps + lighting + re-renders + report out.

Stages (each timed; the ``--json`` summary lists them in ``timings``):

============  ===================================================================================
stage         work
============  ===================================================================================
``inputs``    read, exposure-match and check the shots (:func:`.inputs.load_inputs`); the
              working size (:func:`.resample.working_size`) and the shots resampled to it
``model``     the model: the ``predictor`` given, else :func:`load_predictor` (the shipped model
              or ``--checkpoint``, :func:`ebr_mitsuba.model.predict.load_predictor`)
``lighting``  once per capture, at the model grid: lighting net, SG extraction, exemplar
              selection (:meth:`~ebr_mitsuba.model.predictor.StagedPredictor.predict_lighting`)
``maps``      the cascade over the whole working image (:func:`.fullres.predict_maps`); at the
              grid size, ``lighting`` and ``maps`` are one call
              (:meth:`~ebr_mitsuba.model.predictor.Predictor.predict`)
``rerender``  flash intensity, re-render errors of the network's estimate
``refine``    ``--refine-steps N`` > 0: test-time refinement (:mod:`.refine`)
``outputs``   maps, env.json and pictures, re-renders, residuals, novel lights (:mod:`.outputs`)
``report``    ``report.html`` (:mod:`.report`)
============  ===================================================================================

The model is an argument (a :class:`~ebr_mitsuba.model.predictor.Predictor`): an estimate at the
model grid needs its ``grid``, ``takes_far`` and ``predict``; one above the grid a
:class:`~ebr_mitsuba.model.predictor.StagedPredictor`. :func:`run_estimate` returns the summary
(``estimate.json``) with the estimate itself in memory (:class:`EstimateResult`).

Every stage that can take more than a second says so on stderr when it starts and shows a
progress bar (``bar``); ``--json`` output goes to stdout alone.

Nothing is written until the inputs and the model have passed their checks, and the output
directory appears complete or not at all (:func:`ebr_mitsuba.fsutil.atomic_dir`): an earlier
estimate directory at ``out`` is replaced, any other existing non-empty path is refused.

Flash intensity (needed to re-render; a photo's units are unknown): ``flash_intensity`` when
given; else the shot records of a ``capture.json`` beside the flash shot (``ebr capture``
output); else the least-squares fit of the network maps' flash-only render to the photos'
flash-only image (reported with ``"source": "fitted"``). The far flash is fitted or scaled
likewise (same irradiance at the sample as the near flash when given).

Exposure (``docs/conventions.md``, "Exposure"): the networks were trained on photos at the
*reference exposure* (a pixel value is radiance with the flash at
:data:`ebr_mitsuba.geometry.DEFAULT_FLASH_INTENSITY`). When the near flash intensity in photo
units is known (``flash_intensity`` or ``capture.json``), every shot is multiplied by
``DEFAULT_FLASH_INTENSITY / known`` before the networks and the refinement see it, so the
absolute albedo is restored from the flash; the written images, lighting and intensities are in
the photos' own units again (``summary["exposure"]``). When it is unknown, the photos are taken
as they are (the reference exposure assumed) and the intensity is fitted.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import InputError
from ..fsutil import atomic_dir
from ..geometry import DEFAULT_FLASH_INTENSITY, FAR_DISTANCE, FAR_FOV, Shot
from ..metrics import map_rmse
from ..model.predictor import Prediction, Predictor
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF
from ..typedconfig import config, option
from . import outputs
from .fullres import release_memory
from .inputs import (
    CAPTURE_JSON,
    DEFAULT_FOV,
    DEFAULT_MAX_SHIFT,
    MAX_FOV,
    MIN_FOV,
    Inputs,
    load_inputs,
    read_capture_record,
)
from .options import (
    checkpoint_option,
    flash_fit_option,
    intensity_option,
    max_size_option,
    out_option,
    saturation_option,
)
from .outputs import check_out_dir
from .refine import RefineConfig, ShotTarget, fit_flash_intensity, refine, rerender_errors
from .resample import working_size
from .shading_normals import ShadingNormalsConfig

ESTIMATE_FORMAT = "ebr-estimate/1"


@config(error=InputError, cli=True)
class EstimateConfig:
    """Everything an estimate needs: the options of ``ebr estimate`` (its flags, defaults and help
    are generated from these fields; a bad value is an :class:`~ebr_mitsuba.errors.InputError`
    naming the flag). ``refine`` holds the :class:`~.refine.RefineConfig` of the refinement,
    ``shading`` the :class:`~.shading_normals.ShadingNormalsConfig` of the shading normals."""

    flash: str = option(
        meaning="photo with the flash (EXR, PNG, JPEG); or --lights", flag="--flash", metavar="F"
    )
    out: str = out_option()
    noflash: str | None = option(
        None, "photo without the flash (none: a flash-only capture)", flag="--noflash", metavar="NF"
    )
    far_flash: str | None = option(None, "far shot with the flash", flag="--far-flash", metavar="F2")
    far_noflash: str | None = option(None, "far shot without the flash", flag="--far-noflash", metavar="NF2")
    far_flash_ratio: float | None = option(
        None,
        "the far flash's intensity (W/sr) over the near flash's; 1 for a phone's one flash",
        above=0,
        flag="--far-flash-ratio",
        metavar="R",
        shown="capture.json, else (far / near distance)²: as bright at the sample, as ebr capture",
    )
    checkpoint: str | None = checkpoint_option(
        "model checkpoint (none: with far shots, the shipped near-far model)", "the shipped model"
    )
    refine: RefineConfig = option(RefineConfig(), "test-time refinement (RefineConfig; its --refine-* flags)")
    shading: ShadingNormalsConfig = option(
        ShadingNormalsConfig(),
        "the shading normals' options (ShadingNormalsConfig; --normal-gain, --relief-gain)",
    )
    exposure_ratio: float | None = option(
        None,
        "no-flash exposure / flash exposure when the files carry no EXIF",
        above=0,
        flag="--exposure-ratio",
        metavar="R",
        shown="EXIF, else 1",
    )
    fov: float = option(
        DEFAULT_FOV,
        "horizontal field of view of the photos in degrees",
        minimum=MIN_FOV,
        maximum=MAX_FOV,
        flag="--fov",
        metavar="DEG",
        fix="45 for the capture guide's framing",
    )
    max_shift: float = option(
        DEFAULT_MAX_SHIFT,
        "largest flash/no-flash shift accepted, as a fraction of the width",
        minimum=0,
        maximum=0.5,
        flag="--max-shift",
        metavar="F",
    )
    saturation_level: float | None = saturation_option()
    flash_intensity: float | None = intensity_option(
        "flash intensity in W/sr at the flash shot's exposure (--lights: each light's)"
    )
    max_size: int = max_size_option("larger photos are downsampled to it, with a warning")
    flash_fit: bool = flash_fit_option(
        "diffuse, specular and roughness from the flash-profile fit (estimate/flashfit.py); "
        "--no-flash-fit keeps the network's maps"
    )
    shading_normals: bool = option(
        True,
        "normals from the albedo texture scaled by the flash / no-flash shading "
        "(estimate/shading_normals.py); --no-shading-normals keeps the network's normals",
        flag="--shading-normals",
    )
    highlight_tilt: bool = option(
        True,
        "where the network's normals would be kept (a metal, a glossy sample), the flat normal tilted "
        "to where the flash shot's clipped highlight sits (estimate/highlight_tilt.py); "
        "--no-highlight-tilt keeps the network's",
        flag="--highlight-tilt",
    )
    roughness_pattern: bool = option(
        True,
        "the roughness map follows the albedo texture by a slope read off the flash highlight "
        "(estimate/roughness_pattern.py); --no-roughness-pattern keeps the fitted constant",
        flag="--roughness-pattern",
    )
    drop_horizon_lobes: bool = option(
        False,
        "drop the SG lobes within 3° of the horizon, which the photos barely see, keeping the "
        "sample's irradiance (estimate/horizon.py; no better on the insertion benchmark)",
        flag="--drop-horizon-lobes",
    )


ESTIMATE_FLAGS = tuple(  # the fields ebr estimate sets from flags (refine: its own REFINE_FLAGS)
    f.name for f in dataclasses.fields(EstimateConfig) if f.name not in ("refine", "shading")
)


class EstimateResult(dict):
    """What :func:`run_estimate` returns: the summary (the ``estimate.json`` document, a dict)
    with the estimate in memory, in the photos' units as written: ``maps`` (the final maps, as
    ``maps/``), ``network_maps`` (the network's, as ``maps_network/`` when refined; the same as
    ``maps`` otherwise), ``env`` (the final SG environment; None in flash-only mode) and
    ``shading`` (the :class:`~.shading_normals.ShadingNormals` the normal map was made from; None
    when the shading normals did not apply)."""

    def __init__(
        self, summary: dict, maps: SVBRDF, network_maps: SVBRDF, env: SGEnvironment | None, shading=None
    ):
        super().__init__(summary)
        self.maps, self.network_maps, self.env = maps, network_maps, env
        self.shading = shading


def load_predictor(checkpoint: str | None) -> Predictor:
    """The model :func:`run_estimate` uses when it is given none (also ``ebr demo``'s and the
    gallery's): ``checkpoint`` (None: the shipped model) as a
    :class:`~ebr_mitsuba.model.predict.ModelPredictor`. Imported here: the model pulls in torch."""
    from ..model.predict import load_predictor as load

    return load(checkpoint)


def near_distance(fov: float) -> float:
    """Camera height for which a ``fov``-degree frame is exactly the sample [-1, 1]²."""
    return 1.0 / math.tan(math.radians(fov) / 2)


def capture_intensities(flash_path: str) -> dict[str, float]:
    """Flash intensities per shot file name from a ``capture.json`` beside the flash shot ({} if
    none or not an ``ebr capture`` directory)."""
    meta_path = Path(flash_path).resolve().parent / CAPTURE_JSON
    if not meta_path.is_file():
        return {}
    try:
        meta = read_capture_record(meta_path, "", "")
    except InputError:  # unreadable or not an 'ebr capture' record
        return {}
    out = {}
    for rec in meta.get("shots", []):
        if isinstance(rec, dict) and rec.get("flash") is not None and "file" in rec:
            out[str(rec["file"])] = float(rec.get("flash_intensity", 0.0))
    return out


def _shots(inputs: Inputs) -> dict[str, Shot]:
    d = near_distance(inputs.fov)
    near = (0.0, 0.0, d)
    far = (0.0, 0.0, FAR_DISTANCE)
    shots = {"flash": Shot("flash", near, inputs.fov, near, 1.0, env=not inputs.flash_only)}
    if not inputs.flash_only:
        shots["noflash"] = Shot("noflash", near, inputs.fov, None, 0.0, env=True)
    if inputs.has_far:
        shots["far_flash"] = Shot("far_flash", far, FAR_FOV, far, 1.0, env=True)
        shots["far_noflash"] = Shot("far_noflash", far, FAR_FOV, None, 0.0, env=True)
    return shots


def refine_options_for(options: RefineConfig, flash_fit, shading_fit) -> RefineConfig:
    """The refinement's options for one capture: with ``weighting`` noise, the normals are
    refined only where the shading normals were read (:mod:`.shading_normals`: a dielectric below
    the glint limit); a metal's or a glossy sample's normals, whose glints move far more steeply
    with the normal than diffuse shading does, stay fixed (``docs/estimate.md``)."""
    if options.weighting != "noise" or "normal" in options.fixed:
        return options
    if flash_fit is not None and shading_fit is not None and not flash_fit.metal:
        return options
    return dataclasses.replace(options, fixed=tuple(options.fixed) + ("normal",))


def known_flash_intensity(cfg: EstimateConfig, inputs: Inputs) -> tuple[float | None, str | None]:
    """The near flash intensity in photo units when the capture states it (``flash_intensity``,
    else ``capture.json``) and its source; (None, None) when it must be fitted."""
    if cfg.flash_intensity is not None:
        return float(cfg.flash_intensity), "--flash-intensity"
    value = capture_intensities(cfg.flash).get(Path(inputs.paths["flash"]).name)
    return (float(value), "capture.json") if value else (None, None)


def stated_far_ratio(cfg: EstimateConfig, inputs: Inputs) -> float | None:
    """The far flash's intensity over the near flash's: ``--far-flash-ratio``, else what
    ``capture.json`` states for both, else None (the flash fit then takes (far / near distance)²,
    what ``ebr capture`` and ``ebr generate`` use: :class:`~.flashfit.FarPair`; a phone's far
    pair, its one flash four times farther, is 1 and reads a roughness of 1.0 under that
    assumption)."""
    if cfg.far_flash_ratio is not None:
        return float(cfg.far_flash_ratio)
    known = capture_intensities(cfg.flash)
    near = known.get(Path(inputs.paths["flash"]).name)
    far = known.get(Path(inputs.paths.get("far_flash", "")).name)
    return float(far) / float(near) if near and far else None


def fit_capture_flash(inputs: Inputs, fov: float, far_ratio: float | None = None, options=None):
    """:func:`~.flashfit.fit_flash` of a capture's shots at the reference exposure (``inputs``,
    at the size to fit), as ``ebr estimate`` runs it: the near camera of ``fov``, the photos'
    saturation and clip level, and the far pair when the capture has one (its flash
    ``far_ratio`` × the near one's; None: :class:`~.flashfit.FarPair`'s default). A flash-only
    capture fits its flash shot against a black no-flash one."""
    from .flashfit import FarPair, fit_flash

    flash = inputs.images["flash"]
    noflash = inputs.images.get("noflash")
    if noflash is None:
        noflash = np.zeros_like(flash)
    far_pair = None
    if inputs.has_far and not inputs.flash_only:
        far_pair = FarPair(
            inputs.images["far_flash"],
            inputs.images["far_noflash"],
            camera=(0.0, 0.0, FAR_DISTANCE),
            intensity=None if far_ratio is None else far_ratio * DEFAULT_FLASH_INTENSITY,
            saturated=inputs.saturated,
        )
    return fit_flash(
        flash,
        noflash,
        intensity=DEFAULT_FLASH_INTENSITY,
        camera=(0.0, 0.0, near_distance(fov)),
        saturated=inputs.saturated,
        clip_level=inputs.clip_level if inputs.clip_level is not None else math.inf,
        options=options,
        far=far_pair,
    )


def _highlight_normals(flash_fit, work_inputs: Inputs, fov: float, log) -> tuple[dict, np.ndarray | None]:
    """The normals of a capture that keeps the network's: the flat normal tilted to where the flash
    shot's clipped highlight sits (:mod:`.highlight_tilt`), or None where that reading is not
    trusted; with the ``estimate.json`` record."""
    from .highlight_tilt import read_highlight_tilt, tilted_normals

    sat = np.asarray(work_inputs.saturated, bool)
    if work_inputs.clip_level is not None:  # the near flash shot's own clipped pixels
        sat = sat & (work_inputs.images["flash"].max(axis=-1) >= 0.5 * work_inputs.clip_level)
    tilt = read_highlight_tilt(sat, near_distance(fov), flash_fit.roughness)
    if not tilt.applied:
        return tilt.to_json(), None
    log(
        f"tilting the flat normal to the clipped highlight: {tilt.degrees:.2f}° "
        f"(slopes {tilt.slope[0]:+.4f}, {tilt.slope[1]:+.4f}; estimate/highlight_tilt.py)"
    )
    return tilt.to_json(), tilted_normals(sat.shape, tilt.slope)


def _with_roughness_pattern(flash_fit, work_inputs: Inputs, fov: float, log):
    """``flash_fit`` with the roughness pattern of :mod:`.roughness_pattern` read off the near pair of
    ``work_inputs`` (as :func:`fit_capture_flash` fitted it); a fit whose roughness is the
    network's map is kept as it is."""
    from .roughness_pattern import read_roughness_pattern

    if flash_fit.roughness_map is not None:
        return flash_fit
    pattern = read_roughness_pattern(
        flash_fit,
        work_inputs.images["flash"],
        work_inputs.images["noflash"],
        intensity=DEFAULT_FLASH_INTENSITY,
        camera=(0.0, 0.0, near_distance(fov)),
        saturated=work_inputs.saturated,
    )
    if pattern.applied:
        log(f"roughness pattern: {pattern.slope:+.3f} roughness per unit of log-albedo")
    else:
        log(f"roughness pattern not read ({pattern.reason}): the fitted constant")
    return flash_fit.with_roughness_pattern(pattern)


FAR_DIM_LIMIT = 4.0  # a far flash-only image this many times darker than the near one: a phone's pair


def far_flash_dimness(images: dict) -> float | None:
    """How many times darker the far flash-only image is than the near one (means over the frame,
    the photos at one exposure), when that is more than FAR_DIM_LIMIT; else None. With the far
    flash as bright at the sample (``ebr capture``) the two are alike; a phone's one flash from
    four times farther makes the far one about 17× darker."""
    near = float(np.mean(images["flash"] - images["noflash"]))
    far = float(np.mean(images["far_flash"] - images["far_noflash"]))
    if not near > 0:
        return None
    ratio = near / max(far, near * 1e-6)
    return ratio if ratio > FAR_DIM_LIMIT else None


def _intensities(
    cfg: EstimateConfig, inputs: Inputs, maps: SVBRDF, shots: dict[str, Shot], scale: float = 1.0
) -> dict:
    """The flash intensities of the shots (in the units of ``inputs``: the photos × ``scale``)."""
    import dataclasses

    result = {}
    known = capture_intensities(cfg.flash)
    for name in ("flash", "far_flash"):
        if name not in shots:
            continue
        d = shots[name].camera[2]
        if cfg.flash_intensity is not None:
            ratio = (d / near_distance(inputs.fov)) ** 2  # the near flash: 1
            if name == "far_flash" and cfg.far_flash_ratio is not None:
                ratio = cfg.far_flash_ratio
            value = scale * cfg.flash_intensity * ratio
            source = "--flash-intensity"
        elif Path(inputs.paths[name]).name in known:
            value, source = scale * known[Path(inputs.paths[name]).name], "capture.json"
        else:
            mask = ~inputs.saturated
            value = fit_flash_intensity(
                maps, shots[name], inputs.flash_only_image(far=name == "far_flash"), mask
            )
            source = "fitted"
        shots[name] = dataclasses.replace(shots[name], flash_intensity=float(value))
        result[name] = {"intensity": float(value), "source": source}
    return result


def _refine_targets(
    opts: RefineConfig, inputs: Inputs, shots: dict[str, Shot], targets: list[ShotTarget], mask: np.ndarray
) -> list[ShotTarget]:
    """What the refinement fits (``RefineConfig.target``): the input shots, or each flash shot's
    flash-only image under its flash alone (a flash-only capture has nothing to subtract: its
    targets are the shots already)."""
    if opts.target == "photos" or inputs.flash_only:
        return targets
    return [
        ShotTarget(
            dataclasses.replace(shots[name], name=f"{name} − no-flash", env=False),
            inputs.flash_only_image(far=name == "far_flash"),
            mask,
        )
        for name in ("flash", "far_flash")
        if name in shots
    ]


def _checked(pred: Prediction, size: int, flash_only: bool) -> tuple[SVBRDF, SGEnvironment | None]:
    """The prediction's maps (checked to be ``size``²) and environment (None in flash-only mode;
    no lobes when the model found none)."""
    if pred.maps.shape != (size, size):
        raise RuntimeError(f"the network returned {pred.maps.shape} maps for a {size}x{size} image")
    if flash_only:
        return pred.maps, None
    return pred.maps, pred.env if pred.env is not None else SGEnvironment.empty()


def _shot_args(predictor: Predictor, images: dict[str, np.ndarray]) -> tuple:
    """(flash, no-flash, far flash, far no-flash) for the model (a near model gets no far pair:
    the far shots then serve the re-renders and the refinement only)."""
    far = (images.get("far_flash"), images.get("far_noflash")) if predictor.takes_far else (None, None)
    return images["flash"], images.get("noflash"), *far


PARALLEL_WRITERS = 2  # threads writing the output files of a large estimate
PARALLEL_WRITE_PIXELS = 512 * 512  # from this working size on (below, writing takes < 1 s)


def _warm_imports() -> None:
    """Import matplotlib's colour maps (the residual pictures written at the end, 0.2–0.5 s) in a
    background thread while the networks run, instead of after them. Writing images needs no
    colour-science (:mod:`ebr_mitsuba.imageio` encodes sRGB itself): it is imported only to
    decode PNG/JPEG photos."""
    import threading

    def warm():
        import matplotlib.cm  # noqa: F401  (the colour map registry that outputs.residual_png reads)

    threading.Thread(target=warm, daemon=True, name="ebr-warm-imports").start()


def _write_env(env: SGEnvironment, out: Path) -> list[str]:
    env.save(out / "env.json")
    return outputs.env_pictures(env, out)


def _write_network_renders(out: Path, renders: dict, photos: dict) -> list[str]:
    (out / "rerender_network").mkdir()
    files = []
    for k, img in renders.items():
        outputs.preview(out / "rerender_network" / f"{k}.png", img, outputs.exposure_of(photos[k]))
        outputs.residual_png(out / "rerender_network" / f"{k}_residual.png", img, photos[k])
        files += [f"rerender_network/{k}.png", f"rerender_network/{k}_residual.png"]
    return files


def run_jobs(jobs: list, local: list, workers: int, progress=None) -> list:
    """Run ``jobs`` (``(name, fn, args)`` returning lists) in ``workers`` threads while ``local``
    ones run in this thread; the concatenated results in job order. ``workers`` = 1: everything
    in order in this thread (the first failure stops the rest). A failure in a thread is raised
    here once the running jobs have finished; jobs not yet started are cancelled."""
    total = len(jobs) + len(local)
    done = 0

    def tick(name):
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total, name)

    if progress is not None:
        progress(0, total, (jobs + local)[0][0] if total else "")
    if workers <= 1:
        out = []
        for name, fn, args in jobs + local:
            out += fn(*args)
            tick(name)
        return out
    from concurrent.futures import ThreadPoolExecutor

    results: dict[int, list] = {}
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [pool.submit(fn, *args) for _, fn, args in jobs]
        try:
            for k, (name, fn, args) in enumerate(local):
                results[len(jobs) + k] = fn(*args)
                tick(name)
            for k, f in enumerate(futures):
                results[k] = f.result()
                tick(jobs[k][0])
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    return [x for k in sorted(results) for x in results[k]]


class _Steps:
    """A progress bar over the steps of one stage (``done``/``total`` callbacks); a context
    manager, so that the bar is cleared before an error message is printed."""

    def __enter__(self) -> _Steps:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __init__(self, bar, desc: str, unit: str = "step", delay: float = 0.0):
        self.bar_factory, self.desc, self.unit, self.pbar = bar, desc, unit, None
        self.delay = delay

    def __call__(self, done: int, total: int, what: str = "") -> None:
        if self.bar_factory is None:
            return
        if self.pbar is None:
            extra = {"delay": self.delay} if self.delay > 0 else {}
            self.pbar = self.bar_factory(total=total, desc=self.desc, unit=self.unit, mininterval=0, **extra)
        self.pbar.total = total
        if what:
            self.pbar.set_postfix_str(what, refresh=False)
        self.pbar.update(done - self.pbar.n)  # shown at once (a delayed bar only after its delay)

    def close(self) -> None:
        if self.pbar is not None:
            self.pbar.close()
            self.pbar = None


def run_estimate(
    cfg: EstimateConfig,
    *,
    truth: SVBRDF | None = None,
    log: Callable[[str], None] | None = None,
    bar: Callable | None = None,
    predictor: Predictor | None = None,
) -> EstimateResult:
    """Run the estimate described by ``cfg``; return the summary (also ``estimate.json``) with the
    maps and lighting in memory (:class:`EstimateResult`).

    ``truth``: ground-truth maps (``ebr demo``) to compare against, per map. ``log(msg)``: stage
    messages (stderr in the command); ``bar``: a tqdm-like factory for the refinement progress.
    ``predictor``: the model (a :class:`~ebr_mitsuba.model.predictor.Predictor`, a
    :class:`~ebr_mitsuba.model.predictor.StagedPredictor` above the grid; callers that estimate
    several captures load it once); None: :func:`load_predictor` of ``cfg.checkpoint``.
    """
    log = log or (lambda msg: None)
    stage = outputs.Stages(cfg.out)  # the clock; --out checked
    out, timings, t0 = stage.out, stage.timings, stage.t_start
    # Reading and loading the model can still refuse the inputs (one line, nothing before it): their
    # bars appear only when the stage takes more than a second.
    with _Steps(bar, "inputs", unit="file", delay=0.5) as steps:
        inputs = load_inputs(
            cfg.flash,
            cfg.noflash,
            cfg.far_flash,
            cfg.far_noflash,
            exposure_ratio=cfg.exposure_ratio,
            fov=cfg.fov,
            max_shift=cfg.max_shift,
            saturation_level=cfg.saturation_level,
            progress=steps,
        )
    if cfg.far_flash_ratio is not None and not inputs.has_far:
        raise InputError("--far-flash-ratio needs --far-flash and --far-noflash: it scales the far flash")
    if cfg.refine.lobes and inputs.flash_only:
        raise InputError("--refine-lobes needs --noflash: a flash-only capture has no lighting to refine")
    known, known_source = known_flash_intensity(cfg, inputs)
    if known is not None and not (math.isfinite(known) and known > 0):
        raise InputError(f"flash intensity {known} ({known_source}): give a finite value > 0")
    scale = 1.0 if known is None else DEFAULT_FLASH_INTENSITY / known  # to the reference exposure
    if scale != 1.0:
        inputs = inputs.scaled(scale)
    stage("inputs", t0)
    for w in inputs.warnings:
        log(f"warning: {w}")

    t0 = time.perf_counter()
    model_used = "given by the caller"  # estimate.json "model"
    with _Steps(bar if predictor is None else None, "model", delay=0.5) as steps:
        steps(0, 2, "import")
        if predictor is None:
            steps(1, 2, "load")
            from ..model.predict import default_checkpoint, shipped_model_path

            # none given: with far shots the shipped near-far model, else the shipped near model
            checkpoint = cfg.checkpoint if cfg.checkpoint is not None else default_checkpoint(inputs.has_far)
            predictor = load_predictor(None if checkpoint is None else str(checkpoint))
            model_used = str(checkpoint or shipped_model_path())
        steps(2, 2, "done")
    grid = int(predictor.grid)
    if inputs.has_far and not predictor.takes_far:
        inputs.warnings.append(
            "the model reads near captures only: the far shots are used for the re-renders and the "
            "refinement, not for the prediction"
        )
        log(f"warning: {inputs.warnings[-1]}")
    work = working_size(inputs.size[0], grid, cfg.max_size)
    if inputs.size[0] > work:
        inputs.warnings.append(
            f"the photos are {inputs.size[0]}x{inputs.size[0]} pixels: estimating at {work}x{work} "
            f"(the working size limit, --max-size {cfg.max_size}); give --max-size {inputs.size[0]} "
            f"for the full size"
        )
        log(f"warning: {inputs.warnings[-1]}")
    stage("model", t0)

    _warm_imports()
    t_resample = time.perf_counter()  # counted in the next stage, after its line on stderr
    what = "" if inputs.flash_only else "lighting + "
    tiles, tile, ensemble = 1, work, [work]
    lighting_timings: dict = {}
    if work == grid:  # the whole capture at the model grid: one call
        log(f"estimating {what}maps at the model grid {grid}x{grid}")
        t0 = t_resample
        with _Steps(bar, "lighting + maps") as steps:
            steps(0, 1, f"{grid}x{grid}")
            work_inputs = inputs.resampled((work, work))
            grid_inputs = work_inputs
            pred = predictor.predict(*_shot_args(predictor, grid_inputs.images))
        maps, env = _checked(pred, grid, inputs.flash_only)
        stage("maps", t0)
    else:
        from .fullres import predict_maps

        t0 = t_resample
        log(
            f"estimating the lighting at the model grid {grid}x{grid}"
            if not inputs.flash_only
            else f"selecting the point-light exemplars at the model grid {grid}x{grid}"
        )
        with _Steps(bar, "lighting") as steps:
            steps(0, 3, "resampling the photos")
            work_inputs = inputs.resampled((work, work))
            grid_inputs = work_inputs.resampled((grid, grid))
            lighting = predictor.predict_lighting(*_shot_args(predictor, grid_inputs.images), progress=steps)
        lighting_timings = dict(lighting.timings)
        stage("lighting", t0)
        t0 = time.perf_counter()
        log(f"estimating the maps at {work}x{work}")
        with _Steps(bar, "maps") as steps:
            pred = predict_maps(predictor, lighting, work_inputs.images, grid_inputs.images, progress=steps)
        release_memory()
        maps, env = _checked(pred, work, inputs.flash_only)
        tiles, tile, ensemble = len(pred.tiles), pred.tile, list(pred.members)
        stage("maps", t0)

    flash_fit, shading, shading_fit, highlight = None, None, None, None
    if cfg.flash_fit:
        from .flashfit import FlashFitConfig

        t0 = time.perf_counter()
        log(
            "fitting the flash profile: roughness, specular and the albedo level"
            + (" (near and far flash)" if work_inputs.has_far else "")
        )
        flash_img = work_inputs.images["flash"]
        noflash_img = work_inputs.images.get("noflash")
        if noflash_img is None:  # a flash-only capture: the flash shot is the flash-only image
            noflash_img = np.zeros_like(flash_img)
        fit_options = FlashFitConfig()
        ratio = None
        if work_inputs.has_far and not work_inputs.flash_only:
            ratio = stated_far_ratio(cfg, inputs)
            dim = far_flash_dimness(work_inputs.images) if ratio is None else None
            if dim is not None:
                inputs.warnings.append(
                    f"the far flash-only image is {dim:.0f}x darker than the near one, but the far flash "
                    "is assumed as bright at the sample (no capture.json): a far pair lit by the same "
                    "flash (a phone's) needs --far-flash-ratio 1"
                )
                log(f"warning: {inputs.warnings[-1]}")
        flash_fit = fit_capture_flash(work_inputs, inputs.fov, ratio, fit_options)
        stage("flash fit", t0)
        normal, source = maps.normal, "ebr estimate (network normals, flash fit)"
        if cfg.shading_normals and not flash_fit.metal and not inputs.flash_only:
            from .shading_normals import normals_for

            t0 = time.perf_counter()
            shading, shading_fit = normals_for(
                flash_fit,
                flash_img,
                noflash_img,
                camera_height=near_distance(inputs.fov),
                saturated=work_inputs.saturated,
                options=cfg.shading,
                log=log,
            )
            if shading_fit is not None:  # the photo pattern's shading is the relief's, not the albedo's
                camera = (0.0, 0.0, near_distance(inputs.fov))
                flash_fit = flash_fit.with_normals(shading_fit.normal, camera=camera)
                normal, source = (
                    shading_fit.map_normal(cfg.shading),
                    "ebr estimate (shading normals, flash fit)",
                )
            stage("shading normals", t0)
        if shading_fit is None and cfg.highlight_tilt:
            highlight, tilted = _highlight_normals(flash_fit, work_inputs, inputs.fov, log)
            if tilted is not None:
                normal, source = tilted, "ebr estimate (flat normals tilted to the highlight, flash fit)"
        if flash_fit.misfits(fit_options.misfit_limit):
            log(
                f"the flash profile fits poorly (ring residual {flash_fit.misfit:.3g} > "
                f"{fit_options.misfit_limit:g}): keeping the network's roughness"
            )
            flash_fit = flash_fit.with_network_roughness(np.asarray(maps.roughness))
        weight = fit_options.weight_for(max(flash_img.shape[:2]))
        flash_fit = flash_fit.with_network_diffuse(np.asarray(maps.diffuse), weight)
        if cfg.roughness_pattern and not flash_fit.metal and not inputs.flash_only:
            flash_fit = _with_roughness_pattern(flash_fit, work_inputs, inputs.fov, log)
        maps = flash_fit.maps(normal, source)

    horizon = None
    if env is not None and cfg.drop_horizon_lobes:
        from .horizon import drop_horizon_lobes

        env, horizon = drop_horizon_lobes(env)
        if horizon["applied"]:
            log(
                f"dropped {horizon['dropped']} SG lobe(s) at the horizon "
                f"({100 * horizon['irradiance_share']:.0f} % of the sample's irradiance, kept by the others)"
            )

    t0 = time.perf_counter()
    log(f"re-rendering the shots at {work}x{work}")
    with _Steps(bar, "re-render") as steps:
        steps(0, 2, "flash intensity")
        shots = _shots(work_inputs)
        flash_info = _intensities(cfg, work_inputs, maps, shots, scale)
        mask = ~work_inputs.saturated
        targets = [ShotTarget(shots[k], work_inputs.images[k], mask) for k in shots]
        mode, spp, table = cfg.refine.mode, cfg.refine.spp, cfg.refine.irradiance_table
        steps(1, 2, "re-renders")
        net_errors, net_renders = rerender_errors(maps, env, targets, mode, spp, table)
    release_memory()
    stage("rerender", t0)

    refined = None
    final_maps, final_env, final_renders, final_errors = maps, env, net_renders, net_errors
    if cfg.refine.steps > 0:
        t0 = time.perf_counter()
        budget = "" if cfg.refine.seconds is None else f", at most {cfg.refine.seconds:g} s"
        log(
            f"refining: {cfg.refine.steps} steps"
            + (" (maps + lobes" if cfg.refine.lobes else " (maps")
            + f", coarse to fine{budget})"
        )
        with _Steps(bar, "refine") as steps:
            steps(0, cfg.refine.steps, "")

            def progress(step, total, loss, size):
                steps(step, total, f"{size}x{size}, loss {loss:.4g}")

            fit_targets = _refine_targets(cfg.refine, work_inputs, shots, targets, mask)
            same = fit_targets is targets  # the network's re-renders are the refinement's start
            refine_cfg = refine_options_for(cfg.refine, flash_fit, shading_fit)
            refined = refine(
                maps,
                env,
                fit_targets,
                refine_cfg,
                progress,
                before=net_errors if same else None,
                before_renders=net_renders if same else None,
            )
        release_memory()
        if refined.stopped:
            log(f"note: refinement {refined.budget_note()}")
        if refined.loss_rose:
            log(f"warning: refinement {refined.loss_note()}")
        final_maps, final_env = refined.maps, refined.env
        final_errors, final_renders = refined.after, refined.renders
        if fit_targets is not targets:  # the written re-renders are of the input shots
            final_errors, final_renders = rerender_errors(final_maps, final_env, targets, mode, spp, table)
        stage("refine", t0)
        if len(refined.levels) > 1:
            for lv in refined.levels:
                timings[f"refine at {lv['size']}²"] = lv["seconds"]

    # Back to the photos' units for everything written (module docstring, "Exposure").
    unit = 1.0 / scale
    if scale != 1.0:
        final_env = None if final_env is None else final_env.scaled(unit)
        final_renders = {k: v * np.float32(unit) for k, v in final_renders.items()}
        net_renders = {k: v * np.float32(unit) for k, v in net_renders.items()}
        for rec in flash_info.values():
            rec["intensity"] = rec["intensity"] * unit

    summary = {
        "format": ESTIMATE_FORMAT,
        "version": __version__,
        "out": str(out),
        "capture": "flash-only" if inputs.flash_only else ("near-far" if inputs.has_far else "near"),
        "inputs": inputs.to_json(),
        "model": {"checkpoint": model_used, "takes_far": bool(predictor.takes_far)},
        "model_grid": grid,
        "resolution": work,
        "tiles": tiles,
        "tile": tile,
        "ensemble": ensemble,
        "render_mode": mode,
        "flash": flash_info,
        "exposure": {
            "to_reference": scale,
            "source": known_source or "none (the reference exposure assumed)",
        },
        "flash_fit": None if flash_fit is None else flash_fit.to_json(),
        "shading_normals": shading,
        "highlight_tilt": highlight,
        "lobes": 0 if final_env is None else final_env.num_lobes,
        "horizon_lobes": horizon,
        "rerender_error": {"network": net_errors, "refined": final_errors if refined else None},
        "refine": None
        if refined is None
        else {
            "steps": cfg.refine.steps,
            "lobes": cfg.refine.lobes,
            "seconds": round(refined.seconds, 3),
            "history": [[s, round(v, 6)] for s, v in refined.history],
            "kept_step": refined.kept_step,
            "loss_rose": refined.loss_rose,
            "note": refined.loss_note(),
            "levels": [{k: v for k, v in lv.items() if k != "seconds"} for lv in refined.levels],
            "steps_run": refined.steps_run,
            "seconds_budget": cfg.refine.seconds,
            "stopped": refined.stopped,
            "budget_note": refined.budget_note(),
            "target": cfg.refine.target,
            "weighting": cfg.refine.weighting,
            "fixed": list(refine_cfg.fixed),  # with the normals rule of refine_options_for
        },
        "prediction_timings": {
            k: float(v)
            for k, v in {**lighting_timings, **pred.timings}.items()
            if isinstance(v, (int, float))
        },
        "warnings": list(inputs.warnings),
        "timings": timings,
    }
    if truth is not None:
        summary["map_error"] = {
            "network": map_rmse(maps, truth),
            "refined": map_rmse(final_maps, truth) if refined else None,
        }

    t0 = time.perf_counter()
    files: list[str] = []

    log(f"writing {out}")
    photos = {k: work_inputs.images[k] * np.float32(unit) for k in shots}
    with atomic_dir(out) as tmp, _Steps(bar, "outputs", unit="group") as steps:
        # File groups (pure writes) go to a pool of 2 threads for large outputs; the renders of the
        # novel lights and the exemplar pictures run here meanwhile.
        jobs = [("maps", outputs.write_maps, (final_maps, tmp / "maps", "ebr estimate"))]
        if refined is not None:
            jobs.append(
                (
                    "network maps",
                    outputs.write_maps,
                    (maps, tmp / "maps_network", "ebr estimate (network, before refinement)"),
                )
            )
        jobs.append(("re-renders", outputs.write_shots, (tmp, photos, final_renders)))
        if refined is not None:
            jobs.append(("re-renders before refinement", _write_network_renders, (tmp, net_renders, photos)))
        local = []
        if final_env is not None:
            local.append(("lighting", _write_env, (final_env, tmp)))
        intensity = flash_info["flash"]["intensity"]
        novel_args = (final_maps, final_env, intensity, tmp, near_distance(inputs.fov), mode)
        local.append(("novel lights", outputs.write_novel, novel_args))
        local.append(("exemplars", outputs.write_exemplars, (tmp, pred)))
        workers = PARALLEL_WRITERS if work * work >= PARALLEL_WRITE_PIXELS else 1
        files += run_jobs(jobs, local, workers, steps)
        stage("outputs", t0)
        outputs.write_report_and_summary(tmp, summary, files, stage)
    return EstimateResult(summary, final_maps, maps, final_env, shading_fit)


__all__ = [
    "ESTIMATE_FLAGS",
    "ESTIMATE_FORMAT",
    "EstimateConfig",
    "EstimateResult",
    "run_estimate",
    "check_out_dir",
    "near_distance",
    "capture_intensities",
    "load_predictor",
]
