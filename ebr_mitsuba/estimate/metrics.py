"""Per-map errors of an estimate against ground truth (DESIGN §3 "Metrics").

RMSE per map over all pixels and channels, normals encoded as (n + 1)/2, roughness one channel,
and their mean (as the EBREnv lab reports). Ground truth of another size is area-resampled to
the estimate's grid first (:func:`ebr_mitsuba.materials.resample_svbrdf`).
"""

from __future__ import annotations

import numpy as np

from ..materials import resample_svbrdf
from ..svbrdf import MAP_NAMES, SVBRDF


def map_rmse(estimate: SVBRDF, truth: SVBRDF) -> dict[str, float]:
    """{"normal", "diffuse", "specular", "roughness", "mean"} RMSE of ``estimate`` vs ``truth``."""
    if truth.shape != estimate.shape:
        truth = resample_svbrdf(truth, estimate.shape)
    out = {}
    for name in MAP_NAMES:
        if name == "normal":
            a, b = estimate.encoded_normal(), truth.encoded_normal()
        else:
            a, b = getattr(estimate, name), getattr(truth, name)
        out[name] = float(np.sqrt(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))
    out["mean"] = float(np.mean([out[n] for n in MAP_NAMES]))
    return out


__all__ = ["map_rmse"]
