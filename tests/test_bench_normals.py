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

    assert_needs_data_sets(bench, "EBR_NORMALS_DATA", tmp_path, monkeypatch)
