"""Networks of ebr_mitsuba.nets: shapes, output constraints, gradients, tiny training steps, and
the torch BRDF mirror against the Dr.Jit BRDF.

All networks are built at tiny sizes on the CPU with fixed seeds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.geometry import DEFAULT_FLASH_INTENSITY, NEAR_DISTANCE, pixel_positions
from ebr_mitsuba.nets import (
    PAPER_SIZE,
    SMALL_SIZE,
    Cascade,
    CascadeConfig,
    DualLossConfig,
    DualLossNet,
    LightingNet,
    LightingNetConfig,
    Maps,
    NAFBlock,
    NAFNet,
    NAFNetSize,
    basecolor_metallic_to_diffuse_specular,
)
from ebr_mitsuba.nets import torch_brdf as tb
from ebr_mitsuba.nets.losses import parameter_l1
from ebr_mitsuba.svbrdf import SVBRDF

TINY = NAFNetSize(width=4, enc_blk_nums=(1, 1), middle_blk_num=1, dec_blk_nums=(1, 1))
TINY_DUAL = DualLossConfig(levels=4, width_scale=1 / 16)


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    """Tiny nets gain nothing from threads, and OpenMP spin-waiting on the shared 2 cores made
    these tests 5× slower under load; restore the setting afterwards."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def _rand(*shape, seed=0, low=0.0, high=1.0):
    return low + (high - low) * torch.rand(*shape, generator=_gen(seed))


def _wake_residuals(module, value=0.1):
    """Give every NAF block non-zero β/γ so gradients reach the block convolutions too."""
    with torch.no_grad():
        for m in module.modules():
            if isinstance(m, NAFBlock):
                m.beta.fill_(value)
                m.gamma.fill_(value)


def _assert_all_grads(module):
    missing = [
        name
        for name, p in module.named_parameters()
        if p.grad is None or not torch.isfinite(p.grad).all() or p.grad.abs().sum() == 0
    ]
    assert not missing, f"no gradient reached {missing}"


def _check_maps(maps: Maps, shape):
    b, h, w = shape
    assert maps.normal.shape == (b, 3, h, w) and maps.roughness.shape == (b, 1, h, w)
    assert maps.diffuse.shape == maps.specular.shape == (b, 3, h, w)
    norm = torch.linalg.vector_norm(maps.normal, dim=1)
    assert torch.allclose(norm, torch.ones_like(norm), atol=1e-5)
    assert (maps.normal[:, 2] > 0).all()
    for name in ("diffuse", "specular", "roughness"):
        t = getattr(maps, name)
        assert t.min() >= 0 and t.max() <= 1, name


def _random_maps(b, h, w, seed):
    raw = torch.randn(b, 10, h, w, generator=_gen(seed))
    return Maps.from_raw(raw)


# ---------------------------------------------------------------------------------------------- NAFNet


@pytest.mark.parametrize("hw", [(16, 16), (13, 21), (1, 5)])
def test_nafnet_shapes_pad_and_crop(hw):
    torch.manual_seed(0)
    net = NAFNet(5, 7, SMALL_SIZE)
    y = net(_rand(2, 5, *hw))
    assert y.shape == (2, 7, *hw)
    assert torch.isfinite(y).all()


def test_nafnet_crop_is_not_affected_by_padding_content():
    """The cropped output at a non-multiple size equals the output on a manually edge-padded input
    cropped the same way (padding is replication, cropping takes the top-left H×W)."""
    torch.manual_seed(0)
    net = NAFNet(3, 2, TINY).eval()
    x = _rand(1, 3, 6, 7)
    padded = torch.nn.functional.pad(x, (0, 1, 0, 2), mode="replicate")
    assert torch.allclose(net(x), net(padded)[..., :6, :7], atol=1e-6)


def test_nafblock_is_identity_at_init():
    torch.manual_seed(0)
    block = NAFBlock(6)
    x = torch.randn(2, 6, 5, 7, generator=_gen(1))
    assert torch.equal(block(x), x)
    _wake_residuals(block)
    assert not torch.allclose(block(x), x)


def test_nafnet_gradients_reach_every_parameter():
    torch.manual_seed(0)
    net = NAFNet(4, 3, TINY)
    x = _rand(2, 4, 12, 10)
    # At initialisation the residual scales receive gradient (so they can leave zero) ...
    net(x).square().mean().backward()
    for m in net.modules():
        if isinstance(m, NAFBlock):
            assert m.beta.grad.abs().sum() > 0 and m.gamma.grad.abs().sum() > 0
    # ... and once they are non-zero every parameter does.
    net.zero_grad()
    _wake_residuals(net)
    net(x).square().mean().backward()
    _assert_all_grads(net)


def test_size_presets_and_parameter_counts():
    from ebr_mitsuba.nets import parameter_count

    p = PAPER_SIZE
    assert (p.width, p.enc_blk_nums, p.middle_blk_num, p.dec_blk_nums) == (36, (2, 2, 4, 8), 12, (2, 2, 2, 2))
    assert parameter_count(NAFNet(6, 6, SMALL_SIZE)) == 291_150
    assert parameter_count(NAFNet(6, 6, PAPER_SIZE)) == 36_861_090


def test_size_config_validation():
    assert NAFNetSize.from_value("small") is SMALL_SIZE
    assert NAFNetSize.from_value(
        {"width": 4, "enc_blk_nums": [1], "middle_blk_num": 0, "dec_blk_nums": [2]}
    ).enc_blk_nums == (1,)
    with pytest.raises(ConfigError, match="unknown key"):
        NAFNetSize.from_value({"width": 4, "depth": 3})
    with pytest.raises(ConfigError, match="same length"):
        NAFNetSize(width=4, enc_blk_nums=(1, 1), middle_blk_num=1, dec_blk_nums=(1,))
    with pytest.raises(ConfigError, match="unknown network size"):
        NAFNetSize.from_value("huge")
    with pytest.raises(ConfigError, match="expected int"):
        CascadeConfig.from_dict({"num_env_exemplars": "3"})
    cfg = CascadeConfig.from_dict({"size": "small", "use_exemplars": False})
    assert cfg.size is SMALL_SIZE and not cfg.use_exemplars
    with pytest.raises(InputError, match=r"expected \(B, 5, H, W\)"):
        NAFNet(5, 2, TINY)(torch.zeros(1, 4, 8, 8))


# ---------------------------------------------------------------------------------------- lighting net


@pytest.mark.parametrize("capture,shots", [("near", 2), ("near-far", 4)])
def test_lighting_net_shapes_and_non_negative(capture, shots):
    torch.manual_seed(0)
    net = LightingNet(LightingNetConfig(size=TINY, capture=capture, num_exemplars=3))
    out = net(_rand(2, 3 * shots, 10, 14, high=5.0))
    assert out.exemplars.shape == (2, 3, 3, 10, 14)
    assert out.flash_only.shape == (2, 3, 10, 14)
    assert (out.exemplars > 0).all() and (out.flash_only > 0).all()
    assert torch.allclose(torch.log(out.flash_only), out.log_flash_only, atol=1e-5)
    with pytest.raises(InputError, match="LightingNet shots"):
        net(_rand(2, 3 * shots + 3, 10, 14))


# --------------------------------------------------------------------------------------------- cascade


def _cascade_inputs(b=2, h=10, w=14, k=3, m=3, seed=0):
    return dict(
        noflash=_rand(b, 3, h, w, seed=seed, high=0.5),
        flash_only=_rand(b, 3, h, w, seed=seed + 1, high=2.0),
        env_exemplars=_rand(b, k, 3, h, w, seed=seed + 2, high=0.5),
        point_exemplars=_rand(b, m, 3, h, w, seed=seed + 3, high=2.0),
        photos=_rand(b, 6, h, w, seed=seed + 4, high=2.0),
    )


def _render_photos(maps: Maps) -> torch.Tensor:
    """Stand-in for the flash + SG renderer: flash photo = point light, no-flash = diffuse/π."""
    flash = tb.render_point_light(maps, tb.NEAR_CAMERA)
    return torch.cat([flash, maps.diffuse / math.pi], dim=1)


def test_cascade_forward_shapes_and_wiring():
    torch.manual_seed(0)
    cascade = Cascade(CascadeConfig(size=TINY))
    inputs = _cascade_inputs()
    render_diffuse = tb.near_flash_diffuse()
    out = cascade(**inputs, render_diffuse_flash=render_diffuse, render_photos=_render_photos)
    _check_maps(out.maps, (2, 10, 14))
    _check_maps(out.coarse, (2, 10, 14))
    # The specular image is flash-only minus the diffuse flash render of the first-stage maps.
    expected = inputs["flash_only"] - render_diffuse(out.coarse.normal, out.coarse.diffuse)
    assert torch.allclose(out.specular_image, expected, atol=1e-6)
    assert torch.allclose(out.rendered_photos, _render_photos(out.coarse), atol=1e-6)
    assert not torch.allclose(out.maps.diffuse, out.coarse.diffuse)


def test_cascade_gradients_reach_every_parameter():
    torch.manual_seed(0)
    cascade = Cascade(CascadeConfig(size=TINY))
    _wake_residuals(cascade)
    out = cascade(
        **_cascade_inputs(), render_diffuse_flash=tb.near_flash_diffuse(), render_photos=_render_photos
    )
    parameter_l1(out.maps, _random_maps(2, 10, 14, seed=9))[0].backward()
    _assert_all_grads(cascade)


@pytest.mark.parametrize(
    "flags",
    [
        dict(use_exemplars=False),
        dict(use_cascade=False),
        dict(use_refinement=False),
        dict(use_exemplars=False, use_cascade=False, use_refinement=False),
    ],
)
def test_cascade_ablations(flags):
    torch.manual_seed(0)
    cfg = CascadeConfig(size=TINY, **flags)
    cascade = Cascade(cfg)
    inputs = _cascade_inputs()
    if not cfg.use_exemplars:
        inputs["env_exemplars"] = inputs["point_exemplars"] = None
    out = cascade(**inputs, render_diffuse_flash=tb.near_flash_diffuse(), render_photos=_render_photos)
    _check_maps(out.maps, (2, 10, 14))
    assert (out.specular_image is None) == (not cfg.use_cascade)
    assert (out.coarse is out.maps) == (not cfg.use_refinement)
    assert (cascade.joint_net is None) == cfg.use_cascade


def test_cascade_input_errors():
    cascade = Cascade(CascadeConfig(size=TINY))
    inputs = _cascade_inputs()
    with pytest.raises(InputError, match="render_diffuse_flash is required"):
        cascade(**inputs, render_photos=_render_photos)
    bad = dict(inputs, env_exemplars=inputs["env_exemplars"][:, :2])
    with pytest.raises(InputError, match="env_exemplars"):
        cascade(**bad, render_diffuse_flash=tb.near_flash_diffuse(), render_photos=_render_photos)
    with pytest.raises(InputError, match="render_photos are required"):
        cascade(**inputs, render_diffuse_flash=tb.near_flash_diffuse())


# -------------------------------------------------------------------------------------- dual-loss net


@pytest.mark.parametrize("output", ["diffuse_specular", "basecolor_metallic"])
def test_dual_loss_net_shapes_and_ranges(output):
    torch.manual_seed(0)
    net = DualLossNet(DualLossConfig(levels=4, width_scale=1 / 16, output=output))
    maps = net(_rand(2, 5, 3, 20, 12, high=3.0))
    _check_maps(maps, (2, 20, 12))
    if output == "basecolor_metallic":
        # F₀ = lerp(0.04, base, m) ≥ min(0.04, base) and diffuse = base (1 − m) ≤ base.
        assert (maps.specular + maps.diffuse <= 1.0 + 1e-6).all()
    net(_rand(2, 5, 3, 20, 12)).diffuse.mean().backward()
    _assert_all_grads(net)
    with pytest.raises(InputError, match=r"\(B, 5, 3, H, W\)"):
        net(_rand(2, 4, 3, 20, 12))


def test_basecolor_metallic_conversion():
    base = torch.tensor([0.2, 0.5, 0.9]).view(1, 3, 1, 1)
    for m, d_exp, s_exp in (
        (0.0, base, torch.full_like(base, 0.04)),
        (1.0, torch.zeros_like(base), base),
        (0.5, 0.5 * base, 0.02 + 0.5 * base),
    ):
        d, s = basecolor_metallic_to_diffuse_specular(base, torch.full((1, 1, 1, 1), m))
        assert torch.allclose(d, d_exp) and torch.allclose(s, s_exp)


def test_dual_loss_dropout_only_in_coarse_layers():
    net = DualLossNet(DualLossConfig(levels=6, width_scale=1 / 16))
    with_dropout = [
        i for i, layer in enumerate(net.up) if any(isinstance(m, torch.nn.Dropout) for m in layer)
    ]
    assert with_dropout == [0, 1, 2, 3]  # the four coarsest of five decoder layers


# ------------------------------------------------------------------------------ two training steps each


def _two_steps_lower(params, loss_fn, lr=1e-3):
    opt = torch.optim.Adam(params, lr=lr)
    first = None
    for _ in range(2):
        opt.zero_grad()
        loss = loss_fn()
        first = loss.item() if first is None else first
        loss.backward()
        opt.step()
    with torch.no_grad():
        final = loss_fn().item()
    assert final < first, (first, final)


def test_two_adam_steps_lower_the_loss_for_every_net():
    torch.manual_seed(0)
    target = _random_maps(2, 10, 14, seed=5)

    net = NAFNet(3, 3, TINY)
    x, y = _rand(2, 3, 10, 14, seed=1), _rand(2, 3, 10, 14, seed=2)
    _two_steps_lower(net.parameters(), lambda: (net(x) - y).abs().mean())

    lighting = LightingNet(LightingNetConfig(size=TINY, num_exemplars=2))
    shots, gt = _rand(2, 6, 10, 14, seed=3), _rand(2, 3, 10, 14, seed=4)
    _two_steps_lower(
        lighting.parameters(), lambda: (lighting(shots).log_flash_only - torch.log(gt + 0.01)).abs().mean()
    )

    cascade = Cascade(CascadeConfig(size=TINY))
    inputs = _cascade_inputs()
    _two_steps_lower(
        cascade.parameters(),
        lambda: parameter_l1(
            cascade(
                **inputs, render_diffuse_flash=tb.near_flash_diffuse(), render_photos=_render_photos
            ).maps,
            target,
        )[0],
    )

    dual = DualLossNet(TINY_DUAL)
    images = _rand(2, 5, 3, 10, 14, seed=6)

    def dual_loss():
        torch.manual_seed(1)  # the same dropout masks for every evaluation
        return parameter_l1(dual(images), target)[0]

    _two_steps_lower(dual.parameters(), dual_loss)


# ------------------------------------------------------------------------------------ maps container


def test_maps_stack_and_svbrdf_round_trip():
    maps = _random_maps(2, 5, 6, seed=3)
    again = Maps.unstack(maps.stack())
    assert torch.equal(again.roughness, maps.roughness) and torch.equal(again.normal, maps.normal)
    sv = maps.to_svbrdf(1)
    assert isinstance(sv, SVBRDF) and sv.roughness.shape == (5, 6)
    back = Maps.from_svbrdf([maps.to_svbrdf(0), sv])
    for name in ("normal", "diffuse", "specular", "roughness"):
        assert torch.allclose(getattr(back, name), getattr(maps, name), atol=1e-6), name
    with pytest.raises(InputError, match="roughness"):
        Maps(maps.normal, maps.diffuse, maps.specular, maps.roughness[:, :, :4])


# ------------------------------------------------------------------------------ torch BRDF vs Dr.Jit


def _random_directions(rng, n, below=0.0):
    """Unit vectors, upper hemisphere except a fraction ``below`` mirrored under the horizon."""
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    v[: int(below * n), 2] *= -1.0
    return v.astype(np.float32)


@pytest.mark.parametrize("fresnel", ["schlick", "none"])
def test_torch_brdf_matches_drjit(variant, rng, fresnel):
    """Same values as ebr_mitsuba.brdf.brdf_eval_cos and the same zero set. Tolerance: relative
    2e-5 where the shading is well conditioned (n·l, n·v, l_z, v_z > 0.01; measured max 9.7e-6 over
    200k samples), else 1e-6 of the largest value (grazing cosines amplify float32 rounding)."""
    import mitsuba as mi

    from ebr_mitsuba import brdf

    count = 20_000
    n = _random_directions(rng, count)
    n[:, 2] = np.maximum(n[:, 2], 0.2)  # shading normals tilted by up to ~78°
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    l = _random_directions(rng, count, below=0.1)
    v = _random_directions(rng, count, below=0.1)
    d = rng.uniform(0, 1, (count, 3)).astype(np.float32)
    s = rng.uniform(0, 1, (count, 3)).astype(np.float32)
    r = rng.uniform(0, 1, count).astype(np.float32)
    r[:2000] = rng.uniform(0, 0.05, 2000).astype(np.float32)  # below the 0.03 clamp and just above

    def vec(a, cls):
        return cls(a[:, 0], a[:, 1], a[:, 2])

    ref = (
        brdf.brdf_eval_cos(
            vec(n, mi.Vector3f),
            vec(l, mi.Vector3f),
            vec(v, mi.Vector3f),
            vec(d, mi.Color3f),
            vec(s, mi.Color3f),
            mi.Float(r),
            fresnel,
        )
        .numpy()
        .T
    )
    t = torch.from_numpy
    ours = tb.brdf_eval_cos(t(n), t(l), t(v), t(d), t(s), t(r), fresnel).numpy()
    assert np.isfinite(ours).all()
    zero = (ref == 0).all(axis=1)
    assert 0.1 * count < zero.sum() < 0.6 * count  # the masking is exercised ...
    assert np.array_equal(ours == 0, ref == 0)  # ... and agrees
    nl, nv = (n * l).sum(axis=1), (n * v).sum(axis=1)
    good = (nl > 0.01) & (nv > 0.01) & (l[:, 2] > 0.01) & (v[:, 2] > 0.01)
    assert good.sum() > 0.4 * count
    np.testing.assert_allclose(ours[good], ref[good], rtol=2e-5, atol=0)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-6 * float(np.abs(ref).max()))


@pytest.mark.parametrize("flush_denormal", [False, True])
def test_torch_brdf_gradients_finite_under_the_mask(flush_denormal):
    """Finite gradients where the BRDF is masked (l = −v, grazing), also with denormals flushed
    as the trainer runs (a floor in the denormal range became a 0 divisor there)."""
    torch.set_flush_denormal(flush_denormal)
    try:
        _check_masked_gradients()
    finally:
        torch.set_flush_denormal(False)


def _check_masked_gradients():
    n = torch.tensor([[0.0, 0.0, 1.0]], requires_grad=True)
    l = torch.tensor([[0.6, 0.0, 0.8], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    v = torch.tensor([[-0.6, 0.0, -0.8], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])  # l = −v; normal; grazing
    d = torch.full((3, 3), 0.5, requires_grad=True)
    s = torch.full((3, 3), 0.04, requires_grad=True)
    r = torch.tensor([0.5, 0.01, 0.3], requires_grad=True)
    f = tb.brdf_eval_cos(n, l, v, d, s, r)
    assert f[0].abs().sum() == 0 and f[2].abs().sum() == 0 and f[1].min() > 0
    f.sum().backward()
    for p in (n, d, s, r):
        assert torch.isfinite(p.grad).all()


def test_point_light_renderers_against_hand_formula():
    h, w = 6, 8
    maps = _random_maps(1, h, w, seed=11)
    light = (0.3, -0.2, 1.7)
    img = tb.render_point_light(maps, light, intensity=5.0, camera=(0.0, 0.0, NEAR_DISTANCE))
    p = pixel_positions(h, w)[2, 5]
    to_l = np.asarray(light) - p
    lv = torch.tensor(to_l / np.linalg.norm(to_l), dtype=torch.float32)
    vv = torch.tensor(
        (np.array([0, 0, NEAR_DISTANCE]) - p) / np.linalg.norm([0, 0, NEAR_DISTANCE] - p), dtype=torch.float32
    )
    nv = tb.perturbed_normal(maps.normal[0, :, 2, 5])
    f = tb.brdf_eval_cos(
        nv, lv, vv, maps.diffuse[0, :, 2, 5], maps.specular[0, :, 2, 5], maps.roughness[0, 0, 2, 5]
    )
    assert torch.allclose(img[0, :, 2, 5], f * 5.0 / float(to_l @ to_l), rtol=1e-5)

    # Near flash, diffuse only: d/π · I · max(n·l, 0)/dist² at a flat pixel.
    flat = torch.zeros(1, 3, h, w)
    flat[:, 2] = 1.0
    diffuse = torch.full((1, 3, h, w), 0.3)
    dimg = tb.near_flash_diffuse()(flat, diffuse)
    to_l = np.array([0.0, 0.0, NEAR_DISTANCE]) - p
    dist2 = float(to_l @ to_l)
    expected = 0.3 / math.pi * DEFAULT_FLASH_INTENSITY * (NEAR_DISTANCE / math.sqrt(dist2)) / dist2
    assert torch.allclose(dimg[0, :, 2, 5], torch.full((3,), expected), rtol=1e-5)
    # The full renderer with zero specular and no Fresnel gives the same diffuse image.
    zero = Maps(flat, diffuse, torch.zeros_like(diffuse), torch.full((1, 1, h, w), 0.5))
    full = tb.render_point_light(zero, tb.NEAR_CAMERA, fresnel="none")
    assert torch.allclose(full, dimg, rtol=1e-6)
