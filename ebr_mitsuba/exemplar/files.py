"""Exemplar directories (``ebr exemplars`` writes them, ``ebr extract-sg`` reads them).

==================  ===========================================================================
file                content
==================  ===========================================================================
``r0.100.exr`` …    one linear RGB float32 image (H, W, 3) per exemplar, named by roughness
``exemplars.json``  metadata (below)
==================  ===========================================================================

``exemplars.json`` (``"format": "ebr-exemplars/1"``):

================  ==================================================================================
key               value
================  ==================================================================================
``kind``          ``"env"`` (environment exemplars, flash off) or ``"point"`` (the near flash alone)
``material``      ``{"diffuse": 0.1, "specular": 0.2, "normal": [0, 0, 1]}`` (:mod:`ebr_mitsuba.exemplar`)
``exemplars``     ``[{"file": "r0.100.exr", "roughness": 0.1}, …]`` in the order given
``resolution``    [H, W]
``shot``          the camera (and light) as :meth:`ebr_mitsuba.geometry.Shot.to_json`
``renderer``      ``{"name": "mitsuba" | "fast", "spp", "seed", "mode", "variant"}``
``env``           the environment spec as :meth:`ebr_mitsuba.sources.EnvSource.to_json` (or null)
================  ==================================================================================

:func:`read_exemplars` checks everything (format, files, one size for all, roughness in [0, 1])
and raises one-line :class:`~ebr_mitsuba.errors.InputError`\\ s naming the file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..exemplar import exemplar_material_json
from ..geometry import NEAR_FOV, Shot

FORMAT = "ebr-exemplars/1"
KINDS = ("env", "point")
META = "exemplars.json"


def exemplar_file(roughness: float) -> str:
    return f"r{float(roughness):.3f}.exr"


@dataclass(frozen=True)
class ExemplarSet:
    """Exemplars read from a directory: ``images`` (N, H, W, 3) float32, ``roughness`` (N,),
    ``kind``, the ``shot`` they were rendered from and the raw metadata."""

    images: np.ndarray
    roughness: np.ndarray
    kind: str
    shot: Shot
    meta: dict


def write_exemplars(
    out_dir: Path,
    images: list[np.ndarray],
    roughness: list[float],
    kind: str,
    shot: Shot,
    renderer: dict,
    env: dict | None,
) -> Path:
    """Write an exemplar directory atomically (an existing exemplar directory is replaced; any
    other existing non-empty directory is refused)."""
    from ..fsutil import atomic_dir
    from ..imageio import write_exr

    out_dir = Path(out_dir)
    if out_dir.exists():
        if not out_dir.is_dir():
            raise InputError(f"{out_dir}: exists and is not a directory; choose another --out")
        if any(out_dir.iterdir()) and not (out_dir / META).is_file():
            raise InputError(
                f"{out_dir}: exists and is not an exemplar directory (no {META}); choose a "
                f"new --out or remove it"
            )
    if kind not in KINDS:
        raise InputError(f"exemplar kind {kind!r} is unknown; use one of {', '.join(KINDS)}")
    names = [exemplar_file(r) for r in roughness]
    if len(set(names)) != len(names):
        raise InputError(f"roughness values {list(roughness)} repeat; give each value once")
    shapes = {np.shape(im) for im in images}
    if len(images) != len(roughness) or len(shapes) != 1 or len(next(iter(shapes))) != 3:
        raise InputError(
            f"write_exemplars: give one (H, W, 3) image per roughness value, all of one size "
            f"(got {len(images)} images of shapes {sorted(shapes)} for {len(roughness)} values)"
        )
    h, w = images[0].shape[:2]
    meta = {
        "format": FORMAT,
        "kind": kind,
        "material": exemplar_material_json(),
        "exemplars": [{"file": n, "roughness": float(r)} for n, r in zip(names, roughness)],
        "resolution": [int(h), int(w)],
        "shot": shot.to_json(),
        "renderer": renderer,
        "env": env,
    }
    with atomic_dir(out_dir) as tmp:
        for name, img in zip(names, images):
            write_exr(tmp / name, np.asarray(img, np.float32))
        (tmp / META).write_text(json.dumps(meta, indent=1) + "\n")
    return out_dir


def _shot_from_json(data: dict, source: str) -> Shot:
    try:
        camera = tuple(float(c) for c in data["camera"])
        flash = data.get("flash")
        return Shot(
            str(data.get("name", "exemplar")),
            camera,
            float(data.get("fov", NEAR_FOV)),
            None if flash is None else tuple(float(c) for c in flash),
            float(data.get("flash_intensity", 0.0)),
            bool(data.get("env", True)),
            tuple(float(c) for c in data.get("target", (0.0, 0.0, 0.0))),
            tuple(float(c) for c in data.get("up", (0.0, 1.0, 0.0))),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(
            f"{source}: 'shot' needs 'camera' [x,y,z] (and optional fov, flash) ({type(exc).__name__}: {exc})"
        ) from None


def read_exemplars(directory) -> ExemplarSet:
    """Read and validate an exemplar directory (module docstring)."""
    from ..imageio import read_exr

    directory = Path(directory)
    meta_path = directory / META
    if not directory.is_dir():
        raise InputError(f"{directory}: no such exemplar directory; create one with `ebr exemplars`")
    if not meta_path.is_file():
        raise InputError(f"{directory}: no {META}; an exemplar directory is written by `ebr exemplars`")
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{meta_path}: malformed JSON ({exc}); regenerate it with `ebr exemplars`") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputError(f"{meta_path}: 'format' must be \"{FORMAT}\"")
    kind = meta.get("kind")
    if kind not in KINDS:
        raise InputError(f"{meta_path}: 'kind' must be one of {', '.join(KINDS)} (got {kind!r})")
    entries = meta.get("exemplars")
    if not isinstance(entries, list) or not entries:
        raise InputError(f'{meta_path}: \'exemplars\' must be a non-empty list of {{"file", "roughness"}}')
    images, rough = [], []
    for i, e in enumerate(entries):
        try:
            name, r = str(e["file"]), float(e["roughness"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"{meta_path}: exemplar {i} needs 'file' and 'roughness'") from None
        if not 0.0 <= r <= 1.0:
            raise InputError(f"{meta_path}: exemplar {i} has roughness {r}; it must lie in [0, 1]")
        path = directory / name
        if not path.is_file():
            raise InputError(f"{path}: exemplar image missing; regenerate the directory with `ebr exemplars`")
        img = read_exr(path)
        images.append(np.asarray(img, np.float32)[..., :3])
        rough.append(r)
    shapes = {im.shape for im in images}
    if len(shapes) > 1:
        raise InputError(
            f"{directory}: exemplars of different sizes {sorted(shapes)}; all exemplars must "
            f"share one resolution"
        )
    shot = _shot_from_json(meta.get("shot") or {}, str(meta_path))
    return ExemplarSet(np.stack(images), np.asarray(rough), kind, shot, meta)
