"""``ebr bench normals``: what ``ebr estimate``'s shading normals do to the maps on validation
captures, with and without the relief read off the ratio's residual (:mod:`ebr_mitsuba.estimate.
relief`); writes ``normals.md``, ``normals.json`` and a picture.

Each capture is estimated once by ``ebr estimate`` (the shipped model, its defaults, the data set's
known flash intensity: :func:`ebr_mitsuba.evaluation.evaluate.estimate_sample`). Its maps are then
scored with three normal maps, everything else equal:

* ``flat``: the flat normal;
* ``albedo-following``: the shading normals without the relief reading
  (``ShadingNormals.shrunk(map_gain)``; the default until 2026-12-07);
* ``with relief``: the normal map ``ebr estimate`` wrote (``map_normal()``, the default).

Captures whose shading normals did not apply (a metal, a glossy sample) keep the network's normals
in all three and are counted apart.

The gains (:data:`MAP_GAINS` × :data:`RELIEF_GAINS`): the same captures' normal maps remade with
``ShadingNormals.shrunk(map_gain, relief_gain)`` over a grid of the two gains, each scored by
normal RMSE and by the normal structure of ``ebr bench models`` (every capture counted, the
network's normals where the shading normals did not apply). A gain above the least-squares one
buys structure (the predicted normals' spread) with error; the table and the picture show that
trade against the oracle constant normal (each capture's own mean normal), the line the normal RMSE
must stay under. Metrics as ``ebr bench models``': normal RMSE (as (n+1)/2), the
mean per-map RMSE, the re-render RMSE under 30 held-out lights and the normals' spread over the
truth's (capped at 1 per capture).

Inputs: ``EBR_NORMALS_DATA`` (data sets of ``ebr generate`` with near flash / no-flash shots,
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
    thumbnail_grid,
    validation_captures,
    validation_note,
    validation_sets,
    variant_score,
)

PAGE = "normals.md"
VARIANTS = ("flat", "albedo-following", "with relief")
QUICK_SAMPLES = 2
PICTURES = 4  # captures shown: those the relief changed most (by normal RMSE)
MAP_GAINS = (0.4, 0.6, 0.8, 1.0)  # ShadingNormalsConfig.map_gain values of the gain grid
RELIEF_GAINS = (0.25, 0.5, 0.75, 1.0, 1.5)  # ShadingNormalsConfig.relief_gain values of the grid
THUMB = 128
COMMANDS = """\
export EBR_DATA_DIR=../shared/data
ebr generate configs/data_real_val.toml --out /tmp/ebr-data/real_val --workers 2
ebr generate configs/data_real_val2.toml --out /tmp/ebr-data/real_val2 --workers 2
ebr generate configs/data_proc_val.toml --out /tmp/ebr-data/proc_val --workers 2
D=/tmp/ebr-data
EBR_NORMALS_DATA=$D/real_val:$D/real_val2:$D/proc_val ebr bench normals  # this page"""


def _log(msg: str) -> None:
    print(f"[bench normals] {msg}", file=sys.stderr, flush=True)


def data_sets() -> list[Path]:
    return validation_sets("EBR_NORMALS_DATA")


def unavailable() -> str | None:
    return validation_note("EBR_NORMALS_DATA", PAGE)


def spread(normal: np.ndarray) -> float:
    """The normals' spatial spread: the mean of the x and y components' standard deviations."""
    return float(np.mean(np.asarray(normal)[..., :2].reshape(-1, 2).std(axis=0)))


def variant_normals(result) -> dict[str, np.ndarray]:
    """The three normal maps of an :class:`~ebr_mitsuba.estimate.pipeline.EstimateResult` (module
    docstring); without shading normals, the estimate's own in all three."""
    final = np.asarray(result.maps.normal)
    if result.shading is None:
        return dict.fromkeys(VARIANTS, final)
    from ..estimate.shading_normals import ShadingNormalsConfig

    flat = np.zeros_like(final)
    flat[..., 2] = 1.0
    return {
        "flat": flat,
        "albedo-following": result.shading.shrunk(ShadingNormalsConfig().map_gain),
        "with relief": final,
    }


def measure(roots: list[Path], limit: int = 0, progress=None) -> dict:
    """Per capture: each variant's metrics (module docstring), the relief record and small maps for
    the picture; per data set and over all: the means and how often the relief helped."""
    from .. import metrics
    from ..evaluation.evaluate import _at_size, _truth, estimate_sample
    from ..materials import resample_svbrdf
    from ..model.predict import load_predictor
    from ..svbrdf import SVBRDF

    predictor = load_predictor(None)
    pairs = metrics.rerender_pairs(0)
    rows, thumbs = [], {}
    for root, ds, i, intensity in validation_captures(roots, PAGE, limit):
        item = ds[i]
        truth = _truth(item)
        result = estimate_sample(predictor, root, i, nominal=intensity)
        truth_renders = metrics.rerenders(truth, pairs, intensity)
        row = {
            "data": root.name,
            "index": i,
            "material": str(ds.index["samples"][i]["material"]).split("/")[-1],
            "read": result.shading is not None,
            "relief": (result.get("shading_normals") or {}).get("relief"),
        }
        base = result.maps
        for name, normal in variant_normals(result).items():
            maps = SVBRDF(normal, base.diffuse, base.specular, base.roughness, source=name)
            maps = _at_size(maps, truth.shape)  # the working size may exceed the data set's
            row[name] = variant_score(maps, truth, "normal", pairs, intensity, truth_renders)
            row[name]["spread"] = min(spread(maps.normal) / max(spread(truth.normal), 1e-6), 1.0)
            thumbs[(root.name, i, name)] = resample_svbrdf(maps, THUMB).normal
        thumbs[(root.name, i, "truth")] = resample_svbrdf(truth, THUMB).normal
        row["gains"] = _gain_grid(result, truth)
        row["oracle_normal"] = _oracle_normal_rmse(truth)
        rows.append(row)
        if progress:
            a, b = row["albedo-following"]["normal"], row["with relief"]["normal"]
            progress(f"{root.name} {i}: {row['material']} normal RMSE {a:.4f} -> {b:.4f}")
    summary = by_data_set(rows, roots, _summary)
    return {"rows": rows, "summary": summary, "thumbs": thumbs}


def _normal_rmse(normal: np.ndarray, truth) -> float:
    from .. import metrics

    normal = np.asarray(normal)
    if normal.shape != truth.normal.shape:
        from ..materials import resample_svbrdf
        from ..svbrdf import SVBRDF

        flat = np.zeros(normal.shape[:2] + (3,), np.float32)
        normal = resample_svbrdf(SVBRDF(normal, flat, flat, flat[..., 0]), truth.shape).normal
    return metrics.rmse((normal + 1.0) * 0.5, truth.encoded_normal())


def _oracle_normal_rmse(truth) -> float:
    """Normal RMSE of the oracle constant maps' normal (the truth's own mean normal)."""
    from ..evaluation.baselines import oracle_constant

    return _normal_rmse(oracle_constant(truth).normal, truth)


def _gain_grid(result, truth) -> list[list[float]]:
    """``[map_gain, relief_gain, normal RMSE, spread ÷ truth's (capped)]`` over the gain grid; the
    estimate's own normals at every point where the shading normals did not apply."""
    truth_spread = max(spread(truth.normal), 1e-6)
    out = []
    for m in MAP_GAINS:
        for g in RELIEF_GAINS:
            n = np.asarray(result.maps.normal) if result.shading is None else result.shading.shrunk(m, g)
            out.append([m, g, _normal_rmse(n, truth), min(spread(n) / truth_spread, 1.0)])
    return out


def gain_table(rows: list[dict]) -> list[dict]:
    """Per grid point, over ``rows``: ``{"map_gain", "relief_gain", "normal", "structure"}`` means."""
    grids = np.array([r["gains"] for r in rows], np.float64)  # (captures, points, 4)
    means = grids.mean(axis=0)
    return [  # the gains as the grid has them (a mean of equal floats need not equal them)
        {"map_gain": float(g[0]), "relief_gain": float(g[1]), "normal": float(p[2]), "structure": float(p[3])}
        for g, p in zip(grids[0], means)
    ]


def _summary(rows: list[dict]) -> dict:
    read = [r for r in rows if r["read"]]

    def count(key: str, sign: float) -> int:
        return int(sum(sign * (r["with relief"][key] - r["albedo-following"][key]) > 1e-5 for r in read))

    return {
        "captures": len(rows),
        "read": len(read),
        **{
            v: {k: float(np.mean([r[v][k] for r in rows])) for k in ("normal", "mean", "rerender", "spread")}
            for v in VARIANTS
        },
        "oracle_normal": float(np.mean([r["oracle_normal"] for r in rows])),
        "gains": gain_table(rows),
        "normal_better": count("normal", -1.0),
        "normal_worse": count("normal", 1.0),
        "rerender_better": count("rerender", -1.0),
        "rerender_worse": count("rerender", 1.0),
    }


def _picture(result: dict, path: Path) -> list[dict]:
    """Truth | albedo-following | with relief normals (as (n+1)/2) of the captures the relief
    changed most; returns those rows."""
    read = [r for r in result["rows"] if r["read"]]
    change = lambda r: abs(r["with relief"]["normal"] - r["albedo-following"]["normal"])  # noqa: E731
    shown = sorted(read, key=change, reverse=True)[:PICTURES]
    if shown:
        thumbnail_grid(
            shown,
            ("truth", "albedo-following", "with relief"),
            lambda r, col: np.clip(
                (np.asarray(result["thumbs"][(r["data"], r["index"], col)]) + 1) / 2, 0, 1
            ),
            lambda r, col: col if col == "truth" else f"{col}: {r[col]['normal']:.4f}",
            path,
        )
    return shown


def _default_gains() -> tuple[float, float]:
    from ..estimate.shading_normals import ShadingNormalsConfig

    opts = ShadingNormalsConfig()
    return opts.map_gain, opts.relief_gain


def _gain_picture(result: dict, path: Path) -> None:
    """Normal RMSE against normal structure over the gain grid (all captures): one line per map
    gain through the relief gains, the oracle constant normal's RMSE and the acceptance's
    structure of 0.5 as dashed lines, the default gains starred."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result["summary"]["all"]
    default = _default_gains()
    fig, ax = plt.subplots(figsize=(5.6, 3.8))
    for m in MAP_GAINS:
        pts = [p for p in s["gains"] if p["map_gain"] == m]
        ax.plot(
            [p["structure"] for p in pts], [p["normal"] for p in pts], "o-", ms=3, label=f"map gain {m:g}"
        )
        for p in pts:
            ax.annotate(
                f"{p['relief_gain']:g}",
                (p["structure"], p["normal"]),
                fontsize=6,
                xytext=(2, 2),
                textcoords="offset points",
            )
    for p in s["gains"]:
        if (p["map_gain"], p["relief_gain"]) == default:
            ax.plot(p["structure"], p["normal"], "k*", ms=11, label="default")
    ax.axhline(s["oracle_normal"], color="grey", ls="--", lw=1, label="oracle constant normal")
    ax.axvline(0.5, color="grey", ls=":", lw=1)
    ax.set_xlabel("normal structure (spread ÷ truth's, capped per capture)")
    ax.set_ylabel("normal RMSE, (n+1)/2")
    ax.set_title("gains of the normal map (labels: relief gain)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _gain_lines(result: dict) -> list[str]:
    groups = list(result["summary"])
    default = _default_gains()
    lines = [
        "## The gains: error against structure",
        "",
        "The same estimates' normal maps remade over a grid of `map_gain` (the albedo-following "
        "slopes) and `relief_gain` (the relief's), each scored by normal RMSE and the normal "
        "structure of [models.md](../models.md) (spread ÷ truth's, capped at 1 per capture, every "
        "capture counted: the network's normals where the shading normals did not apply). Issue 15 "
        "asks for a structure of at least 0.5 with the normal RMSE below the oracle constant normal's "
        "(each capture's own mean normal): "
        + ", ".join(f"{g} {result['summary'][g]['oracle_normal']:.5f}" for g in groups)
        + ". Default starred (★).",
        "",
        "| map gain | relief gain | " + " | ".join(f"{g}: RMSE / structure" for g in groups) + " |",
        "|---:|---:|" + "---:|" * len(groups),
    ]
    for k, p in enumerate(result["summary"]["all"]["gains"]):
        star = " ★" if (p["map_gain"], p["relief_gain"]) == default else ""
        points = [result["summary"][g]["gains"][k] for g in groups]
        cells = [f"{q['normal']:.5f} / {q['structure']:.2f}" for q in points]
        lines.append(f"| {p['map_gain']:g}{star} | {p['relief_gain']:g} | " + " | ".join(cells) + " |")
    lines += ["", "![normal RMSE against structure over the gains](normals_gains.png)", ""]
    return lines


def _page(result: dict, roots: list[Path], seconds: float, quick: bool, shown: list[dict]) -> str:
    lines = [
        "# The shading normals on validation captures: with and without the relief reading",
        "",
        "Generated by `ebr bench normals` (`ebr_mitsuba/bench/normals.py`); do not edit by hand.",
        f"Machine: {machine()}; took {seconds:.0f} s.",
        "",
    ]
    if quick:
        lines += [f"**Quick mode** (first {QUICK_SAMPLES} samples per data set): not the documented figures."]
        lines.append("")
    lines += [
        "Each capture is estimated by `ebr estimate` (the shipped model, its defaults) and its maps "
        "scored with three normal maps, everything else equal: *flat*; *albedo-following*, the "
        "shading normals without the relief the albedo does not show (the default until 2026-12-07); "
        "*with relief*, what `ebr estimate` writes ([estimate.md](../estimate.md#relief-the-albedo-does-"
        "not-show-default)). Captures whose shading normals did not apply (a metal, a glossy sample) "
        "keep the network's normals in all three. Metrics as in [models.md](../models.md); spread: the "
        "normals' spatial spread over the truth's, capped at 1 per capture.",
        "",
        f"Data: {', '.join(f'`{r}`' for r in roots)}: validation captures (the training split's material "
        "sets and maps, or new draws of the procedural families: `configs/data_proc_val.toml`), "
        "never the test split; the test split's figures are the `ebr estimate` row of "
        "[models.md](../models.md).",
        "",
        "```",
        COMMANDS,
        "```",
        "",
        "| data | captures (relief read) | normals | normal RMSE | mean per-map RMSE | held-out re-render "
        "| spread ÷ truth's |",
        "|---|---:|---|---:|---:|---:|---:|",
    ]
    for name, s in result["summary"].items():
        for v in VARIANTS:
            c = s[v]
            lines.append(
                f"| {name} | {s['captures']} ({s['read']}) | {v} | {c['normal']:.5f} | {c['mean']:.5f} "
                f"| {c['rerender']:.4f} | {c['spread']:.2f} |"
            )
    lines.append("")
    for name, s in result["summary"].items():
        lines.append(
            f"- **{name}**: with the relief the normal RMSE is lower in {s['normal_better']} and higher in "
            f"{s['normal_worse']} of the {s['read']} captures read (by over 1e-5), the held-out re-render "
            f"lower in {s['rerender_better']} and higher in {s['rerender_worse']}."
        )
    lines.append("")
    if shown:
        lines += [
            "![truth and estimated normals](normals.png)",
            "",
            "*Normals as (n+1)/2 of the captures the relief changed most: truth | albedo-following | "
            "with relief (normal RMSE in the titles).*",
            "",
        ]
    lines += _gain_lines(result)
    lines += [
        "## Per capture",
        "",
        "| data | # | material | normal RMSE: flat | albedo-following | with relief | sky gradient read "
        "| slopes rms |",
        "|---|---:|---|---:|---:|---:|---|---:|",
    ]
    for r in result["rows"]:
        rel = r["relief"] or {}
        sky = ", ".join(f"{x:.2f}" for x in rel.get("sky_gradient", [])) if rel else "–"
        rms = f"{rel['slope_rms']:.3f}" if rel else "–"
        mark = "" if r["read"] else " (network's)"
        lines.append(
            f"| {r['data']} | {r['index']} | {r['material']}{mark} | {r['flat']['normal']:.4f} | "
            f"{r['albedo-following']['normal']:.4f} | {r['with relief']['normal']:.4f} | {sky} | {rms} |"
        )
    lines.append("")
    return "\n".join(lines)


def run(out_dir: Path | str, quick: bool = False) -> Path:
    """Measure every capture of the data sets (``--quick``: the first :data:`QUICK_SAMPLES` of
    each) and write ``out_dir/normals.md`` with its JSON record and picture."""
    from ..fsutil import atomic_write_text

    limit = QUICK_SAMPLES if quick else 0
    roots, result, seconds, out_dir = measure_validation(
        "EBR_NORMALS_DATA", PAGE, lambda roots: measure(roots, limit=limit, progress=_log), out_dir
    )
    shown = _picture(result, out_dir / "normals.png")
    _gain_picture(result, out_dir / "normals_gains.png")
    # the per-capture gain grids stay out of the record (the summaries have their means per data set)
    rows = [{k: v for k, v in r.items() if k != "gains"} for r in result["rows"]]
    record = {"rows": rows, "summary": result["summary"]}
    atomic_write_text(out_dir / "normals.json", json.dumps(record, indent=1) + "\n")
    atomic_write_text(out_dir / PAGE, _page(result, roots, seconds, quick, shown))
    return out_dir / PAGE
