"""The ``ebr`` command line: one entry point, one module per subcommand in
:mod:`ebr_mitsuba.commands`.

Conventions (``docs/conventions.md``, "Command line"): ``--json`` prints a machine-readable summary
on stdout, human output and progress bars go to stderr; exit 0 on success, 2 on bad input (an
:class:`EbrError`, printed as one line), 1 on an internal error.

Global options (before or after the subcommand): ``--variant`` (:mod:`ebr_mitsuba.variant`) and
``--deterministic`` (one Dr.Jit thread, so identical reruns give identical bytes; also
``EBR_DETERMINISTIC=1``; :func:`ebr_mitsuba.variant.set_deterministic`).

A full disk is bad input too (exit 2): one line naming the device, the file being written (its
final name, not the temporary one) and the fix, whichever writer hit it
(:class:`~ebr_mitsuba.errors.DiskFullError`). The writers are atomic, so nothing half-written
is left behind.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
from pathlib import PurePath

from .errors import DiskFullError, EbrError, is_disk_full

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
    "insert",
    "gallery",
    "validate",
    "bench",
    "train",
    "eval",
)


_VARIANT_HELP = "Mitsuba variant: llvm_ad_rgb (default, or $EBR_VARIANT) or cuda_ad_rgb (needs a CUDA GPU)"
_DETERMINISTIC_HELP = (
    "one Dr.Jit thread: the same inputs and seed give the same bytes (slower; default $EBR_DETERMINISTIC)"
)


def _global_options(parser, repeated: bool) -> None:
    """``--variant`` and ``--deterministic``. Subcommands repeat them (``repeated``) with
    ``default=SUPPRESS``, so they may also follow the subcommand without undoing a value given
    before it."""
    suppress = argparse.SUPPRESS
    parser.add_argument(
        "--variant", default=suppress if repeated else None, metavar="VARIANT", help=_VARIANT_HELP
    )
    parser.add_argument(
        "--deterministic",
        action="store_true",
        default=suppress if repeated else False,
        help=_DETERMINISTIC_HELP,
    )


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="ebr",
        description="ebr-mitsuba: inverse rendering of near-planar SVBRDFs under unknown environment light.",
    )
    _global_options(parser, repeated=False)
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
        _global_options(p.add_argument_group("global options"), repeated=True)
        p.set_defaults(_run=module.run)
    return parser


# fsutil's temporary names: ``.NAME.XXXXXXXX.partial`` (atomic_dir), ``.STEM.XXXXXXXX.SUF.tmp.SUF``
# (atomic_path); XXXXXXXX is tempfile's random part.
_TMP_DIR = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}\.partial$")
_TMP_FILE = re.compile(r"^\.(?P<stem>.+)\.[a-z0-9_]{8}(?P<suf>(?:\.[^.]+)?)\.tmp(?P=suf)$")


def final_path(path: str | os.PathLike) -> str:
    """``path`` with every temporary component of :mod:`ebr_mitsuba.fsutil` replaced by the name it
    will be renamed to: what the user asked for, rather than what is being written right now."""
    parts = []
    for part in PurePath(path).parts:
        m = _TMP_DIR.match(part)
        f = _TMP_FILE.match(part)
        parts.append(m["name"] if m else (f["stem"] + f["suf"] if f else part))
    return str(PurePath(*parts)) if parts else str(path)


def _disk_full_cause(exc: BaseException) -> BaseException | None:
    """The full-disk error in ``exc``'s cause/context chain (``exc`` itself first), if any."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if is_disk_full(exc):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def _written_path(exc: BaseException) -> str | None:
    """The file a full-disk error was writing: the :class:`DiskFullError`'s path, the
    ``OSError``'s file name, or the path of the innermost ``pathlib`` write in the traceback."""
    if isinstance(exc, DiskFullError):
        return exc.path
    if isinstance(exc, OSError) and exc.filename:
        return os.fsdecode(exc.filename)
    tb, found = exc.__traceback__, None
    while tb is not None:
        frame = tb.tb_frame
        owner = frame.f_locals.get("self")
        if frame.f_code.co_name in ("write_text", "write_bytes", "open") and isinstance(owner, PurePath):
            found = owner
        tb = tb.tb_next
    return None if found is None else str(found)


def disk_full_error(exc: BaseException, out=None) -> DiskFullError | None:
    """A :class:`DiskFullError` naming the final path being written when ``exc`` (or its cause) is
    a full-disk error, else None; ``out`` (the command's ``--out``) names it when nothing else does."""
    cause = _disk_full_cause(exc)
    if cause is None:
        return None
    path = _written_path(cause) or (None if out is None else str(out))
    return DiskFullError(final_path(path) if path else "the output")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: exit 2 on bad usage, 0 on --help
        return int(exc.code or 0)
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return 2
    restore_threads = None
    try:
        from .variant import deterministic_requested, ensure_variant, set_deterministic

        ensure_variant(args.variant)
        if args.deterministic or deterministic_requested():
            import drjit as dr

            restore_threads = dr.thread_count()
            set_deterministic()
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print(f"ebr {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        full = disk_full_error(exc, getattr(args, "out", None))
        if full is not None:
            exc = full
        if isinstance(exc, EbrError):
            print(f"ebr {args.command}: error: {exc}", file=sys.stderr)
            return exc.exit_code
        # internal error: keep the traceback out of the user's face
        import traceback

        log = traceback.format_exc()
        print(
            f"ebr {args.command}: internal error: {type(exc).__name__}: {exc} "
            f"(set EBR_DEBUG=1 for the traceback)",
            file=sys.stderr,
        )
        if os.environ.get("EBR_DEBUG"):
            print(log, file=sys.stderr)
        return 1
    finally:
        if restore_threads is not None:  # main() called in-process (tests, notebooks)
            import drjit as dr

            dr.set_thread_count(restore_threads)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
