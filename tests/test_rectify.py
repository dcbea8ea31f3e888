"""Rectification (``ebr_mitsuba.estimate.rectify``): camera images of the planar sample onto the
sample grid of docs/conventions.md.

A Lambertian texture lit by a distant environment alone has the same radiance from every view, so
each of the 9 Mitsuba renders of ``--setup multi-view`` (flash off), rectified, must show the
texture-space image of the near camera. Tolerance: 24², 64 spp; over the pixels of weight 1 (in
frame, and not interpolated from camera pixels that straddle the sample's edge), the mean relative
error to a 512-spp centre render is under 4 % (measured about 2 %; the 64-spp centre render
itself 2.9 %), and a mirrored camera frame fails it. Without the edge test the weights are
``nets.mair_views.in_frame_weights``, which the networks were trained with.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ebr_mitsuba.estimate.rectify import bilinear, project, rectify
from ebr_mitsuba.geometry import pixel_positions, setup_shots

N = 24
TOLERANCE = 0.04


@pytest.fixture(scope="module")
def renders():
    """The texture, the 9 shots (flash off) and their Mitsuba renders, and a clean centre render."""
    from ebr_mitsuba.capture import render_shot
    from ebr_mitsuba.sgenv import SGEnvironment
    from ebr_mitsuba.sources import EnvSource
    from ebr_mitsuba.svbrdf import SVBRDF

    p = pixel_positions(N, N)
    diffuse = np.stack(
        [
            0.2 + 0.3 * (p[..., 0] + 1),
            0.2 + 0.3 * (p[..., 1] + 1),
            0.5 + 0.3 * np.sin(3 * p[..., 0]) * np.cos(2 * p[..., 1]),
        ],
        axis=-1,
    ).astype(np.float32)
    flat = np.tile(np.float32([0, 0, 1]), (N, N, 1))
    maps = SVBRDF(flat, diffuse, np.zeros_like(diffuse), np.full((N, N), 0.5, np.float32))
    env = SGEnvironment(np.array([[0.0, 0.0, 1.0]]), np.array([0.5]), np.array([[1.0, 1.0, 1.0]]))
    emitter = EnvSource("<memory>", "sg", sg=env).emitter_dict(1.0)
    shots = [dataclasses.replace(s, flash=None) for s in setup_shots("multi-view")]
    images = [render_shot(maps, emitter, s, 64, k) for k, s in enumerate(shots)]
    clean = render_shot(maps, emitter, shots[4], 512, 99)
    return shots, images, clean


def _error(rect, weight, clean):
    keep = weight > 0
    return float(np.abs(rect - clean)[keep].mean() / clean.mean())


def test_rectified_views_show_the_texture(renders):
    from ebr_mitsuba.nets.mair_views import in_frame_weights

    shots, images, clean = renders
    expected_weights = in_frame_weights(N, N, shots)[:, 0].numpy()
    for k, (s, image) in enumerate(zip(shots, images)):
        rect, weight = rectify(image, s.camera, s.target, s.up, s.fov, N)
        assert rect.shape == (N, N, 3) and weight.shape == (N, N)
        # in frame and interpolated from camera pixels that saw the sample alone: the frame test of
        # the networks' weights, less (oblique views) a ring along the sample's edges (two pixels
        # wide on the far side, where the camera's pixels are larger than the grid's)
        assert np.all(weight <= expected_weights[k]), s.name
        inner = (slice(2, -2), slice(2, -2))
        assert np.array_equal(weight[inner], expected_weights[k][inner]), s.name
        assert 0.8 < weight.mean() <= 1.0, (s.name, weight.mean())
        _, frame_only = rectify(image, s.camera, s.target, s.up, s.fov, N, sample_only=False)
        assert np.array_equal(frame_only, expected_weights[k]), s.name
        assert _error(rect, weight, clean) < TOLERANCE, (s.name, _error(rect, weight, clean))
        # the camera frame mirrored (up flipped): the rectification no longer matches
        if s.camera[:2] != (0.0, 0.0):
            wrong, w2 = rectify(image, s.camera, s.target, (0.0, -1.0, 0.0), s.fov, N)
            assert _error(wrong, w2, clean) > 2 * TOLERANCE, s.name


def test_the_near_camera_at_the_grid_size_is_the_identity():
    rng = np.random.default_rng(0)
    image = rng.random((N, N, 3)).astype(np.float32)
    s = setup_shots("near")[0]
    rect, weight = rectify(image, s.camera, s.target, s.up, s.fov, N)
    assert np.allclose(rect, image, atol=1e-5) and np.all(weight == 1)
    # twice the grid: each output pixel is bilinear between the four nearest input pixel centres
    big, weight = rectify(image, s.camera, s.target, s.up, s.fov, 2 * N)
    assert big.shape == (2 * N, 2 * N, 3) and np.all(weight == 1)
    assert np.allclose(
        big[1:-1:2, 1:-1:2],
        0.75 * 0.75 * image[:-1, :-1]
        + 0.75 * 0.25 * (image[1:, :-1] + image[:-1, 1:])
        + 0.0625 * image[1:, 1:],
        atol=1e-5,
    )


def test_projection_and_sampling():
    # a point behind the camera or outside the frame is not in frame; bilinear at centres is exact
    s = setup_shots("near")[0]
    x, y, inside = project(
        np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 0.0, 9.0]]),
        s.camera,
        s.target,
        s.up,
        s.fov,
        (10, 10),
    )
    assert np.allclose([x[0], y[0]], [5.0, 5.0]) and inside.tolist() == [True, False, False]
    image = np.arange(12, dtype=np.float64).reshape(3, 4, 1)
    assert bilinear(image, np.array([0.5, 1.5, 2.0]), np.array([0.5, 2.5, 1.0]))[:, 0].tolist() == [
        0.0,
        9.0,
        3.5,
    ]
