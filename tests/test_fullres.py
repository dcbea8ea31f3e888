"""Full-resolution estimation (issue 12): lighting once per capture, the cascade over the whole
working image (one pass or tiles) with each pixel's true geometry, the working-size policy,
progress on stderr, coarse-to-fine refinement with a time budget, and the fast paths beside their
references (region renders, the irradiance table, the lobe loop, FastNAFNet, bilinear upsampling).

The CLI tests run the shipped model's cascade (quick at 1.5× its grid) behind a fake
lighting stage (no SG extraction), so that they take seconds; one test runs the whole shipped
model on a capture above its grid and counts the lighting net's calls.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ebr_mitsuba.cli import main
from ebr_mitsuba.errors import InputError
from ebr_mitsuba.geometry import near_shot
from ebr_mitsuba.imageio import write_exr, write_png
from ebr_mitsuba.sgenv import SGEnvironment
from ebr_mitsuba.svbrdf import SVBRDF

ENV = SGEnvironment(
    np.array([[0.5, 0.3, 0.81], [0.0, 0.0, 1.0], [-0.6, 0.1, 0.79]]),
    np.array([60.0, 1.5, 12.0]),
    np.array([[8.0, 7.5, 7.0], [0.25, 0.3, 0.4], [1.0, 0.8, 0.6]]),
)


def _material(n: int, seed: int = 3) -> SVBRDF:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n] / n
    checks = ((np.floor(x * 6) + np.floor(y * 6)) % 2)[..., None]
    from ebr_mitsuba.imageio import resize_area

    blocks = 0.6 + 0.4 * resize_area(rng.random((7, 7, 1)).astype(np.float32), (n, n))
    diffuse = (0.55 * checks + 0.1 * (1 - checks)) * blocks * np.float32([1.0, 0.75, 0.5])
    slopes = 0.15 * np.sin(2 * np.pi * 3 * np.stack([x, y], -1))
    normal = np.concatenate([slopes, np.ones((n, n, 1))], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return SVBRDF(
        normal=normal.astype(np.float32),
        diffuse=diffuse.astype(np.float32),
        specular=np.full((n, n, 3), 0.05, np.float32),
        roughness=(0.3 + 0.3 * x).astype(np.float32),
    )


def _photos(n: int, seed: int = 3) -> dict[str, np.ndarray]:
    from ebr_mitsuba.render import render_numpy

    m = _material(n, seed)
    return {s.name: render_numpy(m, ENV, s) for s in (near_shot(True), near_shot(False))}


def _write_capture(folder: Path, n: int) -> dict[str, Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, img in _photos(n).items():
        paths[name] = folder / f"{name}.exr"
        write_exr(paths[name], img)
    return paths


def _estimate(args, capsys):
    code = main(["estimate", *[str(a) for a in args]])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


# -- the shipped model behind a fake lighting stage ----------------------------------------------------


@pytest.fixture(scope="module")
def shipped():
    from ebr_mitsuba.model.predict import load_predictor

    return load_predictor(None)


def _fake_lighting_predictor(shipped, calls: list):
    """The shipped model with ``predict_lighting`` → the true environment ``ENV`` and fixed
    exemplars (counted in ``calls``); the cascade's methods are the real ones."""
    from ebr_mitsuba.exemplar.images import env_exemplar_images, point_exemplar_images
    from ebr_mitsuba.exemplar.select import Selection
    from ebr_mitsuba.model.predict import ModelPredictor
    from ebr_mitsuba.model.predictor import Lighting, Prediction

    class FakeLighting(ModelPredictor):
        def predict_lighting(self, flash, noflash, far_flash=None, far_noflash=None, *, progress=None, **_):
            calls.append({"shape": flash.shape, "noflash": noflash is not None})
            g = self.grid
            assert flash.shape == (g, g, 3)
            rough = (0.4, 0.1, 0.9)
            env = None if noflash is None else ENV
            fo = flash if noflash is None else np.maximum(flash - noflash, 0)
            env_sel = (
                None
                if env is None
                else Selection(rough, {}, env_exemplar_images(env, rough, g, g, None, "sg", 1))
            )
            if progress is not None:
                progress(3, 3, "done")
            return Lighting(
                g,
                env,
                [],
                fo,
                None,
                {"env": env_sel, "point": Selection(rough, {}, point_exemplar_images(rough, g, g))},
            )

        def predict(self, flash, noflash, far_flash=None, far_noflash=None, **_):
            lighting = self.predict_lighting(flash, noflash)
            inputs = self.grid_pass_inputs(lighting, flash, noflash)
            maps = self.cascade_pass(inputs, lighting.env).maps.to_svbrdf(0)
            return Prediction(maps, lighting.env, [], lighting.flash_only, lighting.selection)

    return FakeLighting(shipped.bundle)


@pytest.fixture
def fake_lighting(monkeypatch, shipped):
    """``ebr estimate`` loads the shipped model behind the fake lighting stage (its calls)."""
    from ebr_mitsuba.estimate import pipeline

    calls: list = []
    fake = _fake_lighting_predictor(shipped, calls)
    monkeypatch.setattr(pipeline, "load_predictor", lambda checkpoint: fake)
    return calls


# -- working size, refusals, progress ----------------------------------------------------------------


def test_full_resolution_maps_one_lighting_pass_and_tiles(
    tmp_path, capsys, fake_lighting, monkeypatch, shipped
):
    """A capture 1.5× the model grid G: maps at that size, the lighting estimated once, at the grid, also when
    the cascade runs in tiles; stdout holds the JSON alone, stderr the stage lines and bars."""
    from ebr_mitsuba.estimate import fullres
    from ebr_mitsuba.imageio import read_exr

    g = shipped.grid
    n = g + g // 2
    paths = _write_capture(tmp_path / "cap", n)
    out = tmp_path / "est"
    code, stdout, err = _estimate(
        ["--flash", paths["flash"], "--noflash", paths["noflash"], "--out", out, "--json", "--no-flash-fit"],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout)  # nothing but the summary on stdout
    assert summary["resolution"] == n and summary["model_grid"] == g and summary["tiles"] == 1
    assert read_exr(out / "maps" / "diffuse.exr").shape == (n, n, 3)
    assert len(fake_lighting) == 1 and fake_lighting[0]["shape"] == (g, g, 3)
    for line in (
        f"estimating the lighting at the model grid {g}x{g}",
        f"estimating the maps at {n}x{n}",
        f"re-rendering the shots at {n}x{n}",
        f"writing {out}",
    ):
        assert line in err, err
    for bar in ("lighting:", "maps:", "re-render:", "outputs:"):
        assert bar in err, err
    assert {"lighting", "maps"} <= set(summary["timings"])
    one_pass = read_exr(out / "maps" / "diffuse.exr")

    fake_lighting.clear()
    monkeypatch.setattr(fullres, "PASS_MEMORY", fullres.pass_bytes(shipped.cascade, g * g))
    code, stdout, err = _estimate(
        ["--flash", paths["flash"], "--noflash", paths["noflash"], "--out", out, "--json", "--no-flash-fit"],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["tiles"] == 4 and 0 < summary["tile"] <= g and len(fake_lighting) == 1
    tiled = read_exr(out / "maps" / "diffuse.exr")
    # Tiles see the same inputs as the one pass (true geometry, one lighting, one flash scale): they
    # differ only through each network's receptive field and channel attention at the tile edges
    # (2.5 % with the earlier small model's 64² tiles of a 96² image; docs/bench/estimate.md measures 1024²).
    assert float(np.mean(np.abs(tiled - one_pass))) < 0.04 * float(np.mean(one_pass))


@pytest.mark.parametrize("shape", [(16, 16), (3, 1000), (31, 64)])
def test_too_small_images_are_refused(tmp_path, capsys, fake_lighting, shape):
    img = np.full(shape + (3,), 0.5, np.float32)
    write_exr(tmp_path / "f.exr", img)
    out = tmp_path / "out"
    code, stdout, err = _estimate(["--flash", tmp_path / "f.exr", "--out", out], capsys)
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith("ebr estimate: error:") and "at least 32 pixels" in lines[0]
    assert f"{shape[1]}x{shape[0]}" in lines[0]
    assert not out.exists() and not fake_lighting


def test_large_image_is_downscaled_with_a_warning(tmp_path, capsys, fake_lighting, shipped):
    """A flash-only photo of 2.5 model grids with --max-size 1.25 grids: estimated at the limit, the
    warning names both sizes."""
    g = shipped.grid
    big, limit = 2 * g + g // 2, g + g // 4
    photo = _photos(big)["flash"]
    write_png(tmp_path / "photo.png", photo / float(photo.max()) * 0.9)
    out = tmp_path / "est"
    code, stdout, err = _estimate(
        ["--flash", tmp_path / "photo.png", "--out", out, "--max-size", str(limit), "--json"], capsys
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["resolution"] == limit and summary["inputs"]["size"] == [big, big]
    needle = f"the photos are {big}x{big} pixels: estimating at {limit}x{limit}"
    assert needle in err and any(needle in w for w in summary["warnings"])
    assert f"--max-size {limit}" in err
    assert len(fake_lighting) == 1 and not fake_lighting[0]["noflash"]


def test_working_size_policy():
    from ebr_mitsuba.estimate.resample import MIN_INPUT_SIZE, working_size

    assert MIN_INPUT_SIZE == 32
    assert working_size(40, 64) == 64  # below the grid: up to the grid
    assert working_size(1000, 64) == 1000
    assert working_size(4096, 64) == 2048  # above the default limit: the limit
    assert working_size(4096, 64, 4096) == 4096
    with pytest.raises(InputError, match="below the model grid"):
        working_size(100, 64, 32)


# -- the full-resolution inputs and the tiling -------------------------------------------------------


def test_tile_plan_covers_with_the_fewest_tiles():
    from ebr_mitsuba.estimate.fullres import TILE_MULTIPLE, tile_plan

    for n, max_side, overlap in ((2048, 1100, 32), (96, 64, 32), (1000, 300, 16), (513, 512, 32)):
        side, starts = tile_plan(n, max_side, overlap)
        assert side <= max(max_side, TILE_MULTIPLE) and side % TILE_MULTIPLE == 0
        covered = np.zeros(n, bool)
        for s in starts:
            covered[s : s + side] = True
        assert covered.all() and starts[-1] == n - side
        assert all(b - a <= side - overlap for a, b in zip(starts, starts[1:]))
        assert len(starts) == int(
            np.ceil((n - overlap) / (max_side // TILE_MULTIPLE * TILE_MULTIPLE - overlap))
        )
    assert tile_plan(2048, 1100, 32) == (1040, [0, 1008])
    assert tile_plan(300, 512) == (300, [0])


def test_full_pass_inputs_at_the_grid_size_are_the_grid_inputs():
    """At N = G the full-resolution inputs are exactly the grid pass's (exemplars, flash-only)."""
    from ebr_mitsuba.estimate.fullres import (
        detail_merge,
        env_exemplars_at,
        full_pass_inputs,
        point_exemplars_at,
    )
    from ebr_mitsuba.exemplar.images import env_exemplar_images, point_exemplar_images
    from ebr_mitsuba.exemplar.select import Selection
    from ebr_mitsuba.imageio import resize_area
    from ebr_mitsuba.model.predictor import Lighting

    g = 32
    photos = _photos(g)
    rough = (0.4, 0.1, 0.9)
    grid_env = env_exemplar_images(ENV, rough, g, g, None, "quadrature", 64)
    lighting = Lighting(
        g,
        ENV,
        [],
        np.maximum(photos["flash"] - photos["noflash"], 0),
        None,
        {
            "env": Selection(rough, {}, grid_env),
            "point": Selection(rough, {}, point_exemplar_images(rough, g, g)),
        },
    )
    inp = full_pass_inputs(lighting, photos, 2)
    np.testing.assert_array_equal(inp.env_exemplars, grid_env)
    np.testing.assert_array_equal(inp.flash_only, lighting.flash_only)
    # At 2G: the closed-form render at 2G with the grid's (quadrature) low frequencies.
    big = env_exemplars_at(ENV, rough, grid_env, 2 * g)
    for k in range(3):
        low = resize_area(big[k], (g, g))
        assert np.sqrt(np.mean((low - grid_env[k]) ** 2)) < 0.03 * np.sqrt(np.mean(grid_env[k] ** 2))
    np.testing.assert_allclose(
        point_exemplars_at(rough, 2 * g), point_exemplar_images(rough, 2 * g, 2 * g), rtol=1e-6, atol=1e-7
    )
    # detail_merge: the low image's averages, the high image's detail.
    rng = np.random.default_rng(0)
    high = rng.random((64, 64, 3)).astype(np.float32)
    low = resize_area(high, (16, 16)) + 0.1
    merged = detail_merge(low, high)
    np.testing.assert_allclose(resize_area(merged, (16, 16)), low, atol=0.02)


def test_cascade_window_renders_are_crops_of_the_full_render():
    """The cascade's renders of a window (a tile) equal the crops of the full-grid renders."""
    import torch

    from ebr_mitsuba.model.renders import diffuse_flash_renderer, photo_renderer
    from ebr_mitsuba.nets import Maps
    from ebr_mitsuba.nets.drwrap import lobes_from_env
    from ebr_mitsuba.render import RenderOptions

    n = 40
    m = Maps.from_svbrdf([_material(n)])
    sub = Maps.from_svbrdf([_crop(_material(n), 8, 4, 24, 32)])
    lobes = [lobes_from_env(ENV)]
    opts = RenderOptions(irradiance_table=32, lobe_loop=True)
    fo = torch.ones(1, 3, n, n)
    full = photo_renderer(lobes, fo, scales=(7.0, None), window=(0, 0, n, n), options=opts)(m)
    part = photo_renderer(lobes, fo[..., 8:32, 4:36], scales=(7.0, None), window=(8, 4, n, n), options=opts)(
        sub
    )
    torch.testing.assert_close(part, full[..., 8:32, 4:36], rtol=1e-5, atol=1e-6)
    # The Dr.Jit diffuse flash render of a window = the torch mirror's full render, cropped.
    ref = diffuse_flash_renderer(10.0)(m.normal, m.diffuse)
    win = diffuse_flash_renderer(10.0, (8, 4, n, n), opts)(sub.normal, sub.diffuse)
    torch.testing.assert_close(win, ref[..., 8:32, 4:36], rtol=1e-5, atol=1e-6)
    # Without a window the renderers are the training ones (fitted flash scale, torch flash term).
    with pytest.raises(InputError, match="needs the capture's flash scales"):
        photo_renderer(lobes, fo, window=(0, 0, n, n))


def _crop(m: SVBRDF, r: int, c: int, h: int, w: int) -> SVBRDF:
    sl = (slice(r, r + h), slice(c, c + w))
    return SVBRDF(m.normal[sl], m.diffuse[sl], m.specular[sl], m.roughness[sl])


# -- the fast paths beside their references ---------------------------------------------------------


@pytest.mark.parametrize("mode", ["sg", "quadrature"])
def test_render_window_and_shared_shots(mode):
    from ebr_mitsuba.render import DrLobes, DrMaps, RenderOptions, render, render_numpy, render_shots

    n = 36
    m = _material(n)
    full = render_numpy(m, ENV, near_shot(True), mode=mode, spp=8)
    win = render_numpy(_crop(m, 5, 9, 20, 24), ENV, near_shot(True), mode=mode, spp=8, window=(5, 9, n, n))
    np.testing.assert_allclose(win, full[5:25, 9:33], rtol=1e-5, atol=1e-7)
    with pytest.raises(InputError, match="does not fit"):
        render_numpy(_crop(m, 0, 0, 20, 24), ENV, near_shot(True), window=(20, 0, n, n))
    opts = RenderOptions(mode=mode, spp=8)
    dm, lb = DrMaps.from_numpy(m), DrLobes.from_env(ENV)
    shots = [near_shot(True), near_shot(False)]
    for shot, img in zip(shots, render_shots(dm, lb, shots, opts)):
        np.testing.assert_allclose(img.numpy(), render(dm, lb, shot, opts).numpy(), rtol=1e-6, atol=1e-7)


def test_irradiance_table_and_lobe_loop_match_the_pair_kernel():
    import drjit as dr

    from ebr_mitsuba.render import DrLobes, DrMaps, RenderOptions, render

    n = 32
    rng = np.random.default_rng(4)
    normal = np.concatenate([rng.normal(0, 0.5, (n, n, 2)), np.ones((n, n, 1))], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)  # up to ~75° from +z
    m = SVBRDF(
        normal.astype(np.float32),
        rng.uniform(0.1, 0.8, (n, n, 3)).astype(np.float32),
        rng.uniform(0.02, 0.4, (n, n, 3)).astype(np.float32),
        rng.uniform(0.05, 0.9, (n, n)).astype(np.float32),
    )
    results = {}
    for key in ((False, 0), (True, 0), (False, 64), (True, 64)):
        dm, lb = DrMaps.from_numpy(m), DrLobes.from_env(ENV)
        for t in (dm.roughness, dm.normal, lb.amplitude):
            dr.enable_grad(t)
        img = render(dm, lb, near_shot(False), RenderOptions(lobe_loop=key[0], irradiance_table=key[1]))
        dr.backward(dr.sum(dr.ravel(img * img)))
        results[key] = [
            img.numpy(),
            dr.grad(dm.roughness).numpy(),
            dr.grad(dm.normal).numpy(),
            dr.grad(lb.amplitude).numpy(),
        ]
    for table in (0, 64):  # the loop: the same values and gradients as the pair kernel
        for a, b in zip(results[(False, table)], results[(True, table)]):
            np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-6 * float(np.abs(a).max()))
    exact, tab = results[(False, 0)][0], results[(False, 64)][0]
    assert np.sqrt(np.mean((tab - exact) ** 2)) < 1e-3 * np.sqrt(np.mean(exact**2))


def test_fast_nafnet_matches_the_module_and_counts_multiply_adds():
    import torch

    from ebr_mitsuba.estimate.fastnet import FastNAFNet, multiply_adds
    from ebr_mitsuba.nets.nafnet import NAFNet, NAFNetSize

    torch.manual_seed(0)
    net = NAFNet(
        5, 4, NAFNetSize(width=12, enc_blk_nums=(1, 2), middle_blk_num=2, dec_blk_nums=(2, 1))
    ).eval()
    for p in net.parameters():  # non-trivial β, γ, LayerNorm affine and biases
        torch.nn.init.normal_(p, 0, 0.3)
    x = torch.randn(2, 5, 33, 47)
    with torch.no_grad():
        ref = net(x)
    np.testing.assert_allclose(
        FastNAFNet(net)(x).numpy(), ref.numpy(), rtol=1e-4, atol=1e-4 * float(ref.abs().max())
    )
    conv = torch.nn.Conv2d(3, 8, 3, padding=1)
    assert multiply_adds(conv, torch.zeros(1, 3, 10, 12)) == 8 * 3 * 9 * 10 * 12
    assert multiply_adds(torch.nn.Conv2d(6, 6, 3, padding=1, groups=6), torch.zeros(1, 6, 4, 4)) == 6 * 9 * 16


def test_upsample_bilinear_matches_the_reference(rng):
    from ebr_mitsuba.estimate.tiling import ramp, tile_starts
    from ebr_mitsuba.imageio import upsample_bilinear, upsample_bilinear_fast

    x = rng.random((13, 17, 3))
    np.testing.assert_allclose(upsample_bilinear_fast(x, (50, 41)), upsample_bilinear(x, (50, 41)), atol=1e-6)
    np.testing.assert_allclose(
        upsample_bilinear_fast(x[..., 0], (26, 34)), upsample_bilinear(x[..., 0], (26, 34)), atol=1e-6
    )
    assert (
        tile_starts(64, 64, 8) == [0]
        and ramp(64, 16).min() > 0
        and ramp(64, 16)[16:48].tolist() == [1.0] * 32
    )


# -- refinement: coarse to fine, time budget ---------------------------------------------------------


def _refine_case(n: int):
    from ebr_mitsuba.estimate.refine import ShotTarget

    truth = _material(n)
    photos = {s.name: p for s, p in zip((near_shot(True), near_shot(False)), _photos(n).values())}
    targets = [
        ShotTarget(s, photos[s.name], np.ones((n, n), bool)) for s in (near_shot(True), near_shot(False))
    ]
    start = SVBRDF(
        normal=truth.normal,
        diffuse=np.clip(truth.diffuse * 0.6 + 0.1, 0, 1),
        specular=np.full((n, n, 3), 0.2, np.float32),
        roughness=np.full((n, n), 0.7, np.float32),
    )
    return truth, targets, start


def test_level_schedule():
    from ebr_mitsuba.estimate.refine import level_sizes, level_steps

    assert level_sizes(1024, 128) == [256, 512, 1024]
    assert level_sizes(256, 128) == [256] and level_sizes(2048, 128) == [256, 512, 1024, 2048]
    assert level_sizes(100, 16) == [25, 50, 100]
    assert level_steps(200, 3, 2.0) == [114, 57, 29] and sum(level_steps(7, 3, 2.0)) == 7
    assert min(level_steps(3, 3, 4.0)) == 1 and level_steps(50, 1, 2.0) == [50]


def test_coarse_to_fine_is_at_least_as_good_as_one_level():
    """64² with levels 32² → 64² against one level at 64², the same 40 steps: a re-render error
    and a full-size loss no worse (and cheaper steps)."""
    from ebr_mitsuba.estimate.refine import RefineConfig, refine

    truth, targets, start = _refine_case(64)
    one = refine(start, ENV, targets, RefineConfig(steps=40, coarse_size=64))
    c2f = refine(start, ENV, targets, RefineConfig(steps=40, coarse_size=16))
    assert len(one.levels) == 1 and [lv["size"] for lv in c2f.levels] == [32, 64]
    assert c2f.after["mean"]["rmse"] <= 1.02 * one.after["mean"]["rmse"]
    assert c2f.history[-1][1] <= 1.02 * one.history[-1][1]
    assert c2f.after["mean"]["rmse"] < 0.6 * c2f.before["mean"]["rmse"]
    assert c2f.kept_step == 40 and not c2f.loss_rose and c2f.history[0][0] == 0
    err = lambda m: float(np.sqrt(np.mean((m.diffuse - truth.diffuse) ** 2)))  # noqa: E731
    assert err(c2f.maps) < err(start)


def test_refinement_time_budget_stops_with_a_note(tmp_path, capsys, fake_lighting):
    import time

    from ebr_mitsuba.estimate.refine import RefineConfig, refine

    _, targets, start = _refine_case(48)
    refine(start, ENV, targets, RefineConfig(steps=3, coarse_size=8))  # compile the kernels first
    t0 = time.perf_counter()
    res = refine(start, ENV, targets, RefineConfig(steps=100000, coarse_size=8, seconds=1.5))
    took = time.perf_counter() - t0
    assert res.stopped and res.steps_run < 100000 and took < 1.5 + 3.0
    assert res.budget_note().startswith("stopped by the time budget of 1.5 s after ")
    assert res.after["mean"]["rmse"] <= res.before["mean"]["rmse"] * (1 + 1e-6)
    # Through the command: the note on stderr and in the summary.
    paths = _write_capture(tmp_path / "cap", 96)
    code, stdout, err = _estimate(
        [
            "--flash",
            paths["flash"],
            "--noflash",
            paths["noflash"],
            "--out",
            tmp_path / "est",
            "--refine-steps",
            "100000",
            "--refine-seconds",
            "2",
            "--flash-intensity",
            "10",
            "--json",
        ],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["refine"]["stopped"] and "stopped by the time budget of 2 s" in err
    assert 0 < summary["refine"]["steps_run"] < 100000  # stopped by the budget, not by the step count
    code, _, err = _estimate(
        ["--flash", paths["flash"], "--out", tmp_path / "x", "--refine-seconds", "2"], capsys
    )
    assert code == 2 and "--refine-seconds needs --refine-steps" in err


def test_real_model_lighting_runs_once_above_the_grid(tmp_path, monkeypatch):
    """The shipped model on a capture 1.5× its grid in forced tiles: one lighting-net forward, and the
    cascade's three networks once at the grid and once per tile."""
    from ebr_mitsuba.estimate import fullres
    from ebr_mitsuba.estimate.pipeline import EstimateConfig, run_estimate
    from ebr_mitsuba.model.predict import load_predictor

    predictor = load_predictor(None)
    calls = {"lighting": 0}
    predictor.bundle.lighting.register_forward_hook(
        lambda *a: calls.__setitem__("lighting", calls["lighting"] + 1)
    )
    g = predictor.grid
    monkeypatch.setattr(fullres, "PASS_MEMORY", fullres.pass_bytes(predictor.cascade, g * g))
    paths = _write_capture(tmp_path / "cap", g + g // 2)
    summary = run_estimate(
        EstimateConfig(flash=str(paths["flash"]), noflash=str(paths["noflash"]), out=str(tmp_path / "est")),
        predictor=predictor,
    )
    assert calls["lighting"] == 1
    assert summary["resolution"] == g + g // 2 and summary["tiles"] == 4
    assert summary["lobes"] > 0 and np.isfinite(summary["rerender_error"]["network"]["mean"]["rmse"])


def test_bench_page_states_the_peak_and_the_acceptance():
    """``ebr bench estimate``'s page from synthetic measurements: the peak's derivation, a table
    row per run, the acceptance lines with pass/fail, and the progress check."""
    from ebr_mitsuba.bench import estimate as bench

    isa = bench.isa_peak()
    assert isa["flops"] == isa["cores"] * isa["clock_ghz"] * 1e9 * isa["flops_per_cycle"]

    def run(size, refine, wall, stderr="lighting: maps: outputs: re-render:"):
        timings = {
            "inputs": 0.1,
            "model": 2.0,
            "lighting": 3.0,
            "maps": wall / 3,
            "outputs": 1.5,
            "report": 0.2,
        }
        if refine:
            timings["refine"] = 50.0
        summary = {
            "timings": timings,
            "total_seconds": wall - 1,
            "tiles": 1,
            "tile": size,
            "ensemble": [size],
            "prediction_timings": {},
            "rerender_error": {"network": {"mean": {"rmse": 0.03}}, "refined": {"mean": {"rmse": 0.02}}},
            "refine": {"levels": [{"size": size, "run": 200}], "seconds": 50.0} if refine else None,
        }
        if refine:
            stderr += " refine:"
        return {
            "code": 0,
            "wall": wall,
            "rss": 1.2e9,
            "summary": summary,
            "stderr": stderr,
            "load": (1.0, 1.2),
        }

    runs = {
        (1024, False): run(1024, False, 14.0),
        (1024, True): run(1024, True, 70.0),
        (2048, False): run(2048, False, 61.0),
        (256, False): run(256, False, 9.0, stderr=""),
    }
    errors = {
        (256, False): {"normal": 0.08, "diffuse": 0.07, "specular": 0.01, "roughness": 0.3, "mean": 0.115},
        (1024, False): {"normal": 0.08, "diffuse": 0.06, "specular": 0.01, "roughness": 0.3, "mean": 0.112},
    }
    flops = [
        {
            "net": "diffuse net",
            "width": 8,
            "macs_per_mp": 6.5e9,
            "flops_per_mp": 1.3e10,
            "seconds_per_mp": 1.0,
        }
    ]
    page = bench.markdown(
        bench.FULL,
        runs,
        errors,
        None,
        None,
        None,
        flops,
        {"isa": isa, "gemm": 1e11},
        [],
        None,
        64,
        30.0,
        600.0,
        False,
    )
    assert "| 1024² maps without refinement ≤ 15 s | 14.0 s | **pass** |" in page
    assert "| 2048² maps without refinement ≤ 60 s | 61.0 s | **FAIL** |" in page
    assert "| 200 refinement steps at 1024² ≤ 120 s | 50.0 s | **pass** |" in page
    assert "mean 0.1120 vs 0.1150 | **pass** |" in page
    assert f"{isa['flops_per_cycle']} float32 FLOPs per cycle" in page and "GFLOP/s" in page
    assert "missing: model, lighting, maps, outputs" in page  # the 256² run showed no bars
    assert bench.progress_shown(runs[(1024, True)]["summary"], runs[(1024, True)]["stderr"]) == {
        "model": False,
        "lighting": True,
        "maps": True,
        "outputs": True,
        "refine": True,
    }


def test_refinement_levels_above_the_memory_budget_are_carried(monkeypatch):
    """With the budget below a 64² level, a 64² refinement runs at 32² only and carries the change
    to 64²: maps of the working size, no worse than the network's (the loss at 64² decides)."""
    from ebr_mitsuba.estimate import refine as rf

    truth, targets, start = _refine_case(64)
    monkeypatch.setattr(rf, "REFINE_MEMORY", 40 * 40 * rf.REFINE_BYTES_PER_PIXEL)
    res = rf.refine(start, ENV, targets, rf.RefineConfig(steps=30, coarse_size=16))
    assert [lv["size"] for lv in res.levels] == [32] and res.maps.shape == (64, 64)
    assert res.kept_step == 30 and not res.loss_rose and res.history[0][0] == 0
    assert res.history[-1][1] < res.history[0][1]  # both at 64²: the carried change lowered the loss
    assert res.after["mean"]["rmse"] < res.before["mean"]["rmse"]
