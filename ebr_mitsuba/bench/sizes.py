"""``ebr bench sizes``: the network-size curve, validation error against parameters and CPU seconds.

:func:`run` writes ``<out_dir>/sizes.md``, ``sizes.json`` and the plot ``sizes.png`` (atomically).

**What is measured** (DESIGN §5: every approximation has a knob and a measured curve; issue 15:
"pick the network size from a measured curve").

* *One point per cascade size* of :data:`TRAINED` (the NAFNet presets of
  :data:`ebr_mitsuba.nets.nafnet.SIZE_PRESETS`): the cascade's diffuse and specular nets trained from
  scratch by ``ebr train`` with the recipe of ``configs/train_size_curve.toml`` (the same samples of
  ``$EBR_TRAIN_DATA``, the same steps, the same seed), over the shipped model's lighting net (so
  every point reads the same lighting). ``[model].cascade_size`` is the one field that differs.
  The runs live in ``$EBR_SIZE_RUNS`` (default ``<tmp>/ebr-size-curve/<size>``): a finished run
  whose config matches is reused, an interrupted one resumed (``ebr train --resume``), and the
  stage-1 selection cache, which does not depend on the size, is filled once and linked into the
  other runs.
* *Error*: each trained model on the validation set ``$EBR_VAL_DATA`` (never the test split: this
  is model selection, DESIGN §6), the metrics of ``ebr eval`` (per-map RMSE, normals as (n+1)/2, and
  their mean; re-render RMSE under 30 seeded held-out lights): the network's maps, and the maps of
  ``ebr estimate`` with that model (flash fit and shading normals on top: what a user gets). The
  shipped model is scored in the same run for reference (its cascade is ``small``, trained longer
  on other data: docs/models.md).
* *CPU seconds*: one forward pass of the cascade's diffuse and specular nets at 256² (batch 1,
  float32, ``torch.inference_mode``, the torch threads of this process), the median of
  :data:`REPEATS` after a warm-up; and one training step (forward + backward + Adam, batch 8, at
  the training set's resolution) of the diffuse net, the median of :data:`REPEATS`. Both are
  measured for every preset, the ``paper`` size too, which is timed but not trained: at the
  measured seconds per step the recipe would take hours on two cores (a GPU run's config).
* *Parameters*: the trainable scalars of the cascade (diffuse + specular nets).

**The choice.** The size of lowest validation mean per-map RMSE of the network's maps; a larger
size must beat a smaller one by more than :data:`MARGIN` (relative) to be chosen. The page says
which, and the CPU seconds it costs.

``--quick``: two sizes, 10 steps per phase on 16 samples, 2 validation samples (a smoke test, its
numbers are not the documented ones). Timings depend on the machine and its load: the page records
other processes' load during the run.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from ..errors import InputError
from ._common import OtherLoad, load_sentence, machine, median_seconds

DEFAULT_OUT = "docs/bench"
CONFIG = Path(__file__).resolve().parents[2] / "configs" / "train_size_curve.toml"
TRAINED = ("tiny", "small", "medium")  # the sizes trained for the curve, smallest first
TIMED_ONLY = ("paper",)  # timed and counted, not trained on two cores
QUICK_SIZES = ("tiny", "small")
QUICK_STEPS = 10
QUICK_SAMPLES = 16
QUICK_VAL = 2
REPEATS = 5  # timed repetitions (median) after one warm-up
TIMING_SIZE = 256  # side of the forward-pass timing input
MARGIN = 0.02  # a larger size is chosen only when its mean RMSE is this much (relative) lower
MAP_NAMES = ("normal", "diffuse", "roughness", "specular", "mean")


def unavailable() -> str | None:
    missing = [v for v in ("EBR_TRAIN_DATA", "EBR_VAL_DATA") if not os.environ.get(v)]
    if missing:
        return f"set {' and '.join('$' + v for v in missing)} (docs/bench/sizes.md)"
    if not CONFIG.is_file():
        return f"{CONFIG} not found (run from a checkout of ebr-mitsuba)"
    return None


def runs_root(quick: bool) -> Path:
    root = Path(os.environ.get("EBR_SIZE_RUNS") or Path(tempfile.gettempdir()) / "ebr-size-curve")
    return root / "quick" if quick else root


def point_config(base, size: str, quick: bool):
    """The training config of one point: ``base`` with ``[model].cascade_size = size`` (and the
    quick budget)."""
    cfg = dataclasses.replace(base, model={**base.model, "cascade_size": size})
    if quick:
        cfg = dataclasses.replace(
            cfg,
            data=dataclasses.replace(cfg.data, max_samples=QUICK_SAMPLES),
            stages=dataclasses.replace(cfg.stages, diffuse=QUICK_STEPS, specular=QUICK_STEPS),
        )
    return cfg


def _link_stage1(source: Path | None, run_dir: Path) -> None:
    """Hard-link the stage-1 cache files of ``source`` (a finished point's run) into ``run_dir``:
    the selection under the true lighting does not depend on the cascade's size."""
    if source is None:
        return
    src = source / "cache" / "stage1"
    if not src.is_dir():
        return
    dst = run_dir / "cache" / "stage1"
    dst.mkdir(parents=True, exist_ok=True)
    for f in src.glob("*.npz"):
        target = dst / f.name
        if not target.exists():
            try:
                os.link(f, target)
            except OSError:  # another file system: copy
                shutil.copyfile(f, target)


def train_point(cfg, run_dir: Path, stage1_from: Path | None, log=print) -> dict:
    """Train (or reuse, or resume) one point's run; returns its ``summary.json``."""
    from ..commands._common import progress
    from ..train.ddp import shutdown
    from ..train.trainer import Trainer

    model, summary_file, config_file = run_dir / "model.pt", run_dir / "summary.json", run_dir / "config.json"
    wanted = json.loads(json.dumps(cfg.to_dict()))  # as the trainer compares its config.json
    if config_file.is_file():
        have = json.loads(config_file.read_text())
        if have != wanted:
            raise InputError(
                f"{run_dir}: a run of another config (not this size curve's); remove it or set "
                "$EBR_SIZE_RUNS to another folder"
            )
    if model.is_file() and summary_file.is_file():
        log(f"[bench sizes] {run_dir.name}: reusing {model}")
        return json.loads(summary_file.read_text())
    resume = (run_dir / "last.pt").is_file()
    _link_stage1(stage1_from, run_dir)
    log(f"[bench sizes] {run_dir.name}: training{' (resumed)' if resume else ''} into {run_dir}")
    trainer = Trainer(cfg, run_dir, resume=resume, log=log, progress=progress)
    try:
        return trainer.run()
    finally:
        trainer.close()
        shutdown(trainer.dist)


def _in_channels(net) -> int:
    import torch

    return next(m for m in net.modules() if isinstance(m, torch.nn.Conv2d)).in_channels


def _sync(device) -> None:
    import torch

    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def time_size(size: str, cascade_config, train_res: int, repeats: int = REPEATS, device: str = "cpu") -> dict:
    """Seconds and parameters of the cascade at ``size`` on ``device`` (module docstring)."""
    import torch

    from ..nets import Cascade
    from ..nets.nafnet import parameter_count

    torch.manual_seed(0)
    cascade = Cascade(dataclasses.replace(cascade_config, size=size, use_refinement=False)).to(device)
    nets = [cascade.diffuse_net, cascade.specular_net]
    inputs = [torch.rand(1, _in_channels(n), TIMING_SIZE, TIMING_SIZE, device=device) for n in nets]

    def forward():
        with torch.inference_mode():
            for n, x in zip(nets, inputs, strict=True):
                n(x)
        _sync(device)

    net = cascade.diffuse_net
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    batch = torch.rand(8, _in_channels(net), train_res, train_res, device=device)

    def step():
        opt.zero_grad(set_to_none=True)
        net(batch).abs().mean().backward()
        opt.step()
        _sync(device)

    return {
        "parameters": int(sum(parameter_count(n) for n in nets)),
        "forward_seconds": median_seconds(forward, repeats),
        "train_step_seconds": median_seconds(step, max(1, repeats // 2)),
    }


def time_all(device: str, resolutions=(128, 256), repeats: int = REPEATS) -> dict:
    """Every size preset timed on ``device`` at each training resolution (``python -m
    ebr_mitsuba.bench.sizes --time-only``): what a run on another machine, a CUDA GPU, costs. Needs
    torch alone (no Mitsuba, no data set)."""
    import platform

    import torch

    from ..nets import CascadeConfig

    cascade_config = CascadeConfig()
    name = torch.cuda.get_device_name(0) if torch.device(device).type == "cuda" else platform.processor()
    out = {"device": name or device, "torch": torch.__version__, "sizes": {}}
    for size in (*TRAINED, *TIMED_ONLY):
        out["sizes"][size] = {
            str(res): time_size(size, cascade_config, res, repeats, device) for res in resolutions
        }
    return out


def evaluate_point(checkpoint: Path | None, val: str, limit: int) -> dict:
    """The network's maps and ``ebr estimate``'s maps with that model on the validation set."""
    from ..commands._common import progress
    from ..estimate.refine import RefineConfig
    from ..evaluation.evaluate import estimate_predictor, evaluate_many, model_predictor
    from ..model.predict import load_predictor

    pred = load_predictor(checkpoint)
    network, run = model_predictor(pred), estimate_predictor(pred, val, RefineConfig())
    both = evaluate_many(
        lambda item, names: {"network": network(item, names), "estimate": run(item, names)["estimate"]},
        val,
        limit=limit,
        seed=0,
        progress=progress,
    )
    return {name: {k: v for k, v in m.items() if k != "per_sample"} for name, m in both.items()}


def choose(points: dict[str, dict]) -> str:
    """The chosen size (module docstring, "The choice"): walk the trained sizes from the smallest;
    a larger one replaces the choice only when its network mean RMSE is MARGIN below it."""
    chosen = None
    for name, p in points.items():
        if "network" not in p:
            continue
        err = p["network"]["per_map_rmse"]["mean"]
        if chosen is None or err < (1 - MARGIN) * points[chosen]["network"]["per_map_rmse"]["mean"]:
            chosen = name
    return chosen


def _plot(points: dict[str, dict], path: Path, shipped: dict | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    from ..fsutil import atomic_path

    trained = {k: p for k, p in points.items() if "network" in p}
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for ax, key, scale, label in (
        (axes[0], "parameters", 1.0, "cascade parameters (log)"),
        (axes[1], "forward_seconds", 1e3, "CPU milliseconds, one 256² forward pass"),
    ):
        for which, style in (("network", "o-"), ("estimate", "s--")):
            xs = [p[key] * scale for p in trained.values()]
            ys = [p[which]["per_map_rmse"]["mean"] for p in trained.values()]
            ax.plot(xs, ys, style, label=f"{which} maps")
        for name, p in trained.items():
            xy = (p[key] * scale, p["network"]["per_map_rmse"]["mean"])
            ax.annotate(name, xy, textcoords="offset points", xytext=(4, 4))
        if shipped is not None:
            for which, colour in (("network", "C0"), ("estimate", "C1")):
                ax.axhline(shipped[which]["per_map_rmse"]["mean"], color=colour, lw=0.8, ls=":")
        if key == "parameters":
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel(label)
        ax.set_ylabel("validation mean per-map RMSE")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)


def _fmt_time(seconds: float) -> str:
    return f"{seconds * 1e3:.0f} ms" if seconds < 10 else f"{seconds:.0f} s"


def _page(points, shipped, chosen, base, quick, seconds, val, n_val, load) -> str:
    stages = base.stages
    from ..model.predict import shipped_model_path

    shipped_name = shipped_model_path().name
    lines = [
        "# Network size against error and CPU time: `ebr bench sizes`",
        "",
        "Generated by `ebr bench sizes` (`ebr_mitsuba/bench/sizes.py`); do not edit by hand.",
        f"Machine: {machine()}; {time.strftime('%Y-%m-%d')}; the run took {seconds:.0f} s. {load}",
        "",
    ]
    if quick:
        lines += ["**Quick run** (`--quick`): a smoke test; these numbers are not the documented ones.", ""]
    lines += [
        f"Each point is the cascade (diffuse and specular nets) at one size, trained from scratch by "
        f"`ebr train configs/train_size_curve.toml` with `[model].cascade_size` set to it: "
        f"{stages.diffuse} diffuse and {stages.specular} specular steps, batch {base.train.batch_size}, "
        f"on the first {base.data.max_samples or 'all'} samples of `{base.data.train}`, over the shipped "
        "model's lighting net. Scored on the validation set "
        f"`{val}` ({n_val} captures; never the test split: this is model selection), metrics of "
        "`ebr eval` (per-map RMSE with normals as (n+1)/2, their mean, and the re-render RMSE under 30 "
        "held-out lights): the network's maps, and the maps `ebr estimate` makes with that model "
        "(flash fit and shading normals on top).",
        "",
        "```",
        "export EBR_DATA_DIR=../shared/data EBR_TRAIN_DATA=/tmp/ebr-data/real_train \\",
        "       EBR_VAL_DATA=/tmp/ebr-data/real_val",
        "ebr generate configs/data_real_train.toml --out $EBR_TRAIN_DATA --workers 2",
        "ebr generate configs/data_real_val.toml --out $EBR_VAL_DATA --workers 2",
        "ebr bench sizes   # this page; the runs go to $EBR_SIZE_RUNS (default <tmp>/ebr-size-curve)",
        "```",
        "",
        "| size | cascade parameters | CPU, 256² forward | CPU, training step | training run | "
        "network: N | D | R | S | mean | re-render | ebr estimate: mean | re-render |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, p in points.items():
        cells = [
            name + (" (chosen)" if name == chosen else ""),
            f"{p['parameters']:,}".replace(",", " "),
            _fmt_time(p["forward_seconds"]),
            _fmt_time(p["train_step_seconds"]),
        ]
        if "network" in p:
            nm, es = p["network"], p["estimate"]
            cells.append(f"{p['run_seconds'] / 60:.1f} min")
            cells += [f"{nm['per_map_rmse'][k]:.4f}" for k in MAP_NAMES] + [f"{nm['rerender_rmse']:.4f}"]
            cells += [f"{es['per_map_rmse']['mean']:.4f}", f"{es['rerender_rmse']:.4f}"]
        else:
            steps = stages.diffuse + stages.specular
            est = p["train_step_seconds"] * steps / 3600
            cells.append(f"not trained (≈ {est:.1f} h of steps)")
            cells += ["–"] * 8
        lines.append("| " + " | ".join(cells) + " |")
    if shipped is not None:
        nm, es = shipped["network"], shipped["estimate"]
        lines.append(
            f"| shipped model `{shipped_name}` (reference) | | | | | "
            + " | ".join(f"{nm['per_map_rmse'][k]:.4f}" for k in MAP_NAMES)
            + f" | {nm['rerender_rmse']:.4f} | {es['per_map_rmse']['mean']:.4f} | {es['rerender_rmse']:.4f} |"
        )
    lines += [
        "",
        "![validation error against parameters and CPU seconds](sizes.png)",
        "",
        f"Dotted: the shipped model's (`{shipped_name}`) network and `ebr estimate` means on the same "
        "captures.",
        "",
    ]
    if chosen:
        c = points[chosen]
        lines += [
            f"**Chosen: `{chosen}`** — the lowest validation mean per-map RMSE of the network's maps "
            f"({c['network']['per_map_rmse']['mean']:.4f}), a larger size counting only when it is more "
            f"than {MARGIN:.0%} lower; it costs {_fmt_time(c['forward_seconds'])} per 256² forward pass "
            f"and {_fmt_time(c['train_step_seconds'])} per training step on this machine.",
            "",
        ]
    lines += [
        "CPU seconds: the diffuse and specular nets' forward pass on one 256² input (float32, "
        "inference mode, median of "
        f"{REPEATS} after a warm-up), and one training step of the diffuse net (batch 8 at the "
        "training set's resolution: forward, backward, Adam). The `paper` size is timed, not trained: "
        'its recipe is a GPU run\'s (`[train].device = "cuda"`, the same config).',
        "",
    ]
    return "\n".join(lines)


def device_lines(out_dir: Path, steps: int) -> list[str]:
    """The timings of :func:`time_all` on other devices, read from ``out_dir/sizes_<device>.json``
    (written by ``python -m ebr_mitsuba.bench.sizes --time-only --device D --out ...``)."""
    lines = []
    for path in sorted(Path(out_dir).glob("sizes_*.json")):
        try:
            d = json.loads(path.read_text())
            sizes = d["sizes"]
        except (OSError, ValueError, KeyError):
            continue
        lines += [
            f"### The same sizes on {d.get('device', path.stem)} (`{path.name}`)",
            "",
            "Measured there by `python -m ebr_mitsuba.bench.sizes --time-only --device cuda "
            f"--out {path.name}` "
            f"(torch {d.get('torch', '?')}; the nets alone, nothing trained): what the same configs cost "
            f"on a GPU. The last column is the {steps} steps of this page's recipe at 256².",
            "",
            "| size | cascade parameters | 256² forward | training step, 128² | training step, 256² "
            "| recipe at 256² |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for name, by_res in sizes.items():
            t128, t256 = by_res.get("128", {}), by_res.get("256", {})
            first = t256 or t128
            cells = [
                name,
                f"{first.get('parameters', 0):,}".replace(",", " "),
                _fmt_time(first.get("forward_seconds", float("nan"))),
                _fmt_time(t128["train_step_seconds"]) if t128 else "–",
                _fmt_time(t256["train_step_seconds"]) if t256 else "–",
                f"{t256['train_step_seconds'] * steps / 60:.1f} min" if t256 else "–",
            ]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return lines


def run(out_dir: Path | str = DEFAULT_OUT, quick: bool = False, log=print) -> Path:
    """Train, score and time every size; write ``out_dir/sizes.md`` (module docstring)."""
    from ..data.dataset import GeneratedDataset
    from ..fsutil import atomic_write_text
    from ..model.bundle import DataFacts
    from ..model.config import load_config
    from ..model.predict import shipped_model_path

    reason = unavailable()
    if reason:
        raise InputError(f"ebr bench sizes: {reason}")
    train, val = os.environ["EBR_TRAIN_DATA"], os.environ["EBR_VAL_DATA"]
    for var, path in (("EBR_TRAIN_DATA", train), ("EBR_VAL_DATA", val)):
        if not (Path(path) / "dataset.json").is_file():
            raise InputError(f"${var} = {path}: not a data set of `ebr generate` (docs/bench/sizes.md)")
    os.environ.setdefault("EBR_INIT", str(shipped_model_path()))
    base = load_config(CONFIG)
    out_dir = Path(out_dir)
    runs = runs_root(quick)
    n_val = len(GeneratedDataset(val))
    limit = QUICK_VAL if quick else 0
    n_val = min(limit, n_val) if limit else n_val
    load = OtherLoad()
    t0 = time.perf_counter()
    points: dict[str, dict] = {}
    first = None
    for size in QUICK_SIZES if quick else TRAINED:
        cfg = point_config(base, size, quick)
        run_dir = runs / size
        summary = train_point(cfg, run_dir, first, log)
        first = first or run_dir
        log(f"[bench sizes] {size}: scoring on {val}")
        points[size] = {
            "run_seconds": float(summary.get("seconds", 0.0)),
            **evaluate_point(run_dir / "model.pt", val, limit),
        }
    cascade_config = base.cascade_config()
    res = DataFacts.from_dataset(train).resolution
    for size in [*points, *([] if quick else TIMED_ONLY)]:
        log(f"[bench sizes] {size}: timing")
        points.setdefault(size, {}).update(time_size(size, cascade_config, res, 1 if quick else REPEATS))
    order = list(TRAINED + TIMED_ONLY)
    points = dict(sorted(points.items(), key=lambda kv: order.index(kv[0])))
    log("[bench sizes] shipped model: scoring")
    shipped = evaluate_point(None, val, limit)
    chosen = choose(points)
    seconds = time.perf_counter() - t0
    out_dir.mkdir(parents=True, exist_ok=True)
    _plot(points, out_dir / "sizes.png", shipped)
    cfg = point_config(base, chosen or "small", quick)
    page = _page(points, shipped, chosen, cfg, quick, seconds, val, n_val, load_sentence(load.cores()))
    page += "\n".join(["", *device_lines(out_dir, cfg.stages.diffuse + cfg.stages.specular)])
    atomic_write_text(out_dir / "sizes.md", page)
    atomic_write_text(
        out_dir / "sizes.json",
        json.dumps({"points": points, "shipped": shipped, "chosen": chosen}, indent=1, default=float) + "\n",
    )
    return out_dir / "sizes.md"


def main(argv=None) -> int:
    """``python -m ebr_mitsuba.bench.sizes --time-only [--device cuda] [--out FILE]``: the timings of
    :func:`time_all` as JSON (``ebr bench sizes`` shows ``sizes_<device>.json`` beside its page)."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m ebr_mitsuba.bench.sizes", description=main.__doc__)
    p.add_argument("--time-only", action="store_true", required=True, help="time every size, train nothing")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    p.add_argument("--out", default=None, help="write the JSON here (default: stdout)")
    args = p.parse_args(argv)
    text = json.dumps(time_all(args.device), indent=1) + "\n"
    if args.out:
        Path(args.out).write_text(text)
    else:
        print(text, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
