"""The phases of ``ebr train`` as small objects (the table of phases is in :mod:`.trainer`).

:func:`plan_phases` lists a run's phases — :class:`PhasePlan` (name, steps, trained modules, initial
learning rate) — without computing anything; :func:`build_phase` makes the :class:`Phase` of one plan
once the cache it reads exists. A phase holds everything it reads as constructor arguments: the
:class:`PhaseInputs` every phase shares (training data, device, capture, loss options), the module
whose forward it runs (``top``; the trainer wraps it in DDP and hands the wrapped one back as
``model``) and, for the cascade phases, its cache (stage 1 or stage 2, :mod:`.cache`) and its
forward (:func:`first_stage_forward` or :func:`full_forward`); a MAIR phase (:class:`MAIRPhase`)
its stage and the multi-view geometry (:class:`MultiViewInputs`). Its one method the training
loop calls is ``loss(model, idx, gen) → (loss, {term: value})``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import torch

from ..model.config import LossConfig, MAIRLossConfig, TrainConfig
from ..model.renders import cascade_forward, diffuse_flash_renderer
from ..nets import Maps
from ..nets.losses import (
    MapWeights,
    entropy_regulariser,
    masked_angular_l1,
    masked_mse,
    multiview_rerender_loss,
    parameter_l1,
    rendering_loss,
    sample_view_light_pairs,
    scale_invariant_log_mse,
    scale_invariant_mse,
)
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
    capture: str  # "near" or "near-far" (ebrenv; "near" for dualloss and mair, unused there)
    flash_intensity: float  # the data set's nominal flash intensity
    weights: MapWeights
    loss: LossConfig | MAIRLossConfig

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


@dataclass(frozen=True)
class MultiViewInputs:
    """What a MAIR phase reads besides :class:`PhaseInputs`: the geometry of the views of the 3×3
    capture the model reads, on the data set's grid (:mod:`ebr_mitsuba.nets.mair_views`), and g4's
    direction grid.

    The N views are those ``MAIRConfig.views`` selects
    (:func:`~ebr_mitsuba.nets.mair_views.selected_shots`): all 9 (``"all"``) or the centre camera's
    alone (``"centre"``, N = 1), in :func:`~ebr_mitsuba.nets.mair_views.multiview_shots` order.
    ``shots``: the data set's index of each of them; ``directions`` (N, 3, H, W) and ``weights``
    (N, 1, H, W) their per-pixel directions and in-frame weights; ``cameras`` (N, 3) their camera
    (= flash) positions; ``lighting_directions`` (D, 3) where g4 compares the incident radiance.
    """

    shots: tuple[int, ...]
    directions: torch.Tensor
    weights: torch.Tensor
    cameras: torch.Tensor
    lighting_directions: torch.Tensor

    @classmethod
    def build(cls, data: TrainingData, loss: MAIRLossConfig, device, *, views: str) -> MultiViewInputs:
        """The inputs of the views ``views`` (``MAIRConfig.views``) selects."""
        from ..nets.mair_lighting import hemisphere_directions
        from ..nets.mair_views import in_frame_weights, selected_shots, view_direction_maps

        shots = selected_shots(views)
        h, w = data.maps.shape[-2:]
        return cls(
            tuple(data.shot(s.name) for s in shots),
            view_direction_maps(h, w, shots).to(device),
            in_frame_weights(h, w, shots).to(device),
            torch.tensor([s.camera for s in shots], dtype=torch.float32, device=device),
            hemisphere_directions(loss.lighting_rows, loss.lighting_cols, device=device),
        )


class MAIRBatch(NamedTuple):
    """One batch of a MAIR phase: ``views`` (B, N, 3, H, W) — the photos at the reference exposure
    (clamped at 0) times their in-frame weights, so the networks see what a rectified camera
    capture shows —, ``directions`` (B, N, 3, H, W), ``weights`` (B, N, 1, H, W), the true maps,
    the true incident radiance (B, 3D, H, W) at the g4 directions (lighting stage; else None) and
    ``unclipped`` (B, N, 1, H, W): 0 where a channel of the photo saturated (camera value ≥
    :data:`CLIP_LEVEL`), which the re-render loss leaves out."""

    views: torch.Tensor
    directions: torch.Tensor
    weights: torch.Tensor
    target: Maps
    radiance: torch.Tensor | None
    unclipped: torch.Tensor


CLIP_LEVEL = 254.5 / 255.0  # a photo value (camera units) at or above this counts as saturated


def incident_radiance(lobes: Sequence[torch.Tensor], directions: torch.Tensor) -> torch.Tensor:
    """Radiance ``Σ_k μ_k exp(λ_k(ξ_k·ω − 1))`` of each sample's lobes (K_b, 7) at directions
    (D, 3): (B, D, 3)."""
    out = []
    for lb in lobes:
        lb = lb.to(directions)
        cos = directions @ lb[:, :3].T  # (D, K)
        out.append(torch.exp(lb[:, 3] * (cos - 1.0)) @ lb[:, 4:])
    return torch.stack(out)


class MAIRPhase(Phase):
    """One of MAIR's stages (``normal``, ``lighting``, ``brdf``: :data:`MAIRModel.STAGES`), trained
    in turn with the others frozen, on the views of each multi-view sample the model reads
    (``views``, a :class:`MultiViewInputs`: all 9, or the centre one for ``MAIRConfig.views =
    "centre"``; every loss, the re-render loss included, sees those N views only). ``top`` is the
    module whose forward runs: the normal net, the lighting net, or the whole model for ``brdf``;
    ``mair`` the :class:`~ebr_mitsuba.nets.MAIRModel`.

    Losses (weights of :class:`~ebr_mitsuba.model.config.MAIRLossConfig`):

    * ``normal``: g1 angular L1 + g2 MSE of the normals;
    * ``lighting``: g4 scale-invariant log-MSE of the per-pixel incident radiance at the
      ``lighting_rows × lighting_cols`` hemisphere grid against the data set's lobes (``env.json``,
      in photo units: on the unoccluded plane every pixel sees that distant environment, visibility
      1), + g5 binary entropy of the visibility μ;
    * ``brdf``: g3 scale-invariant MSE of the diffuse map, g2 MSE of the specular and roughness
      maps, the multi-view re-render loss (:func:`~ebr_mitsuba.nets.mair_render.multiview_renders`
      under the predicted lighting and each view's flash, least-squares τ_d, τ_s; saturated
      photo pixels left out).
    """

    def __init__(self, plan: PhasePlan, inputs: PhaseInputs, mair: torch.nn.Module, views: MultiViewInputs):
        top = {"normal": mair.normal_net, "lighting": mair.lighting_net}.get(plan.name, mair)
        super().__init__(plan, inputs, top)
        self.mair, self.views = mair, views

    def batch(self, idx: torch.Tensor) -> MAIRBatch:
        x, d, v = self.inputs, self.inputs.data, self.views
        photos = d.photos[idx][:, list(v.shots)].to(x.device).clamp_min(0.0)
        b = photos.shape[0]
        camera_units = photos * d.exposure[idx].to(photos).view(b, 1, 1, 1, 1)
        unclipped = (camera_units < CLIP_LEVEL).all(dim=2, keepdim=True).to(photos.dtype)
        weights = v.weights.expand(b, *v.weights.shape)
        directions = v.directions.expand(b, *v.directions.shape)
        radiance = None
        if self.name == "lighting":
            r = incident_radiance(d.lobes(idx), v.lighting_directions)  # (B, D, 3)
            h, w = photos.shape[-2:]
            radiance = r.reshape(b, -1, 1, 1).expand(b, r.shape[1] * 3, h, w)
        return MAIRBatch(photos * weights, directions, weights, x.target(idx), radiance, unclipped)

    def loss(self, model, idx, gen):
        c: MAIRLossConfig = self.inputs.loss
        bt = self.batch(idx)
        if self.name == "normal":
            normal = model(bt.views, bt.directions, bt.weights)
            g1 = masked_angular_l1(normal, bt.target.normal)
            g2 = masked_mse(normal, bt.target.normal)
            return c.angular * g1 + c.normal * g2, {"angular": g1, "normal_mse": g2}
        if self.name == "lighting":
            with torch.no_grad():
                normal = self.mair.normal_net(bt.views, bt.directions, bt.weights)
            lighting = model(bt.views, bt.directions, normal, bt.weights)
            pred = lighting.radiance_image(self.views.lighting_directions)
            g4 = scale_invariant_log_mse(pred, bt.radiance)
            g5 = entropy_regulariser(lighting.visibility_distribution(), dim=1)
            return c.lighting * g4 + c.visibility * g5, {"lighting": g4, "visibility": g5}
        from ..nets.mair_render import multiview_renders

        out = model(bt.views, bt.directions, bt.weights)
        m, t = out.maps, bt.target
        g3 = scale_invariant_mse(m.diffuse, t.diffuse)
        spec = masked_mse(m.specular, t.specular)
        rough = masked_mse(m.roughness, t.roughness)
        diffuse_r, specular_r = multiview_renders(
            m, out.lighting, bt.directions, self.views.cameras, self.inputs.flash_intensity
        )
        rr, _ = multiview_rerender_loss(bt.views, diffuse_r, specular_r, bt.weights * bt.unclipped)
        loss = c.diffuse * g3 + c.specular * spec + c.roughness * rough + c.rerender * rr
        return loss, {"diffuse": g3, "specular": spec, "roughness": rough, "rerender": rr}


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
    if c.kind == "mair":
        m = bundle.mair
        plans = [
            PhasePlan(stage, c.stages.steps(stage), tuple(getattr(m, n) for n in names), t.lr)
            for stage, names in m.STAGES.items()
        ]
        return [p for p in plans if p.steps > 0]
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
    if bundle.kind == "mair":
        views = MultiViewInputs.build(inputs.data, inputs.loss, inputs.device, views=bundle.mair.config.views)
        return MAIRPhase(plan, inputs, bundle.mair, views)
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
    "MAIRBatch",
    "MAIRPhase",
    "MultiViewInputs",
    "Phase",
    "PhaseInputs",
    "PhasePlan",
    "build_phase",
    "first_stage_forward",
    "full_forward",
    "incident_radiance",
    "plan_phases",
]
