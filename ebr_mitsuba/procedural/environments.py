"""Procedural SG environments (world z-up, RGB amplitudes), scaled to a level set by the flash.

``make_environment(seed, kind=None, intensity=None)`` draws a kind and a level from
``np.random.default_rng(seed)`` (both draws always happen, so giving the kind or the level the seed
would have picked returns the identical environment), builds the lobes of that kind, scales them
so that the luminance of the irradiance on the sample plane (normal +z) is

    E_env = INTENSITY_LEVELS[level] × FLASH_IRRADIANCE,

and finally rotates the whole environment by a random angle about z. ``FLASH_IRRADIANCE`` is the
default flash's irradiance at the sample centre, ``DEFAULT_FLASH_INTENSITY / NEAR_DISTANCE²`` ≈ 1.72
(a mid-grey diffuse surface then shows ≈ 0.27 radiance under the flash alone). The irradiance is the
exact clamped-cosine integral of each lobe (``SGEnvironment.irradiance``), summed.

===========  ====================================================================================
kind         lobes
===========  ====================================================================================
sun_sky      sun: λ log-uniform in [1e3, 5e3], elevation 12°–75°, warmer when low, 55–85 % of the
             irradiance; sky: a blue zenith lobe (λ 1.5–4), a whitish circumsolar/horizon lobe
             towards the sun (λ 3–8) and a pale opposite-horizon lobe (λ 2–4); ground bounce: a lobe
             on −z (λ 1–2.5) of radiance albedo·E/π, albedo 0.1–0.3, earthy colour
window       indoor: one or two window lobes (λ log-uniform in [20, 300], elevation 5°–45°, azimuths
             within ±60° of each other, daylight or warm white) giving 60–85 % of the irradiance, a
             warm diffuse fill lobe from above (λ 0.5–2) and a dim floor bounce on −z
overcast     three to five broad lobes (λ 0.5–4), one near the zenith, the others at elevations
             20°–70°, grey-white to slightly blue; a dim ground lobe on −z
===========  ====================================================================================

==========  ======================  ==========
level       irradiance / flash's    E (≈)
==========  ======================  ==========
low         0.2                     0.34
medium      1.0                     1.72
high        3.0                     5.15
==========  ======================  ==========
"""

from __future__ import annotations

import math

import numpy as np

from ..colour import LUMINANCE
from ..errors import InputError
from ..geometry import DEFAULT_FLASH_INTENSITY, NEAR_DISTANCE
from ..sgenv import SGEnvironment

ENV_KINDS = ("sun_sky", "window", "overcast")
INTENSITY_LEVELS: dict[str, float] = {"low": 0.2, "medium": 1.0, "high": 3.0}
#: Irradiance of the default flash at the sample centre (W/sr / distance²).
FLASH_IRRADIANCE = DEFAULT_FLASH_INTENSITY / NEAR_DISTANCE**2


def irradiance_luminance(env: SGEnvironment, normal=(0.0, 0.0, 1.0)) -> float:
    """Luminance of the irradiance of ``env`` on a plane of unit ``normal``
    (:meth:`~ebr_mitsuba.sgenv.SGEnvironment.irradiance`; the quantity the intensity levels fix)."""
    return float(env.irradiance(normal) @ LUMINANCE)


def _direction(elevation: float, azimuth: float) -> np.ndarray:
    ce = math.cos(elevation)
    return np.array([ce * math.cos(azimuth), ce * math.sin(azimuth), math.sin(elevation)])


def _unit_lum(rgb) -> np.ndarray:
    c = np.asarray(rgb, dtype=np.float64)
    return c / float(c @ LUMINANCE)


def _log_uniform(rng, lo, hi) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _lobe_irradiance(axis, lam) -> float:
    """Irradiance on +z of a unit-amplitude lobe."""
    return irradiance_luminance(SGEnvironment(np.asarray(axis)[None], [lam], [[1.0, 1.0, 1.0]]))


def _assemble(lobes, shares, target: float, extras=()) -> SGEnvironment:
    """Lobes ``(axis, λ, colour)`` with luminance-1 colours; ``shares`` of the +z irradiance.

    Each lobe's amplitude gives it ``share × target`` of the irradiance; ``extras`` are lobes
    ``(axis, λ, radiance RGB)`` (e.g. ground bounce) added as they are. The sum is then rescaled to
    hit ``target`` exactly.
    """
    axes, lams, amps = [], [], []
    for (axis, lam, colour), share in zip(lobes, shares):
        e = _lobe_irradiance(axis, lam)
        axes.append(axis)
        lams.append(lam)
        amps.append(colour * (share * target / e))
    for axis, lam, radiance in extras:
        axes.append(axis)
        lams.append(lam)
        amps.append(np.asarray(radiance, dtype=np.float64))
    env = SGEnvironment(np.array(axes), np.array(lams), np.array(amps))
    return env.scaled(target / irradiance_luminance(env))


def _sun_sky(rng, target: float) -> SGEnvironment:
    elev = math.radians(rng.uniform(12.0, 75.0))
    warm = 1.0 - math.sin(elev)
    sun = (
        _direction(elev, 0.0),
        _log_uniform(rng, 1e3, 5e3),
        _unit_lum([1.0, 0.95 - 0.25 * warm, 0.88 - 0.45 * warm]),
    )
    zenith = (
        np.array([0.0, 0.0, 1.0]),
        rng.uniform(1.5, 4.0),
        _unit_lum([0.45, 0.62, 1.0] * (1.0 + 0.1 * rng.uniform(-1, 1, 3))),
    )
    circum = (
        _direction(0.5 * elev, rng.uniform(-0.2, 0.2)),
        rng.uniform(3.0, 8.0),
        _unit_lum([0.95, 0.93, 1.0]),
    )
    opposite = (
        _direction(math.radians(rng.uniform(5, 20)), math.pi + rng.uniform(-0.5, 0.5)),
        rng.uniform(2.0, 4.0),
        _unit_lum([0.7, 0.8, 1.0]),
    )
    sun_share = rng.uniform(0.55, 0.85)
    sky = rng.dirichlet([3.0, 2.0, 1.0]) * (1.0 - sun_share)
    albedo = rng.uniform(0.1, 0.3)
    ground_rgb = _unit_lum([0.32, 0.28, 0.2] * (1.0 + 0.15 * rng.uniform(-1, 1, 3)))
    ground = (np.array([0.0, 0.0, -1.0]), rng.uniform(1.0, 2.5), ground_rgb * albedo * target / math.pi)
    return _assemble([sun, zenith, circum, opposite], [sun_share, *sky], target, extras=[ground])


def _window(rng, target: float) -> SGEnvironment:
    count = int(rng.integers(1, 3))
    daylight = rng.uniform() < 0.6
    base_az = rng.uniform(-math.pi, math.pi)
    lobes = []
    for i in range(2):  # always draw two, use ``count``
        elev = math.radians(rng.uniform(5.0, 45.0))
        az = base_az + (0.0 if i == 0 else rng.uniform(-math.pi / 3, math.pi / 3))
        colour = [0.9, 0.95, 1.0] if daylight else [1.0, 0.85, 0.65]
        lobe = (
            _direction(elev, az),
            _log_uniform(rng, 20.0, 300.0),
            _unit_lum(np.asarray(colour) * (1.0 + 0.05 * rng.uniform(-1, 1, 3))),
        )
        if i < count:
            lobes.append(lobe)
    window_share = rng.uniform(0.6, 0.85)
    split = rng.dirichlet([2.0, 2.0]) if count == 2 else np.array([1.0])
    fill = (
        _direction(math.radians(rng.uniform(50, 90)), rng.uniform(-math.pi, math.pi)),
        rng.uniform(0.5, 2.0),
        _unit_lum([1.0, 0.9, 0.78] * (1.0 + 0.08 * rng.uniform(-1, 1, 3))),
    )
    floor = (
        np.array([0.0, 0.0, -1.0]),
        rng.uniform(1.0, 2.0),
        _unit_lum([0.6, 0.5, 0.4]) * rng.uniform(0.05, 0.2) * target / math.pi,
    )
    return _assemble([*lobes, fill], [*(split * window_share), 1.0 - window_share], target, extras=[floor])


def _overcast(rng, target: float) -> SGEnvironment:
    count = int(rng.integers(3, 6))
    tint = [0.92, 0.96, 1.0] * (1.0 + 0.04 * rng.uniform(-1, 1, 3))
    lobes = [
        (
            _direction(math.radians(rng.uniform(70, 90)), rng.uniform(-math.pi, math.pi)),
            rng.uniform(0.5, 2.0),
            _unit_lum(tint),
        )
    ]
    for _ in range(count - 1):
        lobes.append(
            (
                _direction(math.radians(rng.uniform(20, 70)), rng.uniform(-math.pi, math.pi)),
                rng.uniform(0.5, 4.0),
                _unit_lum(tint * (1.0 + 0.05 * rng.uniform(-1, 1, 3))),
            )
        )
    shares = rng.dirichlet(np.ones(count))
    ground = (
        np.array([0.0, 0.0, -1.0]),
        rng.uniform(1.0, 2.0),
        _unit_lum([0.3, 0.3, 0.28]) * rng.uniform(0.1, 0.25) * target / math.pi,
    )
    return _assemble(lobes, shares, target, extras=[ground])


_BUILDERS = {"sun_sky": _sun_sky, "window": _window, "overcast": _overcast}


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"procedural environment: seed {seed!r} must be an integer >= 0")
    return int(seed)


def environment_choice(seed: int, kind: str | None = None, intensity: str | None = None) -> tuple[str, str]:
    """The ``(kind, level)`` that :func:`make_environment` uses for these arguments."""
    rng = np.random.default_rng(_check_seed(seed))
    return _choose(rng, kind, intensity)


def _choose(rng, kind, intensity) -> tuple[str, str]:
    drawn_kind = ENV_KINDS[int(rng.integers(len(ENV_KINDS)))]
    drawn_level = tuple(INTENSITY_LEVELS)[int(rng.integers(len(INTENSITY_LEVELS)))]
    if kind is not None and kind not in ENV_KINDS:
        raise InputError(
            f"procedural environment: unknown kind {kind!r}; choose one of {', '.join(ENV_KINDS)}"
        )
    if intensity is not None and intensity not in INTENSITY_LEVELS:
        raise InputError(
            f"procedural environment: unknown intensity {intensity!r}; choose one of "
            f"{', '.join(INTENSITY_LEVELS)}"
        )
    return kind or drawn_kind, intensity or drawn_level


def make_environment(seed: int, kind: str | None = None, intensity: str | None = None) -> SGEnvironment:
    """A procedural SG environment (see the module docstring); deterministic per arguments."""
    rng = np.random.default_rng(_check_seed(seed))
    kind, level = _choose(rng, kind, intensity)
    target = INTENSITY_LEVELS[level] * FLASH_IRRADIANCE
    env = _BUILDERS[kind](rng, target)
    return env.rotated_z(rng.uniform(0.0, 2.0 * math.pi))
