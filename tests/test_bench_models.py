"""Unit figures of ``ebr bench models`` that need no data set."""

from __future__ import annotations

import pytest

from ebr_mitsuba.bench.models import normal_structure


def test_normal_structure_caps_each_sample_at_the_truth():
    # a flat estimate of a flat truth has all the structure there is; more than the truth counts as 1
    assert normal_structure([0.02, 0.2], [0.1, 0.1]) == pytest.approx((0.2 + 1.0) / 2)
    # one nearly flat truth (a brushed metal) cannot lift nearly flat estimates elsewhere
    flat_elsewhere = normal_structure([0.026, 0.003, 0.003], [0.004, 0.2, 0.15])
    assert flat_elsewhere == pytest.approx((1.0 + 0.015 + 0.02) / 3)
    assert flat_elsewhere < 0.5


def test_baseline_lines_name_each_row_or_why_it_is_missing():
    from ebr_mitsuba.bench.models import NO_EXEMPLARS, PREVIOUS, _baseline_lines

    some = {"shipped model": {}, "oracle constant": {}}
    text = " ".join(_baseline_lines(some))
    assert "(ii) the training-set mean maps, not in this run (set `EBR_TRAIN_DATA`)" in text
    assert f"(iii) the previously shipped model, not in this run (name it `{PREVIOUS}`" in text
    assert f"not in this run (name it `{NO_EXEMPLARS}`" in text
    full = {**some, "training-set mean maps": {}, PREVIOUS: {}, NO_EXEMPLARS: {}}
    text = " ".join(_baseline_lines(full))
    assert "not in this run" not in text
    assert f"row *{PREVIOUS}*" in text and f"row *{NO_EXEMPLARS}*" in text


def test_rerender_shares_sum_to_one_and_name_the_heavy_class():
    from ebr_mitsuba.bench.models import rerender_shares

    rows = [
        {"c": "tiles", "rerender_rmse": 3.0},
        {"c": "wood", "rerender_rmse": 0.5},
        {"c": "wood", "rerender_rmse": 0.5},
    ]
    shares = rerender_shares(rows, lambda r: r["c"])
    assert shares == pytest.approx({"tiles": 0.75, "wood": 0.25})


def test_diagnostic_lines_say_which_missing_structure_fails_the_target():
    from ebr_mitsuba.bench.models import _diagnostic_lines

    def res(rr, tiles):
        return {
            "rerender_rmse": rr,
            "n": 2,
            "per_map_rmse": {"mean": 0.01},
            "classes": {
                "procedural:tiles": {"n": 1, "rerender_rmse": tiles},
                "procedural:wood": {"n": 1, "rerender_rmse": 0.1},
            },
            "per_sample": [
                {"material": "procedural:tiles:1", "rerender_rmse": tiles},
                {"material": "procedural:wood:1", "rerender_rmse": 0.1},
            ],
        }

    results = {"oracle constant": res(1.0, 1.9)}
    diag = {"truth maps, constant roughness": res(0.95, 1.8), "truth maps, flat normals": res(0.3, 0.5)}
    text = "\n".join(_diagnostic_lines(results, diag))
    assert "class *procedural:tiles* (1 case) holds 95 %" in text
    assert "perfect but for constant roughness would not meet" in text
    assert "one perfect but for flat normals would." in text
    assert _diagnostic_lines(results, None) == []
