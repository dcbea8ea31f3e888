"""Measure speed against error and write the tables and plots under docs/bench/.

  ebr bench [renderer|generate|extract-sg|estimate|models|all] [--out DIR] [--quick] [--json]

Each benchmark writes ``OUT/<name>.md`` (a Markdown table with the reference it was measured
against, and the PNG plots it links) and returns its path:

* ``renderer``: Mitsuba spp sweep, the fast renderer's ``sg`` and ``quadrature`` modes at several
  spp, against a high-spp path-traced reference, per roughness and view angle;
* ``generate``: data-generation samples/s per core for the ``mitsuba`` and ``fast`` renderers, and
  the error of ``fast`` against ``mitsuba`` on the same samples;
* ``extract-sg``: the SG-extraction ablation, the exemplar roughness study and the timing;
* ``estimate``: the estimate pipeline's stages, time against re-render error;
* ``models``: the shipped model against its baselines and ablations on the held-out set, and its
  training summary (writes ``docs/models.md``; needs the data sets and runs named by
  ``EBR_TRAIN_DATA``, ``EBR_TEST_DATA``, ``EBR_RUNS``).

``--out`` defaults to ``docs/bench`` (``docs`` for ``models``).

``all`` runs every benchmark this version has. ``--quick`` runs a reduced version (small sizes,
for smoke tests; its numbers are not the documented ones). ``--json`` prints
``{"written": {name: path}, "seconds": {name: s}}``. Timings depend on the machine and its load:
regenerate the pages on a quiet machine.
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
import time
from pathlib import Path

from ..errors import InputError
from ._common import emit_json, say

NAME = "bench"
HELP = "measure speed against error; write docs/bench/*.md"

BENCHMARKS = ("renderer", "generate", "extract-sg", "estimate", "models")


def _module_name(name: str) -> str:
    return f"ebr_mitsuba.bench.{name.replace('-', '_')}"


def available() -> list[str]:
    """The benchmarks this version has (a module in :mod:`ebr_mitsuba.bench` with ``run``)."""
    return [b for b in BENCHMARKS if importlib.util.find_spec(_module_name(b)) is not None]


def add_arguments(p) -> None:
    p.add_argument(
        "which",
        nargs="?",
        default="all",
        choices=(*BENCHMARKS, "all"),
        help="benchmark to run (default: all)",
    )
    p.add_argument(
        "--out", type=Path, default=None, help="output folder (default docs/bench; docs for 'models')"
    )
    p.add_argument("--quick", action="store_true", help="reduced sizes, for smoke tests")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args) -> int:
    names = available() if args.which == "all" else [args.which]
    if args.which != "all" and args.which not in available():
        raise InputError(
            f"benchmark '{args.which}' is not in this version; available: {', '.join(available())}"
        )
    written, seconds = {}, {}
    for name in names:
        module = importlib.import_module(_module_name(name))
        reason = module.unavailable() if hasattr(module, "unavailable") else None
        if reason and args.which == "all":
            say(f"[bench] {name}: skipped ({reason})")
            continue
        kwargs = {"quick": True} if args.quick and "quick" in inspect.signature(module.run).parameters else {}
        say(f"[bench] {name} ...")
        t0 = time.perf_counter()
        out = args.out if args.out is not None else Path(getattr(module, "DEFAULT_OUT", "docs/bench"))
        path = module.run(out, **kwargs)
        seconds[name] = time.perf_counter() - t0
        written[name] = str(path)
        say(f"[bench] {name}: wrote {path} ({seconds[name]:.0f} s)")
    if args.json:
        emit_json({"written": written, "seconds": seconds})
    return 0
