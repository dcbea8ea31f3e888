"""A batch of SVBRDF maps as torch tensors: the named output of every material network.

Shapes (image layout, the pixel grid of ``docs/conventions.md``, "Geometry and pixel grid"):

* ``normal``: (B, 3, H, W), tangent-space unit vectors with ``n_z > 0``;
* ``diffuse``: (B, 3, H, W), linear RGB in [0, 1];
* ``specular``: (B, 3, H, W), linear RGB F₀ in [0, 1];
* ``roughness``: (B, 1, H, W), in [0, 1].

Stacked, the channels follow :data:`MAP_LAYOUT` (normal 0–2, diffuse 3–5, specular 6–8,
roughness 9): ``(B, 10, H, W)``. :meth:`Maps.from_raw` turns 10 raw network channels into maps with
the constraints of :mod:`.transforms`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import InputError
from ..svbrdf import SVBRDF
from .transforms import unit_interval, unit_normal

MAP_LAYOUT = (("normal", 3), ("diffuse", 3), ("specular", 3), ("roughness", 1))
NUM_MAP_CHANNELS = sum(c for _, c in MAP_LAYOUT)


@dataclass
class Maps:
    """Normal, diffuse, specular and roughness maps of a batch (see the module docstring)."""

    normal: torch.Tensor
    diffuse: torch.Tensor
    specular: torch.Tensor
    roughness: torch.Tensor

    def __post_init__(self):
        ref = self.normal.shape
        if self.normal.ndim != 4 or ref[1] != 3:
            raise InputError(f"Maps: normal has shape {tuple(ref)}; expected (B, 3, H, W)")
        for name, channels in MAP_LAYOUT[1:]:
            shape = getattr(self, name).shape
            if tuple(shape) != (ref[0], channels, ref[2], ref[3]):
                raise InputError(
                    f"Maps: {name} has shape {tuple(shape)}; expected "
                    f"({ref[0]}, {channels}, {ref[2]}, {ref[3]}) to match the normal map"
                )

    def stack(self) -> torch.Tensor:
        """All maps as one ``(B, 10, H, W)`` tensor in :data:`MAP_LAYOUT` order."""
        return torch.cat([getattr(self, name) for name, _ in MAP_LAYOUT], dim=1)

    @classmethod
    def unstack(cls, stacked: torch.Tensor) -> Maps:
        """Inverse of :meth:`stack` (no constraint applied)."""
        if stacked.ndim != 4 or stacked.shape[1] != NUM_MAP_CHANNELS:
            raise InputError(f"Maps.unstack: got shape {tuple(stacked.shape)}; expected (B, 10, H, W)")
        parts, start = {}, 0
        for name, channels in MAP_LAYOUT:
            parts[name] = stacked[:, start : start + channels]
            start += channels
        return cls(**parts)

    @classmethod
    def from_raw(cls, raw: torch.Tensor) -> Maps:
        """Constrained maps from 10 raw channels: unit normal (``z > 0``), sigmoid for the rest."""
        r = cls.unstack(raw)
        return cls(
            unit_normal(r.normal),
            unit_interval(r.diffuse),
            unit_interval(r.specular),
            unit_interval(r.roughness),
        )

    @classmethod
    def from_svbrdf(cls, items: Sequence[SVBRDF], device=None) -> Maps:
        """A batch from :class:`~ebr_mitsuba.svbrdf.SVBRDF` map sets of one size (float32)."""
        if not items:
            raise InputError("Maps.from_svbrdf: got no SVBRDF")

        def batch(name):
            arrays = [np.asarray(getattr(s, name), dtype=np.float32) for s in items]
            if name == "roughness":
                arrays = [a[..., None] for a in arrays]
            shapes = {a.shape for a in arrays}
            if len(shapes) != 1:
                raise InputError(
                    f"Maps.from_svbrdf: {name} maps differ in size {sorted(shapes)}; "
                    f"resample them to one size"
                )
            return torch.from_numpy(np.stack(arrays)).permute(0, 3, 1, 2).contiguous().to(device)

        return cls(**{name: batch(name) for name, _ in MAP_LAYOUT})

    def to_svbrdf(self, index: int = 0, source: str = "<network>") -> SVBRDF:
        """Batch element ``index`` as a numpy :class:`~ebr_mitsuba.svbrdf.SVBRDF` (H, W, C)."""

        def arr(t):
            return t[index].detach().to("cpu", torch.float32).permute(1, 2, 0).numpy()

        return SVBRDF(
            arr(self.normal),
            arr(self.diffuse).clip(0, 1),
            arr(self.specular).clip(0, 1),
            arr(self.roughness)[..., 0].clip(0, 1),
            source=source,
        )

    def detach(self) -> Maps:
        return Maps(*(getattr(self, name).detach() for name, _ in MAP_LAYOUT))
