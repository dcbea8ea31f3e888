"""Exception types of ebr-mitsuba.

Every error a user can cause derives from :class:`EbrError`; its message is one line that names
the file or option at fault and the fix. The CLI turns an ``EbrError`` into that line on stderr
and exit code 2; any other exception is an internal error (exit code 1).
"""

from __future__ import annotations


class EbrError(Exception):
    """Base class of all user-facing errors (CLI exit code 2)."""

    exit_code = 2

    def __init__(self, message: str):
        # Keep messages to one line: the CLI prints exactly this.
        super().__init__(" ".join(str(message).split()))


class InputError(EbrError):
    """A file or value given by the user is missing, unreadable or out of range."""


class ConfigError(EbrError):
    """A configuration file, scene file or option is malformed (unknown key, wrong type, ...)."""


class RuntimeSetupError(EbrError):
    """The machine lacks something the toolkit needs (LLVM runtime, CUDA, optional extra)."""


class BusyError(EbrError):
    """Another process is writing the same output (see :func:`ebr_mitsuba.fsutil.output_lock`)."""


class DiskFullError(EbrError):
    """The file system filled up (or a quota ran out) while writing an output.

    ``path`` is the output being written, ``device`` the mount point holding it; the message says
    both and the fix. Writers leave nothing half-written (:mod:`ebr_mitsuba.fsutil`).
    """

    def __init__(self, path, device: str | None = None):
        import os

        self.path = os.fspath(path)
        self.device = device or mount_point(self.path)
        super().__init__(
            f"no space left on device {self.device} writing {self.path}; free space on "
            f"{self.device} or choose another --out"
        )

    def __reduce__(self):  # pickled across process pools with its fields, not its message
        return (type(self), (self.path, self.device))


_DISK_FULL_TEXT = ("no space left on device", "disk quota exceeded", "file too large")


def is_disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` reports a full file system: ``OSError`` with ``ENOSPC``/``EDQUOT``/``EFBIG``,
    or a library's ``RuntimeError`` quoting that text (OpenEXR, Mitsuba's Bitmap)."""
    import errno

    if isinstance(exc, DiskFullError):
        return True
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        return True
    return isinstance(exc, (OSError, RuntimeError)) and any(t in str(exc).lower() for t in _DISK_FULL_TEXT)


def mount_point(path) -> str:
    """The mount point of the file system that holds (or would hold) ``path``."""
    import os

    p = os.path.abspath(os.fspath(path))
    while not os.path.exists(p) and os.path.dirname(p) != p:
        p = os.path.dirname(p)
    while not os.path.ismount(p):
        p = os.path.dirname(p)
    return p


class reraise_disk_full:  # noqa: N801 - used as a context manager, like contextlib's
    """``with reraise_disk_full(path): ...`` turns a full-disk error inside the block into
    :class:`DiskFullError` naming ``path`` (other exceptions pass unchanged)."""

    def __init__(self, path):
        self.path = path

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc is not None and not isinstance(exc, DiskFullError) and is_disk_full(exc):
            raise DiskFullError(self.path) from exc
        return False
