"""The worker protocol of ``ebr generate``: how a process that makes samples is set up and run.

Every backend runs the same ``make(plan, index, root) -> Path`` (``make_sample`` of
:mod:`.generate`, a module-level function, so that it pickles by name) in a process set up by
:func:`setup_process` — the variant and one Dr.Jit thread, which makes the renders bit-identical
whichever worker makes a sample (the fast renderer's scatter-adds depend on the thread count):

==========================  ===================================================================
backend                     what runs where
==========================  ===================================================================
:func:`run_in_process`      this process, Dr.Jit on one thread for the loop (restored after)
:func:`run_pool`            a ``spawn`` pool; each worker set up by :func:`init_pool_worker`
                            (also dies with its parent, :func:`die_with_parent`, and leaves
                            Ctrl-C to it) makes one sample per task, :func:`make_one`
:func:`make_shard`          the body of a Ray task (:mod:`.ray_backend`): sets its process up
                            once, makes a shard of samples in a temporary directory and returns
                            their files (``{relative path: bytes}``) for the driver to write
==========================  ===================================================================

This module imports neither :mod:`.generate` nor :mod:`.ray_backend`; both receive what they run as
arguments.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from . import store

MakeSample = Callable[..., Path]
"""``make(plan, index, root) -> Path``: make sample ``index`` under ``root``; returns its directory."""

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
WATCHDOG_SECONDS = 1.0

_STATE: dict = {}
"""This worker process's set-up: ``variant``; in a pool worker also ``make``, ``plan``, ``root``."""


def die_with_parent(parent_pid: int, poll: float = WATCHDOG_SECONDS, use_prctl: bool = True) -> None:
    """Make this (worker) process end when ``parent_pid`` does, however the parent ends (SIGKILL
    included): on Linux the kernel sends SIGKILL at the parent's death (``prctl(PR_SET_PDEATHSIG)``);
    everywhere a daemon thread checks every ``poll`` seconds that the parent is still the parent
    and exits otherwise (the fallback, and the check for a parent that died before the
    ``prctl``). Without this a pool's workers, and multiprocessing's resource tracker that waits for
    them, outlive a killed ``ebr generate`` for as long as their current sample takes.
    ``use_prctl=False`` leaves the watchdog alone (to test it)."""
    import signal
    import sys
    import threading

    if use_prctl and sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # pragma: no cover - not glibc: the watchdog remains
            pass
    if os.getppid() != parent_pid:
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(poll)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="ebr-parent-watchdog", daemon=True).start()


def setup_process(variant: str, parent_pid: int | None = None) -> None:
    """Per-process set-up of a worker: the variant and one Dr.Jit thread; a pool worker
    (``parent_pid`` given) also dies with its parent (:func:`die_with_parent`) and leaves Ctrl-C
    to it (the parent stops the pool). Ray manages its own workers."""
    import signal

    import drjit as dr

    from ..variant import ensure_variant

    if parent_pid is not None:
        die_with_parent(parent_pid)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    ensure_variant(variant)
    dr.set_thread_count(1)
    _STATE["variant"] = variant


def init_pool_worker(variant: str, make: MakeSample, plan, root: str, parent_pid: int) -> None:
    """The pool's initializer: :func:`setup_process`, then what :func:`make_one` makes."""
    setup_process(variant, parent_pid)
    _STATE.update(make=make, plan=plan, root=Path(root))


def make_one(index: int) -> int:
    """A pool task: make sample ``index`` (the worker set up by :func:`init_pool_worker`)."""
    _STATE["make"](_STATE["plan"], index, _STATE["root"])
    return index


def make_shard(variant: str, make: MakeSample, plan, indices: list[int]) -> list[tuple[int, dict]]:
    """A Ray task: make ``indices`` in a temporary directory and return ``[(index, files)]``
    (:func:`.store.read_files`); the process is set up on its first task."""
    if _STATE.get("variant") != variant:
        setup_process(variant)
    out = []
    with tempfile.TemporaryDirectory(prefix="ebr-ray-") as tmp:
        for index in indices:
            directory = make(plan, index, Path(tmp))
            out.append((index, store.read_files(directory)))
    return out


def run_in_process(make: MakeSample, plan, root: Path, todo: list[int], tick) -> None:
    """Make ``todo`` here, one after the other; ``tick()`` per sample."""
    import drjit as dr

    threads = dr.thread_count()
    dr.set_thread_count(1)
    try:
        for index in todo:
            make(plan, index, root)
            tick()
    finally:
        dr.set_thread_count(threads)


def stop_workers(timeout: float = 5.0) -> None:
    """Terminate (then kill) this process's multiprocessing children: the pool's workers."""
    import multiprocessing as mp

    children = mp.active_children()
    for p in children:
        p.terminate()
    deadline = time.monotonic() + timeout
    for p in children:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(1.0)


def _quiet_broken_pool_report() -> None:
    """Python 3.11's executor thread, seeing the workers we stop, tries to fail futures we have
    already cancelled and dies with an ``InvalidStateError`` traceback on stderr (fixed in later
    Pythons): the stop is ours and already reported in one line, so that report is dropped."""
    import threading
    from concurrent.futures import InvalidStateError

    previous = threading.excepthook

    def hook(args):
        if args.exc_type is not None and issubclass(args.exc_type, InvalidStateError):
            return
        previous(args)

    threading.excepthook = hook


def run_pool(make: MakeSample, plan, root: Path, todo: list[int], workers: int, tick) -> None:
    """Make ``todo`` in a ``spawn`` pool of ``workers`` processes; ``tick()`` per sample.

    ``ProcessPoolExecutor`` (not ``multiprocessing.Pool``): a worker that dies or fails its set-up
    breaks the pool with an error instead of being respawned forever. Workers die with this process
    (:func:`die_with_parent`); on any exception here (a worker's error, Ctrl-C, SIGTERM turned into
    an exception by the CLI) they are terminated at once instead of finishing their current sample,
    and their half-written samples are removed (the caller holds the lock of ``root``)."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_EXCEPTION, ProcessPoolExecutor, wait

    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(
        workers,
        mp_context=ctx,
        initializer=init_pool_worker,
        initargs=(plan.variant, make, plan, str(root), os.getpid()),
    ) as pool:
        pending = {pool.submit(make_one, index) for index in todo}
        try:
            while pending:
                done, pending = wait(pending, return_when=FIRST_EXCEPTION)
                for future in done:
                    future.result()  # re-raises a worker's exception here
                    tick()
        except BaseException:
            _quiet_broken_pool_report()
            for future in pending:
                future.cancel()
            stop_workers()
            store.remove_partials(root)
            raise


__all__ = [
    "MakeSample",
    "die_with_parent",
    "init_pool_worker",
    "make_one",
    "make_shard",
    "run_in_process",
    "run_pool",
    "setup_process",
    "stop_workers",
]
