"""The flash-profile fit (ebr_mitsuba.estimate.flashfit) on synthetic captures with known answers.

Captures are rendered by the torch mirror of the BRDF (near flash, flat sample) so that the fit's
model is exact: the tolerances then bound the fit's own error (ring statistics, the roughness grid
step of 0.01, the saturated tip). Fixed seeds; 128² to keep the suite fast.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ebr_mitsuba.errors import InputError
from ebr_mitsuba.estimate.flashfit import FlashFitConfig, fit_flash
from ebr_mitsuba.nets import torch_brdf as tb
from ebr_mitsuba.nets.maps import Maps

RES = 128


def _capture(diffuse, specular, roughness, ambient=0.02, meter=0.9, seed=0, noise=0.0, normal=None):
    """(flash, noflash, exposure) photos of a sample, flat unless ``normal`` (H, W, 3) is given:
    flash-only render + a constant ambient term, exposed so that the 99th percentile of the flash
    photo sits at ``meter``, clipped at 1."""
    h = w = RES
    if normal is None:
        normal = torch.zeros(1, 3, h, w)
        normal[:, 2] = 1
    else:
        normal = torch.from_numpy(np.asarray(normal, np.float32)).permute(2, 0, 1)[None]
    d = torch.as_tensor(np.asarray(diffuse, np.float32)).permute(2, 0, 1)[None]
    s = torch.tensor(specular, dtype=torch.float32).view(1, 3, 1, 1).expand(1, 3, h, w)
    r = torch.full((1, 1, h, w), float(roughness))
    flash_only = tb.render_point_light(Maps(normal, d, s, r), tb.NEAR_CAMERA)[0].permute(1, 2, 0).numpy()
    env = ambient * np.asarray(diffuse, np.float32) + 1e-3
    flash = flash_only + env
    exposure = meter / float(np.quantile(flash.max(-1), 0.99))
    rng = np.random.default_rng(seed)

    def photo(x):
        x = x * exposure
        if noise:
            x = x + rng.normal(0.0, noise, x.shape)
        return np.clip(x, 0.0, 1.0).astype(np.float32)

    return photo(flash), photo(env), exposure


def _uniform(rgb):
    return np.broadcast_to(np.asarray(rgb, np.float32), (RES, RES, 3)).copy()


@pytest.mark.parametrize("roughness", [0.15, 0.4, 0.7])
def test_dielectric_roughness_and_level_recovered(roughness):
    albedo = (0.35, 0.25, 0.15)
    flash, noflash, exposure = _capture(_uniform(albedo), (0.04,) * 3, roughness)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert not fit.metal
    assert abs(fit.roughness - roughness) <= 0.05, fit.roughness
    np.testing.assert_allclose(fit.level, albedo, rtol=0.03)
    np.testing.assert_allclose(
        fit.maps(np.dstack([np.zeros((RES, RES, 2)), np.ones((RES, RES))])).specular, 0.04
    )


def test_sharp_highlight_is_clipped_and_still_found():
    flash, noflash, exposure = _capture(_uniform((0.3, 0.3, 0.3)), (0.04,) * 3, 0.08)
    assert (flash >= 0.995).any(), "the test needs a clipped highlight tip"
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert abs(fit.roughness - 0.08) <= 0.04, fit.roughness


def test_metal_hypothesis():
    f0 = (0.9, 0.6, 0.3)
    flash, noflash, exposure = _capture(_uniform((0.0, 0.0, 0.0)), f0, 0.35, ambient=0.0)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert fit.metal
    assert abs(fit.roughness - 0.35) <= 0.05, fit.roughness
    np.testing.assert_allclose(fit.specular_rgb, f0, rtol=0.1)
    assert float(np.abs(fit.diffuse).max()) == 0.0


def test_a_diffuse_sample_whose_fall_off_the_model_misjudges_stays_a_dielectric():
    """A phone photo's fall-off rarely follows the model's (its field of view is a guess): a
    diffuse sample whose flash image falls off less steeply than modelled rises towards the edges
    in g, which only a flat metal lobe (roughness ≥ 0.9) can follow. No lobe that flat tells a metal
    from a diffuse surface, so the fit stays a dielectric and keeps the texture (module docstring,
    "Metal or dielectric"); before, it read a metal of roughness 1, F0 clipped at 1, no diffuse."""
    from ebr_mitsuba.estimate.flashfit import METAL_MARGIN, METAL_MAX_ROUGHNESS

    rng = np.random.default_rng(2)
    albedo = np.clip(0.15 + 0.05 * rng.standard_normal((RES, RES, 1)), 0, 1) * np.array([1.0, 0.8, 0.55])
    flash, noflash, exposure = _capture(albedo.astype(np.float32), (0.04,) * 3, 0.9, ambient=0.0, meter=0.5)
    yy, xx = np.mgrid[-1 : 1 : RES * 1j, -1 : 1 : RES * 1j]
    flash = np.clip(flash * (1 + 0.15 * (xx**2 + yy**2))[..., None], 0, 1).astype(np.float32)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert not fit.metal
    assert fit.decision["metal_ratio"] < METAL_MARGIN  # the metal fits better ...
    assert fit.decision["metal_roughness"] >= METAL_MAX_ROUGHNESS  # ... with a lobe too flat to tell
    level = float(albedo[..., 0].mean())  # the fit's level is the albedo's within the fall-off error
    assert 0.8 * level < float(fit.level[0]) < 1.3 * level
    # the texture is kept: the fitted red channel follows the albedo's
    assert np.corrcoef(fit.diffuse[..., 0].ravel(), albedo[..., 0].ravel())[0, 1] > 0.9


def test_a_polished_metal_in_the_dark_stays_a_metal():
    """Away from a sharp metal highlight the flash-only image is photo noise about zero; clamping
    each pixel of flash − no-flash at 0 lifted every ring to a false albedo level that only the
    dielectric hypothesis could explain (a polished copper under a dark map read as a dielectric
    with F0 0.04)."""
    f0 = (0.8, 0.45, 0.01)
    flash, noflash, exposure = _capture(_uniform((0.0, 0.0, 0.0)), f0, 0.07, ambient=0.0, noise=0.002)
    assert (flash >= 0.995).any(), "the test needs a clipped highlight tip"
    flash, noflash = (np.round(x * 255) / 255 for x in (flash, noflash))  # 8-bit, as a PNG photo
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert fit.metal  # with the clamp: a dielectric of roughness 0.13
    assert abs(fit.roughness - 0.07) <= 0.02, fit.roughness
    # F0 by least squares on the lobe: the median of the per-pixel ratios was 0 (most pixels hold
    # noise about zero) and F0 sat at its 0.001 floor
    rgb = fit.specular_rgb
    assert rgb[0] > rgb[1] > rgb[2] and rgb[1] > 0.2, rgb


def test_texture_pattern_beats_the_constant():
    """A checker albedo: the fitted diffuse map carries the texture (its RMSE well below that of
    the map's own mean) under photo noise."""
    yy, xx = np.mgrid[0:RES, 0:RES]
    checker = ((yy // 8 + xx // 8) % 2).astype(np.float32)
    albedo = np.stack([0.2 + 0.3 * checker] * 3, -1)
    flash, noflash, exposure = _capture(albedo, (0.04,) * 3, 0.5, noise=0.002)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    err = float(np.sqrt(np.mean((fit.diffuse - albedo) ** 2)))
    const = float(np.sqrt(np.mean((albedo.mean() - albedo) ** 2)))
    assert err < 0.3 * const, (err, const)


def test_low_frequencies_of_the_albedo_are_kept():
    """Two planks, albedo 0.2 and 0.45 side by side (larger than the pattern's box), with a fine
    checker on both: over its local mean the photo loses the planks (both come out at the
    level); with ``pattern_lows`` the flash-only ratio puts them back, per channel."""
    yy, xx = np.mgrid[0:RES, 0:RES]
    planks = np.where(xx < RES // 2, 0.2, 0.45).astype(np.float32)
    checker = 1.0 + 0.2 * (((yy // 4 + xx // 4) % 2) - 0.5)
    albedo = np.stack([planks * checker, 0.8 * planks * checker, 0.6 * planks * checker], -1)
    flash, noflash, exposure = _capture(albedo, (0.04,) * 3, 0.5, noise=0.002)
    err = {}
    for lows in (True, False):
        fit = fit_flash(flash, noflash, to_radiance=1 / exposure, options=FlashFitConfig(pattern_lows=lows))
        err[lows] = float(np.sqrt(np.mean((fit.diffuse - albedo) ** 2)))
        left, right = (
            fit.diffuse[:, 8 : RES // 2 - 24].mean((0, 1)),
            fit.diffuse[:, RES // 2 + 24 : -8].mean((0, 1)),
        )
        if lows:  # each plank's colour, within 10 %
            np.testing.assert_allclose(left, albedo[:, 8 : RES // 2 - 24].mean((0, 1)), rtol=0.1)
            np.testing.assert_allclose(right, albedo[:, RES // 2 + 24 : -8].mean((0, 1)), rtol=0.1)
        else:  # the planks averaged away
            assert np.all(right < 1.3 * left), (left, right)
    assert err[True] < 0.5 * err[False], err


def test_level_of_a_skewed_texture():
    """Bricks with bright mortar in a tenth of the pixels: the clean level is the albedo's mean per
    channel, the trimmed mean (which cuts the mortar as the top decile) falls short of it."""
    yy, xx = np.mgrid[0:RES, 0:RES]
    mortar = ((yy % 10) == 0).astype(np.float32)[..., None]
    albedo = (1 - mortar) * np.float32([0.35, 0.12, 0.08]) + mortar * np.float32([0.7, 0.7, 0.7])
    flash, noflash, exposure = _capture(albedo, (0.04,) * 3, 0.5)
    clean = fit_flash(flash, noflash, to_radiance=1 / exposure)
    trimmed = fit_flash(
        flash, noflash, to_radiance=1 / exposure, options=FlashFitConfig(level_statistic="trimmed")
    )
    mean = albedo.reshape(-1, 3).mean(0)
    np.testing.assert_allclose(clean.level, mean, rtol=0.03)
    assert (trimmed.level < 0.9 * mean).any(), (trimmed.level, mean)


def test_explicit_mask_and_no_clip_level():
    flash, noflash, exposure = _capture(_uniform((0.3, 0.3, 0.3)), (0.04,) * 3, 0.5)
    a = fit_flash(flash, noflash, to_radiance=1 / exposure)
    b = fit_flash(flash, noflash, to_radiance=1 / exposure, saturated=(flash >= 0.995).any(-1))
    assert a.roughness == b.roughness
    c = fit_flash(flash, noflash, to_radiance=1 / exposure, clip_level=float("inf"))
    assert abs(c.roughness - 0.5) <= 0.05


def test_bad_inputs_are_one_line_errors():
    flash, noflash, exposure = _capture(_uniform((0.3, 0.3, 0.3)), (0.04,) * 3, 0.5)
    with pytest.raises(InputError, match="same"):
        fit_flash(flash, noflash[:-1])
    with pytest.raises(InputError, match="unsaturated"):
        fit_flash(np.ones_like(flash), noflash)
    with pytest.raises(InputError, match="saturation mask"):
        fit_flash(flash, noflash, saturated=np.zeros((4, 4), bool))
    with pytest.raises(InputError, match="roughness_min"):
        FlashFitConfig(roughness_min=0.9, roughness_max=0.5)
    with pytest.raises(InputError):
        FlashFitConfig(f0=1.5)


@pytest.mark.parametrize("statistic", ["trimmed", "mean"])
def test_a_lobe_cannot_hide_inside_the_central_ring(statistic):
    """procedural:tiles:2 (dark grout, roughness 0.58–0.88) rendered with its own maps, unclipped
    (as an EXR capture): the model's ring value averages the lobe over the ring's own pixels, so a
    roughness far sharper than the truth cannot hide in the central ring. (Ring medians, the
    former statistic, picked 0.08 here.)"""
    from ebr_mitsuba.procedural.materials import make_material

    m = make_material("tiles", 2, RES)

    def t(a):
        return torch.as_tensor(np.asarray(a, np.float32)).reshape(RES, RES, -1).permute(2, 0, 1)[None]

    maps = Maps(t(m.normal), t(m.diffuse), t(m.specular), t(m.roughness))
    flash_only = tb.render_point_light(maps, tb.NEAR_CAMERA)[0].permute(1, 2, 0).numpy()
    env = 0.02 * np.asarray(m.diffuse) + 1e-3
    exposure = 0.5 / float(np.quantile((flash_only + env).max(-1), 0.99))
    rng = np.random.default_rng(0)
    flash = (flash_only + env) * exposure + rng.normal(0, 0.002, env.shape)
    noflash = env * exposure + rng.normal(0, 0.002, env.shape)
    opts = FlashFitConfig(ring_statistic=statistic)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure, clip_level=float("inf"), options=opts)
    assert not fit.metal
    assert abs(fit.roughness - float(np.mean(m.roughness))) <= 0.1, fit.roughness


def test_network_diffuse_is_scaled_to_the_level_and_blended():
    """The network's map enters at the fitted level (a network map off by a factor of 3 is
    rescaled), weighted by ``weight``; a metal keeps no diffuse; a wrong size is refused."""
    yy, xx = np.mgrid[0:RES, 0:RES]
    checker = ((yy // 8 + xx // 8) % 2).astype(np.float32)
    albedo = np.stack([0.2 + 0.3 * checker] * 3, -1)
    flash, noflash, exposure = _capture(albedo, (0.04,) * 3, 0.5, noise=0.002)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    network = 3.0 * albedo
    only_net = fit.with_network_diffuse(network, 1.0).diffuse
    np.testing.assert_allclose(only_net.reshape(-1, 3).mean(0), fit.level, rtol=1e-3)
    np.testing.assert_array_equal(fit.with_network_diffuse(network, 0.0).diffuse, fit.diffuse)
    half = fit.with_network_diffuse(network, 0.5).diffuse
    np.testing.assert_allclose(half, 0.5 * fit.diffuse + 0.5 * only_net, atol=1e-6)
    err = lambda d: float(np.sqrt(np.mean((d - albedo) ** 2)))  # noqa: E731
    assert err(half) < err(fit.diffuse)  # the clean network texture lowers the photo's noise
    with pytest.raises(InputError, match="network's diffuse map"):
        fit.with_network_diffuse(network[:-1], 0.5)
    f0 = (0.9, 0.6, 0.3)
    flash, noflash, exposure = _capture(_uniform((0.0, 0.0, 0.0)), f0, 0.35, ambient=0.0)
    metal = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert metal.metal and float(np.abs(metal.with_network_diffuse(network, 0.5).diffuse).max()) == 0.0


def test_large_photos_are_fitted_on_an_area_averaged_copy():
    """fit_size below the photo: the profile runs on a 2× area-averaged copy and finds the same
    roughness; the maps keep the photo's size."""
    flash, noflash, exposure = _capture(_uniform((0.3, 0.25, 0.2)), (0.04,) * 3, 0.4)
    full = fit_flash(flash, noflash, to_radiance=1 / exposure)
    half = fit_flash(flash, noflash, to_radiance=1 / exposure, options=FlashFitConfig(fit_size=64))
    assert abs(half.roughness - full.roughness) <= 0.02
    assert half.diffuse.shape == full.diffuse.shape == (RES, RES, 3)
    np.testing.assert_allclose(half.level, full.level, rtol=0.02)


def test_network_weight_grows_above_the_size_threshold():
    from ebr_mitsuba.estimate.flashfit import NETWORK_WEIGHT_SIZE as N

    opts = FlashFitConfig(network_weight=0.5, pattern_detail=False)
    assert opts.weight_for(N // 2) == opts.weight_for(N) == 0.5
    assert opts.weight_for(2 * N) == pytest.approx(0.75)
    assert opts.weight_for(4 * N) == pytest.approx(0.875)
    assert FlashFitConfig(network_weight=1.0).weight_for(8 * N) == 1.0
    # with the pattern's detail shrunk the photo's share falls as 1 / √size
    shrunk = FlashFitConfig(network_weight=0.5)
    assert shrunk.weight_for(N) == 0.5
    assert shrunk.weight_for(4 * N) == pytest.approx(0.75)
    assert shrunk.weight_for(2 * N) == pytest.approx(1 - 0.5 / 2**0.5)


def test_pattern_detail_is_shrunk_by_its_signal_share():
    """The detail above NETWORK_WEIGHT_SIZE² of a pattern whose detail is signal s plus noise n,
    the other pattern the same s plus independent noise: the gain is var(s) / (var(s) + var(n))
    within 5 %, the shrunk pattern is nearer the truth than the raw one, the low frequencies are
    kept, and two noise-free copies keep their detail whole."""
    from ebr_mitsuba.estimate.flashfit import NETWORK_WEIGHT_SIZE as N
    from ebr_mitsuba.estimate.flashfit import _detail_shrunk
    from ebr_mitsuba.imageio import resize_area

    rng = np.random.default_rng(0)
    size = 4 * N
    x = np.mgrid[0:size, 0:size][1] / size
    low = (1.0 + 0.2 * np.sin(2 * np.pi * x)).astype(np.float32)
    signal = rng.normal(0, 0.1, (size, size)).astype(np.float32)  # white: almost all above N²
    truth = low + signal
    flash = truth + rng.normal(0, 0.1, (size, size)).astype(np.float32)
    noflash = truth + rng.normal(0, 0.1, (size, size)).astype(np.float32)
    ok = np.ones((size, size), bool)
    out = _detail_shrunk(flash, noflash, ok)
    gain = np.std(out - resize_area(resize_area(out, (N, N)), (size, size))) / np.std(
        flash - resize_area(resize_area(flash, (N, N)), (size, size))
    )
    assert gain == pytest.approx(0.5, rel=0.05)  # var(s) / (var(s) + var(n)) = 1/2
    assert np.sqrt(np.mean((out - truth) ** 2)) < 0.8 * np.sqrt(np.mean((flash - truth) ** 2))
    coarse = (N // 8, N // 8)  # the low frequencies kept (up to the bilinear upsampling's blur)
    np.testing.assert_allclose(resize_area(out, coarse), resize_area(flash, coarse), atol=5e-3)
    np.testing.assert_allclose(_detail_shrunk(truth, truth, ok), truth, atol=1e-5)


def _near_far_capture(diffuse, specular, roughness, ambient=0.02, meter=0.9):
    """(flash, noflash, far flash, far noflash, exposure): a flat sample under the near flash and
    under the far flash of ``ebr capture --setup near-far`` (camera and flash at FAR_DISTANCE, the
    intensity × (far / near distance)²: the same irradiance), one exposure for the four shots."""
    from ebr_mitsuba.geometry import DEFAULT_FLASH_INTENSITY, FAR_DISTANCE, NEAR_DISTANCE

    h = w = RES
    normal = torch.zeros(1, 3, h, w)
    normal[:, 2] = 1
    d = torch.as_tensor(np.asarray(diffuse, np.float32)).permute(2, 0, 1)[None]
    s = torch.tensor(specular, dtype=torch.float32).view(1, 3, 1, 1).expand(1, 3, h, w)
    maps = Maps(normal, d, s, torch.full((1, 1, h, w), float(roughness)))
    far_cam = (0.0, 0.0, FAR_DISTANCE)
    far_intensity = DEFAULT_FLASH_INTENSITY * (FAR_DISTANCE / NEAR_DISTANCE) ** 2
    near_only = tb.render_point_light(maps, tb.NEAR_CAMERA)[0].permute(1, 2, 0).numpy()
    far_only = tb.render_point_light(maps, far_cam, far_intensity, far_cam)[0].permute(1, 2, 0).numpy()
    env = ambient * np.asarray(diffuse, np.float32) + 1e-3
    exposure = meter / float(np.quantile((near_only + env).max(-1), 0.99))
    photo = lambda x: np.clip(x * exposure, 0.0, 1.0).astype(np.float32)  # noqa: E731
    return photo(near_only + env), photo(env), photo(far_only + env), photo(env), exposure


def _radial_albedo(amplitude):
    """An albedo brighter towards the frame's centre, where the near flash's highlight sits: from
    the near shot alone it reads partly as a sharper lobe."""
    c = (np.arange(RES) + 0.5) / RES * 2 - 1
    bump = np.exp(-(c[None, :] ** 2 + c[:, None] ** 2) / 0.3)
    return ((0.3 + amplitude * bump)[..., None] * np.array([1.0, 0.9, 0.8])).astype(np.float32)


@pytest.mark.parametrize("roughness", [0.6, 0.8])
def test_far_pair_separates_albedo_from_the_lobe(roughness):
    """Near − far per ring cancels the albedo: with the far pair the roughness of a sample whose
    albedo falls off like a lobe is recovered (within the grid step and the rings' error, 0.03);
    from the near shots alone it is read too low (the albedo taken for the lobe)."""
    from ebr_mitsuba.estimate.flashfit import FarPair

    flash, noflash, far_flash, far_noflash, exposure = _near_far_capture(
        _radial_albedo(0.2), (0.04,) * 3, roughness
    )
    rings_only = FlashFitConfig(noflash_albedo=False)
    near = fit_flash(flash, noflash, to_radiance=1 / exposure, options=rings_only)
    both = fit_flash(
        flash, noflash, to_radiance=1 / exposure, far=FarPair(far_flash, far_noflash), options=rings_only
    )
    assert not both.metal and both.far_pair and not near.far_pair
    assert both.to_json()["far_pair"] is True
    assert both.pixel_median is None  # the far pair reads the roughness: no pixel-median reading
    assert abs(both.roughness - roughness) <= 0.03, both.roughness
    assert abs(near.roughness - roughness) > 0.1, near.roughness  # what the far pair fixes
    np.testing.assert_allclose(both.level, near.level, rtol=0.25)  # the level is the near rings'


@pytest.mark.parametrize("roughness", [0.6, 0.8])
def test_noflash_rings_separate_albedo_from_the_lobe(roughness):
    """The near shots alone: the no-flash shot's rings give each ring's albedo share, so the
    albedo that falls off like a lobe no longer reads as one (within 0.03, as with the far pair);
    without them it is read too low (> 0.1 off). The no-flash shot is the albedo's alone (the
    helper's constant 1e-3 taken out: a term without the albedo dilutes the shares, 0.8 then
    reads 0.65). The no-flash shot too dark to read leaves the rings at 1."""
    flash, noflash, *_, exposure = _near_far_capture(_radial_albedo(0.2), (0.04,) * 3, roughness)
    noflash = noflash - np.float32(1e-3 * exposure)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    plain = fit_flash(flash, noflash, to_radiance=1 / exposure, options=FlashFitConfig(noflash_albedo=False))
    assert not fit.metal and not fit.far_pair
    assert abs(fit.roughness - roughness) <= 0.03, fit.roughness
    assert abs(plain.roughness - roughness) > 0.1, plain.roughness
    dark = fit_flash(flash, noflash * 1e-3, to_radiance=1 / exposure)
    assert dark.roughness == pytest.approx(
        fit_flash(
            flash, noflash * 1e-3, to_radiance=1 / exposure, options=FlashFitConfig(noflash_albedo=False)
        ).roughness
    )


def test_far_pair_keeps_a_metal_and_a_uniform_dielectric():
    from ebr_mitsuba.estimate.flashfit import FarPair

    flash, noflash, far_flash, far_noflash, exposure = _near_far_capture(
        _uniform((0.3, 0.25, 0.2)), (0.04,) * 3, 0.4
    )
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure, far=FarPair(far_flash, far_noflash))
    assert not fit.metal and abs(fit.roughness - 0.4) <= 0.03
    f0 = (0.9, 0.6, 0.3)
    flash, noflash, far_flash, far_noflash, exposure = _near_far_capture(
        _uniform((0.0, 0.0, 0.0)), f0, 0.35, ambient=0.0
    )
    metal = fit_flash(flash, noflash, to_radiance=1 / exposure, far=FarPair(far_flash, far_noflash))
    assert metal.metal and abs(metal.roughness - 0.35) <= 0.05, metal.roughness


def test_far_pair_of_another_size_is_refused():
    from ebr_mitsuba.estimate.flashfit import FarPair

    flash, noflash, far_flash, far_noflash, exposure = _near_far_capture(
        _uniform((0.3, 0.25, 0.2)), (0.04,) * 3, 0.4
    )
    with pytest.raises(InputError, match="far shots"):
        fit_flash(flash, noflash, far=FarPair(far_flash[:-1], far_noflash[:-1]))
    with pytest.raises(InputError, match="far saturation mask"):
        fit_flash(flash, noflash, far=FarPair(far_flash, far_noflash, saturated=np.zeros((3, 3), bool)))


def _patchy_relief(share: float, spread: float, seed: int = 0):
    """(H, W, 3) unit normals: flat, except a random ``share`` of the pixels tilted by a normal
    slope of ``spread`` per axis (the bevels and pits of a glazed tile, seen as a distribution)."""
    rng = np.random.default_rng(seed)
    tilted = rng.random((RES, RES)) < share
    slopes = rng.normal(0.0, spread, (RES, RES, 2)) * tilted[..., None]
    n = np.dstack([slopes, np.ones((RES, RES))])
    return (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)


def _relief_capture(normal, roughness, albedo=0.3):
    """:func:`_capture` of a grey dielectric with a normal map, under photo noise."""
    return _capture(_uniform((albedo,) * 3), (0.04,) * 3, roughness, noise=0.002, normal=normal)


@pytest.mark.parametrize("spread", [0.2, 0.4])
def test_relief_reads_the_sharp_lobe(spread):
    """Roughness 0.3 with half the pixels tilted: one lobe reads the tilted pixels' glints as a
    rougher material; the two-lobe profile keeps the flat faces' roughness."""
    flash, noflash, exposure = _relief_capture(_patchy_relief(0.5, spread), 0.3)
    plain = fit_flash(flash, noflash, to_radiance=1 / exposure, options=FlashFitConfig(relief=False))
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert plain.roughness > 0.4, plain.roughness
    assert fit.relief is not None and fit.relief["broad"] > fit.relief["sharp"] == fit.roughness
    # the tilted pixels are not exactly a GGX lobe, so the sharp lobe is near, not at, the truth
    assert abs(fit.roughness - 0.3) <= 0.1, (fit.roughness, fit.relief)
    assert abs(fit.roughness - 0.3) < abs(plain.roughness - 0.3) - 0.05, (fit.roughness, plain.roughness)
    assert fit.to_json()["relief"] == fit.relief
    assert fit.pixel_median is None  # the relief reading took the tilted pixels apart already


def test_pixel_median_reading_resists_a_minority_of_glints():
    """Roughness 0.5 with 40 % of the pixels tilted (slopes 0.3, too few and too broad for the
    two-lobe relief reading): their glints lift the trimmed ring means (0.54), while each ring's
    median of the per-pixel residual follows the flat majority (within 0.02); the estimate is the
    mean of the two readings, recorded in estimate.json's flash_fit."""
    flash, noflash, exposure = _relief_capture(_patchy_relief(0.4, 0.3), 0.5)
    profile = fit_flash(flash, noflash, to_radiance=1 / exposure, options=FlashFitConfig(pixel_median=False))
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert fit.relief is None and profile.pixel_median is None
    median = fit.pixel_median
    assert median["used"] and median["profile"] == pytest.approx(profile.roughness)
    assert abs(median["roughness"] - 0.5) <= 0.02 < abs(profile.roughness - 0.5), (median, profile.roughness)
    assert fit.roughness == pytest.approx(0.5 * (median["roughness"] + profile.roughness))
    assert fit.to_json()["pixel_median"] == median
    for weight in (0.0, 0.75, 1.0):  # the share of the median reading (FlashFitConfig.median_weight)
        weighted = fit_flash(
            flash, noflash, to_radiance=1 / exposure, options=FlashFitConfig(median_weight=weight)
        )
        want = weight * median["roughness"] + (1.0 - weight) * median["profile"]
        assert weighted.roughness == pytest.approx(want, abs=1e-3), weight
        assert weighted.pixel_median == median
    # where the two readings differ by more than FlashFitConfig.median_alone, the median's alone
    gap = abs(median["roughness"] - median["profile"])
    assert gap > 0.01
    for limit, want in ((gap / 2, median["roughness"]), (min(2 * gap, 1.0), fit.roughness)):
        gated = fit_flash(
            flash, noflash, to_radiance=1 / exposure, options=FlashFitConfig(median_alone=limit)
        )
        assert gated.roughness == pytest.approx(want, abs=1e-3), limit


def test_pixel_median_reading_not_used_for_a_lobe_it_cannot_resolve():
    """Roughness 0.06: the lobe lights a few central pixels that ring medians ignore; a reading below
    MEDIAN_MIN_ROUGHNESS is recorded but the profile's roughness is kept."""
    from ebr_mitsuba.estimate.flashfit import MEDIAN_MIN_ROUGHNESS

    flash, noflash, exposure = _relief_capture(_patchy_relief(0.0, 0.0), 0.06)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert fit.pixel_median["roughness"] < MEDIAN_MIN_ROUGHNESS and not fit.pixel_median["used"]
    assert fit.roughness == fit.pixel_median["profile"]
    assert abs(fit.roughness - 0.06) <= 0.02


@pytest.mark.parametrize("roughness", [0.3, 0.5])
def test_no_relief_on_a_flat_sample(roughness):
    flash, noflash, exposure = _relief_capture(_patchy_relief(0.0, 0.0), roughness)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert fit.relief is None, fit.relief
    assert abs(fit.roughness - roughness) <= 0.05, fit.roughness


def test_lobe_table_resolves_a_sharp_lobe():
    """The tabulated lobe (uniform in θ from 0) against the lobe evaluated at each pixel: within
    1 % of the peak for roughness 0.074 (α = 0.0055 rad), whose core a table uniform in cos θ
    missed; and over each pixel's footprint its sum is the lobe's integral (a 12× finer grid)
    within 2 %, where the pixel centres alone are off by more."""
    from ebr_mitsuba.estimate.flashfit import _footprint_cos, _lobe, _LobeTable
    from ebr_mitsuba.geometry import NEAR_DISTANCE, view_directions

    camera = (0.0, 0.0, NEAR_DISTANCE)
    v = torch.from_numpy(view_directions(RES, RES, camera)).reshape(-1, 3)
    exact = _lobe(v, 0.074, 1.0)
    table = _LobeTable(v[:, 2].contiguous())(0.074, 1.0)
    assert float((table - exact).abs().max()) <= 0.01 * float(exact.max())

    r = 0.08
    fine = _LobeTable(torch.from_numpy(view_directions(RES * 12, RES * 12, camera)[..., 2]).reshape(-1))
    integral = float(fine(r, 1.0).sum()) / 144
    centres = float(_LobeTable(v[:, 2].contiguous())(r, 1.0).sum())
    footprint = float(_LobeTable(v[:, 2].contiguous(), _footprint_cos(RES, RES, camera))(r, 1.0).sum())
    assert abs(footprint / integral - 1) <= 0.02, (footprint, integral)
    assert abs(centres / integral - 1) > abs(footprint / integral - 1), (centres, footprint, integral)


def test_misfit_recorded_and_the_network_roughness_taken_above_the_limit():
    """A clean single-lobe capture fits its rings closely (misfit far below the default limit);
    above a limit the network's roughness map replaces the fitted constant (module docstring,
    "Misfit"), diffuse and F0 unchanged; a metal never falls back."""
    flash, noflash, exposure = _capture(_uniform((0.3, 0.3, 0.3)), (0.04,) * 3, 0.4)
    fit = fit_flash(flash, noflash, to_radiance=1 / exposure)
    assert fit.misfit is not None and fit.misfit < FlashFitConfig().misfit_limit / 10, fit.misfit
    assert not fit.misfits(FlashFitConfig().misfit_limit) and fit.misfits(fit.misfit / 2)
    net = np.linspace(0.2, 0.6, RES * RES, dtype=np.float32).reshape(RES, RES, 1)
    swapped = fit.with_network_roughness(net)
    flat = np.dstack([np.zeros((RES, RES, 2)), np.ones((RES, RES))])
    maps, before = swapped.maps(flat), fit.maps(flat)
    np.testing.assert_array_equal(np.asarray(maps.roughness).reshape(RES, RES), net[..., 0])
    np.testing.assert_array_equal(maps.diffuse, before.diffuse)
    np.testing.assert_array_equal(maps.specular, before.specular)
    assert swapped.to_json()["roughness_from"] == "network" and fit.to_json()["roughness_from"] == "fit"
    with pytest.raises(InputError, match="roughness map"):
        fit.with_network_roughness(np.zeros((3, 3), np.float32))
    from dataclasses import replace

    assert not replace(fit, metal=True).misfits(0.0)
