"""Render a synthetic capture (photos + ground truth) of a material under an environment.

  ebr capture --material M --env E --setup near|near-far|five-light|multi-view --out DIR
              [--spp N] [--res N] [--seed S] [--integrator direct|path] [--env-scale X] [--json]

M is a material directory or procedural:FAMILY:SEED; E is an env.json, an equirectangular
.exr/.hdr or procedural:SEED. DIR receives one EXR per shot (near: flash, noflash; near-far: +
far_flash, far_noflash; five-light: light0..light4, environment off; multi-view: 3x3
view{a}{b}_flash and noflash, the centre camera without its flash), the ground-truth maps in
DIR/maps, env.json (SG environments) and
capture.json (cameras, lights, intensities, spp, seeds, variant and versions). The directory is
written atomically; an existing capture directory at DIR is replaced, anything else is refused.
``--json`` prints {"out", "setup", "files", "seconds", "spp", "resolution", "seed", "variant"}.

The options ``--spp`` … ``--env-scale`` are the fields of :class:`ebr_mitsuba.capture.CaptureConfig`;
their flags, defaults and help are generated from its field metadata (see ``--help``); a bad value
is one line naming the flag (exit 2).
"""

from __future__ import annotations

import time
from pathlib import Path

from ..capture import CAPTURE_FLAGS, CaptureConfig
from ..geometry import SETUPS
from ..typedconfig import add_flags, from_args
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
    # The CaptureConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(parser, CaptureConfig, CAPTURE_FLAGS)
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def config_from_args(args) -> CaptureConfig:
    """The :class:`~ebr_mitsuba.capture.CaptureConfig` of the parsed options (InputError if bad)."""
    return from_args(CaptureConfig, args, CAPTURE_FLAGS)


def run(args) -> int:
    from ..capture import capture

    cfg = config_from_args(args)
    t0 = time.perf_counter()
    meta = capture(args.material, args.env, args.setup, Path(args.out), cfg, progress=True)
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
            f"wrote {args.out}: {len(meta['shots'])} shots at {cfg.res}x{cfg.res}, {cfg.spp} spp "
            f"({seconds:.1f} s)"
        )
    return 0
