"""Insert a virtual object into an estimate: a sphere, cube or mesh standing on the estimated sample
(the svbrdf BSDF with ESTIMATE_DIR/maps), lit by the estimated SG environment (ESTIMATE_DIR/env.json,
no flash), shadows and inter-reflections included, seen from the estimate's camera; rendered
with Mitsuba (path tracer). With --truth CAPTURE_DIR (an `ebr capture` directory), the same
insertion with the true maps and true environment too, and the RMSE between the two.

  ebr insert ESTIMATE_DIR --out IMG [--object sphere|cube|none|MESH.obj] [--material M]
             [--truth CAPTURE_DIR] [--spp N] [--res N] [--object-scale F] [--position X,Y]
             [--elevation DEG] [--seed S] [--truth-seed S] [--mesh-up y|z] [--json]

ESTIMATE_DIR is the --out of `ebr estimate` with lighting (a flash/no-flash estimate: maps/,
env.json, estimate.json), or an `ebr capture` directory (its true maps and environment).

Options (defaults in brackets):

  option             meaning
  -----------------  ----------------------------------------------------------------------
  --out IMG          the insertion image: .exr (linear radiance) or .png (sRGB preview)
  --object O         sphere | cube | none (the plane alone) | a mesh file .obj/.ply [sphere]
  --material M       diffuse (grey 0.8) | mirror | glossy (rough metal) | plastic (red) |
                     glass [diffuse]
  --truth DIR        an `ebr capture` directory: also render the truth and report the RMSE
  --spp N            samples per pixel of each render [64]
  --res N            image size, square [the resolution of the estimate's maps, at most 512]
  --object-scale F   the object's width as a fraction of the sample's width, in (0, 1] [1/3]
  --position X,Y     the object's centre on the sample, x and y in [-1, 1] [0,0]
  --elevation DEG    camera elevation in [10, 90]; 90 is the estimate's camera, straight
                     above; lower swings it towards -y at the same distance [90]
  --seed S           sampler seed [0]
  --truth-seed S     sampler seed of the truth render [--seed: correlated noise, which
                     mostly cancels in the RMSE]
  --mesh-up A        the mesh file's up axis, y (Wavefront's usual) or z [y]
  --json             print the summary on stdout

With --truth, IMG's stem + _truth (same suffix) holds the truth insertion and IMG's stem +
_compare.png shows estimate | truth | |difference| x4 at one exposure (PNGs are exposed at 1 /
the 99.5th luminance percentile of the truth, else of the insertion). The images appear together
after every render succeeded, or not at all. Bad input (a missing estimate directory, env.json
or maps, an unreadable mesh, an unknown material, a bad number) exits 2 with one line before
anything is rendered. --json prints {"out", "files", "object", "material", "spp", "resolution",
"seed", "truth_seed", "rmse" and "rel_rmse" (with --truth), "seconds", ...}; progress goes to
stderr. See docs/insert.md.
"""

from __future__ import annotations

import math

from ..errors import InputError
from ..insert import (
    DEFAULT_ELEVATION,
    DEFAULT_MATERIAL,
    DEFAULT_MAX_RES,
    DEFAULT_MESH_UP,
    DEFAULT_OBJECT,
    DEFAULT_SCALE,
    DEFAULT_SEED,
    DEFAULT_SPP,
    MATERIALS,
)
from ._common import emit_json, say

NAME = "insert"
HELP = "render a virtual object on an estimate under its lighting (and against the truth)"


def add_arguments(parser) -> None:
    # Numbers are read as text and checked in run(): a bad one is one line, exit 2.
    parser.add_argument(
        "estimate", metavar="ESTIMATE_DIR", help="output directory of `ebr estimate` (or of `ebr capture`)"
    )
    parser.add_argument("--out", required=True, metavar="IMG", help="output image (.exr or .png)")
    parser.add_argument(
        "--object",
        default=DEFAULT_OBJECT,
        metavar="O",
        help=f"sphere, cube, none or a .obj/.ply file [{DEFAULT_OBJECT}]",
    )
    parser.add_argument(
        "--material",
        default=DEFAULT_MATERIAL,
        metavar="M",
        help=f"one of {', '.join(MATERIALS)} [{DEFAULT_MATERIAL}]",
    )
    parser.add_argument(
        "--truth",
        metavar="CAPTURE_DIR",
        help="`ebr capture` directory: also render the truth and report the RMSE",
    )
    parser.add_argument(
        "--spp", default=str(DEFAULT_SPP), metavar="N", help=f"samples per pixel [{DEFAULT_SPP}]"
    )
    parser.add_argument(
        "--res",
        default=None,
        metavar="N",
        help=f"image size [the maps' resolution, at most {DEFAULT_MAX_RES}]",
    )
    parser.add_argument(
        "--object-scale",
        default=None,
        metavar="F",
        help=f"object width / sample width, in (0, 1] [{DEFAULT_SCALE:.3g}]",
    )
    parser.add_argument(
        "--position", default="0,0", metavar="X,Y", help="object centre on the sample, in [-1, 1]² [0,0]"
    )
    parser.add_argument(
        "--elevation",
        default=f"{DEFAULT_ELEVATION:g}",
        metavar="DEG",
        help=f"camera elevation in degrees, 90: the estimate's camera [{DEFAULT_ELEVATION:g}]",
    )
    parser.add_argument(
        "--seed", default=str(DEFAULT_SEED), metavar="S", help=f"sampler seed [{DEFAULT_SEED}]"
    )
    parser.add_argument("--truth-seed", default=None, metavar="S", help="seed of the truth render [--seed]")
    parser.add_argument(
        "--mesh-up",
        default=DEFAULT_MESH_UP,
        metavar="A",
        help=f"up axis of a mesh file, y or z [{DEFAULT_MESH_UP}]",
    )
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def _int(text: str | None, option: str) -> int | None:
    if text is None:
        return None
    try:
        return int(str(text).strip())
    except ValueError:
        raise InputError(f"{option} {text!r}: give an integer") from None


def _float(text: str, option: str) -> float:
    try:
        value = float(str(text).strip())
    except ValueError:
        raise InputError(f"{option} {text!r}: give a number") from None
    if not math.isfinite(value):
        raise InputError(f"{option} {text!r}: give a finite number")
    return value


def _position(text: str) -> tuple[float, float]:
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) != 2:
        raise InputError(f"--position {text!r}: write X,Y (two numbers, e.g. 0.3,-0.2)")
    return _float(parts[0], "--position x"), _float(parts[1], "--position y")


def config_from_args(args):
    """The :class:`~ebr_mitsuba.insert.InsertConfig` of the parsed options (InputError if bad)."""
    from ..insert import InsertConfig

    return InsertConfig(
        object=args.object,
        material=args.material,
        spp=_int(args.spp, "--spp"),
        res=_int(args.res, "--res"),
        scale=DEFAULT_SCALE if args.object_scale is None else _float(args.object_scale, "--object-scale"),
        position=_position(args.position),
        elevation=_float(args.elevation, "--elevation"),
        seed=_int(args.seed, "--seed"),
        truth_seed=_int(args.truth_seed, "--truth-seed"),
        mesh_up=args.mesh_up,
    )


def run(args) -> int:
    from ..insert import run_insert

    cfg = config_from_args(args)
    summary = run_insert(args.estimate, args.out, cfg, truth_dir=args.truth, progress=True)
    if args.json:
        emit_json(summary)
    else:
        res = summary["resolution"]
        msg = (
            f"wrote {summary['out']} ({cfg.object}, {cfg.material}, {res[1]}x{res[0]}, {cfg.spp} spp, "
            f"{summary['seconds']:.1f} s)"
        )
        if "rmse" in summary:
            msg += (
                f"; against the truth: RMSE {summary['rmse']:.5f} (relative {summary['rel_rmse']:.3f}); "
                f"also wrote {', '.join(summary['files'][1:])}"
            )
        say(msg)
        for warning in summary.get("warnings", []):
            say(f"warning: {warning}")
    return 0
