"""Near-far training of the EBREnv networks (four shots in; ebr_mitsuba.train, ``ebr train``).

A tiny near-far data set (4 samples at 32², fast renderer, configs/data_tiny_near_far.toml: the
``tiny_nf`` fixture of tests/conftest.py, generated once per test run) is shared, and
configs/train_tiny_near_far.toml trains two steps of every phase on it through the CLI; the
trained model then predicts from the four shots, and the training path of
stage 2 is checked against :func:`ebr_mitsuba.model.predict.predict` on the same sample.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tomllib
import torch

from ebr_mitsuba.cli import main
from ebr_mitsuba.errors import InputError
from ebr_mitsuba.model.config import PHASES, load_config, parse_config

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
NEAR_FAR_SHOTS = ["flash", "noflash", "far_flash", "far_noflash"]


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread


@pytest.fixture(scope="module")
def run_nf(tiny_nf, tmp_path_factory) -> Path:
    """configs/train_tiny_near_far.toml as shipped, through ``ebr train``: two steps per phase."""
    out = tmp_path_factory.mktemp("run_nf") / "run"
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("EBR_TRAIN_DATA", str(tiny_nf))
        code = main(["train", str(CONFIGS / "train_tiny_near_far.toml"), "--out", str(out)])
    assert code == 0
    return out


def _shots(item: dict) -> list[np.ndarray]:
    """The four photos at the reference exposure (÷ the recorded exposure, as training sees them)."""
    return [item["photos"][k].permute(1, 2, 0).numpy() / float(item["exposure"]) for k in range(4)]


def test_tiny_near_far_data_has_four_shots(tiny_nf):
    from ebr_mitsuba.data.dataset import GeneratedDataset
    from ebr_mitsuba.train.data import CAPTURE_SHOTS, load_training_data

    ds = GeneratedDataset(tiny_nf)
    assert ds.shot_names == NEAR_FAR_SHOTS and list(CAPTURE_SHOTS["near-far"]) == NEAR_FAR_SHOTS
    assert ds.flash_only_names == ["flash", "far_flash"]
    d = load_training_data(tiny_nf)
    idx = torch.tensor([2, 0])
    x = d.shots(idx, CAPTURE_SHOTS["near-far"])
    assert x.shape == (2, 12, 32, 32)
    assert torch.equal(x[:, 6:9], d.photos[idx, 2]) and torch.equal(
        d.flash_only_of(idx, "far_flash"), d.flash_only[idx, 1]
    )
    far = d.far_flash_only(idx)
    assert torch.equal(far, (d.photos[idx, 2] - d.photos[idx, 3]).clamp_min(0.0))  # PNG photos are >= 0
    assert far.mean() > 0  # the far flash lights the sample
    with pytest.raises(InputError, match="flash-only images \\['flash', 'far_flash'\\], not 'light0'"):
        d.flash_only_of(idx, "light0")


def test_every_phase_trains_two_steps(run_nf):
    summary = json.loads((run_nf / "summary.json").read_text())
    assert list(summary["phases"]) == list(PHASES)
    for phase, info in summary["phases"].items():
        assert info["steps"] == 2 and np.isfinite(info["final_loss"]), phase
    rows = (run_nf / "log.csv").read_text().splitlines()
    assert len(rows) == 1 + 2 * len(PHASES)
    assert len(list((run_nf / "cache" / "stage1").glob("*.npz"))) == 4
    assert len(list((run_nf / "cache" / "stage2").glob("*.npz"))) == 2  # finetune_samples = 2
    from ebr_mitsuba.model.checkpoint import load_checkpoint

    data = load_checkpoint(run_nf / "model.pt")
    assert data["data"]["setup"] == "near-far" and data["config"]["model"]["capture"] == "near-far"


def test_predict_from_four_shots(tiny_nf, run_nf):
    from ebr_mitsuba.data.dataset import GeneratedDataset
    from ebr_mitsuba.model.predict import load_model, predict
    from ebr_mitsuba.svbrdf import SVBRDF

    bundle = load_model(run_nf / "model.pt")
    assert bundle.lighting.config.num_shots == 4 and bundle.cascade.config.num_photos == 4
    flash, noflash, far_flash, far_noflash = _shots(GeneratedDataset(tiny_nf)[1])
    pred = predict(bundle, flash, noflash, far_flash, far_noflash)
    assert isinstance(pred.maps, SVBRDF) and pred.maps.shape == (32, 32)
    m = pred.maps
    assert np.allclose(np.linalg.norm(m.normal, axis=-1), 1, atol=1e-4)
    for a in (m.diffuse, m.specular, m.roughness):
        assert np.all(np.isfinite(a)) and a.min() >= 0 and a.max() <= 1
    assert pred.env is not None and 1 <= pred.env.num_lobes <= 4 and len(pred.env_exemplars) == 4
    with pytest.raises(InputError, match="needs the far flash and far no-flash shots"):
        predict(bundle, flash, noflash)


def test_stage2_training_path_matches_predict(tiny_nf, run_nf):
    """The finetune phase's cascade inputs (cached lighting, SGs, selections; photos; far
    flash-only image) are the ones predict builds: the same weights give the same maps."""
    from ebr_mitsuba.data.dataset import GeneratedDataset
    from ebr_mitsuba.model.predict import predict
    from ebr_mitsuba.train.trainer import Trainer

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("EBR_TRAIN_DATA", str(tiny_nf))
        config = load_config(CONFIGS / "train_tiny_near_far.toml")
    trainer = Trainer(config, run_nf, resume=True)  # the finished run's weights and caches
    finetune = trainer.phase("finetune")  # loads the stage-2 cache (files exist: no recompute)
    trainer.bundle.train(False)
    i = 1
    with torch.no_grad():
        out = finetune.forward(trainer.bundle.cascade, torch.tensor([i]))
    trainer.close()  # releases the lock of run_nf (a Trainer that is not run keeps it)
    assert out.rendered_photos.shape == (1, 12, 32, 32)
    pred = predict(trainer.bundle, *_shots(GeneratedDataset(tiny_nf)[i]))
    train_maps = out.maps.to_svbrdf(0)
    for name in ("normal", "diffuse", "specular", "roughness"):
        # measured ≤ 7e-7; the data set's (clipping-free) far flash-only image instead of the
        # photos' difference gives 4e-3 … 4e-2, halving the far photos 0.06 … 0.3
        np.testing.assert_allclose(
            getattr(train_maps, name), getattr(pred.maps, name), atol=1e-5, err_msg=name
        )


def test_setup_mismatch_is_one_line_exit_2(tiny, tiny_nf, tmp_path, capsys, monkeypatch):
    cases = [
        (
            "train_tiny_near_far.toml",
            tiny,
            "a 'near' data set; train_tiny_near_far.toml has [model].capture = 'near-far'",
        ),
        ("train_tiny.toml", tiny_nf, "a 'near-far' data set; train_tiny.toml has [model].capture = 'near'"),
    ]
    for k, (name, data, message) in enumerate(cases):
        monkeypatch.setenv("EBR_TRAIN_DATA", str(data))
        out = tmp_path / f"out{k}"
        assert main(["train", str(CONFIGS / name), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
        assert not out.exists()  # refused before anything is written


def test_near_far_cascade_needs_far_flash_only():
    from ebr_mitsuba.model.renders import cascade_forward
    from ebr_mitsuba.nets import Cascade

    size = {"width": 4, "enc_blk_nums": [1], "middle_blk_num": 1, "dec_blk_nums": [1]}
    doc = {"data": {"train": "x"}, "model": {"capture": "near-far", "size": size}}
    cascade = Cascade(parse_config(doc).cascade_config())
    img = torch.rand(1, 3, 8, 8)
    ex = torch.rand(1, 3, 3, 8, 8)
    with pytest.raises(InputError, match="needs far_flash_only"):
        cascade_forward(cascade, img, img, ex, ex, torch.rand(1, 12, 8, 8), [None], 10.0)


def test_train_near_far_config_parses(monkeypatch, tmp_path):
    monkeypatch.setenv("EBR_TRAIN_DATA", str(tmp_path))
    for name in ("train_near_far.toml", "train_tiny_near_far.toml"):
        config = load_config(CONFIGS / name)
        assert config.model["capture"] == "near-far" and config.lighting_config(4).num_shots == 4, name
        assert config.cascade_config().num_photos == 4
    doc = tomllib.loads((CONFIGS / "data_tiny_near_far.toml").read_text())
    assert doc["capture"]["setup"] == "near-far"


def test_eval_scores_a_near_far_model(tiny_nf, run_nf, capsys):
    """``ebr eval`` passes the far pair to a near-far model."""
    from ebr_mitsuba.cli import main

    code = main(
        ["eval", "--checkpoint", str(run_nf / "model.pt"), "--data", str(tiny_nf), "--limit", "1", "--json"]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["n"] == 1 and np.isfinite(out["per_map_rmse"]["mean"])
