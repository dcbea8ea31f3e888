"""The fast differentiable renderer: one shading point per pixel of the sample grid, no path tracing.

It produces the images and conventions of the Mitsuba renders of the same scene (``ebr capture``):
a pinhole camera at ``shot.camera``, radiance towards it from the surface point at each pixel
centre (the pixel grid of :mod:`ebr_mitsuba.geometry`), an isotropic point light of intensity I
[W/sr] with inverse-square falloff, and the SG environment ``L(ω) = Σ_k G_k(ω)`` over the upper
hemisphere (the plane occludes the lower one; no other occlusion or interreflection exists in this
scene).

``image = flash + env_scale · env`` with

* ``flash = f(l, v) · max(n·l, 0) · I / d²`` (exact, :func:`ebr_mitsuba.brdf.brdf_eval_cos`), present
  when ``shot.flash`` is set;
* ``env`` the environment term, present when ``shot.env`` and K > 0: ``mode="sg"`` closed form
  (:mod:`.env_sg`) or ``mode="quadrature"`` deterministic MIS quadrature (:mod:`.env_quadrature`).

Cameras: the view vector is ``normalize(camera − p)`` per pixel, so a sample-grid shot
(:meth:`Shot.in_sample_grid`) gives exactly the camera's image, and any other camera position
gives the *texture-space* render used by rendering losses (pixel (i, j) still shows grid point
(i, j), seen from ``camera``). :func:`view_shot` builds such shots.

Every Python number that varies between calls (camera, light, intensity, env scale) is made
opaque, so one kernel serves all calls with the same shapes, mode and spp.
"""

from __future__ import annotations

from collections.abc import Sequence

import drjit as dr
import mitsuba as mi
import numpy as np

from ..brdf import brdf_eval_cos
from ..errors import InputError
from ..geometry import DEFAULT_FLASH_INTENSITY, NEAR_FOV, Shot
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF
from .env_quadrature import quadrature_environment
from .env_sg import sg_environment
from .inputs import DrLobes, DrMaps, RenderOptions
from .points import ShadingPoints, opaque_point, points_from_maps


def _require_variant() -> None:
    if mi.variant() is None:
        from ..variant import ensure_variant

        ensure_variant()


def view_shot(
    camera, light=None, intensity: float = DEFAULT_FLASH_INTENSITY, env: bool = True, name: str = "view"
) -> Shot:
    """A shot from an arbitrary ``camera`` position with an optional point ``light`` (positions in
    world units, z > 0 above the sample), for rendering losses over random view/light pairs."""
    return Shot(
        name,
        tuple(float(c) for c in camera),
        NEAR_FOV,
        None if light is None else tuple(float(c) for c in light),
        float(intensity),
        env,
    )


def check_shot(shot: Shot) -> None:
    if not isinstance(shot, Shot):
        raise InputError(f"render: shot must be an ebr_mitsuba.geometry.Shot (got {type(shot).__name__})")
    if not float(shot.camera[2]) > 0.0:
        raise InputError(
            f"render: shot '{shot.name}' has its camera at z = {shot.camera[2]}, not above "
            f"the sample plane; place the camera at z > 0"
        )
    if shot.flash is not None and not (np.isfinite(shot.flash_intensity) and shot.flash_intensity >= 0):
        raise InputError(
            f"render: shot '{shot.name}' has flash intensity {shot.flash_intensity}; give a finite value >= 0"
        )


def point_light(
    points: ShadingPoints, positions: mi.Vector3f, light, intensity, fresnel: str = "schlick"
) -> mi.Color3f:
    """``f(l, v) · max(n·l, 0) · I / d²`` per point; ``light`` a 3-vector, ``intensity`` I [W/sr]."""
    to_light = light - positions
    dist2 = dr.squared_norm(to_light)
    l = to_light * dr.rsqrt(dr.maximum(dist2, 1e-12))
    fcos = brdf_eval_cos(points.n, l, points.v, points.diffuse, points.specular, points.roughness, fresnel)
    return fcos * (intensity / dr.maximum(dist2, 1e-12))


def environment(
    points: ShadingPoints,
    lobes: DrLobes,
    options: RenderOptions,
    guide: tuple[ShadingPoints, DrLobes] | None = None,
) -> mi.Color3f:
    """The environment term (without ``env_scale``) in the selected mode."""
    if options.mode == "sg":
        return sg_environment(
            points,
            lobes,
            fresnel=options.fresnel,
            irradiance_nodes=options.irradiance_nodes,
            table_resolution=options.irradiance_table,
            lobe_loop=options.lobe_loop,
        )
    return quadrature_environment(
        points,
        lobes,
        spp=options.spp,
        fresnel=options.fresnel,
        max_lanes=options.max_lanes,
        seed=options.seed,
        guide=guide,
    )


def render(
    maps: DrMaps,
    lobes: DrLobes,
    shot: Shot,
    options: RenderOptions | None = None,
    *,
    guide: tuple[DrMaps, DrLobes] | None = None,
) -> mi.TensorXf:
    """Render ``maps`` under ``lobes`` and the shot's point light: (H, W, 3) ``mi.TensorXf``.

    Differentiable w.r.t. every map tensor and lobe array. ``guide`` (quadrature mode only): the
    maps and lobes the sample directions are drawn from, default detached copies of the inputs;
    pass fixed ones to make the estimate a smooth function of the parameters.
    """
    _require_variant()
    options = options or RenderOptions()
    check_shot(shot)
    if not isinstance(maps, DrMaps) or not isinstance(lobes, DrLobes):
        raise InputError(
            "render: give the maps as DrMaps and the lobes as DrLobes "
            "(DrMaps.from_numpy(svbrdf), DrLobes.from_env(env))"
        )
    h, w = maps.shape
    camera = opaque_point(shot.camera)
    points, positions = points_from_maps(maps, camera, options.window)
    image = dr.zeros(mi.Color3f, h * w)
    if shot.flash is not None:
        image = image + point_light(
            points,
            positions,
            opaque_point(shot.flash),
            dr.opaque(mi.Float, float(shot.flash_intensity)),
            options.fresnel,
        )
    if shot.env and lobes.num_lobes > 0:
        guide_pts = None
        if guide is not None:
            if guide[0].shape != maps.shape or guide[1].num_lobes != lobes.num_lobes:
                raise InputError("render: the guide must have the shapes of the maps and lobes")
            guide_pts = (points_from_maps(guide[0], camera, options.window)[0], guide[1])
        env = environment(points, lobes, options, guide_pts)
        image = image + env * dr.opaque(mi.Float, float(options.env_scale))
    return mi.TensorXf(dr.ravel(image), (h, w, 3))


def render_shots(
    maps: DrMaps, lobes: DrLobes, shots: Sequence[Shot], options: RenderOptions | None = None
) -> list[mi.TensorXf]:
    """:func:`render` of one set of maps for several shots, sharing the work between shots from
    the same camera: their shading points and environment term are computed once (a flash /
    no-flash pair costs one environment term, not two). Same values as calling :func:`render`
    per shot; differentiable likewise."""
    _require_variant()
    options = options or RenderOptions()
    if not isinstance(maps, DrMaps) or not isinstance(lobes, DrLobes):
        raise InputError("render_shots: give the maps as DrMaps and the lobes as DrLobes")
    for shot in shots:
        check_shot(shot)
    h, w = maps.shape
    per_camera: dict[tuple, tuple] = {}
    out = []
    for shot in shots:
        key = tuple(float(c) for c in shot.camera)
        if key not in per_camera:
            points, positions = points_from_maps(maps, opaque_point(shot.camera), options.window)
            per_camera[key] = (points, positions, None)
        points, positions, env = per_camera[key]
        image = dr.zeros(mi.Color3f, h * w)
        if shot.flash is not None:
            image = image + point_light(
                points,
                positions,
                opaque_point(shot.flash),
                dr.opaque(mi.Float, float(shot.flash_intensity)),
                options.fresnel,
            )
        if shot.env and lobes.num_lobes > 0:
            if env is None:
                env = environment(points, lobes, options) * dr.opaque(mi.Float, float(options.env_scale))
                per_camera[key] = (points, positions, env)
            image = image + env
        out.append(mi.TensorXf(dr.ravel(image), (h, w, 3)))
    return out


def render_numpy(
    svbrdf: SVBRDF,
    env: SGEnvironment | None,
    shot: Shot,
    mode: str = "sg",
    spp: int = 64,
    env_scale: float = 1.0,
    **options,
) -> np.ndarray:
    """numpy convenience: (H, W, 3) float32 render of ``svbrdf`` under ``env`` (None: no
    environment). Extra keyword arguments go to :class:`RenderOptions`."""
    _require_variant()
    opts = RenderOptions(mode=mode, spp=spp, env_scale=env_scale, **options)
    lobes = DrLobes.from_env(env if env is not None else SGEnvironment.empty())
    with dr.suspend_grad():
        image = render(DrMaps.from_numpy(svbrdf), lobes, shot, opts)
    return np.asarray(image.numpy(), dtype=np.float32)
