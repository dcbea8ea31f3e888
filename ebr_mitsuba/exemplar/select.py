"""Adaptive exemplar selection (step 3 of ``docs/conventions.md``, "Pipeline"): which roughness
values the cascade's exemplars use.

The lighting network predicts exemplars at fixed roughness values; the diffuse and specular
networks work better with an exemplar whose reflection looks like the photographed material's.
:func:`select_exemplars` searches the roughness r of the uniform exemplar material (diffuse 0.1,
specular 0.2 grey, flat normal) whose render is *structurally* closest to a target image, on a
coarse grid and then on a finer one around the best coarse value, and returns that exemplar
followed by two fixed anchors (low and high roughness, so the networks always see the sharpest and
the blurriest view of the lighting):

* environment exemplars (``point_light=False``): renders under the extracted SG environment,
  flash off (:func:`.images.env_exemplar_images`), against the **no-flash** photo;
* point-light exemplars (``point_light=True``): renders lit by the near flash alone
  (:func:`.images.point_exemplar_images`), against the **flash-only** image (flash − no-flash).

**Score.** The photographed material is not the exemplar material: its albedo, specular level and
colour differ, so its image differs from every exemplar by a brightness and a diffuse-to-specular
balance; only the *shape* of the specular reflection tells its roughness. Each candidate r is
scored on luminance, at a small comparison resolution, as follows:

1. fit the target ``t`` by the best non-negative combination ``a·D + b·S_r`` of two basis renders
   in the same light and shot: ``D`` (diffuse albedo 1, specular 0) and ``S_r`` (diffuse 0,
   specular 0.2, roughness r), by least squares. Under the environment ``D`` is a constant (flat
   normal, distant light), so this removes any offset and gain; under the flash ``D`` is the
   smooth cos/d² fall-off, which would otherwise pass for a broad highlight;
2. map ``t`` and the fit by the target's range to [0, 1] (``(x − min t)/(max t − min t)``);
3. score = SSIM (Wang et al. 2004, constants ``K1 = 0.01``, ``K2 = 0.03``, data range 1) with one
   window spanning the whole image (:func:`global_ssim`). After step 1 its luminance and contrast
   terms are ≈ 1 and the score is essentially the correlation of the target with the fit.

Why a global window: the usual 11-pixel Gaussian windows
(:func:`ebr_mitsuba.extract.msssim.ssim`, also tried at 16²–64², and MS-SSIM) see no structure in
near-shot no-flash images, whose specular part varies smoothly by a few per cent over the frame
(the near camera sees only ±30° of reflected directions): every candidate scored ≈ 1 and the
choice was noise (40–50 % of uniform test materials off by more than 0.1, against 0 % for the
global window on non-overcast environments).

**Renders.** The comparison runs at ``compare_size`` pixels per side (target area-averaged
down); the basis images are rendered at ``supersample ×`` that and area-averaged, so a sharp
highlight is integrated over the pixel like the photo's. Environment bases use the ``quadrature``
mode at ``env_spp`` directions: the closed form's error depends on roughness and view (overshoot
up to ≈ 1.3× for rough lobes, see :mod:`ebr_mitsuba.render.env_sg`) — exactly the quantity being
searched — and biased bases mis-selected 20–40 % of the test cases; quadrature at 64 directions
was too noisy (its noise is as large as the structure under overcast light). Point-light bases
are exact (no sampling).

**Limits.** Under overcast light (broad lobes only) the no-flash image hardly depends on
roughness: the selection there is weakly determined (it often falls back to the low end), and so
is which exemplar would help. The coarse grid must be fine enough for the score's narrow peaks
(a coarse step of 0.2 missed r = 1 and r = 0.15 cases that the 0.15 step finds).

Options: :class:`SelectConfig` (its table, generated from the field metadata, is in its
docstring and in ``docs/config.md``).

Cost: one diffuse and ≤ 11 specular basis renders at 64² (256 directions each) plus the three
returned exemplars at the target's size.

Shapes: ``target`` (H, W, 3) linear float, H, W ≥ 4; ``Selection.images`` (3, H, W, 3) float32.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..colour import LUMINANCE
from ..errors import InputError
from ..floors import ROUGHNESS_MIN
from ..geometry import Shot
from ..sgenv import SGEnvironment
from ..typedconfig import config, option
from . import EXEMPLAR_SPECULAR
from .images import env_exemplar_images, env_shot, flash_shot, point_exemplar_images, uniform_renders

MIN_SIZE = 4


@config
class SelectConfig:
    """Knobs of :func:`select_exemplars`. :data:`SELECT_PRESETS` names ``default`` (``ebr
    select-exemplars``) and ``training`` (closed-form SG renders at a 16-pixel comparison: the
    defaults of a training config's ``[selection]`` table)."""

    coarse: tuple[float, ...] = option(
        (0.05, 0.2, 0.35, 0.5, 0.65, 0.8, 0.95),
        "roughness values tried first (step 0.15)",
        minimum=0.0,
        maximum=1.0,
        nonempty=True,
    )
    fine_step: float = option(0.05, "step of the refinement grid", above=0)
    fine_radius: float = option(
        0.1, "refinement: best coarse r ± k·step, |k·step| ≤ radius, inside [ROUGHNESS_MIN, 1]", minimum=0
    )
    anchors: tuple[float, float] = option(
        (0.1, 0.9),
        "the fixed low and high exemplars (the ends of the lighting network's default set)",
        minimum=0.0,
        maximum=1.0,
        ordered=True,
        metavar="LOW,HIGH",
    )
    env_mode: str = option(
        "quadrature",
        "fast-renderer environment term of the env bases and exemplars",
        choices=("sg", "quadrature"),
        flag="--mode",
        metavar="MODE",
    )
    env_spp: int = option(256, "quadrature directions per pixel", minimum=1, flag="--spp")
    compare_size: int = option(32, "comparison resolution (longer side, pixels)", minimum=MIN_SIZE)
    supersample: int = option(2, "basis renders at supersample × that", minimum=1)

    def fine_grid(self, best: float) -> tuple[float, ...]:
        """The refinement candidates around ``best`` (``best`` itself excluded), in
        [ROUGHNESS_MIN, 1] (below ROUGHNESS_MIN the BRDF clamps: every value renders alike)."""
        k = int(np.floor(self.fine_radius / self.fine_step + 1e-9))
        values = [round(best + i * self.fine_step, 6) for i in range(-k, k + 1) if i != 0]
        return tuple(r for r in values if ROUGHNESS_MIN <= r <= 1.0)


SELECT_PRESETS = {
    "default": SelectConfig(),
    "training": SelectConfig(env_mode="sg", compare_size=16),
}


@dataclass(frozen=True)
class Selection:
    """The selected exemplars: ``roughness`` = (adaptive choice, low anchor, high anchor),
    ``scores`` = SSIM per roughness tried (coarse and fine), ``images`` (K, H, W, 3) float32 in
    the order of ``roughness``."""

    roughness: tuple[float, ...]
    scores: dict[float, float] = field(repr=False)
    images: np.ndarray = field(repr=False)

    @property
    def adaptive(self) -> float:
        return self.roughness[0]

    def to_json(self) -> dict:
        return {
            "roughness": [float(r) for r in self.roughness],
            "scores": {f"{r:g}": float(s) for r, s in sorted(self.scores.items())},
        }


# -- score -----------------------------------------------------------------------------------------


def _luminance(image: np.ndarray) -> np.ndarray:
    return np.asarray(image, np.float64) @ LUMINANCE


def _nonnegative_fit(t: np.ndarray, d: np.ndarray, s: np.ndarray) -> np.ndarray:
    """argmin over a, b ≥ 0 of ‖t − a d − b s‖² (2-variable NNLS, closed form); returns a d + b s."""
    shape = t.shape
    t, d, s = t.ravel(), d.ravel(), s.ravel()
    best, best_err = np.zeros_like(t), float(t @ t)
    gram = np.array([[d @ d, d @ s], [d @ s, s @ s]])
    rhs = np.array([d @ t, s @ t])
    candidates = []
    if abs(np.linalg.det(gram)) > 1e-12 * max(gram[0, 0] * gram[1, 1], 1e-300):
        candidates.append(np.linalg.solve(gram, rhs))
    if gram[0, 0] > 0:
        candidates.append(np.array([rhs[0] / gram[0, 0], 0.0]))
    if gram[1, 1] > 0:
        candidates.append(np.array([0.0, rhs[1] / gram[1, 1]]))
    for ab in candidates:
        if np.all(ab >= 0):
            fit = ab[0] * d + ab[1] * s
            err = float(np.sum((t - fit) ** 2))
            if err < best_err:
                best, best_err = fit, err
    return best.reshape(shape)


def global_ssim(a: np.ndarray, b: np.ndarray, data_range: float) -> float:
    """SSIM of Wang et al. (2004) with one window spanning the whole image (uniform weights):
    ``l·c·s`` from the global means, variances and covariance, ``C1 = (0.01 L)²``,
    ``C2 = (0.03 L)²``, ``C3 = C2/2``; a, b (H, W) of one shape."""
    a = np.asarray(a, np.float64).ravel()
    b = np.asarray(b, np.float64).ravel()
    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    ma, mb = a.mean(), b.mean()
    va, vb = a.var(), b.var()
    cov = float(np.mean((a - ma) * (b - mb)))
    return float((2 * ma * mb + c1) * (2 * cov + c2) / ((ma * ma + mb * mb + c1) * (va + vb + c2)))


def structural_score(target_lum: np.ndarray, diffuse_basis: np.ndarray, specular_basis: np.ndarray) -> float:
    """Score of one candidate (module docstring): :func:`global_ssim` of the target luminance
    (H, W) and its best non-negative fit by the two basis luminances (H, W), both mapped by the
    target's own range to [0, 1] (``(x − min t)/(max t − min t)``); in [−1, 1], 1 = same structure."""
    fit = _nonnegative_fit(target_lum, diffuse_basis, specular_basis)
    lo = float(target_lum.min())
    span = max(float(target_lum.max()) - lo, 1e-30)
    return global_ssim((target_lum - lo) / span, (fit - lo) / span, data_range=1.0)


# -- selection -------------------------------------------------------------------------------------


def _check_target(target, what: str = "select_exemplars") -> np.ndarray:
    if not isinstance(target, np.ndarray):
        raise InputError(f"{what}: the target must be an (H, W, 3) numpy image (got {type(target).__name__})")
    if target.ndim != 3 or target.shape[2] != 3:
        raise InputError(f"{what}: the target has shape {target.shape}; expected an (H, W, 3) RGB image")
    if target.shape[0] < MIN_SIZE or target.shape[1] < MIN_SIZE:
        raise InputError(
            f"{what}: the target is {target.shape[1]}x{target.shape[0]} pixels; give at "
            f"least {MIN_SIZE}x{MIN_SIZE}"
        )
    if not np.all(np.isfinite(target)):
        raise InputError(f"{what}: the target has NaN or Inf pixels; give a finite image")
    lum = _luminance(target)
    if not float(np.max(lum)) > 0.0:
        raise InputError(f"{what}: the target image is black; nothing to compare the exemplars with")
    if not float(np.max(lum)) > float(np.min(lum)):
        raise InputError(
            f"{what}: the target image is uniform; it has no structure to compare the exemplars with"
        )
    return np.maximum(np.asarray(target, np.float32), 0.0)


def _working_size(h: int, w: int, size: int) -> tuple[int, int]:
    """(h, w) scaled so that the longer side is at most ``size`` (never up), aspect kept."""
    f = min(1.0, size / max(h, w))
    return max(MIN_SIZE, round(h * f)), max(MIN_SIZE, round(w * f))


def select_exemplars(
    env: SGEnvironment | None,
    target: np.ndarray,
    *,
    point_light: bool = False,
    config: SelectConfig | None = None,
    shot: Shot | None = None,
) -> Selection:
    """Coarse-to-fine roughness search (module docstring) and the selected exemplars.

    ``env``: the (extracted) SG environment; required unless ``point_light``. ``target``: the
    no-flash image, or the flash-only image when ``point_light`` (H, W, 3) linear. ``shot``: the
    camera (and, for point-light exemplars, the flash) the target was taken with; default the near
    shot of :mod:`ebr_mitsuba.geometry` (its flash for ``point_light``).
    """
    from ..imageio import resize_area

    config = config or SelectConfig()
    target = _check_target(target)
    if point_light:
        light_env, render_shot, mode, spp = None, flash_shot(shot), "sg", 1
    else:
        if not isinstance(env, SGEnvironment):
            raise InputError(
                "select_exemplars: environment exemplars need the SG environment (env=...); "
                "pass point_light=True to select point-light exemplars"
            )
        light_env, render_shot, mode, spp = env, env_shot(shot), config.env_mode, config.env_spp
    h, w = target.shape[:2]
    ch, cw = _working_size(h, w, int(config.compare_size))
    rh, rw = ch * int(config.supersample), cw * int(config.supersample)

    def compare_lum(image: np.ndarray) -> np.ndarray:
        return _luminance(image if image.shape[:2] == (ch, cw) else resize_area(image, (ch, cw)))

    def renders(materials) -> list[np.ndarray]:
        images = uniform_renders(materials, light_env, render_shot, rh, rw, mode, spp)
        return [compare_lum(im) for im in images]

    t_lum = compare_lum(target)
    diffuse_lum = renders([(1.0, 0.0, 0.5)])[0]

    scores: dict[float, float] = {}

    def score(values: Sequence[float]) -> None:
        todo = [r for r in values if r not in scores]
        if not todo:
            return
        spec = renders([(0.0, EXEMPLAR_SPECULAR, r) for r in todo])
        for r, s_lum in zip(todo, spec):
            scores[r] = structural_score(t_lum, diffuse_lum, s_lum)

    score([round(r, 6) for r in config.coarse])
    best_coarse = max(scores, key=lambda r: (scores[r], -r))
    score(config.fine_grid(best_coarse))
    best = max(scores, key=lambda r: (scores[r], -abs(r - best_coarse)))
    roughness = (best, *config.anchors)
    if point_light:
        images = point_exemplar_images(roughness, h, w, render_shot)
    else:
        images = env_exemplar_images(env, roughness, h, w, render_shot, config.env_mode, config.env_spp)
    return Selection(roughness=roughness, scores=dict(sorted(scores.items())), images=images)


__all__ = [
    "SELECT_PRESETS",
    "Selection",
    "SelectConfig",
    "global_ssim",
    "select_exemplars",
    "structural_score",
]
