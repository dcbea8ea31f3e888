"""The ``ebr`` command line: one entry point, one module per subcommand in
:mod:`ebr_mitsuba.commands`.

Conventions (DESIGN §4): ``--json`` prints a machine-readable summary on stdout, human output and
progress bars go to stderr; exit 0 on success, 2 on bad input (an :class:`EbrError`, printed as one
line), 1 on an internal error.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .errors import EbrError

# Subcommand modules, in --help order. Each defines ``NAME``, ``HELP``, ``add_arguments(parser)``
# and ``run(args) -> int``.
COMMANDS = (
    "demo",
    "render",
    "capture",
    "generate",
    "dataset",
    "fit-env",
    "exemplars",
    "extract-sg",
    "select-exemplars",
    "estimate",
    "gallery",
    "validate",
    "bench",
    "train",
    "eval",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ebr",
        description="ebr-mitsuba: inverse rendering of near-planar SVBRDFs under unknown environment light.",
    )
    parser.add_argument(
        "--variant",
        default=None,
        help="Mitsuba variant (default: $EBR_VARIANT or llvm_ad_rgb; cuda_ad_rgb where available)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        modname = f"{__package__}.commands.{name.replace('-', '_')}"
        module = importlib.import_module(modname)
        p = sub.add_parser(
            module.NAME,
            help=module.HELP,
            description=module.__doc__,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: exit 2 on bad usage, 0 on --help
        return int(exc.code or 0)
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        from .variant import ensure_variant

        ensure_variant(args.variant)
        return int(args._run(args) or 0)
    except EbrError as exc:
        print(f"ebr {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print(f"ebr {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # internal error: keep the traceback out of the user's face
        import traceback

        log = traceback.format_exc()
        print(
            f"ebr {args.command}: internal error: {type(exc).__name__}: {exc} "
            f"(set EBR_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        import os

        if os.environ.get("EBR_DEBUG"):
            print(log, file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
