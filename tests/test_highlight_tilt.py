"""The highlight tilt (ebr_mitsuba/estimate/highlight_tilt.py): a glossy sample's mean tilt read off
the flash shot's clipped highlight, on fast-renderer captures of known tilt (fixed maps, no noise)."""

from __future__ import annotations

import numpy as np
import pytest

from ebr_mitsuba.errors import InputError
from ebr_mitsuba.estimate.highlight_tilt import (
    MAX_ROUGHNESS,
    MAX_TILT,
    central_component,
    read_highlight_tilt,
    tilted_normals,
)
from ebr_mitsuba.geometry import NEAR_DISTANCE, near_shot
from ebr_mitsuba.render.fast import render_numpy
from ebr_mitsuba.svbrdf import SVBRDF

PIXEL_SLOPE = 2.0 / 256 / NEAR_DISTANCE  # one pixel of the 256² near frame, as a slope


def _glossy(slope, n: int = 256, roughness: float = 0.1) -> SVBRDF:
    return SVBRDF(
        normal=tilted_normals((n, n), slope),
        diffuse=np.full((n, n, 3), 0.3, np.float32),
        specular=np.full((n, n, 3), 0.04, np.float32),
        roughness=np.full((n, n), roughness, np.float32),
    )


def _clipped(maps: SVBRDF, pixels: int = 400) -> np.ndarray:
    """The flash-only shot's saturation mask with the exposure clipping its ``pixels`` brightest."""
    grey = render_numpy(maps, None, near_shot(flash=True, env=False)).max(axis=-1)
    return grey >= np.sort(grey.ravel())[-pixels]


@pytest.mark.parametrize("slope", [(0.0, 0.0), (0.004, -0.003), (-0.006, 0.005)])
def test_reads_the_tilt_of_a_glossy_sample(slope):
    """Within a third of a pixel (0.001 in slope) of the true tilt, on a flat sample and on two
    tilted by 0.3–0.45° (a normal map's 8-bit bias is 0.0039 per axis)."""
    tilt = read_highlight_tilt(_clipped(_glossy(slope)), NEAR_DISTANCE, 0.1)
    assert tilt.applied, tilt
    assert np.abs(tilt.slope - np.asarray(slope)).max() < PIXEL_SLOPE / 3, (tilt.slope, slope)
    assert tilt.pixels >= 300 and tilt.size == (256, 256)
    record = tilt.to_json()
    assert record["applied"] and record["grid"] == [256, 256] and "reason" not in record
    assert record["degrees"] == pytest.approx(np.degrees(np.arctan(np.hypot(*slope))), abs=0.02)


def test_larger_photos_are_read_at_the_fit_size():
    """A 512² capture of the same sample reads the same tilt (its mask area-reduced to 256²)."""
    slope = (0.004, -0.003)
    tilt = read_highlight_tilt(_clipped(_glossy(slope, n=512), pixels=1600), NEAR_DISTANCE, 0.1)
    assert tilt.applied and tilt.size == (256, 256)
    assert np.abs(tilt.slope - np.asarray(slope)).max() < PIXEL_SLOPE / 2


def test_untrusted_readings_are_recorded_not_applied():
    """A rough fit, a highlight off the centre (a tilt beyond MAX_TILT), a tiny clipped spot and no
    clipping at all: each gives a reason and no tilt to apply."""
    mask = _clipped(_glossy((0.0, 0.0)))
    rough = read_highlight_tilt(mask, NEAR_DISTANCE, MAX_ROUGHNESS + 0.05)
    assert not rough.applied and "roughness" in rough.reason
    far = read_highlight_tilt(_clipped(_glossy((5 * MAX_TILT, 0.0)), pixels=100), NEAR_DISTANCE, 0.1)
    assert not far.applied and "no clipped highlight" in far.reason  # nothing saturated near the centre
    near_edge = read_highlight_tilt(_clipped(_glossy((1.6 * MAX_TILT, 0.0)), pixels=2500), NEAR_DISTANCE, 0.1)
    assert not near_edge.applied and "not the lobe's tip" in near_edge.reason
    assert near_edge.slope[0] == pytest.approx(1.6 * MAX_TILT, abs=PIXEL_SLOPE)
    tiny = np.zeros((256, 256), bool)
    tiny[127:129, 127:129] = True
    small = read_highlight_tilt(tiny, NEAR_DISTANCE, 0.1)
    assert not small.applied and "too small" in small.reason
    none = read_highlight_tilt(np.zeros((256, 256), bool), NEAR_DISTANCE, 0.1)
    assert not none.applied and none.pixels == 0 and none.to_json()["reason"]


def test_central_component_keeps_the_blob_at_the_centre():
    mask = np.zeros((64, 64), bool)
    mask[28:36, 30:38] = True  # the highlight
    mask[2:10, 2:10] = True  # a reflection elsewhere
    mask[36, 34] = True  # touching the highlight (4-connected)
    comp = central_component(mask, radius=4.0)
    assert comp.sum() == 65 and not comp[:20, :20].any()
    assert central_component(mask, radius=0.5) is None  # no saturated pixel that close
    with pytest.raises(InputError, match="expected \\(H, W\\)"):
        central_component(np.zeros((4, 4, 3), bool), 1.0)


def test_tilted_normals_are_unit_and_hold_the_slope():
    n = tilted_normals((3, 5), (0.01, -0.02))
    assert n.shape == (3, 5, 3) and n.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(n[..., :2] / n[..., 2:], np.broadcast_to([0.01, -0.02], (3, 5, 2)), atol=1e-6)


def test_bad_inputs_are_one_line_errors():
    with pytest.raises(InputError, match="camera height"):
        read_highlight_tilt(np.zeros((8, 8), bool), 0.0, 0.1)
    with pytest.raises(InputError, match="saturation mask"):
        read_highlight_tilt(np.zeros((8, 8, 3), bool), NEAR_DISTANCE, 0.1)
