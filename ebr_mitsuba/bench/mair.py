"""``ebr bench mair``: the multi-view (MAIR) models of issue 13 on the 3×3 captures of the fixed
test split; writes ``mair_eval.md`` with ``mair_eval.jpg`` (views, maps, per-pixel lighting and an
insertion of one test sample) and ``mair_eval_maps.jpg`` (contact sheet).

Test captures: ``configs/data_real_multiview_test.toml`` (the real material sets and HDR maps of
``scenes/test_split.toml``, the seed and draws of ``configs/data_real_test.toml``; the nine camera
images of ``ebr capture --setup multi-view``, path traced by Mitsuba at 256²). Every model sees
each sample as ``ebr estimate --views SAMPLE_DIR`` does (:func:`ebr_mitsuba.estimate.multiview.
estimate_views`: rectification onto the sample grid, the known flash intensity in photo units).
Figures, all on the same samples:

* **maps**: per-map RMSE and their mean, re-render RMSE and SSIM under 30 seeded random lights and
  views (:func:`ebr_mitsuba.evaluation.evaluate.evaluate`, the protocol of ``ebr bench models``)
  for every run of ``EBR_MAIR_RUNS`` (``name=RUN_DIR`` separated by ``;``; the ablation of
  ``configs/mair_small*.toml``: attention, mean pooling, centre view only), the first run's model
  fed its centre view alone (no retraining), the first run with the multi-view specular fit (the
  default of ``ebr estimate --views``; the other rows are ``--no-view-fit``), the oracle constant
  (each sample's own mean maps), with ``EBR_TRAIN_DATA`` the training set's mean maps, and with
  ``EBR_SPLIT_DATA`` (the near flash / no-flash test split) the shipped EBREnv model as ``ebr
  estimate`` runs it on the same materials;
* **lighting**: MAIR's g4, the scale-invariant log-MSE (:func:`ebr_mitsuba.nets.losses.
  scale_invariant_log_mse`) of each pixel's incident radiance on the 8 × 16 hemisphere grid of
  :func:`~ebr_mitsuba.nets.mair_lighting.hemisphere_directions` against the truth: the sample's
  environment lobes (``env.json``; every pixel of the unoccluded plane sees the whole distant
  environment), beside the same error of a constant radiance (a lighting estimate that knows
  nothing);
* **insertion**: ``ebr insert``'s default object (a grey diffuse sphere on the sample) rendered by
  Mitsuba into the first run's estimate with the view fit (its maps, the centre pixel's lighting
  in photo units averaged over azimuth, as ``ebr estimate --views`` writes env.json by default) and
  into the truth (the true maps, the true environment as rendered: the rotated, scaled HDR map, at
  the sample's exposure), and the truth again with another seed: the insertion's relative RMSE
  against the truth's own noise floor, on the first :data:`INSERT_SAMPLES` test samples.

Inputs: ``EBR_MAIR_DATA`` names the generated multi-view test set, ``EBR_MAIR_RUNS`` the training
runs (the page's first section has the commands).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from ..errors import InputError
from ._common import lobes_emitter, machine, named_runs, truth_emitter
from .models import _recording, _row, _sheet, _small, training_summary

DEFAULT_OUT = "docs"
PAGE = "mair_eval.md"
QUICK_LIMIT = 2
CENTRE_GAIN = 0.15  # issue 13: attention's mean per-map RMSE at least this far below the centre view's
MEAN_GAIN = 0.05  # ... and this far below mean pooling's
INSERT_RATIO = 2.0  # ... and the insertion's relative RMSE within this factor of the truth's noise floor
INSERT_SAMPLES = 4  # insertions on the first test samples (each: three Mitsuba renders)
INSERT_RES, INSERT_SPP = 128, 256
QUICK_INSERT = (1, 64, 16)  # samples, resolution, spp of --quick
CENTRE_ONLY = "first run, centre view only (no retraining)"
WITH_FIT = " + view fit (ebr estimate --views)"
RUNS_HINT = "give the runs of 'ebr train configs/mair_small*.toml' (docs/mair_eval.md)"
REGENERATE = """\
export EBR_DATA_DIR=../shared/data EBR_MAIR_DATA=/tmp/ebr-data/real_mv_test \\
       EBR_TRAIN_DATA=/tmp/ebr-data/real_mv_train
ebr generate configs/data_real_multiview_test.toml --out $EBR_MAIR_DATA --workers 2
ebr generate configs/data_real_multiview_train.toml --out $EBR_TRAIN_DATA --workers 2
for c in mair_small mair_small_mean mair_small_centre; do
  ebr train configs/$c.toml --out /tmp/ebr-runs/$c
done
R=/tmp/ebr-runs
export EBR_MAIR_RUNS="attention=$R/mair_small;mean pooling=$R/mair_small_mean"
EBR_MAIR_RUNS+=";centre view only=$R/mair_small_centre"
EBR_SPLIT_DATA=/tmp/ebr-data/real_test ebr bench mair  # this page (EBREnv on the near split)"""


def unavailable() -> str | None:
    data = os.environ.get("EBR_MAIR_DATA")
    if not data or not Path(data).is_dir():
        return "EBR_MAIR_DATA does not name a multi-view test set (docs/mair_eval.md)"
    if not os.environ.get("EBR_MAIR_RUNS", "").strip():
        return "EBR_MAIR_RUNS names no MAIR training run (docs/mair_eval.md)"
    return None


class CentreViewOnly:
    """A :class:`~ebr_mitsuba.model.predictor.ViewsPredictor` feeding ``inner`` the centre camera's
    view alone (:func:`~ebr_mitsuba.nets.mair_views.view_indices`): a nine-view model asked what one
    view tells it, out of its training distribution."""

    def __init__(self, inner):
        self.inner = inner

    @property
    def grid(self) -> int:
        return self.inner.grid

    @property
    def views(self) -> int:
        return self.inner.views

    def predict_views(self, views, weights=None, cameras=None):
        from ..nets.mair_views import view_indices

        (k,) = view_indices("centre", cameras)
        w = None if weights is None else weights[k : k + 1]
        cams = None if cameras is None else [cameras[k]]
        return self.inner.predict_views(views[k : k + 1], w, cams)


@dataclass
class Recorded:
    """What a views predictor leaves per sample besides its maps: the g4 lighting errors of its
    lobes and of a constant, and for the first samples the estimate itself (for the insertions
    and the figure)."""

    lighting: list[float] = field(default_factory=list)
    constant: list[float] = field(default_factory=list)
    estimates: list = field(default_factory=list)


def lighting_errors(prediction_lighting, item: dict, rows: int, cols: int) -> tuple[float, float]:
    """(g4 of the predicted per-pixel lobes, g4 of a constant radiance) against the sample's
    environment lobes at every pixel (module docstring)."""
    import torch

    from ..estimate.multiview import _torch_lighting
    from ..nets.drwrap import lobes_from_padded
    from ..nets.losses import scale_invariant_log_mse
    from ..nets.mair_lighting import hemisphere_directions
    from ..train.phases import incident_radiance

    dirs = hemisphere_directions(rows, cols)
    g = prediction_lighting.shape[0]
    pred = _torch_lighting(prediction_lighting, g).radiance_image(dirs)  # (1, 3D, G, G)
    lobes = lobes_from_padded(item["sg"][None], item["sg_mask"][None])
    truth = incident_radiance(lobes, dirs).reshape(1, -1, 1, 1).expand_as(pred)
    with torch.no_grad():
        return (
            float(scale_invariant_log_mse(pred, truth)),
            float(scale_invariant_log_mse(torch.ones_like(truth), truth)),
        )


def views_predictor(predictor, data: Path, record: Recorded, keep: int, view_fit: bool = False):
    """``predict(item, names) -> SVBRDF``: what ``ebr estimate --views SAMPLE_DIR`` makes of each
    sample with ``predictor`` (``view_fit``: its multi-view specular fit, the default of ``ebr
    estimate --views``; False: ``--no-view-fit``, the network's maps); the lighting errors go to
    ``record``, and the first ``keep`` estimates
    (:class:`~ebr_mitsuba.estimate.multiview.ViewsEstimate`) too."""
    from ..data.store import sample_dirname
    from ..estimate.multiview import MultiViewConfig, estimate_views
    from ..materials import resample_svbrdf
    from ..model.config import MAIRLossConfig

    loss = MAIRLossConfig()

    def run(item, names):
        sample = data / sample_dirname(int(item["index"]))
        with tempfile.TemporaryDirectory(prefix="ebr-bench-mv-") as tmp:
            cfg = MultiViewConfig(views=str(sample), out=str(Path(tmp) / "unused"), view_fit=view_fit)
            est = estimate_views(cfg, predictor)
        mine, const = lighting_errors(est.prediction.lighting, item, loss.lighting_rows, loss.lighting_cols)
        record.lighting.append(mine)
        record.constant.append(const)
        if len(record.estimates) < keep:
            record.estimates.append(est)
        size = tuple(item["maps"].shape[1:])
        return est.maps if est.maps.shape == size else resample_svbrdf(est.maps, size)

    return run


SWAPS = (  # the insertion's error taken apart: each plate swaps one part of the estimate for the truth
    ("maps", "estimated maps, true environment"),
    ("lighting", "true maps, estimated lighting"),
    ("lobes", "true maps, the true environment's SG lobes"),
)


def insertions(estimates: list, truths: list, samples: list[Path], res: int, spp: int, log=print) -> dict:
    """The default insertion (module docstring) into each estimate and its truth: per sample the
    relative RMSE of the estimate's against the truth's, the truth's noise floor (seed 1 against
    seed 0), the same error of the plates of :data:`SWAPS` (the estimated maps under the true
    environment, the true maps under the estimated lighting, the true maps under the SG lobes
    fitted to the true environment: what MAIR's lighting representation allows at best) and the
    pictures; skipped for dark samples."""
    from ..estimate.multiview import insertion_environment
    from ..insert import Plate
    from ..scene import sg_emitter_dict
    from .insert import measure

    rows, pictures = [], []
    for est, truth, sample in zip(estimates, truths, samples):
        made = truth_emitter(sample)
        if made is None:
            continue
        emitter, described = made
        fov = est.shots[len(est.shots) // 2].fov
        env = insertion_environment(est.lighting)  # what ebr estimate --views writes to env.json
        lighting = partial(sg_emitter_dict, env)
        # a sample with the no-flash view ([capture] noflash_view): composited into it, as ebr insert does
        photo = next((est.views.images[s.name] for s in est.shots if s.flash is None), None)
        plate = Plate(sample, "estimate", est.maps, fov, lighting, photo=photo)
        swaps = {
            "maps": Plate(sample, "estimate", est.maps, fov, emitter, photo=photo),
            "lighting": Plate(sample, "estimate", truth, fov, lighting, photo=photo),
        }
        lobes = lobes_emitter(sample)
        if lobes is not None:
            swaps["lobes"] = Plate(sample, "estimate", truth, fov, lobes[0], photo=photo)
        log(f"[bench mair] insertion into {sample.name} ({res}², {spp} spp, {3 + len(swaps)} renders)")
        r = measure(plate, Plate(sample, "capture", truth, fov, emitter), "diffuse", res, spp, others=swaps)
        rows.append(
            {
                "sample": sample.name,
                "env": described,
                "rel_rmse": r["composite_rel"],
                "noise_floor": r["floor_rel"],
                "swaps": r["others"],
                "composited": r["composited"],
            }
        )
        pictures.append(r["picture"])
    return {"rows": rows, "pictures": pictures, "res": res, "spp": spp}


def _figure(est, truth, insertion_picture, path: Path) -> None:
    """One test sample: its nine rectified views, the truth's and the estimate's maps, the per-pixel
    lighting of a 4 × 4 grid of pixels and the insertion (estimate | truth | difference × 4)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..estimate.multiview import hemisphere_mosaic
    from ..fsutil import atomic_path
    from ..imageio import linear_to_srgb

    views = [est.views.images[n] for n in est.names]
    gain = 1.0 / max(float(np.percentile(np.stack(views), 99.5)), 1e-6)
    rowsv = [np.concatenate(views[r * 3 : r * 3 + 3], axis=1) for r in range(3)]
    mosaic = linear_to_srgb(np.clip(np.concatenate(rowsv, axis=0) * gain, 0, 1))
    lights = hemisphere_mosaic(est.lighting)
    light_gain = 1.0 / max(float(np.percentile(lights, 99.5)), 1e-12)

    def tiles(m):
        return [
            (m.normal + 1) / 2,
            linear_to_srgb(np.clip(m.diffuse, 0, 1)),
            linear_to_srgb(np.clip(m.specular, 0, 1)),
            np.repeat(np.clip(m.roughness, 0, 1)[..., None], 3, axis=2),
        ]

    fig = plt.figure(figsize=(12, 6.2))
    grid = fig.add_gridspec(2, 6)
    panels = [
        (grid[0, 0:2], mosaic, "the 9 views, rectified"),
        (grid[0, 2], linear_to_srgb(np.clip(lights * light_gain, 0, 1)), "lighting, 4×4 pixels"),
    ]
    if insertion_picture is not None:
        ins = linear_to_srgb(np.clip(insertion_picture, 0, 1))
        panels.append((grid[0, 3:6], ins, "insertion: estimate | truth | |diff| × 4"))
    names = ("normal", "diffuse", "specular", "roughness")
    both = [np.concatenate([a, b], axis=0) for a, b in zip(tiles(truth), tiles(est.maps))]
    for k, (img, name) in enumerate(zip(both, names)):
        panels.append((grid[1, k], img, f"{name}: truth / estimate"))
    for spec, img, title in panels:
        ax = fig.add_subplot(spec)
        ax.imshow(np.clip(img, 0, 1))
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=80, format="jpg", pil_kwargs={"quality": 85})
    plt.close(fig)


def _role(run_dir: Path) -> str:
    """``attention``, ``mean pooling`` or ``centre view``: what a MAIR run's [model] table makes it."""
    model = json.loads((run_dir / "config.json").read_text()).get("model", {})
    if model.get("views") == "centre":
        return "centre view"
    return "mean pooling" if model.get("fusion") == "mean" else "attention"


def _budget(summary: dict) -> str:
    phases = summary["phases"]
    steps = " / ".join(str(phases[p]["steps"]) for p in ("normal", "lighting", "brdf") if p in phases)
    hours = sum(p["seconds"] for p in phases.values()) / 3600
    return f"{steps} steps, {hours:.2f} h"


def run(out_dir: Path | str = DEFAULT_OUT, quick: bool = False, log=print) -> Path:
    """Evaluate every predictor on ``$EBR_MAIR_DATA`` and write ``out_dir/mair_eval.md``."""
    from ..commands._common import progress
    from ..data.dataset import GeneratedDataset
    from ..data.store import sample_dirname
    from ..estimate.multiview import load_mair
    from ..evaluation.baselines import MeanMaps
    from ..evaluation.evaluate import _truth, estimate_predictor, evaluate, oracle_predictor
    from ..fsutil import atomic_write_text
    from ..model.predict import load_predictor

    reason = unavailable()
    if reason:
        raise InputError(reason)
    data = Path(os.environ["EBR_MAIR_DATA"])
    ds = GeneratedDataset(data)
    if ds.dataset.get("config", {}).get("capture", {}).get("setup") != "multi-view":
        raise InputError(f"$EBR_MAIR_DATA = {data}: not a multi-view data set; {RUNS_HINT}")
    runs = named_runs("EBR_MAIR_RUNS", RUNS_HINT)
    out_dir = Path(out_dir)
    n = len(ds) if not quick else min(QUICK_LIMIT, len(ds))
    n_insert, res, spp = QUICK_INSERT if quick else (INSERT_SAMPLES, INSERT_RES, INSERT_SPP)
    n_insert = min(n_insert, n)
    truths = [_truth(ds[i]) for i in range(n)]

    first = load_mair(runs[0][1] / "model.pt")
    records: dict[str, Recorded] = {}
    predictors = []
    for k, (name, path) in enumerate(runs):
        model = first if k == 0 else load_mair(path / "model.pt")
        records[name] = Recorded()
        predictors.append((name, views_predictor(model, data, records[name], 0)))
    fitted = f"{runs[0][0]}{WITH_FIT}"  # the default of ebr estimate --views: its estimates are inserted
    records[fitted] = Recorded()
    predictors.append((fitted, views_predictor(first, data, records[fitted], n_insert, view_fit=True)))
    records[CENTRE_ONLY] = Recorded()
    predictors.append((CENTRE_ONLY, views_predictor(CentreViewOnly(first), data, records[CENTRE_ONLY], 0)))
    predictors.append(("oracle constant", oracle_predictor))
    train = os.environ.get("EBR_TRAIN_DATA")
    if train:
        predictors.append(("training-set mean maps", MeanMaps.from_dataset(train).item_predictor()))

    t0 = time.perf_counter()
    results, sheets = {}, {}
    for name, predict in predictors:
        log(f"[bench mair] {name}")
        store: list = []
        results[name] = evaluate(_recording(predict, store), data, limit=n, progress=progress)
        sheets[name] = store
    ebrenv = None
    near = os.environ.get("EBR_SPLIT_DATA")
    if near:
        log("[bench mair] EBREnv shipped model, ebr estimate (near flash / no-flash test split)")
        estimate = estimate_predictor(load_predictor(None), near, flash_fit=True)
        ebrenv = evaluate(
            lambda item, names: estimate(item, names)["estimate"], near, limit=n, progress=progress
        )
    samples = [data / sample_dirname(int(ds[i]["index"])) for i in range(n_insert)]
    inserted = insertions(records[fitted].estimates, truths[:n_insert], samples, res, spp, log)
    seconds = time.perf_counter() - t0

    summaries = {name: training_summary(path) for name, path in runs}
    roles = {name: _role(path) for name, path in runs}
    out_dir.mkdir(parents=True, exist_ok=True)
    _sheet([_small(t) for t in truths], sheets, out_dir / "mair_eval_maps.jpg")
    est0 = records[fitted].estimates[0] if records[fitted].estimates else None
    if est0 is not None:
        picture = inserted["pictures"][0] if inserted["pictures"] else None
        _figure(est0, truths[0], picture, out_dir / "mair_eval.jpg")
    record = {
        "date": time.strftime("%Y-%m-%d"),
        "machine": machine(),
        "n": n,
        "quick": quick,
        "results": {k: {kk: vv for kk, vv in v.items() if kk != "per_sample"} for k, v in results.items()},
        "ebrenv": None if ebrenv is None else {k: v for k, v in ebrenv.items() if k != "per_sample"},
        "lighting": {
            name: {"g4": float(np.mean(r.lighting)), "constant": float(np.mean(r.constant))}
            for name, r in records.items()
        },
        "insertion": inserted["rows"],
        "roles": roles,
    }
    page = _page(record, summaries, runs, ds, seconds, inserted, est0 is not None)
    atomic_write_text(out_dir / "mair_eval.json", json.dumps(record, indent=1, default=float) + "\n")
    atomic_write_text(out_dir / PAGE, page)
    return out_dir / PAGE


def acceptance_lines(record: dict) -> list[str]:
    """The issue's two comparisons of mean per-map RMSE: attention against the centre view only
    (trained so, or else the attention model fed one view) and against mean pooling."""
    res, roles = record["results"], record["roles"]
    by_role = {role: name for name, role in roles.items()}
    if "attention" not in by_role:
        return ["(No attention run in EBR_MAIR_RUNS: the acceptance comparisons need one.)", ""]
    att = res[by_role["attention"]]["per_map_rmse"]["mean"]
    lines = []
    centre = by_role.get("centre view", CENTRE_ONLY)
    for other, gain, what in (
        (centre, CENTRE_GAIN, "the centre view alone"),
        (by_role.get("mean pooling"), MEAN_GAIN, "mean pooling"),
    ):
        if other is None or other not in res:
            lines.append(f"- attention against {what}: not measured (no such run in EBR_MAIR_RUNS)")
            continue
        v = res[other]["per_map_rmse"]["mean"]
        drop = (v - att) / v if v > 0 else 0.0
        ok = drop >= gain
        lines.append(
            f"- **attention against {what}** ({other}): mean per-map RMSE {att:.4f} against {v:.4f}, "
            f"{drop:+.0%} lower (acceptance: at least {gain:.0%} lower) — {'yes' if ok else 'no'}"
        )
    fitted = f"{by_role['attention']}{WITH_FIT}"
    if fitted in res:
        v = res[fitted]["per_map_rmse"]["mean"]
        lines.append(
            f"- with the multi-view specular fit ({fitted}, the default of `ebr estimate --views`): mean "
            f"per-map RMSE {v:.4f} against the network's {att:.4f} ({(att - v) / att:+.0%}); not an "
            "acceptance figure: the fit reads F0 and roughness off all nine views for every network alike"
        )
    ins = record.get("insertion") or []
    if ins:
        ratios = [_ratio(r["rel_rmse"], r) for r in ins]
        ok = sum(q <= INSERT_RATIO for q in ratios)
        lines.append(
            f"- **insertion** (first run + view fit): relative RMSE within {INSERT_RATIO:g}× of the "
            f"truth-vs-truth noise floor in {ok} of {len(ins)} samples (ratios "
            f"{', '.join(f'{q:.1f}' for q in ratios)}) — {'yes' if ok == len(ins) else 'no'}; "
            "where the error comes from: [Object insertion](#object-insertion)"
        )
    return lines + [""]


def _ratio(value: float, row: dict) -> float:
    """``value`` (a relative RMSE against the truth render) over the row's noise floor."""
    return value / row["noise_floor"] if row["noise_floor"] > 0 else float("inf")


def _swap_lines(ins: list[dict]) -> list[str]:
    """The table of :data:`SWAPS`: each plate's insertion error over the noise floor, per sample."""
    names = [(key, label) for key, label in SWAPS if any(key in r.get("swaps", {}) for r in ins)]
    if not names:
        return []

    def cell(r, key):
        v = r.get("swaps", {}).get(key)
        return "" if v is None else f"{_ratio(v, r):.1f}"

    return [
        "Where the error comes from: the same insertion with one part of the estimate swapped for the "
        "truth, each as its ratio to the noise floor (same truth render, same floor). The last column "
        "is the best MAIR's lighting representation allows: the true maps under the SG lobes fitted "
        "to the true environment (32 lobes; the estimate has 3 per pixel).",
        "",
        "| sample | estimate | " + " | ".join(label for _, label in names) + " |",
        "|---|---:|" + "---:|" * len(names),
        *(
            f"| {r['sample']} | {_ratio(r['rel_rmse'], r):.1f} | "
            + " | ".join(cell(r, key) for key, _ in names)
            + " |"
            for r in ins
        ),
        "",
    ]


def _page(record, summaries, runs, ds, seconds, inserted, figure: bool) -> str:
    head = "| predictor | normal | diffuse | roughness | specular | mean | re-render | SSIM | training |"
    rule = "|---|---:|---:|---:|---:|---:|---:|---:|---|"
    rows = []
    for name, res in record["results"].items():
        s = summaries.get(name)
        rows.append(_row(name, res, _budget(s) if s else ""))
    if record["ebrenv"] is not None:
        rows.append(
            _row(
                "EBREnv shipped model, ebr estimate (near flash / no-flash, same materials)", record["ebrenv"]
            )
        )
    cfg = ds.dataset.get("config", {})
    render = cfg.get("render", {})
    n, quick = record["n"], record["quick"]
    lines = [
        "# Multi-view estimation (MAIR): the models, the fusion ablation, lighting and insertion",
        "",
        "Generated by `ebr bench mair` (`ebr_mitsuba/bench/mair.py`); do not edit by hand.",
        f"Machine: {record['machine']}; {record['date']}; evaluation took {seconds:.0f} s"
        + (f"; **quick run: {n} samples only, not the documented figures**." if quick else "."),
        "",
        f"Test captures: {n} samples of `configs/data_real_multiview_test.toml` — the real material sets "
        "and HDR maps of the fixed test split (`scenes/test_split.toml`), the same draws as the EBREnv "
        "model's test split, as the camera images of `ebr capture --setup multi-view` (the nine flash "
        "views; the no-flash view where the config renders it), "
        f"{cfg.get('dataset', {}).get('resolution', '?')}², renderer `{render.get('renderer', '?')}` at "
        f"{render.get('spp', '?')} spp. Each model sees a sample as `ebr estimate --views SAMPLE_DIR` "
        "does (rectified onto the sample grid, the known flash intensity). Metrics as in "
        "[models.md](models.md): per-map RMSE (normals as (n+1)/2, roughness one channel) and their "
        "mean; re-render RMSE and SSIM under 30 seeded random lights and views. Networks and training: "
        "[mair.md](mair.md).",
        "",
        "```",
        REGENERATE,
        "```",
        "",
        "## Maps on the multi-view test split",
        "",
        head,
        rule,
        *rows,
        "",
        *(
            []
            if record["ebrenv"] is not None
            else [
                "The EBREnv flash / no-flash model on the same materials was not run here (no "
                '`EBR_SPLIT_DATA`): its figures on this split are the "shipped model, ebr estimate" row '
                "of [models.md](models.md) (and the EBREnv row of [fivelight.md](fivelight.md)).",
                "",
            ]
        ),
        f"*{CENTRE_ONLY}*: the first run's nine-view model fed the centre camera's view alone, out of "
        "its training distribution; the fair centre-view comparison is a model trained so "
        "(`configs/mair_small_centre.toml`, same budget).",
        "",
        "## Acceptance figures (issue 13)",
        "",
        *acceptance_lines(record),
        "## Lighting",
        "",
        "MAIR's g4 (scale-invariant log-MSE of each pixel's incident radiance on the 8 × 16 hemisphere "
        "grid) against the sample's environment lobes at every pixel, mean over the test samples; "
        "beside it the same error of a constant radiance (what a lighting estimate that knows nothing "
        "scores).",
        "",
        "| predictor | g4 of the per-pixel lobes | g4 of a constant |",
        "|---|---:|---:|",
        *(f"| {k} | {v['g4']:.4f} | {v['constant']:.4f} |" for k, v in record["lighting"].items()),
        "",
        "## Object insertion",
        "",
    ]
    ins = record["insertion"]
    if ins:
        ratio = [_ratio(r["rel_rmse"], r) for r in ins]
        lines += [
            f"`ebr insert`'s default object (a grey diffuse sphere a third of the sample wide) on the "
            f"first run's estimate with the view fit (`ebr estimate --views`' default) of the first "
            f"{len(ins)} test samples, rendered by Mitsuba at "
            f"{inserted['res']}², {inserted['spp']} spp, against the same insertion into the truth (true "
            "maps, the environment as rendered, at the sample's exposure); the noise floor is the truth "
            "rendered with another seed. "
            + (
                "Composited into each sample's no-flash view (`[capture] noflash_view`), as `ebr insert` "
                "does (the scale fit reads that view too)."
                if all(r.get("composited") for r in ins)
                else "Rendered whole (samples without the no-flash view)."
            ),
            "",
            "| sample | true environment | insertion rel. RMSE | truth-vs-truth noise floor | ratio |",
            "|---|---|---:|---:|---:|",
            *(
                f"| {r['sample']} | {r['env']} | {r['rel_rmse']:.4f} | {r['noise_floor']:.4f} | {q:.1f} |"
                for r, q in zip(ins, ratio)
            ),
            "",
            *_swap_lines(ins),
        ]
    else:
        lines += ["(No insertion: the first samples have no environment.)", ""]
    if figure:
        lines += [
            "![views, maps, lighting and an insertion of one test sample](mair_eval.jpg)",
            "",
            "*The first test sample: its nine views rectified onto the sample grid (top left), the first "
            "run's per-pixel lighting (scaled by the view fit) at a 4 × 4 grid of pixels (each hemisphere "
            "seen from above), the insertion; below, each map of the truth (top) and the estimate (bottom).*",
            "",
        ]
    lines += [
        "## Contact sheet",
        "",
        "Per test sample (rows): the truth's normal, diffuse, specular and roughness, then the same four "
        f"maps of each predictor in the order {', '.join(record['results'])} (96² thumbnails).",
        "",
        "![truth and estimates per test sample](mair_eval_maps.jpg)",
        "",
    ]
    return "\n".join(lines)


__all__ = ["CentreViewOnly", "acceptance_lines", "lighting_errors", "run", "unavailable"]
