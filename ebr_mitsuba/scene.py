"""Mitsuba scenes: loading XML files and building the scene dictionaries of a capture.

Loading
-------
:func:`load_scene` selects the variant (which registers the ``sgenvmap`` and ``svbrdf`` plugins),
then calls ``mi.load_file``. Every failure becomes a one-line :class:`~ebr_mitsuba.errors.EbrError`
naming the file: a missing file is an :class:`InputError`; malformed XML, an unknown plugin, an
undefined or unused ``$parameter`` or a bad value is a :class:`ConfigError`.
:func:`bundled_scene` / :func:`bundled_scenes` find the scenes shipped in
:mod:`ebr_mitsuba.scenes` (through ``importlib.resources``); :func:`resolve_scene_path` accepts
a file or a bundled scene's bare name.

Scene-dictionary builders (``docs/conventions.md``, "Geometry and pixel grid")
-------------------------------------
=========================  ========================================================================
builder                    what it returns
=========================  ========================================================================
``sensor_dict``            perspective camera at ``shot.camera`` looking at ``shot.target``, up
                           ``shot.up``, ``fov`` along x; box reconstruction filter (a pixel is the
                           mean over its footprint); ``hdrfilm`` RGB float32; ``independent``
                           sampler with ``spp`` samples and ``seed``
``svbrdf_bsdf_dict``       the ``svbrdf`` BSDF with four nearest-texel ``bitmap`` textures
                           (``raw=True``); rows are flipped so that map row 0 lies at +y
``sample_shape_dict``      the sample: Mitsuba's ``rectangle`` = [-1,1]² at z = 0, normal +z,
                           uv = ((x+1)/2, (y+1)/2)
``sg_emitter_dict``        the ``sgenvmap`` emitter with inline lobes of an :class:`SGEnvironment`
``equirect_emitter_dict``  Mitsuba's ``envmap`` for an equirectangular file, rotated y-up → z-up
``point_light_dict``       an isotropic ``point`` light (intensity in W/sr, inverse-square falloff)
``integrator_dict``        ``direct`` (default) or ``path`` with ``max_depth`` 2
=========================  ========================================================================

Pixel ↔ surface mapping: for a shot in the sample grid (``Shot.in_sample_grid()``), pixel (i, j)
of an H×W image integrates the surface cell around ``x = −1 + (2j+1)/W``, ``y = 1 − (2i+1)/H``;
at equal resolution that cell is exactly map texel (i, j) (tested in ``tests/test_capture.py``).
"""

from __future__ import annotations

import importlib.resources
import re
from pathlib import Path

import numpy as np

from .errors import ConfigError, EbrError, InputError, RuntimeSetupError
from .geometry import Shot
from .sgenv import SGEnvironment
from .svbrdf import SVBRDF

INTEGRATORS = ("direct", "path")
PATH_MAX_DEPTH = 2  # camera → plane → light: a plane never sees itself, one bounce is exact


# -- loading ---------------------------------------------------------------------------------------


def bundled_scenes() -> list[str]:
    """Names (without ``.xml``) of the scenes shipped in :mod:`ebr_mitsuba.scenes`."""
    root = importlib.resources.files("ebr_mitsuba.scenes")
    return sorted(p.name[:-4] for p in root.iterdir() if p.name.endswith(".xml"))


def bundled_scene(name: str) -> Path:
    """Path of the bundled scene ``name`` (``default``, ``exemplar``, ``near_flash``, ...)."""
    stem = name[:-4] if name.endswith(".xml") else name
    path = importlib.resources.files("ebr_mitsuba.scenes") / f"{stem}.xml"
    if not path.is_file():
        raise InputError(f"no bundled scene named {name!r}; use one of {', '.join(bundled_scenes())}")
    return Path(str(path))


def resolve_scene_path(spec: str | Path) -> Path:
    """A scene file: ``spec`` itself when it exists, else a bundled scene of that bare name."""
    path = Path(spec)
    if path.is_file():
        return path
    if path.parent == Path(".") and path.stem in bundled_scenes():
        return bundled_scene(path.stem)
    if path.is_dir():
        raise InputError(f"{path}: is a directory; give a Mitsuba XML scene file")
    raise InputError(
        f"{path}: no such scene file; give an existing Mitsuba XML file or a bundled "
        f"scene name ({', '.join(bundled_scenes())})"
    )


_PARSER_PREFIX = re.compile(r"^\s*\[[^\]]*\]\s*")


def _clean_mitsuba_message(msg: str) -> str:
    """Strip Mitsuba's ``[parser.cpp:NNN]`` prefix and fold the message onto one line."""
    return " ".join(_PARSER_PREFIX.sub("", str(msg)).split())


_ERROR_TYPES = {cls.__name__: cls for cls in (InputError, ConfigError, RuntimeSetupError, EbrError)}
_TRACEBACK = "Traceback (most recent call last):"


def _split_plugin_traceback(raw: str) -> tuple[str, str | None]:
    """Mitsuba reports an exception raised in a Python plugin as its context, then the Python
    traceback: keep the context and the final ``Type: message`` line; return that type's name
    (None when there is no traceback)."""
    if _TRACEBACK not in raw:
        return _clean_mitsuba_message(raw), None
    head, _, tb = raw.partition(_TRACEBACK)
    lines = [line.strip() for line in tb.splitlines() if line.strip()]
    last = lines[-1] if lines else "unknown error"
    etype, sep, emsg = last.partition(": ")
    etype = etype.rsplit(".", 1)[-1] if sep else "Exception"
    return f"{_clean_mitsuba_message(head)} {emsg if sep else last}", etype


def load_scene(path: str | Path, **params):
    """Load a Mitsuba XML scene (which may use the ebr plugins) with ``$name`` parameters.

    ``params`` values are passed to ``mi.load_file`` as strings (numbers, bools and sequences
    are converted). Raises :class:`InputError` for a missing file and :class:`ConfigError` for
    anything Mitsuba rejects (malformed XML, unknown plugin, undefined or unused parameter, bad
    value), each one line naming the file. An :class:`EbrError` raised inside one of our plugins
    (e.g. a missing ``env.json``) keeps its type; any other exception from a plugin is a bug and
    is re-raised as ``RuntimeError``.
    """
    from .variant import ensure_variant

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such scene file; give an existing Mitsuba XML file")
    ensure_variant()
    import mitsuba as mi

    str_params = {str(k): _param_str(v) for k, v in params.items()}
    try:
        return mi.load_file(str(path), **str_params)
    except EbrError as exc:  # raised by one of our plugins while the scene was built
        raise type(exc)(f"{path}: {exc}") from None
    except Exception as exc:
        msg, plugin_error = _split_plugin_traceback(str(exc))
        if plugin_error is not None and plugin_error not in _ERROR_TYPES:
            # A non-ebr exception inside a plugin is a bug, not bad input (CLI exit code 1).
            raise RuntimeError(f"{path}: {msg} ({plugin_error})") from None
        if plugin_error is not None:
            raise _ERROR_TYPES[plugin_error](f"{path}: {msg}") from None
        hint = ""
        if "unused parameters" in msg:
            hint = "; pass only parameters the scene declares with <default name=...>"
        elif "undefined parameter" in msg:
            hint = "; pass it with -D name=value or add a <default> to the scene"
        elif "not found" in msg and "plugin" in msg.lower():
            hint = "; check the plugin name (ebr plugins: sgenvmap, svbrdf)"
        raise ConfigError(f"{path}: Mitsuba could not load the scene: {msg}{hint}") from None


def _param_str(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple, np.ndarray)):
        return ", ".join(_param_str(v) for v in np.asarray(value).reshape(-1).tolist())
    return str(value)


# -- scene-dictionary builders ----------------------------------------------------------------------


def _resolution(res) -> tuple[int, int]:
    """``res`` as (height, width): an int is a square image."""
    if isinstance(res, (int, np.integer)):
        h = w = int(res)
    else:
        h, w = (int(v) for v in res)
    if h < 1 or w < 1:
        raise InputError(f"resolution must be positive (got {res!r})")
    return h, w


def sensor_dict(shot: Shot, res, spp: int, seed: int = 0) -> dict:
    """Perspective sensor of ``shot`` (``res``: int for square or (H, W)); see module docstring."""
    import mitsuba as mi

    h, w = _resolution(res)
    return {
        "type": "perspective",
        "fov": float(shot.fov),
        "fov_axis": "x",
        "near_clip": 1e-3,
        "far_clip": 1e4,
        "to_world": mi.ScalarTransform4f().look_at(
            origin=list(map(float, shot.camera)),
            target=list(map(float, shot.target)),
            up=list(map(float, shot.up)),
        ),
        "film": {
            "type": "hdrfilm",
            "width": w,
            "height": h,
            "rfilter": {"type": "box"},
            "pixel_format": "rgb",
            "component_format": "float32",
        },
        "sampler": {"type": "independent", "sample_count": int(spp), "seed": int(seed)},
    }


def bitmap_dict(array: np.ndarray) -> dict:
    """A nearest-texel, clamped, raw (linear) ``bitmap`` texture from an (H, W[, C]) map whose
    row 0 is the +y edge: the rows are flipped because a Mitsuba bitmap's row 0 is v = 0 (−y)."""
    import mitsuba as mi

    arr = np.asarray(array, dtype=np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3:
        raise InputError(f"texture must be (H, W) or (H, W, C); got shape {arr.shape}")
    return {
        "type": "bitmap",
        "data": mi.TensorXf(np.ascontiguousarray(arr[::-1])),
        "raw": True,
        "filter_type": "nearest",
        "wrap_mode": "clamp",
    }


def svbrdf_bsdf_dict(svbrdf: SVBRDF, fresnel: str = "schlick") -> dict:
    """The ``svbrdf`` BSDF (plugin :mod:`ebr_mitsuba.plugins.svbrdf`) showing ``svbrdf``'s maps."""
    return {
        "type": "svbrdf",
        "normal": bitmap_dict(svbrdf.normal),
        "diffuse": bitmap_dict(svbrdf.diffuse),
        "specular": bitmap_dict(svbrdf.specular),
        "roughness": bitmap_dict(svbrdf.roughness),
        "fresnel": fresnel,
    }


def sample_shape_dict(bsdf: dict) -> dict:
    """The material sample: Mitsuba's ``rectangle`` is [-1,1]² at z = 0 with normal +z."""
    return {"type": "rectangle", "bsdf": bsdf}


def sg_emitter_dict(env: SGEnvironment, scale: float = 1.0) -> dict:
    """The ``sgenvmap`` emitter (plugin :mod:`ebr_mitsuba.plugins.sgenvmap`) with ``env``'s lobes
    given inline, in the plugin's string form (``repr`` of the float32 values, so exact; the
    tensor form makes ``mi.load_dict`` print nanobind conversion warnings)."""

    def rows(array) -> str:
        return ", ".join(" ".join(repr(float(v)) for v in np.atleast_1d(row)) for row in array)

    return {
        "type": "sgenvmap",
        "id": "env",
        "axis": rows(env.axis),
        "sharpness": rows(env.sharpness),
        "amplitude": rows(env.amplitude),
        "scale": float(scale),
    }


def equirect_emitter_dict(source, scale: float = 1.0) -> dict:
    """Mitsuba's ``envmap`` for an equirectangular map (path of a y-up ``.exr``/``.hdr``,
    ``EquirectMap`` or (H, W, 3) array), rotated to the z-up world by
    :func:`ebr_mitsuba.envmap.envmap_emitter_dict`."""
    from .envmap import envmap_emitter_dict

    return envmap_emitter_dict(source, scale=scale)


def point_light_dict(position, intensity: float) -> dict:
    """An isotropic point light at ``position`` with ``intensity`` W/sr (grey)."""
    return {
        "type": "point",
        "position": [float(v) for v in position],
        "intensity": {"type": "rgb", "value": float(intensity)},
    }


def integrator_dict(integrator: str = "direct") -> dict:
    """``direct`` (one emitter and one BSDF sample per spp, MIS) or ``path`` (``max_depth`` 2).

    The sample is a plane, which never sees itself, so direct lighting is the whole light
    transport and both give the same expectation. Emitters seen directly by the camera (off the
    sample, in oblique multi-view shots) are hidden: those pixels are black.
    """
    if integrator == "direct":
        return {"type": "direct", "hide_emitters": True}
    if integrator == "path":
        return {"type": "path", "max_depth": PATH_MAX_DEPTH, "hide_emitters": True}
    raise InputError(f"unknown integrator {integrator!r}; use one of {', '.join(INTEGRATORS)}")


def shot_scene_dict(
    bsdf: dict, env_emitter: dict | None, shot: Shot, res, spp: int, seed: int = 0, integrator: str = "direct"
) -> dict:
    """The whole scene of one shot: sample + camera + (flash) + (environment when ``shot.env``)."""
    scene = {
        "type": "scene",
        "integrator": integrator_dict(integrator),
        "sensor": sensor_dict(shot, res, spp, seed),
        "sample": sample_shape_dict(bsdf),
    }
    if shot.flash is not None:
        scene["flash"] = point_light_dict(shot.flash, shot.flash_intensity)
    if shot.env and env_emitter is not None:
        scene["env"] = env_emitter
    return scene
