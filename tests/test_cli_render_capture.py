"""``ebr render`` and ``ebr capture`` through :func:`ebr_mitsuba.cli.main`: the bundled scenes
render, summaries are JSON, and bad input exits with code 2, one stderr line naming the culprit
and nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ebr_mitsuba import cli
from ebr_mitsuba.scene import bundled_scene, bundled_scenes

BUNDLED = ("default", "exemplar", "near_flash", "near_noflash", "far_flash", "far_noflash")


@pytest.fixture(autouse=True)
def only_these_commands(monkeypatch):
    """Build the parser from the two subcommands under test only, so these tests do not depend on
    the other subcommand modules importing."""
    monkeypatch.setattr(cli, "COMMANDS", ("render", "capture"))


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def assert_bad_input(code: int, err: str, name: str, tmp_path: Path, before: set) -> None:
    """Exit 2, exactly one stderr line that names ``name``, and no new file or directory."""
    assert code == 2, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert name in lines[0], lines[0]
    assert set(tmp_path.rglob("*")) == before


# -- ebr render -------------------------------------------------------------------------------------


def test_bundled_scene_list():
    assert set(BUNDLED) <= set(bundled_scenes())


@pytest.mark.parametrize("name", BUNDLED)
def test_render_bundled_scene(tmp_path, capsys, name):
    from ebr_mitsuba.imageio import read_exr

    out = tmp_path / f"{name}.exr"
    code, stdout, err = run_cli(
        capsys, "render", bundled_scene(name), "--out", out, "--spp", 2, "-D", "res=8", "--json"
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert set(summary) >= {"out", "seconds", "spp", "resolution", "variant"}
    assert summary["spp"] == 2 and summary["resolution"] == [8, 8]
    image = read_exr(out)
    assert image.shape == (8, 8, 3) and np.all(np.isfinite(image)) and image.mean() > 0


def test_render_parameters_change_the_image(tmp_path, capsys):
    """-D sets scene parameters: a rougher exemplar is a different image; the bundled name works
    without a path."""
    from ebr_mitsuba.imageio import read_exr

    for r in ("0.1", "0.9"):
        code, _, err = run_cli(
            capsys,
            "render",
            "exemplar",
            "--out",
            tmp_path / f"r{r}.exr",
            "-D",
            "res=8",
            "-D",
            "spp=4",
            "-D",
            f"roughness={r}",
        )
        assert code == 0, err
    assert not np.allclose(read_exr(tmp_path / "r0.1.exr"), read_exr(tmp_path / "r0.9.exr"))


def test_render_same_seed_same_image(tmp_path, capsys):
    from ebr_mitsuba.imageio import read_exr

    for name in ("a", "b"):
        assert (
            run_cli(
                capsys,
                "render",
                "near_flash",
                "--out",
                tmp_path / f"{name}.exr",
                "--spp",
                2,
                "-D",
                "res=8",
                "--seed",
                5,
            )[0]
            == 0
        )
    np.testing.assert_array_equal(read_exr(tmp_path / "a.exr"), read_exr(tmp_path / "b.exr"))


@pytest.mark.parametrize("define, name", [("res", "res"), ("=3", "=3"), ("1x=3", "1x")])
def test_render_bad_define(tmp_path, capsys, define, name):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, "render", "default", "--out", tmp_path / "x.exr", "-D", define)
    assert_bad_input(code, err, name, tmp_path, before)


def test_render_undeclared_parameter(tmp_path, capsys):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, "render", "default", "--out", tmp_path / "x.exr", "-D", "nosuch=1")
    assert_bad_input(code, err, "default.xml", tmp_path, before)
    assert "nosuch" in err


def test_render_missing_scene(tmp_path, capsys):
    before = set(tmp_path.rglob("*"))
    missing = tmp_path / "missing.xml"
    code, _, err = run_cli(capsys, "render", missing, "--out", tmp_path / "x.exr")
    assert_bad_input(code, err, "missing.xml", tmp_path, before)


@pytest.mark.parametrize(
    "text, words",
    [
        ('<scene version="3.0.0"><shape type="rectangle"></scene>', "mismatch"),
        ('<scene version="3.0.0"><shape type="nosuchplugin"/></scene>', "nosuchplugin"),
        (
            '<scene version="3.0.0"><emitter type="sgenvmap"><string name="filename" value="nope.json"/>'
            "</emitter></scene>",
            "nope.json",
        ),
    ],
)
def test_render_bad_scene_file(tmp_path, capsys, text, words):
    scene = tmp_path / "bad.xml"
    scene.write_text(text)
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, "render", scene, "--out", tmp_path / "x.exr")
    assert_bad_input(code, err, "bad.xml", tmp_path, before)
    assert words in err


def test_render_output_must_be_exr(tmp_path, capsys):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, "render", "default", "--out", tmp_path / "x.png")
    assert_bad_input(code, err, "x.png", tmp_path, before)


# -- ebr capture ------------------------------------------------------------------------------------


def test_capture_cli_procedural(tmp_path, capsys):
    out = tmp_path / "cap"
    code, stdout, err = run_cli(
        capsys,
        "capture",
        "--material",
        "procedural:wood:3",
        "--env",
        "procedural:5",
        "--setup",
        "near",
        "--out",
        out,
        "--res",
        16,
        "--spp",
        2,
        "--seed",
        1,
        "--json",
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["files"][:2] == ["flash.exr", "noflash.exr"] and summary["resolution"] == [16, 16]
    meta = json.loads((out / "capture.json").read_text())
    assert meta["material"] == {
        "spec": "procedural:wood:3",
        "kind": "procedural",
        "family": "wood",
        "seed": 3,
        "maps": "maps",
    }
    assert meta["env"]["spec"] == "procedural:5" and meta["env"]["seed"] == 5
    assert (out / "maps" / "normal.exr").is_file() and (out / "env.json").is_file()


def test_capture_cli_material_dir(tmp_path, capsys):
    """A material directory is resampled to --res (area average) and saved as the ground truth."""
    from ebr_mitsuba.materials import load_material_dir, save_material_dir
    from ebr_mitsuba.procedural import make_material

    src = make_material("tiles", 2, 32)
    save_material_dir(src, tmp_path / "mat")
    out = tmp_path / "cap"
    code, _, err = run_cli(
        capsys,
        "capture",
        "--material",
        tmp_path / "mat",
        "--env",
        bundled_scene("default").with_name("default_env.json"),
        "--setup",
        "near",
        "--out",
        out,
        "--res",
        16,
        "--spp",
        1,
    )
    assert code == 0, err
    gt = load_material_dir(out / "maps")
    expected = src.diffuse.reshape(16, 2, 16, 2, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(gt.diffuse, expected, atol=1e-5)


def _capture_args(tmp_path, **over):
    args = {
        "--material": "procedural:wood:1",
        "--env": "procedural:1",
        "--setup": "near",
        "--out": tmp_path / "cap",
        "--res": 8,
        "--spp": 1,
    }
    args.update(over)
    return ["capture"] + [str(v) for kv in args.items() for v in kv]


def test_capture_missing_material_dir(tmp_path, capsys):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, *_capture_args(tmp_path, **{"--material": tmp_path / "nomat"}))
    assert_bad_input(code, err, "nomat", tmp_path, before)


def test_capture_missing_env_file(tmp_path, capsys):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, *_capture_args(tmp_path, **{"--env": tmp_path / "noenv.json"}))
    assert_bad_input(code, err, "noenv.json", tmp_path, before)


def test_capture_missing_equirect_file(tmp_path, capsys):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, *_capture_args(tmp_path, **{"--env": tmp_path / "sky.hdr"}))
    assert_bad_input(code, err, "sky.hdr", tmp_path, before)


@pytest.mark.parametrize(
    "text",
    [
        '{"format": "ebr-sg/1", "lobes": [',
        '{"format": "other"}',
        '{"format": "ebr-sg/1", "lobes": [{"axis": [0, 0, 1]}]}',
    ],
)
def test_capture_malformed_env_json(tmp_path, capsys, text):
    env = tmp_path / "env.json"
    env.write_text(text)
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, *_capture_args(tmp_path, **{"--env": env}))
    assert_bad_input(code, err, "env.json", tmp_path, before)


def test_capture_unknown_setup(tmp_path, capsys):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, *_capture_args(tmp_path, **{"--setup": "sideways"}))
    assert_bad_input(code, err, "sideways", tmp_path, before)


@pytest.mark.parametrize(
    "spec, name",
    [
        ("procedural:velvet:1", "velvet"),
        ("procedural:wood:x", "procedural:wood:x"),
        ("procedural:wood", "procedural:wood"),
    ],
)
def test_capture_bad_procedural_material(tmp_path, capsys, spec, name):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, *_capture_args(tmp_path, **{"--material": spec}))
    assert_bad_input(code, err, name, tmp_path, before)


@pytest.mark.parametrize("spec", ["procedural:-1", "procedural:a", "sky.txt"])
def test_capture_bad_env_spec(tmp_path, capsys, spec):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, *_capture_args(tmp_path, **{"--env": spec}))
    assert_bad_input(code, err, spec, tmp_path, before)


@pytest.mark.parametrize(
    "option, value", [("--spp", 0), ("--res", 0), ("--seed", -1), ("--integrator", "bdpt")]
)
def test_capture_bad_numbers(tmp_path, capsys, option, value):
    before = set(tmp_path.rglob("*"))
    code, _, err = run_cli(capsys, *_capture_args(tmp_path, **{option: value}))
    assert_bad_input(code, err, str(value), tmp_path, before)
