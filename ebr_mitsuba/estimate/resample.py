"""The working resolution of an estimate and the resampling to it.

The network's lighting stage sees square images at its grid size G (``bundle.resolution``, read
from the model, 64 for the shipped one); the maps are estimated at the *working size* W. For a
(square-cropped) input of N pixels per side:

========================  =================================================================
case                      working size
========================  =================================================================
N < ``MIN_INPUT_SIZE``    refused (exit 2, one line; :data:`MIN_INPUT_SIZE` = 32 pixels)
N ≤ G                     G: the shots are area-resampled (up) to the grid
G < N ≤ ``max_size``      N: the full resolution (:mod:`.fullres`)
N > ``max_size``          ``max_size`` (default :data:`DEFAULT_MAX_SIZE` = 2048): the shots are
                          area-averaged down, with a warning naming both sizes
========================  =================================================================

Maps come out at the working size; re-renders, residuals and the refinement run there. The
default limit keeps a 4096² phone photo within the time and memory of a 2048² estimate (see
docs/bench/estimate.md); ``--max-size`` raises or lowers it (at least G).
"""

from __future__ import annotations

from ..errors import InputError
from ..materials import resample_svbrdf
from ..svbrdf import SVBRDF

DEFAULT_GRID = 256
DEFAULT_MAX_SIZE = 2048
MIN_INPUT_SIZE = 32


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


def working_size(input_size: int, grid: int, max_size: int = DEFAULT_MAX_SIZE) -> int:
    """Working resolution for a square input of ``input_size`` pixels (see the module table)."""
    if max_size < grid:
        raise InputError(f"--max-size {max_size} is below the model grid {grid}; give at least {grid}")
    return max(int(grid), min(int(input_size), int(max_size)))


def resample_maps(maps: SVBRDF, size: int) -> SVBRDF:
    """Maps area-resampled to ``size``² (normals renormalised)."""
    return resample_svbrdf(maps, (size, size))


__all__ = [
    "DEFAULT_GRID",
    "DEFAULT_MAX_SIZE",
    "MIN_INPUT_SIZE",
    "model_grid",
    "working_size",
    "resample_maps",
]
