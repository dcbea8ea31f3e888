"""``ebr bench renderer``: speed against error of Mitsuba and of the fast renderer's two modes.

:func:`run` writes ``<out_dir>/renderer.md`` and ``<out_dir>/renderer.png`` (error against time,
log-log, one curve per renderer, one panel per view angle), each atomically.

**What is measured.** The environment term only (no flash: the flash term of the fast renderer
is exact), for

* materials: two uniform materials, the exemplar material (diffuse 0.1, specular 0.2: what SG
  extraction renders) and a plastic (diffuse 0.3, specular 0.04), at each roughness of
  :data:`ROUGHNESS_BUCKETS`, and two procedural SVBRDFs (``tiles`` and ``metal``, normal-mapped,
  their own roughness maps), queried at texel centres (the ``svbrdf`` plugin reads nearest texels);
* environments: ``scenes/default_env.json`` and procedural ``window`` and ``overcast`` ones
  (:func:`ebr_mitsuba.procedural.make_environment`);
* views: every query point seen along one direction at :data:`VIEW_BUCKETS` degrees from the
  normal (0° is the near shot's centre, 30° about its corners; 60° and 80° are grazing), from
  ``VIEW_DISTANCE`` away, as :mod:`ebr_mitsuba.validate` does.

Each (material, environment, view) case has ``points`` query rays over [-0.8, 0.8]². The
reference is Mitsuba's ``direct`` integrator (the ``ebr capture`` default; for a lone plane it is
the whole light transport) with our ``sgenvmap`` emitter and ``svbrdf`` BSDF at ``ref_spp``
samples per ray (:func:`ebr_mitsuba.pathref.trace`); its relative standard error is reported.
Candidates: the same integrator at :data:`MITSUBA_SPP` (independent seeds), the fast renderer's
``sg`` closed form and its ``quadrature`` mode at :data:`QUADRATURE_SPP` directions
(:func:`ebr_mitsuba.validate.fast_radiance`). Error = relative RMSE ``‖a − ref‖ / ‖ref‖`` over
the case's rays and channels; a bucket reports the mean over its cases.

**Time** is measured separately on whole images, the way the renderers are used: a 128² render of
the ``tiles`` SVBRDF under the default environment in the near no-flash shot (fast renderer:
:func:`ebr_mitsuba.render.render_numpy`; Mitsuba: :func:`ebr_mitsuba.capture.render_shot` at 64²),
after one warm-up call (kernel compilation excluded), median of ``repeats``; reported as seconds
per megapixel with all of the machine's Dr.Jit threads.

The "which mode when" section is computed from the tables: for each roughness and view bucket,
the cheapest setting whose error is within :data:`TARGETS`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from pathlib import Path

import numpy as np

from ..exemplar import EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR
from ..metrics import rel_rmse
from ._common import machine, median_seconds

ROUGHNESS_BUCKETS = (0.05, 0.2, 0.5, 0.9)
VIEW_BUCKETS = (0.0, 30.0, 60.0, 80.0)
MITSUBA_SPP = (16, 64, 256, 1024)
QUADRATURE_SPP = (16, 64, 256)
TARGETS = (0.02, 0.05)  # relative-RMSE budgets of the "which mode when" section
# (name, diffuse, specular)
UNIFORM_MATERIALS = (("exemplar", EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR), ("plastic", 0.3, 0.04))
SVBRDF_MATERIALS = (("tiles", 1), ("metal", 2))
ENV_SPECS = (("default", None, None), ("window", 3, "window"), ("overcast", 4, "overcast"))


@dataclasses.dataclass(frozen=True)
class Settings:
    """Sizes of one benchmark run (``FULL`` documents the page; ``QUICK`` is a smoke test)."""

    points: int
    ref_spp: int
    texture: int
    time_res: int
    mitsuba_time_res: int
    repeats: int
    roughness: tuple = ROUGHNESS_BUCKETS
    views: tuple = VIEW_BUCKETS
    mitsuba_spp: tuple = MITSUBA_SPP
    quadrature_spp: tuple = QUADRATURE_SPP
    envs: tuple = ENV_SPECS
    svbrdfs: tuple = SVBRDF_MATERIALS


FULL = Settings(points=64, ref_spp=32768, texture=64, time_res=256, mitsuba_time_res=128, repeats=3)
QUICK = Settings(
    points=6,
    ref_spp=256,
    texture=16,
    time_res=16,
    mitsuba_time_res=16,
    repeats=1,
    roughness=(0.2, 0.9),
    views=(0.0, 80.0),
    mitsuba_spp=(4, 16),
    quadrature_spp=(4, 16),
    envs=ENV_SPECS[:1],
    svbrdfs=SVBRDF_MATERIALS[:1],
)


@dataclasses.dataclass(frozen=True)
class Material:
    """One benchmark material: a label, its group (``exemplar``, ``plastic``, ``svbrdf``), its
    roughness bucket (``-`` for SVBRDFs) and its (numpy) SVBRDF."""

    name: str
    group: str
    bucket: str
    svbrdf: object  # ebr_mitsuba.svbrdf.SVBRDF


def _environments(settings: Settings) -> list[tuple[str, object]]:
    from importlib import resources

    from ..procedural import make_environment
    from ..sgenv import SGEnvironment

    out = []
    for name, seed, kind in settings.envs:
        if seed is None:
            path = Path(str(resources.files("ebr_mitsuba.scenes") / "default_env.json"))
            out.append((name, SGEnvironment.load(path)))
        else:
            out.append((name, make_environment(seed, kind=kind, intensity="medium")))
    return out


def _materials(settings: Settings) -> list[Material]:
    from ..procedural import make_material
    from ..svbrdf import SVBRDF

    n = settings.texture
    mats = [
        Material(f"{name} r={r:g}", name, f"{r:g}", SVBRDF.uniform(n, n, d, s, r))
        for name, d, s in UNIFORM_MATERIALS
        for r in settings.roughness
    ]
    mats += [
        Material(f"{family}:{seed}", "svbrdf", "-", make_material(family, seed, size=n))
        for family, seed in settings.svbrdfs
    ]
    return mats


def _query(svbrdf, points: int, view_deg: float, seed: int):
    """Texel-centre points (P, 3), camera positions (P, 3) and the per-point maps (a
    :class:`ebr_mitsuba.validate.PlaneScene` of per-point arrays, lobes filled in later)."""
    from ..geometry import pixel_positions
    from ..validate import VIEW_DISTANCE

    h, w = svbrdf.shape
    rng = np.random.default_rng(seed)
    grid = pixel_positions(h, w)
    inside = np.argwhere((np.abs(grid[..., 0]) <= 0.8) & (np.abs(grid[..., 1]) <= 0.8))
    pick = inside[rng.choice(len(inside), size=min(points, len(inside)), replace=False)]
    i, j = pick[:, 0], pick[:, 1]
    pts = grid[i, j]
    th, ph = math.radians(view_deg), math.radians(20.0)
    d = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    return pts, pts + VIEW_DISTANCE * d[None, :], (i, j)


def _plane(svbrdf, ij, env):
    """Per-point maps and the lobes as the :class:`~ebr_mitsuba.validate.PlaneScene` that
    :func:`~ebr_mitsuba.validate.fast_radiance` shades (its fields broadcast per point)."""
    from ..validate import PlaneScene

    i, j = ij
    return PlaneScene(
        normal=svbrdf.normal[i, j].astype(np.float64),
        diffuse=svbrdf.diffuse[i, j].astype(np.float64),
        specular=svbrdf.specular[i, j].astype(np.float64),
        roughness=svbrdf.roughness[i, j].astype(np.float64),
        axis=env.axis.astype(np.float64),
        sharpness=env.sharpness.astype(np.float64),
        amplitude=env.amplitude.astype(np.float64),
        light=None,
        intensity=np.zeros(3),
    )


def setting_labels(settings: Settings) -> list[str]:
    """The settings compared, in table order: ``mitsuba N``, ``sg``, ``quadrature N``."""
    return (
        [f"mitsuba {s}" for s in settings.mitsuba_spp]
        + ["sg"]
        + [f"quadrature {s}" for s in settings.quadrature_spp]
    )


def measure_errors(settings: Settings, seed: int = 0, progress=None) -> list[dict]:
    """One row per (material, environment, view): ``{"material", "bucket", "env", "view",
    "ref_noise", "errors": {setting: rel RMSE}}``."""
    import mitsuba as mi

    from ..pathref import trace
    from ..scene import integrator_dict, sample_shape_dict, sg_emitter_dict, svbrdf_bsdf_dict
    from ..validate import fast_radiance

    integrator = integrator_dict("direct")
    rows = []
    for m_idx, mat in enumerate(_materials(settings)):
        for e_idx, (env_name, env) in enumerate(_environments(settings)):
            scene = mi.load_dict(
                {
                    "type": "scene",
                    "sample": sample_shape_dict(svbrdf_bsdf_dict(mat.svbrdf)),
                    "env": sg_emitter_dict(env),
                }
            )
            for v_idx, view in enumerate(settings.views):
                case_seed = (seed * 1000 + m_idx) * 100 + e_idx * 10 + v_idx
                pts, cams, ij = _query(mat.svbrdf, settings.points, view, case_seed)
                dirs = pts - cams
                ref = trace(scene, cams, dirs, spp=settings.ref_spp, seed=case_seed, integrator=integrator)
                plane = _plane(mat.svbrdf, ij, env)
                errors = {}
                for k, spp in enumerate(settings.mitsuba_spp):
                    est = trace(
                        scene, cams, dirs, spp=spp, seed=case_seed + 7919 * (k + 1), integrator=integrator
                    )
                    errors[f"mitsuba {spp}"] = rel_rmse(est.mean, ref.mean)
                errors["sg"] = rel_rmse(fast_radiance(plane, pts, cams, "sg", 1), ref.mean)
                for spp in settings.quadrature_spp:
                    quad = fast_radiance(plane, pts, cams, "quadrature", spp)
                    errors[f"quadrature {spp}"] = rel_rmse(quad, ref.mean)
                rows.append(
                    {
                        "material": mat.name,
                        "group": mat.group,
                        "bucket": mat.bucket,
                        "env": env_name,
                        "view": float(view),
                        "ref_noise": ref.relative_noise(),
                        "errors": errors,
                    }
                )
                if progress is not None:
                    progress(rows[-1])
    return rows


def measure_times(settings: Settings) -> dict[str, float]:
    """Seconds per megapixel of each setting (module docstring)."""
    from ..capture import render_shot
    from ..geometry import near_shot
    from ..procedural import make_material
    from ..render import render_numpy
    from ..scene import sg_emitter_dict

    env = _environments(settings)[0][1]
    shot = near_shot(False)
    family, mseed = settings.svbrdfs[0]
    n = settings.time_res
    fast_mat = make_material(family, mseed, size=n)
    out = {}
    mpx = n * n / 1e6
    out["sg"] = median_seconds(lambda: render_numpy(fast_mat, env, shot, mode="sg"), settings.repeats) / mpx
    for spp in settings.quadrature_spp:
        out[f"quadrature {spp}"] = (
            median_seconds(
                lambda s=spp: render_numpy(fast_mat, env, shot, mode="quadrature", spp=s), settings.repeats
            )
            / mpx
        )
    m = settings.mitsuba_time_res
    mitsuba_mat = make_material(family, mseed, size=m)
    for spp in settings.mitsuba_spp:
        out[f"mitsuba {spp}"] = median_seconds(
            lambda s=spp: render_shot(mitsuba_mat, sg_emitter_dict(env), shot, s, seed=1), settings.repeats
        ) / (m * m / 1e6)
    return out


# -- summaries -----------------------------------------------------------------------------------


def _mean(values) -> float:
    v = list(values)
    return float(np.mean(v)) if v else float("nan")


def bucket_table(rows: list[dict], labels: list[str], key) -> dict:
    """Mean error per (group key, setting): ``{group: {setting: mean rel RMSE, "ref_noise": mean
    reference noise, "cases": count}}``, groups in order of first appearance."""
    groups: dict = {}
    for r in rows:
        groups.setdefault(key(r), []).append(r)
    out = {}
    for g, rs in groups.items():
        out[g] = {s: _mean(r["errors"][s] for r in rs) for s in labels}
        out[g]["ref_noise"] = _mean(r["ref_noise"] for r in rs)
        out[g]["cases"] = len(rs)
    return out


def fine_key(row: dict) -> tuple[str, str, str]:
    """(material group, roughness bucket, view) of a result row."""
    return row["group"], row["bucket"], f"{row['view']:g}"


def _where(keys: list[tuple[str, str, str]], views: list[str]) -> str:
    """'exemplar r=0.05 (all views); svbrdf (0°, 30°)' from (group, bucket, view) keys."""
    by: dict = {}
    for g, b, v in keys:
        by.setdefault((g, b), []).append(v)
    parts = []
    for (g, b), vs in by.items():
        label = g if b == "-" else f"{g} r={b}"
        parts.append(f"{label} ({'all views' if vs == views else ', '.join(v + '°' for v in vs)})")
    return "; ".join(parts)


def cheapest(errors: dict[str, float], times: dict[str, float], target: float) -> str | None:
    """The fastest setting whose error is ≤ ``target`` (None when none is)."""
    ok = [s for s, e in errors.items() if s in times and np.isfinite(e) and e <= target]
    return min(ok, key=lambda s: times[s]) if ok else None


def advice(rows: list[dict], labels: list[str], times: dict[str, float], targets=TARGETS) -> list[str]:
    """The "which mode when" paragraph, computed from the numbers (one bullet per finding)."""
    table = bucket_table(rows, labels, fine_key)
    views = list(dict.fromkeys(k[2] for k in table))
    lines = []
    for target in targets:
        picks: dict = {}
        for key, errs in table.items():
            picks.setdefault(cheapest({s: errs[s] for s in labels}, times, target), []).append(key)
        for choice, keys in sorted(picks.items(), key=lambda kv: times.get(kv[0], math.inf)):
            if choice is None:
                lines.append(
                    f"- Within {100 * target:g} %: no tested setting reaches it for {_where(keys, views)}."
                )
            else:
                lines.append(
                    f"- Within {100 * target:g} %: **{choice}** ({times[choice]:.2g} s/Mpx) is the "
                    f"cheapest for {_where(keys, views)}."
                )
    (wg, wb, wv), worst = max(table.items(), key=lambda kv: kv[1]["sg"])
    bad = [k for k, e in table.items() if e["sg"] > targets[-1]]
    lines.append(
        f"- The closed form (`sg`) is worst for {wg if wb == '-' else f'{wg} r={wb}'} at {wv}° "
        f"({100 * worst['sg']:.1f} % mean error); it exceeds {100 * targets[-1]:g} % for "
        f"{_where(bad, views) if bad else 'no bucket'}."
    )
    return lines


# -- output --------------------------------------------------------------------------------------


def _pct(v: float) -> str:
    return "inf" if not np.isfinite(v) else f"{100 * v:.2f} %"


def plot(rows: list[dict], labels: list[str], times: dict[str, float], views, path: Path) -> Path:
    """Error (mean over the view's cases) against seconds per megapixel, one panel per view."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..fsutil import atomic_path

    table = bucket_table(rows, labels, lambda r: f"{r['view']:g}")
    fig, axes = plt.subplots(1, len(views), figsize=(3.6 * len(views), 3.4), sharey=True, squeeze=False)
    series = {"mitsuba": ("C0", "o-"), "quadrature": ("C1", "s-"), "sg": ("C3", "*")}
    for ax, view in zip(axes[0], views):
        errs = table[f"{view:g}"]
        for name, (color, style) in series.items():
            pts = [(times[s], errs[s]) for s in labels if s.split()[0] == name]
            if pts:
                x, y = zip(*sorted(pts))
                ax.plot(x, y, style, color=color, label=name, markersize=9 if name == "sg" else 5)
                for s in labels:
                    if s.split()[0] == name and len(s.split()) > 1:
                        ax.annotate(
                            s.split()[1],
                            (times[s], errs[s]),
                            fontsize=7,
                            xytext=(3, 3),
                            textcoords="offset points",
                        )
        ax.axhline(errs["ref_noise"], color="grey", lw=0.8, ls=":", label="reference noise")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"view {view:g}°")
        ax.set_xlabel("seconds per megapixel")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel("relative RMSE (mean over cases)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return path


def markdown(rows, labels, times, settings: Settings, seconds: float, quick: bool) -> str:
    views = [f"{v:g}" for v in settings.views]
    by_setting = bucket_table(rows, labels, lambda r: "all")["all"]
    lines = [
        "# Renderer: speed against error",
        "",
        "Generated by `ebr bench renderer` (`ebr_mitsuba.bench.renderer.run`); do not edit by hand."
        + (" **Quick mode: smoke-test sizes, not the documented numbers.**" if quick else ""),
        f"Machine: {machine()}. Total time {seconds:.0f} s. Seed 0.",
        "",
        "Environment term only (the flash term of the fast renderer is exact). "
        "Materials: uniform "
        + ", ".join(f"{name} (diffuse {d:g}, specular {sp:g})" for name, d, sp in UNIFORM_MATERIALS)
        + f" at roughness {', '.join(f'{r:g}' for r in settings.roughness)}, and the procedural SVBRDFs "
        f"{', '.join(f'{f}:{s}' for f, s in settings.svbrdfs)} ({settings.texture}² maps, queried at "
        "texel centres). "
        f"Environments: {', '.join(name for name, _, _ in settings.envs)} (`scenes/default_env.json`, "
        "`make_environment(seed, kind, 'medium')`). "
        f"Views: {', '.join(views)}° from the normal (0° = the near shot's centre, 30° ≈ its corners), "
        f"{settings.points} rays per case over [-0.8, 0.8]². Reference: Mitsuba `direct` with our `sgenvmap` "
        f"and `svbrdf` plugins at {settings.ref_spp} samples per ray; its relative standard error is the "
        "*ref noise* column (an error below it cannot be resolved). Error: relative RMSE ‖a − ref‖/‖ref‖ "
        "per case, mean over the cases of a row.",
        "",
        f"Time: whole {settings.time_res}² images of `{settings.svbrdfs[0][0]}:{settings.svbrdfs[0][1]}` "
        f"under the default environment, near no-flash shot (Mitsuba at {settings.mitsuba_time_res}²), "
        f"median of {settings.repeats} after a warm-up call, all Dr.Jit threads of this machine.",
        "",
        "## All cases",
        "",
        "| setting | s / Mpx | mean error | worst bucket error |",
        "|---|---:|---:|---:|",
    ]
    fine = bucket_table(rows, labels, fine_key)
    for s in labels:
        worst = max(v[s] for v in fine.values())
        lines.append(f"| {s} | {times[s]:.3g} | {_pct(by_setting[s])} | {_pct(worst)} |")
    lines += [
        "",
        f"Reference noise (mean over cases): {_pct(by_setting['ref_noise'])}.",
        "",
        "## Error by material, roughness and view",
        "",
        "Mean relative RMSE over the environments (and the two materials, for the SVBRDF rows).",
        "",
        "| material | roughness | view | ref noise | " + " | ".join(labels) + " |",
        "|---|---|---:|---:|" + "---:|" * len(labels),
    ]
    for (group, bucket, view), errs in fine.items():
        lines.append(
            f"| {group} | {bucket} | {view}° | {_pct(errs['ref_noise'])} | "
            + " | ".join(_pct(errs[s]) for s in labels)
            + " |"
        )
    env_table = bucket_table(rows, labels, lambda r: r["env"])
    lines += [
        "",
        "## Error by environment",
        "",
        "| environment | ref noise | " + " | ".join(labels) + " |",
        "|---|---:|" + "---:|" * len(labels),
    ]
    for env, errs in env_table.items():
        cells = " | ".join(_pct(errs[s]) for s in labels)
        lines.append(f"| {env} | {_pct(errs['ref_noise'])} | {cells} |")
    lines += [
        "",
        "![error against time](renderer.png)",
        "",
        "## Which mode when",
        "",
        "Computed from the tables above (mean error of each material/roughness/view bucket, "
        "time per megapixel):",
        "",
    ]
    lines += advice(rows, labels, times)
    return "\n".join(lines) + "\n"


def run(out_dir: Path, quick: bool = False) -> Path:
    """Run the benchmark; write ``out_dir/renderer.md`` and ``out_dir/renderer.png``; return the
    Markdown path."""
    import drjit as dr

    from ..fsutil import atomic_write_text
    from ..variant import ensure_variant

    ensure_variant()
    dr.set_thread_count(os.cpu_count() or 1)
    settings = QUICK if quick else FULL
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    labels = setting_labels(settings)
    rows = measure_errors(settings)
    times = measure_times(settings)
    plot(rows, labels, times, settings.views, out_dir / "renderer.png")
    path = out_dir / "renderer.md"
    atomic_write_text(path, markdown(rows, labels, times, settings, time.perf_counter() - t0, quick))
    return path


__all__ = [
    "FULL",
    "QUICK",
    "Settings",
    "advice",
    "bucket_table",
    "cheapest",
    "fine_key",
    "measure_errors",
    "measure_times",
    "run",
    "setting_labels",
]
