"""The estimate job: photos in, maps + lighting + re-renders + report out.

Stages (each timed; the ``--json`` summary lists them in ``timings``):

============  ===================================================================================
stage         work
============  ===================================================================================
``inputs``    read, exposure-match and check the shots (:func:`.inputs.load_inputs`)
``model``     load the network (:func:`ebr_mitsuba.train.inference.load_model`)
``predict``   one pass at the model grid: lighting (SGs, exemplars) and maps
``tiles``     inputs larger than the grid: tiled maps at the working resolution (:mod:`.tiling`)
``rerender``  flash intensity, re-render errors of the network's estimate
``refine``    ``--refine-steps N`` > 0: test-time refinement (:mod:`.refine`)
``outputs``   maps, env.json and pictures, re-renders, residuals, novel lights (:mod:`.outputs`)
``report``    ``report.html`` (:mod:`.report`)
============  ===================================================================================

Nothing is written until the inputs and the model have passed their checks, and the output
directory appears complete or not at all (:func:`ebr_mitsuba.fsutil.atomic_dir`): an earlier
estimate directory at ``out`` is replaced, any other existing non-empty path is refused.

Flash intensity (needed to re-render; a photo's units are unknown): ``flash_intensity`` when
given; else the shot records of a ``capture.json`` beside the flash shot (``ebr capture``
output); else the least-squares fit of the network maps' flash-only render to the photos'
flash-only image (reported with ``"source": "fitted"``). The far flash is fitted or scaled
likewise (same irradiance at the sample as the near flash when given).
"""

from __future__ import annotations

import importlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import InputError, RuntimeSetupError
from ..fsutil import atomic_dir
from ..geometry import FAR_DISTANCE, FAR_FOV, Shot
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF
from . import outputs
from .inputs import DEFAULT_FOV, DEFAULT_MAX_SHIFT, Inputs, load_inputs
from .metrics import map_rmse
from .refine import RefineConfig, ShotTarget, fit_flash_intensity, refine, rerender_errors
from .resample import DEFAULT_MAX_SIZE, model_grid, working_size
from .tiling import DEFAULT_OVERLAP, merge_detail, tiled_maps

ESTIMATE_FORMAT = "ebr-estimate/1"
INFERENCE_MODULE = "ebr_mitsuba.train.inference"


@dataclass(frozen=True)
class EstimateConfig:
    """Everything an estimate needs (defaults here are the command's defaults)."""

    flash: str
    out: str
    noflash: str | None = None
    far_flash: str | None = None
    far_noflash: str | None = None
    checkpoint: str | None = None
    refine: RefineConfig = field(default_factory=RefineConfig)
    exposure_ratio: float | None = None
    fov: float = DEFAULT_FOV
    max_shift: float = DEFAULT_MAX_SHIFT
    saturation_level: float | None = None
    flash_intensity: float | None = None
    tile: bool = True
    max_size: int = DEFAULT_MAX_SIZE
    tile_overlap: int = DEFAULT_OVERLAP


def inference_module():
    """The network inference module (imported lazily: it pulls in torch)."""
    try:
        return importlib.import_module(INFERENCE_MODULE)
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.startswith(INFERENCE_MODULE):
            raise RuntimeSetupError(
                f"this installation lacks {INFERENCE_MODULE} (the network inference); reinstall ebr-mitsuba"
            ) from None
        raise


def check_out_dir(out: Path) -> None:
    """Refuse to replace anything but an earlier estimate directory (or an empty directory)."""
    if not out.exists():
        return
    if not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a directory; choose another --out")
    if any(out.iterdir()) and not (out / "estimate.json").is_file():
        raise InputError(
            f"--out {out}: exists and is not an estimate directory (no estimate.json); "
            f"choose a new --out or remove it"
        )


def near_distance(fov: float) -> float:
    """Camera height for which a ``fov``-degree frame is exactly the sample [-1, 1]²."""
    return 1.0 / math.tan(math.radians(fov) / 2)


def capture_intensities(flash_path: str) -> dict[str, float]:
    """Flash intensities per shot file name from a ``capture.json`` beside the flash shot ({} if
    none or not an ``ebr capture`` directory)."""
    meta_path = Path(flash_path).resolve().parent / "capture.json"
    if not meta_path.is_file():
        return {}
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        return {}
    if not isinstance(meta, dict) or meta.get("format") != "ebr-capture/1":
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


def _intensities(cfg: EstimateConfig, inputs: Inputs, maps: SVBRDF, shots: dict[str, Shot]) -> dict:
    import dataclasses

    result = {}
    known = capture_intensities(cfg.flash)
    for name in ("flash", "far_flash"):
        if name not in shots:
            continue
        d = shots[name].camera[2]
        if cfg.flash_intensity is not None:
            value = cfg.flash_intensity * (d / near_distance(inputs.fov)) ** 2
            source = "--flash-intensity"
        elif Path(inputs.paths[name]).name in known:
            value, source = known[Path(inputs.paths[name]).name], "capture.json"
        else:
            mask = ~inputs.saturated
            value = fit_flash_intensity(
                maps, shots[name], inputs.flash_only_image(far=name == "far_flash"), mask
            )
            source = "fitted"
        shots[name] = dataclasses.replace(shots[name], flash_intensity=float(value))
        result[name] = {"intensity": float(value), "source": source}
    return result


def _check_prediction(pred, grid: int, flash_only: bool):
    maps = getattr(pred, "maps", None)
    if not isinstance(maps, SVBRDF):
        raise RuntimeError(f"the network returned {type(maps).__name__} maps, not an SVBRDF")
    if maps.shape != (grid, grid):
        raise RuntimeError(f"the network returned {maps.shape} maps for a {grid}x{grid} grid")
    env = getattr(pred, "env", None)
    if flash_only:
        return maps, None
    if env is not None and not isinstance(env, SGEnvironment):
        raise RuntimeError(f"the network returned a {type(env).__name__} environment, not an SGEnvironment")
    return maps, env if env is not None else SGEnvironment.empty()


def model_takes_far(bundle) -> bool:
    """Whether the model's lighting net reads the far pair (a near-far model)."""
    lighting = getattr(bundle, "lighting", None)
    config = getattr(lighting, "config", None)
    return getattr(config, "num_shots", 4) == 4


def _predict(inf, bundle, inputs: Inputs):
    im = inputs.images
    if not model_takes_far(bundle):  # a near model: the far pair serves the re-renders and refinement
        return inf.predict(bundle, im["flash"], im.get("noflash"))
    return inf.predict(bundle, im["flash"], im.get("noflash"), im.get("far_flash"), im.get("far_noflash"))


def run_estimate(
    cfg: EstimateConfig,
    *,
    truth: SVBRDF | None = None,
    log: Callable[[str], None] | None = None,
    bar: Callable | None = None,
    bundle=None,
) -> dict:
    """Run the estimate described by ``cfg``; return the summary (also ``estimate.json``).

    ``truth``: ground-truth maps (``ebr demo``) to compare against, per map. ``log(msg)``: stage
    messages (stderr in the command); ``bar``: a tqdm-like factory for the refinement progress.
    ``bundle``: the model already loaded from ``cfg.checkpoint`` (callers that estimate several
    captures load it once); None loads it here.
    """
    log = log or (lambda msg: None)
    timings: dict[str, float] = {}
    t_start = time.perf_counter()

    def stage(name, t0):
        timings[name] = round(time.perf_counter() - t0, 3)

    out = Path(cfg.out)
    t0 = time.perf_counter()
    check_out_dir(out)
    inputs = load_inputs(
        cfg.flash,
        cfg.noflash,
        cfg.far_flash,
        cfg.far_noflash,
        exposure_ratio=cfg.exposure_ratio,
        fov=cfg.fov,
        max_shift=cfg.max_shift,
        saturation_level=cfg.saturation_level,
    )
    if cfg.refine.lobes and inputs.flash_only:
        raise InputError("--refine-lobes needs --noflash: a flash-only capture has no lighting to refine")
    stage("inputs", t0)
    for w in inputs.warnings:
        log(f"warning: {w}")

    t0 = time.perf_counter()
    inf = inference_module()
    if bundle is None:
        bundle = inf.load_model(cfg.checkpoint)
    grid = model_grid(bundle)
    if inputs.has_far and not model_takes_far(bundle):
        inputs.warnings.append(
            "the model reads near captures only: the far shots are used for the re-renders and the "
            "refinement, not for the prediction"
        )
        log(f"warning: {inputs.warnings[-1]}")
    work = working_size(inputs.size[0], grid, cfg.tile, cfg.max_size)
    stage("model", t0)

    t0 = time.perf_counter()
    log(f"predicting at {grid}x{grid}" + ("" if inputs.flash_only else " (lighting + maps)"))
    pred = _predict(inf, bundle, inputs.resampled((grid, grid)))
    maps, env = _check_prediction(pred, grid, inputs.flash_only)
    stage("predict", t0)

    tiled = work > grid
    work_inputs = inputs.resampled((work, work))
    if tiled:
        t0 = time.perf_counter()
        log(f"tiled inference at {work}x{work} ({grid}-pixel tiles, overlap {cfg.tile_overlap})")

        def predict_tile(crops):
            tile_inputs = Inputs(
                images=crops, paths=inputs.paths, saturated=np.zeros((grid, grid), bool), fov=inputs.fov
            )
            return _check_prediction(_predict(inf, bundle, tile_inputs), grid, True)[0]

        maps = merge_detail(maps, tiled_maps(predict_tile, work_inputs.images, grid, cfg.tile_overlap))
        stage("tiles", t0)

    t0 = time.perf_counter()
    shots = _shots(work_inputs)
    flash_info = _intensities(cfg, work_inputs, maps, shots)
    mask = ~work_inputs.saturated
    targets = [ShotTarget(shots[k], work_inputs.images[k], mask) for k in shots]
    mode, spp = cfg.refine.mode, cfg.refine.spp
    net_errors, net_renders = rerender_errors(maps, env, targets, mode, spp)
    stage("rerender", t0)

    refined = None
    final_maps, final_env, final_renders, final_errors = maps, env, net_renders, net_errors
    if cfg.refine.steps > 0:
        t0 = time.perf_counter()
        log(f"refining: {cfg.refine.steps} steps" + (" (maps + lobes)" if cfg.refine.lobes else " (maps)"))
        pbar = bar(total=cfg.refine.steps, desc="refine", unit="step") if bar else None

        def progress(step, total, loss):
            if pbar is not None:
                pbar.n = step
                pbar.set_postfix_str(f"loss {loss:.4g}")
                pbar.refresh()

        refined = refine(maps, env, targets, cfg.refine, progress, before=net_errors)
        if pbar is not None:
            pbar.close()
        if refined.loss_rose:
            log(f"warning: refinement {refined.loss_note()}")
        final_maps, final_env = refined.maps, refined.env
        final_errors, final_renders = refined.after, refined.renders
        stage("refine", t0)

    summary = {
        "format": ESTIMATE_FORMAT,
        "version": __version__,
        "out": str(out),
        "capture": "flash-only" if inputs.flash_only else ("near-far" if inputs.has_far else "near"),
        "inputs": inputs.to_json(),
        "model_grid": grid,
        "resolution": work,
        "tiled": tiled,
        "render_mode": mode,
        "flash": flash_info,
        "lobes": 0 if final_env is None else final_env.num_lobes,
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
        },
        "prediction_timings": {
            k: float(v)
            for k, v in (getattr(pred, "timings", None) or {}).items()
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
    from .report import write_report

    with atomic_dir(out) as tmp:
        files += outputs.write_maps(final_maps, tmp / "maps", "ebr estimate")
        if refined is not None:
            files += outputs.write_maps(
                maps, tmp / "maps_network", "ebr estimate (network, before refinement)"
            )
        if final_env is not None:
            final_env.save(tmp / "env.json")
            files += outputs.env_pictures(final_env, tmp)
        photos = {k: work_inputs.images[k] for k in shots}
        files += outputs.write_shots(tmp, photos, final_renders)
        if refined is not None:
            (tmp / "rerender_network").mkdir()
            for k, img in net_renders.items():
                outputs.preview(tmp / "rerender_network" / f"{k}.png", img, outputs.exposure_of(photos[k]))
                outputs.residual_png(tmp / "rerender_network" / f"{k}_residual.png", img, photos[k])
                files += [f"rerender_network/{k}.png", f"rerender_network/{k}_residual.png"]
        files += outputs.write_novel(
            final_maps, final_env, flash_info["flash"]["intensity"], tmp, near_distance(inputs.fov), mode
        )
        files += outputs.write_exemplars(tmp, pred)
        stage("outputs", t0)
        t0 = time.perf_counter()
        summary["files"] = sorted(files) + ["estimate.json", "report.html"]
        write_report(tmp, summary)
        stage("report", t0)
        summary["total_seconds"] = round(time.perf_counter() - t_start, 3)
        (tmp / "estimate.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    return summary


__all__ = [
    "ESTIMATE_FORMAT",
    "EstimateConfig",
    "run_estimate",
    "check_out_dir",
    "near_distance",
    "capture_intensities",
    "inference_module",
]
