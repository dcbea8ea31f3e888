"""Choosing and reporting the Mitsuba variant.

``llvm_ad_rgb`` is the default; ``cuda_ad_rgb`` is used when asked for and available. These two
are the only variants the toolkit supports (:data:`SUPPORTED_VARIANTS`): its plugins and renderers
need an autodiff RGB variant. :func:`ensure_variant` is the one place that sets it; every module
that needs Mitsuba calls it. An unsupported variant, or ``cuda_ad_rgb`` on a machine without a
CUDA device, is a one-line :class:`~ebr_mitsuba.errors.RuntimeSetupError` (CLI exit 2).

:func:`set_deterministic` makes Dr.Jit's results independent of thread timing (one thread): see
docs/extract-sg.md, "Reproducibility".
"""

from __future__ import annotations

import os

from .errors import RuntimeSetupError

DEFAULT_VARIANT = "llvm_ad_rgb"
SUPPORTED_VARIANTS = ("llvm_ad_rgb", "cuda_ad_rgb")
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


def cuda_available() -> bool:
    """Whether Dr.Jit can use a CUDA device here (driver and GPU found)."""
    import drjit as dr

    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # pragma: no cover - depends on the machine
        return False


def ensure_variant(variant: str | None = None) -> str:
    """Set the Mitsuba variant (once) and register the ebr plugins; return the variant name.

    ``variant=None`` keeps an already selected variant, else uses :func:`requested_variant`.
    Raises :class:`RuntimeSetupError` for a variant outside :data:`SUPPORTED_VARIANTS`, for
    ``cuda_ad_rgb`` without a CUDA device and for a missing or too old LLVM runtime.
    """
    import mitsuba as mi

    current = mi.variant()
    want = variant or current or requested_variant()
    if want not in SUPPORTED_VARIANTS:
        source = "" if variant or current else " (from $EBR_VARIANT)"
        raise RuntimeSetupError(f"unsupported variant '{want}'{source}; use llvm_ad_rgb or cuda_ad_rgb")
    if want not in mi.variants():
        raise RuntimeSetupError(
            f"Mitsuba variant '{want}' is not compiled into this Mitsuba build; use {DEFAULT_VARIANT}"
        )
    if want.startswith("cuda") and want != current and not cuda_available():
        raise RuntimeSetupError(
            f"variant '{want}': no CUDA device (Dr.Jit found no CUDA driver or GPU); "
            f"use {DEFAULT_VARIANT} on this machine"
        )
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


def set_deterministic(enabled: bool = True) -> None:
    """Make Dr.Jit's results independent of thread timing, or undo it.

    Dr.Jit's LLVM backend adds the terms of a ``scatter_reduce`` (and of every gather's adjoint)
    with atomics in the order its worker threads reach them, so multi-threaded reruns differ in the
    last bits (and an optimisation amplifies that). With one thread the order is fixed: the same
    inputs and seed give the same bytes. ``enabled=False`` restores all cores. Costs about 1.5-2x
    in Dr.Jit-bound commands (``ebr extract-sg``, refinement in ``ebr estimate``).
    """
    import drjit as dr

    dr.set_thread_count(1 if enabled else (os.cpu_count() or 1))


def deterministic_requested() -> bool:
    """Whether ``EBR_DETERMINISTIC`` asks for :func:`set_deterministic` (``1``, ``true``, ``yes``)."""
    return os.environ.get("EBR_DETERMINISTIC", "").strip().lower() in ("1", "true", "yes", "on")


def describe() -> dict:
    """Variant and library versions, for metadata files and benchmark headers."""
    import drjit as dr
    import mitsuba as mi

    info = {"variant": mi.variant(), "mitsuba": mi.__version__, "drjit": dr.__version__}
    if (mi.variant() or "").startswith("llvm"):
        info["llvm"] = ".".join(map(str, dr.detail.llvm_version()))
    return info
