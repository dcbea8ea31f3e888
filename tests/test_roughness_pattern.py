"""The roughness pattern (ebr_mitsuba.estimate.roughness_pattern) on synthetic captures with known
answers: flat samples whose roughness follows their log-albedo by a known slope, rendered by the
torch mirror of the BRDF (near flash); fixed seeds, 128²."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ebr_mitsuba.errors import InputError
from ebr_mitsuba.estimate import roughness_pattern as rp
from ebr_mitsuba.estimate.flashfit import fit_flash
from ebr_mitsuba.floors import ROUGHNESS_MIN
from ebr_mitsuba.imageio import box_mean
from ebr_mitsuba.nets import torch_brdf as tb
from ebr_mitsuba.nets.maps import Maps

RES = 128


def _albedo(seed: int = 0) -> np.ndarray:
    """(RES, RES, 3) a blotchy grey albedo texture in about [0.1, 0.6] (smoothed noise)."""
    rng = np.random.default_rng(seed)
    field = box_mean(rng.normal(size=(RES, RES)), 3)
    field = (field - field.mean()) / field.std()
    grey = np.exp(np.log(0.25) + 0.45 * field)
    return np.repeat(np.clip(grey, 0.05, 0.9)[..., None], 3, -1).astype(np.float32)


def _roughness(albedo: np.ndarray, r0: float, k: float) -> np.ndarray:
    u = np.log(albedo.mean(-1))
    return np.clip(r0 + k * (u - u.mean()), ROUGHNESS_MIN, 1.0).astype(np.float32)


def _capture(albedo, roughness, ambient=0.3, meter=0.9, noise=0.002, seed=0):
    """(flash, noflash, exposure): the flash-only render plus an ambient term proportional to the
    albedo, exposed so that the 99th percentile of the flash photo sits at ``meter``."""
    normal = torch.zeros(1, 3, RES, RES)
    normal[:, 2] = 1
    d = torch.from_numpy(albedo).permute(2, 0, 1)[None]
    s = torch.full((1, 3, RES, RES), 0.04)
    r = torch.from_numpy(np.asarray(roughness, np.float32))[None, None]
    flash_only = tb.render_point_light(Maps(normal, d, s, r), tb.NEAR_CAMERA)[0].permute(1, 2, 0).numpy()
    env = ambient * albedo
    exposure = meter / float(np.quantile((flash_only + env).max(-1), 0.99))
    rng = np.random.default_rng(seed)

    def photo(x):
        return np.clip(x * exposure + rng.normal(0.0, noise, x.shape), 0.0, 1.0).astype(np.float32)

    return photo(flash_only + env), photo(env), exposure


def _read(albedo, roughness):
    flash, noflash, exposure = _capture(albedo, roughness)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    return fit, rp.read_roughness_pattern(fit, flash, noflash, to_radiance=1 / exposure)


@pytest.mark.parametrize("r0", [0.3, 0.5])
@pytest.mark.parametrize("k", [-0.1, 0.1])
def test_slope_sign_and_size_recovered(r0, k):
    """The slope read has the truth's sign and its size within a factor of 2.5 (the reading is
    diluted by the no-flash shot's noise; the map takes GAIN times it)."""
    albedo = _albedo()
    fit, pattern = _read(albedo, _roughness(albedo, r0, k))
    assert pattern.applied, pattern
    assert np.sign(pattern.read) == np.sign(k), pattern
    assert abs(k) / 2.5 <= abs(pattern.read) <= 2.5 * abs(k), pattern


def test_uniform_roughness_reads_a_slope_near_zero():
    albedo = _albedo(seed=1)
    fit, pattern = _read(albedo, np.full((RES, RES), 0.4, np.float32))
    assert pattern.applied
    assert abs(pattern.read) < 0.02, pattern


def test_the_map_beats_the_constant_on_a_patterned_sample():
    albedo = _albedo(seed=2)
    truth = _roughness(albedo, 0.4, -0.08)
    fit, pattern = _read(albedo, truth)
    mapped = fit.with_roughness_pattern(pattern)
    assert mapped.roughness_pattern["applied"]
    est = mapped.maps(np.dstack([np.zeros((RES, RES, 2)), np.ones((RES, RES))])).roughness
    err = float(np.sqrt(np.mean((est - truth) ** 2)))
    const = float(np.sqrt(np.mean((fit.roughness - truth) ** 2)))
    assert err < 0.6 * const, (err, const)
    assert mapped.to_json()["roughness_from"] == "fit"


def test_too_rough_a_fit_is_not_read():
    albedo = _albedo(seed=3)
    fit, pattern = _read(albedo, np.full((RES, RES), 0.9, np.float32))
    assert fit.roughness > rp.MAX_ROUGHNESS
    assert not pattern.applied and "roughness" in pattern.reason
    kept = fit.with_roughness_pattern(pattern)
    assert kept.roughness_map is None and kept.roughness_pattern == pattern.to_json()


def test_a_metal_and_the_network_fallback_keep_their_maps():
    albedo = _albedo(seed=4)
    fit, _ = _read(albedo, _roughness(albedo, 0.4, 0.1))
    from dataclasses import replace

    metal = replace(fit, metal=True)
    flash, noflash, exposure = _capture(albedo, _roughness(albedo, 0.4, 0.1))
    assert not rp.read_roughness_pattern(metal, flash, noflash, to_radiance=1 / exposure).applied
    net = np.full((RES, RES), 0.6, np.float32)
    fallback = fit.with_network_roughness(net)
    pattern = rp.RoughnessPattern(0.1, 0.05, 0.01, 0.0, applied=True)
    assert fallback.with_roughness_pattern(pattern) is fallback
    assert fallback.to_json()["roughness_from"] == "network"


def test_roughness_map_is_centred_and_clipped():
    albedo = _albedo(seed=5)
    mild = rp.RoughnessPattern(0.05, applied=True).roughness_map(0.5, albedo)
    assert mild.shape == (RES, RES) and mild.dtype == np.float32
    assert abs(float(mild.mean()) - 0.5) < 1e-3
    steep = rp.RoughnessPattern(-2.0, applied=True).roughness_map(0.9, albedo)
    assert float(steep.min()) == pytest.approx(ROUGHNESS_MIN) and float(steep.max()) <= 1.0
    assert float(steep.max()) == pytest.approx(1.0)


def test_bad_shapes_are_one_line_errors():
    albedo = _albedo()
    fit, _ = _read(albedo, np.full((RES, RES), 0.4, np.float32))
    with pytest.raises(InputError, match="same"):
        rp.read_roughness_pattern(fit, albedo, albedo[:64])
    with pytest.raises(InputError, match="diffuse map"):
        rp.RoughnessPattern(0.1, applied=True).roughness_map(0.4, albedo[..., 0])
