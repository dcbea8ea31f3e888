"""``ebr bench flash-fit``: where the flash-profile fit's roughness error comes from (issue 15);
writes ``flash_fit.md``, ``flash_fit.json`` and a scatter plot.

The fit (:mod:`ebr_mitsuba.estimate.flashfit`) reads one roughness per capture off the flash
shot's radial profile, modelling the flash-only image as an albedo texture plus *one* GGX lobe of
a flat sample. A real material breaks that model in two ways that no amount of photo quality
removes: its normal map's relief broadens the highlight, and its roughness varies over the
sample (a mixture of lobes is not the lobe of the mean roughness). This benchmark separates those
from everything else by fitting, for every dielectric capture of a generated near data set,

* ``capture``: the data set's photos, read as ``ebr estimate`` reads them (Mitsuba path traced,
  camera noise, the real environment in the no-flash shot);
* noise-free renders of the capture's own true maps (the flash-only image of the fast renderer,
  :func:`ebr_mitsuba.render.fast.render_numpy`, the one BRDF; the no-flash shot the albedo under a
  uniform white sky, ``ρ · (1 + n_z) / 2``), in four variants: ``maps`` (as they are),
  ``flat normals`` (the normal map replaced by the flat normal), ``constant roughness`` (the
  roughness map replaced by its mean), ``flat, constant`` (both: the fit's own floor).

A near-far data set (``configs/data_real_near_far_val.toml``) adds the same five fits with its
far pair (``+ far``: the roughness read off near − far per ring, where the albedo cancels; the
noise-free far shot rendered likewise, its sky the near one's).

The error of each is its roughness minus the truth map's mean (what an RMSE-optimal constant
would be); the page gives their RMS over the captures and per capture. What ``maps`` misses is the
single-lobe model's error on that material; ``capture`` minus ``maps`` is what light transport,
noise and the real sky add. Metals (true specular above :data:`METAL_F0`) are left out: their F0 is
fitted, and their relief is the same question with another lobe.

Inputs: ``EBR_FLASHFIT_DATA`` (data sets of ``ebr generate`` with near flash / no-flash shots,
and optionally far ones, separated by ``:``; default ``EBR_VAL_DATA``), e.g.
``configs/data_real_val.toml``, ``configs/data_real_val2.toml`` and
``configs/data_real_near_far_val.toml``: training materials and maps, never the test split.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from ..errors import InputError
from ._common import machine, measure_validation, validation_note, validation_sets

PAGE = "flash_fit.md"
METAL_F0 = 0.1  # a capture whose true specular map averages above this is a metal (left out)
VARIANTS = ("maps", "flat normals", "constant roughness", "flat, constant")
COLUMNS = ("capture", *VARIANTS)
FAR = " + far"  # the same fit with the far pair (near-far data sets)
SKY = 0.5  # radiance of the uniform sky of the noise-free no-flash shot (the fit reads its shares)
QUICK_SAMPLES = 2
COMMANDS = """\
export EBR_DATA_DIR=../shared/data
ebr generate configs/data_real_val.toml --out /tmp/ebr-data/real_val --workers 2
ebr generate configs/data_real_val2.toml --out /tmp/ebr-data/real_val2 --workers 2
ebr generate configs/data_real_near_far_val.toml --out /tmp/ebr-data/real_nf_val --workers 2
EBR_FLASHFIT_DATA=/tmp/ebr-data/real_val:/tmp/ebr-data/real_val2:/tmp/ebr-data/real_nf_val \\
  ebr bench flash-fit  # this page"""


def _log(msg: str) -> None:
    print(f"[bench flash-fit] {msg}", file=sys.stderr, flush=True)


def data_sets() -> list[Path]:
    return validation_sets("EBR_FLASHFIT_DATA")


def unavailable() -> str | None:
    return validation_note("EBR_FLASHFIT_DATA", PAGE)


def capture_fit(root: Path, index: int, nominal: float, far: bool = False):
    """The flash fit of sample ``index`` of data set ``root`` from its photo files, as
    ``ebr estimate`` reads them (exposure-matched, scaled to the reference flash intensity by the
    data set's ``nominal`` intensity × the sample's exposure, as ``capture.json`` states it);
    ``far``: with the sample's far pair (an error when it has none)."""
    from ..data.store import sample_dirname
    from ..estimate.inputs import load_inputs
    from ..estimate.pipeline import fit_capture_flash
    from ..geometry import DEFAULT_FLASH_INTENSITY

    sample = root / sample_dirname(index)
    record = json.loads((sample / "sample.json").read_text())
    shots = {s["name"]: sample / s["photo"] for s in record["shots"]}
    if "flash" not in shots or "noflash" not in shots:
        raise InputError(f"{sample}: shots {sorted(shots)}; the flash fit needs a flash / no-flash pair")
    if far and not {"far_flash", "far_noflash"} <= set(shots):
        raise InputError(f"{sample}: shots {sorted(shots)}; no far pair to fit with")
    far_paths = (str(shots["far_flash"]), str(shots["far_noflash"])) if far else (None, None)
    inputs = load_inputs(str(shots["flash"]), str(shots["noflash"]), *far_paths)
    inputs = inputs.scaled(DEFAULT_FLASH_INTENSITY / (nominal * float(record["camera"]["exposure"])))
    fit = fit_capture_flash(inputs, inputs.fov)  # the far flash: FarPair's default, as generated
    return fit, Path(record["material"].get("spec", "?")).name


def variant_maps(maps, variant: str):
    """``maps`` (:class:`~ebr_mitsuba.svbrdf.SVBRDF`) with its normals flattened and / or its
    roughness replaced by its mean, per ``variant`` (one of :data:`VARIANTS`)."""
    from ..svbrdf import SVBRDF

    if variant not in VARIANTS:
        raise ValueError(f"variant {variant!r}; one of {VARIANTS}")
    normal = np.asarray(maps.normal, np.float32).copy()
    rough = np.asarray(maps.roughness, np.float32).copy()
    if variant in ("flat normals", "flat, constant"):
        normal[:] = (0.0, 0.0, 1.0)
    if variant in ("constant roughness", "flat, constant"):
        rough[:] = rough.mean()
    return SVBRDF(normal, maps.diffuse, maps.specular, rough, source=f"truth, {variant}")


def noise_free_fit(maps, far: bool = False):
    """The flash fit of a noise-free near capture of ``maps``: the fast renderer's flash-only image
    plus a no-flash shot of the albedo under a uniform sky of radiance :data:`SKY`; ``far``: with a
    far pair made the same way (the far flash as bright at the sample, the same sky)."""
    from ..estimate.flashfit import FarPair, fit_flash
    from ..geometry import DEFAULT_FLASH_INTENSITY, FAR_DISTANCE, NEAR_DISTANCE, far_shot, near_shot
    from ..render.fast import render_numpy

    flash_only = render_numpy(maps, None, near_shot(flash=True, env=False)).astype(np.float64)
    nz = np.clip(np.asarray(maps.normal, np.float64)[..., 2:3], 0.0, 1.0)
    noflash = SKY * np.asarray(maps.diffuse, np.float64) * (1.0 + nz) / 2.0
    h, w = noflash.shape[:2]
    pair = None
    if far:
        far_only = render_numpy(maps, None, far_shot(flash=True, env=False)).astype(np.float64)
        pair = FarPair(far_only + noflash, noflash, (0.0, 0.0, FAR_DISTANCE))
    return fit_flash(
        flash_only + noflash,
        noflash,
        intensity=DEFAULT_FLASH_INTENSITY,
        camera=(0.0, 0.0, NEAR_DISTANCE),
        saturated=np.zeros((h, w), bool),
        clip_level=math.inf,
        far=pair,
    )


def measure(roots: list[Path], limit: int = 0, progress=None) -> dict:
    """Per dielectric capture: the truth's mean roughness and each column's fitted roughness (and
    whether it took the metal or the relief reading); the RMS and mean of each column's error."""
    from ..data.dataset import GeneratedDataset
    from ..evaluation.evaluate import _truth

    rows, metals, refused = [], 0, []
    for root in roots:
        if not (root / "dataset.json").is_file():
            raise InputError(f"{root}: not a data set of ebr generate; make it with the commands in {PAGE}")
        meta = json.loads((root / "dataset.json").read_text())
        nominal = float(meta["config"]["capture"]["flash_intensity"])
        ds = GeneratedDataset(root)
        has_far = {"far_flash", "far_noflash"} <= {shot["name"] for shot in meta.get("shots", [])}
        n = len(ds) if limit <= 0 else min(limit, len(ds))
        for i in range(n):
            truth = _truth(ds[i])
            if float(np.mean(truth.specular)) > METAL_F0:
                metals += 1
                continue
            try:
                fit, name = capture_fit(root, i, nominal)
                far_fit = capture_fit(root, i, nominal, far=True)[0] if has_far else None
            except InputError as e:  # a capture ebr estimate refuses (e.g. saturated): counted, not fitted
                refused.append(f"{root.name} {i}: {e}")
                continue
            row = {"data": root.name, "index": i, "material": name, "truth": float(np.mean(truth.roughness))}
            row["truth_std"] = float(np.std(truth.roughness))
            fits = {"capture": fit}
            for v in VARIANTS:
                fits[v] = noise_free_fit(variant_maps(truth, v))
            if has_far:
                fits["capture" + FAR] = far_fit
                for v in VARIANTS:
                    fits[v + FAR] = noise_free_fit(variant_maps(truth, v), far=True)
            for col, f in fits.items():
                row[col] = {
                    "roughness": float(f.roughness),
                    "metal": bool(f.metal),
                    "relief": f.relief is not None,
                }
            rows.append(row)
            if progress:
                progress(f"{root.name} {i}: {name} truth {row['truth']:.3f} capture {fit.roughness:.3f}")
    summary = {}
    for col in (*COLUMNS, *(c + FAR for c in COLUMNS)):
        err = np.array([r[col]["roughness"] - r["truth"] for r in rows if col in r])
        if col.endswith(FAR) and not len(err):
            continue
        summary[col] = {
            "n": int(len(err)),
            "rms": float(np.sqrt(np.mean(err**2))) if len(err) else float("nan"),
            "mean": float(err.mean()) if len(err) else float("nan"),
            "metal": int(sum(r[col]["metal"] for r in rows if col in r)),
            "relief": int(sum(r[col]["relief"] for r in rows if col in r)),
        }
    paired = {}  # the near-far captures: each fit from the near pair alone and with the far pair
    both = [r for r in rows if "capture" + FAR in r]
    for col in COLUMNS if both else ():
        near = np.array([r[col]["roughness"] - r["truth"] for r in both])
        far = np.array([r[col + FAR]["roughness"] - r["truth"] for r in both])
        paired[col] = {
            "n": len(both),
            "near": float(np.sqrt(np.mean(near**2))),
            "far": float(np.sqrt(np.mean(far**2))),
        }
    spread = np.array([r["truth_std"] for r in rows])
    return {
        "rows": rows,
        "summary": summary,
        "metals_left_out": metals,
        "refused": refused,
        "paired": paired,
        "truth_spread_rms": float(np.sqrt(np.mean(spread**2))) if len(spread) else float("nan"),
    }


def _plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    truth = [r["truth"] for r in rows]
    fig, ax = plt.subplots(figsize=(5.2, 4.6))
    for col, marker in (("capture", "o"), ("maps", "x"), ("flat, constant", ".")):
        ax.scatter(truth, [r[col]["roughness"] for r in rows], marker=marker, label=col, alpha=0.8)
    ax.plot([0, 1], [0, 1], color="grey", lw=0.8)
    ax.set_xlabel("true roughness (mean of the map)")
    ax.set_ylabel("fitted roughness")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("flash fit: photos vs noise-free renders of the true maps", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _page(result: dict, roots: list[Path], seconds: float, quick: bool) -> str:
    s = result["summary"]
    lines = [
        "# Where the flash fit's roughness error comes from",
        "",
        "Generated by `ebr bench flash-fit` (`ebr_mitsuba/bench/flash_fit.py`); do not edit by hand.",
        f"Machine: {machine()}; took {seconds:.0f} s.",
        "",
    ]
    if quick:
        lines += [f"**Quick mode** (first {QUICK_SAMPLES} samples per data set): not the documented figures."]
        lines.append("")
    lines += [
        "The flash-profile fit ([estimate.md](../estimate.md#the-flash-profile-fit-default)) reads one "
        "roughness per capture, modelling the flash-only image as an albedo texture plus one GGX lobe "
        "of a flat sample. Each dielectric capture is fitted from its photos (*capture*) and from "
        "noise-free renders of its own true maps (the fast renderer's flash-only image; the no-flash "
        "shot the albedo under a uniform sky): the maps as they are (*maps*), with flat normals, with "
        "the roughness map replaced by its mean, and with both (*flat, constant*: the fit's floor). "
        "Error: the fitted roughness minus the mean of the true roughness map.",
        "",
        f"Data: {', '.join(f'`{r}`' for r in roots)} ({len(result['rows'])} dielectric captures; "
        f"{result['metals_left_out']} metal captures left out"
        + (f"; {len(result['refused'])} refused by the photo checks" if result["refused"] else "")
        + "). Training materials and maps only, "
        "never the test split.",
        "",
        "```",
        COMMANDS,
        "```",
        "",
        "| fitted from | captures | RMS error | mean error | read as metal | two-lobe relief |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for col, c in s.items():
        lines.append(
            f"| {col} | {c['n']} | {c['rms']:.4f} | {c['mean']:+.4f} | {c['metal']} | {c['relief']} |"
        )
    if result.get("paired"):
        n = next(iter(result["paired"].values()))["n"]
        lines += [
            "",
            f"The near-far captures alone ({n}), each fitted from its near pair and with its far pair "
            "(RMS error):",
            "",
            "| fitted from | near pair | near + far pair |",
            "|---|---:|---:|",
        ]
        for col, c in result["paired"].items():
            lines.append(f"| {col} | {c['near']:.4f} | {c['far']:.4f} |")
    lines += [
        "",
        f"For scale: the true roughness maps' own spread (what the best constant scores on the map's "
        f"RMSE) is {result['truth_spread_rms']:.4f} (RMS over the same captures); a constant roughness "
        "map's RMSE is the root of its squared error above plus that spread squared.",
        "",
        "![fitted against true roughness](flash_fit.png)",
        "",
    ]

    def cell(v: dict) -> str:
        tags = (" (metal)" if v["metal"] else "") + (" (relief)" if v["relief"] else "")
        return f"{v['roughness']:.2f}{tags}"

    far_rows = [r for r in result["rows"] if "capture" + FAR in r]
    for title, columns, rows in (
        ("Per capture", COLUMNS, result["rows"]),
        ("Per capture, with the far pair", tuple(c + FAR for c in COLUMNS), far_rows),
    ):
        if not rows:
            continue
        lines += [
            f"## {title}",
            "",
            "| data | # | material | truth (mean ± sd) | " + " | ".join(columns) + " |",
            "|---|---:|---|---:|" + "---:|" * len(columns),
        ]
        for r in rows:
            lines.append(
                f"| {r['data']} | {r['index']} | {r['material']} | {r['truth']:.3f} ± {r['truth_std']:.3f} | "
                + " | ".join(cell(r[c]) for c in columns)
                + " |"
            )
        lines.append("")
    return "\n".join(lines)


def run(out_dir: Path | str, quick: bool = False) -> Path:
    """Measure every capture of the data sets (``--quick``: the first :data:`QUICK_SAMPLES` of
    each) and write ``out_dir/flash_fit.md`` with its JSON record and plot."""
    from ..fsutil import atomic_write_text

    limit = QUICK_SAMPLES if quick else 0
    roots, result, seconds, out_dir = measure_validation(
        "EBR_FLASHFIT_DATA", PAGE, lambda roots: measure(roots, limit=limit, progress=_log), out_dir
    )
    _plot(result, out_dir / "flash_fit.png")
    atomic_write_text(out_dir / "flash_fit.json", json.dumps(result, indent=1) + "\n")
    atomic_write_text(out_dir / PAGE, _page(result, roots, seconds, quick))
    return out_dir / PAGE
