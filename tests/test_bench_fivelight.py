"""``ebr bench fivelight`` (ebr_mitsuba.bench.fivelight) end to end on the tiny five-light data set,
its refusals, and the grid-resampled dual-loss estimate of ``ebr eval`` (a data set finer than the
model's grid). The models are two-step runs of ``configs/dualloss_tiny.toml``: the page's figures
are meaningless; the tests check what is scored and written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from ebr_mitsuba.bench import fivelight as bench
from ebr_mitsuba.cli import main
from ebr_mitsuba.errors import InputError

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread


@pytest.fixture(scope="module")
def runs(tiny5, tmp_path_factory) -> dict[str, Path]:
    """Two tiny dual-loss runs (the ablation's three names, the third reusing the first run)."""
    root = tmp_path_factory.mktemp("dlruns")
    out = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("EBR_TRAIN_DATA", str(tiny5))
        for name in ("dual", "params"):
            assert main(["train", str(CONFIGS / "dualloss_tiny.toml"), "--out", str(root / name)]) == 0
            out[name] = root / name
    return out


def test_quick_page_scores_every_run_and_baseline(runs, tiny5, tmp_path, monkeypatch):
    monkeypatch.setenv("EBR_FIVELIGHT_DATA", str(tiny5))
    monkeypatch.setenv("EBR_TRAIN_DATA", str(tiny5))
    monkeypatch.setenv(
        "EBR_FIVELIGHT_RUNS",
        f"dual loss={runs['dual']}; parameter loss only={runs['params']}; rendering loss only={runs['dual']}",
    )
    monkeypatch.delenv("EBR_SPLIT_DATA", raising=False)
    models_page = "# Models\n\nabove\n\n## Five known lights\n\nold text\n\n## Contact sheet\n\nbelow\n"
    (tmp_path / "models.md").write_text(models_page)
    path = bench.run(tmp_path, quick=True, log=lambda msg: None)
    page = path.read_text()
    for row in ("| dual loss |", "| parameter loss only |", "| rendering loss only |", "| oracle constant |"):
        assert row in page
    assert "training-set mean maps" in page
    assert "quick run: 2 samples only" in page
    # the dual run is scored against itself as "rendering loss only": a tie is not a win
    assert "does **not** beat both single losses" in page
    assert "normal RMSE" in page and "≤ 0.03" in page
    assert (tmp_path / "fivelight_maps.jpg").stat().st_size > 0
    assert (tmp_path / "fivelight_loss.png").stat().st_size > 0
    # the ablation beside the paper's figures, also in the models.md beside the page (the rest kept)
    ablation = json.loads((tmp_path / "fivelight.json").read_text())
    assert list(ablation["runs"]) == ["dual loss", "parameter loss only", "rendering loss only"]
    dual = ablation["runs"]["dual loss"]
    assert 0 <= dual["metal_rough"]["metallic"] <= 1 and dual["steps"] == 2
    models = (tmp_path / "models.md").read_text()
    assert "old text" not in models and models.startswith("# Models\n\nabove\n\n## Five known lights")
    assert models.endswith("## Contact sheet\n\nbelow\n")
    for text in (models, page):
        assert "| paper, dual loss (their test set) |" in text and "its test set differs" in models
        assert f"| dual loss | {dual['per_map_rmse']['normal']:.4f} |" in text
        assert f"{dual['metal_rough']['base colour']:.4f} | {dual['metal_rough']['metallic']:.4f}" in text
    assert "once `ebr bench fivelight` has written `fivelight.json`" in "\n".join(bench.models_section(None))


def test_refuses_a_missing_data_set_and_a_bad_run_list(runs, tiny5, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("EBR_FIVELIGHT_DATA", raising=False)
    assert bench.unavailable() is not None
    assert main(["bench", "fivelight", "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip().splitlines()  # the "[bench] fivelight ..." line, then one error
    assert "Traceback" not in "\n".join(err)
    assert err[-1].startswith("ebr bench: error:") and "EBR_FIVELIGHT_DATA" in err[-1]
    monkeypatch.setenv("EBR_FIVELIGHT_DATA", str(tiny5))
    monkeypatch.setenv("EBR_FIVELIGHT_RUNS", f"dual={tmp_path / 'nowhere'}")
    with pytest.raises(InputError, match="NAME=RUN_DIR"):
        bench.run(tmp_path / "b", quick=True, log=lambda msg: None)
    assert not (tmp_path / "b" / "fivelight.md").exists()


def test_eval_of_a_finer_data_set_runs_the_model_at_its_grid(runs):
    """Photos finer than the model grid are area-averaged to it and the maps area-resampled back."""
    from ebr_mitsuba.evaluation.evaluate import model_predictor
    from ebr_mitsuba.materials import resample_svbrdf
    from ebr_mitsuba.model.predict import as_predictor, load_model

    bundle = load_model(str(runs["dual"] / "model.pt"), expect_kind="dualloss")
    grid = bundle.resolution
    photos = torch.rand(5, 3, 2 * grid, 2 * grid, generator=torch.Generator().manual_seed(0))
    got = model_predictor(as_predictor(bundle))(
        {"photos": photos, "exposure": 2.0}, [f"light{k}" for k in range(5)]
    )
    assert got.shape == (2 * grid, 2 * grid)
    small = torch.nn.functional.interpolate(photos / 2.0, size=(grid, grid), mode="area")
    with torch.no_grad():
        expect = resample_svbrdf(bundle.dualloss(small[None]).to_svbrdf(0), 2 * grid)
    np.testing.assert_allclose(got.diffuse, expect.diffuse, atol=1e-6)
    np.testing.assert_allclose(got.normal, expect.normal, atol=1e-6)
