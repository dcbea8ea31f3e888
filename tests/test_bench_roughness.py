"""``ebr bench roughness``: the roughness maps it scores, and the quick page on the tiny data set
(the shipped model through ``ebr estimate``) with its refusals."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from bench_checks import assert_needs_data_sets

from ebr_mitsuba.bench import roughness as bench
from ebr_mitsuba.estimate.roughness_pattern import GAIN, RoughnessPattern
from ebr_mitsuba.svbrdf import SVBRDF


def _result(pattern: RoughnessPattern | None, source: str = "fit", fitted: float = 0.4):
    rng = np.random.default_rng(0)
    diffuse = np.exp(rng.normal(np.log(0.3), 0.3, (8, 8, 3))).astype(np.float32)
    if pattern is not None and pattern.applied and source == "fit":
        rough = pattern.roughness_map(fitted, diffuse)
    else:
        rough = np.full((8, 8), fitted, np.float32)
    normal = np.zeros((8, 8, 3), np.float32)
    normal[..., 2] = 1
    maps = SVBRDF(normal, diffuse, np.full((8, 8, 3), 0.04, np.float32), rough, source="test")
    fit = {
        "roughness": fitted,
        "roughness_from": source,
        "roughness_pattern": None if pattern is None else pattern.to_json(),
    }
    return SimpleNamespace(maps=maps, get={"flash_fit": fit}.get)


def test_variants_are_the_constant_the_written_map_and_the_gains():
    pattern = RoughnessPattern(0.0, -0.06, 0.01, 0.0, applied=True).at_gain(GAIN)
    result = _result(pattern)
    written = bench.variant_roughness(result)
    np.testing.assert_array_equal(written, result.maps.roughness)
    assert float(np.ptp(written)) > 0
    np.testing.assert_allclose(bench.variant_roughness(result, 0.0), 0.4)
    np.testing.assert_allclose(bench.variant_roughness(result, GAIN), written, atol=1e-6)
    steeper = bench.variant_roughness(result, 2 * GAIN)
    assert float(np.std(steeper)) == pytest.approx(2 * float(np.std(written)), rel=1e-3)
    # not read, or the network's map: the map as written at every gain
    for other in (
        _result(RoughnessPattern(0.0, applied=False, reason="metal")),
        _result(pattern, source="network"),
        _result(None),
    ):
        for gain in bench.GAINS:
            np.testing.assert_array_equal(bench.variant_roughness(other, gain), other.maps.roughness)


def test_quick_page_on_the_tiny_set_and_refusals(tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("EBR_ROUGHNESS_DATA", str(tiny))
    assert bench.unavailable() is None
    path = bench.run(tmp_path, quick=True)
    page = path.read_text()
    record = json.loads((tmp_path / "roughness.json").read_text())
    assert "Quick mode" in page and len(record["rows"]) == bench.QUICK_SAMPLES
    for row in record["rows"]:
        assert f"| {row['material']}" in page
        for v in bench.VARIANTS:
            assert 0 <= row[v]["roughness"] < 1 and row[v]["rerender"] >= 0
        if not row["read"]:
            assert row["pattern"]["roughness"] == row["constant"]["roughness"]
        assert row["record"] is None or "applied" in row["record"]  # estimate.json's record
    summary = record["summary"]["all"]
    assert set(record["summary"]) == {tiny.name, "all"} and summary["captures"] == bench.QUICK_SAMPLES
    assert [p["gain"] for p in summary["gains"]] == list(bench.GAINS)
    assert summary["gains"][0]["roughness"] == pytest.approx(summary["constant"]["roughness"], abs=1e-9)
    assert "## The gain" in page and (tmp_path / "roughness_gains.png").is_file()

    # a capture whose pattern was read gets its reading in the per-capture table
    row = dict(
        record["rows"][0], read=True, record={"applied": True, "slope": 0.1, "read": 0.05, "stderr": 0.01}
    )
    result = {"rows": [row], "summary": record["summary"], "pool": record["pool"]}
    assert "+0.050 ± 0.010 | +0.100" in bench._page(result, [tiny], 1.0, True, [])

    assert_needs_data_sets(bench, "EBR_ROUGHNESS_DATA", tmp_path, monkeypatch)
