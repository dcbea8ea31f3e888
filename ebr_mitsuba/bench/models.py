"""``ebr bench models``: the shipped model against its baselines and ablations; writes models.md.

:func:`run` writes ``<out_dir>/models.md`` with ``models_loss.png`` and ``models_eval.png`` beside
it (``ebr bench models`` uses ``--out docs`` by default: the page is ``docs/models.md``).

**Inputs.** The data sets and the training runs are not in the repository; three environment
variables name them (the page's first section lists the commands that make them):

* ``EBR_TRAIN_DATA``: the shipped model's training set (``configs/data_small_train.toml``), for
  baseline (a), the per-pixel mean maps of the training set;
* ``EBR_TEST_DATA``: the held-out set (``configs/data_small_test.toml``): real texture sets,
  procedural families left out of training, HDR environment maps never seen in training;
* ``EBR_RUNS``: the folder holding the runs ``small/`` (the shipped model's, for the training
  summary), ``noex/`` (``configs/train_small_noexemplars.toml``: baseline (b)) and ``nocas/``
  (``configs/train_small_nocascade.toml``: the "without cascade" ablation).

**What is measured.** :func:`ebr_mitsuba.train.evaluate.evaluate` on every held-out sample, all
predictors on the same samples and the same 30 seeded re-render light/view pairs (``docs/conventions.md``
metrics): the shipped model (``ebr_mitsuba/models/ebrenv_small.pt``), baseline (a), baseline (b),
and the paper's §5.3.2 ablations: without cascade (one joint net for all maps), without
exemplars (= baseline (b)) and without adaptive selection (the shipped model with both exemplar
roughnesses fixed at :data:`FIXED_ROUGHNESS`).
"""

from __future__ import annotations

import csv
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from ..errors import InputError

DEFAULT_OUT = "docs"
FIXED_ROUGHNESS = 0.5
QUICK_LIMIT = 3
COLUMNS = ("normal", "diffuse", "roughness", "specular", "mean")
REGENERATE = """\
export EBR_DATA_DIR=../shared/data EBR_TRAIN_DATA=/tmp/ebr-data/small_train \\
       EBR_TEST_DATA=/tmp/ebr-data/small_test EBR_RUNS=/tmp/ebr-runs
ebr generate configs/data_small_train.toml --out $EBR_TRAIN_DATA --workers 2
ebr generate configs/data_small_test.toml --out $EBR_TEST_DATA --workers 2
ebr train configs/train_small.toml --out $EBR_RUNS/small --export ebr_mitsuba/models/ebrenv_small.pt
EBR_INIT=$EBR_RUNS/small/after_lighting.pt ebr train configs/train_small_noexemplars.toml --out $EBR_RUNS/noex
EBR_INIT=$EBR_RUNS/small/after_lighting.pt ebr train configs/train_small_nocascade.toml --out $EBR_RUNS/nocas
ebr bench models            # this page"""


def unavailable() -> str | None:
    """Why this benchmark cannot run here (``ebr bench all`` skips it then), or None."""
    missing = [n for n in ("EBR_TRAIN_DATA", "EBR_TEST_DATA", "EBR_RUNS") if not os.environ.get(n)]
    return f"set {', '.join('$' + n for n in missing)}; see docs/models.md" if missing else None


def _env_path(name: str) -> Path:
    value = os.environ.get(name)
    if not value:
        raise InputError(
            f"${name} is not set; 'ebr bench models' needs it (see the docstring of ebr_mitsuba.bench.models)"
        )
    path = Path(value).expanduser()
    if not path.exists():
        raise InputError(f"${name} = {path}: does not exist; make it with the commands in docs/models.md")
    return path


def _checkpoint(runs: Path, run: str) -> Path:
    path = runs / run / "model.pt"
    if not path.is_file():
        raise InputError(f"{path}: missing; train it with the commands in docs/models.md")
    return path


def training_summary(run_dir: Path) -> dict:
    """Per phase: steps, final loss (mean of the last 4 logged values), seconds; from log.csv (a
    step logged twice, by an interrupted run and its resume, counts once: the later row)."""
    log = run_dir / "log.csv"
    if not log.is_file():
        raise InputError(f"{log}: missing; the run in {run_dir} did not log")
    with log.open() as f:  # a step logged twice (interrupted run, then its resume): keep the later row
        rows = list({(r["phase"], r["step"]): r for r in csv.DictReader(f)}.values())
    phases: dict[str, dict] = {}
    for r in rows:
        p = phases.setdefault(r["phase"], {"steps": 0, "losses": [], "seconds": 0.0, "rates": []})
        p["steps"] = max(p["steps"], int(r["step"]))
        p["losses"].append(float(r["loss"]))
        p["seconds"] = max(p["seconds"], float(r["seconds"]))
        p["rates"].append(float(r["samples_per_s"]))
    out = {
        name: {
            "steps": p["steps"],
            "first_loss": p["losses"][0],
            "final_loss": float(np.mean(p["losses"][-4:])),
            "seconds": p["seconds"],
            "samples_per_s": float(np.median(p["rates"])),
            "curve": p["losses"],
        }
        for name, p in phases.items()
    }
    summary_path = run_dir / "summary.json"
    extra = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    config_path = run_dir / "config.json"
    loss = json.loads(config_path.read_text()).get("loss", {}) if config_path.is_file() else {}
    return {
        "phases": out,
        "samples": extra.get("samples"),
        "device": extra.get("device", "cpu"),
        "loss": loss,
    }


def objective_text(loss: dict) -> str:
    """One sentence on the training objective of a run, from its ``[loss]`` settings."""
    maps = ", ".join(f"{k} {loss[k]:g}" for k in ("normal", "diffuse", "specular", "roughness") if k in loss)
    text = f"Objective: L1 per map (weights {maps})" if maps else "Objective: L1 per map"
    if loss.get("render", 0.0) > 0:
        text += (
            f", plus the rendering loss (weight {loss['render']:g}; L1 of log(x + 1) over "
            f"{loss.get('render_pairs', 10)} view/light pairs, {loss.get('render_highlights', 5)} with a "
            "forced highlight, rendered by the Dr.Jit renderer through `dr.wrap`) in refinement and stage 2"
        )
    return text + "."


def _row(name: str, m: dict) -> str:
    p = m["per_map_rmse"]
    cells = [f"{p[k]:.4f}" for k in COLUMNS]
    sec = f"{m['seconds_per_sample']:.2f}" if "seconds_per_sample" in m else "–"
    return f"| {name} | " + " | ".join(cells) + f" | {m['rerender_rmse']:.4f} | {m['ssim']:.3f} | {sec} |"


def _short(spec: str) -> str:
    """A material or environment spec without its folder (``.../materials/Metal009`` → ``Metal009``)."""
    return spec if spec.startswith("procedural:") else Path(spec).name


def _outliers(main: dict, base: dict, count: int = 6) -> list[str]:
    """Where the shipped model's re-render error exceeds the mean maps' most: the samples with the
    largest excess and their share of the total excess (computed, per sample, same pairs)."""
    rows = [
        (m["rerender_rmse"] - b["rerender_rmse"], m, b)
        for m, b in zip(main["per_sample"], base["per_sample"])
    ]
    total = sum(d for d, _, _ in rows)
    worst = sorted(rows, key=lambda r: r[0], reverse=True)[:count]
    if total <= 0 or not worst or worst[0][0] <= 0:
        return []
    share = sum(max(d, 0.0) for d, _, _ in worst) / total
    out = [
        "",
        "### Where the re-render error comes from",
        "",
        f"The {len(worst)} samples on which the shipped model's re-render RMSE exceeds the mean maps' "
        f"the most carry {100 * share:.0f} % of the summed difference over all {len(rows)} samples "
        "(positive: the model is worse). A re-render RMSE over random point lights is dominated by "
        "highlights: a model that overestimates a sample's specular albedo pays far more than the "
        "mean maps' conservative guess, while its lower per-map errors elsewhere move the mean little.",
        "",
        "| sample | material | environment | model re-render | mean maps re-render "
        "| per-map RMSE, model / mean maps |",
        "|---:|---|---|---:|---:|---:|",
    ]
    for _, m, b in worst:
        out.append(
            f"| {m['index']} | {_short(str(m['material']))} | {_short(str(m['env']))} | "
            f"{m['rerender_rmse']:.3f} | "
            f"{b['rerender_rmse']:.3f} | {m['per_map_rmse']['mean']:.3f} / {b['per_map_rmse']['mean']:.3f} |"
        )
    return out


def _plot_loss(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    phases = summary["phases"]
    fig, axes = plt.subplots(1, len(phases), figsize=(3.2 * len(phases), 2.8))
    for ax, (name, p) in zip(np.atleast_1d(axes), phases.items()):
        steps = np.linspace(p["steps"] / len(p["curve"]), p["steps"], len(p["curve"]))
        ax.plot(steps, p["curve"], lw=1)
        ax.set_title(name)
        ax.set_xlabel("step")
        ax.set_yscale("log")
    np.atleast_1d(axes)[0].set_ylabel("training loss")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _plot_eval(results: dict[str, dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = (*COLUMNS, "rerender")
    names = list(results)
    width = 0.8 / len(names)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    x = np.arange(len(keys))
    for i, name in enumerate(names):
        m = results[name]
        vals = [m["per_map_rmse"][k] for k in COLUMNS] + [m["rerender_rmse"]]
        ax.bar(x + (i - (len(names) - 1) / 2) * width, vals, width, label=name)
    ax.set_xticks(x, keys)
    ax.set_ylabel("RMSE (held-out set)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def run(out_dir: Path | str = DEFAULT_OUT, quick: bool = False, log=print) -> Path:
    """Evaluate and write ``out_dir/models.md``; ``quick`` scores :data:`QUICK_LIMIT` samples."""
    from ..commands._common import progress
    from ..fsutil import atomic_write_text
    from ..train.baselines import MeanMaps
    from ..train.evaluate import evaluate, group_means, material_group, model_predictor
    from ..train.inference import load_model, shipped_model_path

    train_data, test_data, runs = (_env_path(n) for n in ("EBR_TRAIN_DATA", "EBR_TEST_DATA", "EBR_RUNS"))
    noex, nocas = _checkpoint(runs, "noex"), _checkpoint(runs, "nocas")
    summary = training_summary(runs / "small")
    limit = QUICK_LIMIT if quick else 0
    t_start = time.perf_counter()

    shipped = load_model(None)
    mean = MeanMaps.from_dataset(train_data)
    predictors = {
        "shipped model": model_predictor(shipped),
        "(a) training-set mean maps": lambda item, names: mean.predict(tuple(item["maps"].shape[1:])),
        "(b) without exemplars": model_predictor(load_model(noex)),
        "without cascade": model_predictor(load_model(nocas)),
        f"without adaptive selection (r = {FIXED_ROUGHNESS})": model_predictor(shipped, FIXED_ROUGHNESS),
    }
    results = {}
    for name, pred in predictors.items():
        log(f"[models] {name}")
        r = evaluate(pred, test_data, limit=limit, seed=0, progress=progress)
        r["groups"] = group_means(r["per_sample"], material_group)
        results[name] = r
    seconds = time.perf_counter() - t_start

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    _plot_loss(summary, out_dir / "models_loss.png")
    _plot_eval({k: v for k, v in results.items()}, out_dir / "models_eval.png")

    import torch

    model_mb = shipped_model_path().stat().st_size / 1e6
    params = sum(p.numel() for net in shipped.nets().values() for p in net.parameters())
    main = results["shipped model"]
    base_a, base_b = results["(a) training-set mean maps"], results["(b) without exemplars"]
    n = main["n"]

    def beats(other: dict) -> str:
        wins = [k for k in ("mean",) if main["per_map_rmse"][k] < other["per_map_rmse"][k]]
        rr = main["rerender_rmse"] < other["rerender_rmse"]
        return (
            f"mean per-map RMSE {main['per_map_rmse']['mean']:.4f} vs {other['per_map_rmse']['mean']:.4f} "
            f"({'lower' if wins else 'NOT lower'}), re-render RMSE {main['rerender_rmse']:.4f} vs "
            f"{other['rerender_rmse']:.4f} ({'lower' if rr else 'NOT lower'})"
        )

    header = "| predictor | normal | diffuse | roughness | specular | mean | re-render | SSIM | s / sample |"
    rule = "|---|---:|---:|---:|---:|---:|---:|---:|---:|"
    lines = [
        "# The shipped model: training summary and held-out evaluation",
        "",
        "Generated by `ebr bench models` (`ebr_mitsuba/bench/models.py`); do not edit by hand.",
        f"Machine: {platform.machine()}, {os.cpu_count()} logical cores (shared), torch {torch.__version__}, "
        f"{time.strftime('%Y-%m-%d')}; evaluation took {seconds:.0f} s"
        + (f"; **quick run: {n} samples only, not the documented figures**." if quick else "."),
        "",
        "`ebr_mitsuba/models/ebrenv_small.pt` is what `ebr estimate`, `ebr demo` and `ebr eval` use when "
        "no `--checkpoint` is given: the EBREnv lighting net and cascade "
        f"([conventions](conventions.md#pipeline)) at the NAFNet `small` size on a 64² grid, "
        f"{params / 1e6:.2f} M parameters, {model_mb:.1f} MB (float16 weights).",
        "",
        "## How it is made (and how to regenerate every table here)",
        "",
        "```",
        REGENERATE,
        "```",
        "",
        "Training data: 1200 near flash / no-flash captures at 64² of six procedural families "
        "(tiles, wood, metal, leather, plaster, fabric; 30 % two-material blends) under procedural "
        "SG environments (sun + sky, window, overcast), rendered by the fast renderer (64-direction "
        "quadrature), with exposure, white-balance and noise jitter (`configs/data_small_train.toml`).",
        "",
        "## Training summary",
        "",
        f"Run `{runs / 'small'}` on {summary['device']}, {summary['samples']} samples, one torch thread "
        "(`configs/train_small.toml`). Stage 1 trains the lighting net, then the cascade in sequence "
        "with exemplars selected under the true environment; stage 2 (`finetune`) fine-tunes the whole "
        "cascade on SGs extracted from the lighting net's own exemplars. "
        f"{objective_text(summary.get('loss', {}))} Loss columns: mean of the last four "
        "logged values; learning rate cosine-decayed per phase.",
        "",
        "| phase | steps | first loss | final loss | samples / s | seconds |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, p in summary["phases"].items():
        lines.append(
            f"| {name} | {p['steps']} | {p['first_loss']:.4f} | {p['final_loss']:.4f} | "
            f"{p['samples_per_s']:.1f} | {p['seconds']:.0f} |"
        )
    lines += [
        "",
        "![training loss per phase](models_loss.png)",
        "",
        "## Held-out evaluation (`ebr eval`)",
        "",
        f"`$EBR_TEST_DATA` ({n} samples of `configs/data_small_test.toml`): the real texture sets of "
        "`shared/data/materials` and the procedural families `marble` and `painted` (never in training) "
        "under the four Poly Haven HDR maps of `shared/data/envmaps` (training saw procedural SG skies "
        "only). Metrics of [conventions](conventions.md#metrics): per-map RMSE (normals as (n+1)/2) and "
        "their mean; re-render RMSE and SSIM over 30 seeded point-light/view pairs (seed 0); seconds per "
        "sample of the whole prediction (lighting net, SG extraction, exemplar selection, cascade) on "
        "this CPU. Lower is better except SSIM.",
        "",
        header,
        rule,
    ]
    lines += [_row(name, m) for name, m in results.items()]
    lines += [
        "",
        "Same command: `ebr eval --data $EBR_TEST_DATA --baseline-mean $EBR_TRAIN_DATA "
        "--baseline-checkpoint no-exemplars=$EBR_RUNS/noex/model.pt --json` (the shipped model with "
        "baselines (a) and (b) in one run); add `--fixed-roughness 0.5` or `--checkpoint "
        "$EBR_RUNS/nocas/model.pt` for the ablations.",
        "",
        f"- against (a), the mean maps: {beats(base_a)};",
        f"- against (b), the same network trained without exemplars: {beats(base_b)}.",
        "",
        "![held-out RMSE per map](models_eval.png)",
        "",
        "### By material source",
        "",
        "| predictor | group | n | mean per-map RMSE | re-render RMSE | SSIM |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for name, m in results.items():
        for group, g in m["groups"].items():
            lines.append(
                f"| {name} | {group} | {g['n']} | {g['per_map_rmse']['mean']:.4f} | "
                f"{g['rerender_rmse']:.4f} | "
                f"{g['ssim']:.3f} |"
            )
    lines += _outliers(main, base_a)
    lines += [
        "",
        "## Ablations (paper §5.3.2)",
        "",
        "The rows *without cascade*, *(b) without exemplars* and *without adaptive selection* above are "
        "the paper's three ablations, measured on the same samples and pairs as the shipped model. "
        "*Without cascade* replaces the diffuse → specular cascade by one joint net trained for the "
        "same total steps (`configs/train_small_nocascade.toml`); *without exemplars* feeds the cascade "
        "no exemplar images (`configs/train_small_noexemplars.toml`); *without adaptive selection* keeps "
        f"the shipped weights and fixes both exemplar roughnesses at {FIXED_ROUGHNESS} instead of the "
        "coarse-to-fine SSIM search (`ebr eval --fixed-roughness`). Both retrained variants start from "
        "the shipped run's lighting net (`after_lighting.pt`).",
        "",
        "## Beside the EBREnv paper's Table 1",
        "",
        "The paper trains the full-size networks (NAFNet width 36) on 256² Mitsuba renders on a GPU and "
        "reports per-map RMSE on its own synthetic test set. The shipped model is the `small` size on "
        "64² fast-renderer data trained for about half an hour on two CPU cores, and it is scored on a "
        "held-out set that differs from its training data in materials *and* lighting (real texture "
        "sets, unseen families, real HDR maps), so its numbers are not comparable with the paper's "
        "row by row. The paper's Table 1 values are not part of this project's reference material "
        "(`shared/`), and none are quoted here from memory; `configs/train_paper.toml` is the "
        "paper-size configuration for a user with a GPU, evaluated with the same `ebr eval` command.",
        "",
    ]
    path = out_dir / "models.md"
    atomic_write_text(path, "\n".join(lines))
    return path


__all__ = ["DEFAULT_OUT", "FIXED_ROUGHNESS", "run", "training_summary", "unavailable"]
