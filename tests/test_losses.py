"""Losses and transforms of ebr_mitsuba.nets against hand-computed values."""

from __future__ import annotations

import math

import pytest
import torch

from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.nets import Maps
from ebr_mitsuba.nets import torch_brdf as tb
from ebr_mitsuba.nets.losses import (
    RENDER_DISTANCE,
    MapWeights,
    entropy_regulariser,
    least_squares_scale,
    masked_angular_l1,
    masked_mse,
    parameter_l1,
    rendering_loss,
    sample_view_light_pairs,
    scale_invariant_log_mse,
    scale_invariant_mse,
)
from ebr_mitsuba.nets.transforms import (
    LOG_EPS,
    log_input,
    log_radiance_to_image,
    log_ratio,
    signed_log,
    unit_normal,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread


def _const_maps(b=1, h=2, w=3, normal=(0.0, 0.0, 1.0), diffuse=0.5, specular=0.04, roughness=0.5):
    n = torch.tensor(normal, dtype=torch.float32).view(1, 3, 1, 1).expand(b, 3, h, w).clone()
    return Maps(
        n,
        torch.full((b, 3, h, w), diffuse),
        torch.full((b, 3, h, w), specular),
        torch.full((b, 1, h, w), roughness),
    )


# ------------------------------------------------------------------------------------- transforms


def test_log_transforms():
    x = torch.tensor([0.0, 0.5, 3.0, -1.0])
    assert torch.allclose(log_input(x), torch.log(torch.tensor([0.0, 0.5, 3.0, 0.0]) + LOG_EPS))
    pos = x[:3]
    assert torch.allclose(signed_log(pos), log_input(pos) - math.log(LOG_EPS), atol=1e-5)
    assert torch.allclose(signed_log(-pos), -signed_log(pos))
    assert torch.allclose(
        log_ratio(torch.tensor([1.0]), torch.tensor([0.0])), torch.tensor([math.log(1.01 / 0.01)])
    )
    raw = torch.tensor([-1000.0, -1.0, 0.0, 1.0, 1000.0])
    img = log_radiance_to_image(raw)
    assert (img > 0).all() and torch.isfinite(img).all() and img[-1] <= math.exp(15.0) * 1.0001
    assert torch.allclose(img[1:4], torch.exp(raw[1:4]), rtol=2e-3)


def test_unit_normal_constraint():
    raw = torch.tensor([[3.0, -2.0, -50.0], [0.0, 0.0, 0.0]]).T.reshape(1, 3, 1, 2)
    n = unit_normal(raw)
    assert torch.allclose(torch.linalg.vector_norm(n, dim=1), torch.ones(1, 1, 2))
    assert (n[:, 2] > 0).all()
    assert torch.allclose(n[0, :, 0, 1], torch.tensor([0.0, 0.0, 1.0]))


# ------------------------------------------------------------------------------------ parameter L1


def test_parameter_l1_hand_value():
    a = _const_maps(diffuse=0.5, specular=0.04, roughness=0.5)
    b = _const_maps(diffuse=0.2, specular=0.10, roughness=0.9, normal=(0.6, 0.0, 0.8))
    total, per = parameter_l1(a, b, MapWeights(normal=2.0, diffuse=1.0, specular=0.5, roughness=0.0))
    assert per["diffuse"].item() == pytest.approx(0.3)
    assert per["specular"].item() == pytest.approx(0.06)
    assert per["roughness"].item() == pytest.approx(0.4)
    assert per["normal"].item() == pytest.approx((0.6 + 0.0 + 0.2) / 3)
    assert total.item() == pytest.approx(2 * 0.8 / 3 + 0.3 + 0.5 * 0.06)
    assert parameter_l1(a, a)[0].item() == 0
    with pytest.raises(ConfigError, match="diffuse weight"):
        MapWeights(diffuse=-1.0)


# ----------------------------------------------------------------------------- view/light sampling


def test_sampler_geometry_and_forced_highlights():
    pairs = sample_view_light_pairs(4, torch.Generator().manual_seed(3), count=10, highlights=5)
    assert pairs.cameras.shape == pairs.lights.shape == pairs.points.shape == (4, 10, 3)
    assert pairs.highlight.tolist() == [False] * 5 + [True] * 5
    distance = torch.full((4, 10), RENDER_DISTANCE)
    assert torch.allclose(torch.linalg.vector_norm(pairs.cameras, dim=-1), distance)
    assert (pairs.cameras[..., 2] > 0).all() and (pairs.lights[..., 2] > 0).all()
    plain, hl = ~pairs.highlight, pairs.highlight
    assert torch.allclose(
        torch.linalg.vector_norm(pairs.lights[:, plain], dim=-1), torch.full((4, 5), RENDER_DISTANCE)
    )
    # Forced highlights: the light is at distance 2.14 from p and mirrors the view about +z at p.
    p = pairs.points[:, hl]
    assert (p[..., :2].abs() <= 1).all() and (p[..., 2] == 0).all()
    to_l = pairs.lights[:, hl] - p
    to_v = pairs.cameras[:, hl] - p
    assert torch.allclose(torch.linalg.vector_norm(to_l, dim=-1), torch.full((4, 5), RENDER_DISTANCE))
    l = to_l / torch.linalg.vector_norm(to_l, dim=-1, keepdim=True)
    v = to_v / torch.linalg.vector_norm(to_v, dim=-1, keepdim=True)
    h = (l + v) / torch.linalg.vector_norm(l + v, dim=-1, keepdim=True)
    assert torch.allclose(h, torch.tensor([0.0, 0.0, 1.0]).expand_as(h), atol=1e-6)


def test_sampler_highlight_shows_at_the_point():
    """On a flat glossy sample the brightest pixel of a forced-highlight render is next to p."""
    h = w = 32
    maps = _const_maps(h=h, w=w, diffuse=0.0, specular=0.5, roughness=0.15)
    pairs = sample_view_light_pairs(1, torch.Generator().manual_seed(0), count=4, highlights=4)
    for k in range(4):
        img = tb.render_point_light(maps, pairs.lights[:, k], 1.0, pairs.cameras[:, k]).sum(dim=1)[0]
        i, j = divmod(int(img.argmax()), w)
        x, y = -1 + (2 * j + 1) / w, 1 - (2 * i + 1) / h
        px, py = pairs.points[0, k, :2].tolist()
        assert abs(x - px) <= 2.0 / w and abs(y - py) <= 2.0 / h


def test_sampler_seeding_and_errors():
    a = sample_view_light_pairs(2, torch.Generator().manual_seed(7))
    b = sample_view_light_pairs(2, torch.Generator().manual_seed(7))
    c = sample_view_light_pairs(2, torch.Generator().manual_seed(8))
    assert torch.equal(a.lights, b.lights) and torch.equal(a.cameras, b.cameras)
    assert not torch.equal(a.lights, c.lights)
    with pytest.raises(ConfigError, match="highlights"):
        sample_view_light_pairs(2, torch.Generator(), count=3, highlights=4)


# --------------------------------------------------------------------------------- rendering loss


def test_rendering_loss_hand_value_and_gradient():
    cams = torch.tensor([[[0.0, 0.0, 2.0], [0.0, 0.0, 1.0]]])
    pairs = sample_view_light_pairs(1, torch.Generator().manual_seed(0), count=2, highlights=0)
    pairs.cameras = cams

    def render(maps, camera, light):  # fake renderer: diffuse scaled by the camera height
        return maps.diffuse * camera[:, 2].view(-1, 1, 1, 1)

    pred = _const_maps(diffuse=0.5)
    target = _const_maps(diffuse=0.2)
    pred.diffuse.requires_grad_(True)
    loss = rendering_loss(pred, target, pairs, render)
    expected = 0.5 * (abs(math.log(2.0) - math.log(1.4)) + abs(math.log(1.5) - math.log(1.2)))
    assert loss.item() == pytest.approx(expected, rel=1e-6)
    loss.backward()
    assert (pred.diffuse.grad > 0).all()
    assert rendering_loss(target, target, pairs, render).item() == 0


def test_rendering_loss_with_torch_renderer():
    pairs = sample_view_light_pairs(2, torch.Generator().manual_seed(1))

    def render(maps, camera, light):
        return tb.render_point_light(maps, light, 10.0, camera)

    a = _const_maps(b=2, h=8, w=8)
    b = _const_maps(b=2, h=8, w=8, roughness=0.2)
    assert rendering_loss(a, a, pairs, render).item() == 0
    assert rendering_loss(a, b, pairs, render).item() > 0.01


# ----------------------------------------------------------------------------------- MAIR losses


def test_masked_angular_l1():
    z = torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, 1, 2)
    pred = torch.tensor([[1.0, 0.0], [0.0, 0.0], [0.0, 2.0]]).view(1, 3, 1, 2)  # 90°, 0° (non-unit)
    assert masked_angular_l1(pred, z).item() == pytest.approx(math.pi / 4, abs=1e-5)
    mask = torch.tensor([1.0, 0.0]).view(1, 1, 1, 2)
    assert masked_angular_l1(pred, z, mask).item() == pytest.approx(math.pi / 2, abs=1e-5)
    opposite = -z
    assert masked_angular_l1(opposite, z).item() == pytest.approx(math.pi, abs=1e-5)
    p = pred.clone().requires_grad_(True)
    masked_angular_l1(p, z).backward()
    assert torch.isfinite(p.grad).all()


def test_masked_mse_and_mask_shape_error():
    pred = torch.tensor([1.0, 2.0, 3.0, 4.0]).view(1, 1, 2, 2)
    target = torch.zeros(1, 1, 2, 2)
    mask = torch.tensor([1.0, 1.0, 0.0, 0.0]).view(1, 1, 2, 2)
    assert masked_mse(pred, target, mask).item() == pytest.approx((1 + 4) / 2)
    assert masked_mse(pred, target).item() == pytest.approx(30 / 4)
    with pytest.raises(InputError, match="mask"):
        masked_mse(pred, target, torch.ones(1, 1, 3, 2))


def test_scale_invariant_losses():
    g = torch.Generator().manual_seed(0)
    pred = torch.rand(2, 3, 4, 5, generator=g) + 0.1
    scale = torch.tensor([3.0, 0.25]).view(2, 1, 1, 1)
    target = scale * pred
    assert torch.allclose(least_squares_scale(pred, target).view(2), scale.view(2))
    assert scale_invariant_mse(pred, target).item() == pytest.approx(0.0, abs=1e-10)
    assert scale_invariant_log_mse(pred, target).item() == pytest.approx(0.0, abs=1e-10)
    # Hand value: ŷ = (1, 2), y = (1, 1): τ = 3/5, residuals (−0.4, 0.2) → MSE 0.1.
    yh = torch.tensor([1.0, 2.0]).view(1, 1, 1, 2)
    y = torch.ones(1, 1, 1, 2)
    assert least_squares_scale(yh, y).item() == pytest.approx(0.6)
    assert scale_invariant_mse(yh, y).item() == pytest.approx(0.1)
    log_expected = ((math.log(1.6) - math.log(2)) ** 2 + (math.log(2.2) - math.log(2)) ** 2) / 2
    assert scale_invariant_log_mse(yh, y).item() == pytest.approx(log_expected, rel=1e-5)
    # The mask removes the second pixel: τ = 1 and the loss is zero.
    mask = torch.tensor([1.0, 0.0]).view(1, 1, 1, 2)
    assert scale_invariant_mse(yh, y, mask).item() == pytest.approx(0.0, abs=1e-12)


def test_entropy_regulariser():
    uniform = torch.ones(1, 4, 2, 2)
    assert entropy_regulariser(uniform).item() == pytest.approx(math.log(4))
    onehot = torch.zeros(1, 4, 2, 2)
    onehot[:, 1] = 3.0
    assert entropy_regulariser(onehot).item() == pytest.approx(0.0, abs=1e-9)
    mixed = torch.cat([uniform[..., :1], onehot[..., 1:]], dim=-1)  # left column uniform
    mask = torch.tensor([1.0, 0.0]).view(1, 1, 1, 2).expand(1, 1, 2, 2)
    assert entropy_regulariser(mixed, mask=mask).item() == pytest.approx(math.log(4))
    assert entropy_regulariser(mixed).item() == pytest.approx(math.log(4) / 2)
    w = torch.rand(1, 3, 2, 2, generator=torch.Generator().manual_seed(2)).requires_grad_(True)
    entropy_regulariser(w).backward()
    assert torch.isfinite(w.grad).all()
