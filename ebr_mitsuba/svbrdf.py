"""The SVBRDF map set, validated on construction.

Shapes at this boundary (numpy, float32, all maps of one H×W grid, row 0 = top = +y):

* ``normal``: (H, W, 3), tangent-space unit vectors (OpenGL +Y), renormalised on construction;
* ``diffuse``: (H, W, 3), linear RGB in [0, 1];
* ``specular``: (H, W, 3), linear RGB F₀ in [0, 1];
* ``roughness``: (H, W), in [0, 1] (α = r², clamped to ≥ 0.03 inside the BRDF only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .exemplar import EXEMPLAR_DIFFUSE, EXEMPLAR_SPECULAR

MAP_NAMES = ("normal", "diffuse", "specular", "roughness")


@dataclass(frozen=True)
class SVBRDF:
    normal: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    roughness: np.ndarray
    source: str = "<memory>"

    def __post_init__(self):
        src = self.source
        n = np.asarray(self.normal, dtype=np.float32)
        d = np.asarray(self.diffuse, dtype=np.float32)
        s = np.asarray(self.specular, dtype=np.float32)
        r = np.asarray(self.roughness, dtype=np.float32)
        if r.ndim == 3 and r.shape[-1] == 1:
            r = r[..., 0]
        for name, arr, ch in (("normal", n, 3), ("diffuse", d, 3), ("specular", s, 3)):
            if arr.ndim != 3 or arr.shape[-1] != ch:
                raise InputError(f"{src}: {name} map has shape {arr.shape}; expected (H, W, {ch})")
        if r.ndim != 2:
            raise InputError(f"{src}: roughness map has shape {r.shape}; expected (H, W) or (H, W, 1)")
        shape = n.shape[:2]
        for name, arr in (("diffuse", d), ("specular", s), ("roughness", r)):
            if arr.shape[:2] != shape:
                raise InputError(
                    f"{src}: {name} map is {arr.shape[1]}x{arr.shape[0]} but normal is "
                    f"{shape[1]}x{shape[0]}; resample the maps to one size"
                )
        for name, arr in (("normal", n), ("diffuse", d), ("specular", s), ("roughness", r)):
            if not np.all(np.isfinite(arr)):
                raise InputError(f"{src}: {name} map has NaN or Inf values; fix or regenerate it")
        tol = 1e-4
        for name, arr in (("diffuse", d), ("specular", s), ("roughness", r)):
            lo, hi = float(arr.min()), float(arr.max())
            if lo < -tol or hi > 1 + tol:
                raise InputError(
                    f"{src}: {name} map has values in [{lo:.4g}, {hi:.4g}], outside [0, 1]; "
                    f"clip or rescale it"
                )
        if float(np.abs(n).max()) > 1 + 1e-3:
            raise InputError(
                f"{src}: normal map has components outside [-1, 1]; decode PNG normals as 2·v − 1"
            )
        if float(n[..., 2].min()) < 0:
            raise InputError(
                f"{src}: normal map has normals pointing into the surface (z < 0); "
                f"check the normal convention (OpenGL/DirectX)"
            )
        length = np.linalg.norm(n, axis=-1, keepdims=True)
        if float(length.min()) < 1e-6:
            raise InputError(f"{src}: normal map has zero-length normals; fix the map")
        # Renormalise only where needed, so rebuilding from unit normals is bit-exact (idempotent).
        off = np.abs(length - 1.0) > 1e-6
        n = np.where(off, n / length, n).astype(np.float32)
        object.__setattr__(self, "normal", n)
        object.__setattr__(self, "diffuse", np.clip(d, 0, 1))
        object.__setattr__(self, "specular", np.clip(s, 0, 1))
        object.__setattr__(self, "roughness", np.clip(r, 0, 1))

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.normal.shape[0]), int(self.normal.shape[1])

    @staticmethod
    def uniform(
        height: int,
        width: int,
        diffuse=EXEMPLAR_DIFFUSE,
        specular=EXEMPLAR_SPECULAR,
        roughness=0.5,
        normal=(0, 0, 1),
    ):
        """A spatially constant material (by default the exemplar material of
        :mod:`ebr_mitsuba.exemplar`, roughness 0.5)."""

        def rgb(v):
            return np.broadcast_to(
                np.asarray(v, np.float32).reshape(-1)[:3] if np.ndim(v) else np.full(3, v, np.float32),
                (height, width, 3),
            ).copy()

        return SVBRDF(
            normal=np.broadcast_to(np.asarray(normal, np.float32), (height, width, 3)).copy(),
            diffuse=rgb(diffuse),
            specular=rgb(specular),
            roughness=np.full((height, width), roughness, np.float32),
            source="<uniform>",
        )

    def encoded_normal(self) -> np.ndarray:
        """Normals encoded as (n + 1)/2 (for PNG output and the RMSE metric)."""
        return (self.normal + 1.0) * 0.5
