"""Issue 12 (1024² estimate in 15 s): the faster forms give the values of the forms they replace.

* :func:`ebr_mitsuba.imageio.linear_to_srgb` evaluates the sRGB inverse EOTF itself: the same
  float32 values as colour-science's ``eotf_inverse_sRGB``, and ``write_png`` does not import
  colour-science;
* :func:`ebr_mitsuba.imageio.fast_writes`: uncompressed EXRs (read back bit-exact by our reader,
  OpenEXR and Mitsuba's bundled one) and zlib level 1 PNGs (the same codes);
* ``unit_normal`` and the torch BRDF's ``_normalize`` without ``vector_norm``: the same normals
  and gradients.
"""

from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch

from ebr_mitsuba import imageio as io


def _colour():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour
    return colour


def test_linear_to_srgb_equals_colour_science_bit_for_bit(rng):
    x = np.concatenate(
        [
            rng.random(20000),
            rng.random(2000) * 0.01,
            [-0.5, 0.0, 1.0, io.SRGB_LINEAR_KNEE, 2.0, np.nan, np.inf],
        ]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        want = np.asarray(_colour().models.eotf_inverse_sRGB(x), np.float32)
    got = io.linear_to_srgb(x)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)


def test_srgb_png_codes_match_the_float64_encoding(tmp_path, rng):
    import mitsuba as mi

    img = rng.random((64, 48, 3)).astype(np.float32) * 1.2 - 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        enc = _colour().models.eotf_inverse_sRGB(np.clip(img.astype(np.float64), 0, 1))
    want = np.rint(enc * 255)
    io.write_png(tmp_path / "a.png", img)
    got = np.array(mi.Bitmap(str(tmp_path / "a.png"))).astype(np.float64)
    assert np.abs(got - want).max() <= 1
    assert np.count_nonzero(got != want) <= 2  # only values within 1e-6 of a rounding boundary


def test_writing_pngs_does_not_import_colour_science(tmp_path):
    code = (
        "import sys, numpy as np\n"
        "from ebr_mitsuba.imageio import write_png, linear_to_srgb\n"
        f"write_png({str(tmp_path / 'x.png')!r}, np.full((4, 4, 3), 0.5, np.float32))\n"
        "linear_to_srgb(np.zeros(3))\n"
        "print('colour' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_fast_writes_exr_uncompressed_and_readable_everywhere(tmp_path, rng):
    import mitsuba as mi
    import OpenEXR

    img = rng.standard_normal((33, 20, 3)).astype(np.float32)
    with io.fast_writes():
        io.write_exr(tmp_path / "fast.exr", img)
    io.write_exr(tmp_path / "zip.exr", img)
    for name, codec in (("fast", OpenEXR.NO_COMPRESSION), ("zip", OpenEXR.ZIP_COMPRESSION)):
        with OpenEXR.File(str(tmp_path / f"{name}.exr")) as f:
            assert f.header()["compression"] == codec
        np.testing.assert_array_equal(io.read_exr(tmp_path / f"{name}.exr"), img)
        np.testing.assert_array_equal(np.array(mi.Bitmap(str(tmp_path / f"{name}.exr"))), img)
    with pytest.raises(ValueError, match="compression"):
        io.write_exr(tmp_path / "bad.exr", img, compression="zstd")


def test_fast_writes_png_same_codes(tmp_path, rng):
    img = rng.random((40, 30, 3)).astype(np.float32)
    io.write_png(tmp_path / "a.png", img)
    with io.fast_writes():
        io.write_png(tmp_path / "b.png", img)
    np.testing.assert_array_equal(
        io.read_ldr(tmp_path / "a.png", "linear"), io.read_ldr(tmp_path / "b.png", "linear")
    )
    with pytest.raises(ValueError, match="level"):
        io.write_png(tmp_path / "c.png", img, level=0)


def test_fast_writes_is_scoped():
    assert not io._FAST_WRITES.get()
    with io.fast_writes():
        assert io._FAST_WRITES.get()
        with io.fast_writes(False):
            assert not io._FAST_WRITES.get()
        assert io._FAST_WRITES.get()
    assert not io._FAST_WRITES.get()


def test_unit_normal_equals_the_vector_norm_form():
    from ebr_mitsuba.nets.transforms import NORMAL_Z_MIN, unit_normal

    raw = torch.randn(2, 3, 17, 9, dtype=torch.float64, requires_grad=True)
    z = torch.nn.functional.softplus(raw[:, 2:3]) + NORMAL_Z_MIN
    n = torch.cat([raw[:, 0:2], z], dim=1)
    want = n / torch.linalg.vector_norm(n, dim=1, keepdim=True)
    got = unit_normal(raw)
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    w = torch.randn_like(want)
    (g_want,) = torch.autograd.grad((want * w).sum(), raw)
    (g_got,) = torch.autograd.grad((got * w).sum(), raw)
    torch.testing.assert_close(g_got, g_want, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("layout", ["contiguous", "permuted"])
def test_torch_brdf_normalize_equals_the_vector_norm_form(layout):
    from ebr_mitsuba.nets.torch_brdf import _normalize

    v = torch.randn(2, 3, 8, 5, dtype=torch.float64).permute(0, 2, 3, 1)
    if layout == "contiguous":
        v = v.contiguous()
    v.requires_grad_(True)
    want = v / torch.linalg.vector_norm(v, dim=-1, keepdim=True).clamp_min(1e-30)
    got = _normalize(v)
    torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12)
    w = torch.randn_like(want)
    (g_want,) = torch.autograd.grad((want * w).sum(), v)
    (g_got,) = torch.autograd.grad((got * w).sum(), v)
    torch.testing.assert_close(g_got, g_want, rtol=1e-10, atol=1e-12)


def _random_maps(rng, size: int):
    from ebr_mitsuba.svbrdf import SVBRDF

    n = rng.normal(size=(size, size, 3)).astype(np.float32)
    n[..., 2] = np.abs(n[..., 2]) + 0.2
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    rand = [rng.random((size, size, 3)).astype(np.float32) for _ in range(2)]
    return SVBRDF(n, rand[0], rand[1], rng.random((size, size)).astype(np.float32))


def test_ensemble_equals_the_numpy_mean_of_upsampled_maps(rng):
    from ebr_mitsuba.estimate.fullres import _Ensemble, _MapSum, upsample_maps
    from ebr_mitsuba.nets.maps import Maps

    members = [_random_maps(rng, s) for s in (32, 16, 8)]
    want = _MapSum(32)
    got = _Ensemble(32)
    for m in members:
        want.add(upsample_maps(m, 32))
    got.add_svbrdf(members[0])
    torch_maps = Maps(
        *(
            torch.from_numpy(np.ascontiguousarray((a if a.ndim == 3 else a[..., None]).transpose(2, 0, 1)))[
                None
            ]
            for a in (members[1].normal, members[1].diffuse, members[1].specular, members[1].roughness)
        )
    )
    got.add_maps(torch_maps)
    got.add_svbrdf(members[2])
    w, g = want.mean("a"), got.mean("b")
    for name in ("normal", "diffuse", "specular", "roughness"):
        np.testing.assert_allclose(getattr(g, name), getattr(w, name), rtol=0, atol=2e-6)


def test_add_shuffled_equals_pixel_shuffle_plus_skip():
    from ebr_mitsuba.estimate.fastnet import _add_shuffled, _shuffle_rows

    c, c_in = 4, 6
    w = torch.randn(4 * c, c_in)
    h = torch.randn(2, 5, 3, c_in)
    skip = torch.randn(2, 10, 6, c)
    y = torch.nn.functional.linear(h, w).permute(0, 3, 1, 2)  # (B, 4C, H, W), PixelShuffle order
    want = torch.nn.PixelShuffle(2)(y).permute(0, 2, 3, 1) + skip
    got = _add_shuffled(skip.clone(), torch.nn.functional.linear(h, _shuffle_rows(w)))
    torch.testing.assert_close(got, want, rtol=0, atol=1e-6)


def test_log_input_in_place_form_is_bit_identical():
    from ebr_mitsuba.nets.transforms import log_input

    x = torch.randn(2, 3, 7, 5) * 3
    want = torch.log(x.clamp_min(0.0) + 0.01)
    with torch.no_grad():
        torch.testing.assert_close(log_input(x), want, rtol=0, atol=0)
    torch.testing.assert_close(log_input(x), want, rtol=0, atol=0)
    xg = x.clone().requires_grad_(True)
    out = log_input(xg)
    torch.testing.assert_close(out, want, rtol=0, atol=0)
    out.sum().backward()
    torch.testing.assert_close(xg.grad, (x > 0).float() / (x.clamp_min(0.0) + 0.01), rtol=1e-6, atol=0)


@pytest.mark.parametrize(
    "shape,size",
    [
        ((64, 48, 3), (32, 24)),
        ((64, 48), (32, 48)),
        ((64, 48, 1), (64, 24)),
        ((30, 40, 3), (15, 10)),
        ((64, 64, 3), (16, 16)),
        ((33, 20, 3), (11, 10)),
    ],
)
def test_resize_area_block_path_equals_the_axis_path(rng, shape, size):
    a = (rng.random(shape) * 10 - 2).astype(np.float32)
    want = io._area_axis(io._area_axis(a, size[0], 0), size[1], 1).astype(np.float32)
    np.testing.assert_array_equal(io.resize_area(a, size), want)
    c = np.full(shape, 0.3, np.float32)
    np.testing.assert_array_equal(io.resize_area(c, size), np.full(want.shape, 0.3, np.float32))


@pytest.mark.parametrize("channels", [8, 16, 3])
def test_layer_norm_as_gemvs_equals_layer_norm(channels):
    from ebr_mitsuba.estimate.fastnet import _layer_norm_cl

    x = torch.randn(2, 9, 7, channels) * 3 + torch.randn(channels) * 4
    want = torch.nn.functional.layer_norm(x, (channels,), eps=1e-6)
    torch.testing.assert_close(_layer_norm_cl(x, 1e-6), want, rtol=1e-5, atol=2e-6)


def test_in_place_transforms_are_bit_identical_without_grad():
    from ebr_mitsuba.nets.transforms import NORMAL_Z_MIN, signed_log, unit_normal

    x = torch.randn(2, 3, 7, 5) * 3
    with torch.no_grad():
        torch.testing.assert_close(signed_log(x), torch.sign(x) * torch.log1p(x.abs() / 0.01), rtol=0, atol=0)
        z = torch.nn.functional.softplus(x[:, 2:3]) + NORMAL_Z_MIN
        n = torch.cat([x[:, 0:2], z], dim=1)
        want = n / torch.sqrt((n * n).sum(dim=1, keepdim=True))
        torch.testing.assert_close(unit_normal(x), want, rtol=0, atol=0)
    xg = x.clone().requires_grad_(True)
    torch.testing.assert_close(signed_log(xg), torch.sign(x) * torch.log1p(x.abs() / 0.01), rtol=0, atol=0)
    signed_log(xg).sum().backward()
    assert torch.isfinite(xg.grad).all()
