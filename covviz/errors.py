"""The one kind of error that means "bad input": the command line prints it as one line, exit 2.

Every module that validates what a user gives it (a sequence folder, a box, a
results folder, a command-line value) raises a subclass of :class:`InputError`.
An output that cannot be written — a full disk, a read-only folder — is the
user's to fix in the same way (free some space, choose another folder), so
:class:`WriteError` is one too. Anything else that escapes a command — a
``ValueError`` raised by a tracker in the middle of a run included — is a bug:
the command line shows its traceback and exits 1.
"""

from __future__ import annotations

import errno
import shutil
from pathlib import Path

__all__ = ["InputError", "WriteError", "free_space"]


class InputError(ValueError):
    """Bad input from a user; the message says what to fix (printed as one line, exit code 2)."""


class WriteError(InputError):
    """A file cannot be written (a full disk, a read-only or missing folder); the message names it."""

    @classmethod
    def from_os_error(cls, path, exc: OSError, hint: str) -> WriteError:
        """One line for an ``OSError`` raised while writing ``path``, ending with ``hint`` (what to do)."""
        name = str(getattr(exc, "filename", None) or path)
        path = Path(name.removesuffix(".part"))  # the file being replaced
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            what = "no space left on the device" if exc.errno == errno.ENOSPC else "disk quota exceeded"
            return cls(f"{what} while writing {path} ({free_space(path)}); free some space, or {hint}")
        return cls(f"cannot write {path}: {exc.strerror or exc}; {hint}")


def free_space(path) -> str:
    """``"12.0 MB free in /mnt/runs"``, for the nearest existing folder of ``path``."""
    p = Path(path)
    while (not p.exists() or not p.is_dir()) and p != p.parent:
        p = p.parent
    try:
        free = shutil.disk_usage(p).free
    except OSError:
        return "free space unknown"
    return f"{free / 1e6:.1f} MB free in {p}"
