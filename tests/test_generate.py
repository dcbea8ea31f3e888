"""``ebr generate`` / ``ebr dataset``: config schema, determinism, resume, verify, Ray, Dataset.

The Ray path runs against ``tests/fake_ray.py`` by default, against Ray itself with ``-m slow``.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ebr_mitsuba.cli import main
from ebr_mitsuba.data import generate as gen_mod
from ebr_mitsuba.data import store
from ebr_mitsuba.data.config import load_config, parse_config
from ebr_mitsuba.data.generate import generate
from ebr_mitsuba.data.verify import verify
from ebr_mitsuba.errors import ConfigError, InputError

RES = 32
COUNT = 4

TINY = f"""
[dataset]
seed = 7
count = {COUNT}
resolution = {RES}

[render]
renderer = "{{renderer}}"
spp = 2
fast_mode = "quadrature"
fast_spp = 8

[exemplars]
env_roughness = [0.2, 0.8]
point_roughness = [0.3]

[[materials]]
type = "procedural"
families = ["tiles", "metal", "wood"]
blend = 0.5

[[environments]]
type = "procedural"
"""


def write_config(
    directory: Path, renderer: str = "mitsuba", extra: str = "", name: str = "tiny.toml"
) -> Path:
    path = directory / name
    path.write_text(TINY.format(renderer=renderer) + extra)
    return path


def file_hashes(root: Path) -> dict:
    """{relative path: sha256} of every file but the documented non-deterministic timing.json."""
    return {
        p.relative_to(root).as_posix(): store.sha256_file(p)
        for p in sorted(root.rglob("*"))
        if p.is_file() and p.name != store.TIMING_JSON
    }


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny Mitsuba data set made in this process (one worker): (root, config path)."""
    base = tmp_path_factory.mktemp("reference")
    cfg_path = write_config(base)
    root = base / "A"
    summary = generate(load_config(cfg_path), root, workers=1, progress=False)
    assert summary.generated == COUNT and summary.skipped == 0
    return root, cfg_path


# -- the data set ---------------------------------------------------------------------------------


def test_layout_and_verify(reference):
    root, _ = reference
    report = verify(root)
    assert report.ok, report.errors
    assert report.samples == COUNT
    ds = store.read_json(root / "dataset.json")
    assert ds["layout"]["photos"] == {"flash": "photos/flash.png", "noflash": "photos/noflash.png"}
    assert ds["layout"]["flash_only"] == {"flash": "flash_only/flash.exr"}
    meta = store.read_json(root / "samples/000000/sample.json")
    assert meta["seed"] == [7, 0] and meta["resolution"] == [RES, RES]
    assert [e["roughness"] for e in meta["exemplars"]["env"]] == [0.2, 0.8]
    timing = store.read_json(root / store.TIMING_JSON)
    assert timing["runs"][-1]["generated"] == COUNT


def test_sample_content_is_consistent(reference):
    """flash photo ≈ flash-only + no-flash photo (camera units); maps valid; env.json lobes."""
    root, _ = reference
    ds = store.read_json(root / "dataset.json")
    for i in range(COUNT):
        s = store.load_sample(root, ds, i)
        cam = s["meta"]["camera"]
        assert 0.5 < cam["exposure"] < 2.0
        flash = s["photos"]["flash"]
        predicted = np.clip(s["flash_only"]["flash"] + s["photos"]["noflash"], 0, 1)
        unclipped = (flash < 0.99) & (predicted < 0.99)
        # the environment parts are independent 2-spp renders: compare means, not pixels
        assert abs(float(np.mean((flash - predicted)[unclipped]))) < 0.02
        assert s["env"].num_lobes == s["meta"]["env"]["lobes"] > 0
        assert s["maps"]["roughness"].shape == (RES, RES)
        np.testing.assert_allclose(np.linalg.norm(s["maps"]["normal"], axis=-1), 1.0, atol=1e-5)
        # exemplars of rough and smooth material differ; point exemplar lit at the centre
        assert not np.allclose(s["env_exemplars"][0], s["env_exemplars"][1])
        assert s["point_exemplars"][0][RES // 2, RES // 2].mean() > 0


@pytest.mark.parametrize("renderer", ["mitsuba", "fast"])
def test_identical_files_whatever_the_worker_count(reference, tmp_path, renderer):
    if renderer == "mitsuba":
        root_a, cfg_path = reference
    else:  # the fast renderer's scatter-adds are what single-threaded workers make reproducible
        cfg_path = write_config(tmp_path, "fast")
        root_a = tmp_path / "A"
        generate(load_config(cfg_path), root_a, workers=1, progress=False)
    root_b = tmp_path / "B"
    summary = generate(load_config(cfg_path), root_b, workers=2, progress=False)
    assert summary.backend == "pool" and summary.workers == 2
    a, b = file_hashes(root_a), file_hashes(root_b)
    assert len(a) > COUNT * 10
    assert a == b


def test_resume_after_an_interrupted_run(reference, tmp_path, monkeypatch):
    root_a, cfg_path = reference
    out = tmp_path / "R"
    real = gen_mod.make_sample

    def crash_at_two(plan, index, root):
        if index == 2:
            raise RuntimeError("simulated crash")
        return real(plan, index, root)

    monkeypatch.setattr(gen_mod, "make_sample", crash_at_two)
    with pytest.raises(RuntimeError, match="simulated crash"):
        generate(load_config(cfg_path), out, workers=1, progress=False)
    monkeypatch.setattr(gen_mod, "make_sample", real)
    assert store.is_complete(out, 0) and store.is_complete(out, 1)
    assert not (out / "samples/000002").exists() and not (out / "index.json").exists()
    # a kill during a write leaves a temporary directory: resume removes it
    (out / "samples/.000002.abcd.partial").mkdir()
    report = verify(out)
    assert not report.ok  # no index yet
    with pytest.raises(InputError, match="--resume"):
        generate(load_config(cfg_path), out, workers=1, progress=False)
    summary = generate(load_config(cfg_path), out, workers=1, resume=True, progress=False)
    assert (summary.generated, summary.skipped, summary.partials_removed) == (2, 2, 1)
    assert file_hashes(out) == file_hashes(root_a)
    assert verify(out).ok


def test_resume_extends_the_count_and_refuses_another_config(reference, tmp_path):
    root_a, cfg_path = reference
    out = tmp_path / "E"
    shutil.copytree(root_a, out)
    summary = generate(load_config(cfg_path).with_count(COUNT + 1), out, resume=True, progress=False)
    assert (summary.generated, summary.skipped) == (1, COUNT)
    assert verify(out).ok and store.read_json(out / "index.json")["count"] == COUNT + 1
    other = write_config(tmp_path, "fast", name="other.toml")
    with pytest.raises(InputError, match="different config"):
        generate(load_config(other), out, resume=True, progress=False)


def test_refuses_a_foreign_directory(tmp_path, reference):
    _, cfg_path = reference
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    with pytest.raises(InputError, match="not empty"):
        generate(load_config(cfg_path), tmp_path / "mine", progress=False)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"


def test_resume_after_a_kill_during_the_map_fits(reference, tmp_path):
    """Killed while fitting the maps: only envs/ exists; --resume starts the set, a plain run refuses."""
    root_a, cfg_path = reference
    out = tmp_path / "F"
    (out / "envs").mkdir(parents=True)
    with pytest.raises(InputError, match="not empty"):
        generate(load_config(cfg_path), out, progress=False)
    generate(load_config(cfg_path), out, resume=True, progress=False)
    assert file_hashes(out) == file_hashes(root_a)


@pytest.mark.slow
def test_kill_midway_and_resume(reference, tmp_path):
    """A real SIGKILL of `ebr generate` in the middle of a 40-sample run, then --resume: the set
    verifies and its first samples equal the uninterrupted reference run's."""
    root_a, cfg_path = reference
    out = tmp_path / "K"
    cmd = [
        sys.executable,
        "-m",
        "ebr_mitsuba.cli",
        "generate",
        str(cfg_path),
        "--out",
        str(out),
        "--count",
        "40",
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not store.is_complete(out, 1) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert store.is_complete(out, 1) and not (out / "index.json").exists()  # interrupted midway
    done = [i for i in range(40) if store.is_complete(out, i)]
    assert len(done) < 40
    result = subprocess.run(cmd + ["--resume"], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert verify(out).ok
    a, b = file_hashes(root_a), file_hashes(out)
    for i in range(COUNT):
        prefix = store.sample_dirname(i) + "/"
        assert {k: v for k, v in a.items() if k.startswith(prefix)} == {
            k: v for k, v in b.items() if k.startswith(prefix)
        }


# -- verify ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "damage, needle",
    [
        ("corrupt", "checksum"),
        ("missing", "missing"),
        ("extra", "not listed"),
        ("nan", "NaN"),
        ("no_sample", "sample directory missing"),
        ("index", "index.json"),
    ],
)
def test_verify_catches_damage(reference, tmp_path, damage, needle, capsys):
    root_a, _ = reference
    root = tmp_path / "D"
    shutil.copytree(root_a, root)
    sample = root / "samples/000001"
    if damage == "corrupt":
        path = sample / "exemplars/env_0.exr"
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(data))
    elif damage == "missing":
        (sample / "maps/roughness.exr").unlink()
    elif damage == "extra":
        (sample / "stray.txt").write_text("x")
    elif damage == "nan":  # a NaN written with a matching checksum: only the content check sees it
        from ebr_mitsuba.imageio import write_exr

        img = np.zeros((RES, RES, 3), np.float32)
        img[3, 4, 1] = np.nan
        write_exr(sample / "flash_only/flash.exr", img)
        manifest = store.read_json(sample / "manifest.json")
        manifest["files"] = store.manifest_of(sample)
        (sample / "manifest.json").write_text(store.dumps(manifest))
        index = store.read_json(root / "index.json")
        index["samples"][1]["manifest_sha256"] = store.sha256_file(sample / "manifest.json")
        (root / "index.json").write_text(store.dumps(index))
    elif damage == "no_sample":
        shutil.rmtree(sample)
    elif damage == "index":
        index = store.read_json(root / "index.json")
        index["samples"][2]["manifest_sha256"] = "0" * 64
        (root / "index.json").write_text(store.dumps(index))
    report = verify(root)
    assert not report.ok
    assert any(needle in e for e in report.errors), report.errors
    rc = main(["dataset", "verify", str(root)])
    assert rc == 2
    assert needle in capsys.readouterr().err


def test_cli_verify_ok_and_sheet(reference, tmp_path, capsys):
    root, _ = reference
    assert main(["dataset", "verify", str(root), "--json"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["ok"] is True
    png = tmp_path / "sheet.png"
    assert main(["dataset", "sheet", str(root), "--out", str(png), "--samples", "3"]) == 0
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# -- configs ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "extra, needles",
    [
        ("\n[camera]\nexposure_evv = [0, 1]\n", ["camera.exposure_evv", "exposure_ev"]),
        ("\n[render2]\nspp = 3\n", ["render2"]),
        ('\n[[materials]]\ntype = "procedural"\nweight = "heavy"\n', ["materials[1].weight", "number"]),
        (
            '\n[[materials]]\ntype = "directory"\npaths = ["no/such/dir"]\n',
            ["materials[1].paths[0]", "no/such/dir"],
        ),
        (
            '\n[[environments]]\ntype = "equirect"\npaths = ["missing.hdr"]\n',
            ["environments[1].paths[0]", "missing.hdr"],
        ),
        ('\n[[environments]]\ntype = "sky"\n', ["environments[1].type", "procedural"]),
        ('\n[[materials]]\ntype = "procedural"\nfamilies = ["lava"]\n', ["families[0]", "lava"]),
        ('\n[capture]\nsetup = "far"\n', ["capture.setup", "near-far"]),
        (
            '\n[[materials]]\ntype = "directory"\npaths = ["${EBR_NOT_SET_ANYWHERE}/x"]\n',
            ["EBR_NOT_SET_ANYWHERE"],
        ),
    ],
)
def test_bad_config_exits_2_naming_the_key(tmp_path, capsys, extra, needles):
    cfg = write_config(tmp_path, extra=extra)
    rc = main(["generate", str(cfg), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1, err
    for needle in needles:
        assert needle in err
    assert not (tmp_path / "out").exists()


def test_bad_types_and_counts(tmp_path, capsys):
    text = TINY.format(renderer="mitsuba")
    for bad, needle in (
        (text.replace("resolution = 32", 'resolution = "32"'), "dataset.resolution"),
        (text.replace(f"count = {COUNT}", "count = 0"), "dataset.count"),
        (text.replace("spp = 2", "spp = 2.5"), "render.spp"),
    ):
        path = tmp_path / "bad.toml"
        path.write_text(bad)
        assert main(["generate", str(path), "--out", str(tmp_path / "o")]) == 2
        assert needle in capsys.readouterr().err
    good = write_config(tmp_path)
    assert main(["generate", str(good), "--out", str(tmp_path / "o"), "--count", "0"]) == 2
    assert "--count" in capsys.readouterr().err
    assert main(["generate", str(tmp_path / "absent.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "absent.toml" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="camera.quantize"):
        parse_config(
            {
                "camera": {"clip": False},
                "materials": [{"type": "procedural"}],
                "environments": [{"type": "none"}],
            }
        )


def test_bundled_example_configs_parse(monkeypatch, data_dir):
    from ebr_mitsuba.data.config import bundled_configs

    monkeypatch.setenv("EBR_DATA_DIR", str(data_dir))
    names = bundled_configs()
    assert {"near_train", "near_far_train", "five_light", "multiview", "test_real"} <= set(names)
    setups = {load_config(n).capture.setup for n in names}
    assert setups == {"near", "near-far", "five-light", "multi-view"}


def test_cli_generate_summary(tmp_path, capsys):
    cfg = write_config(tmp_path, "fast")
    rc = main(["generate", str(cfg), "--out", str(tmp_path / "o"), "--count", "2", "--json"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    summary = json.loads(captured.out)
    assert summary["generated"] == 2 and summary["count"] == 2
    assert "samples/s" in captured.err


# -- sources ----------------------------------------------------------------------------------------


def test_real_material_sources(tmp_path, data_dir):
    """Directory sources on the shared texture sets: maps at the data-set size, in range."""
    from ebr_mitsuba.data.sample import Plan, draw_sample

    mats = data_dir / "materials"
    extra = f"""
[[materials]]
type = "directory"
weight = 1000.0
augment = true
paths = ["{mats / "wood_floor"}", "{mats / "painted_plaster_wall"}", "{mats / "Metal009"}"]
"""
    cfg = load_config(write_config(tmp_path, extra=extra))
    plan = Plan(cfg, {})
    seen = set()
    for i in range(12):
        d = draw_sample(plan, i)
        if d.material["type"] != "directory":
            continue
        seen.add(Path(d.material["path"]).name)
        m = d.svbrdf
        assert m.shape == (RES, RES)
        for name in ("diffuse", "specular", "roughness"):
            a = getattr(m, name)
            assert np.all(np.isfinite(a)) and a.min() >= 0 and a.max() <= 1
        if Path(d.material["path"]).name == "Metal009":  # metalness 1: coloured F0, no diffuse
            assert m.specular.mean() > 0.3 and m.diffuse.max() < 0.05
        else:
            assert m.specular.max() < 0.06
    assert len(seen) >= 2


def test_map_lit_sample_rotation_matches_its_sg(tmp_path, data_dir):
    """The rotated, scaled envmap emitter and the rotated, scaled SG fit describe one environment."""
    import drjit as dr
    import mitsuba as mi

    from ebr_mitsuba.data.renderers import _rotated_envmap_dict
    from ebr_mitsuba.data.sample import Plan, draw_sample, equirect_map, prepare_maps

    hdr = data_dir / "envmaps" / "venice_sunset_1k.hdr"
    extra = f"""
[[environments]]
type = "equirect"
weight = 1000.0
lobes = 6
fit_iterations = 20
paths = ["{hdr}"]
"""
    cfg = load_config(write_config(tmp_path, extra=extra))
    plan = Plan(cfg, prepare_maps(cfg, tmp_path / "ds"))
    draw = next(d for d in (draw_sample(plan, i) for i in range(8)) if d.env.kind == "equirect")
    env = draw.env
    assert env.record["map"]["sha256"] and 0 <= env.rotation < 2 * math.pi
    emitter = mi.load_dict(_rotated_envmap_dict(env))
    rng = np.random.default_rng(3)
    d = rng.normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    si = dr.zeros(mi.SurfaceInteraction3f, 64)
    si.wi = mi.Vector3f(-d[:, 0], -d[:, 1], -d[:, 2])
    got = np.asarray(emitter.eval(si)).T
    c, s = math.cos(-env.rotation), math.sin(-env.rotation)
    back = d @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T  # world → unrotated map frame
    want = env.scale * equirect_map(str(hdr)).eval(back)
    np.testing.assert_allclose(got, want, rtol=2e-3, atol=1e-6 * want.max())
    # the SG ground truth is the fit turned the same way
    fit = plan.maps[str(hdr)].fit
    np.testing.assert_allclose(env.sg.eval(d), env.scale * fit.eval(back), rtol=1e-4, atol=1e-7)


# -- camera ------------------------------------------------------------------------------------------


def test_camera_simulation_without_noise():
    from ebr_mitsuba.data.camera import photo_linear, quantize
    from ebr_mitsuba.data.sample import CameraDraw

    cam = CameraDraw(
        exposure=2.0,
        white_balance=(1.1, 1.0, 0.9),
        read_noise=0.0,
        shot_noise=0.0,
        clip=True,
        quantize=True,
        noise_seed=0,
    )
    x = np.linspace(0, 1, 3 * 16, dtype=np.float32).reshape(4, 4, 3)
    got = photo_linear(x, cam, np.random.default_rng(0))
    np.testing.assert_allclose(got, np.clip(x * 2.0 * np.array([1.1, 1.0, 0.9]), 0, 1), rtol=1e-6)
    q = quantize(got)
    assert np.max(np.abs(q - got)) < 0.01 and len(np.unique(q)) <= 256


# -- torch ------------------------------------------------------------------------------------------


def test_torch_dataset_shapes(reference):
    import torch

    from ebr_mitsuba.data.dataset import GeneratedDataset

    root, _ = reference
    ds = GeneratedDataset(root)
    assert len(ds) == COUNT
    item = ds[1]
    k = ds.max_lobes
    shapes = {
        "photos": (2, 3, RES, RES),
        "flash_only": (1, 3, RES, RES),
        "env_exemplars": (2, 3, RES, RES),
        "point_exemplars": (1, 3, RES, RES),
        "maps": (10, RES, RES),
        "sg": (k, 7),
        "sg_mask": (k,),
        "exposure": (),
        "white_balance": (3,),
        "index": (),
    }
    assert {name: tuple(t.shape) for name, t in item.items()} == shapes
    assert all(t.dtype == torch.float32 for n, t in item.items() if n != "index")
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=2)))
    assert tuple(batch["photos"].shape) == (2, 2, 3, RES, RES)
    lobes = store.read_json(root / "samples/000001/sample.json")["env"]["lobes"]
    assert float(item["sg_mask"].sum()) == lobes


# -- Ray ----------------------------------------------------------------------------------------------


def test_ray_missing_is_one_clear_line(reference, tmp_path, capsys, monkeypatch):
    _, cfg_path = reference
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray → ImportError
    rc = main(["generate", str(cfg_path), "--out", str(tmp_path / "o"), "--ray", "auto"])
    err = capsys.readouterr().err
    assert rc == 2
    assert "pip install 'ebr-mitsuba[ray]'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


@pytest.fixture
def fake_ray(monkeypatch):
    """tests/fake_ray.py as the module ``ray`` (tasks in a spawn process pool), calls recorded afresh."""
    import fake_ray

    monkeypatch.setitem(sys.modules, "ray", fake_ray)
    monkeypatch.setattr(fake_ray, "calls", [])
    yield fake_ray
    fake_ray.shutdown()  # a test that failed half-way leaves no pool behind


def test_ray_path_gives_the_same_files(reference, tmp_path, fake_ray):
    """The whole --ray path (generate → ray_backend → workers.make_shard in other processes →
    files written by the driver) with the fake Ray: the reference's bytes (= the pool's, above)."""
    root_a, cfg_path = reference
    summary = generate(
        load_config(cfg_path), tmp_path / "ray", ray="local", workers=2, shard_size=3, progress=False
    )
    assert (summary.backend, summary.generated) == ("ray", COUNT)
    assert file_hashes(tmp_path / "ray") == file_hashes(root_a)
    assert fake_ray.calls == [("init", None, 2), ("remote", {"num_cpus": 1, "max_retries": 2}), ("shutdown",)]
    assert not fake_ray.is_initialized()


def test_ray_errors_are_one_line(tmp_path, fake_ray):
    """A task's error is raised as itself; an address without a cluster is a RuntimeSetupError
    naming the fix; a cluster the caller initialised is left running."""
    from ebr_mitsuba.data.ray_backend import run_ray
    from ebr_mitsuba.errors import RuntimeSetupError

    got = []
    with pytest.raises(ValueError, match=r"^boom \[(0, 1|2)\]$"):
        run_ray(fake_ray, "fake://head", fake_ray.failing_task, ("boom",), [0, 1, 2], 2, 1, got.append)
    assert got == [] and fake_ray.calls[-1] == ("shutdown",)
    with pytest.raises(RuntimeSetupError, match="--ray 10.0.0.1:1: cannot connect.*ray start --head"):
        run_ray(fake_ray, "10.0.0.1:1", fake_ray.failing_task, ("x",), [0], 1, 1, got.append)
    fake_ray.init(num_cpus=1)
    run_ray(fake_ray, "auto", sorted, (), [2, 1, 0], 2, 1, got.append)
    assert sorted(got) == [[0], [1, 2]] and fake_ray.is_initialized()


@pytest.mark.slow
def test_ray_local_cluster_gives_the_same_files(reference, tmp_path):
    ray = pytest.importorskip(
        "ray", reason="Ray is not installed (optional extra: pip install 'ebr-mitsuba[ray]')"
    )
    root_a, cfg_path = reference
    ray.init(
        num_cpus=2,
        include_dashboard=False,
        log_to_driver=False,
        runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join(sys.path)}},
    )
    try:
        summary = generate(load_config(cfg_path), tmp_path / "ray", ray="auto", shard_size=2, progress=False)
    finally:
        ray.shutdown()
    assert summary.backend == "ray"
    assert file_hashes(tmp_path / "ray") == file_hashes(root_a)


def test_docs_describe_every_config_key():
    from ebr_mitsuba.data.config import schema_table

    page = (Path(__file__).resolve().parents[1] / "docs" / "generate.md").read_text()
    missing = [key for key, *_ in schema_table() if f"`{key.rsplit('.', 1)[-1]}`" not in page]
    assert not missing, f"docs/generate.md does not describe {missing}"


def test_metering_sets_the_exposure_from_the_brightest_shot(tmp_path):
    """[camera].meter: the recorded exposure puts the brightest clean shot's 99th-percentile
    largest-channel value at the meter level (× the jitter, none here), and the training loader
    divides it out."""
    from ebr_mitsuba.data.renderers import render_clean
    from ebr_mitsuba.data.sample import draw_sample
    from ebr_mitsuba.train.data import load_training_data

    extra = (
        "\n[camera]\nmeter = 0.5\nexposure_ev = [0.0, 0.0]\nread_noise = [0.0, 0.0]\n"
        "shot_noise = [0.0, 0.0]\n"
    )
    cfg = load_config(write_config(tmp_path, "fast", extra))
    root = tmp_path / "metered"
    generate(cfg, root, workers=1, progress=False)
    from ebr_mitsuba.data.sample import Plan, prepare_maps
    from ebr_mitsuba.variant import ensure_variant

    plan = Plan(cfg, prepare_maps(cfg, root), ensure_variant())
    exposures = []
    for i in range(COUNT):
        meta = json.loads((root / store.sample_dirname(i) / "sample.json").read_text())
        exposures.append(meta["camera"]["exposure"])
        clean = render_clean(cfg, draw_sample(plan, i))
        level = max(np.percentile(v.astype(np.float64).max(axis=-1), 99.0) for v in clean.shots.values())
        assert math.isclose(exposures[-1] * level, 0.5, rel_tol=1e-5)
    assert len(set(exposures)) == COUNT  # one exposure per sample, not the fixed base
    from ebr_mitsuba.data.dataset import GeneratedDataset

    td = load_training_data(root)  # the loader's photos × exposure are the stored photos
    item = GeneratedDataset(root)[0]
    np.testing.assert_allclose(
        td.photos[0].numpy() * exposures[0], item["photos"].numpy(), rtol=1e-5, atol=1e-7
    )
    np.testing.assert_allclose(td.gains[0].numpy(), item["white_balance"].numpy())
