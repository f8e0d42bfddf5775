"""The tracking loop: frames in, boxes and records out, observers informed.

``run(tracker, sequence, observers)`` initialises the tracker on the first
frame, calls ``update`` on every later frame, times each call, and hands the
tracker's :class:`~covviz.records.FrameRecord` with the :class:`Frame` to every
observer. Observers are plain objects with any of the methods
``on_start(sequence, tracker)``, ``on_frame(frame, record)`` and
``on_end(result)``; the core never imports them.

A Ctrl-C or an exception inside the tracker stops the loop; observers still get
``on_end`` with the frames done so far (``result.interrupted`` is True), so a
recording holds every frame logged before the interruption. The exception is
then re-raised. Every observer gets its ``on_end`` even if another one's fails,
and a stop signal that arrives meanwhile waits until they are done
(:func:`covviz.signals.shielded`).

An observer that keeps files up to date while the run goes (the results
writer, :class:`covviz.experiments.results.ResultWriter`) also has ``on_progress(results)``
and a ``progress_seconds`` period: the runner calls it with the results of the
frames done so far (``interrupted`` True) at most that often.
"""

from __future__ import annotations

import logging
import queue
import shutil
import sys
import threading
import time
from collections.abc import Iterable
from collections.abc import Sequence as Seq

import numpy as np

from covviz.data.frames import Frame, Sequence
from covviz.errors import WriteError
from covviz.records import FrameRecord, RunResult
from covviz.signals import shielded

log = logging.getLogger("covviz")

__all__ = ["BackgroundObserver", "FreeSpaceGuard", "Observer", "ResultCollector", "run", "run_many"]


class Observer:
    """Base class for observers (all methods optional)."""

    def on_start(self, sequence: Sequence, trackers: Seq) -> None:  # pragma: no cover - interface
        pass

    def on_frame(self, frame: Frame, records: Seq[FrameRecord]) -> None:  # pragma: no cover
        pass

    def on_end(self, results: Seq[RunResult]) -> None:  # pragma: no cover
        pass


class ResultCollector(Observer):
    """Keeps the results handed to ``on_end`` (also after an interruption)."""

    def __init__(self) -> None:
        self.results: list[RunResult] = []

    def on_end(self, results: Seq[RunResult]) -> None:
        self.results = list(results)


class BackgroundObserver(Observer):
    """Runs another observer's ``on_frame`` on a worker thread, behind a bounded queue.

    Tracking goes on while the previous frames are being logged, so an
    observer's cost overlaps the tracker's instead of adding to it. Records and
    frames are never mutated after they are handed over, so nothing is copied.
    ``on_end`` waits until every queued frame is done (an interrupted run keeps
    all of them), then calls the wrapped ``on_end``. An exception in the worker
    is raised again in the tracking thread at the next call.

    Parameters
    ----------
    observer : object
        Any observer (``on_start``/``on_frame``/``on_end``, all optional).
    maxsize : int
        Frames that may wait in the queue (bounds memory; the tracker blocks
        when the observer is that far behind).
    """

    _STOP = object()

    def __init__(self, observer, maxsize: int = 8) -> None:
        self.observer = observer
        self._queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self._error: BaseException | None = None
        self._thread: threading.Thread | None = None

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            try:
                if item is self._STOP:
                    return
                if self._error is None:
                    self.observer.on_frame(*item)
            except BaseException as exc:  # noqa: BLE001 - handed to the tracking thread
                self._error = exc
            finally:
                self._queue.task_done()

    def _raise(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            raise err

    def on_start(self, sequence, trackers) -> None:
        if hasattr(self.observer, "on_start"):
            self.observer.on_start(sequence, trackers)
        if hasattr(self.observer, "on_frame"):
            self._thread = threading.Thread(target=self._work, name="covviz-observer", daemon=True)
            self._thread.start()

    def on_frame(self, frame, records) -> None:
        self._raise()
        if self._thread is not None:
            self._queue.put((frame, records))

    def on_end(self, results) -> None:
        if self._thread is not None:
            self._queue.put(self._STOP)
            self._thread.join()
            self._thread = None
        try:
            self._raise()
        finally:
            if hasattr(self.observer, "on_end"):
                self.observer.on_end(results)


class FreeSpaceGuard(Observer):
    """Stops a run while the disk under its files still has room to finish them.

    A recording needs room at the end for its footer (a manifest of every chunk,
    ~3% of the file) and for the batches still in memory; a results file for
    its last write. Every ``progress_seconds`` the guard compares the free
    space of each path's file system with ``reserve_bytes`` plus
    ``footer_share`` of the file's size so far, and raises
    :class:`~covviz.errors.WriteError` (the run stops, its files are finished
    and readable) when there is less.

    Parameters
    ----------
    paths : iterable of path
        Files (or folders) the run writes.
    reserve_bytes : int
    footer_share : float
    progress_seconds : float
    """

    def __init__(self, paths, reserve_bytes: int = 8_000_000, footer_share: float = 0.05,
                 progress_seconds: float = 1.0) -> None:
        from pathlib import Path

        self.paths = [Path(p) for p in paths]
        self.reserve_bytes = int(reserve_bytes)
        self.footer_share = float(footer_share)
        self.progress_seconds = float(progress_seconds)

    def on_progress(self, results) -> None:
        for p in self.paths:
            folder = p if p.is_dir() else p.parent
            try:
                free = shutil.disk_usage(folder).free
                size = p.stat().st_size if p.is_file() else 0
            except OSError:
                continue  # a folder that went away: the writes will say so
            need = self.reserve_bytes + self.footer_share * size
            if free < need:
                raise WriteError(
                    f"the disk of {p} is {'full' if free < 1e6 else 'almost full'} ({free / 1e6:.1f} MB free, "
                    f"{need / 1e6:.0f} MB kept to finish the files): the run stopped; free some space, or write "
                    "elsewhere (--out, --save)"
                )


def _progress(total: int, desc: str, enabled: bool):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", file=sys.stderr, dynamic_ncols=True, leave=False)


def run_many(
    trackers: Seq,
    sequence: Sequence,
    observers: Iterable = (),
    max_frames: int | None = None,
    progress: bool = False,
    seeds: Seq[int | None] | None = None,
) -> list[RunResult]:
    """Run several trackers side by side on the same frames (each frame read once).

    Parameters
    ----------
    trackers : sequence of Tracker
    sequence : Sequence
    observers : iterable
        Objects with optional ``on_start(sequence, trackers)``,
        ``on_frame(frame, records)`` (one record per tracker, in order),
        ``on_progress(results)`` (with a ``progress_seconds`` period: the
        results so far, marked interrupted) and ``on_end(results)``.
    max_frames : int, optional
        Stop after this many frames (including the first).
    progress : bool
        Show a progress bar on stderr.
    seeds : sequence of int, optional
        Seeds to write into the results (one per tracker).

    Returns
    -------
    list of RunResult, one per tracker.
    """
    observers = list(observers)
    n = len(sequence) if max_frames is None else min(len(sequence), int(max_frames))
    if n < 1:
        raise ValueError("nothing to track: the sequence has no frames (or --max-frames is 0)")
    k = len(trackers)
    boxes = np.full((k, n, 4), np.nan)
    times = np.zeros((k, n))
    gt = np.full((n, 4), np.nan)
    seeds = list(seeds) if seeds is not None else [None] * k
    done = 0
    interrupted = False
    stopped_by: BaseException | None = None

    def results_so_far(stopped: bool) -> list[RunResult]:
        return [
            RunResult(
                sequence=sequence.name,
                tracker=tr.name,
                seed=seeds[j],
                boxes=boxes[j, :done],
                times=times[j, :done],
                groundtruth=gt[:done],
                config=tr.config_dict() if hasattr(tr, "config_dict") else {},
                interrupted=stopped,
            )
            for j, tr in enumerate(trackers)
        ]

    # Observers that want the results so far, each with its own period (a monotonic deadline).
    periodic = [[ob, time.monotonic() + float(ob.progress_seconds)] for ob in observers
                if hasattr(ob, "on_progress")]
    bar = None
    started = []
    try:
        # A stop signal while the observers start (the recorder opening its file) waits until
        # they all have, so that each of them also gets its on_end.
        with shielded():
            for ob in observers:
                if hasattr(ob, "on_start"):
                    ob.on_start(sequence, trackers)
                started.append(ob)
        bar = _progress(n, f"{sequence.name}", progress)
        for i in range(n):
            frame = sequence.frame(i)
            if frame.gt is not None:
                gt[i] = frame.gt
            records = []
            for j, tr in enumerate(trackers):
                t0 = time.perf_counter()
                if i == 0:
                    tr.init(frame.image, sequence.init_box)
                    box = np.asarray(sequence.init_box, dtype=np.float64)
                else:
                    box = np.asarray(tr.update(frame.image), dtype=np.float64)
                times[j, i] = time.perf_counter() - t0
                boxes[j, i] = box
                rec = tr.last_record
                if rec is None:
                    rec = FrameRecord(index=i, box=box, tracker=tr.name)
                records.append(rec)
            # A frame counts as done once every observer has it: a stop signal while one waits
            # (the recorder's queue full) is held until then, so the recording and the results
            # end on the same frame.
            with shielded():
                done = i + 1
                for ob in observers:
                    if hasattr(ob, "on_frame"):
                        ob.on_frame(frame, records)
            if periodic:
                now = time.monotonic()
                partial = None
                for due in periodic:
                    if now >= due[1]:
                        partial = partial or results_so_far(stopped=True)
                        due[0].on_progress(partial)
                        due[1] = time.monotonic() + float(due[0].progress_seconds)
            if bar is not None:
                bar.update(1)
                if i % 10 == 0:
                    tot = times[:, 1 : i + 1].sum()
                    if tot > 0:
                        bar.set_postfix(fps=f"{k * i / tot:.0f}")
    except BaseException as exc:
        interrupted = True
        stopped_by = exc
        raise
    finally:
        if bar is not None:
            bar.close()
        results = results_so_far(interrupted)
        _end(started, results, failing=stopped_by if interrupted else None)
    return results


def _end(observers, results, failing: BaseException | None) -> None:
    """Every observer's ``on_end``, even when one fails; a stop signal waits until they are done.

    The first failure is raised afterwards, unless the run is already failing (``failing``, the
    exception that stopped it): then that exception goes on, with the observers' failures added
    as notes (``add_note``: a traceback shows them; the command line words them its own way).
    """
    errors: list[BaseException] = []
    with shielded():
        for ob in observers:
            if hasattr(ob, "on_end"):
                try:
                    ob.on_end(results)
                except BaseException as exc:  # noqa: BLE001 - the others still get theirs
                    errors.append(exc)
    if not errors:
        return
    if failing is not None:
        for exc in errors:
            failing.add_note(f"{type(exc).__name__}: {exc}")
        return
    raise errors[0]


def run(tracker, sequence: Sequence, observers: Iterable = (), max_frames=None, progress=False, seed=None):
    """Run one tracker over a sequence; see :func:`run_many`. Returns a :class:`RunResult`."""
    return run_many([tracker], sequence, observers, max_frames, progress, seeds=[seed])[0]
