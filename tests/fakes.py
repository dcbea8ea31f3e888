"""Shared test doubles for ``ebr estimate``: a fake model and a small synthetic capture.

``FakePredictor(grid)`` is a :class:`ebr_mitsuba.model.predictor.Predictor` (uniform maps, one SG
lobe, no network); ``use_fake_model(monkeypatch, grid)`` makes ``ebr estimate`` load it;
``write_pair(folder, seed, lobes)`` renders a flash / no-flash pair of a random-diffuse plate with
the fast renderer (``flash.exr``, ``noflash.exr``) and returns the folder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

GRID = 32
SUN = ([0.3, 0.2, 0.93], 20.0, [4.0, 3.5, 3.0])
SKY = ([0.0, 0.0, 1.0], 1.0, [0.3, 0.3, 0.35])


class FakePredictor:
    """The :class:`ebr_mitsuba.model.predictor.Predictor` contract without a network (uniform maps,
    one SG lobe)."""

    takes_far = True

    def __init__(self, grid: int = GRID):
        self.grid = grid

    def predict(self, flash, noflash, far_flash=None, far_noflash=None):
        from ebr_mitsuba.model.predictor import Prediction
        from ebr_mitsuba.sgenv import SGEnvironment
        from ebr_mitsuba.svbrdf import SVBRDF

        n = flash.shape[0]
        maps = SVBRDF.uniform(n, n, 0.3, 0.04, 0.5)
        env = SGEnvironment(np.array([[0.0, 0.0, 1.0]]), np.array([2.0]), np.array([[0.5, 0.5, 0.5]]))
        return Prediction(maps, env, [flash * 0.1], np.maximum(flash - noflash, 0))


def use_fake_model(monkeypatch, grid: int = GRID) -> FakePredictor:
    """``ebr estimate`` (and ``demo``, ``gallery``) load a :class:`FakePredictor` instead of a
    model: it replaces :func:`ebr_mitsuba.estimate.pipeline.load_predictor`."""
    from ebr_mitsuba.estimate import pipeline

    fake = FakePredictor(grid)
    monkeypatch.setattr(pipeline, "load_predictor", lambda checkpoint: fake)
    return fake


def write_pair(folder: Path, seed: int, lobes=(SUN,), grid: int = GRID) -> Path:
    """``folder/flash.exr`` and ``folder/noflash.exr`` of a plate with random diffuse albedo."""
    from ebr_mitsuba.geometry import near_shot
    from ebr_mitsuba.imageio import write_exr
    from ebr_mitsuba.render import render_numpy
    from ebr_mitsuba.sgenv import SGEnvironment
    from ebr_mitsuba.svbrdf import SVBRDF

    env = SGEnvironment(
        np.array([l[0] for l in lobes]), np.array([l[1] for l in lobes]), np.array([l[2] for l in lobes])
    )
    rng = np.random.default_rng(seed)
    mat = SVBRDF(
        normal=np.broadcast_to(np.float32([0, 0, 1]), (grid, grid, 3)).copy(),
        diffuse=(0.2 + 0.5 * rng.random((grid, grid, 3))).astype(np.float32),
        specular=np.full((grid, grid, 3), 0.05, np.float32),
        roughness=np.full((grid, grid), 0.4, np.float32),
    )
    for shot in (near_shot(True), near_shot(False)):
        write_exr(Path(folder) / f"{shot.name}.exr", render_numpy(mat, env, shot))
    return Path(folder)
