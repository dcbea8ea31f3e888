"""Real training data: the fixed test split, index-described texture sets, glob + split in data
configs, and lossy HDR maps (small negative texels)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ebr_mitsuba import imageio as io
from ebr_mitsuba.data import split as sp
from ebr_mitsuba.data.config import parse_config
from ebr_mitsuba.envmap import EquirectMap
from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.materials import load_texture_set

SHARED = sp.data_dir()
needs_shared = pytest.mark.skipif(
    not (SHARED / "materials_extra" / "index.json").is_file(),
    reason="shared assets not found; set EBR_DATA_DIR",
)


def test_bundled_split_is_well_formed_and_disjoint():
    split = sp.load_split()
    assert len(split.materials) >= 12 and len(split.environments) >= 8
    assert len(set(split.materials)) == len(split.materials)
    assert len(set(split.environments)) == len(split.environments)
    assert not set(split.materials) & set(split.environments)
    assert all(m.split("/")[0] in sp.MATERIAL_DIRS for m in split.materials)
    assert all(e.split("/")[0] in sp.ENVMAP_DIRS for e in split.environments)


@needs_shared
def test_split_covers_every_class_and_the_assets_exist():
    split = sp.load_split()
    for rel in split.materials + split.environments:
        assert (SHARED / rel).exists(), rel
    test = sp.real_materials("test")
    train = sp.real_materials("train")
    assert not set(test) & set(train)
    assert len(test) == len(split.materials)
    index = json.loads((SHARED / "materials_extra" / "index.json").read_text())["sets"]
    classes = {v["class"] for v in index.values()}
    assert {sp.material_class(p) for p in test} >= classes
    envs_test, envs_train = sp.real_envmaps("test"), sp.real_envmaps("train")
    assert len(envs_test) == len(split.environments) and not set(envs_test) & set(envs_train)


def _write_set(root: Path, name: str, entry: dict, size=(8, 12)) -> Path:
    d = root / name
    d.mkdir(parents=True)
    h, w = size
    rng = np.random.default_rng(0)
    io.write_png(d / "albedo.png", rng.uniform(0.2, 0.8, (h, w, 3)), encode="linear")
    normal = np.zeros((h, w, 3))
    normal[..., 0] = 0.2
    normal[..., 2] = 1.0
    normal[0, 0] = (0.0, 0.0, -0.02)  # a lossy-JPEG texel just below the surface
    io.write_png(d / "normal.png", (normal + 1) / 2, encode="linear")
    io.write_png(d / "rough.png", np.full((h, w, 3), 0.5), encode="linear")
    io.write_png(d / "metal.png", np.ones((h, w, 3)), encode="linear")
    index = root / "index.json"
    doc = json.loads(index.read_text()) if index.is_file() else {"format": "ebr-texture-sets/1", "sets": {}}
    doc["sets"][name] = entry
    index.write_text(json.dumps(doc))
    return d


def test_indexed_texture_set_reads_roles_and_metalness(tmp_path):
    maps = {"albedo": "albedo.png", "normal": "normal.png", "roughness": "rough.png"}
    plain = _write_set(tmp_path, "plain", {"class": "wood", "maps": maps, "normal_convention": "opengl"})
    metal = _write_set(tmp_path, "metal", {"class": "metal", "maps": {**maps, "metalness": "metal.png"}})
    bare = _write_set(tmp_path, "bare", {"class": "metal", "maps": maps, "metalness_constant": 1.0})
    m = load_texture_set(plain)
    np.testing.assert_allclose(m.specular, 0.04, atol=1e-6)  # unknown metalness: dielectric
    assert m.normal[0, 0, 2] >= 0.05 - 1e-6 and np.allclose(np.linalg.norm(m.normal, axis=-1), 1, atol=1e-5)
    assert m.roughness.shape == (8, 12) and abs(float(m.roughness.mean()) - 0.5) < 0.01
    for d in (metal, bare):  # metal = 1: F0 is the (sRGB-decoded) base colour, no diffuse
        x = load_texture_set(d)
        assert float(x.diffuse.max()) < 1e-6
        np.testing.assert_allclose(x.specular, io.read_image(d / "albedo.png", "srgb"), atol=1e-6)


def test_indexed_set_missing_role_names_the_set(tmp_path):
    maps = {"albedo": "albedo.png", "normal": "normal.png"}
    d = _write_set(tmp_path, "broken", {"class": "wood", "maps": maps})
    with pytest.raises(InputError, match="broken.*roughness"):
        load_texture_set(d)


def _config(paths, split, kind="materials"):
    mats = [{"type": "procedural"}]
    envs = [{"type": "procedural"}]
    if kind == "materials":
        mats = [{"type": "directory", "paths": paths, "split": split}]
    else:
        envs = [{"type": "equirect", "paths": paths, "split": split}]
    return {"dataset": {"resolution": 16}, "materials": mats, "environments": envs}


@needs_shared
def test_config_globs_filter_by_split_and_refuse_named_test_assets():
    pattern = [f"{SHARED}/materials/*", f"{SHARED}/materials_extra/*"]
    train = parse_config(_config(pattern, "train")).materials[0].paths
    test = parse_config(_config(pattern, "test")).materials[0].paths
    assert sorted(test) == sorted(sp.real_materials("test"))
    assert sorted(train) == sorted(sp.real_materials("train"))
    named = sp.real_materials("test")[:1]
    with pytest.raises(ConfigError, match="fixed test split"):
        parse_config(_config(pattern + named, "train"))
    envs = (
        parse_config(
            _config(
                [f"{SHARED}/envmaps_extra/*.hdr", f"{SHARED}/envmaps_extra/*.exr"], "test", "environments"
            )
        )
        .environments[0]
        .paths
    )
    assert sorted(envs) == sorted(p for p in sp.real_envmaps("test") if "envmaps_extra" in p)


def test_config_glob_matching_nothing_is_one_line(tmp_path):
    with pytest.raises(ConfigError, match="matches no directory"):
        parse_config(_config([f"{tmp_path}/nothing*"], "all"))


def test_lossy_map_negatives_are_clipped_large_ones_refused():
    data = np.ones((4, 8, 3), np.float32)
    data[0, 0, 0] = -0.002  # DWAB noise: 0.2 % of the mean
    env = EquirectMap(data, source="lossy.exr")
    assert float(env.data.min()) == 0.0
    data[0, 0, 0] = -0.5
    with pytest.raises(InputError, match="negative radiance"):
        EquirectMap(data, source="bad.exr")


def test_indexed_set_with_material_dir_like_names_loads_as_a_texture_set(tmp_path):
    from ebr_mitsuba.materials import load_material

    maps = {"albedo": "color.png", "normal": "normal.png", "roughness": "rough.png"}
    d = _write_set(tmp_path, "rock", {"class": "stone", "maps": maps})
    (d / "albedo.png").rename(d / "color.png")
    m = load_material(d, size=4)
    assert m.shape == (4, 4)


def test_center_square_crop_of_a_non_square_set():
    from ebr_mitsuba.sources import center_square
    from ebr_mitsuba.svbrdf import SVBRDF

    h, w = 6, 10
    diffuse = np.zeros((h, w, 3), np.float32)
    diffuse[:, 2:8] = 0.5
    m = SVBRDF(
        np.dstack([np.zeros((h, w, 2)), np.ones((h, w))]),
        diffuse,
        np.full((h, w, 3), 0.04),
        np.full((h, w), 0.3),
    )
    sq = center_square(m)
    assert sq.shape == (6, 6) and np.all(sq.diffuse == 0.5)
    assert center_square(sq) is sq


def test_oracle_constant_is_the_truths_mean_and_scores_its_spread():
    from ebr_mitsuba.evaluation.baselines import oracle_constant
    from ebr_mitsuba.metrics import map_rmse
    from ebr_mitsuba.svbrdf import SVBRDF

    rng = np.random.default_rng(3)
    h = w = 8
    n = np.dstack([rng.normal(0, 0.1, (h, w, 2)), np.ones((h, w))])
    truth = SVBRDF(n, rng.uniform(0, 1, (h, w, 3)), rng.uniform(0, 0.1, (h, w, 3)), rng.uniform(0, 1, (h, w)))
    oc = oracle_constant(truth)
    assert oc.shape == truth.shape
    np.testing.assert_allclose(oc.diffuse[3, 4], truth.diffuse.reshape(-1, 3).mean(0), rtol=1e-5)
    np.testing.assert_allclose(oc.roughness, truth.roughness.mean(), rtol=1e-5)
    assert np.allclose(np.linalg.norm(oc.normal, axis=-1), 1, atol=1e-5)
    err = map_rmse(oc, truth)
    np.testing.assert_allclose(err["roughness"], truth.roughness.std(), rtol=1e-4)
    assert map_rmse(oracle_constant(oc), oc)["mean"] < 1e-6


def test_material_class_of_rows():
    from ebr_mitsuba.evaluation.evaluate import material_class

    assert material_class({"material": "procedural:tiles:12"}) == "procedural:tiles"
    assert material_class({"material": str(SHARED / "materials" / "Metal009")}) == "metal"


def test_batched_ssim_equals_the_reference_per_pair():
    from ebr_mitsuba.extract.msssim import ssim, ssim_many

    rng = np.random.default_rng(5)
    a = rng.uniform(0, 1, (3, 24, 20, 3))
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    got = ssim_many(a, b, data_range=1.0)
    want = [ssim(x, y, data_range=1.0) for x, y in zip(a, b)]
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    with pytest.raises(InputError, match="smaller than"):
        ssim_many(a[:, :8], b[:, :8], data_range=1.0)


def test_truth_but_replaces_only_the_named_maps_by_their_means():
    from ebr_mitsuba.errors import InputError
    from ebr_mitsuba.evaluation.baselines import oracle_constant, truth_but
    from ebr_mitsuba.metrics import map_rmse
    from ebr_mitsuba.svbrdf import SVBRDF

    rng = np.random.default_rng(4)
    h = w = 8
    n = np.dstack([rng.normal(0, 0.1, (h, w, 2)), np.ones((h, w))])
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    truth = SVBRDF(n, rng.uniform(0, 1, (h, w, 3)), rng.uniform(0, 0.1, (h, w, 3)), rng.uniform(0, 1, (h, w)))
    tb = truth_but(truth, ("roughness", "normal"))
    err, oerr = map_rmse(tb, truth), map_rmse(oracle_constant(truth), truth)
    assert err["diffuse"] < 1e-6 and err["specular"] < 1e-6
    np.testing.assert_allclose(
        [err["roughness"], err["normal"]], [oerr["roughness"], oerr["normal"]], rtol=1e-5
    )
    with pytest.raises(InputError, match="unknown map"):
        truth_but(truth, ("albedo",))


def test_truth_roughness_diagnostics_keep_the_stated_part_of_the_pattern():
    from ebr_mitsuba.errors import InputError
    from ebr_mitsuba.evaluation.baselines import (
        oracle_constant,
        truth_roughness_from_albedo,
        truth_roughness_scaled,
    )
    from ebr_mitsuba.metrics import map_rmse
    from ebr_mitsuba.svbrdf import SVBRDF

    rng = np.random.default_rng(5)
    h = w = 16
    n = np.dstack([np.zeros((h, w, 2)), np.ones((h, w))])
    albedo = rng.uniform(0.05, 0.8, (h, w, 3))
    u = np.log(albedo.mean(-1) + 1e-3)
    follows = 0.5 - 0.1 * (u - u.mean())  # a roughness that is a line in the log albedo
    noise = rng.normal(0, 0.05, (h, w))  # ... plus a pattern the albedo does not show
    truth = SVBRDF(n, albedo, np.full((h, w, 3), 0.04), np.clip(follows + noise, 0.05, 1))
    exact = SVBRDF(n, albedo, np.full((h, w, 3), 0.04), follows)
    # an albedo-following roughness is recovered exactly; the rest of a pattern is lost
    np.testing.assert_allclose(truth_roughness_from_albedo(exact).roughness, follows, atol=1e-5)
    err = map_rmse(truth_roughness_from_albedo(truth), truth)["roughness"]
    assert abs(err - float(np.std(truth.roughness - follows))) < 0.01
    assert err < map_rmse(oracle_constant(truth), truth)["roughness"]
    # the scaled pattern: 0 is the constant mean, 1 the truth, ½ half the constant's error
    const_err = map_rmse(oracle_constant(truth), truth)["roughness"]
    np.testing.assert_allclose(truth_roughness_scaled(truth, 1.0).roughness, truth.roughness, atol=1e-6)
    for gain in (0.0, 0.5):
        scaled = truth_roughness_scaled(truth, gain)
        got = map_rmse(scaled, truth)
        np.testing.assert_allclose(got["roughness"], (1 - gain) * const_err, rtol=1e-4)
        assert got["diffuse"] < 1e-6 and got["normal"] < 1e-6
    with pytest.raises(InputError, match="outside"):
        truth_roughness_scaled(truth, 1.5)
