"""Ground-truth validation: our plugins against Mitsuba's built-ins, and the fast renderer against
path-traced references.

A validation *case* is a Mitsuba XML scene of the sample plane with constant maps (our ``svbrdf``
BSDF, our ``sgenvmap`` emitter, an optional point light) plus a view direction and the claims to
check. Cases live in ``scenes/validation.toml``; any XML scene with the same ids (``sample`` with a
constant-map ``svbrdf``, ``env`` an ``sgenvmap``, ``light`` a point light) can be validated too.

Comparisons are made at ``points`` surface points spread over the sample, each seen from the case's
view direction at distance 2.14, through :func:`ebr_mitsuba.pathref.trace` (Mitsuba's ``path``
integrator on explicit rays, with per-point standard errors):

* ``fast-sg`` / ``fast-quadrature``: the fast renderer (:mod:`ebr_mitsuba.render`) against the
  path-traced reference of the XML scene;
* ``builtin-bsdf``: ``svbrdf`` (``fresnel="none"``) against ``normalmap(blendbsdf(0.5, diffuse(2d),
  roughconductor(ggx, α=r², material="none", 2F₀)))`` under the same built-in ``envmap``;
* ``builtin-emitter``: ``sgenvmap`` against a built-in ``envmap`` rasterised from the same lobes,
  both lighting the same built-in BSDF.

Every comparison reports ``rel_rmse = ‖a − b‖ / ‖reference‖`` (RMS over points and channels) and
passes when ``rel_rmse ≤ 3·noise + budget``: ``noise`` is the measured relative Monte-Carlo
standard error of the difference (both sides when both are path traced), so 3·noise is the
difference pure noise stays below, and ``budget`` is the systematic error the case allows (1% for
plugin-vs-built-in; per mode for the fast renderer, stated in validation.toml).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import tomllib

from .errors import ConfigError, InputError
from .metrics import rel_rmse
from .typedconfig import config, option

VIEW_DISTANCE = 2.14
DEFAULT_SPP = 131072
DEFAULT_BUDGETS = {"fast-sg": 0.05, "fast-quadrature": 0.02, "builtin-bsdf": 0.01, "builtin-emitter": 0.01}
CHECKS = tuple(DEFAULT_BUDGETS)


@config(error=InputError)
class ValidateConfig:
    """How :func:`run_case` traces its references (the options of ``ebr validate``; a bad value is
    an :class:`~ebr_mitsuba.errors.InputError`)."""

    spp: int = option(DEFAULT_SPP, "samples per point of the path-traced references", minimum=1)
    seed: int = option(0, "seed of the references", minimum=0)


#: The fields ``ebr validate`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
VALIDATE_FLAGS = ("spp", "seed")


def _validate_config(config, options) -> ValidateConfig:
    if config is not None and not isinstance(config, ValidateConfig):
        raise TypeError(f"config must be a ValidateConfig, got {config!r}")
    return dataclasses.replace(config or ValidateConfig(), **options)


@dataclass(frozen=True)
class Case:
    """One validation case (see the module docstring); ``params`` are the scene's ``-D`` values."""

    name: str
    scene: Path
    params: dict = field(default_factory=dict)
    view_deg: float = 30.0
    view_azimuth_deg: float = 20.0
    points: int = 48
    checks: tuple = ("fast-sg", "fast-quadrature")
    budgets: dict = field(default_factory=dict)
    quadrature_spp: int = 256
    note: str = ""

    def budget(self, check: str) -> float:
        return float(self.budgets.get(check, DEFAULT_BUDGETS[check]))


_CASE_KEYS = {
    "name",
    "scene",
    "params",
    "view_deg",
    "view_azimuth_deg",
    "points",
    "checks",
    "budgets",
    "quadrature_spp",
    "note",
}


def bundled_cases_file() -> Path:
    return Path(str(resources.files("ebr_mitsuba.scenes") / "validation.toml"))


def load_cases(path: Path | None = None) -> list[Case]:
    """Read the ``[[case]]`` tables of a validation TOML (default: the bundled one)."""
    path = Path(path) if path else bundled_cases_file()
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: no such validation file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: malformed TOML ({exc}); fix the file") from None
    cases = []
    for i, entry in enumerate(data.get("case", [])):
        unknown = set(entry) - _CASE_KEYS
        if unknown:
            raise ConfigError(
                f"{path}: case {i}: unknown key(s) {sorted(unknown)}; allowed: {sorted(_CASE_KEYS)}"
            )
        if "name" not in entry or "scene" not in entry:
            raise ConfigError(f"{path}: case {i} needs 'name' and 'scene'")
        checks = tuple(entry.get("checks", ("fast-sg", "fast-quadrature")))
        bad = [c for c in checks if c not in CHECKS]
        if bad:
            raise ConfigError(f"{path}: case {entry['name']}: unknown check(s) {bad}; use {list(CHECKS)}")
        cases.append(
            Case(
                name=str(entry["name"]),
                scene=(path.parent / entry["scene"]).resolve(),
                params={k: str(v) for k, v in entry.get("params", {}).items()},
                view_deg=float(entry.get("view_deg", 30.0)),
                view_azimuth_deg=float(entry.get("view_azimuth_deg", 20.0)),
                points=int(entry.get("points", 48)),
                checks=checks,
                budgets=dict(entry.get("budgets", {})),
                quadrature_spp=int(entry.get("quadrature_spp", 256)),
                note=str(entry.get("note", "")),
            )
        )
    return cases


# -- scene contents -----------------------------------------------------------------------------


@dataclass(frozen=True)
class PlaneScene:
    """What a validation scene contains, read back from Mitsuba (numpy, world z-up)."""

    normal: np.ndarray  # (3,)
    diffuse: np.ndarray  # (3,)
    specular: np.ndarray  # (3,)
    roughness: float
    axis: np.ndarray  # (K, 3)
    sharpness: np.ndarray  # (K,)
    amplitude: np.ndarray  # (K, 3), env scale applied
    light: np.ndarray | None  # (3,) or None
    intensity: np.ndarray  # (3,)


def read_plane_scene(scene, source: str) -> PlaneScene:
    import mitsuba as mi

    p = mi.traverse(scene)

    def get(key, n):
        if key not in p:
            raise InputError(
                f"{source}: validation needs parameter '{key}' (a constant-map 'svbrdf' on a "
                f"shape with id 'sample', an 'sgenvmap' with id 'env', a point light 'light')"
            )
        return np.array(p[key], dtype=np.float64).reshape(-1)[:n] if n else np.array(p[key], dtype=np.float64)

    k_axis = np.array(p["env.axis"], dtype=np.float64).reshape(-1, 3) if "env.axis" in p else None
    if k_axis is None:
        raise InputError(f"{source}: validation needs an 'sgenvmap' emitter with id 'env'")
    scale = float(np.array(p["env.scale"]).reshape(-1)[0]) if "env.scale" in p else 1.0
    normal = get("sample.bsdf.normal.value", 3) if "sample.bsdf.normal.value" in p else np.array([0, 0, 1.0])
    light = get("light.position", 3) if "light.position" in p else None
    intensity = get("light.intensity.value", 3) if "light.intensity.value" in p else np.zeros(3)
    return PlaneScene(
        normal=normal / np.linalg.norm(normal),
        diffuse=np.broadcast_to(get("sample.bsdf.diffuse.value", 3), (3,)).copy(),
        specular=np.broadcast_to(get("sample.bsdf.specular.value", 3), (3,)).copy(),
        roughness=float(get("sample.bsdf.roughness.value", 1)[0]),
        axis=k_axis,
        sharpness=np.array(p["env.sharpness"], dtype=np.float64).reshape(-1),
        amplitude=np.array(p["env.amplitude"], dtype=np.float64).reshape(-1, 3) * scale,
        light=light,
        intensity=intensity,
    )


def query_geometry(case: Case) -> tuple[np.ndarray, np.ndarray]:
    """Surface points (P, 3) on a jittered grid over [-0.8, 0.8]² and the camera positions (P, 3)."""
    side = max(1, int(math.ceil(math.sqrt(case.points))))
    rng = np.random.default_rng(7)
    g = (np.arange(side) + 0.5) / side * 1.6 - 0.8
    xx, yy = np.meshgrid(g, g)
    pts = np.stack([xx.ravel(), yy.ravel(), np.zeros(side * side)], axis=1)[: case.points]
    pts[:, :2] += rng.uniform(-0.4, 0.4, (pts.shape[0], 2)) * (1.6 / side)
    th = math.radians(case.view_deg)
    ph = math.radians(case.view_azimuth_deg)
    d = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    return pts, pts + VIEW_DISTANCE * d[None, :]


def fast_radiance(scene: PlaneScene, pts: np.ndarray, cams: np.ndarray, mode: str, spp: int) -> np.ndarray:
    """The fast renderer's radiance (P, 3) at ``pts`` towards ``cams``."""
    import drjit as dr
    import mitsuba as mi

    from .brdf import perturbed_normal
    from .render.fast import point_light
    from .render.inputs import DrLobes
    from .render.points import ShadingPoints

    count = pts.shape[0]
    v = cams - pts
    v /= np.linalg.norm(v, axis=1, keepdims=True)

    def vec(a, kind=mi.Vector3f):
        a = np.broadcast_to(np.asarray(a, np.float32), (count, 3))
        return kind(a[:, 0].copy(), a[:, 1].copy(), a[:, 2].copy())

    n = perturbed_normal(vec(scene.normal))
    rough = mi.Float(np.full(count, scene.roughness, np.float32))
    sp = ShadingPoints(
        n,
        vec(v),
        vec(scene.diffuse, mi.Color3f),
        vec(scene.specular, mi.Color3f),
        rough,
        dr.arange(mi.UInt32, count),
        count,
    )
    total = dr.zeros(mi.Color3f, count)
    if scene.axis.shape[0] > 0:
        lobes = DrLobes.from_numpy(scene.axis, scene.sharpness, scene.amplitude)
        if mode == "sg":
            from .render.env_sg import sg_environment

            total = total + sg_environment(sp, lobes)
        else:
            from .render.env_quadrature import quadrature_environment

            total = total + quadrature_environment(sp, lobes, spp=spp)
    if scene.light is not None and float(np.max(scene.intensity)) > 0:
        total = total + point_light(
            sp, vec(pts), mi.Vector3f(*map(float, scene.light)), mi.Color3f(*map(float, scene.intensity))
        )
    return np.array(total, dtype=np.float64).T


def _builtin_bsdf(scene: PlaneScene) -> dict:
    import mitsuba as mi

    from .floors import ROUGHNESS_MIN

    r = min(max(scene.roughness, ROUGHNESS_MIN), 1.0)
    if float(scene.diffuse.max()) > 0.5:
        raise InputError("builtin-bsdf check needs diffuse <= 0.5 (the built-in 'diffuse' takes 2·d <= 1)")
    normal_texels = np.broadcast_to(((scene.normal + 1) / 2).astype(np.float32), (2, 2, 3)).copy()
    return {
        "type": "normalmap",
        "flip_invalid_normals": False,
        "use_shadowing_function": False,
        "normalmap": {
            "type": "bitmap",
            "raw": True,
            "filter_type": "nearest",
            "data": mi.TensorXf(normal_texels),
        },
        "bsdf": {
            "type": "blendbsdf",
            "weight": 0.5,
            "bsdf_0": {
                "type": "diffuse",
                "reflectance": {"type": "rgb", "value": (2 * scene.diffuse).tolist()},
            },
            "bsdf_1": {
                "type": "roughconductor",
                "distribution": "ggx",
                "alpha": r * r,
                "material": "none",
                "specular_reflectance": {"type": "rgb", "value": (2 * scene.specular).tolist()},
            },
        },
    }


def _our_bsdf(scene: PlaneScene, fresnel: str) -> dict:
    return {
        "type": "svbrdf",
        "fresnel": fresnel,
        "normal": {"type": "rgb", "value": scene.normal.tolist()},
        "diffuse": {"type": "rgb", "value": scene.diffuse.tolist()},
        "specular": {"type": "rgb", "value": scene.specular.tolist()},
        "roughness": float(scene.roughness),
    }


def _env_dicts(scene: PlaneScene, res: int = 1024) -> tuple[dict, dict]:
    from .envmap import envmap_emitter_dict, sg_to_equirect
    from .plugins.sgenvmap import sgenvmap_dict
    from .sgenv import SGEnvironment

    env = SGEnvironment(scene.axis, scene.sharpness, scene.amplitude)
    return sgenvmap_dict(env), envmap_emitter_dict(sg_to_equirect(env, res, 2 * res))


def _scene_dict(bsdf: dict, emitter: dict, scene: PlaneScene) -> dict:
    d = {"type": "scene", "sample": {"type": "rectangle", "bsdf": bsdf}, "env": emitter}
    if scene.light is not None and float(np.max(scene.intensity)) > 0:
        d["light"] = {
            "type": "point",
            "position": scene.light.tolist(),
            "intensity": {"type": "rgb", "value": scene.intensity.tolist()},
        }
    return d


def _row(name, reference, a, b_est, noise, budget, seconds, extra=None) -> dict:
    ref = b_est
    diff = a - ref
    finite = bool(np.all(np.isfinite(a)) and np.all(np.isfinite(ref)))
    rel = rel_rmse(a, ref)
    tol = 3.0 * noise + budget
    # Systematic part of the difference: what remains after removing the expected noise energy.
    excess = math.sqrt(max(rel * rel - noise * noise, 0.0)) if finite else float("inf")
    row = {
        "name": name,
        "reference": reference,
        "rel_rmse": rel,
        "excess": excess,
        "max_abs": float(np.max(np.abs(diff))) if finite else float("inf"),
        "tolerance": tol,
        "noise": noise,
        "budget": budget,
        "passed": bool(finite and rel <= tol),
        "seconds": seconds,
    }
    if extra:
        row.update(extra)
    return row


def run_case(case: Case, config: ValidateConfig | None = None, **options) -> list[dict]:
    """Run every check of ``case`` with the references of ``config`` (default:
    :class:`ValidateConfig`'s), ``options`` (its fields, ``spp=1024``) set over it; one result row
    per check."""
    import mitsuba as mi

    from .pathref import trace
    from .scene import load_scene

    cfg = _validate_config(config, options)
    spp, seed = cfg.spp, cfg.seed
    rows = []
    t0 = time.perf_counter()
    scene_obj = load_scene(case.scene, **case.params)
    plane = read_plane_scene(scene_obj, str(case.scene))
    pts, cams = query_geometry(case)
    dirs = pts - cams
    ref = None
    if any(c.startswith("fast") for c in case.checks):
        ref = trace(scene_obj, cams, dirs, spp=spp, seed=seed)
    t_ref = time.perf_counter() - t0
    for check in case.checks:
        t1 = time.perf_counter()
        if check.startswith("fast"):
            mode = check.split("-", 1)[1]
            a = fast_radiance(plane, pts, cams, "sg" if mode == "sg" else "quadrature", case.quadrature_spp)
            label = f"mitsuba path, {spp} spp"
            rows.append(
                _row(
                    f"{case.name}/{check}",
                    label,
                    a,
                    ref.mean,
                    ref.relative_noise(),
                    case.budget(check),
                    time.perf_counter() - t1 + t_ref,
                    {"mode": mode, "spp_fast": case.quadrature_spp if mode != "sg" else None},
                )
            )
        else:
            sg_emitter, envmap_emitter = _env_dicts(plane)
            if check == "builtin-bsdf":
                ours = mi.load_dict(_scene_dict(_our_bsdf(plane, "none"), envmap_emitter, plane))
                theirs = mi.load_dict(_scene_dict(_builtin_bsdf(plane), _env_dicts(plane)[1], plane))
                label = f"normalmap(blendbsdf(diffuse, roughconductor)) under envmap, {spp} spp"
            else:
                # Fresh dicts per load: mi.load_dict may consume the tensors it is given.
                ours = mi.load_dict(_scene_dict(_builtin_bsdf(plane), sg_emitter, plane))
                theirs = mi.load_dict(_scene_dict(_builtin_bsdf(plane), envmap_emitter, plane))
                label = f"envmap rasterised 1024x2048 from the lobes, {spp} spp"
            ea = trace(ours, cams, dirs, spp=spp, seed=seed + 1)
            eb = trace(theirs, cams, dirs, spp=spp, seed=seed + 2)
            noise = math.hypot(ea.relative_noise(), eb.relative_noise())
            rows.append(
                _row(
                    f"{case.name}/{check}",
                    label,
                    ea.mean,
                    eb.mean,
                    noise,
                    case.budget(check),
                    time.perf_counter() - t1,
                )
            )
    return rows


def validate(cases: list[Case], config: ValidateConfig | None = None, progress=None, **options) -> dict:
    """Run ``cases`` (:func:`run_case` with ``config`` and ``options``); returns ``{"passed": bool,
    "cases": [rows]}``."""
    cfg = _validate_config(config, options)
    rows = []
    for case in cases:
        rows.extend(run_case(case, cfg))
        if progress is not None:
            progress(case, rows)
    return {"passed": all(r["passed"] for r in rows), "cases": rows}
