"""One writer per output: two runs that would write the same file cannot both start.

Two ``covviz track`` runs with the same ``--save`` (or the same ``--out``,
sequence, tracker and seed) would interleave their writes: a recording that no
reader accepts, results that hold the other run's frames. :func:`hold_outputs`
takes an exclusive ``flock`` on a hidden lock file beside each output
(``.covviz-lock-HASH``, a hash of the output's name) for the whole run, and refuses the second run before it
writes anything, with a sentence naming the output and the run that holds it.

The lock goes with the process: a killed run leaves at most the empty lock
file, which the next run takes over. A run that ends removes its lock files.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Iterator
from pathlib import Path

from covviz.errors import InputError

__all__ = ["OutputBusy", "hold_outputs", "lock_path"]


class OutputBusy(InputError):
    """Another process is writing an output of this run; the message names it and what to do."""


def lock_path(output: Path) -> Path:
    """The lock file of ``output``: ``DIR/.covviz-lock-HASH``, a short name whatever the length of ``output``'s."""
    import hashlib

    output = Path(output)
    return output.parent / f".covviz-lock-{hashlib.sha1(os.fsencode(output.name)).hexdigest()[:16]}"


def _take(output: Path, hint: str):
    """Open and ``flock`` the lock file of ``output`` (retrying if a finishing run removed it meanwhile)."""
    import fcntl

    path = lock_path(output)
    while True:
        fh = open(path, "a+")  # noqa: SIM115 - held until released
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            who = fh.read().strip() or "another process"
            fh.close()
            raise OutputBusy(f"another covviz run ({who}) is writing {output}; wait for it to finish, "
                             f"or {hint}") from None
        except BaseException:
            fh.close()
            raise
        try:
            same = os.path.samestat(os.fstat(fh.fileno()), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        fh.close()  # the run before removed the file between our open and our lock: take the new one
    fh.seek(0)
    fh.truncate()
    fh.write(f"pid {os.getpid()}, since {time.strftime('%H:%M:%S')}\n")
    fh.flush()
    return fh, path


@contextlib.contextmanager
def hold_outputs(outputs: list[tuple[Path, str]]) -> Iterator[None]:
    """Hold the lock of every output for the block, or raise :class:`OutputBusy` before any is written.

    Parameters
    ----------
    outputs : list of (path, hint)
        The files the block will write (their folders exist), each with what a
        user can do instead (``"choose another --save"``).
    """
    held = []
    try:
        for output, hint in outputs:
            held.append(_take(Path(output), hint))
        yield
    finally:
        for fh, path in reversed(held):
            with contextlib.suppress(OSError):
                path.unlink()  # while still locked: a waiting run then retries on a new file
            fh.close()
