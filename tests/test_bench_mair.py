"""``ebr bench mair`` (ebr_mitsuba.bench.mair) end to end on a tiny Mitsuba multi-view test set
(two samples, 32², 4 spp), and its parts: the centre-view-only predictor, the lighting error,
the acceptance verdicts. The models are conftest's two-step ``configs/mair_tiny.toml`` run and a
centre-view-only one: the page's figures are meaningless; the tests check what is scored and
written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import tomllib
import torch

from ebr_mitsuba.bench import mair as bench
from ebr_mitsuba.cli import main
from ebr_mitsuba.errors import InputError

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread

TEST_SET = """\
[dataset]
seed = 3000
count = 2
resolution = 32
[capture]
setup = "multi-view"
noflash_view = true
[render]
renderer = "mitsuba"
spp = 4
[exemplars]
env_roughness = []
point_roughness = []
[camera]
meter = 0.9
[[materials]]
type = "procedural"
[[environments]]
type = "procedural"
"""


@pytest.fixture(scope="module")
def mv_test(tmp_path_factory) -> Path:
    """Two Mitsuba multi-view samples (camera images and the no-flash view, as
    configs/data_real_multiview_test.toml)."""
    root = tmp_path_factory.mktemp("mvtest")
    (root / "data.toml").write_text(TEST_SET)
    assert main(["generate", str(root / "data.toml"), "--out", str(root / "data")]) == 0
    return root / "data"


@pytest.fixture(scope="module")
def centre_run(tiny_mv, tmp_path_factory) -> Path:
    from ebr_mitsuba.model.config import parse_config
    from ebr_mitsuba.train.trainer import Trainer

    doc = tomllib.loads((CONFIGS / "mair_tiny.toml").read_text())
    doc["data"] = {"train": str(tiny_mv)}
    doc["model"] = {**doc.get("model", {}), "views": "centre"}
    out = tmp_path_factory.mktemp("mair_centre") / "run"
    Trainer(parse_config(doc, "mair_tiny_centre.toml"), out).run()
    return out


def test_quick_page_scores_every_run_lighting_and_insertion(
    mair_tiny_run, centre_run, mv_test, tiny_mv, tmp_path, monkeypatch
):
    monkeypatch.setenv("EBR_MAIR_DATA", str(mv_test))
    monkeypatch.setenv("EBR_MAIR_RUNS", f"attention={mair_tiny_run}; centre view only={centre_run}")
    monkeypatch.setenv("EBR_TRAIN_DATA", str(tiny_mv))
    monkeypatch.delenv("EBR_SPLIT_DATA", raising=False)
    path = bench.run(tmp_path, quick=True, log=lambda msg: None)
    page = path.read_text()
    for row in ("| attention |", "| centre view only |", f"| {bench.CENTRE_ONLY} |", "| oracle constant |"):
        assert row in page, row
    assert "| training-set mean maps |" in page and "quick run: 2 samples only" in page
    record = json.loads((tmp_path / "mair_eval.json").read_text())
    assert record["roles"] == {"attention": "attention", "centre view only": "centre view"}
    for name in ("attention", "centre view only", bench.CENTRE_ONLY):
        res = record["results"][name]
        assert (
            res["n"] == 2 and np.isfinite(res["per_map_rmse"]["mean"]) and np.isfinite(res["rerender_rmse"])
        )
        g4 = record["lighting"][name]
        assert np.isfinite(g4["g4"]) and g4["g4"] >= 0 and g4["constant"] > 0
    # the centre-only run is the centre-view comparison; mean pooling was not given
    assert "attention against the centre view alone** (centre view only)" in page
    assert "attention against mean pooling: not measured" in page
    (row,) = record["insertion"]  # quick: one sample
    assert row["noise_floor"] > 0 and np.isfinite(row["rel_rmse"]) and row["env"].endswith("SG lobes")
    # composited into the sample's no-flash view, as ebr insert does
    assert row["composited"] and "Composited into each sample's no-flash view" in page
    # the error taken apart: every swap measured; this sample's environment is its lobes, so the
    # true maps under them leave only the photo's own noise, the tiny model's lighting far more
    assert set(row["swaps"]) == {"maps", "lighting", "lobes"}
    assert all(np.isfinite(v) and v >= 0 for v in row["swaps"].values())
    assert row["swaps"]["lobes"] < 0.5 * row["swaps"]["lighting"]
    assert "| estimate | estimated maps, true environment |" in page
    for picture in ("mair_eval.jpg", "mair_eval_maps.jpg"):
        assert (tmp_path / picture).stat().st_size > 0, picture
    assert "![views, maps, lighting and an insertion of one test sample](mair_eval.jpg)" in page


def test_centre_view_only_feeds_the_centre_view(mair_tiny_run):
    from ebr_mitsuba.estimate.multiview import load_mair
    from ebr_mitsuba.nets.mair_views import multiview_shots

    model = load_mair(mair_tiny_run / "model.pt")
    rng = np.random.default_rng(0)
    views = rng.uniform(0, 0.5, (9, 32, 32, 3)).astype(np.float32)
    cams = [s.camera for s in multiview_shots()]
    order = [8, 4, 0, 1, 2, 3, 5, 6, 7]  # the centre camera is at position 1 of this order
    got = bench.CentreViewOnly(model).predict_views(views[order], None, [cams[k] for k in order])
    want = model.predict_views(views[4:5], None, [cams[4]])
    assert np.allclose(got.maps.diffuse, want.maps.diffuse) and np.allclose(got.maps.normal, want.maps.normal)
    other = model.predict_views(views[0:1], None, [cams[0]])
    assert not np.allclose(got.maps.diffuse, other.maps.diffuse)


def test_lighting_error_is_zero_for_the_truth_and_scale_free():
    from ebr_mitsuba.model.predictor import PixelLighting

    # a sample whose environment is one lobe, and a per-pixel lighting of that lobe everywhere
    axis = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    sg = torch.tensor([[*axis, 8.0, 2.0, 1.5, 1.0]], dtype=torch.float32)
    item = {"sg": sg, "sg_mask": torch.ones(1)}
    g = 4

    def lighting(scale, sharp=8.0):
        return PixelLighting(
            np.broadcast_to(axis, (1, g, g, 3)).astype(np.float32),
            np.full((1, g, g), sharp, np.float32),
            np.ones((1, g, g), np.float32),
            np.array([[2.0, 1.5, 1.0]], np.float32) * scale,
        )

    exact, constant = bench.lighting_errors(lighting(1.0), item, 8, 16)
    assert exact < 1e-6 and constant > 0.01
    assert bench.lighting_errors(lighting(7.0), item, 8, 16)[0] < 1e-3  # scale-invariant (log1p: nearly)
    assert bench.lighting_errors(lighting(1.0, sharp=80.0), item, 8, 16)[0] > 1e-3


def test_acceptance_verdicts():
    def rec(att, mean, centre):
        res = {"a": att, "m": mean, "c": centre}
        return {
            "results": {k: {"per_map_rmse": {"mean": v}} for k, v in res.items()},
            "roles": {"a": "attention", "m": "mean pooling", "c": "centre view"},
        }

    lines = "\n".join(bench.acceptance_lines(rec(0.080, 0.090, 0.100)))
    assert "the centre view alone** (c): mean per-map RMSE 0.0800 against 0.1000, +20% lower" in lines
    assert lines.count("— yes") == 2
    lines = "\n".join(bench.acceptance_lines(rec(0.080, 0.082, 0.090)))
    assert lines.count("— no") == 2  # 2 % below mean pooling, 11 % below the centre view
    r = rec(0.080, 0.090, 0.100)
    r["insertion"] = [{"rel_rmse": 0.15, "noise_floor": 0.1}, {"rel_rmse": 0.3, "noise_floor": 0.1}]
    lines = "\n".join(bench.acceptance_lines(r))
    assert "within 2× of the truth-vs-truth noise floor in 1 of 2 samples (ratios 1.5, 3.0) — no" in lines
    r["insertion"] = r["insertion"][:1]
    assert "in 1 of 1 samples (ratios 1.5) — yes" in "\n".join(bench.acceptance_lines(r))


def test_refusals(monkeypatch, tmp_path, tiny_mv):
    monkeypatch.delenv("EBR_MAIR_DATA", raising=False)
    assert "EBR_MAIR_DATA" in bench.unavailable()
    monkeypatch.setenv("EBR_MAIR_DATA", str(tiny_mv))
    monkeypatch.setenv("EBR_MAIR_RUNS", f"attention={tmp_path}")
    with pytest.raises(InputError, match="is not NAME=RUN_DIR with RUN_DIR/model.pt"):
        bench.run(tmp_path / "out", quick=True, log=lambda msg: None)
    assert not (tmp_path / "out").exists()
