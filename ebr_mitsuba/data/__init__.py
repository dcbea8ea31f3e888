"""Scene-file driven data generation (``ebr generate``, ``ebr dataset``) and reading it back.

=====================  ==============================================================================
module                 what
=====================  ==============================================================================
:mod:`.config`         the typed TOML schema (defaults in one place, unknown keys rejected)
:mod:`.sample`         deterministic per-sample draws: material, environment, camera, seeds
:mod:`.renderers`      clean renders of a sample with ``mitsuba`` or ``fast``
:mod:`.camera`         LDR photo simulation (exposure, white balance, noise, clipping, 8-bit sRGB)
:mod:`.store`          the on-disk format (``ebr-dataset/1``), atomic sample writes, index
:mod:`.generate`       the run: one process, a ``spawn`` pool, or Ray (:mod:`.ray_backend`)
:mod:`.verify`         ``ebr dataset verify``
:mod:`.sheet`          ``ebr dataset sheet`` (contact sheet)
:mod:`.dataset`        :class:`GeneratedDataset`, a torch ``Dataset`` (imports torch)
=====================  ==============================================================================

The entry point is :func:`ebr_mitsuba.data.generate.generate` (the package does not re-export it,
so that ``ebr_mitsuba.data.generate`` stays the module). The user page is ``docs/generate.md``.
"""

from .config import GenerateConfig, load_config, parse_config
from .verify import VerifyReport, verify

__all__ = ["GenerateConfig", "load_config", "parse_config", "VerifyReport", "verify"]
