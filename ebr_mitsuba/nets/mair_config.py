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
(``attention`` or the ``mean`` pooling ablation), the SG sharpness range and the input transform.
Both read TOML tables through :func:`~._config.dataclass_from_dict` (unknown keys rejected; a size
may be given by preset name).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from ..errors import ConfigError
from ._config import dataclass_from_dict
from .nafnet import NAFNetSize
from .transforms import LOG_EPS

FUSIONS = ("attention", "mean")


def _positive(where: str, **values) -> None:
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ConfigError(f"{where}: {name} must be a positive integer, got {value!r}")


@dataclass(frozen=True)
class UNetSize:
    """How big RefineNet's U-Net is.

    ==========  ===============  ============  =====================================================
    field       type             default       meaning
    ==========  ===============  ============  =====================================================
    ``widths``  tuple[int, ...]  (32, 64, 128) channels per level, fine → coarse (each further level
                                               halves the resolution; inputs are padded to a multiple
                                               of ``2**(len(widths) − 1)``)
    ``depth``   int              2             conv3×3 → GroupNorm → GELU units per level and side
    ``groups``  int              8             GroupNorm groups (``gcd(groups, channels)`` per layer)
    ==========  ===============  ============  =====================================================
    """

    widths: tuple[int, ...] = (32, 64, 128)
    depth: int = 2
    groups: int = 8

    def __post_init__(self):
        object.__setattr__(self, "widths", tuple(self.widths))
        if not self.widths:
            raise ConfigError("UNetSize: widths must name at least one level")
        for w in self.widths:
            _positive("UNetSize", widths=w)
        _positive("UNetSize", depth=self.depth, groups=self.groups)

    @property
    def levels(self) -> int:
        return len(self.widths)


@dataclass(frozen=True)
class MAIRSize:
    """How big every stage of :class:`~.mair.MAIRModel` is.

    ==================  ==========  ========  ====================================================
    field               type        default   meaning
    ==================  ==========  ========  ====================================================
    ``encoder_width``   int         8         F_e: channels of the shared per-view encoder of the
                                              normal and lighting nets (pooled to 2·F_e)
    ``normal``          NAFNetSize  (small)   normal net backbone
    ``lighting``        NAFNetSize  (small)   SV-SG lighting net backbone
    ``spec_hidden``     int         32        SpecNet hidden width
    ``spec_layers``     int         2         SpecNet hidden layers
    ``spec_features``   int         16        F_s: SpecNet output features per view and pixel
    ``mva_dim``         int         32        D: MVANet token width
    ``mva_heads``       int         4         attention heads (must divide D)
    ``mva_depth``       int         2         MVANet blocks (attention + MLP, or MLP alone)
    ``mva_mlp``         int         64        MVANet MLP hidden width
    ``brdf_features``   int         16        F_b: fused BRDF features handed to RefineNet
    ``refine``          UNetSize    (small)   RefineNet size
    ==================  ==========  ========  ====================================================

    The defaults are the ``small`` preset.
    """

    encoder_width: int = 8
    normal: NAFNetSize = NAFNetSize(width=8, enc_blk_nums=(1, 1, 1), middle_blk_num=1, dec_blk_nums=(1, 1, 1))
    lighting: NAFNetSize = NAFNetSize(
        width=8, enc_blk_nums=(1, 1, 1), middle_blk_num=1, dec_blk_nums=(1, 1, 1)
    )
    spec_hidden: int = 32
    spec_layers: int = 2
    spec_features: int = 16
    mva_dim: int = 32
    mva_heads: int = 4
    mva_depth: int = 2
    mva_mlp: int = 64
    brdf_features: int = 16
    refine: UNetSize = UNetSize(widths=(16, 32, 64), depth=1, groups=8)

    def __post_init__(self):
        _positive(
            "MAIRSize",
            encoder_width=self.encoder_width,
            spec_hidden=self.spec_hidden,
            spec_layers=self.spec_layers,
            spec_features=self.spec_features,
            mva_dim=self.mva_dim,
            mva_heads=self.mva_heads,
            mva_depth=self.mva_depth,
            mva_mlp=self.mva_mlp,
            brdf_features=self.brdf_features,
        )
        if self.mva_dim % self.mva_heads:
            raise ConfigError(f"MAIRSize: mva_heads ({self.mva_heads}) must divide mva_dim ({self.mva_dim})")
        for name, cls in (("normal", NAFNetSize), ("lighting", NAFNetSize), ("refine", UNetSize)):
            if not isinstance(getattr(self, name), cls):
                raise ConfigError(f"MAIRSize: {name} must be a {cls.__name__}, got {getattr(self, name)!r}")

    @classmethod
    def from_value(cls, value, where: str = "size") -> MAIRSize:
        """A preset name (``"tiny"``, ``"small"``, ``"paper"``), a table of fields, or a ``MAIRSize``."""
        if isinstance(value, MAIRSize):
            return value
        if isinstance(value, str):
            if value not in MAIR_SIZE_PRESETS:
                raise ConfigError(
                    f"{where}: unknown MAIR size {value!r}; use one of "
                    f"{', '.join(MAIR_SIZE_PRESETS)} or a table of MAIRSize fields"
                )
            return MAIR_SIZE_PRESETS[value]
        if isinstance(value, Mapping):
            return dataclass_from_dict(
                cls,
                value,
                where,
                nested={
                    "normal": NAFNetSize.from_value,
                    "lighting": NAFNetSize.from_value,
                    "refine": lambda v, w: (
                        v if isinstance(v, UNetSize) else dataclass_from_dict(UNetSize, v, w)
                    ),
                },
            )
        raise ConfigError(f"{where}: expected a MAIR size preset name or a table, got {value!r}")


_TINY_NAF = NAFNetSize(width=4, enc_blk_nums=(1, 1), middle_blk_num=1, dec_blk_nums=(1, 1))
MAIR_SIZE_PRESETS = {
    "tiny": MAIRSize(
        encoder_width=4,
        normal=_TINY_NAF,
        lighting=_TINY_NAF,
        spec_hidden=8,
        spec_layers=1,
        spec_features=4,
        mva_dim=8,
        mva_heads=2,
        mva_depth=1,
        mva_mlp=16,
        brdf_features=8,
        refine=UNetSize(widths=(8, 16), depth=1, groups=4),
    ),
    "small": MAIRSize(),
    "paper": MAIRSize(
        encoder_width=32,
        normal=NAFNetSize(width=32, enc_blk_nums=(2, 2, 4, 8), middle_blk_num=12, dec_blk_nums=(2, 2, 2, 2)),
        lighting=NAFNetSize(width=32, enc_blk_nums=(1, 1, 2, 4), middle_blk_num=4, dec_blk_nums=(1, 1, 1, 1)),
        spec_hidden=64,
        spec_layers=2,
        spec_features=32,
        mva_dim=64,
        mva_heads=4,
        mva_depth=2,
        mva_mlp=256,
        brdf_features=64,
        refine=UNetSize(widths=(64, 128, 256, 512), depth=2, groups=16),
    ),
}


@dataclass(frozen=True)
class MAIRConfig:
    """Options of :class:`~.mair.MAIRModel`.

    ===================  ===============  ==========  ============================================
    field                type             default     meaning
    ===================  ===============  ==========  ============================================
    ``size``             MAIRSize         ``small``   stage sizes (preset name or table in files)
    ``num_sgs``          int              3           S_D: SGs of incident lighting per pixel
    ``fusion``           str              attention   ``attention`` (MVANet) or ``mean`` (the
                                                      ablation: per-view MLPs, weighted mean pool)
    ``sharpness_range``  (float, float)   (1, 2000)   λ_min, λ_max of the per-pixel SGs
                                                      (log-uniform in between, via a sigmoid)
    ``log_eps``          float            0.01        ε of the input transform ``log(x + ε)``
    ===================  ===============  ==========  ============================================
    """

    size: MAIRSize = MAIR_SIZE_PRESETS["small"]
    num_sgs: int = 3
    fusion: str = "attention"
    sharpness_range: tuple[float, float] = (1.0, 2000.0)
    log_eps: float = LOG_EPS

    def __post_init__(self):
        if isinstance(self.size, (str, Mapping)):
            object.__setattr__(self, "size", MAIRSize.from_value(self.size, "MAIRConfig.size"))
        object.__setattr__(self, "sharpness_range", tuple(float(v) for v in self.sharpness_range))
        _positive("MAIRConfig", num_sgs=self.num_sgs)
        if self.fusion not in FUSIONS:
            raise ConfigError(f"MAIRConfig: fusion must be one of {', '.join(FUSIONS)}, got {self.fusion!r}")
        lo_hi = self.sharpness_range
        if len(lo_hi) != 2 or not 0 < lo_hi[0] < lo_hi[1]:
            raise ConfigError(
                f"MAIRConfig: sharpness_range must be (λ_min, λ_max) with 0 < λ_min < λ_max, got {lo_hi}"
            )
        if not self.log_eps > 0:
            raise ConfigError(f"MAIRConfig: log_eps must be > 0, got {self.log_eps}")
        if not isinstance(self.size, MAIRSize):
            raise ConfigError(f"MAIRConfig: size must be a MAIRSize or a preset name, got {self.size!r}")

    @classmethod
    def from_dict(cls, data: Mapping, where: str = "model") -> MAIRConfig:
        return dataclass_from_dict(cls, data, where, nested={"size": MAIRSize.from_value})
