"""The one kind of error that means "bad input": the command line prints it as one line, exit 2.

Every module that validates what a user gives it (a sequence folder, a box, a
results folder, a command-line value) raises a subclass of :class:`InputError`.
Anything else that escapes a command — a ``ValueError`` raised by a tracker in
the middle of a run included — is a bug: the command line shows its traceback
and exits 1.
"""

from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input from a user; the message says what to fix (printed as one line, exit code 2)."""
