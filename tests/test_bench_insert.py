"""``ebr bench insert --quick``: a synthetic capture estimated by the shipped model, its insertion
composited and rendered whole against the truth and the truth's noise floor (48², 16 spp:
seconds); the same capture multi-view, estimated by the shipped MAIR model with and without its
no-flash view."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ebr_mitsuba.bench import insert as bench


def test_quick_page_measures_composite_render_and_floor(tmp_path, monkeypatch):
    monkeypatch.delenv("EBR_SPLIT_DATA", raising=False)
    path = bench.run(tmp_path, quick=True)
    page = path.read_text()
    assert path.name == "insert.md" and "Quick mode" in page
    record = json.loads((tmp_path / "insert.json").read_text())
    row, mv = record["rows"]  # quick: one capture, the diffuse sphere; near, then multi-view
    assert row["group"] == "synthetic" and row["material"] == "diffuse" and row["composited"]
    assert row["floor"] > 0 and row["composite"] > 0 and row["render"] > 0
    assert row["composite"] != row["render"]
    assert row["ratio"] == pytest.approx(row["composite"] / row["floor"])
    assert f"**{row['ratio']:.1f}×**" in page and f"{row['render_ratio']:.1f}×" in page
    # the same estimate with its horizon lobes dropped, measured beside it
    assert row["dropped_ratio"] > 0 and f"{row['dropped_ratio']:.1f}× |" in page
    assert "horizon lobes dropped" in page
    for name in ("insert_ratios.png", "insert_0.png", "insert_1.png"):
        assert (tmp_path / name).is_file() and f"]({name})" in page
    # multi-view: composited into the capture's no-flash view; beside it the 9 flash views alone
    assert mv["group"] == bench.MULTIVIEW and mv["material"] == "diffuse" and mv["composited"]
    assert mv["floor"] == pytest.approx(row["floor"])  # the same truth (maps, environment, seeds)
    assert mv["ratio"] == pytest.approx(mv["composite"] / mv["floor"]) and mv["dropped_ratio"] > 0
    assert "## Multi-view captures" in page and f"**{mv['ratio']:.1f}×**" in page
    assert f"{mv['dropped_ratio']:.1f}× |" in page and "the 9 flash views only" in page
    # the network's own lobes and the true environment, against the same truth and floor
    assert set(mv["others_ratio"]) == set(bench.MULTIVIEW_OTHERS)
    for name, ratio in mv["others_ratio"].items():
        assert ratio > 0 and f"{ratio:.1f}× |" in page, name
    assert mv["others_ratio"]["network lobes"] != mv["ratio"]  # env.json averaged over azimuth
    assert "of its mean direction" not in page  # the lobes' spread needs two captures (quick: one)


def test_lobe_spread_is_the_largest_angle_from_the_mean_axis():
    from ebr_mitsuba.sgenv import SGEnvironment

    def env(*elevations):
        axes = [[np.cos(np.radians(e)), 0.0, np.sin(np.radians(e))] for e in elevations]
        return SGEnvironment(np.array(axes), np.ones(len(axes)), np.ones((len(axes), 3)))

    assert bench.lobe_spread([]) == []
    assert bench.lobe_spread([env(30, 60), env(30, 60)]) == pytest.approx([0, 0], abs=0.05)  # float32 axes
    assert bench.lobe_spread([env(30, 60), env(40, 60)]) == pytest.approx([5, 0], abs=0.05)
