"""Evaluation metrics of estimated maps (``docs/conventions.md``, "Metrics").

* per-map RMSE (:func:`ebr_mitsuba.metrics.map_rmse`): normals encoded (n + 1)/2,
  roughness one channel, and the mean of the four;
* re-render RMSE: the estimated and the true maps rendered under the same ``RERENDER_PAIRS`` = 30
  seeded random light/view pairs (cosine-hemisphere directions, light and camera at distance
  2.14 from the sample centre, one isotropic point light of the data set's flash intensity, no
  environment; :func:`ebr_mitsuba.nets.losses.sample_view_light_pairs` with no forced
  highlights, the exact torch mirror of the BRDF), RMSE over all pixels, channels and pairs of
  the linear renders;
* SSIM (:func:`ebr_mitsuba.extract.msssim.ssim`, 11-pixel Gaussian windows) of the same renders
  sRGB-encoded after clipping to [0, 1], averaged over the pairs.

The pairs depend on ``seed`` only (default 0), so every model is measured on the same renders.
"""

from __future__ import annotations

import numpy as np
import torch

from ..geometry import DEFAULT_FLASH_INTENSITY
from ..metrics import map_rmse, rmse
from ..nets import Maps
from ..nets import torch_brdf as tb
from ..nets.losses import ViewLightPairs, sample_view_light_pairs
from ..svbrdf import SVBRDF

RERENDER_PAIRS = 30
MAP_KEYS = ("normal", "diffuse", "roughness", "specular", "mean")


def rerender_pairs(seed: int = 0, count: int = RERENDER_PAIRS) -> ViewLightPairs:
    """The seeded light/view pairs of the re-render metric (batch of one)."""
    return sample_view_light_pairs(1, torch.Generator().manual_seed(seed), count=count, highlights=0)


@torch.no_grad()
def rerenders(maps: SVBRDF, pairs: ViewLightPairs, intensity: float = DEFAULT_FLASH_INTENSITY) -> np.ndarray:
    """(count, H, W, 3) linear renders of ``maps`` under the pairs."""
    m = Maps.from_svbrdf([maps])
    out = [
        tb.render_point_light(m, pairs.lights[:, k], intensity, pairs.cameras[:, k])[0]
        for k in range(pairs.count)
    ]
    return torch.stack(out).permute(0, 2, 3, 1).numpy()


def rerender_metrics(
    estimate: SVBRDF, truth: SVBRDF, pairs: ViewLightPairs, intensity: float = DEFAULT_FLASH_INTENSITY
) -> tuple[float, float]:
    """(re-render RMSE, mean SSIM) of ``estimate`` against ``truth`` (same grid)."""
    from ..extract.msssim import ssim_many
    from ..imageio import linear_to_srgb

    a, b = rerenders(estimate, pairs, intensity), rerenders(truth, pairs, intensity)
    sa, sb = linear_to_srgb(np.clip(a, 0, 1)), linear_to_srgb(np.clip(b, 0, 1))
    return rmse(a, b), float(np.mean(ssim_many(sa, sb, data_range=1.0)))


def sample_metrics(
    estimate: SVBRDF, truth: SVBRDF, pairs: ViewLightPairs, intensity: float = DEFAULT_FLASH_INTENSITY
) -> dict:
    """``{"per_map_rmse": {...}, "rerender_rmse", "ssim"}`` of one sample."""
    err, s = rerender_metrics(estimate, truth, pairs, intensity)
    per_map = map_rmse(estimate, truth)
    return {"per_map_rmse": {k: per_map[k] for k in MAP_KEYS}, "rerender_rmse": err, "ssim": s}


def average(rows: list[dict]) -> dict:
    """Mean of :func:`sample_metrics` rows (plus ``seconds_per_sample`` when the rows have
    ``seconds``) and ``n``."""
    out = {
        "per_map_rmse": {k: float(np.mean([r["per_map_rmse"][k] for r in rows])) for k in MAP_KEYS},
        "rerender_rmse": float(np.mean([r["rerender_rmse"] for r in rows])),
        "ssim": float(np.mean([r["ssim"] for r in rows])),
    }
    if rows and "seconds" in rows[0]:
        out["seconds_per_sample"] = float(np.mean([r["seconds"] for r in rows]))
    out["n"] = len(rows)
    return out


__all__ = [
    "MAP_KEYS",
    "RERENDER_PAIRS",
    "average",
    "rerender_metrics",
    "rerender_pairs",
    "rerenders",
    "sample_metrics",
]
