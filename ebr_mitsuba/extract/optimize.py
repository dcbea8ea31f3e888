"""Adam refinement of all lobes against the exemplars (Dr.Jit gradients).

Loss over the exemplars i (weights λ_i), on ``g²`` pixels per exemplar re-drawn every iteration
(:func:`ebr_mitsuba.extract.forward.stratified_indices`, full-resolution targets):

    L = Σ_i λ_i ( ‖ŷ_i − y_i‖ / ‖y_i‖  +  β ‖log(ŷ_i + ε_i) − log(y_i + ε_i)‖ / √(3 g²) )

with ``‖y_i‖`` the exemplar's full-image RMS scaled to g² pixels, ``ε_i`` = ``log_eps`` × its mean
radiance and β = ``log_weight``. Saturated pixels (see :class:`Problem`) count only when the
model is *below* them (a clipped pixel is a lower bound). Parameters are unconstrained: the axis
as a free 3-vector (normalised by the renderer), ``log λ`` (clamped to [log 0.5, log 2·10⁴]) and
``log μ`` (so μ > 0 always), learning rates decaying along a cosine to 10 % over each call of
:func:`run_adam` (one stage between densification rounds). The pixel indices are data and the
quadrature seed is opaque, so one
set of kernels serves every iteration, and the whole step (forward, backward, Adam update) is a
:func:`drjit.freeze` function: traced once per lobe count and replayed after that. The loss is
read back every ``READBACK`` iterations only.
"""

from __future__ import annotations

import gc
import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from ..render.inputs import DrLobes, RenderOptions
from .forward import ExemplarGeometry, stratified_indices

READBACK = 25
LOG_LAMBDA_MIN = math.log(0.5)
LOG_LAMBDA_MAX = math.log(2.0e4)


@dataclass
class Problem:
    """The normalised exemplar stack and the per-exemplar loss constants.

    ``targets`` (N·H·W, 3) float32 flat (normalised radiance), ``saturated`` (N·H·W,) bool (clipped
    pixels), ``weights``/``eps``/``rms`` (N,) per exemplar, ``correction`` (N·H·W, 3) added to
    (``offset``) or multiplied into (``ratio``) the closed-form model in ``corrected`` mode.
    """

    geometry: ExemplarGeometry
    targets: np.ndarray
    saturated: np.ndarray
    weights: np.ndarray
    eps: np.ndarray
    rms: np.ndarray
    correction: np.ndarray

    def __post_init__(self):
        t = self.targets.astype(np.float32)
        self.dr_targets = mi.Color3f(t[:, 0], t[:, 1], t[:, 2])
        self.dr_saturated = mi.Bool(self.saturated)
        self.dr_weights = mi.Float(self.weights.astype(np.float32))
        self.dr_eps = mi.Float(self.eps.astype(np.float32))
        self.dr_rms = mi.Float(self.rms.astype(np.float32))
        self.set_correction(self.correction)

    def arrays(self) -> dict:
        """The Dr.Jit arrays of the loss and the forward model, by name."""
        return {
            "targets": self.dr_targets,
            "saturated": self.dr_saturated,
            "weights": self.dr_weights,
            "eps": self.dr_eps,
            "rms": self.dr_rms,
            "correction": self.dr_correction,
            "view": self.geometry.view,
            "roughness": self.geometry.roughness_array,
        }

    def set_correction(self, correction: np.ndarray) -> None:
        self.correction = np.asarray(correction, np.float32)
        c = self.correction
        self.dr_correction = mi.Color3f(c[:, 0], c[:, 1], c[:, 2])

    def row_weights(self, index: np.ndarray) -> np.ndarray:
        """Per-pixel least-squares weight λ_i/‖y_i‖ (for the amplitude solve), (P,)."""
        img = index // self.geometry.pixels
        return (self.weights / np.maximum(self.rms, 1e-30))[img]


def loss_terms(
    problem: Problem,
    yhat: mi.Color3f,
    index: mi.UInt32,
    per_image: int,
    log_weight: float,
    arrays: dict | None = None,
):
    """The loss (module docstring) of model values ``yhat`` at ``index``; ``arrays`` overrides
    the problem's Dr.Jit arrays (the frozen step passes them explicitly)."""
    arr = arrays or problem.arrays()
    n_pix = problem.geometry.pixels
    img = index // n_pix
    y = dr.gather(mi.Color3f, arr["targets"], index)
    sat = dr.gather(mi.Bool, arr["saturated"], index)
    eps = dr.gather(mi.Float, arr["eps"], img)
    diff = yhat - y
    above = sat & (diff > 0.0)
    diff = dr.select(above, 0.0, diff)
    logd = dr.log(dr.maximum(yhat, 0.0) + eps) - dr.log(y + eps)
    logd = dr.select(above, 0.0, logd)
    n = problem.geometry.count
    lin = dr.zeros(mi.Float, n)
    lg = dr.zeros(mi.Float, n)
    # the indices are sorted by exemplar: a packet of lanes shares its target (ReduceMode.Local)
    dr.scatter_reduce(dr.ReduceOp.Add, lin, dr.squared_norm(diff), img, mode=dr.ReduceMode.Local)
    dr.scatter_reduce(dr.ReduceOp.Add, lg, dr.squared_norm(logd), img, mode=dr.ReduceMode.Local)
    norm = arr["rms"] * math.sqrt(per_image)
    terms = dr.safe_sqrt(lin) / dr.maximum(norm, 1e-30) + log_weight * dr.safe_sqrt(lg / (3.0 * per_image))
    return dr.sum(arr["weights"] * terms)


def lobes_from_params(axis, log_sharpness, log_amplitude) -> DrLobes:
    lam = dr.exp(dr.clip(log_sharpness, LOG_LAMBDA_MIN, LOG_LAMBDA_MAX))
    return DrLobes(axis, lam, dr.exp(log_amplitude))


def initial_params(axis: np.ndarray, sharpness: np.ndarray, amplitude: np.ndarray) -> list:
    """Unconstrained parameters [axis, log λ, log μ] as Dr.Jit arrays."""
    a = np.asarray(axis, np.float32)
    s = np.log(np.clip(np.asarray(sharpness, np.float64), 0.5, 2.0e4)).astype(np.float32)
    m = np.log(np.maximum(np.asarray(amplitude, np.float64), 1e-12)).astype(np.float32)
    return [
        mi.Vector3f(*(aligned(a[:, i]) for i in range(3))),
        mi.Float(aligned(s)),
        mi.Color3f(*(aligned(m[:, i]) for i in range(3))),
    ]


def aligned(a: np.ndarray) -> np.ndarray:
    """A contiguous copy of the 1-D array ``a`` starting on a 64-byte boundary.

    Dr.Jit maps numpy memory without copying and compiles the kernels that read it for the
    pointer's alignment: numpy's 16-byte alignment made the first traced Adam step's kernels
    differ from call to call and miss the kernel cache (0.5–1 s of compilation per call)."""
    a = np.asarray(a).reshape(-1)
    buf = np.empty(a.nbytes + 64, np.uint8)
    off = (-buf.ctypes.data) % 64
    out = buf[off : off + a.nbytes].view(a.dtype)
    out[:] = a
    return out


def read_lobes(params) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Current lobes as numpy (axis (K, 3) unit, sharpness (K,), amplitude (K, 3)); lobes with a
    non-finite parameter are dropped."""
    a = np.asarray(params[0].numpy(), np.float64).T
    s = np.exp(np.clip(np.asarray(params[1].numpy(), np.float64), LOG_LAMBDA_MIN, LOG_LAMBDA_MAX))
    m = np.exp(np.asarray(params[2].numpy(), np.float64)).T
    norm = np.linalg.norm(a, axis=1)
    ok = np.isfinite(a).all(1) & np.isfinite(s) & np.isfinite(m).all(1) & (norm > 1e-12)
    return a[ok] / norm[ok, None], s[ok], m[ok]


BETA1, BETA2, ADAM_EPS = 0.9, 0.999, 1e-8
LR_FLOOR = 0.1  # cosine decay of the learning rates to this fraction over one run_adam call


def _make_step(
    problem: Problem, options: RenderOptions, corrected: str | None, per_image: int, log_weight: float
):
    """A frozen Adam step (:func:`drjit.freeze`): traced once per lobe count, then replayed, so an
    iteration costs its kernels and no Python tracing. Every value that changes between steps is
    an argument (parameters, moments, step count, pixel indices)."""
    geom = problem.geometry

    def step(params, m1, m2, t, lrs, index, arrays):
        params = [dr.detach(p) for p in params]
        dr.enable_grad(params)
        # two lobe sets built from the same parameters: the pairs gather from one, the per-lobe
        # irradiance reads the other, so the reverse pass is one kernel (forward module docstring)
        lobes = lobes_from_params(*params)
        diffuse_lobes = lobes_from_params(*params)
        yhat = geom.render_with(lobes, index, options, arrays["view"], arrays["roughness"], diffuse_lobes)
        if corrected == "offset":
            yhat = yhat + dr.gather(mi.Color3f, arrays["correction"], index)
        elif corrected == "ratio":
            yhat = yhat * dr.gather(mi.Color3f, arrays["correction"], index)
        loss = loss_terms(problem, yhat, index, per_image, log_weight, arrays)
        dr.backward(loss)
        c1 = 1.0 - dr.power(BETA1, t)
        c2 = 1.0 - dr.power(BETA2, t)
        new_p, new_m1, new_m2 = [], [], []
        for p, a, b, lr in zip(params, m1, m2, lrs):
            g = dr.grad(p)
            g = dr.select(dr.isfinite(g), g, 0.0)
            a = BETA1 * a + (1.0 - BETA1) * g
            b = BETA2 * b + (1.0 - BETA2) * g * g
            upd = lr * (a / c1) / (dr.sqrt(b / c2) + ADAM_EPS)
            new_p.append(dr.detach(p) - upd)
            new_m1.append(a)
            new_m2.append(b)
        return new_p, new_m1, new_m2, dr.detach(loss)

    return dr.freeze(step)


def run_adam(
    problem: Problem,
    lobes: tuple,
    iters: int,
    first: int,
    *,
    lr: float,
    lr_axis: float,
    log_weight: float,
    grid: int,
    options: RenderOptions,
    corrected: str | None,
    rng: np.random.Generator,
    history: list,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``iters`` Adam steps from ``lobes`` (numpy triple); iteration numbers start at ``first``
    (the loss history uses them). Appends ``[iteration, loss]`` to ``history`` every
    :data:`READBACK` iterations. Returns the refined lobes. Adam's moments start from zero."""
    if iters <= 0 or len(lobes[1]) == 0:
        return lobes
    geom = problem.geometry
    per_image = min(grid, geom.height) * min(grid, geom.width)
    params = initial_params(*lobes)
    m1 = [dr.zeros(type(p), dr.width(p)) for p in params]
    m2 = [dr.zeros(type(p), dr.width(p)) for p in params]
    arrays = problem.arrays()
    step = _make_step(problem, options, corrected, per_image, log_weight)
    # Dr.Jit 1.5 aborts the process when memory mapped from numpy is released while a frozen
    # function records (RecordThreadState::enqueue_host_func). Collect pending garbage now and
    # keep the cyclic collector off during the loop, so no such release can fall into a recording.
    gc.collect()
    dr.sync_thread()
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        for k in range(iters):
            it = first + k
            decay = LR_FLOOR + (1.0 - LR_FLOOR) * 0.5 * (1.0 + math.cos(math.pi * k / iters))
            lrs = [mi.Float(lr_axis * decay), mi.Float(lr * decay), mi.Float(lr * decay)]
            index = mi.UInt32(aligned(stratified_indices(rng, geom.count, geom.height, geom.width, grid)))
            params, m1, m2, loss = step(params, m1, m2, mi.Float(float(k + 1)), lrs, index, arrays)
            if it % READBACK == 0:
                history.append([it, float(loss.numpy()[0])])
    finally:
        if was_enabled:
            gc.enable()
    dr.eval(params)
    return read_lobes(params)
