"""Render a synthetic capture (photos + ground truth) of a material under an environment.

  ebr capture --material M --env E --setup near|near-far|five-light|multi-view --out DIR
              [--spp N] [--res N] [--seed S] [--integrator direct|path] [--env-scale X] [--json]

M is a material directory or procedural:FAMILY:SEED; E is an env.json, an equirectangular
.exr/.hdr or procedural:SEED. DIR receives one EXR per shot (near: flash, noflash; near-far: +
far_flash, far_noflash; five-light: light0..light4, environment off; multi-view: 3x3
view{a}{b}_flash), the ground-truth maps in DIR/maps, env.json (SG environments) and
capture.json (cameras, lights, intensities, spp, seeds, variant and versions). The directory is
written atomically; an existing capture directory at DIR is replaced, anything else is refused.
``--json`` prints {"out", "setup", "files", "seconds", "spp", "resolution", "seed", "variant"}.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..capture import DEFAULT_INTEGRATOR, DEFAULT_RES, DEFAULT_SEED, DEFAULT_SPP
from ..geometry import SETUPS
from ..scene import INTEGRATORS
from ._common import emit_json, say

NAME = "capture"
HELP = "render a synthetic flash/no-flash capture with ground-truth maps"


def add_arguments(parser) -> None:
    parser.add_argument(
        "--material", required=True, metavar="M", help="material directory or procedural:FAMILY:SEED"
    )
    parser.add_argument(
        "--env", required=True, metavar="E", help="env.json, equirectangular .exr/.hdr, or procedural:SEED"
    )
    # Validated by geometry.setup_shots (one-line error) rather than argparse choices.
    parser.add_argument("--setup", required=True, metavar="SETUP", help=f"one of {', '.join(SETUPS)}")
    parser.add_argument("--out", required=True, metavar="DIR", help="output capture directory")
    parser.add_argument(
        "--spp", type=int, default=DEFAULT_SPP, help=f"samples per pixel (default {DEFAULT_SPP})"
    )
    parser.add_argument(
        "--res",
        type=int,
        default=DEFAULT_RES,
        help=f"image and map resolution, square (default {DEFAULT_RES})",
    )
    parser.add_argument(
        "--seed", type=int, default=DEFAULT_SEED, help=f"render seed (default {DEFAULT_SEED})"
    )
    parser.add_argument(
        "--integrator",
        default=DEFAULT_INTEGRATOR,
        metavar="NAME",
        help=f"one of {', '.join(INTEGRATORS)} (default {DEFAULT_INTEGRATOR})",
    )
    parser.add_argument(
        "--env-scale", type=float, default=1.0, help="environment radiance multiplier (default 1)"
    )
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args) -> int:
    import math

    from ..capture import capture
    from ..errors import InputError

    if not (math.isfinite(args.env_scale) and args.env_scale >= 0):
        raise InputError(f"--env-scale must be a finite value >= 0 (got {args.env_scale})")
    t0 = time.perf_counter()
    meta = capture(
        args.material,
        args.env,
        args.setup,
        Path(args.out),
        spp=args.spp,
        res=args.res,
        seed=args.seed,
        integrator=args.integrator,
        env_scale=args.env_scale,
        progress=True,
    )
    seconds = time.perf_counter() - t0
    files = [s["file"] for s in meta["shots"]] + ["maps", "capture.json"]
    if meta["env"] and meta["env"].get("file"):
        files.append(meta["env"]["file"])
    if args.json:
        emit_json(
            {
                "out": str(args.out),
                "setup": meta["setup"],
                "files": files,
                "seconds": round(seconds, 3),
                "spp": meta["spp"],
                "resolution": meta["resolution"],
                "seed": meta["seed"],
                "variant": meta["renderer"]["variant"],
            }
        )
    else:
        say(
            f"wrote {args.out}: {len(meta['shots'])} shots at {args.res}x{args.res}, {args.spp} spp "
            f"({seconds:.1f} s)"
        )
    return 0
