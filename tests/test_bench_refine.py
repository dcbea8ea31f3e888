"""``ebr bench refine``: the summary's counts, and the quick page on the tiny data set (the shipped
model through ``ebr estimate`` with each refinement) with its refusals."""

from __future__ import annotations

import json

import pytest
from bench_checks import assert_needs_data_sets

from ebr_mitsuba.bench import refine as bench


def _row(before: tuple[float, float], after: tuple[float, float], name: str) -> dict:
    def scores(mean, rerender):
        return {
            "normal": mean,
            "diffuse": mean,
            "roughness": mean,
            "specular": mean,
            "mean": mean,
            "rerender": rerender,
        }

    return {name: {"before": scores(*before), "after": scores(*after), "seconds": 1.0}}


def test_summary_counts_lower_maps_renders_and_both():
    name = "v"
    rows = [
        _row((0.05, 0.5), (0.04, 0.4), name),  # both lower
        _row((0.05, 0.5), (0.04, 0.6), name),  # maps only
        _row((0.05, 0.5), (0.06, 0.4), name),  # re-render only
        _row((0.05, 0.5), (0.05, 0.5), name),  # unchanged: not lower
    ]
    s = bench._summary(rows, name)
    assert s["captures"] == 4
    assert s["maps_lower"] == 0.5 and s["rerender_lower"] == 0.5 and s["both_lower"] == 0.25
    assert s["before"]["mean"] == pytest.approx(0.05) and s["after"]["rerender"] == pytest.approx(0.475)
    assert s["map_lower"]["diffuse"] == 0.5 and s["seconds"] == 1.0


def test_quick_page_on_the_tiny_set_and_refusals(tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("EBR_REFINE_DATA", str(tiny))
    monkeypatch.setenv("EBR_SPLIT_DATA", str(tiny))  # named as the test split: its acceptance line
    assert bench.unavailable() is None
    path = bench.run(tmp_path, quick=True)
    page = path.read_text()
    record = json.loads((tmp_path / "refine.json").read_text())
    assert "Quick mode" in page and len(record["rows"]) == bench.QUICK_SAMPLES
    assert record["steps"] == bench.QUICK_STEPS
    for row in record["rows"]:
        assert f"| {row['material']} |" in page
        for name in bench.VARIANTS:
            for when in ("before", "after"):
                assert 0 <= row[name][when]["mean"] < 1 and row[name][when]["rerender"] >= 0
            assert row[name]["seconds"] > 0
    summary = record["summary"][tiny.name]
    assert set(summary) == set(bench.VARIANTS)
    for name in bench.VARIANTS:
        assert (
            0
            <= summary[name]["both_lower"]
            <= min(summary[name]["maps_lower"], summary[name]["rerender_lower"])
        )
        assert f"**{name}** on the test split: both lower in" in page
    assert "(the test split)" in page

    monkeypatch.delenv("EBR_SPLIT_DATA")
    assert_needs_data_sets(bench, "EBR_REFINE_DATA", tmp_path, monkeypatch)
