"""Fitting a spherical-Gaussian mixture to an equirectangular environment map (``ebr fit-env``).

The fit minimises, over K lobes ``G_k(ω) = μ_k exp(λ_k(ξ_k·ω − 1))``, a solid-angle weighted sum
over the texels t of a resampled map (weights ``Ω_t``, the cell solid angles, sum 4π):

    loss = Σ_t Ω_t ‖ŷ_t − y_t‖² / Σ_t Ω_t ‖y_t‖²                      (linear term)
         + β · Σ_t Ω_t ‖log(ŷ_t + ε) − log(y_t + ε)‖² / Σ_t Ω_t        (log term)

with ``ŷ_t = Σ_k G_k(ω_t)``, ``ε = 0.01 ×`` the solid-angle weighted mean radiance and β the
``log_weight``. The linear term fits the energy that dominates renders (sun, windows); the log
term keeps the dim sky and ground from being ignored. Parameters are unconstrained for Adam
(Dr.Jit ``dr.opt.Adam``): the axis as a free 3-vector (normalised in the model), ``log λ`` and
``log μ`` (:mod:`ebr_mitsuba.sgparams`, λ unbounded). The sum over lobes is one flat kernel over
(lobe, texel) pairs with one ``scatter_reduce`` into the texels (a per-lobe Python loop of
gathers is far slower in reverse mode: ``docs/conventions.md``, "Dr.Jit on the CPU").

Initialisation is greedy matching pursuit on the resampled map (:func:`greedy_init`): each new
lobe is centred near the brightest remaining cells, moved to the local mode of the residual
(mean shift), given the sharpness (from a √2-spaced grid) and least-squares amplitude that remove
the most residual energy, and subtracted; lobes the map does not need are spread over a Fibonacci
sphere with a small amplitude. Deterministic: no random numbers.

Resampling (:func:`resample_equirect`): the map is area-averaged (radiance weighted by solid
angle) to ``height × 2·height`` cells; each cell's direction is the centre of its footprint in the
source map's parameterisation (rows align-corners, :mod:`ebr_mitsuba.envmap`), its weight
the footprint's exact solid angle. The fit runs at ``height`` rows, the error is reported at
``eval_height`` rows (the settings and their defaults: :class:`EnvFitConfig`):

==============  ==================================================================================
error           definition (solid-angle weighted, over RGB)
==============  ==================================================================================
``rel_l1``      Σ Ω |ŷ − y| / Σ Ω |y| (the "sin-weighted relative L1" peers quote)
``rel_rmse``    sqrt(Σ Ω ‖ŷ − y‖² / Σ Ω ‖y‖²)
``log_rmse``    sqrt(Σ Ω ‖log(ŷ + ε) − log(y + ε)‖² / (3 Σ Ω))
``energy``      Σ Ω ŷ / Σ Ω y − 1 (luminance): relative error of the total power
==============  ==================================================================================

:func:`load_physg_fit` reads the peer fit format of PhySG (``(K, 7)`` rows: unnormalised axis in
its y-up frame, λ, μ; see ``../shared/data/README.md``) into our z-up :class:`SGEnvironment`.

Fitting runs single-threaded in Dr.Jit (:func:`fit_sg` sets ``dr.set_thread_count(1)`` for its
duration): the scatter-add order is then fixed and the same map gives a bit-identical fit, which
``ebr generate`` relies on.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import sgparams
from .colour import LUMINANCE
from .envmap import EquirectMap, equirect_solid_angles, map_to_world, uv_to_direction
from .errors import ConfigError, InputError
from .imageio import resize_area
from .sgenv import SGEnvironment
from .typedconfig import config, option

MAX_LOBES = 512


@config
class EnvFitConfig:
    """The settings of :func:`fit_sg` (the options of ``ebr fit-env``; a bad value given in code
    is a :class:`~ebr_mitsuba.errors.ConfigError`)."""

    lobes: int = option(32, "SG lobes", minimum=1, maximum=MAX_LOBES)
    iterations: int = option(400, "Adam iterations", minimum=0, flag="--iters")
    height: int = option(64, "rows of the resampled map the fit runs on", minimum=2)
    lr: float = option(0.03, "Adam learning rate", above=0)
    log_weight: float = option(0.1, "weight β of the log-space term", minimum=0)
    eval_height: int = option(128, "rows of the resampled map the error is reported at", minimum=2)


#: The fields ``ebr fit-env`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
ENVFIT_FLAGS = ("lobes", "iterations", "height", "lr", "log_weight")


@dataclass(frozen=True)
class Cells:
    """An equirectangular map resampled for fitting: N = h·2h cells.

    ``directions`` (N, 3) float64 unit world vectors; ``solid_angle`` (N,) float64 (sum 4π);
    ``radiance`` (N, 3) float64 (solid-angle weighted mean over each cell's footprint).
    """

    directions: np.ndarray
    solid_angle: np.ndarray
    radiance: np.ndarray


def resample_equirect(emap: EquirectMap, height: int) -> Cells:
    """Area-resample ``emap`` to ``height × 2·height`` cells (see the module docstring)."""
    h_src, w_src = emap.shape
    height = int(height)
    if height < 2:
        raise ConfigError(f"fit resolution {height} rows is too small; use at least 2")
    height = min(height, h_src)
    width = 2 * height
    omega_src = equirect_solid_angles(h_src, w_src)
    # Σ over each footprint = mean × (source texels per cell)
    per_cell = (h_src / height) * (w_src / width)
    omega = resize_area(omega_src, (height, width)).astype(np.float64) * per_cell
    weighted = resize_area(emap.data.astype(np.float64) * omega_src[..., None], (height, width))
    radiance = weighted.astype(np.float64) * per_cell / np.maximum(omega[..., None], 1e-300)
    # footprint centres in source texel coordinates → uv of the source parameterisation
    rows = (np.arange(height) + 0.5) * (h_src / height) - 0.5
    cols = (np.arange(width) + 0.5) * (w_src / width) - 0.5
    v = np.clip(rows / (h_src - 1), 0.0, 1.0)
    u = (cols + 0.5) / w_src
    uv = np.stack(np.meshgrid(u, v, indexing="xy"), axis=-1)
    dirs = uv_to_direction(uv)
    return Cells(dirs.reshape(-1, 3), omega.reshape(-1), radiance.reshape(-1, 3))


def fit_error(env: SGEnvironment, cells: Cells) -> dict:
    """Errors of ``env`` against ``cells`` (module docstring), as Python floats."""
    y = cells.radiance
    yhat = env.eval(cells.directions) if env.num_lobes else np.zeros_like(y)
    w = cells.solid_angle[:, None]
    eps = 0.01 * float((w * y).sum() / (3.0 * w.sum()))
    eps = max(eps, 1e-12)
    diff = yhat - y
    lum_y = float((w[:, 0] * (y @ LUMINANCE)).sum())
    lum_hat = float((w[:, 0] * (yhat @ LUMINANCE)).sum())
    return {
        "rel_l1": float((w * np.abs(diff)).sum() / max((w * np.abs(y)).sum(), 1e-300)),
        "rel_rmse": float(math.sqrt((w * diff**2).sum() / max((w * y**2).sum(), 1e-300))),
        "log_rmse": float(
            math.sqrt((w * (np.log(yhat + eps) - np.log(y + eps)) ** 2).sum() / (3.0 * w.sum()))
        ),
        "energy": lum_hat / max(lum_y, 1e-300) - 1.0,
    }


def greedy_init(cells: Cells, lobes: int) -> SGEnvironment:
    """Matching-pursuit initial lobes (module docstring); deterministic.

    Each step tries every pair (centre, λ) of the :data:`INIT_CANDIDATES` cells of largest
    remaining luminance and the sharpness values of :data:`INIT_SHARPNESS` that the resolution
    resolves, gives each its least-squares amplitude (solid-angle weighted, ≥ 0 per channel) and
    keeps the pair that removes the most residual energy. When no pair helps any more, the
    remaining lobes are spread over a Fibonacci sphere with a small amplitude (so that Adam can
    still move them: lobes stacked on one axis would receive identical updates forever).
    """
    residual = cells.radiance.copy()
    w = cells.solid_angle
    dirs = cells.directions
    n_rows = math.sqrt(dirs.shape[0] / 2.0)
    texel = math.pi / max(n_rows - 1.0, 1.0)
    lam_max = 2.0 / texel**2  # a lobe about one cell wide
    candidates = [lam for lam in INIT_SHARPNESS if lam <= lam_max] or [INIT_SHARPNESS[0]]
    mean = (w[:, None] * cells.radiance).sum(0) / w.sum()
    floor = np.maximum(1e-3 * mean, 1e-12)
    total = float((w[:, None] * cells.radiance**2).sum())
    axes, sharp, amps = [], [], []
    while len(axes) < lobes:
        lum = residual @ LUMINANCE
        m = min(INIT_CANDIDATES, lum.size)
        top = np.argpartition(-lum, m - 1)[:m]
        cos_m1 = dirs @ dirs[top].T - 1.0  # (N, m)
        best = None
        for lam in candidates:
            g = np.exp(lam * cos_m1)
            num = (g * w[:, None]).T @ residual  # (m, 3)
            den = np.maximum((w[:, None] * g * g).sum(0), 1e-300)  # (m,)
            gain = (np.maximum(num, 0.0) ** 2).sum(1) / den
            j = int(np.argmax(gain))
            if best is None or gain[j] > best[0]:
                best = (float(gain[j]), lam, top[j], np.maximum(num[j] / den[j], 0.0), g[:, j])
        gain, lam, cell, amp, g = best
        if gain <= 1e-9 * total:
            break
        axis, lam, amp, g = _refine(dirs, w, residual, dirs[cell], lam, candidates)
        residual = residual - g[:, None] * amp[None, :]
        axes.append(axis)
        sharp.append(lam)
        amps.append(np.maximum(amp, floor))
    n_fill = lobes - len(axes)
    if n_fill:
        lam_fill = max(1.0, n_fill / (2.0 * math.pi))
        for axis in fibonacci_sphere(n_fill):
            axes.append(axis)
            sharp.append(lam_fill)
            amps.append(floor)
    return SGEnvironment(np.array(axes), np.array(sharp), np.array(amps))


def _ls_lobe(dirs, w, residual, axis, candidates):
    """Best (λ, amplitude ≥ 0, gain, values) of a lobe on ``axis`` over the λ candidates."""
    cos_m1 = dirs @ axis - 1.0
    best = None
    for lam in candidates:
        g = np.exp(lam * cos_m1)
        num = (w * g) @ residual
        den = max(float((w * g * g).sum()), 1e-300)
        gain = float((np.maximum(num, 0.0) ** 2).sum() / den)
        if best is None or gain > best[2]:
            best = (lam, np.maximum(num / den, 0.0), gain, g)
    return best


def _refine(dirs, w, residual, axis, lam, candidates, steps: int = 3):
    """Move a picked centre to the local mode of the residual (Gaussian mean shift with the
    lobe's own kernel), then choose λ again: a centre one cell off the true axis would otherwise
    leave a ring that the next steps waste lobes on."""
    positive = np.maximum(residual @ LUMINANCE, 0.0) * w
    for _ in range(steps):
        g = np.exp(lam * (dirs @ axis - 1.0))
        mean = (positive * g) @ dirs
        norm = float(np.linalg.norm(mean))
        if norm <= 0.0:
            break
        axis = mean / norm
        lam, _, _, _ = _ls_lobe(dirs, w, residual, axis, candidates)
    lam, amp, _, g = _ls_lobe(dirs, w, residual, axis, candidates)
    return axis, lam, amp, g


#: Sharpness candidates of :func:`greedy_init`.
INIT_SHARPNESS = tuple(2.0 ** (k / 2.0) for k in range(0, 25))  # 1 … 4096, ratio √2
#: Cells of largest remaining luminance tried as centres in each step of :func:`greedy_init`.
INIT_CANDIDATES = 16


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` nearly uniform unit vectors (n, 3) (golden-angle spiral), deterministic."""
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


@dataclass(frozen=True)
class FitResult:
    """A fitted mixture, its errors (:func:`fit_error` at the evaluation resolution, and at the
    fit resolution under ``"fit"``), the loss every 50 iterations and the settings used."""

    env: SGEnvironment
    error: dict
    initial_error: dict
    loss_history: list = field(default_factory=list)
    seconds: float = 0.0
    settings: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "lobes": self.env.num_lobes,
            "error": self.error,
            "initial_error": self.initial_error,
            "loss_history": self.loss_history,
            "seconds": round(self.seconds, 3),
            "settings": self.settings,
        }


def fit_sg(emap: EquirectMap, config: EnvFitConfig | None = None, *, progress=None, **options) -> FitResult:
    """Fit SG lobes to ``emap`` (module docstring) with the settings of ``config`` (default:
    :class:`EnvFitConfig`'s), ``options`` (its fields, ``lobes=8``) set over it; returns a
    :class:`FitResult`.

    ``progress``: optional callable ``(iteration, loss)`` called every 50 iterations.
    Deterministic (single-threaded Dr.Jit for the duration of the call).
    """
    if config is not None and not isinstance(config, EnvFitConfig):
        raise TypeError(f"fit_sg: config must be an EnvFitConfig, got {config!r}")
    cfg = dataclasses.replace(config or EnvFitConfig(), **options)
    lobes, iterations, height, lr, log_weight = cfg.lobes, cfg.iterations, cfg.height, cfg.lr, cfg.log_weight
    eval_height = cfg.eval_height
    import drjit as dr

    from .variant import ensure_variant

    ensure_variant()
    t0 = time.perf_counter()
    cells = resample_equirect(emap, height)
    eval_cells = resample_equirect(emap, eval_height)
    init = greedy_init(cells, int(lobes))
    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        env, history = _adam(cells, init, int(iterations), float(lr), float(log_weight), progress)
    finally:
        dr.set_thread_count(threads)
    error = fit_error(env, eval_cells)
    error["fit"] = fit_error(env, cells)
    settings = {
        "lobes": int(lobes),
        "iterations": int(iterations),
        "height": int(min(height, emap.shape[0])),
        "lr": float(lr),
        "log_weight": float(log_weight),
        "eval_height": int(eval_height),
        "source": emap.source,
    }
    return FitResult(env, error, fit_error(init, eval_cells), history, time.perf_counter() - t0, settings)


def _adam(cells: Cells, init: SGEnvironment, iterations: int, lr: float, log_weight: float, progress):
    import drjit as dr
    import mitsuba as mi

    n = cells.directions.shape[0]
    k = init.num_lobes
    d = cells.directions.astype(np.float32)
    dirs = mi.Vector3f(d[:, 0], d[:, 1], d[:, 2])
    y = cells.radiance.astype(np.float32)
    target = mi.Color3f(y[:, 0], y[:, 1], y[:, 2])
    w = mi.Float(cells.solid_angle.astype(np.float32))
    wy = cells.solid_angle[:, None] * cells.radiance
    eps = max(0.01 * float(wy.sum() / (3.0 * cells.solid_angle.sum())), 1e-12)
    lin_norm = float((cells.solid_angle[:, None] * cells.radiance**2).sum())
    lin_norm = max(lin_norm, 1e-30)
    log_norm = float(3.0 * cells.solid_angle.sum())
    log_target = dr.log(target + eps)

    idx = dr.arange(mi.UInt32, n * k)
    lobe = idx // n
    texel = idx - lobe * n
    pair_dirs = dr.gather(mi.Vector3f, dirs, texel)

    # sharpness unbounded (sgparams docstring): sky lobes of real maps go below the extraction's 0.5
    a, s, m = sgparams.encode(init.axis, init.sharpness, init.amplitude, bounded=False)
    opt = dr.opt.Adam(
        lr=lr,
        params={
            "axis": mi.Vector3f(a[:, 0], a[:, 1], a[:, 2]),
            "log_sharpness": mi.Float(s),
            "log_amplitude": mi.Color3f(m[:, 0], m[:, 1], m[:, 2]),
        },
    )
    opt.set_learning_rate(axis=lr * 0.5)

    def model():
        axis = dr.normalize(opt["axis"])
        lam, amp = sgparams.dr_decode(opt["log_sharpness"], opt["log_amplitude"], bounded=False)
        ax = dr.gather(mi.Vector3f, axis, lobe)
        lam_p = dr.gather(mi.Float, lam, lobe)
        amp_p = dr.gather(mi.Color3f, amp, lobe)
        val = amp_p * dr.exp(lam_p * (-0.5 * dr.squared_norm(ax - pair_dirs)))
        yhat = dr.zeros(mi.Color3f, n)
        dr.scatter_reduce(dr.ReduceOp.Add, yhat, val, texel)
        return yhat

    history = []
    for it in range(iterations):
        yhat = model()
        diff = yhat - target
        lin = dr.sum(w * dr.squared_norm(diff)) / lin_norm
        logd = dr.log(yhat + eps) - log_target
        loss = lin + log_weight * dr.sum(w * dr.squared_norm(logd)) / log_norm
        dr.backward(loss)
        opt.step()
        if it % 50 == 0 or it == iterations - 1:
            value = float(loss[0])
            history.append([it, value])
            if progress is not None:
                progress(it, value)
    axis = dr.normalize(opt["axis"]).numpy().T.astype(np.float64)
    lam, amp = sgparams.decode(opt["log_sharpness"].numpy(), opt["log_amplitude"].numpy().T, bounded=False)
    env = SGEnvironment(axis, np.maximum(lam, 1e-6), amp)
    return env, history


# -- the peer fit -----------------------------------------------------------------------------


def load_physg_fit(path: str | Path) -> SGEnvironment:
    """A PhySG ``(K, 7)`` ``.npy`` SG fit as a z-up :class:`SGEnvironment`.

    Rows are ``[axis xyz (unnormalised), λ, μ rgb]`` (λ and μ taken in absolute value, as PhySG
    does) in PhySG's y-up frame; ``a → (a_z, a_y, −a_x)`` takes an axis to Mitsuba's envmap frame
    and :func:`ebr_mitsuba.envmap.map_to_world` to ours.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file; give a PhySG (K, 7) .npy SG fit")
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"{path}: cannot read it as a .npy array ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != 7:
        raise InputError(f"{path}: array of shape {arr.shape}; a PhySG SG fit is (K, 7)")
    a = arr[:, :3].astype(np.float64)
    mitsuba_frame = np.stack([a[:, 2], a[:, 1], -a[:, 0]], axis=-1)
    return SGEnvironment(map_to_world(mitsuba_frame), np.abs(arr[:, 3]), np.abs(arr[:, 4:7]))


def equirect_irradiance(emap: EquirectMap, normal=(0.0, 0.0, 1.0)) -> np.ndarray:
    """RGB irradiance (3,) of ``emap`` on a plane with unit ``normal`` (clamped cosine, the
    solid-angle weighted sum over texels), float64."""
    h, w = emap.shape
    from .envmap import equirect_directions

    cos = np.maximum(equirect_directions(h, w) @ np.asarray(normal, np.float64), 0.0)
    weight = equirect_solid_angles(h, w) * cos
    return (emap.data.astype(np.float64) * weight[..., None]).sum(axis=(0, 1))


__all__ = [
    "Cells",
    "FitResult",
    "fit_error",
    "fit_sg",
    "greedy_init",
    "load_physg_fit",
    "resample_equirect",
    "equirect_irradiance",
]
