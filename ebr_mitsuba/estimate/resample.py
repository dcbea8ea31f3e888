"""The working resolution of an estimate and the resampling to it.

The network sees square images at its grid size G (``bundle.resolution``). An input of size N:

==============================  =============================================================
case                            working resolution
==============================  =============================================================
N ≤ G                           G: the shots are area-resampled (up) to the grid
N > G, tiling on (default)      min(N, ``max_size``): tiled inference (:mod:`.tiling`) there
N > G, ``--no-tile``            G: the shots are area-averaged down to the grid
==============================  =============================================================

Maps come out at the working resolution; re-renders, residuals and the refinement run there.
"""

from __future__ import annotations

from ..errors import InputError
from ..materials import resample_svbrdf
from ..svbrdf import SVBRDF

DEFAULT_GRID = 256
DEFAULT_MAX_SIZE = 2048


def model_grid(bundle) -> int:
    """The square grid size G of a loaded model (``bundle.resolution``: an int or (H, W))."""
    res = getattr(bundle, "resolution", None)
    if res is None:
        return DEFAULT_GRID
    if isinstance(res, (tuple, list)):
        if len(res) != 2 or int(res[0]) != int(res[1]):
            raise InputError(
                f"the model's grid {tuple(res)} is not square; this estimate needs a square grid"
            )
        res = res[0]
    return int(res)


def working_size(input_size: int, grid: int, tile: bool = True, max_size: int = DEFAULT_MAX_SIZE) -> int:
    """Working resolution for a square input of ``input_size`` pixels (see the module table)."""
    if max_size < grid:
        raise InputError(f"--max-size {max_size} is below the model grid {grid}; give at least {grid}")
    if input_size <= grid or not tile:
        return grid
    return min(int(input_size), int(max_size))


def resample_maps(maps: SVBRDF, size: int) -> SVBRDF:
    """Maps area-resampled to ``size``² (normals renormalised)."""
    return resample_svbrdf(maps, (size, size))


__all__ = ["DEFAULT_GRID", "DEFAULT_MAX_SIZE", "model_grid", "working_size", "resample_maps"]
