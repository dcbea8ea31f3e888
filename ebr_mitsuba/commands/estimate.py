"""Estimate SVBRDF maps and the lighting from a flash/no-flash photo pair (or a flash-only photo),
or SVBRDF maps from five photos lit by five known point lights.

  ebr estimate --flash F [--noflash NF] [--far-flash F2 --far-noflash NF2] --out DIR
               [--checkpoint C] [--refine-steps N] [--refine-lobes] [--json] [options]
  ebr estimate --lights L0 L1 L2 L3 L4 --out DIR [--checkpoint C] [--json]
  ebr estimate --lights CAPTURE_DIR --out DIR [--checkpoint C] [--json]

Inputs: EXR (linear) or PNG/JPEG (sRGB, 8/16 bit), all of one size, the sample filling the frame
(see docs/capture-guide.md). Without --noflash the capture is flash-only (a dark room): no
lighting is estimated. DIR receives maps/ (EXR + PNG), env.json with lat-long and hemisphere
pictures of the SGs, re-renders of the shots and residuals, renders under novel lights,
estimate.json and a self-contained report.html. DIR appears complete or not at all; an earlier
estimate directory there is replaced, anything else is refused. One run per DIR: a second
`ebr estimate` into a DIR in use is refused (exit 2) instead of replacing the first one's output.

Five lights (--lights): one fixed camera framing the sample as for --flash, five photos each lit
by one point light at a known position (no other light), estimated by a dual-loss model
(`ebr train` with kind = "dualloss"; --checkpoint is needed while none is shipped). The light
positions (and intensities) come from the capture.json of `ebr capture --setup five-light` in
CAPTURE_DIR or beside L0; without one, L0..L4 (or CAPTURE_DIR/light0..light4) are at the
positions of that setup. DIR receives maps/, inputs/, rerender/ and residual/ per light, novel/,
estimate.json and report.html (no lighting files: the lights are known). Exit 2 for another count
than five, photos of different sizes, a missing light position, an unreadable file. Of the
options below only --checkpoint, --flash-intensity (each light's intensity), --saturation-level,
--max-size and --json apply.

Options (defaults in brackets):

  --checkpoint C         model checkpoint [the shipped model]
  --refine-steps N       test-time refinement steps against the photos [0]
  --refine-lobes         refine the SG lobes too (needs --noflash)
  --refine-lr X          refinement learning rate [0.02]
  --refine-seconds S     time budget of the refinement: it stops after S seconds with a note [none]
  --refine-basis K       specular and roughness as K basis materials mixed per pixel (0: per pixel) [0]
  --render-mode M        environment term of the re-renders and refinement: sg | quadrature [sg]
  --exposure-ratio R     no-flash exposure / flash exposure when the files carry no EXIF [EXIF or 1]
  --fov DEG              horizontal field of view of the photos [45]
  --flash-intensity I    flash intensity in W/sr at the flash shot's exposure [capture.json or fitted]
  --max-shift F          largest flash/no-flash shift accepted, as a fraction of the width [0.02]
  --saturation-level V   EXR value at which pixels count as clipped [none]
  --max-size N           largest working size: larger photos are downsampled to it, with a warning [2048]
  --no-flash-fit         keep the network's diffuse, specular and roughness (no flash-profile fit)

Sizes: the lighting is estimated once at the model's grid (64x64 for the shipped model); the maps
at the photos' resolution up to --max-size. Photos smaller than 32 pixels on the shorter side are
refused (exit 2). The refinement runs coarse to fine (from at most 256x256 up to the working size).

--json prints the summary (estimate.json: timings per stage, re-render errors before/after
refinement, warnings, files) on stdout; progress goes to stderr. Exit 2 on bad input.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..estimate.inputs import DEFAULT_FOV, DEFAULT_MAX_SHIFT
from ..estimate.refine import RefineConfig
from ..estimate.resample import DEFAULT_MAX_SIZE
from ._common import emit_json, progress, say

NAME = "estimate"
HELP = "estimate SVBRDF maps and lighting from flash/no-flash photos"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--flash", metavar="F", help="photo with the flash (EXR, PNG, JPEG); or --lights")
    parser.add_argument("--noflash", metavar="NF", help="photo without the flash (omit: flash-only capture)")
    parser.add_argument("--far-flash", metavar="F2", help="far shot with the flash (optional)")
    parser.add_argument("--far-noflash", metavar="NF2", help="far shot without the flash")
    parser.add_argument(
        "--lights",
        nargs="+",
        metavar="L",
        help="five photos lit by five known point lights (light0..light4), or one directory of "
        "'ebr capture --setup five-light'; instead of --flash",
    )
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    parser.add_argument("--checkpoint", metavar="C", help="model checkpoint (default: the shipped model)")
    add_refine_arguments(parser)
    parser.add_argument(
        "--exposure-ratio",
        type=float,
        metavar="R",
        help="no-flash exposure / flash exposure (default: from EXIF, else 1)",
    )
    parser.add_argument(
        "--fov", type=float, default=DEFAULT_FOV, help=f"horizontal field of view [{DEFAULT_FOV:g}]"
    )
    parser.add_argument(
        "--flash-intensity",
        type=float,
        metavar="I",
        help="flash intensity [W/sr] (default: capture.json beside --flash, else fitted)",
    )
    parser.add_argument(
        "--max-shift",
        type=float,
        default=DEFAULT_MAX_SHIFT,
        help=f"largest accepted shift between the shots, fraction of the width [{DEFAULT_MAX_SHIFT}]",
    )
    parser.add_argument(
        "--saturation-level", type=float, metavar="V", help="EXR clipping level (default none)"
    )
    parser.add_argument(
        "--max-size",
        type=int,
        default=DEFAULT_MAX_SIZE,
        metavar="N",
        help=f"largest working size; larger photos are downsampled to it (warning) [{DEFAULT_MAX_SIZE}]",
    )
    parser.add_argument(
        "--no-flash-fit",
        dest="flash_fit",
        action="store_false",
        help="keep the network's diffuse, specular and roughness maps (no flash-profile fit)",
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")


def add_refine_arguments(parser: argparse.ArgumentParser) -> None:
    """The refinement options (shared with ``ebr demo`` and ``ebr gallery``)."""
    d = RefineConfig()
    parser.add_argument(
        "--refine-steps",
        type=int,
        default=d.steps,
        metavar="N",
        help=f"test-time refinement steps [{d.steps}]",
    )
    parser.add_argument("--refine-lobes", action="store_true", help="refine the SG lobes too")
    parser.add_argument("--refine-lr", type=float, default=d.lr, help=f"refinement learning rate [{d.lr}]")
    parser.add_argument(
        "--refine-seconds",
        type=float,
        default=d.seconds,
        metavar="S",
        help="time budget of the refinement in seconds; it stops there with a note [none]",
    )
    parser.add_argument(
        "--refine-basis",
        type=int,
        default=d.basis,
        metavar="K",
        help=f"specular and roughness as K basis materials with per-pixel weights (0: per pixel) [{d.basis}]",
    )
    parser.add_argument(
        "--render-mode", default=d.mode, metavar="M", help=f"environment term: sg or quadrature [{d.mode}]"
    )


def refine_config(args) -> RefineConfig:
    return RefineConfig(
        steps=args.refine_steps,
        lobes=args.refine_lobes,
        lr=args.refine_lr,
        mode=args.render_mode,
        seconds=args.refine_seconds,
        basis=args.refine_basis,
    )


def check_flags(args) -> None:
    """Conflicting or malformed options, refused before anything is read."""
    from ..errors import InputError
    from ..estimate.inputs import check_shot_flags

    check_shot_flags(args.flash, args.noflash, args.far_flash, args.far_noflash, args.exposure_ratio)
    if args.refine_lobes and args.refine_steps == 0:
        raise InputError("--refine-lobes needs --refine-steps N > 0")
    if args.refine_lobes and args.noflash is None:
        raise InputError("--refine-lobes needs --noflash: a flash-only capture has no lighting to refine")
    if args.refine_seconds is not None and args.refine_steps == 0:
        raise InputError("--refine-seconds needs --refine-steps N > 0")
    if args.flash_intensity is not None and not (
        args.flash_intensity > 0 and args.flash_intensity < float("inf")
    ):
        raise InputError(f"--flash-intensity {args.flash_intensity}: give a finite value > 0")
    if args.checkpoint is not None and not Path(args.checkpoint).is_file():
        raise InputError(
            f"--checkpoint {args.checkpoint}: no such file; give a model checkpoint or omit it "
            f"for the shipped model"
        )
    out = Path(args.out).resolve()
    for p in (args.flash, args.noflash, args.far_flash, args.far_noflash):
        if p is not None and out in Path(p).resolve().parents:
            raise InputError(f"--out {args.out} contains the input {p}; choose another --out")


FLASH_ONLY_OPTIONS = (  # (attribute, flag): options of the flash/no-flash estimate alone
    ("flash", "--flash"),
    ("noflash", "--noflash"),
    ("far_flash", "--far-flash"),
    ("far_noflash", "--far-noflash"),
    ("exposure_ratio", "--exposure-ratio"),
    ("refine_lobes", "--refine-lobes"),
    ("refine_seconds", "--refine-seconds"),
)


def check_light_flags(args) -> None:
    """``--lights``: the options that do not apply to it refused, the others checked."""
    from ..errors import InputError

    for attr, flag in FLASH_ONLY_OPTIONS:
        if getattr(args, attr) not in (None, False):
            raise InputError(f"{flag} does not apply to --lights (five known point lights); drop it")
    d = RefineConfig()
    for attr, flag, default in (
        ("refine_steps", "--refine-steps", d.steps),
        ("refine_lr", "--refine-lr", d.lr),
        ("render_mode", "--render-mode", d.mode),
        ("fov", "--fov", DEFAULT_FOV),
        ("max_shift", "--max-shift", DEFAULT_MAX_SHIFT),
    ):
        if getattr(args, attr) != default:
            raise InputError(f"{flag} does not apply to --lights (five known point lights); drop it")
    if args.flash_intensity is not None and not (
        args.flash_intensity > 0 and args.flash_intensity < float("inf")
    ):
        raise InputError(f"--flash-intensity {args.flash_intensity}: give a finite value > 0")
    out = Path(args.out).resolve()
    for p in args.lights:
        if out == Path(p).resolve() or out in Path(p).resolve().parents:
            raise InputError(f"--out {args.out} contains the input {p}; choose another --out")


def run_lights(args) -> int:
    """``ebr estimate --lights``: :func:`ebr_mitsuba.estimate.fivelight.run_fivelight`."""
    from ..estimate.fivelight import FiveLightConfig, run_fivelight
    from ..fsutil import output_lock

    check_light_flags(args)
    cfg = FiveLightConfig(
        lights=tuple(args.lights),
        out=args.out,
        checkpoint=args.checkpoint,
        light_intensity=args.flash_intensity,
        saturation_level=args.saturation_level,
        max_size=args.max_size,
    )
    with output_lock(args.out, "ebr estimate"):  # one writer per --out: a second one is refused
        summary = run_fivelight(cfg, log=say)
    if args.json:
        emit_json(summary)
    else:
        print_summary(summary)
    return 0


def run(args) -> int:
    from ..estimate.pipeline import EstimateConfig, run_estimate
    from ..fsutil import output_lock

    if args.lights is not None:
        return run_lights(args)
    if args.flash is None:
        from ..errors import InputError

        raise InputError("give --flash F (a flash/no-flash capture) or --lights L0 … L4 (five known lights)")
    check_flags(args)
    cfg = EstimateConfig(
        flash=args.flash,
        noflash=args.noflash,
        far_flash=args.far_flash,
        far_noflash=args.far_noflash,
        out=args.out,
        checkpoint=args.checkpoint,
        refine=refine_config(args),
        exposure_ratio=args.exposure_ratio,
        fov=args.fov,
        max_shift=args.max_shift,
        saturation_level=args.saturation_level,
        flash_intensity=args.flash_intensity,
        max_size=args.max_size,
        flash_fit=args.flash_fit,
    )
    with output_lock(args.out, "ebr estimate"):  # one writer per --out: a second one is refused
        summary = run_estimate(cfg, log=say, bar=progress)
    if args.json:
        emit_json(summary)
    else:
        print_summary(summary)
    return 0


def print_summary(summary: dict) -> None:
    """The human summary on stderr."""
    err = summary["rerender_error"]
    net = err["network"]["mean"]
    line = f"re-render RMSE {net['rmse']:.4g} (relative {net['rel_rmse']:.3f})"
    if err["refined"]:
        ref = err["refined"]["mean"]
        line += (
            f" -> {ref['rmse']:.4g} (relative {ref['rel_rmse']:.3f}) after "
            f"{summary['refine']['steps']} refinement steps ({summary['refine']['seconds']:.1f} s)"
        )
        if summary["refine"].get("note"):  # the loss rose: the best iterate was kept
            line += f"; {summary['refine']['note']}"
    say(line)
    lighting = "five known lights" if summary["capture"] == "five-light" else f"{summary['lobes']} SG lobes"
    say(
        f"wrote {summary['out']} ({summary['resolution']}x{summary['resolution']}, {lighting}, "
        f"{summary['total_seconds']:.1f} s); report: {Path(summary['out']) / 'report.html'}"
    )
