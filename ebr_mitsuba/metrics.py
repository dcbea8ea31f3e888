"""Error metrics: the definitions of ``docs/conventions.md`` ("Metrics"), in one place.

=================================  ===========================================================================
function                           definition (float64, over every pixel, channel and image given)
=================================  ===========================================================================
:func:`rmse`                       √mean((a − b)²)
:func:`rms`                        √mean(a²)
:func:`rel_rmse`                   rmse(a, ref) / rms(ref); ``inf`` when either holds a non-finite value;
                                   for an all-zero ``ref``: 0 when ``a`` is zero too, else ``inf``
:func:`image_errors`               ``{"rmse", "rel_rmse"}`` over the unmasked pixels, ``rel_rmse`` = rmse /
                                   rms of the target; ``nan`` where undefined (empty mask, black target)
:func:`lighting_error`             :func:`image_errors` of renders under the estimated SGs against the same
                                   renders under the true environment (exemplars, a test material); the
                                   benchmarks rank on it with ``judge=True`` (``rel_rmse`` by
                                   :func:`rel_rmse`: ``extract.evaluate.lighting_errors``)
:func:`noise_corrected_rel_rmse`   √(max(Σ(a − ref)² − noise2, 0) / Σ ref²): the relative error left once the
                                   expected Monte-Carlo noise energy ``noise2`` of the pair is removed
:func:`map_rmse`                   RMSE per map (normals encoded (n + 1)/2, roughness one channel) and the
                                   mean of the four; ground truth of another size is area-resampled to the
                                   estimate's grid first
:func:`metal_rough_rmse`           ``{"base colour", "metallic"}`` RMSE of both SVBRDFs read as glTF
                                   metal/rough maps (:func:`ebr_mitsuba.materials.to_metal_rough`), resampled
                                   as :func:`map_rmse`; the dual-loss paper's base colour / metallic figures
:func:`rerender_metrics`           (re-render RMSE, SSIM) of two SVBRDFs (same grid) under the seeded
                                   :func:`rerender_pairs` (below)
:func:`sample_metrics`             ``{"per_map_rmse", "rerender_rmse", "ssim"}`` of one estimate
                                   (:func:`map_rmse` of the keys ``MAP_KEYS``, :func:`rerender_metrics`)
:func:`average`                    the mean of :func:`sample_metrics` rows (``ebr eval``'s summary)
=================================  ===========================================================================

The evaluation protocol of ``ebr eval`` and the benches (:mod:`ebr_mitsuba.evaluation`):

* re-render RMSE: the estimated and the true maps rendered under the same ``RERENDER_PAIRS`` = 30
  seeded random light/view pairs (cosine-hemisphere directions, light and camera at distance
  2.14 from the sample centre, one isotropic point light of the data set's flash intensity, no
  environment; :func:`ebr_mitsuba.nets.losses.sample_view_light_pairs` with no forced
  highlights, the exact torch mirror of the BRDF), RMSE over all pixels, channels and pairs of
  the linear renders;
* SSIM (:func:`ebr_mitsuba.extract.msssim.ssim`, 11-pixel Gaussian windows) of the same renders
  sRGB-encoded after clipping to [0, 1], averaged over the pairs.

The pairs depend on ``seed`` only (default 0), so every model is measured on the same renders.
This module imports numpy only; the re-render metrics import torch when called.

:func:`rel_rmse` judges (benchmarks, ``ebr validate``, ``ebr extract-sg``'s ``rel_rmse_exemplars``): a
broken render must lose, hence ``inf``. :func:`image_errors` reports (``ebr estimate``, ``ebr demo``):
a value that does not exist is ``nan``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .geometry import DEFAULT_FLASH_INTENSITY

if TYPE_CHECKING:
    from .nets.losses import ViewLightPairs
    from .svbrdf import SVBRDF

RERENDER_PAIRS = 30
MAP_KEYS = ("normal", "diffuse", "roughness", "specular", "mean")


def rmse(a: np.ndarray, b: np.ndarray) -> float:
    """√mean((a − b)²) in float64."""
    return float(np.sqrt(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2)))


def rms(a: np.ndarray) -> float:
    """√mean(a²) in float64."""
    return float(np.sqrt(np.mean(np.asarray(a, np.float64) ** 2)))


def rel_rmse(estimate: np.ndarray, reference: np.ndarray) -> float:
    """``rmse(estimate, reference) / rms(reference)`` (module docstring for the edge cases)."""
    a, ref = np.asarray(estimate, np.float64), np.asarray(reference, np.float64)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(ref))):
        return float("inf")
    num, den = rmse(a, ref), rms(ref)
    if den > 0:
        return num / den
    return 0.0 if num == 0 else float("inf")


def image_errors(render: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> dict:
    """``{"rmse", "rel_rmse"}`` of ``render`` against ``target`` (same shape) over the pixels where
    ``mask`` (the leading axes of the images) is true; all pixels without a mask."""
    render, target = np.asarray(render, np.float64), np.asarray(target, np.float64)
    if mask is not None:
        m = np.asarray(mask).astype(bool)
        if not m.any():
            return {"rmse": float("nan"), "rel_rmse": float("nan")}
        render, target = render[m], target[m]
    err, norm = rmse(render, target), rms(target)
    return {"rmse": err, "rel_rmse": err / norm if norm > 0 else float("nan")}


def lighting_error(estimate_renders: np.ndarray, truth_renders: np.ndarray, *, judge: bool = False) -> dict:
    """The lighting error (``docs/conventions.md``, "Metrics"): ``{"rmse", "rel_rmse"}`` of renders
    (exemplars, or the held-out test material) under the estimated SGs against the same renders
    under the true environment, over all renders given.

    One quantity, two edge-case policies (module docstring): reported (``ebr demo``) it is
    :func:`image_errors` (``nan`` where undefined); with ``judge`` (the benchmarks rank on it,
    :func:`ebr_mitsuba.extract.evaluate.lighting_errors`) ``rel_rmse`` is :func:`rel_rmse`, so a
    broken render (non-finite values) is ``inf`` and loses. Where both are defined they are equal."""
    if judge:
        return {
            "rmse": rmse(estimate_renders, truth_renders),
            "rel_rmse": rel_rmse(estimate_renders, truth_renders),
        }
    return image_errors(estimate_renders, truth_renders)


def noise_corrected_rel_rmse(estimate: np.ndarray, reference: np.ndarray, noise2: float) -> float:
    """Relative error of ``estimate`` against a noisy ``reference`` with the expected noise energy
    ``noise2`` (Σ of the squared noise over all values) removed (module docstring)."""
    a, ref = np.asarray(estimate, np.float64), np.asarray(reference, np.float64)
    e2 = float(np.sum((a - ref) ** 2)) - noise2
    return float(np.sqrt(max(e2, 0.0) / max(float(np.sum(ref**2)), 1e-300)))


def map_rmse(estimate, truth) -> dict[str, float]:
    """``{"normal", "diffuse", "specular", "roughness", "mean"}`` RMSE of the SVBRDF ``estimate``
    against ``truth`` (module docstring)."""
    from .materials import resample_svbrdf
    from .svbrdf import MAP_NAMES

    if truth.shape != estimate.shape:
        truth = resample_svbrdf(truth, estimate.shape)
    out = {}
    for name in MAP_NAMES:
        if name == "normal":
            a, b = estimate.encoded_normal(), truth.encoded_normal()
        else:
            a, b = getattr(estimate, name), getattr(truth, name)
        out[name] = rmse(a, b)
    out["mean"] = float(np.mean([out[n] for n in MAP_NAMES]))
    return out


def metal_rough_rmse(estimate, truth) -> dict[str, float]:
    """``{"base colour", "metallic"}`` RMSE of ``estimate`` against ``truth`` (SVBRDFs), both read as
    metal/rough maps (module docstring)."""
    from .materials import resample_svbrdf, to_metal_rough

    if truth.shape != estimate.shape:
        truth = resample_svbrdf(truth, estimate.shape)
    (base_e, metal_e), (base_t, metal_t) = to_metal_rough(estimate), to_metal_rough(truth)
    return {"base colour": rmse(base_e, base_t), "metallic": rmse(metal_e, metal_t)}


def rerender_pairs(seed: int = 0, count: int = RERENDER_PAIRS) -> ViewLightPairs:
    """The seeded light/view pairs of the re-render metric (batch of one)."""
    import torch

    from .nets.losses import sample_view_light_pairs

    return sample_view_light_pairs(1, torch.Generator().manual_seed(seed), count=count, highlights=0)


def rerenders(maps: SVBRDF, pairs: ViewLightPairs, intensity: float = DEFAULT_FLASH_INTENSITY) -> np.ndarray:
    """(count, H, W, 3) linear renders of ``maps`` under the pairs."""
    import torch

    from .nets import Maps
    from .nets import torch_brdf as tb

    with torch.no_grad():
        m = Maps.from_svbrdf([maps])
        out = [
            tb.render_point_light(m, pairs.lights[:, k], intensity, pairs.cameras[:, k])[0]
            for k in range(pairs.count)
        ]
        return torch.stack(out).permute(0, 2, 3, 1).numpy()


def rerender_metrics(
    estimate: SVBRDF,
    truth: SVBRDF,
    pairs: ViewLightPairs,
    intensity: float = DEFAULT_FLASH_INTENSITY,
    truth_renders: np.ndarray | None = None,
) -> tuple[float, float]:
    """(re-render RMSE, mean SSIM) of ``estimate`` against ``truth`` (same grid); ``truth_renders``:
    :func:`rerenders` of ``truth`` under the same pairs, when already made (several estimates of
    one sample)."""
    from .extract.msssim import ssim_many
    from .imageio import linear_to_srgb

    a = rerenders(estimate, pairs, intensity)
    b = rerenders(truth, pairs, intensity) if truth_renders is None else truth_renders
    sa, sb = linear_to_srgb(np.clip(a, 0, 1)), linear_to_srgb(np.clip(b, 0, 1))
    return rmse(a, b), float(np.mean(ssim_many(sa, sb, data_range=1.0)))


def sample_metrics(
    estimate: SVBRDF,
    truth: SVBRDF,
    pairs: ViewLightPairs,
    intensity: float = DEFAULT_FLASH_INTENSITY,
    truth_renders: np.ndarray | None = None,
) -> dict:
    """``{"per_map_rmse": {...}, "rerender_rmse", "ssim"}`` of one sample (``truth_renders``: as
    :func:`rerender_metrics`)."""
    err, s = rerender_metrics(estimate, truth, pairs, intensity, truth_renders)
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
    "image_errors",
    "lighting_error",
    "map_rmse",
    "metal_rough_rmse",
    "noise_corrected_rel_rmse",
    "rel_rmse",
    "rerender_metrics",
    "rerender_pairs",
    "rerenders",
    "rms",
    "rmse",
    "sample_metrics",
]
