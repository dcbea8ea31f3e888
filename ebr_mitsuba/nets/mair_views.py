"""View geometry and per-view weights of the MAIR networks (:mod:`.mair`): every view in the sample grid.

Pixel (i, j) of every (rectified or texture-space) view shows the sample-grid point ``p_ij`` of
:mod:`ebr_mitsuba.geometry`; a view differs from the others in its per-pixel direction
``v_ij = normalise(camera − p_ij)`` (:func:`view_direction_maps`) and in which points its camera
framed (:func:`in_frame_weights`). :func:`normalised_weights` turns per-view weights w into the
pooling weights every fusion uses. :func:`view_indices` and :func:`selected_shots` pick the views a
model reads (``MAIRConfig.views``: all nine, or the centre camera's alone).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch

from ..errors import InputError
from ..geometry import Shot, pixel_positions, setup_shots, view_directions
from .mair_config import VIEW_SETS

WEIGHT_FLOOR = 1e-6  # w is clamped to this: a pixel no view saw falls back to uniform weights
CENTRE_XY = (0.0, 0.0)  # (x, y) of the grid's centre camera, straight above the sample centre
CENTRE_TOLERANCE = 0.3  # half the grid spacing: the centre camera is the one this close to CENTRE_XY


# ------------------------------------------------------------------------------------ geometry


def multiview_shots() -> list[Shot]:
    """The 9 shots of ``--setup multi-view`` (row-major over the 3×3 grid, ``view{a}{b}_flash``)."""
    return setup_shots("multi-view")


def view_indices(views: str, cameras: Sequence[Sequence[float]] | None = None) -> list[int]:
    """Indices of the views a model with ``MAIRConfig.views = views`` reads, among the N views
    whose camera positions are ``cameras`` (N × 3; None: those of :func:`multiview_shots`, in its
    order).

    ``"all"``: every view, in order; ``"centre"``: the one view whose camera is nearest in (x, y)
    to the centre camera :data:`CENTRE_XY` (index 4 of :func:`multiview_shots`, ``view11_flash``).
    Raises :class:`InputError` for another ``views``, or for ``"centre"`` when no camera is within
    :data:`CENTRE_TOLERANCE` of the centre.
    """
    if views not in VIEW_SETS:
        raise InputError(f"MAIR: views: got {views!r}; use one of {', '.join(VIEW_SETS)}")
    cams = [s.camera for s in multiview_shots()] if cameras is None else cameras
    xy = np.asarray(cams, np.float64).reshape(-1, 3)[:, :2]
    if views == "all":
        return list(range(len(xy)))
    off = np.linalg.norm(xy - np.asarray(CENTRE_XY), axis=1)
    k = int(np.argmin(off)) if len(off) else -1
    if k < 0 or off[k] > CENTRE_TOLERANCE:
        raise InputError(
            f"MAIR: views = 'centre' needs a camera within {CENTRE_TOLERANCE} of (x, y) = {CENTRE_XY}; "
            f"the {len(xy)} cameras given have none"
        )
    return [k]


def selected_shots(views: str) -> list[Shot]:
    """The shots of :func:`multiview_shots` that a model with ``MAIRConfig.views = views`` reads,
    in that order (:func:`view_indices`): all 9, or the centre camera's alone."""
    shots = multiview_shots()
    return [shots[k] for k in view_indices(views)]


def view_direction_maps(height: int, width: int, shots: list[Shot] | None = None) -> torch.Tensor:
    """Per-pixel unit directions from the sample-grid points to each camera, ``(N, 3, H, W)`` float32.

    ``shots`` defaults to :func:`multiview_shots`; direction ``v = normalise(camera − p_ij)``
    (:func:`ebr_mitsuba.geometry.view_directions`), world frame, ``v_z > 0``.
    """
    shots = multiview_shots() if shots is None else shots
    dirs = np.stack([view_directions(height, width, s.camera) for s in shots])  # (N, H, W, 3)
    return torch.from_numpy(dirs.astype(np.float32)).permute(0, 3, 1, 2).contiguous()


def in_frame_weights(height: int, width: int, shots: list[Shot] | None = None) -> torch.Tensor:
    """1 where the sample-grid point ``p_ij`` lies inside shot k's frame, else 0: ``(N, 1, H, W)``.

    The per-view weights w of rectified camera images (an oblique view does not see every corner of
    the sample). Pinhole camera at ``shot.camera`` looking at ``shot.target`` with ``shot.up``,
    horizontal field of view ``shot.fov``; texture-space renders see every point (use ones).
    """
    shots = multiview_shots() if shots is None else shots
    p = pixel_positions(height, width)
    out = []
    for s in shots:
        c = np.asarray(s.camera, np.float64)
        f = np.asarray(s.target, np.float64) - c
        f /= np.linalg.norm(f)
        r = np.cross(f, np.asarray(s.up, np.float64))
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        d = p - c
        depth = d @ f
        half_x = math.tan(math.radians(s.fov) / 2)
        half_y = half_x * height / width
        inside = (depth > 0) & (np.abs(d @ r) <= half_x * depth) & (np.abs(d @ u) <= half_y * depth)
        out.append(inside.astype(np.float32))
    return torch.from_numpy(np.stack(out))[:, None]


def check_inputs(views: torch.Tensor, directions: torch.Tensor, weights: torch.Tensor | None):
    """Validate and broadcast: views (B,N,3,H,W); directions and weights with or without B."""
    if views.ndim != 5 or views.shape[2] != 3:
        raise InputError(f"MAIR: views have shape {tuple(views.shape)}; expected (B, N, 3, H, W)")
    b, n, _, h, w = views.shape

    def broadcast(name, x, channels):
        if x.ndim == 4:
            x = x[None]
        if x.ndim != 5 or tuple(x.shape[1:]) != (n, channels, h, w) or x.shape[0] not in (1, b):
            raise InputError(
                f"MAIR: {name} have shape {tuple(x.shape)}; expected ({b}, {n}, {channels}, "
                f"{h}, {w}) or ({n}, {channels}, {h}, {w})"
            )
        return x.to(views.dtype).expand(b, n, channels, h, w)

    directions = broadcast("directions", directions, 3)
    weights = None if weights is None else broadcast("weights", weights, 1)
    return directions, weights


def normalised_weights(weights: torch.Tensor | None, like: torch.Tensor) -> torch.Tensor:
    """``p_k = w_k / Σ_k w_k`` over the views (dim 1), ``(B, N, 1, H, W)``; uniform when None."""
    b, n, _, h, w = like.shape
    if weights is None:
        return like.new_full((b, n, 1, h, w), 1.0 / n)
    w_eff = weights.clamp_min(WEIGHT_FLOOR)
    return w_eff / w_eff.sum(dim=1, keepdim=True)
