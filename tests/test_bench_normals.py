"""``ebr bench normals``: the three normal maps it scores, and the quick page on the tiny data set
(the shipped model through ``ebr estimate``) with its refusals."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
from bench_checks import assert_needs_data_sets

from ebr_mitsuba.bench import normals as bench
from ebr_mitsuba.estimate.relief import Relief
from ebr_mitsuba.estimate.shading_normals import ShadingNormals
from ebr_mitsuba.svbrdf import SVBRDF


def _maps(normal):
    size = normal.shape[:2]
    return SVBRDF(
        normal,
        np.full((*size, 3), 0.5, np.float32),
        np.full((*size, 3), 0.04, np.float32),
        np.full(size, 0.5, np.float32),
        source="test",
    )


def test_variants_are_flat_albedo_following_and_the_written_map():
    rng = np.random.default_rng(0)
    fitted = np.concatenate([0.1 * rng.standard_normal((8, 8, 2)), np.ones((8, 8, 1))], -1)
    fitted = (fitted / np.linalg.norm(fitted, axis=-1, keepdims=True)).astype(np.float32)
    relief = Relief(0.05 * rng.standard_normal((8, 8, 2)).astype(np.float32), np.zeros(2), 0.01, 1e-4)
    shading = ShadingNormals(fitted, 0.01, np.zeros(2), 64, 0.5, relief)
    written = shading.map_normal()
    v = bench.variant_normals(SimpleNamespace(maps=_maps(written), shading=shading))
    assert set(v) == set(bench.VARIANTS)
    assert np.all(v["flat"][..., 2] == 1) and np.all(v["flat"][..., :2] == 0)
    np.testing.assert_array_equal(v["with relief"], written)
    np.testing.assert_allclose(v["albedo-following"], shading.shrunk(0.6), atol=1e-6)
    assert not np.allclose(v["albedo-following"], written, atol=1e-4)
    # no shading normals (a metal, a glossy sample): the estimate's own normals in all three
    none = bench.variant_normals(SimpleNamespace(maps=_maps(fitted), shading=None))
    for k in bench.VARIANTS:
        np.testing.assert_array_equal(none[k], fitted)


def test_gain_grid_matches_the_written_map_at_the_default_gains():
    rng = np.random.default_rng(1)
    slopes = 0.2 * rng.standard_normal((16, 16, 2))
    truth_n = np.concatenate([slopes, np.ones((16, 16, 1))], -1)
    truth = _maps((truth_n / np.linalg.norm(truth_n, axis=-1, keepdims=True)).astype(np.float32))
    fitted = np.concatenate([0.5 * slopes, np.ones((16, 16, 1))], -1)
    fitted = (fitted / np.linalg.norm(fitted, axis=-1, keepdims=True)).astype(np.float32)
    relief = Relief(0.05 * rng.standard_normal((16, 16, 2)).astype(np.float32), np.zeros(2), 0.01, 1e-4)
    shading = ShadingNormals(fitted, 0.01, np.zeros(2), 64, 0.5, relief)
    result = SimpleNamespace(maps=_maps(shading.map_normal()), shading=shading)
    grid = bench._gain_grid(result, truth)
    assert len(grid) == len(bench.MAP_GAINS) * len(bench.RELIEF_GAINS)
    default = bench._default_gains()
    at_default = [p for p in grid if (p[0], p[1]) == default]
    assert len(at_default) == 1  # the default gains are a grid point
    expected = np.sqrt(np.mean((truth.encoded_normal() - (shading.map_normal() + 1) / 2) ** 2))
    assert abs(at_default[0][2] - expected) < 1e-6
    # structure grows with either gain and is capped at 1
    by = {(p[0], p[1]): p[3] for p in grid}
    assert by[(1.0, 1.5)] > by[(0.4, 0.25)] and all(0 <= v <= 1 for v in by.values())
    # without shading normals every grid point is the estimate's own normal map
    flat_result = SimpleNamespace(maps=_maps(fitted), shading=None)
    assert len({round(p[2], 9) for p in bench._gain_grid(flat_result, truth)}) == 1
    # the oracle constant normal: the truth's mean normal, not better than any slope-free guess
    assert (
        bench._oracle_normal_rmse(truth)
        <= bench._normal_rmse(np.broadcast_to([0, 0, 1.0], (16, 16, 3)), truth) + 1e-9
    )
    table = bench.gain_table([{"gains": grid}] * 96)  # 96 times 0.6, averaged, is not 0.6
    assert abs(table[0]["normal"] - grid[0][2]) < 1e-12 and table[0]["map_gain"] == bench.MAP_GAINS[0]
    assert [(p["map_gain"], p["relief_gain"]) for p in table].count(default) == 1


def test_spread_of_flat_normals_is_zero():
    flat = np.zeros((4, 4, 3), np.float32)
    flat[..., 2] = 1
    assert bench.spread(flat) == 0.0


def test_quick_page_on_the_tiny_set_and_refusals(tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("EBR_NORMALS_DATA", str(tiny))
    assert bench.unavailable() is None
    path = bench.run(tmp_path, quick=True)
    page = path.read_text()
    record = json.loads((tmp_path / "normals.json").read_text())
    assert "Quick mode" in page and len(record["rows"]) == bench.QUICK_SAMPLES
    for row in record["rows"]:
        assert f"| {row['material']}" in page
        for v in bench.VARIANTS:
            assert 0 <= row[v]["normal"] < 1 and 0 <= row[v]["spread"] <= 1
        assert row["flat"]["spread"] == 0 or not row["read"]
    assert set(record["summary"]) == {tiny.name, "all"}
    assert record["summary"]["all"]["captures"] == bench.QUICK_SAMPLES
    assert len(record["summary"]["all"]["gains"]) == len(bench.MAP_GAINS) * len(bench.RELIEF_GAINS)
    assert "## The gains: error against structure" in page and (tmp_path / "normals_gains.png").is_file()

    assert_needs_data_sets(bench, "EBR_NORMALS_DATA", tmp_path, monkeypatch)
