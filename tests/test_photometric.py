"""The photometric fit of five-light captures (ebr_mitsuba.estimate.photometric).

The photos are rendered by the one BRDF's torch mirror (``render_point_light``) at the five lights
of ``ebr capture --setup five-light``, from maps with a bumped normal field and a two-tone albedo,
so the fit's model is exact up to the flash fit's roughness grid: the recovered normals and albedo
are held to tight tolerances, the failure paths (a photo that is not what the model describes, a
metal, bad input) to what they must return."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ebr_mitsuba.errors import InputError
from ebr_mitsuba.estimate.photometric import PhotometricConfig, fit_photometric
from ebr_mitsuba.geometry import DEFAULT_FLASH_INTENSITY, FIVE_LIGHT_POSITIONS, NEAR_DISTANCE
from ebr_mitsuba.nets import Maps
from ebr_mitsuba.nets import torch_brdf as tb
from ebr_mitsuba.svbrdf import SVBRDF

SIZE = 96
CAMERA = (0.0, 0.0, NEAR_DISTANCE)


def _truth(roughness: float = 0.4, f0: float = 0.04) -> SVBRDF:
    y, x = np.mgrid[0:SIZE, 0:SIZE] / SIZE
    nx = 0.08 * np.sin(2 * math.pi * 3 * x)
    ny = 0.06 * np.cos(2 * math.pi * 2 * y)
    n = np.stack([nx, ny, np.ones_like(nx)], -1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    tone = ((np.floor(x * 6) + np.floor(y * 6)) % 2)[..., None]
    diffuse = np.where(tone > 0, [0.6, 0.45, 0.3], [0.2, 0.25, 0.3])
    return SVBRDF(
        n.astype(np.float32),
        diffuse.astype(np.float32),
        np.full((SIZE, SIZE, 3), f0, np.float32),
        np.full((SIZE, SIZE), roughness, np.float32),
        "test truth",
    )


def _photos(truth: SVBRDF) -> list[np.ndarray]:
    maps = Maps.from_svbrdf([truth])
    out = []
    for light in FIVE_LIGHT_POSITIONS:
        img = tb.render_point_light(
            maps, torch.tensor(light, dtype=torch.float32), DEFAULT_FLASH_INTENSITY, CAMERA
        )
        out.append(img[0].permute(1, 2, 0).numpy().astype(np.float32))
    return out


def _flat_network() -> SVBRDF:
    n = np.zeros((SIZE, SIZE, 3), np.float32)
    n[..., 2] = 1
    return SVBRDF(
        n,
        np.full((SIZE, SIZE, 3), 0.3, np.float32),
        np.full((SIZE, SIZE, 3), 0.1, np.float32),
        np.full((SIZE, SIZE), 0.7, np.float32),
        "placeholder network",
    )


def _fit(photos, **kw):
    return fit_photometric(
        photos, FIVE_LIGHT_POSITIONS, [DEFAULT_FLASH_INTENSITY] * 5, _flat_network(), camera=CAMERA, **kw
    )


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1, 1)))


def test_recovers_normals_albedo_and_roughness_of_exact_photos():
    truth = _truth()
    fit = _fit(_photos(truth))
    assert not fit.fallback and fit.flash is not None and not fit.flash.metal
    assert fit.usable.mean() > 0.99
    assert abs(fit.maps.roughness.mean() - 0.4) <= 0.03  # the flash fit's grid step is ~0.01
    # two passes from flat normals leave a fraction of a degree (the lobe is evaluated at the
    # previous pass's normals); the flat normals are several times further off
    err = _angle_deg(fit.maps.normal, truth.normal)
    flat = np.median(_angle_deg(_flat_network().normal, truth.normal))
    assert np.median(err) < 1.0 and np.median(err) < 0.25 * flat
    assert np.percentile(err, 90) < 3.0  # the worst are the highlights' cores, weighted down
    assert np.abs(fit.maps.diffuse - truth.diffuse).mean() < 0.01
    assert fit.residual < 0.01


def test_a_saturated_photo_is_left_out_where_it_clips():
    truth = _truth()
    photos = _photos(truth)
    masks = [np.zeros((SIZE, SIZE), bool) for _ in photos]
    clipped = photos[1].copy()
    clipped[: SIZE // 2] = 0.05  # garbage where the mask says "saturated"
    masks[1][: SIZE // 2] = True
    photos[1] = clipped
    fit = _fit(photos, saturated=masks)
    err = _angle_deg(fit.maps.normal, truth.normal)
    assert np.median(err) < 1.5
    unmasked = _fit(photos)  # the same garbage taken at face value bends the normals
    assert np.median(_angle_deg(unmasked.maps.normal, truth.normal)) > 2 * np.median(err)


def test_photos_the_model_does_not_explain_keep_the_network_normals():
    truth = _truth()
    photos = [p + 0.3 * float(p.mean()) * (k + 1) for k, p in enumerate(_photos(truth))]  # other light
    fit = _fit(photos)
    assert fit.residual > PhotometricConfig().residual_max
    assert fit.fallback and not fit.usable.any()
    np.testing.assert_array_equal(fit.maps.normal, _flat_network().normal)
    strict = _fit(photos, options=PhotometricConfig(residual_max=1e3))
    assert not strict.fallback and strict.usable.any()


def test_a_metal_keeps_the_network_normals_and_has_no_diffuse():
    truth = _truth(roughness=0.35, f0=0.9)
    truth = SVBRDF(truth.normal, np.zeros_like(truth.diffuse), truth.specular, truth.roughness, "metal")
    fit = _fit(_photos(truth))
    assert fit.flash.metal
    assert float(fit.maps.diffuse.max()) == 0.0
    np.testing.assert_array_equal(fit.maps.normal, _flat_network().normal)
    assert fit.maps.specular.mean() > 0.5


def test_bad_input_is_refused():
    photos = _photos(_truth())
    with pytest.raises(InputError, match="at least three photos"):
        fit_photometric(photos[:2], FIVE_LIGHT_POSITIONS[:2], [10.0] * 2, _flat_network(), camera=CAMERA)
    with pytest.raises(InputError, match="must all be"):
        fit_photometric(
            [photos[0][:-1], *photos[1:]], FIVE_LIGHT_POSITIONS, [10.0] * 5, _flat_network(), camera=CAMERA
        )
