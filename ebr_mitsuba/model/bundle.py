"""A trained model in memory: its networks, its configs and the facts of its training data.

:class:`ModelBundle` is what :func:`ebr_mitsuba.model.predict.load_model` returns and what the
trainer builds. ``facts`` (:class:`DataFacts`) records what the networks assume about their
inputs: the grid resolution, the roughness values of the lighting net's exemplars, the nominal
flash intensity and the capture setup.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from ..data import store
from ..errors import ConfigError, InputError
from .config import TrainConfig, config_from_dict


@dataclass(frozen=True)
class DataFacts:
    """What a model knows about its training data (stored in every checkpoint)."""

    resolution: int
    env_roughness: tuple[float, ...]
    point_roughness: tuple[float, ...]
    flash_intensity: float
    setup: str

    @staticmethod
    def from_dataset(root: str | Path) -> DataFacts:
        root = Path(root)
        path = root / store.DATASET_JSON
        d = store.read_doc(
            path,
            store.DATASET_FORMAT,
            f"generate the data set with 'ebr generate ... --out {root}' (or finish it with --resume)",
        )
        h, w = (int(v) for v in d["resolution"])
        if h != w:
            raise InputError(f"{path}: resolution {h}x{w}; training needs square images")
        cfg = d["config"]
        return DataFacts(
            h,
            tuple(float(r) for r in cfg["exemplars"]["env_roughness"]),
            tuple(float(r) for r in cfg["exemplars"]["point_roughness"]),
            float(cfg["capture"]["flash_intensity"]),
            str(d["setup"]),
        )

    @staticmethod
    def from_dict(data: dict) -> DataFacts:
        return DataFacts(
            int(data["resolution"]),
            tuple(data["env_roughness"]),
            tuple(data["point_roughness"]),
            float(data["flash_intensity"]),
            str(data["setup"]),
        )

    def to_dict(self) -> dict:
        d = asdict(self)
        d["env_roughness"], d["point_roughness"] = list(self.env_roughness), list(self.point_roughness)
        return d


@dataclass
class ModelBundle:
    """Networks + configs of one model. ``kind`` ``"ebrenv"``: ``lighting`` and ``cascade`` are
    set; ``"dualloss"``: ``dualloss`` is set; ``"mair"``: ``mair`` (a :class:`~ebr_mitsuba.nets.MAIRModel`)
    is set. ``resolution`` is the model grid (square)."""

    kind: str
    config: TrainConfig
    facts: DataFacts
    lighting: torch.nn.Module | None = None
    cascade: torch.nn.Module | None = None
    dualloss: torch.nn.Module | None = None
    mair: torch.nn.Module | None = None
    device: torch.device = torch.device("cpu")
    meta: dict | None = None

    @property
    def resolution(self) -> int:
        return self.facts.resolution

    def nets(self) -> dict[str, torch.nn.Module]:
        return {
            name: net
            for name in ("lighting", "cascade", "dualloss", "mair")
            if (net := getattr(self, name)) is not None
        }

    def state(self) -> dict:
        return {name: net.state_dict() for name, net in self.nets().items()}

    def load_state(self, state: dict, where: str, strict: bool = True) -> None:
        """Load state dicts by net name; ``strict=False`` loads only the tensors whose names and
        shapes match (initialising one model from another)."""
        for name, net in self.nets().items():
            if name not in state:
                if strict:
                    raise InputError(
                        f"{where}: checkpoint has no '{name}' weights; it belongs to another model"
                    )
                continue
            weights = {k: v.float() if v.is_floating_point() else v for k, v in state[name].items()}
            if not strict:  # initialisation from another model: take the tensors that fit
                own = net.state_dict()
                weights = {k: v for k, v in weights.items() if k in own and own[k].shape == v.shape}
            try:
                net.load_state_dict(weights, strict=strict)
            except RuntimeError as exc:
                raise InputError(
                    f"{where}: '{name}' weights do not fit this network "
                    f"({str(exc).splitlines()[0][:100]}); check the config"
                ) from None

    def train(self, mode: bool = True) -> ModelBundle:
        for net in self.nets().values():
            net.train(mode)
        return self


def net_configs(bundle: ModelBundle) -> dict:
    """The network configs as plain data (for the checkpoint)."""
    from .config import _plain

    return {name: _plain(net.config) for name, net in bundle.nets().items()}


def build_bundle(config: TrainConfig, facts: DataFacts, device: torch.device | str = "cpu") -> ModelBundle:
    """Fresh networks for ``config`` on data with ``facts``."""
    from ..nets import Cascade, DualLossNet, LightingNet, MAIRModel

    device = torch.device(device)
    if config.kind == "mair":
        return ModelBundle(
            "mair", config, facts, mair=MAIRModel(config.mair_config()).to(device), device=device
        )
    if config.kind == "dualloss":
        return ModelBundle(
            "dualloss",
            config,
            facts,
            dualloss=DualLossNet(config.dualloss_config()).to(device),
            device=device,
        )
    lighting = LightingNet(config.lighting_config(len(facts.env_roughness))).to(device)
    cascade = Cascade(config.cascade_config()).to(device)
    return ModelBundle("ebrenv", config, facts, lighting=lighting, cascade=cascade, device=device)


def bundle_from_checkpoint(data: dict, where: str, device: torch.device | str = "cpu") -> ModelBundle:
    """Rebuild the networks of a loaded checkpoint (:func:`.checkpoint.load_checkpoint`)."""
    try:
        config = config_from_dict(data["config"])
        facts = DataFacts.from_dict(data["data"])
    except (KeyError, TypeError, ValueError, ConfigError) as exc:
        raise InputError(f"{where}: damaged checkpoint config ({exc}); retrain or re-export it") from None
    bundle = build_bundle(config, facts, device)
    bundle.load_state(data["model"], where)
    bundle.meta = {k: data.get(k) for k in ("git", "version", "step", "metrics")}
    return bundle


__all__ = ["DataFacts", "ModelBundle", "build_bundle", "bundle_from_checkpoint", "net_configs"]
