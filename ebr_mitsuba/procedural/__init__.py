"""Procedural training data: SVBRDF families, map augmentation and SG environments (numpy only).

==========================  ========================================================================
name                        what
==========================  ========================================================================
``FAMILIES``                family name → generator (:mod:`.materials` documents every family)
``make_material``           ``(family, seed, size=256, **params) -> SVBRDF``; backs
                            ``--material procedural:FAMILY:SEED``
``ENV_KINDS``               ``("sun_sky", "window", "overcast")``
``INTENSITY_LEVELS``        ``{"low": 0.2, "medium": 1.0, "high": 3.0}`` × the flash's irradiance
``make_environment``        ``(seed, kind=None, intensity=None) -> SGEnvironment``; backs
                            ``--env procedural:SEED``
``augment``                 random rotation / scale / crop / colour jitter / blend of an SVBRDF
                            driven by an explicit ``np.random.Generator`` (:mod:`.augment`)
==========================  ========================================================================
"""

from .augment import (
    AugmentSettings,
    augment,
    blend,
    jitter_diffuse,
    mirror,
    random_mask,
    rotate90,
    rotate_scale_crop,
)
from .environments import (
    ENV_KINDS,
    FLASH_IRRADIANCE,
    INTENSITY_LEVELS,
    environment_choice,
    irradiance_luminance,
    make_environment,
)
from .materials import FAMILIES, METALS, family_parameters, make_material

__all__ = [
    "FAMILIES",
    "METALS",
    "make_material",
    "family_parameters",
    "ENV_KINDS",
    "INTENSITY_LEVELS",
    "FLASH_IRRADIANCE",
    "make_environment",
    "environment_choice",
    "irradiance_luminance",
    "AugmentSettings",
    "augment",
    "blend",
    "jitter_diffuse",
    "mirror",
    "random_mask",
    "rotate90",
    "rotate_scale_crop",
]
