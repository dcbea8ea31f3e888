"""SG extraction (ebr_mitsuba.extract): SSIM, NNLS, quad-tree, forward model, merge, the pipeline,
its robustness cases, exemplar directories and the two commands.

Sizes are small (32²–48², tens of iterations) so the file runs in well under a minute; the
acceptance run at 128² is marked slow. Seeds are fixed; tolerances are stated per test.
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.extract import ExtractConfig, extract_sg, fibonacci_nnls, ms_ssim, ms_ssim_error, ssim
from ebr_mitsuba.extract.amplitudes import nnls
from ebr_mitsuba.extract.merge import energies, merge_lobes
from ebr_mitsuba.extract.quadtree import quadtree
from ebr_mitsuba.sgenv import SGEnvironment

ROUGH = [0.1, 0.3, 0.6, 0.9]
# A short schedule for tests: every stage runs once.
FAST = dict(iters=80, densify_at=(40,), correct_at=(0, 40), sample_grid=16, correction_grid=32)


def _exemplars(env, size, seed=11):
    from ebr_mitsuba.extract.evaluate import quadrature_mean

    return quadrature_mean(env, ROUGH, size, spp=256, seeds=4, seed0=seed)


def _sun_sky():
    axis = np.array([[0.3, 0.1, 0.95], [0.0, 0.0, 1.0], [0.8, -0.5, 0.3]])
    return SGEnvironment(axis, [300.0, 2.0, 8.0], [[20.0, 18.0, 15.0], [0.3, 0.4, 0.6], [0.5, 0.4, 0.3]])


def _check_env(env, max_lobes=64):
    assert env.num_lobes <= max_lobes
    for arr in (env.axis, env.sharpness, env.amplitude):
        assert np.all(np.isfinite(arr))
    assert np.all(env.amplitude >= 0) and np.all(env.sharpness > 0)


# -- SSIM ---------------------------------------------------------------------------------------------


def test_ssim_identity_symmetry_and_noise(rng):
    a = rng.random((40, 48, 3))
    assert ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    assert ms_ssim(a, a) == pytest.approx(1.0, abs=1e-12)
    b = a + 0.05 * rng.standard_normal(a.shape)
    c = a + 0.2 * rng.standard_normal(a.shape)
    assert ssim(a, b) == pytest.approx(ssim(b, a), abs=1e-12)
    assert 1.0 > ssim(a, b) > ssim(a, c)
    err = ms_ssim_error(a, c)
    assert err.shape == (40, 48) and np.all((err >= 0) & (err <= 1))
    assert np.allclose(ms_ssim_error(a, a), 0.0, atol=1e-9)


def test_ssim_known_value_for_a_constant_offset():
    # Flat images: σ = 0, so SSIM = luminance term (2μaμb + C1)/(μa² + μb² + C1) exactly.
    a = np.full((16, 16, 3), 0.5)
    b = np.full((16, 16, 3), 0.25)
    c1 = (0.01 * 1.0) ** 2
    expect = (2 * 0.5 * 0.25 + c1) / (0.25 + 0.0625 + c1)
    assert ssim(a, b, data_range=1.0) == pytest.approx(expect, rel=1e-9)


def test_ssim_rejects_bad_input():
    with pytest.raises(InputError):
        ssim(np.zeros((8, 8, 3)), np.zeros((8, 8, 3)))
    with pytest.raises(InputError):
        ssim(np.zeros((16, 16, 3)), np.zeros((16, 17, 3)))
    with pytest.raises(InputError):
        ssim(np.full((16, 16), np.nan), np.zeros((16, 16)))


# -- NNLS, quad-tree, merge ------------------------------------------------------------------------------


def test_lighting_error_is_one_quantity_with_two_edge_case_policies(rng):
    """extract.evaluate.lighting_errors ranks on metrics.lighting_error(judge=True): the same value
    as the reported lighting error where both are defined; a broken render is inf, not nan."""
    from ebr_mitsuba.metrics import lighting_error, rel_rmse

    a, b = rng.random((2, 8, 8, 3)), rng.random((2, 8, 8, 3))
    assert lighting_error(a, b) == lighting_error(a, b, judge=True)
    assert lighting_error(a, b, judge=True)["rel_rmse"] == rel_rmse(a, b)
    broken = a.copy()
    broken[0, 0, 0, 0] = np.nan
    assert lighting_error(broken, b, judge=True)["rel_rmse"] == float("inf")
    black = np.zeros_like(b)
    assert np.isnan(lighting_error(a, black)["rel_rmse"])
    assert lighting_error(a, black, judge=True)["rel_rmse"] == float("inf")


def test_nnls_matches_brute_force(rng):
    for _ in range(4):
        a = rng.random((30, 5))
        b = rng.random(30) - 0.4
        x = nnls(a, b)
        best = None
        for mask in itertools.product([0, 1], repeat=5):
            idx = [i for i in range(5) if mask[i]]
            z = np.zeros(5)
            if idx:
                z[idx] = np.linalg.lstsq(a[:, idx], b, rcond=None)[0]
            if np.all(z >= 0):
                r = np.linalg.norm(a @ z - b)
                best = (r, z) if best is None or r < best[0] else best
        assert np.all(x >= 0)
        np.testing.assert_allclose(x, best[1], atol=1e-7)


def test_quadtree_splits_at_a_highlight_only():
    img = np.full((64, 64, 3), 0.2)
    assert len(quadtree(img, 0.05, 6)) == 1
    img[40:43, 10:13] = 50.0
    leaves = quadtree(img, 0.05, 6)
    assert sum(p.height * p.width for p in leaves) == 64 * 64  # a partition
    deepest = max(leaves, key=lambda p: p.level)
    assert deepest.level >= 4
    r, c = deepest.centre
    assert abs(r - 41.5) < 6 and abs(c - 11.5) < 6
    # a far corner stays coarse
    corner = [p for p in leaves if p.row == 0 and p.col == 32]
    assert corner and corner[0].level == 1


def test_merge_combines_neighbours_and_keeps_energy():
    axis = np.array([[0, 0, 1.0], [0.01, 0, 1.0], [1.0, 0, 0]])
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    sharp = np.array([100.0, 120.0, 100.0])
    amp = np.array([[1.0, 1, 1], [0.5, 0.5, 0.5], [1.0, 1, 1]])
    a, s, m = merge_lobes(axis, sharp, amp, budget=10)
    assert len(s) == 2
    assert energies(s, m).sum() == pytest.approx(energies(sharp, amp).sum(), rel=1e-9)
    a2, s2, m2 = merge_lobes(axis, sharp, amp, budget=1)
    assert len(s2) == 1


def test_config_rejects_bad_values():
    with pytest.raises(ConfigError):
        ExtractConfig(env_mode="exact")
    with pytest.raises(ConfigError):
        ExtractConfig(max_lobes=0)
    with pytest.raises(ConfigError):
        ExtractConfig.from_dict({"iterations": 3})
    assert ExtractConfig.from_dict({"densify_at": [5]}).densify_at == (5,)


# -- forward model ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("mode", ["sg", "quadrature"])
def test_forward_equals_exemplar_images(mode):
    import drjit as dr
    import mitsuba as mi

    from ebr_mitsuba.exemplar.images import exemplar_images
    from ebr_mitsuba.extract.forward import ExemplarGeometry
    from ebr_mitsuba.geometry import near_shot
    from ebr_mitsuba.render import DrLobes, RenderOptions

    env = _sun_sky()
    opts = RenderOptions(mode=mode, spp=8)
    ref = np.stack([np.asarray(t.numpy()) for t in exemplar_images(env, ROUGH, 24, 20, options=opts)])
    geom = ExemplarGeometry(np.array(ROUGH, np.float32), 24, 20, near_shot(False))
    got = geom.render_numpy(DrLobes.from_env(env), opts)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6)
    # a subset of pixels gives the same values as the full render
    idx = np.array([5, 480 + 7, 3 * 480 + 479], np.uint32)
    with dr.suspend_grad():
        sub = np.asarray(geom.render(DrLobes.from_env(env), mi.UInt32(idx), opts).numpy()).T
    np.testing.assert_allclose(sub, got.reshape(-1, 3)[idx], rtol=1e-5, atol=1e-6)


def test_mirror_axis_is_the_reflected_view():
    from ebr_mitsuba.extract.forward import ExemplarGeometry
    from ebr_mitsuba.geometry import near_shot, view_directions

    geom = ExemplarGeometry(np.array([0.1], np.float32), 16, 16, near_shot(False))
    v = view_directions(16, 16)[3, 12]
    r = 2 * v[2] * np.array([0, 0, 1.0]) - v
    np.testing.assert_allclose(geom.mirror_axes(np.array([3.5]), np.array([12.5]))[0], r, atol=1e-12)


# -- the pipeline --------------------------------------------------------------------------------------------


def test_extract_reproduces_a_procedural_environment():
    from ebr_mitsuba.extract.evaluate import quadrature_mean
    from ebr_mitsuba.metrics import rel_rmse
    from ebr_mitsuba.procedural import make_environment

    env = make_environment(2)
    y = _exemplars(env, 32)
    res = extract_sg(y, ROUGH, config=ExtractConfig(**FAST))
    _check_env(res.env)
    assert res.iterations == 80
    assert res.loss_history and res.loss_history[-1][1] < res.loss_history[0][1]
    ref = _exemplars(env, 32, seed=77)  # independent patterns (the two differ by 1.1 %)
    est = quadrature_mean(res.env, ROUGH, 32, spp=256, seeds=4, seed0=500)
    # 32² and 80 iterations gave 3.0 %; 4 % bounds a working fit (the default 400 iterations: 1.4 %;
    # the documented 128² numbers are in docs/bench/extract_sg.md).
    assert rel_rmse(est, ref) < 0.04
    assert set(res.stage_seconds) >= {"init", "merge", "solve", "optimize", "densify", "prune", "correct"}


def test_extract_respects_the_lobe_budget_and_switches():
    from ebr_mitsuba.procedural import make_environment

    y = _exemplars(make_environment(0), 32)
    res = extract_sg(y, ROUGH, config=ExtractConfig(max_lobes=5, **FAST))
    _check_env(res.env, 5)
    res = extract_sg(
        y, ROUGH, config=ExtractConfig(optimize=False, env_mode="sg", init="random", merge=False)
    )
    assert res.iterations == 0
    _check_env(res.env)


def test_all_black_exemplars_give_an_empty_environment():
    res = extract_sg(np.zeros((4, 32, 32, 3), np.float32), ROUGH)
    assert res.env.num_lobes == 0 and res.rel_rmse_exemplars == 0.0


def test_single_sharp_sun_lobe():
    sun = SGEnvironment([[0.1, -0.05, 1.0]], [1.0e4], [[5000.0, 4800.0, 4500.0]])
    y = _exemplars(sun, 48)
    res = extract_sg(y, ROUGH, config=ExtractConfig(**FAST))
    _check_env(res.env)
    strongest = int(np.argmax(res.env.energy()))
    # the dominant extracted lobe points at the sun (within 2°)
    cos = float(res.env.axis[strongest] @ (sun.axis[0] / np.linalg.norm(sun.axis[0])))
    assert cos > np.cos(np.radians(2.0))


def test_clipped_and_tiny_exemplars():
    y = _exemplars(_sun_sky(), 32)
    clipped = np.minimum(y, np.quantile(y, 0.97))
    res = extract_sg(clipped, ROUGH, config=ExtractConfig(**FAST))
    _check_env(res.env)
    # clipped pixels are lower bounds: the fit keeps at least the clipped level there
    assert res.env.num_lobes > 0
    base = extract_sg(y, ROUGH, config=ExtractConfig(**FAST))
    tiny = extract_sg(y * 1e-6, ROUGH, config=ExtractConfig(**FAST))
    _check_env(tiny.env)
    # the pipeline is scale-free: same lobes at 1e-6 radiance, amplitudes scaled (float32 rounding)
    assert tiny.env.num_lobes == base.env.num_lobes
    np.testing.assert_allclose(tiny.env.amplitude * 1e6, base.env.amplitude, rtol=2e-2, atol=1e-3)


def test_bad_exemplar_input_is_an_input_error():
    good = np.ones((32, 32, 3), np.float32)
    with pytest.raises(InputError, match="different sizes"):
        extract_sg([good, np.ones((32, 40, 3), np.float32)], [0.1, 0.5])
    with pytest.raises(InputError, match="roughness"):
        extract_sg(np.stack([good, good]), [0.1])
    with pytest.raises(InputError, match="negative"):
        extract_sg(-np.stack([good, good]), [0.1, 0.2])
    with pytest.raises(InputError, match="NaN"):
        extract_sg(np.stack([good * np.nan, good]), [0.1, 0.2])
    with pytest.raises(InputError, match="at least"):
        extract_sg(np.ones((1, 8, 8, 3)), [0.1])


def test_baseline_is_24_nonnegative_lobes():
    y = _exemplars(_sun_sky(), 32)
    res = fibonacci_nnls(y, ROUGH)
    _check_env(res.env, 24)
    assert 0 < res.rel_rmse_exemplars < 1


# -- exemplar directories and commands ---------------------------------------------------------


def test_cli_exemplars_then_extract(tmp_path, capsys):
    from ebr_mitsuba.cli import main

    out = tmp_path / "ex"
    assert (
        main(
            [
                "exemplars",
                "--env",
                "procedural:3",
                "--renderer",
                "fast",
                "--res",
                "32",
                "--spp",
                "16",
                "--out",
                str(out),
                "--json",
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out)
    assert summary["kind"] == "env" and (out / "exemplars.json").is_file()
    env_path = tmp_path / "env.json"
    assert main(["extract-sg", str(out), "--out", str(env_path), "--iters", "10", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary) == {"lobes", "iterations", "seconds", "rel_rmse_exemplars", "loss_history"}
    assert SGEnvironment.load(env_path).num_lobes == summary["lobes"]
    # errors: exit 2 with one line
    assert main(["extract-sg", str(tmp_path / "missing"), "--out", str(env_path)]) == 2
    assert main(["exemplars", "--env", "procedural:3", "--roughness", "0.1,2", "--out", str(out)]) == 2
    pt = tmp_path / "pt"
    assert main(["exemplars", "--point-light", "--renderer", "fast", "--res", "16", "--out", str(pt)]) == 0
    assert main(["extract-sg", str(pt), "--out", str(env_path)]) == 2


def test_exemplar_dir_with_mixed_sizes_is_refused(tmp_path):
    from ebr_mitsuba.exemplar.files import exemplar_file
    from ebr_mitsuba.extract import read_exemplars, write_exemplars
    from ebr_mitsuba.geometry import near_shot
    from ebr_mitsuba.imageio import write_exr

    d = write_exemplars(
        tmp_path / "ex",
        [np.ones((16, 16, 3)), np.ones((16, 16, 3))],
        [0.1, 0.5],
        "env",
        near_shot(False),
        {"name": "test"},
        None,
    )
    back = read_exemplars(d)
    assert back.images.shape == (2, 16, 16, 3) and back.shot.camera == near_shot(False).camera
    write_exr(d / exemplar_file(0.5), np.ones((20, 16, 3), np.float32))
    with pytest.raises(InputError, match="different sizes"):
        read_exemplars(d)


# -- acceptance (slow) ----------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 11])
def test_acceptance_procedural_128(seed):
    """Issue 4: ≤ 8 true lobes at 128²: exemplars within 2 %, held-out material within 5 %
    (references: 8 × 256-spp quadrature patterns, independent of the extraction's)."""
    from ebr_mitsuba.extract.evaluate import lighting_errors, quadrature_mean
    from ebr_mitsuba.procedural import make_environment

    env = make_environment(seed)
    assert env.num_lobes <= 8
    y = quadrature_mean(env, ROUGH, 128)
    res = extract_sg(y, ROUGH)
    _check_env(res.env)
    err = lighting_errors(res.env, env, ROUGH, 128, reference={"exemplars": y})
    assert err["exemplars"] < 0.02
    assert err["test"] < 0.05
