"""What the rest of the toolkit asks of a model: the :class:`Predictor` protocols and their results.

``ebr estimate`` (:func:`ebr_mitsuba.estimate.pipeline.run_estimate`), ``ebr eval``, the benches
and the trainer's stage-2 cache take a predictor as an argument; :class:`.predict.ModelPredictor`
(a loaded model, :func:`.predict.load_predictor`) implements the first two protocols, a dual-loss model's
:class:`.predict.DualLossPredictor` the :class:`LightsPredictor`, a MAIR model's
:class:`.predict.MAIRPredictor` the :class:`ViewsPredictor`, and tests pass small fakes.

=======================  ===============================================================================
protocol                 surface
=======================  ===============================================================================
:class:`Predictor`       ``grid`` (the model grid G, square), ``takes_far`` (the lighting net reads the
                         far pair: a near-far model), ``predict(flash, noflash, far_flash=None,
                         far_noflash=None) -> Prediction`` on (G, G, 3) photos (``noflash`` None:
                         flash-only mode); what an estimate at the grid needs
:class:`StagedPredictor` a :class:`Predictor` whose stages run apart (what a full-resolution estimate,
                         :mod:`ebr_mitsuba.estimate.fullres`, and the trainer's cache need):
                         ``cascade`` (the network), ``estimate_lighting`` (lighting net + SG
                         extraction), ``predict_lighting -> Lighting`` (+ exemplar selection, once
                         per capture), ``grid_pass_inputs -> PassInputs`` and ``cascade_pass`` (one
                         pass of the cascade over any block of any image)
:class:`LightsPredictor` a five-light (dual-loss) model: ``grid``, ``lights`` (N) and
                         ``predict_lights(photos) -> Prediction`` on N (G, G, 3) photos, one per
                         point light (``env`` None); what ``ebr eval`` and the five-light bench take
                         for a ``dualloss`` model (:class:`.predict.DualLossPredictor`)
:class:`ViewsPredictor`  a multi-view (MAIR) model: ``grid``, ``views`` (N = 9) and
                         ``predict_views(views, weights, cameras) -> ViewsPrediction`` on N views
                         resampled onto the (G, G) sample grid; what ``ebr estimate --views`` takes
                         (:class:`.predict.MAIRPredictor`)
=======================  ===============================================================================

The result types (:class:`Prediction`, :class:`Lighting`, :class:`PassInputs`,
:class:`PixelLighting`, :class:`ViewsPrediction`) are plain numpy
dataclasses; this module imports neither torch nor Mitsuba.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF


@dataclass
class Prediction:
    """What :meth:`Predictor.predict` returns.

    ``maps``: SVBRDF at the model grid; ``env``: extracted SG environment in the photos' units
    (None in flash-only mode); ``env_exemplars``: the lighting net's N exemplars, (H, W, 3) each,
    in the order of the model's ``env_roughness`` (empty in flash-only mode); ``flash_only``:
    (H, W, 3) the flash-only image the cascade used; ``selection``: ``{"env": Selection | None,
    "point": Selection}``; ``timings``: seconds per stage.
    """

    maps: SVBRDF
    env: SGEnvironment | None
    env_exemplars: list[np.ndarray] = field(default_factory=list)
    flash_only: np.ndarray | None = None
    selection: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)


@dataclass
class Lighting:
    """The capture's lighting, estimated once at the model grid G
    (:meth:`StagedPredictor.predict_lighting`): what every part of a full-resolution estimate shares.

    ``env``: the extracted SGs in photo units (None in flash-only mode); ``env_exemplars``: the
    lighting net's N exemplars (G, G, 3) (empty in flash-only mode); ``flash_only`` (G, G, 3):
    the lighting net's flash-only image (the flash photo in flash-only mode);
    ``far_flash_only`` (G, G, 3) or None: the far pair's ``max(far flash − far no-flash, 0)`` (a
    near-far model); ``selection``: ``{"env": Selection | None, "point": Selection}`` with the
    selected exemplars at the grid in the model's training render mode; ``timings``: seconds per
    stage (``lighting``, ``extract``, ``select``).
    """

    grid: int
    env: SGEnvironment | None
    env_exemplars: list[np.ndarray]
    flash_only: np.ndarray
    far_flash_only: np.ndarray | None
    selection: dict
    timings: dict = field(default_factory=dict)


@dataclass
class PassInputs:
    """The cascade's inputs for one pass over an (H, W) image (numpy, linear float32):
    ``noflash``, ``flash_only`` (H, W, 3); ``env_exemplars``, ``point_exemplars`` (K, H, W, 3);
    ``photos``: (flash, no-flash[, far flash, far no-flash]) each (H, W, 3); ``far_flash_only``
    (H, W, 3) or None."""

    noflash: np.ndarray
    flash_only: np.ndarray
    env_exemplars: np.ndarray
    point_exemplars: np.ndarray
    photos: list[np.ndarray]
    far_flash_only: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.noflash.shape[0]), int(self.noflash.shape[1])

    def crop(self, row: int, col: int, height: int, width: int) -> PassInputs:
        """The block of rows ``row … row+height−1`` and columns ``col … col+width−1``."""
        sl = (slice(row, row + height), slice(col, col + width))

        def cut(a):
            return None if a is None else np.ascontiguousarray(a[..., sl[0], sl[1], :])

        return PassInputs(
            cut(self.noflash),
            cut(self.flash_only),
            cut(self.env_exemplars),
            cut(self.point_exemplars),
            [cut(p) for p in self.photos],
            cut(self.far_flash_only),
        )


class Predictor(Protocol):
    """Photos at the model grid in, maps and lighting out (module docstring)."""

    @property
    def grid(self) -> int:
        """The model grid G: ``predict`` takes (G, G, 3) photos."""
        ...

    @property
    def takes_far(self) -> bool:
        """Whether the lighting net reads the far pair (a near-far model); a near model is given
        none (the far shots then serve the re-renders and the refinement only)."""
        ...

    def predict(
        self,
        flash: np.ndarray,
        noflash: np.ndarray | None,
        far_flash: np.ndarray | None = None,
        far_noflash: np.ndarray | None = None,
    ) -> Prediction:
        """Maps (G, G) and lighting from (G, G, 3) linear float32 photos."""
        ...


class StagedPredictor(Predictor, Protocol):
    """A :class:`Predictor` whose stages run apart (module docstring)."""

    @property
    def cascade(self) -> Any:
        """The cascade (:class:`ebr_mitsuba.nets.Cascade`): its config and networks."""
        ...

    def estimate_lighting(
        self, flash, noflash, far_flash=None, far_noflash=None, *, extract_config=None, progress=None
    ) -> tuple[np.ndarray, np.ndarray, SGEnvironment, dict]:
        """Lighting net + SG extraction: ``(exemplars (N, G, G, 3), flash_only, env, timings)``."""
        ...

    def predict_lighting(
        self, flash, noflash, far_flash=None, far_noflash=None, *, progress=None
    ) -> Lighting:
        """Lighting net, SG extraction and exemplar selection at the grid, once per capture."""
        ...

    def grid_pass_inputs(
        self, lighting: Lighting, flash, noflash, far_flash=None, far_noflash=None
    ) -> PassInputs:
        """The cascade's inputs over the grid."""
        ...

    def cascade_pass(
        self,
        inputs: PassInputs,
        env: SGEnvironment | None,
        *,
        cascade=None,
        window: tuple[int, int, int, int] | None = None,
        scales: tuple | None = None,
        render_options=None,
    ) -> Any:
        """One pass of the cascade over ``inputs``: a :class:`~ebr_mitsuba.nets.ebrenv.CascadeOutput`."""
        ...


@runtime_checkable
class LightsPredictor(Protocol):
    """Photos under N known point lights at the model grid in, maps out (module docstring).
    ``isinstance(p, LightsPredictor)`` tells it from a flash / no-flash :class:`Predictor`."""

    @property
    def grid(self) -> int:
        """The model grid G: ``predict_lights`` takes (G, G, 3) photos."""
        ...

    @property
    def lights(self) -> int:
        """N: how many photos (one per light, in the model's light order) the model reads."""
        ...

    def predict_lights(self, photos: Sequence[np.ndarray]) -> Prediction:
        """Maps (G, G) from N (G, G, 3) linear float32 photos at the reference exposure."""
        ...


@dataclass
class PixelLighting:
    """Per-pixel SG incident lighting (MAIR's S_D lobes per pixel; ``docs/mair.md``), numpy.

    At pixel (i, j) the radiance from direction ω is ``Σ_s amplitude[s, i, j] · exp(sharpness[s, i, j]
    (axis[s, i, j]·ω − 1))``: ``axis`` (S, H, W, 3) unit, world frame; ``sharpness`` (S, H, W);
    ``visibility`` (S, H, W) μ ∈ [0, 1]; ``intensity`` (S, 3) η; ``amplitude`` = μ η (S, H, W, 3).
    """

    axis: np.ndarray
    sharpness: np.ndarray
    visibility: np.ndarray
    intensity: np.ndarray

    @property
    def num_sgs(self) -> int:
        return int(self.axis.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.axis.shape[1]), int(self.axis.shape[2])

    @property
    def amplitude(self) -> np.ndarray:
        return (self.visibility[..., None] * self.intensity[:, None, None, :]).astype(np.float32)

    def scaled(self, factor: float) -> PixelLighting:
        """The same lobes with ``η`` times ``factor``."""
        return PixelLighting(self.axis, self.sharpness, self.visibility, self.intensity * np.float32(factor))

    def pixel_environment(self, row: int | None = None, col: int | None = None) -> SGEnvironment:
        """The S lobes at one pixel (default: the centre) as an :class:`SGEnvironment`."""
        h, w = self.shape
        row = h // 2 if row is None else row
        col = w // 2 if col is None else col
        amp = (self.visibility[:, row, col, None] * self.intensity).astype(np.float32)  # μ η at that pixel
        amp = np.maximum(amp.astype(np.float64), 0.0)
        sharp = np.maximum(self.sharpness[:, row, col].astype(np.float64), 1e-6)
        return SGEnvironment(self.axis[:, row, col].astype(np.float64), sharp, amp)


@dataclass
class ViewsPrediction:
    """What :meth:`ViewsPredictor.predict_views` returns: ``maps`` (SVBRDF at the grid),
    ``lighting`` (:class:`PixelLighting` at the grid, in the views' units up to the scale the
    network cannot know), ``timings`` (seconds per stage)."""

    maps: SVBRDF
    lighting: PixelLighting
    timings: dict = field(default_factory=dict)


@runtime_checkable
class ViewsPredictor(Protocol):
    """N views of the planar sample, each resampled onto the (G, G) sample grid, in; maps and
    per-pixel SG lighting out (module docstring). ``isinstance(p, ViewsPredictor)`` tells it from
    the other predictors."""

    @property
    def grid(self) -> int:
        """The model grid G: ``predict_views`` takes (N, G, G, 3) views."""
        ...

    @property
    def views(self) -> int:
        """N: how many views a capture must provide (9, the 3×3 grid), whichever of them the model reads."""
        ...

    def predict_views(
        self,
        views: np.ndarray,
        weights: np.ndarray | None = None,
        cameras: Sequence[Sequence[float]] | None = None,
    ) -> ViewsPrediction:
        """Maps and lighting from N (G, G, 3) linear float32 views at the reference exposure
        (``views``: (N, G, G, 3)), their in-frame weights (N, G, G) (None: every pixel seen) and
        camera positions (N × 3; None: those of ``ebr capture --setup multi-view``)."""
        ...


__all__ = [
    "Lighting",
    "LightsPredictor",
    "PassInputs",
    "PixelLighting",
    "Prediction",
    "Predictor",
    "StagedPredictor",
    "ViewsPrediction",
    "ViewsPredictor",
]
