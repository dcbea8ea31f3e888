"""The whole pipeline on the bundled default scene: render, estimate, compare with the truth.

  ebr demo [--out DIR] [--res N] [--spp N] [--refine-steps N] [--checkpoint C] [--json]

1. renders the near capture (flash + no-flash) of the default scene with Mitsuba: the material
   and lighting of ``scenes/default.xml`` (a checkerboard diffuse 0.60/0.42/0.25 and
   0.12/0.09/0.07 in 8x8 squares, specular 0.04, roughness 0.35, under the sun + sky SGs of
   ``scenes/default_env.json``, 10 W/sr flash) into DIR/capture (``ebr capture`` layout, with
   the ground-truth maps);
2. runs ``ebr estimate`` on it with refinement into DIR/estimate (report.html there);
3. compares the maps with the ground truth per map (RMSE, normals as (n+1)/2) before and after
   refinement, and the lighting (RMSE of exemplars rendered under the estimated vs the true SGs);
4. writes DIR/demo.json and DIR/demo.png (photos, re-render, maps, lighting in one strip) and
   prints the errors and where the report is.

Defaults (chosen to finish well under 10 minutes on a 2-core CPU): --res = the model grid,
--spp 64, --refine-steps 100, --out ebr-demo. An existing DIR must be an earlier demo.
``--json`` prints {"out", "report", "map_error", "lighting_error", "rerender_error", "timings"}.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..errors import InputError
from ._common import emit_json, progress, say

NAME = "demo"
HELP = "run the whole pipeline on the bundled default scene and compare with the truth"

DEFAULT_OUT = "ebr-demo"
DEFAULT_SPP = 64
DEFAULT_REFINE_STEPS = 100
CHECKER_COLORS = ((0.60, 0.42, 0.25), (0.12, 0.09, 0.07))
CHECKER_SQUARES = 8
SPECULAR, ROUGHNESS = 0.04, 0.35
EXEMPLAR_ROUGHNESS = (0.1, 0.3, 0.6, 0.9)


def add_arguments(parser) -> None:
    parser.add_argument("--out", default=DEFAULT_OUT, metavar="DIR", help=f"output directory [{DEFAULT_OUT}]")
    parser.add_argument("--res", type=int, default=None, help="capture resolution [the model grid]")
    parser.add_argument(
        "--spp", type=int, default=DEFAULT_SPP, help=f"Mitsuba samples per pixel [{DEFAULT_SPP}]"
    )
    parser.add_argument(
        "--refine-steps",
        type=int,
        default=DEFAULT_REFINE_STEPS,
        help=f"test-time refinement steps [{DEFAULT_REFINE_STEPS}]",
    )
    parser.add_argument("--checkpoint", metavar="C", help="model checkpoint (default: the shipped model)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def default_material(res: int):
    """The default scene's material (scenes/default.xml) as an SVBRDF of res×res: Mitsuba's
    checkerboard puts colour 0 where u and v fall in the same half period (the bottom-left
    square, uv origin at −x, −y)."""
    from ..svbrdf import SVBRDF

    i, j = np.mgrid[0:res, 0:res]
    sq_v = ((res - 1 - i) * CHECKER_SQUARES) // res
    sq_u = (j * CHECKER_SQUARES) // res
    odd = ((sq_u + sq_v) % 2).astype(bool)[..., None]
    c0, c1 = (np.asarray(c, np.float32) for c in CHECKER_COLORS)
    diffuse = np.where(odd, c1, c0).astype(np.float32)
    return SVBRDF(
        normal=np.broadcast_to(np.float32([0, 0, 1]), (res, res, 3)).copy(),
        diffuse=diffuse,
        specular=np.full((res, res, 3), SPECULAR, np.float32),
        roughness=np.full((res, res), ROUGHNESS, np.float32),
        source="scenes/default.xml",
    )


def default_env():
    import importlib.resources

    from ..sgenv import SGEnvironment

    return SGEnvironment.load(Path(str(importlib.resources.files("ebr_mitsuba.scenes") / "default_env.json")))


def lighting_error(estimated, truth, res: int = 64) -> dict:
    """RMSE and relative RMSE of exemplars (roughness 0.1, 0.3, 0.6, 0.9) rendered under the
    estimated vs the true SGs (DESIGN §3 "Lighting error"), fast renderer, near camera."""
    from ..render import exemplar_images
    from ..sgenv import SGEnvironment

    est = [
        np.asarray(t.numpy())
        for t in exemplar_images(estimated or SGEnvironment.empty(), EXEMPLAR_ROUGHNESS, res, res)
    ]
    ref = [np.asarray(t.numpy()) for t in exemplar_images(truth, EXEMPLAR_ROUGHNESS, res, res)]
    d = np.stack(est).astype(np.float64) - np.stack(ref)
    rmse = float(np.sqrt(np.mean(d**2)))
    rms = float(np.sqrt(np.mean(np.stack(ref).astype(np.float64) ** 2)))
    return {"rmse": rmse, "rel_rmse": rmse / rms if rms > 0 else float("nan")}


def demo_strip(out: Path, path: Path, true_env=None) -> Path:
    """The README picture: a labelled two-row figure. Top: the two photos and the ground-truth
    maps and lighting; bottom: the re-render of the flash photo and the estimated maps and
    lighting (refined where refinement ran). Images are the PNG previews the capture and the
    estimate wrote (``out/capture/maps``, ``out/estimate``)."""
    import tempfile

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..estimate.outputs import env_pictures
    from ..fsutil import atomic_path
    from ..imageio import read_ldr

    def read_png(p):  # display values (the PNG's code values), grey maps as RGB
        img = read_ldr(p, "linear")
        return np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img

    est, cap = out / "estimate", out / "capture" / "maps"
    with tempfile.TemporaryDirectory() as tmp:
        true_sphere = None
        if true_env is not None:
            env_pictures(true_env, Path(tmp))
            true_sphere = read_png(Path(tmp) / "env_sphere.png")
        rows = [
            [
                ("flash photo", read_png(est / "inputs/flash.png")),
                ("no-flash photo", read_png(est / "inputs/noflash.png")),
                ("true diffuse", read_png(cap / "diffuse.png")),
                ("true normal", read_png(cap / "normal.png")),
                ("true roughness", read_png(cap / "roughness.png")),
                ("true specular", read_png(cap / "specular.png")),
                ("true lighting", true_sphere),
            ],
            [
                ("re-render (flash)", read_png(est / "rerender/flash.png")),
                ("re-render (no-flash)", read_png(est / "rerender/noflash.png")),
                ("estimated diffuse", read_png(est / "maps/diffuse.png")),
                ("estimated normal", read_png(est / "maps/normal.png")),
                ("estimated roughness", read_png(est / "maps/roughness.png")),
                ("estimated specular", read_png(est / "maps/specular.png")),
                ("estimated lighting", read_png(est / "env_sphere.png") if (est / "env_sphere.png").is_file() else None),
            ],
        ]
    fig, axes = plt.subplots(2, 7, figsize=(14, 4.3))
    for r, row in enumerate(rows):
        for c, (title, img) in enumerate(row):
            ax = axes[r, c]
            ax.axis("off")
            ax.set_title(title, fontsize=9)
            if img is not None:
                ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=80)
    plt.close(fig)
    return path


def _check_out(out: Path) -> None:
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not (out / "demo.json").is_file())):
        raise InputError(
            f"--out {out}: exists and is not an earlier demo directory (no demo.json); "
            f"choose another --out or remove it"
        )


def run(args) -> int:
    from ..capture import capture
    from ..estimate.pipeline import EstimateConfig, inference_module, run_estimate
    from ..estimate.refine import RefineConfig
    from ..estimate.resample import model_grid
    from ..fsutil import atomic_write_text
    from ..sgenv import SGEnvironment

    t0 = time.perf_counter()
    out = Path(args.out)
    _check_out(out)
    if args.checkpoint is not None and not Path(args.checkpoint).is_file():
        raise InputError(f"--checkpoint {args.checkpoint}: no such file; omit it for the shipped model")
    if args.spp < 1 or args.refine_steps < 0:
        raise InputError("--spp must be >= 1 and --refine-steps >= 0")
    grid = model_grid(inference_module().load_model(args.checkpoint))
    res = int(args.res or grid)
    truth, env = default_material(res), default_env()
    timings = {}

    say(f"rendering the default scene ({res}x{res}, {args.spp} spp) with Mitsuba")
    t = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    capture(truth, env, "near", out / "capture", spp=args.spp, res=res, progress=True)
    timings["capture"] = round(time.perf_counter() - t, 3)

    t = time.perf_counter()
    cfg = EstimateConfig(
        flash=str(out / "capture" / "flash.exr"),
        noflash=str(out / "capture" / "noflash.exr"),
        out=str(out / "estimate"),
        checkpoint=args.checkpoint,
        refine=RefineConfig(steps=args.refine_steps),
    )
    summary = run_estimate(cfg, truth=truth, log=say, bar=progress)
    timings["estimate"] = round(time.perf_counter() - t, 3)
    est_env = (
        SGEnvironment.load(out / "estimate" / "env.json")
        if (out / "estimate" / "env.json").is_file()
        else None
    )
    light = lighting_error(est_env, env)
    demo_strip(out, out / "demo.png", env)
    timings["total"] = round(time.perf_counter() - t0, 3)
    result = {
        "out": str(out),
        "report": str(out / "estimate" / "report.html"),
        "resolution": res,
        "spp": args.spp,
        "map_error": summary["map_error"],
        "lighting_error": light,
        "rerender_error": {k: (v["mean"] if v else None) for k, v in summary["rerender_error"].items()},
        "refine": summary["refine"] and {k: summary["refine"][k] for k in ("steps", "seconds")},
        "timings": {**timings, "estimate_stages": summary["timings"]},
    }
    atomic_write_text(out / "demo.json", json.dumps(result, indent=1, default=float) + "\n")
    if args.json:
        emit_json(result)
    me = summary["map_error"]
    say("per-map RMSE against the ground truth (normals as (n+1)/2):")
    say(f"  {'map':<10} {'network':>9}" + (f" {'refined':>9}" if me["refined"] else ""))
    for m in ("normal", "diffuse", "specular", "roughness", "mean"):
        say(f"  {m:<10} {me['network'][m]:9.4f}" + (f" {me['refined'][m]:9.4f}" if me["refined"] else ""))
    rr = result["rerender_error"]
    say(
        f"re-render RMSE: network {rr['network']['rmse']:.4g}"
        + (f", refined {rr['refined']['rmse']:.4g}" if rr["refined"] else "")
    )
    say(f"lighting RMSE (exemplars): {light['rmse']:.4g} (relative {light['rel_rmse']:.3f})")
    say(f"report: {out / 'estimate' / 'report.html'}   ({timings['total']:.0f} s)")
    return 0
