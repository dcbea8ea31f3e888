"""Validate the plugins and the fast renderer against path-traced references.

  ebr validate [CASES.toml | SCENE.xml ...] [--case NAME ...] [--spp N] [--seed S]
               [--markdown FILE.md] [--json]

With no argument the bundled cases (``scenes/validation.toml``) run. A ``.toml`` argument is a
case file of the same format; an ``.xml`` argument is a validation scene (the sample plane with a
constant-map ``svbrdf`` of id ``sample``, an ``sgenvmap`` of id ``env``, optionally a point light of
id ``light``: see ``scenes/validate_plane.xml``), checked with every check at a 30° view.

Checks (each a row): ``builtin-bsdf`` (our ``svbrdf`` against Mitsuba's built-in BSDFs under the
same ``envmap``), ``builtin-emitter`` (our ``sgenvmap`` against a rasterised built-in ``envmap``),
``fast-sg`` and ``fast-quadrature`` (the fast renderer's two environment modes against Mitsuba's
``path`` integrator). A check passes when ``rel_rmse <= 3 * noise + budget``, ``noise`` being the
measured Monte-Carlo standard error of the comparison.

Exit status: 0 when every check passes, 1 when one fails, 2 on bad input. ``--json`` prints
``{"passed", "spp", "seconds", "cases": [{"name", "reference", "rel_rmse", "excess", "max_abs",
"tolerance", "noise", "budget", "passed", "seconds"}, ...]}``; ``--markdown`` writes the table.
``--spp`` and ``--seed`` are the fields of :class:`ebr_mitsuba.validate.ValidateConfig` (flags,
defaults and help generated from its metadata).
"""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import InputError
from ..typedconfig import add_flags, from_args
from ._common import emit_json, progress, say

NAME = "validate"
HELP = "check plugins and fast renderer against path-traced references"


def add_arguments(p) -> None:
    from ..validate import VALIDATE_FLAGS, ValidateConfig

    p.add_argument(
        "scenes",
        nargs="*",
        metavar="CASES.toml|SCENE.xml",
        help="case files or validation scenes (default: the bundled cases)",
    )
    p.add_argument(
        "--case", action="append", default=[], metavar="NAME", help="run only the named case(s) (repeatable)"
    )
    # The ValidateConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(p, ValidateConfig, VALIDATE_FLAGS)
    p.add_argument(
        "--markdown",
        type=Path,
        default=None,
        metavar="FILE.md",
        help="also write the result table as Markdown",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def config_from_args(args):
    """The :class:`~ebr_mitsuba.validate.ValidateConfig` of the parsed options (InputError if bad)."""
    from ..validate import VALIDATE_FLAGS, ValidateConfig

    return from_args(ValidateConfig, args, VALIDATE_FLAGS)


def _cases(args):
    from ..validate import CHECKS, Case, load_cases

    if not args.scenes:
        cases = load_cases()
    else:
        cases = []
        for spec in args.scenes:
            path = Path(spec)
            if not path.is_file():
                raise InputError(f"{path}: no such file; pass a validation .toml or a scene .xml")
            if path.suffix.lower() == ".toml":
                cases += load_cases(path)
            elif path.suffix.lower() == ".xml":
                cases.append(Case(name=path.stem, scene=path.resolve(), checks=CHECKS))
            else:
                raise InputError(f"{path}: expected a .toml case file or an .xml scene")
    if args.case:
        names = {c.name for c in cases}
        missing = [n for n in args.case if n not in names]
        if missing:
            raise InputError(f"--case {missing[0]}: no such case; known: {', '.join(sorted(names))}")
        cases = [c for c in cases if c.name in args.case]
    if not cases:
        raise InputError("no validation cases to run")
    return cases


def markdown_table(result: dict) -> str:
    """The rows of a validation run as a Markdown table."""
    lines = [
        f"Path-traced references at {result['spp']} spp per point, seed {result['seed']}; "
        f"{result['seconds']:.1f} s in all. A check passes when rel_rmse ≤ 3·noise + budget.",
        "",
        "| check | reference | rel_rmse | noise | budget | tolerance | passed |",
        "|---|---|---:|---:|---:|---:|:---:|",
    ]
    for r in result["cases"]:
        lines.append(
            f"| {r['name']} | {r['reference']} | {r['rel_rmse']:.4f} | {r['noise']:.4f} | "
            f"{r['budget']:.3f} | {r['tolerance']:.4f} | {'yes' if r['passed'] else '**no**'} |"
        )
    return "\n".join(lines) + "\n"


def run(args) -> int:
    from ..fsutil import atomic_write_text
    from ..validate import run_case

    cfg = config_from_args(args)
    cases = _cases(args)
    t0 = time.perf_counter()
    rows = []
    bar = progress(cases, desc="validate", unit="case")
    for case in bar:
        bar.set_postfix_str(case.name)
        rows.extend(run_case(case, cfg))
    result = {
        "passed": all(r["passed"] for r in rows),
        "spp": cfg.spp,
        "seed": cfg.seed,
        "seconds": time.perf_counter() - t0,
        "cases": rows,
    }
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        mark = "ok  " if r["passed"] else "FAIL"
        say(
            f"{mark} {r['name']:<{width}}  rel_rmse {r['rel_rmse']:.4f}  (tolerance {r['tolerance']:.4f}: "
            f"3 x noise {r['noise']:.4f} + budget {r['budget']:.3f})"
        )
    failed = [r["name"] for r in rows if not r["passed"]]
    say(
        f"{len(rows) - len(failed)}/{len(rows)} checks passed in {result['seconds']:.1f} s"
        + (f"; failed: {', '.join(failed)}" if failed else "")
    )
    if args.markdown is not None:
        atomic_write_text(args.markdown, markdown_table(result))
        say(f"wrote {args.markdown}")
    if args.json:
        emit_json(result)
    return 0 if result["passed"] else 1
