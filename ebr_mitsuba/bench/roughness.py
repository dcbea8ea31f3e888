"""``ebr bench roughness``: what ``ebr estimate``'s roughness pattern (:mod:`ebr_mitsuba.estimate.
roughness_pattern`) does to the maps on validation captures; writes ``roughness.md``,
``roughness.json`` and two pictures.

Each capture is estimated once by ``ebr estimate`` (the shipped model, its defaults, the data set's
known flash intensity: :func:`ebr_mitsuba.evaluation.evaluate.estimate_sample`). Its maps are then
scored with two roughness maps, everything else equal:

* ``constant``: the flash fit's one roughness (the default until 2026-12-07);
* ``pattern``: the roughness map ``ebr estimate`` wrote, the fitted roughness plus the slope read off
  the flash highlight times the estimate's log-albedo.

Captures whose pattern was not read (a metal, a fit rougher than ``MAX_ROUGHNESS``, the network's
map after a misfit) have the same map in both and are counted apart. The gains (:data:`GAINS`): the
same captures' maps remade with ``GAIN`` replaced by each of a grid (:meth:`RoughnessPattern.at_gain`;
0 is the constant), scored by roughness and mean per-map RMSE. Metrics as ``ebr bench models``':
per-map RMSE (roughness one channel), their mean, the re-render RMSE under 30 held-out lights; the
*oracle constant roughness* is each capture's own mean roughness (its RMSE the truth's spread).

Inputs: ``EBR_ROUGHNESS_DATA`` (data sets of ``ebr generate`` with near flash / no-flash shots,
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

PAGE = "roughness.md"
VARIANTS = ("constant", "pattern")
QUICK_SAMPLES = 2
PICTURES = 4  # captures shown: those the pattern changed most (by roughness RMSE)
GAINS = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)  # the grid of gains on the capped reading
THUMB = 128
COMMANDS = """\
export EBR_DATA_DIR=../shared/data
ebr generate configs/data_real_val.toml --out /tmp/ebr-data/real_val --workers 2
ebr generate configs/data_real_val2.toml --out /tmp/ebr-data/real_val2 --workers 2
EBR_ROUGHNESS_DATA=/tmp/ebr-data/real_val:/tmp/ebr-data/real_val2 ebr bench roughness  # this page"""


def _log(msg: str) -> None:
    print(f"[bench roughness] {msg}", file=sys.stderr, flush=True)


def data_sets() -> list[Path]:
    return validation_sets("EBR_ROUGHNESS_DATA")


def unavailable() -> str | None:
    return validation_note("EBR_ROUGHNESS_DATA", PAGE)


def variant_roughness(result, gain: float | None = None) -> np.ndarray:
    """The (H, W) roughness map of an :class:`~ebr_mitsuba.estimate.pipeline.EstimateResult` with
    the pattern at ``gain`` (None: the map as written; 0: the fitted constant). A map the pattern
    did not make (not read, the network's, no flash fit) is returned as written whatever the gain."""
    from ..estimate.roughness_pattern import RoughnessPattern

    written = np.asarray(result.maps.roughness, np.float32).reshape(result.maps.roughness.shape[:2])
    fit = result.get("flash_fit") or {}
    pattern = RoughnessPattern.from_json(fit.get("roughness_pattern"))
    if gain is None or pattern is None or not pattern.applied or fit.get("roughness_from") != "fit":
        return written
    return pattern.at_gain(gain).roughness_map(float(fit["roughness"]), np.asarray(result.maps.diffuse))


POOL_SIZE = 256  # the real sets are read at this size for their correlation
POOL_STRONG = 0.7  # |r| counted as a roughness that follows the albedo


def pool_correlations(limit: int = 0) -> list[dict]:
    """Per real material set of the training split (``$EBR_DATA_DIR``; ``limit`` > 0: the first
    ``limit``): ``{"set", "r"}``, the correlation of its roughness map with its grey log-albedo at
    POOL_SIZE², sets with a constant roughness or albedo left out."""
    from ..data.split import real_materials
    from ..materials import load_texture_set

    out = []
    paths = real_materials("train")
    for path in paths if limit <= 0 else paths[:limit]:
        maps = load_texture_set(path, POOL_SIZE)
        rough = np.asarray(maps.roughness, np.float64).reshape(-1)
        u = np.log(np.maximum(np.asarray(maps.diffuse, np.float64).mean(-1).reshape(-1), 1e-3))
        if rough.std() > 0 and u.std() > 0:
            out.append({"set": Path(path).name, "r": float(np.corrcoef(rough, u)[0, 1])})
    return out


def measure(roots: list[Path], limit: int = 0, progress=None) -> dict:
    """Per capture: each variant's metrics and the gain grid (module docstring) and small maps for
    the picture; per data set and over all: the means and how often the pattern helped."""
    from .. import metrics
    from ..evaluation.evaluate import _at_size, _truth, estimate_sample
    from ..materials import resample_svbrdf
    from ..model.predict import load_predictor
    from ..svbrdf import SVBRDF

    predictor = load_predictor(None)
    pairs = metrics.rerender_pairs(0)
    rows, thumbs = [], {}
    for root, ds, i, intensity in validation_captures(roots, PAGE, limit):
        truth = _truth(ds[i])
        result = estimate_sample(predictor, root, i, nominal=intensity)
        truth_renders = metrics.rerenders(truth, pairs, intensity)
        fit = result.get("flash_fit") or {}
        pattern = fit.get("roughness_pattern") or {}
        row = {
            "data": root.name,
            "index": i,
            "material": str(ds.index["samples"][i]["material"]).split("/")[-1],
            "read": bool(pattern.get("applied")) and fit.get("roughness_from") == "fit",
            "record": pattern or None,  # estimate.json flash_fit.roughness_pattern
            "fitted": fit.get("roughness"),
            "oracle": float(np.std(truth.roughness)),
        }
        base = result.maps

        def scored(rough, name, base=base, truth=truth):
            maps = SVBRDF(base.normal, base.diffuse, base.specular, rough, source=name)
            return _at_size(maps, truth.shape)  # the working size may exceed the data set's

        for name, gain in (("constant", 0.0), ("pattern", None)):
            maps = scored(variant_roughness(result, gain), name)
            row[name] = variant_score(maps, truth, "roughness", pairs, intensity, truth_renders)
            thumbs[(root.name, i, name)] = resample_svbrdf(maps, THUMB).roughness
        thumbs[(root.name, i, "truth")] = resample_svbrdf(truth, THUMB).roughness
        row["gains"] = []
        for gain in GAINS:
            per_map = metrics.map_rmse(scored(variant_roughness(result, gain), "gain"), truth)
            row["gains"].append([gain, per_map["roughness"], per_map["mean"]])
        rows.append(row)
        if progress:
            a, b = row["constant"]["roughness"], row["pattern"]["roughness"]
            progress(f"{root.name} {i}: {row['material']} roughness RMSE {a:.4f} -> {b:.4f}")
    summary = by_data_set(rows, roots, _summary)
    pool = pool_correlations(limit=QUICK_SAMPLES if limit > 0 else 0)
    return {"rows": rows, "summary": summary, "thumbs": thumbs, "pool": pool}


def gain_table(rows: list[dict]) -> list[dict]:
    """Per gain of :data:`GAINS`, over ``rows``: ``{"gain", "roughness", "mean"}`` means."""
    grids = np.array([r["gains"] for r in rows], np.float64)  # (captures, gains, 3)
    means = grids.mean(axis=0)
    return [{"gain": g, "roughness": float(p[1]), "mean": float(p[2])} for g, p in zip(GAINS, means)]


def _summary(rows: list[dict]) -> dict:
    read = [r for r in rows if r["read"]]

    def count(key: str, sign: float) -> int:
        return int(sum(sign * (r["pattern"][key] - r["constant"][key]) > 1e-5 for r in read))

    return {
        "captures": len(rows),
        "read": len(read),
        **{
            v: {k: float(np.mean([r[v][k] for r in rows])) for k in ("roughness", "mean", "rerender")}
            for v in VARIANTS
        },
        "oracle": float(np.mean([r["oracle"] for r in rows])),
        "gains": gain_table(rows),
        "roughness_better": count("roughness", -1.0),
        "roughness_worse": count("roughness", 1.0),
        "rerender_better": count("rerender", -1.0),
        "rerender_worse": count("rerender", 1.0),
    }


def _picture(result: dict, path: Path) -> list[dict]:
    """Truth | constant | pattern roughness of the captures the pattern changed most; returns those
    rows."""
    read = [r for r in result["rows"] if r["read"]]
    change = lambda r: abs(r["pattern"]["roughness"] - r["constant"]["roughness"])  # noqa: E731
    shown = sorted(read, key=change, reverse=True)[:PICTURES]
    if shown:
        thumbnail_grid(
            shown,
            ("truth", "constant", "pattern"),
            lambda r, col: np.asarray(result["thumbs"][(r["data"], r["index"], col)]),
            lambda r, col: col if col == "truth" else f"{col}: {r[col]['roughness']:.4f}",
            path,
            cmap="gray",
            vmin=0,
            vmax=1,
        )
    return shown


def _gain_picture(result: dict, path: Path) -> None:
    """Roughness RMSE over the gains, one line per data set relative to its constant (gain 0), the
    default gain marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..estimate.roughness_pattern import GAIN

    fig, ax = plt.subplots(figsize=(5.2, 3.4))
    for name, s in result["summary"].items():
        base = s["gains"][0]["roughness"]
        ax.plot(GAINS, [p["roughness"] / base for p in s["gains"]], "o-", ms=3, label=name)
    ax.axvline(GAIN, color="grey", ls=":", lw=1, label="default gain")
    ax.axhline(1.0, color="grey", ls="--", lw=1)
    ax.set_xlabel("gain on the slope read off the highlight")
    ax.set_ylabel("roughness RMSE ÷ the constant's")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _page(result: dict, roots: list[Path], seconds: float, quick: bool, shown: list[dict]) -> str:
    from ..estimate.roughness_pattern import GAIN, MAX_ROUGHNESS, MAX_SLOPE

    lines = [
        "# The roughness pattern on validation captures",
        "",
        "Generated by `ebr bench roughness` (`ebr_mitsuba/bench/roughness.py`); do not edit by hand.",
        f"Machine: {machine()}; took {seconds:.0f} s.",
        "",
    ]
    if quick:
        lines += [
            f"**Quick mode** (first {QUICK_SAMPLES} samples per data set): not the documented figures.",
            "",
        ]
    pool = result["pool"]
    strong = [c for c in pool if abs(c["r"]) >= POOL_STRONG]
    negative = sum(c["r"] < 0 for c in strong)
    lines += [
        f"Why a pattern that follows the albedo: of the {len(pool)} real material sets of the training "
        f"split (`$EBR_DATA_DIR`, read at {POOL_SIZE}²), {len(strong)} have their roughness map "
        f"correlated with their log-albedo by |r| ≥ {POOL_STRONG:g}, {negative} negatively and "
        f"{len(strong) - negative} positively; the median |r| is "
        f"{float(np.median([abs(c['r']) for c in pool])) if pool else 0.0:.2f}.",
        "",
        "Each capture is estimated by `ebr estimate` (the shipped model, its defaults) and its maps scored "
        "with two roughness maps, everything else equal: *constant*, the flash fit's one roughness (the "
        "default until 2026-12-07); *pattern*, what `ebr estimate` writes: the fitted roughness plus "
        f"{GAIN:g} × the slope read off the flash highlight (capped at ±{MAX_SLOPE:g}) times the "
        "estimate's log-albedo ([estimate.md](../estimate.md#the-roughness-pattern-default)). Captures "
        f"whose pattern was not read (a metal, a fit rougher than {MAX_ROUGHNESS:g}, the network's map "
        "after a misfit) have the same map in both. Metrics as in [models.md](../models.md); the oracle "
        "constant roughness is each capture's own mean roughness.",
        "",
        f"Data: {', '.join(f'`{r}`' for r in roots)}: validation captures (the training split's material "
        "sets and maps), never the test split; the test split's figures are the `ebr estimate` row of "
        "[models.md](../models.md).",
        "",
        "```",
        COMMANDS,
        "```",
        "",
        "| data | captures (pattern read) | roughness | roughness RMSE | mean per-map RMSE "
        "| held-out re-render |",
        "|---|---:|---|---:|---:|---:|",
    ]
    for name, s in result["summary"].items():
        for v in VARIANTS:
            c = s[v]
            lines.append(
                f"| {name} | {s['captures']} ({s['read']}) | {v} | {c['roughness']:.5f} | {c['mean']:.5f} "
                f"| {c['rerender']:.4f} |"
            )
        lines.append(f"| {name} | | oracle constant | {s['oracle']:.5f} | | |")
    lines.append("")
    for name, s in result["summary"].items():
        lines.append(
            f"- **{name}**: with the pattern the roughness RMSE is lower in {s['roughness_better']} and "
            f"higher in {s['roughness_worse']} of the {s['read']} captures read (by over 1e-5), the "
            f"held-out re-render lower in {s['rerender_better']} and higher in {s['rerender_worse']}."
        )
    lines.append("")
    if shown:
        lines += [
            "![truth and estimated roughness](roughness.png)",
            "",
            "*Roughness (black 0, white 1) of the captures the pattern changed most: truth | constant | "
            "pattern (roughness RMSE in the titles).*",
            "",
        ]
    groups = list(result["summary"])
    lines += [
        "## The gain",
        "",
        "The same estimates' roughness maps remade with each gain on the capped reading (0: the "
        f"constant; the default {GAIN:g} starred ★): roughness RMSE / mean per-map RMSE.",
        "",
        "| gain | " + " | ".join(groups) + " |",
        "|---:|" + "---:|" * len(groups),
    ]
    for k, g in enumerate(GAINS):
        star = " ★" if g == GAIN else ""
        points = [result["summary"][n]["gains"][k] for n in groups]
        cells = [f"{p['roughness']:.5f} / {p['mean']:.5f}" for p in points]
        lines.append(f"| {g:g}{star} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "![roughness RMSE over the gain](roughness_gains.png)",
        "",
        "## Per capture",
        "",
        "| data | # | material | fitted | slope read ± s.e. | applied slope | roughness RMSE: constant "
        "| pattern | oracle |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in result["rows"]:
        p = r["record"] or {}
        if r["read"]:
            read, slope = f"{p['read']:+.3f} ± {p['stderr']:.3f}", f"{p['slope']:+.3f}"
        else:
            read, slope = (p.get("reason") or "not read"), "–"
        fitted = "–" if r["fitted"] is None else f"{r['fitted']:.3f}"
        lines.append(
            f"| {r['data']} | {r['index']} | {r['material']} | {fitted} | {read} | {slope} | "
            f"{r['constant']['roughness']:.4f} | {r['pattern']['roughness']:.4f} | {r['oracle']:.4f} |"
        )
    lines.append("")
    return "\n".join(lines)


def run(out_dir: Path | str, quick: bool = False) -> Path:
    """Measure every capture of the data sets (``--quick``: the first :data:`QUICK_SAMPLES` of
    each) and write ``out_dir/roughness.md`` with its JSON record and pictures."""
    from ..fsutil import atomic_write_text

    limit = QUICK_SAMPLES if quick else 0
    roots, result, seconds, out_dir = measure_validation(
        "EBR_ROUGHNESS_DATA", PAGE, lambda roots: measure(roots, limit=limit, progress=_log), out_dir
    )
    shown = _picture(result, out_dir / "roughness.png")
    _gain_picture(result, out_dir / "roughness_gains.png")
    rows = [{k: v for k, v in r.items() if k != "gains"} for r in result["rows"]]
    record = {"rows": rows, "summary": result["summary"], "pool": result["pool"]}
    atomic_write_text(out_dir / "roughness.json", json.dumps(record, indent=1) + "\n")
    atomic_write_text(out_dir / PAGE, _page(result, roots, seconds, quick, shown))
    return out_dir / PAGE
