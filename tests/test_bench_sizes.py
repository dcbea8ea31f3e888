"""``ebr bench sizes``: the size-curve points' configs, the choice, the timings, the run reuse, and
``[model].cascade_size``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import tomllib

from ebr_mitsuba.bench import sizes
from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.model.config import load_config, parse_config
from ebr_mitsuba.nets import CascadeConfig
from ebr_mitsuba.nets.nafnet import SIZE_PRESETS, NAFNet, parameter_count

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread


def _doc(data: Path, **model) -> dict:
    doc = tomllib.loads(sizes.CONFIG.read_text())
    doc["data"] = {"train": str(data), "max_samples": 2}
    doc["train"].update(batch_size=2, log_every=1, checkpoint_every=1, threads=1, init="")
    doc["stages"].update(diffuse=2, specular=2)
    doc["extract"] = {"iters": 3, "max_lobes": 4}
    doc["model"].update(model)
    return doc


def test_cascade_size_sizes_the_cascade_alone(tmp_path):
    cfg = parse_config(_doc(tmp_path, size="small", cascade_size="tiny"), "curve.toml")
    assert cfg.lighting_config(4).size == SIZE_PRESETS["small"]
    assert cfg.cascade_config().size == SIZE_PRESETS["tiny"]
    plain = parse_config(_doc(tmp_path, size="small"), "curve.toml")  # the shipped config's default
    doc = plain.to_dict()
    doc["model"].pop("cascade_size")
    assert parse_config(doc, "plain.toml").cascade_config().size == SIZE_PRESETS["small"]
    with pytest.raises(ConfigError, match=r"curve\.toml: model.*huge"):
        parse_config(_doc(tmp_path, cascade_size="huge"), "curve.toml")


def test_point_config_varies_the_size_alone(monkeypatch, tmp_path):
    monkeypatch.setenv("EBR_TRAIN_DATA", str(tmp_path))
    monkeypatch.setenv("EBR_INIT", str(tmp_path / "init.pt"))
    base = load_config(sizes.CONFIG)
    point = sizes.point_config(base, "medium", quick=False)
    assert point.model["cascade_size"] == "medium" and point.cascade_config().size == SIZE_PRESETS["medium"]
    assert point.lighting_config(4).size == SIZE_PRESETS["small"]  # every point: the shipped lighting net
    assert point.stages == base.stages and point.data == base.data and point.train == base.train
    assert base.model["cascade_size"] == "small"  # base untouched
    quick = sizes.point_config(base, "tiny", quick=True)
    assert quick.data.max_samples == sizes.QUICK_SAMPLES
    assert (quick.stages.diffuse, quick.stages.specular) == (sizes.QUICK_STEPS,) * 2
    assert base.stages.diffuse > sizes.QUICK_STEPS


def _point(mean: float) -> dict:
    return {"network": {"per_map_rmse": {"mean": mean}}}


def test_choose_takes_a_larger_size_only_past_the_margin():
    assert sizes.choose({"tiny": _point(0.100), "small": _point(0.099), "medium": _point(0.0995)}) == "tiny"
    assert sizes.choose({"tiny": _point(0.100), "small": _point(0.097), "medium": _point(0.096)}) == "small"
    assert sizes.choose({"tiny": _point(0.100), "small": _point(0.105), "medium": _point(0.090)}) == "medium"
    assert sizes.choose({"tiny": _point(0.1), "paper": {"parameters": 1}}) == "tiny"  # untrained: no vote
    assert sizes.choose({"paper": {"parameters": 1}}) is None


def test_time_size_counts_the_two_nets_and_times_them(monkeypatch, tmp_path):
    monkeypatch.setattr(sizes, "TIMING_SIZE", 32)
    cfg = CascadeConfig()
    t = sizes.time_size("tiny", cfg, 16, repeats=1)
    ex = 3 * cfg.num_env_exemplars
    expected = parameter_count(NAFNet(6 + ex, 6, SIZE_PRESETS["tiny"])) + parameter_count(
        NAFNet(6 + 3 * cfg.num_point_exemplars, 4, SIZE_PRESETS["tiny"])
    )
    assert t["parameters"] == expected
    assert t["forward_seconds"] > 0 and t["train_step_seconds"] > 0
    # another device's timings, as `python -m ebr_mitsuba.bench.sizes --time-only` writes them
    other = {"device": "Some GPU", "torch": "x", "sizes": {"tiny": {"128": t, "256": t}}}
    (tmp_path / "sizes_cuda.json").write_text(json.dumps(other))
    (tmp_path / "sizes_broken.json").write_text("{")  # unreadable: left out, not an error
    lines = "\n".join(sizes.device_lines(tmp_path, steps=600))
    assert "Some GPU" in lines and "| tiny |" in lines
    assert f"{t['train_step_seconds'] * 600 / 60:.1f} min" in lines
    out = tmp_path / "t.json"
    monkeypatch.setattr(sizes, "TRAINED", ("tiny",))
    monkeypatch.setattr(sizes, "TIMED_ONLY", ())
    monkeypatch.setattr(sizes, "time_all", lambda device: {"device": device, "sizes": {}})
    assert sizes.main(["--time-only", "--out", str(out)]) == 0
    assert json.loads(out.read_text())["device"] == "cpu"


def test_train_point_reuses_resumes_and_refuses(tiny, tmp_path):
    logged: list[str] = []
    cfg = parse_config(_doc(tiny, cascade_size="tiny"), "curve.toml")
    first = tmp_path / "tiny"
    summary = sizes.train_point(cfg, first, None, logged.append)
    assert set(summary["phases"]) == {"diffuse", "specular"} and (first / "model.pt").is_file()
    stage1 = sorted(p.name for p in (first / "cache" / "stage1").glob("*.npz"))
    assert stage1
    again = sizes.train_point(cfg, first, None, logged.append)  # finished, same config: reused
    assert again == summary and any("reusing" in m for m in logged)
    other = parse_config(_doc(tiny, cascade_size="small"), "curve.toml")
    with pytest.raises(InputError, match="another config"):
        sizes.train_point(other, first, None, logged.append)
    second = tmp_path / "small"  # the next point starts with the first point's stage-1 cache
    sizes._link_stage1(first, second)
    assert sorted(p.name for p in (second / "cache" / "stage1").glob("*.npz")) == stage1
    assert (second / "cache" / "stage1" / stage1[0]).stat().st_ino == (
        first / "cache" / "stage1" / stage1[0]
    ).stat().st_ino
    sizes.train_point(other, second, first, logged.append)  # a cache-only folder starts a run
    assert (second / "model.pt").is_file()


def test_unavailable_names_the_variables(monkeypatch):
    monkeypatch.delenv("EBR_TRAIN_DATA", raising=False)
    monkeypatch.setenv("EBR_VAL_DATA", "x")
    assert "$EBR_TRAIN_DATA" in sizes.unavailable()
    monkeypatch.setenv("EBR_TRAIN_DATA", "x")
    assert sizes.unavailable() is None
    with pytest.raises(InputError, match=r"\$EBR_TRAIN_DATA = x: not a data set"):
        sizes.run("/nonexistent-out", quick=True, log=lambda m: None)


def test_page_rows_the_points_the_choice_and_the_untrained_size(monkeypatch, tmp_path):
    monkeypatch.setenv("EBR_TRAIN_DATA", str(tmp_path))
    monkeypatch.setenv("EBR_INIT", str(tmp_path / "init.pt"))
    cfg = sizes.point_config(load_config(sizes.CONFIG), "small", quick=False)

    def scored(mean: float) -> dict:
        maps = {k: mean for k in sizes.MAP_NAMES}
        return {"per_map_rmse": maps, "rerender_rmse": 2 * mean}

    timing = {"parameters": 1234567, "forward_seconds": 0.05, "train_step_seconds": 0.2}
    points = {
        "tiny": {**timing, "run_seconds": 60.0, "network": scored(0.1), "estimate": scored(0.05)},
        "small": {**timing, "run_seconds": 120.0, "network": scored(0.08), "estimate": scored(0.04)},
        "paper": {**timing, "train_step_seconds": 4.0},
    }
    shipped = {"network": scored(0.09), "estimate": scored(0.045)}
    chosen = sizes.choose(points)
    page = sizes._page(points, shipped, chosen, cfg, False, 10.0, "VAL", 24, "quiet.")
    assert chosen == "small" and "| small (chosen) | 1 234 567 | 50 ms | 200 ms | 2.0 min |" in page
    steps = cfg.stages.diffuse + cfg.stages.specular
    assert f"not trained (≈ {4.0 * steps / 3600:.1f} h of steps)" in page
    assert "**Chosen: `small`**" in page and "(0.0800)" in page
    assert "reference) | | | | | 0.0900" in page and "Quick run" not in page
