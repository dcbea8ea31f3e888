"""Check or preview a generated data set.

  ebr dataset verify DIR [--json]
  ebr dataset sheet DIR --out sheet.png [--samples N]

verify: checks dataset.json, index.json and every sample (files present and listed in the
manifest, sizes and SHA-256 checksums, images readable with the right size and channels and no
NaN/Inf, env.json valid); prints every problem on stderr and exits 2 if there is any, 0 otherwise.
--json prints {"root", "ok", "samples", "errors", "notes"}.

sheet: a contact sheet (matplotlib PNG) of --samples samples evenly spread over the data set: the
four maps, the photos, a flash-only image and the exemplars, one row per sample. ``--samples`` is
the field of :class:`SheetConfig` (flag, default and help generated from its metadata; a bad value
is one line naming the flag, exit 2).
"""

from __future__ import annotations

from ..errors import InputError
from ..typedconfig import add_flags, config, from_args, option
from ._common import emit_json, say

NAME = "dataset"
HELP = "verify a generated data set or draw its contact sheet"


@config(error=InputError, cli=True)
class SheetConfig:
    """The options of ``ebr dataset sheet`` (a bad value is an
    :class:`~ebr_mitsuba.errors.InputError` naming the flag)."""

    samples: int = option(16, "rows: samples evenly spread over the data set", minimum=1)


#: The fields ``ebr dataset sheet`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
SHEET_FLAGS = ("samples",)


def add_arguments(parser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    v = sub.add_parser("verify", help="check every sample and the index")
    v.add_argument("dir", metavar="DIR", help="data-set directory")
    v.add_argument("--json", action="store_true", help="print a JSON report on stdout")
    s = sub.add_parser("sheet", help="draw a contact sheet (PNG)")
    s.add_argument("dir", metavar="DIR", help="data-set directory")
    s.add_argument("--out", required=True, metavar="sheet.png", help="output PNG")
    # The SheetConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(s, SheetConfig, SHEET_FLAGS)


def run(args) -> int:
    if args.action == "verify":
        from ..data.verify import verify

        report = verify(args.dir, progress=True)
        for line in report.errors:
            say(f"error: {line}")
        for line in report.notes:
            say(f"note: {line}")
        if args.json:
            emit_json(report.to_json())
        if report.ok:
            say(f"{args.dir}: {report.samples} samples verified, no problems")
            return 0
        say(
            f"ebr dataset verify: {args.dir}: {len(report.errors)} problem(s) in {report.samples} checked "
            f"samples"
        )
        return 2
    from ..data.sheet import contact_sheet

    cfg = from_args(SheetConfig, args, SHEET_FLAGS)
    out = contact_sheet(args.dir, args.out, samples=cfg.samples)
    say(f"wrote {out}")
    return 0
