"""Data-parallel training with ``torchrun`` (DDP): gloo on the CPU, NCCL on CUDA.

``torchrun --nproc_per_node 2 -m ebr_mitsuba.cli train CONFIG.toml --out DIR`` starts two
processes; each reads ``RANK``/``WORLD_SIZE``/``LOCAL_RANK`` from the environment, trains on its
share of every batch's samples (rank r takes the permutation's entries r, r + W, …) and averages
gradients through :class:`torch.nn.parallel.DistributedDataParallel`. Rank 0 alone writes
checkpoints, the CSV log and the progress bar; the on-disk caches are filled by all ranks (each
its share) behind a barrier. Without ``WORLD_SIZE`` (or with 1) everything runs in one process.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist


@dataclass(frozen=True)
class DistInfo:
    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        return self.rank == 0

    @property
    def active(self) -> bool:
        return self.world > 1


def init_distributed(device: torch.device) -> DistInfo:
    """Join the process group when launched by ``torchrun`` (``WORLD_SIZE`` > 1).

    On CUDA the group has both backends: NCCL for the gradients on the GPU, gloo for the CPU
    scalars of :func:`all_mean`.
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return DistInfo()
    if not dist.is_initialized():
        dist.init_process_group("cpu:gloo,cuda:nccl" if device.type == "cuda" else "gloo")
    return DistInfo(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", "0")))


def local_device(device: torch.device) -> torch.device:
    """The device of this process: under ``torchrun`` on CUDA, the GPU of ``LOCAL_RANK``."""
    if device.type != "cuda" or int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return device
    local = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    torch.cuda.set_device(local)
    return local


def barrier(info: DistInfo) -> None:
    if info.active:
        dist.barrier()


def share(indices, info: DistInfo) -> list[int]:
    """This rank's share of ``indices``: the entries r, r + W, … (all of them in one process)."""
    return [i for k, i in enumerate(indices) if k % info.world == info.rank]


def wrap(module: torch.nn.Module, info: DistInfo, device: torch.device) -> torch.nn.Module:
    """DDP around ``module`` (its trainable parameters as they are now) when distributed."""
    if not info.active:
        return module
    ids = [device.index] if device.type == "cuda" else None
    return torch.nn.parallel.DistributedDataParallel(module, device_ids=ids, find_unused_parameters=True)


def all_mean(value: float, info: DistInfo) -> float:
    """Mean of a scalar over the ranks (for logging)."""
    if not info.active:
        return value
    t = torch.tensor([value], dtype=torch.float64)
    dist.all_reduce(t)
    return float(t) / info.world


def shutdown(info: DistInfo) -> None:
    if info.active and dist.is_initialized():
        dist.destroy_process_group()


__all__ = ["DistInfo", "all_mean", "barrier", "init_distributed", "local_device", "share", "shutdown", "wrap"]
