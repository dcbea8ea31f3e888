"""The multi-view estimate (``ebr estimate --views DIR``): the 9 views of the 3×3 capture in; SVBRDF
maps, per-pixel SG lighting, re-renders of every view and a report out.

The network is the MAIR model (:class:`ebr_mitsuba.nets.MAIRModel`, ``docs/mair.md``: a checkpoint
of ``ebr train`` with ``kind = "mair"``, run through the model's
:class:`~ebr_mitsuba.model.predict.MAIRPredictor`). The shipped model
(``ebr_mitsuba/models/mair_small.pt``, ``configs/mair_small.toml``) runs when ``--checkpoint`` is
not given; without one ``--checkpoint`` is required (without it: exit 2 with one line saying how to
train one). :func:`run_multiview` writes the same kind of output directory as the other estimates
(:func:`ebr_mitsuba.estimate.pipeline.run_estimate`, :func:`.fivelight.run_fivelight`), with the
same writers (:mod:`.outputs`, :mod:`.report`) and the same atomic directory: complete or not at
all, an earlier estimate directory replaced, anything else refused.

**Inputs.** ``DIR`` is the directory of ``ebr capture --setup multi-view``: its ``capture.json``
(``"format": "ebr-capture/1"``, ``"setup": "multi-view"``) lists the 9 flash views and, optionally,
views without their flash (``ebr capture`` adds one: ``noflash``, the centre camera), each with

=======================  ==========================================================================
key                      meaning
=======================  ==========================================================================
``name``                 ``view{a}{b}_flash``: row a (0: the cameras at y = +0.6, 1: y = 0, 2:
                         y = −0.6) and column b (0: x = −0.6, 1: x = 0, 2: x = +0.6) of the grid;
                         ``noflash`` for the centre camera without its flash (any unique name)
``file``                 the image in ``DIR`` (``view{a}{b}_flash.exr`` as written by the capture;
                         PNG and JPEG are read as sRGB)
``camera``, ``target``,  the pinhole camera: position, the point it looks at, its up vector
``up``
``fov``                  horizontal field of view in degrees (``fov_axis`` "x")
``flash``,               the view's flash (a point light, at the camera in the 3×3 setup; null: a
``flash_intensity``      view without its flash) and its intensity in W/sr at the image's exposure
                         (absent: fitted)
=======================  ==========================================================================

A photographed set can be estimated by writing such a ``capture.json`` by hand beside its nine
images. ``DIR`` may also be a sample of a generated multi-view data set: its ``sample.json`` is read
as the record (:func:`sample_capture_record`). Refused with one line (exit 2) and nothing written:
no or an unreadable ``capture.json``, one of another setup, another count than 9 flash views, two
records of one name or file, a view file missing or unreadable, views of different sizes or under
32 pixels, a shot record without a camera, a camera below the sample, more than half of the pixels
saturated, a checkpoint of another kind, no checkpoint.

**Rectification** (:mod:`.rectify`): each view is resampled onto the sample grid of
``docs/conventions.md`` by projecting the grid's surface points into its camera; the points a
camera did not frame, or saw only through pixels straddling the sample's edge, get in-frame
weight 0 (the network sees each view times its weight, the errors leave them out). The working
size follows :func:`.resample.working_size`; the network runs at its grid G (rectified views
area-averaged to it; a pixel counts as in frame there when all of it was), its maps are
area-resampled to the working size, its per-pixel lighting stays at G.

**Exposure and units.** The network saw the views at the *reference exposure* (each flash at
:data:`~ebr_mitsuba.geometry.DEFAULT_FLASH_INTENSITY`). When the flash intensities in photo units
are known (``--flash-intensity``, else ``capture.json``), view k is multiplied by
``DEFAULT_FLASH_INTENSITY / I_k`` before the network sees it. Neither the network's lighting nor
its diffuse map has an absolute scale (their training losses g4 and g3 are scale-invariant), so
the re-render fits them (:func:`fit_scales`): view k is ``a_k F_k + b E_k``, with ``F_k`` the maps
lit by view k's flash at the reference intensity (:func:`ebr_mitsuba.nets.mair_render.
multiview_renders`), ``E_k`` the maps under the predicted per-pixel SGs read as the radiance they
mean, the one ``ebr insert`` renders (:func:`env_renders`: the SGs' irradiance over the
hemisphere above each pixel, their specular reflection by SG convolution), ``a_k`` the known flash
factor (0 for a view without its flash) and ``b ≥ 0`` by least squares over the in-frame,
unsaturated pixels of all views. With the a_k known, the diffuse parts of ``F_k`` and ``E_k`` take
a factor free per pixel and channel while b is fitted, so that the flash, a light of known
intensity, sets the albedo's level and what the views show beyond it sets the environment's. From
the flash views alone that is how each pixel changes from flash to flash, a few per cent of it,
which shading the maps miss moves (a 3 % error per pixel and view took b 4–7 % low in
``tests/test_estimate_views.py``; on a wood capture under a blue sky the lighting came out 0.75 /
0.67 / 0.49 of the truth per channel); the no-flash view of ``ebr capture`` shows ``α b E`` alone
and pins b down. Its pixels weigh as much in the least squares as the flash views' together
(:func:`fit_scales`): at equal weights per pixel that wood's lighting came out 0.96 / 0.94 / 0.86,
weighted 0.995 / 0.99 / 0.95 (docs/mair.md, "Estimating"). The diffuse map is then
brought to photo units by
that factor, per pixel where at least :data:`MIN_VIEWS_PER_PIXEL` views saw it (within
:data:`PIXEL_ALBEDO_RANGE` of its median per channel, ``diffuse_scale``), so that the map's texture
is the views' at the working size and not the network's at its grid (``--no-pixel-albedo``: the
median alone; clipped to [0, 1] either way). Taking the network's diffuse map
as absolute instead made the flash term over-shoot most views, b ≈ 0 and the insertion black
(issue 13). Without known intensities one ``a`` for every view is fitted with ``b`` and the maps
are taken as they are. The lighting written is the network's times ``b``: in photo units.

**The multi-view specular fit** (:func:`fit_specular`, default on; ``--no-view-fit`` keeps the
network's specular and roughness maps). The small MAIR model's specular is coarse
(docs/mair_eval.md: F0 0.032 RMSE on a test split of dielectrics at 0.04; the first shipped model,
trained a fifth as long, 0.09). The views say more: each view's flash puts its highlight at another
place of the sample, so per pixel the nine views sample the lobe at nine angles while the albedo and
the environment's diffuse light are the same in all. For each hypothesis of F0 (grey: 0.04, the
dielectrics of the measured table, or 0.25 / 0.5 / 0.9, a metal) and roughness (20 values, 0.05–1;
every other one first, then the two beside the best), constant over the sample, the re-render is
fitted to the views as above (α per pixel, ``b``) at :data:`FIT_SIZE` and its residual kept; the
hypothesis of least residual replaces the network's maps when it explains the views better than they
do (``relative_residual`` < 1 in ``estimate.json`` under ``view_fit``). Then ``b`` is fitted per
channel: with the specular known, the lighting's colour is the views' beyond the flash (one ``b``
left the network's lighting colour in the albedo: on training samples of real sets, a grey fabric's
diffuse came out 0.68 / 0.29 / 0.06). Needs the flash intensities (``capture.json`` or
``--flash-intensity``). On 8 training-set samples of ``configs/data_real_multiview_train.toml`` (not
the test split) it took the mean per-map RMSE from 0.130 to 0.082 (diffuse 0.187 → 0.075, specular
0.087 → 0.007) with the first shipped model; on the multi-view test split (docs/mair_eval.md,
2026-12-07, with its no-flash view, ablation runs retrained) from 0.0585 to 0.0523 (specular 0.035
→ 0.008, diffuse 0.065 → 0.046, but roughness 0.099 → 0.120: the network's roughness map beats
the one fitted value there; on the
validation set, configs/data_real_multiview_val.toml, keeping the network's roughness with the
fitted F0 was the worse of the two: roughness 0.086 → 0.106, diffuse 0.060 → 0.070), about 6 s per
estimate at 256² on two cores. What it cannot do: a roughness map (one value for the sample); a
mirror-like surface (on one of those samples, a facade of roughness 0.06, the fit read 1.0).
The fit reads the flash views only: a view without its flash shows the environment's reflection,
whose shape the lighting network does not know (below), and read with it the roughness went wrong.
On the validation set with its no-flash view (``configs/data_real_multiview_val.toml`` with
``[capture] noflash_view = true``, 16 samples) the mean per-map RMSE was 0.0517 with it and 0.0456
without (roughness 0.108 → 0.086, better in 8 samples and worse in 1; diffuse 0.0493 → 0.0509);
on the test split, measured after the choice, 0.0641 → 0.0523 (roughness 0.164 → 0.120).

**The environment for insertion** (``env.json``, what ``ebr insert`` lights the object with;
:func:`insertion_environment`, default ``--azimuthal-env``). The per-pixel lobes place the
lighting where the views cannot: a plane seen from above shows how bright the sky is and its
colour (``b``), hardly where around the vertical its light comes from. The shipped small model's
lobes do not depend on the capture: at the centre pixel of ten synthetic multi-view captures
(procedural tiles, wood, plaster, metal, leather and fabric under ten procedural skies, two of
them the ``ebr bench insert`` captures) each of its three lobes' axes lay within 1.2°, 2.7° and
2.2° of its mean (a broad lobe 9° off the zenith towards −y, two sharp blue ones at elevations 65°
and 40°), whatever the sky. A direction that is the same for every capture is the training
prior, and a sphere lit from it is shaded from a side the true sky need not favour. So env.json
holds the centre pixel's lighting averaged over azimuth, one lobe at the zenith
(:meth:`~ebr_mitsuba.sgenv.SGEnvironment.azimuthal`: its profile fitted to the averaged radiance,
the z-up irradiance kept, so the plane is lit as the views say): the expected lighting when the
azimuth is unknown. The per-pixel lobes (``lighting/``) and the re-renders keep the network's.
Chosen on eight synthetic captures that are not the benchmark's (procedural wood:2, plaster:3,
metal:4, leather:6, tiles:7, fabric:1, wood:9 and plaster:8 under procedural maps 5, 11, 12, 9,
4, 6, 10 and 14; ``ebr insert --truth --noise-floor`` at 128², 256 spp, composited): the diffuse
sphere's ratio to the noise floor went from a geometric mean of 4.93 to 4.76 (lower in 6 of 8),
the mirror sphere's 11.7 to 11.0 (lower in 4, higher in 3). With the true environment instead,
everything else estimated, the diffuse ratios are 0.5–1.1: the lighting is the whole error, and
what remains is mostly a sun the network does not find (ratios 6–12). ``ebr bench insert``
measures both (docs/bench/insert.md). For the flash / no-flash estimate the same average is not
used: its lobes come from the exemplars and do carry direction (a procedural tile capture's
diffuse sphere 1.6× → 2.9× averaged).

**Outputs** (beside those of :mod:`.outputs`: ``maps/``, ``inputs/``, ``rerender/``,
``residual/`` per view name, ``novel/``, ``estimate.json``, ``report.html``):

==============================  ===================================================================
path                            content
==============================  ===================================================================
``inputs/<view>.png``           the rectified views (times their in-frame weight), exposure-matched
``lighting/lobes.exr``          the per-pixel SGs at the grid: per lobe s the channels
                                ``sg<s>.axis.X|Y|Z`` (unit, world), ``sg<s>.sharpness``,
                                ``sg<s>.visibility`` (μ) and ``sg<s>.amplitude.R|G|B`` (μ η b, the
                                radiance units of the views)
``lighting/lighting.json``      the lobe count, channel list, η and b
``lighting/irradiance.exr|png`` the SGs' irradiance on the plane (z-up normal) per pixel
``lighting/hemispheres.png``    the incident lighting of a 4 × 4 grid of pixels, each seen from
                                above as ``env_sphere.png`` shows one environment
``env.json``, ``env_*``         the environment for insertion (below) and its pictures
``weights/<view>.png``          the in-frame weight of each view (white: seen)
==============================  ===================================================================
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import numpy as np

from .. import __version__
from ..data.store import SAMPLE_FORMAT, SAMPLE_JSON
from ..errors import InputError
from ..fsutil import atomic_dir
from ..geometry import DEFAULT_FLASH_INTENSITY, Shot, setup_shots
from ..imageio import fast_writes, resize_area, write_exr, write_png
from ..materials import resample_svbrdf
from ..metrics import image_errors
from ..sgenv import SGEnvironment
from ..typedconfig import config, option
from . import outputs
from .inputs import (
    CAPTURE_JSON,
    MAX_SATURATED,
    WARN_SATURATED,
    capture_vector,
    check_saturation_level,
    clip_negatives,
    read_capture_record,
    read_shots_of_one_size,
    saturation_masks,
)
from .options import checkpoint_option, intensity_option, max_size_option, out_option, saturation_option
from .rectify import rectify
from .resample import working_size

VIEW_COUNT = 9
SHIPPED_MAIR_MODEL = "mair_small.pt"  # in ebr_mitsuba/models/ (configs/mair_small.toml), when shipped
SETUP = "multi-view"
POSITION_WARN = 0.05  # world units (the sample is 2 wide) from the training camera positions
HEMISPHERE_GRID = 4  # lighting/hemispheres.png: the lighting of GRID × GRID pixels
HEMISPHERE_SIZE = 48
_FIX = "give the directory of 'ebr capture --setup multi-view' (its 9 views and capture.json)"
TRAIN_HINT = (
    "train one with 'ebr train configs/mair_small.toml' (see docs/mair.md, 'Training') and pass "
    "--checkpoint RUN/model.pt"
)


@config(error=InputError, cli=True)
class MultiViewConfig:
    """Everything a multi-view estimate needs: the options of ``ebr estimate --views`` (flags,
    defaults and help generated from these fields; ``--out``, ``--checkpoint``,
    ``--flash-intensity``, ``--saturation-level`` and ``--max-size`` are the flags of the same
    :class:`~ebr_mitsuba.estimate.pipeline.EstimateConfig` fields). ``views``: the capture
    directory (module docstring)."""

    views: str = option(
        meaning="directory of 'ebr capture --setup multi-view' (its views and capture.json) or a "
        "generated multi-view sample (sample.json; docs/mair.md, 'Estimating'); instead of --flash",
        flag="--views",
        metavar="DIR",
    )
    out: str = out_option()
    checkpoint: str | None = checkpoint_option(
        'MAIR model checkpoint (ebr train, kind = "mair")', "the shipped ebr_mitsuba/models/mair_small.pt"
    )
    flash_intensity: float | None = intensity_option(
        "every view's flash intensity in W/sr at the views' exposure"
    )
    saturation_level: float | None = saturation_option()
    max_size: int = max_size_option("larger views are rectified to it")
    view_fit: bool = option(
        True,
        "the specular F0 and roughness fitted to the nine views (module docstring, 'The multi-view "
        "specular fit'); --no-view-fit keeps the network's",
        flag="--view-fit",
    )
    pixel_albedo: bool = option(
        True,
        "the diffuse map's texture read off the views pixel by pixel (the re-render fit's α, where "
        "at least 3 views see the pixel; module docstring, 'Exposure and units'); --no-pixel-albedo "
        "keeps the network's map times one factor per channel",
        flag="--pixel-albedo",
    )
    azimuthal_env: bool = option(
        True,
        "env.json (what ebr insert lights with) is the centre pixel's lighting averaged over azimuth, "
        "one lobe at the zenith (module docstring, 'The environment for insertion'); "
        "--no-azimuthal-env writes the network's lobes as they are",
        flag="--azimuthal-env",
    )


MULTIVIEW_FLAGS = tuple(f.name for f in dataclasses.fields(MultiViewConfig))  # all set by flags


@dataclass(frozen=True)
class ViewShot:
    """One view of a multi-view capture: its file, camera and flash."""

    name: str
    path: str
    camera: tuple[float, float, float]
    target: tuple[float, float, float]
    up: tuple[float, float, float]
    fov: float
    flash: tuple[float, float, float] | None
    intensity: float | None = None  # W/sr in photo units; None: unknown


# -- the model --------------------------------------------------------------------------------------


def shipped_model_path() -> Path:
    """Where the shipped multi-view (MAIR) model lives (:mod:`ebr_mitsuba.models`; it may be absent)."""
    from importlib import resources

    return Path(str(resources.files("ebr_mitsuba.models").joinpath(SHIPPED_MAIR_MODEL)))


def model_path(checkpoint: str | None) -> Path:
    """``checkpoint``, or the shipped MAIR model; :class:`InputError` when neither exists."""
    if checkpoint is None:
        path = shipped_model_path()
        if not path.is_file():
            raise InputError(f"--views needs a multi-view (MAIR) model and none is shipped; {TRAIN_HINT}")
        return path
    path = Path(checkpoint)
    if not path.is_file():
        raise InputError(
            f"--checkpoint {checkpoint}: no such file; give a checkpoint of 'ebr train' with kind = \"mair\""
        )
    return path


def load_mair(path: str | Path, device: str = "auto"):
    """The MAIR model in ``path`` as a :class:`~ebr_mitsuba.model.predict.MAIRPredictor`; another
    kind of checkpoint is refused with one line naming the file."""
    from ..model.bundle import bundle_from_checkpoint
    from ..model.checkpoint import load_checkpoint
    from ..model.device import pick_device
    from ..model.predict import as_predictor

    data = load_checkpoint(path)
    if data.get("kind") != "mair":
        raise InputError(
            f"{path}: a '{data.get('kind')}' checkpoint, but --views needs a multi-view 'mair' one; "
            f"{TRAIN_HINT}"
        )
    return as_predictor(bundle_from_checkpoint(data, str(path), pick_device(device)).train(False))


# -- the capture ------------------------------------------------------------------------------------


_vector = partial(capture_vector, fix=f"fix {CAPTURE_JSON}")


def read_capture_json(folder: Path) -> dict:
    """``folder/capture.json`` of a multi-view capture, or the record of a generated multi-view
    sample (:func:`sample_capture_record`); :class:`InputError` naming the file otherwise."""
    path = folder / CAPTURE_JSON
    if not path.is_file():
        if (folder / SAMPLE_JSON).is_file():
            return sample_capture_record(folder / SAMPLE_JSON)
        raise InputError(f"--views {folder}: no {CAPTURE_JSON} (the cameras of the views); {_FIX}")
    meta = read_capture_record(path, "fix it or capture again", _FIX)
    if meta.get("setup") != SETUP:
        raise InputError(f"{path}: a '{meta.get('setup')}' capture; --views needs a '{SETUP}' one ({_FIX})")
    return meta


def sample_capture_record(path: Path) -> dict:
    """A generated sample's ``sample.json`` (``ebr generate``, :mod:`ebr_mitsuba.data.store`) read
    as the ``capture.json`` of its views: each shot's ``photo`` is its ``file`` and its flash
    intensity is stated in photo units (the data set's intensity times the sample's exposure)."""
    meta = read_capture_record(path, "regenerate the sample", _FIX, SAMPLE_FORMAT, "a generated sample")
    if meta.get("setup") != SETUP:
        raise InputError(f"{path}: a '{meta.get('setup')}' sample; --views needs a '{SETUP}' one ({_FIX})")
    try:
        exposure = float(meta["camera"]["exposure"])
    except (KeyError, TypeError, ValueError):
        raise InputError(f"{path}: no camera exposure; regenerate the sample") from None
    shots = []
    for rec in meta.get("shots") or []:
        if not isinstance(rec, dict):
            raise InputError(f"{path}: a shot record is not a table; regenerate the sample")
        shot = {k: v for k, v in rec.items() if k not in ("photo", "flash_intensity")}
        shot["file"] = rec.get("photo")
        if isinstance(rec.get("flash_intensity"), (int, float)):
            shot["flash_intensity"] = float(rec["flash_intensity"]) * exposure
        shots.append(shot)
    return {"setup": SETUP, "shots": shots, "record_path": str(path)}


def resolve_views(views: str | Path) -> tuple[list[ViewShot], list[str]]:
    """The views of the capture directory ``views`` (module docstring, "Inputs"): the 9 flash views
    and any views without their flash, in record order, and warnings about them."""
    folder = Path(views)
    if not folder.is_dir():
        raise InputError(f"--views {views}: not a directory; {_FIX}")
    meta = read_capture_json(folder)
    where = Path(meta.get("record_path") or folder / CAPTURE_JSON)
    records = meta.get("shots")
    records = records if isinstance(records, list) else []
    n = sum(1 for r in records if not isinstance(r, dict) or r.get("flash") is not None)
    if n != VIEW_COUNT:
        raise InputError(
            f"{where}: {n} flash views; a multi-view capture has {VIEW_COUNT} (the 3×3 grid), "
            f'plus optionally views without their flash ("flash": null)'
        )
    shots, warnings = [], []
    defaults = {s.name: s for s in setup_shots(SETUP)}
    for k, rec in enumerate(records):
        if not isinstance(rec, dict) or not isinstance(rec.get("file"), str):
            raise InputError(f"{where}: shot record {k} has no 'file'; fix {CAPTURE_JSON}")
        name = str(rec.get("name") or f"view{k}")
        for key in ("camera", "fov"):
            if rec.get(key) is None:
                raise InputError(f"{where}: shot {name} has no '{key}'; fix {CAPTURE_JSON}")
        camera = _vector(rec["camera"], f"{where}: shot {name} camera")
        target = _vector(rec.get("target", [0.0, 0.0, 0.0]), f"{where}: shot {name} target")
        up = _vector(rec.get("up", [0.0, 1.0, 0.0]), f"{where}: shot {name} up")
        try:
            fov = float(rec["fov"])
        except (TypeError, ValueError):
            fov = float("nan")
        if not (0 < fov < 180):
            raise InputError(f"{where}: shot {name} fov {rec['fov']!r}: give degrees in (0, 180)")
        if camera[2] <= 0:
            raise InputError(f"{where}: shot {name} camera {list(camera)} is not above the sample (z > 0)")
        flash = None if rec.get("flash") is None else _vector(rec["flash"], f"{where}: shot {name} flash")
        intensity = rec.get("flash_intensity")
        intensity = float(intensity) if isinstance(intensity, (int, float)) and flash is not None else None
        if intensity is not None and not (math.isfinite(intensity) and intensity > 0):
            raise InputError(f"{where}: shot {name} flash_intensity {intensity}: give a finite value > 0")
        path = folder / rec["file"]
        if not path.is_file():
            raise InputError(f"--views {folder}: view {name} ({path.name}) is missing; {_FIX}")
        shots.append(ViewShot(name, str(path), camera, target, up, fov, flash, intensity))
        ref = defaults.get(name)
        if ref is not None and math.dist(camera, ref.camera) > POSITION_WARN:
            warnings.append(
                f"{name}: camera at {list(camera)}, {math.dist(camera, ref.camera):.2f} from the position "
                f"the model was trained with ({list(ref.camera)}); expect a bias"
            )
        if flash is not None and math.dist(flash, camera) > POSITION_WARN:
            warnings.append(f"{name}: the flash is not at the camera; the model was trained with it there")
    if len({s.path for s in shots}) != len(shots):
        raise InputError(f"{where}: two shot records name the same file; give one image per view")
    if len({s.name for s in shots}) != len(shots):
        raise InputError(f"{where}: two shot records have the same name; give each view its own")
    return shots, warnings


@dataclass
class CameraViews:
    """The 9 camera images as read and checked: ``images`` (name → (h, w, 3) float32, photo
    units, negatives clipped), ``saturated`` (name → (h, w) bool), ``saturated_fraction``."""

    images: dict[str, np.ndarray]
    saturated: dict[str, np.ndarray]
    saturated_fraction: float

    @property
    def size(self) -> tuple[int, int]:
        return next(iter(self.images.values())).shape[:2]


@dataclass
class RectifiedViews:
    """The views on the sample grid at the working size: ``images`` (name → (W, W, 3), photo units,
    times the in-frame weight), ``weights`` (name → (W, W) in {0, 1}), ``saturated`` (name →
    (W, W) bool), ``source_size`` (h, w) of the camera images."""

    images: dict[str, np.ndarray]
    weights: dict[str, np.ndarray]
    saturated: dict[str, np.ndarray]
    source_size: tuple[int, int]
    saturated_fraction: float


def read_views(shots: list[ViewShot], saturation_level: float | None, warnings: list[str]) -> CameraViews:
    """Read and check the 9 camera images (module docstring, "Inputs"): one size, at least
    :data:`~.resample.MIN_INPUT_SIZE` pixels, at most half of the pixels saturated."""
    check_saturation_level(saturation_level)
    images, levels, _ = read_shots_of_one_size(
        [(s.name, s.path) for s in shots], "views", "give 9 views of one size"
    )
    masks = saturation_masks(images, levels, saturation_level)
    frac = float(np.mean([m.mean() for m in masks.values()]))
    if frac > MAX_SATURATED:
        raise InputError(
            f"--views: {frac:.0%} of the pixels are saturated (clipped) in the views; lower the exposure "
            f"and capture again"
        )
    if frac > WARN_SATURATED:
        warnings.append(f"{frac:.1%} of the pixels are saturated; they are left out of the errors")
    clip_negatives(images, warnings)
    return CameraViews(images, masks, frac)


def rectify_views(
    shots: list[ViewShot],
    camera: CameraViews,
    work: int,
    progress: Callable[[str], None] | None = None,
) -> RectifiedViews:
    """The views on the ``work``² sample grid (module docstring, "Rectification")."""
    rect, weights, sat = {}, {}, {}
    for s in shots:
        if progress is not None:
            progress(s.name)
        # the saturation mask rides along as a fourth channel: one projection per view
        both = np.concatenate([camera.images[s.name], camera.saturated[s.name][..., None]], axis=-1)
        out, wt = rectify(both, s.camera, s.target, s.up, s.fov, work)
        if not wt.any():
            raise InputError(f"--views: {s.path}: its camera does not see the sample; check {CAPTURE_JSON}")
        rect[s.name] = (out[..., :3] * wt[..., None]).astype(np.float32)
        weights[s.name] = wt
        sat[s.name] = out[..., 3] > 0
    h, w = camera.size
    return RectifiedViews(rect, weights, sat, (int(h), int(w)), camera.saturated_fraction)


# -- re-renders -------------------------------------------------------------------------------------


def _torch_lighting(lighting, size: int):
    """:class:`~ebr_mitsuba.model.predictor.PixelLighting` as the torch one, bilinearly resized to
    ``size``² (axes renormalised)."""
    import torch
    import torch.nn.functional as F

    from ..nets.mair_lighting import PixelSGLighting

    def t(a, channels):  # (S, H, W[, C]) → (1, S, C, size, size)
        x = torch.from_numpy(np.ascontiguousarray(a, np.float32))
        x = x[..., None] if x.ndim == 3 else x
        x = x.permute(0, 3, 1, 2)
        if x.shape[-1] != size:
            x = F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False)
        return x[None]

    axis = t(lighting.axis, 3)
    axis = axis / axis.norm(dim=2, keepdim=True).clamp_min(1e-8)
    return PixelSGLighting(
        axis,
        t(lighting.sharpness, 1),
        t(lighting.visibility, 1),
        torch.from_numpy(np.asarray(lighting.intensity, np.float32))[None],
    )


#: Sharpness range of the table of :func:`clamped_cosine_fraction` (log-spaced; the network's
#: lobes lie in ``sharpness_range`` = [1, 2000], values outside are clamped to the table's ends).
CLAMPED_COSINE_SHARPNESS = (0.25, 8192.0)


@functools.lru_cache(maxsize=1)
def _clamped_cosine_table(n_sharpness: int = 97, n_cos: int = 129, n_theta: int = 2048):
    """``(n_sharpness, n_cos)`` float64 table of :func:`clamped_cosine_fraction` at log-spaced λ
    over :data:`CLAMPED_COSINE_SHARPNESS` and ``c = n·ξ`` evenly over [−1, 1]: the azimuth integral
    in closed form (the modified Bessel function I₀), the polar one by the midpoint rule."""
    import torch

    lo, hi = (math.log(v) for v in CLAMPED_COSINE_SHARPNESS)
    lam = torch.exp(torch.linspace(lo, hi, n_sharpness, dtype=torch.float64))[:, None, None]
    c = torch.linspace(-1.0, 1.0, n_cos, dtype=torch.float64)[None, :, None]
    s = (1.0 - c * c).clamp_min(0.0).sqrt()
    theta = (torch.arange(n_theta, dtype=torch.float64) + 0.5) * (math.pi / 2) / n_theta
    ct, st = torch.cos(theta), torch.sin(theta)
    x = lam * s * st  # ∫ exp(x cos φ) dφ = 2π I₀(x) = 2π e^x i0e(x)
    g = torch.exp(lam * (c * ct + s * st - 1.0)) * torch.special.i0e(x)  # ≤ 1: no overflow
    h = 2 * math.pi * (g * ct * st).sum(-1) * (math.pi / 2) / n_theta
    integral = 2 * math.pi * (-torch.expm1(-2 * lam[..., 0, 0])) / lam[..., 0, 0]
    return (h / integral[:, None]).to(torch.float32)


def clamped_cosine_fraction(sharpness, cos):
    """``∫_{n·ω>0} G(ω) (n·ω) dω / ∫ G(ω) dω`` of the SG ``G(ω) = exp(λ(ξ·ω − 1))`` with
    ``cos = n·ξ`` (torch tensors of one shape): what the lobe's integral, read as a light from
    ``ξ``, must be weighed by so that it lights a surface of normal n as the SG radiance itself
    does (the clamped-cosine convolution; → ``max(cos, 0)`` for sharp lobes). Interpolated
    bilinearly in (log λ, cos) from :func:`_clamped_cosine_table` (error under 10⁻³)."""
    import torch
    import torch.nn.functional as F

    table = _clamped_cosine_table().to(cos)
    lo, hi = (math.log(v) for v in CLAMPED_COSINE_SHARPNESS)
    u = (torch.log(sharpness.clamp(*CLAMPED_COSINE_SHARPNESS)) - lo) / (hi - lo) * 2 - 1
    v = cos.clamp(-1.0, 1.0)
    grid = torch.stack([v.reshape(-1), u.reshape(-1)], dim=-1)[None, None]  # x: cos, y: λ
    out = F.grid_sample(table[None, None], grid, mode="bilinear", align_corners=True)
    return out.reshape(cos.shape)


def sg_product_integral(lam1, lam2, d):
    """``∫ exp(λ₁(ξ₁·ω − 1)) exp(λ₂(ξ₂·ω − 1)) dω`` over the sphere with ``d = ‖λ₁ξ₁ + λ₂ξ₂‖``
    (torch, elementwise): ``2π e^(d − λ₁ − λ₂) (1 − e^(−2d)) / d``."""
    import torch

    dd = d.clamp_min(1e-6)
    return 2 * math.pi * torch.exp(d - lam1 - lam2) * (-torch.expm1(-2 * dd)) / dd


def env_renders(maps, lighting, directions):
    """The diffuse and specular light of the per-pixel SGs on ``maps`` (torch
    :class:`~ebr_mitsuba.nets.maps.Maps`, one image) seen along ``directions`` (N, 3, H, W), each
    (N, H, W, 3): the radiance the written lighting means and ``ebr insert`` renders,
    ``L_p(ω) = Σ_s μ_s η_s exp(λ_s(ξ_s·ω − 1))``. Diffuse: the albedo / π times the SGs' irradiance
    over the hemisphere above the pixel (:func:`clamped_cosine_fraction`). Specular: the
    spherical-Gaussian convolution of Wang et al. (2009) — GGX's D as the SG
    ``exp((2/α²)(h·n − 1)) / (π α²)``, warped about the mirror direction r to sharpness
    ``2/α² / (4 n·v)`` and integrated against each lobe in closed form (:func:`sg_product_integral`),
    times Fresnel, the Smith term and the cosine at r. Reading each lobe as a light from its axis
    carrying its whole integral (what :func:`~ebr_mitsuba.nets.mair_render.multiview_renders` does
    for the training loss, where free scales absorb it) counts a broad lobe's half below the
    horizon and its grazing light at full cosine, and its specular reflection at the GGX peak:
    for the λ ≈ 1 ambient lobe the network predicts, about twice the diffuse light, and more of the
    specular."""
    import torch

    from ..nets import torch_brdf as tb
    from ..nets.mair_render import sg_integral

    n = tb.perturbed_normal(maps.normal[0].permute(1, 2, 0))  # (H, W, 3)
    dif = maps.diffuse[0].permute(1, 2, 0)
    spec = maps.specular[0].permute(1, 2, 0)
    alpha = tb.alpha_from_roughness(maps.roughness[0, 0])  # (H, W)
    xi = lighting.axis[0].permute(0, 2, 3, 1)  # (S, H, W, 3)
    lam = lighting.sharpness[0, :, 0]  # (S, H, W)
    amp = lighting.amplitude[0].permute(0, 2, 3, 1)  # (S, H, W, 3)
    v = directions.to(n).permute(0, 2, 3, 1)  # (N, H, W, 3)

    irr = (amp * (sg_integral(lam) * clamped_cosine_fraction(lam, (xi * n).sum(-1)))[..., None]).sum(0)
    cv = (n * v).sum(-1)  # (N, H, W)
    seen = ((cv > 0) & (v[..., 2] > 0))[..., None]
    env_d = torch.where(seen, dif * tb.INV_PI * irr, torch.zeros_like(v))

    r = 2 * cv[..., None] * n - v  # the mirror direction
    cr = (n * r).sum(-1)
    lam_w = (2 / (alpha * alpha)) / (4 * cv.clamp_min(1e-3))  # (N, H, W)
    light = torch.zeros_like(v)
    for s in range(lam.shape[0]):
        d = torch.linalg.vector_norm(lam[s][None, ..., None] * xi[s][None] + lam_w[..., None] * r, dim=-1)
        light = light + amp[s][None] * sg_product_integral(lam[s][None], lam_w, d)[..., None]
    brdf = (
        tb.fresnel_schlick(spec, cv)
        * (
            tb.smith_vis(cr.clamp_min(0.0), cv.clamp_min(0.0), alpha)
            * cr.clamp_min(0.0)
            / (math.pi * alpha * alpha)
        )[..., None]
    )
    ok = seen & ((cr > 0) & (r[..., 2] > 0))[..., None]
    env_s = torch.where(ok, light * brdf, torch.zeros_like(v))
    return env_d, env_s


@dataclass
class RerenderParts:
    """The re-render's parts per view, each (N, size, size, 3): the maps lit by the view's flash at
    :data:`DEFAULT_FLASH_INTENSITY` (``flash_diffuse``, ``flash_specular``) and by the per-pixel SGs
    at the network's scale (``env_diffuse``, ``env_specular``)."""

    flash_diffuse: np.ndarray
    flash_specular: np.ndarray
    env_diffuse: np.ndarray
    env_specular: np.ndarray

    @property
    def flash(self) -> np.ndarray:
        return self.flash_diffuse + self.flash_specular

    @property
    def env(self) -> np.ndarray:
        return self.env_diffuse + self.env_specular


def rerender_parts(maps, lighting, shots: list[ViewShot], size: int) -> RerenderParts:
    """Per view (N, size, size, 3): the maps lit by the view's flash at
    :data:`DEFAULT_FLASH_INTENSITY` from its position, and under the per-pixel SGs at the network's
    scale (:func:`env_renders`), diffuse and specular apart. The flash's renderer
    (:func:`~ebr_mitsuba.nets.mair_render.multiview_renders`) takes it at the camera, as in the 3×3
    setup (a flash elsewhere is a warning of :func:`resolve_views`)."""
    import torch

    from ..nets.mair_lighting import PixelSGLighting
    from ..nets.mair_render import multiview_renders
    from ..nets.mair_views import view_direction_maps
    from ..nets.maps import Maps

    with torch.no_grad():
        m = Maps.from_svbrdf([maps])
        vshots = [Shot(s.name, s.camera, s.fov, s.flash) for s in shots]
        dirs = view_direction_maps(size, size, vshots)
        flashes = torch.tensor(
            [s.flash if s.flash is not None else s.camera for s in shots], dtype=torch.float32
        )
        lt = _torch_lighting(lighting, size)
        env_d, env_s = env_renders(m, lt, dirs)
        # no lobes: the flash alone
        dark = PixelSGLighting(lt.axis[:, :0], lt.sharpness[:, :0], lt.visibility[:, :0], lt.intensity[:, :0])
        fl_d, fl_s = multiview_renders(m, dark, dirs, flashes, DEFAULT_FLASH_INTENSITY)

    def hwc(x):
        return x[0].permute(0, 2, 3, 1).numpy().astype(np.float32)

    def hwc_(x):
        return x.numpy().astype(np.float32)

    return RerenderParts(hwc(fl_d), hwc(fl_s), hwc_(env_d), hwc_(env_s))


@dataclass(frozen=True)
class Scales:
    """What :func:`fit_scales` finds: the flash factor ``a`` per view, the lighting scale ``b``
    and ``diffuse`` (3,), the factor per channel the network's diffuse map is brought to photo
    units with (ones where it was not fitted)."""

    a: list[float]
    b: tuple[float, float, float]
    diffuse: tuple[float, float, float] = (1.0, 1.0, 1.0)
    residual: float = 0.0  # the views' squared residual at (a, b, α), summed over the masks
    alpha: np.ndarray | None = field(default=None, repr=False)  # α per pixel and channel (H, W, 3)
    seen: np.ndarray | None = field(default=None, repr=False)  # (H, W): α counts there (enough views)

    def pixel_factor(self) -> np.ndarray | None:
        """The diffuse factor per pixel (H, W, 3): α where enough views saw the pixel, kept within
        :data:`PIXEL_ALBEDO_RANGE` of the median ``diffuse`` (per channel), the median elsewhere;
        None when α was not fitted (unknown flash intensities)."""
        if self.alpha is None or self.seen is None:
            return None
        median = np.asarray(self.diffuse, np.float32)
        alpha = np.clip(self.alpha, median / PIXEL_ALBEDO_RANGE, median * PIXEL_ALBEDO_RANGE)
        return np.where(self.seen[..., None], alpha, median).astype(np.float32)


#: How far the per-pixel diffuse factor α may stray from its median (a factor either way): a
#: specular highlight the fit's constant F0 and roughness miss lands in α (a dark green sample of the
#: validation set came out 0.06 / 0.08 / 0.14 for 0.011 / 0.006 / 0.005). Chosen on
#: ``configs/data_real_multiview_val.toml`` (16 samples): diffuse RMSE 0.0693 with the median alone,
#: 0.0624 with α unclipped, 0.0604 within 2×, 0.0601 within 1.5×.
PIXEL_ALBEDO_RANGE = 2.0


#: What ``env.json`` holds (``lighting/lighting.json``'s and estimate.json's ``env_json``).
ENV_AZIMUTHAL = "the centre pixel's lobes averaged over azimuth: one lobe at the zenith"
ENV_CENTRE = "the centre pixel's lobes as the network predicts them"

#: Lighting scales :func:`fit_scales` tries (times b₀, the scale at which the lighting alone
#: explains the views) before refining the best by golden-section search.
SCALE_GRID = np.concatenate([[0.0], np.geomspace(1e-4, 4.0, 161)])
MIN_VIEWS_PER_PIXEL = 3  # pixels seen by fewer views leave the diffuse factor's median out


def _views_sum(x, y, w) -> np.ndarray:
    return np.einsum("nhwc,nhwc,nhw->hwc", x, y, w, optimize=True)


def fit_scales(
    photos,
    parts: RerenderParts,
    masks,
    known: list[float] | None,
    colour: bool = False,
    lit: list[bool] | None = None,
) -> Scales:
    """The re-render's scales (module docstring, "Exposure and units") by least squares over
    ``masks`` (in-frame, unsaturated pixels of each view); ``photos`` (N, H, W, 3) per view,
    ``parts`` their :func:`rerender_parts`; ``known``: the flash factors a_k (None: one fitted a);
    ``colour``: b fitted per channel (the lighting's colour too, as after the view fit; else one b);
    ``lit``: per view, whether its flash fired (None: every view's). A view without its flash has
    the flash factor 0 (in ``known`` too): it shows ``α (b E_d) + b E_s`` alone, the environment's
    level and colour on the albedo the flash views set, which pins b down (module docstring,
    "Exposure and units"). The views without a flash weigh as much in the sums as the flash views
    together (each pixel of one no-flash view among nine flash views: 9 times a flash view's).

    With the a_k known, view k is modelled as ``α(p) (a_k F_d,k + b E_d,k) + a_k F_s,k + b E_s,k``
    with a diffuse factor α ≥ 0 free per pixel and channel: the network's diffuse map has no
    absolute scale (its loss g3 is scale-invariant) and little of the texture right, and a map
    taken as is makes a_k F_d,k over- or under-shoot the views, which then leaves the environment
    a negative residual (b clamped to 0: a black insertion) or too much. α is solved in closed form
    for each b, whose residual (the views' sums precomputed per pixel as quadratics in b) is then
    minimised over b ≥ 0: what separates flash from environment is how each pixel's flash term
    changes from view to view while the environment's diffuse light does not. The maps are brought
    to photo units with the median α per channel (``diffuse``). Without the a_k, one a and b are
    fitted with the maps as they are (α = 1): the flash's level and the albedo's cannot be told
    apart then."""
    w = np.stack([np.asarray(m, np.float64) for m in masks])
    if known is not None:
        on = np.asarray(known) > 0
    else:
        on = np.ones(len(w), bool) if lit is None else np.asarray(lit, bool)
    if on.any() and not on.all():  # the no-flash views weigh as much as the flash views together
        w[~on] *= on.sum() / (~on).sum()
    p = np.stack([np.asarray(x, np.float64) for x in photos])
    fd, fs = parts.flash_diffuse.astype(np.float64), parts.flash_specular.astype(np.float64)
    ed, es = parts.env_diffuse.astype(np.float64), parts.env_specular.astype(np.float64)
    if known is None:
        return _fit_unknown_flash(p, fd + fs, ed + es, w, on.astype(np.float64))
    a = np.asarray(known, np.float64)[:, None, None, None]
    groups = [slice(c, c + 1) for c in range(3)] if colour else [slice(None)]  # b per group
    bs, alphas, res, seen = [], [], 0.0, True
    for sl in groups:
        b, al, r, seen_g = _fit_known_flash(
            p[..., sl], fd[..., sl], fs[..., sl], ed[..., sl], es[..., sl], w, a
        )
        bs += [float(b)] * (3 // len(groups))
        alphas.append(al)
        res += r
        seen = seen & seen_g
    al = np.concatenate(alphas, -1)
    diffuse = tuple(float(np.median(al[..., c][seen])) if seen.any() else 1.0 for c in range(3))
    return Scales(list(map(float, known)), tuple(bs), diffuse, res, al.astype(np.float32), seen)


def _fit_known_flash(p, fd, fs, ed, es, w, a):
    """(b, α per pixel, residual, pixels α counts over) for known flash factors ``a`` (N, 1, 1, 1),
    on the channels of the arrays given (:func:`fit_scales`)."""
    r0, r1 = p - a * fs, es  # the views less the specular parts: r0 − b r1
    h0, h1 = a * fd, ed  # the diffuse parts at α = 1: h0 + b h1
    rr = [_views_sum(r0, r0, w), -2 * _views_sum(r0, r1, w), _views_sum(r1, r1, w)]
    rh = [_views_sum(r0, h0, w), _views_sum(r0, h1, w) - _views_sum(r1, h0, w), -_views_sum(r1, h1, w)]
    hh = [_views_sum(h0, h0, w), 2 * _views_sum(h0, h1, w), _views_sum(h1, h1, w)]

    def quad(c, b):
        return c[0] + b * (c[1] + b * c[2])

    def alpha(b):  # (α, its numerator) at b: a scalar, or (K, 1, 1, 1) for K b's at once
        num = np.maximum(quad(rh, b), 0.0)
        den = quad(hh, b)
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0), num

    def residuals(bs) -> np.ndarray:  # the residual at each b of bs, a block of b's at a time
        out = []
        block = max(1, int(2e6 // max(rr[0].size, 1)))
        for i in range(0, len(bs), block):
            b = np.asarray(bs[i : i + block], np.float64).reshape(-1, *([1] * rr[0].ndim))
            al, num = alpha(b)
            out.append((quad(rr, b) - al * num).reshape(len(b), -1).sum(1))
        return np.concatenate(out)

    def residual(b) -> float:
        return float(residuals([b])[0])

    ee = float(np.sum(hh[2] + 2 * _views_sum(h1, r1, w) + rr[2]))  # ‖E_d + E_s‖²
    pe = float(np.sum(_views_sum(p, ed + es, w)))
    b0 = pe / ee if ee > 0 and pe > 0 else 0.0
    b = 0.0
    if b0 > 0:
        grid = SCALE_GRID * b0
        res = residuals(grid)
        k = int(np.argmin(res))
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        g = (math.sqrt(5) - 1) / 2
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        r1, r2 = residual(x1), residual(x2)
        for _ in range(40):  # golden-section search in the best grid cell's neighbourhood
            if r1 <= r2:  # the minimum is in [lo, x2]: x1 becomes the upper probe
                hi, x2, r2 = x2, x1, r1
                x1 = hi - g * (hi - lo)
                r1 = residual(x1)
            else:
                lo, x1, r1 = x1, x2, r2
                x2 = lo + g * (hi - lo)
                r2 = residual(x2)
        b = min((grid[k], (lo + hi) / 2), key=residual)
    al = alpha(b)[0]
    seen = ((w > 0).sum(0) >= MIN_VIEWS_PER_PIXEL) & (hh[0] > 0).all(-1)
    return b, al, residual(b), seen


def _fit_unknown_flash(p, f, e, w, on) -> Scales:
    """One a for every flash view (``on`` 1 per view; its flash part ``f`` counts only there) and
    b ≥ 0 (module docstring), the maps as they are."""
    f = f * on[:, None, None, None]

    def dot(x, y):
        return float(np.sum(_views_sum(x, y, w)))

    ff, ee, fe, pf, pe = dot(f, f), dot(e, e), dot(f, e), dot(p, f), dot(p, e)
    det = ff * ee - fe * fe
    a, b = (
        ((pf * ee - pe * fe) / det, (pe * ff - pf * fe) / det)
        if det > 1e-12 * max(ff * ee, 1e-30)
        else (-1, -1)
    )
    if a < 0 or b < 0:  # the best of the two one-term fits
        a1 = pf / ff if ff > 0 else 0.0
        b1 = pe / ee if ee > 0 else 0.0
        r_a = float(np.sum(w[..., None] * (p - a1 * f) ** 2))
        r_b = float(np.sum(w[..., None] * (p - b1 * e) ** 2))
        a, b = (max(a1, 0.0), 0.0) if r_a <= r_b else (0.0, max(b1, 0.0))
    if not a > 0:
        raise InputError(
            "--views: the views show no light from their flashes; check the files, or give --flash-intensity"
        )
    return Scales([float(a * x) for x in on], (b, b, b))


def scale_diffuse(maps, parts: RerenderParts, factor) -> tuple[object, RerenderParts]:
    """``maps`` with the diffuse map times ``factor`` ((3,), or (H, W, 3) per pixel), clipped to
    [0, 1], and ``parts`` to match (the diffuse parts are linear in the diffuse map, pixel by
    pixel)."""
    old = np.asarray(maps.diffuse, np.float32)
    new = np.clip(old * np.asarray(factor, np.float32), 0.0, 1.0).astype(np.float32)
    ratio = np.where(old > 0, new / np.where(old > 0, old, 1.0), 0.0).astype(np.float32)
    return dataclasses.replace(maps, diffuse=new), dataclasses.replace(
        parts, flash_diffuse=parts.flash_diffuse * ratio, env_diffuse=parts.env_diffuse * ratio
    )


# -- the multi-view specular fit ----------------------------------------------------------------

#: The hypotheses of :func:`fit_specular`: a grey F0 (0.04: the dielectrics of the measured table;
#: the others: metals) times a roughness of the grid, both constant over the sample.
FIT_F0 = (0.04, 0.25, 0.5, 0.9)
FIT_ROUGHNESS = tuple(float(x) for x in np.round(np.linspace(0.05, 1.0, 20), 3))
#: The size the views are area-averaged to for the fit (the maps are then set at the full size).
FIT_SIZE = 64


@dataclass(frozen=True)
class SpecularFit:
    """What :func:`fit_specular` finds: the F0 and roughness of lowest residual, whether a metal
    (F0 above 0.04) won, the residual relative to the network's specular and roughness (< 1: the
    fit explains the views better), and the grid's residuals (F0 × roughness)."""

    f0: float
    roughness: float
    relative_residual: float
    residuals: np.ndarray

    @property
    def metal(self) -> bool:
        return self.f0 > FIT_F0[0]

    def to_json(self) -> dict:
        return {
            "f0": self.f0,
            "roughness": self.roughness,
            "metal": self.metal,
            "relative_residual": self.relative_residual,
            "f0_grid": list(FIT_F0),
            "roughness_grid": list(FIT_ROUGHNESS),
        }


def constant_specular(maps, f0: float, roughness: float):
    """``maps`` (an (H, W) SVBRDF) with a grey specular ``f0`` and a ``roughness`` constant over it."""
    h, w = maps.shape
    return dataclasses.replace(
        maps,
        specular=np.full((h, w, 3), f0, np.float32),
        roughness=np.full((h, w), roughness, np.float32),
    )


def fit_specular(
    maps, lighting, shots, photos, masks, known: list[float], size: int = FIT_SIZE
) -> SpecularFit:
    """The specular F0 and roughness, constant over the sample, that re-render the views best
    (module docstring, "The multi-view specular fit"): for each hypothesis of FIT_F0 × FIT_ROUGHNESS
    the views' re-render is fitted as by :func:`fit_scales` (known flash factors ``known``, the
    diffuse factor free per pixel, the lighting's scale b) at ``size`` and its residual compared
    with that of the network's own specular and roughness maps."""

    def small(a):
        a = np.asarray(a, np.float32)
        return a if a.shape[0] == size else resize_area(a, (size, size))

    photos_s = [small(p) for p in photos]
    masks_s = [small(np.asarray(m, np.float32)[..., None])[..., 0] >= 1 - 1e-6 for m in masks]
    base = resample_svbrdf(maps, size) if maps.shape != (size, size) else maps

    def residual(f0: float | None, r: float | None) -> float:
        m = base if f0 is None else constant_specular(base, f0, r)
        parts = rerender_parts(m, lighting, shots, size)
        return fit_scales(photos_s, parts, masks_s, known, colour=True).residual

    # every other roughness of the grid first, then the two beside the best of each F0
    grid = np.full((len(FIT_F0), len(FIT_ROUGHNESS)), np.inf)
    for i, f0 in enumerate(FIT_F0):
        for j in range(0, len(FIT_ROUGHNESS), 2):
            grid[i, j] = residual(f0, FIT_ROUGHNESS[j])
        j = int(np.argmin(grid[i]))
        for jj in (j - 1, j + 1):
            if 0 <= jj < len(FIT_ROUGHNESS) and not np.isfinite(grid[i, jj]):
                grid[i, jj] = residual(f0, FIT_ROUGHNESS[jj])
    i, j = np.unravel_index(int(np.argmin(grid)), grid.shape)
    network = residual(None, None)
    rel = float(grid[i, j] / network) if network > 0 else 1.0
    return SpecularFit(FIT_F0[i], FIT_ROUGHNESS[j], rel, grid)


# -- lighting files ---------------------------------------------------------------------------------


def lobe_channels(num_sgs: int) -> list[str]:
    """The channel names of ``lighting/lobes.exr`` (module docstring)."""
    out = []
    for s in range(num_sgs):
        out += [f"sg{s}.axis.{c}" for c in "XYZ"] + [f"sg{s}.sharpness", f"sg{s}.visibility"]
        out += [f"sg{s}.amplitude.{c}" for c in "RGB"]
    return out


def lighting_irradiance(lighting) -> np.ndarray:
    """Irradiance (H, W, 3) of the per-pixel SGs on the z-up plane (each lobe a directional
    light of its integral, as the re-render reads it)."""
    lam = lighting.sharpness.astype(np.float64)
    integral = 2 * np.pi * (-np.expm1(-2 * lam)) / lam
    cos = np.maximum(lighting.axis[..., 2].astype(np.float64), 0.0)
    return np.einsum("shw,shwc->hwc", integral * cos, lighting.amplitude.astype(np.float64)).astype(
        np.float32
    )


def hemisphere_mosaic(lighting, grid: int = HEMISPHERE_GRID, size: int = HEMISPHERE_SIZE) -> np.ndarray:
    """The incident lighting of a ``grid × grid`` set of pixels (evenly spread, row-major as in the
    image), each an upper hemisphere seen from above (+x right, +y up), tiled with 2-pixel gaps."""
    d, inside = outputs.hemisphere_directions(size)
    h, w = lighting.shape
    rows = [int((r + 0.5) * h / grid) for r in range(grid)]
    cols = [int((c + 0.5) * w / grid) for c in range(grid)]
    gap = 2
    mosaic = np.zeros((grid * (size + gap) - gap, grid * (size + gap) - gap, 3), np.float32)
    for a, i in enumerate(rows):
        for b, j in enumerate(cols):
            img = lighting.pixel_environment(i, j).eval(d.reshape(-1, 3)).reshape(size, size, 3)
            y, x = a * (size + gap), b * (size + gap)
            mosaic[y : y + size, x : x + size] = img * inside[..., None]
    return mosaic


def insertion_environment(lighting, azimuthal: bool = True) -> SGEnvironment:
    """The environment ``env.json`` holds (module docstring, "The environment for insertion"): the
    centre pixel's lobes of ``lighting`` (:class:`~ebr_mitsuba.model.predictor.PixelLighting`),
    averaged over azimuth into one zenith lobe (:meth:`SGEnvironment.azimuthal`) unless
    ``azimuthal`` is False."""
    env = lighting.pixel_environment()
    return env.azimuthal() if azimuthal else env


def read_centre_lobes(out: Path) -> SGEnvironment:
    """The centre pixel's lobes as ``out/lighting/`` holds them (what ``--no-azimuthal-env`` writes
    to env.json), read back from ``lobes.exr`` without estimating again."""
    from ..imageio import read_exr

    meta = json.loads((out / "lighting" / "lighting.json").read_text())
    lobes = read_exr(out / "lighting" / "lobes.exr", meta["channels"])
    h, w = lobes.shape[:2]
    px = lobes[h // 2, w // 2].reshape(meta["num_sgs"], 8)  # axis, sharpness, visibility, amplitude
    return SGEnvironment(px[:, :3], np.maximum(px[:, 3], 1e-6), np.maximum(px[:, 5:], 0.0))


def write_lighting(
    out: Path, network_lighting, scale: tuple[float, float, float], azimuthal: bool = True
) -> tuple[list[str], SGEnvironment]:
    """``lighting/`` and ``env.json`` + pictures (module docstring): the network's lighting times
    ``scale`` (R, G, B); env.json the :func:`insertion_environment`. Returns the files and that
    environment."""
    (out / "lighting").mkdir(exist_ok=True)
    scale = [float(x) for x in scale]
    lighting = network_lighting.scaled(np.asarray(scale, np.float32))
    amp = lighting.amplitude
    planes = []
    for s in range(lighting.num_sgs):
        planes += [
            lighting.axis[s],
            lighting.sharpness[s][..., None],
            lighting.visibility[s][..., None],
            amp[s],
        ]
    with fast_writes():
        write_exr(
            out / "lighting" / "lobes.exr",
            np.concatenate(planes, axis=-1),
            channels=lobe_channels(lighting.num_sgs),
        )
    meta = {
        "format": "ebr-pixel-sg/1",
        "num_sgs": lighting.num_sgs,
        "resolution": list(lighting.shape),
        "channels": lobe_channels(lighting.num_sgs),
        "radiance": "L_p(w) = sum_s amplitude_s(p) exp(sharpness_s(p) (axis_s(p).w - 1)); amplitude = "
        "visibility * intensity (photo units)",
        "intensity": lighting.intensity.tolist(),
        "network_intensity": network_lighting.intensity.tolist(),
        "scale": scale,
        "scale_note": "intensity = network_intensity * scale per channel (least squares of the re-renders "
        "to the views)",
        "env_json": ENV_AZIMUTHAL if azimuthal else ENV_CENTRE,
    }
    (out / "lighting" / "lighting.json").write_text(json.dumps(meta, indent=1) + "\n")
    irr = lighting_irradiance(lighting)
    mosaic = hemisphere_mosaic(lighting)
    with fast_writes():
        write_exr(out / "lighting" / "irradiance.exr", irr)
    outputs.preview(out / "lighting" / "irradiance.png", irr, outputs.exposure_of(irr))
    sky = float(np.median(mosaic[mosaic.sum(-1) > 0].sum(-1) / 3)) if (mosaic > 0).any() else 0.0
    outputs.preview(out / "lighting" / "hemispheres.png", mosaic, 0.25 / sky if sky > 0 else 1.0)
    env = insertion_environment(lighting, azimuthal)
    env.save(out / "env.json")
    files = ["lighting/lobes.exr", "lighting/lighting.json", "lighting/irradiance.exr"]
    files += ["lighting/irradiance.png", "lighting/hemispheres.png"]
    return files + outputs.env_pictures(env, out), env


def write_weights(out: Path, weights: dict[str, np.ndarray]) -> list[str]:
    (out / "weights").mkdir(exist_ok=True)
    files = []
    for name, w in weights.items():
        with fast_writes():
            write_png(out / "weights" / f"{name}.png", np.repeat(w[..., None], 3, axis=-1), encode="linear")
        files.append(f"weights/{name}.png")
    return files


# -- the job ----------------------------------------------------------------------------------------


@dataclass
class ViewsEstimate:
    """What :func:`estimate_views` makes of a capture: its ``shots``, the rectified ``views`` at the
    working size ``work``, the model ``grid``, the ``maps`` at ``work``, the network's ``prediction``
    (lighting without scale), the re-render parts ``flash`` and ``env`` per view (of ``maps``), the
    fitted flash factors ``a`` and lighting scale ``b`` (the lighting in photo units is the
    network's times b), ``known`` (the flash intensities in photo units, None: fitted) and where
    they came from, ``to_reference`` (each view's factor to the reference exposure), ``warnings``,
    ``diffuse_scale`` (the factor per channel ``maps``' diffuse is the network's times, before
    clipping to [0, 1]; module docstring, "Exposure and units"), ``specular_fit`` (None: not run;
    ``maps`` carry its F0 and roughness when its relative residual is below 1)."""

    shots: list[ViewShot]
    views: RectifiedViews
    work: int
    grid: int
    maps: object
    prediction: object
    flash: np.ndarray
    env: np.ndarray
    a: list[float]
    b: tuple[float, float, float]
    known: list[float] | None
    known_source: str | None
    to_reference: list[float]
    warnings: list[str]
    diffuse_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    specular_fit: SpecularFit | None = None

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.shots]

    @property
    def lighting(self):
        """The per-pixel lighting in photo units (:class:`~ebr_mitsuba.model.predictor.PixelLighting`)."""
        return self.prediction.lighting.scaled(np.asarray(self.b, np.float32))

    def masks(self) -> list[np.ndarray]:
        """Per view: the pixels it saw in frame and unsaturated (where the errors count)."""
        return [(self.views.weights[n] > 0) & ~self.views.saturated[n] for n in self.names]

    def renders(self) -> dict[str, np.ndarray]:
        """Per view: the re-render ``a_k F_k + b E_k`` times the view's in-frame weight."""
        return {
            n: (
                (self.a[k] * self.flash[k] + np.float32(self.b) * self.env[k])
                * self.views.weights[n][..., None]
            ).astype(np.float32)
            for k, n in enumerate(self.names)
        }


def estimate_views(
    cfg: MultiViewConfig,
    predictor,
    *,
    log: Callable[[str], None] | None = None,
    tick: Callable[[str], None] | None = None,
    stage: Callable | None = None,
    resolved: tuple[list[ViewShot], list[str]] | None = None,
) -> ViewsEstimate:
    """Read, rectify and estimate the capture of ``cfg.views`` with ``predictor`` (a
    :class:`~ebr_mitsuba.model.predictor.ViewsPredictor`, or None: ``cfg.checkpoint``) and fit the
    re-render's scales (module docstring); writes nothing. ``log``: stage messages; ``tick(what)``:
    called after each view's rectification and after the network and the re-render; ``stage(name,
    t0)``: the clock of :class:`.outputs.Stages`; ``resolved``: what :func:`resolve_views` made of
    ``cfg.views`` already (None: resolved here)."""
    from ..model.predictor import ViewsPredictor

    log = log or (lambda msg: None)
    tick = tick or (lambda what: None)
    stage = stage or (lambda name, t0: None)
    t0 = time.perf_counter()
    path = model_path(cfg.checkpoint) if predictor is None else None
    shots, warnings = resolve_views(cfg.views) if resolved is None else resolved
    lit = [s.flash is not None for s in shots]  # the network reads the flash views; the fit all
    camera_views = read_views(shots, cfg.saturation_level, warnings)
    if cfg.flash_intensity is not None:  # finite and > 0: the frozen config checked it
        known, known_source = [float(cfg.flash_intensity) if on else 0.0 for on in lit], "--flash-intensity"
    elif all(s.intensity is not None for s in shots if s.flash is not None):
        known, known_source = [float(s.intensity) if on else 0.0 for s, on in zip(shots, lit)], CAPTURE_JSON
    else:
        known, known_source = None, None
    stage("inputs", t0)

    t0 = time.perf_counter()
    if predictor is None:
        predictor = load_mair(path)
    if not isinstance(predictor, ViewsPredictor):
        raise InputError(f"--checkpoint {cfg.checkpoint}: not a multi-view model; {TRAIN_HINT}")
    grid = int(predictor.grid)
    size = min(camera_views.size)
    work = working_size(size, grid, cfg.max_size)
    if size > work:
        warnings.append(
            f"the views are {size}x{size} pixels or more: estimating at {work}x{work} (the working size "
            f"limit, --max-size {cfg.max_size}); give --max-size {size} for the full size"
        )
    stage("model", t0)
    for w in warnings:
        log(f"warning: {w}")

    t0 = time.perf_counter()
    log(f"rectifying the {len(shots)} views onto the sample grid")
    views = rectify_views(shots, camera_views, work, tick)
    stage("rectify", t0)

    t0 = time.perf_counter()
    log(f"estimating the maps and the per-pixel lighting at {grid}x{grid} (working size {work}x{work})")
    names = [s.name for s in shots]
    # each flash view's factor to the reference exposure (None: a view without its flash)
    to_reference = [
        None if not on else DEFAULT_FLASH_INTENSITY / known[i] if known else 1.0 for i, on in enumerate(lit)
    ]
    seen = [(s, f) for s, f in zip(shots, to_reference) if f is not None]  # what the network reads
    stack = np.stack([views.images[s.name] * np.float32(f) for s, f in seen])
    wts = np.stack([views.weights[s.name] for s, _ in seen])
    if work != grid:
        stack = np.stack([resize_area(v, (grid, grid)) for v in stack])
        wts = np.stack([resize_area(w[..., None], (grid, grid))[..., 0] >= 1 - 1e-6 for w in wts])
    cameras = [s.camera for s, _ in seen]
    pred = predictor.predict_views(stack.astype(np.float32), wts.astype(np.float32), cameras)
    maps = pred.maps if work == grid else resample_svbrdf(pred.maps, work)
    if maps.shape != (work, work):
        raise RuntimeError(f"the network returned {maps.shape} maps for a {work}x{work} grid")
    tick("network")
    stage("network", t0)

    t0 = time.perf_counter()
    photos = [views.images[n] for n in names]
    masks = [(views.weights[n] > 0) & ~views.saturated[n] for n in names]
    factors = [k / DEFAULT_FLASH_INTENSITY for k in known] if known else None
    specular_fit = None
    if cfg.view_fit and factors is not None:  # the flash's known level is what separates F0 from albedo
        log("fitting the specular F0 and roughness to the flash views")
        on = [k for k, flash in enumerate(lit) if flash]  # module docstring: the flash views only
        specular_fit = fit_specular(
            maps,
            pred.lighting,
            [shots[k] for k in on],
            [photos[k] for k in on],
            [masks[k] for k in on],
            [factors[k] for k in on],
        )
        if specular_fit.relative_residual < 1:
            maps = constant_specular(maps, specular_fit.f0, specular_fit.roughness)
        stage("view fit", t0)
        t0 = time.perf_counter()
    log(f"re-rendering the {len(shots)} views")
    parts = rerender_parts(maps, pred.lighting, shots, work)
    scales = fit_scales(photos, parts, masks, factors, colour=specular_fit is not None, lit=lit)
    per_pixel = scales.pixel_factor() if cfg.pixel_albedo else None
    maps, parts = scale_diffuse(maps, parts, scales.diffuse if per_pixel is None else per_pixel)
    tick("re-render")
    stage("rerender", t0)
    return ViewsEstimate(
        shots,
        views,
        work,
        grid,
        maps,
        pred,
        parts.flash,
        parts.env,
        scales.a,
        scales.b,
        known,
        known_source,
        to_reference,
        warnings,
        scales.diffuse,
        specular_fit,
    )


def _finite_mean(values) -> float | None:
    finite = [float(v) for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def run_multiview(
    cfg: MultiViewConfig,
    *,
    log: Callable[[str], None] | None = None,
    bar: Callable | None = None,
    predictor=None,
) -> dict:
    """Run the multi-view estimate of ``cfg``; return the summary (also ``estimate.json``).

    ``log(msg)``: stage messages (stderr in the command); ``bar``: a tqdm-like factory for the
    progress bar (stderr); ``predictor``: a :class:`~ebr_mitsuba.model.predictor.ViewsPredictor`
    already loaded (None: ``cfg.checkpoint``)."""
    from .pipeline import ESTIMATE_FORMAT

    log = log or (lambda msg: None)
    stage = outputs.Stages(cfg.out)  # the clock; --out checked
    out, timings = stage.out, stage.timings
    path = model_path(cfg.checkpoint) if predictor is None else None

    resolved = resolve_views(cfg.views)
    steps = len(resolved[0]) + 4  # each view's rectification, network, re-render, files
    progress = None  # opened at the first step: the inputs and the model are checked before

    def tick(what: str) -> None:
        nonlocal progress
        if bar is None:
            return
        if progress is None:
            progress = bar(total=steps, desc="estimate --views", unit="step")
        progress.set_postfix_str(what)
        progress.update(1)

    try:
        est = estimate_views(cfg, predictor, log=log, tick=tick, stage=stage, resolved=resolved)
        shots, views, work, names = est.shots, est.views, est.work, est.names
        known, warnings = est.known, est.warnings
        photos = [views.images[n] for n in names]
        renders = est.renders()
        errors = {
            n: image_errors(renders[n], photos[k], m) for k, (n, m) in enumerate(zip(names, est.masks()))
        }
        errors["mean"] = {  # over the views it is defined for (a black no-flash view has no rel_rmse)
            key: _finite_mean([errors[n][key] for n in names]) for key in ("rmse", "rel_rmse")
        }
        lighting = est.lighting
        intensities = {
            n: (
                est.a[k] * DEFAULT_FLASH_INTENSITY,
                "no flash" if s.flash is None else est.known_source if known else "fitted",
            )
            for k, (n, s) in enumerate(zip(names, shots))
        }
        folder = Path(cfg.views)
        geometry = folder / (CAPTURE_JSON if (folder / CAPTURE_JSON).is_file() else SAMPLE_JSON)

        summary = {
            "format": ESTIMATE_FORMAT,
            "version": __version__,
            "out": str(out),
            "capture": SETUP,
            "model": {"kind": "mair", "checkpoint": str(path) if path is not None else None},
            "inputs": {
                "paths": {s.name: s.path for s in shots},
                "views": {
                    s.name: {
                        "camera": list(s.camera),
                        "fov": s.fov,
                        "in_frame": float(views.weights[s.name].mean()),
                    }
                    for s in shots
                },
                "size": [work, work],
                "source_size": list(views.source_size),
                "fov": shots[0].fov,
                "flash_only": False,
                "exposure": {n: {"factor": 1.0, "source": "as captured (one exposure)"} for n in names},
                "shifts": {},
                "alignment": {},
                "highlight": None,
                "saturated_fraction": views.saturated_fraction,
                "warnings": list(warnings),
                "geometry": str(geometry),
            },
            "model_grid": est.grid,
            "resolution": work,
            "tiles": 1,
            "tile": work,
            "ensemble": [work],
            "render_mode": "per-pixel SGs",
            "flash": {n: {"intensity": float(v), "source": src} for n, (v, src) in intensities.items()},
            "exposure": {
                "to_reference": dict(zip(names, est.to_reference)),
                "source": est.known_source or "none (the reference exposure assumed)",
            },
            "lobes": lighting.num_sgs,
            "lighting": {
                "per_pixel_sgs": lighting.num_sgs,
                "grid": list(lighting.shape),
                "scale": [float(x) for x in est.b],
                "diffuse_scale": list(est.diffuse_scale),
                "centre_pixel": "env.json",
                "env_json": ENV_AZIMUTHAL if cfg.azimuthal_env else ENV_CENTRE,
            },
            "view_fit": None if est.specular_fit is None else est.specular_fit.to_json(),
            "rerender_error": {"network": errors, "refined": None},
            "refine": None,
            "prediction_timings": {k: round(v, 3) for k, v in est.prediction.timings.items()},
            "flash_fit": None,
            "warnings": list(warnings),
            "timings": timings,
        }

        t0 = time.perf_counter()
        log(f"writing {out}")
        maps = est.maps
        with atomic_dir(out) as tmp:
            files = outputs.write_maps(maps, tmp / "maps", "ebr estimate --views (MAIR network)")
            files += outputs.write_shots(tmp, dict(zip(names, photos)), renders)
            files += write_weights(tmp, views.weights)
            written, env = write_lighting(tmp, est.prediction.lighting, est.b, cfg.azimuthal_env)
            files += written
            centre = min((s for s in shots if s.flash is not None), key=lambda s: math.hypot(*s.camera[:2]))
            files += outputs.write_novel(maps, env, intensities[centre.name][0], tmp, float(centre.camera[2]))
            stage("outputs", t0)
            tick("outputs")
            outputs.write_report_and_summary(tmp, summary, files, stage)
            tick("report")
    finally:
        if progress is not None:
            progress.close()
    return summary


__all__ = [
    "MULTIVIEW_FLAGS",
    "MultiViewConfig",
    "TRAIN_HINT",
    "VIEW_COUNT",
    "RerenderParts",
    "Scales",
    "ViewShot",
    "ViewsEstimate",
    "clamped_cosine_fraction",
    "env_renders",
    "estimate_views",
    "fit_scales",
    "load_mair",
    "read_views",
    "rectify_views",
    "rerender_parts",
    "scale_diffuse",
    "model_path",
    "resolve_views",
    "run_multiview",
]
