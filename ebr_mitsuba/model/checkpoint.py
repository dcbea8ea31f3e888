"""Checkpoints of ``ebr train``: one ``torch.save`` file, written atomically.

A checkpoint is a dict (``format = "ebr-checkpoint/1"``):

==================  ===========================================================================
key                 content
==================  ===========================================================================
``format``          ``"ebr-checkpoint/1"``
``kind``            ``"ebrenv"`` (lighting net + cascade), ``"dualloss"`` or ``"mair"``
``config``          the training config as plain data (:meth:`TrainConfig.to_dict`)
``model``           ``{"lighting": {...}, "cascade": {...}}``, ``{"dualloss": {...}}`` or
                    ``{"mair": {...}}``: state
                    dicts (tensors; float16 in an exported model, float32 otherwise)
``net_config``      the network configs as plain data (enough to rebuild the nets)
``data``            what the model needs from its training data: ``resolution``,
                    ``env_roughness``, ``point_roughness``, ``flash_intensity``
``step``            ``{"phase": name, "step": n}``: where training stands (resume point)
``optimizer``       optimizer and scheduler state of the current phase (None in exports)
``rng``             torch/numpy RNG states for an exact resume (None in exports)
``git``             the source tree's commit hash (``"unknown"`` outside a git checkout)
``version``         ebr-mitsuba version
``summary``         per phase of this run: steps, final loss, seconds (training checkpoints;
                    kept in exports)
``lineage``         exports only: the runs this model was warm-started from, earliest first
                    (:func:`lineage_entry`); ``[]`` for a model trained from scratch
==================  ===========================================================================

:func:`save_checkpoint` writes through :func:`ebr_mitsuba.fsutil.atomic_path` (a killed run never
leaves a half-written file under the final name). :func:`load_checkpoint` raises
:class:`~ebr_mitsuba.errors.InputError` with one line naming the file for a missing, corrupt or
foreign file and for a checkpoint of the wrong ``kind``.

Older dualloss checkpoints (before issue 14) carry the ebrenv-only tables ``stages``,
``selection`` and ``extract`` in their ``config`` (defaults the user never wrote, which the config
parser refuses for a dualloss config); :func:`load_checkpoint` drops them (:func:`upgrade_config`),
so those checkpoints load, evaluate and resume like new ones.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import torch

from .. import __version__
from ..errors import InputError
from ..fsutil import atomic_path
from .config import DROPPED_TABLES

CHECKPOINT_FORMAT = "ebr-checkpoint/1"
KINDS = ("ebrenv", "dualloss", "mair")
REQUIRED = ("format", "kind", "config", "model", "net_config", "data", "step")


def git_hash(start: Path | None = None) -> str:
    """The commit hash of the git checkout holding this package ("unknown" if none)."""
    root = start or Path(__file__).resolve().parents[2]
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10, check=False
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    text = out.stdout.strip()
    return text if out.returncode == 0 and len(text) == 40 else "unknown"


def save_checkpoint(path: str | Path, payload: dict) -> Path:
    """Write ``payload`` (the keys of the module docstring; ``format``, ``git`` and ``version`` are
    filled in) atomically to ``path``."""
    path = Path(path)
    missing = [k for k in REQUIRED if k not in payload and k != "format"]
    if missing:
        raise ValueError(f"save_checkpoint: payload lacks {', '.join(missing)}")
    if payload["kind"] not in KINDS:
        raise ValueError(f"save_checkpoint: kind {payload['kind']!r} is not one of {KINDS}")
    full = {
        "format": CHECKPOINT_FORMAT,
        "git": git_hash(),
        "version": __version__,
        "optimizer": None,
        "rng": None,
        **payload,
    }
    full["format"] = CHECKPOINT_FORMAT
    with atomic_path(path) as tmp:
        torch.save(full, tmp)
    return path


def upgrade_config(kind: str, config):
    """The stored ``config`` of a ``kind`` checkpoint as :meth:`TrainConfig.to_dict` writes it now:
    without the tables that apply to other kinds (older dualloss checkpoints carried
    ``stages``, ``selection`` and ``extract``; :data:`~.config.DROPPED_TABLES`). Anything but a
    dict is returned unchanged."""
    dropped = DROPPED_TABLES.get(kind, ())
    if not dropped or not isinstance(config, dict):
        return config
    return {k: v for k, v in config.items() if k not in dropped}


def load_checkpoint(path: str | Path, expect_kind: str | None = None, map_location="cpu") -> dict:
    """Read a checkpoint; check its format and (if given) its kind.

    Raises :class:`InputError` naming ``path`` when the file is missing, unreadable, not an
    ``ebr train`` checkpoint, or of another kind than ``expect_kind``.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint file; give a checkpoint written by 'ebr train'")
    try:
        data = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch raises many types for corrupt / foreign files
        reason = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise InputError(
            f"{path}: not a readable checkpoint ({reason}); give a checkpoint written by 'ebr train'"
        ) from None
    if not isinstance(data, dict) or data.get("format") != CHECKPOINT_FORMAT:
        raise InputError(
            f"{path}: not an ebr model checkpoint (no format '{CHECKPOINT_FORMAT}'); give a "
            f"checkpoint written by 'ebr train'"
        )
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise InputError(
            f"{path}: checkpoint lacks {', '.join(missing)}; it is damaged, retrain or re-export it"
        )
    data["config"] = upgrade_config(data["kind"], data["config"])
    if expect_kind is not None and data["kind"] != expect_kind:
        raise InputError(
            f"{path}: a '{data['kind']}' checkpoint, but this needs a '{expect_kind}' one "
            f"(wrong kind); give a checkpoint of the right model"
        )
    return data


def lineage_entry(path: str | Path, data: dict) -> dict:
    """One run of a model's lineage, described from its checkpoint ``data`` (read from ``path``):
    ``checkpoint`` (the path it was read from), ``git``, ``resolution`` (its grid), ``train_data``
    (its ``[data].train``) and ``phases`` (name → steps and seconds; ``{}`` when the checkpoint
    carries no summary, as exports before the lineage did not)."""
    summary = data.get("summary") if isinstance(data.get("summary"), dict) else {}
    phases = {
        name: {"steps": int(p.get("steps", 0)), "seconds": float(p.get("seconds", 0.0))}
        for name, p in summary.get("phases", {}).items()
    }
    config = data.get("config") if isinstance(data.get("config"), dict) else {}
    return {
        "checkpoint": str(path),
        "git": data.get("git", "unknown"),
        "resolution": data.get("data", {}).get("resolution"),
        "train_data": config.get("data", {}).get("train"),
        "phases": phases,
    }


def lineage(data: dict) -> list[dict]:
    """The runs a checkpoint (``data``) was warm-started from, earliest first: its own ``lineage``
    when it is an export that has one; else its ``[train].init`` checkpoint's lineage plus that
    checkpoint itself (one entry, ``{"checkpoint": path, "missing": True}``, when the init file is
    gone); ``[]`` without an init."""
    if isinstance(data.get("lineage"), list):
        return data["lineage"]
    config = data.get("config") if isinstance(data.get("config"), dict) else {}
    init = config.get("train", {}).get("init")
    if not init:
        return []
    if not Path(init).is_file():
        return [{"checkpoint": str(init), "missing": True}]
    parent = load_checkpoint(init)
    return [*lineage(parent), lineage_entry(init, parent)]


def export_model(checkpoint: str | Path, out: str | Path, half: bool = True) -> Path:
    """A deployable copy of ``checkpoint``: weights (float16 when ``half``), configs, data facts,
    step, git hash, its run's summary and its :func:`lineage`; no optimizer or RNG state (what
    ships in :mod:`ebr_mitsuba.models`)."""
    data = load_checkpoint(checkpoint)

    def convert(state: dict) -> dict:
        return {k: (v.half() if half and v.is_floating_point() else v) for k, v in state.items()}

    model = {name: convert(state) for name, state in data["model"].items()}
    payload = {k: data[k] for k in REQUIRED if k != "format"}
    payload.update(
        model=model,
        optimizer=None,
        rng=None,
        git=data.get("git", "unknown"),
        version=data.get("version", __version__),
    )
    if "metrics" in data:
        payload["metrics"] = data["metrics"]
    if isinstance(data.get("summary"), dict):
        payload["summary"] = data["summary"]
    payload["lineage"] = lineage(data)
    out = Path(out)
    with atomic_path(out) as tmp:
        torch.save({"format": CHECKPOINT_FORMAT, **payload}, tmp)
    return out


__all__ = [
    "CHECKPOINT_FORMAT",
    "KINDS",
    "export_model",
    "git_hash",
    "lineage",
    "lineage_entry",
    "load_checkpoint",
    "save_checkpoint",
    "upgrade_config",
]
