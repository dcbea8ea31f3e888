"""Dominant spherical-Gaussian extraction from environment exemplars (step 2 of
``docs/conventions.md``, "Pipeline").

``extract_sg(exemplars, roughness)`` turns N exemplar images — renders of the uniform exemplar
material (diffuse 0.1, specular 0.2, roughness r_i, flat normal) under an unknown environment,
seen by the near camera — into an :class:`~ebr_mitsuba.sgenv.SGEnvironment` of at most
``max_lobes`` lobes. Stages (each can be switched off for the ablation, :class:`ExtractConfig`):

1. **normalise** by the stack's mean radiance (undone at the end: the result is scale-free, so
   1e-6 and 1e6 radiance behave alike); detect clipped pixels (many pixels exactly at an
   exemplar's maximum) and treat them as lower bounds;
2. **initialise**: quad-tree patches → one lobe each (:mod:`.init`), or random lobes;
3. **merge** similar lobes down to the budget ``max_lobes − densify_count·rounds``
   (:mod:`.merge`), then add the fill lobes (quad-tree initialisation only);
4. **amplitude solve**: the best non-negative amplitudes for the initial axes and sharpness, in
   closed form (:mod:`.amplitudes`), pruning of the lobes it leaves (nearly) empty, and — if
   more than the budget remain — the most energetic ones kept and solved again;
5. **optimise** all parameters with Adam (:mod:`.optimize`), interrupted at ``densify_at`` by
6. **densification** (:mod:`.densify`, MS-SSIM error map) followed by pruning and a new
   amplitude solve;
7. **prune** negligible lobes (:mod:`.prune`) and keep at most ``max_lobes``.

The forward model is the fast renderer's exemplar render (:mod:`.forward`). ``env_mode``:
``sg`` uses the closed form, which overshoots rough exemplars (its bias would leak into the lobes
as too little light); ``quadrature`` uses the MIS quadrature (unbiased, noisy); ``corrected``
(default) uses the closed form times a fixed per-pixel ratio ``Q(θ₀)/S(θ₀)`` (quadrature over
closed form on a grid of at most ``correction_grid`` pixels per side, ``correction_spp``
directions, 3×3 box-filtered and bilinearly up-sampled; ``correction="offset"`` adds
``Q(θ₀) − S(θ₀)`` instead) recomputed at ``correct_at`` for the current lobes θ₀: at a fixed
point the model matches the quadrature, and the optimiser runs at the closed form's speed.
docs/extract-sg.md has the measured comparison.

``rel_rmse_exemplars`` of the result: ``‖ŷ − y‖/‖y‖`` over all exemplar pixels, ŷ the loop's
model (in ``corrected`` mode the closed form with the last correction) at full resolution.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..geometry import Shot, near_shot
from ..imageio import box3, upsample_bilinear
from ..metrics import rel_rmse
from ..sgenv import SGEnvironment
from .config import ExtractConfig
from .forward import ExemplarGeometry, centre_indices

MIN_SIZE = 16
SATURATION_FRACTION = 0.002  # pixels exactly at the maximum, above which an exemplar counts as clipped
AMPLITUDE_GRID = 48  # pixels per side of the fixed grid of the amplitude solve and pruning


@dataclass
class ExtractResult:
    """The extracted environment and how it was obtained.

    ``env``: the lobes (radiance units of the exemplars); ``iterations``: Adam steps run;
    ``seconds``: wall time; ``rel_rmse_exemplars``: module docstring; ``loss_history``: the loss
    every 25 iterations (``[iteration, loss]``); ``stage_seconds``: wall time per stage.
    """

    env: SGEnvironment
    iterations: int
    seconds: float
    rel_rmse_exemplars: float
    loss_history: list = field(default_factory=list)
    stage_seconds: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """The ``--json`` summary of ``ebr extract-sg``."""
        return {
            "lobes": self.env.num_lobes,
            "iterations": self.iterations,
            "seconds": round(self.seconds, 3),
            "rel_rmse_exemplars": self.rel_rmse_exemplars,
            "loss_history": self.loss_history,
        }


def check_exemplars(exemplars, roughness) -> tuple[np.ndarray, np.ndarray]:
    """Validate the exemplar stack (N, H, W, 3) and its N roughness values; returns float64
    copies. A list of images of different sizes, NaN/Inf or negative radiance, or roughness
    outside [0, 1] is an :class:`InputError`."""
    if isinstance(exemplars, (list, tuple)):
        shapes = {np.shape(e) for e in exemplars}
        if len(shapes) > 1:
            raise InputError(
                f"extract-sg: exemplars of different sizes {sorted(shapes)}; render all "
                f"exemplars at one resolution"
            )
    images = np.asarray(exemplars, dtype=np.float64)
    if images.ndim != 4 or images.shape[-1] != 3 or images.shape[0] < 1:
        raise InputError(f"extract-sg: exemplars of shape {images.shape}; expected (N, H, W, 3) with N >= 1")
    if min(images.shape[1:3]) < MIN_SIZE:
        raise InputError(
            f"extract-sg: exemplars of {images.shape[2]}x{images.shape[1]} pixels; give at "
            f"least {MIN_SIZE}x{MIN_SIZE}"
        )
    if not np.all(np.isfinite(images)):
        raise InputError("extract-sg: NaN or Inf radiance in the exemplars; give finite linear images")
    if np.any(images < 0):
        raise InputError(
            f"extract-sg: negative radiance in the exemplars (min {images.min():.3g}); give "
            f"linear radiance >= 0"
        )
    r = np.asarray(roughness, dtype=np.float64).reshape(-1)
    if r.size != images.shape[0]:
        raise InputError(
            f"extract-sg: {images.shape[0]} exemplars but {r.size} roughness values; give one "
            f"roughness per exemplar"
        )
    if not (np.all(np.isfinite(r)) and r.min() >= 0 and r.max() <= 1):
        raise InputError(f"extract-sg: roughness values {r.tolist()} must lie in [0, 1]")
    return images, r


def saturated_mask(images: np.ndarray) -> np.ndarray:
    """(N, H, W) bool: pixels at their exemplar's maximum, for exemplars where more than
    :data:`SATURATION_FRACTION` (and less than half) of the pixels sit exactly there."""
    out = np.zeros(images.shape[:3], dtype=bool)
    for i, img in enumerate(images):
        top = img.max(axis=-1)
        vmax = float(top.max())
        if vmax <= 0:
            continue
        at_max = top >= vmax * (1.0 - 1e-6)
        frac = float(at_max.mean())
        if SATURATION_FRACTION < frac < 0.5 and int(at_max.sum()) >= 4:
            out[i] = at_max
    return out


def _options(config: ExtractConfig):
    from ..render.inputs import RenderOptions

    if config.env_mode == "quadrature":
        return RenderOptions(mode="quadrature", spp=config.spp)
    return RenderOptions(mode="sg")


def _quadrature_options(config: ExtractConfig):
    from ..render.inputs import RenderOptions

    return RenderOptions(mode="quadrature", spp=config.correction_spp, seed=config.seed + 1)


class _Run:
    """One extraction: owns the problem, the lobes between stages and the timings."""

    def __init__(
        self, images: np.ndarray, roughness: np.ndarray, shot: Shot, config: ExtractConfig, progress: bool
    ):
        from .optimize import Problem

        self.config = config
        self.progress = progress
        self.rng = np.random.default_rng(config.seed)
        self.stage_seconds: dict[str, float] = {}
        n, h, w, _ = images.shape
        self.scale = float(images.mean())
        self.images = (images / self.scale).astype(np.float32)
        self.geometry = ExemplarGeometry(roughness.astype(np.float32), h, w, shot)
        flat = self.images.reshape(-1, 3)
        weights = (
            np.ones(n) if config.exemplar_weights is None else np.asarray(config.exemplar_weights, np.float64)
        )
        if weights.size != n:
            raise InputError(
                f"extract-sg: {weights.size} exemplar weights for {n} exemplars; give one per exemplar"
            )
        per = self.images.reshape(n, -1, 3)
        rms = np.sqrt((per**2).sum(-1).mean(1))
        eps = config.log_eps * per.mean(axis=(1, 2)) + 1e-12
        self.corrected = config.correction if config.env_mode == "corrected" else None
        neutral = np.ones_like(flat) if self.corrected == "ratio" else np.zeros_like(flat)
        self.problem = Problem(
            self.geometry, flat, saturated_mask(self.images).reshape(-1), weights, eps, rms, neutral
        )
        self.options = _options(config)
        self.grid_index = centre_indices(n, h, w, AMPLITUDE_GRID)
        self.history: list = []

    def timed(self, stage: str, fn, *args):
        t0 = time.perf_counter()
        out = fn(*args)
        self.stage_seconds[stage] = self.stage_seconds.get(stage, 0.0) + time.perf_counter() - t0
        return out

    # -- stages -------------------------------------------------------------------------------------
    def initial(self):
        from .init import quadtree_lobes, random_lobes

        c = self.config
        if c.init == "quadtree":
            return quadtree_lobes(self.images, self.geometry, c.variance_threshold, c.max_level)
        return random_lobes(self.budget(), 1.0, self.rng)

    def fill(self, lobes):
        from .init import fill_lobes

        new = fill_lobes(self.config.fill_lobes, 1.0)
        return tuple(np.concatenate([a, b]) for a, b in zip(lobes, new))

    def budget(self) -> int:
        """Lobes kept after merging (and after the first solve): the budget less the
        densification reserve."""
        c = self.config
        reserve = c.densify_count * len(c.densify_at) if (c.densify and c.optimize) else 0
        return max(c.max_lobes - reserve, max(c.max_lobes // 2, 1))

    def cap(self, lobes):
        """At most :meth:`budget` lobes (the most energetic), amplitudes re-solved if any went."""
        from .merge import keep_strongest

        if len(lobes[1]) <= self.budget():
            return lobes
        return self.solve(keep_strongest(*lobes, self.budget()))

    def reduce(self, lobes):
        from .merge import keep_strongest, merge_lobes

        c = self.config
        if c.merge:
            return merge_lobes(*lobes, self.budget(), c.merge_angle, c.merge_ratio)
        return keep_strongest(*lobes, self.budget())

    def solve(self, lobes):
        from .amplitudes import solve_amplitudes

        axis, sharp, _ = lobes
        if len(sharp) == 0:
            return lobes
        p = self.problem
        targets = p.targets - p.correction if self.corrected == "offset" else p.targets
        scale = p.correction[self.grid_index] if self.corrected == "ratio" else None
        amp = solve_amplitudes(
            self.geometry,
            targets,
            p.row_weights(self.grid_index),
            axis,
            sharp,
            self.grid_index,
            self.options,
            channel_scale=scale,
        )
        return axis, sharp, amp

    def model(self, lobes) -> np.ndarray:
        """The loop's model at every pixel, (N, H, W, 3)."""
        from ..render.inputs import DrLobes

        if len(lobes[1]) == 0:
            return np.zeros_like(self.images)
        img = self.geometry.render_numpy(DrLobes.from_numpy(*lobes), self.options)
        if self.corrected == "offset":
            img = img + self.problem.correction.reshape(img.shape)
        elif self.corrected == "ratio":
            img = img * self.problem.correction.reshape(img.shape)
        return img

    def correct(self, lobes) -> None:
        """Refresh the ``corrected`` mode's correction (ratio or offset) for ``lobes``."""
        from ..render.inputs import DrLobes

        if len(lobes[1]) == 0:
            return
        g = self.geometry
        hc, wc = min(g.height, self.config.correction_grid), min(g.width, self.config.correction_grid)
        coarse = g if (hc, wc) == (g.height, g.width) else ExemplarGeometry(g.roughness, hc, wc, g.shot)
        dl = DrLobes.from_numpy(*lobes)
        q = np.stack([box3(d) for d in coarse.render_numpy(dl, _quadrature_options(self.config))])
        s = np.stack([box3(d) for d in coarse.render_numpy(dl, self.options)])
        if self.corrected == "ratio":
            # the bias field is smooth, the noise is not: both sides box-filtered; ε keeps dark
            # pixels at ratio ≈ 1
            eps = 0.01 * max(float(s.mean()), 1e-30)
            delta = np.clip((q + eps) / (s + eps), 0.2, 5.0)
        else:
            delta = q - s
        if coarse is not g:
            delta = np.stack([upsample_bilinear(d, (g.height, g.width)) for d in delta])
        self.problem.set_correction(delta.reshape(-1, 3))

    def prune(self, lobes):
        from .amplitudes import lobe_basis
        from .prune import prune_mask

        axis, sharp, amp = lobes
        if len(sharp) == 0:
            return lobes
        basis = lobe_basis(self.geometry, axis, sharp, self.grid_index, self.options)
        keep = prune_mask(
            basis,
            amp,
            self.problem.targets[self.grid_index],
            self.problem.row_weights(self.grid_index),
            self.config.prune_threshold,
        )
        return axis[keep], sharp[keep], amp[keep]

    def densify(self, lobes):
        from .densify import densify_lobes

        c = self.config
        room = c.max_lobes - len(lobes[1])
        new = densify_lobes(
            self.model(lobes), self.images, self.geometry, min(c.densify_count, room), c.densify_threshold
        )
        return tuple(np.concatenate([a, b]) for a, b in zip(lobes, new))

    def adam(self, lobes, iters: int, first: int):
        from .optimize import run_adam

        c = self.config
        return run_adam(
            self.problem,
            lobes,
            iters,
            first,
            lr=c.lr,
            lr_axis=c.lr_axis,
            log_weight=c.log_weight,
            grid=c.sample_grid,
            options=self.options,
            corrected=self.corrected,
            rng=self.rng,
            history=self.history,
        )

    # -- the whole ---------------------------------------------------------------------------------------
    def run(self):
        c = self.config
        lobes = self.timed("init", self.initial)
        lobes = self.timed("merge", self.reduce, lobes)
        if c.init == "quadtree":
            lobes = self.fill(lobes)
        if self.corrected and 0 in c.correct_at:
            self.timed("correct", self.correct, lobes)
        lobes = self.timed("solve", self.solve, lobes)
        if c.prune:
            lobes = self.timed("prune", self.prune, lobes)
        lobes = self.timed("solve", self.cap, lobes)
        iterations = 0
        if c.optimize and c.iters > 0:
            events = sorted({i for i in (*c.densify_at, *c.correct_at) if 0 < i < c.iters} | {c.iters})
            start = 0
            bar = None
            if self.progress:
                from tqdm import tqdm

                bar = tqdm(
                    total=c.iters, desc="extract-sg", unit="it", leave=False, dynamic_ncols=True, disable=None
                )
            for stop in events:
                lobes = self.timed("optimize", self.adam, lobes, stop - start, start)
                iterations += stop - start
                if bar is not None:
                    bar.update(stop - start)
                start = stop
                if stop == c.iters:
                    break
                if self.corrected and stop in c.correct_at:
                    self.timed("correct", self.correct, lobes)
                if c.densify and stop in c.densify_at:
                    if c.prune:
                        lobes = self.timed("prune", self.prune, lobes)
                    lobes = self.timed("densify", self.densify, lobes)
                    lobes = self.timed("solve", self.solve, lobes)
            if bar is not None:
                bar.close()
        if c.prune:
            lobes = self.timed("prune", self.prune, lobes)
        from .merge import keep_strongest

        lobes = keep_strongest(*lobes, c.max_lobes)
        model = self.timed("evaluate", self.model, lobes)
        err = rel_rmse(model, self.images)
        return lobes, iterations, err


def to_environment(lobes, scale: float) -> SGEnvironment:
    """numpy lobes (normalised units) → a validated environment in the exemplars' units; lobes
    with a non-finite or zero parameter are dropped, sharpness floored at 1e-4."""
    axis, sharp, amp = (np.asarray(x, np.float64) for x in lobes)
    amp = np.maximum(amp, 0.0) * scale
    ok = (
        np.isfinite(axis).all(1)
        & (np.linalg.norm(axis, axis=1) > 1e-9)
        & np.isfinite(sharp)
        & np.isfinite(amp).all(1)
        & (amp.max(axis=1, initial=0.0) > 0)
    )
    if not ok.any():
        return SGEnvironment.empty()
    return SGEnvironment(axis[ok], np.maximum(sharp[ok], 1e-4), amp[ok])


def extract_sg(
    exemplars: np.ndarray,
    roughness: Sequence[float],
    *,
    config: ExtractConfig | None = None,
    shot: Shot | None = None,
    progress: bool = False,
) -> ExtractResult:
    """Extract dominant SG lobes from environment exemplars (module docstring).

    ``exemplars``: (N, H, W, 3) float linear radiance (or a list of N (H, W, 3) images of one
    size); ``roughness``: the N exemplar roughness values; ``shot``: the camera the exemplars were
    rendered from (default: the near shot, as :func:`ebr_mitsuba.exemplar.images.exemplar_images`).
    Never returns NaN/Inf or negative lobes; an all-black stack gives an empty environment.
    """
    t0 = time.perf_counter()
    config = config or ExtractConfig()
    images, r = check_exemplars(exemplars, roughness)
    shot = shot or near_shot(False)
    if not isinstance(shot, Shot):
        raise InputError(f"extract-sg: shot must be an ebr_mitsuba.geometry.Shot (got {type(shot).__name__})")
    scale = float(images.mean())
    if not scale > 1e-30:
        return ExtractResult(SGEnvironment.empty(), 0, time.perf_counter() - t0, 0.0, [], {})
    from ..variant import ensure_variant

    ensure_variant()
    run = _Run(images, r, shot, config, progress)
    lobes, iterations, err = run.run()
    env = to_environment(lobes, run.scale)
    return ExtractResult(
        env,
        iterations,
        time.perf_counter() - t0,
        err,
        [[int(i), float(v)] for i, v in run.history],
        run.stage_seconds,
    )
