"""Scene builders and Mitsuba captures: the pixel ↔ surface mapping of docs/conventions.md, the flash
decomposition flash − noflash = flash-only, and the files and metadata each setup writes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ebr_mitsuba import SVBRDF, SGEnvironment
from ebr_mitsuba.capture import CAPTURE_FORMAT, capture, render_flash_only, render_shot, shot_seed
from ebr_mitsuba.errors import InputError
from ebr_mitsuba.geometry import NEAR_DISTANCE, pixel_positions, setup_shots
from ebr_mitsuba.scene import sg_emitter_dict

RES = 16


@pytest.fixture(scope="module")
def default_env() -> SGEnvironment:
    from importlib.resources import files

    return SGEnvironment.load(str(files("ebr_mitsuba.scenes") / "default_env.json"))


def _flat(diffuse, specular=0.0, roughness=0.5) -> SVBRDF:
    h, w = np.shape(diffuse)[:2]
    return SVBRDF(
        normal=np.tile(np.float32([0, 0, 1]), (h, w, 1)),
        diffuse=diffuse,
        specular=np.broadcast_to(np.float32(specular), (h, w, 3)).copy(),
        roughness=np.broadcast_to(np.float32(roughness), (h, w)).copy(),
    )


def _textured(rng, size) -> SVBRDF:
    """A spatially varying material with tilted normals, for the decomposition test."""
    slope = rng.uniform(-0.3, 0.3, (size, size, 2))
    normal = np.concatenate([slope, np.ones((size, size, 1))], axis=-1)
    return SVBRDF(
        normal=normal,
        diffuse=rng.uniform(0.05, 0.8, (size, size, 3)),
        specular=rng.uniform(0.02, 0.3, (size, size, 3)),
        roughness=rng.uniform(0.15, 0.8, (size, size)),
    )


# -- pixel ↔ surface mapping -----------------------------------------------------------------


def test_bright_quadrant_lands_where_design_says():
    """A diffuse map bright only in its top-left quadrant (rows < H/2, columns < W/2), lit by the
    flash alone: exactly the pixels that see x < 0, y > 0 are bright."""
    diffuse = np.full((RES, RES, 3), 0.02, np.float32)
    diffuse[: RES // 2, : RES // 2] = 0.9
    flash = setup_shots("near")[0]
    image = render_flash_only(_flat(diffuse), flash, spp=16, seed=1)
    pos = pixel_positions(RES, RES)
    expect_bright = (pos[..., 0] < 0) & (pos[..., 1] > 0)
    bright = image[..., 1] > 0.1  # bright texels give ≈ 0.9/π·I·cos/r² ≥ 0.3, dark ones ≤ 0.02
    np.testing.assert_array_equal(bright, expect_bright)


def test_each_pixel_sees_exactly_its_texel(rng):
    """With the box filter and nearest-texel maps at equal resolution, pixel (i, j) integrates
    texel (i, j) only: the ratio to a white render with the same seed (same sample positions)
    is the texel value to float precision. Flash-only with specular 0: camera and light coincide,
    so v·h = 1 and Schlick's F = 0; the image is purely diffuse."""
    diffuse = rng.uniform(0.2, 1.0, (RES, RES, 3)).astype(np.float32)
    flash = setup_shots("near")[0]
    textured = render_flash_only(_flat(diffuse), flash, spp=16, seed=3)
    white = render_flash_only(_flat(np.ones((RES, RES, 3), np.float32)), flash, spp=16, seed=3)
    np.testing.assert_allclose(textured / white, diffuse, rtol=1e-5, atol=0)


def test_flash_only_radiance_is_inverse_square_lambertian():
    """White diffuse (d = 1) under the near flash: each pixel is the footprint mean of
    I/π · cosθ/r² = I/π · z/r³ (exact integral by a 64×64 midpoint rule per pixel).
    Noise: only the pixel-position jitter (delta light); at 256 spp the measured worst pixel was
    0.23% and the image mean 1e-4 off, so the tolerances are 1% per pixel and 1e-3 on the mean."""
    flash = setup_shots("near")[0]
    image = render_flash_only(_flat(np.ones((RES, RES, 3), np.float32)), flash, spp=256, seed=5)
    n = 64
    i, j = np.meshgrid(np.arange(RES * n), np.arange(RES * n), indexing="ij")
    x = -1 + (2 * j + 1) / (RES * n)
    y = 1 - (2 * i + 1) / (RES * n)
    z = NEAR_DISTANCE
    fine = flash.flash_intensity / math.pi * z / (x * x + y * y + z * z) ** 1.5
    expected = fine.reshape(RES, n, RES, n).mean(axis=(1, 3))
    rel = image / expected[..., None] - 1
    assert np.abs(rel).max() < 1e-2
    assert abs(rel.mean()) < 1e-3


# -- flash − noflash = flash-only -------------------------------------------------------------


def test_flash_minus_noflash_is_flash_only(rng, default_env):
    """r = flash − noflash − flashonly has zero mean; its spread is Monte-Carlo noise.

    Tolerance from measured noise: each image is rendered twice with different seeds and its
    per-pixel noise variance estimated as mean((a₁ − a₂)²)/2; the three images are independent,
    so E[r²] = v_flash + v_noflash + v_flashonly. We require mean(r²) < 1.5·that (measured ratio
    0.91–0.99) and |mean(r)| < 4 standard errors sqrt(Σv/N). A flash intensity 5% off shifts
    mean(r) by ≈ 0.02, about 10 standard errors here, so the test detects it."""
    material = _textured(rng, RES)
    env = sg_emitter_dict(default_env)
    flash, noflash = setup_shots("near")
    spp = 64
    renders = {}
    for rep in (1, 2):
        renders["flash", rep] = render_shot(material, env, flash, spp, seed=10 + rep)
        renders["noflash", rep] = render_shot(material, env, noflash, spp, seed=20 + rep)
        renders["only", rep] = render_flash_only(material, flash, spp, seed=30 + rep)
    var = {k: float(np.mean((renders[k, 1] - renders[k, 2]) ** 2) / 2) for k in ("flash", "noflash", "only")}
    total = sum(var.values())
    assert renders["noflash", 1].mean() > 0.05 and renders["only", 1].mean() > 0.05  # both terms matter
    for rep in (1, 2):
        r = renders["flash", rep] - renders["noflash", rep] - renders["only", rep]
        assert np.mean(r**2) < 1.5 * total
        assert abs(r.mean()) < 4 * math.sqrt(total / r.size)


def test_flash_only_needs_a_flash():
    with pytest.raises(InputError, match="no flash"):
        render_flash_only(_flat(np.ones((4, 4, 3), np.float32)), setup_shots("near")[1], spp=1)


# -- capture directories --------------------------------------------------------------------------

EXPECTED_FILES = {
    "near": ["flash.exr", "noflash.exr"],
    "near-far": ["flash.exr", "noflash.exr", "far_flash.exr", "far_noflash.exr"],
    "five-light": [f"light{k}.exr" for k in range(5)],
    "multi-view": [f"view{a}{b}_flash.exr" for a in range(3) for b in range(3)] + ["noflash.exr"],
}


@pytest.mark.parametrize("setup", list(EXPECTED_FILES))
def test_capture_writes_setup(tmp_path, setup, rng, default_env):
    from ebr_mitsuba.imageio import read_exr
    from ebr_mitsuba.materials import load_material_dir

    material = _textured(rng, RES)
    out = tmp_path / "cap"
    meta = capture(material, default_env, setup, out, spp=4, res=RES, seed=7, progress=False)
    names = EXPECTED_FILES[setup]
    assert sorted(p.name for p in out.iterdir()) == sorted(names + ["capture.json", "env.json", "maps"])
    on_disk = json.loads((out / "capture.json").read_text())
    assert on_disk == meta
    assert meta["format"] == CAPTURE_FORMAT and meta["setup"] == setup
    assert meta["resolution"] == [RES, RES] and meta["spp"] == 4 and meta["seed"] == 7
    assert meta["renderer"]["variant"].endswith("_rgb") and "mitsuba" in meta["renderer"]
    assert meta["integrator"]["type"] == "direct" and meta["reconstruction_filter"] == "box"
    assert meta["env"]["file"] == "env.json" and meta["env"]["lobes"] == default_env.num_lobes
    assert [s["file"] for s in meta["shots"]] == names
    for k, shot in enumerate(meta["shots"]):
        assert shot["seed"] == shot_seed(7, k)
        image = read_exr(out / shot["file"])
        assert image.shape == (RES, RES, 3) and np.all(np.isfinite(image)) and image.max() > 0
    # Ground truth: the maps exactly as rendered, and the environment.
    maps = load_material_dir(out / "maps")
    np.testing.assert_allclose(maps.diffuse, material.diffuse, atol=1e-6)
    np.testing.assert_allclose(maps.normal, material.normal, atol=1e-6)
    np.testing.assert_allclose(maps.roughness, material.roughness, atol=1e-6)
    env = SGEnvironment.load(out / "env.json")
    np.testing.assert_allclose(env.amplitude, default_env.amplitude)

    shots = {s["name"]: s for s in meta["shots"]}
    if setup == "five-light":
        assert all(not s["env"] and s["flash"] is not None for s in shots.values())
        assert {tuple(s["flash"]) for s in shots.values()} == {tuple(s.flash) for s in setup_shots(setup)}
    if setup == "near-far":
        assert shots["far_flash"]["camera"] == [0.0, 0.0, 10.0]
        assert shots["far_noflash"]["flash"] is None and shots["far_noflash"]["env"]
        # Same irradiance from the flash at the sample centre, near and far (inverse square).
        near_i, far_i = shots["flash"]["flash_intensity"], shots["far_flash"]["flash_intensity"]
        assert far_i / 10.0**2 == pytest.approx(near_i / NEAR_DISTANCE**2)
    if setup == "multi-view":
        assert shots["view11_flash"]["in_sample_grid"]
        assert not shots["view00_flash"]["in_sample_grid"]
        # Oblique views see past the sample edge; emitters are hidden, so those pixels are black.
        assert np.any(read_exr(out / "view00_flash.exr").sum(-1) == 0)
        assert np.all(read_exr(out / "view11_flash.exr").sum(-1) > 0)
        # the centre camera without its flash: the near setup's no-flash shot, lit by the environment
        assert shots["noflash"]["flash"] is None and shots["noflash"]["env"]
        assert (
            shots["noflash"]["camera"] == shots["view11_flash"]["camera"]
            and shots["noflash"]["in_sample_grid"]
        )
        flash_only = read_exr(out / "view11_flash.exr") - read_exr(out / "noflash.exr")
        assert flash_only.mean() > 0


def test_five_light_ignores_environment(tmp_path, rng, default_env):
    """Five-light shots are rendered with the environment off: identical with and without it."""
    material = _textured(rng, 8)
    a = capture(material, default_env, "five-light", tmp_path / "a", spp=2, res=8, seed=1, progress=False)
    b = capture(material, None, "five-light", tmp_path / "b", spp=2, res=8, seed=1, progress=False)
    from ebr_mitsuba.imageio import read_exr

    for shot in a["shots"]:
        np.testing.assert_array_equal(
            read_exr(tmp_path / "a" / shot["file"]), read_exr(tmp_path / "b" / shot["file"])
        )
    assert b["env"] is None and not (tmp_path / "b" / "env.json").exists()


def test_capture_is_deterministic(tmp_path, rng, default_env):
    from ebr_mitsuba.imageio import read_exr

    material = _textured(rng, 8)
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        capture(material, default_env, "near", tmp_path / name, spp=2, res=8, seed=seed, progress=False)
    a, b, c = (read_exr(tmp_path / n / "noflash.exr") for n in "abc")
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_capture_failure_leaves_nothing(tmp_path, rng, default_env, monkeypatch):
    """An error in the middle of a capture (second shot) leaves no output and no temporary dir."""
    import ebr_mitsuba.capture as cap

    calls = []
    real = cap.render_shot

    def failing(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("simulated renderer failure")
        return real(*args, **kwargs)

    monkeypatch.setattr(cap, "render_shot", failing)
    with pytest.raises(RuntimeError, match="simulated"):
        cap.capture(_textured(rng, 8), default_env, "near", tmp_path / "cap", spp=1, res=8, progress=False)
    assert list(tmp_path.iterdir()) == []


def test_capture_replaces_only_capture_dirs(tmp_path, rng, default_env):
    material = _textured(rng, 8)
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(InputError, match="not a capture directory"):
        capture(material, default_env, "near", other, spp=1, res=8, progress=False)
    assert (other / "keep.txt").read_text() == "mine"
    out = tmp_path / "cap"
    capture(material, default_env, "near", out, spp=1, res=8, progress=False)
    capture(material, default_env, "near-far", out, spp=1, res=8, progress=False)  # replaces it
    assert (out / "far_flash.exr").is_file()


def test_capture_rejects_material_of_other_size(tmp_path, rng, default_env):
    with pytest.raises(InputError, match="8x8"):
        capture(_textured(rng, 8), default_env, "near", tmp_path / "cap", spp=1, res=16, progress=False)
    assert not (tmp_path / "cap").exists()


def test_path_integrator_matches_direct(rng, default_env):
    """``path`` with max_depth 2 and ``direct`` have the same expectation on a plane: their
    image means agree within 4 standard errors of the difference (noise from repeated seeds)."""
    material = _textured(rng, RES)
    env = sg_emitter_dict(default_env)
    shot = setup_shots("near")[0]
    d = [render_shot(material, env, shot, 32, seed=s, integrator="direct") for s in (1, 2)]
    p = [render_shot(material, env, shot, 32, seed=s, integrator="path") for s in (3, 4)]
    var_d = np.mean((d[0] - d[1]) ** 2) / 2
    var_p = np.mean((p[0] - p[1]) ** 2) / 2
    stderr = math.sqrt((var_d + var_p) / d[0].size)
    assert abs(d[0].mean() - p[0].mean()) < 4 * stderr


def test_equirect_environment_capture(tmp_path, rng):
    """An equirectangular .exr environment renders and is identified by path and SHA-256."""
    from ebr_mitsuba.envmap import sg_to_equirect
    from ebr_mitsuba.imageio import write_exr
    from ebr_mitsuba.sources import file_sha256

    sky = SGEnvironment(np.array([[0.0, 0.0, 1.0]]), np.array([2.0]), np.array([[1.0, 1.0, 1.0]]))
    path = tmp_path / "sky.exr"
    write_exr(path, sg_to_equirect(sky, 16, 32))
    meta = capture(_textured(rng, 8), str(path), "near", tmp_path / "cap", spp=2, res=8, progress=False)
    assert meta["env"]["kind"] == "equirect" and meta["env"]["sha256"] == file_sha256(path)
    assert not (tmp_path / "cap" / "env.json").exists()


def test_shot_seeds_differ_and_are_stable():
    seeds = [shot_seed(0, k) for k in range(9)]
    assert len(set(seeds)) == 9 and seeds == [shot_seed(0, k) for k in range(9)]
    assert shot_seed(1, 0) != shot_seed(0, 0)


# -- bundled XML scenes against the scene-dict builders ---------------------------------------------


def _checkerboard_material(res: int, checks: int = 4) -> SVBRDF:
    """The material of the bundled near/far scenes as maps: Mitsuba's checkerboard gives color0
    where frac(checks·u) < ½ and frac(checks·v) < ½ agree, with u = (x+1)/2, v = (y+1)/2."""
    pos = pixel_positions(res, res)
    u, v = (pos[..., 0] + 1) / 2, (pos[..., 1] + 1) / 2
    same = (np.mod(checks * u, 1) < 0.5) == (np.mod(checks * v, 1) < 0.5)
    diffuse = np.where(same[..., None], np.float32([0.60, 0.42, 0.25]), np.float32([0.12, 0.09, 0.07]))
    return _flat(diffuse.astype(np.float32), specular=0.04, roughness=0.35)


@pytest.mark.parametrize("name, shot_index", [("near_flash", 0), ("far_noflash", 3)])
def test_bundled_xml_matches_scene_builders(default_env, name, shot_index):
    """near_flash.xml / far_noflash.xml (camera, flash, environment, checkerboard material) equal
    the capture builders' render of the same shot within noise: mean squared difference below 1.5×
    the summed noise variances (estimated from two seeds) and mean difference within 4 standard
    errors."""
    import mitsuba as mi

    from ebr_mitsuba.scene import bundled_scene, load_scene

    shot = setup_shots("near-far")[shot_index]
    spp = 32
    xml = [np.array(mi.render(load_scene(bundled_scene(name), res=RES, spp=spp), seed=s)) for s in (1, 2)]
    material = _checkerboard_material(RES)
    ours = [render_shot(material, sg_emitter_dict(default_env), shot, spp, seed=s) for s in (3, 4)]
    var = (np.mean((xml[0] - xml[1]) ** 2) + np.mean((ours[0] - ours[1]) ** 2)) / 2
    diff = xml[0] - ours[0]
    assert np.mean(diff**2) < 1.5 * var
    assert abs(diff.mean()) < 4 * math.sqrt(var / diff.size)


def test_bundled_exemplar_scene_uses_the_exemplar_material():
    """scenes/exemplar.xml writes the exemplar material as literals; they are the constants of
    :mod:`ebr_mitsuba.exemplar`."""
    import xml.etree.ElementTree as ET

    from ebr_mitsuba.exemplar import EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR
    from ebr_mitsuba.scene import bundled_scene

    bsdf = ET.parse(bundled_scene("exemplar")).getroot().find("./shape/bsdf[@type='svbrdf']")
    values = {e.get("name"): e.get("value") for e in bsdf.findall("rgb")}
    assert float(values["diffuse"]) == EXEMPLAR_DIFFUSE and float(values["specular"]) == EXEMPLAR_SPECULAR


def test_load_scene_converts_python_parameters():
    import mitsuba as mi

    from ebr_mitsuba.scene import bundled_scene, load_scene

    scene = load_scene(bundled_scene("default"), res=4, spp=1, diffuse0=[0.5, 0.5, 0.5], roughness=0.2)
    assert np.array(mi.render(scene)).shape == (4, 4, 3)


def test_plugin_bug_is_not_reported_as_bad_input(tmp_path):
    """A non-ebr exception raised inside a plugin constructor is an internal error (RuntimeError),
    not an InputError/ConfigError."""
    import mitsuba as mi

    from ebr_mitsuba.scene import load_scene

    class Broken(mi.Emitter):
        def __init__(self, props):
            super().__init__(props)
            raise ValueError("broken on purpose")

    mi.register_emitter("ebr_test_broken", lambda props: Broken(props))
    scene = tmp_path / "broken.xml"
    scene.write_text('<scene version="3.0.0"><emitter type="ebr_test_broken"/></scene>')
    with pytest.raises(RuntimeError, match="broken on purpose") as info:
        load_scene(scene)
    assert "broken.xml" in str(info.value) and "ValueError" in str(info.value)
