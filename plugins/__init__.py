"""Mitsuba plugins of ebr-mitsuba, one per file, registered explicitly.

* ``sgenvmap`` (emitter): :mod:`ebr_mitsuba.plugins.sgenvmap`
* ``svbrdf`` (BSDF): :mod:`ebr_mitsuba.plugins.svbrdf`

Plugin classes subclass variant-specific Mitsuba types, so they are defined and registered after
a variant is set: :func:`register_all` (called by :func:`ebr_mitsuba.ensure_variant`) does it, and
importing ``ebr_mitsuba`` (which imports this package then) or this package registers them when a
variant is already set.
"""

from __future__ import annotations

import importlib

_registered_for: str | None = None


def register_all() -> None:
    """Register every plugin for the current Mitsuba variant (idempotent)."""
    global _registered_for
    import mitsuba as mi

    variant = mi.variant()
    if variant is None or variant == _registered_for:
        return
    for name in ("sgenvmap", "svbrdf"):
        module = importlib.import_module(f"{__name__}.{name}")
        if getattr(module, "_variant", None) != variant:
            module = importlib.reload(module)
        module.register()
    _registered_for = variant


try:  # register at import time when a variant is already selected
    import mitsuba as _mi

    if _mi.variant() is not None:
        register_all()
except ImportError:  # pragma: no cover
    pass
