"""Object insertion: a virtual object standing on an estimated sample, lit by the estimated
environment, rendered with Mitsuba, and (for a synthetic capture) the same insertion with the
true maps and the true environment, and the error between the two.

Scene (``docs/conventions.md``, "Geometry and pixel grid"; ``docs/insert.md``)
===================  ==========================================================================
part                 what it is
===================  ==========================================================================
sample               the plane [-1,1]² at z = 0 with the ``svbrdf`` BSDF showing the maps of
                     ``ESTIMATE_DIR/maps`` (:func:`ebr_mitsuba.scene.svbrdf_bsdf_dict`)
lighting             the ``sgenvmap`` emitter with the lobes of ``ESTIMATE_DIR/env.json`` (no
                     flash: the insertion is seen under the environment alone)
object               ``sphere`` (radius = width/2), ``cube`` (edge = width) or a mesh file
                     (``.obj``/``.ply``; its up axis, ``+y`` by default as Wavefront files
                     usually are, turned to +z), scaled to ``width`` = ``scale`` × the sample
                     width (2) along its larger horizontal side, centred on ``position`` (x, y)
                     with its lowest point on the plane; ``none`` renders the plane alone
camera               the estimate's camera: at ``near_distance(fov)`` above the sample centre
                     with the photos' horizontal field of view (the frame is exactly the
                     sample); ``elevation`` < 90° swings it towards −y on the same distance,
                     looking at the centre (+y stays up in the image)
integrator           ``path``, ``max_depth`` 8 (object ↔ plane inter-reflections, a mirror seeing
                     the plane and the sky), emitters hidden from camera rays (background
                     pixels of an oblique view are black)
===================  ==========================================================================

Background (``background``, default ``photo``). Into an estimate of a flash / no-flash pair, seen
from the estimate's own camera (``elevation`` 90), the object is composited into the no-flash
photo by differential rendering (Debevec 1998): the scene is rendered with and without the
object under the estimated light, the object's pixels (:func:`object_coverage`) are taken from
the render, and every other pixel is the photo times the render's ratio with / without the
object — the shadow and the light the object throws back, applied to what the camera saw
(:func:`differential`). The plate then keeps the photo's own texture and light wherever the
object leaves it alone, and the estimate is judged where the insertion changes the picture.
``render`` (and any other camera, an estimate without a no-flash view, a capture directory)
renders the whole frame; a multi-view estimate with the no-flash view of ``ebr capture --setup
multi-view`` (named ``noflash``) is composited into it like a flash / no-flash one. The photo is
the one the estimate fitted, on the sample grid and in its radiance units:
``rerender/noflash.exr`` − ``residual/noflash.exr`` (the residual is re-render − photo,
:mod:`ebr_mitsuba.estimate.outputs`).

The object's materials (:data:`MATERIALS`) are Mitsuba's own BSDFs. The render is split into
passes of at most :data:`PASS_SPP` samples (each its own seed, derived from ``seed`` as
:func:`ebr_mitsuba.capture.shot_seed` does) averaged with their sample counts as weights, so
a progress bar can follow it; the average has the expectation and variance of one render.

Truth (``truth``): a directory of ``ebr capture`` (``capture.json``): the same scene with its
``maps`` and its environment (``env.json``, or the equirectangular map named in
``capture.json`` after a SHA-256 check), seen by the estimate's camera (a different field of
view in the capture is reported as a warning). By default the truth is
rendered with the same seed as the estimate, so that their sampling noise is correlated and
mostly cancels in the difference; ``truth_seed`` makes it independent (the truth-vs-truth noise
floor: ``ebr insert CAPTURE_DIR --truth CAPTURE_DIR --truth-seed 1``, at the same ``spp`` as
the insertion it is compared with: the default 64 spp makes it twice the 256-spp floor).
``noise_floor`` (``--noise-floor``) renders that floor in the same run (:func:`truth_again`) and
reports the insertion's RMSE over it. ESTIMATE_DIR may itself be a capture directory (its true
maps and environment).

Errors in the inputs are :class:`~ebr_mitsuba.errors.InputError` (one line naming the file and
the fix) raised before anything is rendered or written; the images are written atomically
together, after every render succeeded (:func:`write_outputs`).
"""

from __future__ import annotations

import contextlib
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError
from .geometry import Shot
from .metrics import rel_rmse, rmse
from .sgenv import SGEnvironment
from .svbrdf import SVBRDF
from .typedconfig import check, config, option

#: Built-in objects; anything else must be a mesh file with one of :data:`MESH_SUFFIXES`.
OBJECTS = ("sphere", "cube", "none")
MESH_SUFFIXES = (".obj", ".ply")
#: Object materials: name → (what it is, Mitsuba BSDF dict).
MATERIALS: dict[str, tuple[str, dict]] = {
    "diffuse": (
        "grey Lambertian, albedo 0.8",
        {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}},
    ),
    "mirror": ("perfect mirror (reflectance 1)", {"type": "conductor", "material": "none"}),
    "glossy": (
        "grey rough metal, GGX α 0.1, reflectance 0.9",
        {
            "type": "roughconductor",
            "distribution": "ggx",
            "alpha": 0.1,
            "material": "none",
            "specular_reflectance": {"type": "rgb", "value": [0.9, 0.9, 0.9]},
        },
    ),
    "plastic": (
        "red rough plastic, GGX α 0.1, diffuse (0.6, 0.08, 0.05)",
        {
            "type": "roughplastic",
            "distribution": "ggx",
            "alpha": 0.1,
            "diffuse_reflectance": {"type": "rgb", "value": [0.6, 0.08, 0.05]},
        },
    ),
    "glass": ("clear glass, index 1.5", {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}),
}
MESH_UP = ("y", "z")

DEFAULT_OBJECT = "sphere"
DEFAULT_MATERIAL = "diffuse"
DEFAULT_SPP = 64
DEFAULT_SCALE = 1.0 / 3.0  # the object's width as a fraction of the sample's width
DEFAULT_POSITION = (0.0, 0.0)
DEFAULT_ELEVATION = 90.0
DEFAULT_SEED = 0
DEFAULT_MESH_UP = "y"
DEFAULT_MAX_RES = 512  # the default resolution is the maps' one, at most this
MAX_DEPTH = 8
BACKGROUNDS = ("photo", "render")
DEFAULT_BACKGROUND = "photo"
#: Plate pixels whose render without the object is below this share of its mean luminance take
#: the render's difference instead of its ratio (a ratio of two near-zero renders is noise).
RATIO_FLOOR = 0.01
COVERAGE_SPP = 16  # samples per pixel of the depth passes that find the object's pixels
PASS_SPP = 16
MIN_RES, MAX_RES = 8, 4096
MAX_SPP = 1 << 16
MIN_ELEVATION = 10.0
SAMPLE_WIDTH = 2.0
CAPTURE_FORMAT = "ebr-capture/1"
ESTIMATE_FORMAT = "ebr-estimate/1"
#: Gain of the |estimate − truth| panel of the side-by-side picture.
DIFF_GAIN = 4.0
GAP = 4  # white pixels between the panels


# -- configuration ----------------------------------------------------------------------------------


@config(error=InputError, cli=True)
class InsertConfig:
    """What to insert and how to render it (the options of ``ebr insert``; a bad value is an
    :class:`~ebr_mitsuba.errors.InputError` naming the flag)."""

    object: str = option(
        DEFAULT_OBJECT, "sphere, cube, none or a .obj/.ply file", flag="--object", metavar="O"
    )
    material: str = option(DEFAULT_MATERIAL, "object material", choices=tuple(MATERIALS), metavar="M")
    spp: int = option(DEFAULT_SPP, "samples per pixel of each render", minimum=1, maximum=MAX_SPP)
    res: int | None = option(
        None,
        "image size, square",
        minimum=MIN_RES,
        maximum=MAX_RES,
        shown=f"the maps' resolution, at most {DEFAULT_MAX_RES}",
    )
    scale: float = option(
        DEFAULT_SCALE,
        "the object's width as a fraction of the sample's width",
        above=0,
        maximum=1,
        flag="--object-scale",
        metavar="F",
        shown="1/3",
    )
    position: tuple[float, float] = option(
        DEFAULT_POSITION,
        "the object's centre on the sample",
        minimum=-1,
        maximum=1,
        metavar="X,Y",
        shown="0,0",
    )
    elevation: float = option(
        DEFAULT_ELEVATION,
        "camera elevation in degrees (90: the estimate's camera, straight above)",
        minimum=MIN_ELEVATION,
        maximum=90,
        metavar="DEG",
        fix="90 is the estimate's camera, straight above",
    )
    background: str = option(
        DEFAULT_BACKGROUND,
        "photo: composite into the estimate's no-flash photo (differential rendering, the "
        "estimate's camera); render: render the whole frame",
        choices=BACKGROUNDS,
        metavar="B",
    )
    seed: int = option(DEFAULT_SEED, "sampler seed", minimum=0, below=2**32, metavar="S")
    truth_seed: int | None = option(
        None,
        "sampler seed of the truth render (correlated noise, which mostly cancels in the RMSE)",
        minimum=0,
        below=2**32,
        metavar="S",
        shown="--seed",
    )
    mesh_up: str = option(
        DEFAULT_MESH_UP, "the mesh file's up axis, y (Wavefront's usual) or z", choices=MESH_UP, metavar="A"
    )
    noise_floor: bool = option(
        False,
        "with --truth: render the truth once more with the next seed and report the truth-vs-truth "
        "RMSE (noise_floor) and the insertion's RMSE over it (floor_ratio), issue 13's measure",
        flag="--noise-floor",
    )

    def __post_init__(self):
        check(self)
        if self.object not in OBJECTS:
            path = Path(self.object)
            if path.suffix.lower() not in MESH_SUFFIXES:
                raise InputError(
                    f"--object {self.object!r}: not one of {', '.join(OBJECTS)} and not a "
                    f"mesh file ({', '.join(MESH_SUFFIXES)}); give a built-in object or a "
                    f"Wavefront .obj"
                )
            if not path.is_file():
                raise InputError(f"{path}: no such mesh file; give an existing .obj (or .ply) file")

    @property
    def width(self) -> float:
        """The object's width in world units."""
        return self.scale * SAMPLE_WIDTH

    @property
    def true_seed(self) -> int:
        """The truth render's seed: ``truth_seed``, else ``seed``."""
        return self.seed if self.truth_seed is None else self.truth_seed

    @property
    def floor_seed(self) -> int:
        """The seed of the truth's second render (the noise floor): the truth's next one."""
        return (self.true_seed + 1) % 2**32

    def to_json(self) -> dict:
        return {
            "object": self.object,
            "material": self.material,
            "spp": self.spp,
            "res": self.res,
            "object_scale": self.scale,
            "width": self.width,
            "position": list(self.position),
            "elevation": self.elevation,
            "background": self.background,
            "seed": self.seed,
            "truth_seed": self.true_seed,
            "noise_floor": self.noise_floor,
            **({"mesh_up": self.mesh_up} if self.object not in OBJECTS else {}),
        }


#: The fields ``ebr insert`` sets from its flags (:func:`ebr_mitsuba.typedconfig.add_flags`).
INSERT_FLAGS = (
    "object",
    "material",
    "spp",
    "res",
    "scale",
    "position",
    "elevation",
    "background",
    "seed",
    "truth_seed",
    "mesh_up",
    "noise_floor",
)


# -- the scene's inputs: maps, lighting, camera -------------------------------------------------------


@dataclass(frozen=True)
class Plate:
    """What the object is inserted into: the sample's maps, its lighting and the camera's field
    of view. ``emitter`` builds the Mitsuba emitter dict (a fresh one per scene: a dict's tensors
    are consumed by one ``mi.load_dict``); ``kind`` is ``estimate`` or ``capture``; ``photo``
    the (H, W, 3) no-flash photo the estimate fitted, on the sample grid in the plate's radiance
    units (None: no such photo; the frame is rendered whole)."""

    source: Path
    kind: str
    maps: SVBRDF
    fov: float
    emitter: Callable[[], dict] = field(repr=False)
    env: dict = field(default_factory=dict)
    photo: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def resolution(self) -> int:
        return int(self.maps.shape[0])


def _read_json(path: Path, what: str) -> dict:
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(
            f"{path}: unreadable {what} ({getattr(exc, 'msg', None) or exc}); regenerate it"
        ) from None
    if not isinstance(data, dict):
        raise InputError(
            f"{path}: expected a JSON object ({what}), got a {type(data).__name__}; regenerate it"
        )
    return data


def _load_maps(directory: Path, fix: str) -> SVBRDF:
    from .materials import load_material_dir

    if not directory.is_dir():
        raise InputError(f"{directory}: no maps directory; {fix}")
    try:
        return load_material_dir(directory, albedo_colorspace="linear")
    except InputError as exc:
        raise InputError(f"{exc}; {fix}") from None


def _check_fov(fov, source: Path) -> float:
    try:
        fov = float(fov)
    except (TypeError, ValueError):
        fov = float("nan")
    if not (math.isfinite(fov) and 1.0 <= fov <= 150.0):
        raise InputError(
            f"{source}: the camera's field of view is {fov!r}; expected degrees in "
            f"[1, 150]; regenerate the file"
        )
    return fov


def _sg_plate_env(env: SGEnvironment, path: Path) -> tuple[Callable[[], dict], dict]:
    from .scene import sg_emitter_dict

    if env.num_lobes == 0:
        raise InputError(
            f"{path}: the environment has no lobes (a dark scene); an insertion needs "
            f"light: use an estimate from a flash/no-flash pair"
        )
    return (lambda: sg_emitter_dict(env)), {"kind": "sg", "file": str(path), "lobes": env.num_lobes}


def load_estimate(directory) -> Plate:
    """The plate of ``ebr estimate``'s output directory (``estimate.json``, ``maps/``,
    ``env.json``), or of an ``ebr capture`` directory (its true maps and environment)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(
            f"{directory}: no such estimate directory; give the --out directory of `ebr estimate`"
        )
    if not (directory / "estimate.json").is_file():
        if (directory / "capture.json").is_file():
            return load_capture(directory)
        raise InputError(
            f"{directory}: not an estimate directory (no estimate.json); give the --out "
            f"directory of `ebr estimate` (or an `ebr capture` directory)"
        )
    meta_path = directory / "estimate.json"
    meta = _read_json(meta_path, "estimate summary")
    if meta.get("format") != ESTIMATE_FORMAT:
        raise InputError(
            f"{meta_path}: 'format' is {meta.get('format')!r}, not \"{ESTIMATE_FORMAT}\"; "
            f"give the output of `ebr estimate`"
        )
    inputs = meta.get("inputs") if isinstance(meta.get("inputs"), dict) else {}
    fov = _check_fov(inputs.get("fov"), meta_path)
    env_path = directory / "env.json"
    if not env_path.is_file():
        raise InputError(
            f"{env_path}: missing; this estimate has no lighting (a flash-only or "
            f"five-light estimate): run `ebr estimate` with --noflash for one"
        )
    env = SGEnvironment.load(env_path)
    maps = _load_maps(directory / "maps", "re-run `ebr estimate` to write the maps")
    emitter, env_record = _sg_plate_env(env, env_path)
    return Plate(directory, "estimate", maps, fov, emitter, env_record, estimate_photo(directory))


def estimate_photo(directory) -> np.ndarray | None:
    """The no-flash photo an estimate fitted, (H, W, 3) float32 in its radiance units:
    ``rerender/noflash.exr`` − ``residual/noflash.exr``; None when the estimate has no no-flash
    shot (flash-only, five-light, multi-view of the flash views alone). A present but unreadable
    pair is an InputError."""
    from .imageio import read_exr

    directory = Path(directory)
    paths = [directory / "rerender" / "noflash.exr", directory / "residual" / "noflash.exr"]
    if not all(path.is_file() for path in paths):
        return None
    try:
        rerender, residual = (np.asarray(read_exr(path), np.float32)[..., :3] for path in paths)
    except Exception as exc:  # an EXR reader error of any kind: one line, the fix
        raise InputError(
            f"{directory}: unreadable no-flash re-render or residual ({exc}); re-run `ebr estimate` "
            f"or use --background render"
        ) from None
    if rerender.shape != residual.shape or rerender.ndim != 3:
        raise InputError(
            f"{directory}: rerender/noflash.exr is {rerender.shape} but residual/noflash.exr "
            f"{residual.shape}; re-run `ebr estimate` or use --background render"
        )
    return rerender - residual


def _capture_fov(meta: dict, meta_path: Path) -> float:
    """Field of view of the capture's fronto-parallel camera (the shot that frames the sample)."""
    shots = [s for s in meta.get("shots", []) if isinstance(s, dict)]
    framing = [s for s in shots if s.get("in_sample_grid")]
    noflash = [s for s in framing if s.get("flash") is None]
    pick = (noflash or framing or [None])[0]
    if pick is None:
        raise InputError(
            f"{meta_path}: no shot frames the sample (in_sample_grid); give a capture "
            f"of the near, near-far, five-light or multi-view setup"
        )
    return _check_fov(pick.get("fov"), meta_path)


def load_capture(directory) -> Plate:
    """The true plate of an ``ebr capture`` directory: ``maps/``, the environment it was rendered
    with and the field of view of its camera."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"{directory}: no such capture directory; give the --out directory of `ebr capture`")
    meta_path = directory / "capture.json"
    if not meta_path.is_file():
        raise InputError(
            f"{directory}: not a capture directory (no capture.json); --truth needs the "
            f"--out directory of `ebr capture`"
        )
    meta = _read_json(meta_path, "capture metadata")
    if meta.get("format") != CAPTURE_FORMAT:
        raise InputError(
            f"{meta_path}: 'format' is {meta.get('format')!r}, not \"{CAPTURE_FORMAT}\"; "
            f"give a directory written by `ebr capture`"
        )
    fov = _capture_fov(meta, meta_path)
    record = meta.get("env")
    if not isinstance(record, dict):
        raise InputError(
            f"{meta_path}: the capture has no environment (a dark capture); an insertion "
            f"needs light: capture with --env"
        )
    maps = _load_maps(
        directory / (meta.get("material", {}) or {}).get("maps", "maps"),
        "re-run `ebr capture` to write the true maps",
    )
    if record.get("kind") == "sg":
        env_path = directory / str(record.get("file", "env.json"))
        emitter, env_record = _sg_plate_env(SGEnvironment.load(env_path), env_path)
    elif record.get("kind") == "equirect":
        emitter, env_record = _equirect_env(record, meta_path)
    else:
        raise InputError(
            f"{meta_path}: unknown environment kind {record.get('kind')!r}; regenerate the capture"
        )
    return Plate(directory, "capture", maps, fov, emitter, env_record)


def _equirect_env(record: dict, meta_path: Path) -> tuple[Callable[[], dict], dict]:
    from .sources import file_sha256, parse_env

    path = Path(str(record.get("path", "")))
    if not path.is_file():
        raise InputError(
            f"{meta_path}: the environment map {path} is gone; put it back or re-run the capture"
        )
    if record.get("sha256") and file_sha256(path) != record["sha256"]:
        raise InputError(
            f"{path}: changed since the capture (SHA-256 differs from capture.json); "
            f"restore it or re-run the capture"
        )
    source = parse_env(str(path))
    scale = float(record.get("scale", 1.0))
    return (lambda: source.emitter_dict(scale)), {"kind": "equirect", "file": str(path), "scale": scale}


# -- the scene -------------------------------------------------------------------------------------


def camera_shot(fov: float, elevation: float = DEFAULT_ELEVATION) -> Shot:
    """The insertion camera: the estimate's near camera, swung to ``elevation`` degrees towards −y."""
    distance = 1.0 / math.tan(math.radians(fov) / 2)  # the frame is exactly [-1,1]² from above
    if elevation >= 90.0:
        camera = (0.0, 0.0, distance)
    else:
        e = math.radians(elevation)
        camera = (0.0, -distance * math.cos(e), distance * math.sin(e))
    return Shot("insert", camera, float(fov), None, 0.0, env=True)


def _mesh_dict(cfg: InsertConfig) -> dict:
    """The mesh of ``cfg.object``, turned z-up, scaled and placed (see the module docstring)."""
    import mitsuba as mi

    path = Path(cfg.object)
    kind = path.suffix.lower()[1:]
    up = (
        mi.ScalarTransform4f().rotate([1.0, 0.0, 0.0], 90.0) if cfg.mesh_up == "y" else mi.ScalarTransform4f()
    )
    try:
        mesh = mi.load_dict({"type": kind, "filename": str(path.resolve()), "to_world": up})
    except Exception as exc:  # Mitsuba's parser error: keep its reason, on one line
        reason = " ".join(str(exc).split(": ", 2)[-1].split())
        raise InputError(
            f"{path}: Mitsuba could not read the mesh ({reason}); give a valid Wavefront .obj (or .ply) file"
        ) from None
    if mesh.face_count() == 0:
        raise InputError(f"{path}: the mesh has no faces; give a .obj with at least one face")
    box = mesh.bbox()
    lo, hi = np.array(box.min, dtype=np.float64), np.array(box.max, dtype=np.float64)
    extent = hi - lo
    if not np.all(np.isfinite(extent)):
        raise InputError(f"{path}: the mesh has non-finite vertex positions; fix the file")
    side = max(extent[0], extent[1]) if max(extent[0], extent[1]) > 0 else extent[2]
    if not side > 0:
        raise InputError(f"{path}: the mesh has zero size; give a mesh with some extent")
    s = float(cfg.width / side)
    cx, cy = ((lo[:2] + hi[:2]) / 2).tolist()
    x, y = cfg.position
    to_world = (
        mi.ScalarTransform4f().translate([x, y, 0.0])
        @ mi.ScalarTransform4f().scale([s, s, s])
        @ mi.ScalarTransform4f().translate([-cx, -cy, -float(lo[2])])
        @ up
    )
    return {"type": kind, "filename": str(path.resolve()), "to_world": to_world, "face_normals": False}


def object_dict(cfg: InsertConfig) -> dict | None:
    """The Mitsuba shape dict of the inserted object with its BSDF (None for ``none``)."""
    import mitsuba as mi

    if cfg.object == "none":
        return None
    half = cfg.width / 2
    x, y = cfg.position
    if cfg.object == "sphere":
        shape = {"type": "sphere", "center": [x, y, half], "radius": half}
    elif cfg.object == "cube":
        shape = {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().translate([x, y, half]) @ mi.ScalarTransform4f().scale(half),
        }
    else:
        shape = _mesh_dict(cfg)
    shape["bsdf"] = dict(MATERIALS[cfg.material][1])
    return shape


def scene_dict(
    plate: Plate,
    cfg: InsertConfig,
    res: int,
    with_object: bool = True,
    shape: dict | None = None,
    fov: float | None = None,
) -> dict:
    """The insertion scene of ``plate`` (module docstring); ``shape``: a prepared
    :func:`object_dict` (built from ``cfg`` when None); ``fov``: the camera's field of view
    (None: the plate's own)."""
    from .scene import sample_shape_dict, sensor_dict, svbrdf_bsdf_dict

    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": MAX_DEPTH, "hide_emitters": True},
        "sensor": sensor_dict(camera_shot(plate.fov if fov is None else fov, cfg.elevation), res, 1, 0),
        "sample": sample_shape_dict(svbrdf_bsdf_dict(plate.maps)),
        "env": plate.emitter(),
    }
    if with_object:
        shape = object_dict(cfg) if shape is None else shape
        if shape is not None:
            scene["object"] = shape
    return scene


def pass_sizes(spp: int) -> list[int]:
    """``spp`` split into passes of at most :data:`PASS_SPP` samples."""
    full, rest = divmod(int(spp), PASS_SPP)
    return [PASS_SPP] * full + ([rest] if rest else [])


def render(
    scene_desc: dict, res: int, spp: int, seed: int, tick: Callable[[int], None] | None = None
) -> np.ndarray:
    """Render ``scene_desc`` in passes (module docstring); (res, res, 3) float32 radiance.
    ``tick(n)`` is called after each pass with its sample count."""
    import mitsuba as mi

    from .capture import shot_seed

    scene = mi.load_dict(scene_desc)
    acc = np.zeros((res, res, 3), dtype=np.float64)
    for k, n in enumerate(pass_sizes(spp)):
        image = np.array(mi.render(scene, spp=n, seed=shot_seed(seed, k)), dtype=np.float32)
        acc += image.reshape(res, res, -1)[..., :3].astype(np.float64) * n
        if tick is not None:
            tick(n)
    image = (acc / spp).astype(np.float32)
    if not np.all(np.isfinite(image)):
        raise RuntimeError("the insertion render has NaN/Inf pixels")
    return image


def object_coverage(
    plate: Plate, cfg: InsertConfig, res: int, shape: dict | None, fov: float, spp: int = COVERAGE_SPP
) -> np.ndarray:
    """(res, res, 1) float32, 1 where a camera ray of the insertion meets the object before the
    plane (any of the pixel's ``spp`` rays: its mean depth differs from the plane's), else 0."""
    import mitsuba as mi

    depths = []
    for with_object in (True, False):
        desc = scene_dict(plate, cfg, res, with_object=with_object, shape=shape, fov=fov)
        desc["integrator"] = {"type": "aov", "aovs": "depth:depth"}
        depths.append(np.array(mi.render(mi.load_dict(desc), spp=spp, seed=0), np.float32)[..., 0])
    scale = max(float(np.max(np.abs(depths[1]))), 1e-6)
    return (np.abs(depths[0] - depths[1]) > 1e-5 * scale).astype(np.float32)[..., None]


def differential(
    photo: np.ndarray, with_object: np.ndarray, without_object: np.ndarray, coverage: np.ndarray
) -> np.ndarray:
    """The object composited into ``photo`` (module docstring, "Background"); every argument is
    (H, W, 3) radiance on one grid but ``coverage`` (H, W, 1) in [0, 1]. Plate pixels are the photo
    × with / without (the object's shadow and inter-reflection as a change of the light the
    camera saw); where the render without the object is darker than :data:`RATIO_FLOOR` × its mean
    luminance, the photo + with − without; object pixels are the render with the object."""
    from .colour import LUMINANCE

    photo = np.asarray(photo, np.float32)
    lum = without_object @ np.asarray(LUMINANCE, np.float32)
    floor = RATIO_FLOOR * max(float(lum.mean()), 1e-12)
    bright = (lum > floor)[..., None]
    ratio = with_object / np.where(bright, without_object, 1.0)
    plate = np.where(bright, photo * ratio, photo + with_object - without_object)
    out = coverage * with_object + (1.0 - coverage) * np.maximum(plate, 0.0)
    return out.astype(np.float32)


def composites(plate: Plate, cfg: InsertConfig) -> bool:
    """Whether the insertion is composited into the plate's photo: ``--background photo``, the
    estimate's own camera and a no-flash photo; else the frame is rendered whole."""
    return cfg.background == "photo" and cfg.elevation >= 90.0 and plate.photo is not None


def photo_background(plate: Plate, cfg: InsertConfig, res: int) -> np.ndarray | None:
    """The photo the insertion is composited into at ``res``², or None when the frame is rendered
    whole (:func:`composites`)."""
    from .imageio import resize_area, upsample_bilinear_fast

    if not composites(plate, cfg):
        return None
    photo = plate.photo
    if photo.shape[:2] == (res, res):
        return photo
    if photo.shape[0] > res:
        return resize_area(photo, (res, res))
    return upsample_bilinear_fast(photo, (res, res)).astype(np.float32)


def insertion_images(
    plate: Plate, cfg: InsertConfig, res: int, shape: dict | None, truth: Plate | None = None, bar=None
) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """The insertion of ``cfg``'s object (``shape``: its prepared :func:`object_dict`) into
    ``plate`` at ``res``², and into ``truth`` when given: ``({"insert": the insertion (composited
    into the plate's photo where :func:`photo_background` allows, else rendered whole), "render":
    the whole-frame render, ["truth": the truth's render]}, seconds per render)``. ``bar``: a
    tqdm bar advanced by each pass's samples."""
    photo = photo_background(plate, cfg, res)
    renders = [("render", plate, cfg.seed, True)]
    if photo is not None and shape is not None:
        renders.append(("render, no object", plate, cfg.seed, False))
    if truth is not None:
        renders.append(("truth", truth, cfg.true_seed, True))
    images, seconds = {}, {}
    for key, p, seed, with_object in renders:
        if bar is not None:
            bar.set_postfix_str(key)
        t = time.perf_counter()
        obj = dict(shape) if shape and with_object else None
        desc = scene_dict(p, cfg, res, with_object, shape=obj, fov=plate.fov)
        images[key] = render(desc, res, cfg.spp, seed, tick=None if bar is None else bar.update)
        seconds[key] = round(time.perf_counter() - t, 3)
    if photo is None:
        images["insert"] = images["render"]
    elif shape is None:  # nothing inserted: the photo itself
        images["insert"] = photo
    else:
        if bar is not None:
            bar.set_postfix_str("composite")
        t = time.perf_counter()
        coverage = object_coverage(plate, cfg, res, dict(shape), plate.fov)
        images["insert"] = differential(photo, images["render"], images.pop("render, no object"), coverage)
        seconds["composite"] = round(time.perf_counter() - t, 3)
    return images, seconds


def truth_again(
    truth: Plate, cfg: InsertConfig, res: int, shape: dict | None, fov: float, bar=None
) -> np.ndarray:
    """The truth's insertion (``shape``: the prepared :func:`object_dict`) rendered once more with
    :attr:`InsertConfig.floor_seed` from the camera of field of view ``fov`` (the estimate's, as
    :func:`insertion_images` renders the truth): against the first truth render its RMSE is the
    truth-vs-truth noise floor at ``cfg.spp`` (issue 13's measure; ``--noise-floor``, ``ebr bench
    insert``)."""
    if bar is not None:
        bar.set_postfix_str("truth again")
    desc = scene_dict(truth, cfg, res, True, shape=dict(shape) if shape else None, fov=fov)
    return render(desc, res, cfg.spp, cfg.floor_seed, tick=None if bar is None else bar.update)


# -- outputs ---------------------------------------------------------------------------------------


def output_paths(out, truth: bool) -> dict[str, Path]:
    """The files written for ``--out OUT``: ``insert`` (OUT), with a truth also ``truth``
    (OUT's stem + ``_truth``, same suffix) and ``compare`` (stem + ``_compare.png``)."""
    out = Path(out)
    if out.suffix.lower() not in (".exr", ".png"):
        raise InputError(
            f"--out {out}: give an image file name ending in .exr (linear radiance) or .png (sRGB preview)"
        )
    if out.is_dir():
        raise InputError(f"--out {out}: is a directory; give an image file name")
    paths = {"insert": out}
    if truth:
        paths["truth"] = out.with_name(f"{out.stem}_truth{out.suffix}")
        paths["compare"] = out.with_name(f"{out.stem}_compare.png")
    for p in paths.values():
        if p.parent.exists() and not p.parent.is_dir():
            raise InputError(f"--out {out}: {p.parent} is not a directory; choose another --out")
        if p.is_dir():
            raise InputError(f"{p}: is a directory; choose another --out")
    return paths


def exposure(image: np.ndarray) -> float:
    """Preview exposure: 1 / the 99.5th luminance percentile (as ``ebr estimate``'s pictures)."""
    from .colour import LUMINANCE

    lum = np.asarray(image, np.float64) @ np.asarray(LUMINANCE, np.float64)
    p = float(np.percentile(lum, 99.5)) if lum.size else 0.0
    return 1.0 / p if p > 0 and math.isfinite(p) else 1.0


def side_by_side(estimate: np.ndarray, truth: np.ndarray, gain: float) -> np.ndarray:
    """[estimate | truth | |estimate − truth| × :data:`DIFF_GAIN`], each × ``gain``, white gaps."""
    h = estimate.shape[0]
    gap = np.ones((h, GAP, 3), np.float32)
    diff = np.abs(estimate - truth) * DIFF_GAIN
    panels = [estimate, gap, truth, gap, diff]
    return np.concatenate([p if p is gap else p * np.float32(gain) for p in panels], axis=1)


def write_outputs(paths: dict[str, Path], images: dict[str, np.ndarray], gain: float) -> list[str]:
    """Write every image under a temporary name, then rename them all: nothing appears unless
    every write succeeded."""
    from .fsutil import atomic_path
    from .imageio import write_exr, write_png

    def write(path: Path, tmp: Path, image: np.ndarray, png_gain: float) -> None:
        if path.suffix.lower() == ".exr":
            write_exr(tmp, image)
        else:
            write_png(tmp, image * np.float32(png_gain), clip="hue")

    with contextlib.ExitStack() as stack:
        temps = {k: stack.enter_context(atomic_path(paths[k])) for k in paths}
        for key in ("insert", "truth"):
            if key in paths:
                write(paths[key], temps[key], images[key], gain)
        if "compare" in paths:
            write_png(temps["compare"], side_by_side(images["insert"], images["truth"], gain), clip="hue")
    return [str(p) for p in paths.values()]


# -- the job ---------------------------------------------------------------------------------------


def run_insert(estimate_dir, out, cfg: InsertConfig, truth_dir=None, progress: bool = True) -> dict:
    """Insert ``cfg``'s object into the estimate at ``estimate_dir`` and write ``out`` (plus the
    truth insertion and the side-by-side picture when ``truth_dir`` is a capture directory).
    Returns the summary (``--json``). Every input is checked before the first render."""
    from tqdm import tqdm

    from .variant import describe, ensure_variant

    t0 = time.perf_counter()
    paths = output_paths(out, truth_dir is not None)
    ensure_variant()
    plate = load_estimate(estimate_dir)
    truth = load_capture(truth_dir) if truth_dir is not None else None
    res = cfg.res or min(plate.resolution, DEFAULT_MAX_RES)
    shape = object_dict(cfg)  # loads (and checks) a mesh file once
    composited = composites(plate, cfg)
    floor = truth is not None and cfg.noise_floor
    renders = 1 + (truth is not None) + (composited and shape is not None) + floor
    bar = tqdm(
        total=cfg.spp * renders,
        desc="insert",
        unit="spp",
        disable=None if progress else True,
        leave=False,
        dynamic_ncols=True,
    )
    try:
        images, seconds = insertion_images(plate, cfg, res, shape, truth, bar)
        again = truth_again(truth, cfg, res, shape, plate.fov, bar) if floor else None
    finally:
        bar.close()
    rendered = images.pop("render")
    gain = exposure(images.get("truth", images["insert"]))
    files = write_outputs(paths, images, gain)
    summary = {
        "out": str(paths["insert"]),
        "files": files,
        "estimate": {
            "path": str(plate.source),
            "kind": plate.kind,
            "env": plate.env,
            "maps": list(plate.maps.shape),
        },
        **cfg.to_json(),
        "resolution": [res, res],
        "fov": plate.fov,
        "camera": list(camera_shot(plate.fov, cfg.elevation).camera),
        "integrator": {"type": "path", "max_depth": MAX_DEPTH, "hide_emitters": True},
        "composited": composited,
        "preview_exposure": gain,
        "render_seconds": seconds,
        "renderer": describe(),
    }
    if truth is not None:
        summary["truth"] = {
            "path": str(truth.source),
            "env": truth.env,
            "maps": list(truth.maps.shape),
            "fov": truth.fov,
        }
        if abs(truth.fov - plate.fov) > 1e-3:
            summary["warnings"] = [
                f"the capture's field of view is {truth.fov:g} degrees, the estimate's "
                f"{plate.fov:g}: both are rendered with the estimate's camera"
            ]
        summary["rmse"] = rmse(images["insert"], images["truth"])
        summary["rel_rmse"] = rel_rmse(images["insert"], images["truth"])
        if composited:  # the same insertion rendered whole, for comparison
            summary["render_rmse"] = rmse(rendered, images["truth"])
            summary["render_rel_rmse"] = rel_rmse(rendered, images["truth"])
        if again is not None:
            summary["noise_floor"] = rmse(again, images["truth"])
            floor_rmse = summary["noise_floor"]
            summary["floor_ratio"] = summary["rmse"] / floor_rmse if floor_rmse > 0 else None
    summary["seconds"] = round(time.perf_counter() - t0, 3)
    return summary


__all__ = [
    "InsertConfig",
    "Plate",
    "MATERIALS",
    "OBJECTS",
    "camera_shot",
    "composites",
    "differential",
    "estimate_photo",
    "insertion_images",
    "load_capture",
    "load_estimate",
    "object_coverage",
    "object_dict",
    "output_paths",
    "photo_background",
    "render",
    "run_insert",
    "scene_dict",
    "side_by_side",
    "truth_again",
]
