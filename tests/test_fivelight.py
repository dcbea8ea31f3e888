"""Issue 14: dual-loss checkpoints that load (``ebr eval``, ``load_model``) and the five-light
estimate ``ebr estimate --lights`` (ebr_mitsuba.estimate.fivelight).

The model is ``configs/dualloss_tiny.toml`` trained for two steps by ``ebr train`` on the tiny
five-light data set (conftest ``tiny5``, 4 samples at 32²); the captures are ``ebr capture --setup
five-light`` renders at 32² with few samples. The maps of a two-step model are meaningless: the
tests check the plumbing (which photos, positions, intensities and exposures reach the network,
and what is written), never the quality of the maps.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from cli_run import assert_each_refused, estimate_json, nonblank_lines

from ebr_mitsuba.cli import main
from ebr_mitsuba.errors import ConfigError
from ebr_mitsuba.estimate import fivelight
from ebr_mitsuba.geometry import FIVE_LIGHT_POSITIONS
from ebr_mitsuba.imageio import read_exr, write_exr
from ebr_mitsuba.model import checkpoint as ck

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread


@pytest.fixture(scope="module")
def dl_model(tiny5, tmp_path_factory) -> Path:
    """``ebr train configs/dualloss_tiny.toml`` (two steps) on the tiny five-light data."""
    out = tmp_path_factory.mktemp("dl") / "run"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("EBR_TRAIN_DATA", str(tiny5))
        assert main(["train", str(CONFIGS / "dualloss_tiny.toml"), "--out", str(out)]) == 0
    return out / "model.pt"


@pytest.fixture(scope="module")
def capture5(tmp_path_factory) -> Path:
    """``ebr capture --setup five-light`` at 32² (4 spp): light0..light4.exr + capture.json."""
    out = tmp_path_factory.mktemp("cap") / "cap5"
    code = main(
        [
            "capture",
            "--material",
            "procedural:wood:3",
            "--env",
            "procedural:1",
            "--setup",
            "five-light",
            "--res",
            "32",
            "--spp",
            "4",
            "--out",
            str(out),
        ]
    )
    assert code == 0
    return out


def _net_maps(model: Path, photos: list[np.ndarray]):
    """The dual-loss network's maps for five (H, W, 3) photos, straight from the checkpoint."""
    from ebr_mitsuba.model.predict import load_model

    bundle = load_model(model, expect_kind="dualloss")
    x = torch.from_numpy(np.stack(photos).astype(np.float32)).permute(0, 3, 1, 2)[None]
    with torch.no_grad():
        return bundle.dualloss(x).to_svbrdf(0)


# -- checkpoints (deliverable 1) ------------------------------------------------------------------


def test_dualloss_checkpoint_carries_only_its_tables_and_loads(dl_model, tiny5, capsys):
    from ebr_mitsuba.model.predict import load_model

    data = ck.load_checkpoint(dl_model, expect_kind="dualloss")
    assert data["kind"] == "dualloss" and set(data["model"]) == {"dualloss"}
    ebrenv_only = {"stages", "selection", "extract"}
    assert not ebrenv_only & set(data["config"])
    assert not ebrenv_only & set(json.loads((dl_model.parent / "config.json").read_text()))
    raw = torch.load(dl_model, weights_only=True)  # as written, not as upgraded on load
    assert "stages" not in raw["config"]
    bundle = load_model(dl_model, expect_kind="dualloss")
    assert bundle.kind == "dualloss" and bundle.resolution == 32 and not bundle.dualloss.training
    assert main(["eval", "--checkpoint", str(dl_model), "--data", str(tiny5), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n"] == 4 and np.isfinite(out["per_map_rmse"]["mean"]) and out["rerender_rmse"] > 0


def test_old_dualloss_checkpoint_with_default_stages_loads(dl_model, tiny5, tmp_path, capsys):
    """A checkpoint written before the fix (a default [stages], empty [selection] / [extract] in
    its config) loads, evaluates and estimates like a new one."""
    from ebr_mitsuba.model.config import StageSteps, config_from_dict
    from ebr_mitsuba.model.predict import load_model

    old = torch.load(dl_model, weights_only=True)
    stages = dataclasses.asdict(StageSteps())
    old["config"] = {**old["config"], "stages": stages, "selection": {}, "extract": {}}
    with pytest.raises(ConfigError, match=r"\[stages\] is for kind = 'ebrenv'"):
        config_from_dict(old["config"])  # what load_model used to fail with
    legacy = tmp_path / "legacy.pt"
    torch.save(old, legacy)
    assert ck.load_checkpoint(legacy)["config"] == ck.load_checkpoint(dl_model)["config"]
    assert load_model(legacy, expect_kind="dualloss").kind == "dualloss"
    assert main(["eval", "--checkpoint", str(legacy), "--data", str(tiny5), "--limit", "1"]) == 0
    capsys.readouterr()
    # an old run resumes: its last.pt (and config.json) with the old tables
    run = tmp_path / "run"
    shutil.copytree(dl_model.parent, run)
    last = torch.load(run / "last.pt", weights_only=True)
    torch.save({**last, "config": old["config"]}, run / "last.pt")
    (run / "config.json").write_text(json.dumps(old["config"]))
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("EBR_TRAIN_DATA", str(tiny5))
        assert main(["train", str(CONFIGS / "dualloss_tiny.toml"), "--out", str(run), "--resume"]) == 0
    assert "stages" not in json.loads((run / "config.json").read_text())
    capsys.readouterr()
    # a damaged config names the file (it used to say "<checkpoint>")
    old["config"]["train"] = {"steps": "many"}
    torch.save(old, tmp_path / "damaged.pt")
    assert main(["eval", "--checkpoint", str(tmp_path / "damaged.pt"), "--data", str(tiny5)]) == 2
    assert f"{tmp_path / 'damaged.pt'}: damaged checkpoint config" in capsys.readouterr().err


def test_dualloss_config_refuses_ebrenv_tables(tmp_path):
    from ebr_mitsuba.model.config import load_config

    base = 'kind = "dualloss"\n[data]\ntrain = "x"\n'
    for table in ("stages", "selection", "extract"):
        path = tmp_path / "c.toml"
        path.write_text(base + f"[{table}]\n")
        with pytest.raises(ConfigError, match=rf"c\.toml: \[{table}\] is for kind = 'ebrenv'"):
            load_config(path)
    path.write_text(base)
    assert set(load_config(path).to_dict()) == {"kind", "data", "model", "train", "loss"}


# -- ebr estimate --lights (deliverable 2) --------------------------------------------------------


def _exposure(data: Path) -> float:
    """The recorded exposure of sample 0 of ``data``."""
    return float(json.loads((data / "samples" / "000000" / "sample.json").read_text())["camera"]["exposure"])


def _estimate_sample(capsys, model, data: Path, out: Path, *extra):
    """``ebr estimate --lights`` on sample 0's photos at its known light intensity (nominal 10 W/sr
    × exposure, as capture.json would state it)."""
    photos = data / "samples" / "000000" / "photos"
    intensity = 10.0 * _exposure(data)
    return estimate_json(
        capsys,
        "--lights",
        photos,
        "--checkpoint",
        model,
        "--flash-intensity",
        intensity,
        *extra,
        "--out",
        out,
    )


def test_estimate_lights_on_a_data_set_sample_matches_the_network(dl_model, tiny5, tmp_path, capsys):
    """The photos of a data set sample, at its known light intensity (nominal × exposure, as
    capture.json would state it): the maps are the network's on the photos at the reference
    exposure (what training showed it), and every output is written."""
    sample, exposure, out = tiny5 / "samples" / "000000", _exposure(tiny5), tmp_path / "est"
    code, summary, err = _estimate_sample(capsys, dl_model, tiny5, out, "--no-flash-fit")
    assert code == 0, err
    assert summary["flash_fit"] is None
    assert summary["capture"] == "five-light" and summary["resolution"] == 32 and summary["model_grid"] == 32
    assert summary["inputs"]["geometry"] == "default five-light geometry"
    assert summary["inputs"]["lights"] == {f"light{k}": list(p) for k, p in enumerate(FIVE_LIGHT_POSITIONS)}
    assert summary["exposure"]["to_reference"]["light3"] == pytest.approx(1.0 / exposure)
    assert {v["source"] for v in summary["flash"].values()} == {"--flash-intensity"}
    for name in summary["files"]:
        assert (out / name).is_file(), name
    for k in range(5):
        for sub in ("rerender", "residual"):
            assert f"{sub}/light{k}.exr" in summary["files"]
    assert {f"maps/{m}.exr" for m in ("normal", "diffuse", "specular", "roughness")} <= set(summary["files"])
    assert json.loads((out / "estimate.json").read_text())["files"] == summary["files"]
    assert "light3 (light at -1.2, 1.2, 2)" in (out / "report.html").read_text()
    # the maps: the network on photo / exposure
    from ebr_mitsuba.imageio import read_image

    photos = [read_image(sample / "photos" / f"light{k}.png", "srgb") / exposure for k in range(5)]
    want = _net_maps(dl_model, photos)
    got = {m: read_exr(out / "maps" / f"{m}.exr") for m in ("diffuse", "roughness", "normal")}
    np.testing.assert_allclose(got["diffuse"], want.diffuse, atol=1e-5)
    np.testing.assert_allclose(got["roughness"].reshape(want.roughness.shape), want.roughness, atol=1e-5)
    np.testing.assert_allclose(got["normal"], want.normal, atol=1e-5)
    # residual = re-render − photo, in the photos' units
    photo0 = read_image(sample / "photos" / "light0.png", "srgb")
    np.testing.assert_allclose(
        read_exr(out / "residual" / "light0.exr"),
        read_exr(out / "rerender" / "light0.exr") - photo0,
        atol=1e-5,
    )


def test_estimate_lights_fits_the_photos_by_default(dl_model, tiny5, tmp_path, capsys):
    """Without --no-flash-fit the maps are the photometric fit (estimate/photometric.py) of the
    photos at the reference exposure, the network's maps its fallback; the summary says what it
    found."""
    from ebr_mitsuba.estimate.photometric import fit_photometric
    from ebr_mitsuba.geometry import NEAR_DISTANCE
    from ebr_mitsuba.imageio import read_image

    sample, exposure, out = tiny5 / "samples" / "000000", _exposure(tiny5), tmp_path / "est"
    code, summary, err = _estimate_sample(capsys, dl_model, tiny5, out)
    assert code == 0, err
    fit = summary["flash_fit"]
    assert set(fit) == {"flash_fit", "photometric_fraction", "residual", "fallback"}
    photos = [read_image(sample / "photos" / f"light{k}.png", "srgb") / exposure for k in range(5)]
    want = fit_photometric(
        photos,
        FIVE_LIGHT_POSITIONS,
        [10.0] * 5,
        _net_maps(dl_model, photos),
        camera=(0.0, 0.0, NEAR_DISTANCE),
        saturated=[
            np.any(read_image(sample / "photos" / f"light{k}.png", "srgb") >= 1.0, -1) for k in range(5)
        ],
    )
    assert fit["fallback"] == want.fallback
    np.testing.assert_allclose(read_exr(out / "maps" / "diffuse.exr"), want.maps.diffuse, atol=1e-4)
    np.testing.assert_allclose(read_exr(out / "maps" / "normal.exr"), want.maps.normal, atol=1e-4)


def test_estimate_lights_on_a_capture(dl_model, capture5, tmp_path, capsys):
    """An `ebr capture --setup five-light` directory; its five files in another order; the same
    photos brighter with a proportionally stronger light (the same maps: the reference exposure);
    the photos away from capture.json (default geometry, fitted intensity)."""
    code, by_dir, err = estimate_json(
        capsys, "--lights", capture5, "--checkpoint", dl_model, "--out", tmp_path / "a"
    )
    assert code == 0, err
    assert by_dir["inputs"]["geometry"] == str(capture5 / "capture.json")
    assert by_dir["flash"]["light0"] == {"intensity": 10.0, "source": "capture.json"}
    assert by_dir["inputs"]["highlight"] is not None  # light0 sits at the camera
    diffuse = read_exr(tmp_path / "a" / "maps" / "diffuse.exr")

    files = [capture5 / f"light{k}.exr" for k in (3, 0, 4, 1, 2)]
    code, shuffled, err = estimate_json(
        capsys, "--lights", *files, "--checkpoint", dl_model, "--out", tmp_path / "b"
    )
    assert code == 0, err
    assert list(shuffled["inputs"]["paths"]) == [f"light{k}" for k in range(5)]
    assert any("light order of" in w for w in shuffled["warnings"])
    np.testing.assert_array_equal(read_exr(tmp_path / "b" / "maps" / "diffuse.exr"), diffuse)

    bright = tmp_path / "bright"
    bright.mkdir()
    for k in range(5):
        write_exr(bright / f"light{k}.exr", 4.0 * read_exr(capture5 / f"light{k}.exr"))
    code, scaled, err = estimate_json(
        capsys, "--lights", bright, "--checkpoint", dl_model, "--flash-intensity", 40, "--out", tmp_path / "c"
    )
    assert code == 0, err
    assert scaled["exposure"]["to_reference"]["light0"] == pytest.approx(0.25)
    np.testing.assert_allclose(read_exr(tmp_path / "c" / "maps" / "diffuse.exr"), diffuse, atol=1e-5)
    assert scaled["rerender_error"]["network"]["mean"]["rmse"] == pytest.approx(
        4.0 * by_dir["rerender_error"]["network"]["mean"]["rmse"], rel=1e-3
    )

    code, fitted, err = estimate_json(
        capsys, "--lights", bright, "--checkpoint", dl_model, "--out", tmp_path / "d"
    )
    assert code == 0, err
    assert fitted["inputs"]["geometry"] == "default five-light geometry"
    assert {v["source"] for v in fitted["flash"].values()} == {"fitted"}
    assert 0 < fitted["flash"]["light0"]["intensity"] < float("inf")
    assert len({v["intensity"] for v in fitted["flash"].values()}) == 1  # one lamp, five positions
    # least squares over the five shots: the residuals are orthogonal to the re-renders
    r = np.stack([read_exr(tmp_path / "d" / "rerender" / f"light{k}.exr") for k in range(5)])
    res = np.stack([read_exr(tmp_path / "d" / "residual" / f"light{k}.exr") for k in range(5)])
    r, res = r.astype(np.float64), res.astype(np.float64)
    assert abs(float(np.sum(r * res))) < 1e-4 * float(np.sum(r * r))


def _bad_setups(capture5: Path, tmp: Path) -> dict:
    """name → (arguments after --lights, text the one-line error must contain)."""
    files = [capture5 / f"light{k}.exr" for k in range(5)]
    small = tmp / "small"
    small.mkdir(parents=True)
    for k, f in enumerate(files):
        img = read_exr(f)
        write_exr(small / f.name, img[:16, :16] if k == 2 else img)
    bad_json = tmp / "nopos"
    shutil.copytree(capture5, bad_json)
    meta = json.loads((bad_json / "capture.json").read_text())
    meta["shots"][3]["flash"] = None
    (bad_json / "capture.json").write_text(json.dumps(meta))
    near = tmp / "near"
    shutil.copytree(capture5, near)
    meta = json.loads((near / "capture.json").read_text())
    meta["setup"] = "near"
    (near / "capture.json").write_text(json.dumps(meta))
    broken = tmp / "broken"
    shutil.copytree(capture5, broken)
    (broken / "light1.exr").write_bytes(b"not an exr at all")
    nojson = tmp / "nojson"
    nojson.mkdir()
    for f in files[:4]:
        shutil.copy(f, nojson / f.name)
    return {
        "three photos": (files[:3], "--lights: 3 paths given; give five photos"),
        "six photos": (files + [files[0]], "--lights: 6 paths given"),
        "one file": (files[:1], "--lights: 1 path given"),
        "mismatched sizes": ([small / f.name for f in files], f"{small / 'light2.exr'} is 16x16 but"),
        "missing position": ([bad_json], f"{bad_json / 'capture.json'}: shot light3 has no light position"),
        "another setup": ([near], f"{near / 'capture.json'}: a 'near' capture; --lights needs a five-light"),
        "unreadable file": ([broken], str(broken / "light1.exr")),
        "missing file": (files[:4] + [tmp / "light4.exr"], f"--lights {tmp / 'light4.exr'}: no such file"),
        "missing light in a folder": ([nojson], f"--lights {nojson}: no capture.json and no light4 photo"),
        "same file twice": (
            [nojson / f.name for f in files[:4]] + [nojson / "light0.exr"],
            "the same file is given for two lights",
        ),
        "two files of one name": (files[:4] + [nojson / "light0.exr"], "two photos share a file name"),
    }


def test_estimate_lights_bad_input_exits_2_with_one_line(dl_model, capture5, tmp_path, capsys):
    cases = _bad_setups(capture5, tmp_path / "in")
    assert_each_refused(
        capsys, cases, lambda lights: ["--lights", *lights, "--checkpoint", dl_model], tmp_path / "out"
    )


def test_estimate_lights_model_and_flag_errors(dl_model, capture5, tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    # no --checkpoint and no shipped dual-loss model
    monkeypatch.setattr(fivelight, "shipped_model_path", lambda: tmp_path / "none.pt")
    code, _, err = estimate_json(capsys, "--lights", capture5, "--out", out)
    assert code == 2 and len(nonblank_lines(err)) == 1 and "pass --checkpoint" in err
    # a checkpoint of another kind
    other = torch.load(dl_model, weights_only=True)
    other["kind"] = "ebrenv"
    torch.save(other, tmp_path / "ebrenv.pt")
    code, _, err = estimate_json(
        capsys, "--lights", capture5, "--checkpoint", tmp_path / "ebrenv.pt", "--out", out
    )
    assert code == 2 and len(nonblank_lines(err)) == 1 and "wrong kind" in err and "ebrenv.pt" in err
    # options of the flash/no-flash estimate
    for extra in (["--noflash", capture5 / "light0.exr"], ["--refine-steps", "5"], ["--fov", "50"]):
        code, _, err = estimate_json(
            capsys, "--lights", capture5, "--checkpoint", dl_model, *extra, "--out", out
        )
        assert code == 2 and f"{extra[0]} does not apply to --lights" in err, extra
    code, _, err = estimate_json(
        capsys, "--lights", capture5, "--checkpoint", dl_model, "--out", capture5.parent
    )
    assert code == 2 and "contains the input" in err
    code, _, err = estimate_json(capsys, "--out", out)
    assert code == 2 and "--flash F" in err and "--lights" in err
    assert not out.exists()


def test_the_shipped_model_estimates_a_capture(capture5, tmp_path, capsys):
    """The tracked five-light model (ebr_mitsuba/models/dualloss_small.pt) is what --lights uses
    without --checkpoint: a missing file is a failure here, not a skip."""
    assert fivelight.shipped_model_path().is_file()
    out = tmp_path / "est"
    code, summary, err = estimate_json(capsys, "--lights", capture5, "--out", out)
    assert code == 0, err
    assert summary["model"]["checkpoint"].endswith("dualloss_small.pt")
    assert summary["model_grid"] == 128 and summary["flash_fit"] is not None
    for m in ("normal", "diffuse", "specular", "roughness"):
        assert (out / "maps" / f"{m}.exr").is_file()
