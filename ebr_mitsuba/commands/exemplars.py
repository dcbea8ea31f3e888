"""Render the exemplars of an environment: the uniform exemplar material (diffuse 0.1, specular
0.2 grey, roughness r, flat normal) seen by the near camera, one image per roughness value.

  ebr exemplars --env E --roughness 0.1,0.3,0.6,0.9 --out DIR [--point-light]
                [--renderer mitsuba|fast] [--res N] [--spp N] [--seed S] [--json]

E is an env.json, an equirectangular .exr/.hdr or procedural:SEED. Environment exemplars are
rendered with the flash off; with --point-light, the near flash alone lights them (E is then
ignored). DIR receives one EXR per exemplar and exemplars.json (format ebr-exemplars/1, see
ebr_mitsuba.exemplar.files); `ebr extract-sg DIR` reads it.

=================  ========  ==============================================================
option             default   meaning
=================  ========  ==============================================================
--roughness        0.1,0.3,  comma-separated roughness values in [0, 1]
                   0.6,0.9
--renderer         mitsuba   mitsuba: path-traced (direct integrator, box filter);
                             fast: the fast renderer's quadrature (SG environments only)
--res              256       image size (square)
--spp              256       Mitsuba samples / quadrature directions per pixel
--seed             0         sampler seed (quadrature pattern for fast)
=================  ========  ==============================================================

--json prints {"out", "kind", "files", "roughness", "renderer", "seconds", "resolution"}.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import InputError
from ..exemplar.images import RENDERERS
from ..geometry import DEFAULT_EXEMPLAR_ROUGHNESS
from ._common import emit_json, say

NAME = "exemplars"
HELP = "render environment (or point-light) exemplars of the uniform exemplar material"

DEFAULT_ROUGHNESS = ",".join(f"{r:g}" for r in DEFAULT_EXEMPLAR_ROUGHNESS)
DEFAULT_RES = 256
DEFAULT_SPP = 256


def add_arguments(parser) -> None:
    parser.add_argument(
        "--env", default=None, metavar="E", help="env.json, equirectangular .exr/.hdr or procedural:SEED"
    )
    parser.add_argument(
        "--roughness",
        default=DEFAULT_ROUGHNESS,
        metavar="R1,R2,...",
        help=f"exemplar roughness values (default {DEFAULT_ROUGHNESS})",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output exemplar directory")
    parser.add_argument("--point-light", action="store_true", help="point-light exemplars (near flash only)")
    parser.add_argument(
        "--renderer",
        default="mitsuba",
        metavar="NAME",
        help=f"one of {', '.join(RENDERERS)} (default mitsuba)",
    )
    parser.add_argument("--res", type=int, default=DEFAULT_RES, help=f"resolution (default {DEFAULT_RES})")
    parser.add_argument(
        "--spp", type=int, default=DEFAULT_SPP, help=f"samples per pixel (default {DEFAULT_SPP})"
    )
    parser.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def parse_roughness(text: str) -> list[float]:
    """``"0.1,0.3"`` → [0.1, 0.3]; values must be numbers in [0, 1], given once each."""
    try:
        values = [float(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise InputError(
            f"--roughness {text!r}: write comma-separated numbers, e.g. {DEFAULT_ROUGHNESS}"
        ) from None
    if not values or any(not 0.0 <= v <= 1.0 for v in values):
        raise InputError(f"--roughness {text!r}: give one or more values in [0, 1]")
    if len({f"{v:.3f}" for v in values}) != len(values):
        raise InputError(f"--roughness {text!r}: a value repeats; give each once")
    return values


def run(args) -> int:
    import mitsuba as mi

    from ..exemplar.files import META, exemplar_file, write_exemplars
    from ..exemplar.images import render_exemplars

    roughness = parse_roughness(args.roughness)
    t0 = time.perf_counter()
    images, shot, env = render_exemplars(
        args.env, roughness, args.point_light, args.renderer, args.res, args.spp, args.seed
    )
    kind = "point" if args.point_light else "env"
    renderer = {
        "name": args.renderer,
        "spp": args.spp,
        "seed": args.seed,
        "variant": mi.variant(),
        "mode": "path-traced (direct)" if args.renderer == "mitsuba" else "quadrature",
    }
    out = write_exemplars(Path(args.out), images, roughness, kind, shot, renderer, env)
    seconds = time.perf_counter() - t0
    files = [exemplar_file(r) for r in roughness] + [META]
    if args.json:
        emit_json(
            {
                "out": str(out),
                "kind": kind,
                "files": files,
                "roughness": roughness,
                "renderer": renderer,
                "seconds": round(seconds, 3),
                "resolution": [args.res, args.res],
            }
        )
    else:
        say(
            f"wrote {out}: {len(roughness)} {kind} exemplars at {args.res}x{args.res} ({args.renderer}, "
            f"{args.spp} spp, {seconds:.1f} s)"
        )
    return 0
