"""Training, checkpoints, inference and evaluation (ebr_mitsuba.train, ebr train, ebr eval).

Tiny data sets (4 samples at 32², fast renderer) are generated once per module from
configs/data_tiny*.toml; every training config of configs/ trains two steps per phase on them.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomllib
import torch

from ebr_mitsuba.cli import main
from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.model import checkpoint as ck
from ebr_mitsuba.model.config import KINDS, MAIR_PHASES, PHASES, load_config, parse_config

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
TRAIN_CONFIGS = sorted(p.name for p in CONFIGS.glob("*.toml") if not p.name.startswith("data_"))
# full-size networks: seconds per step on a CPU
SLOW_CONFIGS = {"train_paper.toml", "dualloss.toml", "mair_paper.toml"}
FIXTURE_CONFIG = "train_tiny.toml"  # trained by the tiny_model fixture (checked there)
NEAR_FAR_SMOKE = "train_tiny_near_far.toml"  # trained by tests/test_train_near_far.py
MAIR_SMOKE = "mair_tiny.toml"  # trained by tests/test_train_mair.py


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread


def _smoke_doc(name: str, data: Path) -> dict:
    """A config of configs/ cut down to two steps per phase on the tiny data."""
    doc = tomllib.loads((CONFIGS / name).read_text())
    doc["data"] = {"train": str(data)}
    train = doc.setdefault("train", {})
    train.update(batch_size=2, log_every=1, checkpoint_every=1, threads=1, init="")
    if doc.get("kind", "ebrenv") == "ebrenv":
        stages = doc.setdefault("stages", {})
        for phase in PHASES:
            stages[phase] = 0 if stages.get(phase, 1) == 0 else 2
        stages["finetune_samples"] = 1
        doc["extract"] = {"iters": 3, "max_lobes": 4}
    elif doc["kind"] == "mair":
        doc["stages"] = dict.fromkeys(MAIR_PHASES, 2)
    else:
        train["steps"] = 2
    return doc


def _train(doc: dict, out: Path, resume: bool = False) -> dict:
    from ebr_mitsuba.train.trainer import Trainer

    return Trainer(parse_config(doc, "smoke.toml"), out, resume=resume).run()


def _check_smoke(summary: dict, out: Path, name: str) -> None:
    assert summary["phases"], name
    for phase, info in summary["phases"].items():
        assert info["steps"] == 2 and np.isfinite(info["final_loss"]), (name, phase)
    rows = (out / "log.csv").read_text().splitlines()
    assert rows[0].split(",")[:3] == ["phase", "step", "loss"] and len(rows) == 1 + 2 * len(summary["phases"])
    assert (out / "model.pt").is_file()


@pytest.fixture(scope="module")
def tiny_model(tiny, tmp_path_factory) -> Path:
    """configs/train_tiny.toml, two steps of every phase (the smoke test of that config)."""
    out = tmp_path_factory.mktemp("run") / "tiny"
    summary = _train(_smoke_doc(FIXTURE_CONFIG, tiny), out)
    _check_smoke(summary, out, FIXTURE_CONFIG)
    assert list(summary["phases"]) == list(PHASES)
    return out / "model.pt"


# -- config -------------------------------------------------------------------------------------


def test_every_shipped_config_parses(monkeypatch, tmp_path):
    monkeypatch.setenv("EBR_TRAIN_DATA", str(tmp_path))
    monkeypatch.setenv("EBR_INIT", str(tmp_path / "init.pt"))
    for name in TRAIN_CONFIGS:
        config = load_config(CONFIGS / name)
        assert config.data.train == str(tmp_path), name
        assert config.to_dict()["kind"] in KINDS


def test_config_errors_name_file_and_key(tmp_path, monkeypatch):
    monkeypatch.delenv("EBR_NOT_SET", raising=False)
    cases = {
        '[data]\ntrain = "x"\n[train]\nlr = "fast"\n': r"bad\.toml: train\.lr: expected float",
        '[data]\ntrain = "x"\n[train]\nbatchsize = 2\n': r"train\.batchsize: unknown key",
        'kind = "ebrenv"\n[data]\n': r"data\.train: is required",
        'kind = "gan"\n[data]\ntrain = "x"\n': r"kind: got 'gan'",
        '[data]\ntrain = "$EBR_NOT_SET/x"\n': r"\$EBR_NOT_SET is not set",
        '[data]\ntrain = "x"\n[model]\nwidth = 3\n': r"model\.width: unknown key",
        '[data]\ntrain = "x"\n[extract]\niterations = 3\n': r"extract\.iterations: unknown key",
        '[data]\ntrain = "x"\n[optim]\n': r"optim: unknown table",
    }
    for text, pattern in cases.items():
        path = tmp_path / "bad.toml"
        path.write_text(text)
        with pytest.raises(ConfigError, match=pattern):
            load_config(path)
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "missing.toml")


def test_config_defaults_and_relative_paths(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[data]\ntrain = "data/set"\n')
    c = load_config(path)
    assert c.kind == "ebrenv" and c.data.train == str(tmp_path / "data" / "set")
    assert c.train.batch_size == 8 and c.stages.lighting == 1000 and c.loss.render == 0.0
    assert c.select_config().env_mode == "sg" and c.extract_config().max_lobes == 16


# -- checkpoints ----------------------------------------------------------------------------------


def test_checkpoint_round_trip_and_errors(tiny_model, tmp_path):
    data = ck.load_checkpoint(tiny_model, expect_kind="ebrenv")
    assert data["kind"] == "ebrenv" and data["step"]["phase"] == "finetune"
    assert set(data["model"]) == {"lighting", "cascade"}
    assert data["data"]["resolution"] == 32 and len(data["git"]) in (7, 40) or data["git"] == "unknown"
    assert data["config"]["kind"] == "ebrenv"
    with pytest.raises(InputError, match=f"{tiny_model}: a 'ebrenv' checkpoint.*wrong kind"):
        ck.load_checkpoint(tiny_model, expect_kind="dualloss")
    bad = tmp_path / "corrupt.pt"
    bad.write_bytes(tiny_model.read_bytes()[:1000])
    with pytest.raises(InputError, match="corrupt.pt: not a readable checkpoint"):
        ck.load_checkpoint(bad)
    foreign = tmp_path / "foreign.pt"
    torch.save({"not": "a model"}, foreign)
    with pytest.raises(InputError, match="foreign.pt: not an ebr model checkpoint"):
        ck.load_checkpoint(foreign)
    with pytest.raises(InputError, match="no such checkpoint"):
        ck.load_checkpoint(tmp_path / "none.pt")
    exported = ck.export_model(tiny_model, tmp_path / "export.pt")
    small = ck.load_checkpoint(exported)
    assert small["optimizer"] is None
    assert all(v.dtype == torch.float16 for v in small["model"]["cascade"].values() if v.is_floating_point())
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # atomic writes leave nothing


def test_export_records_the_warm_start_lineage(tiny_model, tmp_path):
    """An export carries its run's summary and the runs it was warm-started from, earliest first,
    read through ``[train].init`` (and through an init export's own lineage); a gone init file
    is one ``missing`` entry; a run without an init has an empty lineage."""
    root = ck.export_model(tiny_model, tmp_path / "root.pt")
    data = ck.load_checkpoint(root)
    assert data["lineage"] == [] and data["summary"]["phases"]
    steps = {k: v["steps"] for k, v in data["summary"]["phases"].items()}

    def child(init, name):
        payload = ck.load_checkpoint(tiny_model)
        payload["config"]["train"]["init"] = str(init)
        payload["summary"] = {"phases": {"diffuse": {"steps": 7, "seconds": 36.0}}}
        ck.save_checkpoint(tmp_path / f"{name}_run.pt", payload)
        return ck.export_model(tmp_path / f"{name}_run.pt", tmp_path / f"{name}.pt")

    first = ck.load_checkpoint(child(root, "first"))["lineage"]
    assert len(first) == 1 and first[0]["checkpoint"] == str(root)
    assert {k: v["steps"] for k, v in first[0]["phases"].items()} == steps
    assert first[0]["resolution"] == 32
    second = ck.load_checkpoint(child(tmp_path / "first.pt", "second"))["lineage"]
    assert [r["checkpoint"] for r in second] == [str(root), str(tmp_path / "first.pt")]
    assert second[1]["phases"] == {"diffuse": {"steps": 7, "seconds": 36.0}}
    gone = ck.load_checkpoint(child(tmp_path / "gone.pt", "orphan"))["lineage"]
    assert gone == [{"checkpoint": str(tmp_path / "gone.pt"), "missing": True}]


def test_models_page_reads_the_training_record_from_the_export(tiny_model, tmp_path):
    """Without the run directory, ``ebr bench models`` takes the shipped model's training table
    from the record its export carries: every phase's steps, final loss and seconds, the columns
    only the run's log has shown as "–", no loss plot; an export without a record gives None."""
    from ebr_mitsuba.bench import models as bm

    exported = ck.export_model(tiny_model, tmp_path / "export.pt")
    summary = bm.checkpoint_summary(exported)
    record = ck.load_checkpoint(exported)["summary"]["phases"]
    assert summary["from_checkpoint"] and set(summary["phases"]) == set(record)
    for name, phase in summary["phases"].items():
        assert phase["steps"] == record[name]["steps"] and phase["seconds"] == record[name]["seconds"]
        assert phase["first_loss"] is None and phase["curve"] is None
    lines = "\n".join(bm._model_card(summary, None))
    assert "carried by the checkpoint" in lines and "models_loss.png" not in lines
    first = next(iter(summary["phases"]))
    assert f"| {first} | {record[first]['steps']} | – |" in lines
    payload = ck.load_checkpoint(tiny_model)
    payload.pop("summary", None)
    ck.save_checkpoint(tmp_path / "bare.pt", payload)
    assert bm.checkpoint_summary(tmp_path / "bare.pt") is None


# -- training -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name",
    [n for n in TRAIN_CONFIGS if n not in SLOW_CONFIGS | {FIXTURE_CONFIG, NEAR_FAR_SMOKE, MAIR_SMOKE}]
    + [pytest.param(n, marks=pytest.mark.slow) for n in sorted(SLOW_CONFIGS)],
)
def test_every_config_trains_two_steps(name, tiny, tiny5, tiny_nf, tiny_mv, tmp_path):
    raw = tomllib.loads((CONFIGS / name).read_text())
    if raw.get("kind") == "dualloss":
        data = tiny5
    elif raw.get("kind") == "mair":
        data = tiny_mv
    elif raw.get("model", {}).get("capture") == "near-far":
        data = tiny_nf
    else:
        data = tiny
    doc = _smoke_doc(name, data)
    if name == "dualloss.toml":
        doc["model"]["levels"] = 5  # 32² tiny data
    _check_smoke(_train(doc, tmp_path / "run"), tmp_path / "run", name)


def test_resume_continues_bit_exactly(tiny, tmp_path, monkeypatch):
    from ebr_mitsuba.train.trainer import Trainer

    doc = _smoke_doc("train_tiny.toml", tiny)
    doc["stages"] = {"lighting": 5, "diffuse": 0, "specular": 0, "refinement": 0, "finetune": 0}
    _train(doc, tmp_path / "straight")
    calls = {"n": 0}
    original = Trainer._loss

    def interrupted(self, *args):
        calls["n"] += 1
        if calls["n"] == 2:  # interrupted in step 2: mid-way through the first permutation
            raise KeyboardInterrupt
        return original(self, *args)

    monkeypatch.setattr(Trainer, "_loss", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _train(doc, tmp_path / "resumed")
    monkeypatch.setattr(Trainer, "_loss", original)
    assert ck.load_checkpoint(tmp_path / "resumed" / "last.pt")["step"]["step"] == 1
    with pytest.raises(InputError, match="not empty; pass --resume"):
        _train(doc, tmp_path / "resumed")
    _train(doc, tmp_path / "resumed", resume=True)
    a = ck.load_checkpoint(tmp_path / "straight" / "model.pt")["model"]["lighting"]
    b = ck.load_checkpoint(tmp_path / "resumed" / "model.pt")["model"]["lighting"]
    assert all(torch.equal(a[k], b[k]) for k in a)
    other = dict(doc, train={**doc["train"], "lr": 5e-4})
    with pytest.raises(InputError, match="another config"):
        _train(other, tmp_path / "resumed", resume=True)


def test_phases_are_objects_with_explicit_inputs(tiny, tiny_model):
    """Issue 11.4: each phase carries its inputs (cache, forward, trained modules); the first-stage
    phases run the cascade with ``refine=False`` — the refinement net is never swapped out, nor run."""
    from ebr_mitsuba.train import phases as ph
    from ebr_mitsuba.train.trainer import Trainer

    config = parse_config(_smoke_doc(FIXTURE_CONFIG, tiny), "smoke.toml")
    trainer = Trainer(config, tiny_model.parent, resume=True)
    try:
        cascade = trainer.bundle.cascade
        refinement, calls = cascade.refinement_net, []
        refinement.register_forward_hook(lambda *args: calls.append(1))
        built = {name: trainer.phase(name) for name in PHASES}  # the finished run's caches: no recompute
        assert [p.name for p in trainer.phases()] == list(PHASES)
        diffuse, specular = built["diffuse"], built["specular"]
        assert diffuse.stage_forward is ph.first_stage_forward
        assert built["refinement"].stage_forward is ph.full_forward
        assert diffuse.modules == (cascade.diffuse_net,) and built["finetune"].modules == (cascade,)
        assert diffuse.cache is specular.cache is built["refinement"].cache  # stage 1 loaded once
        assert (diffuse.size, built["finetune"].size) == (4, 1)  # finetune_samples = 1
        idx, gen = torch.tensor([0, 1]), torch.Generator().manual_seed(0)
        with torch.no_grad():
            loss, parts = specular.loss(cascade, idx, gen)
            assert set(parts) == {"specular", "roughness"} and torch.isfinite(loss)
            assert calls == [] and cascade.refinement_net is refinement
            first = diffuse.forward(cascade, idx)
            full = built["refinement"].forward(cascade, idx)
        assert len(calls) == 1 and first.rendered_photos is None and first.maps is first.coarse
        assert torch.equal(first.coarse.stack(), full.coarse.stack())  # the same first stage
        with pytest.raises(ValueError, match="no phase 'dualloss' in this run"):
            trainer.phase("dualloss")
    finally:
        trainer.close()


def test_cli_train_and_wrong_setup(tiny, tiny5, tmp_path, capsys):
    doc = _smoke_doc("train_tiny.toml", tiny)
    doc["stages"] = {"lighting": 2, "diffuse": 0, "specular": 0, "refinement": 0, "finetune": 0}
    cfg = tmp_path / "c.toml"
    cfg.write_text(_toml(doc))
    assert main(["train", str(cfg), "--out", str(tmp_path / "o"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["phases"]["lighting"]["steps"] == 2
    # a finished run: --resume only rewrites model.pt, keeps the summary, --export writes float16
    exported = tmp_path / "shipped.pt"
    assert main(["train", str(cfg), "--out", str(tmp_path / "o"), "--resume", "--export", str(exported)]) == 0
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["phases"]["lighting"]["steps"] == 2
    payload = torch.load(exported, weights_only=False)
    assert payload["optimizer"] is None
    assert {t.dtype for net in payload["model"].values() for t in net.values() if t.is_floating_point()} == {
        torch.float16
    }
    assert (
        main(
            [
                "train",
                str(cfg),
                "--out",
                str(tmp_path / "o"),
                "--resume",
                "--export",
                str(tmp_path / "no" / "x.pt"),
            ]
        )
        == 2
    )
    assert "its folder does not exist" in capsys.readouterr().err
    doc["data"]["train"] = str(tiny5)
    cfg.write_text(_toml(doc))
    assert main(["train", str(cfg), "--out", str(tmp_path / "o2")]) == 2
    assert "a 'five-light' data set" in capsys.readouterr().err


def _toml(doc: dict) -> str:
    lines = []
    for key, value in doc.items():
        if not isinstance(value, dict):
            lines.append(f"{key} = {json.dumps(value)}")
    for key, value in doc.items():
        if isinstance(value, dict):
            lines.append(f"[{key}]")
            for k, v in value.items():
                if isinstance(v, dict):
                    v = "{ " + ", ".join(f"{a} = {json.dumps(b)}" for a, b in v.items()) + " }"
                    lines.append(f"{k} = {v}")
                else:
                    lines.append(f"{k} = {json.dumps(v)}")
    return "\n".join(lines) + "\n"


@pytest.mark.slow
def test_ddp_two_cpu_processes(tiny, tmp_path):
    doc = _smoke_doc("train_tiny.toml", tiny)
    doc["stages"] = {"lighting": 2, "diffuse": 2, "specular": 0, "refinement": 0, "finetune": 0}
    cfg = tmp_path / "c.toml"
    cfg.write_text(_toml(doc))
    env = dict(os.environ, OMP_NUM_THREADS="1", TQDM_DISABLE="1")
    ebr = shutil.which("ebr", path=str(Path(sys.executable).parent))
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node",
        "2",
        ebr,
        "train",
        str(cfg),
        "--out",
        str(tmp_path / "ddp"),
        "--json",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((tmp_path / "ddp" / "summary.json").read_text())
    assert summary["world_size"] == 2 and summary["phases"]["diffuse"]["steps"] == 2
    # rank 0 alone prints (issue 16.15): each phase line and the final line once
    for line in ("lighting: 2 steps", "diffuse: 2 steps", "wrote "):
        assert proc.stderr.count(line) == 1, proc.stderr[-2000:]


# -- inference and evaluation ----------------------------------------------------------------------


def test_predict_and_flash_only(tiny, tiny_model):
    from ebr_mitsuba.data.dataset import GeneratedDataset
    from ebr_mitsuba.model.predict import load_model, predict
    from ebr_mitsuba.svbrdf import SVBRDF

    bundle = load_model(tiny_model)
    assert bundle.resolution == 32 and not bundle.cascade.training
    item = GeneratedDataset(tiny)[0]
    flash, noflash = (item["photos"][k].permute(1, 2, 0).numpy() for k in (0, 1))
    pred = predict(bundle, flash, noflash)
    assert isinstance(pred.maps, SVBRDF) and pred.maps.shape == (32, 32)
    assert pred.env is not None and 1 <= pred.env.num_lobes <= 4
    assert len(pred.env_exemplars) == 4 and pred.flash_only.shape == (32, 32, 3)
    assert pred.selection["env"].images.shape == (3, 32, 32, 3)
    assert {"lighting", "extract", "select", "cascade"} <= set(pred.timings)
    n = np.linalg.norm(pred.maps.normal, axis=-1)
    assert np.allclose(n, 1, atol=1e-4) and pred.maps.diffuse.min() >= 0 and pred.maps.roughness.max() <= 1
    fo = predict(bundle, flash, None)
    assert fo.env is None and fo.env_exemplars == [] and fo.selection["env"] is None
    fixed = predict(bundle, flash, noflash, fixed_roughness=0.5)
    assert fixed.selection["env"].roughness[0] == 0.5
    with pytest.raises(InputError, match=r"flash has shape \(16, 16, 3\); expected \(32, 32, 3\)"):
        predict(bundle, flash[:16, :16], noflash[:16, :16])
    with pytest.raises(InputError, match="near captures only"):
        predict(bundle, flash, noflash, flash, noflash)
    with pytest.raises(InputError, match="wrong kind"):
        load_model(tiny_model, expect_kind="dualloss")


def test_shipped_model_loads():
    from ebr_mitsuba.model.predict import load_model, shipped_model_path

    assert shipped_model_path().is_file(), f"{shipped_model_path()}: the tracked shipped model is missing"
    bundle = load_model(None)
    assert bundle.kind == "ebrenv" and bundle.resolution >= 32
    assert shipped_model_path().stat().st_size <= 20e6  # issue 15: shipped weights ≤ 20 MB


def test_metrics_identity_and_mean_baseline(tiny):
    from ebr_mitsuba import metrics
    from ebr_mitsuba.evaluation.baselines import MeanMaps
    from ebr_mitsuba.svbrdf import SVBRDF

    mean = MeanMaps.from_dataset(tiny)
    m = mean.predict((32, 32))
    pairs = metrics.rerender_pairs(0)
    same = metrics.sample_metrics(m, m, pairs)
    assert same["rerender_rmse"] == 0 and same["ssim"] == pytest.approx(1.0)
    assert same["per_map_rmse"]["mean"] == 0
    other = SVBRDF.uniform(32, 32, 0.5, 0.04, 0.3)
    diff = metrics.sample_metrics(other, m, pairs)
    assert diff["rerender_rmse"] > 0 and diff["ssim"] < 1 and diff["per_map_rmse"]["diffuse"] > 0
    assert pairs.count == 30 and torch.equal(metrics.rerender_pairs(0).lights, pairs.lights)


def test_cli_eval_json(tiny, tiny_model, capsys):
    code = main(
        [
            "eval",
            "--checkpoint",
            str(tiny_model),
            "--data",
            str(tiny),
            "--limit",
            "1",
            "--baseline-mean",
            str(tiny),
            "--baseline-checkpoint",
            f"again={tiny_model}",
            "--json",
        ]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["per_map_rmse"]) == {"normal", "diffuse", "roughness", "specular", "mean"}
    assert out["n"] == 1 and len(out["per_sample"]) == 1 and out["seconds_per_sample"] > 0
    assert 0 <= out["ssim"] <= 1 and out["rerender_rmse"] > 0
    assert out["baselines"]["mean_maps"]["n"] == 1 and "procedural" in out["groups"]
    # the same checkpoint as a baseline scores the same maps on the same pairs
    again = out["baselines"]["again"]
    assert again["per_map_rmse"] == pytest.approx(out["per_map_rmse"], rel=1e-6)
    # float32 renders summed by Dr.Jit's threads: the reduction order may differ (≈1e-6 relative)
    assert again["rerender_rmse"] == pytest.approx(out["rerender_rmse"], rel=1e-5)
    for bad in ("again", "again=", f"mean_maps={tiny_model}"):
        assert (
            main(["eval", "--checkpoint", str(tiny_model), "--data", str(tiny), "--baseline-checkpoint", bad])
            == 2
        )
        assert "--baseline-checkpoint" in capsys.readouterr().err
    assert main(["eval", "--checkpoint", str(tiny_model), "--data", str(tiny), "--limit", "-1"]) == 2
    assert "--limit -1" in capsys.readouterr().err


def test_bench_models_page(tiny, tiny_nf, tiny_model, tmp_path, monkeypatch):
    """``ebr bench models`` on tiny data: every predictor scored on the same samples, the page,
    the contact sheet and the plots written, the acceptance lines computed; the near-far section
    on tiny near-far data (no near-far model installed: the near model with and without the far
    pair)."""
    from ebr_mitsuba.bench import models
    from ebr_mitsuba.model import predict as inference

    for name in ("EBR_SPLIT_DATA", "EBR_TRAIN_DATA", "EBR_SHIPPED_RUN", "EBR_CANDIDATES", "EBR_REFINE"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("EBR_NEAR_FAR_DATA", str(tiny_nf))
    assert "EBR_SPLIT_DATA" in models.unavailable()
    monkeypatch.setenv("EBR_REFINE", '{"steps": 4}')
    monkeypatch.setitem(models.CAPTURE_CHECK, "res", 64)  # the capture check, small
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    shutil.copy(tiny_model.parent / "log.csv", run_dir / "log.csv")
    monkeypatch.setenv("EBR_SPLIT_DATA", str(tiny))
    monkeypatch.setenv("EBR_TRAIN_DATA", str(tiny))
    monkeypatch.setenv("EBR_SHIPPED_RUN", str(run_dir))
    monkeypatch.setenv("EBR_CANDIDATES", f"previous={tiny_model}")
    shipped = lambda near_far=False: tmp_path / "none.pt" if near_far else tiny_model  # noqa: E731
    monkeypatch.setattr(inference, "shipped_model_path", shipped)
    assert models.unavailable() is None
    run = {"per_map_rmse": dict.fromkeys(("normal", "diffuse", "roughness", "specular", "mean"), 0.5)}
    run |= {"metal_rough": {"base colour": 0.25, "metallic": 0.125}, "rerender_rmse": 0.75, "ssim": 0.5}
    run |= {"steps": 7, "hours": 0.5}
    ablation = {"date": "today", "machine": "here", "n": 3, "quick": False, "runs": {"dual loss": run}}
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "fivelight.json").write_text(json.dumps(ablation))  # ebr bench fivelight's
    page = models.run(tmp_path / "docs", quick=True, log=lambda msg: None)
    text = page.read_text()
    assert (
        "| dual loss | 0.5000 | 0.5000 | 0.5000 | 0.5000 | 0.5000 | 0.2500 | 0.1250 | 0.7500 | 7 steps"
        in text
    )
    for row in (
        "| shipped model |",
        "| previous |",
        "| oracle constant |",
        "| training-set mean maps |",
        "| EBREnv paper",
    ):
        assert row in text
    assert "quick run" in text and "| lighting | 2 |" in text and "**previous**:" in text
    # ebr estimate on the photo files, with and without refinement, judged per case on maps and lights
    assert "| shipped model, ebr estimate |" in text
    assert "| shipped model, ebr estimate + refinement (steps 4) |" in text
    verdict = json.loads((tmp_path / "docs" / "models.json").read_text())["refinement_verdict"]
    assert verdict["n"] == 2 and len(verdict["cases"]) == 2 and 0 <= verdict["both"] <= 1
    assert f"both in {100 * verdict['both']:.0f} %" in text
    near_far = json.loads((tmp_path / "docs" / "models.json").read_text())["near_far"]
    assert set(near_far) == {models.NEAR_ONLY, models.NEAR_FAR_FIT, "oracle constant"}
    for name in near_far:
        assert f"| {name} |" in text
    assert "No near-far model is installed" in text and "acceptance: below" in text
    check = json.loads((tmp_path / "docs" / "models.json").read_text())["capture_check"]
    assert 0 < check["flash_rel_rmse"] and check["flash"]["source"] == "capture.json"
    assert f"off by {100 * check['flash_rel_rmse']:.1f} % relative RMSE" in text
    for png in ("models_loss.png", "models_maps.jpg", "models_classes.png"):
        assert (tmp_path / "docs" / png).is_file()
    monkeypatch.setenv("EBR_NEAR_FAR_DATA", str(tmp_path / "nowhere"))
    with pytest.raises(InputError, match="EBR_NEAR_FAR_DATA"):
        models.near_far_results(1)
    monkeypatch.setenv("EBR_CANDIDATES", "broken")
    with pytest.raises(InputError, match="EBR_CANDIDATES"):
        models.run(tmp_path / "docs2", quick=True, log=lambda msg: None)
    monkeypatch.setenv("EBR_CANDIDATES", "")
    monkeypatch.setenv("EBR_REFINE", "[1]")
    with pytest.raises(InputError, match="EBR_REFINE"):
        models.run(tmp_path / "docs3", quick=True, log=lambda msg: None)


def test_init_nets_takes_only_the_named_nets(tiny, tiny_model, tmp_path):
    """``[train] init_nets``: the named nets start from ``init``, the others from their own seeded
    initialisation; a name the checkpoint lacks is refused with the fix."""
    import torch

    from ebr_mitsuba.errors import InputError

    init = ck.load_checkpoint(tiny_model, expect_kind="ebrenv")["model"]

    def weights(nets: list[str], out: Path) -> dict:
        doc = _smoke_doc(FIXTURE_CONFIG, tiny)
        doc["stages"] = dict.fromkeys(PHASES, 0)  # no step: the weights are the initial ones
        doc["train"].update(init=str(tiny_model), init_nets=nets)
        _train(doc, out)
        return ck.load_checkpoint(out / "model.pt", expect_kind="ebrenv")["model"]

    def same(a: dict, b: dict) -> bool:
        return all(torch.equal(a[k].float(), b[k].float()) for k in a)

    only = weights(["lighting"], tmp_path / "lighting")
    assert same(only["lighting"], init["lighting"])
    assert not same(only["cascade"], init["cascade"])  # trained weights differ from a fresh net's
    both = weights([], tmp_path / "all")
    assert same(both["lighting"], init["lighting"]) and same(both["cascade"], init["cascade"])

    doc = _smoke_doc(FIXTURE_CONFIG, tiny)
    doc["train"].update(init=str(tiny_model), init_nets=["mair"])
    with pytest.raises(InputError, match=r"has no mair weights.*init_nets"):
        _train(doc, tmp_path / "bad")
