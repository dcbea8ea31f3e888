"""Helpers shared by the benchmark modules."""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np

# ``../shared/data`` next to the checkout; ``$EBR_DATA_DIR`` overrides it.
DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def shared_data_dir() -> Path:
    """The shared assets folder: ``$EBR_DATA_DIR``, else :data:`DEFAULT_DATA_DIR`."""
    return Path(os.environ.get("EBR_DATA_DIR", DEFAULT_DATA_DIR))


def machine() -> str:
    """The machine line of a page: CPU, cores, Mitsuba variant and library versions."""
    from ..variant import describe

    d = describe()
    return (f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical cores (shared), "
            f"{d['variant']}, Mitsuba {d['mitsuba']}, Dr.Jit {d['drjit']}, LLVM {d.get('llvm', '-')}")


def rel_rms(a: np.ndarray, ref: np.ndarray) -> float:
    """``rms(a − ref) / rms(ref)`` in float64; ``inf`` when either holds a non-finite value."""
    a, ref = np.asarray(a, np.float64), np.asarray(ref, np.float64)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(ref))):
        return float("inf")
    return float(np.sqrt(np.mean((a - ref) ** 2)) / max(np.sqrt(np.mean(ref**2)), 1e-12))
