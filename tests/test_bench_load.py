"""The benchmarks' statement of the machine's load (ebr_mitsuba.bench._common.OtherLoad): other
processes' CPU time, not the benchmark's own (the load average counts both)."""

from __future__ import annotations

import os
import sys

import pytest

from ebr_mitsuba.bench import _common
from ebr_mitsuba.bench._common import QUIET_CORES, OtherLoad, load_sentence, other_cores


def test_other_cores_subtracts_our_own_time():
    assert other_cores(busy=10.0, own=8.0, wall=4.0) == pytest.approx(0.5)
    assert other_cores(busy=3.0, own=3.5, wall=2.0) == 0.0  # tick rounding: never negative
    assert other_cores(busy=1.0, own=0.0, wall=0.0) == 0.0


def test_sentence_says_quiet_or_shared():
    assert "quiet machine" in load_sentence(QUIET_CORES / 2)
    shared = load_sentence(1.5)
    assert "1.50 cores" in shared and "rerun on a quiet one" in shared
    assert "not measured" in load_sentence(None)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/stat is Linux's")
def test_own_busy_work_is_not_counted_as_others(monkeypatch):
    """Our own CPU time (here a busy loop) comes off the machine's busy time: with a fake /proc/stat
    that advances exactly by our own time, the other processes' share is zero."""
    base = _common._busy_seconds()
    assert base is not None and base > 0
    start_own = _common._own_seconds()
    monkeypatch.setattr(_common, "_busy_seconds", lambda: base + (_common._own_seconds() - start_own))
    load = OtherLoad()
    x = 0
    for i in range(300_000):
        x += i * i
    assert load.cores() == pytest.approx(0.0, abs=1e-9)
    # a waited-for child's CPU time is ours as well
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)
    assert load.cores() == pytest.approx(0.0, abs=1e-9)
