"""Shared fixtures: one Mitsuba variant for the whole session, data-dir lookup, fixed seeds."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="session", autouse=True)
def variant():
    """Select the variant once (``EBR_VARIANT`` or ``llvm_ad_rgb``) and register our plugins;
    skip everything when the machine cannot run it."""
    from ebr_mitsuba import ensure_variant
    from ebr_mitsuba.errors import RuntimeSetupError

    try:
        name = ensure_variant()
    except RuntimeSetupError as exc:  # pragma: no cover - machine dependent
        pytest.skip(f"no usable Mitsuba variant here: {exc}")
    import drjit as dr

    dr.set_thread_count(os.cpu_count() or 2)
    return name


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """The shared real assets (``EBR_DATA_DIR``, default ../shared/data); skip when absent."""
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    path = Path(os.environ.get("EBR_DATA_DIR", default))
    if not path.is_dir():
        pytest.skip(f"shared assets not found at {path} (set EBR_DATA_DIR to ../shared/data)")
    return path


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture(scope="module")
def one_torch_thread():
    """Torch on one thread for a module (``pytestmark = pytest.mark.usefixtures(...)``): bit-exact
    training runs, and no OpenMP stalls when the two cores are shared."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
