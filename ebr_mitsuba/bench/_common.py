"""Helpers shared by the benchmark modules."""

from __future__ import annotations

import os
import platform
from pathlib import Path

# ``../shared/data`` next to the checkout; ``$EBR_DATA_DIR`` overrides it.
DEFAULT_DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def shared_data_dir() -> Path:
    """The shared assets folder: ``$EBR_DATA_DIR``, else :data:`DEFAULT_DATA_DIR`."""
    return Path(os.environ.get("EBR_DATA_DIR", DEFAULT_DATA_DIR))


def machine() -> str:
    """The machine line of a page: CPU, cores, Mitsuba variant and library versions."""
    from ..variant import describe

    d = describe()
    return (
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical cores (shared), "
        f"{d['variant']}, Mitsuba {d['mitsuba']}, Dr.Jit {d['drjit']}, LLVM {d.get('llvm', '-')}"
    )
