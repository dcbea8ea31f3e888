"""Neural networks and losses of ebr-mitsuba (PyTorch, CPU or CUDA).

=================  ===========================================================================
module             contents
=================  ===========================================================================
``nafnet``         :class:`NAFNet` backbone, :class:`NAFNetSize`, ``PAPER_SIZE``, ``SMALL_SIZE``
``maps``           :class:`Maps` — named (B, C, H, W) SVBRDF map tensors
``transforms``     input log transforms and output constraints
``ebrenv``         :class:`LightingNet` and the :class:`Cascade` (diffuse → specular → refinement)
``dualloss``       :class:`DualLossNet` — five-light 3-D-conv + U-Net estimator
``mair``           MAIR multi-view stages (:class:`NormalNet`, :class:`SVSGNet`, :class:`SpecNet`,
                   :class:`RefineNet`) and :class:`MAIRModel`
``mair_fusion``    :class:`MVANet` — attention (or mean-pool) fusion across the views
``mair_views``     per-pixel view directions and in-frame weights of the 3×3 capture
``mair_config``    :class:`MAIRConfig`, :class:`MAIRSize`, :class:`UNetSize`, ``MAIR_SIZE_PRESETS``
``mair_lighting``  :class:`PixelSGLighting` (per-pixel SGs with visibility), hemisphere directions
``mair_params``    ``python -m ebr_mitsuba.nets.mair_params``: parameter counts of the MAIR presets
``losses``         parameter L1, rendering loss and its view/light sampler, MAIR losses
``torch_brdf``     torch mirror of :mod:`ebr_mitsuba.brdf` and point-light renderers
``drwrap``         the Dr.Jit fast renderer called from torch through ``dr.wrap`` (point light + SGs,
                   gradients into torch); imported on demand (``ebr_mitsuba.nets.drwrap``)
=================  ===========================================================================

Importing this package imports torch but not Mitsuba; ``torch_brdf`` uses only the constants of
:mod:`ebr_mitsuba.brdf` (importing it needs Dr.Jit, not a selected variant).
"""

from .dualloss import DualLossConfig, DualLossNet, basecolor_metallic_to_diffuse_specular
from .ebrenv import Cascade, CascadeConfig, CascadeOutput, LightingNet, LightingNetConfig, LightingOutput
from .mair import (
    MAIRModel,
    MAIROutput,
    MVANet,
    MVAOutput,
    NormalNet,
    RefineNet,
    SpecNet,
    SVSGNet,
    in_frame_weights,
    view_direction_maps,
)
from .mair_config import MAIR_SIZE_PRESETS, MAIRConfig, MAIRSize, UNetSize
from .mair_lighting import PixelSGLighting, hemisphere_directions
from .maps import MAP_LAYOUT, NUM_MAP_CHANNELS, Maps
from .nafnet import PAPER_SIZE, SIZE_PRESETS, SMALL_SIZE, NAFBlock, NAFNet, NAFNetSize, parameter_count

__all__ = [
    "NAFNet",
    "NAFNetSize",
    "NAFBlock",
    "PAPER_SIZE",
    "SMALL_SIZE",
    "SIZE_PRESETS",
    "parameter_count",
    "Maps",
    "MAP_LAYOUT",
    "NUM_MAP_CHANNELS",
    "LightingNet",
    "LightingNetConfig",
    "LightingOutput",
    "Cascade",
    "CascadeConfig",
    "CascadeOutput",
    "DualLossNet",
    "DualLossConfig",
    "basecolor_metallic_to_diffuse_specular",
    "MAIRModel",
    "MAIROutput",
    "MAIRConfig",
    "MAIRSize",
    "UNetSize",
    "MAIR_SIZE_PRESETS",
    "NormalNet",
    "SVSGNet",
    "SpecNet",
    "MVANet",
    "MVAOutput",
    "RefineNet",
    "PixelSGLighting",
    "hemisphere_directions",
    "view_direction_maps",
    "in_frame_weights",
]
