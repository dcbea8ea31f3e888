"""On-disk caches of the per-sample work that does not change during a phase.

* **stage 1** (``cache/stage1/NNNNNN.npz``): the adaptive exemplar selection under the
  ground-truth environment (in photo units) — env exemplars against the no-flash photo,
  point-light exemplars against the ground-truth flash-only image;
* **stage 2** (``cache/stage2/NNNNNN.npz``): the trained lighting net's flash-only image, the SGs
  :func:`ebr_mitsuba.extract.extract_sg` extracts from its exemplars, and the selection under them.

Both follow :func:`ebr_mitsuba.model.predict.predict`: the lighting net takes the model's shots
(four for a near-far model, :data:`.data.CAPTURE_SHOTS`); the selections compare with the near
no-flash photo and the near flash-only image. (The far flash-only image is not cached: it is a
function of the photos, :func:`ebr_mitsuba.model.renders.far_flash_only`.)

Arrays are float32, images (K, H, W, 3) as selection returns them; lobes (K, 7). A cache file
is written atomically and reused when present (``ebr train --resume``); under DDP each rank fills
its share. :func:`load_cache` stacks the files of samples 0 … N−1 into tensors; :class:`RunCaches`
is a run's pair of caches, each filled and loaded when a phase first asks for it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..fsutil import atomic_path
from ..model.predictor import StagedPredictor
from . import ddp


def cache_file(root: Path, stage: str, index: int) -> Path:
    return Path(root) / "cache" / stage / f"{index:06d}.npz"


def _save(path: Path, **arrays) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **{k: np.asarray(v, np.float32) for k, v in arrays.items()})


def _selection_arrays(env_sel, point_sel, size: int) -> dict:
    env_images = env_sel.images if env_sel is not None else np.zeros((3, size, size, 3), np.float32)
    env_r = env_sel.roughness if env_sel is not None else (0.0, 0.0, 0.0)
    return {
        "env_images": env_images,
        "env_roughness": env_r,
        "point_images": point_sel.images,
        "point_roughness": point_sel.roughness,
    }


def fill_stage1(root: Path, data, indices, select_config, progress=None) -> None:
    """Stage-1 selections for ``indices`` (skipping cached ones)."""
    from ..model.predict import select_pair
    from ..sgenv import SGEnvironment

    todo = [i for i in indices if not cache_file(root, "stage1", i).is_file()]
    nf_i = data.shot("noflash")
    for i in progress(todo, desc="stage-1 selection", unit="sample") if progress else todo:
        lobes = data.lobes(torch.tensor([i]))[0].numpy()
        env = SGEnvironment(lobes[:, :3], lobes[:, 3], lobes[:, 4:]) if len(lobes) else SGEnvironment.empty()
        noflash = data.photos[i, nf_i].clamp_min(0.0).permute(1, 2, 0).numpy()  # as predict's input check
        flash_only = data.flash_only_of(torch.tensor([i]))[0].permute(1, 2, 0).numpy()
        env_sel, point_sel = select_pair(env, noflash, flash_only, select_config)
        _save(cache_file(root, "stage1", i), **_selection_arrays(env_sel, point_sel, noflash.shape[0]))


def fill_stage2(
    root: Path, data, indices, predictor: StagedPredictor, select_config, extract_config, progress=None
) -> None:
    """Stage-2 lighting, extracted SGs and selections for ``indices`` (skipping cached ones), from
    ``predictor``'s lighting net and SG extraction (:meth:`StagedPredictor.estimate_lighting`)."""
    from ..model.predict import select_pair
    from ..nets.drwrap import lobes_from_env
    from .data import CAPTURE_SHOTS

    todo = [i for i in indices if not cache_file(root, "stage2", i).is_file()]
    names = CAPTURE_SHOTS["near-far" if predictor.takes_far else "near"]
    for i in progress(todo, desc="stage-2 extraction", unit="sample") if progress else todo:
        # max(·, 0) as predict's input check does
        shots = [data.photos[i, data.shot(n)].clamp_min(0.0).permute(1, 2, 0).numpy() for n in names]
        flash, noflash = shots[0], shots[1]
        _, flash_only, env, _ = predictor.estimate_lighting(*shots, extract_config=extract_config)
        arrays = {"flash_only": flash_only, "sg": lobes_from_env(env).numpy()}
        if predictor.cascade.config.use_exemplars:
            arrays.update(
                _selection_arrays(*select_pair(env, noflash, flash_only, select_config), flash.shape[0])
            )
        _save(cache_file(root, "stage2", i), **arrays)


def load_cache(root: Path, stage: str, indices) -> dict:
    """Stacked tensors of a stage's cache: images as (N, K, 3, H, W) / (N, 3, H, W); ``sg`` as a
    list of (K_b, 7) tensors."""
    files = [np.load(cache_file(root, stage, i)) for i in indices]
    out = {}
    for key in files[0].files:
        arrays = [f[key] for f in files]
        if key == "sg":
            out[key] = [torch.from_numpy(a.reshape(-1, 7)) for a in arrays]
        elif arrays[0].ndim == 4:
            out[key] = torch.from_numpy(np.stack(arrays)).permute(0, 1, 4, 2, 3).contiguous()
        elif arrays[0].ndim == 3:
            out[key] = torch.from_numpy(np.stack(arrays)).permute(0, 3, 1, 2).contiguous()
        else:
            out[key] = torch.from_numpy(np.stack(arrays))
    return out


class RunCaches:
    """The caches of one run under ``root`` (``--out``) for ``data`` and ``config`` (a
    :class:`~ebr_mitsuba.model.config.TrainConfig`: selection and extraction options,
    ``finetune_samples``).

    :meth:`stage1` and :meth:`stage2` fill their cache (this rank's share of the samples, files
    already there skipped; then a barrier) on the first call, load it and keep it for later calls.
    ``progress``: a tqdm-like factory for the filling (None: no bars).
    """

    def __init__(self, root: Path, data, config, dist: ddp.DistInfo, progress=None):
        self.root, self.data, self.config, self.dist, self.progress = Path(root), data, config, dist, progress
        self._loaded: dict[str, dict] = {}

    def stage1(self) -> dict:
        """The stage-1 selections of every sample."""
        if "stage1" not in self._loaded:
            n, select = len(self.data), self.config.select_config()
            fill_stage1(self.root, self.data, ddp.share(range(n), self.dist), select, self.progress)
            ddp.barrier(self.dist)
            self._loaded["stage1"] = load_cache(self.root, "stage1", range(n))
        return self._loaded["stage1"]

    def stage2(self, bundle) -> dict:
        """Stage 2 of the first ``finetune_samples`` samples, from ``bundle``'s lighting net as it
        is at the first call (put in eval mode), as a :class:`~ebr_mitsuba.model.predict.ModelPredictor`."""
        from ..model.predict import ModelPredictor

        if "stage2" not in self._loaded:
            c = self.config
            m = min(len(self.data), c.stages.finetune_samples)
            bundle.train(False)
            fill_stage2(
                self.root,
                self.data,
                ddp.share(range(m), self.dist),
                ModelPredictor(bundle),
                c.select_config(),
                c.extract_config(),
                self.progress,
            )
            ddp.barrier(self.dist)
            self._loaded["stage2"] = load_cache(self.root, "stage2", range(m))
        return self._loaded["stage2"]


__all__ = ["RunCaches", "cache_file", "fill_stage1", "fill_stage2", "load_cache"]
