"""Render a Mitsuba XML scene (which may use the ebr plugins) to an EXR image.

  ebr render SCENE.xml --out IMG.exr [--spp N] [--seed S] [-D key=value ...] [--json]

SCENE.xml is a file, or the bare name of a bundled scene (default, exemplar, near_flash,
near_noflash, far_flash, far_noflash). Scene parameters (``$name`` in the XML) are set with
``-D name=value`` (repeatable); a parameter the scene does not declare is an error. ``--spp``
overrides the sample count of the scene's sampler. The image is written atomically as linear
RGB float32 EXR. ``--json`` prints {"out", "scene", "seconds", "spp", "resolution", "variant"}.
``--spp`` and ``--seed`` are the fields of :class:`RenderConfig` (flags, defaults and help generated
from its metadata); a bad value is one line naming the flag (exit 2).

Bundled scenes (camera, flash and sample as docs/conventions.md, "Geometry and pixel grid"; direct
integrator, box filter) and their parameters, defaults in brackets:

  near_flash, default   near shot with flash: spp [64], res [256], diffuse0 [0.60,0.42,0.25],
                        diffuse1 [0.12,0.09,0.07], checks [4] (checkerboard periods),
                        specular [0.04], roughness [0.35], flash_intensity [10 W/sr],
                        env [default_env.json, sun + sky SGs], env_scale [1]
  near_noflash          as near_flash without the flash (no flash_intensity)
  far_flash             camera and flash at z = 10, flash_intensity [171.57] (same irradiance)
  far_noflash           as far_flash without the flash
  exemplar              uniform exemplar material (diffuse 0.1, specular 0.2), flash off:
                        spp, res, roughness [0.5], env, env_scale
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..typedconfig import add_flags, config, from_args, option
from ._common import emit_json, say

NAME = "render"
HELP = "render a Mitsuba XML scene to an EXR image"

_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@config(error=InputError, cli=True)
class RenderConfig:
    """How ``ebr render`` renders a scene (a bad value is an :class:`~ebr_mitsuba.errors.InputError`
    naming the flag)."""

    spp: int | None = option(
        None, "samples per pixel (none: the scene's sampler setting)", minimum=1, shown="the scene's sampler"
    )
    seed: int = option(0, "sampler seed", minimum=0, maximum=2**32 - 1, metavar="S")


#: The fields ``ebr render`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
RENDER_FLAGS = ("spp", "seed")


def add_arguments(parser) -> None:
    parser.add_argument("scene", metavar="SCENE.xml", help="Mitsuba XML scene file or bundled scene name")
    parser.add_argument("--out", required=True, metavar="IMG.exr", help="output image (.exr)")
    # The RenderConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(parser, RenderConfig, RENDER_FLAGS)
    parser.add_argument(
        "-D",
        dest="defines",
        action="append",
        default=[],
        metavar="key=value",
        help="set the scene parameter $key (repeatable)",
    )
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def parse_defines(defines: list[str]) -> dict[str, str]:
    """``["key=value", ...]`` → ``{key: value}``; malformed entries are an InputError."""
    params: dict[str, str] = {}
    for item in defines:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not _KEY.match(key):
            raise InputError(
                f"-D {item!r}: write -D name=value with a parameter name of letters, digits and underscores"
            )
        if key in params:
            raise InputError(f"-D {key}: given twice; give each parameter once")
        params[key] = value.strip()
    return params


def run(args) -> int:
    import mitsuba as mi

    from ..imageio import write_exr
    from ..scene import load_scene, resolve_scene_path

    out = Path(args.out)
    if out.suffix.lower() != ".exr":
        raise InputError(f"{out}: the output must be an .exr file")
    if out.is_dir():
        raise InputError(f"{out}: is a directory; give an image file name")
    cfg = from_args(RenderConfig, args, RENDER_FLAGS)
    params = parse_defines(args.defines)
    path = resolve_scene_path(args.scene)
    t0 = time.perf_counter()
    scene = load_scene(path, **params)
    sensor = scene.sensors()[0]
    spp = cfg.spp if cfg.spp is not None else int(sensor.sampler().sample_count())
    image = np.array(mi.render(scene, spp=spp, seed=cfg.seed), dtype=np.float32)
    image = image.reshape(image.shape[0], image.shape[1], -1)
    if image.shape[-1] > 3:
        image = image[..., :3]
    write_exr(out, image)  # atomic
    seconds = time.perf_counter() - t0
    summary = {
        "out": str(out),
        "scene": str(path),
        "seconds": round(seconds, 3),
        "spp": spp,
        "resolution": [int(image.shape[0]), int(image.shape[1])],
        "variant": mi.variant(),
    }
    if args.json:
        emit_json(summary)
    else:
        say(f"wrote {out} ({image.shape[1]}x{image.shape[0]}, {spp} spp, {seconds:.2f} s)")
    return 0
