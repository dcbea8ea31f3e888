"""``ebr bench flash-fit``: the variants of the true maps, the fit's floor on a noise-free render of
a flat, constant-roughness material, the quick page on the tiny data set and its refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
from bench_checks import assert_needs_data_sets

from ebr_mitsuba.bench import flash_fit as bench
from ebr_mitsuba.errors import InputError
from ebr_mitsuba.svbrdf import SVBRDF


def _maps(size=64, roughness=0.4, seed=0):
    rng = np.random.default_rng(seed)
    slopes = 0.15 * rng.standard_normal((size, size, 2)).astype(np.float32)
    normal = np.concatenate([-slopes, np.ones((size, size, 1), np.float32)], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    diffuse = np.clip(0.4 + 0.1 * rng.standard_normal((size, size, 3)), 0.05, 0.9).astype(np.float32)
    specular = np.full((size, size, 3), 0.04, np.float32)
    rough = np.clip(roughness + 0.1 * rng.standard_normal((size, size)), 0.05, 1.0).astype(np.float32)
    return SVBRDF(normal, diffuse, specular, rough, source="test")


def test_variants_flatten_the_normals_and_flatten_the_roughness_alone():
    maps = _maps()
    same = bench.variant_maps(maps, "maps")
    np.testing.assert_array_equal(same.normal, maps.normal)
    np.testing.assert_array_equal(same.roughness, maps.roughness)
    flat = bench.variant_maps(maps, "flat normals")
    assert np.all(flat.normal == np.array([0, 0, 1], np.float32))
    np.testing.assert_array_equal(flat.roughness, maps.roughness)
    const = bench.variant_maps(maps, "constant roughness")
    np.testing.assert_array_equal(const.normal, maps.normal)
    assert np.ptp(const.roughness) == 0 and const.roughness[0, 0] == pytest.approx(maps.roughness.mean())
    both = bench.variant_maps(maps, "flat, constant")
    assert np.all(both.normal[..., 2] == 1) and np.ptp(both.roughness) == 0
    for v in (same, flat, const, both):  # albedo and F0 untouched
        np.testing.assert_array_equal(v.diffuse, maps.diffuse)
        np.testing.assert_array_equal(v.specular, maps.specular)
    with pytest.raises(ValueError):
        bench.variant_maps(maps, "rough normals")


@pytest.mark.parametrize("roughness", [0.3, 0.6])
def test_noise_free_flat_constant_render_reads_its_roughness(roughness):
    """The fit's floor: a flat sample of one roughness (albedo texture only), rendered without
    noise, reads within two grid steps (0.02) of the truth."""
    maps = bench.variant_maps(_maps(roughness=roughness), "flat, constant")
    fit = bench.noise_free_fit(maps)
    assert not fit.metal
    assert fit.roughness == pytest.approx(float(maps.roughness.mean()), abs=0.02)


def test_relief_reads_rougher_than_the_flat_sample():
    """The broadening the page measures: the same material with its relief reads rougher."""
    maps = _maps(roughness=0.3)
    relief = bench.noise_free_fit(bench.variant_maps(maps, "constant roughness")).roughness
    flat = bench.noise_free_fit(bench.variant_maps(maps, "flat, constant")).roughness
    assert relief > flat + 0.02


def test_quick_page_on_the_tiny_set_and_refusals(tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("EBR_FLASHFIT_DATA", str(tiny))
    assert bench.unavailable() is None
    path = bench.run(tmp_path, quick=True)
    page = path.read_text()
    record = json.loads((tmp_path / "flash_fit.json").read_text())
    assert "Quick mode" in page and (tmp_path / "flash_fit.png").is_file()
    assert len(record["rows"]) + record["metals_left_out"] == bench.QUICK_SAMPLES
    for row in record["rows"]:
        assert set(bench.COLUMNS) <= set(row) and 0 < row["truth"] <= 1
        assert f"| {row['material']} |" in page
    for col in bench.COLUMNS:
        assert f"| {col} |" in page
    assert not any(col.endswith(bench.FAR) for col in record["summary"])  # a near set: no far pair

    assert_needs_data_sets(bench, "EBR_FLASHFIT_DATA", tmp_path, monkeypatch)
    assert not (tmp_path / "out").exists()


def test_far_pair_noise_free_reads_its_roughness_and_marks_the_fit():
    maps = bench.variant_maps(_maps(roughness=0.4), "flat, constant")
    fit = bench.noise_free_fit(maps, far=True)
    assert fit.far_pair and not fit.metal
    assert fit.roughness == pytest.approx(float(maps.roughness.mean()), abs=0.02)


def test_quick_page_of_a_near_far_set_adds_the_far_columns(tiny_nf, tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("EBR_FLASHFIT_DATA", str(tiny_nf))
    page = bench.run(tmp_path, quick=True).read_text()
    record = json.loads((tmp_path / "flash_fit.json").read_text())
    rows = record["rows"]
    assert len(rows) + record["metals_left_out"] + len(record["refused"]) == bench.QUICK_SAMPLES
    for refused in record["refused"]:  # one line naming the sample and why (a saturated tiny capture)
        assert "\n" not in refused and "saturated" in refused and f"{len(record['refused'])} refused" in page
    assert rows and all("capture" + bench.FAR in r for r in rows)
    assert record["summary"]["capture" + bench.FAR]["n"] == len(rows)
    assert "## Per capture, with the far pair" in page and "| flat, constant + far |" in page
    paired = record["paired"]
    assert set(paired) == set(bench.COLUMNS) and all(p["n"] == len(rows) for p in paired.values())
    err = [r["capture" + bench.FAR]["roughness"] - r["truth"] for r in rows]
    assert paired["capture"]["far"] == pytest.approx(float(np.sqrt(np.mean(np.square(err)))))
    assert "| near pair | near + far pair |" in page
    with pytest.raises(InputError, match="no far pair"):
        bench.capture_fit(tiny, 0, 10.0, far=True)
