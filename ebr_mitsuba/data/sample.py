"""What one sample of a generated data set contains, drawn deterministically from (seed, index).

Every random choice of sample ``i`` comes from ``np.random.default_rng(SeedSequence([seed, i,
stream]))`` with one stream per concern, so a sample depends on nothing but the config and its
index (not on the worker that makes it, nor on the samples made before it):

==========  =======  ========================================================================
stream      value    draws (always all of them, in this order, whatever the config)
==========  =======  ========================================================================
choice      0        material source, environment source (probability ∝ ``weight``)
material    1        family/path, seed, second family/path + seed (blend partner), augment seed
environment 2        procedural: kind, level, seed; map/sg: path, rotation, level
camera      3        exposure jitter, white-balance gains, read noise, shot noise, noise seed
render      4        sampler seeds of the renders (Mitsuba) / quadrature pattern seeds (fast)
==========  =======  ========================================================================

:func:`draw_sample` returns a :class:`SampleDraw`: the SVBRDF at the data set's resolution, the
ground-truth environment (:class:`EnvDraw`: SG lobes in radiance units, and for map-lit samples the
map, its rotation about z and its scale), the camera (:class:`CameraDraw`) and JSON records of all
of it for ``sample.json``. Real materials and maps are loaded once per process (cached by path).

Map-lit samples (``type = "equirect"``): the map is rotated about z by a uniform angle and scaled so
that its irradiance on the sample (normal +z, exact texel sum) is ``level × FLASH_IRRADIANCE``
(:mod:`ebr_mitsuba.procedural.environments`); the SG ground truth is the map's fit (made once per
data set by :func:`prepare_maps`, stored in ``envs/``) rotated and scaled the same way.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..colour import LUMINANCE
from ..errors import InputError
from ..procedural import FAMILIES, FLASH_IRRADIANCE, INTENSITY_LEVELS, AugmentSettings, augment, make_material
from ..procedural import make_environment as procedural_environment
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF
from .config import (
    DirectoryMaterials,
    EquirectEnvironments,
    GenerateConfig,
    NoEnvironment,
    ProceduralEnvironments,
    ProceduralMaterials,
    SGEnvironments,
)

STREAMS = {"choice": 0, "material": 1, "environment": 2, "camera": 3, "render": 4}
SEED_BOUND = 2**31


def stream_rng(seed: int, index: int, stream: str) -> np.random.Generator:
    """The generator of ``stream`` (see the module docstring) for sample ``index``."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(index), STREAMS[stream]]))


def _pick(rng: np.random.Generator, weights) -> int:
    w = np.asarray(weights, dtype=np.float64)
    cdf = np.cumsum(w) / w.sum()
    return int(min(np.searchsorted(cdf, rng.uniform(), side="right"), len(w) - 1))


# -- prepared equirectangular maps ----------------------------------------------------------------


@dataclass(frozen=True)
class PreparedMap:
    """An equirectangular map of the config, with its SG fit (made once per data set).

    ``fit_file`` is relative to the data-set root; ``irradiance`` the luminance of the map's
    irradiance on the sample plane (at file scale); ``fit_error`` as :func:`ebr_mitsuba.envfit.fit_error`.
    """

    path: str
    name: str
    sha256: str
    fit: SGEnvironment
    fit_file: str
    fit_error: dict
    irradiance: float

    def record(self) -> dict:
        return {
            "path": self.path,
            "name": self.name,
            "sha256": self.sha256,
            "sg_fit": self.fit_file,
            "lobes": self.fit.num_lobes,
            "fit_rel_l1": round(float(self.fit_error["rel_l1"]), 6),
        }


@dataclass(frozen=True)
class Plan:
    """Everything a worker needs to make any sample: the config and the prepared maps (by path)."""

    config: GenerateConfig
    maps: dict = field(default_factory=dict)
    variant: str = "llvm_ad_rgb"


def fit_file_name(path: str, sha256: str, lobes: int, iterations: int) -> str:
    return f"envs/{Path(path).stem}-{sha256[:12]}-k{lobes}-i{iterations}.json"


def prepare_maps(config: GenerateConfig, root: Path, progress=None) -> dict:
    """Fit (or load from ``root/envs``) the SG ground truth of every equirect map of ``config``.

    The fit is saved first and the saved file is what every sample uses, so a fresh run and a
    resumed one use identical lobes. Returns ``{path: PreparedMap}``.
    """
    from ..envfit import equirect_irradiance, fit_error, fit_sg, resample_equirect
    from ..fsutil import atomic_write_text
    from ..sources import file_sha256

    out = {}
    for src in config.environments:
        if not isinstance(src, EquirectEnvironments):
            continue
        for path in src.paths:
            if path in out:
                continue
            emap = _load_map(path)
            sha = file_sha256(Path(path))
            rel = fit_file_name(path, sha, src.lobes, src.fit_iterations)
            target = root / rel
            info_file = target.with_suffix(".fit.json")
            if not target.is_file() or not info_file.is_file():
                if progress is not None:
                    progress(f"fitting {src.lobes} SG lobes to {Path(path).name}")
                result = fit_sg(emap, lobes=src.lobes, iterations=src.fit_iterations)
                result.env.save(target)
                info = {
                    "map": path,
                    "sha256": sha,
                    "settings": result.settings,
                    "error": result.error,
                    "initial_error": result.initial_error,
                }
                atomic_write_text(info_file, json.dumps(info, indent=1, default=float) + "\n")
            fit = SGEnvironment.load(target)
            error = fit_error(fit, resample_equirect(emap, 128))
            irr = float(equirect_irradiance(emap) @ LUMINANCE)
            if not irr > 0:
                raise InputError(
                    f"{path}: the map gives no light on the sample (zero irradiance from "
                    f"above); give a map with a lit upper hemisphere"
                )
            out[path] = PreparedMap(path, Path(path).name, sha, fit, rel, error, irr)
    return out


# -- process-wide caches of real assets ----------------------------------------------------------


@functools.lru_cache(maxsize=16)
def _load_map(path: str):
    from ..envmap import load_equirect

    return load_equirect(path)


@functools.lru_cache(maxsize=32)
def _load_material(path: str, size: int) -> SVBRDF:
    from ..materials import load_material
    from ..sources import center_square, fit_to_resolution

    # real sets keep the photo's aspect (1024×596, ...): their centred square is what is drawn
    return fit_to_resolution(center_square(load_material(path)), size, source=path)


@functools.lru_cache(maxsize=64)
def _load_sg(path: str) -> SGEnvironment:
    return SGEnvironment.load(path)


@functools.lru_cache(maxsize=64)
def _sg_irradiance(path: str) -> float:
    from ..procedural import irradiance_luminance

    return irradiance_luminance(_load_sg(path))


def equirect_map(path: str):
    """The (cached) :class:`~ebr_mitsuba.envmap.EquirectMap` at ``path``."""
    return _load_map(path)


# -- draws -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class EnvDraw:
    """The ground-truth environment of a sample.

    ``kind``: ``"sg"`` (procedural or env.json: rendered from the lobes), ``"equirect"`` (rendered
    from the map ``map_path`` rotated by ``rotation`` about z and scaled by ``scale``; ``sg`` is the
    rotated, scaled fit) or ``"none"`` (dark; ``sg`` has no lobes).
    """

    kind: str
    sg: SGEnvironment
    record: dict
    map_path: str | None = None
    rotation: float = 0.0
    scale: float = 1.0


@dataclass(frozen=True)
class CameraDraw:
    """The LDR simulation of one sample (see :mod:`.camera`)."""

    exposure: float
    white_balance: tuple[float, float, float]
    read_noise: float
    shot_noise: float
    clip: bool
    quantize: bool
    noise_seed: int

    def record(self) -> dict:
        return {
            "exposure": self.exposure,
            "white_balance": list(self.white_balance),
            "read_noise": self.read_noise,
            "shot_noise": self.shot_noise,
            "clip": self.clip,
            "quantize": self.quantize,
            "noise_seed": self.noise_seed,
        }


@dataclass(frozen=True)
class SampleDraw:
    index: int
    svbrdf: SVBRDF
    material: dict
    env: EnvDraw
    camera: CameraDraw
    render_seeds: tuple[int, ...]


def render_count(config: GenerateConfig) -> int:
    """Renders per sample: two per shot (flash part, environment part) plus the exemplars."""
    from ..geometry import setup_shots

    ex = config.exemplars
    shots = len(setup_shots(config.capture.setup)) + bool(config.capture.noflash_view)
    return 2 * shots + len(ex.env_roughness) + len(ex.point_roughness)


def draw_sample(plan: Plan, index: int) -> SampleDraw:
    """Draw sample ``index`` of ``plan`` (module docstring)."""
    cfg = plan.config
    seed = cfg.dataset.seed
    choice = stream_rng(seed, index, "choice")
    m_idx = _pick(choice, [m.weight for m in cfg.materials])
    e_idx = _pick(choice, [e.weight for e in cfg.environments])
    svbrdf, material = _draw_material(
        cfg.materials[m_idx], stream_rng(seed, index, "material"), cfg.dataset.resolution
    )
    material["source_index"] = m_idx
    env = _draw_env(cfg.environments[e_idx], stream_rng(seed, index, "environment"), plan)
    env.record["source_index"] = e_idx
    camera = _draw_camera(cfg, stream_rng(seed, index, "camera"))
    seeds = stream_rng(seed, index, "render").integers(0, SEED_BOUND, render_count(cfg))
    render_seeds = tuple(int(s) for s in seeds)
    return SampleDraw(int(index), svbrdf, material, env, camera, render_seeds)


def _draw_material(src, rng: np.random.Generator, res: int) -> tuple[SVBRDF, dict]:
    if isinstance(src, ProceduralMaterials):
        families = src.families or list(FAMILIES)
        fam = families[int(rng.integers(len(families)))]
        mseed = int(rng.integers(SEED_BOUND))
        fam2 = families[int(rng.integers(len(families)))]
        mseed2 = int(rng.integers(SEED_BOUND))
        aug_seed = int(rng.integers(SEED_BOUND))
        svbrdf = make_material(fam, mseed, res)
        record = {"type": "procedural", "spec": f"procedural:{fam}:{mseed}", "family": fam, "seed": mseed}
        other = make_material(fam2, mseed2, res) if (src.augment and src.blend > 0) else None
        partner = f"procedural:{fam2}:{mseed2}"
        work = res
    elif isinstance(src, DirectoryMaterials):
        paths = src.paths
        path = paths[int(rng.integers(len(paths)))]
        rng.integers(SEED_BOUND)  # keeps the draw order of the procedural branch
        path2 = paths[int(rng.integers(len(paths)))]
        rng.integers(SEED_BOUND)
        aug_seed = int(rng.integers(SEED_BOUND))
        work = 2 * res if src.augment else res  # headroom for the zoom of the augmentation
        svbrdf = _load_material(path, work)
        record = {"type": "directory", "spec": path, "path": path}
        other = _load_material(path2, work) if (src.augment and src.blend > 0) else None
        partner = path2
    else:  # pragma: no cover - the config parser admits no other type
        raise TypeError(f"unknown material source {src!r}")
    if src.augment:
        settings = AugmentSettings().replace(blend=src.blend)
        svbrdf = augment(svbrdf, np.random.default_rng(aug_seed), other, settings)
        record["augment"] = {
            "seed": aug_seed,
            "blend": src.blend,
            "blend_partner": partner if other is not None else None,
            "operations": svbrdf.source,
        }
    if svbrdf.shape != (res, res):
        from ..materials import resample_svbrdf

        svbrdf = resample_svbrdf(svbrdf, res)
    return svbrdf, record


def _level_scale(rng: np.random.Generator, levels, irradiance: float) -> tuple[str | None, float]:
    if not levels:
        rng.integers(len(INTENSITY_LEVELS))
        return None, 1.0
    level = levels[int(rng.integers(len(levels)))]
    return level, INTENSITY_LEVELS[level] * FLASH_IRRADIANCE / irradiance


def _draw_env(src, rng: np.random.Generator, plan: Plan) -> EnvDraw:
    if isinstance(src, NoEnvironment):
        return EnvDraw("none", SGEnvironment.empty(), {"type": "none"})
    if isinstance(src, ProceduralEnvironments):
        kind = src.kinds[int(rng.integers(len(src.kinds)))]
        level = src.levels[int(rng.integers(len(src.levels)))]
        eseed = int(rng.integers(SEED_BOUND))
        env = procedural_environment(eseed, kind=kind, intensity=level)
        return EnvDraw(
            "sg",
            env,
            {
                "type": "procedural",
                "spec": f"procedural:{eseed}",
                "kind": kind,
                "level": level,
                "seed": eseed,
            },
        )
    path = src.paths[int(rng.integers(len(src.paths)))]
    angle = float(rng.uniform(0.0, 2.0 * math.pi))
    if not src.rotate:
        angle = 0.0
    if isinstance(src, EquirectEnvironments):
        prepared: PreparedMap = plan.maps[path]
        level, scale = _level_scale(rng, src.levels, prepared.irradiance)
        sg = prepared.fit.rotated_z(angle).scaled(scale)
        record = {
            "type": "equirect",
            "map": prepared.record(),
            "rotation": angle,
            "scale": scale,
            "level": level,
        }
        return EnvDraw("equirect", sg, record, map_path=path, rotation=angle, scale=scale)
    if isinstance(src, SGEnvironments):
        base = _load_sg(path)
        level, scale = _level_scale(rng, src.levels, _sg_irradiance(path) if src.levels else 1.0)
        sg = base.rotated_z(angle).scaled(scale)
        return EnvDraw(
            "sg", sg, {"type": "sg", "path": path, "rotation": angle, "scale": scale, "level": level}
        )
    raise TypeError(f"unknown environment source {src!r}")  # pragma: no cover


def _draw_camera(cfg: GenerateConfig, rng: np.random.Generator) -> CameraDraw:
    cam = cfg.camera
    ev = float(rng.uniform(*cam.exposure_ev))  # low == high gives low (one draw either way)
    gains = rng.uniform(1.0 - cam.white_balance, 1.0 + cam.white_balance, size=2)
    read = float(rng.uniform(*cam.read_noise))
    shot = float(rng.uniform(*cam.shot_noise))
    noise_seed = int(rng.integers(SEED_BOUND))
    return CameraDraw(
        exposure=float(cam.exposure * 2.0**ev),
        white_balance=(float(gains[0]), 1.0, float(gains[1])),
        read_noise=read,
        shot_noise=shot,
        clip=cam.clip,
        quantize=cam.quantize,
        noise_seed=noise_seed,
    )
