"""Choose the exemplar roughness values for a photo (adaptive exemplar selection, step 3 of
docs/conventions.md, "Pipeline").

  ebr select-exemplars --env env.json --image noflash.exr [--json]
  ebr select-exemplars --image flash_only.exr --point-light [--json]

Searches the roughness of the uniform exemplar material (diffuse 0.1, specular 0.2) whose
render is structurally closest to the image: a coarse grid, then a finer one around the best
value, scored by SSIM after the best non-negative diffuse + specular gains
(:mod:`ebr_mitsuba.exemplar.select` documents the score). Prints the selection: the adaptive
choice followed by the two fixed anchors (low, high).

Options: ``--env`` (an SG environment: ``env.json``, e.g. from ``ebr extract-sg``, or
``procedural:SEED``; required without ``--point-light``), ``--image`` (the no-flash photo, or the
flash-only image with ``--point-light``; linear EXR/HDR, or PNG/JPEG sRGB-decoded, RGB),
``--point-light``, ``--out DIR`` (also write ``DIR/exemplar_<k>_r<r>.exr`` and
``DIR/selection.json``), ``--json`` (print ``{"roughness": [...], "scores": {r: ssim}}``); and
``--coarse``, ``--anchors``, ``--mode``, ``--spp``, the fields of
:class:`ebr_mitsuba.exemplar.select.SelectConfig` (flags, defaults and help generated from its
metadata).

Exit status 2 (one line on stderr) on bad input: a missing or unreadable image, a channel count
other than 3, NaN/Inf pixels, a black image, a missing or malformed environment.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import InputError
from ._common import emit_json, say

NAME = "select-exemplars"
HELP = "choose exemplar roughness values for a photo by SSIM (coarse-to-fine)"


FLAGS = ("coarse", "anchors", "env_mode", "env_spp")  # the SelectConfig fields set from the command line


def add_arguments(p) -> None:
    from ..exemplar.select import SelectConfig
    from ..typedconfig import add_flags

    p.add_argument(
        "--env",
        default=None,
        metavar="ENV",
        help="SG environment: env.json or procedural:SEED (required without --point-light)",
    )
    p.add_argument(
        "--image",
        required=True,
        type=Path,
        metavar="IMG",
        help="no-flash image (or flash-only image with --point-light)",
    )
    p.add_argument("--point-light", action="store_true", help="select point-light exemplars")
    add_flags(p, SelectConfig, FLAGS)
    p.add_argument("--out", type=Path, default=None, metavar="DIR", help="also write the selected exemplars")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def _load_env(spec: str | None, point_light: bool):
    if point_light:
        return None
    if spec is None:
        raise InputError("--env is required for environment exemplars (or pass --point-light)")
    from ..sources import parse_env

    source = parse_env(spec)
    if source.kind != "sg":
        raise InputError(
            f"{spec}: select-exemplars needs an SG environment (env.json or procedural:SEED); "
            f"fit the map first with `ebr fit-env`"
        )
    return source.sg


def run(args) -> int:
    from ..exemplar.select import SelectConfig, select_exemplars
    from ..fsutil import atomic_dir
    from ..imageio import read_image, write_exr
    from ..typedconfig import from_args

    if not args.image.is_file():
        raise InputError(f"{args.image}: no such image; give the no-flash (or flash-only) photo")
    image = read_image(args.image, expect_channels=3)
    env = _load_env(args.env, args.point_light)
    config = from_args(SelectConfig, args, FLAGS)
    selection = select_exemplars(env, image, point_light=args.point_light, config=config)
    summary = selection.to_json()
    if args.out is not None:
        with atomic_dir(args.out) as tmp:
            for k, (r, im) in enumerate(zip(selection.roughness, selection.images)):
                write_exr(tmp / f"exemplar_{k}_r{r:g}.exr", im)
            record = {**summary, "point_light": bool(args.point_light), "image": str(args.image)}
            (tmp / "selection.json").write_text(json.dumps(record, indent=1) + "\n")
    if args.json:
        emit_json(summary)
    else:
        kind = "point-light" if args.point_light else "environment"
        best = selection.roughness[0]
        values = ", ".join(f"{r:g}" for r in selection.roughness)
        say(
            f"{kind} exemplars for {args.image}: roughness {values} "
            f"(adaptive {best:g}, SSIM {selection.scores[best]:.4f}; anchors "
            f"{', '.join(f'{r:g}' for r in selection.roughness[1:])})"
        )
    return 0
