"""ebr-mitsuba: physically based inverse rendering of near-planar SVBRDFs under unknown
environment light (EBREnv), on Mitsuba 3 and Dr.Jit.

Importing the package does not select a Mitsuba variant; :func:`ensure_variant` does (and
registers the ``sgenvmap`` emitter and ``svbrdf`` BSDF plugins). When a variant is already set
(``mi.set_variant(...)`` before ``import ebr_mitsuba``), importing the package registers the
plugins for it, so ``mi.load_file`` / ``mi.load_string`` find them, as Mitsuba users expect.
"""

from .errors import ConfigError, EbrError, InputError, RuntimeSetupError
from .sgenv import SGEnvironment
from .svbrdf import SVBRDF
from .variant import ensure_variant

__version__ = "0.1.0"

__all__ = [
    "EbrError",
    "InputError",
    "ConfigError",
    "RuntimeSetupError",
    "SGEnvironment",
    "SVBRDF",
    "ensure_variant",
    "load_scene",
    "__version__",
]


def load_scene(path, **params):
    """Load a Mitsuba XML scene that may use the ebr plugins (sets the variant first)."""
    from .scene import load_scene as _load

    return _load(path, **params)


def _register_for_current_variant() -> None:
    """Register the plugins when Mitsuba is already imported with a variant set (never imports
    Mitsuba itself: ``import ebr_mitsuba`` stays cheap and variant-free otherwise)."""
    import sys

    mi = sys.modules.get("mitsuba")
    if mi is None or mi.variant() is None:
        return
    from .plugins import register_all

    register_all()


_register_for_current_variant()
