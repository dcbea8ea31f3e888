"""``ebr insert``: the object appears and casts a shadow, the truth comparison is exact when the
estimate is the truth, it runs on the output of ``ebr estimate``, and bad input exits 2 with one
line and nothing written. Renders are 32-48 px at a few spp; the shadow is made unambiguous by
a sharp "sun" lobe 45 degrees above +x."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from ebr_mitsuba import cli
from ebr_mitsuba.imageio import read_exr
from ebr_mitsuba.insert import differential, estimate_photo
from ebr_mitsuba.sgenv import SGEnvironment
from ebr_mitsuba.svbrdf import SVBRDF

RES = 48
SQ = 0.5**0.5
# A sharp sun 45° above +x (irradiance ≈ 3 on the plane) and a dim sky (≈ 0.4).
SUN_ENV = SGEnvironment(
    np.array([[SQ, 0.0, SQ], [0.0, 0.0, 1.0]]),
    np.array([300.0, 1.0]),
    np.array([[200.0, 200.0, 200.0], [0.2, 0.2, 0.2]]),
)
CUBE_OBJ = """# unit cube, y up
v -1 0 -1\nv 1 0 -1\nv 1 2 -1\nv -1 2 -1\nv -1 0 1\nv 1 0 1\nv 1 2 1\nv -1 2 1
f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 4 8 7\nf 4 7 3\nf 1 5 8\nf 1 8 4\nf 2 3 7\nf 2 7 6
"""


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _capture(path: Path, env, material=None, res: int = 32) -> Path:
    from ebr_mitsuba.capture import capture

    material = material if material is not None else SVBRDF.uniform(res, res, 0.5, 0.04, 0.6)
    capture(material, env, "near", path, spp=2, res=res, progress=False)
    return path


@pytest.fixture(scope="module")
def sun_capture(tmp_path_factory) -> Path:
    """A capture of a uniform grey plate under :data:`SUN_ENV` (read only)."""
    return _capture(tmp_path_factory.mktemp("insert") / "cap", SUN_ENV)


def _fake_estimate(
    path: Path, capture_dir: Path, diffuse: float | None = None, env: bool = True, maps: bool = True
) -> Path:
    """An estimate directory made of a capture's own maps (``diffuse``: replace the albedo)."""
    from ebr_mitsuba.materials import load_material_dir, save_material_dir

    path.mkdir(parents=True)
    (path / "estimate.json").write_text(json.dumps({"format": "ebr-estimate/1", "inputs": {"fov": 45.0}}))
    if env:
        shutil.copy(capture_dir / "env.json", path / "env.json")
    if maps:
        truth = load_material_dir(capture_dir / "maps")
        if diffuse is not None:
            truth = SVBRDF(
                truth.normal, np.full_like(truth.diffuse, diffuse), truth.specular, truth.roughness
            )
        save_material_dir(truth, path / "maps")
    return path


def _box(image: np.ndarray, x0: float, x1: float, y0: float, y1: float) -> float:
    """Mean of the pixels of a top-down (sample-grid) image that see x in [x0, x1], y in [y0, y1]."""
    h, w = image.shape[:2]
    x = -1 + (2 * np.arange(w) + 1) / w
    y = 1 - (2 * np.arange(h) + 1) / h
    rows = (y >= y0) & (y <= y1)
    cols = (x >= x0) & (x <= x1)
    assert rows.any() and cols.any()
    return float(image[rows][:, cols].mean())


def test_writes_the_image_and_json(tmp_path, capsys, sun_capture):
    out = tmp_path / "img" / "ins.exr"
    code, stdout, err = run_cli(capsys, "insert", sun_capture, "--out", out, "--spp", 4, "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["out"] == str(out) and summary["files"] == [str(out)]
    assert summary["resolution"] == [32, 32] and summary["spp"] == 4  # default: the maps' size
    assert summary["object"] == "sphere" and summary["width"] == pytest.approx(2 / 3)
    image = read_exr(out)
    assert image.shape == (32, 32, 3) and np.all(np.isfinite(image)) and image.mean() > 0
    assert sorted(p.name for p in out.parent.iterdir()) == ["ins.exr"]  # no temporaries left


@pytest.mark.parametrize("material", ["diffuse", "mirror"])
def test_object_casts_a_shadow(tmp_path, capsys, sun_capture, material):
    """The sun 45° above +x: the plane at x in [-0.75, -0.5] (beyond the sphere's silhouette,
    inside its shadow) is much darker with the sphere than without; a corner on the sunny side
    is not."""
    images = {}
    for obj in ("sphere", "none"):
        out = tmp_path / f"{obj}.exr"
        code, _, err = run_cli(
            capsys,
            "insert",
            sun_capture,
            "--out",
            out,
            "--object",
            obj,
            "--material",
            material,
            "--res",
            RES,
            "--spp",
            8,
        )
        assert code == 0, err
        images[obj] = read_exr(out).mean(axis=-1)

    def ratio(*box):
        return _box(images["sphere"], *box) / _box(images["none"], *box)

    shadow, corner = ratio(-0.75, -0.5, -0.1, 0.1), ratio(0.6, 0.95, 0.6, 0.95)
    assert shadow < 0.5, shadow
    assert corner > 0.9, corner
    # The object itself is seen at the centre: the top of a sphere differs from the bare plane.
    centre = abs(ratio(-0.1, 0.1, -0.1, 0.1) - 1)
    assert centre > 0.05, centre


def test_mesh_object_and_oblique_view(tmp_path, capsys, sun_capture):
    """A .obj cube (y up) at an oblique view renders and differs from the plate alone."""
    mesh = tmp_path / "cube.obj"
    mesh.write_text(CUBE_OBJ)
    images = {}
    for obj in (mesh, "none"):
        out = tmp_path / f"{Path(str(obj)).stem}.exr"
        code, stdout, err = run_cli(
            capsys,
            "insert",
            sun_capture,
            "--out",
            out,
            "--object",
            obj,
            "--elevation",
            40,
            "--spp",
            4,
            "--json",
        )
        assert code == 0, err
        images[str(obj)] = read_exr(out)
    summary = json.loads(stdout)
    assert summary["camera"][1] < 0 and summary["camera"][2] > 0  # swung towards -y
    assert np.abs(images[str(mesh)] - images["none"]).mean() > 0.01


def test_truth_equal_to_estimate_gives_zero(tmp_path, capsys, sun_capture):
    """The capture as its own estimate (and a copy of its maps and env.json as an estimate
    directory): RMSE 0 with the same seed; > 0 with an independent seed or other maps. With
    --truth the three images are written."""
    fake = _fake_estimate(tmp_path / "same", sun_capture)
    for estimate in (sun_capture, fake):
        out = tmp_path / f"{estimate.name}.exr"
        code, stdout, err = run_cli(
            capsys,
            "insert",
            estimate,
            "--truth",
            sun_capture,
            "--out",
            out,
            "--spp",
            4,
            "--material",
            "glossy",
            "--json",
        )
        assert code == 0, err
        summary = json.loads(stdout)
        assert summary["rmse"] == 0.0 and summary["rel_rmse"] == 0.0
        assert summary["files"] == [
            str(out),
            str(tmp_path / f"{estimate.name}_truth.exr"),
            str(tmp_path / f"{estimate.name}_compare.png"),
        ]
        assert all(Path(f).is_file() for f in summary["files"])
        assert np.array_equal(read_exr(out), read_exr(summary["files"][1]))
    code, stdout, err = run_cli(
        capsys,
        "insert",
        fake,
        "--truth",
        sun_capture,
        "--out",
        tmp_path / "n.png",
        "--spp",
        4,
        "--truth-seed",
        1,
        "--json",
    )
    assert code == 0, err
    noise = json.loads(stdout)["rmse"]
    assert noise > 0
    # --noise-floor: the truth once more with the next seed (here 2) against the truth (seed 1)
    code, stdout, err = run_cli(
        capsys, "insert", fake, "--truth", sun_capture, "--out", tmp_path / "f.png", "--spp", 4,
        "--truth-seed", 1, "--noise-floor", "--json",
    )  # fmt: skip
    assert code == 0, err
    floor = json.loads(stdout)
    assert floor["rmse"] == noise and floor["noise_floor"] > 0 and floor["noise_floor"] != noise
    assert floor["floor_ratio"] == pytest.approx(noise / floor["noise_floor"])
    # with seeds 2 (estimate) and 1 (truth) the estimate is the truth's second render: ratio 1
    code, stdout, err = run_cli(
        capsys, "insert", sun_capture, "--truth", sun_capture, "--out", tmp_path / "g.png", "--spp", 4,
        "--seed", 2, "--truth-seed", 1, "--noise-floor", "--json",
    )  # fmt: skip
    assert code == 0, err
    assert json.loads(stdout)["floor_ratio"] == pytest.approx(1.0)
    other = _fake_estimate(tmp_path / "other", sun_capture, diffuse=0.2)
    code, stdout, err = run_cli(
        capsys, "insert", other, "--truth", sun_capture, "--out", tmp_path / "o.png", "--spp", 4, "--json"
    )
    assert code == 0, err
    assert json.loads(stdout)["rmse"] > 0.05  # albedo 0.2 instead of 0.5 under a bright sun


def test_on_the_output_of_ebr_estimate(tmp_path, capsys, monkeypatch):
    """`ebr estimate` (its pipeline with a fake network) → `ebr insert --truth`."""
    from fakes import use_fake_model

    use_fake_model(monkeypatch, 32)
    cap = _capture(tmp_path / "cap", SUN_ENV)
    est = tmp_path / "est"
    code, _, err = run_cli(
        capsys, "estimate", "--flash", cap / "flash.exr", "--noflash", cap / "noflash.exr", "--out", est
    )
    assert code == 0, err
    out = tmp_path / "ins.png"
    code, stdout, err = run_cli(capsys, "insert", est, "--truth", cap, "--out", out, "--spp", 4, "--json")
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["estimate"]["kind"] == "estimate" and summary["fov"] == 45.0
    assert np.isfinite(summary["rmse"]) and summary["rmse"] > 0
    assert all(Path(f).is_file() for f in summary["files"])
    # composited into the no-flash photo by default; the whole-frame render's error beside it
    assert summary["composited"] and summary["background"] == "photo"
    assert np.isfinite(summary["render_rmse"]) and summary["render_rmse"] != summary["rmse"]
    photo = estimate_photo(est)
    assert photo.shape == (32, 32, 3)
    # the photo is the shot the estimate read (capture units; ebr capture's exposure is 1)
    assert np.allclose(photo, read_exr(cap / "noflash.exr"), rtol=1e-4, atol=1e-5)
    images = {}
    for extra in ([], ["--object", "none"], ["--background", "render"]):
        out = tmp_path / f"ins{len(images)}.exr"
        code, stdout, err = run_cli(capsys, "insert", est, "--out", out, "--spp", 4, "--json", *extra)
        assert code == 0, err
        images[" ".join(extra)] = (read_exr(out), json.loads(stdout))
    assert np.allclose(images["--object none"][0], photo)  # nothing inserted: the photo itself
    assert not images["--background render"][1]["composited"]
    composite, rendered = images[""][0], images["--background render"][0]
    # away from the sphere and its shadow (the sun is at +x: the shadow falls towards -x) the
    # composite is the photo; the rendered frame is the estimate's plate instead
    assert _box(composite, 0.7, 1.0, 0.7, 1.0) == pytest.approx(_box(photo, 0.7, 1.0, 0.7, 1.0), rel=0.03)
    centre = (-0.1, 0.1, -0.1, 0.1)  # on the sphere: the render with the object
    assert _box(composite, *centre) == pytest.approx(_box(rendered, *centre), rel=1e-6)


def test_differential_composite():
    """Object pixels come from the render with the object; plate pixels are the photo times the
    render's ratio with / without the object (1 where the object changes nothing, the shadow's
    fraction in its shadow), or photo + difference where the plate render is dark."""
    rng = np.random.default_rng(0)
    photo = rng.uniform(0.2, 0.8, (8, 8, 3)).astype(np.float32)
    without = rng.uniform(0.3, 0.6, (8, 8, 3)).astype(np.float32)
    with_object = without.copy()
    with_object[:2] *= 0.25  # a shadow over the first two rows
    with_object[4:6, 4:6] = 0.9  # the object
    without[6:, :] = 0.0  # a plate render black in the last two rows ...
    with_object[6:, :] = 0.05  # ... where the object throws light
    coverage = np.zeros((8, 8, 1), np.float32)
    coverage[4:6, 4:6] = 1.0
    out = differential(photo, with_object, without, coverage)
    assert np.allclose(out[:2], 0.25 * photo[:2], rtol=1e-6)
    assert np.allclose(out[2:4], photo[2:4], rtol=1e-6)
    assert np.allclose(out[4:6, 4:6], 0.9)
    assert np.allclose(out[6:], photo[6:] + 0.05, rtol=1e-6)
    assert out.dtype == np.float32 and (out >= 0).all()


def test_object_coverage_is_the_spheres_silhouette(sun_capture):
    """The default sphere (radius 1/3, centred, on the plane) seen from straight above covers its
    silhouette: a disc of radius D tan(asin(r / (D − r))) on the plane (D the camera's height),
    whole pixels (any ray meeting the sphere counts), so between the disc and the disc grown by
    a pixel's diagonal; none of the corners."""
    from ebr_mitsuba.insert import InsertConfig, load_capture, object_coverage, object_dict
    from ebr_mitsuba.variant import ensure_variant

    ensure_variant()
    plate = load_capture(sun_capture)
    cfg = InsertConfig()
    cov = object_coverage(plate, cfg, 32, object_dict(cfg), plate.fov)[..., 0]
    assert cov.shape == (32, 32) and set(np.unique(cov)) <= {0.0, 1.0}
    assert cov[14:18, 14:18].all() and not cov[:6, :6].any() and not cov[-6:, -6:].any()
    height, r, pixel = 1 / np.tan(np.radians(plate.fov) / 2), 1 / 3, 2 / 32
    silhouette = height * np.tan(np.arcsin(r / (height - r)))
    assert np.pi * silhouette**2 / 4 < cov.mean() < np.pi * (silhouette + pixel * 2**0.5) ** 2 / 4


def _bad_cases(tmp: Path, cap: Path) -> list[tuple[list, str]]:
    """(argv after `insert`, the text the one error line must contain)."""
    bad_obj = tmp / "bad.obj"
    bad_obj.write_text("v 1 2\nf 1 2 3 x\n")
    empty_obj = tmp / "empty.obj"
    empty_obj.write_text("# nothing\n")
    no_env = _fake_estimate(tmp / "no_env", cap, env=False)
    no_maps = _fake_estimate(tmp / "no_maps", cap, maps=False)
    not_est = tmp / "plain"
    not_est.mkdir()
    dark = _capture(tmp / "dark", None, res=32)
    out = ["--out", tmp / "o.exr"]
    return [
        ([tmp / "missing", *out], "missing"),
        ([not_est, *out], "estimate.json"),
        ([no_env, *out], "env.json"),
        ([no_maps, *out], "maps"),
        ([cap, *out, "--object", bad_obj], "bad.obj"),
        ([cap, *out, "--object", empty_obj], "empty.obj"),
        ([cap, *out, "--object", tmp / "gone.obj"], "gone.obj"),
        ([cap, *out, "--object", "teapot"], "teapot"),
        ([cap, *out, "--material", "velvet"], "velvet"),
        ([cap, *out, "--spp", "0"], "--spp"),
        ([cap, *out, "--spp", "many"], "--spp"),
        ([cap, *out, "--res", "3"], "--res"),
        ([cap, *out, "--object-scale", "1.5"], "--object-scale"),
        ([cap, *out, "--object-scale", "nan"], "--object-scale"),
        ([cap, *out, "--position", "2,0"], "--position"),
        ([cap, *out, "--position", "0.5"], "--position"),
        ([cap, *out, "--elevation", "5"], "--elevation"),
        ([cap, *out, "--seed", "-1"], "--seed"),
        ([cap, *out, "--mesh-up", "x"], "--mesh-up"),
        ([cap, *out, "--background", "sky"], "--background"),
        ([cap, "--out", tmp / "o.txt"], "o.txt"),
        ([cap, *out, "--truth", not_est], "capture.json"),
        ([cap, *out, "--truth", dark], "environment"),
        ([dark, *out], "environment"),
    ]


def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, capsys, sun_capture):
    cases = _bad_cases(tmp_path, sun_capture)
    capsys.readouterr()
    before = set(tmp_path.rglob("*"))
    for argv, name in cases:
        code, stdout, err = run_cli(capsys, "insert", *argv)
        assert code == 2, (argv, err)
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1, (argv, err)
        assert name in lines[0], (argv, lines[0])
        assert stdout == ""
        assert set(tmp_path.rglob("*")) == before, argv


@pytest.mark.slow
def test_shipped_model_estimate_then_insert(tmp_path, capsys):
    """The shipped EBREnv model on a 64² procedural capture, then the insertion against the truth."""
    cap = tmp_path / "cap"
    code, _, err = run_cli(
        capsys,
        "capture",
        "--material",
        "procedural:tiles:1",
        "--env",
        "procedural:3",
        "--setup",
        "near",
        "--res",
        64,
        "--spp",
        16,
        "--out",
        cap,
    )
    assert code == 0, err
    est = tmp_path / "est"
    code, _, err = run_cli(
        capsys, "estimate", "--flash", cap / "flash.exr", "--noflash", cap / "noflash.exr", "--out", est
    )
    assert code == 0, err
    code, stdout, err = run_cli(
        capsys, "insert", est, "--truth", cap, "--out", tmp_path / "i.exr", "--spp", 16, "--json"
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert 0 < summary["rmse"] < float("inf") and summary["rel_rmse"] < 1.0
