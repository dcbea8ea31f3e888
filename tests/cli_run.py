"""Running ``ebr estimate`` in-process and reading what it printed (or refused), for the tests of
the estimates that read a capture directory (test_estimate_views, test_fivelight)."""

from __future__ import annotations

import json
from pathlib import Path

from ebr_mitsuba.cli import main


def estimate_json(capsys, *args) -> tuple[int, dict | None, str]:
    """``ebr estimate ARGS --json``: (exit code, the printed summary when it succeeded, stderr)."""
    code = main(["estimate", *map(str, args), "--json"])
    captured = capsys.readouterr()
    return code, (json.loads(captured.out) if code == 0 else None), captured.err


def nonblank_lines(text: str) -> list[str]:
    """The lines of ``text`` that are not blank."""
    return [line for line in text.splitlines() if line.strip()]


def assert_each_refused(capsys, cases: dict, argv, out_root: Path) -> None:
    """Every case of ``cases`` (name → (inputs, text in the error)) refused by ``ebr estimate
    ARGV(inputs) --out out_root/NAME``: exit code 2, one line holding the text, nothing written
    (no temporary directories either)."""
    for name, (inputs, text) in cases.items():
        out = out_root / name.replace(" ", "_")
        code, _, err = estimate_json(capsys, *argv(inputs), "--out", out)
        assert code == 2, (name, err)
        lines = nonblank_lines(err)
        assert len(lines) == 1 and text in lines[0], (name, err)
        assert not out.exists(), name
    leftovers = list(out_root.iterdir()) if out_root.exists() else []
    assert leftovers == []  # no temporary directories either
