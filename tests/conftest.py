"""Shared fixtures: one Mitsuba variant for the whole session, data-dir lookup, fixed seeds, and the
tiny generated data sets (each generated once per test run).

============  ======================================  ================================================
fixture       config                                  content
============  ======================================  ================================================
``tiny``      ``configs/data_tiny.toml``              4 near samples at 32², fast renderer
``tiny_nf``   ``configs/data_tiny_near_far.toml``     4 near-far samples (four shots) at 32²
``tiny5``     ``configs/data_tiny_five_light.toml``   4 five-light samples at 32²
``tiny_mv``   ``configs/data_tiny_multiview.toml``    4 multi-view samples (3×3 views) at 32²
============  ======================================  ================================================

``mair_tiny_run`` is ``configs/mair_tiny.toml`` trained on ``tiny_mv`` (the run directory, its
``model.pt`` the tiny MAIR checkpoint of ``tests/test_train_mair.py`` and
``tests/test_estimate_views.py``), equally shared and read-only.

The data sets are shared by every test of the session: read them, never change them. A test that
damages, extends or resumes a data set works on a copy (``shutil.copytree(tiny, tmp_path / ...)``).

``EBR_REQUIRE_VARIANT=1`` (set by ``.ci/run``) turns "no usable Mitsuba variant" from a skip of
every test into an error of every test, so that CI cannot pass without running anything.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


@pytest.fixture(scope="session", autouse=True)
def variant():
    """Select the variant once (``EBR_VARIANT`` or ``llvm_ad_rgb``) and register our plugins;
    skip everything when the machine cannot run it (fail everything under
    ``EBR_REQUIRE_VARIANT=1``)."""
    from ebr_mitsuba import ensure_variant
    from ebr_mitsuba.errors import RuntimeSetupError

    try:
        name = ensure_variant()
    except RuntimeSetupError as exc:  # pragma: no cover - machine dependent
        if os.environ.get("EBR_REQUIRE_VARIANT") == "1":
            pytest.fail(f"no usable Mitsuba variant here (EBR_REQUIRE_VARIANT=1): {exc}", pytrace=False)
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


def generate_tiny(config: str, out: Path, count: int | None = None) -> Path:
    """Generate ``configs/<config>`` (optionally only ``count`` samples) into ``out``."""
    from ebr_mitsuba.data.config import load_config
    from ebr_mitsuba.data.generate import generate

    cfg = load_config(CONFIGS / config)
    generate(cfg if count is None else cfg.with_count(count), out, progress=False)
    return out


@pytest.fixture(scope="session")
def tiny(tmp_path_factory) -> Path:
    """``configs/data_tiny.toml`` (module docstring: shared, read-only)."""
    return generate_tiny("data_tiny.toml", tmp_path_factory.mktemp("tiny") / "data")


@pytest.fixture(scope="session")
def tiny_nf(tmp_path_factory) -> Path:
    """``configs/data_tiny_near_far.toml`` (module docstring: shared, read-only)."""
    return generate_tiny("data_tiny_near_far.toml", tmp_path_factory.mktemp("tiny_nf") / "data")


@pytest.fixture(scope="session")
def tiny5(tmp_path_factory) -> Path:
    """``configs/data_tiny_five_light.toml`` (module docstring: shared, read-only)."""
    return generate_tiny("data_tiny_five_light.toml", tmp_path_factory.mktemp("tiny5") / "data")


@pytest.fixture(scope="session")
def tiny_mv(tmp_path_factory) -> Path:
    """``configs/data_tiny_multiview.toml`` (module docstring: shared, read-only)."""
    return generate_tiny("data_tiny_multiview.toml", tmp_path_factory.mktemp("tiny_mv") / "data")


@pytest.fixture(scope="session")
def mair_tiny_run(tiny_mv, tmp_path_factory) -> Path:
    """``configs/mair_tiny.toml`` trained on ``tiny_mv`` (torch on one thread: bit-exact): the run
    directory (module docstring: shared, read-only)."""
    import tomllib
    import torch

    from ebr_mitsuba.model.config import parse_config
    from ebr_mitsuba.train.trainer import Trainer

    doc = tomllib.loads((CONFIGS / "mair_tiny.toml").read_text())
    doc["data"] = {"train": str(tiny_mv)}
    out = tmp_path_factory.mktemp("mair") / "run"
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        Trainer(parse_config(doc, "mair_tiny.toml"), out).run()
    finally:
        torch.set_num_threads(previous)
    return out
