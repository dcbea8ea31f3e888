"""Test-time refinement: the network's maps (and optionally lobes) optimised against the photos.

Starting from the prediction, Adam minimises over the input shots k (each a
:class:`ShotTarget`: the shot's geometry, its photo y_k and a mask of usable pixels)

    E = Σ_k [ mean_m (x_k − y_k)² / mean_m y_k²  +  w_log · mean_m |log(x_k + ε_k) − log(y_k + ε_k)| ]
      + w_prior · Σ_maps mean (map − map₀)²  +  w_smooth · (TV(roughness) + TV(specular) + TV(normal))

with x_k the fast differentiable render (:func:`ebr_mitsuba.render.render`) of the current maps
under the shot's flash and the SG environment, ``mean_m`` the mean over unmasked pixels,
ε_k = 1% of the photo's mean, map₀ the prediction (normals compared as (n+1)/2) and TV the mean
absolute difference of neighbouring pixels. The data term is scale-free per shot, so the flash
and no-flash shots weigh alike; the prior keeps the maps near the network's answer where the
photos do not constrain them (e.g. the specular colour of a dark diffuse); the smoothness term
suppresses noise fitted into roughness, specular and normals.

Caveat: one co-located view leaves a trade-off between specular F₀ and roughness that the
per-pixel diffuse map absorbs, and per-pixel maps can fit the photos' noise. Adam keeps stepping
by about its learning rate even at the optimum, so the normals get a rate 10× below the other
maps and every rate decays linearly to 10% over the run; without that the normals dithered by
about 7° on the demo capture whatever the prior weight. On the demo capture (``ebr demo``, 100
steps) the defaults lower the re-render RMSE from 0.053 to 0.012 and the mean per-map RMSE from
0.037 to 0.027; the report shows both numbers for every run.

Best iterate. E is read (a host sync) at step 0, every ``log_every`` steps and after the last
update; the parameters of the lowest E read are returned (``RefineResult.kept_step``; at step 0
the input maps and lobes unchanged), so a refinement never returns a higher loss than it started
from. ``RefineResult.loss_rose`` / :meth:`RefineResult.loss_note` ("loss rose from X to Y; kept
step K") tell when the last E read is above the kept one; the estimate's summary and report
print that note.

Parametrisation (unconstrained, so every step stays a valid SVBRDF): diffuse, specular and
roughness through a sigmoid of a logit (initial values clamped to [1e-3, 1 − 1e-3]); the normal
as n = normalize(p_x, p_y, 1) of a free 2-vector p (always n_z > 0). Lobes (``lobes=True``, only
when the environment lights a shot): log amplitude, log sharpness and a free axis vector
(normalised inside the renderer).

=================  =======  =========  ===============================================================
option             type     default    meaning
=================  =======  =========  ===============================================================
``steps``          int      0          Adam iterations (0: no refinement)
``lr``             float    0.02       Adam learning rate of the logit maps (diffuse, specular, roughness)
``normal_lr``      float    0.002      Adam learning rate of the normal slopes (p_x, p_y)
``final_lr_fraction`` float 0.1       every learning rate decays linearly to this fraction at the end
``lobes``          bool     False      also optimise the SG lobes
``lobe_lr``        float    0.01       learning rate of the lobe parameters
``prior_weight``   float    1.0        w_prior
``smooth_weight``  float    0.1        w_smooth
``log_weight``     float    0.1        w_log
``mode``           str      ``sg``     environment term of the renderer (``sg`` | ``quadrature``)
``spp``            int      16         quadrature directions per pixel (``mode="quadrature"``)
``log_every``      int      10         loss read back (host sync) every so many steps; the best
                                       iterate is chosen among these reads
=================  =======  =========  ===============================================================
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..geometry import Shot
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF

_EPS = 1e-3


@dataclass(frozen=True)
class ShotTarget:
    """One photo to fit: the shot's geometry, the image (H, W, 3) and a usable-pixel mask (H, W)."""

    shot: Shot
    image: np.ndarray
    mask: np.ndarray


@dataclass(frozen=True)
class RefineConfig:
    """Options of :func:`refine` (see the module table)."""

    steps: int = 0
    lr: float = 0.02
    normal_lr: float = 0.002
    final_lr_fraction: float = 0.1
    lobes: bool = False
    lobe_lr: float = 0.01
    prior_weight: float = 1.0
    smooth_weight: float = 0.1
    log_weight: float = 0.1
    mode: str = "sg"
    spp: int = 16
    log_every: int = 10

    def __post_init__(self):
        if not isinstance(self.steps, int) or self.steps < 0:
            raise InputError(f"--refine-steps {self.steps}: give an integer >= 0")
        if not (math.isfinite(self.final_lr_fraction) and 0 < self.final_lr_fraction <= 1):
            raise InputError(f"refinement final_lr_fraction {self.final_lr_fraction}: give a value in (0, 1]")
        for name in ("lr", "normal_lr", "lobe_lr"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InputError(f"refinement {name} {v}: give a finite value > 0")
        for name in ("prior_weight", "smooth_weight", "log_weight"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise InputError(f"refinement {name} {v}: give a finite value >= 0")
        if self.mode not in ("sg", "quadrature"):
            raise InputError(f"--render-mode {self.mode!r}: use sg or quadrature")


@dataclass
class RefineResult:
    """Refined maps and lobes, re-render errors before/after (per shot) and the loss history."""

    maps: SVBRDF
    env: SGEnvironment | None
    before: dict
    after: dict
    seconds: float
    history: list[tuple[int, float]] = field(default_factory=list)
    renders: dict[str, np.ndarray] = field(default_factory=dict)  # the re-renders behind ``after``
    kept_step: int = 0  # the iterate returned: the one of lowest loss in ``history``

    @property
    def loss_rose(self) -> bool:
        """Whether the last loss read is above the kept (lowest) one: the run diverged or
        oscillated after ``kept_step``."""
        return bool(self.history) and self.history[-1][0] != self.kept_step

    def loss_note(self) -> str | None:
        """``"loss rose from X to Y; kept step K"`` when :attr:`loss_rose`, else None."""
        if not self.loss_rose:
            return None
        return loss_note(self.history, self.kept_step)

    def to_json(self) -> dict:
        return {
            "seconds": round(self.seconds, 3),
            "before": self.before,
            "after": self.after,
            "history": [[s, round(v, 6)] for s, v in self.history],
            "kept_step": self.kept_step,
            "loss_rose": self.loss_rose,
        }


def loss_note(history, kept_step: int) -> str:
    """The one-line note of a refinement whose loss rose after ``kept_step`` (report and CLI)."""
    best = dict((int(s), float(v)) for s, v in history)[int(kept_step)]
    last = float(history[-1][1])
    return f"loss rose from {best:.4g} to {last:.4g}; kept step {kept_step}"


# -- rendering and errors (numpy in, numpy out) ---------------------------------------------------------


def render_options(mode: str = "sg", spp: int = 16):
    from ..render import RenderOptions

    return RenderOptions(mode=mode, spp=int(spp))


def rerender(
    maps: SVBRDF, env: SGEnvironment | None, shot: Shot, mode: str = "sg", spp: int = 16
) -> np.ndarray:
    """The fast render (H, W, 3) of ``maps`` for ``shot`` (its flash, the environment if lit)."""
    from ..render import render_numpy

    return render_numpy(maps, env, shot, mode=mode, spp=spp)


def image_errors(render: np.ndarray, target: np.ndarray, mask: np.ndarray) -> dict:
    """RMSE (linear) and relative RMSE (÷ RMS of the target) over the unmasked pixels."""
    m = mask.astype(bool)
    if not m.any():
        return {"rmse": float("nan"), "rel_rmse": float("nan")}
    diff = (render - target)[m]
    rmse = float(np.sqrt(np.mean(diff.astype(np.float64) ** 2)))
    rms = float(np.sqrt(np.mean(target[m].astype(np.float64) ** 2)))
    return {"rmse": rmse, "rel_rmse": rmse / rms if rms > 0 else float("nan")}


def rerender_errors(
    maps: SVBRDF, env: SGEnvironment | None, targets: list[ShotTarget], mode: str = "sg", spp: int = 16
) -> tuple[dict, dict[str, np.ndarray]]:
    """Per shot name: {"rmse", "rel_rmse"} and the re-render (H, W, 3); plus ``"mean"`` of both."""
    errors, renders = {}, {}
    for t in targets:
        renders[t.shot.name] = rerender(maps, env, t.shot, mode, spp)
        errors[t.shot.name] = image_errors(renders[t.shot.name], t.image, t.mask)
    errors["mean"] = {
        k: float(np.mean([errors[t.shot.name][k] for t in targets])) for k in ("rmse", "rel_rmse")
    }
    return errors, renders


def fit_flash_intensity(maps: SVBRDF, shot: Shot, flash_only: np.ndarray, mask: np.ndarray) -> float:
    """Least-squares intensity I [W/sr] of ``shot``'s flash making the flash-only render of ``maps``
    match ``flash_only`` (the units of the photo are unknown for real captures)."""
    import dataclasses

    unit = rerender(maps, None, dataclasses.replace(shot, flash_intensity=1.0, env=False))
    m = mask.astype(bool)
    num = float(np.sum(unit[m].astype(np.float64) * flash_only[m]))
    den = float(np.sum(unit[m].astype(np.float64) ** 2))
    if not (den > 0 and num > 0):
        raise InputError("the flash shot has no light from the flash; check --flash and --noflash")
    return num / den


# -- the optimisation -------------------------------------------------------------------------------------


def _logit(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, np.float64), _EPS, 1 - _EPS)
    return np.log(x / (1 - x)).astype(np.float32)


class _Params:
    """Unconstrained Dr.Jit parameters ↔ DrMaps / DrLobes."""

    def __init__(self, maps: SVBRDF, env: SGEnvironment | None, lobes: bool):
        import mitsuba as mi

        nz = np.maximum(maps.normal[..., 2:3], 0.05)
        self.shape = maps.shape
        self.values = {
            "diffuse": mi.TensorXf(_logit(maps.diffuse)),
            "specular": mi.TensorXf(_logit(maps.specular)),
            "roughness": mi.TensorXf(_logit(maps.roughness)),
            "normal_xy": mi.TensorXf(np.ascontiguousarray(maps.normal[..., :2] / nz, dtype=np.float32)),
        }
        self.lobes = bool(lobes and env is not None and env.num_lobes > 0)
        self.env = env
        if self.lobes:
            self.values.update(
                {
                    "axis": mi.TensorXf(np.ascontiguousarray(env.axis, dtype=np.float32)),
                    "log_sharpness": mi.TensorXf(np.log(env.sharpness).astype(np.float32)),
                    "log_amplitude": mi.TensorXf(np.log(env.amplitude + 1e-6).astype(np.float32)),
                }
            )

    def maps(self, p):
        import drjit as dr
        import mitsuba as mi

        from ..render import DrMaps

        h, w = self.shape
        xy = dr.unravel(mi.Vector2f, p["normal_xy"].array)
        n = dr.normalize(mi.Vector3f(xy.x, xy.y, 1.0))
        return DrMaps(
            normal=mi.TensorXf(dr.ravel(n), (h, w, 3)),
            diffuse=dr.rcp(1 + dr.exp(-p["diffuse"])),
            specular=dr.rcp(1 + dr.exp(-p["specular"])),
            roughness=dr.rcp(1 + dr.exp(-p["roughness"])),
        )

    def lobes_of(self, p):
        import drjit as dr

        from ..render import DrLobes

        if not self.lobes:
            return DrLobes.from_env(self.env if self.env is not None else SGEnvironment.empty())
        return DrLobes(p["axis"], dr.exp(p["log_sharpness"]), dr.exp(p["log_amplitude"]))


def _masked_mean(x, mask_t, count: float):
    import drjit as dr

    return dr.sum(dr.ravel(x * mask_t)) / count


def refine(
    maps: SVBRDF,
    env: SGEnvironment | None,
    targets: list[ShotTarget],
    config: RefineConfig,
    progress: Callable[[int, int, float], None] | None = None,
    before: dict | None = None,
) -> RefineResult:
    """Optimise ``maps`` (and with ``config.lobes`` the lobes of ``env``) against ``targets``.

    ``progress(step, steps, loss)`` is called every ``config.log_every`` steps. Returns the
    refined maps/lobes and the re-render errors of the fast renderer before and after (``before``:
    those of ``maps``/``env`` when the caller has them already, from :func:`rerender_errors`).
    """
    import drjit as dr
    import mitsuba as mi

    from ..render import render

    t0 = time.perf_counter()
    if not targets:
        raise InputError("refinement needs at least one shot")
    for t in targets:
        if t.image.shape[:2] != maps.shape or t.mask.shape != maps.shape:
            raise InputError(
                f"refinement: shot {t.shot.name} has image {tuple(t.image.shape[:2])}, mask "
                f"{tuple(t.mask.shape)}; the maps are {maps.shape}: give the shot and its mask at "
                f"the maps' size"
            )
    opts = render_options(config.mode, config.spp)
    if before is None:
        before, _ = rerender_errors(maps, env, targets, config.mode, config.spp)
    if config.steps == 0:
        return RefineResult(maps, env, before, before, time.perf_counter() - t0)

    params = _Params(maps, env, config.lobes)
    init = {
        k: mi.TensorXf(v)
        for k, v in (
            ("diffuse", maps.diffuse),
            ("specular", maps.specular),
            ("roughness", maps.roughness),
            ("normal", maps.encoded_normal()),
        )
    }
    data = []
    for t in targets:
        y = np.ascontiguousarray(t.image, dtype=np.float32)
        m = t.mask.astype(bool)
        count = float(max(m.sum(), 1) * 3)
        ms = float(np.mean(y[m].astype(np.float64) ** 2)) if m.any() else 1.0
        eps = 0.01 * float(np.mean(y[m])) + 1e-6 if m.any() else 1e-3
        mask3 = np.repeat(m[..., None], 3, axis=2).astype(np.float32)
        # Per-shot constants are opaque: one kernel serves every capture of this size.
        data.append(
            (
                t.shot,
                mi.TensorXf(y),
                mi.TensorXf(mask3),
                dr.opaque(mi.Float, count),
                dr.opaque(mi.Float, max(ms, 1e-12)),
                dr.opaque(mi.Float, eps),
            )
        )

    opt = dr.opt.Adam(lr=config.lr)
    for k, v in params.values.items():
        opt[k] = v
    base_lr = {k: config.lr for k in params.values}
    base_lr["normal_xy"] = config.normal_lr
    if params.lobes:
        for k in ("axis", "log_sharpness", "log_amplitude"):
            base_lr[k] = config.lobe_lr
    history = []
    h, w = maps.shape

    def objective(p):
        dm = params.maps(p)
        lobes = params.lobes_of(p)
        loss = mi.Float(0.0)
        for shot, y, mask_t, count, ms, eps in data:
            x = render(dm, lobes, shot, opts)
            diff = x - y
            loss += _masked_mean(diff * diff, mask_t, count) / ms
            if config.log_weight > 0:
                lg = dr.abs(dr.log(dr.maximum(x, 0.0) + eps) - dr.log(y + eps))
                loss += config.log_weight * _masked_mean(lg, mask_t, count)
        if config.prior_weight > 0:
            n_enc = (dm.normal + 1.0) * 0.5
            for name, cur in (
                ("diffuse", dm.diffuse),
                ("specular", dm.specular),
                ("roughness", dm.roughness),
                ("normal", n_enc),
            ):
                d = cur - init[name]
                loss += config.prior_weight * dr.mean(dr.ravel(d * d))
        if config.smooth_weight > 0 and h > 1 and w > 1:
            for cur in (dm.roughness, dm.specular, dm.normal):
                tv = dr.mean(dr.ravel(dr.abs(cur[1:, :] - cur[:-1, :]))) + dr.mean(
                    dr.ravel(dr.abs(cur[:, 1:] - cur[:, :-1]))
                )
                loss += config.smooth_weight * tv
        return loss

    # The loss of the iterate after ``step`` updates is read at step 0, every ``log_every`` steps
    # and after the last update; the best iterate read is kept (a diverging run returns the
    # maps it started from rather than worse ones).
    best_loss, best_step, best_params = math.inf, 0, None
    for step in range(config.steps + 1):
        p = {k: opt[k] for k in params.values}
        loss = objective(p)
        read = step == 0 or step % config.log_every == 0 or step == config.steps
        if read:
            value = float(loss[0])  # host sync: only every log_every steps
            history.append((step, value))
            if math.isfinite(value) and value < best_loss:
                best_loss, best_step = value, step
                best_params = {k: dr.detach(v) for k, v in p.items()}
                dr.eval(best_params)
            if progress is not None and step > 0:
                progress(step, config.steps, value)
        if step == config.steps:
            break
        # Adam's steps stay near lr even at the optimum (sign-like updates on noisy gradients):
        # decaying the rates lets per-pixel maps settle instead of dithering around it.
        frac = 1.0 - (1.0 - config.final_lr_fraction) * step / max(config.steps - 1, 1)
        opt.set_learning_rate({k: v * frac for k, v in base_lr.items()})
        dr.backward(loss)
        opt.step()

    with dr.suspend_grad():
        if best_params is None or best_step == 0:  # nothing better than the start: return it as given
            out_maps, out_env, best_step = maps, env, 0
        else:
            dm = params.maps(best_params)
            out_maps = SVBRDF(
                normal=dm.normal.numpy(),
                diffuse=dm.diffuse.numpy(),
                specular=dm.specular.numpy(),
                roughness=dm.roughness.numpy(),
                source="refined",
            )
            out_env = params.lobes_of(best_params).to_env() if params.lobes else env
    after, renders = rerender_errors(out_maps, out_env, targets, config.mode, config.spp)
    return RefineResult(out_maps, out_env, before, after, time.perf_counter() - t0, history, renders,
                        kept_step=best_step)


__all__ = [
    "ShotTarget",
    "RefineConfig",
    "RefineResult",
    "refine",
    "rerender",
    "rerender_errors",
    "image_errors",
    "fit_flash_intensity",
    "render_options",
]
