"""The torch device a model runs on (:func:`pick_device`): the one place that chooses it."""

from __future__ import annotations

import torch

from ..errors import InputError


def pick_device(name: str = "auto") -> torch.device:
    """``auto``: CUDA when present, else CPU."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError("device 'cuda' requested but torch sees no CUDA device; use 'auto' or 'cpu'")
    return torch.device(name)


__all__ = ["pick_device"]
