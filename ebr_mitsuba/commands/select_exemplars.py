"""Choose the exemplar roughness values for a photo (adaptive exemplar selection, step 3 of
docs/conventions.md, "Pipeline").

  ebr select-exemplars --env env.json --image noflash.exr [--json]
  ebr select-exemplars --image flash_only.exr --point-light [--json]

Searches the roughness of the uniform exemplar material (diffuse 0.1, specular 0.2) whose
render is structurally closest to the image: a coarse grid, then a finer one around the best
value, scored by SSIM after the best non-negative diffuse + specular gains
(:mod:`ebr_mitsuba.extract.select` documents the score). Prints the selection: the adaptive
choice followed by the two fixed anchors (low, high).

==================  ===========================  ==================================================
option              default                      meaning
==================  ===========================  ==================================================
``--env``           (required without            SG environment the exemplars are lit by: an
                    ``--point-light``)           ``env.json`` (e.g. from ``ebr extract-sg``) or
                                                 ``procedural:SEED``
``--image``         (required)                   the no-flash photo (environment exemplars) or the
                                                 flash-only image (``--point-light``); linear EXR/
                                                 HDR, or PNG/JPEG (sRGB-decoded), RGB
``--point-light``   off                          select point-light exemplars (near flash only)
``--coarse``        0.05,0.2,0.35,0.5,0.65,0.8,  coarse roughness grid
                    0.95
``--anchors``       0.1,0.9                      the two fixed exemplars (low, high)
``--mode``          quadrature                   fast-renderer environment term (``sg`` is faster,
                                                 biased for rough exemplars)
``--spp``           256                          quadrature directions per pixel
``--out``           none                         also write the selected exemplars as
                                                 ``DIR/exemplar_<k>_r<r>.exr`` and ``DIR/selection.json``
``--json``          off                          print ``{"roughness": [...], "scores": {r: ssim}}``
==================  ===========================  ==================================================

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


def _floats(text: str, what: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise InputError(f"{what} {text!r}: give comma-separated numbers, e.g. 0.1,0.9") from None
    if not values:
        raise InputError(f"{what}: give at least one value")
    return values


def add_arguments(p) -> None:
    from ..extract.select import SelectConfig

    d = SelectConfig()
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
    p.add_argument(
        "--coarse",
        default=",".join(f"{r:g}" for r in d.coarse),
        help="coarse roughness grid (default %(default)s)",
    )
    p.add_argument(
        "--anchors",
        default=",".join(f"{r:g}" for r in d.anchors),
        help="fixed low,high exemplars (default %(default)s)",
    )
    p.add_argument(
        "--mode",
        choices=("sg", "quadrature"),
        default=d.env_mode,
        help="environment term of the exemplar renders (default %(default)s)",
    )
    p.add_argument("--spp", type=int, default=d.env_spp, help="quadrature directions (default %(default)s)")
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
    from ..errors import ConfigError
    from ..extract.select import SelectConfig, select_exemplars
    from ..fsutil import atomic_dir
    from ..imageio import read_image, write_exr

    if not args.image.is_file():
        raise InputError(f"{args.image}: no such image; give the no-flash (or flash-only) photo")
    image = read_image(args.image, expect_channels=3)
    env = _load_env(args.env, args.point_light)
    try:
        config = SelectConfig(
            coarse=_floats(args.coarse, "--coarse"),
            anchors=_floats(args.anchors, "--anchors"),
            env_mode=args.mode,
            env_spp=args.spp,
        )
    except ConfigError as exc:
        raise InputError(str(exc).replace("SelectConfig:", "select-exemplars:")) from None
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
