"""Measure speed against error and write the tables and plots (docs/bench/ in a checkout).

  ebr bench [renderer|generate|extract-sg|estimate|sizes|models|fivelight|mair|insert|flash-fit|
             normals|roughness|tilt|refine|all]
            [--out DIR] [--quick] [--json]

Each benchmark writes ``OUT/<name>.md`` (a Markdown table with the reference it was measured
against, and the PNG plots it links) and returns its path:

* ``renderer``: Mitsuba spp sweep, the fast renderer's ``sg`` and ``quadrature`` modes at several
  spp, against a high-spp path-traced reference, per roughness and view angle;
* ``generate``: data-generation samples/s per core for the ``mitsuba`` and ``fast`` renderers, and
  the error of ``fast`` against ``mitsuba`` on the same samples;
* ``extract-sg``: the SG-extraction ablation, the exemplar roughness study and the timing;
* ``estimate``: ``ebr estimate`` at 256²–2048² with and without 200 refinement steps on a 1024²
  Mitsuba capture: time per stage, peak memory, the maps' error against resolution, a 4096² photo,
  the networks' FLOPs against the CPU's peak (writes ``estimate.md`` and three plots);
* ``sizes``: the network-size curve: the cascade trained at each size preset with one recipe
  (``configs/train_size_curve.toml``), its validation error against parameters and CPU seconds,
  and the size it picks (writes ``sizes.md``; needs ``EBR_TRAIN_DATA`` and ``EBR_VAL_DATA``;
  optionally ``EBR_SIZE_RUNS``);
* ``models``: the shipped model (its training summary) and every model and baseline (the oracle
  constant, the training-set mean maps, candidate checkpoints) on the fixed test split of the real
  assets, EBREnv Table 1 protocol, per material class, with a contact sheet (writes ``models.md``;
  needs ``EBR_SPLIT_DATA``; optionally ``EBR_SHIPPED_RUN``, ``EBR_TRAIN_DATA``, ``EBR_CANDIDATES``);
* ``fivelight``: the five-light dual-loss models, the loss ablation (dual, parameter only, rendering
  only) and the baselines on the five-light captures of the test split, beside the EBREnv model on
  the same materials (writes ``fivelight.md``; needs ``EBR_FIVELIGHT_DATA``; optionally
  ``EBR_FIVELIGHT_RUNS``, ``EBR_TRAIN_DATA``, ``EBR_SPLIT_DATA``);
* ``mair``: the multi-view MAIR models and their fusion ablation (attention, mean pooling, centre
  view only) on the 3×3 captures of the test split, their per-pixel lighting error, an object
  insertion against the truth, beside the EBREnv model on the same materials (writes
  ``mair_eval.md``; needs ``EBR_MAIR_DATA`` and ``EBR_MAIR_RUNS``; optionally ``EBR_TRAIN_DATA``,
  ``EBR_SPLIT_DATA``);
* ``insert``: ``ebr insert``'s sphere in estimates of synthetic captures (flash / no-flash, and
  multi-view by the shipped MAIR model with and without the capture's no-flash view; with
  ``EBR_SPLIT_DATA``, also test-split samples) against the truth and its noise floor, composited
  into the photo and rendered whole (writes ``insert.md``, a picture per capture and a plot);
* ``flash-fit``: the flash-profile fit's roughness on validation captures against the same fit on
  noise-free renders of their true maps, as they are and with flat normals and / or a constant
  roughness: how much of its error the single-lobe model makes (writes ``flash_fit.md``; needs
  ``EBR_FLASHFIT_DATA`` or ``EBR_VAL_DATA``);
* ``normals``: ``ebr estimate``'s shading normals on validation captures, flat, without and with the
  relief read off the flash / no-flash ratio's residual: normal RMSE, mean per-map RMSE, held-out
  re-render, the normals' spread, a picture (writes ``normals.md``; needs ``EBR_NORMALS_DATA`` or
  ``EBR_VAL_DATA``);
* ``roughness``: ``ebr estimate``'s roughness pattern on validation captures, the fitted constant
  against the map that follows the albedo, over a grid of gains: roughness RMSE, mean per-map RMSE,
  held-out re-render, pictures (writes ``roughness.md``; needs ``EBR_ROUGHNESS_DATA`` or
  ``EBR_VAL_DATA``);
* ``tilt``: ``ebr estimate``'s highlight tilt on the metal and glossy validation captures that keep
  the network's normals: the network's normals, the flat normal and the flat normal tilted to the
  clipped highlight, by normal RMSE, mean per-map RMSE and held-out re-render, a picture of the
  highlights read (writes ``tilt.md``; needs ``EBR_TILT_DATA`` or ``EBR_VAL_DATA``);
* ``refine``: test-time refinement judged by the maps and by held-out lights: each refinement
  variant against the same estimates without it, how often it lowers the mean per-map RMSE, the
  held-out re-render and both (writes ``refine.md``; needs ``EBR_REFINE_DATA`` or ``EBR_VAL_DATA``).

Default ``--out``: inside a checkout of ebr-mitsuba (the current directory or one above it holds
the project's ``pyproject.toml``) the checkout's ``docs/bench`` (``docs`` for ``models``,
``fivelight`` and ``mair``), the pages the documentation links; anywhere else ``./ebr-bench``, so that a run
elsewhere never writes into the installed package's source tree.

``--out`` and ``--quick`` are the fields of :class:`BenchConfig` (flags, defaults and help generated
from its metadata). ``all`` runs every benchmark this version has. ``--quick`` runs a reduced
version (small sizes and few iterations, under a minute each on two cores: a smoke test; its numbers
are not the documented ones). ``--json`` prints ``{"written": {name: path}, "seconds": {name: s}}``.
Timings depend on the machine and its load: regenerate the pages on a quiet machine.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import time
from pathlib import Path

import tomllib

from ..errors import InputError
from ..typedconfig import add_flags, config, from_args, option
from ._common import emit_json, say

NAME = "bench"
HELP = "measure speed against error; write the benchmark pages (docs/bench/*.md in a checkout)"

# Every benchmark name the toolkit plans; `available()` is the subset this version has (a module in
# ebr_mitsuba.bench). Only those are listed in --help.
BENCHMARKS = (
    "renderer",
    "generate",
    "extract-sg",
    "estimate",
    "sizes",
    "models",
    "fivelight",
    "mair",
    "insert",
    "flash-fit",
    "normals",
    "roughness",
    "tilt",
    "refine",
)
OUTSIDE_CHECKOUT = Path("ebr-bench")
PROJECT = "ebr-mitsuba"


@config(error=InputError, cli=True)
class BenchConfig:
    """The options of ``ebr bench`` (a bad value is an :class:`~ebr_mitsuba.errors.InputError`
    naming the flag)."""

    out: str | None = option(
        None,
        "output folder",
        metavar="OUT",
        shown=f"docs/bench of the checkout you are in, docs for 'models', 'fivelight' and 'mair'; "
        f"./{OUTSIDE_CHECKOUT} outside a checkout",
    )
    quick: bool = option(False, "reduced sizes, under a minute each: a smoke test")


#: The fields ``ebr bench`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
BENCH_FLAGS = ("out", "quick")


def _module_name(name: str) -> str:
    return f"ebr_mitsuba.bench.{name.replace('-', '_')}"


def available() -> list[str]:
    """The benchmarks this version has (a module in :mod:`ebr_mitsuba.bench` with ``run``)."""
    return [b for b in BENCHMARKS if importlib.util.find_spec(_module_name(b)) is not None]


def checkout_root(start: Path | None = None) -> Path | None:
    """The ebr-mitsuba checkout holding ``start`` (default: the current directory): the nearest
    folder at or above it whose ``pyproject.toml`` names the project ``ebr-mitsuba``; else None."""
    start = (start or Path.cwd()).resolve()
    for folder in (start, *start.parents):
        pyproject = folder / "pyproject.toml"
        if not pyproject.is_file():
            continue
        try:
            name = tomllib.loads(pyproject.read_text()).get("project", {}).get("name")
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
            continue
        if name == PROJECT:
            return folder
    return None


def default_out(name: str, start: Path | None = None) -> Path:
    """Where benchmark ``name`` writes without ``--out`` (module docstring)."""
    root = checkout_root(start)
    if root is None:
        return OUTSIDE_CHECKOUT
    module = importlib.import_module(_module_name(name))
    return root / getattr(module, "DEFAULT_OUT", "docs/bench")


def add_arguments(p) -> None:
    names = (*available(), "all")
    p.add_argument(
        "which",
        nargs="?",
        default="all",
        metavar="{" + ",".join(names) + "}",
        help="benchmark to run (default: all)",
    )
    # The BenchConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(p, BenchConfig, BENCH_FLAGS)
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args) -> int:
    cfg = from_args(BenchConfig, args, BENCH_FLAGS)
    have = available()
    if args.which != "all" and args.which not in have:
        if args.which in BENCHMARKS:
            raise InputError(f"benchmark '{args.which}' is not in this version; available: {', '.join(have)}")
        raise InputError(f"unknown benchmark '{args.which}'; choose one of {', '.join(have)} or all")
    names = have if args.which == "all" else [args.which]
    written, seconds = {}, {}
    for name in names:
        module = importlib.import_module(_module_name(name))
        reason = module.unavailable() if hasattr(module, "unavailable") else None
        if reason and args.which == "all":
            say(f"[bench] {name}: skipped ({reason})")
            continue
        kwargs = {"quick": True} if cfg.quick and "quick" in inspect.signature(module.run).parameters else {}
        say(f"[bench] {name} ...")
        t0 = time.perf_counter()
        out = Path(cfg.out) if cfg.out is not None else default_out(name)
        path = module.run(out, **kwargs)
        seconds[name] = time.perf_counter() - t0
        written[name] = str(path)
        say(f"[bench] {name}: wrote {path} ({seconds[name]:.0f} s)")
    if args.json:
        emit_json({"written": written, "seconds": seconds})
    return 0
