"""The ``sgenvmap`` emitter and ``svbrdf`` BSDF plugins: χ² tests of sampling against pdfs,
exact evaluation against numpy / Mitsuba built-ins, furnace, hard cases and XML loading.

χ² tests use ``mitsuba.chi2`` with 10⁶ samples, seed 0 and a 1% significance level (Šidák-
corrected over the tests of one group). Sharp lobes get finer histograms (res 401, ires 8) so that
the reference integration resolves them (BSDF at r = 0.05: res 801, ires 16).
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

from ebr_mitsuba.sgenv import SGEnvironment

SIGNIFICANCE = 0.01


# -- helpers ------------------------------------------------------------------------------------
def _sgenvmap_dict(env, **extra):
    from ebr_mitsuba.plugins.sgenvmap import sgenvmap_dict

    return sgenvmap_dict(env, **extra)


def _emitter(env, **extra):
    return mi.load_dict(_sgenvmap_dict(env, **extra))


def _unit(rng, n):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _vec(a):
    """(N, 3) numpy → mi.Vector3f."""
    return mi.Vector3f(np.ascontiguousarray(np.asarray(a, np.float32).T))


def _np(v):
    """Dr.Jit 3-vector / colour → (N, 3) numpy."""
    return np.asarray(v.numpy(), np.float64).T


def _random_env(rng, k, lam_range=(1.0, 200.0)):
    axis = _unit(rng, k)
    lam = np.exp(rng.uniform(np.log(lam_range[0]), np.log(lam_range[1]), k))
    amp = rng.uniform(0.0, 3.0, (k, 3))
    return SGEnvironment(axis, lam, amp)


def _emitter_eval(em, d_np):
    si = dr.zeros(mi.SurfaceInteraction3f, d_np.shape[0])
    si.wi = -_vec(d_np)
    return _np(em.eval(si))


def _direction_sample(d_np):
    ds = dr.zeros(mi.DirectionSample3f, d_np.shape[0])
    ds.d = _vec(d_np)
    return ds


def _plane_scene(env_dict, bsdf, integrator="path", res=16, max_depth=None):
    integ = {"type": integrator}
    if max_depth is not None:
        integ["max_depth"] = max_depth
    return mi.load_dict(
        {
            "type": "scene",
            "integrator": integ,
            "env": env_dict,
            "plane": {"type": "rectangle", "bsdf": bsdf},
            "sensor": {
                "type": "perspective",
                "fov": 45.0,
                "to_world": mi.ScalarTransform4f().look_at(
                    origin=[0, 0, 2.414], target=[0, 0, 0], up=[0, 1, 0]
                ),
                "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent"},
            },
        }
    )


def _render(scene, spp, seed=0):
    return np.asarray(mi.render(scene, spp=spp, seed=seed), np.float64)


# -- sgenvmap: evaluation ------------------------------------------------------------------------
@pytest.mark.parametrize("k", [3, 12])  # 3: unrolled lobe sum; 12: symbolic loop
def test_sgenvmap_eval_matches_numpy(rng, k):
    env = _random_env(rng, k)
    em = _emitter(env, scale=1.7)
    d = _unit(rng, 4000)
    ref = 1.7 * env.eval(d)
    tol = 2e-5 * ref + 1e-6 * ref.max()
    assert np.all(np.abs(_emitter_eval(em, d) - ref) <= tol)
    it = dr.zeros(mi.Interaction3f, d.shape[0])
    got = _np(em.eval_direction(it, _direction_sample(d)))
    assert np.all(np.abs(got - ref) <= tol)


@pytest.mark.parametrize("k", [3, 12])
def test_sgenvmap_sampling_weight_is_radiance_over_pdf(rng, k):
    env = _random_env(rng, k)
    em = _emitter(env)
    n = 20000
    it = dr.zeros(mi.Interaction3f, n)
    it.p = mi.Point3f(0.3, -0.2, 0.0)
    ds, weight = em.sample_direction(it, mi.Point2f(rng.random((2, n)).astype(np.float32)))
    d = _np(ds.d)
    pdf = np.asarray(ds.pdf.numpy(), np.float64)
    assert np.all(np.isfinite(d)) and np.all(pdf > 0)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-5)
    # pdf_direction agrees with the pdf of the sample record
    np.testing.assert_allclose(em.pdf_direction(it, ds).numpy(), pdf, rtol=1e-5)
    # weight = L / pdf with L from the numpy reference
    np.testing.assert_allclose(_np(weight), env.eval(d) / pdf[:, None], rtol=1e-4, atol=1e-7)
    # the shadow-ray endpoint lies far along the direction
    p = _np(ds.p)
    dist = np.asarray(ds.dist.numpy())
    np.testing.assert_allclose(p, np.array([0.3, -0.2, 0.0]) + d * dist[:, None], rtol=1e-5, atol=1e-3)
    assert np.all(dist >= 2.0e3 * (1 - 1e-6))
    assert not np.any(ds.delta.numpy())
    # sample_ray: same lobe sample, ray towards the scene from the disk of radius scene_radius
    offsets = mi.Point2f(rng.random((2, n)).astype(np.float32))
    samples = mi.Point2f(rng.random((2, n)).astype(np.float32))
    ray, ray_weight = em.sample_ray(0.0, 0.5, offsets, samples)
    ds2, weight2 = em.sample_direction(dr.zeros(mi.Interaction3f, n), samples)
    np.testing.assert_allclose(_np(ray.d), -_np(ds2.d), atol=1e-6)
    np.testing.assert_allclose(_np(ray_weight), np.pi * 1.0e6 * _np(weight2), rtol=1e-5)
    origin = _np(ray.o)
    along = np.sum(origin * _np(ds2.d), axis=1)
    np.testing.assert_allclose(along, 1.0e3, rtol=1e-5)  # disk centred at R·d, perpendicular to d
    assert np.all(np.linalg.norm(origin - along[:, None] * _np(ds2.d), axis=1) <= 1.0e3 * (1 + 1e-5))


def test_sgenvmap_gradients_flow_through_traversed_parameters(rng):
    for k in (3, 12):
        env = _random_env(rng, k)
        em = _emitter(env)
        params = mi.traverse(em)
        dr.enable_grad(params["amplitude"])
        dr.enable_grad(params["sharpness"])
        params.update()
        d = _unit(rng, 512)
        it = dr.zeros(mi.Interaction3f, d.shape[0])
        radiance = em.eval_direction(it, _direction_sample(d))
        dr.backward(dr.sum(radiance.x + 2.0 * radiance.y + 3.0 * radiance.z))
        cos = d @ env.axis.T.astype(np.float64)
        e = np.exp(env.sharpness * (cos - 1.0))  # (N, K)
        w = np.array([1.0, 2.0, 3.0])
        grad_amp = (e.sum(axis=0)[:, None] * w[None, :]).reshape(-1)
        grad_lam = ((cos - 1.0) * e * (env.amplitude @ w)[None, :]).sum(axis=0)
        np.testing.assert_allclose(dr.grad(params["amplitude"]).numpy(), grad_amp, rtol=1e-4)
        np.testing.assert_allclose(
            dr.grad(params["sharpness"]).numpy(), grad_lam, rtol=1e-3, atol=1e-4 * np.abs(grad_lam).max()
        )


def test_sgenvmap_parameter_update_changes_lobes(rng):
    env = _random_env(rng, 2)
    em = _emitter(env)
    params = mi.traverse(em)
    new = _random_env(rng, 5)
    params["axis"] = mi.Float(3.0 * new.axis.reshape(-1))  # not unit: renormalised on update
    params["sharpness"] = mi.Float(new.sharpness)
    params["amplitude"] = mi.Float(new.amplitude.reshape(-1))
    params.update()
    d = _unit(rng, 1000)
    np.testing.assert_allclose(_emitter_eval(em, d), new.eval(d), rtol=2e-5, atol=1e-6)
    params["sharpness"] = mi.Float(np.r_[new.sharpness, 1.0])
    with pytest.raises(Exception, match="sharpness values need"):
        params.update()


def test_sgenvmap_loads_env_json_and_inline_xml(tmp_path, rng):
    env = _random_env(rng, 3)
    env.save(tmp_path / "env.json")
    d = _unit(rng, 500)
    from_file = mi.load_string(f"""<emitter version="3.0.0" type="sgenvmap">
        <string name="filename" value="{tmp_path / "env.json"}"/>
        <float name="scale" value="2"/>
    </emitter>""")
    np.testing.assert_allclose(_emitter_eval(from_file, d), 2.0 * env.eval(d), rtol=2e-5, atol=1e-6)

    def rows(a):
        return ", ".join(" ".join(repr(float(v)) for v in row) for row in np.atleast_2d(a))

    inline = mi.load_string(f"""<emitter version="3.0.0" type="sgenvmap">
        <string name="axis" value="{rows(env.axis)}"/>
        <string name="sharpness" value="{", ".join(repr(float(v)) for v in env.sharpness)}"/>
        <string name="amplitude" value="{rows(env.amplitude)}"/>
    </emitter>""")
    np.testing.assert_allclose(_emitter_eval(inline, d), env.eval(d), rtol=2e-5, atol=1e-6)


@pytest.mark.parametrize(
    "body, message",
    [
        ('<string name="axis" value="0 0 1"/>', "missing sharpness, amplitude"),
        (
            '<string name="axis" value="0 0 1, 1 0"/><string name="sharpness" value="1 2"/>'
            '<string name="amplitude" value="1 1 1, 1 1 1"/>',
            "lobe 1 has 2 numbers",
        ),
        (
            '<string name="axis" value="0 0 1"/><string name="sharpness" value="-1"/>'
            '<string name="amplitude" value="1 1 1"/>',
            "sharpness must be > 0",
        ),
        ('<string name="filename" value="/nonexistent/env.json"/>', "no such SG environment file"),
        ('<string name="filename" value="x.json"/><string name="axis" value="0 0 1"/>', "not both"),
        (
            '<string name="axis" value=""/><string name="sharpness" value=""/>'
            '<string name="amplitude" value=""/><float name="scale" value="-1"/>',
            "'scale' is -1",
        ),
    ],
)
def test_sgenvmap_rejects_bad_input(body, message):
    with pytest.raises(RuntimeError, match=message):
        mi.load_string(f'<emitter version="3.0.0" type="sgenvmap">{body}</emitter>')


# -- sgenvmap: χ² --------------------------------------------------------------------------------
def _emitter_chi2(env, res, ires):
    em = _emitter(env)

    def sample(s):
        ds, _ = em.sample_direction(dr.zeros(mi.Interaction3f), s)
        return ds.d

    def pdf(d):
        ds = dr.zeros(mi.DirectionSample3f, dr.width(d))
        ds.d = d
        return em.pdf_direction(dr.zeros(mi.Interaction3f), ds)

    return ChiSquareTest(
        SphericalDomain(), sample, pdf, sample_dim=2, sample_count=1_000_000, res=res, ires=ires, seed=0
    )


_EMITTER_CASES = {
    "sharp_1e3": (SGEnvironment([[0.6, 0.0, 0.8]], [1.0e3], [[1.0, 1.0, 1.0]]), 401, 8),
    "mix_3": (
        SGEnvironment(
            [[0.6, 0.0, 0.8], [0.0, 0.3, -1.0], [-1.0, 1.0, 0.2]],
            [1.0e3, 5.0, 0.01],
            [[3.0, 2.0, 1.0], [0.1, 0.2, 0.3], [0.05, 0.05, 0.05]],
        ),
        401,
        8,
    ),
    "mix_12": (None, 101, 4),  # symbolic-loop path, random lobes λ ∈ [1, 200]
}


@pytest.mark.parametrize("case", list(_EMITTER_CASES))
def test_sgenvmap_chi2(case):
    env, res, ires = _EMITTER_CASES[case]
    if env is None:
        env = _random_env(np.random.default_rng(7), 12)
    test = _emitter_chi2(env, res, ires)
    assert test.run(SIGNIFICANCE, test_count=len(_EMITTER_CASES), quiet=True), test.messages


# -- svbrdf: χ² ----------------------------------------------------------------------------------
_BSDF_CASES = [(r, theta, None) for r in (0.05, 0.5, 1.0) for theta in (10.0, 50.0, 80.0)] + [
    (0.3, 40.0, [0.3, -0.2, 0.9]),
    (0.05, 60.0, [-0.4, 0.1, 0.8]),
]


@pytest.mark.parametrize("roughness, theta, normal", _BSDF_CASES)
def test_svbrdf_chi2(roughness, theta, normal):
    props = {
        "type": "svbrdf",
        "diffuse": {"type": "rgb", "value": [0.5, 0.4, 0.3]},
        "specular": 0.04,
        "roughness": roughness,
    }
    if normal is not None:
        props["normal"] = {"type": "rgb", "value": normal}
    t = math.radians(theta)
    sample, pdf = BSDFAdapter("svbrdf", props, wi=[math.sin(t), 0.0, math.cos(t)])
    res, ires = (801, 16) if roughness < 0.1 else (101, 4)
    test = ChiSquareTest(
        SphericalDomain(), sample, pdf, sample_dim=3, sample_count=1_000_000, res=res, ires=ires, seed=0
    )
    assert test.run(SIGNIFICANCE, test_count=len(_BSDF_CASES), quiet=True), test.messages


# -- svbrdf: evaluation --------------------------------------------------------------------------
def _local_si(n, wi_np, uv=(0.5, 0.5)):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = _vec(wi_np)
    si.uv = mi.Point2f(*uv)
    si.n = mi.Normal3f(0.0, 0.0, 1.0)
    si.sh_frame = mi.Frame3f(
        mi.Vector3f(1.0, 0.0, 0.0), mi.Vector3f(0.0, 1.0, 0.0), mi.Vector3f(0.0, 0.0, 1.0)
    )
    si.dp_du = mi.Vector3f(1.0, 0.0, 0.0)
    si.dp_dv = mi.Vector3f(0.0, 1.0, 0.0)
    return si


def _builtin_reference(normal, diffuse, specular, roughness):
    """Mitsuba's normalmap(blendbsdf(0.5, diffuse(2d), roughconductor(GGX, F=2s)))
    (docs/conventions.md, "Dr.Jit and Mitsuba on the CPU")."""
    encoded = (np.asarray(normal, np.float32) + 1.0) / 2.0
    return mi.load_dict(
        {
            "type": "normalmap",
            "flip_invalid_normals": False,
            "use_shadowing_function": False,
            "normalmap": {
                "type": "bitmap",
                "raw": True,
                "data": mi.TensorXf(np.broadcast_to(encoded, (2, 2, 3)).copy()),
            },
            "bsdf": {
                "type": "blendbsdf",
                "weight": 0.5,
                "bsdf_0": {
                    "type": "diffuse",
                    "reflectance": {"type": "rgb", "value": list(2.0 * np.asarray(diffuse))},
                },
                "bsdf_1": {
                    "type": "roughconductor",
                    "distribution": "ggx",
                    "alpha": roughness**2,
                    "material": "none",
                    "specular_reflectance": {"type": "rgb", "value": list(2.0 * np.asarray(specular))},
                },
            },
        }
    )


@pytest.mark.parametrize(
    "normal, roughness",
    [
        ([0.0, 0.0, 1.0], 0.5),
        ([0.0, 0.0, 1.0], 0.05),
        ([0.3, -0.2, 0.9], 0.3),
        ([-0.5, 0.4, 0.75], 0.9),
    ],
)
def test_svbrdf_matches_mitsuba_builtins(rng, normal, roughness):
    diffuse, specular = [0.45, 0.3, 0.1], [0.04, 0.3, 0.5]  # the built-ins need 2d, 2s <= 1
    n_unit = np.asarray(normal) / np.linalg.norm(normal)
    normal_map = np.broadcast_to(n_unit.astype(np.float32), (2, 2, 3)).copy()
    ours = mi.load_dict(
        {
            "type": "svbrdf",
            "fresnel": "none",
            "roughness": roughness,
            "diffuse": {"type": "rgb", "value": diffuse},
            "specular": {"type": "rgb", "value": specular},
            "normal": {"type": "bitmap", "raw": True, "data": mi.TensorXf(normal_map)},
        }
    )
    ref = _builtin_reference(n_unit, diffuse, specular, roughness)
    count = 20000
    wi = _unit(rng, count)
    wi[:, 2] = np.abs(wi[:, 2])  # viewer above the surface (a one-sided BSDF sees nothing else)
    wo = _unit(rng, count)  # light anywhere, below-surface directions must give zero in both
    ctx = mi.BSDFContext()
    si = _local_si(count, wi)
    f_ours = _np(ours.eval(ctx, si, _vec(wo)))
    f_ref = _np(ref.eval(ctx, si, _vec(wo)))
    np.testing.assert_allclose(f_ours, f_ref, rtol=1e-5, atol=1e-6 * f_ref.max())
    assert np.count_nonzero(f_ref.sum(axis=1) > 0) > count // 10  # the comparison is not vacuous
    # pdf sanity: positive wherever the BSDF is, zero elsewhere, the same support as the built-in
    pdf = np.asarray(ours.pdf(ctx, si, _vec(wo)).numpy())
    pdf_ref = np.asarray(ref.pdf(ctx, si, _vec(wo)).numpy())
    nonzero = f_ours.sum(axis=1) > 0
    assert np.all(pdf[nonzero] > 0) and np.all(pdf[~nonzero] == 0)
    assert np.array_equal(pdf > 0, pdf_ref > 0)
    f2, pdf2 = ours.eval_pdf(ctx, si, _vec(wo))
    np.testing.assert_array_equal(_np(f2), f_ours)
    np.testing.assert_array_equal(pdf2.numpy(), pdf)


@pytest.mark.parametrize("fresnel", ["schlick", "none"])
def test_svbrdf_sample_weight_and_records(rng, fresnel):
    bsdf = mi.load_dict(
        {
            "type": "svbrdf",
            "fresnel": fresnel,
            "roughness": 0.4,
            "diffuse": {"type": "rgb", "value": [0.5, 0.2, 0.1]},
            "specular": 0.3,
            "normal": {"type": "rgb", "value": [0.2, 0.1, 0.95]},
        }
    )
    count = 20000
    wi = _unit(rng, count)
    wi[:, 2] = np.abs(wi[:, 2]) + 0.05
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    ctx = mi.BSDFContext()
    si = _local_si(count, wi)
    s1 = mi.Float(rng.random(count).astype(np.float32))
    s2 = mi.Point2f(rng.random((2, count)).astype(np.float32))
    bs, weight = bsdf.sample(ctx, si, s1, s2)
    f, pdf = bsdf.eval_pdf(ctx, si, bs.wo)
    ok = bs.pdf.numpy() > 0
    assert ok.mean() > 0.8
    np.testing.assert_allclose(bs.pdf.numpy()[ok], pdf.numpy()[ok], rtol=1e-4)
    expect = _np(f)[ok] / pdf.numpy()[ok][:, None]
    np.testing.assert_allclose(_np(weight)[ok], expect, rtol=1e-4, atol=1e-6)
    assert np.all(_np(weight)[~ok] == 0)
    assert np.all(bs.eta.numpy() == 1.0)
    glossy = bs.sampled_component.numpy() == 0
    types = bs.sampled_type.numpy()
    assert np.all(types[glossy] == int(mi.BSDFFlags.GlossyReflection))
    assert np.all(types[~glossy] == int(mi.BSDFFlags.DiffuseReflection))
    assert 0.05 < glossy.mean() < 0.95


def test_svbrdf_texture_gradients(rng):
    """Maps are differentiable through ``mi.traverse``: ∂f/∂d is cos/π (f is linear in d) and
    ∂f/∂r matches a central finite difference."""
    bsdf = mi.load_dict(
        {
            "type": "svbrdf",
            "roughness": 0.4,
            "specular": 0.3,
            "diffuse": {"type": "rgb", "value": [0.2, 0.3, 0.4]},
        }
    )
    params = mi.traverse(bsdf)
    count = 2000
    wi, wo = _unit(rng, count), _unit(rng, count)
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    ctx = mi.BSDFContext()

    def total(r=None):
        if r is not None:
            params["roughness.value"] = r
            params.update()
        f = bsdf.eval(ctx, _local_si(count, wi), _vec(wo))
        return dr.sum(f.x + f.y + f.z)

    dr.enable_grad(params["diffuse.value"])
    dr.enable_grad(params["roughness.value"])
    params.update()
    dr.backward(total())
    np.testing.assert_allclose(
        dr.grad(params["diffuse.value"]).numpy()[:, 0], np.sum(wo[:, 2]) / np.pi, rtol=1e-4
    )
    grad_r = float(dr.grad(params["roughness.value"]).numpy()[0])
    h = 1e-2
    with dr.suspend_grad():
        fd = (float(total(0.4 + h).numpy()[0]) - float(total(0.4 - h).numpy()[0])) / (2 * h)
    np.testing.assert_allclose(grad_r, fd, rtol=2e-3)


def test_svbrdf_encoded_normals_and_flags(rng):
    n = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    plain = mi.load_dict({"type": "svbrdf", "normal": {"type": "rgb", "value": list(n)}})
    encoded = mi.load_string(f"""<bsdf version="3.0.0" type="svbrdf">
        <rgb name="normal" value="{" ".join(str((v + 1) / 2) for v in n)}"/>
        <boolean name="normal_encoded" value="true"/>
    </bsdf>""")
    wi, wo = _unit(rng, 1000), _unit(rng, 1000)
    wi[:, 2] = np.abs(wi[:, 2])
    ctx = mi.BSDFContext()
    si = _local_si(1000, wi)
    np.testing.assert_allclose(
        _np(encoded.eval(ctx, si, _vec(wo))), _np(plain.eval(ctx, si, _vec(wo))), rtol=1e-5, atol=1e-7
    )
    flags = plain.flags()
    for flag in (
        mi.BSDFFlags.GlossyReflection,
        mi.BSDFFlags.DiffuseReflection,
        mi.BSDFFlags.FrontSide,
        mi.BSDFFlags.SpatiallyVarying,
    ):
        assert mi.has_flag(flags, flag)
    assert plain.component_count() == 2
    with pytest.raises(RuntimeError, match="'fresnel' is 'fancy'"):
        mi.load_dict({"type": "svbrdf", "fresnel": "fancy"})


# -- rendering ------------------------------------------------------------------------------------
@pytest.mark.parametrize("integrator", ["path", "direct"])
def test_white_furnace(integrator):
    """Diffuse albedo 1 under a constant unit environment reflects radiance 1."""
    env = SGEnvironment([[0.0, 0.0, 1.0]], [1.0e-5], [[1.0, 1.0, 1.0]])  # L ∈ [e^{-2e-5}, 1]
    bsdf = {"type": "svbrdf", "diffuse": 1.0, "specular": 0.0}
    img = _render(_plane_scene(_sgenvmap_dict(env), bsdf, integrator, res=8), spp=1024)
    assert np.all(np.isfinite(img))
    assert abs(img.mean() - 1.0) < 0.01  # measured: 1.0007 (path), 1.0004 (direct)
    assert np.all(np.abs(img - 1.0) < 0.05)  # per-pixel noise: std 0.8%


def _rasterise_for_envmap(env, width=256, height=128):
    """The environment as a Mitsuba ``envmap`` bitmap (+Y up, rows align-corners, columns at
    texel centres; :mod:`ebr_mitsuba.envmap`), to be used with ``to_world = rotate(x, 90°)``
    (local +Y → world +Z)."""
    u = (np.arange(width) + 0.5) / width
    v = np.arange(height) / (height - 1)
    phi, theta = np.meshgrid(2 * np.pi * u, np.pi * v)
    local = np.stack([np.sin(phi) * np.sin(theta), np.cos(theta), -np.cos(phi) * np.sin(theta)], -1)
    world = np.stack([local[..., 0], -local[..., 2], local[..., 1]], -1)  # rotate +90° about x
    return env.eval(world).astype(np.float32)


def test_sgenvmap_render_matches_rasterised_envmap():
    env = SGEnvironment(
        [[0.3, 0.2, 0.9], [-0.7, 0.1, 0.5], [0.0, 0.0, 1.0]],
        [8.0, 3.0, 0.5],
        [[2.0, 1.5, 1.0], [0.3, 0.6, 0.9], [0.2, 0.2, 0.2]],
    )
    bsdf = {
        "type": "svbrdf",
        "diffuse": {"type": "rgb", "value": [0.5, 0.4, 0.3]},
        "specular": 0.2,
        "roughness": 0.6,
    }
    ours = _render(_plane_scene(_sgenvmap_dict(env), bsdf, "path", res=8), spp=256)
    envmap = {
        "type": "envmap",
        "bitmap": mi.Bitmap(_rasterise_for_envmap(env)),
        "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90),
    }
    ref = _render(_plane_scene(envmap, bsdf, "path", res=8), spp=256)
    # image means (8×8 px × 256 spp each); bilinear rasterisation error ≪ 1% for λ ≤ 8
    np.testing.assert_allclose(ours.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.01)


_HARD_ENVS = {
    "black_k0": SGEnvironment.empty(),
    "flat_1e-3": SGEnvironment([[0.0, 0.0, 1.0]], [1.0e-3], [[1.0, 1.0, 1.0]]),
    "sharp_1e4": SGEnvironment([[0.3, 0.0, 0.95]], [1.0e4], [[50.0, 40.0, 30.0]]),
    "below_horizon": SGEnvironment([[0.0, 0.2, -1.0]], [30.0], [[5.0, 5.0, 5.0]]),
    "zero_amplitude": SGEnvironment([[0.0, 0.0, 1.0]], [3.0], [[0.0, 0.0, 0.0]]),
}


@pytest.mark.parametrize("case", list(_HARD_ENVS))
def test_hard_environments_stay_finite(rng, case):
    env = _HARD_ENVS[case]
    em = _emitter(env)
    n = 4096
    it = dr.zeros(mi.Interaction3f, n)
    ds, weight = em.sample_direction(it, mi.Point2f(rng.random((2, n)).astype(np.float32)))
    d = _unit(rng, n)
    values = [
        _np(weight),
        ds.pdf.numpy(),
        _emitter_eval(em, d),
        em.pdf_direction(it, _direction_sample(d)).numpy(),
    ]
    assert all(np.all(np.isfinite(v)) for v in values)
    assert all(np.all(v >= 0) for v in values)
    ref = env.eval(d)
    # float32 directions (and the emitter's to_world transform) are off by ~1e-7 each, which moves
    # the exponent λ(ξ·ω − 1) by up to λ‖ω − ξ‖·δ: the tolerance grows with it (δ = 1e-6)
    slack = np.zeros(len(d))
    for k in range(env.num_lobes):
        ax = env.axis[k] / np.linalg.norm(env.axis[k])
        slack = np.maximum(slack, float(env.sharpness[k]) * np.linalg.norm(d - ax, axis=1) * 1e-6)
    err = np.abs(_emitter_eval(em, d) - ref)
    assert np.all(err <= (2e-5 + slack)[:, None] * ref + 1e-6 * ref.max(initial=0.0)), err.max()
    ray, ray_weight = em.sample_ray(0.0, 0.5, mi.Point2f(0.3, 0.6), mi.Point2f(0.2, 0.7))
    assert np.all(np.isfinite(_np(ray_weight)))
    if env.num_lobes == 0 or case == "zero_amplitude":
        assert np.all(_np(weight) == 0) and np.all(ds.pdf.numpy() == 0)
    bsdf = {"type": "svbrdf", "roughness": 0.05, "normal": {"type": "rgb", "value": [0.2, 0.0, 0.98]}}
    for integrator in ("path", "direct"):
        img = _render(_plane_scene(_sgenvmap_dict(env), bsdf, integrator, res=8), spp=8)
        assert np.all(np.isfinite(img)) and np.all(img >= 0)
        if env.num_lobes == 0 or case == "zero_amplitude":
            assert np.all(img == 0)
        if case == "below_horizon":  # only the lobe's far tail (< e^-20) reaches the upper hemisphere
            assert img.max() < 1e-6


_XML_SCENE = """<scene version="3.0.0">
    <integrator type="{integrator}"/>
    <sensor type="perspective">
        <float name="fov" value="45"/>
        <transform name="to_world"><lookat origin="0, 0, 2.414" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="12"/><integer name="height" value="12"/></film>
        <sampler type="independent"><integer name="sample_count" value="8"/></sampler>
    </sensor>
    <emitter type="sgenvmap" id="env">
        <string name="axis" value="0 0 1, 0.6 0 0.8"/>
        <string name="sharpness" value="2, 300"/>
        <string name="amplitude" value="0.5 0.5 0.6, 20 18 15"/>
    </emitter>
    <shape type="rectangle" id="sample">
        <bsdf type="svbrdf" id="material">
            <rgb name="normal" value="0.1 -0.1 1"/>
            <rgb name="diffuse" value="0.4 0.3 0.2"/>
            <float name="specular" value="0.2"/>
            <float name="roughness" value="0.3"/>
        </bsdf>
    </shape>
</scene>"""


@pytest.mark.parametrize("integrator", ["path", "direct"])
def test_xml_scene_with_both_plugins_renders(integrator):
    scene = mi.load_string(_XML_SCENE.format(integrator=integrator))
    img = np.asarray(mi.render(scene), np.float64)
    assert img.shape == (12, 12, 3)
    assert np.all(np.isfinite(img)) and img.mean() > 0.01
    params = mi.traverse(scene)
    assert {"env.axis", "env.sharpness", "env.amplitude", "env.scale"} <= set(params.keys())
    assert "sample.bsdf.roughness.value" in params.keys()  # a nested BSDF is keyed by its shape


def test_prb_gradients_through_symbolic_lobe_loop():
    """Reverse-mode AD through a ``prb`` render with K = 12 (the dr.while_loop path).

    Radiance is homogeneous of degree 1 in the amplitudes and linear in ``scale``, so the same
    estimator must satisfy Σ μ·∂I/∂μ = scale·∂I/∂scale exactly, and ∂I/∂scale estimates I itself
    (different paths in PRB's replay: ~1% noise at 64 spp, tolerance 5%).
    """
    env = _random_env(np.random.default_rng(3), 12, lam_range=(1.0, 30.0))
    bsdf = {"type": "svbrdf", "roughness": 0.5}
    scene = _plane_scene(_sgenvmap_dict(env, id="env"), bsdf, "prb", res=8)
    params = mi.traverse(scene)
    keys = ("env.amplitude", "env.sharpness", "env.axis", "env.scale")
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    img = mi.render(scene, params, spp=64, seed=1)
    mean = dr.mean(img, axis=None)
    dr.backward(mean)
    grads = {key: np.asarray(dr.grad(params[key]).numpy(), np.float64) for key in keys}
    assert all(np.all(np.isfinite(g)) for g in grads.values())
    assert np.all(grads["env.amplitude"] >= 0) and grads["env.amplitude"].max() > 0
    assert np.abs(grads["env.sharpness"]).max() > 0 and np.abs(grads["env.axis"]).max() > 0
    euler = float(np.dot(params["env.amplitude"].numpy(), grads["env.amplitude"]))
    np.testing.assert_allclose(euler, grads["env.scale"][0], rtol=1e-4)
    np.testing.assert_allclose(grads["env.scale"][0], float(mean.array[0]), rtol=0.05)


# -- registration ---------------------------------------------------------------------------------
_IMPORT_AFTER_VARIANT = r"""
import sys
import mitsuba as mi
mi.set_variant(sys.argv[1])
import ebr_mitsuba  # registers the plugins for the variant already set
em = mi.load_string('<emitter version="3.0.0" type="sgenvmap"><string name="axis" value="0 0 1"/>'
                    '<string name="sharpness" value="2"/><string name="amplitude" value="1 1 1"/></emitter>')
bsdf = mi.load_file(sys.argv[2])
print(type(em).__name__, type(bsdf).__name__)
"""

_IMPORT_BEFORE_VARIANT = r"""
import sys
import ebr_mitsuba
assert "mitsuba" not in sys.modules, "import ebr_mitsuba imported Mitsuba"
scene = ebr_mitsuba.load_scene(sys.argv[2])
import mitsuba as mi
print(mi.variant(), type(scene).__name__)
"""


@pytest.mark.parametrize(
    "script, expected",
    [(_IMPORT_AFTER_VARIANT, "SGEnvMap SVBRDFBSDF"), (_IMPORT_BEFORE_VARIANT, "Scene")],
    ids=["set_variant_then_import", "import_then_load_scene"],
)
def test_plugins_register_whatever_the_import_order(tmp_path, variant, script, expected):
    """``mi.set_variant(...); import ebr_mitsuba`` registers both plugins for ``mi.load_file``;
    ``import ebr_mitsuba`` first imports no Mitsuba, and ``ebr_mitsuba.load_scene`` sets the
    variant and registers them (fresh interpreters: this one has them registered already)."""
    import subprocess
    import sys

    if script is _IMPORT_AFTER_VARIANT:
        xml = '<bsdf version="3.0.0" type="svbrdf"><float name="roughness" value="0.3"/></bsdf>'
    else:
        xml = (
            '<scene version="3.0.0"><emitter type="sgenvmap"><string name="axis" value="0 0 1"/>'
            '<string name="sharpness" value="2"/><string name="amplitude" value="1 1 1"/></emitter>'
            '<shape type="rectangle"><bsdf type="svbrdf"/></shape></scene>'
        )
    (tmp_path / "x.xml").write_text(xml)
    proc = subprocess.run(
        [sys.executable, "-c", script, variant, str(tmp_path / "x.xml")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split()[-len(expected.split()) :] == expected.split(), proc.stdout
