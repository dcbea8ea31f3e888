"""Choosing and reporting the Mitsuba variant.

``llvm_ad_rgb`` is the default; ``cuda_ad_rgb`` is used when asked for and available.
:func:`ensure_variant` is the one place that sets it; every module that needs Mitsuba calls it.
"""

from __future__ import annotations

import os

from .errors import RuntimeSetupError

DEFAULT_VARIANT = "llvm_ad_rgb"
_MIN_LLVM = (17, 0, 0)
_LLVM_HINT = (
    "install Debian's libllvm19 ('apt-get install -y libllvm19') or point DRJIT_LIBLLVM_PATH at "
    "libLLVM >= 17; the system's LLVM 15 crashes Dr.Jit ('Cannot select ... fminimum')"
)


def requested_variant() -> str:
    """The variant asked for through ``EBR_VARIANT`` (default ``llvm_ad_rgb``)."""
    return os.environ.get("EBR_VARIANT", DEFAULT_VARIANT)


def _check_llvm() -> None:
    import drjit as dr

    try:
        version = tuple(dr.detail.llvm_version())
    except Exception as exc:  # pragma: no cover - depends on the machine
        raise RuntimeSetupError(f"Dr.Jit found no LLVM runtime: {_LLVM_HINT}") from exc
    if version < _MIN_LLVM:
        raise RuntimeSetupError(
            f"Dr.Jit loaded LLVM {'.'.join(map(str, version))}, which is too old: {_LLVM_HINT}"
        )


def ensure_variant(variant: str | None = None) -> str:
    """Set the Mitsuba variant (once) and register the ebr plugins; return the variant name.

    ``variant=None`` keeps an already selected variant, else uses :func:`requested_variant`.
    """
    import mitsuba as mi

    current = mi.variant()
    want = variant or current or requested_variant()
    if want not in mi.variants():
        raise RuntimeSetupError(f"Mitsuba variant '{want}' is not available here; use one of {mi.variants()}")
    if want.startswith("llvm"):
        _check_llvm()
    if current != want:
        try:
            mi.set_variant(want)
        except Exception as exc:
            raise RuntimeSetupError(f"cannot use Mitsuba variant '{want}': {exc}") from exc
    from .plugins import register_all

    register_all()
    return want


def describe() -> dict:
    """Variant and library versions, for metadata files and benchmark headers."""
    import drjit as dr
    import mitsuba as mi

    info = {"variant": mi.variant(), "mitsuba": mi.__version__, "drjit": dr.__version__}
    if (mi.variant() or "").startswith("llvm"):
        info["llvm"] = ".".join(map(str, dr.detail.llvm_version()))
    return info
