"""Camera / LDR simulation of the generated photos (numpy, deterministic per sample).

A clean render ``x`` (linear radiance, (H, W, 3) float32) becomes a photo in these steps:

1. **exposure and white balance**: ``x · exposure · g`` with per-channel gains ``g = (g_R, 1, g_B)``;
   the same factor is applied to the flash-only images and the exemplars of the sample (their
   "camera units"), which get no noise, clipping or quantisation;
2. **noise** (Poisson–Gaussian, heteroscedastic): ``+ sqrt(shot · max(x, 0) + read²) · N(0, 1)``,
   one standard normal per pixel and channel from ``default_rng(noise_seed)``, shots in setup order;
3. **clipping** (``clip``): to [0, 1] (saturation; otherwise only negatives are cut at 0);
4. **quantisation** (``quantize``): 8-bit sRGB codes ``round(255 · srgb(x))``, colour-science's
   encoding (:func:`ebr_mitsuba.imageio.write_png`); the photo is stored as that PNG and decodes to
   ``srgb⁻¹(code / 255)``. Without quantisation the photo is stored as float32 EXR.
"""

from __future__ import annotations

import numpy as np

from ..imageio import linear_to_srgb, srgb_to_linear
from .sample import CameraDraw


def camera_units(image: np.ndarray, camera: CameraDraw) -> np.ndarray:
    """Step 1 only: ``image · exposure · gains`` (float32), for flash-only images and exemplars."""
    gains = np.asarray(camera.white_balance, dtype=np.float64) * camera.exposure
    return (np.asarray(image, dtype=np.float64) * gains).astype(np.float32)


def photo_linear(image: np.ndarray, camera: CameraDraw, rng: np.random.Generator) -> np.ndarray:
    """Steps 1–3: exposed, white-balanced, noisy, clipped linear float32 (H, W, 3).

    Quantisation (step 4) happens when the photo is written as an 8-bit sRGB PNG; use
    :func:`quantize` to get the decoded values in memory.
    """
    x = camera_units(image, camera).astype(np.float64)
    noise = rng.standard_normal(x.shape)
    sigma = np.sqrt(camera.shot_noise * np.maximum(x, 0.0) + camera.read_noise**2)
    x = x + sigma * noise
    x = np.clip(x, 0.0, 1.0) if camera.clip else np.maximum(x, 0.0)
    return x.astype(np.float32)


def quantize(linear: np.ndarray) -> np.ndarray:
    """The values an 8-bit sRGB PNG of ``linear`` (in [0, 1]) decodes to, float32."""
    codes = np.rint(linear_to_srgb(np.clip(linear, 0.0, 1.0)).astype(np.float64) * 255.0)
    return srgb_to_linear(codes / 255.0)
