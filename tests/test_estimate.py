"""`ebr estimate`: input checks and every bad-input case of the issue, the pipeline's outputs and
report, refinement and the demo/gallery plumbing (full resolution above the model grid:
tests/test_fullres.py).

The network is replaced by a fake :class:`~ebr_mitsuba.model.predictor.Predictor` (``grid``,
``takes_far``, ``predict``) that returns plausible maps and a two-lobe environment, so these tests
need no trained model; ``test_real_model_end_to_end`` (slow) runs the shipped one. Captures are rendered at
48-64 px with the fast renderer (exact for the flash term, closed-form SG environment).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ebr_mitsuba.cli import main
from ebr_mitsuba.errors import InputError
from ebr_mitsuba.geometry import far_shot, near_shot
from ebr_mitsuba.imageio import write_exr, write_png
from ebr_mitsuba.model.predictor import Prediction
from ebr_mitsuba.sgenv import SGEnvironment
from ebr_mitsuba.svbrdf import SVBRDF

GRID = 48
ENV = SGEnvironment(
    np.array([[0.5, 0.3, 0.81], [0.0, 0.0, 1.0]]),
    np.array([60.0, 1.5]),
    np.array([[8.0, 7.5, 7.0], [0.25, 0.3, 0.4]]),
)


# -- fake model ---------------------------------------------------------------------------------------


class FakePredictor:
    """A :class:`ebr_mitsuba.model.predictor.Predictor` without a network: plausible maps from the
    flash-only image and a two-lobe environment; each ``predict`` call is counted in ``calls``."""

    grid = GRID
    takes_far = True

    def __init__(self, calls: list):
        self.calls = calls

    def load(self, path):
        """Stands in for :func:`ebr_mitsuba.estimate.pipeline.load_predictor` (for the shipped
        models too: a near-far capture's default is the shipped near-far model's file)."""
        from ebr_mitsuba.model.predict import shipped_model_path

        if path is not None and Path(path) == shipped_model_path(near_far=True):
            return self
        if path is not None and Path(path).read_bytes()[:9] != b"FAKE-CKPT":
            raise InputError(
                f"{path}: not an ebr model checkpoint (wrong kind); give a checkpoint of `ebr train`"
            )
        return self

    def predict(self, flash, noflash, far_flash=None, far_noflash=None):
        self.calls.append(
            {"shape": flash.shape, "noflash": noflash is not None, "far": far_flash is not None}
        )
        assert flash.shape == (GRID, GRID, 3) and flash.dtype == np.float32
        fo = flash if noflash is None else np.maximum(flash - noflash, 0)
        lum = fo.mean(axis=-1, keepdims=True)
        diffuse = np.clip(0.5 * fo / (lum.mean() * 2 + 1e-6), 0, 1)
        h, w = flash.shape[:2]
        maps = SVBRDF(
            normal=np.broadcast_to(np.float32([0, 0, 1]), (h, w, 3)).copy(),
            diffuse=diffuse,
            specular=np.full((h, w, 3), 0.04, np.float32),
            roughness=np.full((h, w), 0.5, np.float32),
        )
        env = None if noflash is None else ENV.scaled(0.8)
        return Prediction(maps, env, [fo * 0.1, fo * 0.2], fo, {"roughness": [0.2, 0.6]}, {"lighting": 0.01})


@pytest.fixture
def fake_net(monkeypatch):
    """``ebr estimate``, ``demo`` and ``gallery`` load the fake model (the calls of its ``predict``)."""
    from ebr_mitsuba.estimate import pipeline

    calls: list = []
    monkeypatch.setattr(pipeline, "load_predictor", FakePredictor(calls).load)
    return calls


# -- synthetic captures -----------------------------------------------------------------------------


def _material(n: int, seed: int = 3) -> SVBRDF:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n] / n
    checks = ((np.floor(x * 4) + np.floor(y * 4)) % 2)[..., None]
    # Checks modulated by random blocks of 7x7 cells: not periodic, so alignment is well posed.
    from ebr_mitsuba.imageio import resize_area

    blocks = 0.6 + 0.4 * resize_area(rng.random((7, 7, 1)).astype(np.float32), (n, n))
    diffuse = (0.55 * checks + 0.1 * (1 - checks)) * blocks * np.float32(
        [1.0, 0.75, 0.5]
    ) + 0.02 * rng.random((n, n, 3))
    return SVBRDF(
        normal=np.broadcast_to(np.float32([0, 0, 1]), (n, n, 3)).copy(),
        diffuse=diffuse.astype(np.float32),
        specular=np.full((n, n, 3), 0.05, np.float32),
        roughness=(0.3 + 0.2 * x).astype(np.float32),
    )


def _render(m: SVBRDF, shots) -> dict:
    from ebr_mitsuba.render import render_numpy

    return {s.name: render_numpy(m, ENV, s) for s in shots}


def _write_capture(tmp_path: Path, n: int = GRID, far: bool = False, suffix: str = ".exr") -> dict[str, Path]:
    shots = [near_shot(True), near_shot(False)] + ([far_shot(True), far_shot(False)] if far else [])
    paths = {}
    for name, img in _render(_material(n), shots).items():
        p = tmp_path / f"{name}{suffix}"
        if suffix == ".exr":
            write_exr(p, img)
        else:
            write_png(p, img / max(float(img.max()), 1e-6) * 0.9)
        paths[name] = p
    return paths


def _estimate(args, capsys):
    code = main(["estimate", *[str(a) for a in args]])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def _assert_refused(code, err, out_dir: Path):
    assert code == 2
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("ebr estimate: error:"), err
    assert "Traceback" not in err
    assert not out_dir.exists()
    assert not list(out_dir.parent.glob(f".{out_dir.name}*")), "partial output left behind"


# -- bad input: exit 2, one line, no output directory -----------------------------------------------


def test_mismatched_sizes(tmp_path, capsys, fake_net):
    paths = _write_capture(tmp_path)
    small = tmp_path / "small.exr"
    write_exr(small, np.ones((GRID // 2, GRID, 3), np.float32))
    out = tmp_path / "out"
    code, _, err = _estimate(["--flash", paths["flash"], "--noflash", small, "--out", out], capsys)
    _assert_refused(code, err, out)
    assert "differ in size" in err


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nonfinite_exr(tmp_path, capsys, fake_net, bad):
    paths = _write_capture(tmp_path)
    img = np.ones((GRID, GRID, 3), np.float32) * 0.1
    img[3, 5, 1] = bad
    write_exr(tmp_path / "bad.exr", img)
    out = tmp_path / "out"
    code, _, err = _estimate(
        ["--flash", paths["flash"], "--noflash", tmp_path / "bad.exr", "--out", out], capsys
    )
    _assert_refused(code, err, out)
    assert "NaN or Inf" in err


def _jpeg_bytes(n=GRID) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray((np.random.default_rng(0).random((n, n, 3)) * 255).astype(np.uint8)).save(buf, "JPEG")
    return buf.getvalue()


@pytest.mark.parametrize("content", ["truncated", "garbage"])
def test_unreadable_jpeg(tmp_path, capsys, fake_net, content):
    data = _jpeg_bytes()
    (tmp_path / "f.jpg").write_bytes(data[: len(data) // 2] if content == "truncated" else b"not a jpeg" * 50)
    (tmp_path / "nf.jpg").write_bytes(data)
    out = tmp_path / "out"
    code, _, err = _estimate(
        ["--flash", tmp_path / "f.jpg", "--noflash", tmp_path / "nf.jpg", "--out", out], capsys
    )
    _assert_refused(code, err, out)
    assert "f.jpg" in err


def test_missing_file(tmp_path, capsys, fake_net):
    paths = _write_capture(tmp_path)
    out = tmp_path / "out"
    code, _, err = _estimate(
        ["--flash", paths["flash"], "--noflash", tmp_path / "nope.exr", "--out", out], capsys
    )
    _assert_refused(code, err, out)
    assert "no such file" in err


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--far-flash", "{flash}"], "needs --far-noflash"),
        (["--far-noflash", "{noflash}"], "needs --far-flash"),
        (["--exposure-ratio", "2", "--noflash", None], "needs --noflash"),
        (["--refine-lobes", "--refine-steps", "5", "--noflash", None], "needs --noflash"),
        (["--refine-lobes"], "needs --refine-steps"),
        (["--refine-seconds", "5"], "needs --refine-steps"),
        (["--noflash", "{flash}"], "same file"),
    ],
)
def test_conflicting_flags(tmp_path, capsys, fake_net, extra, needle):
    paths = _write_capture(tmp_path)
    args = ["--flash", paths["flash"], "--noflash", paths["noflash"], "--out", tmp_path / "out"]
    extra = [e.format(**{k: str(v) for k, v in paths.items()}) if isinstance(e, str) else e for e in extra]
    if "--noflash" in extra:  # drop or replace the default --noflash
        i = extra.index("--noflash")
        value = extra[i + 1]
        del extra[i : i + 2]
        j = args.index("--noflash")
        del args[j : j + 2]
        if value is not None:
            args += ["--noflash", value]
    code, _, err = _estimate(args + extra, capsys)
    _assert_refused(code, err, tmp_path / "out")
    assert needle in err


def test_wrong_kind_checkpoint(tmp_path, capsys, fake_net):
    paths = _write_capture(tmp_path)
    ckpt = tmp_path / "model.pt"
    ckpt.write_bytes(b'{"something": "else"}')
    out = tmp_path / "out"
    code, _, err = _estimate(
        ["--flash", paths["flash"], "--noflash", paths["noflash"], "--checkpoint", ckpt, "--out", out], capsys
    )
    _assert_refused(code, err, out)
    assert "wrong kind" in err
    code, _, err = _estimate(
        ["--flash", paths["flash"], "--checkpoint", tmp_path / "missing.pt", "--out", out], capsys
    )
    _assert_refused(code, err, out)


def test_misaligned_and_swapped(tmp_path, capsys, fake_net):
    paths = _write_capture(tmp_path)
    from ebr_mitsuba.imageio import read_exr

    nf = read_exr(paths["noflash"])
    write_exr(tmp_path / "shifted.exr", np.roll(nf, (4, -3), axis=(0, 1)))
    out = tmp_path / "out"
    code, _, err = _estimate(
        ["--flash", paths["flash"], "--noflash", tmp_path / "shifted.exr", "--out", out], capsys
    )
    _assert_refused(code, err, out)
    assert "shifted by (-3, +4)" in err
    code, _, err = _estimate(["--flash", paths["noflash"], "--noflash", paths["flash"], "--out", out], capsys)
    _assert_refused(code, err, out)
    assert "swapped" in err


def test_out_dir_not_an_estimate_is_refused(tmp_path, capsys, fake_net):
    paths = _write_capture(tmp_path)
    out = tmp_path / "busy"
    out.mkdir()
    (out / "precious.txt").write_text("keep")
    code, _, err = _estimate(["--flash", paths["flash"], "--noflash", paths["noflash"], "--out", out], capsys)
    assert code == 2 and "not an estimate directory" in err
    assert (out / "precious.txt").read_text() == "keep"


# -- input checks as functions ----------------------------------------------------------------------


def test_shift_and_highlight_estimates():
    from ebr_mitsuba.estimate.inputs import estimate_shift, highlight_position

    imgs = _render(_material(64), [near_shot(True), near_shot(False)])
    est = estimate_shift(imgs["flash"], np.roll(imgs["noflash"], (5, -2), axis=(0, 1)))
    assert (est.dy, est.dx) == (5.0, -2.0) and est.prominence > 5 and est.confident
    est = estimate_shift(imgs["flash"], imgs["noflash"])
    assert (est.dy, est.dx) == (0.0, 0.0) and est.confident
    x, y = highlight_position(imgs["flash"] - imgs["noflash"])["position"]
    assert np.hypot(x, y) < 0.1  # co-located flash, fronto-parallel: the lobe is centred
    # An off-centre light (flash to the right): the peak moves right.
    from ebr_mitsuba.geometry import Shot
    from ebr_mitsuba.render import render_numpy

    side = render_numpy(_material(64), None, Shot("s", (0, 0, 2.414), 45.0, (1.0, 0.0, 1.5), 10.0, env=False))
    fit = highlight_position(side)
    x = fit["position"][0]
    assert fit["fit_r2"] > 0.3
    assert x > 0.35


def test_exif_exposure_and_saturation(tmp_path):
    from PIL import Image

    from ebr_mitsuba.estimate.inputs import load_inputs

    imgs = _render(_material(GRID), [near_shot(True), near_shot(False)])
    scale = 0.8 / float(imgs["flash"].max())

    def save(name, img, t):
        from ebr_mitsuba.imageio import linear_to_srgb

        codes = np.rint(linear_to_srgb(np.clip(img * scale, 0, 1)) * 255).astype(np.uint8)
        exif = Image.Exif()
        exif.get_ifd(0x8769).update({0x829A: t, 0x829D: 2.0, 0x8827: 100})
        Image.fromarray(codes).save(tmp_path / name, "JPEG", quality=98, exif=exif)

    save("f.jpg", imgs["flash"], 0.01)
    save("nf.jpg", imgs["noflash"] * 4, 0.04)  # four times the exposure
    inp = load_inputs(tmp_path / "f.jpg", tmp_path / "nf.jpg")
    assert inp.exposure["noflash"]["source"] == "exif"
    assert inp.exposure["noflash"]["factor"] == pytest.approx(0.25)
    ratio = inp.images["noflash"].mean() / (imgs["noflash"].mean() * scale)
    assert ratio == pytest.approx(1.0, rel=0.05)
    # --exposure-ratio overrides and says so.
    inp = load_inputs(tmp_path / "f.jpg", tmp_path / "nf.jpg", exposure_ratio=2.0)
    assert inp.exposure["noflash"]["factor"] == 0.5 and any("overrides" in w for w in inp.warnings)
    # Saturation: a clipped block is masked and warned about; a clipped frame is refused.
    sat = imgs["flash"] * scale
    sat[:10, :10] = 1.0
    write_png(tmp_path / "sat.png", sat)
    write_png(tmp_path / "nf.png", imgs["noflash"] * scale)
    inp = load_inputs(tmp_path / "sat.png", tmp_path / "nf.png")
    assert inp.saturated[:10, :10].all() and inp.saturated.mean() < 0.1
    assert any("saturated" in w for w in inp.warnings)
    write_png(tmp_path / "white.png", np.ones((GRID, GRID, 3), np.float32))
    with pytest.raises(InputError, match="saturated"):
        load_inputs(tmp_path / "white.png", tmp_path / "nf.png")


def test_fov_range():
    from ebr_mitsuba.estimate.inputs import check_fov

    assert check_fov(45) == 45.0
    for bad in (5.0, 150.0, float("nan")):
        with pytest.raises(InputError, match="--fov"):
            check_fov(bad)


# -- tiling -----------------------------------------------------------------------------------------


# -- refinement -------------------------------------------------------------------------------------


def test_refinement_lowers_rerender_error():
    from ebr_mitsuba.estimate.refine import RefineConfig, ShotTarget, refine

    n = 32
    truth = _material(n)
    shots = [near_shot(True), near_shot(False)]
    photos = _render(truth, shots)
    mask = np.ones((n, n), bool)
    targets = [ShotTarget(s, photos[s.name], mask) for s in shots]
    start = SVBRDF(
        normal=truth.normal,
        diffuse=np.clip(truth.diffuse * 0.6 + 0.1, 0, 1),
        specular=np.full((n, n, 3), 0.2, np.float32),
        roughness=np.full((n, n), 0.7, np.float32),
    )
    result = refine(start, ENV, targets, RefineConfig(steps=40))
    assert result.after["mean"]["rmse"] < 0.6 * result.before["mean"]["rmse"]
    assert result.history and result.history[-1][0] == 40
    # Maps stay valid (the constructor validated them) and move towards the truth.
    err = lambda m: float(np.sqrt(np.mean((m.diffuse - truth.diffuse) ** 2)))  # noqa: E731
    assert err(result.maps) < err(start)
    # With lobes: the lobes move and the error drops at least as much from a wrong environment.
    res2 = refine(start, ENV.scaled(1.5), targets, RefineConfig(steps=40, lobes=True))
    assert res2.after["mean"]["rmse"] < res2.before["mean"]["rmse"]
    assert not np.allclose(res2.env.amplitude, ENV.scaled(1.5).amplitude)


def test_basis_prior_recovers_two_materials_and_fits_the_photos():
    """basis_params' k-means finds the two (F0, roughness) materials of a two-material map; the
    refinement with K = 1 keeps specular and roughness spatially constant, with K = 2 within the
    two bases' hull, and lowers the re-render error of a wrong start."""
    from ebr_mitsuba.estimate.refine import RefineConfig, ShotTarget, basis_params, refine

    n = 32
    truth = _material(n)
    left = np.arange(n)[None, :] < n // 2
    spec = np.repeat(np.where(left[..., None], 0.04, 0.5).repeat(n, 0), 3, axis=2).astype(np.float32)
    rough = np.where(left, 0.3, 0.8).repeat(n, 0).astype(np.float32)
    two = SVBRDF(truth.normal, truth.diffuse, spec, rough)
    p = basis_params(two, 2)
    sig = lambda x: 1 / (1 + np.exp(-x))  # noqa: E731
    got = sorted(zip(sig(p["basis_roughness"]), sig(p["basis_specular"]).reshape(2, 3)[:, 0]))
    np.testing.assert_allclose(got, [(0.3, 0.04), (0.8, 0.5)], atol=1e-3)
    assert p["basis_weights"].shape == (n, n, 2)

    shots = [near_shot(True), near_shot(False)]
    photos = _render(two, shots)
    mask = np.ones((n, n), bool)
    targets = [ShotTarget(s, photos[s.name], mask) for s in shots]
    start = SVBRDF(
        truth.normal,
        np.clip(truth.diffuse * 0.7 + 0.05, 0, 1),
        np.full((n, n, 3), 0.2, np.float32),
        np.full((n, n), 0.6, np.float32),
    )
    one = refine(start, ENV, targets, RefineConfig(steps=30, basis=1))
    assert one.after["mean"]["rmse"] < one.before["mean"]["rmse"]
    assert np.ptp(one.maps.roughness) < 1e-5 and np.ptp(one.maps.specular[..., 0]) < 1e-5
    two_start = SVBRDF(start.normal, start.diffuse, spec, rough)
    res = refine(two_start, ENV, targets, RefineConfig(steps=30, basis=2))
    assert res.after["mean"]["rmse"] <= res.before["mean"]["rmse"]
    lo, hi = res.maps.roughness.min(), res.maps.roughness.max()
    assert hi - lo > 0.2  # two materials stay two
    with pytest.raises(InputError, match="--refine-basis"):
        RefineConfig(basis=-1)


# -- the whole pipeline -----------------------------------------------------------------------------


def _check_outputs(out: Path, summary: dict, flash_only: bool = False, far: bool = False):
    for name in ("normal", "diffuse", "specular", "roughness"):
        assert (out / "maps" / f"{name}.exr").is_file() and (out / "maps" / f"{name}.png").is_file()
    assert (out / "report.html").is_file() and (out / "estimate.json").is_file()
    assert (out / "env.json").is_file() != flash_only
    assert (out / "env_sphere.png").is_file() != flash_only
    shots = ["flash"] + ([] if flash_only else ["noflash"]) + (["far_flash", "far_noflash"] if far else [])
    for s in shots:
        for sub, ext in (("rerender", "exr"), ("rerender", "png"), ("residual", "exr"), ("residual", "png")):
            assert (out / sub / f"{s}.{ext}").is_file(), f"{sub}/{s}.{ext}"
    assert list((out / "novel").glob("*.png"))
    html = (out / "report.html").read_text()
    assert 'src="data:image/png;base64,' in html and 'src="http' not in html and 'src="maps' not in html
    assert ("How the maps were read" in html) == (summary.get("flash_fit") is not None)
    for f in summary["files"]:
        assert (out / f).exists(), f
    assert set(summary["timings"]) >= {"inputs", "model", "maps", "rerender", "outputs", "report"}


def test_estimate_near_with_refinement_json(tmp_path, capsys, fake_net):
    paths = _write_capture(tmp_path)
    out = tmp_path / "est"
    code, stdout, err = _estimate(
        [
            "--flash",
            paths["flash"],
            "--noflash",
            paths["noflash"],
            "--out",
            out,
            "--refine-steps",
            "15",
            "--flash-intensity",
            "10",
            "--json",
        ],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout)
    _check_outputs(out, summary)
    assert summary["capture"] == "near" and summary["flash"]["flash"]["source"] == "--flash-intensity"
    before = summary["rerender_error"]["network"]["mean"]["rmse"]
    after = summary["rerender_error"]["refined"]["mean"]["rmse"]
    assert after < before
    assert (out / "maps_network" / "diffuse.exr").is_file()
    html = (out / "report.html").read_text()
    assert "Refinement" in html and f"{before:.4g}" in html and f"{after:.4g}" in html
    assert fake_net and fake_net[0]["noflash"]
    # A second run replaces the earlier estimate directory.
    code, _, err = _estimate(["--flash", paths["flash"], "--noflash", paths["noflash"], "--out", out], capsys)
    assert code == 0, err
    assert not (out / "maps_network").exists()


def test_estimate_refines_against_the_flash_only_image(tmp_path, capsys, fake_net):
    """--refine-target flash-only fits flash − no-flash under the flash alone; the written
    re-renders and errors are still of the input shots (both), after the refinement."""
    paths = _write_capture(tmp_path)
    out = tmp_path / "est"
    args = ["--flash", paths["flash"], "--noflash", paths["noflash"], "--out", out, "--refine-steps", "15"]
    code, stdout, err = _estimate(
        args + ["--flash-intensity", "10", "--refine-target", "flash-only", "--json"], capsys
    )
    assert code == 0, err
    summary = json.loads(stdout)
    _check_outputs(out, summary)
    refined = summary["rerender_error"]["refined"]
    assert set(refined) >= {"flash", "noflash", "mean"}
    assert all(np.isfinite(refined[s]["rmse"]) for s in ("flash", "noflash"))
    assert refined["flash"]["rmse"] != summary["rerender_error"]["network"]["flash"]["rmse"]
    assert summary["refine"]["target"] == "flash-only" and summary["refine"]["weighting"] == "signal"
    code, _, err = _estimate(args + ["--refine-target", "flash"], capsys)
    assert code == 2 and "--refine-target" in err and "flash-only" in err
    # noise weighting: recorded with the maps it held fixed (the normals too without shading normals)
    noise = ["--refine-weighting", "noise", "--refine-fixed", "specular", "roughness", "--json"]
    code, stdout, err = _estimate(
        args + ["--flash-intensity", "10", "--refine-target", "flash-only"] + noise, capsys
    )
    assert code == 0, err
    record = json.loads(stdout)["refine"]
    assert record["weighting"] == "noise" and {"specular", "roughness"} <= set(record["fixed"])
    shading = json.loads(stdout).get("shading_normals") or {}
    assert ("normal" in record["fixed"]) == (not shading.get("applied", False))
    code, _, err = _estimate(args + ["--refine-weighting", "loud"], capsys)
    assert code == 2 and "--refine-weighting" in err


def test_estimate_near_far_from_capture_dir(tmp_path, capsys, fake_net):
    from ebr_mitsuba.capture import capture

    cap = tmp_path / "cap"
    capture(_material(GRID), ENV, "near-far", cap, spp=4, res=GRID, progress=False)
    out = tmp_path / "est"
    code, stdout, err = _estimate(
        [
            "--flash",
            cap / "flash.exr",
            "--noflash",
            cap / "noflash.exr",
            "--far-flash",
            cap / "far_flash.exr",
            "--far-noflash",
            cap / "far_noflash.exr",
            "--out",
            out,
            "--json",
        ],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout)
    _check_outputs(out, summary, far=True)
    assert summary["capture"] == "near-far"
    assert summary["flash"]["flash"] == {"intensity": 10.0, "source": "capture.json"}
    assert summary["flash"]["far_flash"]["source"] == "capture.json"
    assert fake_net[0]["far"]
    assert not any("--far-flash-ratio" in w for w in summary["warnings"])


def test_estimate_flash_only_png(tmp_path, capsys, fake_net):
    paths = _write_capture(tmp_path, suffix=".png")
    out = tmp_path / "est"
    code, stdout, err = _estimate(["--flash", paths["flash"], "--out", out, "--json"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    _check_outputs(out, summary, flash_only=True)
    assert summary["capture"] == "flash-only" and summary["lobes"] == 0
    assert summary["flash"]["flash"]["source"] == "fitted"
    assert not fake_net[0]["noflash"]


def test_estimate_max_size_at_the_grid(tmp_path, capsys, fake_net):
    """An 80² capture with --max-size at the model grid: one call at the grid (lighting and maps),
    the photos area-averaged down, with the warning that names both sizes."""
    paths = _write_capture(tmp_path, n=80)
    out = tmp_path / "est"
    code, stdout, err = _estimate(
        [
            "--flash",
            paths["flash"],
            "--noflash",
            paths["noflash"],
            "--out",
            out,
            "--max-size",
            str(GRID),
            "--json",
        ],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["resolution"] == GRID and summary["tiles"] == 1 and len(fake_net) == 1
    assert f"the photos are 80x80 pixels: estimating at {GRID}x{GRID}" in err
    from ebr_mitsuba.imageio import read_exr

    assert read_exr(out / "maps" / "diffuse.exr").shape == (GRID, GRID, 3)


def test_real_model_end_to_end(tmp_path, capsys):
    """The shipped model on a generated near capture."""
    from ebr_mitsuba.model.predict import load_predictor

    grid = load_predictor(None).grid
    paths = _write_capture(tmp_path, n=grid)
    out = tmp_path / "est"
    code, stdout, err = _estimate(
        [
            "--flash",
            paths["flash"],
            "--noflash",
            paths["noflash"],
            "--out",
            out,
            "--refine-steps",
            "20",
            "--json",
        ],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout)
    _check_outputs(out, summary)
    ckpt = tmp_path / "wrong.pt"
    import torch

    torch.save({"not": "a model"}, ckpt)
    code, _, err = _estimate(
        ["--flash", paths["flash"], "--checkpoint", ckpt, "--out", tmp_path / "o2"], capsys
    )
    _assert_refused(code, err, tmp_path / "o2")


def test_real_model_near_far_and_real_flash_only_photo(tmp_path, capsys, data_dir):
    """The shipped models on a generated near-far capture (the near-far model, reading the four
    shots, refined 5 steps) and on a real flash-only phone photo (upsampled to twice the model grid,
    estimated at --max-size = the grid: downscaled with a warning)."""
    from ebr_mitsuba.capture import capture
    from ebr_mitsuba.model.predict import load_predictor

    grid = load_predictor(None).grid
    cap = tmp_path / "cap"
    capture(_material(grid), ENV, "near-far", cap, spp=4, res=grid, progress=False)
    out = tmp_path / "nf"
    argv = ["--flash", cap / "flash.exr", "--noflash", cap / "noflash.exr"]
    argv += ["--far-flash", cap / "far_flash.exr", "--far-noflash", cap / "far_noflash.exr"]
    argv += ["--out", out, "--refine-steps", "5", "--json"]
    code, stdout, err = _estimate(argv, capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    _check_outputs(out, summary, far=True)
    assert summary["model"]["takes_far"] and summary["refine"]["steps"] == 5
    assert not any("far shots are used for the re-renders" in w for w in summary["inputs"]["warnings"])
    from PIL import Image

    photo = sorted((data_dir / "photos" / "flash_only").glob("*.png"))[0]
    big = tmp_path / "photo_2x.png"  # twice the grid, whatever the grid: --max-size downscales it
    Image.open(photo).convert("RGB").resize((2 * grid, 2 * grid), Image.BICUBIC).save(big)
    out = tmp_path / "photo"
    code, stdout, err = _estimate(["--flash", big, "--out", out, "--max-size", str(grid), "--json"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    _check_outputs(out, summary, flash_only=True)
    assert summary["resolution"] == grid and summary["tiles"] == 1
    assert any(f"estimating at {grid}x{grid}" in w for w in summary["warnings"])


# -- demo -------------------------------------------------------------------------------------------


def test_demo_with_fake_network(tmp_path, capsys, fake_net):
    out = tmp_path / "demo"
    # at the fake's grid (the demo's default 256² takes the full-resolution path, which the fake lacks)
    args = ["demo", "--out", str(out), "--res", str(GRID), "--spp", "4", "--refine-steps", "10", "--json"]
    code = main(args)
    cap = capsys.readouterr()
    assert code == 0, cap.err
    result = json.loads(cap.out)
    assert set(result["map_error"]["network"]) == {"normal", "diffuse", "specular", "roughness", "mean"}
    assert result["map_error"]["refined"] is not None
    assert result["lighting_error"]["rmse"] >= 0
    assert (out / "estimate" / "report.html").is_file() and (out / "demo.png").is_file()
    assert (out / "capture" / "maps" / "diffuse.exr").is_file()
    assert "per-map RMSE" in cap.err and "report:" in cap.err
    html = (out / "estimate" / "report.html").read_text()
    assert "Against ground truth" in html


def test_demo_material_matches_the_default_scene():
    """The demo's ground truth is the checkerboard Mitsuba renders from scenes/default.xml: same
    colour layout (bottom-left square colour 0)."""
    from ebr_mitsuba.commands.demo import CHECKER_COLORS, default_material

    m = default_material(64)
    np.testing.assert_allclose(m.diffuse[-1, 0], CHECKER_COLORS[0], atol=1e-6)
    np.testing.assert_allclose(m.diffuse[-1, 8], CHECKER_COLORS[1], atol=1e-6)
    np.testing.assert_allclose(m.diffuse[0, 0], CHECKER_COLORS[1], atol=1e-6)  # 8 squares: top-left odd


# -- gallery ----------------------------------------------------------------------------------------


def _gallery(argv, capsys):
    """``ebr gallery`` through its module (cli.COMMANDS lists it once the lead registers it)."""
    import argparse

    from ebr_mitsuba.commands import gallery

    parser = argparse.ArgumentParser()
    gallery.add_arguments(parser)
    code = gallery.run(parser.parse_args([str(a) for a in argv]))
    return code, capsys.readouterr()


def test_gallery_page(tmp_path, capsys, fake_net):
    photos = tmp_path / "photos"
    photos.mkdir()
    imgs = _render(_material(GRID), [near_shot(True, env=False)])
    write_png(photos / "b.png", imgs["flash"] / imgs["flash"].max() * 0.8)
    write_png(photos / "a.png", imgs["flash"][::-1] / imgs["flash"].max() * 0.7)
    (photos / "LICENSE.txt").write_text("MIT")
    code, cap = _gallery([photos, "--docs", tmp_path / "docs", "--json"], capsys)
    assert code == 0
    result = json.loads(cap.out)
    assert [p["name"] for p in result["photos"]] == ["a.png", "b.png"]
    page = (tmp_path / "docs" / "gallery.md").read_text()
    assert "![a.png](gallery/a.png)" in page and "## b.png" in page
    assert (tmp_path / "docs" / "gallery" / "a.png").is_file()
    assert all(not c["noflash"] for c in fake_net)
    from ebr_mitsuba.estimate.gallery import find_photos

    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="no PNG"):
        find_photos(empty)
    with pytest.raises(InputError, match="no such photo folder"):
        find_photos(tmp_path / "missing")


@pytest.mark.slow
def test_gallery_real_photos(tmp_path, capsys, data_dir):
    """The 13 real flash-only photos with the shipped model."""
    code, cap = _gallery([data_dir / "photos" / "flash_only", "--docs", tmp_path, "--json"], capsys)
    assert code == 0
    assert len(json.loads(cap.out)["photos"]) == 13


# -- issue 16: exposure hint, refinement at the grid, alignment confidence ---------------------------


def test_unequal_exposure_without_exif_suggests_exposure_ratio(tmp_path):
    """Two PNGs without EXIF, the no-flash one exposed 6× longer: the refusal names
    --exposure-ratio (and the ratio needed); with it the pair loads."""
    from ebr_mitsuba.estimate.inputs import load_inputs

    imgs = _render(_material(GRID), [near_shot(True), near_shot(False)])
    scale = 0.8 / float(imgs["flash"].max())
    ratio = 6.0
    assert imgs["noflash"].mean() * ratio > imgs["flash"].mean()  # the no-flash PNG is the brighter
    write_png(tmp_path / "f.png", imgs["flash"] * scale)
    write_png(tmp_path / "nf.png", np.clip(imgs["noflash"] * scale * ratio, 0, 0.9))
    hint = r"swapped.*--exposure-ratio R \(no-flash exposure ÷ flash exposure; here R > "
    with pytest.raises(InputError, match=hint):
        load_inputs(tmp_path / "f.png", tmp_path / "nf.png")
    inp = load_inputs(tmp_path / "f.png", tmp_path / "nf.png", exposure_ratio=ratio)
    assert inp.exposure["noflash"] == {"factor": 1 / ratio, "source": "--exposure-ratio"}
    # With an explicit ratio (or EXIF) the hint is not repeated: the shots are then really swapped.
    with pytest.raises(InputError, match="swapped") as exc:
        load_inputs(tmp_path / "f.png", tmp_path / "nf.png", exposure_ratio=1.0)
    assert "--exposure-ratio" not in str(exc.value)


def test_grid_refinement_above_the_grid(tmp_path, capsys, fake_net):
    """--max-size at the grid with --refine-steps N on an input above the model grid: the
    saturation mask is resampled as a 2-D mask (it became (64,) and every refinement failed)."""
    from ebr_mitsuba.estimate.inputs import load_inputs

    paths = _write_capture(tmp_path, n=64)
    inp = load_inputs(paths["flash"], paths["noflash"])
    assert inp.resampled((GRID, GRID)).saturated.shape == (GRID, GRID)
    out = tmp_path / "est"
    code, stdout, err = _estimate(
        [
            "--flash",
            paths["flash"],
            "--noflash",
            paths["noflash"],
            "--out",
            out,
            "--max-size",
            str(GRID),
            "--refine-steps",
            "2",
            "--flash-intensity",
            "10",
            "--json",
        ],
        capsys,
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["resolution"] == GRID and summary["refine"]["steps"] == 2


def test_refinement_shape_error_names_every_shape():
    from ebr_mitsuba.estimate.refine import RefineConfig, ShotTarget, refine

    maps = _material(8)
    bad = ShotTarget(near_shot(True), np.zeros((8, 8, 3), np.float32), np.ones(8, bool))
    with pytest.raises(InputError, match=r"image \(8, 8\), mask \(8,\); the maps are \(8, 8\)"):
        refine(maps, ENV, [bad], RefineConfig(steps=1))


def test_alignment_refuses_only_confident_shifts(tmp_path):
    """`ebr capture` shots are aligned by construction: dark, noisy captures of a bare plate and
    of copper (64², 16 spp; the old check refused every one of these as shifted by 3–8 px) load,
    at most with a warning that alignment could not be verified. A genuinely shifted textured
    capture is still refused."""
    from ebr_mitsuba.capture import capture
    from ebr_mitsuba.estimate.inputs import load_inputs
    from ebr_mitsuba.imageio import read_exr

    plate = SVBRDF.uniform(64, 64, diffuse=0.5, specular=0.04, roughness=0.1)
    copper = SVBRDF.uniform(64, 64, diffuse=0.0, specular=(0.955, 0.638, 0.538), roughness=0.25)
    cases = [
        (plate, "procedural:1", 1.0, 0),
        (plate, "procedural:1", 1.0, 1),
        (copper, "procedural:1", 1.0, 1),
        (plate, "procedural:2", 0.1, 1),
        (plate, "procedural:3", 1.0, 0),
    ]
    for k, (material, env, scale, seed) in enumerate(cases):
        cap = tmp_path / f"dark{k}"
        capture(material, env, "near", cap, spp=16, res=64, seed=seed, env_scale=scale, progress=False)
        inp = load_inputs(cap / "flash.exr", cap / "noflash.exr")  # no refusal
        est = inp.alignment["near"]
        assert not est["confident"] and est["peak_ratio"] < 2.0, (k, est)
        assert any("alignment could not be verified" in w for w in inp.warnings), (k, inp.warnings)
    # Dark and noisy: a textured sample under a dim environment with sensor-like noise.
    imgs = _render(_material(64), [near_shot(True), near_shot(False)])
    rng = np.random.default_rng(5)
    dark = imgs["noflash"] * 0.05
    noisy = np.maximum(dark + rng.normal(0.0, 2.0 * float(dark.mean()), dark.shape), 0).astype(np.float32)
    write_exr(tmp_path / "f.exr", imgs["flash"])
    write_exr(tmp_path / "dark.exr", noisy)
    inp = load_inputs(tmp_path / "f.exr", tmp_path / "dark.exr")
    assert inp.alignment["near"]["texture_to_noise"][1] < inp.alignment["near"]["texture_to_noise"][0]
    # A genuine shift of a textured capture: confident, refused.
    cap = tmp_path / "textured"
    capture(_material(64), "procedural:1", "near", cap, spp=16, res=64, seed=0, progress=False)
    write_exr(tmp_path / "shifted.exr", np.roll(read_exr(cap / "noflash.exr"), (4, -3), axis=(0, 1)))
    with pytest.raises(InputError, match=r"shifted by \(-3, \+4\) pixels .*peak ratio"):
        load_inputs(cap / "flash.exr", tmp_path / "shifted.exr")
    assert load_inputs(cap / "flash.exr", cap / "noflash.exr").alignment["near"]["confident"]


def _refine_problem(n: int = 16):
    """A 16² material's near shots as refinement targets and a start that is off on every map but
    the normals (diffuse dimmed, specular 0.2, roughness 0.7)."""
    from ebr_mitsuba.estimate.refine import ShotTarget

    truth = _material(n)
    shots = [near_shot(True), near_shot(False)]
    photos = _render(truth, shots)
    targets = [ShotTarget(s, photos[s.name], np.ones((n, n), bool)) for s in shots]
    start = SVBRDF(
        normal=truth.normal,
        diffuse=np.clip(truth.diffuse * 0.6 + 0.1, 0, 1),
        specular=np.full((n, n, 3), 0.2, np.float32),
        roughness=np.full((n, n), 0.7, np.float32),
    )
    return start, targets


def test_refinement_leaves_fixed_maps_alone():
    """``fixed`` maps come back exactly as they went in while the free ones move and the photos'
    error falls; fixing specular or roughness beside a basis prior is refused with the fix."""
    from ebr_mitsuba.estimate.refine import RefineConfig, refine

    start, targets = _refine_problem()
    res = refine(start, ENV, targets, RefineConfig(steps=20, fixed=["specular", "roughness"]))
    assert res.after["mean"]["rmse"] < res.before["mean"]["rmse"]
    np.testing.assert_array_equal(res.maps.specular, start.specular)
    np.testing.assert_array_equal(res.maps.roughness, start.roughness)
    assert np.abs(res.maps.diffuse - start.diffuse).max() > 1e-3
    with pytest.raises(InputError, match="--refine-fixed roughness with --refine-basis 2"):
        RefineConfig(basis=2, fixed=["roughness"])
    with pytest.raises(InputError, match="--refine-fixed"):
        RefineConfig(fixed=["albedo"])


def test_refinement_keeps_the_best_iterate():
    """A diverging refinement (learning rate 30) returns the maps it started from and says the loss
    rose; an oscillating one (lr 0.3, no decay) returns its best iterate, the one a shorter run
    ends on; a converging one keeps its last step."""
    from ebr_mitsuba.estimate.refine import RefineConfig, refine

    start, targets = _refine_problem()

    wild = refine(start, ENV, targets, RefineConfig(steps=10, lr=30.0, normal_lr=3.0, log_every=5))
    assert [s for s, _ in wild.history] == [0, 5, 10] and wild.history[-1][1] > wild.history[0][1]
    assert wild.kept_step == 0 and wild.loss_rose
    assert wild.loss_note() == (
        f"loss rose from {wild.history[0][1]:.4g} to {wild.history[-1][1]:.4g}; kept step 0"
    )
    for name in ("diffuse", "specular", "roughness", "normal"):
        np.testing.assert_allclose(getattr(wild.maps, name), getattr(start, name), atol=1e-5)
    assert wild.after["mean"]["rmse"] == pytest.approx(wild.before["mean"]["rmse"], rel=1e-5)

    cfg = dict(lr=0.3, normal_lr=0.03, log_every=2, final_lr_fraction=1.0)
    wobbly = refine(start, ENV, targets, RefineConfig(steps=8, **cfg))
    losses = dict(wobbly.history)
    assert wobbly.kept_step == min(losses, key=losses.get) and 0 < wobbly.kept_step < 8
    assert wobbly.loss_rose and f"kept step {wobbly.kept_step}" in wobbly.loss_note()
    short = refine(start, ENV, targets, RefineConfig(steps=wobbly.kept_step, **cfg))
    np.testing.assert_allclose(wobbly.maps.diffuse, short.maps.diffuse, atol=1e-6)

    good = refine(start, ENV, targets, RefineConfig(steps=10, log_every=5))
    assert good.kept_step == 10 and not good.loss_rose and good.loss_note() is None


def test_diverging_refinement_is_reported(tmp_path, capsys, fake_net):
    """`ebr estimate --refine-lr 50`: the summary line and report.html say the loss rose and which
    step was kept; the maps written are the network's."""
    from ebr_mitsuba.imageio import read_exr

    paths = _write_capture(tmp_path)
    out = tmp_path / "est"
    args = [
        "--flash",
        paths["flash"],
        "--noflash",
        paths["noflash"],
        "--out",
        out,
        "--refine-steps",
        "10",
        "--refine-lr",
        "50",
        "--flash-intensity",
        "10",
    ]
    code, _, err = _estimate(args, capsys)
    assert code == 0, err
    assert "loss rose from" in err and "kept step 0" in err
    summary = json.loads((out / "estimate.json").read_text())
    assert summary["refine"]["loss_rose"] and summary["refine"]["kept_step"] == 0
    assert "loss rose from" in (out / "report.html").read_text()
    np.testing.assert_allclose(
        read_exr(out / "maps" / "diffuse.exr"), read_exr(out / "maps_network" / "diffuse.exr"), atol=1e-5
    )


def test_near_model_on_a_near_far_capture(tmp_path, capsys):
    """The shipped near model given a near-far capture: the far pair stays out of the network (a
    near model refuses it; the maps pass used to hand it over) and serves the flash fit and the
    re-renders; the summary warns that the model reads near captures only."""
    from ebr_mitsuba.capture import capture
    from ebr_mitsuba.model.predict import shipped_model_path

    cap = tmp_path / "cap"
    capture(_material(128), ENV, "near-far", cap, spp=4, res=128, progress=False)  # above the grid
    out = tmp_path / "est"
    shots = ["--flash", cap / "flash.exr", "--noflash", cap / "noflash.exr"]
    shots += ["--far-flash", cap / "far_flash.exr", "--far-noflash", cap / "far_noflash.exr"]
    code, stdout, err = _estimate(
        [*shots, "--checkpoint", shipped_model_path(), "--out", out, "--json"], capsys
    )
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["capture"] == "near-far"
    assert any("near captures only" in w for w in summary["warnings"])
    assert summary["flash_fit"] is not None and 0.0 < summary["flash_fit"]["roughness"] <= 1.0
    decision = summary["flash_fit"]["decision"]  # the metal-or-dielectric decision, recorded
    assert set(decision) == {"metal_ratio", "metal_level", "metal_roughness"}
    assert summary["flash_fit"]["metal"] == (
        decision["metal_ratio"] < 0.5 and decision["metal_roughness"] < 0.75
    )
    assert (out / "renders" / "far_flash.exr").is_file() or any(out.rglob("*far_flash*"))


def test_a_near_far_capture_uses_the_shipped_near_far_model(tmp_path, capsys):
    """No --checkpoint and far shots: ebr estimate loads ebrenv_near_far.pt (it reads all four
    shots), and the flash fit reads the roughness off the far pair; a near capture keeps the near
    model."""
    from ebr_mitsuba.capture import capture
    from ebr_mitsuba.model.predict import shipped_model_path

    assert shipped_model_path(near_far=True).is_file()
    cap = tmp_path / "cap"
    capture(_material(64), ENV, "near-far", cap, spp=4, res=64, progress=False)
    near = ["--flash", cap / "flash.exr", "--noflash", cap / "noflash.exr"]
    far = ["--far-flash", cap / "far_flash.exr", "--far-noflash", cap / "far_noflash.exr"]
    code, stdout, err = _estimate([*near, *far, "--out", tmp_path / "nf", "--json"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["model"] == {"checkpoint": str(shipped_model_path(near_far=True)), "takes_far": True}
    assert not any("near captures only" in w for w in summary["warnings"])
    assert summary["flash_fit"]["far_pair"] is True
    code, stdout, err = _estimate([*near, "--out", tmp_path / "n", "--json"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert summary["model"] == {"checkpoint": str(shipped_model_path()), "takes_far": False}
    assert summary["flash_fit"]["far_pair"] is False


def test_shading_normals_follow_the_relief_and_can_be_switched_off(tmp_path, capsys):
    """A tiled sample whose grout is both darker and lower than the tiles (procedural:tiles), under
    a sun: the default normals come from the flash / no-flash shading (estimate.json records the
    fit) and are closer to the truth than the network's (--no-shading-normals), whose run records
    none."""
    from ebr_mitsuba.capture import capture
    from ebr_mitsuba.materials import load_material_dir
    from ebr_mitsuba.metrics import map_rmse

    cap = tmp_path / "cap"
    capture("procedural:tiles:1", ENV, "near", cap, spp=16, res=128, progress=False)
    shots = ["--flash", cap / "flash.exr", "--noflash", cap / "noflash.exr"]
    code, stdout, err = _estimate([*shots, "--out", tmp_path / "sn", "--json"], capsys)
    assert code == 0, err
    record = json.loads(stdout)["shading_normals"]
    assert record["applied"] is True and record["glint_ratio"] <= 1.0
    assert record["coefficient"] > 0 and record["pixels"] > 0
    assert set(record["relief"]) == {"sky_gradient", "slope_rms", "noise_rms"} and record["relief_gain"] > 0
    html = (tmp_path / "sn" / "report.html").read_text()
    assert "the relief the albedo does not show" in html
    code, stdout, err = _estimate(
        [*shots, "--out", tmp_path / "net", "--no-shading-normals", "--json"], capsys
    )
    assert code == 0, err
    assert json.loads(stdout)["shading_normals"] is None
    truth = load_material_dir(cap / "maps")
    shaded, network = (
        load_material_dir(tmp_path / "sn" / "maps"),
        load_material_dir(tmp_path / "net" / "maps"),
    )
    # by a margin that depends on the shipped network: 0.064 against 0.071 with the 256² model
    assert map_rmse(shaded, truth)["normal"] < 0.95 * map_rmse(network, truth)["normal"]
    # larger gains (--normal-gain, --relief-gain) give the normal map more relief, recorded as used
    code, stdout, err = _estimate(
        [*shots, "--out", tmp_path / "more", "--normal-gain", "1", "--relief-gain", "1.5", "--json"], capsys
    )
    assert code == 0, err
    more = json.loads(stdout)["shading_normals"]
    assert more["map_gain"] == 1.0 and more["relief_gain"] == 1.5 and record["relief_gain"] == 0.75
    more_maps = load_material_dir(tmp_path / "more" / "maps")
    more_html = (tmp_path / "more" / "report.html").read_text()
    assert "× 1 in the map, --normal-gain" in more_html and "× 1.5 in the map, --relief-gain" in more_html

    def spread(maps):
        return float(np.mean(maps.normal[..., :2].reshape(-1, 2).std(axis=0)))

    assert spread(more_maps) > 1.2 * spread(shaded)


def test_roughness_pattern_is_recorded_and_can_be_switched_off(tmp_path, capsys):
    """A procedural tile capture read as a dielectric: estimate.json records the roughness
    pattern's reading, and the roughness map follows it (its mean the fitted roughness, a spread
    when applied); --no-roughness-pattern keeps the fitted constant and records none."""
    from ebr_mitsuba.capture import capture
    from ebr_mitsuba.materials import load_material_dir

    cap = tmp_path / "cap"
    capture("procedural:tiles:1", ENV, "near", cap, spp=8, res=96, progress=False)
    shots = ["--flash", cap / "flash.exr", "--noflash", cap / "noflash.exr"]
    code, stdout, err = _estimate([*shots, "--out", tmp_path / "on", "--json"], capsys)
    assert code == 0, err
    fit = json.loads(stdout)["flash_fit"]
    assert not fit["metal"] and fit["roughness_from"] == "fit"
    pattern = fit["roughness_pattern"]
    rough = load_material_dir(tmp_path / "on" / "maps").roughness
    if pattern["applied"]:
        assert pattern["slope"] != 0.0 and float(np.std(rough)) > 0.0
    else:
        assert pattern["reason"] and float(np.std(rough)) == 0.0
    assert abs(float(np.mean(rough)) - fit["roughness"]) < 0.02
    code, stdout, err = _estimate(
        [*shots, "--out", tmp_path / "off", "--no-roughness-pattern", "--json"], capsys
    )
    assert code == 0, err
    off = json.loads(stdout)["flash_fit"]
    assert off["roughness_pattern"] is None and off["roughness_from"] == "fit"
    constant = load_material_dir(tmp_path / "off" / "maps").roughness
    assert float(np.ptp(constant)) == 0.0 and float(constant.mean()) == pytest.approx(
        off["roughness"], abs=1e-4
    )


def test_phone_far_pair_needs_the_far_flash_ratio(tmp_path, capsys, fake_net):
    """A phone's far pair: its one flash from four times farther, so the far flash-only image is
    (far / near)² ≈ 17× darker than ``ebr capture``'s (whose far flash is as bright at the sample).
    Without capture.json the flash fit assumes the latter and the near − far rings read nonsense;
    ``--far-flash-ratio 1`` states the phone's case and the roughness comes out right."""
    material = _material(GRID)  # the fake model's grid
    shots = [near_shot(True), near_shot(False), far_shot(True, intensity=10.0), far_shot(False)]
    paths = {}
    for name, img in _render(material, shots).items():
        paths[name] = tmp_path / f"{name}.exr"
        write_exr(paths[name], img)
    args = ["--flash", paths["flash"], "--noflash", paths["noflash"]]
    args += ["--far-flash", paths["far_flash"], "--far-noflash", paths["far_noflash"]]
    truth = float(material.roughness.mean())
    rough = {}
    for ratio in (None, 1.0):
        extra = [] if ratio is None else ["--far-flash-ratio", ratio]
        code, stdout, err = _estimate([*args, *extra, "--out", tmp_path / f"est{ratio}", "--json"], capsys)
        assert code == 0, err
        summary = json.loads(stdout)
        fit = summary["flash_fit"]
        assert fit["far_pair"] is True
        rough[ratio] = fit["roughness"]
        warned = [w for w in summary["warnings"] if "--far-flash-ratio 1" in w]
        assert len(warned) == (ratio is None), summary["warnings"]  # said when not stated
    assert abs(rough[1.0] - truth) < 0.1
    assert abs(rough[None] - truth) > 0.2  # the assumption a phone's far pair breaks

    code, _, err = _estimate([*args[:4], "--far-flash-ratio", 1, "--out", tmp_path / "bad"], capsys)
    _assert_refused(code, err, tmp_path / "bad")
    assert "--far-flash-ratio needs --far-flash" in err


def test_report_says_how_the_flash_fit_read_the_maps():
    from ebr_mitsuba.estimate.report import flash_fit_rows

    fit = {
        "roughness": 0.41,
        "specular": [0.04, 0.04, 0.04],
        "diffuse_level": [0.3, 0.2, 0.1],
        "metal": False,
        "far_pair": False,
        "relief": None,
        "misfit": 0.0002,
        "pixel_median": {"roughness": 0.4, "profile": 0.42, "used": True},
        "decision": {"metal_ratio": 0.3, "metal_level": 0.9, "metal_roughness": 1.0},
        "roughness_from": "fit",
    }
    rows = dict((k, v) for k, v in flash_fit_rows(fit))
    assert rows["material read as"].startswith("dielectric")
    assert (
        "0.3 (a metal needs below 0.5" in rows["metal or dielectric"]
        and "roughness 1" in rows["metal or dielectric"]
    )
    assert "pixel-median reading's 0.4" in rows["roughness"]
    assert "roughness pattern" not in rows
    patterned = dict(
        flash_fit_rows(
            {**fit, "roughness_pattern": {"applied": True, "slope": -0.108, "read": -0.054, "stderr": 0.0025}}
        )
    )
    assert patterned["roughness pattern"].startswith("-0.108 roughness per unit of log-albedo")
    skipped = {"applied": False, "slope": 0.0, "reason": "roughness 0.875 > 0.7"}
    assert (
        "not read (roughness 0.875 > 0.7)"
        in dict(flash_fit_rows({**fit, "roughness_pattern": skipped}))["roughness pattern"]
    )
    net = flash_fit_rows({**fit, "roughness_from": "network", "misfit": 0.0071})
    assert "the network's map: the profile misfits (ring residual 0.0071 > 0.003)" in dict(net)["roughness"]
    metal = dict(flash_fit_rows({**fit, "metal": True, "pixel_median": None, "specular": [0.9, 0.6, 0.3]}))
    assert metal["material read as"].startswith("metal") and metal["specular F0 (RGB)"] == "0.9, 0.6, 0.3"


# -- noise-weighted refinement ------------------------------------------------------------------------


def test_noise_variance_reads_white_noise_past_texture_edges():
    """noise_variance recovers the variance of white noise added to a textured image (checks with
    sharp edges, a smooth ramp) within 20 % (the edges read as a little noise), reads a noise-free
    one as nearly 0, and leaves masked pixels out."""
    from ebr_mitsuba.estimate.refine import noise_variance

    n = 96
    clean = _material(n).diffuse + np.linspace(0, 0.2, n, dtype=np.float32)[None, :, None]
    rng = np.random.default_rng(5)
    noisy = clean + rng.normal(0.0, 0.05, clean.shape).astype(np.float32)
    mask = np.ones((n, n), bool)
    assert noise_variance(noisy, mask) == pytest.approx(0.05**2, rel=0.2)
    assert noise_variance(clean, mask) < 0.05 * 0.05**2
    half = mask.copy()
    half[:, : n // 2] = False
    wild = noisy.copy()
    wild[:, : n // 2] += rng.normal(0.0, 1.0, (n, n // 2, 3)).astype(np.float32)
    assert noise_variance(wild, half) == pytest.approx(0.05**2, rel=0.2)


def _noisy_flash_problem(n: int = 32, sigma: float = 0.03, seed: int = 2):
    """A material's flash-only shot (the flash alone, no environment) with white noise of ``sigma``
    as the refinement's one target."""
    import dataclasses

    from ebr_mitsuba.estimate.refine import ShotTarget

    truth = _material(n)
    shot = dataclasses.replace(near_shot(True), env=False)
    photo = _render(truth, [shot])[shot.name]
    rng = np.random.default_rng(seed)
    noisy = np.maximum(photo + rng.normal(0.0, sigma, photo.shape), 0.0).astype(np.float32)
    return truth, [ShotTarget(shot, noisy, np.ones((n, n), bool))]


def test_adaptive_prior_reads_the_start_maps_error():
    """The adaptive diffuse prior deviation is near its floor for a start at the truth (its render
    misses the photo by the noise alone) and of the start's own error for a start whose diffuse
    map is off by 0.08 everywhere."""
    from ebr_mitsuba.estimate.refine import ADAPTIVE_SIGMA_RANGE, adaptive_diffuse_sigma, rerender_errors

    truth, targets = _noisy_flash_problem()
    _, renders = rerender_errors(truth, None, targets)
    assert adaptive_diffuse_sigma(truth, targets, renders) < 0.01
    off = SVBRDF(truth.normal, np.clip(truth.diffuse + 0.08, 0, 1), truth.specular, truth.roughness)
    _, renders = rerender_errors(off, None, targets)
    tau = adaptive_diffuse_sigma(off, targets, renders)
    assert 0.04 < tau < 0.16 and ADAPTIVE_SIGMA_RANGE[0] < tau


def test_noise_weighted_refinement_moves_maps_by_what_the_photos_know():
    """Against a noisy flash-only photo: from the truth, the noise-weighted refinement leaves the
    diffuse map within 0.01 of it while the signal-weighted one fits the noise (further than 0.02);
    from a start off by 0.08, it brings the diffuse map closer to the truth."""
    from ebr_mitsuba.estimate.refine import RefineConfig, refine

    truth, targets = _noisy_flash_problem()
    err = lambda m: float(np.sqrt(np.mean((m.diffuse - truth.diffuse) ** 2)))  # noqa: E731
    fixed = ["specular", "roughness", "normal"]
    noise = RefineConfig(steps=40, weighting="noise", smooth_weight=0.0, fixed=fixed)
    signal = RefineConfig(steps=40, smooth_weight=0.0, fixed=fixed)
    calm, fitted = refine(truth, None, targets, noise), refine(truth, None, targets, signal)
    assert err(calm.maps) < 0.01 and err(fitted.maps) > 0.02
    off = SVBRDF(truth.normal, np.clip(truth.diffuse + 0.08, 0, 1), truth.specular, truth.roughness)
    better = refine(off, None, targets, noise)
    assert err(better.maps) < 0.85 * err(off)


def test_refine_options_fix_the_normals_of_glossy_captures():
    """With noise weighting the normals are refined only where the shading normals were read: a
    metal's or a capture without shading normals gets them fixed; signal weighting is left alone."""
    from types import SimpleNamespace

    from ebr_mitsuba.estimate.pipeline import refine_options_for
    from ebr_mitsuba.estimate.refine import RefineConfig

    noise = RefineConfig(steps=10, weighting="noise", fixed=["specular"])
    dielectric, metal = SimpleNamespace(metal=False), SimpleNamespace(metal=True)
    read = object()
    assert refine_options_for(noise, dielectric, read) is noise
    assert refine_options_for(noise, dielectric, None).fixed == ("specular", "normal")
    assert refine_options_for(noise, metal, read).fixed == ("specular", "normal")
    assert refine_options_for(noise, None, None).fixed == ("specular", "normal")
    signal = RefineConfig(steps=10)
    assert refine_options_for(signal, metal, None) is signal
    with pytest.raises(InputError, match="prior_sigma"):
        RefineConfig(prior_sigma=(0.03, 0.03, 0.01))


def test_highlight_tilt_of_a_glossy_sample(tmp_path, capsys, fake_net):
    """A glazed checker (roughness 0.1, F0 0.04) whose normal map is tilted by (0.006, −0.004),
    photographed with its highlight clipped: too glossy for the shading normals, its normal map is
    the flat normal tilted to the clipped highlight (within half a pixel's slope of the truth at 48²:
    the checks move the clipped disc; tests/test_highlight_tilt.py has the precision),
    recorded in estimate.json and the report; --no-highlight-tilt keeps the network's (flat)."""
    from ebr_mitsuba.estimate.highlight_tilt import tilted_normals
    from ebr_mitsuba.estimate.pipeline import near_distance
    from ebr_mitsuba.materials import load_material_dir

    slope = (0.006, -0.004)
    maps = SVBRDF(
        normal=tilted_normals((GRID, GRID), slope),
        diffuse=_material(GRID).diffuse,  # textured: the shots' alignment check needs texture
        specular=np.full((GRID, GRID, 3), 0.04, np.float32),
        roughness=np.full((GRID, GRID), 0.1, np.float32),
    )
    shots = _render(maps, [near_shot(True), near_shot(False)])
    level = float(np.sort(shots["flash"].max(axis=-1).ravel())[-40])  # the exposure clips 40 pixels
    args = []
    for name, img in shots.items():
        write_exr(tmp_path / f"{name}.exr", np.minimum(img, level))
        args += [f"--{name}", tmp_path / f"{name}.exr"]
    args += ["--saturation-level", level]
    code, stdout, err = _estimate([*args, "--out", tmp_path / "on", "--json"], capsys)
    assert code == 0, err
    summary = json.loads(stdout)
    assert not summary["shading_normals"]["applied"]  # glossy: the glint rule keeps the network's
    tilt = summary["highlight_tilt"]
    assert tilt["applied"], tilt
    pixel = 2.0 / GRID / near_distance(summary["inputs"]["fov"])
    assert np.abs(np.asarray(tilt["slope"]) - slope).max() < pixel / 2, (tilt, pixel)  # the checks shift it
    normal = load_material_dir(tmp_path / "on" / "maps").normal
    np.testing.assert_allclose(normal, tilted_normals((GRID, GRID), tilt["slope"]), atol=2e-3)
    assert "tilted" in (tmp_path / "on" / "report.html").read_text()
    code, stdout, err = _estimate([*args, "--out", tmp_path / "off", "--no-highlight-tilt", "--json"], capsys)
    assert code == 0, err
    assert json.loads(stdout)["highlight_tilt"] is None
    flat = load_material_dir(tmp_path / "off" / "maps").normal
    np.testing.assert_allclose(flat[..., 2], 1.0, atol=2e-3)  # the fake network's flat normals
