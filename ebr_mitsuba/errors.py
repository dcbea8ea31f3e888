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
