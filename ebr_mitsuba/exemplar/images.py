"""Exemplar images: renders of the exemplar material (:mod:`ebr_mitsuba.exemplar`) under a light.

=============================  ========================================================================
function                       what
=============================  ========================================================================
:func:`exemplar_material`      the exemplar material as an (H, W) :class:`~ebr_mitsuba.svbrdf.SVBRDF`
:func:`exemplar_images`        environment exemplars with the fast renderer (Dr.Jit tensors, one
                               kernel over every exemplar, differentiable w.r.t. the lobes)
:func:`env_exemplar_images`    the same as one numpy stack (K, H, W, 3)
:func:`point_exemplar_images`  point-light exemplars: the near flash alone, exact
:func:`uniform_renders`        renders of any uniform flat materials (the selection's basis images)
:func:`render_exemplars`       ``ebr exemplars``: path-traced (Mitsuba) or fast-renderer exemplars
=============================  ========================================================================

Environment exemplars are rendered with the flash off, point-light exemplars with the flash only
(``docs/conventions.md``, "Exemplars"). Mitsuba and Dr.Jit are imported when a function runs.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError
from ..geometry import DEFAULT_EXEMPLAR_ROUGHNESS, Shot, near_shot
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF
from ..typedconfig import check, config, option
from . import EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR

if TYPE_CHECKING:
    import mitsuba as mi

    from ..render.inputs import DrLobes, RenderOptions

RENDERERS = ("mitsuba", "fast")


@config(error=InputError, cli=True)
class ExemplarsConfig:
    """How :func:`render_exemplars` renders (the options of ``ebr exemplars``; a bad value is an
    :class:`~ebr_mitsuba.errors.InputError` naming the flag)."""

    roughness: tuple[float, ...] = option(
        DEFAULT_EXEMPLAR_ROUGHNESS,
        "exemplar roughness values, each given once",
        minimum=0,
        maximum=1,
        nonempty=True,
        metavar="R1,R2,...",
    )
    point_light: bool = option(False, "point-light exemplars (near flash only; --env is then ignored)")
    renderer: str = option(
        "mitsuba",
        "mitsuba: path-traced (direct integrator, box filter); fast: the fast renderer's quadrature "
        "(SG environments only)",
        choices=RENDERERS,
        metavar="NAME",
    )
    res: int = option(256, "image size, square", minimum=16, maximum=4096)
    spp: int = option(256, "Mitsuba samples / quadrature directions per pixel", minimum=1)
    seed: int = option(0, "sampler seed (quadrature pattern for fast)", minimum=0)

    def __post_init__(self):
        check(self)
        if len({f"{r:.3f}" for r in self.roughness}) != len(self.roughness):
            text = ",".join(f"{r:g}" for r in self.roughness)
            raise InputError(f"--roughness {text!r}: a value repeats; give each once")


#: The fields ``ebr exemplars`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
EXEMPLARS_FLAGS = ("roughness", "point_light", "renderer", "res", "spp", "seed")


def exemplar_material(size: int, roughness: float) -> SVBRDF:
    """The exemplar material (size, size) at ``roughness``."""
    return SVBRDF.uniform(size, size, EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR, float(roughness))


def _require_variant() -> None:
    import mitsuba as mi

    if mi.variant() is None:
        from ..variant import ensure_variant

        ensure_variant()


def flash_shot(shot: Shot | None) -> Shot:
    """``shot`` (default: the near flash shot) lit by its flash alone."""
    shot = shot or near_shot(True, env=False)
    if shot.flash is None:
        raise InputError(f"point-light exemplars need a shot with a flash; shot {shot.name!r} has none")
    return dataclasses.replace(shot, env=False)


def env_shot(shot: Shot | None) -> Shot:
    """``shot`` (default: the near shot) lit by the environment alone."""
    return dataclasses.replace(shot or near_shot(False), flash=None, env=True)


def _check_roughness(roughness_list: Sequence[float], what: str) -> np.ndarray:
    r = np.asarray(roughness_list, dtype=np.float64).reshape(-1)
    if r.size == 0 or not np.all(np.isfinite(r)) or r.min() < 0 or r.max() > 1:
        raise InputError(f"{what}: roughness values {r.tolist()} must be a non-empty list in [0, 1]")
    return r


def uniform_renders(
    materials: Sequence[tuple[float, float, float]],
    env: SGEnvironment | None,
    shot: Shot,
    height: int,
    width: int,
    mode: str,
    spp: int,
) -> np.ndarray:
    """Renders (K, H, W, 3) float32 of uniform flat materials (diffuse, specular, roughness) with
    the fast renderer; one kernel serves every material (the maps are data, not constants)."""
    import drjit as dr

    from ..render import DrLobes, DrMaps, RenderOptions, render

    _require_variant()
    lobes = DrLobes.from_env(env if env is not None else SGEnvironment.empty())
    options = RenderOptions(mode=mode, spp=int(spp))
    out = np.empty((len(materials), height, width, 3), np.float32)
    with dr.suspend_grad():
        for k, (d, s, r) in enumerate(materials):
            maps = DrMaps.uniform(height, width, diffuse=d, specular=s, roughness=r)
            out[k] = np.asarray(render(maps, lobes, shot, options).numpy(), np.float32)
    return out


def point_exemplar_images(
    roughness_list: Sequence[float], height: int, width: int, shot: Shot | None = None
) -> np.ndarray:
    """Point-light exemplars (K, H, W, 3) float32: the exemplar material (diffuse 0.1, specular
    0.2, roughness r, flat normal) lit by ``shot``'s flash alone (default: the near flash shot),
    no environment; exact (the flash term has no sampling)."""
    r = _check_roughness(roughness_list, "point_exemplar_images")
    return uniform_renders(
        [(EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR, float(v)) for v in r],
        None,
        flash_shot(shot),
        int(height),
        int(width),
        "sg",
        1,
    )


def env_exemplar_images(
    env: SGEnvironment,
    roughness_list: Sequence[float],
    height: int,
    width: int,
    shot: Shot | None = None,
    mode: str = "quadrature",
    spp: int = 64,
) -> np.ndarray:
    """Environment exemplars (K, H, W, 3) float32 (:func:`exemplar_images`, flash off) as one
    numpy stack."""
    import drjit as dr

    _require_variant()
    r = _check_roughness(roughness_list, "env_exemplar_images")
    with dr.suspend_grad():
        images = exemplar_images(
            env, r.tolist(), int(height), int(width), shot=env_shot(shot), mode=mode, spp=int(spp)
        )
    return np.stack([np.asarray(im.numpy(), np.float32) for im in images])


def exemplar_images(
    env_lobes: DrLobes | SGEnvironment,
    roughness_list: Sequence[float],
    height: int,
    width: int,
    shot: Shot | None = None,
    mode: str = "sg",
    spp: int = 64,
    options: RenderOptions | None = None,
) -> list[mi.TensorXf]:
    """Environment exemplars (``docs/conventions.md``, "Exemplars"): renders of the exemplar
    material (:mod:`ebr_mitsuba.exemplar`: diffuse 0.1, specular 0.2 grey, roughness r, flat
    normal) under the lobes, flash off, one (H, W, 3) ``mi.TensorXf`` per roughness,
    differentiable w.r.t. the lobes.

    All exemplars run as one kernel over (exemplar, lobe, pixel) pairs; the flat normal makes the
    diffuse part one irradiance per lobe. ``shot`` gives the camera (default: the near shot);
    its flash is ignored. ``options`` overrides ``mode``/``spp`` when given.
    """
    import drjit as dr
    import mitsuba as mi

    from ..render.fast import check_shot, environment
    from ..render.inputs import DrLobes, RenderOptions
    from ..render.points import ShadingPoints, grid_positions, opaque_point, view_vectors

    _require_variant()
    if isinstance(env_lobes, SGEnvironment):
        env_lobes = DrLobes.from_env(env_lobes)
    roughness = np.asarray(roughness_list, dtype=np.float32).reshape(-1)
    in_range = roughness.size > 0 and np.all(np.isfinite(roughness)) and roughness.min() >= 0
    if not (in_range and roughness.max() <= 1):
        raise InputError(
            f"exemplar_images: roughness values {roughness.tolist()} must be a non-empty list in [0, 1]"
        )
    options = options or RenderOptions(mode=mode, spp=spp)
    shot = shot or near_shot(False)
    check_shot(shot)
    n_img = int(roughness.size)
    pixels = height * width
    if env_lobes.num_lobes == 0:
        return [dr.zeros(mi.TensorXf, (height, width, 3)) for _ in range(n_img)]
    positions, pixel = grid_positions(height, width)
    v = view_vectors(positions, opaque_point(shot.camera))
    idx = dr.arange(mi.UInt32, n_img * pixels)
    img = idx // pixels
    q = idx - img * pixels
    count = n_img * pixels
    points = ShadingPoints(
        n=mi.Vector3f(0.0, 0.0, 1.0) + dr.zeros(mi.Vector3f, count),
        v=dr.gather(mi.Vector3f, v, q),
        diffuse=mi.Color3f(EXEMPLAR_DIFFUSE) + dr.zeros(mi.Color3f, count),
        specular=mi.Color3f(EXEMPLAR_SPECULAR) + dr.zeros(mi.Color3f, count),
        roughness=dr.gather(mi.Float, mi.Float(roughness), img),
        pixel=dr.gather(mi.UInt32, pixel, q),
        count=count,
        flat_normal=True,
    )
    radiance = environment(points, env_lobes, options) * dr.opaque(mi.Float, float(options.env_scale))
    stack = mi.TensorXf(dr.ravel(radiance), (n_img, height, width, 3))
    return [stack[i] for i in range(n_img)]


def render_exemplars(env_spec: str | None, config: ExemplarsConfig | None = None):
    """``ebr exemplars``' images (list of (res, res, 3) float32), the shot and the env record, as
    ``config`` (default: :class:`ExemplarsConfig`'s defaults) says: ``renderer`` ``mitsuba``
    (path-traced, :func:`ebr_mitsuba.capture.render_shot`, seed ``shot_seed(seed, k)`` per
    exemplar) or ``fast`` (the fast renderer's quadrature, SG environments only); ``env_spec`` as
    ``--env`` (ignored for point-light exemplars)."""
    from ..capture import render_shot, shot_seed
    from ..sources import parse_env

    cfg = config or ExemplarsConfig()
    roughness, point_light, renderer = list(cfg.roughness), cfg.point_light, cfg.renderer
    res, spp, seed = cfg.res, cfg.spp, cfg.seed
    if point_light:
        shot = near_shot(True, env=False)
        source = None
    else:
        if env_spec is None:
            raise InputError("--env is required for environment exemplars (or give --point-light)")
        shot = near_shot(False)
        source = parse_env(env_spec)
    material = [exemplar_material(res, r) for r in roughness]
    if renderer == "mitsuba":
        emitter = None if source is None else source.emitter_dict()
        images = [render_shot(m, emitter, shot, spp, shot_seed(seed, k)) for k, m in enumerate(material)]
    else:
        from ..render import RenderOptions, render_numpy

        if point_light:
            images = [render_numpy(m, None, shot) for m in material]
        else:
            if source.kind != "sg":
                raise InputError(
                    f"--env {env_spec}: the fast renderer needs an SG environment (env.json or "
                    f"procedural:SEED); use --renderer mitsuba for an equirectangular map"
                )
            opts = RenderOptions(mode="quadrature", spp=spp, seed=seed)
            images = [
                np.asarray(t.numpy(), np.float32)
                for t in exemplar_images(source.sg, roughness, res, res, shot=shot, options=opts)
            ]
    return images, shot, (None if source is None else source.to_json())


__all__ = [
    "EXEMPLARS_FLAGS",
    "RENDERERS",
    "ExemplarsConfig",
    "env_exemplar_images",
    "env_shot",
    "exemplar_images",
    "exemplar_material",
    "flash_shot",
    "point_exemplar_images",
    "render_exemplars",
    "uniform_renders",
]
