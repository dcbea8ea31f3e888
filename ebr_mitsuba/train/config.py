"""Training configuration: typed TOML tables, every default in this one file, unknown keys rejected.

Precedence: the defaults below < the config file < the command line (``ebr train --out``).
Errors name the file and the key (``train_small.toml: [train].lr: expected float, got 'fast'``).

A config has a top-level ``kind`` and five tables::

    kind = "ebrenv"                 # "ebrenv" (lighting net + cascade) or "dualloss"

    [data]                          # DataConfig
    [model]                         # ebrenv: lighting/cascade options; dualloss: DualLossConfig
    [train]                         # TrainOptions (seed, batch, learning rate, device, logging)
    [stages]                        # ebrenv: steps per phase (StageSteps)
    [loss]                          # LossConfig

**[data]**

=================  ======  =========  ========================================================
key                type    default    meaning
=================  ======  =========  ========================================================
``train``          str     required   data set directory (``ebr generate``); ``$VAR`` and ``~``
                                      expanded, relative paths from the config file's directory
``max_samples``    int     0          use the first N samples only (0: all)
=================  ======  =========  ========================================================

**[model]** (ebrenv) — ``size`` (NAFNet preset ``"paper"``/``"small"`` or a table, every net),
``capture`` (``near``), ``use_exemplars``, ``use_cascade``, ``use_refinement`` (the §5.3.2
ablations), ``log_eps``. The number of lighting-net exemplars and their roughness values come
from the data set (``[exemplars].env_roughness``). (dualloss) — the fields of
:class:`ebr_mitsuba.nets.DualLossConfig`.

**[train]**

=====================  ======  ========  ===================================================
key                    type    default   meaning
=====================  ======  ========  ===================================================
``seed``               int     0         seeds torch, the sample order and the loss sampling
``steps``              int     1000      dualloss: training steps (ebrenv: see [stages])
``batch_size``         int     8         samples per step (per process under DDP)
``lr``                 float   1e-3      initial learning rate of every phase (Adam)
``lr_final``           float   1e-5      learning rate at the end of a phase (cosine decay)
``weight_decay``       float   0.0       Adam weight decay
``device``             str     ``auto``  ``auto`` (CUDA when present), ``cpu``, ``cuda``
``threads``            int     0         torch CPU threads (0: torch's default)
``log_every``          int     10        steps between loss read-backs (CSV row, bar update)
``checkpoint_every``   int     200       steps between checkpoints (and at each phase end)
``init``               str     ``""``    checkpoint whose matching weights start the run
=====================  ======  ========  ===================================================

**[stages]** (ebrenv; steps per phase, run in this order; 0 skips a phase)

==============  ======  =======  ============================================================
key             type    default  phase
==============  ======  =======  ============================================================
``lighting``    int     1000     stage 1: lighting net (shots → exemplars, flash-only)
``diffuse``     int     1000     stage 1: diffuse net (or the joint net without cascade), GT env
``specular``    int     1000     stage 1: specular net, diffuse net frozen, GT env
``refinement``  int     1000     stage 1: refinement net, first stage frozen, GT env residuals
``finetune``    int     500      stage 2: whole cascade on the extracted SGs (cached on disk)
``finetune_lr`` float   1e-4     initial learning rate of stage 2
``finetune_samples`` int 200     samples whose extracted SGs stage 2 caches and trains on
==============  ======  =======  ============================================================

**[selection]** — :class:`ebr_mitsuba.extract.select.SelectConfig` fields for the exemplar
selection of training and inference; defaults :data:`SELECTION_DEFAULTS` (closed-form SG
renders at a 16-pixel comparison: about 0.4 s per sample at 64², against 1.3 s for the
selection's own defaults). **[extract]** — :class:`ebr_mitsuba.extract.ExtractConfig` fields of
the SG extraction in stage 2 and at inference; defaults :data:`EXTRACT_DEFAULTS`.

[stages], [selection] and [extract] apply to ``kind = "ebrenv"`` alone: a dualloss config that
sets one is refused, and :meth:`TrainConfig.to_dict` (the config a checkpoint carries) leaves
them out for a dualloss config.

**[loss]**

=====================  ======  =======  ===========================================================
key                    type    default  meaning
=====================  ======  =======  ===========================================================
``normal``             float   1.0      weight of the normal map's L1
``diffuse``            float   1.0      weight of the diffuse map's L1
``specular``           float   1.0      weight of the specular map's L1
``roughness``          float   1.0      weight of the roughness map's L1
``render``             float   0.0      ebrenv: weight of the rendering loss in refinement and
                                        stage 2; dualloss: weight of the rendering loss (1.0 there)
``render_pairs``       int     10       view/light pairs per step of the rendering loss
``render_highlights``  int     5        of which forced highlights
=====================  ======  =======  ===========================================================
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomllib

from ..errors import ConfigError

KINDS = ("ebrenv", "dualloss")
PHASES = ("lighting", "diffuse", "specular", "refinement", "finetune")


@dataclass(frozen=True)
class DataConfig:
    train: str = ""
    max_samples: int = 0


@dataclass(frozen=True)
class TrainOptions:
    seed: int = 0
    steps: int = 1000
    batch_size: int = 8
    lr: float = 1e-3
    lr_final: float = 1e-5
    weight_decay: float = 0.0
    device: str = "auto"
    threads: int = 0
    log_every: int = 10
    checkpoint_every: int = 200
    init: str = ""


@dataclass(frozen=True)
class StageSteps:
    lighting: int = 1000
    diffuse: int = 1000
    specular: int = 1000
    refinement: int = 1000
    finetune: int = 500
    finetune_lr: float = 1e-4
    finetune_samples: int = 200

    def steps(self, phase: str) -> int:
        return int(getattr(self, phase))


@dataclass(frozen=True)
class LossConfig:
    normal: float = 1.0
    diffuse: float = 1.0
    specular: float = 1.0
    roughness: float = 1.0
    render: float = 0.0
    render_pairs: int = 10
    render_highlights: int = 5


@dataclass(frozen=True)
class TrainConfig:
    """A whole training config (see the module docstring). ``model`` is the raw [model] table,
    turned into network configs by :meth:`lighting_config`, :meth:`cascade_config`,
    :meth:`dualloss_config`."""

    kind: str
    data: DataConfig
    model: dict
    train: TrainOptions = field(default_factory=TrainOptions)
    stages: StageSteps = field(default_factory=StageSteps)
    loss: LossConfig = field(default_factory=LossConfig)
    selection: dict = field(default_factory=dict)
    extract: dict = field(default_factory=dict)
    source: str = "<memory>"

    def to_dict(self) -> dict:
        """Plain data (for the checkpoint and ``config.json``): the tables of this ``kind`` only
        (a dualloss config has no [stages], [selection] or [extract]), so that
        :func:`config_from_dict` accepts what it wrote."""
        out = {
            "kind": self.kind,
            "data": dataclasses.asdict(self.data),
            "model": _plain(self.model),
            "train": dataclasses.asdict(self.train),
            "stages": dataclasses.asdict(self.stages),
            "loss": dataclasses.asdict(self.loss),
            "selection": _plain(self.selection),
            "extract": _plain(self.extract),
        }
        if self.kind != "ebrenv":
            for name in EBRENV_TABLES:
                del out[name]
        return out

    def select_config(self):
        from ..extract.select import SelectConfig
        from ..nets._config import dataclass_from_dict

        return dataclass_from_dict(
            SelectConfig, {**SELECTION_DEFAULTS, **self.selection}, f"{self.source}: [selection]"
        )

    def extract_config(self):
        from ..extract import ExtractConfig

        try:
            return ExtractConfig.from_dict({**EXTRACT_DEFAULTS, **self.extract})
        except ConfigError as exc:
            raise ConfigError(f"{self.source}: [extract]: {exc}") from None

    def lighting_config(self, num_exemplars: int):
        from ..nets import LightingNetConfig

        m = self.model
        table = {k: m[k] for k in ("size", "capture", "log_eps") if k in m}
        return LightingNetConfig.from_dict(
            {**table, "num_exemplars": num_exemplars}, f"{self.source}: [model]"
        )

    def cascade_config(self):
        from ..nets import CascadeConfig

        m = self.model
        table = {
            k: m[k] for k in ("size", "use_exemplars", "use_cascade", "use_refinement", "log_eps") if k in m
        }
        photos = 4 if m.get("capture", "near") == "near-far" else 2
        return CascadeConfig.from_dict({**table, "num_photos": photos}, f"{self.source}: [model]")

    def dualloss_config(self):
        from ..nets import DualLossConfig

        return DualLossConfig.from_dict(self.model, f"{self.source}: [model]")


SELECTION_DEFAULTS = {"env_mode": "sg", "compare_size": 16}
EXTRACT_DEFAULTS = {"iters": 100, "max_lobes": 16}
EBRENV_TABLES = ("stages", "selection", "extract")  # tables that apply to kind = "ebrenv" alone
EBRENV_MODEL_KEYS = ("size", "capture", "use_exemplars", "use_cascade", "use_refinement", "log_eps")


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if dataclasses.is_dataclass(value):
        return _plain(dataclasses.asdict(value))
    return value


def _table(cls, data, where: str):
    if data is None:
        return cls()
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table, got {type(data).__name__}")
    hints = {f.name: f.type for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(hints))
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}: unknown key; allowed: {', '.join(sorted(hints))}")
    defaults = cls()
    out = {}
    for key, value in data.items():
        expected = type(getattr(defaults, key))
        ok = (
            (isinstance(value, expected) and not isinstance(value, bool))
            if expected is not bool
            else isinstance(value, bool)
        )
        if expected is float and isinstance(value, int) and not isinstance(value, bool):
            value, ok = float(value), True
        if not ok:
            raise ConfigError(f"{where}.{key}: expected {expected.__name__}, got {value!r}")
        out[key] = value
    return cls(**out)


def _expand(text: str, where: str, base: Path) -> str:
    def var(name):
        if name not in os.environ:
            raise ConfigError(f"{where}: ${name} is not set; export it or write the path out")
        return os.environ[name]

    import re

    text = re.sub(r"\$\{(\w+)\}|\$(\w+)", lambda m: var(m.group(1) or m.group(2)), text)
    path = Path(text).expanduser()
    return str(path if path.is_absolute() else (base / path))


def parse_config(doc: dict[str, Any], source: str = "<memory>", base_dir: str | Path = ".") -> TrainConfig:
    """Validate a parsed TOML document (see the module docstring); ``source`` names it in errors."""
    allowed = {"kind", "data", "model", "train", "stages", "loss", "selection", "extract"}
    unknown = sorted(set(doc) - allowed)
    if unknown:
        raise ConfigError(
            f"{source}: '{unknown[0]}' is not a known table or key; use {', '.join(sorted(allowed))}"
        )
    kind = doc.get("kind", "ebrenv")
    if kind not in KINDS:
        raise ConfigError(f"{source}: kind = {kind!r}; use one of {', '.join(KINDS)}")
    data = _table(DataConfig, doc.get("data"), f"{source}: [data]")
    if not data.train:
        raise ConfigError(f"{source}: [data].train is required (a data set directory from 'ebr generate')")
    data = dataclasses.replace(data, train=_expand(data.train, f"{source}: [data].train", Path(base_dir)))
    if data.max_samples < 0:
        raise ConfigError(f"{source}: [data].max_samples must be >= 0")
    train = _table(TrainOptions, doc.get("train"), f"{source}: [train]")
    if train.init:
        train = dataclasses.replace(
            train, init=_expand(train.init, f"{source}: [train].init", Path(base_dir))
        )
    for key in ("batch_size", "log_every", "checkpoint_every"):
        if getattr(train, key) < 1:
            raise ConfigError(f"{source}: [train].{key} must be >= 1")
    if not (train.lr > 0 and 0 < train.lr_final <= train.lr):
        raise ConfigError(f"{source}: [train] needs lr > 0 and 0 < lr_final <= lr")
    if train.device not in ("auto", "cpu", "cuda"):
        raise ConfigError(f"{source}: [train].device = {train.device!r}; use auto, cpu or cuda")
    stages = _table(StageSteps, doc.get("stages"), f"{source}: [stages]")
    if any(stages.steps(p) < 0 for p in PHASES) or stages.finetune_samples < 0 or not stages.finetune_lr > 0:
        raise ConfigError(f"{source}: [stages] step and sample counts must be >= 0 and finetune_lr > 0")
    if kind == "dualloss" and doc.get("stages") is not None:
        raise ConfigError(f"{source}: [stages] is for kind = 'ebrenv'; a dualloss config sets [train].steps")
    for name in ("selection", "extract"):
        if kind == "dualloss" and doc.get(name) is not None:
            raise ConfigError(
                f"{source}: [{name}] is for kind = 'ebrenv' (exemplars and SG lighting); remove it "
                f"from this dualloss config"
            )
    if train.steps < 0:
        raise ConfigError(f"{source}: [train].steps must be >= 0")
    loss = _table(LossConfig, doc.get("loss"), f"{source}: [loss]")
    if not 0 <= loss.render_highlights <= loss.render_pairs or loss.render_pairs < 1:
        raise ConfigError(
            f"{source}: [loss] needs 1 <= render_pairs and 0 <= render_highlights <= render_pairs"
        )
    model = doc.get("model") or {}
    if not isinstance(model, dict):
        raise ConfigError(f"{source}: [model] must be a table")
    tables = {}
    for name in ("selection", "extract"):
        table = doc.get(name) or {}
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: [{name}] must be a table")
        tables[name] = dict(table)
    config = TrainConfig(
        kind, data, dict(model), train, stages, loss, tables["selection"], tables["extract"], source
    )
    # Build the network configs once so that bad model keys fail here, before any work.
    if kind == "ebrenv":
        unknown = sorted(set(model) - set(EBRENV_MODEL_KEYS))
        if unknown:
            raise ConfigError(
                f"{source}: [model].{unknown[0]}: unknown key; allowed: {', '.join(EBRENV_MODEL_KEYS)}"
            )
        config.lighting_config(4)
        config.cascade_config()
        config.select_config()
        config.extract_config()
    else:
        config.dualloss_config()
    return config


def load_config(path: str | Path) -> TrainConfig:
    """Read and validate a training config file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such config file")
    try:
        doc = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None
    return parse_config(doc, source=path.name, base_dir=path.resolve().parent)


def config_from_dict(data: dict) -> TrainConfig:
    """Rebuild a config stored in a checkpoint (paths are already absolute)."""
    return parse_config(data, source="<checkpoint>", base_dir="/")


__all__ = [
    "DataConfig",
    "EBRENV_TABLES",
    "EXTRACT_DEFAULTS",
    "KINDS",
    "SELECTION_DEFAULTS",
    "LossConfig",
    "PHASES",
    "StageSteps",
    "TrainConfig",
    "TrainOptions",
    "config_from_dict",
    "load_config",
    "parse_config",
]
