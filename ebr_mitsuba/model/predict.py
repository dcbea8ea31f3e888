"""Running a trained model: photos in, maps + SG lighting out (``docs/conventions.md``, "Pipeline").

:func:`load_model` reads a checkpoint (None: the model shipped in :mod:`ebr_mitsuba.models`) as a
:class:`~.bundle.ModelBundle`; :func:`load_predictor` wraps it as a :class:`ModelPredictor`, the
:class:`~.predictor.Predictor` that ``ebr estimate``, ``ebr eval``, the benches and the trainer's
cache take (a ``dualloss`` model: a :class:`DualLossPredictor`, the
:class:`~.predictor.LightsPredictor` of ``ebr eval`` and the five-light bench; a ``mair`` model: a
:class:`MAIRPredictor`, the :class:`~.predictor.ViewsPredictor` of ``ebr estimate --views``). :func:`predict`
runs, on numpy (H, W, 3) linear float32 images at the model grid (``bundle.resolution``):

==============  ==========================================================================
stage           work (``Prediction.timings`` key)
==============  ==========================================================================
``lighting``    lighting net: (flash, no-flash[, far pair]) → N env exemplars + flash-only
``extract``     :func:`ebr_mitsuba.extract.extract_sg` on the exemplars → SG environment
``select``      :func:`ebr_mitsuba.exemplar.select.select_exemplars`: env exemplars against
                the no-flash photo, point-light exemplars against the flash-only image
``cascade``     diffuse → specular → refinement nets (:func:`.renders.cascade_forward`)
==============  ==========================================================================

The first three stages belong to the capture, not to a part of the image: :func:`predict_lighting`
runs them once (a :class:`Lighting`), and :func:`cascade_pass` runs the cascade over any
:class:`PassInputs` — the whole grid (:func:`predict` = both over the grid), or a full-resolution
image or a tile of one, with each pixel's true geometry (``window``) and the capture's flash
scale (``scales``); :mod:`ebr_mitsuba.estimate.fullres` builds those.

**Flash-only mode** (``noflash`` None): no lighting stage; the flash photo is the flash-only
image, the environment exemplars and the no-flash input are black, and ``env`` is None.

Extraction and selection use the settings the model was trained with (its config's
``[extract]`` and ``[selection]`` tables); ``extract_config`` overrides the former.
"""

from __future__ import annotations

import time
from importlib import resources
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..sgenv import SGEnvironment
from .bundle import ModelBundle, bundle_from_checkpoint
from .checkpoint import load_checkpoint
from .device import pick_device
from .predictor import Lighting, PassInputs, PixelLighting, Prediction, ViewsPrediction

SHIPPED_MODEL = "ebrenv_real.pt"
SHIPPED_NEAR_FAR_MODEL = "ebrenv_near_far.pt"  # configs/train_real_near_far.toml: four-shot captures
FALLBACK_ROUGHNESS = 0.5


def shipped_model_path(near_far: bool = False) -> Path:
    """Path of the model shipped in the package (:mod:`ebr_mitsuba.models`); ``near_far``: the
    near-far model's, which ``ebr estimate`` uses for a capture with far shots when present."""
    name = SHIPPED_NEAR_FAR_MODEL if near_far else SHIPPED_MODEL
    return Path(str(resources.files("ebr_mitsuba.models").joinpath(name)))


def default_checkpoint(has_far: bool) -> Path | None:
    """The checkpoint ``ebr estimate`` loads when none is given: the shipped near-far model for a
    capture with far shots (when it is installed), else None (the shipped near model)."""
    path = shipped_model_path(near_far=True)
    return path if has_far and path.is_file() else None


def load_model(
    path: str | Path | None = None, device: str = "auto", expect_kind: str | None = "ebrenv"
) -> ModelBundle:
    """The model in checkpoint ``path`` (None: the shipped model), networks in eval mode.

    Raises :class:`InputError` naming the file when it is missing, corrupt or of another kind.
    """
    path = shipped_model_path() if path is None else Path(path)
    if not path.is_file() and path == shipped_model_path():
        raise InputError(
            f"{path}: the shipped model is missing from this installation; reinstall "
            f"ebr-mitsuba or pass --checkpoint"
        )
    data = load_checkpoint(path, expect_kind=expect_kind)
    return bundle_from_checkpoint(data, str(path), pick_device(device)).train(False)


def takes_far(bundle: ModelBundle) -> bool:
    """Whether the model's lighting net reads the far pair (four shots: a near-far model)."""
    return bundle.lighting is not None and bundle.lighting.config.num_shots == 4


def _image(name: str, image, size: int) -> np.ndarray:
    a = np.asarray(image, dtype=np.float32)
    if a.shape != (size, size, 3):
        raise InputError(
            f"predict: {name} has shape {a.shape}; expected ({size}, {size}, 3) at the model grid "
            f"(resample the photos first)"
        )
    if not np.all(np.isfinite(a)):
        raise InputError(f"predict: {name} contains NaN or Inf values")
    return np.maximum(a, 0.0)


def _chw(a: np.ndarray, device) -> torch.Tensor:
    """(H, W, 3) or (N, H, W, 3) numpy → (1, 3, H, W) or (1, N, 3, H, W) tensor."""
    t = torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))
    t = t.permute(2, 0, 1) if t.ndim == 3 else t.permute(0, 3, 1, 2)
    return t[None].to(device)


def _hwc(t: torch.Tensor) -> np.ndarray:
    """(3, H, W) or (N, 3, H, W) tensor → numpy (H, W, 3) / (N, H, W, 3) float32."""
    t = t.detach().to("cpu", torch.float32)
    return (t.permute(1, 2, 0) if t.ndim == 3 else t.permute(0, 2, 3, 1)).numpy().copy()


def _structured(image: np.ndarray) -> bool:
    """True when the image's luminance varies (the selection's score needs structure)."""
    from ..colour import LUMINANCE

    lum = np.asarray(image, np.float64) @ LUMINANCE
    return bool(lum.max() > 0.0 and lum.max() > lum.min())


def select_pair(
    env: SGEnvironment | None,
    noflash: np.ndarray | None,
    flash_only: np.ndarray,
    select_config,
    fixed_roughness: float | None = None,
):
    """Adaptive selection of the env exemplars (vs. the no-flash photo; None without one) and the
    point-light exemplars (vs. the flash-only image). Returns ``(env Selection | None, point
    Selection)``. ``fixed_roughness``: skip the search and use (r, low anchor, high anchor) — the
    "without adaptive selection" ablation; also used when a target is black or uniform (a saturated
    photo), with :data:`FALLBACK_ROUGHNESS`."""
    from ..exemplar.images import env_exemplar_images, point_exemplar_images
    from ..exemplar.select import Selection, select_exemplars

    env = env if env is not None else SGEnvironment.empty()
    h, w = flash_only.shape[:2]
    if fixed_roughness is None and not (
        _structured(flash_only) and (noflash is None or _structured(noflash))
    ):
        fixed_roughness = FALLBACK_ROUGHNESS  # black / uniform (e.g. saturated) target: nothing to search
    if fixed_roughness is not None:
        rough = (float(fixed_roughness), *select_config.anchors)
        env_sel = (
            None
            if noflash is None
            else Selection(
                rough,
                {},
                env_exemplar_images(env, rough, h, w, None, select_config.env_mode, select_config.env_spp),
            )
        )
        return env_sel, Selection(rough, {}, point_exemplar_images(rough, h, w))
    env_sel = None if noflash is None else select_exemplars(env, noflash, config=select_config)
    point_sel = select_exemplars(None, flash_only, point_light=True, config=select_config)
    return env_sel, point_sel


@torch.no_grad()
def estimate_lighting(
    bundle: ModelBundle,
    flash: np.ndarray,
    noflash: np.ndarray,
    far_flash: np.ndarray | None = None,
    far_noflash: np.ndarray | None = None,
    *,
    extract_config=None,
    progress=None,
) -> tuple[np.ndarray, np.ndarray, SGEnvironment, dict]:
    """Lighting net + SG extraction: ``(exemplars (N, H, W, 3), flash_only (H, W, 3), env, timings)``;
    ``progress(done, total, what)`` (of the 3 steps of :func:`predict_lighting`) before the extraction."""
    from ..extract import extract_sg

    timings = {}
    t0 = time.perf_counter()
    shots = [flash, noflash] + ([far_flash, far_noflash] if takes_far(bundle) else [])
    x = torch.cat([_chw(s, bundle.device) for s in shots], dim=1)
    out = bundle.lighting(x)
    exemplars, flash_only = _hwc(out.exemplars[0]), _hwc(out.flash_only[0])
    timings["lighting"] = time.perf_counter() - t0
    if progress is not None:
        progress(1, 3, "SG extraction")
    t0 = time.perf_counter()
    result = extract_sg(
        exemplars, bundle.facts.env_roughness, config=extract_config or bundle.config.extract_config()
    )
    timings["extract"] = time.perf_counter() - t0
    return exemplars, flash_only, result.env, timings


def _check_shots(bundle: ModelBundle, flash, noflash, far_flash, far_noflash, size: int | None):
    """Validated (flash, no-flash, [far pair]) at ``size`` (None: any square size)."""
    if bundle.kind != "ebrenv":
        raise InputError(
            f"predict: a '{bundle.kind}' model; flash/no-flash prediction needs an 'ebrenv' model"
        )
    n = size if size is not None else int(np.asarray(flash).shape[0])
    flash = _image("flash", flash, n)
    near_far = takes_far(bundle)
    has_far = far_flash is not None or far_noflash is not None
    if has_far and not near_far:
        raise InputError(
            "predict: this model takes near captures only; leave out the far flash/no-flash shots"
        )
    if near_far and noflash is not None and (far_flash is None or far_noflash is None):
        raise InputError("predict: this near-far model needs the far flash and far no-flash shots")
    nf = None if noflash is None else _image("noflash", noflash, n)
    far = [None, None]
    if near_far and noflash is not None:
        far = [_image(k, a, n) for k, a in (("far_flash", far_flash), ("far_noflash", far_noflash))]
    return flash, nf, far, near_far


@torch.no_grad()
def predict_lighting(
    bundle: ModelBundle,
    flash,
    noflash,
    far_flash=None,
    far_noflash=None,
    *,
    extract_config=None,
    fixed_roughness: float | None = None,
    progress=None,
) -> Lighting:
    """Lighting net, SG extraction and exemplar selection at the model grid (stages ``lighting``,
    ``extract``, ``select`` of the module docstring): once per capture. Arguments as :func:`predict`;
    ``progress(done, total, what)``: called as each stage starts and at the end."""
    size = bundle.resolution
    flash, nf, far, near_far = _check_shots(bundle, flash, noflash, far_flash, far_noflash, size)
    report = progress or (lambda done, total, what: None)
    timings: dict[str, float] = {}
    env, exemplars, far_fo = None, [], None
    if nf is None:
        fo = flash
    else:
        report(0, 3, "lighting net")
        ex, fo, env, t = estimate_lighting(
            bundle, flash, nf, *far, extract_config=extract_config, progress=report
        )
        exemplars = list(ex)
        timings.update(t)
        if near_far:
            far_fo = np.maximum(far[0] - far[1], 0.0)
    report(2, 3, "exemplar selection")
    t0 = time.perf_counter()
    env_sel, point_sel = select_pair(env, nf, fo, bundle.config.select_config(), fixed_roughness)
    timings["select"] = time.perf_counter() - t0
    report(3, 3, "done")
    return Lighting(size, env, exemplars, fo, far_fo, {"env": env_sel, "point": point_sel}, timings)


def grid_pass_inputs(
    bundle: ModelBundle, lighting: Lighting, flash, noflash, far_flash=None, far_noflash=None
) -> PassInputs:
    """The cascade's inputs at the grid: the photos, the lighting net's flash-only image and the
    selected exemplars (black no-flash photo and environment exemplars in flash-only mode)."""
    size = bundle.resolution
    flash, nf, far, near_far = _check_shots(bundle, flash, noflash, far_flash, far_noflash, size)
    env_sel, point_sel = lighting.selection["env"], lighting.selection["point"]
    nf = np.zeros_like(flash) if nf is None else nf
    env_images = env_sel.images if env_sel is not None else np.zeros((3, size, size, 3), np.float32)
    far_fo = lighting.far_flash_only
    if near_far and far[0] is None:  # flash-only mode of a near-far model: black far pair
        far, far_fo = [np.zeros_like(flash)] * 2, np.zeros_like(flash)
    photos = [flash, nf] + (list(far) if near_far else [])
    return PassInputs(nf, lighting.flash_only, env_images, point_sel.images, photos, far_fo)


@torch.no_grad()
def cascade_pass(
    bundle: ModelBundle,
    inputs: PassInputs,
    env: SGEnvironment | None,
    *,
    cascade=None,
    window: tuple[int, int, int, int] | None = None,
    scales: tuple | None = None,
    render_options=None,
):
    """One pass of the cascade over ``inputs`` (:func:`.renders.cascade_forward`): returns the
    :class:`~ebr_mitsuba.nets.ebrenv.CascadeOutput` (batch of one).

    ``cascade``: the network to run (default ``bundle.cascade``; e.g. a fast view of it);
    ``window``: the inputs are that block ``(row0, col0, full_h, full_w)`` of a larger grid, and
    the cascade's renders use each pixel's true position; ``scales``: fixed flash scales ``(k_near,
    k_far | None)`` instead of fitting them to the pass (one fit per capture, the same for every
    tile); ``render_options``: :class:`ebr_mitsuba.render.RenderOptions` of the environment render.
    """
    from ..nets.drwrap import lobes_from_env
    from .renders import cascade_forward

    dev = bundle.device
    return cascade_forward(
        cascade if cascade is not None else bundle.cascade,
        _chw(inputs.noflash, dev),
        _chw(inputs.flash_only, dev),
        _chw(inputs.env_exemplars, dev),
        _chw(inputs.point_exemplars, dev),
        torch.cat([_chw(p, dev) for p in inputs.photos], dim=1),
        [lobes_from_env(env, dev)],
        bundle.facts.flash_intensity,
        None if inputs.far_flash_only is None else _chw(inputs.far_flash_only, dev),
        window=window,
        scales=scales,
        options=render_options,
    )


@torch.no_grad()
def predict(
    bundle: ModelBundle,
    flash,
    noflash,
    far_flash=None,
    far_noflash=None,
    *,
    extract_config=None,
    fixed_roughness: float | None = None,
) -> Prediction:
    """Maps and lighting from photos at the model grid (see the module docstring).

    ``flash``, ``noflash`` (None: flash-only mode), ``far_flash``, ``far_noflash``: (H, W, 3)
    linear float32 with H = W = ``bundle.resolution``. A near-far model needs the far pair; a near
    model refuses it. ``fixed_roughness``: exemplars at a fixed roughness instead of the adaptive
    selection (ablation). Same as :func:`predict_lighting` followed by one :func:`cascade_pass`
    over the grid.
    """
    lighting = predict_lighting(
        bundle,
        flash,
        noflash,
        far_flash,
        far_noflash,
        extract_config=extract_config,
        fixed_roughness=fixed_roughness,
    )
    t0 = time.perf_counter()
    inputs = grid_pass_inputs(bundle, lighting, flash, noflash, far_flash, far_noflash)
    out = cascade_pass(bundle, inputs, lighting.env)
    maps = out.maps.to_svbrdf(0, source="ebr_mitsuba network")
    timings = dict(lighting.timings)
    timings["cascade"] = time.perf_counter() - t0
    return Prediction(
        maps, lighting.env, lighting.env_exemplars, lighting.flash_only, dict(lighting.selection), timings
    )


class ModelPredictor:
    """A loaded ``ebrenv`` model as a :class:`~.predictor.Predictor` and
    :class:`~.predictor.StagedPredictor`: this module's functions bound to ``bundle``.

    ``grid``: ``bundle.resolution``; ``takes_far``: the lighting net reads four shots.
    ``fixed_roughness``: every prediction selects exemplars at that roughness instead of the
    adaptive selection (the ablation of ``ebr eval --fixed-roughness``). ``predict`` and
    ``predict_lighting`` also take ``extract_config`` and ``fixed_roughness`` (as the module's
    functions; a ``fixed_roughness`` given there wins)."""

    def __init__(self, bundle: ModelBundle, fixed_roughness: float | None = None):
        self.bundle = bundle
        self.fixed_roughness = fixed_roughness

    @property
    def grid(self) -> int:
        return int(self.bundle.resolution)

    @property
    def takes_far(self) -> bool:
        return takes_far(self.bundle)

    @property
    def cascade(self):
        return self.bundle.cascade

    def predict(self, flash, noflash, far_flash=None, far_noflash=None, **options) -> Prediction:
        options.setdefault("fixed_roughness", self.fixed_roughness)
        return predict(self.bundle, flash, noflash, far_flash, far_noflash, **options)

    def estimate_lighting(self, flash, noflash, far_flash=None, far_noflash=None, **options):
        return estimate_lighting(self.bundle, flash, noflash, far_flash, far_noflash, **options)

    def predict_lighting(self, flash, noflash, far_flash=None, far_noflash=None, **options) -> Lighting:
        options.setdefault("fixed_roughness", self.fixed_roughness)
        return predict_lighting(self.bundle, flash, noflash, far_flash, far_noflash, **options)

    def grid_pass_inputs(
        self, lighting: Lighting, flash, noflash, far_flash=None, far_noflash=None
    ) -> PassInputs:
        return grid_pass_inputs(self.bundle, lighting, flash, noflash, far_flash, far_noflash)

    def cascade_pass(self, inputs: PassInputs, env: SGEnvironment | None, **options):
        return cascade_pass(self.bundle, inputs, env, **options)


class MAIRPredictor:
    """A loaded ``mair`` model as a :class:`~.predictor.ViewsPredictor`: maps and per-pixel SG
    lighting from the N views of the 3×3 capture, each resampled onto the (G, G) sample grid
    (``ebr_mitsuba.estimate.rectify``), as the MAIR phase of ``ebr train`` feeds them: each view at
    the reference exposure, clamped at 0 and times its in-frame weight, with the per-pixel view
    directions to its camera (:func:`ebr_mitsuba.nets.mair_views.view_direction_maps`).

    ``grid``: ``bundle.resolution``; ``views``: 9, the views a capture must provide. The network
    reads those its config selects (``MAIRConfig.views``,
    :func:`ebr_mitsuba.nets.mair_views.view_indices`): all of them, or for a centre-only model
    (``views = "centre"``) the centre camera's alone. The networks are fully convolutional: views
    of another square size run too (at the scale the model was not trained at)."""

    def __init__(self, bundle: ModelBundle):
        if bundle.kind != "mair":
            raise InputError(
                f"MAIRPredictor: a '{bundle.kind}' model; the multi-view estimate needs a 'mair' one"
            )
        self.bundle = bundle

    @property
    def grid(self) -> int:
        return int(self.bundle.resolution)

    @property
    def views(self) -> int:
        """The views a capture must provide (9), whichever of them the network reads."""
        return 9

    @torch.no_grad()
    def predict_views(self, views, weights=None, cameras=None) -> ViewsPrediction:
        """Maps (G, G) and :class:`~.predictor.PixelLighting` from (N, G, G, 3) views (see
        :meth:`~.predictor.ViewsPredictor.predict_views`): ``weights`` (N, G, G) or None,
        ``cameras`` N × 3 or None (the views in :func:`~ebr_mitsuba.nets.mair_views.multiview_shots`
        order). The network reads the views its config selects: all N, or for ``views =
        "centre"`` the one whose camera is the centre camera (matched by position when
        ``cameras`` is given, else index 4 of that order); maps and lighting come back as for a
        model that reads all nine."""
        from ..geometry import Shot
        from ..nets.mair_views import multiview_shots, view_direction_maps, view_indices

        t0 = time.perf_counter()
        v = np.asarray(views, dtype=np.float32)
        if v.ndim != 4 or v.shape[-1] != 3 or v.shape[1] != v.shape[2]:
            raise InputError(f"predict_views: views have shape {v.shape}; expected (N, G, G, 3)")
        if not np.all(np.isfinite(v)):
            raise InputError("predict_views: the views contain NaN or Inf values")
        n, h, w = v.shape[:3]
        if cameras is None:
            shots = multiview_shots()
            if n != len(shots):
                raise InputError(f"predict_views: {n} views and no cameras; give the {n} camera positions")
        else:
            if len(cameras) != n:
                raise InputError(f"predict_views: {n} views but {len(cameras)} cameras; give one per view")
            shots = [
                Shot(f"view{k}", tuple(float(c) for c in cam), 45.0, None) for k, cam in enumerate(cameras)
            ]
        wt = np.ones((n, h, w), np.float32) if weights is None else np.asarray(weights, np.float32)
        if wt.shape != (n, h, w):
            raise InputError(f"predict_views: weights have shape {wt.shape}; expected {(n, h, w)}")
        keep = view_indices(self.bundle.mair.config.views, [s.camera for s in shots])
        v, wt, shots = v[keep], wt[keep], [shots[k] for k in keep]
        dev = self.bundle.device
        x = torch.from_numpy(np.maximum(v, 0.0) * wt[..., None]).permute(0, 3, 1, 2)[None].to(dev)
        wts = torch.from_numpy(np.ascontiguousarray(wt))[:, None][None].to(dev)
        dirs = view_direction_maps(h, w, shots).to(dev)
        out = self.bundle.mair(x, dirs, wts)
        maps = out.maps.to_svbrdf(0, source="ebr estimate --views (MAIR network)")
        lt = out.lighting

        def np_(t, perm):
            return t[0].detach().to("cpu", torch.float32).permute(*perm).numpy().copy()

        lighting = PixelLighting(
            np_(lt.axis, (0, 2, 3, 1)),
            np_(lt.sharpness[:, :, 0], (0, 1, 2)),
            np_(lt.visibility[:, :, 0], (0, 1, 2)),
            lt.intensity[0].detach().to("cpu", torch.float32).numpy().copy(),
        )
        return ViewsPrediction(maps, lighting, {"network": time.perf_counter() - t0})


class DualLossPredictor:
    """A loaded ``dualloss`` model as a :class:`~.predictor.LightsPredictor`: maps from N photos
    (one per point light, in the model's light order) at the model grid.

    ``grid``: ``bundle.resolution``; ``lights``: the number of photos the network reads."""

    def __init__(self, bundle: ModelBundle):
        self.bundle = bundle

    @property
    def grid(self) -> int:
        return int(self.bundle.resolution)

    @property
    def lights(self) -> int:
        return int(self.bundle.dualloss.config.num_lights)

    @torch.no_grad()
    def predict_lights(self, photos) -> Prediction:
        """Maps (G, G) from the N (G, G, 3) linear float32 photos at the reference exposure
        (``env`` None: the model estimates no environment)."""
        t0 = time.perf_counter()
        x = torch.from_numpy(np.ascontiguousarray(np.stack(photos), dtype=np.float32))
        x = x.permute(0, 3, 1, 2).contiguous()[None].to(self.bundle.device)
        maps = self.bundle.dualloss(x).to_svbrdf(0)
        return Prediction(maps, None, timings={"network": time.perf_counter() - t0})


def as_predictor(
    bundle: ModelBundle, fixed_roughness: float | None = None
) -> ModelPredictor | DualLossPredictor | MAIRPredictor:
    """The predictor of a loaded model: a :class:`ModelPredictor` (``ebrenv``, with
    ``fixed_roughness``), a :class:`DualLossPredictor` (``dualloss``) or a :class:`MAIRPredictor`
    (``mair``, the multi-view model of ``ebr estimate --views``); the last two have no exemplars,
    so ``fixed_roughness`` is refused for them."""
    if bundle.kind in ("dualloss", "mair"):
        if fixed_roughness is not None:
            raise InputError(
                f"fixed_roughness applies to ebrenv models (a {bundle.kind} model has no exemplars)"
            )
        return DualLossPredictor(bundle) if bundle.kind == "dualloss" else MAIRPredictor(bundle)
    return ModelPredictor(bundle, fixed_roughness)


def load_predictor(
    path: str | Path | None = None,
    device: str = "auto",
    expect_kind: str | None = "ebrenv",
    fixed_roughness: float | None = None,
) -> ModelPredictor | DualLossPredictor | MAIRPredictor:
    """:func:`load_model` (None: the shipped model; ``expect_kind`` as there) as its predictor
    (:func:`as_predictor`): a :class:`ModelPredictor` for an ``ebrenv`` model, a
    :class:`DualLossPredictor` for a ``dualloss`` one, a :class:`MAIRPredictor` for a ``mair``
    one (no MAIR model is shipped: give its ``path``)."""
    return as_predictor(load_model(path, device, expect_kind), fixed_roughness)


__all__ = [
    "DualLossPredictor",
    "MAIRPredictor",
    "ModelPredictor",
    "as_predictor",
    "cascade_pass",
    "grid_pass_inputs",
    "predict_lighting",
    "SHIPPED_MODEL",
    "SHIPPED_NEAR_FAR_MODEL",
    "default_checkpoint",
    "estimate_lighting",
    "load_model",
    "load_predictor",
    "predict",
    "select_pair",
    "shipped_model_path",
    "takes_far",
]
