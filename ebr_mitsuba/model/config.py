"""The config a model is trained from and carries in every checkpoint: typed TOML tables, every
default in this one file, unknown keys rejected.

``ebr train`` reads it (:func:`load_config`); :func:`ebr_mitsuba.model.bundle.bundle_from_checkpoint`
rebuilds a model's networks, extraction and selection settings from the copy in its checkpoint
(:func:`config_from_dict`), so the model package owns it and does not depend on
:mod:`ebr_mitsuba.train`.

Precedence: the defaults below < the config file < the command line (``ebr train --out``).
Errors name the file and the key (``train_small.toml: train.lr: expected float (a number), got 'fast'``),
in the one format of :mod:`ebr_mitsuba.typedconfig`.

A config has a top-level ``kind`` and five tables::

    kind = "ebrenv"                 # "ebrenv" (lighting net + cascade), "dualloss" or "mair"

    [data]                          # DataConfig
    [model]                         # ebrenv: lighting/cascade options; dualloss: DualLossConfig;
                                    # mair: MAIRConfig
    [train]                         # TrainOptions (seed, batch, learning rate, device, logging)
    [stages]                        # ebrenv: steps per phase (StageSteps); mair: MAIRStageSteps
    [loss]                          # LossConfig; mair: MAIRLossConfig

**[data]** (:class:`DataConfig`)

.. options:: DataConfig

**[model]** (ebrenv) — ``size`` (NAFNet preset ``"tiny"``/``"small"``/``"medium"``/``"paper"`` or a
table, every net), ``cascade_size`` (the cascade's nets alone, the lighting net keeping ``size``: the
size curve of ``ebr bench sizes`` varies it over one lighting net),
``capture`` (``near``), ``use_exemplars``, ``use_cascade``, ``use_refinement`` (the §5.3.2
ablations), ``log_eps``. The number of lighting-net exemplars and their roughness values come
from the data set (``[exemplars].env_roughness``). (dualloss) — the fields of
:class:`ebr_mitsuba.nets.DualLossConfig`. (mair) — the fields of
:class:`ebr_mitsuba.nets.MAIRConfig` (``size`` = ``"tiny"`` | ``"small"`` | ``"paper"`` or a table).

**[train]** (:class:`TrainOptions`)

.. options:: TrainOptions

**[stages]** (ebrenv, :class:`StageSteps`; steps per phase, run in this order; 0 skips a phase)

.. options:: StageSteps

**[selection]** — :class:`ebr_mitsuba.exemplar.select.SelectConfig` fields for the exemplar
selection of training and inference over the named preset ``SELECT_PRESETS["training"]``
(closed-form SG renders at a 16-pixel comparison: about 0.4 s per sample at 64², against 1.3 s
for the selection's own defaults). **[extract]** — :class:`ebr_mitsuba.extract.ExtractConfig`
fields of the SG extraction in stage 2 and at inference over ``EXTRACT_PRESETS["training"]``.
Their tables with these defaults are in ``docs/config.md``.

[stages], [selection] and [extract] apply to ``kind = "ebrenv"`` alone: a dualloss config that
sets one is refused, and :meth:`TrainConfig.to_dict` (the config a checkpoint carries) leaves
them out for a dualloss config. A ``mair`` config has [stages] (its own, :class:`MAIRStageSteps`)
and refuses [selection] and [extract].

**[loss]** (:class:`LossConfig`)

.. options:: LossConfig

**[stages]** (mair, :class:`MAIRStageSteps`; MAIR's stages in order, 0 skips one)

.. options:: MAIRStageSteps

**[loss]** (mair, :class:`MAIRLossConfig`; the MAIR losses of :mod:`ebr_mitsuba.nets.losses`)

.. options:: MAIRLossConfig
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ..typedconfig import (
    Meta,
    check,
    config,
    convert,
    document,
    expand_path,
    from_dict,
    option,
    read_toml,
    unknown_keys,
)

KINDS = ("ebrenv", "dualloss", "mair")
PHASES = ("lighting", "diffuse", "specular", "refinement", "finetune")
MAIR_PHASES = ("normal", "lighting", "brdf")  # MAIRModel.STAGES, trained in this order


@config
class DataConfig:
    """The ``[data]`` table."""

    train: str = option(
        "",
        "data set directory (ebr generate); $VAR and ~ expanded, relative paths from the config "
        "file's directory",
        required=True,
        shown="required",
    )
    max_samples: int = option(0, "use the first N samples only (0: all)", minimum=0)


@config
class TrainOptions:
    """The ``[train]`` table."""

    seed: int = option(0, "seeds torch, the sample order and the loss sampling")
    steps: int = option(1000, "dualloss: training steps (ebrenv, mair: see [stages])", minimum=0)
    batch_size: int = option(8, "samples per step (per process under DDP)", minimum=1)
    lr: float = option(1e-3, "initial learning rate of every phase (Adam)", above=0)
    lr_final: float = option(1e-5, "learning rate at the end of a phase (cosine decay); at most lr", above=0)
    weight_decay: float = option(0.0, "Adam weight decay")
    device: str = option("auto", "auto (CUDA when present), cpu, cuda", choices=("auto", "cpu", "cuda"))
    threads: int = option(0, "torch CPU threads (0: torch's default)")
    log_every: int = option(10, "steps between loss read-backs (CSV row, bar update)", minimum=1)
    checkpoint_every: int = option(200, "steps between checkpoints (and at each phase end)", minimum=1)
    init: str = option("", "checkpoint whose matching weights start the run")
    init_nets: list[str] = option(
        [],
        'the nets of init that start the run (empty: all); ["lighting"]: the cascade starts from scratch',
        choices=("lighting", "cascade", "dualloss", "mair"),
    )

    def __post_init__(self):
        check(self)
        if self.lr_final > self.lr:
            raise ConfigError(f"TrainOptions: lr_final: must be <= lr ({self.lr:g}), got {self.lr_final:g}")


@config
class StageSteps:
    """The ``[stages]`` table (kind = "ebrenv")."""

    lighting: int = option(1000, "stage 1: lighting net (shots → exemplars, flash-only)", minimum=0)
    diffuse: int = option(1000, "stage 1: diffuse net (or the joint net without cascade), GT env", minimum=0)
    specular: int = option(1000, "stage 1: specular net, diffuse net frozen, GT env", minimum=0)
    refinement: int = option(1000, "stage 1: refinement net, first stage frozen, GT env residuals", minimum=0)
    finetune: int = option(500, "stage 2: whole cascade on the extracted SGs (cached on disk)", minimum=0)
    finetune_lr: float = option(1e-4, "initial learning rate of stage 2", above=0)
    finetune_samples: int = option(200, "samples whose extracted SGs stage 2 caches and trains on", minimum=0)

    def steps(self, phase: str) -> int:
        return int(getattr(self, phase))


@config
class LossConfig:
    """The ``[loss]`` table."""

    normal: float = option(1.0, "weight of the normal map's L1")
    diffuse: float = option(1.0, "weight of the diffuse map's L1")
    specular: float = option(1.0, "weight of the specular map's L1")
    roughness: float = option(1.0, "weight of the roughness map's L1")
    render: float = option(
        0.0,
        "ebrenv: weight of the rendering loss in refinement and stage 2; dualloss: weight of the "
        "rendering loss (1.0 there)",
    )
    render_pairs: int = option(10, "view/light pairs per step of the rendering loss", minimum=1)
    render_highlights: int = option(5, "of which forced highlights (at most render_pairs)", minimum=0)

    def __post_init__(self):
        check(self)
        if self.render_highlights > self.render_pairs:
            raise ConfigError(
                f"LossConfig: render_highlights: must be <= render_pairs ({self.render_pairs}), "
                f"got {self.render_highlights}"
            )


@config
class MAIRStageSteps:
    """The ``[stages]`` table (kind = "mair"): steps of each MAIR stage, trained in this order."""

    normal: int = option(1000, "normal net: g1 angular L1 + g2 MSE on the normals", minimum=0)
    lighting: int = option(
        1000, "per-pixel SG lighting net: g4 on the incident lighting + g5 visibility entropy", minimum=0
    )
    brdf: int = option(
        1000,
        "SpecNet, MVANet and RefineNet (normal and lighting nets frozen): g3 diffuse, g2 specular and "
        "roughness, multi-view re-render loss",
        minimum=0,
    )

    def steps(self, phase: str) -> int:
        return int(getattr(self, phase))


@config
class MAIRLossConfig:
    """The ``[loss]`` table (kind = "mair"): weights of MAIR's losses, each stage its own terms."""

    angular: float = option(1.0, "normal stage: g1, masked angular L1 of the normals (radians)", minimum=0)
    normal: float = option(1.0, "normal stage: g2, masked MSE of the normals", minimum=0)
    lighting: float = option(
        1.0,
        "lighting stage: g4, scale-invariant log-MSE of the per-pixel incident radiance against "
        "the data set's (env.json)",
        minimum=0,
    )
    visibility: float = option(0.01, "lighting stage: g5, binary entropy of the SG visibility μ", minimum=0)
    lighting_rows: int = option(8, "g4 direction grid: polar rows over the upper hemisphere", minimum=1)
    lighting_cols: int = option(16, "g4 direction grid: azimuth columns", minimum=1)
    diffuse: float = option(1.0, "brdf stage: g3, scale-invariant MSE of the diffuse map", minimum=0)
    specular: float = option(1.0, "brdf stage: g2, MSE of the specular map", minimum=0)
    roughness: float = option(1.0, "brdf stage: g2, MSE of the roughness map", minimum=0)
    rerender: float = option(
        1.0,
        "brdf stage: multi-view re-render loss Σ_k w_k‖I_k − τ_d Ĩ_d,k − τ_s Ĩ_s,k‖² (least-squares τ)",
        minimum=0,
    )


@dataclass(frozen=True)
class TrainConfig:
    """A whole training config (see the module docstring). ``model`` is the raw [model] table,
    turned into network configs by :meth:`lighting_config`, :meth:`cascade_config`,
    :meth:`dualloss_config`."""

    kind: str
    data: DataConfig
    model: dict
    train: TrainOptions = field(default_factory=TrainOptions)
    stages: StageSteps | MAIRStageSteps = field(default_factory=StageSteps)
    loss: LossConfig | MAIRLossConfig = field(default_factory=LossConfig)
    selection: dict = field(default_factory=dict)
    extract: dict = field(default_factory=dict)
    source: str = "<memory>"

    def to_dict(self) -> dict:
        """Plain data (for the checkpoint and ``config.json``): the tables of this ``kind`` only
        (a dualloss config has no [stages], [selection] or [extract], a mair config no
        [selection] or [extract]), so that :func:`config_from_dict` accepts what it wrote."""
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
        for name in DROPPED_TABLES[self.kind]:
            del out[name]
        return out

    def select_config(self):
        """The exemplar selection: ``[selection]`` over ``SELECT_PRESETS["training"]``."""
        from ..exemplar.select import SELECT_PRESETS, SelectConfig

        return from_dict(
            SelectConfig, self.selection, self.source, key="selection", base=SELECT_PRESETS[SELECT_PRESET]
        )

    def extract_config(self):
        """The SG extraction: ``[extract]`` over ``EXTRACT_PRESETS["training"]``."""
        from ..extract.config import EXTRACT_PRESETS, ExtractConfig

        return from_dict(
            ExtractConfig, self.extract, self.source, key="extract", base=EXTRACT_PRESETS[EXTRACT_PRESET]
        )

    def lighting_config(self, num_exemplars: int):
        from ..nets import LightingNetConfig

        m = self.model
        table = {k: m[k] for k in ("size", "capture", "log_eps") if k in m}
        return LightingNetConfig.from_dict(
            {**table, "num_exemplars": num_exemplars}, self.source, key="model"
        )

    def cascade_config(self):
        from ..nets import CascadeConfig

        m = self.model
        table = {
            k: m[k] for k in ("size", "use_exemplars", "use_cascade", "use_refinement", "log_eps") if k in m
        }
        if "cascade_size" in m:  # the cascade's own size; the lighting net keeps ``size``
            table["size"] = m["cascade_size"]
        photos = 4 if m.get("capture", "near") == "near-far" else 2
        return CascadeConfig.from_dict({**table, "num_photos": photos}, self.source, key="model")

    def dualloss_config(self):
        from ..nets import DualLossConfig

        return DualLossConfig.from_dict(self.model, self.source, key="model")

    def mair_config(self):
        from ..nets import MAIRConfig

        return MAIRConfig.from_dict(self.model, self.source, key="model")


SELECT_PRESET = "training"  # the SELECT_PRESETS entry [selection] overrides
EXTRACT_PRESET = "training"  # the EXTRACT_PRESETS entry [extract] overrides
EBRENV_TABLES = ("stages", "selection", "extract")  # tables that apply to kind = "ebrenv" alone
# the tables a config of each kind does not have (parse_config refuses them, to_dict leaves them out)
DROPPED_TABLES = {"ebrenv": (), "dualloss": EBRENV_TABLES, "mair": ("selection", "extract")}
EBRENV_MODEL_KEYS = (
    "size",
    "cascade_size",
    "capture",
    "use_exemplars",
    "use_cascade",
    "use_refinement",
    "log_eps",
)


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if dataclasses.is_dataclass(value):
        return _plain(dataclasses.asdict(value))
    return value


def _expand(text: str, source: str, key: str, base: Path) -> str:
    return str(expand_path(text, base, where=source, key=key))


TABLES = {"data": DataConfig, "train": TrainOptions, "stages": StageSteps, "loss": LossConfig}
MAIR_TABLES = {"stages": MAIRStageSteps, "loss": MAIRLossConfig}  # replace TABLES' for kind = "mair"


def parse_config(doc: dict[str, Any], source: str = "<memory>", base_dir: str | Path = ".") -> TrainConfig:
    """Validate a parsed TOML document (see the module docstring); ``source`` names it in errors."""
    allowed = ("kind", "data", "model", "train", "stages", "loss", "selection", "extract")
    unknown_keys(doc, allowed, where=source, noun="table or key")
    kind = convert(doc.get("kind", "ebrenv"), str, Meta("", choices=KINDS), where=source, key="kind")
    classes = {**TABLES, **MAIR_TABLES} if kind == "mair" else TABLES
    tables = {name: from_dict(cls, doc.get(name) or {}, source, key=name) for name, cls in classes.items()}
    data, train = tables["data"], tables["train"]
    if not data.train:
        raise ConfigError(f"{source}: data.train: is required (a data set directory from 'ebr generate')")
    base = Path(base_dir)
    data = dataclasses.replace(data, train=_expand(data.train, source, "data.train", base))
    if train.init:
        train = dataclasses.replace(train, init=_expand(train.init, source, "train.init", base))
    for name in DROPPED_TABLES[kind]:
        if doc.get(name) is not None:
            fix = (
                "; a dualloss config sets [train].steps"
                if name == "stages"
                else f" (exemplars and SG lighting); remove it from this {kind} config"
            )
            raise ConfigError(f"{source}: [{name}] is for kind = 'ebrenv'{fix}")
    raw = {}
    for name in ("model", "selection", "extract"):
        table = doc.get(name) or {}
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: {name}: expected a table, got {table!r}")
        raw[name] = dict(table)
    model = raw["model"]
    config = TrainConfig(
        kind, data, model, train, tables["stages"], tables["loss"], raw["selection"], raw["extract"], source
    )
    # Build the network configs once so that bad model keys fail here, before any work.
    if kind == "ebrenv":
        unknown_keys(model, EBRENV_MODEL_KEYS, where=source, key="model")
        config.lighting_config(4)
        config.cascade_config()
        config.select_config()
        config.extract_config()
    elif kind == "mair":
        config.mair_config()
    else:
        config.dualloss_config()
    return config


def load_config(path: str | Path) -> TrainConfig:
    """Read and validate a training config file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such config file")
    return parse_config(read_toml(path), source=path.name, base_dir=path.resolve().parent)


def config_from_dict(data: dict) -> TrainConfig:
    """Rebuild a config stored in a checkpoint (paths are already absolute)."""
    return parse_config(data, source="<checkpoint>", base_dir="/")


__all__ = [
    "DataConfig",
    "DROPPED_TABLES",
    "EBRENV_TABLES",
    "EXTRACT_PRESET",
    "KINDS",
    "SELECT_PRESET",
    "LossConfig",
    "MAIRLossConfig",
    "MAIRStageSteps",
    "MAIR_PHASES",
    "PHASES",
    "StageSteps",
    "TrainConfig",
    "TrainOptions",
    "config_from_dict",
    "load_config",
    "parse_config",
]

__doc__ = document(
    __doc__,
    DataConfig=DataConfig,
    TrainOptions=TrainOptions,
    StageSteps=StageSteps,
    LossConfig=LossConfig,
    MAIRStageSteps=MAIRStageSteps,
    MAIRLossConfig=MAIRLossConfig,
)
