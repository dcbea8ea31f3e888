"""Settings of SG extraction, with their defaults in one place (:class:`ExtractConfig`).

:data:`EXTRACT_PRESETS` names the settings used elsewhere: ``default`` (``ebr extract-sg``) and
``training`` (fewer lobes and iterations: stage 2 of training and the trained model's inference,
the defaults of a training config's ``[extract]`` table).
"""

from __future__ import annotations

from ..typedconfig import config, from_dict, option

ENV_MODES = ("sg", "quadrature", "corrected")
INIT_MODES = ("quadtree", "random")
CORRECTIONS = ("ratio", "offset")


@config
class ExtractConfig:
    """Knobs of :func:`ebr_mitsuba.extract.extract_sg` (frozen; unknown keys are rejected by
    :meth:`from_dict`)."""

    max_lobes: int = option(64, "lobe budget (never exceeded)", minimum=1)
    iters: int = option(400, "Adam iterations in all (densification rounds included)", minimum=0)
    lr: float = option(0.1, "Adam learning rate of log λ and log μ", above=0)
    lr_axis: float = option(
        0.02,
        "Adam learning rate of the (free) axis vectors (both follow a cosine decay to 10 % over each "
        "stage between densification rounds)",
        above=0,
    )
    log_weight: float = option(1.0, "weight of the ‖log ŷ − log y‖ term", minimum=0)
    log_eps: float = option(0.01, "ε of log(x + ε), × the exemplar's mean radiance", above=0)
    exemplar_weights: tuple[float, ...] | None = option(None, "λ_i per exemplar (none: all 1)", minimum=0)
    sample_grid: int = option(
        32,
        "pixels per exemplar per iteration: one random pixel in each cell of a g×g grid (re-drawn "
        "every iteration, full-resolution targets)",
        minimum=2,
    )
    variance_threshold: float = option(
        0.05,
        "quad-tree: split a patch while its luminance standard deviation exceeds this × the exemplar's mean",
        above=0,
    )
    max_level: int = option(6, "deepest quad-tree level", minimum=0)
    fill_lobes: int = option(
        16,
        "Fibonacci directions of the upper hemisphere, each given fill lobes of λ = 3, 30 and 300 "
        "after merging (light the mirror directions never show; empty ones are pruned)",
        minimum=0,
    )
    merge_angle: float = option(1.5, "merge two lobes closer than this / √λ_max rad", above=0)
    merge_ratio: float = option(4.0, "... whose sharpness ratio is below this", minimum=1)
    densify_at: tuple[int, ...] = option((150, 250), "iterations at which lobes are added", minimum=0)
    densify_count: int = option(6, "lobes added per round at most", minimum=0)
    densify_threshold: float = option(0.02, "minimum (1 − MS-SSIM) × relative residual", minimum=0)
    prune_threshold: float = option(
        1e-3, "drop lobes contributing less than this fraction of the exemplars' norm", minimum=0
    )
    env_mode: str = option(
        "corrected",
        "forward model in the loop: sg (closed form), quadrature, or corrected (closed form "
        "corrected towards the quadrature, the correction refreshed at correct_at)",
        choices=ENV_MODES,
    )
    spp: int = option(16, "quadrature directions per pixel in the loop (quadrature mode)", minimum=1)
    correction_spp: int = option(
        64, "quadrature directions per pixel of the corrected mode's correction", minimum=1
    )
    correct_at: tuple[int, ...] = option(
        (0, 150, 250, 325), "iterations at which corrected refreshes the correction", minimum=0
    )
    correction_grid: int = option(
        64,
        "the correction is computed on at most this many pixels per side and bilinearly up-sampled",
        minimum=2,
    )
    correction: str = option(
        "ratio",
        "corrected mode: ratio (model S·Q₀/S₀) or offset (model S + Q₀ − S₀)",
        choices=CORRECTIONS,
    )
    seed: int = option(0, "pixel sampling, random initialisation", minimum=0)
    init: str = option("quadtree", "quadtree or random (ablation)", choices=INIT_MODES)
    merge: bool = option(True, "merge similar initial lobes (else keep the max_lobes most energetic ones)")
    optimize: bool = option(True, "run Adam (else stop after the amplitude solve)")
    densify: bool = option(True, "MS-SSIM densification rounds")
    prune: bool = option(True, "prune negligible lobes")

    @classmethod
    def from_dict(
        cls, values: dict, where: str = "ExtractConfig", *, key: str = "", base=None
    ) -> ExtractConfig:
        """Build from a plain dict (e.g. parsed TOML/JSON) over ``base`` (a preset) or the
        defaults; unknown keys are a ConfigError and lists become tuples."""
        return from_dict(cls, values, where, key=key, base=base)


EXTRACT_PRESETS = {
    "default": ExtractConfig(),
    "training": ExtractConfig(iters=100, max_lobes=16),
}
