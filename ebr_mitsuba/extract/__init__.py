"""Dominant spherical-Gaussian extraction from environment exemplars (step 2 of
``docs/conventions.md``, "Pipeline").

=========================  =====================================================================
name                       what
=========================  =====================================================================
``extract_sg``             ``(exemplars (N, H, W, 3), roughness (N,), *, config, shot, progress)
                           -> ExtractResult``: the whole pipeline (:mod:`.pipeline`)
``ExtractConfig``          its settings, defaults in one place (:mod:`.config`)
``ExtractResult``          ``env``, ``iterations``, ``seconds``, ``rel_rmse_exemplars``,
                           ``loss_history``, ``stage_seconds``
``fibonacci_nnls``         the Two-Shot-style baseline: 24 Fibonacci axes, shared sharpness,
                           NNLS amplitudes (:mod:`.baseline`)
``read_exemplars``,        exemplar directories (``ebr exemplars`` / ``ebr extract-sg``,
``write_exemplars``        :mod:`.exemplar_io`)
``ssim``, ``ms_ssim``,     structural similarity of (H, W, 3) images (:mod:`.msssim`)
``ms_ssim_error``
``lighting_errors``        exemplar and held-out-material error of an estimate (:mod:`.evaluate`)
=========================  =====================================================================

Stages, one module each: :mod:`.quadtree`, :mod:`.init`, :mod:`.merge`, :mod:`.amplitudes`,
:mod:`.optimize`, :mod:`.densify`, :mod:`.prune`; the forward model is :mod:`.forward` (the fast
renderer's exemplar render at chosen pixels). Importing this package needs no Mitsuba variant;
the functions select one when called.
"""

from ..exemplar.files import read_exemplars, write_exemplars
from .baseline import fibonacci_nnls
from .config import ExtractConfig
from .evaluate import lighting_errors
from .msssim import ms_ssim, ms_ssim_error, ssim
from .pipeline import ExtractResult, extract_sg

__all__ = [
    "ExtractConfig",
    "ExtractResult",
    "extract_sg",
    "fibonacci_nnls",
    "lighting_errors",
    "ms_ssim",
    "ms_ssim_error",
    "read_exemplars",
    "ssim",
    "write_exemplars",
]
