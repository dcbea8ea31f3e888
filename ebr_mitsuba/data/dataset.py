"""A torch ``Dataset`` over a generated data set (format of :mod:`ebr_mitsuba.data.store`).

``GeneratedDataset(root)[i]`` is a dict of float32 tensors (S shots, F flash-only images, E and P
exemplars in the order of the config's roughness lists, K = ``max_lobes``; every image in the
(C, H, W) layout, linear values — PNG photos decoded from sRGB):

======================  ==================  ========================================================
key                     shape               content
======================  ==================  ========================================================
``photos``              (S, 3, H, W)        camera-simulated photos, shots in ``shot_names`` order
``flash_only``          (F, 3, H, W)        flash-only images (``flash_only_names`` order)
``env_exemplars``       (E, 3, H, W)        environment exemplars
``point_exemplars``     (P, 3, H, W)        point-light exemplars
``maps``                (10, H, W)          normal 0–2, diffuse 3–5, specular 6–8, roughness 9
                                            (:data:`ebr_mitsuba.nets.maps.MAP_LAYOUT`)
``sg``                  (K, 7)              lobes [axis xyz, λ, μ rgb] (radiance units), zero-padded
``sg_mask``             (K,)                1.0 for real lobes, 0.0 for padding
``exposure``            ()                  camera exposure of the sample
``white_balance``       (3,)                camera white-balance gains
``index``               () int64            sample index
======================  ==================  ========================================================

E or P may be 0 (an empty exemplar list); F is 0 for setups without environment-lit flash shots.
``max_lobes`` defaults to the largest lobe count in the data set (read from the index once).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import InputError
from . import store


def _chw(images, size: tuple[int, int]) -> torch.Tensor:
    if not images:
        return torch.zeros((0, 3, *size), dtype=torch.float32)
    stack = np.stack([np.asarray(im, np.float32) for im in images])  # (N, H, W, 3)
    return torch.from_numpy(np.ascontiguousarray(stack.transpose(0, 3, 1, 2)))


class GeneratedDataset(Dataset):
    """Samples of the data set at ``root`` as tensors (see the module docstring).

    Needs ``dataset.json`` and ``index.json`` of a complete run (an interrupted run or ``--count``
    extension is refused); raises :class:`InputError` naming the file otherwise. ``max_lobes``: K
    of the padded ``sg`` tensor (a sample with more lobes is an error naming it). ``check``: before
    reading a sample, check its files against its manifest (sizes and SHA-256,
    :func:`.store.check_sample`), so that a damaged file is refused by name instead of being used.
    """

    def __init__(self, root: str | Path, max_lobes: int | None = None, check: bool = True):
        self.root = Path(root)
        self.check = check
        finish = (
            f"generate the data set with 'ebr generate ... --out {self.root}' (or finish it with --resume)"
        )
        self.dataset = store.read_doc(self.root / store.DATASET_JSON, store.DATASET_FORMAT, finish)
        self.index = store.read_doc(self.root / store.INDEX_JSON, store.INDEX_FORMAT, finish)
        wanted, have = self.dataset.get("count"), self.index.get("count")
        entries = self.index.get("samples")
        if not isinstance(entries, list) or have != len(entries):
            raise InputError(
                f"{self.root / store.INDEX_JSON}: 'count' does not match its samples; "
                f"the file is damaged: {finish}"
            )
        if wanted != have:
            raise InputError(
                f"{self.root}: dataset.json asks for {wanted} samples but index.json lists "
                f"{have} (an interrupted --count extension); finish it with 'ebr generate ... "
                f"--out {self.root} --count {wanted} --resume'"
            )
        if self.index.get("fingerprint") != self.dataset.get("fingerprint"):
            raise InputError(
                f"{self.root / store.INDEX_JSON}: its fingerprint differs from dataset.json's; "
                f"the data set is damaged: {finish}"
            )
        lay = self.dataset["layout"]
        self.shot_names = list(lay["photos"])
        self.flash_only_names = list(lay["flash_only"])
        self.size = tuple(int(v) for v in self.dataset["resolution"])
        if max_lobes is None:
            max_lobes = max((int(e["lobes"]) for e in self.index["samples"]), default=0)
        self.max_lobes = int(max_lobes)

    def __len__(self) -> int:
        return int(self.index["count"])

    def __getitem__(self, i: int) -> dict:
        if not 0 <= i < len(self):
            raise IndexError(f"sample {i} out of range [0, {len(self)})")
        if self.check:
            store.check_sample(self.root, self.dataset, i, self.index["samples"][i])
        s = store.load_sample(self.root, self.dataset, i)
        env = s["env"]
        if env.num_lobes > self.max_lobes:
            raise InputError(
                f"{self.root / store.sample_dirname(i)}: {env.num_lobes} SG lobes > max_lobes "
                f"{self.max_lobes}; raise max_lobes"
            )
        sg = np.zeros((self.max_lobes, 7), np.float32)
        sg[: env.num_lobes, :3] = env.axis
        sg[: env.num_lobes, 3] = env.sharpness
        sg[: env.num_lobes, 4:] = env.amplitude
        mask = np.zeros(self.max_lobes, np.float32)
        mask[: env.num_lobes] = 1.0
        maps = s["maps"]
        stacked = np.concatenate(
            [maps["normal"], maps["diffuse"], maps["specular"], maps["roughness"][..., None]], axis=-1
        ).transpose(2, 0, 1)
        cam = s["meta"]["camera"]
        return {
            "photos": _chw([s["photos"][n] for n in self.shot_names], self.size),
            "flash_only": _chw([s["flash_only"][n] for n in self.flash_only_names], self.size),
            "env_exemplars": _chw(s["env_exemplars"], self.size),
            "point_exemplars": _chw(s["point_exemplars"], self.size),
            "maps": torch.from_numpy(np.ascontiguousarray(stacked, dtype=np.float32)),
            "sg": torch.from_numpy(sg),
            "sg_mask": torch.from_numpy(mask),
            "exposure": torch.tensor(float(cam["exposure"]), dtype=torch.float32),
            "white_balance": torch.tensor(cam["white_balance"], dtype=torch.float32),
            "index": torch.tensor(i, dtype=torch.int64),
        }
