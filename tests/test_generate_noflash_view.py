"""``[capture] noflash_view``: generated multi-view samples with the centre camera's no-flash view,
as ``ebr capture --setup multi-view`` writes it (docs/generate.md; ebr_mitsuba/data/config.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cli_run import estimate_json
from conftest import CONFIGS

from ebr_mitsuba.cli import main
from ebr_mitsuba.data.config import load_config, parse_config
from ebr_mitsuba.data.generate import generate
from ebr_mitsuba.errors import ConfigError
from ebr_mitsuba.geometry import capture_shots, setup_shots

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread

COUNT = 2


@pytest.fixture(scope="module")
def with_noflash(tmp_path_factory) -> Path:
    """The first samples of ``configs/data_tiny_multiview.toml`` with ``noflash_view = true``."""
    cfg = load_config(CONFIGS / "data_tiny_multiview.toml").with_count(COUNT)
    cfg = cfg.with_changes("capture", noflash_view=True)
    out = tmp_path_factory.mktemp("mv_noflash") / "data"
    generate(cfg, out, progress=False)
    return out


def _sample(root: Path, i: int) -> dict:
    return json.loads((root / "samples" / f"{i:06d}" / "sample.json").read_text())


def test_the_no_flash_view_is_added_and_the_nine_views_stay_as_they_were(tiny_mv, with_noflash):
    names = [s.name for s in capture_shots("multi-view")]
    assert names == [s.name for s in setup_shots("multi-view")] + ["noflash"]
    for i in range(COUNT):
        new, old = _sample(with_noflash, i), _sample(tiny_mv, i)
        assert [s["name"] for s in new["shots"]] == names
        assert new["shots"][-1]["flash"] is None and new["shots"][-1]["camera"] == new["shots"][4]["camera"]
        assert new["camera"] == old["camera"]  # the same metered exposure
        assert new["render_seeds"][: len(old["render_seeds"])] == old["render_seeds"]
        for shot in old["shots"]:  # the nine flash views: the same files, byte for byte
            a = with_noflash / "samples" / f"{i:06d}" / shot["photo"]
            b = tiny_mv / "samples" / f"{i:06d}" / shot["photo"]
            assert a.read_bytes() == b.read_bytes(), shot["name"]
        photo = with_noflash / "samples" / f"{i:06d}" / new["shots"][-1]["photo"]
        assert photo.is_file()


def test_off_it_leaves_the_fingerprint_of_existing_data_sets_alone(tiny_mv):
    cfg = load_config(CONFIGS / "data_tiny_multiview.toml")
    assert "noflash_view" not in cfg.to_json()["capture"]
    meta = json.loads((tiny_mv / "dataset.json").read_text())
    assert meta["fingerprint"] == cfg.fingerprint()
    on = cfg.with_changes("capture", noflash_view=True)
    assert on.to_json()["capture"]["noflash_view"] is True and on.fingerprint() != cfg.fingerprint()


def test_another_setup_refuses_it(tmp_path, capsys):
    doc = {
        "capture": {"setup": "near", "noflash_view": True},
        "materials": [{"type": "procedural"}],
        "environments": [{"type": "procedural"}],
    }
    with pytest.raises(ConfigError, match="capture.noflash_view: applies to the multi-view setup only"):
        parse_config(doc, "near.toml")
    path = tmp_path / "near.toml"
    path.write_text(
        '[capture]\nsetup = "near"\nnoflash_view = true\n[[materials]]\ntype = "procedural"\n'
        '[[environments]]\ntype = "procedural"\n'
    )
    assert main(["generate", str(path), "--out", str(tmp_path / "out")]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "noflash_view" in err[0] and not (tmp_path / "out").exists()


def test_the_estimate_of_such_a_sample_reads_the_no_flash_view(mair_tiny_run, with_noflash, tmp_path, capsys):
    sample = with_noflash / "samples" / "000000"
    out = tmp_path / "est"
    code, summary, err = estimate_json(
        capsys, "--views", sample, "--checkpoint", mair_tiny_run / "model.pt", "--out", out
    )
    assert code == 0, err
    assert list(summary["inputs"]["paths"])[-1] == "noflash"
    assert summary["flash"]["noflash"]["source"] == "no flash"
    assert summary["exposure"]["to_reference"]["noflash"] is None  # the network does not see it
    assert (out / "rerender" / "noflash.exr").is_file()


def test_mair_training_reads_the_nine_flash_views_of_such_a_set(with_noflash):
    from ebr_mitsuba.model.config import MAIRLossConfig
    from ebr_mitsuba.train.data import load_training_data
    from ebr_mitsuba.train.phases import MultiViewInputs

    data = load_training_data(with_noflash)
    assert data.shot_names[-1] == "noflash"
    inputs = MultiViewInputs.build(data, MAIRLossConfig(), "cpu", views="all")
    assert [data.shot_names[k] for k in inputs.shots] == [s.name for s in setup_shots("multi-view")]
