"""``ebr bench tilt``: the quick page on the tiny data set (the shipped model through ``ebr
estimate``), the page and picture of a capture the tilt was applied to, and the refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest
from bench_checks import assert_needs_data_sets

from ebr_mitsuba.bench import tilt as bench
from ebr_mitsuba.estimate.highlight_tilt import tilted_normals


def test_true_slope_is_the_mean_normals():
    np.testing.assert_allclose(
        bench.true_slope(tilted_normals((4, 4), (0.004, -0.003))), [0.004, -0.003], atol=1e-7
    )


def _applied_row(data: str) -> dict:
    def scores(normal, rerender):
        return {"normal": normal, "mean": 0.03, "rerender": rerender}

    return {
        "data": data,
        "index": 3,
        "material": "acg_Metal034",
        "record": {
            "applied": True,
            "slope": [0.004, -0.002],
            "degrees": 0.26,
            "pixels": 633,
            "grid": [256, 256],
        },
        "true_slope": [0.0039, -0.0039],
        "network": scores(0.0017, 15.1),
        "flat": scores(0.0017, 12.0),
        "tilted": scores(0.0008, 10.4),
    }


def test_quick_page_on_the_tiny_set_and_refusals(tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("EBR_TILT_DATA", str(tiny))
    assert bench.unavailable() is None
    path = bench.run(tmp_path, quick=True)
    page = path.read_text()
    record = json.loads((tmp_path / "tilt.json").read_text())
    assert "Quick mode" in page and "## Per capture" in page
    for row in record["rows"]:  # only captures that keep the network's normals are listed
        assert f"| {row['material']}" in page and "applied" in row["record"]
        if row["record"]["applied"]:
            assert all(row[v]["rerender"] >= 0 for v in bench.VARIANTS)
        else:
            assert row["record"]["reason"]

    # a capture the tilt was applied to: its summary, page row and picture
    rows = [_applied_row(tiny.name)]
    summary = {tiny.name: bench._summary(rows), "all": bench._summary(rows)}
    assert summary["all"]["applied"] == 1 and summary["all"]["rerender_better"] == 1
    assert summary["all"]["tilted"]["normal"] == pytest.approx(0.0008)
    crops = {(tiny.name, 3): np.linspace(0, 1, bench.CROP**2).reshape(bench.CROP, bench.CROP)}
    result = {"rows": rows, "summary": summary, "crops": crops}
    shown = bench._picture(result, tmp_path / "tilt.png")
    assert shown == rows and (tmp_path / "tilt.png").is_file()
    text = bench._page(result, [tiny], 1.0, False, shown)
    assert "+0.0040, -0.0020 | +0.0039, -0.0039 | 633 | yes | 15.1000 | 12.0000 | 10.4000 |" in text
    assert (
        "lower in 1 and higher in 0 of the 1 captures" in text and "![the highlight read](tilt.png)" in text
    )

    assert_needs_data_sets(bench, "EBR_TILT_DATA", tmp_path, monkeypatch)
