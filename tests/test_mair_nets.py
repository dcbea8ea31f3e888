"""MAIR multi-view networks (ebr_mitsuba.nets.mair): shapes and value ranges per stage, the view
geometry, permutation equivariance/invariance of the fusion, the mean-pool ablation, gradients
from the MAIR losses and one optimisation step. All at the ``tiny`` preset on the CPU, fixed seeds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ebr_mitsuba.errors import ConfigError, InputError
from ebr_mitsuba.geometry import NEAR_DISTANCE, Shot, pixel_positions
from ebr_mitsuba.nets import (
    MAIR_SIZE_PRESETS,
    MAIRConfig,
    MAIRModel,
    MAIRSize,
    MVANet,
    PixelSGLighting,
    hemisphere_directions,
    in_frame_weights,
    view_direction_maps,
)
from ebr_mitsuba.nets.losses import (
    entropy_regulariser,
    masked_angular_l1,
    masked_mse,
    scale_invariant_log_mse,
    scale_invariant_mse,
)
from ebr_mitsuba.nets.mair import stage_parameter_counts

TINY = MAIRConfig(size="tiny")


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    """Tiny nets gain nothing from threads on the shared cores; restore the setting afterwards."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _gen(seed=0):
    return torch.Generator().manual_seed(seed)


def _views(b=2, n=9, h=16, w=16, seed=0):
    """Random linear radiance with a few bright 'highlight' pixels."""
    g = _gen(seed)
    highlights = torch.rand(b, n, 1, h, w, generator=g) > 0.95
    return torch.rand(b, n, 3, h, w, generator=g) * 0.5 + 3.0 * highlights


def _wake(module, value=0.1):
    """Give the zero-initialised residual scales (NAF β/γ, attention β/γ) a non-zero value, so the
    identity-at-initialisation blocks pass gradients and mix views."""
    with torch.no_grad():
        for name, p in module.named_parameters():
            if name.endswith(("beta", "gamma")):
                p.fill_(value)
    return module


def _model(fusion="attention", seed=0, **kw):
    torch.manual_seed(seed)
    return _wake(MAIRModel(MAIRConfig(size="tiny", fusion=fusion, **kw)))


def _targets(b, h, w, seed=1):
    g = _gen(seed)
    n = torch.randn(b, 3, h, w, generator=g) * 0.3
    n[:, 2] = 1.0
    n = n / torch.linalg.vector_norm(n, dim=1, keepdim=True)
    return {
        "normal": n,
        "diffuse": torch.rand(b, 3, h, w, generator=g),
        "specular": 0.04 + 0.2 * torch.rand(b, 3, h, w, generator=g),
        "roughness": torch.rand(b, 1, h, w, generator=g),
        "light": 0.1 + torch.rand(b, 3 * 8, h, w, generator=g),
    }


LIGHT_DIRS = hemisphere_directions(2, 4)  # 8 directions: a small g4 target


def _mair_loss(out, t) -> torch.Tensor:
    """g1 + g2 (normals), g3 (albedo), g2 (roughness, specular), g4 (lighting), g5 (visibility)."""
    m = out.maps
    return (
        masked_angular_l1(m.normal, t["normal"])
        + masked_mse(m.normal, t["normal"])
        + scale_invariant_mse(m.diffuse, t["diffuse"])
        + masked_mse(m.roughness, t["roughness"])
        + masked_mse(m.specular, t["specular"])
        + scale_invariant_log_mse(out.lighting.radiance_image(LIGHT_DIRS), t["light"])
        + 0.1 * entropy_regulariser(out.lighting.visibility_distribution(), dim=1)
    )


# ---------------------------------------------------------------------------------- geometry


def test_view_directions_follow_the_cameras():
    h, w = 12, 10
    d = view_direction_maps(h, w)
    assert d.shape == (9, 3, h, w) and d.dtype == torch.float32
    assert torch.allclose(torch.linalg.vector_norm(d, dim=1), torch.ones(9, h, w), atol=1e-6)
    assert (d[:, 2] > 0).all()
    p = pixel_positions(h, w)
    # view00 is the top-left camera (x = −0.6, y = +0.6); view11 the centre one
    for k, cam in ((0, (-0.6, 0.6, NEAR_DISTANCE)), (4, (0.0, 0.0, NEAR_DISTANCE))):
        ref = np.asarray(cam) - p
        ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
        assert np.allclose(d[k].permute(1, 2, 0).numpy(), ref, atol=1e-6)
    # row-major grid: view02 is the top-right camera, view20 the bottom-left one
    assert d[0, 0].mean() < 0 < d[2, 0].mean() and d[6, 1].mean() < 0 < d[0, 1].mean()


def test_in_frame_weights():
    w = in_frame_weights(16, 16)
    assert w.shape == (9, 1, 16, 16)
    assert torch.equal(w[4], torch.ones_like(w[4]))  # the centre camera frames exactly the sample
    cover = w.mean(dim=(1, 2, 3))
    assert ((cover > 0.98) & (cover < 1)).sum() == 8  # each oblique one misses a sliver under itself
    missed = (w[0, 0] == 0).nonzero()  # view00 (camera above x = −0.6, y = +0.6): the top-left corner
    assert len(missed) and (missed < 8).all()
    narrow = Shot("narrow", (0.0, 0.0, NEAR_DISTANCE), 30.0, None)
    m = in_frame_weights(16, 16, [narrow])[0, 0]
    half = NEAR_DISTANCE * math.tan(math.radians(15.0))  # 0.647: the frame on the sample
    x = torch.from_numpy(pixel_positions(16, 16)[..., 0]).float()
    y = torch.from_numpy(pixel_positions(16, 16)[..., 1]).float()
    assert torch.equal(m, ((x.abs() <= half) & (y.abs() <= half)).float())
    assert m[0, 0] == 0 and m[8, 8] == 1


# ------------------------------------------------------------------------ shapes and ranges


@pytest.mark.parametrize("hw", [(16, 16), (20, 28), (32, 32)])
def test_stage_shapes_and_ranges(hw):
    h, w = hw
    b, n, s = 2, 9, 3
    model = _model()
    cfg = model.config
    views = _views(b, n, h, w)
    out = model(views, view_direction_maps(h, w))
    m, light = out.maps, out.lighting
    assert m.normal.shape == m.diffuse.shape == m.specular.shape == (b, 3, h, w)
    assert m.roughness.shape == (b, 1, h, w)
    assert torch.allclose(torch.linalg.vector_norm(m.normal, dim=1), torch.ones(b, h, w), atol=1e-5)
    assert (m.normal[:, 2] > 0).all()
    for name in ("diffuse", "specular", "roughness"):
        t = getattr(m, name)
        assert t.min() >= 0 and t.max() <= 1, name
    assert light.axis.shape == (b, s, 3, h, w) and light.intensity.shape == (b, s, 3)
    assert light.sharpness.shape == light.visibility.shape == (b, s, 1, h, w)
    assert torch.allclose(torch.linalg.vector_norm(light.axis, dim=2), torch.ones(b, s, h, w), atol=1e-5)
    assert (light.axis[:, :, 2] > 0).all()
    lo, hi = cfg.sharpness_range
    assert light.sharpness.min() >= lo * (1 - 1e-5) and light.sharpness.max() <= hi * (1 + 1e-5)
    assert light.visibility.min() >= 0 and light.visibility.max() <= 1
    assert (light.intensity >= 0).all() and torch.isfinite(light.intensity).all()
    size = cfg.size
    assert out.spec_features.shape == (b, n, size.spec_features, h, w)
    assert out.fusion.per_view.shape == (b, n, size.mva_dim, h, w)
    assert out.fusion.pooled.shape == (b, size.mva_dim, h, w)
    assert out.fusion.fused.shape == (b, size.brdf_features, h, w)
    rad = light.radiance_image(LIGHT_DIRS)
    assert rad.shape == (b, 3 * 8, h, w) and (rad >= 0).all()


def test_visibility_stays_in_unit_interval_at_extremes():
    model = _model()
    last = model.lighting_net.net.ending
    s = model.config.num_sgs
    with torch.no_grad():  # drive the visibility logits to ±1e4
        last.bias[4 * s : 5 * s] = torch.tensor([1e4, -1e4, 0.0])
    views = _views(1, 9, 16, 16) * 1e4
    light = model(views, view_direction_maps(16, 16)).lighting
    assert torch.isfinite(light.visibility).all()
    assert light.visibility.min() >= 0 and light.visibility.max() <= 1
    assert light.visibility[:, 0].min() > 0.999 and light.visibility[:, 1].max() < 1e-3
    ent = entropy_regulariser(light.visibility_distribution(), dim=1)
    assert torch.isfinite(ent)


def test_any_view_count_and_single_view():
    model = _model()
    for n in (1, 4):
        dirs = view_direction_maps(16, 16)[:n]
        out = model(_views(1, n), dirs)
        assert out.maps.diffuse.shape == (1, 3, 16, 16) and out.spec_features.shape[1] == n


def test_bad_inputs_are_input_errors():
    model = _model()
    dirs = view_direction_maps(16, 16)
    with pytest.raises(InputError, match="views"):
        model(torch.rand(2, 9, 4, 16, 16), dirs)
    with pytest.raises(InputError, match="directions"):
        model(_views(1), dirs[:8])
    with pytest.raises(InputError, match="weights"):
        model(_views(1), dirs, torch.ones(9, 1, 8, 8))


# ------------------------------------------------------------------------------------ fusion


def _permutation_check(fusion):
    torch.manual_seed(3)
    net = _wake(MVANet(10, dim=8, heads=2, depth=2, mlp=16, out_features=5, fusion=fusion), 0.5)
    g = _gen(4)
    tokens = torch.randn(2, 9, 10, 4, 5, generator=g)
    weights = torch.rand(2, 9, 1, 4, 5, generator=g)
    perm = torch.randperm(9, generator=g)
    a = net(tokens, weights)
    b = net(tokens[:, perm], weights[:, perm])
    assert torch.allclose(b.per_view, a.per_view[:, perm], atol=1e-5)
    assert torch.allclose(b.pooled, a.pooled, atol=1e-5)
    assert torch.allclose(b.fused, a.fused, atol=1e-5)
    return net, tokens, weights, a


def test_attention_fusion_is_permutation_equivariant_and_invariant():
    net, tokens, weights, a = _permutation_check("attention")
    # ... and the views really attend to each other: changing view 0 changes view 1's token
    other = tokens.clone()
    other[:, 0] += 1.0
    c = net(other, weights)
    assert (c.per_view[:, 1] - a.per_view[:, 1]).abs().max() > 1e-3


def test_mean_fusion_is_permutation_invariant_without_view_mixing():
    net, tokens, weights, a = _permutation_check("mean")
    other = tokens.clone()
    other[:, 0] += 1.0
    c = net(other, weights)
    assert torch.equal(c.per_view[:, 1:], a.per_view[:, 1:])  # no exchange between views
    assert (c.fused - a.fused).abs().max() > 1e-3


def test_whole_model_is_invariant_to_view_order():
    model = _model(seed=5)
    h, w = 16, 16
    views, dirs = _views(1, 9, h, w, seed=6), view_direction_maps(h, w)
    weights = 0.2 + torch.rand(9, 1, h, w, generator=_gen(7))
    perm = torch.tensor([4, 0, 8, 2, 6, 1, 3, 7, 5])
    a = model(views, dirs, weights)
    b = model(views[:, perm], dirs[perm], weights[perm])
    for name in ("normal", "diffuse", "specular", "roughness"):
        assert torch.allclose(getattr(a.maps, name), getattr(b.maps, name), atol=1e-5), name
    assert torch.allclose(a.lighting.axis, b.lighting.axis, atol=1e-5)
    assert torch.allclose(a.lighting.intensity, b.lighting.intensity, rtol=1e-5)
    assert torch.allclose(b.spec_features, a.spec_features[:, perm], atol=1e-5)


def test_mean_pool_equals_plain_mean_for_uniform_weights():
    torch.manual_seed(8)
    net = _wake(MVANet(7, dim=8, heads=2, depth=1, mlp=16, out_features=3, fusion="mean"), 0.5)
    tokens = torch.randn(2, 9, 7, 3, 4, generator=_gen(9))
    for weights in (None, torch.full((2, 9, 1, 3, 4), 0.37)):
        out = net(tokens, weights)
        assert torch.allclose(out.pooled, out.per_view.mean(dim=1), atol=1e-6)
    w = torch.rand(2, 9, 1, 3, 4, generator=_gen(10))
    out = net(tokens, w)
    weighted = (w * out.per_view).sum(dim=1) / w.sum(dim=1)
    assert torch.allclose(out.pooled, weighted, atol=1e-6)
    assert (out.pooled - out.per_view.mean(dim=1)).abs().max() > 1e-3


@pytest.mark.parametrize("fusion", ["attention", "mean"])
def test_zero_weight_view_is_ignored(fusion):
    torch.manual_seed(11)
    net = _wake(MVANet(6, dim=8, heads=2, depth=2, mlp=16, out_features=4, fusion=fusion), 0.5)
    tokens = torch.randn(1, 9, 6, 3, 3, generator=_gen(12))
    weights = torch.ones(1, 9, 1, 3, 3)
    weights[:, 2] = 0.0
    other = tokens.clone()
    other[:, 2] = torch.randn(1, 6, 3, 3, generator=_gen(13)) * 3
    a, b = net(tokens, weights), net(other, weights)
    assert torch.allclose(a.fused, b.fused, atol=1e-4)
    assert not torch.allclose(net(tokens).fused, net(other).fused, atol=1e-3)  # it matters at w = 1


# ------------------------------------------------------------------------ lighting evaluation


def test_pixel_sg_radiance_matches_the_sg_formula():
    g = _gen(14)
    b, s, h, w = 2, 3, 3, 4
    axis = torch.nn.functional.normalize(torch.randn(b, s, 3, h, w, generator=g), dim=2)
    light = PixelSGLighting(
        axis,
        1 + 50 * torch.rand(b, s, 1, h, w, generator=g),
        torch.rand(b, s, 1, h, w, generator=g),
        torch.rand(b, s, 3, generator=g),
    )
    dirs = hemisphere_directions(3, 5)
    assert dirs.shape == (15, 3) and (dirs[:, 2] > 0).all()
    assert torch.allclose(torch.linalg.vector_norm(dirs, dim=1), torch.ones(15), atol=1e-6)
    rad = light.radiance(dirs)
    i, j, bb = 2, 1, 1
    env = light.pixel_environment(bb, i, j)
    ref = env.eval(dirs.double().numpy())
    assert np.allclose(rad[bb, :, :, i, j].numpy(), ref, rtol=1e-4, atol=1e-6)
    # one lobe by hand
    k = 7
    by_hand = sum(
        light.visibility[bb, q, 0, i, j]
        * light.intensity[bb, q]
        * torch.exp(light.sharpness[bb, q, 0, i, j] * ((light.axis[bb, q, :, i, j] * dirs[k]).sum() - 1))
        for q in range(s)
    )
    assert torch.allclose(rad[bb, k, :, i, j], by_hand, rtol=1e-5)
    assert torch.equal(light.radiance_image(dirs)[:, 3 * k : 3 * k + 3], rad[:, k])


# -------------------------------------------------------------------------- gradients, training


@pytest.mark.parametrize("fusion", ["attention", "mean"])
def test_gradients_reach_every_parameter(fusion):
    model = _model(fusion, seed=15)
    h = w = 16
    out = model(_views(2, 9, h, w, seed=16), view_direction_maps(h, w))
    _mair_loss(out, _targets(2, h, w)).backward()
    missing = [
        name
        for name, p in model.named_parameters()
        if p.grad is None or not torch.isfinite(p.grad).all() or p.grad.abs().sum() == 0
    ]
    assert not missing, f"no gradient reached {missing}"


def test_stage_parameters_partition_the_model():
    model = MAIRModel(TINY)
    ids = [id(p) for stage in MAIRModel.STAGES for p in model.stage_parameters(stage)]
    assert len(ids) == len(set(ids)) == len(list(model.parameters()))
    with pytest.raises(InputError, match="stage"):
        model.stage_parameters("albedo")


def test_one_step_lowers_the_mair_loss():
    model = _model(seed=17)
    h = w = 16
    views, dirs, t = _views(2, 9, h, w, seed=18), view_direction_maps(h, w), _targets(2, h, w, seed=19)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    before = _mair_loss(model(views, dirs), t)
    opt.zero_grad()
    before.backward()
    opt.step()
    with torch.no_grad():
        after = _mair_loss(model(views, dirs), t)
    assert after < before - 1e-4, (float(before), float(after))


# ------------------------------------------------------------------------------------ config


def test_presets_and_parameter_counts():
    assert set(MAIR_SIZE_PRESETS) == {"tiny", "small", "paper"}
    # quoted in docs/mair.md and the mair_config docstring (`python -m ebr_mitsuba.nets.mair_params`)
    assert stage_parameter_counts(MAIRConfig(size="tiny"))["total"] == 19134
    assert stage_parameter_counts(MAIRConfig(size="tiny", fusion="mean"))["total"] == 18582
    assert stage_parameter_counts(MAIRConfig(size="small"))["total"] == 243490


def test_config_from_dict():
    cfg = MAIRConfig.from_dict({"size": "tiny", "fusion": "mean", "sharpness_range": [2, 100]})
    assert cfg.size == MAIR_SIZE_PRESETS["tiny"] and cfg.fusion == "mean"
    assert cfg.sharpness_range == (2.0, 100.0)
    custom = MAIRConfig.from_dict(
        {
            "size": {
                "mva_dim": 12,
                "mva_heads": 3,
                "normal": "small",
                "refine": {"widths": [8, 16], "depth": 1, "groups": 4},
            }
        }
    )
    assert custom.size.mva_dim == 12 and custom.size.refine.widths == (8, 16)
    with pytest.raises(ConfigError, match="unknown key"):
        MAIRConfig.from_dict({"num_views": 9})
    with pytest.raises(ConfigError, match="unknown key"):
        MAIRConfig.from_dict({"size": {"mva_width": 8}})
    with pytest.raises(ConfigError, match="fusion"):
        MAIRConfig(fusion="max")
    with pytest.raises(ConfigError, match="divide"):
        MAIRSize(mva_dim=10, mva_heads=4)
    with pytest.raises(ConfigError, match="unknown MAIR size"):
        MAIRConfig(size="huge")
    with pytest.raises(ConfigError, match="sharpness_range"):
        MAIRConfig(sharpness_range=(10.0, 1.0))
