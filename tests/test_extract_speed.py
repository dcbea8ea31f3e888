"""The fast Adam step of SG extraction: same numbers as the plain reverse-mode formulation, and the
kernel structure that makes it fast (two kernels over the (pixel, lobe) pairs per iteration, no
recompilation between calls). Kernel counts only; no wall-clock assertions."""

from __future__ import annotations

import math

import numpy as np
import pytest

ROUGH = [0.15, 0.6]
SIZE = 16
GRID = 8


def _lobes(k: int, seed: int):
    rng = np.random.default_rng(seed)
    ax = rng.normal(size=(k, 3))
    ax[:, 2] = np.abs(ax[:, 2]) + 0.3
    ax /= np.linalg.norm(ax, axis=1, keepdims=True)
    return ax, rng.uniform(2.0, 60.0, k), rng.uniform(0.05, 0.5, (k, 3))


def _problem(seed: int = 0):
    from ebr_mitsuba.extract.forward import ExemplarGeometry
    from ebr_mitsuba.extract.optimize import Problem
    from ebr_mitsuba.geometry import near_shot

    rng = np.random.default_rng(seed)
    n = len(ROUGH)
    geom = ExemplarGeometry(np.array(ROUGH, np.float32), SIZE, SIZE, near_shot(False))
    targets = rng.uniform(0.05, 1.5, (n * SIZE * SIZE, 3)).astype(np.float32)
    saturated = rng.uniform(size=len(targets)) < 0.05
    per = targets.reshape(n, -1, 3)
    correction = rng.uniform(0.8, 1.2, targets.shape).astype(np.float32)
    return Problem(
        geom,
        targets,
        saturated,
        np.array([1.0, 0.7]),
        0.01 * per.mean(axis=(1, 2)),
        np.sqrt((per**2).sum(-1).mean(1)),
        correction,
    )


def _reference_adam(problem, lobes, iters, *, lr, lr_axis, log_weight, options, corrected, seed):
    """Plain (unfrozen, one lobe set, one reverse pass) Adam with the same loss, index draws and
    schedule as :func:`run_adam`; the update in numpy (float64)."""
    import drjit as dr
    import mitsuba as mi

    from ebr_mitsuba.extract.forward import stratified_indices
    from ebr_mitsuba.extract.optimize import (
        ADAM_EPS,
        BETA1,
        BETA2,
        LR_FLOOR,
        Pixels,
        initial_params,
        lobes_from_params,
        loss_terms,
        read_lobes,
    )
    from ebr_mitsuba.render.fast import environment

    geom = problem.geometry
    rng = np.random.default_rng(seed)
    per_image = min(GRID, geom.height) * min(GRID, geom.width)
    params = [np.asarray(p.numpy(), np.float64) for p in initial_params(*lobes)]
    m1 = [np.zeros_like(p) for p in params]
    m2 = [np.zeros_like(p) for p in params]
    kinds = (mi.Vector3f, mi.Float, mi.Color3f)
    for k in range(iters):
        index = mi.UInt32(stratified_indices(rng, geom.count, geom.height, geom.width, GRID))
        dp = [kind(p.astype(np.float32)) for kind, p in zip(kinds, params)]
        dr.enable_grad(dp)
        pixels = Pixels.gather(problem, index)
        yhat = environment(geom.points(index), lobes_from_params(*dp), options)
        if corrected == "ratio":
            yhat = yhat * pixels.correction
        dr.backward(loss_terms(problem, yhat, pixels, per_image, log_weight))
        decay = LR_FLOOR + (1.0 - LR_FLOOR) * 0.5 * (1.0 + math.cos(math.pi * k / iters))
        for i, (p, rate) in enumerate(zip(dp, (lr_axis, lr, lr))):
            g = np.nan_to_num(np.asarray(dr.grad(p).numpy(), np.float64), nan=0.0, posinf=0.0, neginf=0.0)
            m1[i] = BETA1 * m1[i] + (1 - BETA1) * g
            m2[i] = BETA2 * m2[i] + (1 - BETA2) * g * g
            c1, c2 = 1 - BETA1 ** (k + 1), 1 - BETA2 ** (k + 1)
            params[i] = params[i] - rate * decay * (m1[i] / c1) / (np.sqrt(m2[i] / c2) + ADAM_EPS)
    return read_lobes([kind(p.astype(np.float32)) for kind, p in zip(kinds, params)])


@pytest.mark.parametrize("corrected", [None, "ratio"])
def test_frozen_adam_matches_plain_reverse_mode(variant, monkeypatch, corrected):
    """run_adam (frozen step, two-stage reverse pass, per-pixel rows, pixel indices uploaded in
    blocks of INDEX_BLOCK iterations, here 3 so that 7 iterations cross two block boundaries and
    end on a short block) follows the plain formulation (rtol 2e-4 after 7 steps) and leaves the
    random generator in the same state."""
    from ebr_mitsuba.extract import optimize
    from ebr_mitsuba.render import RenderOptions

    monkeypatch.setattr(optimize, "INDEX_BLOCK", 3)
    problem = _problem()
    lobes = _lobes(5, 3)
    kw = dict(lr=0.05, lr_axis=0.02, log_weight=0.5, options=RenderOptions(mode="sg"), corrected=corrected)
    rng = np.random.default_rng(7)
    got = optimize.run_adam(problem, lobes, 7, 0, grid=GRID, rng=rng, history=[], **kw)
    ref = _reference_adam(problem, lobes, 7, seed=7, **kw)
    for a, b in zip(got, ref):
        np.testing.assert_allclose(a, b, rtol=2e-4, atol=1e-6)
    # the lobes moved (the comparison is not between two copies of the start)
    assert np.abs(got[2] - lobes[2]).max() > 1e-3
    expected = np.random.default_rng(7)
    for _ in range(7):
        expected.random(2 * len(ROUGH) * GRID * GRID)
    assert rng.random() == expected.random()


def test_adam_step_kernel_structure(variant):
    """Per iteration: exactly two JIT kernels over the (pixel, lobe) pairs (forward and reverse),
    at most 14 JIT kernels in all; a later call with fresh numpy inputs compiles nothing and no
    kernel reads unaligned memory."""
    import drjit as dr

    from ebr_mitsuba.extract.optimize import run_adam
    from ebr_mitsuba.render import RenderOptions

    problem = _problem()
    k_lobes, iters = 7, 6
    kw = dict(
        lr=0.05, lr_axis=0.02, log_weight=0.5, grid=GRID, options=RenderOptions(mode="sg"), corrected="ratio"
    )
    # trace and compile
    run_adam(problem, _lobes(k_lobes, 4), 3, 0, rng=np.random.default_rng(0), history=[], **kw)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        run_adam(problem, _lobes(k_lobes, 5), iters, 0, rng=np.random.default_rng(1), history=[], **kw)
        hist = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    jit = [h for h in hist if h["type"] == dr.KernelType.JIT]
    pairs = k_lobes * len(ROUGH) * GRID * GRID
    assert sum(1 for h in jit if h["size"] == pairs) == 2 * iters
    assert len(jit) <= 14 * iters
    assert [h for h in jit if not h.get("cache_hit", True)] == []
    # no kernel was compiled for unaligned input memory (which made the kernels of a call depend
    # on where numpy happened to allocate its inputs, and miss the cache)
    irs = [str(h["ir"].read() if hasattr(h["ir"], "read") else h["ir"]) for h in jit if h.get("ir")]
    assert irs and not any("align 1," in ir for ir in irs)
