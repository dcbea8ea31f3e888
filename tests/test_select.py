"""Adaptive exemplar selection (ebr_mitsuba.exemplar.select) and ``ebr select-exemplars``.

Targets are uniform materials of known roughness rendered with the fast renderer (quadrature,
256 directions, another seed than the selection's bases) at 48², with albedos unlike the exemplar
material's; the acceptance tolerance is 0.1 in roughness. Environments have a feature
the near camera sees in reflection (under overcast light the selection is weakly determined; the
module docstring says so and no test pretends otherwise).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ebr_mitsuba import cli
from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.exemplar.images import env_exemplar_images, point_exemplar_images
from ebr_mitsuba.exemplar.select import (
    SelectConfig,
    Selection,
    global_ssim,
    select_exemplars,
    structural_score,
)
from ebr_mitsuba.geometry import near_shot
from ebr_mitsuba.imageio import write_exr
from ebr_mitsuba.procedural import make_environment
from ebr_mitsuba.sgenv import SGEnvironment
from ebr_mitsuba.svbrdf import SVBRDF

RES = 48
TOL = 0.1


def _zenith_env() -> SGEnvironment:
    """A bright window lobe 17° from the zenith (reflected into the near camera) over a blue sky."""
    return SGEnvironment(
        np.array([[np.sin(0.3), 0.1, np.cos(0.3)], [0.0, 0.0, 1.0]]),
        np.array([150.0, 1.5]),
        np.array([[8.0, 7.5, 7.0], [0.3, 0.35, 0.45]]),
    )


def _default_env() -> SGEnvironment:
    from importlib import resources
    from pathlib import Path

    return SGEnvironment.load(Path(str(resources.files("ebr_mitsuba.scenes") / "default_env.json")))


ENVS = {"zenith": _zenith_env, "default": _default_env, "window": lambda: make_environment(1)}
MATERIALS = {
    "exemplar-like": (0.1, 0.2),
    "brown plastic": ((0.5, 0.35, 0.2), 0.04),
    "gold-ish": ((0.05, 0.05, 0.08), (0.9, 0.7, 0.4)),
}


def _noflash(env, diffuse, specular, r):
    from ebr_mitsuba.render import render_numpy

    return render_numpy(
        SVBRDF.uniform(RES, RES, diffuse, specular, r),
        env,
        near_shot(False),
        mode="quadrature",
        spp=256,
        seed=9,
    )


def _flash_only(diffuse, specular, r):
    from ebr_mitsuba.render import render_numpy

    return render_numpy(SVBRDF.uniform(RES, RES, diffuse, specular, r), None, near_shot(True, env=False))


@pytest.mark.parametrize(
    "env_name,material,r",
    [
        ("zenith", "exemplar-like", 0.15),
        ("zenith", "brown plastic", 0.65),
        ("zenith", "gold-ish", 1.0),
        ("default", "gold-ish", 0.15),
        ("default", "brown plastic", 0.4),
        ("default", "exemplar-like", 0.85),
        ("window", "brown plastic", 0.05),
        ("window", "gold-ish", 0.65),
    ],
)
def test_env_selection_recovers_roughness(env_name, material, r):
    env = ENVS[env_name]()
    sel = select_exemplars(env, _noflash(env, *MATERIALS[material], r))
    assert abs(sel.roughness[0] - r) <= TOL + 1e-9, (sel.roughness, sel.scores)


@pytest.mark.parametrize(
    "material,r",
    [
        ("exemplar-like", 0.05),
        ("brown plastic", 0.3),
        ("gold-ish", 0.6),
        ("brown plastic", 0.85),
        ("exemplar-like", 1.0),
    ],
)
def test_point_selection_recovers_roughness(material, r):
    sel = select_exemplars(None, _flash_only(*MATERIALS[material], r), point_light=True)
    assert abs(sel.roughness[0] - r) <= TOL + 1e-9, (sel.roughness, sel.scores)


def test_selection_layout_and_images():
    env = _zenith_env()
    config = SelectConfig()
    sel = select_exemplars(env, _noflash(env, 0.2, 0.1, 0.5), config=config)
    assert isinstance(sel, Selection)
    assert len(sel.roughness) == 3 and sel.roughness[1:] == config.anchors
    assert set(config.coarse) <= set(sel.scores)
    best_coarse = max(config.coarse, key=lambda v: sel.scores[v])
    assert set(config.fine_grid(best_coarse)) <= set(sel.scores)
    assert sel.scores[sel.roughness[0]] == max(sel.scores.values())
    assert sel.images.shape == (3, RES, RES, 3) and sel.images.dtype == np.float32
    expected = env_exemplar_images(env, sel.roughness, RES, RES, mode=config.env_mode, spp=config.env_spp)
    np.testing.assert_allclose(sel.images, expected, rtol=1e-6, atol=1e-7)
    data = sel.to_json()
    assert data["roughness"] == list(sel.roughness) and len(data["scores"]) == len(sel.scores)


def test_point_exemplar_is_selected_exactly():
    """An exemplar itself as target: its roughness scores highest (≈ 1: the target is area-averaged
    from 48² and the bases from 64² super-samples, so the pixel footprints differ slightly)."""
    target = point_exemplar_images([0.35], RES, RES)[0]
    sel = select_exemplars(None, target, point_light=True)
    assert sel.roughness[0] == pytest.approx(0.35)
    assert sel.scores[0.35] == max(sel.scores.values()) == pytest.approx(1.0, abs=1e-3)
    np.testing.assert_allclose(sel.images[0], target, rtol=1e-6)


def test_point_exemplar_images_are_flash_lit_exemplar_material():
    from ebr_mitsuba.render import render_numpy

    imgs = point_exemplar_images([0.2, 0.7], 16, 16)
    assert imgs.shape == (2, 16, 16, 3)
    ref = render_numpy(SVBRDF.uniform(16, 16, 0.1, 0.2, 0.7), None, near_shot(True, env=False))
    np.testing.assert_allclose(imgs[1], ref, rtol=1e-6)
    assert imgs[0].max() > imgs[1].max()  # the sharper highlight is brighter at the centre


def test_score_ignores_gain_and_offset_under_environment(rng):
    t = rng.uniform(0.5, 1.0, (20, 20))
    flat = np.ones_like(t)
    s = t + 0.1 * rng.normal(size=t.shape)
    base = structural_score(t, flat, s)
    assert structural_score(3.0 * t + 0.2, flat, s) == pytest.approx(base, rel=1e-9)
    assert structural_score(t, flat, t) == pytest.approx(1.0, abs=1e-12)
    assert structural_score(t, flat, s) < 1.0


def test_global_ssim_properties(rng):
    a = rng.uniform(size=(8, 8))
    assert global_ssim(a, a, 1.0) == pytest.approx(1.0)
    assert global_ssim(a, 1.0 - a, 1.0) < 0.0
    assert global_ssim(a, a * 0.5, 1.0) < global_ssim(a, a * 0.9, 1.0) < 1.0


@pytest.mark.parametrize(
    "target,match",
    [
        (np.zeros((16, 16, 3), np.float32), "black"),
        (np.ones((16, 16, 3), np.float32), "uniform"),
        (np.ones((16, 16, 4), np.float32), r"\(H, W, 3\)"),
        (np.ones((2, 16, 3), np.float32), "at least"),
        (np.full((16, 16, 3), np.nan, np.float32), "NaN"),
        ([[0.0]], "numpy"),
    ],
)
def test_bad_targets(target, match):
    with pytest.raises(InputError, match=match):
        select_exemplars(None, target, point_light=True)


def test_env_needed_and_flash_needed(rng):
    img = rng.uniform(0.1, 1.0, (16, 16, 3)).astype(np.float32)
    with pytest.raises(InputError, match="environment"):
        select_exemplars(None, img)
    with pytest.raises(InputError, match="flash"):
        select_exemplars(None, img, point_light=True, shot=near_shot(False))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"coarse": ()},
        {"coarse": (1.5,)},
        {"anchors": (0.9, 0.1)},
        {"anchors": (0.1,)},
        {"fine_step": 0.0},
        {"env_mode": "path"},
        {"env_spp": 0},
        {"compare_size": 2},
    ],
)
def test_bad_config(kwargs):
    with pytest.raises(ConfigError):
        SelectConfig(**kwargs)


def test_fine_grid_stays_in_range():
    c = SelectConfig()
    assert c.fine_grid(0.05) == (0.1, 0.15)
    assert c.fine_grid(0.95) == (0.85, 0.9, 1.0)
    assert c.fine_grid(0.5) == (0.4, 0.45, 0.55, 0.6)


# -- command line -------------------------------------------------------------------------------


def test_cli_json_and_out(tmp_path, capsys):
    env = _zenith_env()
    env_path = tmp_path / "env.json"
    env.save(env_path)
    img = tmp_path / "noflash.exr"
    write_exr(img, _noflash(env, 0.3, 0.05, 0.65))
    out = tmp_path / "sel"
    code = cli.main(
        ["select-exemplars", "--env", str(env_path), "--image", str(img), "--json", "--out", str(out)]
    )
    assert code == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["roughness"]) == 3 and data["roughness"][1:] == [0.1, 0.9]
    assert abs(data["roughness"][0] - 0.65) <= TOL + 1e-9
    assert all(np.isfinite(v) for v in data["scores"].values())
    assert len(list(out.glob("exemplar_*.exr"))) == 3 and (out / "selection.json").is_file()


def test_cli_point_light(tmp_path, capsys):
    img = tmp_path / "flash_only.exr"
    write_exr(img, _flash_only(0.3, 0.05, 0.3))
    assert cli.main(["select-exemplars", "--image", str(img), "--point-light", "--json"]) == 0
    assert abs(json.loads(capsys.readouterr().out)["roughness"][0] - 0.3) <= TOL + 1e-9


@pytest.mark.parametrize("case", ["missing", "channels", "nan", "no-env", "bad-anchors"])
def test_cli_bad_input(tmp_path, capsys, case):
    img = tmp_path / "img.exr"
    args = ["select-exemplars", "--image", str(img), "--point-light"]
    if case == "channels":
        write_exr(img, np.ones((16, 16), np.float32))  # one channel (Y)
    elif case == "nan":
        a = np.ones((16, 16, 3), np.float32)
        a[3, 4] = np.nan
        write_exr(img, a)
    elif case in ("no-env", "bad-anchors"):
        write_exr(img, np.random.default_rng(0).uniform(0.1, 1.0, (16, 16, 3)).astype(np.float32))
        args = args[:-1] if case == "no-env" else args + ["--anchors", "0.9,0.1"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "error" in err
