"""The phases of ``ebr train`` as small objects (the table of phases is in :mod:`.trainer`).

:func:`plan_phases` lists a run's phases — :class:`PhasePlan` (name, steps, trained modules, initial
learning rate) — without computing anything; :func:`build_phase` makes the :class:`Phase` of one plan
once the cache it reads exists. A phase holds everything it reads as constructor arguments: the
:class:`PhaseInputs` every phase shares (training data, device, capture, loss options), the module
whose forward it runs (``top``; the trainer wraps it in DDP and hands the wrapped one back as
``model``) and, for the cascade phases, its cache (stage 1 or stage 2, :mod:`.cache`) and its
forward (:func:`first_stage_forward` or :func:`full_forward`). Its one method the training loop
calls is ``loss(model, idx, gen) → (loss, {term: value})``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import torch

from ..model.config import LossConfig, TrainConfig
from ..model.renders import cascade_forward, diffuse_flash_renderer
from ..nets import Maps
from ..nets.losses import MapWeights, parameter_l1, rendering_loss, sample_view_light_pairs
from ..nets.transforms import log_input
from .data import CAPTURE_SHOTS, TrainingData


class PhasePlan(NamedTuple):
    """One phase of a run before it is built: ``modules`` are the ones it trains."""

    name: str
    steps: int
    modules: tuple[torch.nn.Module, ...]
    lr: float


@dataclass(frozen=True)
class PhaseInputs:
    """What every phase reads; none of it changes during the run."""

    data: TrainingData
    device: torch.device
    capture: str  # "near" or "near-far" (ebrenv; "near" for dualloss, unused there)
    flash_intensity: float  # the data set's nominal flash intensity
    weights: MapWeights
    loss: LossConfig

    def target(self, idx: torch.Tensor) -> Maps:
        return Maps.unstack(self.data.maps[idx].to(self.device))

    def shots(self, idx: torch.Tensor) -> torch.Tensor:
        """The capture's shots (B, 3S, H, W): the lighting net's input and the refinement's photos."""
        return self.data.shots(idx, CAPTURE_SHOTS[self.capture]).to(self.device)

    def view_light_pairs(self, count: int, gen: torch.Generator):
        return sample_view_light_pairs(
            count, gen, self.loss.render_pairs, self.loss.render_highlights, device=self.device
        )


class Phase:
    """A phase: ``name``, ``steps``, ``lr``, ``modules`` (trained), ``top`` (the module whose
    forward :meth:`loss` runs), ``size`` (the samples it draws batches from) and :meth:`loss`."""

    def __init__(self, plan: PhasePlan, inputs: PhaseInputs, top: torch.nn.Module):
        self.name, self.steps, self.modules, self.lr = plan
        self.inputs, self.top = inputs, top

    @property
    def size(self) -> int:
        return len(self.inputs.data)

    def loss(self, model, idx: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, dict]:
        """The loss of batch ``idx`` (sample indices) with ``model`` (``top``, DDP-wrapped under
        torchrun) and the per-term values; ``gen`` draws the rendering loss's view/light pairs."""
        raise NotImplementedError


class LightingPhase(Phase):
    """Shots → exemplars + flash-only image: L1 of ``log(x + ε)`` against the data set's."""

    def loss(self, model, idx, gen):
        x, d, dev = self.inputs, self.inputs.data, self.inputs.device
        out = model(x.shots(idx))
        ex = (log_input(out.exemplars) - log_input(d.env_exemplars[idx].to(dev))).abs().mean()
        fo = (log_input(out.flash_only) - log_input(d.flash_only_of(idx).to(dev))).abs().mean()
        return ex + fo, {"exemplars": ex, "flash_only": fo}


class DualLossPhase(Phase):
    """Parameter L1 + ``render`` × the rendering loss (Dr.Jit point-light renderer)."""

    def loss(self, model, idx, gen):
        x = self.inputs
        target = x.target(idx)
        pred = model(x.data.photos[idx].to(x.device))
        loss, parts = parameter_l1(pred, target, x.weights)
        if x.loss.render > 0:
            from ..nets.drwrap import point_light_renderer

            pairs = x.view_light_pairs(len(idx), gen)
            r = rendering_loss(pred, target, pairs, point_light_renderer(x.flash_intensity))
            loss, parts = loss + x.loss.render * r, {**parts, "render": r}
        return loss, parts


class CascadeBatch(NamedTuple):
    """The cascade's inputs for one batch (shapes as in :meth:`ebr_mitsuba.nets.Cascade.forward`)."""

    noflash: torch.Tensor
    flash_only: torch.Tensor
    env_exemplars: torch.Tensor | None
    point_exemplars: torch.Tensor | None
    photos: torch.Tensor
    lobes: Sequence[torch.Tensor]
    far_flash_only: torch.Tensor | None


CascadeForward = Callable[[torch.nn.Module, CascadeBatch, float], object]
"""``(cascade or its DDP wrapper, batch, flash intensity) → CascadeOutput``."""


def first_stage_forward(cascade, batch: CascadeBatch, flash_intensity: float):
    """The cascade without its refinement (``refine=False``): diffuse → specular, or the joint net."""
    return cascade(
        batch.noflash,
        batch.flash_only,
        batch.env_exemplars,
        batch.point_exemplars,
        render_diffuse_flash=diffuse_flash_renderer(flash_intensity),
        refine=False,
    )


def full_forward(cascade, batch: CascadeBatch, flash_intensity: float):
    """The whole cascade as inference runs it (:func:`ebr_mitsuba.model.renders.cascade_forward`)."""
    return cascade_forward(
        cascade,
        batch.noflash,
        batch.flash_only,
        batch.env_exemplars,
        batch.point_exemplars,
        batch.photos,
        batch.lobes,
        flash_intensity,
        batch.far_flash_only,
    )


class CascadePhase(Phase):
    """A phase of the material cascade.

    ``stage`` 1 reads the ground-truth flash-only image and SGs, and the stage-1 cache (``cache``;
    None without exemplars); stage 2 reads the stage-2 cache (the lighting net's flash-only image,
    the extracted SGs, their selections) and draws from its samples only. ``forward`` (kept as
    ``stage_forward``) runs the cascade. The loss: with ``keys`` (first-stage phases), the weighted
    L1 of those maps of the first stage; otherwise the parameter L1 of the final maps, plus that of
    the first-stage ones with ``coarse``, plus ``render`` × the rendering loss.
    """

    def __init__(
        self,
        plan: PhasePlan,
        inputs: PhaseInputs,
        cascade: torch.nn.Module,
        *,
        stage: int,
        cache: dict | None,
        forward: CascadeForward,
        keys: tuple[str, ...] = (),
        coarse: bool = False,
    ):
        super().__init__(plan, inputs, cascade)
        self.stage, self.cache, self.keys, self.coarse = stage, cache, keys, coarse
        self.stage_forward = forward

    @property
    def size(self) -> int:
        return len(self.cache["flash_only"]) if self.stage == 2 else len(self.inputs.data)

    def batch(self, idx: torch.Tensor) -> CascadeBatch:
        x, d, dev, src = self.inputs, self.inputs.data, self.inputs.device, self.cache
        noflash = d.photos[idx, d.shot("noflash")].to(dev)
        photos = x.shots(idx)
        far_fo = d.far_flash_only(idx).to(dev) if x.capture == "near-far" else None
        if self.stage == 2:
            flash_only = src["flash_only"][idx].to(dev)
            lobes = [src["sg"][int(i)].to(dev) for i in idx]
        else:
            flash_only = d.flash_only_of(idx).to(dev)
            lobes = [lb.to(dev) for lb in d.lobes(idx)]
        env_ex = src["env_images"][idx].to(dev) if src is not None and "env_images" in src else None
        point_ex = src["point_images"][idx].to(dev) if src is not None and "point_images" in src else None
        return CascadeBatch(noflash, flash_only, env_ex, point_ex, photos, lobes, far_fo)

    def forward(self, model, idx: torch.Tensor):
        """The cascade's output for batch ``idx``."""
        return self.stage_forward(model, self.batch(idx), self.inputs.flash_intensity)

    def loss(self, model, idx, gen):
        x = self.inputs
        target = x.target(idx)
        out = self.forward(model, idx)
        if self.keys:
            m = out.coarse
            parts = {k: (getattr(m, k) - getattr(target, k)).abs().mean() for k in self.keys}
            return sum(getattr(x.weights, k) * v for k, v in parts.items()), parts
        loss, parts = parameter_l1(out.maps, target, x.weights)
        if self.coarse:
            coarse, _ = parameter_l1(out.coarse, target, x.weights)
            loss, parts = loss + coarse, {**parts, "coarse": coarse}
        if x.loss.render > 0:
            from ..nets import torch_brdf as tb

            pairs = x.view_light_pairs(len(idx), gen)
            r = rendering_loss(
                out.maps,
                target,
                pairs,
                lambda m, cam, light: tb.render_point_light(m, light, x.flash_intensity, cam),
            )
            loss, parts = loss + x.loss.render * r, {**parts, "render": r}
        return loss, parts


FIRST_STAGE_KEYS = {
    "joint": ("normal", "diffuse", "specular", "roughness"),
    "diffuse": ("normal", "diffuse"),
    "specular": ("specular", "roughness"),
}


def plan_phases(config: TrainConfig, bundle) -> list[PhasePlan]:
    """The phases of a run in order; phases with nothing to train (0 steps) dropped."""
    c, t = config, config.train
    if c.kind == "dualloss":
        return [PhasePlan("dualloss", t.steps, (bundle.dualloss,), t.lr)]
    cas = bundle.cascade
    out = [PhasePlan("lighting", c.stages.lighting, (bundle.lighting,), t.lr)]
    if cas.joint_net is not None:
        out.append(PhasePlan("diffuse", c.stages.diffuse, (cas.joint_net,), t.lr))
    else:
        out += [
            PhasePlan("diffuse", c.stages.diffuse, (cas.diffuse_net,), t.lr),
            PhasePlan("specular", c.stages.specular, (cas.specular_net,), t.lr),
        ]
    if cas.refinement_net is not None:
        out.append(PhasePlan("refinement", c.stages.refinement, (cas.refinement_net,), t.lr))
    if c.stages.finetune > 0 and c.stages.finetune_samples > 0:
        out.append(PhasePlan("finetune", c.stages.finetune, (cas,), c.stages.finetune_lr))
    return [p for p in out if p.steps > 0]


def build_phase(plan: PhasePlan, inputs: PhaseInputs, bundle, caches) -> Phase:
    """The phase of ``plan``, with the cache it reads from ``caches`` (a :class:`.cache.RunCaches`:
    filled and loaded here when first needed — stage 1 only with exemplars)."""
    name = plan.name
    if name == "lighting":
        return LightingPhase(plan, inputs, bundle.lighting)
    if name == "dualloss":
        return DualLossPhase(plan, inputs, bundle.dualloss)
    cascade = bundle.cascade
    if name == "finetune":
        return CascadePhase(
            plan, inputs, cascade, stage=2, cache=caches.stage2(bundle), forward=full_forward, coarse=True
        )
    cache = caches.stage1() if cascade.config.use_exemplars else None
    if name == "refinement":
        return CascadePhase(plan, inputs, cascade, stage=1, cache=cache, forward=full_forward)
    keys = FIRST_STAGE_KEYS["joint" if cascade.joint_net is not None else name]
    return CascadePhase(plan, inputs, cascade, stage=1, cache=cache, forward=first_stage_forward, keys=keys)


__all__ = [
    "CascadeBatch",
    "CascadePhase",
    "DualLossPhase",
    "LightingPhase",
    "Phase",
    "PhaseInputs",
    "PhasePlan",
    "build_phase",
    "first_stage_forward",
    "full_forward",
    "plan_phases",
]
