"""Tests of the fast differentiable renderer (ebr_mitsuba.render).

References: the float64 numpy module :mod:`ebr_mitsuba.reference` (BRDF, point light, MIS
quadrature of the environment term) and a brute-force Gauss–Legendre × uniform-φ hemisphere
integral written here. Resolutions are 4²–16², seeds fixed; tolerances are stated per test.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from ebr_mitsuba import reference
from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.exemplar.images import exemplar_images
from ebr_mitsuba.geometry import NEAR_DISTANCE, near_shot, pixel_positions, view_directions
from ebr_mitsuba.render import (
    DrLobes,
    DrMaps,
    RenderOptions,
    render,
    render_numpy,
    view_shot,
)
from ebr_mitsuba.sgenv import SGEnvironment
from ebr_mitsuba.svbrdf import SVBRDF

MODES = ("sg", "quadrature")


# -- independent numpy references ------------------------------------------------------------------
def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def hemisphere_rule(n_mu: int = 400, n_phi: int = 800):
    """Directions (M, 3) and weights (M,) integrating over ω_z > 0 (Gauss–Legendre in cos θ,
    uniform φ)."""
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu, wmu = (x + 1.0) / 2.0, w / 2.0
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    st = np.sqrt(1.0 - mu * mu)
    dirs = np.stack([np.outer(st, np.cos(phi)), np.outer(st, np.sin(phi)), np.outer(mu, np.ones(n_phi))], -1)
    return dirs.reshape(-1, 3), np.repeat(wmu * (2.0 * np.pi / n_phi), n_phi)


# -- fixtures ----------------------------------------------------------------------------------------
def random_material(rng, h, w, tilt=0.3, rough=(0.2, 0.9)):
    n = rng.normal(size=(h, w, 3)) * tilt
    n[..., 2] = 1.0
    return SVBRDF(
        _unit(n),
        rng.uniform(0.1, 0.9, (h, w, 3)),
        rng.uniform(0.1, 0.9, (h, w, 3)),
        rng.uniform(*rough, (h, w)),
    )


def random_env(rng, k, lam=(2.0, 30.0)):
    axis = rng.normal(size=(k, 3))
    axis[:, 2] = np.abs(axis[:, 2]) + 0.2
    return SGEnvironment(axis, rng.uniform(*lam, k), rng.uniform(0.2, 2.0, (k, 3)))


# -- point light, geometry -------------------------------------------------------------------------
def test_point_light_matches_analytic_value():
    """Flash-only render equals f·cos·I/d² (reference.render_point, float64) at every pixel of a
    general camera/light pair to 1e-5 relative."""
    rng = np.random.default_rng(3)
    sv = random_material(rng, 8, 8)
    shot = view_shot((0.4, -0.3, 2.2), light=(-0.7, 0.5, 1.6), intensity=7.5, env=False)
    img = render_numpy(sv, SGEnvironment.empty(), shot)
    flat = [
        a.reshape(-1, 3)
        for a in (
            sv.normal,
            view_directions(8, 8, shot.camera),
            pixel_positions(8, 8),
            sv.diffuse,
            sv.specular,
        )
    ]
    ref = reference.render_point(*flat[:3], shot.flash, 7.5, *flat[3:], sv.roughness.reshape(-1))
    assert ref.min() > 0
    np.testing.assert_allclose(img.reshape(-1, 3), ref, rtol=1e-5, atol=0)


def test_pixel_mapping_follows_design_grid():
    """A bright texel at (row 2, col 5) (top-left quadrant) shows at that pixel; a light up and to
    the right (+x, +y) makes the top-right corner the brightest (docs/conventions.md, "Geometry
    and pixel grid")."""
    h = w = 16
    diffuse = np.zeros((h, w, 3), np.float32)
    diffuse[2, 5] = 1.0
    sv = SVBRDF(np.tile([0.0, 0.0, 1.0], (h, w, 1)), diffuse, np.zeros((h, w, 3)), np.full((h, w), 0.5))
    img = render_numpy(sv, None, near_shot(True, env=False), fresnel="none")
    assert np.unravel_index(np.argmax(img[..., 0]), (h, w)) == (2, 5)
    assert np.count_nonzero(img) == 3
    point = pixel_positions(h, w)[2, 5]
    assert point[0] < 0 and point[1] > 0  # top-left of the sample is −x, +y
    d2 = float(np.sum((np.array([0, 0, NEAR_DISTANCE]) - point) ** 2))
    cos = NEAR_DISTANCE / math.sqrt(d2)
    np.testing.assert_allclose(img[2, 5, 0], (1.0 / math.pi) * cos * 10.0 / d2, rtol=1e-5)

    uniform = SVBRDF.uniform(h, w, diffuse=0.5, specular=0.0, roughness=0.5)
    lit = render_numpy(
        uniform, None, view_shot((0, 0, NEAR_DISTANCE), light=(2.0, 2.0, 1.0), env=False), fresnel="none"
    )
    assert np.unravel_index(np.argmax(lit[..., 0]), (h, w)) == (0, w - 1)


def test_matches_mitsuba_capture_renders():
    """Same images as Mitsuba renders of the same scene (ebr_mitsuba.scene, svbrdf + sgenvmap
    plugins, box filter): flash-only median relative difference < 2e-3 (the box filter averages over
    the pixel footprint, we shade the centre); environment-only image means agree within 1%
    (Mitsuba 256 / 1024 spp vs quadrature 256 spp, 16×16 pixels)."""
    from ebr_mitsuba.scene import sg_emitter_dict, shot_scene_dict, svbrdf_bsdf_dict

    rng = np.random.default_rng(2)
    sv = random_material(rng, 16, 16, tilt=0.3, rough=(0.3, 0.9))
    env = random_env(rng, 4, lam=(2.0, 20.0))
    for shot, spp, check in ((near_shot(True, env=False), 256, "pixels"), (near_shot(False), 1024, "mean")):
        scene = shot_scene_dict(svbrdf_bsdf_dict(sv), sg_emitter_dict(env), shot, 16, spp, seed=1)
        scene = mi.load_dict(scene)
        ref = np.asarray(mi.render(scene).numpy(), np.float64)
        ours = render_numpy(sv, env, shot, mode="quadrature", spp=256)
        if check == "pixels":
            assert np.median(np.abs(ours - ref) / ref) < 2e-3
        else:
            assert abs(ours.mean() / ref.mean() - 1.0) < 0.01


# -- environment term: accuracy ------------------------------------------------------------------------
def test_sg_diffuse_is_exact_for_flat_normal():
    """sg mode, F = 0: the diffuse term equals the brute-force hemisphere integral for lobes above,
    straddling and below the horizon: 3e-4 relative with 64 irradiance nodes (the residual is
    sg_irradiance's Gauss–Legendre error at the horizon kink, 1.6e-4 here)."""
    env = SGEnvironment(
        [[0, 0, 1], [1, 0, 0.1], [0.3, -1, -0.2], [0, 1, -1], [1, 1, 0.5]],
        [1e-3, 8.0, 30.0, 3.0, 60.0],
        [[1.0, 0.5, 0.2], [2.0, 2.0, 2.0], [0.5, 1.0, 3.0], [4.0, 1.0, 1.0], [1.0, 1.0, 1.0]],
    )
    sv = SVBRDF.uniform(4, 4, diffuse=(0.2, 0.5, 0.8), specular=0.0, roughness=0.5)
    img = render_numpy(sv, env, near_shot(False), mode="sg", fresnel="none", irradiance_nodes=64)
    dirs, wts = hemisphere_rule(600, 1200)
    irr = np.sum(env.eval(dirs) * (dirs[:, 2] * wts)[:, None], axis=0)
    ref = np.array([0.2, 0.5, 0.8]) / np.pi * irr
    np.testing.assert_allclose(img.reshape(-1, 3), np.broadcast_to(ref, (16, 3)), rtol=3e-4)


def test_quadrature_converges_to_reference():
    """Quadrature mode → reference.render_env as spp grows: RMS relative error at spp 512 below
    1.5% and at least 3× below that of spp 8 (fixed pattern, 8×8 pixels, perturbed normals)."""
    rng = np.random.default_rng(5)
    sv = random_material(rng, 8, 8, tilt=0.25, rough=(0.3, 0.8))
    env = random_env(rng, 5, lam=(2.0, 40.0))
    shot = view_shot((0.5, 0.3, 2.0), env=True)
    pix = ([0, 3, 7, 5], [0, 6, 2, 5])
    ref = reference.render_env(
        env,
        sv.normal[pix],
        view_directions(8, 8, shot.camera)[pix],
        sv.diffuse[pix],
        sv.specular[pix],
        sv.roughness[pix],
    )

    def rel_err(spp):
        got = render_numpy(sv, env, shot, mode="quadrature", spp=spp)[pix]
        return float(np.sqrt(np.mean(((got - ref) / ref) ** 2)))

    coarse, fine = rel_err(8), rel_err(512)
    assert fine < 0.015
    assert fine * 3 < coarse


def test_sg_specular_close_to_quadrature_for_moderate_cases():
    """The SG specular approximation stays within 15% (mean over pixels) of a 1024-spp quadrature
    for roughness 0.3, frontal near view, smooth lobes above the horizon."""
    rng = np.random.default_rng(7)
    env = random_env(rng, 6, lam=(2.0, 20.0))
    sv = SVBRDF.uniform(8, 8, diffuse=0.0, specular=0.5, roughness=0.3)
    sg = render_numpy(sv, env, near_shot(False), mode="sg")
    quad = render_numpy(sv, env, near_shot(False), mode="quadrature", spp=1024)
    assert abs(sg.mean() / quad.mean() - 1.0) < 0.15


def test_quadrature_is_deterministic_and_zero_without_lobes():
    rng = np.random.default_rng(8)
    sv = random_material(rng, 8, 8)
    env = random_env(rng, 3)
    a = render_numpy(sv, env, near_shot(False), mode="quadrature", spp=8)
    b = render_numpy(sv, env, near_shot(False), mode="quadrature", spp=8)
    # the same sample pattern; the per-pixel sums are scatter-reduced across Dr.Jit's threads, whose
    # float32 addition order may vary (1 ulp), so "the same" is to 1e-6, far below what a change of
    # pattern does (another seed moves pixels by percents)
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)
    c = render_numpy(sv, env, near_shot(False), mode="quadrature", spp=8, seed=1)
    assert np.max(np.abs(a - c)) > 1e-3 * np.max(np.abs(a))
    for mode in MODES:
        assert np.all(render_numpy(sv, SGEnvironment.empty(), near_shot(False), mode=mode) == 0)
        assert np.all(render_numpy(sv, env, near_shot(False, env=False), mode=mode) == 0)
        assert np.all(exemplar_images(SGEnvironment.empty(), [0.5], 4, 4, mode=mode)[0].numpy() == 0)


# -- gradients --------------------------------------------------------------------------------------------
def _loss(image: mi.TensorXf, weights: mi.Float):
    return dr.sum(image.array * weights)


def _direction(rng, value):
    """A random perturbation direction of the same type/shape (mean 0.5 so derivatives are O(1))."""
    if isinstance(value, mi.TensorXf):
        return mi.TensorXf(rng.normal(0.5, 1.0, tuple(value.shape)).astype(np.float32))
    if isinstance(value, mi.Float):
        return mi.Float(rng.normal(0.5, 1.0, dr.width(value)).astype(np.float32))
    k = dr.width(value)
    return type(value)(*(mi.Float(rng.normal(0.5, 1.0, k).astype(np.float32)) for _ in range(3)))


def _dot(grad, direction) -> float:
    if isinstance(grad, mi.TensorXf):
        return float(np.dot(grad.numpy().ravel(), direction.numpy().ravel()))
    if isinstance(grad, mi.Float):
        return float(np.dot(grad.numpy(), direction.numpy()))
    return float(np.sum(grad.numpy() * direction.numpy()))


@pytest.mark.parametrize("mode", MODES)
def test_gradients_match_finite_differences(mode):
    """Reverse-mode AD vs central differences (step 1e-3, 1e-2 for λ) along random directions, for
    every map and lobe parameter: relative error < 5e-3 (quadrature with a fixed guide, so the
    estimate is a smooth function; the default guide gives the same gradient at the guide)."""
    rng = np.random.default_rng(11)
    sv = random_material(rng, 12, 12)
    env = random_env(rng, 5)
    shot = view_shot((0.3, -0.2, 2.2), light=(0.5, 0.4, 2.0), intensity=4.0)
    opts = RenderOptions(mode=mode, spp=8)
    weights = mi.Float(rng.uniform(0, 1, 12 * 12 * 3).astype(np.float32))
    guide = (DrMaps.from_numpy(sv), DrLobes.from_env(env)) if mode == "quadrature" else None

    maps, lobes = DrMaps.from_numpy(sv), DrLobes.from_env(env)
    params = {**maps.params(), **lobes.params()}
    for p in params.values():
        dr.enable_grad(p)
    dr.backward(_loss(render(maps, lobes, shot, opts, guide=guide), weights))
    grads = {k: dr.grad(p) for k, p in params.items()}

    if mode == "quadrature":  # the default (detached) guide gives the same gradient at the guide
        maps2, lobes2 = DrMaps.from_numpy(sv), DrLobes.from_env(env)
        dr.enable_grad(lobes2.amplitude, maps2.roughness)
        dr.backward(_loss(render(maps2, lobes2, shot, opts), weights))
        np.testing.assert_allclose(dr.grad(lobes2.amplitude).numpy(), grads["amplitude"].numpy(), rtol=1e-5)
        np.testing.assert_allclose(
            dr.grad(maps2.roughness).numpy(), grads["roughness"].numpy(), rtol=1e-4, atol=1e-6
        )

    for name, value in params.items():
        direction = _direction(rng, value)
        ad = _dot(grads[name], direction)
        step = 1e-2 if name == "sharpness" else 1e-3
        vals = []
        for sign in (1.0, -1.0):
            m, lo = DrMaps.from_numpy(sv), DrLobes.from_env(env)
            target = m if name in m.params() else lo
            setattr(target, name, dr.detach(value) + sign * step * direction)
            with dr.suspend_grad():
                vals.append(float(_loss(render(m, lo, shot, opts, guide=guide), weights)[0]))
        fd = (vals[0] - vals[1]) / (2 * step)
        assert abs(ad - fd) <= 5e-3 * abs(fd), f"{mode} {name}: AD {ad} vs FD {fd}"


HARD_LOBES = SGEnvironment(
    axis=[[0, 0, 1], [1, 0, 0], [0.3, 0.2, -1], [0.2, 0.9, 0.4], [-0.5, 0.1, 0.8], [0, 1, 0.05]],
    sharpness=[1e-3, 1e4, 5.0, 1e4, 1e-3, 200.0],
    amplitude=[
        [0.1, 0.1, 0.1],
        [1e3, 1e3, 1e3],
        [1.0, 1.0, 1.0],
        [1e3, 9e2, 8e2],
        [0.05, 0.1, 0.2],
        [1, 1, 1],
    ],
)


def _hard_maps() -> SVBRDF:
    """8×8 maps mixing roughness 0 / 0.03 / 1 / 0.5 and normals within 2° of the tangent plane."""
    h = w = 8
    rough = np.tile(np.array([0.0, 0.03, 1.0, 0.5], np.float32), (h, w // 4))
    tilt = math.radians(88.0)
    n = np.tile([0.0, 0.0, 1.0], (h, w, 1))
    phis = np.linspace(0, 2 * np.pi, w, endpoint=False)
    for j, phi in enumerate(phis):
        n[::2, j] = [math.sin(tilt) * math.cos(phi), math.sin(tilt) * math.sin(phi), math.cos(tilt)]
    return SVBRDF(n, np.full((h, w, 3), 0.5), np.full((h, w, 3), 0.04), rough)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("case", ["hard", "black", "none"])
def test_hard_cases_are_finite(mode, case):
    """No NaN/Inf in values or gradients: roughness 0/0.03/1, near-tangent normals, grazing views and
    lights, λ = 1e-3 and 1e4, a sun 1e4× the sky, lobes below and at the horizon, a black env, K = 0."""
    env = {"hard": HARD_LOBES, "black": HARD_LOBES.scaled(0.0), "none": SGEnvironment.empty()}[case]
    sv = _hard_maps()
    shots = [
        near_shot(True),
        view_shot((40.0, 3.0, 0.4), light=(-30.0, 0.0, 0.2), intensity=1e3),
        view_shot((0.0, 0.0, 1e-3), light=(0.0, -5.0, 1e-4)),
    ]
    for shot in shots:
        _assert_finite_render(sv, env, shot, mode, f"{case} {shot.name}")


def _assert_finite_render(sv, env, shot, mode, where: str) -> None:
    """Render ``sv`` under ``env`` (spp 8), backpropagate the sum: value and every map and lobe
    gradient finite."""
    maps, lobes = DrMaps.from_numpy(sv), DrLobes.from_env(env)
    params = {**maps.params(), **lobes.params()}
    for p in params.values():
        dr.enable_grad(p)
    image = render(maps, lobes, shot, RenderOptions(mode=mode, spp=8))
    dr.backward(dr.sum(image.array))
    assert np.all(np.isfinite(image.numpy())), f"{where}: image"
    for name, p in params.items():
        assert np.all(np.isfinite(dr.grad(p).numpy())), f"{where}: d/d{name}"


#: Amplitudes from the smallest normal float32 to 1e-19: there the quadrature's lobe-selection
#: weights energy/Σenergy gave NaN/Inf gradients (Σ² underflows), issue 16 item 8.
TINY_AMPLITUDES = (1.2e-38, 1e-30, 1e-25, 1e-19)


def _grazing_flash_shot(theta_deg: float = 89.9):
    th = math.radians(theta_deg)
    return view_shot((0.0, 0.0, 2.0), light=(2.0 * math.sin(th), 0.0, 2.0 * math.cos(th)), intensity=4.0)


@pytest.mark.parametrize("mode", MODES)
def test_tiny_amplitudes_are_finite(mode):
    """A 1×4 map (roughness 0 with a flat normal, 0.03, 1, 0 with a normal 2° off the tangent
    plane), flash at 89.9° and a grazing camera; one lobe of λ = 1e-6, or two of λ = 1e-6 and 1e4,
    with amplitudes from 1.2e-38 to 1e-19: value and every gradient finite."""
    tilt = math.radians(88.0)
    n = np.array([[[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0], [math.sin(tilt), 0.0, math.cos(tilt)]]])
    sv = SVBRDF(n, np.full((1, 4, 3), 0.5), np.full((1, 4, 3), 0.04), np.array([[0.0, 0.03, 1.0, 0.0]]))
    shots = [_grazing_flash_shot(), view_shot((40.0, 3.0, 0.4), light=(-30.0, 0.0, 0.2), intensity=1e3)]
    for amplitude in TINY_AMPLITUDES:
        envs = [
            SGEnvironment([[0.0, 0.3, 1.0]], [1e-6], [[amplitude] * 3]),
            SGEnvironment(
                [[0.0, 0.3, 1.0], [1.0, 0.0, 0.01]],
                [1e-6, 1e4],
                [[amplitude] * 3, [amplitude, 0.0, 2 * amplitude]],
            ),
        ]
        for env in envs:
            for shot in shots:
                where = f"μ={amplitude} K={env.num_lobes} camera {shot.camera}"
                _assert_finite_render(sv, env, shot, mode, where)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("amplitude", (1e-30, 1e-20))
def test_tiny_amplitude_gradients_match_finite_differences(mode, amplitude):
    """Two lobes of amplitude ~1e-30 (1e-20), environment only: AD gradients of every lobe parameter
    match central differences (relative steps) within 5e-3, as at amplitude 1."""
    rng = np.random.default_rng(23)
    sv = random_material(rng, 4, 4)
    env = SGEnvironment(
        [[0.2, 0.3, 1.0], [-0.5, 0.1, 0.6]],
        [3.0, 20.0],
        amplitude * np.array([[1.0, 0.8, 0.6], [2.0, 2.5, 3.0]]),
    )
    shot = view_shot((0.3, -0.2, 2.2), light=None)
    opts = RenderOptions(mode=mode, spp=8)
    weights = mi.Float(rng.uniform(0, 1, 4 * 4 * 3).astype(np.float32))
    guide = (DrMaps.from_numpy(sv), DrLobes.from_env(env)) if mode == "quadrature" else None
    lobes = DrLobes.from_env(env)
    params = lobes.params()
    for p in params.values():
        dr.enable_grad(p)
    dr.backward(_loss(render(DrMaps.from_numpy(sv), lobes, shot, opts, guide=guide), weights))
    for name, value in params.items():
        grad = dr.grad(value)
        assert np.all(np.isfinite(grad.numpy())), f"{mode} d/d{name}"
        direction = _direction(rng, value)
        if name == "amplitude":  # steps relative to the amplitude
            direction = direction * float(amplitude)
        ad = _dot(grad, direction)
        step = 1e-2 if name == "sharpness" else 1e-3
        vals = []
        for sign in (1.0, -1.0):
            lo = DrLobes.from_env(env)
            setattr(lo, name, dr.detach(value) + sign * step * direction)
            with dr.suspend_grad():
                vals.append(
                    float(_loss(render(DrMaps.from_numpy(sv), lo, shot, opts, guide=guide), weights)[0])
                )
        fd = (vals[0] - vals[1]) / (2 * step)
        assert fd != 0.0 and abs(ad - fd) <= 5e-3 * abs(fd), f"{mode} {name}: AD {ad} vs FD {fd}"


# -- exemplars, API --------------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", MODES)
def test_exemplars_equal_uniform_renders_and_are_differentiable(mode):
    rng = np.random.default_rng(13)
    env = random_env(rng, 4)
    rough = [0.1, 0.6]
    lobes = DrLobes.from_env(env)
    dr.enable_grad(lobes.amplitude, lobes.axis)
    images = exemplar_images(lobes, rough, 8, 6, mode=mode, spp=8)
    assert len(images) == 2 and tuple(images[0].shape) == (8, 6, 3)
    for r, img in zip(rough, images):
        ref = render_numpy(
            SVBRDF.uniform(8, 6, diffuse=0.1, specular=0.2, roughness=r),
            env,
            near_shot(False),
            mode=mode,
            spp=8,
        )
        np.testing.assert_allclose(img.numpy(), ref, rtol=2e-5, atol=1e-7)
    dr.backward(dr.sum(images[0].array) + 2.0 * dr.sum(images[1].array))
    for g in (dr.grad(lobes.amplitude), dr.grad(lobes.axis)):
        assert np.all(np.isfinite(g.numpy())) and np.abs(g.numpy()).max() > 0


def test_no_recompilation_when_camera_light_and_scale_change():
    rng = np.random.default_rng(17)
    sv, env = random_material(rng, 8, 8), random_env(rng, 3)
    flag = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        for mode in MODES:
            render_numpy(sv, env, view_shot((0.1, 0.2, 2.0), (0.3, 0.3, 1.5), 3.0), mode=mode, spp=4)
            dr.kernel_history()
            render_numpy(
                sv, env, view_shot((-0.4, 0.7, 3.0), (1.3, -0.2, 2.5), 9.0), mode=mode, spp=4, env_scale=2.5
            )
            kernels = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
            assert kernels and all(k["cache_hit"] for k in kernels), mode
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, flag)


def test_roughness_may_carry_a_channel_axis():
    rng = np.random.default_rng(19)
    sv, env = random_material(rng, 4, 4), random_env(rng, 2)
    maps = DrMaps.from_numpy(sv)
    maps3 = DrMaps(maps.normal, maps.diffuse, maps.specular, mi.TensorXf(sv.roughness[..., None]))
    lobes = DrLobes.from_env(env)
    np.testing.assert_array_equal(
        render(maps, lobes, near_shot(True)).numpy(), render(maps3, lobes, near_shot(True)).numpy()
    )


def test_bad_inputs_raise_specific_errors():
    with pytest.raises(ConfigError, match="mode"):
        RenderOptions(mode="path")
    with pytest.raises(ConfigError, match="spp"):
        RenderOptions(spp=0)
    maps = DrMaps.uniform(4, 4)
    with pytest.raises(InputError, match="roughness"):
        DrMaps(maps.normal, maps.diffuse, maps.specular, mi.TensorXf(np.zeros((4, 5), np.float32)))
    with pytest.raises(InputError, match="per lobe"):
        DrLobes(mi.Vector3f([0, 0], [0, 0], [1, 1]), mi.Float([1.0]), mi.Color3f([1.0, 1.0], 0.0, 0.0))
    with pytest.raises(InputError, match="above the sample plane"):
        render(maps, DrLobes.from_env(SGEnvironment.empty()), view_shot((0, 0, -1)))
    with pytest.raises(InputError, match="roughness"):
        exemplar_images(SGEnvironment.empty(), [1.5], 4, 4)
