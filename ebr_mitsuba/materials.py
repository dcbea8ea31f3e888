"""Material directories and imported texture sets → :class:`~ebr_mitsuba.svbrdf.SVBRDF`.

Material directory (``docs/conventions.md``, "Maps")
-------------------------------------
==================  ==========================================================================
file                content
==================  ==========================================================================
``normal.exr``      (H, W, 3) tangent-space unit normals in [-1, 1], OpenGL (+Y up = row 0)
``diffuse.exr``     (H, W, 3) linear RGB albedo d in [0, 1] (BRDF term d/π)
``specular.exr``    (H, W, 3) linear RGB F₀ in [0, 1]
``roughness.exr``   (H, W) one channel ``Y`` in [0, 1] (α = r²)
``*.png``           8-bit previews written beside the EXRs (normal as (n+1)/2 and roughness
                    linear, diffuse/specular sRGB-encoded); read only when the EXR is absent
``material.json``   ``{"format": "ebr-material/1", "size": [H, W], "conventions": {...},
                    "source": ..., "licence": ...}`` plus any caller metadata
==================  ==========================================================================

:func:`load_material_dir` reads EXR (or PNG/JPEG when the EXR is absent: normals decoded
linearly as 2v − 1, albedo PNGs decoded with ``albedo_colorspace``), flips the green channel for
``normal_convention="directx"``, renormalises non-unit normals, and raises
:class:`~ebr_mitsuba.errors.InputError` naming the file for a missing map, maps of different
sizes, values outside [0, 1] (normals: [-1, 1] with z ≥ 0) and a malformed ``material.json``.
:func:`save_material_dir` writes the whole directory atomically.

Imported texture sets (glTF metallic/roughness)
-----------------------------------------------
:func:`load_texture_set` reads the layouts of the shared assets (``data/README.md``):

=============  ==========================================  ===================================
layout         files (stem suffix)                          meaning
=============  ==========================================  ===================================
Poly Haven     ``_diff_1k``, ``_nor_gl_1k`` / ``_nor_dx_1k``,  base colour (sRGB), normal, packed
               ``_arm_1k`` (or ``_rough_1k`` + ``_metal_1k``)  R = AO (unused), G = roughness,
                                                            B = metalness (linear)
ambientCG      ``_Color``, ``_NormalGL`` / ``_Normal`` /     base colour (sRGB), normal (plain
               ``_NormalDX``, ``_Roughness``, ``_Metalness``  ``_Normal`` is DirectX), roughness,
                                                            metalness (absent: 0)
=============  ==========================================  ===================================

and converts them with :func:`from_metal_rough`: diffuse = base·(1 − m), F₀ = lerp(0.04, base, m),
roughness as is (glTF's perceptual roughness is our r, α = r²). ``size`` resamples the converted
maps by area averaging (:func:`ebr_mitsuba.imageio.resize_area`). :func:`load_material` picks
between a material directory and a texture set.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np

from .errors import ConfigError, InputError
from .fsutil import atomic_dir, atomic_write_text
from .imageio import read_image, resize_area, write_exr, write_png
from .svbrdf import MAP_NAMES, SVBRDF

MATERIAL_FORMAT = "ebr-material/1"
NORMAL_CONVENTIONS = ("opengl", "directx")
DIELECTRIC_F0 = 0.04
_RANGE_TOL = 1e-4  # as SVBRDF: values this far outside [0, 1] are rounding, clipped there
_NORMAL_TOL = 1e-3
_LDR_SUFFIXES = (".png", ".jpg", ".jpeg")

CONVENTIONS = {
    "frame": "tangent space: +x tangent, +y bitangent, +z geometric normal; row 0 of every map "
    "is the top of the sample (+y)",
    "normal": "unit vectors, OpenGL (+Y up); EXR stores n in [-1, 1]; normal.png stores (n+1)/2 linear",
    "diffuse": "linear RGB albedo d in [0, 1], BRDF term d/pi; diffuse.png is sRGB-encoded",
    "specular": "linear RGB Schlick F0 in [0, 1]; specular.png is sRGB-encoded",
    "roughness": "one channel r in [0, 1], GGX alpha = r^2 (clamped to >= 0.03 in the BRDF); "
    "roughness.png is linear",
}
_RESERVED_KEYS = ("format", "size", "conventions", "maps")


# -- helpers ------------------------------------------------------------------------------------


def _check_normal_convention(convention: str) -> None:
    if convention not in NORMAL_CONVENTIONS:
        raise ConfigError(
            f"unknown normal convention {convention!r}; use 'opengl' (+Y up) or "
            f"'directx' (+Y down, green flipped)"
        )


def _parse_size(size) -> tuple[int, int] | None:
    if size is None:
        return None
    if isinstance(size, (int, np.integer)):
        size = (int(size), int(size))
    try:
        h, w = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ConfigError(f"map size {size!r}; give an int or (height, width)") from None
    if h < 1 or w < 1:
        raise ConfigError(f"map size {size!r}; give positive numbers")
    return h, w


def _check_range(
    values: np.ndarray, path, name: str, lo: float = 0.0, hi: float = 1.0, tol: float = _RANGE_TOL
) -> None:
    vmin, vmax = float(values.min()), float(values.max())
    if vmin < lo - tol or vmax > hi + tol:
        raise InputError(
            f"{path}: {name} values lie in [{vmin:.4g}, {vmax:.4g}], outside "
            f"[{lo:g}, {hi:g}]; clip or rescale the {name} map"
        )


# Lowest z a repaired normal keeps (about 87° from the geometric normal).
_MIN_REPAIRED_Z = 0.05


def decode_normals(
    normal: np.ndarray, path, convention: str = "opengl", encoded: bool = False, repair: bool = False
) -> np.ndarray:
    """Tangent-space normals (H, W, 3) → unit OpenGL normals, float32.

    ``encoded``: values are (n+1)/2 in [0, 1] (PNG/JPEG) and decode as 2v − 1. ``directx`` flips
    the green (y) component. Components outside [-1, 1], z < 0 or zero length raise an
    :class:`InputError` naming ``path``; other non-unit normals are renormalised. ``repair``
    (for lossy JPEG texture sets, whose compression puts a few texels below the surface) raises
    z to at least 0.05 instead of refusing.
    """
    _check_normal_convention(convention)
    n = np.asarray(normal, dtype=np.float32)
    if encoded:
        n = n * 2.0 - 1.0
    _check_range(n, path, "normal", -1.0, 1.0, tol=_NORMAL_TOL)
    if convention == "directx":
        n = n * np.array([1.0, -1.0, 1.0], np.float32)
    if repair:
        n = n.copy()
        n[..., 2] = np.maximum(n[..., 2], _MIN_REPAIRED_Z)
    if float(n[..., 2].min()) < 0.0:
        count = int((n[..., 2] < 0).sum())
        raise InputError(
            f"{path}: {count} normals point into the surface (z < 0); give a tangent-space normal map"
        )
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    if float(length.min()) < 1e-6:
        raise InputError(f"{path}: the normal map has zero-length normals; fix the map")
    return (n / length).astype(np.float32)


# -- material directories -------------------------------------------------------------------------


def _map_file(directory: Path, name: str) -> Path:
    for suffix in (".exr",) + _LDR_SUFFIXES:
        candidate = directory / f"{name}{suffix}"
        if candidate.is_file():
            return candidate
    raise InputError(
        f"{directory}: no {name}.exr (or {name}.png); a material directory needs "
        f"{', '.join(f'{m}.exr' for m in MAP_NAMES)}"
    )


def load_material_meta(path: str | os.PathLike) -> dict:
    """The parsed ``material.json`` of a material directory ({} when the file is absent)."""
    file = Path(path) / "material.json"
    if not file.is_file():
        return {}
    try:
        meta = json.loads(file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(
            f"{file}: malformed JSON ({getattr(exc, 'msg', exc)}); fix the file or delete it"
        ) from None
    if not isinstance(meta, dict):
        raise InputError(
            f'{file}: expected a JSON object {{"format": "{MATERIAL_FORMAT}", ...}}, '
            f"got a {type(meta).__name__}"
        )
    if meta.get("format", MATERIAL_FORMAT) != MATERIAL_FORMAT:
        raise InputError(
            f"{file}: 'format' is {meta.get('format')!r}; this version reads \"{MATERIAL_FORMAT}\""
        )
    return meta


def load_material_dir(
    path: str | os.PathLike, albedo_colorspace: str = "srgb", normal_convention: str = "opengl"
) -> SVBRDF:
    """Read a material directory (see the module docstring) as an :class:`SVBRDF`.

    ``albedo_colorspace`` ("srgb" | "linear") decodes diffuse/specular PNGs (ignored for EXR);
    ``normal_convention`` ("opengl" | "directx") says how the stored normals' y points.
    """
    directory = Path(path)
    if not directory.is_dir():
        raise InputError(
            f"{directory}: no such material directory; give a directory with "
            f"{', '.join(f'{m}.exr' for m in MAP_NAMES)}"
        )
    _check_normal_convention(normal_convention)
    load_material_meta(directory)  # validates material.json when present
    files = {name: _map_file(directory, name) for name in MAP_NAMES}
    maps = {}
    f = files["normal"]
    ldr = f.suffix.lower() in _LDR_SUFFIXES
    raw = read_image(f, "linear", expect_channels=3)
    maps["normal"] = decode_normals(raw, f, normal_convention, encoded=ldr)
    for name in ("diffuse", "specular"):
        f = files[name]
        maps[name] = read_image(f, albedo_colorspace, expect_channels=3)
        _check_range(maps[name], f, name)
    f = files["roughness"]
    maps["roughness"] = read_image(f, "linear", expect_channels=1)[..., 0]
    _check_range(maps["roughness"], f, "roughness")
    shape = maps["normal"].shape[:2]
    for name in ("diffuse", "specular", "roughness"):
        if maps[name].shape[:2] != shape:
            h, w = maps[name].shape[:2]
            raise InputError(
                f"{files[name]}: is {w}x{h} but {files['normal'].name} is "
                f"{shape[1]}x{shape[0]}; resample the maps to one size"
            )
    return SVBRDF(source=str(directory), **maps)


def save_material_dir(
    svbrdf: SVBRDF, path: str | os.PathLike, meta: dict | None = None, overwrite: bool = True
) -> Path:
    """Write ``svbrdf`` as a material directory (four EXRs, PNG previews, ``material.json``).

    ``meta`` adds keys to ``material.json`` (e.g. ``source``, ``licence``; the reserved keys
    format/size/conventions/maps cannot be set). The directory appears complete or not at all
    (:func:`ebr_mitsuba.fsutil.atomic_dir`); an existing one is replaced unless
    ``overwrite=False`` (then ``FileExistsError``). Returns the path.
    """
    meta = dict(meta or {})
    clash = [k for k in _RESERVED_KEYS if k in meta]
    if clash:
        raise ValueError(f"save_material_dir: meta may not set {', '.join(clash)}")
    h, w = svbrdf.shape
    doc = {
        "format": MATERIAL_FORMAT,
        "size": [h, w],
        "maps": {name: f"{name}.exr" for name in MAP_NAMES},
        "conventions": CONVENTIONS,
        "source": meta.pop("source", svbrdf.source),
        "licence": meta.pop("licence", "unknown"),
        **meta,
    }
    text = json.dumps(doc, indent=1) + "\n"  # fails before anything is written if meta is not JSON
    path = Path(path)
    with atomic_dir(path, overwrite=overwrite) as tmp:
        write_exr(tmp / "normal.exr", svbrdf.normal)
        write_exr(tmp / "diffuse.exr", svbrdf.diffuse)
        write_exr(tmp / "specular.exr", svbrdf.specular)
        write_exr(tmp / "roughness.exr", svbrdf.roughness)
        write_png(tmp / "normal.png", svbrdf.encoded_normal(), encode="linear")
        write_png(tmp / "diffuse.png", svbrdf.diffuse, encode="srgb")
        write_png(tmp / "specular.png", svbrdf.specular, encode="srgb")
        write_png(tmp / "roughness.png", svbrdf.roughness, encode="linear")
        atomic_write_text(tmp / "material.json", text)
    return path


def resample_svbrdf(svbrdf: SVBRDF, size: int | tuple[int, int]) -> SVBRDF:
    """All four maps area-averaged to ``size`` (int: square, or (height, width)); normals are
    averaged as vectors and renormalised."""
    target = _parse_size(size)
    if target == svbrdf.shape:
        return svbrdf
    return SVBRDF(
        normal=resize_area(svbrdf.normal, target),
        diffuse=resize_area(svbrdf.diffuse, target),
        specular=resize_area(svbrdf.specular, target),
        roughness=resize_area(svbrdf.roughness, target),
        source=svbrdf.source,
    )


# -- glTF metallic/roughness ------------------------------------------------------------------------


def _scalar_map(values, name: str, source: str) -> np.ndarray:
    a = np.asarray(values, dtype=np.float32)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if a.ndim != 2:
        raise InputError(f"{source}: {name} map has shape {np.shape(values)}; expected (H, W) or (H, W, 1)")
    return a


def from_metal_rough(
    basecolor: np.ndarray,
    metallic: np.ndarray,
    roughness: np.ndarray,
    normal: np.ndarray | None = None,
    source: str = "<memory>",
) -> SVBRDF:
    """Convert glTF metallic/roughness maps to our SVBRDF.

    ``basecolor`` (H, W, 3) linear RGB in [0, 1]; ``metallic`` and ``roughness`` (H, W) or
    (H, W, 1) in [0, 1]; ``normal`` (H, W, 3) decoded unit OpenGL normals (None: flat +z).
    diffuse = base·(1 − m); specular F₀ = 0.04·(1 − m) + base·m; roughness unchanged.
    """
    base = np.asarray(basecolor, dtype=np.float32)
    if base.ndim != 3 or base.shape[2] != 3:
        raise InputError(f"{source}: base colour has shape {base.shape}; expected (H, W, 3)")
    m = _scalar_map(metallic, "metalness", source)
    r = _scalar_map(roughness, "roughness", source)
    for name, arr in (("base colour", base), ("metalness", m), ("roughness", r)):
        if arr.shape[:2] != base.shape[:2]:
            raise InputError(
                f"{source}: {name} map is {arr.shape[1]}x{arr.shape[0]} but the base colour "
                f"is {base.shape[1]}x{base.shape[0]}; resample the maps to one size"
            )
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{source}: {name} map has NaN or Inf values; fix the map")
        _check_range(arr, source, name)
    m3 = np.clip(m, 0.0, 1.0)[..., None]
    diffuse = base * (1.0 - m3)
    specular = DIELECTRIC_F0 * (1.0 - m3) + base * m3
    if normal is None:
        normal = np.broadcast_to(np.array([0.0, 0.0, 1.0], np.float32), base.shape).copy()
    return SVBRDF(normal=normal, diffuse=diffuse, specular=specular, roughness=r, source=source)


def to_metal_rough(maps: SVBRDF) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`from_metal_rough`: ``(basecolor (H, W, 3), metallic (H, W))`` in [0, 1].

    One metalness per pixel from the luminances D of the diffuse and S of the specular map:
    S·(1 − m) = 0.04·(1 − m)² + D·m, the positive root, m = 0 where S ≤ 0.04 (a dielectric or a
    specular map below any metal's). Base colour from the diffuse map, D / (1 − m), blended towards
    the specular map's (S − 0.04·(1 − m)) / m with weight m² (the diffuse map carries nothing at
    m → 1). Exact on maps that :func:`from_metal_rough` made; for other maps (an estimate) the
    closest metal/rough reading, clipped to [0, 1].
    """
    from .colour import LUMINANCE_WEIGHTS

    w = np.asarray(LUMINANCE_WEIGHTS, np.float64)
    d = maps.diffuse.astype(np.float64)
    s = maps.specular.astype(np.float64)
    lum_d, lum_s = d @ w, s @ w
    a = DIELECTRIC_F0
    b = lum_d + lum_s - 2.0 * a
    c = a - lum_s
    root = (-b + np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))) / (2.0 * a)
    m = np.where(lum_s > a, np.clip(root, 0.0, 1.0), 0.0)
    m3 = m[..., None]
    from_diffuse = d / np.maximum(1.0 - m3, 1e-6)
    from_specular = (s - a * (1.0 - m3)) / np.maximum(m3, 1e-6)
    base = from_diffuse * (1.0 - m3**2) + from_specular * m3**2
    return np.clip(base, 0.0, 1.0).astype(np.float32), m.astype(np.float32)


# -- texture sets ---------------------------------------------------------------------------------

# role → stem patterns (Poly Haven ``name_role_1k``, ambientCG ``Name_2K_Role``)
_TEXTURE_ROLES = {
    "basecolor": (r"_diff_\d+k$", r"_Color$"),
    "normal_gl": (r"_nor_gl_\d+k$", r"_NormalGL$"),
    "normal_dx": (r"_nor_dx_\d+k$", r"_Normal$", r"_NormalDX$"),
    "arm": (r"_arm_\d+k$",),
    "roughness": (r"_rough_\d+k$", r"_Roughness$"),
    "metalness": (r"_metal_\d+k$", r"_Metalness$"),
}


def _find_textures(directory: Path) -> dict[str, Path]:
    files = sorted(p for p in directory.iterdir() if p.is_file() and p.suffix.lower() in _LDR_SUFFIXES)
    found: dict[str, Path] = {}
    for role, patterns in _TEXTURE_ROLES.items():
        hits = [p for p in files if any(re.search(pat, p.stem) for pat in patterns)]
        if len(hits) > 1:
            raise InputError(
                f"{directory}: several {role} textures ({', '.join(p.name for p in hits)}); "
                f"keep one texture set per directory"
            )
        if hits:
            found[role] = hits[0]
    return found


TEXTURE_INDEX_FORMAT = "ebr-texture-sets/1"
TEXTURE_INDEX = "index.json"


def read_texture_index(path: str | os.PathLike) -> dict:
    """The ``sets`` table of a texture-set index (``materials_extra/index.json``, format
    ``ebr-texture-sets/1``): ``{name: {"class", "maps": {role: file}, "normal_convention",
    "albedo_colorspace", "metalness_constant"?, ...}}``."""
    file = Path(path)
    try:
        doc = json.loads(file.read_text())
    except FileNotFoundError:
        raise InputError(f"{file}: no such texture-set index") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{file}: malformed JSON ({getattr(exc, 'msg', exc)}); restore the file") from None
    if (
        not isinstance(doc, dict)
        or doc.get("format") != TEXTURE_INDEX_FORMAT
        or not isinstance(doc.get("sets"), dict)
    ):
        raise InputError(
            f"{file}: not a texture-set index (expected format {TEXTURE_INDEX_FORMAT!r} and a 'sets' table)"
        )
    return doc["sets"]


_INDEX_CACHE: dict[tuple[str, int, int], dict] = {}


def _indexed_entry(directory: Path) -> dict | None:
    """The index entry of a texture set (None when its folder has no index); the parsed index is
    kept per (path, mtime, size), so loading many sets parses it once and an edit is seen."""
    index = directory.parent / TEXTURE_INDEX
    try:
        st = index.stat()
    except FileNotFoundError:
        return None
    key = (str(index.resolve()), st.st_mtime_ns, st.st_size)
    if key not in _INDEX_CACHE:
        _INDEX_CACHE.clear()  # one index at a time is the usual case; no unbounded growth
        _INDEX_CACHE[key] = read_texture_index(index)
    return _INDEX_CACHE[key].get(directory.name)


def _load_indexed_set(directory: Path, entry: dict) -> SVBRDF:
    """A set described by its index entry: the map roles name the files; metalness comes from the
    ``metalness`` map, the ``arm`` map's B channel, ``metalness_constant``, or is 0 (the index's
    note: sets of unknown metalness, e.g. rusty or painted metals, are treated as dielectric)."""
    maps = entry.get("maps") or {}
    where = f"{directory} ({TEXTURE_INDEX} entry)"
    for role in ("albedo", "normal"):
        if role not in maps:
            raise InputError(f"{where}: no {role!r} map listed; fix the index")
    if "roughness" not in maps and "arm" not in maps:
        raise InputError(f"{where}: neither a 'roughness' nor an 'arm' map listed; fix the index")
    colorspace = entry.get("albedo_colorspace", "srgb")
    base = read_image(directory / maps["albedo"], colorspace)
    if base.shape[2] == 1:  # a grey base colour saved as one channel
        base = np.repeat(base, 3, axis=2)
    base = base[..., :3]
    shape = base.shape[:2]
    nfile = directory / maps["normal"]
    normal = decode_normals(
        read_image(nfile, "linear", expect_channels=3, expect_shape=shape),
        nfile,
        entry.get("normal_convention", "opengl"),
        encoded=True,
        repair=True,
    )
    arm = (
        read_image(directory / maps["arm"], "linear", expect_channels=3, expect_shape=shape)
        if "arm" in maps
        else None
    )
    if "roughness" in maps:
        rough = read_image(directory / maps["roughness"], "linear", expect_shape=shape)[..., 0]
    else:
        rough = arm[..., 1]
    if "metalness" in maps:
        metal = read_image(directory / maps["metalness"], "linear", expect_shape=shape)[..., 0]
    elif arm is not None:
        metal = arm[..., 2]
    else:
        const = entry.get("metalness_constant")
        metal = np.full(shape, float(const) if const is not None else 0.0, np.float32)
    return from_metal_rough(base, metal, rough, normal, source=str(directory))


def load_texture_set(path: str | os.PathLike, size: int | tuple[int, int] | None = None) -> SVBRDF:
    """Read a Poly Haven or ambientCG metallic/roughness texture set (module docstring) as an
    :class:`SVBRDF`, optionally area-resampled to ``size`` (int: square, or (height, width)).

    A set listed in an ``index.json`` beside it (:func:`read_texture_index`) is read as the index
    says; other sets are recognised by their file names."""
    directory = Path(path)
    if not directory.is_dir():
        raise InputError(f"{directory}: no such texture-set directory")
    target = _parse_size(size)
    entry = _indexed_entry(directory)
    if entry is not None:
        svbrdf = _load_indexed_set(directory, entry)
        return svbrdf if target is None else resample_svbrdf(svbrdf, target)
    tex = _find_textures(directory)
    expected = (
        "expected Poly Haven *_diff_1k/*_nor_gl_1k/*_arm_1k or ambientCG "
        "*_Color/*_Normal/*_Roughness[/*_Metalness] images"
    )
    if "basecolor" not in tex:
        raise InputError(f"{directory}: no base-colour texture; {expected}")
    if "normal_gl" in tex:
        normal_file, convention = tex["normal_gl"], "opengl"
    elif "normal_dx" in tex:
        normal_file, convention = tex["normal_dx"], "directx"
    else:
        raise InputError(f"{directory}: no normal texture; {expected}")
    base = read_image(tex["basecolor"], "srgb", expect_channels=3)
    shape = base.shape[:2]
    normal = decode_normals(
        read_image(normal_file, "linear", expect_channels=3, expect_shape=shape),
        normal_file,
        convention,
        encoded=True,
    )
    if "roughness" in tex:  # grey maps; an RGB-saved grey map gives its first channel
        rough = read_image(tex["roughness"], "linear", expect_shape=shape)[..., 0]
        metal = (
            read_image(tex["metalness"], "linear", expect_shape=shape)[..., 0]
            if "metalness" in tex
            else np.zeros(shape, np.float32)
        )
    elif "arm" in tex:
        arm = read_image(tex["arm"], "linear", expect_channels=3, expect_shape=shape)
        rough, metal = arm[..., 1], arm[..., 2]
    else:
        raise InputError(f"{directory}: no roughness texture; {expected}")
    svbrdf = from_metal_rough(base, metal, rough, normal, source=str(directory))
    return svbrdf if target is None else resample_svbrdf(svbrdf, target)


def is_material_dir(path: str | os.PathLike) -> bool:
    """True when ``path`` holds a material directory (``material.json`` or ``normal.exr/.png``)
    and is not a texture set listed in an ``index.json`` beside it."""
    p = Path(path)
    if _indexed_entry(p) is not None:
        return False
    return (p / "material.json").is_file() or any(
        (p / f"normal{s}").is_file() for s in (".exr",) + _LDR_SUFFIXES
    )


def load_material(
    path: str | os.PathLike, size: int | tuple[int, int] | None = None, albedo_colorspace: str = "srgb"
) -> SVBRDF:
    """A material directory (:func:`load_material_dir`) or a texture set
    (:func:`load_texture_set`), optionally area-resampled to ``size``."""
    if is_material_dir(path):
        svbrdf = load_material_dir(path, albedo_colorspace=albedo_colorspace)
        return svbrdf if size is None else resample_svbrdf(svbrdf, size)
    return load_texture_set(path, size=size)
