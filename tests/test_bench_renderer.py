"""``ebr bench renderer`` (ebr_mitsuba.bench.renderer): quick mode end to end, and the computed
"which mode when" logic on fixed numbers. No timing thresholds: times only have to be positive."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ebr_mitsuba.bench import renderer as bench


@pytest.fixture(scope="module")
def quick_page(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    path = bench.run(out, quick=True)
    return out, path


def test_quick_run_writes_only_the_page_and_plot(quick_page):
    out, path = quick_page
    assert path == out / "renderer.md"
    assert sorted(p.name for p in out.iterdir()) == ["renderer.md", "renderer.png"]  # no temp files left
    assert (out / "renderer.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_quick_page_has_every_row_and_finite_errors(quick_page):
    _, path = quick_page
    text = path.read_text()
    s = bench.QUICK
    labels = bench.setting_labels(s)
    for label in labels:
        assert f"| {label} | " in text
    groups = ("| exemplar |", "| plastic |", "| svbrdf |")
    rows = [line for line in text.splitlines() if line.startswith(groups)]
    expected = (len(bench.UNIFORM_MATERIALS) * len(s.roughness) + 1) * len(s.views)
    assert len(rows) == expected
    for line in rows:
        cells = [c.strip() for c in line.strip("|").split("|")][3:]
        assert len(cells) == 1 + len(labels)
        values = [float(c.rstrip(" %")) for c in cells]
        assert all(math.isfinite(v) and v >= 0 for v in values)
    assert "## Which mode when" in text and "Quick mode" in text


def test_measured_rows_cover_the_grid():
    s = bench.QUICK
    rows = bench.measure_errors(s)
    materials = len(bench.UNIFORM_MATERIALS) * len(s.roughness) + len(s.svbrdfs)
    assert len(rows) == materials * len(s.envs) * len(s.views)
    for r in rows:
        assert set(r["errors"]) == set(bench.setting_labels(s))
        assert all(np.isfinite(v) and v >= 0 for v in r["errors"].values())
        assert 0 < r["ref_noise"] < 1


def _rows(errors_by_key):
    return [
        {"group": g, "bucket": b, "view": v, "env": "e", "material": "m", "ref_noise": 0.001, "errors": e}
        for (g, b, v), e in errors_by_key.items()
    ]


def test_cheapest_and_advice_follow_the_numbers():
    times = {"sg": 1.0, "quadrature 64": 3.0, "mitsuba 1024": 50.0}
    labels = list(times)
    assert bench.cheapest({"sg": 0.01, "quadrature 64": 0.005, "mitsuba 1024": 0.001}, times, 0.02) == "sg"
    errs = {"sg": 0.3, "quadrature 64": 0.01, "mitsuba 1024": 0.001}
    assert bench.cheapest(errs, times, 0.02) == "quadrature 64"
    assert bench.cheapest({"sg": 0.3, "quadrature 64": 0.3, "mitsuba 1024": 0.3}, times, 0.02) is None
    rows = _rows(
        {
            ("exemplar", "0.05", 0.0): {"sg": 0.004, "quadrature 64": 0.01, "mitsuba 1024": 0.015},
            ("exemplar", "0.9", 80.0): {"sg": 0.40, "quadrature 64": 0.03, "mitsuba 1024": 0.015},
        }
    )
    text = "\n".join(bench.advice(rows, labels, times, targets=(0.02, 0.05)))
    assert "**sg** (1 s/Mpx) is the cheapest for exemplar r=0.05 (0°)" in text
    assert "**mitsuba 1024** (50 s/Mpx) is the cheapest for exemplar r=0.9 (80°)" in text
    assert "**quadrature 64** (3 s/Mpx) is the cheapest for exemplar r=0.9 (80°)" in text
    assert "worst for exemplar r=0.9 at 80° (40.0 % mean error)" in text
