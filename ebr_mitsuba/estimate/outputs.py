"""The files an estimate writes (all under one output directory, built atomically by the pipeline).

==============================  =================================================================
path                            content
==============================  =================================================================
``maps/``                       the final maps: a material directory (``normal|diffuse|specular|
                                roughness.exr`` + ``.png`` previews + ``material.json``)
``maps_network/``               the network's maps before refinement (only with refinement)
``env.json``                    the SG environment (``ebr-sg/1``; absent for flash-only captures)
``env_latlong.exr|.png``        the SGs as a z-up lat-long image (top row zenith, u = φ/2π)
``env_sphere.png``              the upper hemisphere seen from above (orthographic: +x right,
                                +y up), the light as the sample sees it
``inputs/<shot>.png``           the shots, exposure-matched (preview size)
``rerender/<shot>.exr|.png``    the estimate re-rendered for each shot (fast renderer; EXR at the
                                working size, PNG at the preview size)
``residual/<shot>.exr|.png``    re-render − photo (EXR: signed RGB at the working size; PNG:
                                luminance, blue −, red +, full scale ±``RESIDUAL_SCALE`` × the
                                photo's RMS, preview size)
``novel/<name>.exr|.png``       renders under novel lights (:data:`NOVEL_LIGHTS`), preview size
``exemplars/*.png``             the lighting network's exemplars and flash-only image, when given
``estimate.json``               the summary (also printed by ``--json``)
``report.html``                 :mod:`.report`
==============================  =================================================================

PNG previews of radiance use one exposure per shot (photo and re-render alike, the photo's 99.5th
luminance percentile mapped to 1) and the sRGB curve, so the pairs compare directly. Previews are
at most :data:`PREVIEW_SIZE` pixels per side (area-averaged; the maps' own PNGs are at the
working size): a 2048² estimate writes its pictures in seconds and ``report.html`` stays a few
megabytes.

Every writer here runs inside :func:`ebr_mitsuba.imageio.fast_writes`: the EXRs are uncompressed
(ZIP saved 5–15 % on these float32 images for 10–20× the write time) and the PNGs use zlib
level 1 (15–30 % larger, a third of the time).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry import NEAR_DISTANCE, Shot
from ..imageio import fast_writes, write_exr, write_png
from ..materials import save_material_dir
from ..sgenv import SGEnvironment
from ..svbrdf import SVBRDF
from .inputs import luminance

RESIDUAL_SCALE = 0.5
PREVIEW_SIZE = 512
# Novel lights: name → (point light position or None, intensity factor × the flash's, env rotation
# about +z in degrees or None for no environment).
NOVEL_LIGHTS = {
    "light_upper_left": ((-1.2, 1.2, 2.0), 1.0, None),
    "light_lower_right": ((1.2, -1.2, 2.0), 1.0, None),
    "light_grazing": ((-3.0, 0.0, 0.8), 2.0, None),
    "env_rotated_180": (None, 0.0, 180.0),
}


def exposure_of(image: np.ndarray) -> float:
    """Preview exposure: 1 / the 99.5th luminance percentile (1 for a black image)."""
    p = float(np.percentile(luminance(image), 99.5)) if image.size else 0.0
    return 1.0 / p if p > 0 and math.isfinite(p) else 1.0


def preview_size(image: np.ndarray) -> np.ndarray:
    """``image`` area-averaged to at most :data:`PREVIEW_SIZE` pixels per side (aspect kept)."""
    from ..imageio import resize_area

    h, w = image.shape[:2]
    f = PREVIEW_SIZE / max(h, w)
    if f >= 1:
        return image
    return resize_area(image, (max(1, round(h * f)), max(1, round(w * f))))


def preview(path: Path, image: np.ndarray, exposure: float) -> Path:
    with fast_writes():
        return write_png(path, np.clip(preview_size(image) * exposure, 0, 1))


def residual_png(path: Path, render: np.ndarray, photo: np.ndarray) -> Path:
    """Luminance residual in a diverging colour map, ±RESIDUAL_SCALE × RMS(photo) full scale
    (preview size)."""
    from matplotlib import colormaps

    render, photo = preview_size(render), preview_size(photo)
    rms = float(np.sqrt(np.mean(luminance(photo).astype(np.float64) ** 2))) or 1.0
    r = luminance(render - photo) / (RESIDUAL_SCALE * rms)
    rgb = colormaps["RdBu_r"](np.clip(0.5 + 0.5 * r, 0, 1))[..., :3].astype(np.float32)
    with fast_writes():
        return write_png(path, rgb, encode="linear")


def latlong_directions(height: int) -> np.ndarray:
    """Unit directions (H, 2H, 3) of a z-up lat-long image: column u = φ/2π (φ from +x towards
    +y), row v = θ/π (θ from +z), texel centres."""
    w = 2 * height
    phi = (np.arange(w) + 0.5) / w * 2 * np.pi
    theta = (np.arange(height) + 0.5) / height * np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def hemisphere_directions(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions (S, S, 3) of the upper hemisphere seen from above (orthographic, +x right, +y
    up) and the (S, S) mask of the disk."""
    c = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    inside = r2 < 1
    z = np.sqrt(np.maximum(1 - r2, 0))
    d = np.stack([x, y, z], axis=-1)
    return d, inside


def env_pictures(env: SGEnvironment, out: Path, height: int = 128) -> list[str]:
    """``env_latlong.exr/.png`` and ``env_sphere.png`` of ``env``; returns the file names."""
    latlong = env.eval(latlong_directions(height)).astype(np.float32)
    d, inside = hemisphere_directions(2 * height)
    sphere = (env.eval(d) * inside[..., None]).astype(np.float32)
    # Exposure: the sky (median of the upper hemisphere) at 0.25 keeps both sun and sky readable.
    sky = float(np.median(luminance(latlong[: height // 2])))
    k = 0.25 / sky if sky > 0 else exposure_of(latlong)
    with fast_writes():
        write_exr(out / "env_latlong.exr", latlong)
    preview(out / "env_latlong.png", latlong, k)
    preview(out / "env_sphere.png", sphere, k)
    return ["env.json", "env_latlong.exr", "env_latlong.png", "env_sphere.png"]


def novel_shots(
    flash_intensity: float, distance: float = NEAR_DISTANCE
) -> dict[str, tuple[Shot, float | None]]:
    """The :data:`NOVEL_LIGHTS` as shots from the near camera, with their env rotation (degrees)."""
    cam = (0.0, 0.0, float(distance))
    out = {}
    for name, (pos, factor, rot) in NOVEL_LIGHTS.items():
        out[name] = (
            Shot(
                name,
                cam,
                2 * math.degrees(math.atan(1 / distance)),
                pos,
                float(flash_intensity * factor),
                env=rot is not None,
            ),
            rot,
        )
    return out


def write_novel(
    maps: SVBRDF,
    env: SGEnvironment | None,
    flash_intensity: float,
    out: Path,
    distance: float = NEAR_DISTANCE,
    mode: str = "sg",
) -> list[str]:
    """Renders of ``maps`` under :data:`NOVEL_LIGHTS` into ``out/novel`` (at the preview size);
    returns file names. Environment-lit renders are skipped when there is no environment."""
    from ..materials import resample_svbrdf
    from .refine import rerender

    if max(maps.shape) > PREVIEW_SIZE:
        maps = resample_svbrdf(maps, preview_size(maps.diffuse).shape[:2])
    files = []
    (out / "novel").mkdir(exist_ok=True)
    for name, (shot, rot) in novel_shots(flash_intensity, distance).items():
        if rot is not None and (env is None or env.num_lobes == 0):
            continue
        e = env.rotated_z(math.radians(rot)) if rot is not None else None
        img = rerender(maps, e, shot, mode)
        with fast_writes():
            write_exr(out / "novel" / f"{name}.exr", img)
        preview(out / "novel" / f"{name}.png", img, exposure_of(img))
        files += [f"novel/{name}.exr", f"novel/{name}.png"]
    return files


def write_maps(maps: SVBRDF, path: Path, source: str) -> list[str]:
    with fast_writes():
        save_material_dir(maps, path, meta={"source": source, "licence": "as the input photos"})
    base = path.name
    return [
        f"{base}/{n}.{ext}" for n in ("normal", "diffuse", "specular", "roughness") for ext in ("exr", "png")
    ]


def write_shots(
    out: Path,
    photos: dict[str, np.ndarray],
    renders: dict[str, np.ndarray],
    masks: dict[str, np.ndarray] | None = None,
) -> list[str]:
    """Inputs, re-renders and residuals per shot name."""
    files = []
    for sub in ("inputs", "rerender", "residual"):
        (out / sub).mkdir(exist_ok=True)
    for name, photo in photos.items():
        k = exposure_of(photo)
        preview(out / "inputs" / f"{name}.png", photo, k)
        files.append(f"inputs/{name}.png")
        if name in renders:
            r = renders[name]
            with fast_writes():
                write_exr(out / "rerender" / f"{name}.exr", r)
                write_exr(out / "residual" / f"{name}.exr", r - photo)
            preview(out / "rerender" / f"{name}.png", r, k)
            residual_png(out / "residual" / f"{name}.png", r, photo)
            files += [
                f"rerender/{name}.exr",
                f"rerender/{name}.png",
                f"residual/{name}.exr",
                f"residual/{name}.png",
            ]
    return files


def write_exemplars(out: Path, prediction) -> list[str]:
    """The prediction's environment exemplars and flash-only image as PNGs (whatever is present:
    a list/tuple or dict of (H, W, 3) arrays)."""
    items = []
    ex = getattr(prediction, "env_exemplars", None)
    if isinstance(ex, dict):
        items += [(f"exemplar_{k}", v) for k, v in ex.items()]
    elif isinstance(ex, (list, tuple)) or (isinstance(ex, np.ndarray) and ex.ndim == 4):
        items += [(f"exemplar_{i}", v) for i, v in enumerate(ex)]
    fo = getattr(prediction, "flash_only", None)
    if fo is not None:
        items.append(("flash_only", fo))
    from .report import exemplar_exposure

    items = [(name, np.asarray(img, dtype=np.float32)) for name, img in items]
    items = [(n, a) for n, a in items if a.ndim == 3 and a.shape[2] in (1, 3) and np.all(np.isfinite(a))]
    shared = exemplar_exposure([a for n, a in items if n.startswith("exemplar_")])
    files = []
    for name, a in items:
        (out / "exemplars").mkdir(exist_ok=True)
        safe = "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in str(name))
        exposure = shared if name.startswith("exemplar_") else exposure_of(a)
        with fast_writes():
            write_png(out / "exemplars" / f"{safe}.png", a * exposure, clip="hue")
        files.append(f"exemplars/{safe}.png")
    return files


def check_out_dir(out: Path) -> None:
    """Refuse to replace anything but an earlier estimate directory (or an empty directory)."""
    if not out.exists():
        return
    if not out.is_dir():
        raise InputError(f"--out {out}: exists and is not a directory; choose another --out")
    if any(out.iterdir()) and not (out / "estimate.json").is_file():
        raise InputError(
            f"--out {out}: exists and is not an estimate directory (no estimate.json); "
            f"choose a new --out or remove it"
        )


class Stages:
    """The clock of one estimate run, started first thing: ``stage(name, t0)`` records how long the
    stage begun at ``t0`` (``time.perf_counter``) took in ``timings`` (``estimate.json``'s
    ``timings``), ``t_start`` is when the run began (its ``total_seconds``). Starting it checks the
    output directory ``out`` (:func:`check_out_dir`), the first step of the inputs stage."""

    def __init__(self, out: str | Path) -> None:
        self.t_start = time.perf_counter()
        self.timings: dict[str, float] = {}
        self.out = Path(out)
        check_out_dir(self.out)

    def __call__(self, name: str, t0: float) -> None:
        self.timings[name] = round(time.perf_counter() - t0, 3)


def write_report_and_summary(out: Path, summary: dict, files: list[str], stage: Stages) -> None:
    """Last in every estimate directory: ``report.html`` and ``estimate.json`` (which list every
    file, so they come after the others); ``stage("report", t0)`` times the report and
    ``summary["total_seconds"]`` is set from ``stage.t_start``."""
    import json

    from .report import write_report

    t0 = time.perf_counter()
    summary["files"] = sorted(files) + ["estimate.json", "report.html"]
    write_report(out, summary)
    stage("report", t0)
    summary["total_seconds"] = round(time.perf_counter() - stage.t_start, 3)
    (out / "estimate.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")


__all__ = [
    "Stages",
    "check_out_dir",
    "write_report_and_summary",
    "NOVEL_LIGHTS",
    "PREVIEW_SIZE",
    "RESIDUAL_SCALE",
    "env_pictures",
    "write_novel",
    "write_maps",
    "write_shots",
    "write_exemplars",
    "exposure_of",
    "latlong_directions",
    "hemisphere_directions",
    "novel_shots",
]
