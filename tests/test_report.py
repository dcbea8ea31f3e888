"""report.html of `ebr estimate` (issue 16, item 12): its title names the output directory (not the
temporary ``.partial`` one), the loss-curve labels sit beside the points they describe, and the
exemplar thumbnails are neither washed out nor fringed."""

from __future__ import annotations

import json
import re
import types

import numpy as np
import pytest

from ebr_mitsuba.cli import main
from ebr_mitsuba.colour import LUMINANCE
from ebr_mitsuba.estimate.outputs import write_exemplars
from ebr_mitsuba.estimate.report import EXEMPLAR_KEY, _loss_svg, exemplar_exposure
from ebr_mitsuba.imageio import clip_hue, read_ldr, write_png


@pytest.fixture(scope="module")
def estimate_dir(tmp_path_factory):
    """One estimate (fake network, 20 refinement steps: two loss points) into ``.../my_estimate``."""
    from fakes import use_fake_model, write_pair

    tmp = write_pair(tmp_path_factory.mktemp("report"), seed=2)
    with pytest.MonkeyPatch.context() as monkeypatch:
        use_fake_model(monkeypatch)
        out = tmp / "my_estimate"
        assert (
            main(
                [
                    "estimate",
                    "--flash",
                    str(tmp / "flash.exr"),
                    "--noflash",
                    str(tmp / "noflash.exr"),
                    "--out",
                    str(out),
                    "--checkpoint",
                    str(tmp / "flash.exr"),
                    "--refine-steps",
                    "20",
                ]
            )
            == 0
        )
    return out


def test_title_names_the_output_directory(estimate_dir):
    text = (estimate_dir / "report.html").read_text()
    title = re.search(r"<title>(.*?)</title>", text).group(1)
    assert title == "ebr estimate: my_estimate", title
    assert ".partial" not in text


def _labels(svg: str) -> list[tuple[float, float, str]]:
    return [
        (float(x), float(y), t)
        for x, y, t in re.findall(r'<text x="([-\d.]+)" y="([-\d.]+)"[^>]*>([^<]*)</text>', svg)
    ]


def _points(svg: str) -> list[tuple[float, float]]:
    pts = re.search(r'points="([^"]+)"', svg).group(1).split()
    return [tuple(map(float, p.split(","))) for p in pts]


@pytest.mark.parametrize(
    "history",
    [
        [[0, 0.05], [2, 0.4], [4, 0.02], [6, 0.01]],  # a peak after the first step
        [[0, 1.0], [5, 0.5], [10, 0.2], [15, 0.1]],  # monotone decrease
        [[0, 0.01], [3, 0.02], [6, 0.5]],  # increase: the last value is the peak
    ],
)
def test_loss_labels_sit_beside_their_points(history):
    svg = _loss_svg(history)
    pts = _points(svg)
    labels = _labels(svg)
    first = next(lb for lb in labels if lb[2].startswith("loss "))
    last = next(lb for lb in labels if lb[2].endswith(f"(step {history[-1][0]})") and lb is not first)
    assert f"{history[0][1]:.3g}" in first[2] and "(step 0)" in first[2]
    assert abs(first[1] - pts[0][1]) <= 16 and abs(first[0] - pts[0][0]) <= 4, (first, pts[0])
    assert abs(last[1] - pts[-1][1]) <= 16 and abs(last[0] - pts[-1][0]) <= 4, (last, pts[-1])
    # the extremes are on the axis, at the height of the highest and lowest points
    ticks = {t: y for _, y, t in labels if not t.startswith("loss ") and "(step" not in t}
    top = min(p[1] for p in pts)
    bottom = max(p[1] for p in pts)
    assert abs(ticks[f"{max(v for _, v in history):.3g}"] - top) <= 5
    assert abs(ticks[f"{min(v for _, v in history):.3g}"] - bottom) <= 5


def test_report_loss_curve_present(estimate_dir):
    text = (estimate_dir / "report.html").read_text()
    svg = re.search(r"<svg.*?</svg>", text, re.S).group(0)
    history = json.loads((estimate_dir / "estimate.json").read_text())["refine"]["history"]
    assert len(history) >= 2 and history[-1][0] == 20
    assert f"loss {history[0][1]:.3g} (step {history[0][0]})" in svg and "(step 20)</text>" in svg


def test_clip_hue_keeps_the_colour_of_bright_pixels():
    px = np.array([[[2.0, 1.0, 0.5], [0.5, 0.25, -0.1], [0.3, 0.3, 0.3]]])
    out = clip_hue(px)
    np.testing.assert_allclose(out[0, 0], [1.0, 0.5, 0.25])
    np.testing.assert_allclose(out[0, 1], [0.5, 0.25, 0.0])
    np.testing.assert_allclose(out[0, 2], [0.3, 0.3, 0.3])
    with pytest.raises(ValueError):
        write_png("/nonexistent/x.png", px, clip="nope")


def _stack(rng) -> list[np.ndarray]:
    """Four dim, low-contrast exemplars (as the lighting network makes them) with a brighter,
    reddish one-pixel border (its edge artefact), the second twice as bright as the others."""
    out = []
    for k in range(4):
        a = (0.025 + 0.004 * rng.standard_normal((32, 32, 3))).astype(np.float32)
        a[0, :] = a[:, 0] = np.float32([0.09, 0.05, 0.04])
        out.append(a * (2.0 if k == 1 else 1.0))
    return out


def test_exemplar_thumbnails_not_washed_out_nor_fringed(tmp_path, rng):
    stack = _stack(rng)
    pred = types.SimpleNamespace(env_exemplars=stack, flash_only=None)
    files = write_exemplars(tmp_path, pred)
    assert files == [f"exemplars/exemplar_{k}.png" for k in range(4)]
    shown = [read_ldr(tmp_path / f, colorspace="linear") for f in files]  # sRGB codes in [0, 1]
    interior = [s[4:-4, 4:-4].mean() for s in shown]
    # middle grey (0.18 linear ≈ 0.46 sRGB) for the stack's mean, not near white
    assert all(0.25 < v < 0.7 for v in interior), interior
    assert interior[1] > interior[0] + 0.1, "one shared exposure: the brighter exemplar looks brighter"
    # the bright reddish border keeps its hue (red > green > blue), not clipped to white
    border = shown[1][0, 5:-5].mean(axis=0)
    assert border[0] > border[1] > border[2] and border[2] < 0.95, border
    assert exemplar_exposure(stack) == pytest.approx(
        EXEMPLAR_KEY / np.mean([(a @ LUMINANCE.astype(np.float32)).mean() for a in stack]), rel=1e-5
    )
    assert exemplar_exposure([np.zeros((4, 4, 3), np.float32)]) == 1.0


def test_report_exemplar_thumbnails(estimate_dir):
    files = sorted(p.name for p in (estimate_dir / "exemplars").glob("*.png"))
    assert files == ["exemplar_0.png", "flash_only.png"]
    img = read_ldr(estimate_dir / "exemplars" / "exemplar_0.png", colorspace="linear")
    assert 0.2 < float(img.mean()) < 0.75, float(img.mean())
    assert "exemplar_0" in (estimate_dir / "report.html").read_text()


def test_report_loss_svg_needs_two_points():
    assert _loss_svg([[0, 1.0]]) == ""
    assert _loss_svg([[0, 0.0], [1, float("nan")]]) == ""
