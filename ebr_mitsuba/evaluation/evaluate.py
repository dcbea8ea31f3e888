"""``ebr eval``: a model (or a baseline) on every sample of a generated data set.

For each sample the model sees the photos only (an ``ebrenv`` model the flash / no-flash pair
through its :class:`~ebr_mitsuba.model.predictor.Predictor`, a ``dualloss`` model the five light
shots through its :class:`~ebr_mitsuba.model.predictor.LightsPredictor`; :func:`model_predictor`)
and its maps are scored against the ground truth with :mod:`ebr_mitsuba.metrics`. ``seconds`` per
sample is the wall time of the prediction alone (lighting, extraction, selection and the cascade
for ``ebrenv``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import torch

from .. import metrics
from ..errors import InputError
from ..model.predictor import LightsPredictor, Predictor, ViewsPredictor
from ..svbrdf import SVBRDF


def _truth(item: dict) -> SVBRDF:
    m = item["maps"].numpy().transpose(1, 2, 0)
    return SVBRDF(m[..., :3], m[..., 3:6], m[..., 6:9], m[..., 9], source="ground truth")


def _at_size(maps: SVBRDF, size: tuple[int, int]) -> SVBRDF:
    """A grid-sized model's maps area-resampled back to the data set's resolution ``size``."""
    if maps.shape == size:
        return maps
    from ..materials import resample_svbrdf

    return resample_svbrdf(maps, size)


def model_predictor(predictor: Predictor | LightsPredictor) -> Callable[[dict, list[str]], SVBRDF]:
    """``predict(item, shot_names) -> SVBRDF`` for a model's predictor
    (:func:`ebr_mitsuba.model.predict.load_predictor`): a flash / no-flash
    :class:`~ebr_mitsuba.model.predictor.Predictor` (an ``ebrenv`` model) or a
    :class:`~ebr_mitsuba.model.predictor.LightsPredictor` (a ``dualloss`` model, given every shot).

    The photos are divided by the sample's recorded exposure (the reference exposure of
    ``docs/conventions.md``, "Exposure"). Photos finer than the model's grid are area-averaged to
    the grid and the maps area-resampled
    back to the data set's resolution (the estimate a grid-sized model makes of that capture)."""
    if isinstance(predictor, LightsPredictor):
        return _lights_predictor(predictor)
    if isinstance(predictor, ViewsPredictor):
        raise InputError(
            "a 'mair' (multi-view) model: ebr eval scores flash / no-flash and five-light models; "
            "estimate a multi-view capture with 'ebr estimate --views DIR --checkpoint C' (docs/mair.md)"
        )

    def run(item: dict, names: list[str]) -> SVBRDF:
        photos = item["photos"] / float(item["exposure"])  # the reference exposure, as in training
        if "noflash" not in names:
            raise InputError(f"the data set has shots {names}; an ebrenv model needs flash / no-flash pairs")
        img = {n: photos[k].permute(1, 2, 0).numpy() for k, n in enumerate(names)}
        size = img[names[0]].shape[:2]
        grid = predictor.grid
        if size != (grid, grid):  # a data set finer than the model's grid: the grid-resampled estimate
            from ..imageio import resize_area

            img = {n: resize_area(a, (grid, grid)) for n, a in img.items()}
        far = ()
        if predictor.takes_far:  # a near-far model reads the far pair too
            if "far_flash" not in img or "far_noflash" not in img:
                raise InputError(
                    f"the data set has shots {names}; this near-far model needs a near-far data set"
                )
            far = (img["far_flash"], img["far_noflash"])
        return _at_size(predictor.predict(img["flash"], img["noflash"], *far).maps, size)

    return run


def _lights_predictor(predictor: LightsPredictor) -> Callable[[dict, list[str]], SVBRDF]:
    """:func:`model_predictor` of a five-light model: every shot of the sample, in order."""

    def run(item: dict, names: list[str]) -> SVBRDF:
        photos = item["photos"] / float(item["exposure"])  # the reference exposure, as in training
        size = tuple(photos.shape[-2:])
        grid = int(predictor.grid)
        if size != (grid, grid):  # the grid-resampled estimate, as for the flash / no-flash models
            photos = torch.nn.functional.interpolate(photos, size=(grid, grid), mode="area")
        return _at_size(predictor.predict_lights([p.permute(1, 2, 0).numpy() for p in photos]).maps, size)

    return run


def nominal_flash_intensity(root: str | Path) -> float:
    """The flash intensity of the data set ``root`` (its ``dataset.json``), before each sample's
    exposure."""
    meta = json.loads((Path(root) / "dataset.json").read_text())
    return float(meta["config"]["capture"]["flash_intensity"])


def estimate_sample(
    predictor,
    root: str | Path,
    index: int,
    refine=None,
    flash_fit: bool = True,
    far: bool = True,
    nominal: float | None = None,
    options: dict | None = None,
):
    """What ``ebr estimate`` makes of sample ``index`` of the data set ``root`` from its photo files
    (:func:`estimate_predictor`, whose arguments these are; ``nominal``: the data set's
    :func:`nominal_flash_intensity`, read when not given; ``options``: further
    :class:`~ebr_mitsuba.estimate.pipeline.EstimateConfig` fields, e.g. ``{"highlight_tilt": False}``): the
    :class:`~ebr_mitsuba.estimate.pipeline.EstimateResult`, its files written into a temporary
    directory and dropped."""
    import tempfile

    from ..data.store import sample_dirname
    from ..estimate.pipeline import EstimateConfig, run_estimate
    from ..estimate.refine import RefineConfig

    root = Path(root)
    if nominal is None:
        nominal = nominal_flash_intensity(root)
    sample = root / sample_dirname(int(index))
    record = json.loads((sample / "sample.json").read_text())
    shots = {s["name"]: sample / s["photo"] for s in record["shots"]}
    if "noflash" not in shots:
        raise InputError(f"{sample}: shots {sorted(shots)}; an estimate needs a flash / no-flash pair")
    # the flash in photo units: what capture.json states for an ebr capture directory
    intensity = nominal * float(record["camera"]["exposure"])
    with tempfile.TemporaryDirectory(prefix="ebr-eval-") as tmp:
        cfg = EstimateConfig(
            flash=str(shots["flash"]),
            noflash=str(shots["noflash"]),
            far_flash=str(shots["far_flash"]) if far and "far_flash" in shots else None,
            far_noflash=str(shots["far_noflash"]) if far and "far_noflash" in shots else None,
            out=str(Path(tmp) / "estimate"),
            refine=refine or RefineConfig(),
            flash_intensity=intensity,
            flash_fit=flash_fit,
            **(options or {}),
        )
        return run_estimate(cfg, predictor=predictor)


def estimate_predictor(
    predictor, data: str | Path, refine=None, flash_fit: bool = True, far: bool = True
) -> Callable[[dict, list[str]], dict]:
    """``predict(item, shot_names) -> {"estimate": SVBRDF[, "estimate + refinement": SVBRDF]}``:
    what ``ebr estimate`` makes of each sample's photo files (its working size, full-resolution
    cascade and, with ``refine`` steps > 0, test-time refinement), with the data set's known flash
    intensity in photo units (× the sample's exposure, as an ``ebr capture`` directory's
    ``capture.json`` states it).

    ``flash_fit``: ``ebr estimate``'s flash-profile fit (its default, on; False: ``--no-flash-fit``).
    ``far``: a near-far sample's far shots are given to ``ebr estimate`` (False: its near shots
    only, the same capture estimated as a near one).
    ``predictor``: the :class:`~ebr_mitsuba.model.predictor.Predictor` of the estimates. Each
    sample runs :func:`ebr_mitsuba.estimate.pipeline.run_estimate` into a temporary directory
    (:func:`estimate_sample`; its files are written as by ``ebr estimate``); the maps are the ones
    it returns in memory (``maps`` and, refined, ``network_maps``)."""
    from ..estimate.refine import RefineConfig

    root = Path(data)
    nominal = nominal_flash_intensity(root)
    refine = refine or RefineConfig()

    def run(item: dict, names: list[str]) -> dict:
        if "noflash" not in names:
            raise InputError(f"{root}: shots {names}; the estimate predictor needs flash / no-flash pairs")
        result = estimate_sample(predictor, root, int(item["index"]), refine, flash_fit, far, nominal)
        if refine.steps > 0:
            return {"estimate": result.network_maps, "estimate + refinement": result.maps}
        return {"estimate": result.maps}

    return run


def evaluate(
    predictor: Callable[[dict, list[str]], SVBRDF],
    data: str | Path,
    *,
    limit: int = 0,
    seed: int = 0,
    intensity: float | None = None,
    progress=None,
) -> dict:
    """Per-sample and averaged metrics (:mod:`ebr_mitsuba.metrics`) of ``predictor`` on the data set
    ``data``."""
    return evaluate_many(
        lambda item, names: {"": predictor(item, names)},
        data,
        limit=limit,
        seed=seed,
        intensity=intensity,
        progress=progress,
    )[""]


def evaluate_many(
    predictor: Callable[[dict, list[str]], dict],
    data: str | Path,
    *,
    limit: int = 0,
    seed: int = 0,
    intensity: float | None = None,
    progress=None,
) -> dict[str, dict]:
    """:func:`evaluate` of a predictor that returns several estimates per sample (name → SVBRDF,
    e.g. the network's maps and the refined ones): name → the metrics of that estimate; each
    estimate's ``seconds`` is the wall time of the whole call."""
    from ..data.dataset import GeneratedDataset

    ds = GeneratedDataset(data)
    if intensity is None:
        intensity = float(ds.dataset["config"]["capture"]["flash_intensity"])
    pairs = metrics.rerender_pairs(seed)
    n = len(ds) if limit <= 0 else min(limit, len(ds))
    rows: dict[str, list[dict]] = {}
    for i in progress(range(n), desc="eval", unit="sample") if progress else range(n):
        item = ds[i]
        t0 = time.perf_counter()
        estimates = predictor(item, ds.shot_names)
        seconds = time.perf_counter() - t0
        truth = _truth(item)
        truth_renders = metrics.rerenders(truth, pairs, intensity)  # once for all the estimates
        for name, est in estimates.items():
            row = metrics.sample_metrics(est, truth, pairs, intensity, truth_renders)
            row.update(
                index=i,
                seconds=seconds,
                material=ds.index["samples"][i]["material"],
                env=ds.index["samples"][i]["env"],
            )
            rows.setdefault(name, []).append(row)
    results = {}
    for name, r in rows.items():
        out = metrics.average(r)
        out["per_sample"] = r
        out["seed"] = seed
        results[name] = out
    return results


def group_means(rows: list[dict], key: Callable[[dict], str]) -> dict:
    """Averages of rows grouped by ``key(row)`` (e.g. real vs procedural materials)."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault(key(r), []).append(r)
    return {k: metrics.average(v) for k, v in sorted(groups.items())}


def material_group(row: dict) -> str:
    """``"procedural"`` or ``"real"`` from a row's material spec."""
    return "procedural" if str(row.get("material", "")).startswith("procedural:") else "real"


def material_class(row: dict) -> str:
    """A row's material class: the real set's class (``materials_extra/index.json``; the sets of
    ``materials/`` by name), or ``procedural:FAMILY``."""
    from ..data.split import material_class as real_class

    spec = str(row.get("material", ""))
    if spec.startswith("procedural:"):
        return "procedural:" + spec.split(":")[1]
    return real_class(spec)


def oracle_predictor(item: dict, names: list[str]) -> SVBRDF:
    """Baseline: the sample's own ground-truth means (:func:`.baselines.oracle_constant`)."""
    from .baselines import oracle_constant

    return oracle_constant(_truth(item))


def truth_predictor(transform: Callable[[SVBRDF], SVBRDF]) -> Callable[[dict, list[str]], SVBRDF]:
    """Diagnostic: each sample's ground truth passed through ``transform`` (e.g.
    :func:`.baselines.truth_but`: some maps replaced by their constant means)."""
    return lambda item, names: transform(_truth(item))


__all__ = [
    "estimate_predictor",
    "evaluate",
    "evaluate_many",
    "group_means",
    "material_class",
    "material_group",
    "model_predictor",
    "oracle_predictor",
    "truth_predictor",
]
