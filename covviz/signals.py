"""Stop signals: Ctrl-C (SIGINT) and SIGTERM end a run the same way, and only once.

The command line runs inside :func:`stop_signals`. The first SIGINT or SIGTERM
raises :class:`Interrupted` (a ``KeyboardInterrupt``, so everything that
handles Ctrl-C handles both) and its exit code is 128 + the signal number: 130
for Ctrl-C, 143 for SIGTERM (``kill PID``, ``timeout``, a CI cancel, a service
stop). Every later signal is only reported: it never interrupts the saving that
the first one started (two Ctrl-Cs 20 ms apart used to lose the results).

While the results of a run are being written (:func:`shielded`, used by the
runner around the observers' ``on_end``) a first signal is held back, and
raised when the writing is done. SIGKILL cannot be caught: what survives it is
what the run had already written (see :mod:`covviz.experiments.results` and the README).

A signal handler's exception is lost when the signal lands while C code has
called back into Python: numba compiling a kernel calls llvmlite's object-cache
callback through ctypes, which prints "Exception ignored" and goes on, so the
run carried on as if the Ctrl-C had never come, or numba failed later with "no
compiled object yet" (seen in CI on a cold cache). Two guards:

- A first signal that lands in llvmlite's code is not raised there: it is sent
  again :data:`RESEND_S` later, when Python is back in ordinary code (at most
  :data:`MAX_RESENDS` times, then it is raised wherever it lands).
- Any other lost :class:`Interrupted` is caught in ``sys.unraisablehook``,
  silently, and :func:`check` raises it at the next safe point (the runner
  checks every frame, the bench after compiling and after every job); one still
  lost when the command ends is raised there.

Outside :func:`stop_signals` (library use, tests), nothing changes: Python's
own Ctrl-C handling applies and :func:`shielded` does nothing.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator

__all__ = ["Interrupted", "check", "exit_code", "shielded", "stop_signals"]

log = logging.getLogger("covviz")

#: The signals that stop a run.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
#: A first signal landing in llvmlite's code is sent again this much later (seconds) ...
RESEND_S = 0.05
#: ... at most this many times in a row (then it is raised where it lands).
MAX_RESENDS = 100


class Interrupted(KeyboardInterrupt):
    """A stop signal, raised in the main thread; ``exit_code`` is 128 + the signal number."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)
        self.exit_code = 128 + int(signum)


def exit_code(exc: BaseException) -> int:
    """The exit code of an interruption: 143 for SIGTERM, 130 for Ctrl-C (and a bare KeyboardInterrupt)."""
    return getattr(exc, "exit_code", 128 + signal.SIGINT)


class _State:
    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.active = False
        self.first: int | None = None  # the signal that stopped the run
        self.pending: int | None = None  # a first signal held back while shielded
        self.shield = 0
        self.told = False
        self.lost: int | None = None  # a raised signal that C code swallowed (see the module docstring)
        self.resends = 0


_state = _State()


def _in_llvmlite(frame) -> bool:
    """Whether the Python stack at ``frame`` runs llvmlite's code (its ctypes callbacks among it)."""
    while frame is not None:
        if f"{os.sep}llvmlite{os.sep}" in frame.f_code.co_filename:
            return True
        frame = frame.f_back
    return False


def _handler(signum, frame) -> None:
    s = _state
    if s.first is None and s.pending is None:
        if s.resends < MAX_RESENDS and _in_llvmlite(frame):
            s.resends += 1
            timer = threading.Timer(RESEND_S, os.kill, (os.getpid(), signum))
            timer.daemon = True
            timer.start()
            return
        if s.shield:
            s.pending = signum
            log.warning("%s: stopping as soon as the results are written", signal.Signals(signum).name)
            return
        s.first = signum
        raise Interrupted(signum)
    if not s.told:
        s.told = True
        log.warning("already stopping: writing the results of the frames done (kill -9 abandons them)")


def _unraisable(hook):
    """A ``sys.unraisablehook`` that keeps a swallowed :class:`Interrupted` for :func:`check`, others to ``hook``."""

    def unraisable(info) -> None:
        if isinstance(info.exc_value, Interrupted) and _state.active:
            _state.lost = info.exc_value.signum
            return
        hook(info)

    return unraisable


def check() -> None:
    """Raise the stop signal that C code swallowed, if any (a safe point; a no-op otherwise)."""
    s = _state
    if s.lost is not None and threading.current_thread() is threading.main_thread():
        signum, s.lost = s.lost, None
        raise Interrupted(signum)


@contextlib.contextmanager
def stop_signals() -> Iterator[None]:
    """Handle SIGINT and SIGTERM as described in the module docstring, then restore the old handlers.

    Only the main thread can set signal handlers; elsewhere this does nothing.
    After a stop signal the process is stopping: the handlers are not restored,
    and SIGINT and SIGTERM are ignored from then on.
    """
    if threading.current_thread() is not threading.main_thread() or _state.active:
        yield
        return
    old = {s: signal.signal(s, _handler) for s in STOP_SIGNALS}
    old_hook = sys.unraisablehook
    sys.unraisablehook = _unraisable(old_hook)
    _state.reset()
    _state.active = True
    try:
        yield
        check()  # the command finished, but a Ctrl-C came and was lost on the way: it still counts
    finally:
        sys.unraisablehook = old_hook
        _state.active = False
        stopping = _state.first is not None or _state.pending is not None
        for s, h in old.items():
            # The process is stopping: a later signal must not kill it while the interpreter shuts
            # down (Python then puts its handlers back to SIG_DFL, and a second Ctrl-C 50 ms after
            # the first ended the process by SIGINT after the results were saved). Ignored
            # signals stay ignored through the shutdown.
            signal.signal(s, signal.SIG_IGN if stopping else h)
        _state.reset()


@contextlib.contextmanager
def shielded() -> Iterator[None]:
    """Hold back a first stop signal while the block runs (writing results); raise it afterwards.

    If the block raises, its exception wins and the held-back signal is dropped
    (the run stops anyway). Nested blocks raise once, at the outermost one.
    """
    s = _state
    if not s.active or threading.current_thread() is not threading.main_thread():
        yield
        return
    s.shield += 1
    ok = False
    try:
        yield
        ok = True
    finally:
        s.shield -= 1
        if s.shield == 0 and s.pending is not None:
            signum, s.pending = s.pending, None
            s.first = signum
            if ok:
                raise Interrupted(signum)
