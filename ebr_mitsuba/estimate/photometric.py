"""The photometric fit of a five-light capture: normals and albedo per pixel by photometric stereo,
roughness and specular from the light at the camera (``ebr estimate --lights``).

Five photos from one fixed camera, each lit by one isotropic point light of known position ``L_k``
and intensity ``I_k`` and by nothing else, give at every sample point ``p`` five readings of the one
BRDF (:mod:`ebr_mitsuba.nets.torch_brdf`)

    y_k(p) = [ρ(p)/π + f_s(n, l_k, v; F₀, r)] · max(n·l_k, 0) · I_k / d_k²,
    l_k = (L_k − p)/d_k,  d_k = ‖L_k − p‖,  v = (camera − p)/‖·‖.

1. **Roughness and F₀.** The light at the camera (within ``COLOCATED`` of it: light 0 of ``ebr
   capture --setup five-light``) is a co-located flash with no environment, so its photo is a
   flash-only image: :func:`ebr_mitsuba.estimate.flashfit.fit_flash` reads the roughness and the
   specular F₀ off its profile (or finds a metal). Without such a light the network's median
   roughness and specular are kept.
2. **Photometric stereo** on the photos minus that lobe: with ``b = ρ̄ n`` (ρ̄ the grey albedo) the
   diffuse part is linear, ``ȳ_k − s̄_k = b · l_k I_k / (π d_k²)``, five equations for three unknowns
   per pixel, solved by weighted least squares. Weights: 0 for a photo saturated at that pixel
   (per photo, not the union), and ``1 / (1 + (s̄_k / ȳ_k)²)`` so that readings dominated by a
   highlight (where the lobe's model error is largest) count less. ``n = b / ‖b‖`` (``n_z`` at
   least :data:`~ebr_mitsuba.nets.transforms.NORMAL_Z_MIN`); then each channel's albedo by least
   squares given ``n``. Pixels with fewer than three usable readings keep the network's normal and
   the flash photo's albedo.
3. The lobe is re-evaluated with the new normals and step 2 repeated (``passes``).

``residual``: the full model's squared error over all unsaturated readings relative to their
energy; above ``residual_max`` the photos are not what the model describes (a metal the flash fit
took for a dielectric, a coating, light other than the five) and the network's normals are kept,
each pixel's albedo fitted for them (``fallback``). Chosen on the validation set
``configs/data_real_five_light_val.toml`` (training materials, not the test split): the reading
weight k = 1000 (normal / diffuse RMSE 0.0355 / 0.0328 with k = 1, 0.0285 / 0.0284 with 1000) and
the residual limit 0.06, which catches a glossy metal taken for a dielectric and a painted wood
whose photometric-stereo normals were worse than flat (without it: 0.0396 / 0.0369). Tried and dropped
on the same set: refining the roughness by the residual (a search around the flash fit's value:
roughness RMSE 0.110 → 0.134); the flash profile fitted again against the recovered normals
(roughness 0.110 → 0.100, but normal 0.0285 → 0.0338 and diffuse 0.0284 → 0.0318); six passes
instead of two (normal 0.0285 → 0.0313: the photos are not exactly the model, and each pass
follows the lobe's error further; on exact renders more passes converge further).

A metal (step 1) has no diffuse part to invert: the network's normals are kept, the diffuse map
is 0 and F₀ is the fit's. The fit assumes what the five-light setup promises: no other light, no
shadows or interreflections (a normal-mapped plane has none), known light positions; readings
are in the reference exposure's units (``docs/conventions.md``, "Exposure"). Cost: a few
vectorised passes over the photos, about 0.5 s at 256² on one core (plus the flash fit).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError
from ..geometry import pixel_positions
from ..nets import torch_brdf as tb
from ..nets.transforms import NORMAL_Z_MIN
from ..svbrdf import SVBRDF
from ..typedconfig import config, option
from .flashfit import FlashFit, FlashFitConfig, fit_flash

COLOCATED = 1e-3  # a light this close to the camera (relative to the camera distance) is a flash
MIN_WEIGHT = 1e-6  # a reading of this weight or less does not count towards the three needed
RIDGE = 1e-9  # Tikhonov term of the per-pixel 3 × 3 normal equations (relative to their trace)


@config(error=InputError)
class PhotometricConfig:
    """Options of :func:`fit_photometric` (see the module docstring)."""

    passes: int = option(
        2, "photometric-stereo passes (the lobe re-evaluated with the new normals)", minimum=1
    )
    residual_max: float = option(
        0.06,
        "above this relative residual the model does not explain the photos: the network's normals",
        above=0,
    )
    highlight_weight: float = option(
        1000.0, "k of the reading weight 1 / (1 + k (lobe / reading)²); 0: every reading alike", minimum=0
    )


@dataclass
class PhotometricFit:
    """What :func:`fit_photometric` found: ``maps`` (the SVBRDF), ``flash`` (the fit of the light at
    the camera, None without one), ``usable`` (H, W) bool: pixels solved by photometric stereo."""

    maps: SVBRDF
    flash: FlashFit | None
    usable: np.ndarray
    residual: float
    fallback: bool = False

    def to_json(self) -> dict:
        return {
            "flash_fit": None if self.flash is None else self.flash.to_json(),
            "photometric_fraction": round(float(self.usable.mean()), 4),
            "residual": None if math.isnan(self.residual) else round(self.residual, 5),
            "fallback": self.fallback,
        }


def _geometry(h: int, w: int, position, camera):
    p = torch.from_numpy(pixel_positions(h, w)).reshape(-1, 3)
    to_light = torch.tensor(position, dtype=torch.float64) - p
    d2 = (to_light * to_light).sum(-1)
    v = torch.tensor(camera, dtype=torch.float64) - p
    return to_light / d2.sqrt()[:, None], d2, v / v.norm(dim=-1, keepdim=True)


@dataclass
class _System:
    """The per-pixel readings of one capture (module docstring): ``y`` (K, P, 3), ``ok`` (K, P)
    unsaturated, ``light`` (K, P, 3) unit directions, ``irr`` (K, P) I/d², ``view`` (P, 3),
    ``a`` (K, P, 3) the diffuse reading per unit b."""

    y: torch.Tensor
    ok: torch.Tensor
    light: torch.Tensor
    irr: torch.Tensor
    view: torch.Tensor
    a: torch.Tensor

    @staticmethod
    def build(h, w, positions, intensities, cam, y, ok) -> _System:
        geo = [_geometry(h, w, positions[i], cam) for i in range(len(positions))]
        light = torch.stack([g[0] for g in geo])
        irr = torch.stack([float(intensities[i]) / g[1] for i, g in enumerate(geo)])
        return _System(y, ok, light, irr, geo[0][2], light * (irr / math.pi)[..., None])

    def lobe(self, normal, f0, roughness) -> torch.Tensor:
        """(K, P, 3) radiance of the specular lobe (F₀ ``f0`` RGB, one roughness) at ``normal``."""
        p = normal.shape[0]
        spec = torch.from_numpy(np.broadcast_to(np.asarray(f0, np.float64), (p, 3)).copy())
        rough = torch.full((p,), float(roughness), dtype=torch.float64)
        out = []
        for li, ir in zip(self.light, self.irr):
            cos = (normal * li).sum(-1).clamp_min(0.0)
            out.append(tb.specular_term(normal, li, self.view, spec, rough) * (cos * ir)[:, None])
        return torch.stack(out)

    def weights(self, lobe, highlight_weight) -> torch.Tensor:
        """(K, P): 0 where saturated, less where the lobe dominates the reading."""
        ratio = lobe.mean(-1) / self.y.mean(-1).clamp_min(1e-6)
        return self.ok.double() / (1.0 + highlight_weight * ratio**2)

    def albedo(self, normal, lobe, wgt):
        """(albedo (P, 3), model (K, P, 3)): each channel's least-squares albedo given ``normal``."""
        diffuse_part = (self.y - lobe).clamp_min(0.0)
        shade = (self.a * normal[None]).sum(-1).clamp_min(0.0)  # K,P: reading per unit albedo
        num = torch.einsum("kp,kp,kpc->pc", wgt, shade, diffuse_part)
        den = torch.einsum("kp,kp,kp->p", wgt, shade, shade).clamp_min(1e-30)
        albedo = num / den[:, None]
        return albedo, shade[..., None] * albedo[None] + lobe

    def residual(self, model) -> float:
        """The model's squared error over the unsaturated readings relative to their energy."""
        okf = self.ok.double()[..., None]
        return float(((model - self.y) ** 2 * okf).sum() / ((self.y**2) * okf).sum().clamp_min(1e-30))

    def solve(self, fallback, f0, roughness, passes, highlight_weight):
        """(normal (P, 3), albedo (P, 3), usable (P,), relative residual of the full model)."""
        normal = torch.zeros_like(fallback)
        normal[:, 2] = 1.0
        for _ in range(passes):
            lobe = self.lobe(normal, f0, roughness)
            wgt = self.weights(lobe, highlight_weight)
            grey = (self.y - lobe).clamp_min(0.0).mean(-1)
            m = torch.einsum("kp,kpi,kpj->pij", wgt, self.a, self.a)
            rhs = torch.einsum("kp,kpi,kp->pi", wgt, self.a, grey)
            trace = m.diagonal(dim1=-2, dim2=-1).sum(-1).clamp_min(1e-30)
            b = torch.linalg.solve(
                m + (RIDGE * trace)[:, None, None] * torch.eye(3, dtype=torch.float64), rhs
            )
            usable = ((wgt > MIN_WEIGHT).sum(0) >= 3) & (b[:, 2] > 0)
            n_ps = b / b.norm(dim=-1, keepdim=True).clamp_min(1e-30)
            n_ps = torch.cat([n_ps[:, :2], n_ps[:, 2:].clamp_min(NORMAL_Z_MIN)], -1)
            normal = torch.where(usable[:, None], n_ps / n_ps.norm(dim=-1, keepdim=True), fallback)
            albedo, _ = self.albedo(normal, lobe, wgt)
        lobe = self.lobe(normal, f0, roughness)
        _, model = self.albedo(normal, lobe, self.weights(lobe, highlight_weight))
        return normal, albedo, usable, self.residual(model)


def fit_photometric(
    images: Sequence[np.ndarray],
    positions: Sequence[Sequence[float]],
    intensities: Sequence[float],
    network: SVBRDF,
    *,
    camera: Sequence[float],
    saturated: Sequence[np.ndarray] | None = None,
    clip_level: float | None = None,
    options: PhotometricConfig | None = None,
) -> PhotometricFit:
    """Fit the maps of a five-light capture (module docstring).

    ``images``: K (H, W, 3) linear photos in the reference exposure's units; ``positions`` (K, 3) and
    ``intensities`` (K,) W/sr: their lights; ``network``: the network's maps (H, W) — the normals
    of pixels photometric stereo cannot solve and the fallback roughness / specular; ``camera``: the
    lens position; ``saturated``: K (H, W) bool masks (None: nothing saturated); ``clip_level``:
    the photo value that saturates, for the flash fit (None: ``inf``).
    """
    opts = options or PhotometricConfig()
    k = len(images)
    if k < 3 or len(positions) != k or len(intensities) != k:
        raise InputError(
            f"fit_photometric: {k} photos, {len(positions)} positions, {len(intensities)} intensities; "
            "give at least three photos, each with its light"
        )
    h, w, _ = np.asarray(images[0]).shape
    if any(np.asarray(im).shape != (h, w, 3) for im in images) or network.shape != (h, w):
        raise InputError(f"fit_photometric: the photos and the network's maps must all be {h}x{w}")
    masks = [np.zeros((h, w), bool) for _ in range(k)] if saturated is None else list(saturated)
    y = torch.from_numpy(np.stack([np.asarray(im, np.float64).reshape(-1, 3) for im in images]))  # K,P,3
    ok = torch.from_numpy(np.stack([np.asarray(m, bool).reshape(-1) for m in masks]))  # True: saturated
    ok = ~ok

    cam = np.asarray(camera, np.float64)
    flash_index = next(
        (i for i, pos in enumerate(positions) if np.linalg.norm(np.asarray(pos) - cam) <= COLOCATED * cam[2]),
        None,
    )
    flash = None
    if flash_index is not None:
        flash = fit_flash(
            np.asarray(images[flash_index], np.float32),
            np.zeros((h, w, 3), np.float32),
            intensity=float(intensities[flash_index]),
            camera=tuple(cam),
            saturated=masks[flash_index],
            clip_level=math.inf if clip_level is None else clip_level,
            options=FlashFitConfig(),
        )
        roughness = float(flash.roughness)
        f0 = np.asarray(flash.specular_rgb, np.float64)
    else:
        roughness = float(np.median(network.roughness))
        f0 = np.median(network.specular.reshape(-1, 3), axis=0).astype(np.float64)
    n_net = torch.from_numpy(np.asarray(network.normal, np.float64).reshape(-1, 3))
    if flash is not None and flash.metal:  # no diffuse part to invert
        maps = SVBRDF(
            network.normal.astype(np.float32),
            np.zeros((h, w, 3), np.float32),
            np.broadcast_to(f0.astype(np.float32), (h, w, 3)).copy(),
            np.full((h, w), roughness, np.float32),
            "ebr estimate --lights (network normals, flash fit: a metal)",
        )
        return PhotometricFit(maps, flash, np.zeros((h, w), bool), math.nan)

    system = _System.build(h, w, positions, intensities, cam, y, ok)
    normal, albedo, usable, residual = system.solve(n_net, f0, roughness, opts.passes, opts.highlight_weight)
    if flash is not None:  # pixels photometric stereo could not solve: the flash photo's pattern
        albedo = torch.where(usable[:, None], albedo, torch.from_numpy(flash.diffuse.reshape(-1, 3)).double())
    else:
        albedo = torch.where(
            usable[:, None], albedo, torch.from_numpy(network.diffuse.reshape(-1, 3)).double()
        )
    fallback = residual > opts.residual_max
    if fallback:  # the network's normals, each pixel's albedo for them
        normal = n_net
        lobe = system.lobe(normal, f0, roughness)
        albedo, _ = system.albedo(normal, lobe, system.weights(lobe, opts.highlight_weight))
    maps = SVBRDF(
        normal.reshape(h, w, 3).numpy().astype(np.float32),
        albedo.clamp(0.0, 1.0).reshape(h, w, 3).numpy().astype(np.float32),
        np.broadcast_to(f0.astype(np.float32), (h, w, 3)).copy(),
        np.full((h, w), roughness, np.float32),
        "ebr estimate --lights (photometric stereo, flash fit)",
    )
    return PhotometricFit(maps, flash, usable.reshape(h, w).numpy() & (not fallback), residual, fallback)


__all__ = ["PhotometricConfig", "PhotometricFit", "fit_photometric"]
