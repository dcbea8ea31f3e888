"""The Dr.Jit renderer called from torch (ebr_mitsuba.nets.drwrap): values and gradients.

* the torch mirror (torch_brdf) and the Dr.Jit render agree on point-light images;
* dr.wrap gradients equal central finite differences (maps and lobes, closed-form SG environment);
* dr.wrap gradients equal torch autograd through the torch mirror (point light);
* the rendering loss runs on the wrapped renderer and matches the torch renderer.
"""

from __future__ import annotations

import pytest
import torch

from ebr_mitsuba.errors import InputError
from ebr_mitsuba.geometry import DEFAULT_FLASH_INTENSITY, near_shot
from ebr_mitsuba.nets import Maps, drwrap
from ebr_mitsuba.nets import torch_brdf as tb
from ebr_mitsuba.nets.losses import rendering_loss, sample_view_light_pairs
from ebr_mitsuba.sgenv import SGEnvironment

H = W = 8


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # conftest: torch on one thread


def _maps(seed: int, batch: int = 2) -> Maps:
    g = torch.Generator().manual_seed(seed)
    n = 0.3 * torch.randn(batch, 3, H, W, generator=g)
    n[:, 2] = 1.0
    n = n / n.norm(dim=1, keepdim=True)
    return Maps(
        n,
        torch.rand(batch, 3, H, W, generator=g),
        0.5 * torch.rand(batch, 3, H, W, generator=g),
        0.25 + 0.6 * torch.rand(batch, 1, H, W, generator=g),
    )


LOBES = torch.tensor(
    [
        [0.3, 0.2, 0.9, 6.0, 1.0, 0.8, 0.6],
        [-0.5, 0.1, 0.6, 2.0, 0.4, 0.5, 0.7],
        [0.0, 0.0, 1.0, 0.5, 0.2, 0.2, 0.25],
    ]
)


def test_point_light_matches_torch_mirror():
    maps = _maps(0)
    dr_img = drwrap.render_maps(maps, None, near_shot(True))
    torch_img = tb.render_point_light(maps, tb.NEAR_CAMERA, DEFAULT_FLASH_INTENSITY)
    assert dr_img.shape == (2, 3, H, W) and dr_img.dtype == torch.float32
    assert torch.allclose(dr_img, torch_img, rtol=1e-4, atol=1e-5 * float(torch_img.abs().max()))


def test_float64_maps_render_as_float32():
    maps32 = _maps(1, batch=1)
    maps = Maps(*(t.double() for t in (maps32.normal, maps32.diffuse, maps32.specular, maps32.roughness)))
    img = drwrap.render_maps(maps, None, near_shot(True))
    assert img.dtype == torch.float32
    ref = tb.render_point_light(maps32, tb.NEAR_CAMERA)
    assert torch.allclose(img, ref, rtol=1e-4, atol=1e-4)


def test_gradients_match_torch_autograd_point_light():
    maps = _maps(2)
    leaves = [maps.normal, maps.diffuse, maps.specular, maps.roughness]
    for t in leaves:
        t.requires_grad_(True)
    weight = torch.rand(2, 3, H, W, generator=torch.Generator().manual_seed(3))
    (drwrap.render_maps(maps, None, near_shot(True)) * weight).sum().backward()
    dr_grads = [t.grad.clone() for t in leaves]
    for t in leaves:
        t.grad = None
    (tb.render_point_light(maps, tb.NEAR_CAMERA) * weight).sum().backward()
    for name, a, t in zip(("normal", "diffuse", "specular", "roughness"), dr_grads, leaves):
        scale = float(t.grad.abs().max())
        assert scale > 0, name
        assert torch.allclose(a, t.grad, atol=2e-4 * scale, rtol=1e-3), name


def _fd_check(fn, leaf: torch.Tensor, seed: int, eps: float = 1e-3, rtol: float = 2e-2):
    """Directional derivative along a random direction: autograd vs central differences (float32)."""
    direction = torch.randn(leaf.shape, generator=torch.Generator().manual_seed(seed))
    leaf = leaf.detach().clone().requires_grad_(True)
    fn(leaf).backward()

    analytic = float((leaf.grad * direction).sum())
    with torch.no_grad():
        numeric = float((fn(leaf + eps * direction) - fn(leaf - eps * direction)) / (2 * eps))
    assert abs(numeric) > 1e-3
    assert abs(analytic - numeric) <= rtol * abs(numeric), (analytic, numeric)


@pytest.mark.parametrize("name", ["normal", "diffuse", "specular", "roughness"])
def test_map_gradients_equal_finite_differences(name):
    base = _maps(4, batch=1)
    weight = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(5))
    shot = near_shot(True)

    def fn(x):
        m = Maps(
            **{
                k: (x if k == name else getattr(base, k))
                for k in ("normal", "diffuse", "specular", "roughness")
            }
        )
        return (drwrap.render_maps(m, [LOBES], shot) * weight).sum()

    _fd_check(fn, getattr(base, name), seed=6)


def test_lobe_gradients_equal_finite_differences():
    maps = _maps(7, batch=1)
    weight = torch.rand(1, 3, H, W, generator=torch.Generator().manual_seed(8))
    shot = near_shot(False)

    def fn(lobes):
        return (drwrap.render_maps(maps, [lobes], shot) * weight).sum()

    _fd_check(fn, LOBES, seed=9)


def test_environment_matches_numpy_renderer():
    from ebr_mitsuba.render import render_numpy

    maps = _maps(10, batch=1)
    env = SGEnvironment(LOBES[:, :3].numpy(), LOBES[:, 3].numpy(), LOBES[:, 4:].numpy())
    img = drwrap.render_maps(maps, [drwrap.lobes_from_env(env)], near_shot(True))
    ref = render_numpy(maps.to_svbrdf(0), env, near_shot(True))
    assert torch.allclose(img[0].permute(1, 2, 0), torch.from_numpy(ref), rtol=1e-5, atol=1e-6)


def test_rendering_loss_through_drjit_matches_torch():
    pred, target = _maps(11), _maps(12)
    pred.roughness.requires_grad_(True)
    pairs = sample_view_light_pairs(2, torch.Generator().manual_seed(13), count=4, highlights=2)
    loss_dr = rendering_loss(pred, target, pairs, drwrap.point_light_renderer())
    loss_dr.backward()
    grad_dr = pred.roughness.grad.clone()
    pred.roughness.grad = None

    def torch_render(m, cam, light):
        return tb.render_point_light(m, light, DEFAULT_FLASH_INTENSITY, cam)

    loss_t = rendering_loss(pred, target, pairs, torch_render)
    loss_t.backward()
    loss_dr, loss_t = float(loss_dr.detach()), float(loss_t.detach())
    assert loss_dr > 0
    assert abs(loss_dr - loss_t) <= 1e-4 * loss_t
    assert torch.allclose(grad_dr, pred.roughness.grad, atol=1e-3 * float(pred.roughness.grad.abs().max()))


def test_padded_lobes_and_errors():
    sg = torch.zeros(2, 4, 7)
    sg[0, :3] = LOBES
    mask = torch.tensor([[1.0, 1, 1, 0], [0, 0, 0, 0]])
    lobes = drwrap.lobes_from_padded(sg, mask)
    assert lobes[0].shape == (3, 7) and lobes[1].shape == (0, 7)
    assert drwrap.lobes_from_env(None).shape == (0, 7)
    maps = _maps(14)
    # An element without lobes renders the flash alone.
    img = drwrap.render_maps(maps, lobes, near_shot(True))
    flash = drwrap.render_maps(maps, None, near_shot(True))
    assert torch.equal(img[1], flash[1]) and not torch.allclose(img[0], flash[0])
    with pytest.raises(InputError, match="expected \\(B, K, 7\\)"):
        drwrap.lobes_from_padded(sg[0], mask)
    with pytest.raises(InputError, match="2 maps but 1 shots"):
        drwrap.render_maps(maps, None, [near_shot(True)])
    with pytest.raises(InputError, match="expected \\(K, 7\\)"):
        drwrap.render_maps(maps, [LOBES[:, :6], LOBES[:, :6]], near_shot(True))
