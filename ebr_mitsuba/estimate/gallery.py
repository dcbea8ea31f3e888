"""The real-photo gallery: flash-only estimates of a folder of photos, as a Markdown page.

:func:`build_gallery` runs the flash-only estimate (:func:`.pipeline.run_estimate`, no
``--noflash``) on every PNG/JPEG/EXR photo of a folder, in name order, and writes

=========================  =========================================================================
path                       content
=========================  =========================================================================
``<docs>/gallery.md``      one section per photo: the strip below, the re-render error and the time
``<docs>/gallery/*.png``   per photo one strip: input | re-render | normal | diffuse | roughness |
                           specular | relit from the upper left (192 px each)
=========================  =========================================================================

The estimates themselves are built in a temporary folder and dropped; only the pictures stay.
``gallery/`` is replaced atomically and ``gallery.md`` written atomically, so an interrupted run
leaves the previous gallery intact.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from ..errors import InputError
from ..fsutil import atomic_dir, atomic_write_text
from ..imageio import EXR_SUFFIXES, JPEG_SUFFIXES, PNG_SUFFIXES
from . import pipeline
from .pipeline import EstimateConfig, run_estimate
from .refine import RefineConfig

STRIP = (
    "inputs/flash.png",
    "rerender/flash.png",
    "maps/normal.png",
    "maps/diffuse.png",
    "maps/roughness.png",
    "maps/specular.png",
    "novel/light_upper_left.png",
)
STRIP_LABELS = ("input", "re-render", "normal", "diffuse", "roughness", "specular", "relit")
TILE = 192


def find_photos(folder: Path) -> list[Path]:
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such photo folder; give the folder of flash-only photos")
    photos = sorted(
        p
        for p in folder.iterdir()
        if p.is_file() and p.suffix.lower() in PNG_SUFFIXES + JPEG_SUFFIXES + EXR_SUFFIXES
    )
    if not photos:
        raise InputError(f"{folder}: holds no PNG, JPEG or EXR photo")
    return photos


def strip(est_dir: Path, path: Path) -> None:
    """The pictures of :data:`STRIP` side by side (missing ones left blank)."""
    from PIL import Image

    canvas = Image.new("RGB", ((TILE + 4) * len(STRIP), TILE + 4), "white")
    for k, rel in enumerate(STRIP):
        if (est_dir / rel).is_file():
            with Image.open(est_dir / rel) as im:
                canvas.paste(
                    im.convert("RGB").resize((TILE, TILE), Image.Resampling.LANCZOS), ((TILE + 4) * k + 2, 2)
                )
    canvas.save(path, "PNG")


def build_gallery(
    photos_dir: Path,
    docs_dir: Path,
    checkpoint: str | None = None,
    refine_steps: int = 0,
    log: Callable[[str], None] | None = None,
    predictor=None,
) -> dict:
    """Flash-only estimates of every photo in ``photos_dir`` → ``docs_dir/gallery.md`` + images.
    Returns {"page", "photos": [{"name", "image", "rel_rmse", "seconds", "warnings"}]}.
    ``predictor``: the model (None: :func:`.pipeline.load_predictor` of ``checkpoint``)."""
    log = log or (lambda m: None)
    photos = find_photos(photos_dir)
    docs_dir = Path(docs_dir)
    entries = []
    if predictor is None:
        predictor = pipeline.load_predictor(checkpoint)  # once for all photos
    with (
        tempfile.TemporaryDirectory(prefix="ebr-gallery-") as work,
        atomic_dir(docs_dir / "gallery") as img_dir,
    ):
        for k, photo in enumerate(photos):
            log(f"[{k + 1}/{len(photos)}] {photo.name}")
            t0 = time.perf_counter()
            est = Path(work) / photo.stem
            summary = run_estimate(
                EstimateConfig(
                    flash=str(photo),
                    out=str(est),
                    checkpoint=checkpoint,
                    refine=RefineConfig(steps=refine_steps),
                ),
                predictor=predictor,
            )
            image = f"gallery/{photo.stem}.png"
            strip(est, img_dir / f"{photo.stem}.png")
            err = summary["rerender_error"]["refined"] or summary["rerender_error"]["network"]
            entries.append(
                {
                    "name": photo.name,
                    "image": image,
                    "rel_rmse": err["mean"]["rel_rmse"],
                    "seconds": round(time.perf_counter() - t0, 2),
                    "warnings": summary["warnings"],
                    "flash_intensity": summary["flash"]["flash"]["intensity"],
                }
            )
    page = docs_dir / "gallery.md"
    atomic_write_text(page, render_page(photos_dir, entries, refine_steps))
    return {"page": str(page), "photos": entries}


def render_page(photos_dir: Path, entries: list[dict], refine_steps: int) -> str:
    lines = [
        "# Gallery: real flash-only photos",
        "",
        "Generated by `ebr gallery` (do not edit by hand). Each photo was estimated with",
        f"`ebr estimate --flash PHOTO --out DIR`{f' --refine-steps {refine_steps}' if refine_steps else ''}"
        " in flash-only mode (a dark room: no lighting estimate).",
        "Per photo, left to right: " + " | ".join(STRIP_LABELS) + ". The re-render uses the flash intensity",
        "fitted to the photo; *relit* moves the light to the upper left. There is no ground truth: judge by",
        "eye and by the re-render error (relative RMSE of re-render vs photo).",
        "",
        f"Photos: `{Path(photos_dir).name}/` (Deschaintre et al. 2018, input examples, MIT licence).",
        "",
    ]
    for e in entries:
        lines += [
            f"## {e['name']}",
            "",
            f"![{e['name']}]({e['image']})",
            "",
            f"re-render relative RMSE {e['rel_rmse']:.3f} · {e['seconds']:.1f} s",
            "",
        ]
        for w in e["warnings"]:
            lines.append(f"- warning: {w}")
        lines.append("")
    return "\n".join(lines)


__all__ = ["build_gallery", "find_photos", "render_page", "strip"]
