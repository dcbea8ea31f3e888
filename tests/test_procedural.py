"""Procedural materials, augmentation and environments (ebr_mitsuba.procedural), numpy only."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ebr_mitsuba.colour import LUMINANCE
from ebr_mitsuba.errors import InputError
from ebr_mitsuba.procedural import (
    ENV_KINDS,
    FAMILIES,
    FLASH_IRRADIANCE,
    INTENSITY_LEVELS,
    METALS,
    AugmentSettings,
    augment,
    blend,
    environment_choice,
    family_parameters,
    irradiance_luminance,
    jitter_diffuse,
    make_environment,
    make_material,
    mirror,
    random_mask,
    rotate90,
    rotate_scale_crop,
)
from ebr_mitsuba.procedural.color import hsv_to_rgb, rgb_to_hsv
from ebr_mitsuba.procedural.noise import fbm, gradient_noise, grid, value_noise, worley
from ebr_mitsuba.procedural.normals import normals_from_height, normals_to_slopes, slopes_to_normals
from ebr_mitsuba.svbrdf import SVBRDF

DIELECTRIC = ("tiles", "wood", "leather", "plaster", "fabric", "marble")


# -- materials -----------------------------------------------------------------------------------


@pytest.mark.parametrize("size", [64, 256])
@pytest.mark.parametrize("family", list(FAMILIES))
def test_family_maps_valid(family, size):
    m = make_material(family, 11, size)
    assert m.shape == (size, size)
    for name in ("normal", "diffuse", "specular", "roughness"):
        arr = getattr(m, name)
        assert arr.dtype == np.float32
        assert np.all(np.isfinite(arr)), name
    for name in ("diffuse", "specular", "roughness"):
        arr = getattr(m, name)
        assert arr.min() >= 0.0 and arr.max() <= 1.0, name
    assert np.allclose(np.linalg.norm(m.normal, axis=-1), 1.0, atol=1e-5)
    assert m.normal[..., 2].min() > 0.0
    assert m.source == f"procedural:{family}:11"


@pytest.mark.parametrize("family", list(FAMILIES))
def test_family_deterministic_and_seeded(family):
    a = make_material(family, 5, 64)
    b = make_material(family, 5, 64)
    c = make_material(family, 6, 64)
    for name in ("normal", "diffuse", "specular", "roughness"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert not np.array_equal(a.diffuse, c.diffuse) or not np.array_equal(a.normal, c.normal)


@pytest.mark.parametrize("family", list(FAMILIES))
def test_same_pattern_at_two_sizes(family):
    """64² is the 256² pattern without its finest octaves: 4×4 block means correlate."""
    big = make_material(family, 0, 256).diffuse.reshape(64, 4, 64, 4, 3).mean(axis=(1, 3))
    small = make_material(family, 0, 64).diffuse
    assert np.corrcoef(big.ravel(), small.ravel())[0, 1] > 0.85


def test_physical_statistics():
    for seed in range(3):
        for family in DIELECTRIC:
            m = make_material(family, seed, 64)
            spec = m.specular
            assert np.allclose(spec[..., 0], spec[..., 1]) and np.allclose(spec[..., 1], spec[..., 2]), family
            assert 0.02 <= spec.min() and spec.max() <= 0.08, family
        metal = make_material("metal", seed, 64)
        assert metal.diffuse.max() <= 0.03
        f0 = metal.specular.reshape(-1, 3)
        assert f0.mean() > 0.15  # tarnished titanium at worst; dielectrics stay ≤ 0.08
        assert make_material("fabric", seed, 64).roughness.mean() > 0.6
        assert make_material("marble", seed, 64).roughness.mean() < 0.35
    gold = make_material("metal", 0, 64, metal="gold")
    assert gold.specular[..., 0].mean() > gold.specular[..., 2].mean() + 0.4  # coloured F₀
    assert all(len(v) == 3 and max(v) <= 1.0 for v in METALS.values())


def test_families_differ():
    """Per-family statistics (mean over seeds 0–2 at 64²) differ pairwise by ≥ 0.05 somewhere."""

    def features(m: SVBRDF) -> np.ndarray:
        lum = m.diffuse @ LUMINANCE
        chroma = (m.diffuse.max(-1) - m.diffuse.min(-1)).mean()
        return np.array(
            [
                lum.mean(),
                lum.std(),
                chroma,
                m.specular.mean(),
                m.roughness.mean(),
                m.roughness.std(),
                m.normal[..., :2].std(),
            ]
        )

    feats = {f: np.mean([features(make_material(f, s, 64)) for s in range(3)], axis=0) for f in FAMILIES}
    names = list(feats)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            assert np.abs(feats[a] - feats[b]).max() >= 0.05, (a, b)


def test_parameter_override_keeps_other_draws():
    default = make_material("wood", 7, 64)
    matches = [
        s
        for s in ("light", "oak", "walnut", "cherry")
        if np.array_equal(make_material("wood", 7, 64, species=s).diffuse, default.diffuse)
    ]
    assert len(matches) == 1
    picked = make_material("tiles", 3, 64)
    rows4 = make_material("tiles", 3, 64, style="tiles", rows=4)
    rows6 = make_material("tiles", 3, 64, style="tiles", rows=6)
    assert not np.array_equal(rows4.normal, rows6.normal)
    assert picked.shape == rows4.shape


def test_bad_inputs():
    with pytest.raises(InputError, match="tiles, wood, metal"):
        make_material("velvet", 0)
    with pytest.raises(InputError, match="accepts style, rows"):
        make_material("tiles", 0, 64, colour=(1, 0, 0))
    with pytest.raises(InputError, match="rows"):
        make_material("tiles", 0, 64, rows=0)
    with pytest.raises(InputError, match="metal"):
        make_material("metal", 0, 64, metal="unobtainium")
    with pytest.raises(InputError, match="color"):
        make_material("leather", 0, 64, color=(2.0, 0.0, 0.0))
    with pytest.raises(InputError, match="seed"):
        make_material("wood", -1, 64)
    with pytest.raises(InputError, match="size"):
        make_material("wood", 0, 2)
    assert family_parameters("fabric") == ("threads", "weave", "warp_color", "weft_color", "roughness")


# -- noise ----------------------------------------------------------------------------------------


def test_noise_is_periodic_and_bounded():
    u, v = grid(32, 48)
    assert u.shape == (32, 48) and v[0, 0] < v[-1, 0]  # v grows downwards
    gens = [
        lambda a, b, r: gradient_noise(a, b, (3, 5), r),
        lambda a, b, r: value_noise(a, b, 4, r),
        lambda a, b, r: fbm(a, b, r, freq=(2, 7), octaves=4),
        lambda a, b, r: worley(a, b, 5, r).f1,
    ]
    for gen in gens:
        a = gen(u, v, np.random.default_rng(1))
        b = gen(u + 1.0, v - 2.0, np.random.default_rng(1))
        assert np.allclose(a, b, atol=1e-12)
        assert np.abs(a).max() <= 1.5
    cells = worley(u, v, 6, np.random.default_rng(2))
    assert np.all(cells.f2 >= cells.f1) and cells.cell.max() < 36


# -- normals --------------------------------------------------------------------------------------


def test_normal_from_height_ramp_orientation():
    size = 16
    u, v = grid(size)
    x = 2 * u - 1  # world x of each pixel
    y = 1 - 2 * v  # world y: row 0 is the top (+y)
    a = 0.5
    nx_ramp = normals_from_height(a * x)
    expect = np.array([-a, 0.0, 1.0]) / math.hypot(a, 1.0)
    assert np.allclose(nx_ramp, expect, atol=1e-6)
    ny_ramp = normals_from_height(a * y)  # higher towards the top row
    assert np.allclose(ny_ramp, np.array([0.0, -a, 1.0]) / math.hypot(a, 1.0), atol=1e-6)
    assert ny_ramp[..., 1].max() < 0  # surface rising towards +y faces −y


def test_slope_round_trip():
    rng = np.random.default_rng(3)
    n = rng.normal(size=(8, 8, 3))
    n[..., 2] = np.abs(n[..., 2]) + 0.2
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    assert np.allclose(slopes_to_normals(normals_to_slopes(n)), n, atol=1e-6)


# -- augmentation ---------------------------------------------------------------------------------


def _ramp_material(size: int, a: float, b: float = 0.0) -> SVBRDF:
    u, v = grid(size)
    height = a * (2 * u - 1) + b * (1 - 2 * v)
    return SVBRDF(
        normal=normals_from_height(height),
        diffuse=np.stack([u, v, 0.5 + 0 * u], -1),
        specular=np.full((size, size, 3), 0.04),
        roughness=u.copy(),
    )


@pytest.mark.parametrize("k", [1, 2, 3])
def test_rotate90_turns_normals_with_the_map(k):
    size, a = 16, 0.4
    m = _ramp_material(size, a)
    r = rotate90(m, k)
    u, v = grid(size)
    height = np.rot90(a * (2 * u - 1), k)
    assert np.allclose(r.normal, normals_from_height(height), atol=1e-6)
    direction = {1: (0.0, -a), 2: (a, 0.0), 3: (0.0, a)}[k]  # (-∂h/∂x, -∂h/∂y) after turning
    assert np.allclose(r.normal[..., :2] * math.hypot(a, 1.0), direction, atol=1e-6)
    assert np.array_equal(r.diffuse, np.rot90(m.diffuse, k))


def test_mirror_flips_normal_component():
    m = _ramp_material(8, 0.3, 0.2)
    mx = mirror(m, "x")
    assert np.allclose(mx.normal[..., 0], -np.flip(m.normal[..., 0], 1))
    assert np.allclose(mx.normal[..., 1], np.flip(m.normal[..., 1], 1))
    my = mirror(m, "y")
    assert np.allclose(my.normal[..., 1], -np.flip(m.normal[..., 1], 0))
    with pytest.raises(InputError):
        mirror(m, "z")


def test_small_rotation_of_a_ramp_is_exact():
    """Bilinear resampling of a linear ramp is exact: the rotated map is the rotated ramp."""
    size, a, b = 32, 0.4, -0.25
    m = _ramp_material(size, a, b)
    angle, zoom, centre = math.radians(12.0), 1.5, (0.1, -0.05)
    r = rotate_scale_crop(m, angle, zoom, centre)
    c, s = math.cos(angle), math.sin(angle)
    gx, gy = c * a - s * b, s * a + c * b  # ∇h turned by the angle (normals keep their tilt)
    assert np.allclose(r.normal, np.array([-gx, -gy, 1.0]) / math.sqrt(gx * gx + gy * gy + 1), atol=1e-5)
    # the diffuse map's u channel follows the source point q = R(−θ)p/zoom + centre
    u, v = grid(size)
    px, py = 2 * u - 1, 1 - 2 * v
    qx = (c * px + s * py) / zoom + centre[0]
    assert np.allclose(r.diffuse[..., 0], (qx + 1) / 2, atol=1e-5)
    with pytest.raises(InputError, match="zoom"):
        rotate_scale_crop(m, angle, 1.0)


def test_augment_ranges_determinism_and_identity():
    a = make_material("tiles", 1, 64)
    b = make_material("metal", 2, 64)
    for seed in range(6):
        out = augment(a, np.random.default_rng(seed), other=b)
        assert out.shape == a.shape
        for name in ("diffuse", "specular", "roughness"):
            arr = getattr(out, name)
            assert np.all(np.isfinite(arr)) and arr.min() >= 0 and arr.max() <= 1
        assert np.allclose(np.linalg.norm(out.normal, axis=-1), 1, atol=1e-5) and out.normal[..., 2].min() > 0
    again = augment(a, np.random.default_rng(4), other=b)
    first = augment(a, np.random.default_rng(4), other=b)
    assert np.array_equal(again.normal, first.normal) and np.array_equal(again.diffuse, first.diffuse)
    same = augment(a, np.random.default_rng(0), settings=AugmentSettings.none())
    for name in ("normal", "diffuse", "specular", "roughness"):
        assert np.array_equal(getattr(same, name), getattr(a, name))
    with pytest.raises(InputError, match="unknown field"):
        AugmentSettings().replace(sharpen=1.0)
    with pytest.raises(InputError, match="zoom"):
        AugmentSettings(zoom=(0.5, 1.0))


def test_jitter_diffuse():
    d = make_material("fabric", 3, 32).diffuse
    assert np.allclose(jitter_diffuse(d), d, atol=1e-6)
    j = jitter_diffuse(d, hue=0.3, saturation=1.8, brightness=1.9, contrast=1.9)
    assert j.min() >= 0 and j.max() <= 1 and not np.allclose(j, d, atol=0.05)
    rgb = np.random.default_rng(0).random((50, 3))
    assert np.allclose(hsv_to_rgb(rgb_to_hsv(rgb)), rgb, atol=1e-12)


def test_jitter_saturation_and_contrast_each_act():
    """The saturation and contrast factors of the dual-loss paper's colour jitter each do their own
    job: saturation scales HSV saturation (hue and value kept), contrast scales the spread about
    the mean luminance (the mean kept, up to clipping)."""
    d = 0.2 + 0.6 * np.random.default_rng(5).random((16, 16, 3)).astype(np.float32)
    s0 = rgb_to_hsv(d)
    s1 = rgb_to_hsv(jitter_diffuse(d, saturation=0.5))
    assert np.allclose(s1[..., 1], 0.5 * s0[..., 1], atol=1e-5)
    assert np.allclose(s1[..., 2], s0[..., 2], atol=1e-5)
    lum = lambda x: x @ LUMINANCE  # noqa: E731
    c = jitter_diffuse(d, contrast=0.5)
    assert abs(lum(c).mean() - lum(d).mean()) < 1e-5
    assert np.allclose(lum(c) - lum(c).mean(), 0.5 * (lum(d) - lum(d).mean()), atol=1e-5)


def test_blend_slope_space():
    m = make_material("leather", 4, 64)
    mask = random_mask(np.random.default_rng(1), 64, coverage=0.4)
    assert 0.3 < (mask >= 0.5).mean() < 0.5
    same = blend(m, m, mask)
    assert np.allclose(same.normal, m.normal, atol=1e-6)
    for name in ("diffuse", "specular", "roughness"):
        assert np.allclose(getattr(same, name), getattr(m, name), atol=1e-6)
    other = make_material("wood", 4, 64)
    assert np.allclose(blend(m, other, np.zeros((64, 64))).normal, m.normal, atol=1e-6)
    assert np.allclose(blend(m, other, np.ones((64, 64))).diffuse, other.diffuse, atol=1e-6)
    half = blend(_ramp_material(8, 0.6), _ramp_material(8, -0.2, 0.4), np.full((8, 8), 0.5))
    assert np.allclose(half.normal, np.array([-0.2, -0.2, 1.0]) / math.sqrt(1.08), atol=1e-6)
    with pytest.raises(InputError, match="resample"):
        blend(m, make_material("wood", 4, 32), mask)


# -- environments -------------------------------------------------------------------------------


def _reference_irradiance(env) -> float:
    """Luminance of ∫ L(ω) max(ω_z, 0) dω by brute quadrature in each lobe's own polar frame."""
    total = 0.0
    x, w = np.polynomial.legendre.leggauss(400)
    phi = (np.arange(1024) + 0.5) * (2 * np.pi / 1024)
    for axis, lam, amp in zip(
        env.axis.astype(np.float64), env.sharpness.astype(np.float64), env.amplitude.astype(np.float64)
    ):
        smax = min(2.0, 50.0 / lam)  # 1 − cos θ; e^{−50} is negligible
        s = (x + 1) * smax / 2
        ws = w * smax / 2
        t1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(axis, t1)
        cos_t = 1 - s
        sin_t = np.sqrt(np.clip(1 - cos_t**2, 0, None))
        wz = cos_t[:, None] * axis[2] + sin_t[:, None] * (np.cos(phi) * t1[2] + np.sin(phi) * t2[2])
        inner = np.clip(wz, 0, None).sum(axis=1) * (2 * np.pi / 1024)
        total += float(np.sum(ws * np.exp(-lam * s) * inner)) * float(amp @ LUMINANCE)
    return total


def test_flash_irradiance_value():
    assert FLASH_IRRADIANCE == pytest.approx(10.0 / (1 / math.tan(math.radians(22.5))) ** 2)
    assert 1.6 < FLASH_IRRADIANCE < 1.8


@pytest.mark.parametrize("kind", ENV_KINDS)
def test_environment_irradiance_levels(kind):
    for seed, level in zip((1, 2, 3), INTENSITY_LEVELS):
        env = make_environment(seed, kind=kind, intensity=level)
        target = INTENSITY_LEVELS[level] * FLASH_IRRADIANCE
        assert irradiance_luminance(env) == pytest.approx(target, rel=1e-4)
        assert _reference_irradiance(env) == pytest.approx(target, rel=2e-3)
        assert np.all(env.amplitude >= 0) and np.allclose(np.linalg.norm(env.axis, axis=1), 1, atol=1e-6)


def test_environment_kinds_have_their_shape():
    for seed in range(4):
        sun = make_environment(seed, kind="sun_sky", intensity="medium")
        k = int(np.argmax(sun.sharpness))
        assert 1e3 <= sun.sharpness[k] <= 5e3 and sun.axis[k, 2] > 0
        others = np.delete(sun.amplitude, k, axis=0)
        assert sun.amplitude[k].max() > 100 * others.max()  # the sun is bright
        assert sun.axis[:, 2].min() < -0.99  # ground bounce below the horizon
        window = make_environment(seed, kind="window")
        sharp = window.sharpness[window.sharpness >= 20]
        assert 1 <= len(sharp) <= 2 and sharp.max() <= 300
        overcast = make_environment(seed, kind="overcast")
        assert overcast.sharpness.max() <= 4 and 4 <= overcast.num_lobes <= 6


def test_environment_determinism_and_choice():
    a = make_environment(17)
    b = make_environment(17)
    assert np.array_equal(a.axis, b.axis) and np.array_equal(a.amplitude, b.amplitude)
    kind, level = environment_choice(17)
    c = make_environment(17, kind=kind, intensity=level)
    assert np.array_equal(a.axis, c.axis) and np.array_equal(a.sharpness, c.sharpness)
    assert not np.array_equal(make_environment(18).amplitude[:1], a.amplitude[:1])
    picks = {environment_choice(s) for s in range(40)}
    assert {k for k, _ in picks} == set(ENV_KINDS) and {lv for _, lv in picks} == set(INTENSITY_LEVELS)
    with pytest.raises(InputError, match="sun_sky, window, overcast"):
        make_environment(0, kind="studio")
    with pytest.raises(InputError, match="low, medium, high"):
        make_environment(0, intensity="blinding")
    with pytest.raises(InputError, match="seed"):
        make_environment(-3)
