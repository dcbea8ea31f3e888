"""The options every kind of estimate shares, declared once.

``ebr estimate`` (:class:`~ebr_mitsuba.estimate.pipeline.EstimateConfig`), ``--lights``
(:class:`~ebr_mitsuba.estimate.fivelight.FiveLightConfig`) and ``--views``
(:class:`~ebr_mitsuba.estimate.multiview.MultiViewConfig`) read the same ``--out``,
``--checkpoint``, ``--flash-intensity``, ``--saturation-level`` and ``--max-size`` flags (and the
first two ``--flash-fit``); each function here is one of those fields (flag, metavar, default and
checks), the caller giving only what its kind says differently.
"""

from __future__ import annotations

from typing import Any

from ..typedconfig import option
from .resample import DEFAULT_MAX_SIZE


def out_option() -> Any:
    """``--out DIR`` (required)."""
    return option(
        meaning="output directory (complete or not at all)", required=True, flag="--out", metavar="DIR"
    )


def checkpoint_option(meaning: str, shown: str) -> Any:
    """``--checkpoint C`` (default None; ``shown``: what None means)."""
    return option(None, meaning, flag="--checkpoint", metavar="C", shown=shown)


def intensity_option(meaning: str) -> Any:
    """``--flash-intensity I`` in W/sr (default None: capture.json, else fitted)."""
    return option(
        None, meaning, above=0, flag="--flash-intensity", metavar="I", shown="capture.json, else fitted"
    )


def saturation_option() -> Any:
    """``--saturation-level V``."""
    return option(
        None, "EXR value at which pixels count as clipped", above=0, flag="--saturation-level", metavar="V"
    )


def max_size_option(larger: str) -> Any:
    """``--max-size N`` (default :data:`~.resample.DEFAULT_MAX_SIZE`); ``larger``: what becomes of
    larger inputs."""
    return option(
        DEFAULT_MAX_SIZE,
        f"largest working size (at least the model grid): {larger}",
        flag="--max-size",
        metavar="N",
    )


def flash_fit_option(meaning: str) -> Any:
    """``--flash-fit/--no-flash-fit`` (default on)."""
    return option(True, meaning, flag="--flash-fit")


__all__ = [
    "checkpoint_option",
    "flash_fit_option",
    "intensity_option",
    "max_size_option",
    "out_option",
    "saturation_option",
]
