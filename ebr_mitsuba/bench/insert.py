"""``ebr bench insert``: object insertion into estimates against the truth (issue 13, deliverable 4);
writes ``insert.md`` with a picture per synthetic capture and a plot of the ratios.

Every case is a flash / no-flash capture estimated by ``ebr estimate`` with the shipped model
(no refinement), then ``ebr insert``'s object (a sphere a third of the sample wide, centred, the
estimate's camera straight above) rendered by Mitsuba at :data:`RES`², :data:`SPP` spp:

* into the estimate, composited into its no-flash photo (``--background photo``, the default:
  :func:`ebr_mitsuba.insert.differential`) and rendered whole (``--background render``);
* into the same estimate made with its lobes at the horizon dropped (``ebr estimate
  --drop-horizon-lobes``; :mod:`ebr_mitsuba.estimate.horizon`), composited;
* into the truth (the true maps under the true environment, rendered whole) with the same seed,
  and again with another seed: the truth-vs-truth difference is the noise floor the issue's
  acceptance measures against ("within 2× of the truth-vs-truth difference at 256 spp").

Cases: :data:`CAPTURES` (``ebr capture``, near setup, :data:`RES`², :data:`CAPTURE_SPP` spp; the
first is the example of ``docs/insert.md``) with a diffuse and a mirror sphere, and, with
``EBR_SPLIT_DATA`` (the near flash / no-flash test split, ``configs/data_real_test.toml``), its
first :data:`TEST_SAMPLES` samples (real material sets under real HDR maps) with the diffuse
sphere. RMSE of linear radiance over the whole frame.

Multi-view cases (issue 13's acceptance is stated for the multi-view estimate): the same
:data:`CAPTURES` as ``ebr capture --setup multi-view`` (the 9 flash views and the centre camera's
no-flash view), estimated by ``ebr estimate --views`` with the shipped MAIR model, composited into
the no-flash view; beside it the same capture without its no-flash view (the 9 flash views only,
as the multi-view data sets hold them by default: the lighting's scale read off the flash views alone, no
photo to composite into, so rendered whole), against the same truth render and floor.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

from ._common import machine, truth_emitter

PAGE = "insert.md"
RES, SPP = 128, 256  # the insertions: the acceptance's 256 spp
CAPTURE_SPP = 256  # the synthetic captures' photos
CAPTURES = (  # (material, environment) of the synthetic captures
    ("procedural:tiles:1", "procedural:3"),
    ("procedural:wood:5", "procedural:8"),
    ("procedural:leather:2", "procedural:13"),
)
MATERIALS = ("diffuse", "mirror")
TEST_SAMPLES = 8
ACCEPT_RATIO = 2.0  # issue 13: the insertion within 2× of the truth-vs-truth difference
MULTIVIEW = "multi-view synthetic"  # the group of the multi-view cases
QUICK = {"res": 48, "spp": 16, "capture_spp": 16, "captures": 1, "materials": ("diffuse",), "test": 1}


def _log(msg: str) -> None:
    print(f"[bench insert] {msg}", file=sys.stderr, flush=True)


def measure(plate, truth, material: str, res: int, spp: int, dropped=None, others=None) -> dict:
    """One insertion of ``material``'s default object into ``plate`` and into ``truth`` (both
    :class:`~ebr_mitsuba.insert.Plate`): RMSE of the insertion (composited where the plate has a
    photo) and of the whole-frame render against the truth's, the truth-vs-truth noise floor
    (another seed), the insertion's and the floor's relative RMSE, and the insertion's picture
    (estimate | truth | difference, at the truth's exposure); with ``dropped`` (the plate of the
    same estimate with its horizon lobes dropped), its insertion's ratio to the same floor; with
    ``others`` (name → plate), each one's insertion's relative RMSE against the same truth render
    (``row["others"]``) and its ratio to the same floor (``row["others_ratio"]``), to tell which
    part of the plate the error comes from."""
    from ..insert import InsertConfig, exposure, insertion_images, object_dict, side_by_side, truth_again
    from ..metrics import rel_rmse, rmse

    cfg = InsertConfig(material=material, spp=spp, res=res)
    shape = object_dict(cfg)
    images, _ = insertion_images(plate, cfg, res, shape, truth)
    again = truth_again(truth, cfg, res, shape, plate.fov)  # the next seed: ebr insert --noise-floor
    floor = rmse(again, images["truth"])
    row = {
        "composite": rmse(images["insert"], images["truth"]),
        "render": rmse(images["render"], images["truth"]),
        "floor": floor,
        "composite_rel": rel_rmse(images["insert"], images["truth"]),
        "floor_rel": rel_rmse(again, images["truth"]),
        "composited": images["insert"] is not images["render"],
    }
    row["ratio"] = row["composite"] / floor
    row["render_ratio"] = row["render"] / floor
    if dropped is not None:  # against the same truth render and floor
        other = insertion_images(dropped, cfg, res, shape)[0]["insert"]
        row["dropped_ratio"] = rmse(other, images["truth"]) / floor
    if others:
        inserted = {name: insertion_images(p, cfg, res, shape)[0]["insert"] for name, p in others.items()}
        row["others"] = {name: rel_rmse(image, images["truth"]) for name, image in inserted.items()}
        row["others_ratio"] = {name: rmse(image, images["truth"]) / floor for name, image in inserted.items()}
    picture = side_by_side(images["insert"], images["truth"], exposure(images["truth"]))
    return {**row, "picture": np.clip(picture, 0, None)}


def _estimates(cfg, predictor) -> tuple:
    """The plates of ``ebr estimate`` as configured by ``cfg`` (the default) and with the lobes at
    the horizon dropped (``--drop-horizon-lobes``, into ``cfg.out`` + ``_dropped``)."""
    from ..estimate.pipeline import run_estimate
    from ..insert import load_estimate

    dropped = replace(cfg, drop_horizon_lobes=True, out=cfg.out + "_dropped")
    run_estimate(cfg, predictor=predictor)
    run_estimate(dropped, predictor=predictor)
    return load_estimate(cfg.out), load_estimate(dropped.out)


def _capture_cases(tmp: Path, n: int, res: int, capture_spp: int, predictor) -> list[tuple]:
    """(label, short label, estimate plate, truth plate, estimate plate with the horizon lobes dropped)
    of the first ``n`` :data:`CAPTURES`."""
    from ..capture import capture
    from ..estimate.pipeline import EstimateConfig
    from ..insert import load_capture

    cases = []
    for k, (material, env) in enumerate(CAPTURES[:n]):
        cap, est = tmp / f"cap{k}", tmp / f"est{k}"
        _log(f"capture {material} under {env} ({res}², {capture_spp} spp) and its estimate")
        capture(material, env, "near", cap, spp=capture_spp, res=res, progress=False)
        cfg = EstimateConfig(flash=str(cap / "flash.exr"), noflash=str(cap / "noflash.exr"), out=str(est))
        plates = _estimates(cfg, predictor)
        cases.append((f"`{material}` under `{env}`", material, plates[0], load_capture(cap), plates[1]))
    return cases


#: The multi-view cases' other plates (name → what it is), each against the same truth and floor.
MULTIVIEW_OTHERS = {
    "network lobes": "the network's lobes of the centre pixel as they are (`--no-azimuthal-env`)",
    "true environment": "the estimated maps and photo under the true environment",
}


def _multiview_cases(tmp: Path, n: int, res: int, capture_spp: int) -> list[tuple]:
    """(label, short label, estimate plate, truth plate, estimate plate of the 9 flash views only,
    the plates of :data:`MULTIVIEW_OTHERS`) of the first ``n`` :data:`CAPTURES` captured
    multi-view; [] when no MAIR model is shipped."""
    from ..capture import capture
    from ..estimate.multiview import (
        MultiViewConfig,
        load_mair,
        read_centre_lobes,
        run_multiview,
        shipped_model_path,
    )
    from ..insert import load_capture, load_estimate
    from ..scene import sg_emitter_dict

    if not shipped_model_path().is_file():
        _log("no shipped MAIR model: no multi-view cases")
        return []
    predictor = load_mair(shipped_model_path())
    cases = []
    for k, (material, env) in enumerate(CAPTURES[:n]):
        cap, flash_only = tmp / f"mv_cap{k}", tmp / f"mv_cap{k}_flash_views"
        _log(f"multi-view capture {material} under {env} ({res}², {capture_spp} spp) and its estimates")
        capture(material, env, "multi-view", cap, spp=capture_spp, res=res, progress=False)
        meta = json.loads((cap / "capture.json").read_text())
        flash_only.mkdir()
        for shot in meta["shots"]:
            if shot["flash"] is not None:
                (flash_only / shot["file"]).symlink_to(cap / shot["file"])
        meta["shots"] = [shot for shot in meta["shots"] if shot["flash"] is not None]
        (flash_only / "capture.json").write_text(json.dumps(meta))
        plates = []
        for views in (cap, flash_only):
            out = tmp / f"mv_est{k}_{views.name}"
            run_multiview(MultiViewConfig(views=str(views), out=str(out)), predictor=predictor)
            plates.append(load_estimate(out))
        truth = load_capture(cap)
        lobes = read_centre_lobes(tmp / f"mv_est{k}_{cap.name}")  # --no-azimuthal-env's env.json
        network = {"kind": "sg", "lobes": lobes.num_lobes, "environment": lobes}
        others = {
            "network lobes": replace(plates[0], emitter=partial(sg_emitter_dict, lobes), env=network),
            "true environment": replace(plates[0], emitter=truth.emitter, env=truth.env),
        }
        cases.append((f"`{material}` under `{env}`", material, plates[0], truth, plates[1], others))
    return cases


def _split_cases(tmp: Path, data: Path, n: int, predictor) -> list[tuple]:
    """(label, short label, estimate plate, truth plate, estimate plate with the horizon lobes dropped)
    of the first ``n`` samples of the test split."""
    from ..data.dataset import GeneratedDataset
    from ..data.store import sample_dirname
    from ..estimate.pipeline import EstimateConfig
    from ..evaluation.evaluate import _truth
    from ..insert import Plate

    ds = GeneratedDataset(str(data))
    nominal = float(json.loads((data / "dataset.json").read_text())["config"]["capture"]["flash_intensity"])
    cases = []
    for i in range(min(n, len(ds))):
        sample = data / sample_dirname(int(ds[i]["index"]))
        record = json.loads((sample / "sample.json").read_text())
        made = truth_emitter(sample)
        if made is None:
            continue
        shots = {s["name"]: sample / s["photo"] for s in record["shots"]}
        est = tmp / f"split{i}"
        _log(f"estimate of test sample {sample.name}")
        cfg = EstimateConfig(
            flash=str(shots["flash"]),
            noflash=str(shots["noflash"]),
            out=str(est),
            flash_intensity=nominal * float(record["camera"]["exposure"]),
        )
        plate, dropped = _estimates(cfg, predictor)
        emitter, described = made
        truth = Plate(sample, "capture", _truth(ds[i]), plate.fov, emitter)
        material = Path(record["material"].get("path") or record["material"].get("spec", "?")).name
        cases.append((f"{sample.name}: {material} under {described}", sample.name, plate, truth, dropped))
    return cases


def _geomean(values) -> float:
    return float(np.exp(np.mean(np.log(np.maximum(np.asarray(values, np.float64), 1e-12)))))


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 0.32 * len(rows) + 1.2))
    y = np.arange(len(rows))
    ax.barh(y - 0.2, [r["render_ratio"] for r in rows], 0.4, label="rendered whole")
    ax.barh(y + 0.2, [r["ratio"] for r in rows], 0.4, label="composited into the photo")
    ax.axvline(ACCEPT_RATIO, color="k", lw=1, ls="--", label="acceptance (2×)")
    labels = [f"{r['case_short'].replace('procedural:', '')} / {r['material']}" for r in rows]
    ax.set_yticks(y, labels, fontsize=7)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlabel("insertion RMSE / truth-vs-truth RMSE")
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _table_row(r: dict) -> str:
    """A case's row of either table: RMSEs, floor, the ratios, the alternative's and the other
    plates' (:data:`MULTIVIEW_OTHERS`, where measured)."""
    others = "".join(
        f" {r['others_ratio'][name]:.1f}× |" for name in MULTIVIEW_OTHERS if name in r.get("others_ratio", {})
    )
    return (
        f"| {r['case']} | {r['material']} | {r['composite']:.5f} | {r['render']:.5f} | "
        f"{r['floor']:.5f} | **{r['ratio']:.1f}×** | {r['render_ratio']:.1f}× | "
        f"{r['dropped_ratio']:.1f}× |" + others
    )


def lobe_spread(envs: list) -> list[float]:
    """Per lobe index, the largest angle (degrees) between a capture's lobe axis and their mean
    direction over ``envs`` (SG environments of one lobe count): how much the lobes move with the
    capture."""
    if not envs:
        return []
    axes = np.stack([np.asarray(e.axis, np.float64) for e in envs])  # (captures, lobes, 3)
    mean = axes.mean(axis=0)
    mean /= np.linalg.norm(mean, axis=-1, keepdims=True)
    cos = np.clip(np.einsum("clk,lk->cl", axes, mean), -1.0, 1.0)
    return [float(x) for x in np.degrees(np.arccos(cos)).max(axis=0)]


def _page(
    rows: list[dict],
    pictures: list[tuple[str, str]],
    settings: dict,
    seconds: float,
    quick: bool,
    lobes: list | None = None,
) -> str:
    lines = [
        "# Object insertion against the truth",
        "",
        "Generated by `ebr bench insert` (`ebr_mitsuba/bench/insert.py`); do not edit by hand.",
        f"Machine: {machine()}; {time.strftime('%Y-%m-%d')}; took {seconds:.0f} s."
        + (" **Quick mode: smoke-test sizes, not the documented numbers.**" if quick else ""),
        "",
        f"Each case is a flash / no-flash capture estimated by `ebr estimate` (the shipped model, no "
        f"refinement), then `ebr insert`'s sphere (a third of the sample wide, centred, the estimate's "
        f"camera straight above) rendered by Mitsuba at {settings['res']}², {settings['spp']} spp: "
        "composited into the estimate's no-flash photo (`--background photo`, the default: the "
        "object's pixels rendered, the rest the photo × the render's ratio with / without the object) "
        "and rendered whole (`--background render`), against the same insertion into the truth (true "
        "maps, true environment, the same seed). The noise floor is the truth against itself with "
        "another seed. RMSE of linear radiance over the frame; ratio = RMSE / noise floor "
        f"(issue 13's acceptance: at most {ACCEPT_RATIO:g}). Synthetic captures: `ebr capture "
        f"--setup near --res {settings['res']} --spp {settings['capture_spp']}`; test-split samples "
        "(with `EBR_SPLIT_DATA`): "
        "`configs/data_real_test.toml` (real material sets under real HDR maps, Mitsuba at 256 spp).",
        "",
        "The last column is the composite's ratio with the estimate's lobes at the horizon dropped "
        "(`ebr estimate --drop-horizon-lobes`, "
        "[estimate.md](../estimate.md#lobes-at-the-horizon-an-option)).",
        "",
        "| case | sphere | composite RMSE | rendered-whole RMSE | noise floor | ratio (composite) "
        "| ratio (rendered whole) | ratio (composite), horizon lobes dropped |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        if r["group"] != MULTIVIEW:
            lines.append(_table_row(r))
    mv = [r for r in rows if r["group"] == MULTIVIEW]
    if mv:
        lines += [
            "",
            "## Multi-view captures",
            "",
            f"The same materials and environments as `ebr capture --setup multi-view --res {settings['res']} "
            f"--spp {settings['capture_spp']}` (the 9 flash views and the centre camera's no-flash view), "
            "estimated by `ebr estimate --views` with the shipped MAIR model (its defaults: env.json the "
            "centre pixel's lighting averaged over azimuth), the sphere composited into the no-flash "
            "view. Then, each against the same truth render and floor: the same capture with its "
            "no-flash view left out, the 9 flash views only as a multi-view data set holds them by "
            "default (the lighting's level and colour read off how each pixel changes from flash to "
            "flash alone, and "
            "no photo to composite into: rendered whole); "
            + "; ".join(MULTIVIEW_OTHERS.values())
            + " (composited) ([mair.md](../mair.md#estimating)).",
            "",
            "| case | sphere | composite RMSE | rendered-whole RMSE | noise floor | ratio (composite) "
            "| ratio (rendered whole) | ratio, the 9 flash views only | ratio, the network's lobes "
            "| ratio, estimated maps under the true environment |",
            "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for r in mv:
            lines.append(_table_row(r))
        for material in dict.fromkeys(r["material"] for r in mv):
            sel = [r for r in mv if r["material"] == material]
            lines.append("")
            lines.append(
                f"- **multi-view, {material} sphere**: within {ACCEPT_RATIO:g}× of the noise floor in "
                f"{sum(r['ratio'] <= ACCEPT_RATIO for r in sel)} of {len(sel)} (ratios "
                + ", ".join(f"{r['ratio']:.2f}×" for r in sel)
                + "); the 9 flash views only: "
                f"{sum(r['dropped_ratio'] <= ACCEPT_RATIO for r in sel)} of {len(sel)} (ratios "
                + ", ".join(f"{r['dropped_ratio']:.2f}×" for r in sel)
                + ")."
            )
            by = {name: [r["others_ratio"][name] for r in sel] for name in MULTIVIEW_OTHERS}
            lines[-1] += (
                f" Geometric mean ratio {_geomean([r['ratio'] for r in sel]):.2f}× as written against "
                f"{_geomean(by['network lobes']):.2f}× with the network's lobes (lower averaged in "
                f"{sum(r['ratio'] < x for r, x in zip(sel, by['network lobes']))} of {len(sel)}); under the "
                f"true environment {_geomean(by['true environment']):.2f}× (within {ACCEPT_RATIO:g}× in "
                f"{sum(x <= ACCEPT_RATIO for x in by['true environment'])} of {len(sel)})."
            )
        spread = lobe_spread(lobes or [])
        if len(lobes or []) >= 2:  # a spread needs two captures
            lines += [
                "",
                f"- The network's lobes at the centre pixel across these {len(lobes)} captures (each under "
                "another sky): each lobe's axis within "
                + " / ".join(f"{x:.1f}°" for x in spread)
                + " of its mean direction. What the lighting net predicts is where the light "
                "comes from for every capture alike, hence env.json's average over azimuth "
                "([mair.md](../mair.md#estimating)).",
            ]
    lines += ["", "![insertion error over the noise floor per case](insert_ratios.png)", ""]
    for group in ("synthetic", "test split"):
        sel = [r for r in rows if r["group"] == group]
        if not sel:
            continue
        met = sum(r["ratio"] <= ACCEPT_RATIO for r in sel)
        lines.append(
            f"- **{group}**: within {ACCEPT_RATIO:g}× of the noise floor in {met} of {len(sel)} "
            f"insertions composited (median ratio {np.median([r['ratio'] for r in sel]):.1f}×), "
            f"{sum(r['render_ratio'] <= ACCEPT_RATIO for r in sel)} of {len(sel)} rendered whole "
            f"(median {np.median([r['render_ratio'] for r in sel]):.1f}×). With the horizon lobes "
            f"dropped: {sum(r['dropped_ratio'] <= ACCEPT_RATIO for r in sel)} of {len(sel)} composited, "
            f"median {np.median([r['dropped_ratio'] for r in sel]):.1f}×; geometric mean ratio "
            f"{_geomean([r['ratio'] for r in sel]):.2f}× as estimated against "
            f"{_geomean([r['dropped_ratio'] for r in sel]):.2f}× dropped, lower dropped in "
            f"{sum(r['dropped_ratio'] < r['ratio'] for r in sel)} of {len(sel)}."
        )
    lines += [
        "",
        "Compositing removes the plate's error (the estimated maps and light re-rendering the "
        "sample) wherever the object leaves the photo alone; what remains is the object itself and "
        "its shadow under the estimated light, and the photo's own noise.",
        "",
    ]
    for caption, name in pictures:
        lines += [
            f"![{caption}]({name})",
            "",
            f"*{caption}: estimate (composited) | truth | |difference| × 4, one exposure.*",
            "",
        ]
    return "\n".join(lines)


def unavailable() -> str | None:
    return None


def run(out_dir: Path, quick: bool = False) -> Path:
    """Run the benchmark and write ``out_dir/insert.md`` (+ PNGs); returns the page's path."""
    from ..fsutil import atomic_write_text
    from ..imageio import write_png
    from ..model.predict import load_predictor
    from ..variant import ensure_variant

    ensure_variant()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    s = (
        QUICK
        if quick
        else {
            "res": RES,
            "spp": SPP,
            "capture_spp": CAPTURE_SPP,
            "captures": len(CAPTURES),
            "materials": MATERIALS,
            "test": TEST_SAMPLES,
        }
    )
    predictor = load_predictor(None)
    rows, pictures = [], []
    split = os.environ.get("EBR_SPLIT_DATA")
    with tempfile.TemporaryDirectory(prefix="ebr-bench-insert-") as tmp:
        tmp = Path(tmp)
        cases = [
            ("synthetic", *case, s["materials"], None)
            for case in _capture_cases(tmp, s["captures"], s["res"], s["capture_spp"], predictor)
        ]
        cases += [
            (MULTIVIEW, f"{label} (multi-view)", f"multi-view {short}", *rest, s["materials"], others)
            for label, short, *rest, others in _multiview_cases(
                tmp, s["captures"], s["res"], s["capture_spp"]
            )
        ]
        if split:
            cases += [
                ("test split", *case, ("diffuse",), None)
                for case in _split_cases(tmp, Path(split), s["test"], predictor)
            ]
        else:
            _log("EBR_SPLIT_DATA not set: synthetic captures only")
        pictured = set()  # every synthetic insertion and the first of the test split get a picture
        lobes = [  # the network's centre-pixel lobes of each multi-view capture
            others["network lobes"].env["environment"] for *_, others in cases if others
        ]
        for group, label, short, plate, truth, dropped, materials, others in cases:
            for material in materials:
                _log(f"insertion ({material}) into {label}")
                r = measure(plate, truth, material, s["res"], s["spp"], dropped, others)
                picture = r.pop("picture")
                rows.append({"group": group, "case": label, "case_short": short, "material": material, **r})
                if group != "test split" or group not in pictured:
                    pictured.add(group)
                    name = f"insert_{len(pictures)}.png"
                    write_png(out_dir / name, picture, clip="hue")
                    pictures.append((f"{label}, {material} sphere", name))
    _plot(rows, out_dir / "insert_ratios.png")
    page = _page(rows, pictures, s, time.perf_counter() - t0, quick, lobes)
    path = out_dir / PAGE
    atomic_write_text(path, page)
    atomic_write_text(out_dir / "insert.json", json.dumps({"settings": dict(s), "rows": rows}, indent=1))
    return path
