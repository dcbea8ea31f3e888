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

The options (``--object`` … ``--mesh-up``) are the fields of :class:`ebr_mitsuba.insert.InsertConfig`;
their flags, defaults and help are generated from its field metadata (see ``--help``).

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

from ..insert import INSERT_FLAGS, InsertConfig
from ..typedconfig import add_flags, from_args
from ._common import emit_json, say

NAME = "insert"
HELP = "render a virtual object on an estimate under its lighting (and against the truth)"


def add_arguments(parser) -> None:
    # The InsertConfig options come from its field metadata; their values are read as text and
    # checked by from_args: a bad one is one line naming the flag, exit 2.
    parser.add_argument(
        "estimate", metavar="ESTIMATE_DIR", help="output directory of `ebr estimate` (or of `ebr capture`)"
    )
    parser.add_argument("--out", required=True, metavar="IMG", help="output image (.exr or .png)")
    parser.add_argument(
        "--truth",
        metavar="CAPTURE_DIR",
        help="`ebr capture` directory: also render the truth and report the RMSE",
    )
    add_flags(parser, InsertConfig, INSERT_FLAGS)
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def config_from_args(args) -> InsertConfig:
    """The :class:`~ebr_mitsuba.insert.InsertConfig` of the parsed options (InputError if bad)."""
    return from_args(InsertConfig, args, INSERT_FLAGS)


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
