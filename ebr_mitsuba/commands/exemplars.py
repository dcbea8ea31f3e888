"""Render the exemplars of an environment: the uniform exemplar material (diffuse 0.1, specular
0.2 grey, roughness r, flat normal) seen by the near camera, one image per roughness value.

  ebr exemplars --env E --out DIR [--roughness R1,R2,...] [--point-light]
                [--renderer mitsuba|fast] [--res N] [--spp N] [--seed S] [--json]

E is an env.json, an equirectangular .exr/.hdr or procedural:SEED. Environment exemplars are
rendered with the flash off; with --point-light, the near flash alone lights them (E is then
ignored). DIR receives one EXR per exemplar and exemplars.json (format ebr-exemplars/1, see
ebr_mitsuba.exemplar.files); `ebr extract-sg DIR` reads it.

The options ``--roughness`` … ``--seed`` are the fields of
:class:`ebr_mitsuba.exemplar.images.ExemplarsConfig`; their flags, defaults and help are generated
from its field metadata (see ``--help``); a bad value is one line naming the flag (exit 2).

--json prints {"out", "kind", "files", "roughness", "renderer", "seconds", "resolution"}.
"""

from __future__ import annotations

import time
from pathlib import Path

from ..exemplar.images import EXEMPLARS_FLAGS, ExemplarsConfig
from ..typedconfig import add_flags, from_args
from ._common import emit_json, say

NAME = "exemplars"
HELP = "render environment (or point-light) exemplars of the uniform exemplar material"


def add_arguments(parser) -> None:
    parser.add_argument(
        "--env", default=None, metavar="E", help="env.json, equirectangular .exr/.hdr or procedural:SEED"
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output exemplar directory")
    # The ExemplarsConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(parser, ExemplarsConfig, EXEMPLARS_FLAGS)
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def config_from_args(args) -> ExemplarsConfig:
    """The :class:`~ebr_mitsuba.exemplar.images.ExemplarsConfig` of the parsed options."""
    return from_args(ExemplarsConfig, args, EXEMPLARS_FLAGS)


def run(args) -> int:
    import mitsuba as mi

    from ..exemplar.files import META, exemplar_file, write_exemplars
    from ..exemplar.images import render_exemplars

    cfg = config_from_args(args)
    roughness = list(cfg.roughness)
    t0 = time.perf_counter()
    images, shot, env = render_exemplars(args.env, cfg)
    kind = "point" if cfg.point_light else "env"
    renderer = {
        "name": cfg.renderer,
        "spp": cfg.spp,
        "seed": cfg.seed,
        "variant": mi.variant(),
        "mode": "path-traced (direct)" if cfg.renderer == "mitsuba" else "quadrature",
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
                "resolution": [cfg.res, cfg.res],
            }
        )
    else:
        say(
            f"wrote {out}: {len(roughness)} {kind} exemplars at {cfg.res}x{cfg.res} ({cfg.renderer}, "
            f"{cfg.spp} spp, {seconds:.1f} s)"
        )
    return 0
