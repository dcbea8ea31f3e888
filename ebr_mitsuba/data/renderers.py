"""The clean (noise-free camera, linear radiance) images of one sample, with either renderer.

For every shot of the setup (:func:`ebr_mitsuba.geometry.setup_shots`, flash intensity from the
config) the image is the sum of two renders, the flash alone (environment off) and the environment
alone (flash off); their expectations add exactly, and the flash-only image of the shot is the
first part. The exemplars are the uniform material (diffuse 0.1, specular 0.2 grey, roughness r,
flat normal) seen by the near camera: environment exemplars with the flash off, point-light
exemplars with the near flash alone.

==========  ===========================================================================================
renderer    how
==========  ===========================================================================================
mitsuba     :func:`ebr_mitsuba.capture.render_shot` (``svbrdf`` BSDF plugin, ``direct`` or ``path``
            integrator, ``spp`` samples, box filter). SG environments through the ``sgenvmap``
            emitter; map-lit samples through Mitsuba's ``envmap`` of the map itself, rotated about z
            and scaled. Sampler seed of render j: ``SampleDraw.render_seeds[j]``.
fast        :func:`ebr_mitsuba.render.render_numpy` / :func:`~ebr_mitsuba.exemplar.images.exemplar_images`
            (``fast_mode`` ``sg`` closed form or ``quadrature`` with ``fast_spp`` directions).
            Map-lit samples are rendered under the map's SG fit (the fast renderer knows only SGs).
            Shots outside the sample grid (multi-view) are texture-space renders (see
            :mod:`ebr_mitsuba.render.fast`).
==========  ===========================================================================================

Render j's index, for seeds, counts the renders in this order: per shot flash part then environment
part (parts that do not exist are skipped but keep their index), then environment exemplars,
then point-light exemplars.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from ..exemplar.images import exemplar_material
from ..geometry import Shot, capture_shots, near_shot, setup_shots
from ..svbrdf import SVBRDF
from .config import GenerateConfig
from .sample import EnvDraw, SampleDraw, equirect_map


@dataclass
class CleanImages:
    """Linear radiance images (H, W, 3) float32 of one sample.

    ``shots``: one per shot of the setup, by name; ``flash_only``: by shot name, for the shots lit
    by both the flash and the environment; ``env_exemplars`` / ``point_exemplars``: one per roughness
    of the config, in its order.
    """

    shots: dict = field(default_factory=dict)
    flash_only: dict = field(default_factory=dict)
    env_exemplars: list = field(default_factory=list)
    point_exemplars: list = field(default_factory=list)


def shots_of(config: GenerateConfig) -> list[Shot]:
    """The shots of the config's setup (with ``capture.noflash_view``, those of ``ebr capture``:
    the multi-view setup's no-flash view last)."""
    shots = capture_shots if config.capture.noflash_view else setup_shots
    return shots(config.capture.setup, intensity=config.capture.flash_intensity)


def has_flash_only(shot: Shot) -> bool:
    """Whether a shot gets a flash-only image (lit by the flash and by the environment)."""
    return shot.flash is not None and shot.env


class _Mitsuba:
    def __init__(self, config: GenerateConfig, env: EnvDraw):
        import mitsuba as mi

        from ..scene import sg_emitter_dict

        self.config = config
        self.mi = mi
        self.emitter = None
        if env.kind == "equirect":
            self.emitter = mi.load_dict(_rotated_envmap_dict(env))
        elif env.kind == "sg" and env.sg.num_lobes > 0:
            self.emitter = mi.load_dict(sg_emitter_dict(env.sg))

    def render(self, svbrdf: SVBRDF, shot: Shot, seed: int, bsdf=None) -> np.ndarray:
        from ..capture import render_shot
        from ..scene import svbrdf_bsdf_dict

        if bsdf is None:
            bsdf = self.mi.load_dict(svbrdf_bsdf_dict(svbrdf))
        r = self.config.render
        return render_shot(svbrdf, self.emitter, shot, r.spp, seed, r.integrator, bsdf=bsdf)

    def bsdf(self, svbrdf: SVBRDF):
        from ..scene import svbrdf_bsdf_dict

        return self.mi.load_dict(svbrdf_bsdf_dict(svbrdf))

    def env_exemplars(self, roughness, size: int, shot: Shot, seeds) -> list:
        return [self.render(exemplar_material(size, r), shot, s) for r, s in zip(roughness, seeds)]


def rotated_envmap_dict(map_path: str, rotation: float, scale: float) -> dict:
    """The Mitsuba ``envmap`` emitter of the equirectangular map at ``map_path`` turned by
    ``rotation`` radians about z and scaled by ``scale``: a sample's environment as it was rendered
    (``sample.json``'s ``env``: ``map.path``, ``rotation``, ``scale``)."""
    import mitsuba as mi

    from ..envmap import ENVMAP_TO_WORLD, envmap_emitter_dict

    c, s = math.cos(rotation), math.sin(rotation)
    rot = np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    d = envmap_emitter_dict(equirect_map(map_path), scale=scale)
    d["to_world"] = mi.ScalarTransform4f((rot @ ENVMAP_TO_WORLD).tolist())
    return d


def _rotated_envmap_dict(env: EnvDraw) -> dict:
    return rotated_envmap_dict(env.map_path, env.rotation, env.scale)


def _fast_seed(seed: int) -> int:
    """The quadrature pattern seed: kept below 2**28 (the renderer multiplies it by 8 in 32 bits)."""
    return int(seed) % (1 << 28)


class _Fast:
    def __init__(self, config: GenerateConfig, env: EnvDraw):
        self.config = config
        self.env = env.sg if env.sg.num_lobes > 0 else None

    def render(self, svbrdf: SVBRDF, shot: Shot, seed: int, bsdf=None) -> np.ndarray:
        from ..render import render_numpy

        r = self.config.render
        env = self.env if shot.env else None
        return render_numpy(svbrdf, env, shot, mode=r.fast_mode, spp=r.fast_spp, seed=_fast_seed(seed))

    def bsdf(self, svbrdf: SVBRDF):
        return None

    def env_exemplars(self, roughness, size: int, shot: Shot, seeds) -> list:
        from ..exemplar.images import exemplar_images
        from ..render import RenderOptions

        if self.env is None:
            return [np.zeros((size, size, 3), np.float32) for _ in roughness]
        r = self.config.render
        opts = RenderOptions(mode=r.fast_mode, spp=r.fast_spp, seed=_fast_seed(seeds[0]))
        images = exemplar_images(self.env, list(roughness), size, size, shot=shot, options=opts)
        return [np.asarray(im.numpy(), dtype=np.float32) for im in images]


def render_clean(config: GenerateConfig, draw: SampleDraw, renderer: str | None = None) -> CleanImages:
    """The clean images of ``draw`` (module docstring); ``renderer`` overrides the config's."""
    name = renderer or config.render.renderer
    backend = _Mitsuba(config, draw.env) if name == "mitsuba" else _Fast(config, draw.env)
    size = config.dataset.resolution
    has_env = draw.env.kind != "none"
    out = CleanImages()
    seeds = iter(draw.render_seeds)
    bsdf = backend.bsdf(draw.svbrdf)
    zero = np.zeros((size, size, 3), np.float32)
    for shot in shots_of(config):
        s_flash, s_env = next(seeds), next(seeds)
        flash = zero
        if shot.flash is not None:
            flash = backend.render(draw.svbrdf, dataclasses.replace(shot, env=False), s_flash, bsdf)
        env = zero
        if shot.env and has_env:
            env = backend.render(draw.svbrdf, dataclasses.replace(shot, flash=None), s_env, bsdf)
        out.shots[shot.name] = (flash + env).astype(np.float32)
        if has_flash_only(shot):
            out.flash_only[shot.name] = np.asarray(flash, np.float32)
    ex = config.exemplars
    near = near_shot(False, intensity=config.capture.flash_intensity)
    env_seeds = [next(seeds) for _ in ex.env_roughness]
    if ex.env_roughness:
        if has_env:
            out.env_exemplars = backend.env_exemplars(ex.env_roughness, size, near, env_seeds)
        else:
            out.env_exemplars = [zero.copy() for _ in ex.env_roughness]
    point = dataclasses.replace(near_shot(True, intensity=config.capture.flash_intensity), env=False)
    for r in ex.point_roughness:
        out.point_exemplars.append(backend.render(exemplar_material(size, r), point, next(seeds)))
    return out
