"""Build the real-photo gallery page: flash-only estimates of a folder of photos.

  ebr gallery PHOTOS_DIR [--docs DIR] [--checkpoint C] [--refine-steps N] [--json]

Runs ``ebr estimate`` in flash-only mode on every PNG/JPEG/EXR photo of PHOTOS_DIR (for the
bundled set: ../shared/data/photos/flash_only, 13 phone photos) and writes DIR/gallery.md with one
picture strip per photo under DIR/gallery/ (input, re-render, the four maps, a relit render).
Defaults: --docs docs, --refine-steps 0. ``--json`` prints {"page", "photos": [{"name", "image",
"rel_rmse", "seconds", "warnings", "flash_intensity"}]}.
"""

from __future__ import annotations

from pathlib import Path

from ._common import emit_json, say

NAME = "gallery"
HELP = "flash-only estimates of a folder of photos as a docs gallery page"


def add_arguments(parser) -> None:
    parser.add_argument("photos", metavar="PHOTOS_DIR", help="folder of flash-only photos")
    parser.add_argument("--docs", default="docs", metavar="DIR", help="docs folder to write into [docs]")
    parser.add_argument("--checkpoint", metavar="C", help="model checkpoint (default: the shipped model)")
    parser.add_argument("--refine-steps", type=int, default=0, help="refinement steps per photo [0]")
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args) -> int:
    from ..errors import InputError
    from ..estimate.gallery import build_gallery

    if args.refine_steps < 0:
        raise InputError("--refine-steps must be >= 0")
    if args.checkpoint is not None and not Path(args.checkpoint).is_file():
        raise InputError(f"--checkpoint {args.checkpoint}: no such file; omit it for the shipped model")
    result = build_gallery(Path(args.photos), Path(args.docs), args.checkpoint, args.refine_steps, log=say)
    if args.json:
        emit_json(result)
    else:
        say(f"wrote {result['page']} ({len(result['photos'])} photos)")
    return 0
