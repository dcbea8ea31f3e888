"""``ebr bench tilt``: what ``ebr estimate``'s highlight tilt (:mod:`ebr_mitsuba.estimate.
highlight_tilt`) does to the maps of metal and glossy validation captures; writes ``tilt.md``,
``tilt.json`` and a picture.

Each capture is estimated by ``ebr estimate`` (the shipped model, its defaults, the data set's known
flash intensity: :func:`ebr_mitsuba.evaluation.evaluate.estimate_sample`). The tilt concerns only the
captures that keep the network's normals (a metal, or a sample too glossy for the shading normals);
those whose tilt was read and applied are estimated a second time with ``--no-highlight-tilt``, and
their maps are scored with three normal maps, everything else equal:

* ``network``: the network's normals (``--no-highlight-tilt``; the default until 2026-12-08);
* ``flat``: the flat normal;
* ``tilted``: the flat normal tilted to the clipped highlight, what ``ebr estimate`` writes.

Metrics as ``ebr bench models``': normal RMSE ((n+1)/2), mean per-map RMSE, re-render RMSE under
30 held-out lights. For scale, each capture's tilt is compared with the one its true normal map
holds (the mean normal's slopes).

Inputs: ``EBR_TILT_DATA`` (data sets of ``ebr generate`` with near flash / no-flash shots,
separated by ``:``; default ``EBR_VAL_DATA``): validation sets, never the test split, whose figures
are the ``ebr estimate`` row of ``docs/models.md``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from ._common import (
    by_data_set,
    machine,
    measure_validation,
    validation_captures,
    validation_note,
    validation_sets,
    variant_score,
)

PAGE = "tilt.md"
VARIANTS = ("network", "flat", "tilted")
QUICK_SAMPLES = 2
CROP = 32  # the picture's crop of the flash shot's centre, pixels at the fit size
COMMANDS = """\
export EBR_DATA_DIR=../shared/data
ebr generate configs/data_real_val.toml --out /tmp/ebr-data/real_val --workers 2
ebr generate configs/data_real_val2.toml --out /tmp/ebr-data/real_val2 --workers 2
ebr generate configs/data_proc_val.toml --out /tmp/ebr-data/proc_val --workers 2
D=/tmp/ebr-data
EBR_TILT_DATA=$D/real_val:$D/real_val2:$D/proc_val ebr bench tilt  # this page"""


def _log(msg: str) -> None:
    print(f"[bench tilt] {msg}", file=sys.stderr, flush=True)


def data_sets() -> list[Path]:
    return validation_sets("EBR_TILT_DATA")


def unavailable() -> str | None:
    return validation_note("EBR_TILT_DATA", PAGE)


def true_slope(normal: np.ndarray) -> np.ndarray:
    """The mean normal's slopes (n_x, n_y) / n_z of an (H, W, 3) normal map."""
    n = np.asarray(normal, np.float64).reshape(-1, 3).mean(axis=0)
    return n[:2] / n[2]


def measure(roots: list[Path], limit: int = 0, progress=None) -> dict:
    """Per capture that keeps the network's normals: the tilt's record, the true tilt and, where it
    was applied, each variant's metrics; per data set and over all: the means over the captures
    it was applied to and how often the tilt helped."""
    from .. import metrics
    from ..estimate.highlight_tilt import tilted_normals
    from ..evaluation.evaluate import _at_size, _truth, estimate_sample
    from ..model.predict import load_predictor
    from ..svbrdf import SVBRDF

    predictor = load_predictor(None)
    pairs = metrics.rerender_pairs(0)
    rows, crops = [], {}
    for root, ds, i, intensity in validation_captures(roots, PAGE, limit):
        result = estimate_sample(predictor, root, i, nominal=intensity)
        record = result.get("highlight_tilt")
        if record is None:  # the shading normals applied: the tilt is not read
            continue
        item = ds[i]
        truth = _truth(item)
        row = {
            "data": root.name,
            "index": i,
            "material": str(ds.index["samples"][i]["material"]).split("/")[-1],
            "record": record,
            "true_slope": [float(v) for v in true_slope(truth.normal)],
        }
        if record["applied"]:
            network = estimate_sample(
                predictor, root, i, nominal=intensity, options={"highlight_tilt": False}
            )
            truth_renders = metrics.rerenders(truth, pairs, intensity)
            base = _at_size(result.maps, truth.shape)
            shape = truth.shape
            normals = {
                "network": np.asarray(_at_size(network.maps, shape).normal),
                "flat": tilted_normals(shape, (0.0, 0.0)),
                "tilted": np.asarray(base.normal),
            }
            for name, normal in normals.items():
                maps = SVBRDF(normal, base.diffuse, base.specular, base.roughness, source=name)
                row[name] = variant_score(maps, truth, "normal", pairs, intensity, truth_renders)
            flash = item["photos"][ds.shot_names.index("flash")].permute(1, 2, 0).numpy()
            crops[(root.name, i)] = _crop(flash)
        rows.append(row)
        if progress:
            what = (
                f"re-render {row['network']['rerender']:.4f} -> {row['tilted']['rerender']:.4f}"
                if record["applied"]
                else record.get("reason", "not applied")
            )
            progress(f"{root.name} {i}: {row['material']} {what}")
    summary = by_data_set(rows, roots, _summary)
    return {"rows": rows, "summary": summary, "crops": crops}


def _crop(flash: np.ndarray) -> np.ndarray:
    """The centre (CROP² at the fit size) of a flash shot (H, W, 3), log-scaled to [0, 1], for the
    picture."""
    from ..estimate.flashfit import FIT_SIZE, shrink_factor
    from ..imageio import resize_area

    flash = np.asarray(flash, np.float32)
    f = shrink_factor(*flash.shape[:2], FIT_SIZE)
    if f > 1:
        flash = resize_area(flash, (flash.shape[0] // f, flash.shape[1] // f))
    grey = flash.mean(axis=-1)
    h, w = grey.shape
    y0, x0 = (h - CROP) // 2, (w - CROP) // 2
    c = np.log1p(grey[y0 : y0 + CROP, x0 : x0 + CROP] / max(float(np.median(grey)), 1e-6))
    return c / max(float(c.max()), 1e-6)


def _summary(rows: list[dict]) -> dict:
    applied = [r for r in rows if r["record"]["applied"]]

    def count(key: str, sign: float) -> int:
        return int(sum(sign * (r["tilted"][key] - r["network"][key]) > 1e-6 for r in applied))

    out = {"captures": len(rows), "applied": len(applied)}
    if applied:
        out.update(
            {
                v: {k: float(np.mean([r[v][k] for r in applied])) for k in ("normal", "mean", "rerender")}
                for v in VARIANTS
            }
        )
        out.update(
            rerender_better=count("rerender", -1.0),
            rerender_worse=count("rerender", 1.0),
            normal_better=count("normal", -1.0),
            normal_worse=count("normal", 1.0),
        )
    return out


def _picture(result: dict, path: Path) -> list[dict]:
    """The flash shot's centre per capture the tilt was applied to, with the highlight's centroid
    read (+) and where the true normals' mean tilt puts it (x); returns those rows."""
    shown = [r for r in result["rows"] if r["record"]["applied"]]
    if not shown:
        return shown
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..geometry import NEAR_DISTANCE

    def marks(r):  # (read, truth) centroids in crop pixels (x right, y down)
        size = r["record"]["grid"][0]
        scale = size / 2.0  # sample units to pixels
        out = []
        for s in (r["record"]["slope"], r["true_slope"]):
            x, y = -NEAR_DISTANCE * s[0], -NEAR_DISTANCE * s[1]
            out.append((CROP / 2 - 0.5 + x * scale, CROP / 2 - 0.5 - y * scale))
        return out

    fig, axes = plt.subplots(1, len(shown), figsize=(2.4 * len(shown), 3.0), squeeze=False)
    for ax, r in zip(axes[0], shown):
        ax.imshow(result["crops"][(r["data"], r["index"])], cmap="gray", vmin=0, vmax=1)
        (rx, ry), (tx, ty) = marks(r)
        ax.plot([rx], [ry], "+", color="tab:red", markersize=12, mew=2, label="read")
        ax.plot([tx], [ty], "x", color="tab:cyan", markersize=10, mew=2, label="true normals")
        ax.plot([CROP / 2 - 0.5], [CROP / 2 - 0.5], ".", color="yellow", markersize=6, label="centre")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{r['material'][:18]}\n{r['record']['degrees']:.2f}°", fontsize=8)
    axes[0][0].legend(fontsize=6, loc="lower left")
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return shown


def _page(result: dict, roots: list[Path], seconds: float, quick: bool, shown: list[dict]) -> str:
    from ..estimate.highlight_tilt import MAX_ROUGHNESS, MAX_TILT

    lines = [
        "# The highlight tilt on validation captures",
        "",
        "Generated by `ebr bench tilt` (`ebr_mitsuba/bench/tilt.py`); do not edit by hand.",
        f"Machine: {machine()}; took {seconds:.0f} s.",
        "",
    ]
    if quick:
        lines += [
            f"**Quick mode** (first {QUICK_SAMPLES} samples per data set): not the documented figures.",
            "",
        ]
    lines += [
        "Where `ebr estimate` keeps the network's normals (a metal, or a sample too glossy for the shading "
        "normals), it reads the sample's tilt off the flash shot's clipped highlight and writes the flat "
        "normal tilted by it ([estimate.md](../estimate.md#the-highlight-tilt-default)); it trusts the "
        f"reading for a flash-fitted roughness up to {MAX_ROUGHNESS:g} and a tilt up to {MAX_TILT:g} "
        "(slope). Each such capture is estimated by `ebr estimate` (the shipped model, its defaults); "
        "where the tilt was applied, also with `--no-highlight-tilt`, and its maps scored with three "
        "normal maps, everything else equal: *network*, the network's normals (the default until "
        "2026-12-08); *flat*; *tilted*, what `ebr estimate` writes. Metrics as in "
        "[models.md](../models.md).",
        "",
        f"Data: {', '.join(f'`{r}`' for r in roots)}: validation captures (the training split's material "
        "sets and maps, or new draws of the procedural families), never the test split; the test split's "
        "figures are the `ebr estimate` row of [models.md](../models.md).",
        "",
        "```",
        COMMANDS,
        "```",
        "",
        "| data | captures keeping the network's normals (tilt applied) | normals | normal RMSE "
        "| mean per-map RMSE | held-out re-render |",
        "|---|---:|---|---:|---:|---:|",
    ]
    for name, s in result["summary"].items():
        if not s["applied"]:
            lines.append(f"| {name} | {s['captures']} (0) | – | | | |")
            continue
        for v in VARIANTS:
            c = s[v]
            lines.append(
                f"| {name} | {s['captures']} ({s['applied']}) | {v} | {c['normal']:.5f} | {c['mean']:.5f} "
                f"| {c['rerender']:.4f} |"
            )
    lines.append("")
    for name, s in result["summary"].items():
        if s["applied"]:
            lines.append(
                f"- **{name}**: tilted against the network's normals, the held-out re-render is lower in "
                f"{s['rerender_better']} and higher in {s['rerender_worse']} of the {s['applied']} captures "
                f"the tilt was applied to, the normal RMSE lower in {s['normal_better']} and higher in "
                f"{s['normal_worse']}."
            )
    lines.append("")
    if shown:
        lines += [
            "![the highlight read](tilt.png)",
            "",
            "*The flash shot's centre (log scale) of each capture the tilt was applied to: the centroid of "
            "its clipped highlight (+), where the true normal map's mean tilt puts the highlight (x) and "
            "the frame's centre (dot).*",
            "",
        ]
    lines += [
        "## Per capture",
        "",
        "| data | # | material | tilt read (slopes) | true mean tilt | highlight pixels | applied | "
        "re-render: network | flat | tilted |",
        "|---|---:|---|---:|---:|---:|---|---:|---:|---:|",
    ]
    for r in result["rows"]:
        rec = r["record"]
        read = f"{rec['slope'][0]:+.4f}, {rec['slope'][1]:+.4f}" if rec["pixels"] else "–"
        true = f"{r['true_slope'][0]:+.4f}, {r['true_slope'][1]:+.4f}"
        applied = "yes" if rec["applied"] else rec.get("reason", "no")
        if rec["applied"]:
            cells = " | ".join(f"{r[v]['rerender']:.4f}" for v in VARIANTS)
        else:
            cells = "– | – | –"
        lines.append(
            f"| {r['data']} | {r['index']} | {r['material']} | {read} | {true} | {rec['pixels']} | "
            f"{applied} | {cells} |"
        )
    lines.append("")
    return "\n".join(lines)


def run(out_dir: Path | str, quick: bool = False) -> Path:
    """Measure every capture of the data sets (``--quick``: the first :data:`QUICK_SAMPLES` of
    each) and write ``out_dir/tilt.md`` with its JSON record and picture."""
    from ..fsutil import atomic_write_text

    limit = QUICK_SAMPLES if quick else 0
    roots, result, seconds, out_dir = measure_validation(
        "EBR_TILT_DATA", PAGE, lambda roots: measure(roots, limit=limit, progress=_log), out_dir
    )
    shown = _picture(result, out_dir / "tilt.png")
    record = {"rows": result["rows"], "summary": result["summary"]}
    atomic_write_text(out_dir / "tilt.json", json.dumps(record, indent=1) + "\n")
    atomic_write_text(out_dir / PAGE, _page(result, roots, seconds, quick, shown))
    return out_dir / PAGE
