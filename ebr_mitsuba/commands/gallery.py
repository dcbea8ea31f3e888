"""Build the real-photo gallery page: flash-only estimates of a folder of photos.

  ebr gallery PHOTOS_DIR [--docs DIR] [--checkpoint C] [--refine-steps N] [--json]

Runs ``ebr estimate`` in flash-only mode on every PNG/JPEG/EXR photo of PHOTOS_DIR (for the bundled
set: ../shared/data/photos/flash_only, 13 phone photos) and writes DIR/gallery.md with one picture
strip per photo under DIR/gallery/ (input, re-render, the four maps, a relit render). The options
are the fields of :class:`GalleryConfig` (flags, defaults and help generated from its metadata); a
bad value is one line naming the flag (exit 2). ``--json`` prints {"page", "photos": [{"name",
"image", "rel_rmse", "seconds", "warnings", "flash_intensity"}]}.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError
from ..typedconfig import add_flags, config, from_args, option
from ._common import emit_json, say

NAME = "gallery"
HELP = "flash-only estimates of a folder of photos as a docs gallery page"


@config(error=InputError, cli=True)
class GalleryConfig:
    """The options of ``ebr gallery`` (a bad value is an :class:`~ebr_mitsuba.errors.InputError`
    naming the flag)."""

    docs: str = option("docs", "docs folder to write into", metavar="DIR")
    checkpoint: str | None = option(None, "model checkpoint", metavar="C", shown="the shipped model")
    refine_steps: int = option(0, "refinement steps per photo", minimum=0, flag="--refine-steps")


#: The fields ``ebr gallery`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
GALLERY_FLAGS = ("docs", "checkpoint", "refine_steps")


def add_arguments(parser) -> None:
    parser.add_argument("photos", metavar="PHOTOS_DIR", help="folder of flash-only photos")
    # The GalleryConfig options: values read as text and checked by from_args (one line, exit 2).
    add_flags(parser, GalleryConfig, GALLERY_FLAGS)
    parser.add_argument("--json", action="store_true", help="print a JSON summary on stdout")


def run(args) -> int:
    from ..estimate.gallery import build_gallery

    cfg = from_args(GalleryConfig, args, GALLERY_FLAGS)
    if cfg.checkpoint is not None and not Path(cfg.checkpoint).is_file():
        raise InputError(f"--checkpoint {cfg.checkpoint}: no such file; omit it for the shipped model")
    result = build_gallery(Path(args.photos), Path(cfg.docs), cfg.checkpoint, cfg.refine_steps, log=say)
    if args.json:
        emit_json(result)
    else:
        say(f"wrote {result['page']} ({len(result['photos'])} photos)")
    return 0
