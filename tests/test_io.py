"""Image, material-directory and environment-map I/O (imageio, materials, envmap)."""

from __future__ import annotations

import json
import math
import shutil
import warnings

import numpy as np
import pytest

from ebr_mitsuba import envmap as em
from ebr_mitsuba import imageio as io
from ebr_mitsuba import materials as mat
from ebr_mitsuba.errors import InputError
from ebr_mitsuba.sgenv import SGEnvironment
from ebr_mitsuba.svbrdf import SVBRDF


def _colour():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour
    return colour


def _raises_naming(path, func, *args, match=None, **kwargs) -> str:
    """``func`` raises a one-line InputError that names ``path``; returns the message."""
    with pytest.raises(InputError) as info:
        func(*args, **kwargs)
    msg = str(info.value)
    assert str(path) in msg, msg
    assert "\n" not in msg
    if match is not None:
        assert match in msg, msg
    return msg


def _random_svbrdf(rng, h=12, w=16) -> SVBRDF:
    n = np.concatenate([rng.uniform(-0.6, 0.6, (h, w, 2)), np.ones((h, w, 1))], axis=-1)
    return SVBRDF(
        normal=n,
        diffuse=rng.random((h, w, 3)),
        specular=rng.random((h, w, 3)) * 0.5,
        roughness=rng.random((h, w)),
        source="random test material",
    )


def _write_png_codes(path, codes):
    """Write integer codes with an encoder independent of write_png (Pillow, or Mitsuba for
    16-bit RGB, which Pillow cannot write)."""
    from PIL import Image

    if codes.dtype == np.uint16 and codes.ndim == 3:
        import mitsuba as mi

        mi.Bitmap(codes, pixel_format=mi.Bitmap.PixelFormat.RGB).write(str(path))
    else:
        Image.fromarray(codes).save(path)


# -- EXR ----------------------------------------------------------------------------------------


def test_exr_round_trip_is_bit_exact(tmp_path, rng):
    rgb = (rng.standard_normal((7, 9, 3)) * 1e3).astype(np.float32)
    rgb[0, 0] = [0.0, -0.0, np.float32(1e-40)]  # signed zero and a denormal survive too
    io.write_exr(tmp_path / "rgb.exr", rgb)
    back = io.read_exr(tmp_path / "rgb.exr")
    assert back.dtype == np.float32 and back.shape == (7, 9, 3)
    assert back.tobytes() == rgb.tobytes()

    grey = rng.random((5, 4)).astype(np.float32)
    io.write_exr(tmp_path / "grey.exr", grey)
    back = io.read_image(tmp_path / "grey.exr")
    assert back.shape == (5, 4, 1) and back.tobytes() == grey.tobytes()

    io.write_exr(tmp_path / "depth.exr", grey, channels=("Z",))
    assert io.read_exr(tmp_path / "depth.exr", "Z").tobytes() == grey.tobytes()
    assert io.read_exr(tmp_path / "depth.exr").shape == (5, 4, 1)  # the only channel


def test_exr_half_channels_read_as_float32(tmp_path, rng):
    import OpenEXR

    half = (rng.random((6, 5, 3)) * 100).astype(np.float16)
    pixels = {c: np.ascontiguousarray(half[..., k]) for k, c in enumerate("RGB")}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, pixels) as f:
        f.write(str(tmp_path / "half.exr"))
    back = io.read_exr(tmp_path / "half.exr")
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back, half.astype(np.float32))


def test_exr_channel_selection_errors(tmp_path, rng):
    path = tmp_path / "ab.exr"
    io.write_exr(path, rng.random((3, 3, 2)).astype(np.float32), channels=("A1", "B1"))
    _raises_naming(path, io.read_exr, path, match="no R,G,B or Y")
    _raises_naming(path, io.read_exr, path, ("R",), match="no channel 'R'")
    assert io.read_exr(path, ("B1", "A1")).shape == (3, 3, 2)


# -- PNG / JPEG -------------------------------------------------------------------------------------


@pytest.mark.parametrize("bits,channels", [(8, 3), (8, 1), (16, 3), (16, 1)])
def test_png_decoding_matches_colour_science(tmp_path, rng, bits, channels):
    dtype = np.uint8 if bits == 8 else np.uint16
    top = 2**bits - 1
    shape = (16, 16, 3) if channels == 3 else (16, 16)
    codes = rng.integers(0, top + 1, size=shape).astype(dtype)
    codes.flat[:4] = [0, 1, top - 1, top]
    path = tmp_path / f"codes{bits}.png"
    _write_png_codes(path, codes)
    want = _colour().cctf_decoding(codes.astype(np.float64) / top, function="sRGB")
    got = io.read_ldr(path)
    assert got.dtype == np.float32 and got.shape == (16, 16, channels)
    np.testing.assert_allclose(got.reshape(want.shape), want, rtol=1e-6, atol=1e-9)
    lin = io.read_ldr(path, colorspace="linear")
    np.testing.assert_allclose(lin.reshape(codes.shape), codes / top, rtol=1e-6, atol=0)
    # full precision: every distinct code gives a distinct value (16-bit not cut to 8 bits)
    assert np.unique(got).size == np.unique(codes).size


@pytest.mark.parametrize("bits", [8, 16])
def test_write_png_round_trip_within_half_a_code(tmp_path, rng, bits):
    colour = _colour()
    img = rng.random((9, 11, 3)).astype(np.float32)
    top = 2**bits - 1
    io.write_png(tmp_path / "s.png", img, encode="srgb", bits=bits)
    back = io.read_ldr(tmp_path / "s.png", "srgb")
    enc_err = np.abs(
        colour.cctf_encoding(back.astype(np.float64), function="sRGB")
        - colour.cctf_encoding(img.astype(np.float64), function="sRGB")
    )
    assert enc_err.max() <= 0.5 / top + 1e-6
    io.write_png(tmp_path / "l.png", img[..., :1], encode="linear", bits=bits)
    back = io.read_ldr(tmp_path / "l.png", "linear", expect_channels=1)
    assert np.abs(back - img[..., :1]).max() <= 0.5 / top + 1e-6


def test_jpeg_grey_and_rgb(tmp_path, rng):
    from PIL import Image

    codes = rng.integers(0, 256, size=(8, 8)).astype(np.uint8)
    Image.fromarray(codes).save(tmp_path / "g.jpg", quality=100)
    decoded = np.asarray(Image.open(tmp_path / "g.jpg"))
    got = io.read_image(tmp_path / "g.jpg", "linear")
    assert got.shape == (8, 8, 1)
    np.testing.assert_allclose(got[..., 0], decoded / 255.0, rtol=1e-6)
    Image.fromarray(np.stack([codes] * 3, -1)).save(tmp_path / "c.jpeg")
    assert io.read_image(tmp_path / "c.jpeg").shape == (8, 8, 3)


# -- bad image files ----------------------------------------------------------------------------


def _truncate(src, dst, fraction=0.5):
    data = src.read_bytes()
    dst.write_bytes(data[: int(len(data) * fraction)])
    return dst


def test_bad_image_files_raise_one_line_input_errors(tmp_path, rng):
    import mitsuba as mi
    from PIL import Image

    for name in ("missing.exr", "missing.png", "missing.jpg", "missing.hdr"):
        _raises_naming(tmp_path / name, io.read_image, tmp_path / name, match="no such file")
    _raises_naming(tmp_path, io.read_image, tmp_path / "x.tif", match="unsupported image type")

    img = rng.random((64, 64, 3)).astype(np.float32)
    io.write_exr(tmp_path / "ok.exr", img)
    io.write_png(tmp_path / "ok.png", img)
    Image.fromarray((img * 255).astype(np.uint8)).save(tmp_path / "ok.jpg")
    mi.Bitmap(img, pixel_format=mi.Bitmap.PixelFormat.RGB).write(str(tmp_path / "ok.hdr"))
    # RGBE: 8-bit mantissas sharing the largest channel's exponent (values < 1: steps of 1/256)
    assert np.abs(io.read_image(tmp_path / "ok.hdr") - img).max() <= 1 / 128
    for name in ("ok.exr", "ok.png", "ok.jpg", "ok.hdr"):
        bad = _truncate(tmp_path / name, tmp_path / f"truncated{(tmp_path / name).suffix}")
        _raises_naming(bad, io.read_image, bad, match="cannot read")
    for suffix in (".exr", ".png", ".jpg", ".hdr"):
        junk = tmp_path / f"junk{suffix}"
        junk.write_bytes(b"not an image at all " * 10)
        _raises_naming(junk, io.read_image, junk, match="cannot read")

    io.write_exr(tmp_path / "grey.exr", img[..., 0])
    _raises_naming(
        tmp_path / "grey.exr", io.read_image, tmp_path / "grey.exr", expect_channels=3, match="has 1 channel"
    )
    _raises_naming(
        tmp_path / "ok.png", io.read_image, tmp_path / "ok.png", expect_channels=1, match="has 3 channels"
    )
    _raises_naming(
        tmp_path / "ok.exr", io.read_image, tmp_path / "ok.exr", expect_shape=(32, 64), match="expected 64x32"
    )
    img[3, 5, 1] = np.nan
    img[7, 1, 0] = np.inf
    io.write_exr(tmp_path / "nan.exr", img)
    _raises_naming(
        tmp_path / "nan.exr",
        io.read_image,
        tmp_path / "nan.exr",
        match="2 pixels NaN or Inf (first at row 3, column 5)",
    )
    assert np.isnan(io.read_image(tmp_path / "nan.exr", allow_nonfinite=True)[3, 5, 1])


# -- resampling -------------------------------------------------------------------------------------


@pytest.mark.parametrize("shape_in,shape_out", [((12, 8), (3, 4)), ((10, 7), (4, 3)), ((5, 6), (7, 9))])
def test_resize_area_is_the_exact_box_average(rng, shape_in, shape_out):
    img = rng.random(shape_in + (2,))
    # reference: replicate each texel to a common multiple, then average blocks
    ly, lx = (math.lcm(a, b) for a, b in zip(shape_in, shape_out))
    fine = np.repeat(np.repeat(img, ly // shape_in[0], axis=0), lx // shape_in[1], axis=1)
    ref = fine.reshape(shape_out[0], ly // shape_out[0], shape_out[1], lx // shape_out[1], 2).mean((1, 3))
    got = io.resize_area(img, shape_out)
    assert got.dtype == np.float32 and got.shape == shape_out + (2,)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-6)
    assert np.all(io.resize_area(np.full(shape_in, 0.3), shape_out) == np.float32(0.3))


# -- material directories ---------------------------------------------------------------------------


def test_material_dir_round_trip(tmp_path, rng):
    svbrdf = _random_svbrdf(rng)
    out = mat.save_material_dir(svbrdf, tmp_path / "m", meta={"licence": "CC0", "seed": 7})
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(
        ["material.json"]
        + [f"{m}.{e}" for m in ("normal", "diffuse", "specular", "roughness") for e in ("exr", "png")]
    )
    for name in ("normal", "diffuse", "specular", "roughness"):  # the files hold the exact maps
        stored = io.read_exr(out / f"{name}.exr")
        assert stored.tobytes() == getattr(svbrdf, name).reshape(stored.shape).tobytes(), name
    back = mat.load_material_dir(out)
    for name in ("diffuse", "specular", "roughness"):
        assert getattr(back, name).tobytes() == getattr(svbrdf, name).tobytes(), name
    # normals are renormalised on load (float32 renormalising is not idempotent: ≤ 2 ulp)
    np.testing.assert_allclose(back.normal, svbrdf.normal, rtol=0, atol=3e-7)
    meta = mat.load_material_meta(out)
    assert meta["format"] == mat.MATERIAL_FORMAT and meta["size"] == [12, 16]
    assert meta["licence"] == "CC0" and meta["seed"] == 7 and meta["source"] == "random test material"
    assert "OpenGL" in meta["conventions"]["normal"]

    # without the EXRs the PNG previews load as the same material, to 8-bit precision
    pngs = tmp_path / "pngs"
    shutil.copytree(out, pngs)
    for exr in pngs.glob("*.exr"):
        exr.unlink()
    approx = mat.load_material_dir(pngs)
    assert np.abs(approx.roughness - svbrdf.roughness).max() <= 0.5 / 255 + 1e-6
    assert np.abs(approx.diffuse - svbrdf.diffuse).max() <= 0.01  # sRGB step near 1
    assert np.abs(approx.normal - svbrdf.normal).max() <= 4 / 255

    with pytest.raises(FileExistsError):
        mat.save_material_dir(svbrdf, out, overwrite=False)
    with pytest.raises(ValueError):
        mat.save_material_dir(svbrdf, tmp_path / "x", meta={"format": "mine"})
    assert not (tmp_path / "x").exists()


def test_material_dir_png_normals_renormalised_and_directx_flip(tmp_path):
    h, w = 4, 4
    base = SVBRDF.uniform(h, w, roughness=0.5)
    out = mat.save_material_dir(base, tmp_path / "m")
    for exr in out.glob("*.exr"):
        exr.unlink()
    encoded = np.zeros((h, w, 3), np.float32)
    encoded[...] = [0.5, 0.8, 0.9]  # n = (0, 0.6, 0.8) before 8-bit rounding; |n| ≠ 1 after it
    io.write_png(out / "normal.png", encoded, encode="linear")
    gl = mat.load_material_dir(out)
    dx = mat.load_material_dir(out, normal_convention="directx")
    np.testing.assert_allclose(np.linalg.norm(gl.normal, axis=-1), 1.0, atol=1e-6)
    assert gl.normal[0, 0, 1] > 0.55 and dx.normal[0, 0, 1] < -0.55
    np.testing.assert_array_equal(dx.normal[..., 1], -gl.normal[..., 1])

    # an EXR normal of length 0.5 inside [-1, 1] is renormalised, not refused
    io.write_exr(out / "normal.exr", np.broadcast_to(np.float32([0.0, 0.3, 0.4]), (h, w, 3)))
    np.testing.assert_allclose(mat.load_material_dir(out).normal[0, 0], [0.0, 0.6, 0.8], atol=1e-6)


def test_bad_material_dirs_raise_input_errors_naming_the_file(tmp_path, rng):
    good = mat.save_material_dir(_random_svbrdf(rng, 4, 4), tmp_path / "good")

    def variant(name):
        d = tmp_path / name
        shutil.copytree(good, d)
        return d

    d = variant("rough")
    io.write_exr(d / "roughness.exr", np.full((4, 4), 1.5, np.float32))
    _raises_naming(d / "roughness.exr", mat.load_material_dir, d, match="outside [0, 1]")
    io.write_exr(d / "roughness.exr", np.full((4, 4), -0.2, np.float32))
    _raises_naming(d / "roughness.exr", mat.load_material_dir, d, match="roughness")
    io.write_exr(d / "roughness.exr", np.full((4, 4, 3), 0.5, np.float32))
    _raises_naming(d / "roughness.exr", mat.load_material_dir, d, match="has 3 channels")

    d = variant("json")
    (d / "material.json").write_text('{"format": "ebr-material/1", ')
    _raises_naming(d / "material.json", mat.load_material_dir, d, match="malformed JSON")
    (d / "material.json").write_text("[1, 2]")
    _raises_naming(d / "material.json", mat.load_material_dir, d, match="JSON object")
    (d / "material.json").write_text(json.dumps({"format": "other/2"}))
    _raises_naming(d / "material.json", mat.load_material_dir, d, match="'format'")

    d = variant("missing")
    (d / "specular.exr").unlink()
    (d / "specular.png").unlink()
    _raises_naming(d, mat.load_material_dir, d, match="no specular.exr")

    d = variant("size")
    io.write_exr(d / "diffuse.exr", np.full((4, 5, 3), 0.5, np.float32))
    _raises_naming(d / "diffuse.exr", mat.load_material_dir, d, match="resample")

    d = variant("nan")
    bad = np.full((4, 4, 3), 0.5, np.float32)
    bad[1, 2, 0] = np.nan
    io.write_exr(d / "diffuse.exr", bad)
    _raises_naming(d / "diffuse.exr", mat.load_material_dir, d, match="NaN")

    d = variant("inward")
    io.write_exr(d / "normal.exr", np.broadcast_to(np.float32([0.0, 0.6, -0.8]), (4, 4, 3)))
    _raises_naming(d / "normal.exr", mat.load_material_dir, d, match="z < 0")
    io.write_exr(d / "normal.exr", np.broadcast_to(np.float32([0.0, 0.0, 2.0]), (4, 4, 3)))
    _raises_naming(d / "normal.exr", mat.load_material_dir, d, match="outside [-1, 1]")

    _raises_naming(tmp_path / "nowhere", mat.load_material_dir, tmp_path / "nowhere")


def test_from_metal_rough_follows_gltf():
    base = np.array([[[0.8, 0.5, 0.2], [0.8, 0.5, 0.2], [0.1, 0.9, 0.3]]], np.float32)
    metal = np.array([[0.0, 1.0, 0.25]], np.float32)
    rough = np.array([[0.1, 0.5, 0.9]], np.float32)
    s = mat.from_metal_rough(base, metal, rough)
    np.testing.assert_allclose(s.diffuse[0, 0], [0.8, 0.5, 0.2], atol=1e-7)
    np.testing.assert_allclose(s.specular[0, 0], [0.04] * 3, atol=1e-7)
    np.testing.assert_allclose(s.diffuse[0, 1], [0.0] * 3, atol=1e-7)
    np.testing.assert_allclose(s.specular[0, 1], [0.8, 0.5, 0.2], atol=1e-7)
    np.testing.assert_allclose(s.diffuse[0, 2], np.array([0.1, 0.9, 0.3]) * 0.75, atol=1e-7)
    np.testing.assert_allclose(s.specular[0, 2], 0.04 * 0.75 + np.array([0.1, 0.9, 0.3]) * 0.25, atol=1e-7)
    np.testing.assert_array_equal(s.roughness, rough)
    np.testing.assert_array_equal(s.normal, np.broadcast_to([0, 0, 1], (1, 3, 3)))
    with pytest.raises(InputError, match="metalness"):
        mat.from_metal_rough(base, metal * 2, rough, source="tex")


def test_to_metal_rough_inverts_from_metal_rough():
    rng = np.random.default_rng(3)
    base = rng.uniform(0.0, 1.0, (6, 7, 3)).astype(np.float32)
    metal = rng.uniform(0.0, 1.0, (6, 7)).astype(np.float32)
    metal[0, :3] = [0.0, 1.0, 0.999]  # the ends: a dielectric, a pure metal, nearly one
    rough = rng.uniform(0.1, 0.9, (6, 7)).astype(np.float32)
    s = mat.from_metal_rough(base, metal, rough)
    got_base, got_metal = mat.to_metal_rough(s)
    np.testing.assert_allclose(got_metal, metal, atol=1e-4)
    np.testing.assert_allclose(got_base, base, atol=1e-3)
    # an estimate no metal/rough set made: a specular map below 0.04 reads as a dielectric
    dull = SVBRDF.uniform(2, 2, diffuse=(0.5, 0.4, 0.3), specular=0.02)
    b, m = mat.to_metal_rough(dull)
    np.testing.assert_array_equal(m, 0.0)
    np.testing.assert_allclose(b, np.broadcast_to([0.5, 0.4, 0.3], (2, 2, 3)), atol=1e-6)


def test_metal_rough_rmse_compares_the_metal_rough_reading():
    from ebr_mitsuba.metrics import metal_rough_rmse

    base = np.full((4, 4, 3), 0.6, np.float32)
    rough = np.full((4, 4), 0.4, np.float32)
    a = mat.from_metal_rough(base, np.zeros((4, 4), np.float32), rough)
    b = mat.from_metal_rough(base, np.full((4, 4), 0.5, np.float32), rough)
    same = metal_rough_rmse(a, a)
    assert same == {"base colour": 0.0, "metallic": 0.0}
    out = metal_rough_rmse(b, a)
    assert out["metallic"] == pytest.approx(0.5, abs=1e-4)
    assert out["base colour"] == pytest.approx(0.0, abs=1e-3)


# -- shared texture sets --------------------------------------------------------------------------


def _integrability(normal: np.ndarray) -> float:
    """Correlation of ∂p/∂y with ∂q/∂x for slopes p = n_x/n_z, q = n_y/n_z (y up = row 0).

    A height field has p_y = q_x; a normal map with its y axis flipped has p_y = −q_x. So the
    correlation is clearly positive for correctly oriented (OpenGL) normals, negative if flipped.
    """
    p = normal[..., 0] / normal[..., 2]
    q = normal[..., 1] / normal[..., 2]
    p_y = -(p[2:, 1:-1] - p[:-2, 1:-1])
    q_x = q[1:-1, 2:] - q[1:-1, :-2]
    return float(np.corrcoef(p_y.ravel(), q_x.ravel())[0, 1])


@pytest.mark.parametrize("name", ["wood_floor", "painted_plaster_wall"])
def test_poly_haven_sets(data_dir, name):
    s = mat.load_texture_set(data_dir / "materials" / name, size=128)
    assert s.shape == (128, 128) and s.source.endswith(name)
    assert 0.02 < float(s.diffuse.mean()) < 0.6  # linear albedo of wood / plaster
    # dielectrics (arm B ≈ 0): F₀ ≈ 0.04 almost everywhere
    assert abs(float(np.median(s.specular)) - 0.04) < 0.005
    assert 0.2 < float(s.roughness.mean()) < 1.0
    assert abs(float(s.normal[..., :2].mean())) < 0.02 and float(s.normal[..., 2].mean()) > 0.95
    assert _integrability(s.normal) > 0.1


def test_ambientcg_metal_directx_normals_come_out_opengl(data_dir):
    folder = data_dir / "materials" / "Metal009"
    s = mat.load_texture_set(folder, size=256)
    assert s.shape == (256, 256)
    assert float(s.diffuse.max()) < 1e-6  # metalness 1 everywhere: no diffuse
    assert 0.2 < float(s.specular.mean()) < 0.4  # F₀ = base colour (sRGB ~148/255 → 0.30)
    assert 0.3 < float(s.roughness.mean()) < 0.6
    assert _integrability(s.normal) > 0.1
    raw = io.resize_area(io.read_image(next(folder.glob("*_Normal.jpg")), "linear"), (256, 256))
    as_if_opengl = mat.decode_normals(raw, "raw", "opengl", encoded=True)
    assert _integrability(as_if_opengl) < -0.1  # the test tells the two conventions apart


def test_texture_set_errors(tmp_path, data_dir):
    _raises_naming(tmp_path, mat.load_texture_set, tmp_path, match="no base-colour texture")
    dup = tmp_path / "dup"
    dup.mkdir()
    for f in (data_dir / "materials" / "wood_floor").iterdir():
        shutil.copy(f, dup / f.name)
    shutil.copy(dup / "wood_floor_diff_1k.jpg", dup / "wood_floor_diff_2k.jpg")
    _raises_naming(dup, mat.load_texture_set, dup, match="several basecolor")


def test_load_material_dispatches(tmp_path, rng, data_dir):
    saved = mat.save_material_dir(_random_svbrdf(rng, 8, 8), tmp_path / "m")
    assert mat.load_material(saved, size=4).shape == (4, 4)
    assert mat.load_material(data_dir / "materials" / "wood_floor", size=(32, 64)).shape == (32, 64)


# -- environment maps -------------------------------------------------------------------------------


def test_direction_uv_helpers_and_frame():
    rng = np.random.default_rng(5)
    uv = np.stack([rng.random(500), 0.01 + 0.98 * rng.random(500)], -1)
    d = em.uv_to_direction(uv)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(em.direction_to_uv(d), uv, atol=1e-12)
    # the frame: zenith row is +z; u = 0 → +y, 0.25 → +x, 0.5 → −y, 0.75 → −x
    np.testing.assert_allclose(
        em.uv_to_direction([[0.3, 0.0], [0.0, 0.5], [0.25, 0.5], [0.5, 0.5], [0.75, 0.5], [0.9, 1.0]]),
        [[0, 0, 1], [0, 1, 0], [1, 0, 0], [0, -1, 0], [-1, 0, 0], [0, 0, -1]],
        atol=1e-12,
    )
    m = rng.normal(size=(10, 3))
    np.testing.assert_allclose(em.world_to_map(em.map_to_world(m)), m, atol=1e-15)
    np.testing.assert_allclose(em.map_to_world([0, 1, 0]), [0, 0, 1])
    t = np.array(em.envmap_to_world().matrix)
    np.testing.assert_array_equal(t, em.ENVMAP_TO_WORLD)
    dirs = em.equirect_directions(5, 10)
    np.testing.assert_allclose(dirs[0], np.broadcast_to([0, 0, 1], (10, 3)), atol=1e-12)
    np.testing.assert_allclose(dirs[2, :, 2], 0.0, atol=1e-12)  # v = 1/2: horizon
    omega = em.equirect_solid_angles(5, 10)
    assert omega.min() > 0
    assert abs(float(omega.sum()) - 4 * math.pi) < 1e-12


def _mitsuba_env_eval(emitter_dict, directions):
    """Radiance of the scene's environment emitter seen along world ``directions`` (N, 3)."""
    import drjit as dr
    import mitsuba as mi

    scene = mi.load_dict({"type": "scene", "env": emitter_dict})
    d = np.asarray(directions, np.float32).reshape(-1, 3)
    si = dr.zeros(mi.SurfaceInteraction3f, d.shape[0])
    si.wi = mi.Vector3f(-d[:, 0], -d[:, 1], -d[:, 2])  # escaped rays evaluate at −wi
    return np.array(scene.environment().eval(si)).T


def test_envmap_convention_matches_mitsuba_eval():
    h, w = 16, 32
    # one bright texel: seen at its own direction, not at its neighbours'
    spike = np.zeros((h, w, 3), np.float32)
    spike[5, 7] = [1000.0, 500.0, 250.0]
    dirs = em.equirect_directions(h, w)
    got = _mitsuba_env_eval(em.envmap_emitter_dict(spike), dirs).reshape(h, w, 3)
    np.testing.assert_allclose(got[5, 7], spike[5, 7], rtol=1e-4)
    got[5, 7] = 0
    assert np.abs(got).max() < 1e-3  # 1e-6 of the spike: the neighbours' texel positions see 0

    # a random map (constant pole rows: a pole is one direction): every texel position
    rng = np.random.default_rng(11)
    data = rng.random((h, w, 3)).astype(np.float32)
    data[0], data[-1] = data[0, 0], data[-1, 0]
    emitter = em.envmap_emitter_dict(data, scale=2.0)
    got = _mitsuba_env_eval(emitter, dirs).reshape(h, w, 3)
    np.testing.assert_allclose(got, 2.0 * data, rtol=0, atol=2e-5)  # half-pixel rows: 0.87
    # between texels, Mitsuba's interpolation equals EquirectMap.eval (the numpy reference)
    r = rng.normal(size=(2000, 3))
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    np.testing.assert_allclose(
        _mitsuba_env_eval(emitter, r), 2.0 * em.EquirectMap(data).eval(r), rtol=0, atol=5e-5
    )


def test_sg_to_equirect_reproduces_the_sg_environment():
    env = SGEnvironment(
        axis=[[0.3, -0.2, 0.9], [-0.7, 0.5, 0.1], [0.0, 0.1, -1.0]],
        sharpness=[4.0, 2.0, 1.0],
        amplitude=[[3.0, 2.0, 1.0], [0.5, 1.0, 1.5], [0.2, 0.2, 0.2]],
    )
    h, w = 64, 128
    data = em.sg_to_equirect(env, h, w)
    assert data.dtype == np.float32 and data.shape == (h, w, 3)
    np.testing.assert_allclose(data, env.eval(em.equirect_directions(h, w)), rtol=1e-6)
    rng = np.random.default_rng(3)
    r = rng.normal(size=(2000, 3))
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    got = _mitsuba_env_eval(em.envmap_emitter_dict(data), r)
    # bilinear interpolation error of the rasterised lobes (λ ≤ 4 on a 64×128 map; measured
    # 0.0038): below 1/3 % of the peak amplitude, against the numpy SG and the sgenvmap emitter
    assert np.abs(got - env.eval(r)).max() < 0.01
    from ebr_mitsuba.scene import sg_emitter_dict

    assert np.abs(got - _mitsuba_env_eval(sg_emitter_dict(env), r)).max() < 0.01
    # and the lobe's peak is where the SG axis points (world z-up, not Mitsuba's y-up)
    i, j = np.unravel_index(np.argmax(data[..., 0]), (h, w))
    peak = em.equirect_directions(h, w)[i, j]
    assert float(peak @ env.axis[0]) > math.cos(2 * math.pi / w * 1.5)


def test_load_equirect_on_shared_maps(data_dir):
    for path in sorted((data_dir / "envmaps").glob("*_1k.hdr")):
        m = em.load_equirect(path)
        assert m.shape == (512, 1024) and m.data.dtype == np.float32
        assert float(m.data.min()) >= 0 and float(m.data.max()) > 1.0
    sun = em.load_equirect(data_dir / "envmaps" / "venice_sunset_1k.hdr")
    assert 1e3 < float(sun.data.max()) < 1e4  # the sun, README: ~6.5e3
    exr = em.load_equirect(data_dir / "envmaps" / "physg_envmap3_venice_sunset_500x250.exr")
    assert exr.shape == (250, 500)
    # the file-based emitter shows the file's texels at their texel positions
    sub = (slice(1, None, 37), slice(None, None, 41))
    got = _mitsuba_env_eval(
        em.envmap_emitter_dict(data_dir / "envmaps" / "forest_slope_1k.hdr"),
        em.equirect_directions(512, 1024)[sub],
    )
    ref = em.load_equirect(data_dir / "envmaps" / "forest_slope_1k.hdr").data[sub].reshape(-1, 3)
    np.testing.assert_allclose(got, ref, rtol=2e-3, atol=1e-5)


def test_bad_environment_maps(tmp_path):
    io.write_png(tmp_path / "env.png", np.ones((4, 8, 3)))
    _raises_naming(tmp_path / "env.png", em.load_equirect, tmp_path / "env.png", match=".exr or .hdr")
    io.write_exr(tmp_path / "square.exr", np.ones((8, 8, 3), np.float32))
    _raises_naming(tmp_path / "square.exr", em.load_equirect, tmp_path / "square.exr", match="2:1")
    io.write_exr(tmp_path / "neg.exr", np.full((4, 8, 3), -1.0, np.float32))
    _raises_naming(tmp_path / "neg.exr", em.load_equirect, tmp_path / "neg.exr", match="negative")
    io.write_exr(tmp_path / "grey.exr", np.ones((4, 8), np.float32))
    _raises_naming(tmp_path / "grey.exr", em.load_equirect, tmp_path / "grey.exr", match="1 channel")
    with pytest.raises(InputError, match="scale"):
        em.envmap_emitter_dict(np.ones((4, 8, 3)), scale=float("nan"))
