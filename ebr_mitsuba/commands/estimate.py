"""Estimate SVBRDF maps and the lighting from a flash/no-flash photo pair (or a flash-only photo),
or SVBRDF maps from five photos lit by five known point lights.

  ebr estimate --flash F [--noflash NF] [--far-flash F2 --far-noflash NF2] --out DIR
               [--checkpoint C] [--refine-steps N] [--refine-lobes] [--json] [options]
  ebr estimate --lights L0 L1 L2 L3 L4 --out DIR [--checkpoint C] [--json]
  ebr estimate --lights CAPTURE_DIR --out DIR [--checkpoint C] [--json]
  ebr estimate --views CAPTURE_DIR --out DIR --checkpoint C [--json]

Inputs: EXR (linear) or PNG/JPEG (sRGB, 8/16 bit), all of one size, the sample filling the frame
(see docs/capture-guide.md). Without --noflash the capture is flash-only (a dark room): no
lighting is estimated. DIR receives maps/ (EXR + PNG), env.json with lat-long and hemisphere
pictures of the SGs, re-renders of the shots and residuals, renders under novel lights,
estimate.json and a self-contained report.html. DIR appears complete or not at all; an earlier
estimate directory there is replaced, anything else is refused. One run per DIR: a second
`ebr estimate` into a DIR in use is refused (exit 2) instead of replacing the first one's output.

Five lights (--lights): one fixed camera framing the sample as for --flash, five photos each lit
by one point light at a known position (no other light), estimated by a dual-loss model
(the shipped one, docs/fivelight.md, or --checkpoint of `ebr train` with kind = "dualloss"). The light
positions (and intensities) come from the capture.json of `ebr capture --setup five-light` in
CAPTURE_DIR or beside L0; without one, L0..L4 (or CAPTURE_DIR/light0..light4) are at the
positions of that setup. DIR receives maps/, inputs/, rerender/ and residual/ per light, novel/,
estimate.json and report.html (no lighting files: the lights are known). Exit 2 for another count
than five, photos of different sizes, a missing light position, an unreadable file. Of the
options below only the common ones apply (--checkpoint, --flash-intensity as each light's
intensity, --saturation-level, --max-size, --json); the others are refused.

Multi-view (--views): the directory of `ebr capture --setup multi-view` (the 3x3 grid of cameras
each with its flash: view{a}{b}_flash for row a, column b; the centre camera's noflash view; its
capture.json with every view's file, camera, field of view and flash; docs/mair.md,
"Estimating"), estimated by a MAIR model (the shipped ebr_mitsuba/models/mair_small.pt unless
--checkpoint names another, `ebr train` with kind = "mair"). Each view is rectified onto the sample
grid; DIR receives maps/, lighting/ (the per-pixel SG lobes as EXR, irradiance and hemisphere
pictures), env.json (the environment for insertion: the centre pixel's lighting averaged over
azimuth, one zenith lobe; --no-azimuthal-env: its lobes as predicted) with its pictures, inputs/
(rectified), weights/ (in frame), rerender/ and residual/ per view, novel/, estimate.json and
report.html. Exit 2 for a missing view or capture.json, another count of flash views than 9,
views of different sizes, a checkpoint of another kind, --views with --flash or --lights. Of the
options below only the common ones apply.

The options, their defaults (in brackets) and ranges are generated from the fields of
EstimateConfig (ebr_mitsuba.estimate.pipeline), ShadingNormalsConfig
(ebr_mitsuba.estimate.shading_normals: --normal-gain, --relief-gain, how much of the relief read
off the photos the normal map keeps; docs/bench/normals.md measures their error against the
normals' spread), RefineConfig (ebr_mitsuba.estimate.refine: the --refine-* flags and
--render-mode), FiveLightConfig (ebr_mitsuba.estimate.fivelight: --lights) and MultiViewConfig
(ebr_mitsuba.estimate.multiview: --views), listed below by the mode they apply to;
docs/config.md has their tables.

Sizes: the lighting is estimated once at the model's grid (256x256 for the shipped model); the maps
at the photos' resolution up to --max-size. Photos smaller than 32 pixels on the shorter side are
refused (exit 2). The refinement runs coarse to fine (from at most 256x256 up to the working size).

--json prints the summary (estimate.json: timings per stage, re-render errors before/after
refinement, warnings, files) on stdout; progress goes to stderr. Exit 2 on bad input.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from pathlib import Path

from ..errors import InputError
from ..estimate.fivelight import FIVELIGHT_FLAGS, FiveLightConfig
from ..estimate.multiview import MULTIVIEW_FLAGS, MultiViewConfig
from ..estimate.pipeline import ESTIMATE_FLAGS, EstimateConfig
from ..estimate.refine import REFINE_FLAGS, RefineConfig
from ..estimate.shading_normals import SHADING_FLAGS, ShadingNormalsConfig
from ..typedconfig import add_flags, flag_dest, flag_name, flag_value, from_args
from ._common import emit_json, progress, say

NAME = "estimate"
HELP = "estimate SVBRDF maps and lighting from flash/no-flash photos, five lights or 3x3 views"

# The flags, their defaults and help come from the configs' field metadata (typedconfig.add_flags);
# a FiveLightConfig field whose flag is an EstimateConfig field's flag shares that option.
_LIGHT_FLAG_NAMES = {flag_name(FiveLightConfig, n) for n in FIVELIGHT_FLAGS}
_PAIR_FLAG_NAMES = {flag_name(EstimateConfig, n) for n in ESTIMATE_FLAGS}
COMMON_FLAGS = tuple(n for n in ESTIMATE_FLAGS if flag_name(EstimateConfig, n) in _LIGHT_FLAG_NAMES)
PAIR_FLAGS = tuple(n for n in ESTIMATE_FLAGS if n not in COMMON_FLAGS)  # flash/no-flash alone
LIGHTS_ONLY_FLAGS = tuple(n for n in FIVELIGHT_FLAGS if flag_name(FiveLightConfig, n) not in _PAIR_FLAG_NAMES)
NOT_FOR_LIGHTS = (  # (config, field): refused with --lights
    *((EstimateConfig, n) for n in PAIR_FLAGS),
    *((RefineConfig, n) for n in REFINE_FLAGS),
    *((ShadingNormalsConfig, n) for n in SHADING_FLAGS),
)
_SHARED_FLAG_NAMES = _PAIR_FLAG_NAMES | _LIGHT_FLAG_NAMES
VIEWS_ONLY_FLAGS = tuple(
    n for n in MULTIVIEW_FLAGS if flag_name(MultiViewConfig, n) not in _SHARED_FLAG_NAMES
)
_VIEW_FLAG_NAMES = {flag_name(MultiViewConfig, n) for n in MULTIVIEW_FLAGS}
NOT_FOR_VIEWS = (  # (config, field): refused with --views
    *((EstimateConfig, n) for n in ESTIMATE_FLAGS if flag_name(EstimateConfig, n) not in _VIEW_FLAG_NAMES),
    *((RefineConfig, n) for n in REFINE_FLAGS),
    *((ShadingNormalsConfig, n) for n in SHADING_FLAGS),
    *(
        (FiveLightConfig, n)
        for n in FIVELIGHT_FLAGS
        if flag_name(FiveLightConfig, n) not in _VIEW_FLAG_NAMES | _PAIR_FLAG_NAMES
    ),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    # Values are read as text and checked by from_args: a bad one is one line naming the flag, exit 2.
    add_flags(parser, EstimateConfig, COMMON_FLAGS)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    pair = parser.add_argument_group("flash/no-flash capture (EstimateConfig)")
    add_flags(pair, EstimateConfig, PAIR_FLAGS)
    shading = parser.add_argument_group(
        "shading normals (ShadingNormalsConfig; flash/no-flash only; gains against error: "
        "docs/bench/normals.md)"
    )
    add_flags(shading, ShadingNormalsConfig, SHADING_FLAGS)
    add_refine_arguments(
        parser.add_argument_group("test-time refinement (RefineConfig; flash/no-flash only)")
    )
    lights = parser.add_argument_group("five known lights (FiveLightConfig; with the options above)")
    add_flags(lights, FiveLightConfig, LIGHTS_ONLY_FLAGS)
    views = parser.add_argument_group("3x3 views, MAIR (MultiViewConfig; with the options above)")
    add_flags(views, MultiViewConfig, VIEWS_ONLY_FLAGS)


def add_refine_arguments(parser) -> None:
    """The refinement options: the :data:`~ebr_mitsuba.estimate.refine.REFINE_FLAGS` of
    :class:`~ebr_mitsuba.estimate.refine.RefineConfig`."""
    add_flags(parser, RefineConfig, REFINE_FLAGS)


def refine_config(args) -> RefineConfig:
    """The :class:`~ebr_mitsuba.estimate.refine.RefineConfig` of the parsed refinement flags."""
    return from_args(RefineConfig, args, REFINE_FLAGS)


def estimate_config(args) -> EstimateConfig:
    """The :class:`~ebr_mitsuba.estimate.pipeline.EstimateConfig` of the parsed flags (every value
    checked; an :class:`InputError` naming the flag)."""
    shading = from_args(ShadingNormalsConfig, args, SHADING_FLAGS)
    return from_args(EstimateConfig, args, ESTIMATE_FLAGS, refine=refine_config(args), shading=shading)


def fivelight_config(args) -> FiveLightConfig:
    """The :class:`~ebr_mitsuba.estimate.fivelight.FiveLightConfig` of the parsed flags."""
    return from_args(FiveLightConfig, args, FIVELIGHT_FLAGS)


def check_flags(cfg: EstimateConfig) -> None:
    """Conflicting options, refused before anything is read (each value was checked already)."""
    from ..estimate.inputs import check_shot_flags

    check_shot_flags(cfg.flash, cfg.noflash, cfg.far_flash, cfg.far_noflash, cfg.exposure_ratio)
    if cfg.refine.lobes and cfg.refine.steps == 0:
        raise InputError("--refine-lobes needs --refine-steps N > 0")
    if cfg.refine.lobes and cfg.noflash is None:
        raise InputError("--refine-lobes needs --noflash: a flash-only capture has no lighting to refine")
    if cfg.refine.seconds is not None and cfg.refine.steps == 0:
        raise InputError("--refine-seconds needs --refine-steps N > 0")
    if cfg.checkpoint is not None and not Path(cfg.checkpoint).is_file():
        raise InputError(
            f"--checkpoint {cfg.checkpoint}: no such file; give a model checkpoint or omit it "
            f"for the shipped model"
        )
    out = Path(cfg.out).resolve()
    for p in (cfg.flash, cfg.noflash, cfg.far_flash, cfg.far_noflash):
        if p is not None and out in Path(p).resolve().parents:
            raise InputError(f"--out {cfg.out} contains the input {p}; choose another --out")


def _changed_flag(cls, args, name: str) -> str | None:
    """The flag as given (``--no-x`` for a switch turned off) when the flag of field ``name`` of
    ``cls`` holds another value than the field's default; else None."""
    if getattr(args, flag_dest(cls, name)) is None:
        return None
    f = next(f for f in dataclasses.fields(cls) if f.name == name)
    default = None if f.default is dataclasses.MISSING else f.default
    value = flag_value(cls, args, name)
    if value == default:
        return None
    flag = flag_name(cls, name)
    return "--no-" + flag[2:] if value is False and default is True else flag


def _refuse_changed(args, fields, capture: str) -> None:
    """An :class:`InputError` for the first of ``fields`` ((config class, field name) pairs) whose
    flag was given another value than its default: it does not apply to ``capture``."""
    for cls, name in fields:
        flag = _changed_flag(cls, args, name)
        if flag is not None:
            raise InputError(f"{flag} does not apply to {capture}; drop it")


def check_light_flags(args) -> FiveLightConfig:
    """``--lights``: the options of the flash/no-flash estimate alone refused, the others checked;
    the :class:`~ebr_mitsuba.estimate.fivelight.FiveLightConfig`."""
    _refuse_changed(args, NOT_FOR_LIGHTS, "--lights (five known point lights)")
    cfg = fivelight_config(args)
    out = Path(cfg.out).resolve()
    for p in cfg.lights:
        if out == Path(p).resolve() or out in Path(p).resolve().parents:
            raise InputError(f"--out {cfg.out} contains the input {p}; choose another --out")
    return cfg


def multiview_config(args) -> MultiViewConfig:
    """The :class:`~ebr_mitsuba.estimate.multiview.MultiViewConfig` of the parsed flags."""
    return from_args(MultiViewConfig, args, MULTIVIEW_FLAGS)


def check_view_flags(args) -> MultiViewConfig:
    """``--views``: the options of the other estimates refused (--flash, --lights and theirs), the
    others checked; the :class:`~ebr_mitsuba.estimate.multiview.MultiViewConfig`."""
    if args.lights is not None:
        raise InputError("--views and --lights are two captures; give one of them")
    if args.flash is not None:
        raise InputError("--views and --flash are two captures; give one of them")
    _refuse_changed(args, NOT_FOR_VIEWS, "--views (the 3x3 multi-view capture)")
    cfg = multiview_config(args)
    out, views = Path(cfg.out).resolve(), Path(cfg.views).resolve()
    if out == views or out in views.parents or views in out.parents:
        raise InputError(f"--out {cfg.out} and --views {cfg.views} overlap; choose another --out")
    return cfg


def _write(args, out: str, estimate: Callable[[], dict]) -> int:
    """``estimate()`` writing ``out`` (one writer per --out: a second one is refused); its summary
    printed (JSON with --json, else :func:`print_summary`); exit code 0."""
    from ..fsutil import output_lock

    with output_lock(out, "ebr estimate"):
        summary = estimate()
    if args.json:
        emit_json(summary)
    else:
        print_summary(summary)
    return 0


def run_views(args) -> int:
    """``ebr estimate --views``: :func:`ebr_mitsuba.estimate.multiview.run_multiview`."""
    from ..estimate.multiview import run_multiview

    cfg = check_view_flags(args)
    return _write(args, cfg.out, lambda: run_multiview(cfg, log=say, bar=progress))


def run_lights(args) -> int:
    """``ebr estimate --lights``: :func:`ebr_mitsuba.estimate.fivelight.run_fivelight`."""
    from ..estimate.fivelight import run_fivelight

    cfg = check_light_flags(args)
    return _write(args, cfg.out, lambda: run_fivelight(cfg, log=say))


def run(args) -> int:
    from ..estimate.pipeline import run_estimate

    if args.views is not None:
        return run_views(args)
    if args.lights is not None:
        return run_lights(args)
    if args.flash is None:
        raise InputError(
            "give --flash F (a flash/no-flash capture), --lights L0 … L4 (five known lights) or "
            "--views DIR (the 3x3 multi-view capture)"
        )
    cfg = estimate_config(args)
    check_flags(cfg)
    return _write(args, cfg.out, lambda: run_estimate(cfg, log=say, bar=progress))


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
    lighting = {
        "five-light": "five known lights",
        "multi-view": f"{summary['lobes']} SG lobes per pixel",
    }.get(summary["capture"], f"{summary['lobes']} SG lobes")
    say(
        f"wrote {summary['out']} ({summary['resolution']}x{summary['resolution']}, {lighting}, "
        f"{summary['total_seconds']:.1f} s); report: {Path(summary['out']) / 'report.html'}"
    )
