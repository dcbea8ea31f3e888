"""``ebr dataset verify``: check every sample of a generated data set and its index.

Checks, in order (each failure is one line naming the file):

1. ``dataset.json`` exists, is JSON of format ``ebr-dataset/1`` with a layout;
2. ``index.json`` exists, is JSON of format ``ebr-index/1`` with the same fingerprint, and lists
   samples 0 … count − 1 in order, each pointing to its own directory, as many as ``dataset.json``
   asks for; an interrupted run (no ``index.json``: it is written last) or ``--count`` extension
   (the counts differ) is one failure that says how many samples are complete and that
   ``ebr generate ... --resume`` finishes the set;
3. per sample: the directory and ``manifest.json`` exist; every file the manifest lists exists with
   the recorded size and SHA-256; no file is missing from the manifest or from the layout;
   ``sample.json`` parses and has the right index; the manifest's SHA-256 equals the index entry's;
   every image reads (:func:`ebr_mitsuba.imageio.read_image`) with the data set's resolution, the
   expected channel count (3, roughness 1) and finite values; ``env.json`` loads as an SG
   environment;
4. notes (not failures): leftover ``.partial`` directories of killed runs, and sample directories
   beyond ``count``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import EbrError
from . import store


@dataclass
class VerifyReport:
    """``errors`` (failures), ``notes`` (harmless findings), ``samples`` checked."""

    root: str
    samples: int = 0
    errors: list = field(default_factory=list)
    notes: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors

    def to_json(self) -> dict:
        return {
            "root": self.root,
            "ok": self.ok,
            "samples": self.samples,
            "errors": self.errors,
            "notes": self.notes,
        }


def _load_json(path: Path, report: VerifyReport, fmt: str | None = None) -> dict | None:
    if not path.is_file():
        report.errors.append(f"{path}: missing")
        return None
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        report.errors.append(f"{path}: not valid JSON ({exc})")
        return None
    if not isinstance(doc, dict):
        report.errors.append(f"{path}: expected a JSON object")
        return None
    if fmt is not None and doc.get("format") != fmt:
        report.errors.append(f"{path}: format is {doc.get('format')!r}, expected {fmt!r}")
        return None
    return doc


def _check_sample(root: Path, entry: dict, i: int, dataset: dict, report: VerifyReport) -> None:
    from ..imageio import read_image
    from ..sgenv import SGEnvironment

    rel = store.sample_dirname(i)
    directory = root / rel
    if entry.get("index") != i or entry.get("dir") != rel:
        report.errors.append(
            f"{root / store.INDEX_JSON}: entry {i} is {entry.get('index')}/"
            f"{entry.get('dir')}, expected {i}/{rel}"
        )
    if not directory.is_dir():
        report.errors.append(f"{directory}: sample directory missing")
        return
    manifest = _load_json(directory / store.MANIFEST, report, store.MANIFEST_FORMAT)
    if manifest is None:
        return
    if entry.get("manifest_sha256") != store.sha256_file(directory / store.MANIFEST):
        report.errors.append(f"{directory / store.MANIFEST}: its SHA-256 differs from the one in index.json")
    listed = manifest.get("files", {})
    present = {p.relative_to(directory).as_posix() for p in directory.rglob("*") if p.is_file()}
    present.discard(store.MANIFEST)
    for name in sorted(present - set(listed)):
        report.errors.append(f"{directory / name}: not listed in the manifest")
    lay = dataset["layout"]
    for name in sorted(store.expected_files(lay) - set(listed)):
        report.errors.append(f"{directory / name}: missing from the manifest (the layout needs it)")
    bad = set()
    for name, rec in sorted(listed.items()):
        path = directory / name
        if not path.is_file():
            report.errors.append(f"{path}: missing")
            bad.add(name)
            continue
        if path.stat().st_size != rec.get("bytes") or store.sha256_file(path) != rec.get("sha256"):
            report.errors.append(f"{path}: checksum or size differs from the manifest (corrupted)")
            bad.add(name)
    res = tuple(dataset["resolution"])
    images = [
        (f, 3)
        for f in list(lay["photos"].values())
        + list(lay["flash_only"].values())
        + lay["env_exemplars"]
        + lay["point_exemplars"]
    ]
    images += [(f, 1 if name == "roughness" else 3) for name, f in lay["maps"].items()]
    for name, channels in images:
        if name in bad or not (directory / name).is_file():
            continue
        try:
            read_image(
                directory / name,
                "srgb" if name.endswith(".png") else "linear",
                expect_channels=channels,
                expect_shape=res,
            )
        except EbrError as exc:
            report.errors.append(str(exc))
    if lay["env"] not in bad and (directory / lay["env"]).is_file():
        try:
            SGEnvironment.load(directory / lay["env"])
        except EbrError as exc:
            report.errors.append(str(exc))
    if lay["meta"] not in bad:
        meta = _load_json(directory / lay["meta"], report, store.SAMPLE_FORMAT)
        if meta is not None and meta.get("index") != i:
            report.errors.append(f"{directory / lay['meta']}: index {meta.get('index')}, expected {i}")
    report.samples += 1


def verify(root: str | Path, progress: bool = False) -> VerifyReport:
    """Check the data set at ``root`` (module docstring); returns a :class:`VerifyReport`."""
    from tqdm import tqdm

    root = Path(root)
    report = VerifyReport(str(root))
    if not root.is_dir():
        report.errors.append(f"{root}: no such directory")
        return report
    dataset = _load_json(root / store.DATASET_JSON, report, store.DATASET_FORMAT)
    if dataset is not None and not (root / store.INDEX_JSON).exists():
        # the run writes index.json last: this is an interrupted run, not a damaged file
        count = dataset.get("count")
        done = store.count_complete(root, count) if isinstance(count, int) else 0
        report.errors.append(
            f"{root / store.INDEX_JSON}: missing: the run was interrupted with {done} of "
            f"{count} samples complete; rerun the 'ebr generate ... --out {root}' command "
            f"with --resume to finish it"
        )
        return report
    index = _load_json(root / store.INDEX_JSON, report, store.INDEX_FORMAT)
    if dataset is None or index is None:
        return report
    if not isinstance(dataset.get("layout"), dict) or not isinstance(dataset.get("resolution"), list):
        report.errors.append(
            f"{root / store.DATASET_JSON}: no 'layout' or 'resolution'; regenerate the data set"
        )
        return report
    if index.get("fingerprint") != dataset.get("fingerprint"):
        report.errors.append(f"{root / store.INDEX_JSON}: fingerprint differs from dataset.json's")
    if dataset.get("count") != index.get("count"):
        # dataset.json is rewritten when a run starts, index.json when it ends
        count = dataset.get("count")
        done = store.count_complete(root, count) if isinstance(count, int) else 0
        report.errors.append(
            f"{root}: dataset.json asks for {count} samples but index.json lists "
            f"{index.get('count')}: an interrupted --count extension with {done} of {count} "
            f"samples complete; rerun 'ebr generate ... --out {root} --count {count} "
            f"--resume' to finish it"
        )
    entries = index.get("samples", [])
    count = index.get("count")
    if not isinstance(entries, list) or count != len(entries):
        report.errors.append(
            f"{root / store.INDEX_JSON}: 'count' is {count} but it lists "
            f"{len(entries) if isinstance(entries, list) else 'no'} samples"
        )
        entries = entries if isinstance(entries, list) else []
    for i, entry in enumerate(
        tqdm(entries, desc="verify", unit="sample", disable=None if progress else True, leave=False)
    ):
        _check_sample(root, entry if isinstance(entry, dict) else {}, i, dataset, report)
    samples_dir = root / store.SAMPLES
    if samples_dir.is_dir():
        for p in sorted(samples_dir.iterdir()):
            if p.name.endswith(".partial"):
                report.notes.append(f"{p}: left over by an interrupted run (--resume removes it)")
            elif p.is_dir() and p.name.isdigit() and int(p.name) >= len(entries):
                report.notes.append(f"{p}: beyond the indexed count {len(entries)}")
    return report
