"""Normals from the albedo texture, scaled by the flash / no-flash shading (``ebr estimate``'s
default normals for a near flash / no-flash pair).

One co-located flash shot and one no-flash shot do not determine a normal per pixel: both see the
albedo ρ times a shading, and a pixel's two readings leave the normal's two slopes one equation.
What they do determine well is *one number per capture*, if the shape of the relief is known up to
a scale. Real surfaces carry their relief in their albedo: crevices, grout and pores are darker (or,
for some materials, lighter) than the faces around them, so the height field is, to first order,
``h ≈ c · log ρ`` with a material-dependent signed ``c`` (on the training materials the true
normals correlate with the log-albedo gradient by |r| ≈ 0.45 on average, with either sign). This
module reads ``c`` off the shading.

With ``δ = (n_x, n_y) = −∇h`` the slopes (small tilts), the flash-only image
``F = flash − noflash`` and the no-flash shot ``N`` are, per pixel (luminance),

    log F = log ρ + log(n·l / l_z) + log(l_z / d²) + const,   n·l / l_z ≈ 1 + δ · l_t / l_z,
    log N = log ρ + log E(n) + const,                          log E(n) ≈ log E₀ + δ · e,

with ``l`` the unit direction to the flash (``l_t / l_z = −(x, y) / D`` for the camera at height
``D``) and ``e = ∇ log E`` the no-flash irradiance's gradient over normals (unknown, constant over
the sample: the environment is distant). The albedo cancels in the ratio:

    y = log F − log N − log(l_z / d²) ≈ δ · (l_t / l_z) − δ · e + const.

With ``δ = c · u``, ``u = −∇ log ρ̂`` (ρ̂ the photos' albedo estimate: the mean of log F and log N,
corrected for the flash's fall-off), this is linear in three unknowns,

    y ≈ c · (u · l_t / l_z) + β · u + const,      β = −c · e,

solved by least squares over every unsaturated pixel after removing each term's local mean (a box
of ``highpass`` of the side: the shading's low frequencies are the flash's and the sky's, not the
relief's). ``u · l_t / l_z`` changes across the frame while ``u`` does not, which separates ``c``
from the unknown sky gradient. The normals are ``normalize(gain · c · u, 1)``.

Chosen on the validation captures (``configs/data_real_val.toml``, training materials and maps;
24 captures at 256², ``ebr bench models``' metrics). The basis alone, on flat-normal flash fits:
normal RMSE 0.0528 flat, 0.0476 with these (``c`` fitted to the true normals instead: 0.0468); the
estimated ``c`` has the true one's sign in 23 of 24 captures. Tried and dropped: the albedo
estimate from the flash shot alone (0.0493) or the no-flash shot alone (0.0486); more bases (two
smoothing scales, per-channel log-albedo, the two shots' gradients apart: 0.0483–0.0489,
over-fitted). In the whole pipeline (with the glint gate and the diffuse correction below):
normal 0.0528 → 0.0484, diffuse 0.0528 → 0.0515, mean per-map 0.0520 → 0.0505, the predicted
normals' spread 0.04 → 0.45 of the truth's; the held-out-light re-render unchanged (0.0841 →
0.0837 without the one metal sample that dominates it); Bricks020 0.0935 → 0.0585. Most of the
gain is that brick set (4 of the 24 captures, ``explained`` 0.03–0.17); on most others the fit
explains under 1 % and moves the normal RMSE by under 0.001. On the fixed test split (one
``ebr bench models`` run, docs/models.md) it did not carry over: normal RMSE 0.0356 → 0.0365,
mean per-map 0.0326 → 0.0328, spread 0.16 → 0.32 of the truth's.

Tried and dropped (2026-12-05): applying the normals only where the fit explains at least a
share s of the ratio's variance (else the network's): validation normal RMSE 0.0480 for s = 0
(as shipped), 0.003 and 0.02, 0.0481 for 0.01, 0.0490 for 0.03: the captures it
moves little are the ones it explains little, so a gate changes nothing the gain depends on.

Glossy samples are left alone. A specular lobe's glints in the flash shot follow the normals far
more steeply than the diffuse shading does, and the fit then overshoots ``c`` (a glazed tile:
normal RMSE 0.0555 flat, 0.0658 ungated). ``glint_ratio`` = F0 / (4 α² ρ), the flash fit's
specular peak over its diffuse level, decides: above ``glint_limit`` the capture keeps the
network's normals. Re-checked with the relief reading (2026-12-07): without the limit the 12
glossy captures of the three validation sets (``ebr bench normals``' data) went 0.0260 → 0.0328
in mean normal RMSE, better in 3 (acg_Tiles011 0.0549 → 0.0401, glint ratio 6.6) and worse in 9
(a procedural tile set 0.058 → 0.110 at a ratio of 1.1, a facade 0.027 → 0.044 at 8400): no
ratio separates them, so the limit stays at 1.

With the normals tilted, the flash fit's diffuse map (read with flat normals) is divided by the
tilt's flash shading ``(n·l) / l_z``, normalised to mean 1 (``FlashFit.with_normals``).

Shrinkage. The least-squares ``c`` is the best fit of the shading, not the best guess of the
normals: ``u`` is only partly relief (albedo texture that is not height, photo noise), so the
normals that minimise the expected error are ``c_opt · u`` with ``c_opt`` the regression of the
true slopes on ``u``, which is smaller. Measured against the truth maps, the fitted ``c`` was 1.5 /
1.6 times ``c_opt`` (median) on the validation captures (``configs/data_real_val.toml``, 24;
``configs/data_real_val2.toml``, 48). So the diffuse map's shading correction uses the fitted
slopes (shrinking them there made the diffuse map worse: 0.04606 at 1, 0.04645 / 0.04667 at 0.75 /
0.6 on the first set; a stronger correction, the slopes × 1.3, gave 0.04565 there but 0.02947
against 0.02926 on the second, not adopted), while the normal map takes ``map_gain`` × the slopes.
Over ``map_gain`` 1 / 0.7 / 0.6 / 0.55 the estimate's normal RMSE was 0.04801 / 0.04704 / 0.04716 /
0.04731 on the first set and 0.04481 / 0.04343 / 0.04310 / 0.04298 on the second (the other maps
unchanged), so 0.6 (2026-12-06; before, 1). A per-capture shrinkage from the two shots' gradients
(their covariance over their variance, as the flash fit's ``pattern_detail`` does) did not track
``c_opt`` (the shots' relief shading differs, so that share often came out negative) and is not
used. The predicted normals' spread falls by the same factor. On the fixed test split
(``docs/models.md``, one ``ebr bench models`` run) the estimate's normal RMSE went 0.0361 → 0.0349
(the oracle constant maps 0.0350), the spread 0.28 → 0.21 of the truth's.

Resolution. The fit reads ``c`` off pixel-scale gradients, so photo noise per pixel enters ``u``
as well as ``y``; on small pixels it dominates and the least squares shrink ``c`` towards 0 while
the normals ``c · u`` carry the noise. Photos larger than ``fit_size`` (256, the validation
captures' size) are therefore area-averaged to it, fitted there and the normals upsampled
(bilinear, renormalised). On the 1024² capture of ``ebr bench estimate`` (``procedural:tiles:1``,
64 spp) the fit at full size explained 3 % of the ratio (``c`` 0.0029) and the normal RMSE was
0.0792 (flat: 0.0824); fitted at 512² 0.0577, at 256² 0.0488 (explained 48 %, ``c`` 0.024),
the same as the 256² estimate upsampled. Fitting ``c`` at 256² and taking ``u`` at full size
(box-smoothed over 1–5 pixels) gave 0.060–0.18.

Relief off the albedo (``relief``, default on; 2026-12-07). The fit above reads only the relief
that follows the albedo; what it leaves of the ratio (its residual) still holds the shading of every
other relief, one slope component per pixel: ``r ≈ (v(x) − e) · δ``. :mod:`.relief` reads it: the
sky gradient ``e`` by maximum likelihood from how the residual's variance spreads over the frame
(the flash's own term ``v`` is known), then the slopes as the integrable height field that best
explains the residual under a smoothness prior. The normal map adds ``relief_gain`` (0.75) × those
slopes to ``map_gain`` × the fitted ones (the diffuse correction keeps the fitted ones only). The
lighting network's environment would give ``e`` too, but its direction is no better than chance
on the validation captures, and with it the normals got worse (0.0472 → 0.0496). Measured with the
pipeline (``ebr bench models``' metrics; the relief read where the shading normals apply):

* ``configs/data_real_val.toml`` (24 captures, the relief read in 19): normal RMSE 0.04716 →
  0.04227 (better in 13, worse in 2), normal spread over the truth's 0.30 → 0.41, held-out
  re-render 0.7086 → 0.7074, mean per-map RMSE 0.04358 → 0.04236;
* ``configs/data_real_val2.toml`` (48, read in 38): 0.04310 → 0.03903 (26 / 1), 0.25 → 0.31,
  1.0471 → 1.0458, 0.03987 → 0.03885;
* 24 procedural draws (seed 7100, no memorised texture; read in 16): 0.04545 → 0.04249 (15 / 0),
  0.17 → 0.25, 0.1897 → 0.1893, 0.05328 → 0.05254.

(better / worse: by over 1e-5; on the two validation sets the held-out re-render was lower in 37
of the 57 captures read and higher in 3: ``ebr bench normals``, ``docs/bench/normals.md``.) The
relief's gain and prior weight were chosen on the first set, from the reading without the
pipeline: gains 0.5 / 0.6 / 0.75 gave 0.0419 / 0.0417 / 0.0420 at prior weight 1,
weights 0.5 / 2 gave 0.0417 / 0.0428 at gain 0.5; the per-pixel reading without integrability
0.0434. The largest gains are relief-heavy sets whose albedo is uniform (a rock 0.1034 → 0.0800,
a ground set 0.0475 → 0.0278), the largest loss a brick wall (0.1125 → 0.1191). The figures above
are at that gain, 0.5. Since 2026-12-07 it is 0.75, the lowest normal RMSE of ``ebr bench
normals``' grid of the two gains (``docs/bench/normals.md``, "The gains": map gains 0.4–1, relief
gains 0.25–1.5) over all three validation sets (the two above and the procedural draws: 96
captures, 73 read): 0.04033 against 0.04071 at 0.5 (per set 0.04273 / 0.03820 / 0.04220 against
0.04227 / 0.03903 / 0.04249: the first set alone prefers 0.5), the normal structure 0.32 → 0.36.
Issue 15's structure of 0.5 is reached on these captures only at map gain 1 and relief gain 1.5,
at a normal RMSE of 0.04409 (9 % above the default's; the oracle constant normal: 0.04679): a
gain above the least-squares one buys spread with error. On the fixed test split
(``docs/models.md``, one ``ebr bench models`` run after the choice): normal RMSE 0.0333 → 0.0330,
mean per-map RMSE 0.0301 → 0.0300, normal structure 0.24 → 0.27.

Tried and not adopted (2026-12-07): a gain per capture that undoes part of the height solve's
shrinkage. Per capture, the least-squares gain of the relief's slopes against what the
albedo-following slopes leave of the truth's runs from 0.3 to 5 (median 1.35 over the 38 read on
``configs/data_real_val2.toml``), largest where the reading is small against its own slope scale
``√s²`` (the prior took most of it). A gain ``g0 · min((√s² / rms)^p, cap)`` (rms the reading's)
fitted over the first two sets (g0 0.35, p 1, cap 4) gave normal RMSE 0.04227 / 0.03800 against
0.04227 / 0.03903 at the constant 0.5, but 0.04404 against 0.04249 on the procedural draws; the
most even setting (g0 0.5, p 0.25, cap 2) 0.04208 / 0.03839 / 0.04218 against the constant 0.75's
0.04273 / 0.03820 / 0.04220: no rule earns its place over one constant.

Tried and not adopted (2026-12-07): the relief's slopes in the diffuse map's shading correction too
(the fitted slopes plus g × the relief's): diffuse RMSE 0.04595 / 0.04593 / 0.04597 on the first
validation set for g = 0 / 0.5 / 1, 0.02927 / 0.02928 / 0.02937 on the second, 0.03440 / 0.03454 /
0.03485 on the procedural draws.

What it cannot see: relief whose albedo correlation changes sign within the sample (one ``c`` per
capture), relief under a sky whose gradient is parallel to the flash's tilt everywhere (one slope
component per pixel, the same one), and relief finer than the photo's noise. A metal (no
diffuse part: the flash fit's ``metal``) keeps the network's normals (``ebr estimate`` tilts the flat
normal to the clipped highlight instead where it can: :mod:`.highlight_tilt`). Cost at 256²: about 0.18 s
in all (``estimate.json``'s timings), of which the relief about 0.15 s (the likelihood on every
fourth pixel per axis, 80 conjugate-gradient steps).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..colour import LUMINANCE
from ..errors import InputError
from ..floors import NORMAL_Z_MIN, ROUGHNESS_MIN
from ..geometry import pixel_positions
from ..imageio import box_mean, resize_area, upsample_bilinear_fast
from ..typedconfig import config, option
from .relief import Relief, read_relief

FLOOR = 1e-6  # radiance below which a pixel's logarithm is not read
BORDER = 2  # pixels at each edge left out of the fit (one-sided gradients)


@config(error=InputError)
class ShadingNormalsConfig:
    """Options of :func:`fit_shading_normals` (module docstring)."""

    highpass: float = option(
        1.0 / 16.0,
        "box whose local mean is removed from every term, fraction of the image side",
        above=0,
        maximum=1,
    )
    gain: float = option(1.0, "factor on the fitted slopes (1: the least-squares fit)", minimum=0)
    map_gain: float = option(
        0.6,
        'the normal map\'s slopes over the fitted ones (module docstring, "Shrinkage"); the diffuse '
        "map's shading correction uses the fitted slopes; more: more relief at some error "
        "(docs/bench/normals.md)",
        minimum=0,
        maximum=1,
        flag="--normal-gain",
        metavar="G",
    )
    fit_size: int = option(
        256,
        "largest side the normals are fitted at; larger photos are area-averaged to it and the "
        'normals upsampled (module docstring, "Resolution")',
        minimum=32,
    )
    relief: bool = option(
        True,
        "also read the relief that does not follow the albedo off the ratio's residual (module "
        'docstring, "Relief off the albedo"; estimate/relief.py)',
    )
    relief_gain: float = option(
        0.75,
        "the normal map's share of the relief read off the residual (module docstring; its error "
        "against structure: docs/bench/normals.md)",
        minimum=0,
        maximum=2,
        flag="--relief-gain",
        metavar="G",
    )
    relief_smooth: float = option(
        1.0,
        "weight of the relief's height-field prior against the residual (estimate/relief.py)",
        above=0,
    )
    glint_limit: float = option(
        1.0,
        "largest glint ratio (the flash-fitted lobe's peak over the diffuse level, module docstring) "
        "for which the normals are fitted; above it the network's are kept",
        minimum=0,
    )

    def __post_init__(self):
        from ..typedconfig import check

        check(self)


SHADING_FLAGS = ("map_gain", "relief_gain")  # the fields ebr estimate sets from flags


@dataclass
class ShadingNormals:
    """What :func:`fit_shading_normals` found.

    ``normal`` (H, W, 3) float32 unit normals; ``coefficient`` the fitted ``c`` (height per unit
    log-albedo, world units: the sample is 2 wide); ``sky_gradient`` (2,) ``e`` = −β / c (0 when
    c is 0); ``pixels`` the pixels fitted; ``explained`` the share of the ratio's variance the fit
    explains.
    """

    normal: np.ndarray
    coefficient: float
    sky_gradient: np.ndarray
    pixels: int
    explained: float
    relief: Relief | None = None

    def shrunk(self, factor: float, relief_gain: float = 0.0) -> np.ndarray:
        """(H, W, 3) float32 unit normals with the slopes of :attr:`normal` times ``factor`` (in
        [0, 1]) plus ``relief_gain`` × the slopes of :attr:`relief` (when read)."""
        from ..procedural.normals import normals_to_slopes, slopes_to_normals

        slopes = factor * normals_to_slopes(self.normal)
        if self.relief is not None and relief_gain > 0:
            slopes = slopes - relief_gain * self.relief.slopes  # δ = −∇h: the other sign
        return slopes_to_normals(slopes)

    def map_normal(self, options: ShadingNormalsConfig | None = None) -> np.ndarray:
        """The normal map: :meth:`shrunk` by the options' ``map_gain`` and ``relief_gain``."""
        opts = options or ShadingNormalsConfig()
        return self.shrunk(opts.map_gain, opts.relief_gain)

    def to_json(self) -> dict:
        return {
            "coefficient": round(self.coefficient, 6),
            "sky_gradient": [round(float(x), 4) for x in self.sky_gradient],
            "pixels": self.pixels,
            "explained": round(self.explained, 4),
            "relief": None if self.relief is None else self.relief.to_json(),
        }


def glint_ratio(f0: float, roughness: float, albedo: float) -> float:
    """The specular lobe's peak over the diffuse level under a co-located flash,
    ``F₀ D(0) / 4 ÷ ρ/π = F₀ / (4 α² ρ)`` (GGX, α = r², ``f0`` and ``albedo`` luminances):
    above about 1 the flash-only image of a relief is its glints, not its cosine shading."""
    alpha = max(float(roughness), ROUGHNESS_MIN) ** 2
    return float(f0) / (4.0 * alpha**2 * max(float(albedo), 1e-6))


def _gradient(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d/dx, d/dy) of an (H, W) map in world units (x right, y up; the sample is 2 wide)."""
    h, w = a.shape
    d_row, d_col = np.gradient(a)
    return d_col * (w / 2.0), -d_row * (h / 2.0)


def _highpass(a: np.ndarray, radius: int) -> np.ndarray:
    return a - box_mean(a, radius)


def fit_shading_normals(
    flash: np.ndarray,
    noflash: np.ndarray,
    *,
    camera_height: float,
    saturated: np.ndarray | None = None,
    options: ShadingNormalsConfig | None = None,
) -> ShadingNormals:
    """Normals of a near flash / no-flash pair (module docstring).

    ``flash``, ``noflash``: (H, W, 3) linear photos of the sample grid at one exposure, the flash
    at the camera, ``camera_height`` above the sample centre; ``saturated``: (H, W) pixels clipped
    in either shot (left out). Raises InputError for mismatched shapes or too few usable pixels.
    """
    opts = options or ShadingNormalsConfig()
    if np.shape(flash) != np.shape(noflash) or np.ndim(flash) != 3 or np.shape(flash)[2] != 3:
        raise InputError(
            f"shading normals: the flash shot is {np.shape(flash)} and the no-flash shot "
            f"{np.shape(noflash)}; both must be (H, W, 3)"
        )
    h, w, _ = np.shape(flash)
    if max(h, w) > opts.fit_size:  # module docstring, "Resolution"
        f = opts.fit_size / max(h, w)
        size = (max(1, round(h * f)), max(1, round(w * f)))
        small_saturated = None
        if saturated is not None:
            small_saturated = resize_area(np.asarray(saturated, np.float32)[..., None], size)[..., 0] > 0
        small = fit_shading_normals(
            resize_area(np.asarray(flash, np.float32), size),
            resize_area(np.asarray(noflash, np.float32), size),
            camera_height=camera_height,
            saturated=small_saturated,
            options=opts,
        )
        normal = upsample_bilinear_fast(small.normal, (h, w))
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        relief = small.relief
        if relief is not None:
            relief = replace(relief, slopes=upsample_bilinear_fast(relief.slopes, (h, w)))
        return replace(small, normal=normal.astype(np.float32), relief=relief)
    flash = np.asarray(flash, np.float64)
    noflash = np.asarray(noflash, np.float64)
    lum = np.asarray(LUMINANCE, np.float64)
    f = np.clip(flash - noflash, 0.0, None) @ lum
    n = noflash @ lum
    p = pixel_positions(h, w)
    dist2 = p[..., 0] ** 2 + p[..., 1] ** 2 + camera_height**2
    falloff = camera_height / np.sqrt(dist2) / dist2  # l_z / d² of a flat sample
    valid = (f > FLOOR) & (n > FLOOR)
    if saturated is not None:
        valid &= ~np.asarray(saturated, bool)
    valid[:BORDER, :] = valid[-BORDER:, :] = False
    valid[:, :BORDER] = valid[:, -BORDER:] = False
    if valid.sum() < 64:
        raise InputError(
            f"shading normals: only {int(valid.sum())} pixels are lit by the flash and unsaturated; "
            "give an unclipped flash / no-flash pair or --no-shading-normals"
        )
    log_f = np.log(np.maximum(f / falloff, FLOOR))
    log_n = np.log(np.maximum(n, FLOOR))

    def filled(a):
        return np.where(valid, a, np.median(a[valid]))

    log_albedo = filled(0.5 * (log_f + log_n))
    gx, gy = _gradient(log_albedo)
    ux, uy = -gx, -gy
    radius = max(1, int(round(opts.highpass * max(h, w))))
    ratio = _highpass(filled(log_f - log_n), radius)
    tilt = ux * (-p[..., 0] / camera_height) + uy * (-p[..., 1] / camera_height)
    design = np.stack([_highpass(tilt, radius), _highpass(ux, radius), _highpass(uy, radius)], -1)
    a, b = design[valid], ratio[valid]
    coef, *_ = np.linalg.lstsq(a, b, rcond=None)
    c = float(coef[0])
    residual = b - a @ coef
    explained = float(1.0 - residual.var() / max(b.var(), 1e-30))
    sky = -coef[1:] / c if c != 0.0 else np.zeros(2)
    k = opts.gain * c
    normal = np.stack([k * ux, k * uy, np.ones_like(ux)], -1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    if (normal[..., 2] < NORMAL_Z_MIN).any():  # keep every normal within the convention's cone
        t = np.sqrt(np.maximum(normal[..., 0] ** 2 + normal[..., 1] ** 2, 1e-30))
        z = np.maximum(normal[..., 2], NORMAL_Z_MIN)
        s = np.sqrt(1.0 - z**2) / t
        normal = np.stack([normal[..., 0] * s, normal[..., 1] * s, z], -1)
    relief = None
    if opts.relief:  # module docstring, "Relief off the albedo"
        rest = np.zeros_like(ratio)
        rest[valid] = residual
        relief = read_relief(
            rest, valid, -p[..., 0] / camera_height, -p[..., 1] / camera_height, opts.relief_smooth
        )
    return ShadingNormals(
        normal.astype(np.float32), c, np.asarray(sky, np.float64), int(valid.sum()), explained, relief
    )


def normals_for(
    flash_fit,
    flash: np.ndarray,
    noflash: np.ndarray,
    *,
    camera_height: float,
    saturated: np.ndarray | None = None,
    options: ShadingNormalsConfig | None = None,
    log=None,
) -> tuple[dict, ShadingNormals | None]:
    """``ebr estimate``'s shading normals for a near pair and its :class:`~.flashfit.FlashFit`:
    (the ``estimate.json`` record, the :class:`ShadingNormals`). Its ``normal`` is what the
    diffuse map's shading correction uses, :meth:`ShadingNormals.map_normal` the normal map
    (module docstring, "Shrinkage", "Relief off the albedo"). The fit is None when the fitted
    material is glossy (:func:`glint_ratio` above ``glint_limit``): its flash-only image is the
    relief's glints, which the Lambertian ratio misreads (validation: a glazed tile's normal RMSE
    0.056 → 0.066)."""
    opts = options or ShadingNormalsConfig()
    f0 = flash_fit.specular_rgb if flash_fit.specular_rgb is not None else np.full(3, flash_fit.f0)
    glints = glint_ratio(
        float(np.dot(f0, LUMINANCE)), flash_fit.roughness, float(np.dot(flash_fit.level, LUMINANCE))
    )
    record: dict = {"applied": glints <= opts.glint_limit, "glint_ratio": round(glints, 4)}
    if not record["applied"]:
        if log is not None:
            log(
                f"keeping the network's normals: a glossy sample (glint ratio {glints:.2f} > "
                f"{opts.glint_limit:g}; estimate/shading_normals.py)"
            )
        return record, None
    if log is not None:
        log("fitting the normals to the flash / no-flash shading")
    fit = fit_shading_normals(flash, noflash, camera_height=camera_height, saturated=saturated, options=opts)
    record.update(fit.to_json())
    record["map_gain"] = opts.map_gain
    record["relief_gain"] = opts.relief_gain if fit.relief is not None else 0.0
    return record, fit


__all__ = ["ShadingNormals", "ShadingNormalsConfig", "fit_shading_normals", "glint_ratio", "normals_for"]
