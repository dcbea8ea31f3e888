"""Settings of SG extraction, with their defaults in one place (:class:`ExtractConfig`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from ..errors import ConfigError

ENV_MODES = ("sg", "quadrature", "corrected")
INIT_MODES = ("quadtree", "random")
CORRECTIONS = ("ratio", "offset")


@dataclass(frozen=True)
class ExtractConfig:
    """Knobs of :func:`ebr_mitsuba.extract.extract_sg` (frozen; unknown keys are rejected by
    :meth:`from_dict`).

    ======================  ===========  ==========  ====================================================
    name                    type         default     meaning
    ======================  ===========  ==========  ====================================================
    ``max_lobes``           int          64          lobe budget (never exceeded)
    ``iters``               int          400         Adam iterations in all (densification rounds
                                                     included)
    ``lr``                  float        0.1         Adam learning rate of log λ and log μ
    ``lr_axis``             float        0.02        Adam learning rate of the (free) axis vectors
                                                     (both follow a cosine decay to 10 % over each
                                                     stage between densification rounds)
    ``log_weight``          float        1.0         weight of the ‖log ŷ − log y‖ term
    ``log_eps``             float        0.01        ε of log(x + ε), × the exemplar's mean radiance
    ``exemplar_weights``    tuple|None   None        λ_i per exemplar (None: all 1)
    ``sample_grid``         int          32          pixels per exemplar per iteration: one random
                                                     pixel in each cell of a g×g grid (re-drawn every
                                                     iteration, full-resolution targets)
    ``variance_threshold``  float        0.05        quad-tree: split a patch while its luminance
                                                     standard deviation exceeds this × the
                                                     exemplar's mean
    ``max_level``           int          6           deepest quad-tree level
    ``fill_lobes``          int          16          Fibonacci directions of the upper hemisphere,
                                                     each given fill lobes of λ = 3, 30 and 300
                                                     after merging (light the mirror directions
                                                     never show; empty ones are pruned)
    ``merge_angle``         float        1.5         merge two lobes closer than this / √λ_max rad
    ``merge_ratio``         float        4.0         ... whose sharpness ratio is below this
    ``densify_at``          tuple        (150, 250)  iterations at which lobes are added
    ``densify_count``       int          6           lobes added per round at most
    ``densify_threshold``   float        0.02        minimum (1 − MS-SSIM) × relative residual
    ``prune_threshold``     float        1e-3        drop lobes contributing less than this fraction
                                                     of the exemplars' norm
    ``env_mode``            str          corrected   forward model in the loop: ``sg`` (closed form),
                                                     ``quadrature``, or ``corrected`` (closed form
                                                     corrected towards the quadrature, the
                                                     correction refreshed at ``correct_at``)
    ``spp``                 int          16          quadrature directions per pixel in the loop
                                                     (``quadrature`` mode)
    ``correction_spp``      int          64          quadrature directions per pixel of the
                                                     ``corrected`` mode's correction
    ``correct_at``          tuple        (0, 150,    iterations at which ``corrected`` refreshes
                                         250, 325)   the correction
    ``correction``          str          ratio       ``corrected`` mode: ``ratio`` (model S·Q₀/S₀) or
                                                     ``offset`` (model S + Q₀ − S₀)
    ``correction_grid``     int          64          the correction is computed on at most this many
                                                     pixels per side and bilinearly up-sampled
    ``seed``                int          0           pixel sampling, random initialisation
    ``init``                str          quadtree    ``quadtree`` or ``random`` (ablation)
    ``merge``               bool         True        merge similar initial lobes (else keep the
                                                     ``max_lobes`` most energetic ones)
    ``optimize``            bool         True        run Adam (else stop after the amplitude solve)
    ``densify``             bool         True        MS-SSIM densification rounds
    ``prune``               bool         True        prune negligible lobes
    ======================  ===========  ==========  ====================================================
    """

    max_lobes: int = 64
    iters: int = 400
    lr: float = 0.1
    lr_axis: float = 0.02
    log_weight: float = 1.0
    log_eps: float = 0.01
    exemplar_weights: tuple | None = None
    sample_grid: int = 32
    variance_threshold: float = 0.05
    max_level: int = 6
    fill_lobes: int = 16
    merge_angle: float = 1.5
    merge_ratio: float = 4.0
    densify_at: tuple = (150, 250)
    densify_count: int = 6
    densify_threshold: float = 0.02
    prune_threshold: float = 1e-3
    env_mode: str = "corrected"
    spp: int = 16
    correction_spp: int = 64
    correct_at: tuple = (0, 150, 250, 325)
    correction_grid: int = 64
    correction: str = "ratio"
    seed: int = 0
    init: str = "quadtree"
    merge: bool = True
    optimize: bool = True
    densify: bool = True
    prune: bool = True

    def __post_init__(self):
        def integer(name, lo):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ConfigError(f"extract config: {name} must be an integer >= {lo} (got {v!r})")

        for name, lo in (
            ("max_lobes", 1),
            ("iters", 0),
            ("sample_grid", 2),
            ("max_level", 0),
            ("fill_lobes", 0),
            ("densify_count", 0),
            ("spp", 1),
            ("correction_spp", 1),
            ("correction_grid", 2),
            ("seed", 0),
        ):
            integer(name, lo)
        for name in ("lr", "lr_axis", "log_eps", "variance_threshold", "merge_angle"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ConfigError(f"extract config: {name} must be a finite value > 0 (got {v!r})")
        for name in ("log_weight", "densify_threshold", "prune_threshold"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f"extract config: {name} must be a finite value >= 0 (got {v!r})")
        if not (math.isfinite(self.merge_ratio) and self.merge_ratio >= 1):
            raise ConfigError(f"extract config: merge_ratio must be >= 1 (got {self.merge_ratio!r})")
        if self.env_mode not in ENV_MODES:
            raise ConfigError(
                f"extract config: env_mode {self.env_mode!r} is unknown; use one of {', '.join(ENV_MODES)}"
            )
        if self.correction not in CORRECTIONS:
            raise ConfigError(
                f"extract config: correction {self.correction!r} is unknown; use one of "
                f"{', '.join(CORRECTIONS)}"
            )
        if self.init not in INIT_MODES:
            raise ConfigError(
                f"extract config: init {self.init!r} is unknown; use one of {', '.join(INIT_MODES)}"
            )
        for name in ("densify_at", "correct_at"):
            v = getattr(self, name)
            if not isinstance(v, tuple) or not all(isinstance(i, int) and i >= 0 for i in v):
                raise ConfigError(
                    f"extract config: {name} must be a tuple of iteration numbers >= 0 (got {v!r})"
                )
        if self.exemplar_weights is not None:
            w = self.exemplar_weights
            if not isinstance(w, tuple) or not all(
                isinstance(x, (int, float)) and math.isfinite(x) and x >= 0 for x in w
            ):
                raise ConfigError(
                    f"extract config: exemplar_weights must be a tuple of finite values >= 0 (got {w!r})"
                )

    @classmethod
    def from_dict(cls, values: dict) -> ExtractConfig:
        """Build from a plain dict (e.g. parsed TOML/JSON); unknown keys are a ConfigError and
        lists become tuples."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ConfigError(
                f"extract config: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}"
            )
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})
