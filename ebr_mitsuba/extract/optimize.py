"""Adam refinement of all lobes against the exemplars (Dr.Jit gradients).

Loss over the exemplars i (weights λ_i), on ``g²`` pixels per exemplar re-drawn every iteration
(:func:`ebr_mitsuba.extract.forward.stratified_indices`, full-resolution targets):

    L = Σ_i λ_i ( ‖ŷ_i − y_i‖ / ‖y_i‖  +  β ‖log(ŷ_i + ε_i) − log(y_i + ε_i)‖ / √(3 g²) )

with ``‖y_i‖`` the exemplar's full-image RMS scaled to g² pixels, ``ε_i`` = ``log_eps`` × its mean
radiance and β = ``log_weight``. Saturated pixels (see :class:`Problem`) count only when the
model is *below* them (a clipped pixel is a lower bound). Parameters are unconstrained: the axis
as a free 3-vector (normalised by the renderer), ``log λ`` (clamped to [log 0.5, log 2·10⁴]) and
``log μ`` (so μ > 0 always; :mod:`ebr_mitsuba.sgparams`), learning rates decaying along a cosine
to 10 % over each call of :func:`run_adam` (one stage between densification rounds). The pixel
indices are data and the quadrature seed is opaque, so one set of kernels serves every
iteration, and the whole step (forward, backward, Adam update) is a :func:`drjit.freeze`
function: traced once per call of :func:`run_adam` and replayed after that. The loss is read back
every ``READBACK`` iterations only.

Speed (measured with 64 lobes, 4 exemplars, 32² pixels each per iteration: 262,144 (pixel, lobe)
pairs): an iteration is two kernels over the pairs (forward; reverse, which recomputes the
forward values) and about 40 launches in all, down from 6 pair kernels and 77 launches:

* the reverse pass runs in two stages: the loss's gradient w.r.t. the environment term is
  evaluated first (one kernel, correction included), then propagated to the lobes; together with
  the renderer's :func:`ebr_mitsuba.render.env_sg.sg_environment` this keeps it in one pair kernel;
* the sampled pixels' data (target, correction, saturation: one :data:`ROW`-float row per pixel,
  one cache line per sample instead of one per channel and array), log-targets, view vectors and
  roughness are gathered once per iteration in one kernel, not re-gathered in every kernel;
* pixel indices are drawn with the same generator calls as before but uploaded every
  :data:`INDEX_BLOCK` iterations: each per-iteration numpy array mapped into Dr.Jit queued a host
  callback to release it, which waited for the GIL (up to a few ms per iteration);
* numpy inputs are copied to 64-byte-aligned memory (:func:`aligned`): Dr.Jit compiles kernels
  for the alignment of mapped numpy memory, so the first traced step's kernels differed between
  calls and missed the kernel cache (0.5–1 s of compilation per call).
"""

from __future__ import annotations

import gc
import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .. import sgparams
from ..render.inputs import DrLobes, RenderOptions
from .forward import ExemplarGeometry, stratified_indices

READBACK = 25
ROW = 8  # floats per pixel in Problem's per-pixel rows
INDEX_BLOCK = 50  # iterations whose pixel indices are drawn and uploaded at once


@dataclass
class Problem:
    """The normalised exemplar stack and the per-exemplar loss constants.

    ``targets`` (N·H·W, 3) float32 flat (normalised radiance), ``saturated`` (N·H·W,) bool (clipped
    pixels), ``weights``/``eps``/``rms`` (N,) per exemplar, ``correction`` (N·H·W, 3) added to
    (``offset``) or multiplied into (``ratio``) the closed-form model in ``corrected`` mode. On the
    Dr.Jit side the per-pixel arrays are one row of :data:`ROW` floats per pixel (:meth:`arrays`).
    """

    geometry: ExemplarGeometry
    targets: np.ndarray
    saturated: np.ndarray
    weights: np.ndarray
    eps: np.ndarray
    rms: np.ndarray
    correction: np.ndarray

    def __post_init__(self):
        self.dr_weights = mi.Float(aligned(self.weights.astype(np.float32)))
        self.dr_eps = mi.Float(aligned(self.eps.astype(np.float32)))
        self.dr_rms = mi.Float(aligned(self.rms.astype(np.float32)))
        self.set_correction(self.correction)

    def arrays(self) -> dict:
        """The Dr.Jit arrays of the loss and the forward model, by name: ``rows`` (the per-pixel
        data, :data:`ROW` floats per pixel), ``weights``/``eps``/``rms``, ``view``, ``roughness``."""
        return {
            "rows": self.dr_rows,
            "weights": self.dr_weights,
            "eps": self.dr_eps,
            "rms": self.dr_rms,
            "view": self.geometry.view,
            "roughness": self.geometry.roughness_array,
        }

    def set_correction(self, correction: np.ndarray) -> None:
        """Replace ``correction`` (N·H·W, 3)."""
        self.correction = np.asarray(correction, np.float32)
        # one row of ROW floats per pixel (target RGB, correction RGB, saturated as 0/1, padding),
        # 32 bytes: a sampled pixel costs one cache line, not one per channel and array
        rows = np.zeros((len(self.targets), ROW), np.float32)
        rows[:, 0:3] = self.targets
        rows[:, 3:6] = self.correction
        rows[:, 6] = self.saturated
        self.dr_rows = mi.Float(aligned(rows.reshape(-1)))

    def row_weights(self, index: np.ndarray) -> np.ndarray:
        """Per-pixel least-squares weight λ_i/‖y_i‖ (for the amplitude solve), (P,)."""
        img = index // self.geometry.pixels
        return (self.weights / np.maximum(self.rms, 1e-30))[img]


@dataclass
class Pixels:
    """One iteration's sampled pixels and their loss data, ``P`` lanes each: flat ``index``,
    exemplar ``img``, target ``y`` (Color3f), ``log_y`` = log(y + ε_img), ``eps`` = ε_img,
    ``saturated`` and the model ``correction`` (Color3f)."""

    index: mi.UInt32
    img: mi.UInt32
    y: mi.Color3f
    log_y: mi.Color3f
    eps: mi.Float
    saturated: mi.Bool
    correction: mi.Color3f

    @staticmethod
    def gather(problem: Problem, index: mi.UInt32, arrays: dict | None = None) -> Pixels:
        """The loss data at ``index``; ``arrays`` overrides the problem's Dr.Jit arrays."""
        arr = arrays or problem.arrays()
        img = index // problem.geometry.pixels
        base = index * ROW
        rows = arr["rows"]
        y = mi.Color3f(*(dr.gather(mi.Float, rows, base + c) for c in range(3)))
        correction = mi.Color3f(*(dr.gather(mi.Float, rows, base + c) for c in range(3, 6)))
        saturated = dr.gather(mi.Float, rows, base + 6) > 0.5
        eps = dr.gather(mi.Float, arr["eps"], img)
        return Pixels(index, img, y, dr.log(y + eps), eps, saturated, correction)


def loss_terms(
    problem: Problem,
    yhat: mi.Color3f,
    pixels: Pixels,
    per_image: int,
    log_weight: float,
    arrays: dict | None = None,
):
    """The loss (module docstring) of model values ``yhat`` at ``pixels``; ``arrays`` overrides
    the problem's Dr.Jit arrays (the frozen step passes them explicitly)."""
    arr = arrays or problem.arrays()
    diff = yhat - pixels.y
    above = pixels.saturated & (diff > 0.0)
    diff = dr.select(above, 0.0, diff)
    logd = dr.log(dr.maximum(yhat, 0.0) + pixels.eps) - pixels.log_y
    logd = dr.select(above, 0.0, logd)
    n = problem.geometry.count
    lin = dr.zeros(mi.Float, n)
    lg = dr.zeros(mi.Float, n)
    # the indices are sorted by exemplar: a packet of lanes shares its target (ReduceMode.Local)
    dr.scatter_reduce(dr.ReduceOp.Add, lin, dr.squared_norm(diff), pixels.img, mode=dr.ReduceMode.Local)
    dr.scatter_reduce(dr.ReduceOp.Add, lg, dr.squared_norm(logd), pixels.img, mode=dr.ReduceMode.Local)
    norm = arr["rms"] * math.sqrt(per_image)
    terms = dr.safe_sqrt(lin) / dr.maximum(norm, 1e-30) + log_weight * dr.safe_sqrt(lg / (3.0 * per_image))
    return dr.sum(arr["weights"] * terms)


def lobes_from_params(axis, log_sharpness, log_amplitude) -> DrLobes:
    """The lobes of the parameters (:func:`ebr_mitsuba.sgparams.dr_decode`)."""
    return DrLobes(axis, *sgparams.dr_decode(log_sharpness, log_amplitude))


def initial_params(axis: np.ndarray, sharpness: np.ndarray, amplitude: np.ndarray) -> list:
    """Unconstrained parameters [axis, log λ, log μ] as Dr.Jit arrays
    (:func:`ebr_mitsuba.sgparams.encode`)."""
    a, s, m = sgparams.encode(axis, np.asarray(sharpness, np.float64), amplitude)
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
    s, m = sgparams.decode(params[1].numpy(), params[2].numpy())
    m = m.T
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

    count = geom.count * per_image

    def step(params, m1, m2, t, lrs, index_block, offset, arrays):
        index = dr.gather(mi.UInt32, index_block, dr.arange(mi.UInt32, count) + offset)
        pixels = Pixels.gather(problem, index, arrays)
        points = geom.points(index, arrays["view"], arrays["roughness"])
        # one kernel for this iteration's per-pixel data; the later kernels read it
        dr.eval(pixels, points.v, points.roughness)
        params = [dr.detach(p) for p in params]
        dr.enable_grad(params)
        env = geom.render_points(points, lobes_from_params(*params), options)
        # reverse mode in two stages: the loss's gradient w.r.t. the environment term (one kernel
        # for all three channels, correction included), then from there back to the parameters
        env_free = dr.detach(env)
        dr.enable_grad(env_free)
        if corrected == "offset":
            yhat = env_free + pixels.correction
        elif corrected == "ratio":
            yhat = env_free * pixels.correction
        else:
            yhat = env_free
        loss = loss_terms(problem, yhat, pixels, per_image, log_weight, arrays)
        dr.backward(loss)
        grad_env = dr.grad(env_free)
        dr.eval(grad_env)
        dr.set_grad(env, grad_env)
        dr.backward_from(env)
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


def _index_block(rng: np.random.Generator, geom: ExemplarGeometry, grid: int, iters: int) -> mi.UInt32:
    """The pixel indices of the next ``iters`` (≤ :data:`INDEX_BLOCK`) iterations, drawn in turn
    (:func:`stratified_indices`) and zero-padded to :data:`INDEX_BLOCK` iterations (a fixed width:
    the frozen step is not traced again for a short last block)."""
    draws = [stratified_indices(rng, geom.count, geom.height, geom.width, grid) for _ in range(iters)]
    block = np.zeros(INDEX_BLOCK * len(draws[0]), np.uint32)
    block[: sum(len(d) for d in draws)] = np.concatenate(draws)
    return mi.UInt32(aligned(block))


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
    count = geom.count * per_image
    try:
        for k in range(iters):
            it = first + k
            if k % INDEX_BLOCK == 0:
                block = _index_block(rng, geom, grid, min(INDEX_BLOCK, iters - k))
            decay = LR_FLOOR + (1.0 - LR_FLOOR) * 0.5 * (1.0 + math.cos(math.pi * k / iters))
            lrs = [mi.Float(lr_axis * decay), mi.Float(lr * decay), mi.Float(lr * decay)]
            offset = mi.UInt32((k % INDEX_BLOCK) * count)
            params, m1, m2, loss = step(params, m1, m2, mi.Float(float(k + 1)), lrs, block, offset, arrays)
            if it % READBACK == 0:
                history.append([it, float(loss.numpy()[0])])
    finally:
        if was_enabled:
            gc.enable()
    dr.eval(params)
    return read_lobes(params)
