"""``ebr bench generate``: data-generation throughput, fast-vs-Mitsuba error, SG-fit comparison.

:func:`run` writes ``<out_dir>/generate.md`` and ``<out_dir>/generate_sheet.png``:

1. **Throughput** — samples/s per core at 256² of the bundled ``near_train.toml`` config
   (procedural materials and environments, near setup, 4 + 4 exemplars): one worker in this
   process with one Dr.Jit thread (= one core), the whole per-sample pipeline (draw, render, camera
   simulation, atomic write), first sample (kernel compilation) excluded. Rows: Mitsuba at the
   config's spp and at 4× that, fast ``sg`` and fast ``quadrature``.
2. **Fast vs Mitsuba** — on the same samples (same maps, environments, shots), relative RMSE
   ``‖a − b‖ / ‖b‖`` of each image kind of the fast renderer against Mitsuba at the config's spp,
   next to Mitsuba's own noise (two seeds) and the noise-corrected bias estimate
   ``sqrt(max(e_fm² − e_mm²/2, 0))`` (independent noise: ``E e_fm² = bias² + σ²``, ``E e_mm² = 2σ²``).
3. **SG fit of an environment map** — ours (``ebr fit-env``) and the peer's 100-lobe PhySG fit of
   the same map (``physg_envmap3_venice_sunset_500x250.exr``): map-space errors, and renders of test
   materials (the exemplar material at four roughness values, two procedural materials) under each
   fit against renders under the map itself, all with Mitsuba's ``envmap`` (fits rasterised at
   1024×512) at the same spp, with the reference's own noise for scale.
4. **Contact sheet** — 16 samples of ``near_train.toml`` (``ebr dataset sheet``).

Sizes are :data:`FULL` (the documented page); ``run(quick=True)`` uses :data:`QUICK` (32² images,
one sample per measurement, a 30-iteration fit: a smoke test of the whole page).
"""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ..metrics import rel_rmse
from ._common import machine, shared_data_dir

SIZE = 256
THROUGHPUT_SAMPLES = 4
ERROR_SAMPLES = 6
ERROR_SPP_FACTOR = 4  # the error table's Mitsuba spp, × the config's (less noise in the bias estimate)
FIT_RES = 64
FIT_SPP = 256
SHEET_SAMPLES = 16
SHEET_RES = 128
SHEET_DPI = 72  # keeps the PNG in docs/ near 1 MB
PEER_FIT = "envmaps/physg_envmap3_sg100.npy"
PEER_MAP = "envmaps/physg_envmap3_venice_sunset_500x250.exr"
FIT_LOBES = (32, 100)
FIT_ITERATIONS = 600
RASTER = (512, 1024)  # the fits rasterised for Mitsuba's envmap


@dataclasses.dataclass(frozen=True)
class Settings:
    """Sizes of one run (``FULL`` documents the page; ``QUICK`` is a smoke test)."""

    size: int = SIZE
    throughput_samples: int = THROUGHPUT_SAMPLES
    error_samples: int = ERROR_SAMPLES
    fit_lobes: tuple = FIT_LOBES
    fit_iterations: int = FIT_ITERATIONS
    fit_res: int = FIT_RES
    fit_spp: int = FIT_SPP
    raster: tuple = RASTER
    sheet_samples: int = SHEET_SAMPLES
    sheet_res: int = SHEET_RES


FULL = Settings()
QUICK = Settings(
    size=32,
    throughput_samples=1,
    error_samples=1,
    fit_lobes=(8,),
    fit_iterations=30,
    fit_res=16,
    fit_spp=16,
    raster=(64, 128),
    sheet_samples=4,
    sheet_res=32,
)


def _near_train_config():
    from ..data.config import load_config

    return load_config("near_train")


# -- 1. throughput -------------------------------------------------------------------------------


def throughput(config, samples: int = THROUGHPUT_SAMPLES, size: int = SIZE) -> list[dict]:
    import drjit as dr

    from ..data.generate import make_sample
    from ..data.sample import Plan

    base = config.with_changes("dataset", resolution=size)
    spp = base.render.spp
    variants = [
        ("mitsuba", f"spp {spp}", base),
        ("mitsuba", f"spp {4 * spp}", base.with_changes("render", spp=4 * spp)),
        ("fast", "sg", base.with_changes("render", renderer="fast", fast_mode="sg")),
        (
            "fast",
            f"quadrature {base.render.fast_spp}",
            base.with_changes("render", renderer="fast", fast_mode="quadrature"),
        ),
    ]
    rows = []
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        for renderer, setting, cfg in variants:
            plan = Plan(cfg, {})
            with tempfile.TemporaryDirectory(prefix="ebr-bench-") as tmp:
                make_sample(plan, 0, Path(tmp))  # compiles the kernels
                t0 = time.perf_counter()
                for i in range(1, samples + 1):
                    make_sample(plan, i, Path(tmp))
                seconds = time.perf_counter() - t0
            rows.append(
                {
                    "renderer": renderer,
                    "setting": setting,
                    "samples": samples,
                    "seconds_per_sample": seconds / samples,
                    "samples_per_second": samples / seconds,
                }
            )
    finally:
        dr.set_thread_count(threads)
    return rows


# -- 2. fast vs mitsuba --------------------------------------------------------------------------------


def _kinds(clean) -> dict:
    out = {f"photo {k}": v for k, v in clean.shots.items()}
    out.update({f"flash-only {k}": v for k, v in clean.flash_only.items()})
    out.update({f"env exemplar {i}": v for i, v in enumerate(clean.env_exemplars)})
    out.update({f"point exemplar {i}": v for i, v in enumerate(clean.point_exemplars)})
    return out


def fast_vs_mitsuba(config, samples: int = ERROR_SAMPLES, size: int = SIZE) -> list[dict]:
    from ..data.renderers import render_clean
    from ..data.sample import Plan, draw_sample

    cfg = config.with_changes("dataset", resolution=size)
    cfg = cfg.with_changes("render", spp=ERROR_SPP_FACTOR * config.render.spp)
    plan = Plan(cfg, {})
    acc: dict[str, dict[str, list]] = {}
    for i in range(samples):
        draw = draw_sample(plan, i)
        m1 = _kinds(render_clean(cfg, draw, "mitsuba"))
        reseeded = dataclasses.replace(draw, render_seeds=tuple(s + 1 for s in draw.render_seeds))
        m2 = _kinds(render_clean(cfg, reseeded, "mitsuba"))
        f_sg = _kinds(render_clean(cfg.with_changes("render", fast_mode="sg"), draw, "fast"))
        f_q = _kinds(render_clean(cfg.with_changes("render", fast_mode="quadrature"), draw, "fast"))
        for key, ref in m1.items():
            d = acc.setdefault(key, {"noise": [], "sg": [], "quadrature": []})
            if float(np.abs(ref).max()) == 0.0:
                continue
            d["noise"].append(rel_rmse(m2[key], ref))
            d["sg"].append(rel_rmse(f_sg[key], ref))
            d["quadrature"].append(rel_rmse(f_q[key], ref))
    rows = []
    env_r = cfg.exemplars.env_roughness
    point_r = cfg.exemplars.point_roughness
    for key, d in acc.items():
        if not d["noise"]:
            continue
        label = key
        if key.startswith("env exemplar"):
            label = f"env exemplar r={env_r[int(key.split()[-1])]:g}"
        elif key.startswith("point exemplar"):
            label = f"point exemplar r={point_r[int(key.split()[-1])]:g}"
        noise = float(np.sqrt(np.mean(np.square(d["noise"]))))
        row = {"image": label, "mitsuba_noise": noise, "n": len(d["noise"])}
        for mode in ("sg", "quadrature"):
            e = float(np.sqrt(np.mean(np.square(d[mode]))))
            row[mode] = e
            row[f"{mode}_bias"] = math.sqrt(max(e * e - noise * noise / 2.0, 0.0))
        rows.append(row)
    return rows


# -- 3. SG fit comparison -------------------------------------------------------------------------


def _test_materials(size: int):
    from ..procedural import make_material
    from ..svbrdf import SVBRDF

    mats = [(f"exemplar r={r:g}", SVBRDF.uniform(size, size, 0.1, 0.2, r)) for r in (0.1, 0.3, 0.6, 0.9)]
    mats += [
        ("procedural:tiles:3", make_material("tiles", 3, size)),
        ("procedural:metal:2", make_material("metal", 2, size)),
    ]
    return mats


def _crn_render(svbrdf, bsdf, emitter, shot, spp: int, seed: int) -> np.ndarray:
    """Mitsuba ``direct`` with BSDF sampling only: with one seed, every emitter sees the same
    directions (common random numbers), so differences between emitters carry almost no noise."""
    import mitsuba as mi

    from ..scene import shot_scene_dict

    size = svbrdf.shape
    scene = shot_scene_dict(bsdf, emitter, shot, size, spp, seed)
    scene["integrator"] = {"type": "direct", "emitter_samples": 0, "bsdf_samples": 1, "hide_emitters": True}
    image = mi.render(mi.load_dict(scene), spp=spp, seed=seed)
    return np.array(image, dtype=np.float32).reshape(size[0], size[1], -1)[..., :3]


def fit_comparison(
    data_dir: Path,
    lobes_ours=FIT_LOBES,
    iterations: int = FIT_ITERATIONS,
    res: int = FIT_RES,
    spp: int = FIT_SPP,
    raster: tuple = RASTER,
) -> dict:
    import mitsuba as mi

    from ..envfit import fit_error, fit_sg, load_physg_fit, resample_equirect
    from ..envmap import envmap_emitter_dict, load_equirect, sg_to_equirect
    from ..geometry import near_shot
    from ..scene import svbrdf_bsdf_dict

    emap = load_equirect(data_dir / PEER_MAP)
    fits = {"PhySG (peer), 100 lobes": (load_physg_fit(data_dir / PEER_FIT), None)}
    for k in lobes_ours:
        result = fit_sg(emap, lobes=k, iterations=iterations)
        fits[f"ours, {k} lobes"] = (result.env, result.seconds)
    cells = resample_equirect(emap, emap.shape[0])
    map_rows = [{"fit": name, "seconds": sec, **fit_error(env, cells)} for name, (env, sec) in fits.items()]
    shot = near_shot(False)
    emitters = {"map": mi.load_dict(envmap_emitter_dict(emap))}
    for name, (env, _) in fits.items():
        emitters[name] = mi.load_dict(envmap_emitter_dict(sg_to_equirect(env, *raster)))
    render_rows = []
    for mat_name, svbrdf in _test_materials(res):
        bsdf = mi.load_dict(svbrdf_bsdf_dict(svbrdf))
        ref = _crn_render(svbrdf, bsdf, emitters["map"], shot, spp, seed=1)
        ref2 = _crn_render(svbrdf, bsdf, emitters["map"], shot, spp, seed=2)
        row = {"material": mat_name, "noise": rel_rmse(ref2, ref)}
        for name in fits:
            row[name] = rel_rmse(_crn_render(svbrdf, bsdf, emitters[name], shot, spp, seed=1), ref)
        render_rows.append(row)
    return {
        "map_rows": map_rows,
        "render_rows": render_rows,
        "fits": list(fits),
        "map": PEER_MAP,
        "iterations": iterations,
    }


# -- 4. contact sheet --------------------------------------------------------------------------------


def sheet(config, out_png: Path, samples: int = SHEET_SAMPLES, res: int = SHEET_RES) -> Path:
    from ..data.generate import generate
    from ..data.sheet import contact_sheet

    cfg = config.with_changes("dataset", resolution=res).with_count(samples)
    with tempfile.TemporaryDirectory(prefix="ebr-sheet-") as tmp:
        root = Path(tmp) / "near_train"
        workers = 1 if samples <= 4 else min(2, os.cpu_count() or 1)  # a pool's start-up is seconds
        generate(cfg, root, workers=workers, progress=False)
        return contact_sheet(root, out_png, samples=samples, dpi=SHEET_DPI)


# -- the page --------------------------------------------------------------------------------------


def _pct(v: float) -> str:
    return f"{100.0 * v:.1f} %"


def _data_dir() -> Path | None:
    path = shared_data_dir()
    return path if (path / PEER_FIT).is_file() and (path / PEER_MAP).is_file() else None


def run(out_dir: str | os.PathLike = "docs/bench", quick: bool = False) -> Path:
    """Run the benchmark and write ``out_dir/generate.md`` (+ the contact sheet); returns the path.
    ``quick``: :data:`QUICK` sizes (a smoke test; not the documented numbers)."""
    from ..fsutil import atomic_write_text
    from ..variant import ensure_variant

    ensure_variant()
    s = QUICK if quick else FULL
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    config = _near_train_config()
    tp = throughput(config, s.throughput_samples, s.size)
    err = fast_vs_mitsuba(config, s.error_samples, s.size)
    data_dir = _data_dir()
    fits = (
        fit_comparison(data_dir, s.fit_lobes, s.fit_iterations, s.fit_res, s.fit_spp, s.raster)
        if data_dir is not None
        else None
    )
    sheet_png = sheet(config, out / "generate_sheet.png", s.sheet_samples, s.sheet_res)
    r = config.render
    lines = [
        "# Data generation: throughput, fast vs Mitsuba, SG fits",
        "",
        "Generated by `ebr bench generate` (`ebr_mitsuba.bench.generate.run`); do not edit by hand."
        + (" **Quick mode: smoke-test sizes, not the documented numbers.**" if quick else ""),
        f"Machine: {machine()}. Total time {time.perf_counter() - t_start:.0f} s.",
        "",
        f"## Throughput at {s.size}² (per core)",
        "",
        f"Config `scenes/near_train.toml` at {s.size}×{s.size} (near setup: flash + no-flash photos, a "
        f"flash-only image, {len(config.exemplars.env_roughness)} environment and "
        f"{len(config.exemplars.point_roughness)} point-light exemplars; each photo is a flash render "
        f"plus an environment render), seed {config.dataset.seed}, samples 1–{s.throughput_samples} "
        "after one warm-up sample, one worker with one Dr.Jit thread (one core), everything a sample "
        "costs included (draw, render, camera simulation, EXR/PNG writing). `--workers N` scales "
        "this by about N on N free cores.",
        "",
        "| renderer | setting | s / sample | samples / s / core |",
        "|---|---|---:|---:|",
    ]
    for row in tp:
        lines.append(
            f"| {row['renderer']} | {row['setting']} | {row['seconds_per_sample']:.3f} | "
            f"{row['samples_per_second']:.2f} |"
        )
    lines += [
        "",
        "## Fast renderer against Mitsuba on the same samples",
        "",
        f"Samples 0–{s.error_samples - 1} of `near_train.toml` at {s.size}², clean renders (before the "
        f"camera simulation), Mitsuba `{r.integrator}` at {ERROR_SPP_FACTOR * r.spp} spp "
        f"({ERROR_SPP_FACTOR}× the config's, so that the bias estimate is less noisy), fast `sg` and fast "
        f"`quadrature` ({r.fast_spp} directions). Relative RMSE ‖a − b‖/‖b‖ against the Mitsuba render, "
        "RMS over the samples; *noise* is Mitsuba against itself with other seeds; *bias* removes the "
        "noise: sqrt(e² − noise²/2).",
        "",
        "| image | Mitsuba noise | fast sg | sg bias | fast quadrature | quadrature bias |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for row in err:
        lines.append(
            f"| {row['image']} | {_pct(row['mitsuba_noise'])} | {_pct(row['sg'])} | "
            f"{_pct(row['sg_bias'])} | {_pct(row['quadrature'])} | {_pct(row['quadrature_bias'])} |"
        )
    lines += [
        "",
        "Point-light exemplars and flash-only images have no environment term: there the two "
        "renderers differ only by Mitsuba's pixel-footprint integration (box filter) against the fast "
        "renderer's pixel-centre shading, and by noise. The `sg` mode's bias at roughness 0.3–0.6 is "
        "the closed-form SG×GGX approximation's overshoot (`ebr_mitsuba.render.env_sg`); the "
        "`quadrature` mode is unbiased but is itself a 64-direction estimate, whose own noise "
        "remains in its bias column.",
        "",
    ]
    lines += ["## SG fit of an environment map against the peer's fit", ""]
    if fits is None:
        lines += ["Skipped: the shared assets (`EBR_DATA_DIR`) are not available on this machine.", ""]
    else:
        lines += [
            f"Map `{fits['map']}` (500×250, venice sunset with the sun). Ours: `ebr fit-env` "
            f"({fits['iterations']} Adam iterations, fit on 64×128 cells, solid-angle weighted L2 + 0.1 × "
            "log term); peer: PhySG's 100-lobe fit `physg_envmap3_sg100.npy` (frame converted as in "
            "`ebr_mitsuba.envfit.load_physg_fit`). Map-space errors are solid-angle weighted over all "
            "250×500 texels (definitions in `ebr_mitsuba.envfit`).",
            "",
            "| fit | rel. L1 | rel. RMSE | log RMSE | energy | fit time |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for row in fits["map_rows"]:
            sec = "–" if row["seconds"] is None else f"{row['seconds']:.1f} s"
            lines.append(
                f"| {row['fit']} | {_pct(row['rel_l1'])} | {_pct(row['rel_rmse'])} | "
                f"{row['log_rmse']:.3f} | {row['energy']:+.3f} | {sec} |"
            )
        lines += [
            "",
            f"Renders of test materials (near no-flash shot, {s.fit_res}², {s.fit_spp} spp) under each fit "
            f"against the render under the map itself; relative RMSE. The fits are rasterised to "
            f"{s.raster[1]}×{s.raster[0]} "
            "and rendered with the same `envmap` emitter as the map, by Mitsuba's `direct` integrator with "
            "BSDF sampling only and one seed for all emitters (common random numbers: every render uses "
            "the same directions, so the difference is the lighting's, not noise). *noise* is the "
            "reference against itself with another seed, for scale.",
            "",
            "| material | noise | " + " | ".join(fits["fits"]) + " |",
            "|---|---:|" + "---:|" * len(fits["fits"]),
        ]
        for row in fits["render_rows"]:
            lines.append(
                f"| {row['material']} | {_pct(row['noise'])} | "
                + " | ".join(_pct(row[name]) for name in fits["fits"])
                + " |"
            )
        lines.append("")
    lines += [
        "## Contact sheet",
        "",
        f"{s.sheet_samples} samples of `near_train.toml` at {s.sheet_res}² (`ebr dataset sheet`): maps, "
        "photos (8-bit sRGB as stored), the flash-only image and the exemplars (camera units, clipped, "
        "sRGB).",
        "",
        f"![contact sheet]({sheet_png.name})",
        "",
    ]
    path = out / "generate.md"
    atomic_write_text(path, "\n".join(lines))
    return path
