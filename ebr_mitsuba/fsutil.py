"""Atomic file and directory output: nothing half-written ever appears under its final name."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _public(path: Path, directory: bool) -> None:
    """mkstemp/mkdtemp create private (0600/0700) entries; give them the usual umask mode."""
    os.chmod(path, (0o777 if directory else 0o666) & ~_umask())


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    The temporary name keeps the file's suffix so writers that dispatch on it still work.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.stem}.", suffix=path.suffix + ".tmp" + path.suffix, dir=path.parent
    )
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        if tmp.exists():
            _public(tmp, directory=False)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, overwrite: bool = True):
    """Build a directory under a temporary name and move it to ``path`` when the block succeeds.

    On failure the temporary directory is removed and ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    try:
        yield tmp
        _public(tmp, directory=True)
        if path.exists():
            if not overwrite:
                raise FileExistsError(path)
            backup = path.with_name(f".{path.name}.old")
            if backup.exists():
                shutil.rmtree(backup)
            os.replace(path, backup)
            os.replace(tmp, path)
            shutil.rmtree(backup, ignore_errors=True)
        else:
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


# -- stale temporaries -------------------------------------------------------------------------------


def is_temporary(name: str) -> bool:
    """Whether ``name`` is one of :func:`atomic_path`'s (``.stem.XXXX.ext.tmp.ext``) or
    :func:`atomic_dir`'s (``.name.XXXX.partial``, ``.name.old``) temporary names."""
    return name.startswith(".") and (".tmp." in name or name.endswith((".partial", ".old")))


def remove_stale_temporaries(directory: str | os.PathLike, recursive: bool = True) -> int:
    """Delete the temporaries a killed writer left under ``directory``; returns how many.

    Call it only while holding the directory's :func:`output_lock`: a live writer's temporaries
    look the same."""
    directory = Path(directory)
    if not directory.is_dir():
        return 0
    candidates = directory.rglob(".*") if recursive else directory.glob(".*")
    found = [p for p in candidates if is_temporary(p.name)]
    for p in found:
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    return len(found)


# -- one writer per output -----------------------------------------------------------------------------


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file of output ``path``: ``.NAME.lock`` beside it (the output itself may be replaced
    whole by :func:`atomic_dir`, so the lock cannot live inside it)."""
    path = Path(path).absolute()
    return path.parent / f".{path.name}.lock"


class OutputLock:
    """An advisory, exclusive lock on an output file or directory (``fcntl.flock`` on
    :func:`lock_path`), taken without waiting.

    The kernel drops a ``flock`` when its holder dies, however it dies (SIGKILL included), so a
    killed run never leaves a stale lock: the lock file may stay behind, but the next run takes it.
    :meth:`release` deletes the file; :meth:`acquire` re-checks that the file it locked is still the
    one at the path, so a deletion racing with a new holder cannot give two holders.
    ``what`` (e.g. ``"ebr generate"``) is written into the file for the refusal message. Like a
    file object, a lock no longer referenced is released: keep the object while writing.
    """

    def __init__(self, path: str | os.PathLike, what: str = "ebr"):
        self.path = Path(path)
        self.file = lock_path(path)
        self.what = what
        self._fd: int | None = None

    def acquire(self) -> OutputLock:
        import fcntl

        from .errors import BusyError

        if self._fd is not None:
            return self
        self.file.parent.mkdir(parents=True, exist_ok=True)
        while True:
            fd = os.open(self.file, os.O_RDWR | os.O_CREAT, 0o666 & ~_umask())
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                try:
                    holder = os.read(fd, 200).decode("utf-8", "replace").strip() or "another process"
                finally:
                    os.close(fd)
                raise BusyError(
                    f"{self.path}: in use by {holder} (lock {self.file}); wait for it to finish or "
                    f"choose another output"
                ) from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.file).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)  # the holder before us deleted it after we opened it: lock the new one
        os.ftruncate(fd, 0)
        os.write(fd, f"{self.what} (pid {os.getpid()})".encode())
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            self.file.unlink(missing_ok=True)  # while still holding it (see acquire)
        finally:
            os.close(fd)

    def __del__(self) -> None:  # an abandoned holder; the kernel drops it at exit anyway
        try:
            self.release()
        except Exception:
            pass

    def __enter__(self) -> OutputLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def output_lock(path: str | os.PathLike, what: str = "ebr") -> OutputLock:
    """``with output_lock(out, "ebr estimate"):`` — one writer per output; a second process is
    refused at once with :class:`~ebr_mitsuba.errors.BusyError` (exit 2, one line)."""
    return OutputLock(path, what)


# -- termination ---------------------------------------------------------------------------------------


class Terminated(SystemExit):
    """Raised in the main thread by :func:`sigterm_as_exit`'s handler (exit code 128 + 15)."""


@contextlib.contextmanager
def sigterm_as_exit(message: str | None = None):
    """Turn SIGTERM into a :class:`Terminated` exception in the main thread for the block, so that
    ``finally`` clauses run: atomic writes remove their temporaries, pools stop their workers,
    locks are released. (Python's default SIGTERM action ends the process without any of that.)
    ``message`` is printed on stderr when the signal arrives. Outside the main thread (where
    handlers cannot be installed) it does nothing."""
    import signal
    import sys
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_DFL)  # a second SIGTERM ends the process at once
        if message:
            print(message, file=sys.stderr)
        raise Terminated(128 + signal.SIGTERM)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
