"""On-disk format of a generated data set (``ebr-dataset/1``): layout, atomic sample writes, index.

::

    DIR/
      dataset.json         format, normalised config + fingerprint, setup, per-sample layout, versions
      config.toml          the config file as given (provenance)
      index.json           one entry per sample (written when every sample exists)
      envs/                SG fits of the equirect maps: <stem>-<sha12>-k<K>-i<N>.json (+ .fit.json)
      timing.json          wall times of the runs: NOT deterministic, not part of the data
      samples/000000/      one directory per sample (zero-padded index, 6 digits)
        photos/<shot>.png      the simulated camera photos, one per shot of the setup: 8-bit sRGB
                               (``camera.quantize``) or float32 linear EXR (``photos/<shot>.exr``)
        flash_only/<shot>.exr  flash-only image of each shot lit by flash and environment
        exemplars/env_<i>.exr     environment exemplar i (roughness ``exemplars.env_roughness[i]``)
        exemplars/point_<i>.exr   point-light exemplar i (``exemplars.point_roughness[i]``)
        maps/{normal,diffuse,specular,roughness}.exr, maps/material.json   ground-truth SVBRDF
        env.json               ground-truth SG lobes (``ebr-sg/1``, radiance units, world z-up)
        sample.json            metadata (below)
        manifest.json          {"format": "ebr-manifest/1", "files": {path: {"sha256", "bytes"}}}

Units: photos are camera-simulated (:mod:`.camera`); flash-only images and exemplars are linear
radiance × exposure × white-balance gains (the photos' units before noise and clipping);
``env.json`` is radiance (divide the images by ``camera.exposure · camera.white_balance`` to
compare with renders under it). Maps follow the material-directory conventions
(``docs/conventions.md``, "Maps"). Shot names: near ``flash``, ``noflash``; near-far +
``far_flash``, ``far_noflash``; five-light ``light0`` … ``light4``; multi-view ``view{a}{b}_flash``.

``sample.json`` (``ebr-sample/1``): ``index``, ``seed`` ([data-set seed, index]), ``setup``,
``resolution`` [H, W], ``renderer`` ({name, spp, integrator} or {name, mode, spp}), ``material``
(source type, spec, family/seed or path, augmentation), ``env`` (type; procedural spec, kind, level,
seed; or the map's path, name, SHA-256, SG-fit file, rotation about z and scale; ``lobes``; ``file``),
``camera`` (exposure, white_balance, read_noise, shot_noise, clip, quantize, noise_seed),
``shots`` (the geometry of each shot and its files), ``exemplars``, ``maps``.

Atomicity: a sample directory is built under a temporary name in ``samples/`` and renamed when
complete (:func:`ebr_mitsuba.fsutil.atomic_dir`), so a sample directory under its final name is
always complete; a killed run leaves at most ``samples/.NNNNNN.*.partial`` directories, which
``--resume`` removes. Every file is written deterministically (float32 ZIP EXR, PNG without
time stamps, JSON in a fixed key order), so the same config gives byte-identical files.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..fsutil import atomic_dir, atomic_path, atomic_write_text
from ..imageio import write_exr, write_png
from ..materials import CONVENTIONS, MATERIAL_FORMAT
from ..svbrdf import MAP_NAMES

DATASET_FORMAT = "ebr-dataset/1"
SAMPLE_FORMAT = "ebr-sample/1"
INDEX_FORMAT = "ebr-index/1"
MANIFEST_FORMAT = "ebr-manifest/1"
SAMPLES = "samples"
DATASET_JSON = "dataset.json"
INDEX_JSON = "index.json"
TIMING_JSON = "timing.json"
CONFIG_COPY = "config.toml"
MANIFEST = "manifest.json"
SAMPLE_JSON = "sample.json"
ENV_JSON = "env.json"


def sample_dirname(index: int) -> str:
    """``samples/NNNNNN`` relative to the data-set root."""
    return f"{SAMPLES}/{int(index):06d}"


def layout(config) -> dict:
    """The files of every sample of ``config`` (relative to the sample directory), by role."""
    from .renderers import has_flash_only, shots_of

    photo_ext = ".png" if config.camera.quantize else ".exr"
    shots = shots_of(config)
    return {
        "photos": {s.name: f"photos/{s.name}{photo_ext}" for s in shots},
        "flash_only": {s.name: f"flash_only/{s.name}.exr" for s in shots if has_flash_only(s)},
        "env_exemplars": [f"exemplars/env_{i}.exr" for i in range(len(config.exemplars.env_roughness))],
        "point_exemplars": [f"exemplars/point_{i}.exr" for i in range(len(config.exemplars.point_roughness))],
        "maps": {name: f"maps/{name}.exr" for name in MAP_NAMES},
        "env": ENV_JSON,
        "meta": SAMPLE_JSON,
    }


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def manifest_of(directory: Path) -> dict:
    """``{relative path: {"sha256", "bytes"}}`` of every file under ``directory`` but the manifest."""
    files = {}
    for path in sorted(p for p in directory.rglob("*") if p.is_file()):
        rel = path.relative_to(directory).as_posix()
        if rel == MANIFEST:
            continue
        files[rel] = {"sha256": sha256_file(path), "bytes": path.stat().st_size}
    return files


def dumps(obj) -> str:
    """The one JSON encoding of every file of the format (fixed key order, finite floats)."""
    return json.dumps(obj, indent=1, allow_nan=False) + "\n"


def _material_json(svbrdf_shape, record: dict) -> dict:
    h, w = svbrdf_shape
    licence = (
        "CC0 (generated by ebr-mitsuba)"
        if record.get("type") == "procedural"
        else "as the source material (see source)"
    )
    return {
        "format": MATERIAL_FORMAT,
        "size": [h, w],
        "maps": {n: f"{n}.exr" for n in MAP_NAMES},
        "conventions": CONVENTIONS,
        "source": record.get("spec", "unknown"),
        "licence": licence,
    }


def write_sample(
    root: Path,
    index: int,
    *,
    svbrdf,
    env_sg,
    photos: dict,
    flash_only: dict,
    env_exemplars: list,
    point_exemplars: list,
    meta: dict,
    quantize: bool,
) -> Path:
    """Write sample ``index`` atomically under ``root`` (module docstring); returns its directory.

    ``photos``: shot name → camera-simulated linear (H, W, 3) (clipped to [0, 1] when
    ``quantize``: written as 8-bit sRGB PNG); the other images are written as float32 EXR.
    ``meta`` is the content of ``sample.json``.
    """
    target = Path(root) / sample_dirname(index)
    with atomic_dir(target) as tmp:
        for name, image in photos.items():
            if quantize:
                write_png(tmp / "photos" / f"{name}.png", image, encode="srgb", bits=8)
            else:
                write_exr(tmp / "photos" / f"{name}.exr", image)
        for name, image in flash_only.items():
            write_exr(tmp / "flash_only" / f"{name}.exr", image)
        for i, image in enumerate(env_exemplars):
            write_exr(tmp / "exemplars" / f"env_{i}.exr", image)
        for i, image in enumerate(point_exemplars):
            write_exr(tmp / "exemplars" / f"point_{i}.exr", image)
        for name in MAP_NAMES:
            write_exr(tmp / "maps" / f"{name}.exr", getattr(svbrdf, name))
        material = _material_json(svbrdf.shape, meta["material"])
        atomic_write_text(tmp / "maps" / "material.json", dumps(material))
        atomic_write_text(tmp / ENV_JSON, dumps(env_sg.to_json()))
        atomic_write_text(tmp / SAMPLE_JSON, dumps(meta))
        atomic_write_text(tmp / MANIFEST, dumps({"format": MANIFEST_FORMAT, "files": manifest_of(tmp)}))
    return target


def read_files(directory: Path) -> dict:
    """Every file under a sample directory as ``{relative path: bytes}`` (Ray transfers)."""
    return {
        p.relative_to(directory).as_posix(): p.read_bytes()
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


def write_files(root: Path, index: int, files: dict) -> Path:
    """Write a sample given as ``{relative path: bytes}`` atomically (the Ray driver's side)."""
    target = Path(root) / sample_dirname(index)
    with atomic_dir(target) as tmp:
        for rel, data in files.items():
            path = tmp / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as t:
                t.write_bytes(data)
    return target


def is_complete(root: Path, index: int) -> bool:
    """A sample is complete when its directory exists under its final name (atomic rename) and
    holds its manifest."""
    return (Path(root) / sample_dirname(index) / MANIFEST).is_file()


def remove_partials(root: Path) -> int:
    """Delete the temporary directories a killed run left in ``samples/``; returns how many."""
    samples = Path(root) / SAMPLES
    if not samples.is_dir():
        return 0
    stale = [p for p in samples.iterdir() if p.name.startswith(".") and p.name.endswith((".partial", ".old"))]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def read_json(path: Path) -> dict:
    return json.loads(Path(path).read_text())


def read_doc(path: Path, fmt: str, fix: str) -> dict:
    """A JSON object of format ``fmt`` at ``path``, or :class:`InputError` naming the file and
    ``fix`` (missing, unreadable, not JSON, wrong format)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: missing; {fix}")
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: unreadable ({type(exc).__name__}); {fix}") from None
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        raise InputError(f"{path}: not a {fmt} file; {fix}")
    return doc


def count_complete(root: Path, count: int) -> int:
    """How many of samples 0 … count − 1 are complete (:func:`is_complete`)."""
    return sum(is_complete(root, i) for i in range(int(count)))


def remake_hint(root: Path, index: int) -> str:
    """The fix for a damaged sample, as the error messages give it."""
    directory = Path(root) / sample_dirname(index)
    return (
        f"the sample is damaged: delete {directory} and rerun the 'ebr generate ... --out {root}' "
        f"command with --resume to remake it ('ebr dataset verify {root}' lists every problem)"
    )


def check_sample(root: Path, dataset: dict, index: int, entry: dict) -> None:
    """The cheap integrity check of a sample before it is read for training or evaluation:
    ``manifest.json`` present, parseable and with the SHA-256 ``index.json`` records for it; every
    file the layout needs listed in it; every listed file present with its recorded size and
    SHA-256. Raises :class:`InputError` naming the first bad file and the fix. (``ebr dataset
    verify`` does this and also decodes every image.)"""
    directory = Path(root) / sample_dirname(index)
    hint = remake_hint(root, index)
    manifest_path = directory / MANIFEST
    manifest = read_doc(manifest_path, MANIFEST_FORMAT, hint)
    if entry.get("manifest_sha256") != sha256_file(manifest_path):
        raise InputError(
            f"{manifest_path}: its SHA-256 differs from the one in {Path(root) / INDEX_JSON}; {hint}"
        )
    listed = manifest.get("files")
    if not isinstance(listed, dict):
        raise InputError(f"{manifest_path}: no 'files' table; {hint}")
    unlisted = sorted(expected_files(dataset["layout"]) - set(listed))
    if unlisted:
        raise InputError(
            f"{directory / unlisted[0]}: not in {manifest_path}, but the layout needs it; {hint}"
        )
    for name, rec in sorted(listed.items()):
        path = directory / name
        if not path.is_file():
            raise InputError(f"{path}: missing; {hint}")
        if not isinstance(rec, dict) or path.stat().st_size != rec.get("bytes"):
            raise InputError(f"{path}: size differs from {manifest_path} (truncated or corrupted); {hint}")
        if sha256_file(path) != rec.get("sha256"):
            raise InputError(f"{path}: checksum differs from {manifest_path} (corrupted); {hint}")


def expected_files(lay: dict) -> set:
    """The files (relative to the sample directory) a sample of layout ``lay`` must hold."""
    files = set(lay["photos"].values()) | set(lay["flash_only"].values())
    files |= set(lay["env_exemplars"]) | set(lay["point_exemplars"]) | set(lay["maps"].values())
    return files | {lay["env"], lay["meta"], "maps/material.json"}


def index_entry(root: Path, index: int) -> dict:
    """The index entry of a complete sample (from its sample.json and manifest)."""
    directory = Path(root) / sample_dirname(index)
    meta = read_json(directory / SAMPLE_JSON)
    env = meta["env"]
    return {
        "index": int(index),
        "dir": sample_dirname(index),
        "material": meta["material"].get("spec"),
        "env": env.get("spec") or (env.get("map") or {}).get("name") or env.get("path") or env["type"],
        "env_type": env["type"],
        "lobes": int(env["lobes"]),
        "manifest_sha256": sha256_file(directory / MANIFEST),
    }


def write_index(root: Path, count: int, fingerprint: str) -> dict:
    """Write ``index.json`` for samples 0 … count − 1 (all must be complete); returns it."""
    index = {
        "format": INDEX_FORMAT,
        "count": int(count),
        "fingerprint": fingerprint,
        "samples": [index_entry(root, i) for i in range(int(count))],
    }
    atomic_write_text(Path(root) / INDEX_JSON, dumps(index))
    return index


# -- reading ----------------------------------------------------------------------------------------


def load_sample(root: Path, dataset: dict, index: int) -> dict:
    """Arrays of one sample (numpy float32, linear), by role, in the layout of ``dataset.json``:

    ``photos`` {shot: (H, W, 3)} (PNGs decoded from sRGB), ``flash_only`` {shot: (H, W, 3)},
    ``env_exemplars`` / ``point_exemplars`` [(H, W, 3)], ``maps`` {name: (H, W, 3) or (H, W) for
    roughness}, ``env`` :class:`~ebr_mitsuba.sgenv.SGEnvironment`, ``meta`` (sample.json).
    """
    from ..imageio import read_image
    from ..sgenv import SGEnvironment

    directory = Path(root) / sample_dirname(index)
    lay = dataset["layout"]
    out = {
        "photos": {k: read_image(directory / v, "srgb") for k, v in lay["photos"].items()},
        "flash_only": {k: read_image(directory / v) for k, v in lay["flash_only"].items()},
        "env_exemplars": [read_image(directory / v) for v in lay["env_exemplars"]],
        "point_exemplars": [read_image(directory / v) for v in lay["point_exemplars"]],
        "maps": {k: read_image(directory / v) for k, v in lay["maps"].items()},
        "env": SGEnvironment.load(directory / lay["env"]),
        "meta": read_json(directory / lay["meta"]),
    }
    out["maps"]["roughness"] = np.asarray(out["maps"]["roughness"][..., 0])
    return out
