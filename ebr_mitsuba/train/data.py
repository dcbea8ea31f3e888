"""Training data in memory: the first N samples of a generated data set as stacked tensors.

The data sets of this project are small at training resolutions (64² × 20 images ≈ 1 MB per
sample), so :func:`load_training_data` reads them once through
:class:`ebr_mitsuba.data.dataset.GeneratedDataset` and every step indexes tensors. Shapes (N
samples, image layout):

======================  ====================  ===============================================
field                   shape                 content
======================  ====================  ===============================================
``photos``              (N, S, 3, H, W)       shots in ``shot_names`` order (linear)
``flash_only``          (N, F, 3, H, W)       flash-only images (``flash_only_names`` order)
``env_exemplars``       (N, E, 3, H, W)       the data set's environment exemplars
``maps``                (N, 10, H, W)         ground-truth maps (:data:`MAP_LAYOUT`)
``sg``, ``sg_mask``     (N, K, 7), (N, K)     ground-truth lobes (radiance units), padding mask
``gains``               (N, 3)                white balance (input units / radiance)
``exposure``            (N,)                  the camera exposure the images were divided by
======================  ====================  ===============================================

Exposure (``docs/conventions.md``, "Exposure"): every image is divided by its sample's recorded
camera exposure, so the networks see photos at the *reference exposure* (1: a pixel value is
radiance, the flash at the data set's nominal intensity), the scale ``ebr estimate`` brings a
capture to from its known flash intensity. Clipping and noise stay those of the exposed photo.

Shots and flash-only images are looked up by name (:meth:`TrainingData.shots`,
:meth:`TrainingData.flash_only_of`), never by position: a near data set has the shots
:data:`CAPTURE_SHOTS` ``["near"]``, a near-far one ``["near-far"]`` (step 1 of
``docs/conventions.md``, "Pipeline").
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from ..errors import InputError

CAPTURE_SHOTS = {
    "near": ("flash", "noflash"),
    "near-far": ("flash", "noflash", "far_flash", "far_noflash"),
}
"""The photos an EBREnv model takes, in the order of its lighting-net input and of the
refinement's photos, by ``[model].capture``."""


@dataclass
class TrainingData:
    root: Path
    shot_names: list[str]
    flash_only_names: list[str]
    photos: torch.Tensor
    flash_only: torch.Tensor
    env_exemplars: torch.Tensor
    maps: torch.Tensor
    sg: torch.Tensor
    sg_mask: torch.Tensor
    gains: torch.Tensor
    exposure: torch.Tensor

    def __len__(self) -> int:
        return int(self.maps.shape[0])

    def shot(self, name: str) -> int:
        if name not in self.shot_names:
            raise InputError(
                f"{self.root}: the data set has shots {self.shot_names}, not '{name}'; "
                f"use a data set of the model's capture setup"
            )
        return self.shot_names.index(name)

    def shots(self, idx: torch.Tensor, names) -> torch.Tensor:
        """Photos ``names`` of samples ``idx`` side by side: (B, 3·len(names), H, W)."""
        return torch.cat([self.photos[idx, self.shot(n)] for n in names], dim=1)

    def flash_only_of(self, idx: torch.Tensor, name: str = "flash") -> torch.Tensor:
        """The data set's flash-only image of shot ``name`` (ground truth): (B, 3, H, W)."""
        if name not in self.flash_only_names:
            raise InputError(
                f"{self.root}: the data set has flash-only images {self.flash_only_names}, not "
                f"'{name}'; regenerate it with a setup whose flash shots see the environment"
            )
        return self.flash_only[idx, self.flash_only_names.index(name)]

    def far_flash_only(self, idx: torch.Tensor) -> torch.Tensor:
        """The far flash-only image as inference forms it from the photos (no network predicts
        it): ``max(max(far flash, 0) − max(far no-flash, 0), 0)``, (B, 3, H, W)."""
        from ..model.renders import far_flash_only

        return far_flash_only(
            self.photos[idx, self.shot("far_flash")], self.photos[idx, self.shot("far_noflash")]
        )

    def lobes(self, idx: torch.Tensor) -> list[torch.Tensor]:
        """Ground-truth lobes of samples ``idx`` in photo units, (K_b, 7) each."""
        from ..model.renders import photo_unit_lobes
        from ..nets.drwrap import lobes_from_padded

        return photo_unit_lobes(lobes_from_padded(self.sg[idx], self.sg_mask[idx]), self.gains[idx])


def load_training_data(root: str | Path, max_samples: int = 0, progress=None) -> TrainingData:
    """Read samples 0 … min(N, max_samples) − 1 of the data set at ``root`` (0: all), each
    checked against its manifest first (:func:`ebr_mitsuba.data.store.check_sample`: a damaged
    file is an :class:`InputError` naming it)."""
    from ..data.dataset import GeneratedDataset

    ds = GeneratedDataset(root)
    n = len(ds) if max_samples <= 0 else min(len(ds), max_samples)
    if n == 0:
        raise InputError(f"{root}: the data set has no samples; generate some with 'ebr generate'")
    bar = progress(range(n), desc="loading", unit="sample") if progress else None
    try:
        items = [ds[i] for i in (bar if bar is not None else range(n))]
    finally:  # a damaged sample raises: clear the bar so that the error starts its own line
        if hasattr(bar, "close"):
            bar.close()

    def stack(key):
        return torch.stack([it[key] for it in items])

    gains = torch.stack([it["white_balance"] for it in items])
    exposure = stack("exposure")

    def reference(key):  # the images at the reference exposure (module docstring)
        x = stack(key)
        return x / exposure.view(-1, *([1] * (x.dim() - 1)))

    return TrainingData(
        Path(root),
        ds.shot_names,
        ds.flash_only_names,
        reference("photos"),
        reference("flash_only"),
        reference("env_exemplars"),
        stack("maps"),
        stack("sg"),
        stack("sg_mask"),
        gains,
        exposure,
    )


__all__ = ["CAPTURE_SHOTS", "TrainingData", "load_training_data"]
