"""Reference predictors for ``ebr eval``: what a trained model must beat.

* :class:`MeanMaps` — baseline (a): every sample gets the training set's per-pixel mean maps
  (normals averaged as vectors and renormalised), whatever the photos show.
* :func:`truth_but` — a diagnostic, not a baseline: the ground truth with some maps replaced by
  their constant means (what one map's spatial structure is worth to a metric);
  :func:`truth_roughness_from_albedo` and :func:`truth_roughness_scaled`, the same with the
  roughness map's structure partly kept (what a roughness pattern must get right to pay off).
* :func:`oracle_constant` — the "oracle constant" of the evaluation protocol
  (``docs/conventions.md``, "Metrics"): each test sample gets its *own* ground truth's spatial
  mean, one value per map (normals averaged as vectors and renormalised). No estimator can know
  these means; a model that does not beat them recovers no spatial structure that pays off.

Baseline (b), the same network trained without exemplars, is a checkpoint of its own
(``configs/train_small_noexemplars.toml``) evaluated like any model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..svbrdf import MAP_NAMES, SVBRDF


class MeanMaps:
    """Predicts the per-pixel mean maps of the first ``max_samples`` samples of a data set."""

    def __init__(self, maps: SVBRDF, source: str):
        self.maps = maps
        self.source = source

    @staticmethod
    def from_dataset(root: str | Path, max_samples: int = 0) -> MeanMaps:
        from ..data.dataset import GeneratedDataset

        ds = GeneratedDataset(root)
        n = len(ds) if max_samples <= 0 else min(len(ds), max_samples)
        if n == 0:
            raise InputError(f"{root}: no samples to average")
        total = None
        for i in range(n):
            m = ds[i]["maps"].numpy().astype(np.float64)
            total = m if total is None else total + m
        mean = (total / n).transpose(1, 2, 0).astype(np.float32)
        normal = mean[..., :3] / np.maximum(np.linalg.norm(mean[..., :3], axis=-1, keepdims=True), 1e-6)
        maps = SVBRDF(
            normal,
            mean[..., 3:6].clip(0, 1),
            mean[..., 6:9].clip(0, 1),
            mean[..., 9].clip(0, 1),
            source=f"mean of {n} samples of {root}",
        )
        return MeanMaps(maps, str(root))

    def item_predictor(self):
        """``predict(item, names) -> SVBRDF``: these maps at each data-set item's size (the
        ``evaluate`` predictor of the "training-set mean maps" baseline)."""
        return lambda item, names: self.predict(tuple(item["maps"].shape[1:]))

    def predict(self, size: tuple[int, int]) -> SVBRDF:
        if self.maps.shape != tuple(size):
            from ..materials import resample_svbrdf

            return resample_svbrdf(self.maps, tuple(size))
        return self.maps


def oracle_constant(truth: SVBRDF) -> SVBRDF:
    """The spatial mean of every map of ``truth``, broadcast to its grid."""
    shape = truth.shape
    n = truth.normal.reshape(-1, 3).astype(np.float64).mean(axis=0)
    n = n / max(float(np.linalg.norm(n)), 1e-12)

    def flat(a: np.ndarray, channels: int | None) -> np.ndarray:
        mean = a.reshape(-1, channels).mean(axis=0) if channels else np.array(a.mean())
        return np.broadcast_to(mean.astype(np.float32), shape + ((channels,) if channels else ())).copy()

    return SVBRDF(
        flat(n[None], 3),
        flat(truth.diffuse, 3),
        flat(truth.specular, 3),
        flat(truth.roughness, None),
        source=f"oracle constant of {truth.source}",
    )


def truth_but(truth: SVBRDF, keys: tuple[str, ...]) -> SVBRDF:
    """``truth`` with the maps named in ``keys`` (of normal, diffuse, specular, roughness) replaced by
    their :func:`oracle_constant`: a diagnostic of what one map's spatial structure is worth to a
    metric (``docs/models.md``, "What the re-render figure measures")."""
    unknown = sorted(set(keys) - set(MAP_NAMES))
    if unknown:
        raise InputError(f"truth_but: unknown map(s) {unknown}; expected {', '.join(MAP_NAMES)}")
    const = oracle_constant(truth)
    pick = {k: getattr(const if k in keys else truth, k) for k in MAP_NAMES}
    return SVBRDF(**pick, source=f"{truth.source}, constant {' '.join(keys)}")


def truth_roughness_from_albedo(truth: SVBRDF) -> SVBRDF:
    """``truth`` with its roughness map replaced by its least-squares line in the log grey albedo
    (``a + b · log(mean diffuse + 1e-3)`` over the pixels, clipped to [ROUGHNESS_MIN, 1]): the best
    roughness pattern that follows the albedo, which a capture can read off its texture. A
    diagnostic (``docs/models.md``, "What the re-render figure measures")."""
    from ..floors import ROUGHNESS_MIN

    r = truth.roughness.astype(np.float64)
    u = np.log(truth.diffuse.astype(np.float64).mean(axis=-1) + 1e-3).reshape(-1)
    basis = np.stack([np.ones_like(u), u - u.mean()], axis=1)
    coef, *_ = np.linalg.lstsq(basis, r.reshape(-1), rcond=None)
    rough = (basis @ coef).reshape(r.shape).clip(ROUGHNESS_MIN, 1.0).astype(np.float32)
    return _with_roughness(truth, rough, "roughness regressed on the albedo")


def truth_roughness_scaled(truth: SVBRDF, gain: float) -> SVBRDF:
    """``truth`` with its roughness map's deviations from its mean times ``gain`` (0: the constant
    mean, 1: the truth): the true pattern at part of its amplitude, a diagnostic of how much of it
    an estimate must recover."""
    if not 0.0 <= gain <= 1.0:
        raise InputError(f"truth_roughness_scaled: gain {gain} outside [0, 1]")
    r = truth.roughness.astype(np.float64)
    rough = (r.mean() + gain * (r - r.mean())).astype(np.float32)
    return _with_roughness(truth, rough, f"roughness pattern × {gain:g}")


def _with_roughness(truth: SVBRDF, rough: np.ndarray, what: str) -> SVBRDF:
    return SVBRDF(truth.normal, truth.diffuse, truth.specular, rough, source=f"{truth.source}, {what}")


__all__ = [
    "MeanMaps",
    "oracle_constant",
    "truth_but",
    "truth_roughness_from_albedo",
    "truth_roughness_scaled",
]
