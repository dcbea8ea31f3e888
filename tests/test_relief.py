"""The relief read off the flash / no-flash ratio's residual (ebr_mitsuba.estimate.relief): relief
that does not follow the albedo, a sky gradient the likelihood must find, the noise estimate and
the height solve on known inputs.

Captures as in ``test_shading_normals.py`` (torch mirror of the BRDF, Lambertian, near flash; a sky
of a constant plus a cosine lobe towards ``SUN``), but with a height field drawn independently of
the albedo, so that the albedo-following fit explains none of it. Fixed seeds, 128²."""

from __future__ import annotations

import numpy as np
import pytest
from test_shading_normals import RES, SUN, _albedo, _capture

from ebr_mitsuba.errors import InputError
from ebr_mitsuba.estimate import relief as R
from ebr_mitsuba.estimate.shading_normals import ShadingNormalsConfig, _gradient, fit_shading_normals
from ebr_mitsuba.geometry import NEAR_DISTANCE, pixel_positions
from ebr_mitsuba.imageio import box_mean

SUN_GRADIENT = 1.2 * SUN[:2] / (0.3 + 1.2 * SUN[2])  # ∇ log E at +z for the test sky


def _free_relief(seed: int, rms: float) -> np.ndarray:
    """Unit normals (H, W, 3) of a smooth random height field with slopes of ``rms`` per component,
    unrelated to any albedo."""
    rng = np.random.default_rng(seed)
    h = box_mean(rng.normal(size=(RES, RES)), 2)
    gx, gy = _gradient(h)
    k = rms / np.sqrt(0.5 * (gx.var() + gy.var()))
    n = np.stack([-k * gx, -k * gy, np.ones_like(gx)], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _noisy(image: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (image * (1 + sigma * rng.normal(size=image.shape))).astype(np.float32)


def _slope_correlation(a: np.ndarray, b: np.ndarray) -> float:
    x, y = a[..., :2].ravel(), b[..., :2].ravel()
    return float(np.corrcoef(x, y)[0, 1])


def test_relief_unrelated_to_the_albedo_is_read():
    """The albedo-following fit sees nothing; the residual's relief follows the truth (slopes
    correlated by over 0.6 at the map's gain of 1), with its sky gradient pointing at the sun."""
    albedo = _albedo(10)
    truth = _free_relief(11, 0.1)
    flash, noflash, _ = _capture(albedo, truth)
    flash, noflash = _noisy(flash, 0.01, 1), _noisy(noflash, 0.01, 2)
    fit = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE)
    assert fit.relief is not None
    assert fit.explained < 0.1  # nothing for the albedo-following basis
    normals = fit.shrunk(0.0, 1.0)
    assert _slope_correlation(normals, truth) > 0.6
    assert np.allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-5)
    e = fit.relief.sky_gradient
    cos = float(np.dot(e, SUN_GRADIENT) / (np.linalg.norm(e) * np.linalg.norm(SUN_GRADIENT)))
    assert cos > np.cos(np.radians(30)), (e, SUN_GRADIENT)
    assert fit.relief.to_json()["slope_rms"] > 0.02


def test_a_flat_sample_reads_almost_no_relief():
    """Flat normals and photo noise: the read slopes stay under a tenth of the relief test's."""
    albedo = _albedo(12)
    flat = np.zeros((RES, RES, 3))
    flat[..., 2] = 1
    flash, noflash, _ = _capture(albedo, flat)
    fit = fit_shading_normals(_noisy(flash, 0.01, 3), _noisy(noflash, 0.01, 4), camera_height=NEAR_DISTANCE)
    slopes = fit.relief.slopes
    assert float(np.sqrt((slopes**2).mean())) < 0.01


def test_relief_off_and_gain():
    """``relief=False`` reads none and the map is the albedo-following one; ``relief_gain`` bounds."""
    albedo = _albedo(13)
    flash, noflash, _ = _capture(albedo, _free_relief(14, 0.1))
    no_relief = ShadingNormalsConfig(relief=False)
    off = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE, options=no_relief)
    assert off.relief is None and off.to_json()["relief"] is None
    np.testing.assert_allclose(off.shrunk(0.6, 0.5), off.shrunk(0.6), atol=1e-6)
    on = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE)
    np.testing.assert_allclose(on.normal, off.normal, atol=1e-6)  # the diffuse correction's normals
    assert not np.allclose(on.shrunk(0.6, 0.5), on.shrunk(0.6), atol=1e-3)
    for bad in (-0.1, 2.5):
        with pytest.raises(InputError, match="relief_gain"):
            ShadingNormalsConfig(relief_gain=bad)
    with pytest.raises(InputError, match="relief_smooth"):
        ShadingNormalsConfig(relief_smooth=0)


def test_noise_variance_separates_white_noise_from_smooth_signal():
    rng = np.random.default_rng(5)
    valid = np.ones((RES, RES), bool)
    white = 0.05 * rng.normal(size=(RES, RES))
    smooth = box_mean(rng.normal(size=(RES, RES)), 8)
    assert R.noise_variance(white, valid) == pytest.approx(0.05**2, rel=0.1)
    assert R.noise_variance(smooth, valid) < 0.1 * float(smooth.var())
    assert R.noise_variance(smooth + white, valid) == pytest.approx(0.05**2, rel=0.25)


def test_sky_gradient_by_likelihood_on_a_known_variance_field():
    """Residuals drawn with the model's variance s²|v − e|² + σ² give back e (256², the
    likelihood reading every fourth pixel per axis; the grid steps by 0.125)."""
    rng = np.random.default_rng(6)
    p = pixel_positions(256, 256)
    vx, vy = -p[..., 0] / NEAR_DISTANCE, -p[..., 1] / NEAR_DISTANCE
    e = np.array([0.5, -0.75])
    var = 0.01 * ((vx - e[0]) ** 2 + (vy - e[1]) ** 2) + 1e-4
    r = np.sqrt(var) * rng.normal(size=var.shape)
    found = R.sky_gradient(r, np.ones_like(r, bool), vx, vy, 1e-4)
    np.testing.assert_allclose(found, e, atol=0.25)


def test_height_solve_recovers_the_seen_component():
    """Noise-free residual r = a · δ with a fixed a: the solve returns δ's component along a."""
    truth = _free_relief(15, 0.1)
    delta = truth[..., :2] / truth[..., 2:]
    p = pixel_positions(RES, RES)
    ax, ay = -p[..., 0] / NEAR_DISTANCE - 1.0, -p[..., 1] / NEAR_DISTANCE + 0.5
    r = ax * delta[..., 0] + ay * delta[..., 1]
    valid = np.ones_like(r, bool)
    slopes = R.solve_slopes(r, valid, ax, ay, 1e-4, float(delta.var()), 1.0, iterations=400)
    seen = ax * slopes[..., 0] + ay * slopes[..., 1]
    inner = (slice(4, -4), slice(4, -4))
    assert np.corrcoef(seen[inner].ravel(), r[inner].ravel())[0, 1] > 0.95
    assert _slope_correlation(slopes[inner], delta[inner]) > 0.7
