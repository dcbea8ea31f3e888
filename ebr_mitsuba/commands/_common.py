"""Helpers shared by subcommands: JSON output, progress bars, stderr messages."""

from __future__ import annotations

import json
import sys

from tqdm import tqdm


def emit_json(obj) -> None:
    """Machine-readable summary on stdout."""
    sys.stdout.write(json.dumps(obj, indent=1, default=float) + "\n")
    sys.stdout.flush()


def say(msg: str) -> None:
    """Human output on stderr."""
    print(msg, file=sys.stderr)


def progress(iterable=None, **kwargs):
    """A tqdm progress bar on stderr (silent when stderr is not a terminal and EBR_PROGRESS=0)."""
    kwargs.setdefault("file", sys.stderr)
    kwargs.setdefault("dynamic_ncols", True)
    kwargs.setdefault("leave", False)
    return tqdm(iterable, **kwargs)
