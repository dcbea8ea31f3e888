"""The SG environment type and its ``env.json`` file (format ``ebr-sg/1``).

``SGEnvironment`` holds K lobes as numpy arrays (world frame, z-up):

* ``axis``: (K, 3) float32, unit vectors;
* ``sharpness``: (K,) float32, λ > 0;
* ``amplitude``: (K, 3) float32, RGB μ ≥ 0.

Radiance ``L(ω) = Σ_k μ_k exp(λ_k (ξ_k·ω − 1))``. K = 0 is a valid, all-black environment.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .colour import LUMINANCE
from .errors import InputError
from .fsutil import atomic_write_text

IRRADIANCE_NODES = 64  # Gauss–Legendre nodes per piece of the clamped-cosine integral (sg_irradiance)

FORMAT = "ebr-sg/1"

#: :meth:`SGEnvironment.azimuthal`: the polar steps of its hemisphere grid (twice as many azimuths)
#: and the sharpnesses its zenith lobe is chosen from.
AZIMUTHAL_POLAR_STEPS = 64
AZIMUTHAL_SHARPNESS = np.geomspace(0.05, 2000.0, 241)


@dataclass(frozen=True)
class SGEnvironment:
    axis: np.ndarray
    sharpness: np.ndarray
    amplitude: np.ndarray

    def __post_init__(self):
        axis = np.asarray(self.axis, dtype=np.float64).reshape(-1, 3)
        sharp = np.asarray(self.sharpness, dtype=np.float64).reshape(-1)
        amp = np.asarray(self.amplitude, dtype=np.float64)
        if amp.ndim == 1:
            amp = np.repeat(amp[:, None], 3, axis=1)
        amp = amp.reshape(-1, 3)
        k = axis.shape[0]
        if sharp.shape[0] != k or amp.shape[0] != k:
            raise InputError(
                f"SG environment: {k} axes, {sharp.shape[0]} sharpness values and "
                f"{amp.shape[0]} amplitudes; give one of each per lobe"
            )
        if not (np.all(np.isfinite(axis)) and np.all(np.isfinite(sharp)) and np.all(np.isfinite(amp))):
            raise InputError("SG environment: NaN or Inf in the lobe parameters; give finite values")
        norms = np.linalg.norm(axis, axis=1)
        if np.any(norms < 1e-8):
            raise InputError("SG environment: a lobe axis has zero length; give unit axes")
        if np.any(sharp <= 0):
            raise InputError("SG environment: sharpness must be > 0 for every lobe")
        if np.any(amp < 0):
            raise InputError("SG environment: amplitudes must be >= 0 (RGB) for every lobe")
        object.__setattr__(self, "axis", (axis / norms[:, None]).astype(np.float32))
        object.__setattr__(self, "sharpness", sharp.astype(np.float32))
        object.__setattr__(self, "amplitude", amp.astype(np.float32))

    @property
    def num_lobes(self) -> int:
        return int(self.axis.shape[0])

    @staticmethod
    def empty() -> SGEnvironment:
        return SGEnvironment(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))

    def scaled(self, factor: float) -> SGEnvironment:
        return SGEnvironment(self.axis, self.sharpness, self.amplitude * factor)

    def rotated_z(self, angle: float) -> SGEnvironment:
        c, s = math.cos(angle), math.sin(angle)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return SGEnvironment(self.axis @ rot.T, self.sharpness, self.amplitude)

    def azimuthal(self) -> SGEnvironment:
        """The environment averaged over azimuth as one lobe at the zenith: what is left of it when
        the direction it comes from around the vertical is unknown (the expected radiance over a
        uniformly random turn about z). The lobe's sharpness is the least-squares fit of its profile
        to the averaged radiance over the upper hemisphere (weighted by ``sin θ cos θ``, the
        share each polar angle has in a horizontal plane's irradiance; :data:`AZIMUTHAL_SHARPNESS`
        grid), its amplitude per channel the one that keeps the irradiance of a z-up plane exactly
        (:meth:`irradiance`). An empty environment stays empty."""
        if self.num_lobes == 0:
            return SGEnvironment.empty()
        theta = (np.arange(AZIMUTHAL_POLAR_STEPS) + 0.5) * (math.pi / 2 / AZIMUTHAL_POLAR_STEPS)
        phi = (np.arange(2 * AZIMUTHAL_POLAR_STEPS) + 0.5) * (math.pi / AZIMUTHAL_POLAR_STEPS)
        t, p = np.meshgrid(theta, phi, indexing="ij")
        dirs = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
        profile = self.eval(dirs).mean(axis=1)  # (T, 3): the radiance averaged over azimuth
        weight = np.sin(theta) * np.cos(theta)
        shapes = np.exp(AZIMUTHAL_SHARPNESS[:, None] * (np.cos(theta)[None] - 1.0))  # (L, T)
        amp = np.einsum("lt,tc->lc", shapes * weight, profile) / (shapes**2 @ weight)[:, None]
        misfit = np.einsum("t,ltc->l", weight, (profile[None] - shapes[..., None] * amp[:, None]) ** 2)
        lam = float(AZIMUTHAL_SHARPNESS[int(np.argmin(misfit))])
        zenith = SGEnvironment(np.array([[0.0, 0.0, 1.0]]), np.array([lam]), np.ones((1, 3)))
        amplitude = self.irradiance() / zenith.lobe_irradiance()[0]
        return SGEnvironment(zenith.axis, zenith.sharpness, np.maximum(amplitude, 0.0)[None])

    def concat(self, other: SGEnvironment) -> SGEnvironment:
        return SGEnvironment(
            np.concatenate([self.axis, other.axis]),
            np.concatenate([self.sharpness, other.sharpness]),
            np.concatenate([self.amplitude, other.amplitude]),
        )

    def energy(self) -> np.ndarray:
        """Per-lobe integral ∫G dω, luminance-weighted (K,): used to pick lobes when sampling."""
        lam = self.sharpness.astype(np.float64)
        integ = 2 * np.pi * (-np.expm1(-2 * lam)) / lam
        lum = self.amplitude.astype(np.float64) @ LUMINANCE
        return integ * lum

    def lobe_irradiance(self, normal=(0.0, 0.0, 1.0), nodes: int = IRRADIANCE_NODES) -> np.ndarray:
        """(K,) float64: each lobe's irradiance at unit amplitude on a plane of unit ``normal`` (the
        exact clamped-cosine integral, :func:`ebr_mitsuba.sg.sg_irradiance` with ``nodes``
        Gauss–Legendre nodes per piece)."""
        from drjit.scalar import Array3f

        from .sg import sg_irradiance

        n = Array3f(*(float(c) for c in normal))
        return np.array(
            [
                float(sg_irradiance(Array3f(*(float(c) for c in axis)), float(lam), 1.0, n, n_nodes=nodes))
                for axis, lam in zip(self.axis, self.sharpness)
            ],
            dtype=np.float64,
        )

    def irradiance(self, normal=(0.0, 0.0, 1.0)) -> np.ndarray:
        """RGB irradiance (3,) float64 on a plane of unit ``normal`` (clamped cosine), summed over
        the lobes (:meth:`lobe_irradiance`)."""
        return self.lobe_irradiance(normal) @ self.amplitude.astype(np.float64).reshape(-1, 3)

    def eval(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (…, 3) in unit directions (…, 3), numpy float64."""
        d = np.asarray(directions, dtype=np.float64)
        cos = d @ self.axis.astype(np.float64).T  # (..., K)
        w = np.exp(self.sharpness.astype(np.float64) * (cos - 1.0))
        return w @ self.amplitude.astype(np.float64)

    # -- env.json --------------------------------------------------------------------------
    def to_json(self) -> dict:
        return {
            "format": FORMAT,
            "up": "+z",
            "lobes": [
                {"axis": [float(v) for v in a], "sharpness": float(l), "amplitude": [float(v) for v in m]}
                for a, l, m in zip(self.axis, self.sharpness, self.amplitude)
            ],
        }

    @staticmethod
    def from_json(data: dict, source: str = "env.json") -> SGEnvironment:
        fix = f'{source}: expected {{"format": "{FORMAT}", "up": "+z", "lobes": [...]}}'
        if not isinstance(data, dict):
            raise InputError(f"{fix}; got a {type(data).__name__}")
        if data.get("format") != FORMAT:
            raise InputError(f"{source}: 'format' must be \"{FORMAT}\" (got {data.get('format')!r})")
        if data.get("up", "+z") != "+z":
            raise InputError(f'{source}: only "up": "+z" is supported (got {data.get("up")!r})')
        lobes = data.get("lobes")
        if not isinstance(lobes, list):
            raise InputError(f"{fix}; 'lobes' is missing or not a list")
        axes, sharp, amp = [], [], []
        for i, lobe in enumerate(lobes):
            try:
                a = [float(v) for v in lobe["axis"]]
                lam = float(lobe["sharpness"])
                m = lobe["amplitude"]
                m = [float(m)] * 3 if isinstance(m, (int, float)) else [float(v) for v in m]
            except (KeyError, TypeError, ValueError) as exc:
                raise InputError(
                    f"{source}: lobe {i} needs 'axis' [x,y,z], 'sharpness' λ>0 and "
                    f"'amplitude' [r,g,b] ({type(exc).__name__}: {exc})"
                ) from None
            if len(a) != 3 or len(m) != 3:
                raise InputError(f"{source}: lobe {i}: 'axis' and 'amplitude' need 3 numbers each")
            axes.append(a)
            sharp.append(lam)
            amp.append(m)
        if not lobes:
            return SGEnvironment.empty()
        try:
            return SGEnvironment(np.array(axes), np.array(sharp), np.array(amp))
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None

    def save(self, path: str | Path) -> None:
        atomic_write_text(path, json.dumps(self.to_json(), indent=1) + "\n")

    @staticmethod
    def load(path: str | Path) -> SGEnvironment:
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such SG environment file; give an existing env.json")
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(
                f"{path}: malformed JSON ({exc.msg if hasattr(exc, 'msg') else exc}); "
                f"fix the file or regenerate it"
            ) from None
        return SGEnvironment.from_json(data, source=str(path))
