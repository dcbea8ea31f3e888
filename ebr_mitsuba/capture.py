"""Synthetic captures rendered with Mitsuba: the photos of a setup plus the ground truth.

:func:`capture` renders every shot of a setup (:func:`ebr_mitsuba.geometry.capture_shots`) of one
material under one environment and writes a capture directory, atomically (built under a
temporary name and renamed; on any error no output directory appears):

=====================  ==========================================================================
file                   content
=====================  ==========================================================================
``<shot>.exr``         one linear RGB float32 image per shot, (res, res, 3):
                       near: ``flash``, ``noflash``; near-far: + ``far_flash``, ``far_noflash``;
                       five-light: ``light0`` … ``light4`` (point light only, environment off);
                       multi-view: ``view{a}{b}_flash`` for the 3×3 grid (flash + environment)
                       and ``noflash``, the centre camera without its flash
``maps/``              the ground-truth SVBRDF exactly as rendered (a material directory, written by
                       :func:`ebr_mitsuba.materials.save_material_dir`), in the sample grid
``env.json``           the SG environment as rendered (lobes × ``env_scale``; SG environments only:
                       an equirectangular one is identified in ``capture.json`` by path and SHA-256)
``capture.json``       metadata (below)
=====================  ==========================================================================

``capture.json`` (``"format": "ebr-capture/1"``):

=========================  =====================================================================
key                        value
=========================  =====================================================================
``setup``                  ``near`` | ``near-far`` | ``five-light`` | ``multi-view``
``resolution``             [H, W] of every image and map (square)
``spp``, ``seed``          samples per pixel; capture seed (per-shot seeds in ``shots``)
``integrator``             {"type": "direct" | "path", "hide_emitters": true[, "max_depth": 2]}
``reconstruction_filter``  ``"box"``
``exposure``, ``units``    1.0; linear radiance, flash intensity in W/sr
``grid``                   the pixel ↔ surface mapping in words
``material``               {"spec", "kind": "procedural" | "directory" | "memory", "family",
                           "seed" | "path", "maps": "maps"}
``env``                    null (dark) or {"spec", "kind": "sg" | "equirect", "path", "seed",
                           "lobes" (sg), "sha256", "shape" (equirect), "scale", "file" (sg)}
``shots``                  per shot: name, file, camera, target, up, fov (degrees), fov_axis "x",
                           flash (position or null), flash_intensity (W/sr), env (lit by the
                           environment), seed, in_sample_grid, plus light_index / grid
``renderer``               variant, mitsuba, drjit, llvm versions and ebr_mitsuba version
``seconds``                wall time of the capture
=========================  =====================================================================

Rendering: one scene per shot (:func:`ebr_mitsuba.scene.shot_scene_dict`). The default
integrator is ``direct`` (one emitter + one BSDF sample per spp, combined by MIS): the sample is
a plane, which never sees itself, so direct lighting is the complete light transport; ``path``
with ``max_depth`` 2 is available and has the same expectation. Emitters seen directly by the
camera are hidden (off-sample pixels of oblique views are black). The images are radiance with
exposure 1. Seeds are deterministic: shot k renders with seed
``SeedSequence([seed, k]).generate_state(1)[0]`` (recorded per shot).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from . import __version__
from .errors import InputError
from .fsutil import atomic_dir
from .geometry import SETUPS, Shot, capture_shots
from .imageio import write_exr
from .materials import save_material_dir
from .scene import INTEGRATORS, PATH_MAX_DEPTH, shot_scene_dict, svbrdf_bsdf_dict
from .sgenv import SGEnvironment
from .sources import EnvSource, MaterialSource, parse_env, parse_material
from .svbrdf import SVBRDF
from .typedconfig import config, option
from .variant import describe, ensure_variant

CAPTURE_FORMAT = "ebr-capture/1"
DEFAULT_INTEGRATOR = "direct"
MAX_RES = 8192


@config(error=InputError)
class CaptureConfig:
    """How :func:`capture` renders a capture (the options of ``ebr capture``; a bad value is an
    :class:`~ebr_mitsuba.errors.InputError`)."""

    spp: int = option(64, "samples per pixel", minimum=1)
    res: int = option(256, "image and map resolution, square", minimum=1, maximum=MAX_RES)
    seed: int = option(0, "capture seed (the per-shot seeds derive from it)", minimum=0)
    integrator: str = option(
        DEFAULT_INTEGRATOR,
        "Mitsuba integrator (direct: the complete transport of the plane; path: max_depth 2)",
        choices=INTEGRATORS,
        metavar="NAME",
    )
    env_scale: float = option(1.0, "environment radiance multiplier", minimum=0)


#: The fields ``ebr capture`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
CAPTURE_FLAGS = ("spp", "res", "seed", "integrator", "env_scale")


def shot_seed(seed: int, index: int) -> int:
    """The sampler seed of shot ``index`` of a capture with seed ``seed`` (32-bit, deterministic)."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def _as_material(material) -> tuple[MaterialSource | None, str]:
    if isinstance(material, SVBRDF):
        return None, material.source
    if isinstance(material, MaterialSource):
        return material, material.spec
    source = parse_material(str(material))
    return source, source.spec


def _as_env(env) -> EnvSource | None:
    if env is None:
        return None
    if isinstance(env, EnvSource):
        return env
    if isinstance(env, SGEnvironment):
        return EnvSource("<memory>", "sg", sg=env)
    return parse_env(str(env))


def render_shot(
    svbrdf: SVBRDF,
    env_emitter: dict | None,
    shot: Shot,
    spp: int,
    seed: int = 0,
    integrator: str = DEFAULT_INTEGRATOR,
    bsdf=None,
) -> np.ndarray:
    """Render one shot of ``svbrdf`` at the maps' resolution; returns (H, W, 3) float32.

    ``env_emitter`` is an emitter dict (``EnvSource.emitter_dict()``) or None; it lights the shot
    only when ``shot.env``. ``bsdf`` reuses a BSDF of ``svbrdf`` already instantiated with
    ``mi.load_dict(svbrdf_bsdf_dict(svbrdf))`` (a dict's bitmap tensors are consumed by one load).
    """
    ensure_variant()
    import mitsuba as mi

    h, w = svbrdf.shape
    if bsdf is None:
        bsdf = svbrdf_bsdf_dict(svbrdf)
    scene = mi.load_dict(shot_scene_dict(bsdf, env_emitter, shot, (h, w), spp, seed, integrator))
    image = mi.render(scene, spp=int(spp), seed=int(seed))
    return np.array(image, dtype=np.float32).reshape(h, w, -1)[..., :3]


def render_flash_only(
    svbrdf: SVBRDF, shot: Shot, spp: int, seed: int = 0, integrator: str = DEFAULT_INTEGRATOR
) -> np.ndarray:
    """``shot`` lit by its point light alone (environment off): the flash-only image, (H, W, 3)."""
    if shot.flash is None:
        raise InputError(f"shot {shot.name!r} has no flash; a flash-only image needs one")
    return render_shot(svbrdf, None, dataclasses.replace(shot, env=False), spp, seed, integrator)


def _check_out_dir(out_dir: Path) -> None:
    """Refuse to replace anything but an earlier capture directory (or an empty directory)."""
    if not out_dir.exists():
        return
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a directory; choose another --out")
    if any(out_dir.iterdir()) and not (out_dir / "capture.json").is_file():
        raise InputError(
            f"{out_dir}: exists and is not a capture directory (no capture.json); "
            f"choose a new --out or remove it"
        )


def capture(
    material,
    env,
    setup: str,
    out_dir,
    config: CaptureConfig | None = None,
    *,
    progress: bool = True,
    **options,
) -> dict:
    """Render a capture of ``material`` under ``env`` with ``setup`` into ``out_dir``.

    ``material``: a material spec string, :class:`MaterialSource` or :class:`SVBRDF` (its size
    must equal the resolution); ``env``: a spec string, :class:`EnvSource`, :class:`SGEnvironment`
    or None (dark); ``setup``: one of :data:`ebr_mitsuba.geometry.SETUPS`; ``config``: a
    :class:`CaptureConfig` (default: its defaults), with ``options`` (its fields, ``spp=4,
    res=8``) set over it. Returns the content of ``capture.json``. Everything is validated and
    the material loaded before rendering; output is atomic (an existing capture directory at
    ``out_dir`` is replaced, anything else is refused).
    """
    t0 = time.perf_counter()
    if config is not None and not isinstance(config, CaptureConfig):
        raise TypeError(f"capture: config must be a CaptureConfig, got {config!r}")
    cfg = dataclasses.replace(config or CaptureConfig(), **options)
    res, spp, seed, integrator, env_scale = cfg.res, cfg.spp, cfg.seed, cfg.integrator, cfg.env_scale
    shots = capture_shots(setup)
    out_dir = Path(out_dir)
    _check_out_dir(out_dir)
    material_source, material_spec = _as_material(material)
    env_source = _as_env(env)
    ensure_variant()
    import mitsuba as mi

    svbrdf = material if material_source is None else material_source.load(res)
    if svbrdf.shape != (res, res):
        raise InputError(
            f"material {material_spec!r} is {svbrdf.shape[1]}x{svbrdf.shape[0]}; the capture "
            f"resolution is {res}x{res}"
        )
    env_emitter = None if env_source is None else env_source.emitter_dict(env_scale)
    bsdf = mi.load_dict(svbrdf_bsdf_dict(svbrdf))  # textures uploaded once for all shots

    shot_records = []
    with atomic_dir(out_dir) as tmp:
        # disable=None: tqdm draws only on a terminal (stderr), never into logs or pipes.
        bar = tqdm(
            list(enumerate(shots)),
            desc=f"capture {setup}",
            unit="shot",
            disable=None if progress else True,
            leave=False,
            dynamic_ncols=True,
        )
        for k, shot in bar:
            bar.set_postfix_str(shot.name)
            s = shot_seed(seed, k)
            image = render_shot(svbrdf, env_emitter, shot, spp, s, integrator, bsdf=bsdf)
            if not np.all(np.isfinite(image)):
                raise RuntimeError(f"shot {shot.name}: the render has NaN/Inf pixels")
            fname = f"{shot.name}.exr"
            write_exr(tmp / fname, image)
            record = shot.to_json()
            record.update(
                file=fname,
                seed=s,
                fov_axis="x",
                in_sample_grid=shot.in_sample_grid(),
                env=bool(shot.env and env_source is not None),
            )
            shot_records.append(record)
        bar.close()
        save_material_dir(svbrdf, tmp / "maps")
        env_record = None
        if env_source is not None:
            env_record = env_source.to_json()
            env_record["scale"] = float(env_scale)
            if env_source.kind == "sg":
                env_source.sg.scaled(env_scale).save(tmp / "env.json")
                env_record["file"] = "env.json"
        meta = {
            "format": CAPTURE_FORMAT,
            "setup": setup,
            "resolution": [res, res],
            "spp": spp,
            "seed": seed,
            "integrator": {
                "type": integrator,
                "hide_emitters": True,
                **({"max_depth": PATH_MAX_DEPTH} if integrator == "path" else {}),
            },
            "reconstruction_filter": "box",
            "exposure": 1.0,
            "units": "linear radiance; flash intensity in W/sr (isotropic point light)",
            "grid": "pixel (i, j) sees x = -1 + (2j+1)/W, y = 1 - (2i+1)/H on the sample z = 0 "
            "(shots with in_sample_grid true)",
            "material": {
                **(
                    material_source.to_json()
                    if material_source
                    else {"spec": material_spec, "kind": "memory"}
                ),
                "maps": "maps",
            },
            "env": env_record,
            "shots": shot_records,
            "renderer": {**describe(), "ebr_mitsuba": __version__},
            "seconds": round(time.perf_counter() - t0, 3),
        }
        (tmp / "capture.json").write_text(json.dumps(meta, indent=1) + "\n")
    return meta


__all__ = [
    "CAPTURE_FLAGS",
    "CAPTURE_FORMAT",
    "SETUPS",
    "CaptureConfig",
    "capture",
    "render_shot",
    "render_flash_only",
    "shot_seed",
]
