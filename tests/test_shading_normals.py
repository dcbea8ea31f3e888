"""Normals from the flash / no-flash shading (ebr_mitsuba.estimate.shading_normals) on synthetic
captures whose relief follows the albedo with a known signed scale.

The flash-only shot is rendered by the torch mirror of the BRDF (near flash, the relief's normals,
a Lambertian sample: F0 = 0, the module's model); the no-flash shot is the same sample under a sky
of a constant plus a cosine lobe towards ``SUN`` (so that its shading depends on the normals too).
Fixed seeds, 128². Tilts of 0.06–0.23 rad rms (the real sets' range); the fit is first order in
the tilt, hence the 20 % tolerance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ebr_mitsuba.errors import InputError
from ebr_mitsuba.estimate.shading_normals import (
    ShadingNormalsConfig,
    _gradient,
    fit_shading_normals,
)
from ebr_mitsuba.geometry import NEAR_DISTANCE
from ebr_mitsuba.imageio import box_mean
from ebr_mitsuba.nets import torch_brdf as tb
from ebr_mitsuba.nets.maps import Maps

RES = 128
SUN = np.array([0.5, 0.3, 0.81]) / np.linalg.norm([0.5, 0.3, 0.81])


def _albedo(seed: int) -> np.ndarray:
    """A smooth random texture (H, W, 3) in about [0.1, 0.6], log-normal in luminance."""
    rng = np.random.default_rng(seed)
    g = box_mean(rng.normal(size=(RES, RES)), 3)
    g = (g - g.mean()) / g.std()
    tint = np.array([1.0, 0.85, 0.7])
    return np.clip((0.25 * np.exp(0.35 * g))[..., None] * tint, 0.02, 0.9)


def _relief(albedo: np.ndarray, c: float) -> np.ndarray:
    """Unit normals (H, W, 3) of the height field c · log(luminance of the albedo)."""
    h = c * np.log(albedo.mean(-1))
    gx, gy = _gradient(h)
    n = np.stack([-gx, -gy, np.ones_like(gx)], -1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _capture(albedo, normal, saturate_centre=False):
    """(flash, noflash, saturated): flash-only render + the no-flash sky shading, one exposure."""
    n = torch.from_numpy(normal.astype(np.float32)).permute(2, 0, 1)[None]
    d = torch.from_numpy(albedo.astype(np.float32)).permute(2, 0, 1)[None]
    s = torch.zeros(1, 3, RES, RES)
    r = torch.full((1, 1, RES, RES), 0.4)
    flash_only = tb.render_point_light(Maps(n, d, s, r), tb.NEAR_CAMERA)[0].permute(1, 2, 0).numpy()
    irradiance = 0.3 + 1.2 * np.clip(normal @ SUN, 0, None)
    noflash = albedo / math.pi * irradiance[..., None]
    flash = flash_only + noflash
    saturated = np.zeros((RES, RES), bool)
    if saturate_centre:
        saturated[RES // 2 - 8 : RES // 2 + 8, RES // 2 - 8 : RES // 2 + 8] = True
        flash = np.where(saturated[..., None], flash.max(), flash)
    return flash.astype(np.float32), noflash.astype(np.float32), saturated


def _slope_correlation(a, b):
    x, y = a[..., :2].ravel(), b[..., :2].ravel()
    return float(np.dot(x - x.mean(), y - y.mean()) / (np.std(x) * np.std(y) * x.size))


@pytest.mark.parametrize("c", [0.005, 0.02, -0.02])
def test_signed_scale_of_the_relief_recovered(c):
    """The relief's scale is read with its sign within 20 %, the normals follow the truth."""
    albedo = _albedo(0)
    truth = _relief(albedo, c)
    flash, noflash, _ = _capture(albedo, truth)
    fit = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE)
    assert fit.coefficient == pytest.approx(c, rel=0.2), fit.coefficient
    assert _slope_correlation(fit.normal, truth) > 0.8
    assert fit.explained > 0.8
    assert np.allclose(np.linalg.norm(fit.normal, axis=-1), 1.0, atol=1e-5)


def test_flat_sample_gives_flat_normals():
    """No relief: the fitted scale is near 0 and the normals within 1° of +z."""
    albedo = _albedo(1)
    flat = np.zeros((RES, RES, 3))
    flat[..., 2] = 1
    flash, noflash, _ = _capture(albedo, flat)
    fit = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE)
    assert abs(fit.coefficient) < 0.002, fit.coefficient
    assert float(fit.normal[..., 2].min()) > math.cos(math.radians(1.0))


def test_sky_gradient_recovered():
    """The no-flash sky's gradient over normals (β = −c · e) comes out as the sun's cosine lobe gives it."""
    albedo = _albedo(2)
    truth = _relief(albedo, 0.01)
    flash, noflash, _ = _capture(albedo, truth)
    fit = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE)
    # the sky's gradient over normals is what the sun's cosine lobe gives at +z
    sun_gradient = 1.2 * SUN[:2] / (0.3 + 1.2 * SUN[2])
    np.testing.assert_allclose(fit.sky_gradient, sun_gradient, atol=0.06)


def test_saturated_pixels_are_left_out():
    albedo = _albedo(3)
    truth = _relief(albedo, 0.01)
    flash, noflash, saturated = _capture(albedo, truth, saturate_centre=True)
    fit = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE, saturated=saturated)
    assert fit.coefficient == pytest.approx(0.01, rel=0.2)
    assert fit.pixels <= (RES - 4) ** 2 - 16 * 16


def test_gain_scales_the_slopes():
    albedo = _albedo(4)
    flash, noflash, _ = _capture(albedo, _relief(albedo, 0.01))
    one = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE)
    half = fit_shading_normals(
        flash, noflash, camera_height=NEAR_DISTANCE, options=ShadingNormalsConfig(gain=0.5)
    )
    slope = lambda n: n[..., :2] / n[..., 2:]  # noqa: E731
    np.testing.assert_allclose(slope(half.normal), 0.5 * slope(one.normal), atol=1e-5)


def test_shrunk_scales_the_map_slopes_only():
    """``shrunk(k)``: unit normals with k × the fitted slopes (1: the fit, 0: flat); the fit's own
    normals (the diffuse correction's) are left as fitted."""
    albedo = _albedo(4)
    flash, noflash, _ = _capture(albedo, _relief(albedo, 0.01))
    fit = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE)
    before = fit.normal.copy()
    slope = lambda n: n[..., :2] / n[..., 2:]  # noqa: E731
    np.testing.assert_allclose(slope(fit.shrunk(0.7)), 0.7 * slope(fit.normal), atol=1e-5)
    np.testing.assert_allclose(fit.shrunk(1.0), fit.normal, atol=1e-6)
    np.testing.assert_allclose(fit.shrunk(0.0)[..., 2], 1.0)
    assert np.allclose(np.linalg.norm(fit.shrunk(0.7), axis=-1), 1.0, atol=1e-5)
    np.testing.assert_array_equal(fit.normal, before)
    with pytest.raises(InputError, match="map_gain"):
        ShadingNormalsConfig(map_gain=1.5)


def test_bad_inputs():
    albedo = _albedo(5)
    flash, noflash, _ = _capture(albedo, _relief(albedo, 0.02))
    with pytest.raises(InputError, match="both must be"):
        fit_shading_normals(flash, noflash[:64], camera_height=NEAR_DISTANCE)
    with pytest.raises(InputError, match="--no-shading-normals"):
        fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE, saturated=np.ones((RES, RES), bool))
    with pytest.raises(InputError, match="gain"):
        ShadingNormalsConfig(gain=-1)


def test_large_photos_are_fitted_at_fit_size_and_upsampled():
    """Above ``fit_size`` the fit runs on the area-averaged photos (module docstring,
    "Resolution"): the same coefficient as fitting those by hand, normals at the photos' size,
    unit length and the truth's slopes."""
    from ebr_mitsuba.imageio import resize_area

    albedo = _albedo(5)
    truth = _relief(albedo, 0.01)
    flash, noflash, _ = _capture(albedo, truth)
    small = ShadingNormalsConfig(fit_size=64)
    fit = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE, options=small)
    by_hand = fit_shading_normals(
        resize_area(flash, (64, 64)), resize_area(noflash, (64, 64)), camera_height=NEAR_DISTANCE
    )
    assert fit.normal.shape == (RES, RES, 3)
    assert fit.coefficient == by_hand.coefficient and fit.pixels == by_hand.pixels
    assert np.allclose(np.linalg.norm(fit.normal, axis=-1), 1.0, atol=1e-5)
    assert _slope_correlation(fit.normal, truth) > 0.6
    full = fit_shading_normals(flash, noflash, camera_height=NEAR_DISTANCE)  # 128 ≤ 256: full size
    assert full.pixels > by_hand.pixels
