"""Capture geometry (``docs/conventions.md``, "Geometry and pixel grid"): the sample square, the
pixel grid and the camera/light setups.

The sample is the square [-1,1]² in the plane z = 0 (normal +z, tangent +x, bitangent +y, world
z-up). Pixel (row i from the top, column j) of an H×W image sees ``x = −1 + (2j+1)/W``,
``y = 1 − (2i+1)/H``. Near shot: camera and flash at (0, 0, 2.414), 45° field of view (the frame is
exactly the sample). Far shot: camera and flash at (0, 0, 10), field of view 2·atan(0.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError

NEAR_DISTANCE = 1.0 / math.tan(math.radians(22.5))  # 2.41421...: the 45° frame is exactly [-1,1]²
FAR_DISTANCE = 10.0
NEAR_FOV = 45.0
FAR_FOV = math.degrees(2.0 * math.atan(0.1))
DEFAULT_FLASH_INTENSITY = 10.0  # W/sr of the isotropic flash; recorded in capture.json
SETUPS = ("near", "near-far", "five-light", "multi-view")
# Roughness of the exemplar materials (:mod:`ebr_mitsuba.exemplar`): the default of
# `ebr exemplars`, of data configs and of the demo, chosen from the roughness study of
# docs/bench/extract_sg.md §3 (`ebr bench extract-sg`).
DEFAULT_EXEMPLAR_ROUGHNESS = (0.1, 0.3, 0.6, 0.9)


@dataclass(frozen=True)
class Shot:
    """One image: a pinhole camera looking at ``target`` and an optional point light.

    ``flash`` is the point light's position (None: no point light) with ``flash_intensity`` W/sr;
    ``env`` says whether the environment lights this shot.
    """

    name: str
    camera: tuple[float, float, float]
    fov: float
    flash: tuple[float, float, float] | None
    flash_intensity: float = DEFAULT_FLASH_INTENSITY
    env: bool = True
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    extra: dict = field(default_factory=dict)

    def in_sample_grid(self) -> bool:
        """True when pixel (i, j) of this shot sees the grid point of the module docstring (fronto-parallel,
        centred, framing exactly [-1,1]²)."""
        cx, cy, cz = self.camera
        half = cz * math.tan(math.radians(self.fov) / 2)
        return cx == 0 and cy == 0 and self.target == (0.0, 0.0, 0.0) and abs(half - 1.0) < 1e-6

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "camera": list(self.camera),
            "target": list(self.target),
            "up": list(self.up),
            "fov": self.fov,
            "flash": None if self.flash is None else list(self.flash),
            "flash_intensity": self.flash_intensity if self.flash is not None else 0.0,
            "env": self.env,
            **self.extra,
        }


def near_shot(flash: bool, env: bool = True, intensity: float = DEFAULT_FLASH_INTENSITY, name=None) -> Shot:
    cam = (0.0, 0.0, NEAR_DISTANCE)
    return Shot(
        name or ("flash" if flash else "noflash"), cam, NEAR_FOV, cam if flash else None, intensity, env
    )


def far_shot(flash: bool, env: bool = True, intensity: float | None = None, name=None) -> Shot:
    cam = (0.0, 0.0, FAR_DISTANCE)
    # Keep the flash irradiance at the sample the same as the near shot's (inverse-square law).
    if intensity is None:
        intensity = DEFAULT_FLASH_INTENSITY * (FAR_DISTANCE / NEAR_DISTANCE) ** 2
    return Shot(
        name or ("far_flash" if flash else "far_noflash"),
        cam,
        FAR_FOV,
        cam if flash else None,
        intensity,
        env,
    )


FIVE_LIGHT_POSITIONS = (
    (0.0, 0.0, NEAR_DISTANCE),
    (-1.2, -1.2, 2.0),
    (1.2, -1.2, 2.0),
    (-1.2, 1.2, 2.0),
    (1.2, 1.2, 2.0),
)


def setup_shots(setup: str, intensity: float = DEFAULT_FLASH_INTENSITY) -> list[Shot]:
    """The shots of a capture setup (``near``, ``near-far``, ``five-light``, ``multi-view``)."""
    if setup == "near":
        return [near_shot(True, intensity=intensity), near_shot(False, intensity=intensity)]
    if setup == "near-far":
        return setup_shots("near", intensity) + [far_shot(True), far_shot(False)]
    if setup == "five-light":
        cam = (0.0, 0.0, NEAR_DISTANCE)
        return [
            Shot(f"light{k}", cam, NEAR_FOV, p, intensity, env=False, extra={"light_index": k})
            for k, p in enumerate(FIVE_LIGHT_POSITIONS)
        ]
    if setup == "multi-view":
        shots = []
        for a, oy in enumerate((0.6, 0.0, -0.6)):
            for b, ox in enumerate((-0.6, 0.0, 0.6)):
                cam = (ox, oy, NEAR_DISTANCE)
                shots.append(
                    Shot(f"view{a}{b}_flash", cam, NEAR_FOV, cam, intensity, env=True, extra={"grid": [a, b]})
                )
        return shots
    raise InputError(f"unknown capture setup {setup!r}; use one of {', '.join(SETUPS)}")


def capture_shots(setup: str, intensity: float = DEFAULT_FLASH_INTENSITY) -> list[Shot]:
    """The shots ``ebr capture`` renders for ``setup``: :func:`setup_shots`, and for ``multi-view``
    also the centre camera without its flash (``noflash``, the near setup's no-flash shot). The
    multi-view networks read the nine flash views only; the no-flash view gives the environment's
    level and colour to the lighting's scale fit of ``ebr estimate --views``
    (``ebr_mitsuba.estimate.multiview``, "Exposure and units"). Generated data sets keep
    :func:`setup_shots` unless their config sets ``[capture] noflash_view``
    (:func:`ebr_mitsuba.data.renderers.shots_of`)."""
    shots = setup_shots(setup, intensity)
    if setup == "multi-view":
        shots.append(near_shot(False, intensity=intensity))
    return shots


def pixel_positions(height: int, width: int) -> np.ndarray:
    """Surface points (H, W, 3) seen by the pixels of the sample grid (z = 0)."""
    j = np.arange(width, dtype=np.float64)
    i = np.arange(height, dtype=np.float64)
    x = -1.0 + (2.0 * j + 1.0) / width
    y = 1.0 - (2.0 * i + 1.0) / height
    xx, yy = np.meshgrid(x, y)
    return np.stack([xx, yy, np.zeros_like(xx)], axis=-1)


def view_directions(height: int, width: int, camera=(0.0, 0.0, NEAR_DISTANCE)) -> np.ndarray:
    """Unit directions (H, W, 3) from the surface points towards ``camera``."""
    p = pixel_positions(height, width)
    d = np.asarray(camera, dtype=np.float64) - p
    return d / np.linalg.norm(d, axis=-1, keepdims=True)
