"""Lighting accuracy of an extracted environment (the lighting error of ``docs/conventions.md``,
"Metrics"; :func:`ebr_mitsuba.metrics.lighting_error`).

Two numbers, both relative RMSE ``‖a − b‖ / ‖b‖`` over all pixels and channels:

* **exemplar error** — the exemplars re-rendered under the extracted lobes against the same
  exemplars under the true environment;
* **test-material error** — a fixed material that is not an exemplar (:data:`TEST_MATERIAL`:
  diffuse (0.5, 0.35, 0.2), specular 0.04, roughness 0.45, flat normal), near shot, flash off.

Renders for these comparisons use the fast renderer's quadrature averaged over ``seeds`` patterns
(:func:`quadrature_mean`): one 256-spp pattern alone carries 1.2–2 % noise at 128² (measured), as
large as the errors to resolve, and would flatter an estimate rendered with the same pattern.
Mitsuba renders of map-lit scenes (real environment maps) are made by the benchmark
(:mod:`ebr_mitsuba.bench.extract_sg`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry import Shot, near_shot
from ..metrics import lighting_error
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF

TEST_DIFFUSE = (0.5, 0.35, 0.2)
TEST_SPECULAR = 0.04
TEST_ROUGHNESS = 0.45


def heldout_material(size: int) -> SVBRDF:
    """The held-out test material at ``size``×``size``."""
    return SVBRDF.uniform(size, size, TEST_DIFFUSE, TEST_SPECULAR, TEST_ROUGHNESS)


TEST_MATERIAL = "uniform: diffuse (0.5, 0.35, 0.2), specular 0.04, roughness 0.45, flat normal"


def quadrature_mean(
    env: SGEnvironment,
    roughness: Sequence[float] | None,
    size: int,
    spp: int = 256,
    seeds: int = 8,
    shot: Shot | None = None,
    seed0: int = 1000,
) -> np.ndarray:
    """Low-noise fast renders: the exemplars (N, H, W, 3) for ``roughness``, or the test
    material (H, W, 3) when ``roughness`` is None; the mean of ``seeds`` quadrature patterns of
    ``spp`` directions (seeds ``seed0 …``)."""
    from ..exemplar.images import exemplar_images
    from ..render import RenderOptions, render_numpy

    shot = shot or near_shot(False)
    acc = None
    for s in range(seeds):
        if roughness is None:
            img = render_numpy(heldout_material(size), env, shot, mode="quadrature", spp=spp, seed=seed0 + s)
        else:
            opts = RenderOptions(mode="quadrature", spp=spp, seed=seed0 + s)
            img = np.stack(
                [
                    np.asarray(t.numpy(), np.float32)
                    for t in exemplar_images(env, list(roughness), size, size, shot=shot, options=opts)
                ]
            )
        acc = img.astype(np.float64) if acc is None else acc + img
    return (acc / seeds).astype(np.float32)


def lighting_errors(
    estimate: SGEnvironment,
    truth: SGEnvironment,
    roughness: Sequence[float],
    size: int,
    spp: int = 256,
    seeds: int = 8,
    reference: dict | None = None,
) -> dict:
    """``{"exemplars": rel RMSE, "test": rel RMSE}`` of ``estimate`` against ``truth``: the relative
    :func:`ebr_mitsuba.metrics.lighting_error` with ``judge=True`` (the benchmarks rank on it: a
    broken render is ``inf``); ``reference`` may hold precomputed truth renders under the same keys."""
    reference = reference or {}
    ref_ex = reference.get("exemplars")
    if ref_ex is None:
        ref_ex = quadrature_mean(truth, roughness, size, spp, seeds)
    ref_test = reference.get("test")
    if ref_test is None:
        ref_test = quadrature_mean(truth, None, size, spp, seeds)
    est_ex = quadrature_mean(estimate, roughness, size, spp, seeds, seed0=5000)
    est_test = quadrature_mean(estimate, None, size, spp, seeds, seed0=5000)
    return {
        "exemplars": lighting_error(est_ex, ref_ex, judge=True)["rel_rmse"],
        "test": lighting_error(est_test, ref_test, judge=True)["rel_rmse"],
    }
