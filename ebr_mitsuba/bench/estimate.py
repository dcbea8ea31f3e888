"""``ebr bench estimate``: time per stage, peak memory and error against resolution of ``ebr estimate``.

:func:`run` writes ``<out_dir>/estimate.md`` and its plots ``estimate_time.png``,
``estimate_error.png`` and ``estimate_flops.png`` (each atomically).

**What is measured.**

* *The test capture*: :data:`MATERIAL` under :data:`ENV`, near setup, rendered by Mitsuba
  (``ebr capture``, ``direct`` integrator) at :attr:`Settings.capture_res` (1024²) and
  :attr:`Settings.spp`, with its ground-truth maps. The inputs of the other sizes are its shots
  area-averaged (256², 512²) or area-upsampled (2048²: the timing needs a 2048² input; its maps
  cannot be more accurate than the 1024² truth), each beside the capture's ``capture.json`` (the
  flash intensity).
* *Each size, with and without refinement* (:attr:`Settings.refine_steps` steps): one
  ``ebr estimate --json`` subprocess, as a user runs it: wall time (imports included), the
  summary's time per stage, peak resident memory of that process (``os.wait4``), whether stdout
  holds the JSON alone, and whether every stage longer than one second showed its progress bar
  on stderr.
* *Error against resolution*: each estimate's maps resampled to the truth's 1024² (bilinear up,
  area down; normals renormalised) and compared per map (RMSE, normals as (n+1)/2:
  docs/conventions.md#metrics); the model-grid estimate (``--max-size`` at the grid) and the 256²
  estimate, upsampled, are the baselines.
* *A second capture* (:data:`SECOND`, same setup): the error against resolution of the maps
  (``ebr_mitsuba.estimate.fullres.predict_maps`` in process, no refinement), so that the
  comparison between sizes does not rest on one material.
* *A 4096² photo*: a real flash-only photo (``photos/flash_only``) upsampled to 4096² PNG:
  completes within the 2048² budget, saying the working size.
* *FLOPs*: the multiply-adds of every convolution of each network per megapixel, counted with
  forward hooks (:func:`ebr_mitsuba.estimate.fastnet.multiply_adds`, at 256² and scaled: they
  are linear in the pixel count), FLOPs = 2 × multiply-adds; the time of one
  :class:`~ebr_mitsuba.estimate.fastnet.FastNAFNet` pass per megapixel measured in process at
  1024²; and the time those FLOPs take at this CPU's peak, computed two ways: the vector ISA's
  (cores × clock × FLOPs per cycle, from ``/proc/cpuinfo``: AVX-512 with FMA = 16 float32 lanes
  × 2 FLOPs × 2 FMA ports) and a measured large GEMM (``torch.mm`` of 4096² float32, best of 3).
* *Knobs*: the irradiance table's resolution (:func:`ebr_mitsuba.render.env_sg.irradiance_table`)
  against its error and time, and tiles (:mod:`ebr_mitsuba.estimate.tiling`) against one pass
  (forced tiles at 1024²: the map difference and the time).

Timings depend on the machine and its load; the page records the load average around each run.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ._common import OtherLoad, load_sentence, machine, shared_data_dir

MATERIAL = "procedural:tiles:1"
ENV = "procedural:3"
SECOND = ("procedural:wood:3", "procedural:7")  # a second capture for the error study (in process)
PHOTO = "IMG_20180104_230238.png"  # the real flash-only photo of the 4096² case
STAGES = ("inputs", "model", "lighting", "maps", "rerender", "refine", "outputs", "report")
BARS = {
    "inputs": "inputs",
    "model": "model",
    "lighting": "lighting",
    "maps": "maps",
    "rerender": "re-render",
    "refine": "refine",
    "outputs": "outputs",
    "report": "outputs",
}
# Acceptance of issue 12 (2 cores).
BUDGET = {1024: 15.0, 2048: 60.0}
REFINE_BUDGET = 120.0  # 200 refinement steps at 1024²
MEMORY_BUDGET_GB = 3.0


@dataclasses.dataclass(frozen=True)
class Settings:
    capture_res: int
    spp: int
    sizes: tuple[int, ...]
    refine_steps: int
    photo_size: int
    flops_size: int
    table_sizes: tuple[int, ...]


FULL = Settings(
    capture_res=1024,
    spp=64,
    sizes=(256, 512, 1024, 2048),
    refine_steps=200,
    photo_size=4096,
    flops_size=1024,
    table_sizes=(16, 32, 64, 128),
)
QUICK = Settings(
    capture_res=128,
    spp=4,
    sizes=(96, 128),
    refine_steps=10,
    photo_size=256,
    flops_size=128,
    table_sizes=(16, 64),
)


def _say(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# -- the CPU's peak --------------------------------------------------------------------------------------


def isa_peak() -> dict:
    """Peak float32 FLOP/s of the vector ISA: cores × clock × FLOPs per cycle (``/proc/cpuinfo``)."""
    flags, mhz = set(), []
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags") and not flags:
                flags = set(line.split(":", 1)[1].split())
            elif line.startswith("cpu MHz"):
                mhz.append(float(line.split(":", 1)[1]))
    except OSError:
        pass
    if "avx512f" in flags:
        isa, lanes = "AVX-512", 16
    elif "avx2" in flags or "avx" in flags:
        isa, lanes = "AVX2" if "avx2" in flags else "AVX", 8
    else:
        isa, lanes = "SSE", 4
    fma = "fma" in flags
    ports = 2  # two FMA ports per core (Xeon Scalable / Skylake-SP and later; not in cpuinfo)
    per_cycle = lanes * (2 if fma else 1) * ports
    cores = os.cpu_count() or 1
    clock = max(mhz) * 1e6 if mhz else 2.0e9
    return {
        "isa": isa + (" + FMA" if fma else ""),
        "lanes": lanes,
        "ports": ports,
        "flops_per_cycle": per_cycle,
        "cores": cores,
        "clock_ghz": clock / 1e9,
        "flops": cores * clock * per_cycle,
    }


def gemm_peak(size: int = 4096, repeats: int = 3) -> float:
    """Measured float32 FLOP/s of ``torch.mm`` on ``size``² matrices (best of ``repeats``)."""
    import torch

    a, b = torch.randn(size, size), torch.randn(size, size)
    torch.mm(a, b)
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        torch.mm(a, b)
        best = min(best, time.perf_counter() - t0)
    return 2.0 * size**3 / best


# -- one estimate as a user runs it ----------------------------------------------------------------------


def run_cli(argv: list[str]) -> dict:
    """``ebr estimate ARGV --json`` in a subprocess: wall seconds, peak RSS (bytes), the summary
    (None if stdout is not one JSON document), stderr, the exit code and the load average."""
    cmd = [sys.executable, "-m", "ebr_mitsuba.cli", "estimate", *[str(a) for a in argv], "--json"]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    try:
        summary = json.loads(stdout)
    except json.JSONDecodeError:
        summary = None
    return {
        "code": proc.returncode,
        "wall": wall,
        "rss": usage.ru_maxrss * 1024,
        "summary": summary,
        "stderr": stderr,
        "load": (load, os.getloadavg()[0]),
    }


def progress_shown(summary: dict, stderr: str) -> dict[str, bool]:
    """For each stage longer than 1 s: whether its progress bar appeared on stderr."""
    return {k: f"{BARS[k]}:" in stderr for k, v in summary["timings"].items() if k in BARS and v > 1.0}


# -- the captures ----------------------------------------------------------------------------------------


def make_inputs(capture_dir: Path, size: int, out: Path) -> dict[str, Path]:
    """The capture's shots resampled (area) to ``size``² in ``out`` beside its capture.json."""
    from ..imageio import read_exr, resize_area, write_exr

    out.mkdir(parents=True, exist_ok=True)
    shutil.copy(capture_dir / "capture.json", out / "capture.json")
    paths = {}
    for name in ("flash", "noflash"):
        img = read_exr(capture_dir / f"{name}.exr")
        paths[name] = out / f"{name}.exr"
        write_exr(paths[name], img if img.shape[0] == size else resize_area(img, (size, size)))
    return paths


def maps_at(maps, size: int):
    """Maps resampled to ``size``²: bilinear up, area down; normals renormalised."""
    from ..imageio import upsample_bilinear_fast
    from ..materials import resample_svbrdf
    from ..svbrdf import SVBRDF

    n = maps.shape[0]
    if n >= size:
        return resample_svbrdf(maps, (size, size))
    normal = upsample_bilinear_fast(maps.normal, (size, size))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return SVBRDF(
        normal=normal,
        diffuse=np.clip(upsample_bilinear_fast(maps.diffuse, (size, size)), 0, 1),
        specular=np.clip(upsample_bilinear_fast(maps.specular, (size, size)), 0, 1),
        roughness=np.clip(upsample_bilinear_fast(maps.roughness, (size, size)), 0, 1),
    )


# -- in-process measurements: FLOPs, knobs ---------------------------------------------------------------


def measure_flops(bundle, size: int) -> list[dict]:
    """Per network: multiply-adds per megapixel (hooks at 256², scaled) and the measured seconds
    of a FastNAFNet pass per megapixel at ``size``² (best of 3)."""
    import torch

    from ..estimate.fastnet import CASCADE_NETS, FastNAFNet, multiply_adds

    nets = [("lighting net", bundle.lighting.net)]
    nets += [
        (n.replace("_", " "), getattr(bundle.cascade, n))
        for n in CASCADE_NETS
        if getattr(bundle.cascade, n, None) is not None
    ]
    rows = []
    for name, net in nets:
        probe = 256
        macs = multiply_adds(net, torch.zeros(1, net.in_channels, probe, probe)) / (probe * probe) * 1e6
        fast = FastNAFNet(net)
        x = torch.rand(1, net.in_channels, size, size)
        fast(x)
        best = math.inf
        for _ in range(3):
            t0 = time.perf_counter()
            fast(x)
            best = min(best, time.perf_counter() - t0)
        rows.append(
            {
                "net": name,
                "macs_per_mp": macs,
                "flops_per_mp": 2 * macs,
                "seconds_per_mp": best / (size * size / 1e6),
                "width": net.size.width,
            }
        )
    return rows


def measure_table(size: int, resolutions) -> list[dict]:
    """The irradiance table's relative RMSE against the per-pair form and its render time at
    ``size``² (the test capture's truth maps are not needed: a procedural normal-mapped SVBRDF)."""
    from ..geometry import near_shot
    from ..metrics import rel_rmse
    from ..render import render_numpy
    from ..sgenv import SGEnvironment
    from ..sources import parse_material

    maps = parse_material(MATERIAL).load(size)
    env = SGEnvironment(
        np.array([[0.5, 0.3, 0.81], [0.0, 0.0, 1.0], [-0.6, 0.1, 0.79]]),
        np.array([60.0, 1.5, 12.0]),
        np.array([[8.0, 7.5, 7.0], [0.25, 0.3, 0.4], [1.0, 0.8, 0.6]]),
    )
    shot = near_shot(False)

    def timed(**kw):
        render_numpy(maps, env, shot, lobe_loop=True, **kw)
        t0 = time.perf_counter()
        img = render_numpy(maps, env, shot, lobe_loop=True, **kw)
        return img, time.perf_counter() - t0

    exact, t_exact = timed(irradiance_table=0)
    rows = [{"table": 0, "rel_rmse": 0.0, "seconds": t_exact}]
    for r in resolutions:
        img, t = timed(irradiance_table=r)
        rows.append({"table": r, "rel_rmse": rel_rmse(img, exact), "seconds": t})
    return rows


def measure_errors_in_process(predictor, capture_dir: Path, sizes) -> dict[int, dict]:
    """Per working size: the per-map errors of the estimate of the capture at ``capture_dir``
    (lighting once at the grid, :func:`~ebr_mitsuba.estimate.fullres.predict_maps` per size, the
    grid size through ``predict``) against its truth. ``predictor``: a
    :class:`~ebr_mitsuba.model.predictor.StagedPredictor`."""
    from ..estimate import fullres
    from ..imageio import read_exr, resize_area
    from ..materials import load_material
    from ..metrics import map_rmse

    g = predictor.grid
    truth = load_material(capture_dir / "maps")
    shots = {k: read_exr(capture_dir / f"{k}.exr") for k in ("flash", "noflash")}
    grid = {k: resize_area(v, (g, g)) for k, v in shots.items()}
    lighting = predictor.predict_lighting(grid["flash"], grid["noflash"])
    out = {
        g: map_rmse(maps_at(predictor.predict(grid["flash"], grid["noflash"]).maps, truth.shape[0]), truth)
    }
    for size in sizes:
        photos = {k: v if v.shape[0] == size else resize_area(v, (size, size)) for k, v in shots.items()}
        maps = fullres.predict_maps(predictor, lighting, photos, grid).maps
        out[size] = map_rmse(maps_at(maps, truth.shape[0]), truth)
    return out


def measure_tiles(predictor, capture_dir: Path, size: int) -> dict:
    """One pass against forced tiles (about a quarter of the image each) at ``size``²: seconds and
    the mean absolute difference of the maps relative to their mean."""
    from ..estimate import fullres
    from ..imageio import read_exr, resize_area

    g = predictor.grid
    photos = {k: resize_area(read_exr(capture_dir / f"{k}.exr"), (size, size)) for k in ("flash", "noflash")}
    grid = {k: resize_area(v, (g, g)) for k, v in photos.items()}
    lighting = predictor.predict_lighting(grid["flash"], grid["noflash"])
    out = {}
    for label, memory in (
        ("one pass", None),
        ("tiles", fullres.pass_bytes(predictor.cascade, (size // 2 + 64) ** 2)),
    ):
        t0 = time.perf_counter()
        pred = fullres.predict_maps(predictor, lighting, photos, grid, pass_memory=memory)
        out[label] = {
            "seconds": time.perf_counter() - t0,
            "maps": pred.maps,
            "tiles": len(pred.tiles),
            "tile": pred.tile,
        }
    diff = {}
    for name in ("diffuse", "specular", "roughness"):
        a, b = (np.asarray(getattr(out[k]["maps"], name)) for k in ("one pass", "tiles"))
        diff[name] = float(np.mean(np.abs(a - b)) / max(float(np.mean(np.abs(a))), 1e-12))
    return {
        "one pass": out["one pass"]["seconds"],
        "tiles": out["tiles"]["seconds"],
        "count": out["tiles"]["tiles"],
        "tile": out["tiles"]["tile"],
        "difference": diff,
    }


# -- plots -----------------------------------------------------------------------------------------------


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    from ..fsutil import atomic_path

    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    _plt().close(fig)
    return path


def plot_time(runs: dict, path: Path) -> Path:
    """Stacked time per stage per size (without and with refinement) and peak memory."""
    plt = _plt()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    labels, bottoms = [], []
    keys = [(s, r) for s, r in sorted(runs) if runs[(s, r)]["summary"]]
    x = np.arange(len(keys))
    bottom = np.zeros(len(keys))
    for i, stage in enumerate(("startup",) + STAGES):
        vals = np.array([_stage_seconds(runs[k], stage) for k in keys])
        ax.bar(x, vals, bottom=bottom, color=f"C{i % 10}", label=stage)
        bottom += vals
    labels = [f"{s}²\n{'refine' if r else 'maps'}" for s, r in keys]
    bottoms = bottom
    for s, budget in BUDGET.items():
        if (s, False) in keys:
            ax.plot([keys.index((s, False)) - 0.4, keys.index((s, False)) + 0.4], [budget] * 2, "k--", lw=1)
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel("seconds (wall, 2 cores)")
    ax.set_title("time per stage (dashed: budget)")
    ax.legend(fontsize=6, ncol=2)
    for xi, b in zip(x, bottoms):
        ax.annotate(f"{b:.0f}", (xi, b), ha="center", va="bottom", fontsize=7)
    for refine, style in ((False, "o-"), (True, "s--")):
        pts = [(s, runs[(s, r)]["rss"] / 1e9) for s, r in keys if r == refine]
        if pts:
            ax2.plot(*zip(*pts), style, label="with refinement" if refine else "maps only")
    ax2.axhline(MEMORY_BUDGET_GB, color="k", ls=":", lw=1, label="3 GB budget")
    ax2.set_xscale("log", base=2)
    ax2.set_xlabel("working size (pixels per side)")
    ax2.set_ylabel("peak resident memory (GB)")
    ax2.set_title("peak memory")
    ax2.legend(fontsize=7)
    ax2.grid(True, alpha=0.3)
    return _save(fig, path)


def plot_error(errors: dict, path: Path) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for k, name in enumerate(("normal", "diffuse", "specular", "roughness", "mean")):
        for refined, style in ((False, "-"), (True, ":")):
            pts = [(s, e[name]) for (s, r), e in sorted(errors.items()) if r == refined and e]
            if pts:
                ax.plot(
                    *zip(*pts),
                    style,
                    marker="o",
                    color=f"C{k}",
                    label=name if not refined else f"{name} (refined)",
                    lw=2.2 if name == "mean" else 1.2,
                )
    ax.set_xscale("log", base=2)
    ax.set_xlabel("working size of the estimate (pixels per side)")
    ax.set_ylabel("RMSE against the 1024² truth")
    ax.set_title("map error against resolution")
    ax.legend(fontsize=6, ncol=2)
    ax.grid(True, alpha=0.3)
    return _save(fig, path)


def plot_flops(rows: list[dict], peaks: dict, path: Path) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    x = np.arange(len(rows))
    w = 0.27
    ax.bar(x - w, [r["seconds_per_mp"] for r in rows], w, label="measured (FastNAFNet)")
    ax.bar(x, [r["flops_per_mp"] / peaks["gemm"] for r in rows], w, label="at the measured GEMM peak")
    ax.bar(x + w, [r["flops_per_mp"] / peaks["isa"]["flops"] for r in rows], w, label="at the ISA peak")
    ax.set_xticks(x, [r["net"] for r in rows], fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("seconds per megapixel")
    ax.set_title("network passes against the CPU's peak")
    ax.legend(fontsize=7)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    return _save(fig, path)


# -- the page --------------------------------------------------------------------------------------------


def _stage_seconds(run: dict, stage: str) -> float:
    s = run["summary"]
    if stage == "startup":  # interpreter start and imports before the pipeline's first stage
        return max(run["wall"] - s.get("total_seconds", 0.0), 0.0)
    return float(s["timings"].get(stage, 0.0))


def _fmt_map_errors(e: dict | None) -> list[str]:
    if not e:
        return ["–"] * 5
    return [f"{e[k]:.4f}" for k in ("normal", "diffuse", "specular", "roughness", "mean")]


def _check(ok: bool) -> str:
    return "**pass**" if ok else "**FAIL**"


def markdown(
    settings: Settings,
    runs: dict,
    errors: dict,
    grid_error: dict | None,
    second: dict | None,
    photo: dict | None,
    flops: list[dict],
    peaks: dict,
    table: list[dict],
    tiles: dict | None,
    grid: int,
    capture_seconds: float,
    seconds: float,
    quick: bool,
    others: float | None = None,
) -> str:
    """The page; ``others``: the cores other processes used on average (:class:`OtherLoad`)."""
    sizes = settings.sizes
    lines = [
        "<!-- generated by `ebr bench estimate`; do not edit by hand -->",
        "",
        "# `ebr estimate` at full resolution: time, memory and error against resolution",
        "",
        f"Machine: {machine()}. Load average (1 min) during the runs: "
        f"{min(r['load'][0] for r in runs.values()):.1f}–{max(max(r['load']) for r in runs.values()):.1f}"
        f" (the benchmark's own runs included). {load_sentence(others)}"
        + (" **Quick mode: reduced sizes, not the documented numbers.**" if quick else ""),
        "",
        f"Test capture: `{MATERIAL}` under `{ENV}`, near setup, Mitsuba `direct`, "
        f"{settings.capture_res}², {settings.spp} spp, seed 0 (rendered in {capture_seconds:.0f} s); "
        f"the model's grid is {grid}² (read from the shipped model). Inputs of the other sizes are its "
        f"shots area-resampled ({sizes[-1]}² upsampled). Every row is one `ebr estimate --json` "
        "process, wall time including Python start-up and imports. "
        f"Benchmark run: {seconds:.0f} s.",
        "",
        "## Time per stage and peak memory",
        "",
        "| size | refine | total s | " + " | ".join(("startup",) + STAGES) + " | peak GB | stdout JSON | "
        "progress on stderr |",
        "|" + "---|" * (len(STAGES) + 7),
    ]
    for (s, r), run in sorted(runs.items()):
        summ = run["summary"]
        if summ is None:
            lines.append(f"| {s}² | {settings.refine_steps if r else 0} | failed (exit {run['code']}) |")
            continue
        shown = progress_shown(summ, run["stderr"])
        prog = "all" if all(shown.values()) else "missing: " + ", ".join(k for k, v in shown.items() if not v)
        cells = [
            f"{_stage_seconds(run, k):.1f}" if k in ("startup",) or k in summ["timings"] else "–"
            for k in ("startup",) + STAGES
        ]
        lines.append(
            f"| {s}² | {settings.refine_steps if r else 0} | {run['wall']:.1f} | "
            + " | ".join(cells)
            + f" | {run['rss'] / 1e9:.2f} | yes | {prog} |"
        )
    lines += ["", "![time per stage and peak memory](estimate_time.png)", ""]
    sub = []
    for (s, r), run in sorted(runs.items()):
        summ = run["summary"]
        if summ is None or r:
            continue
        pt = summ.get("prediction_timings") or {}
        sub.append(
            f"| {s}² | "
            + " | ".join(
                f"{pt.get(k, 0.0):.1f}"
                for k in ("lighting", "extract", "select", "grid_pass", "exemplars", "full_pass")
            )
            + f" | {summ['tiles']} × {summ['tile']}²; mean of "
            + ", ".join(f"{m}²" for m in summ.get("ensemble", []))
            + " |"
        )
    lines += [
        "Inside `lighting` (once per capture, at the grid) and `maps` (without refinement):",
        "",
        "| size | lighting net | SG extraction | selection | grid pass | exemplars at N | cascade at N | "
        "passes |",
        "|---|---|---|---|---|---|---|---|",
        *sub,
        "",
    ]
    ref = [
        (s, run) for (s, r), run in sorted(runs.items()) if r and run["summary"] and run["summary"]["refine"]
    ]
    if ref:
        lines += [
            "Refinement (coarse to fine): steps per level and seconds",
            "",
            "| size | levels (size: steps) | refine s | re-render RMSE network → refined |",
            "|---|---|---|---|",
        ]
        for s, run in ref:
            rf = run["summary"]["refine"]
            lv = ", ".join(f"{x['size']}²: {x['run']}" for x in rf["levels"])
            e = run["summary"]["rerender_error"]
            lines.append(
                f"| {s}² | {lv} | {rf['seconds']:.1f} | {e['network']['mean']['rmse']:.4f} → "
                f"{e['refined']['mean']['rmse']:.4f} |"
            )
        lines.append("")

    lines += [
        "## Error against resolution",
        "",
        f"Maps of each estimate resampled to the truth's {settings.capture_res}² and compared per map "
        "(RMSE; normals as (n+1)/2, roughness one channel). The grid row is the estimate at the model "
        f"grid (`--max-size {grid}`) upsampled.",
        "",
        "| estimate | refined | normal | diffuse | specular | roughness | mean |",
        "|---|---|---|---|---|---|---|",
    ]
    if grid_error:
        lines.append(f"| {grid}² (grid) | no | " + " | ".join(_fmt_map_errors(grid_error)) + " |")
    for (s, r), e in sorted(errors.items()):
        lines.append(f"| {s}² | {'yes' if r else 'no'} | " + " | ".join(_fmt_map_errors(e)) + " |")
    lines += ["", "![map error against resolution](estimate_error.png)", ""]
    if second:
        lines += [
            f"The second capture (`{SECOND[0]}` under `{SECOND[1]}`, same setup and spp), maps only, "
            "estimated in process:",
            "",
            "| estimate | normal | diffuse | specular | roughness | mean |",
            "|---|---|---|---|---|---|",
        ]
        for size, e in sorted(second.items()):
            lines.append(
                f"| {size}²{' (grid)' if size == grid else ''} | " + " | ".join(_fmt_map_errors(e)) + " |"
            )
        lines.append("")

    isa = peaks["isa"]
    lines += [
        "## Network FLOPs against the CPU's peak",
        "",
        f"Peak (ISA): {isa['cores']} cores × {isa['clock_ghz']:.2f} GHz (`cpu MHz` of /proc/cpuinfo) × "
        f"{isa['flops_per_cycle']} float32 FLOPs per cycle ({isa['isa']}: {isa['lanes']} lanes × 2 (FMA) × "
        f"{isa['ports']} FMA ports, the ports assumed) = {isa['flops'] / 1e9:.0f} GFLOP/s. Peak (measured): "
        f"`torch.mm` of 4096² float32, best of 3 = {peaks['gemm'] / 1e9:.0f} GFLOP/s. FLOPs = 2 × the "
        "multiply-adds of every convolution (forward hooks); the elementwise work (LayerNorm, gates, "
        f"activations) is not counted. Measured: one FastNAFNet pass at {settings.flops_size}², per "
        "megapixel.",
        "",
        "| network | width | GFLOP / MP | s / MP measured | s / MP at GEMM peak | s / MP at ISA peak | "
        "measured ÷ GEMM peak |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in flops:
        at_gemm = r["flops_per_mp"] / peaks["gemm"]
        lines.append(
            f"| {r['net']} | {r['width']} | {r['flops_per_mp'] / 1e9:.2f} | {r['seconds_per_mp']:.3f} | "
            f"{at_gemm:.4f} | {r['flops_per_mp'] / isa['flops']:.4f} | {r['seconds_per_mp'] / at_gemm:.0f}× |"
        )
    lines += [
        "",
        "The networks are width-8 NAFNets: a few thousand multiply-adds per pixel against dozens of "
        "passes over the activations, so they run at the memory bandwidth, far from the arithmetic "
        "peak; the lighting net runs once at the grid and costs nothing at full resolution.",
        "",
        "![network passes against the peak](estimate_flops.png)",
        "",
    ]

    if table:
        lines += [
            "## Knobs",
            "",
            "Irradiance table (`RenderOptions.irradiance_table`, the diffuse environment "
            f"term of the estimate's renders) against the per-pair closed form, {settings.flops_size}² "
            "no-flash render of the procedural material (lobe loop on):",
            "",
            "| table | relative RMSE | seconds |",
            "|---|---|---|",
        ]
        for r in table:
            lines.append(f"| {r['table'] or 'exact'} | {r['rel_rmse']:.2e} | {r['seconds']:.3f} |")
        lines.append("")
    if tiles:
        d = tiles["difference"]
        lines += [
            f"Tiles against one pass at {settings.flops_size}² ({tiles['count']} tiles of {tiles['tile']}², "
            f"forced): one pass {tiles['one pass']:.1f} s, tiles {tiles['tiles']:.1f} s; mean absolute "
            f"difference of the maps relative to their mean: diffuse {d['diffuse']:.2%}, specular "
            f"{d['specular']:.2%}, roughness {d['roughness']:.2%} (channel attention and receptive "
            "fields at the tile edges; every tile has the capture's lighting, exemplars and flash scale "
            "and its true geometry). Tiles are used only when one pass would exceed "
            "`ebr_mitsuba.estimate.fullres.PASS_MEMORY`.",
            "",
        ]

    lines += ["## Acceptance (issue 12)", "", "| check | measured | result |", "|---|---|---|"]
    for s, budget in BUDGET.items():
        run = runs.get((s, False))
        if run and run["summary"]:
            lines.append(
                f"| {s}² maps without refinement ≤ {budget:g} s | {run['wall']:.1f} s | "
                f"{_check(run['wall'] <= budget)} |"
            )
    big = [r for r in runs.values() if r["summary"]]
    if big:
        peak = max(r["rss"] for r in big) / 1e9
        lines.append(
            f"| peak memory ≤ {MEMORY_BUDGET_GB:g} GB | {peak:.2f} GB | {_check(peak <= MEMORY_BUDGET_GB)} |"
        )
    run = runs.get((1024, True))
    if run and run["summary"]:
        t = run["summary"]["refine"]["seconds"]
        lines.append(
            f"| {settings.refine_steps} refinement steps at 1024² ≤ {REFINE_BUDGET:g} s | {t:.1f} s | "
            f"{_check(t <= REFINE_BUDGET)} |"
        )
    e1024, e256 = errors.get((1024, False)), errors.get((256, False))
    if e1024 and e256:
        lines.append(
            f"| 1024² map error ≤ 256² estimate upsampled | mean {e1024['mean']:.4f} vs "
            f"{e256['mean']:.4f} | {_check(e1024['mean'] <= e256['mean'])} |"
        )
    if photo:
        ok = photo["code"] == 0 and photo["said_size"] and photo["wall"] <= BUDGET[2048]
        lines.append(
            f"| a {settings.photo_size}² photo completes, says the working size, within the 2048² "
            f'budget | exit {photo["code"]}, {photo["wall"]:.1f} s, "{photo["message"]}" | {_check(ok)} |'
        )
    prog_ok = all(all(progress_shown(r["summary"], r["stderr"]).values()) for r in big)
    lines.append(
        f"| every stage above 1 s shows progress on stderr; `--json` clean on stdout | "
        f"{len(big)} runs | {_check(prog_ok and len(big) == len(runs))} |"
    )
    return "\n".join(lines) + "\n"


# -- the benchmark ---------------------------------------------------------------------------------------


def run(out_dir: Path, quick: bool = False, progress: Callable[[str], None] | None = None) -> Path:
    """Run the benchmark; write ``out_dir/estimate.md`` and its plots; return the Markdown path."""
    from ..capture import capture
    from ..fsutil import atomic_write_text
    from ..materials import load_material
    from ..metrics import map_rmse
    from ..model.predict import load_predictor
    from ..variant import ensure_variant

    say = progress or _say
    ensure_variant()
    settings = QUICK if quick else FULL
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    others = OtherLoad()
    predictor = load_predictor(None)
    grid = predictor.grid
    runs, errors = {}, {}
    with tempfile.TemporaryDirectory(prefix="ebr-bench-estimate-") as work:
        work = Path(work)
        say(f"[estimate] rendering the test capture ({settings.capture_res}², {settings.spp} spp) ...")
        t0 = time.perf_counter()
        cap = work / "capture"
        capture(
            MATERIAL, ENV, "near", cap, spp=settings.spp, res=settings.capture_res, seed=0, progress=False
        )
        capture_seconds = time.perf_counter() - t0
        truth = load_material(cap / "maps")
        n_truth = truth.shape[0]
        for size in settings.sizes:
            paths = make_inputs(cap, size, work / f"in{size}")
            for refine in (False, True):
                say(f"[estimate] {size}² {'with' if refine else 'without'} refinement ...")
                out = work / f"est{size}{'r' if refine else ''}"
                argv = ["--flash", paths["flash"], "--noflash", paths["noflash"], "--out", out]
                if refine:
                    argv += ["--refine-steps", settings.refine_steps]
                res = run_cli(argv)
                runs[(size, refine)] = res
                if res["summary"] is not None:
                    errors[(size, refine)] = map_rmse(maps_at(load_material(out / "maps"), n_truth), truth)
                    shutil.rmtree(out, ignore_errors=True)
                else:
                    say(f"[estimate] {size}² failed: {res['stderr'].strip().splitlines()[-1:]}")
        say(f"[estimate] the grid estimate ({grid}²) ...")
        paths = make_inputs(cap, settings.capture_res, work / f"in{settings.capture_res}")
        res = run_cli(
            [
                "--flash",
                paths["flash"],
                "--noflash",
                paths["noflash"],
                "--out",
                work / "estgrid",
                "--max-size",
                grid,
            ]
        )
        grid_error = (
            map_rmse(maps_at(load_material(work / "estgrid" / "maps"), n_truth), truth)
            if res["summary"]
            else None
        )
        photo = None
        src = shared_data_dir() / "photos" / "flash_only" / PHOTO
        if src.is_file():
            from ..imageio import read_image, resize_area, write_png

            say(f"[estimate] a {settings.photo_size}² photo ...")
            big = work / f"photo{settings.photo_size}.png"
            write_png(big, resize_area(read_image(src), (settings.photo_size, settings.photo_size)))
            res = run_cli(["--flash", big, "--out", work / "estphoto"])
            line = next((ln for ln in res["stderr"].splitlines() if "estimating at" in ln), "")
            photo = {
                "code": res["code"],
                "wall": res["wall"],
                "rss": res["rss"],
                "said_size": "estimating at 2048x2048" in line or settings.photo_size <= 2048,
                "message": line.replace("warning: ", "").split(" (")[0][:90],
            }
        second = None
        if SECOND:
            say("[estimate] the second capture ...")
            cap2 = work / "capture2"
            capture(
                SECOND[0],
                SECOND[1],
                "near",
                cap2,
                spp=settings.spp,
                res=settings.capture_res,
                seed=0,
                progress=False,
            )
            second = measure_errors_in_process(
                predictor, cap2, [s for s in settings.sizes if s <= settings.capture_res]
            )
        say("[estimate] FLOPs, peaks and knobs ...")
        peaks = {"isa": isa_peak(), "gemm": gemm_peak(4096 if not quick else 1024)}
        flops = measure_flops(predictor.bundle, settings.flops_size)
        table = measure_table(settings.flops_size, settings.table_sizes)
        tiles = measure_tiles(predictor, cap, settings.flops_size)
    plot_time(runs, out_dir / "estimate_time.png")
    plot_error(errors, out_dir / "estimate_error.png")
    plot_flops(flops, peaks, out_dir / "estimate_flops.png")
    path = out_dir / "estimate.md"
    atomic_write_text(
        path,
        markdown(
            settings,
            runs,
            errors,
            grid_error,
            second,
            photo,
            flops,
            peaks,
            table,
            tiles,
            grid,
            capture_seconds,
            time.perf_counter() - t_start,
            quick,
            others.cores(),
        ),
    )
    return path


__all__ = [
    "FULL",
    "QUICK",
    "Settings",
    "gemm_peak",
    "isa_peak",
    "make_inputs",
    "maps_at",
    "markdown",
    "measure_errors_in_process",
    "measure_flops",
    "measure_table",
    "measure_tiles",
    "progress_shown",
    "run",
    "run_cli",
]
