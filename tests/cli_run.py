"""Running ``ebr estimate`` in-process and reading what it printed, for the tests of the estimates
that read a capture directory (test_estimate_views, test_fivelight)."""

from __future__ import annotations

import json

from ebr_mitsuba.cli import main


def estimate_json(capsys, *args) -> tuple[int, dict | None, str]:
    """``ebr estimate ARGS --json``: (exit code, the printed summary when it succeeded, stderr)."""
    code = main(["estimate", *map(str, args), "--json"])
    captured = capsys.readouterr()
    return code, (json.loads(captured.out) if code == 0 else None), captured.err


def nonblank_lines(text: str) -> list[str]:
    """The lines of ``text`` that are not blank."""
    return [line for line in text.splitlines() if line.strip()]
