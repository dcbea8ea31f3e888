"""Sizes and options of the MAIR multi-view networks (:mod:`.mair`): every default in one place.

:class:`MAIRSize` sizes every stage (NAFNet sizes for the normal and lighting nets, MLP widths for
SpecNet and MVANet, a :class:`UNetSize` for RefineNet); :data:`MAIR_SIZE_PRESETS` names three:

==========  ==============================================================  ======================
preset      what for                                                        parameters (S_D = 3)*
==========  ==============================================================  ======================
``tiny``    unit tests (16²–32² inputs)                                     19 134
``small``   CPU training (``configs/mair_small.toml``)                      243 490
``paper``   a GPU; stage sizes like MAIR's (CVPR 2023) networks             48 693 698
==========  ==============================================================  ======================

\\* with ``fusion="attention"``, measured by ``python -m ebr_mitsuba.nets.mair_params``, which prints the
counts per stage and for the ``mean`` fusion too (``docs/mair.md``).

:class:`MAIRConfig` holds the options that are not sizes: the number of SGs per pixel, the fusion
(``attention`` or the ``mean`` pooling ablation), the views of the 3×3 capture the model reads
(``all`` nine, or the ``centre`` one alone: the other ablation of issue 13; chosen by
:func:`~.mair_views.selected_shots` and :func:`~.mair_views.view_indices`), the SG sharpness range
and the input transform.
Both read TOML tables through :func:`ebr_mitsuba.typedconfig.from_dict` (unknown keys rejected; a
size may be given by preset name); their option tables are generated from the field metadata.
"""

from __future__ import annotations

from collections.abc import Mapping

from ..errors import ConfigError
from ..typedconfig import check, config, from_dict, nested, option
from .nafnet import SIZE_PRESETS, NAFNetSize
from .transforms import LOG_EPS

FUSIONS = ("attention", "mean")
VIEW_SETS = ("all", "centre")  # MAIRConfig.views (nets/mair_views.view_indices reads them)


@config
class UNetSize:
    """How big RefineNet's U-Net is."""

    widths: tuple[int, ...] = option(
        (32, 64, 128),
        "channels per level, fine → coarse (each further level halves the resolution; inputs are "
        "padded to a multiple of 2**(len(widths) − 1))",
        minimum=1,
        nonempty=True,
    )
    depth: int = option(2, "conv3×3 → GroupNorm → GELU units per level and side", minimum=1)
    groups: int = option(8, "GroupNorm groups (gcd(groups, channels) per layer)", minimum=1)

    @property
    def levels(self) -> int:
        return len(self.widths)


_SMALL_NAF = NAFNetSize(width=8, enc_blk_nums=(1, 1, 1), middle_blk_num=1, dec_blk_nums=(1, 1, 1))


def _naf(default, meaning):
    return option(default, meaning, presets=SIZE_PRESETS, preset_kind="network size", shown="(small)")


@config
class MAIRSize:
    """How big every stage of :class:`~.mair.MAIRModel` is; the defaults are the ``small`` preset."""

    encoder_width: int = option(
        8,
        "F_e: channels of the shared per-view encoder of the normal and lighting nets (pooled to 2·F_e)",
        minimum=1,
    )
    normal: NAFNetSize = _naf(_SMALL_NAF, "normal net backbone")
    lighting: NAFNetSize = _naf(_SMALL_NAF, "SV-SG lighting net backbone")
    spec_hidden: int = option(32, "SpecNet hidden width", minimum=1)
    spec_layers: int = option(2, "SpecNet hidden layers", minimum=1)
    spec_features: int = option(16, "F_s: SpecNet output features per view and pixel", minimum=1)
    mva_dim: int = option(32, "D: MVANet token width", minimum=1)
    mva_heads: int = option(4, "attention heads (must divide D)", minimum=1)
    mva_depth: int = option(2, "MVANet blocks (attention + MLP, or MLP alone)", minimum=1)
    mva_mlp: int = option(64, "MVANet MLP hidden width", minimum=1)
    brdf_features: int = option(16, "F_b: fused BRDF features handed to RefineNet", minimum=1)
    refine: UNetSize = option(
        UNetSize(widths=(16, 32, 64), depth=1, groups=8), "RefineNet size", shown="(small)"
    )

    def __post_init__(self):
        check(self)
        if self.mva_dim % self.mva_heads:
            raise ConfigError(f"MAIRSize: mva_heads ({self.mva_heads}) must divide mva_dim ({self.mva_dim})")

    @classmethod
    def from_value(cls, value, where: str = "size") -> MAIRSize:
        """A preset name (``"tiny"``, ``"small"``, ``"paper"``), a table of fields, or a ``MAIRSize``."""
        return nested(cls, value, MAIR_SIZE_PRESETS, where=where, what="MAIR size")


_TINY_NAF = NAFNetSize(width=4, enc_blk_nums=(1, 1), middle_blk_num=1, dec_blk_nums=(1, 1))
_PAPER_NORMAL = NAFNetSize(width=32, enc_blk_nums=(2, 2, 4, 8), middle_blk_num=12, dec_blk_nums=(2, 2, 2, 2))
_PAPER_LIGHTING = NAFNetSize(width=32, enc_blk_nums=(1, 1, 2, 4), middle_blk_num=4, dec_blk_nums=(1, 1, 1, 1))

# The presets side by side, one row per field of MAIRSize: (tiny, paper); "small" is the defaults.
_PRESET_ROWS = {
    "encoder_width": (4, 32),
    "normal": (_TINY_NAF, _PAPER_NORMAL),
    "lighting": (_TINY_NAF, _PAPER_LIGHTING),
    "spec_hidden": (8, 64),
    "spec_layers": (1, 2),
    "spec_features": (4, 32),
    "mva_dim": (8, 64),
    "mva_heads": (2, 4),
    "mva_depth": (1, 2),
    "mva_mlp": (16, 256),
    "brdf_features": (8, 64),
    "refine": (
        UNetSize(widths=(8, 16), depth=1, groups=4),
        UNetSize(widths=(64, 128, 256, 512), depth=2, groups=16),
    ),
}
MAIR_SIZE_PRESETS = {
    "tiny": MAIRSize(**{name: row[0] for name, row in _PRESET_ROWS.items()}),
    "small": MAIRSize(),
    "paper": MAIRSize(**{name: row[1] for name, row in _PRESET_ROWS.items()}),
}


@config
class MAIRConfig:
    """Options of :class:`~.mair.MAIRModel`."""

    size: MAIRSize = option(
        MAIR_SIZE_PRESETS["small"],
        "stage sizes (preset name or table in files)",
        presets=MAIR_SIZE_PRESETS,
        preset_kind="MAIR size",
    )
    num_sgs: int = option(3, "S_D: SGs of incident lighting per pixel", minimum=1)
    fusion: str = option(
        "attention",
        "attention (MVANet) or mean (the ablation: per-view MLPs, weighted mean pool)",
        choices=FUSIONS,
    )
    views: str = option(
        "all",
        "views of the 3×3 capture the model reads: all 9, or centre (the ablation: the camera at (0, 0) "
        "alone, N = 1, in training and prediction)",
        choices=VIEW_SETS,
    )
    sharpness_range: tuple[float, float] = option(
        (1.0, 2000.0), "λ_min, λ_max of the per-pixel SGs (log-uniform in between, via a sigmoid)", above=0
    )
    log_eps: float = option(LOG_EPS, "ε of the input transform log(x + ε)", above=0)

    def __post_init__(self):
        check(self)
        lo_hi = self.sharpness_range
        if not lo_hi[0] < lo_hi[1]:
            raise ConfigError(
                f"MAIRConfig: sharpness_range must be (λ_min, λ_max) with 0 < λ_min < λ_max, got {lo_hi}"
            )

    @classmethod
    def from_dict(cls, data: Mapping, where: str = "model", *, key: str = "") -> MAIRConfig:
        return from_dict(cls, data, where, key=key)
