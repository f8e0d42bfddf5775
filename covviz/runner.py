"""The tracking loop: frames in, boxes and records out, observers informed in a stated order.

``run(tracker, sequence, observers)`` initialises the tracker on the first
frame, calls ``update`` on every later frame, times each call, and hands the
tracker's :class:`~covviz.records.FrameRecord` with the :class:`Frame` to the
observers. Observers follow the :class:`Observer` protocol (``on_start``,
``on_frame``, ``on_end``) and form a pipeline, in the order they are given:
each is handed the :class:`Findings` of those before it (the drift diagnosis's
evidence, events and diagnoses, for the recorder and the results writer after
it) and may return new findings for those after it. The core never imports them,
and no observer reaches into another's state or asks the tracker anything:
what they know of each tracker (name, config, frozen observation model) comes
once, in :class:`RunStart`, after the trackers' ``init`` on the first frame.

The frames are read and decoded on a background thread, up to ``prefetch``
frames ahead of the trackers (:class:`covviz.data.prefetch.Prefetcher`), in
order: decoding overlaps tracking, the boxes are those of reading in place, and
a frame that cannot be read stops the run at that frame with its own error.

A Ctrl-C or an exception inside the tracker stops the loop; observers still get
``on_end`` with the frames done so far (``result.interrupted`` is True), so a
recording holds every frame logged before the interruption. The exception is
then re-raised. Every observer gets its ``on_end`` even if another one's fails,
and a stop signal that arrives meanwhile waits until they are done
(:func:`covviz.signals.shielded`).

An observer that keeps files up to date while the run goes (the results
writer, :class:`covviz.experiments.results.ResultWriter`) is a
:class:`ProgressObserver`: the runner also calls its ``on_progress(results,
found)`` with the results of the frames done so far (``interrupted`` True) at
most every ``progress_seconds``.
"""

from __future__ import annotations

import logging
import queue
import shutil
import sys
import threading
import time
from collections import deque
from collections.abc import Iterable
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from covviz.data.frames import Frame, Sequence
from covviz.data.prefetch import AHEAD, Prefetcher
from covviz.errors import WriteError
from covviz.records import FrameRecord, RunResult
from covviz.signals import check as check_signals
from covviz.signals import shielded
from covviz.trackers.base import TrackerInfo, tracker_info

log = logging.getLogger("covviz")

__all__ = [
    "NOTHING",
    "BackgroundObserver",
    "CheckpointRing",
    "Findings",
    "FreeSpaceGuard",
    "Observer",
    "Pipeline",
    "ProgressObserver",
    "ResultCollector",
    "RunStart",
    "run",
    "run_many",
]


class CheckpointRing:
    """One tracker's past states, kept in bounded memory: dense for the recent past, sparse further back.

    Every ``every`` frames a state goes into the dense ring (the last ``keep`` of them); every
    ``long_every`` frames also into the sparse one (the last ``long_keep``). The counterfactual
    replays fork a tracker from the newest checkpoint before the frame they start at and replay
    unchanged from there, so a loss far from the end of a long run is still reached. A manifold
    state at ``n`` particles takes about ``n · 87 · 8`` bytes (kinematics and templates): the
    defaults (64 + 64 states) hold ~54 MB at 600 particles and reach back 320 frames densely and
    3200 sparsely.
    """

    def __init__(self, every: int = 5, keep: int = 64, long_every: int = 50, long_keep: int = 64) -> None:
        if min(every, keep, long_every, long_keep) < 1:
            raise ValueError("a checkpoint ring needs every, keep, long_every and long_keep >= 1")
        self.every = int(every)
        self.long_every = int(long_every)
        self._ring: deque = deque(maxlen=int(keep))
        self._sparse: deque = deque(maxlen=int(long_keep))

    def __len__(self) -> int:
        return len(self._ring) + len(self._sparse)

    def due(self, index: int) -> bool:
        """Whether the state after frame ``index`` (0-based) is to be kept."""
        return index % self.every == 0 or index % self.long_every == 0

    def add(self, index: int, state) -> None:
        """The state after frame ``index`` (0-based) was tracked."""
        if index % self.every == 0:
            self._ring.append((int(index), state))
        if index % self.long_every == 0:
            self._sparse.append((int(index), state))

    def at_or_before(self, index: int):
        """``(i, state)`` of the newest checkpoint with ``i <= index``, or None."""
        best = None
        for i, state in (*self._sparse, *self._ring):
            if i <= index and (best is None or i > best[0]):
                best = (i, state)
        return best


@dataclass(frozen=True, slots=True)
class RunStart:
    """What observers are told once, when the run starts (after every tracker's ``init`` on frame 1).

    Attributes
    ----------
    sequence : Sequence
    trackers : tuple of TrackerInfo
        Name, config and frozen observation model of each tracker, in order.
    init_box : ndarray, shape (4,)
        The box every tracker was started at (0-based pixels).
    seeds : tuple of int or None
    n_frames : int
        Frames the run will track (``--max-frames`` applied).
    checkpoints : tuple of CheckpointRing or None
        Per tracker, the states the runner keeps while it goes (None: the tracker cannot be
        snapshotted, or checkpoints are off). Read them after the run: they change while it goes.
    """

    sequence: Sequence
    trackers: tuple[TrackerInfo, ...]
    init_box: np.ndarray
    seeds: tuple
    n_frames: int
    checkpoints: tuple = ()


@dataclass(frozen=True, slots=True)
class Findings:
    """What the observers earlier in the pipeline found, handed to those after them.

    Attributes
    ----------
    diagnosis : DiagnosisView, optional
        The drift diagnosis so far (:class:`covviz.diagnosis.drift.DiagnosisView`:
        ``report(j)``, ``config``), from ``on_start`` on.
    news : tuple, optional
        What the diagnosis found on this frame, one
        :class:`covviz.diagnosis.drift.FrameNews` per tracker (``on_frame`` only).
    counterfactual : tuple, optional
        Per tracker, ``{lost_at: Replay}``: the replays of its losses
        (:class:`covviz.diagnosis.counterfactual.Counterfactuals`, ``on_end`` only).
    drift : DriftView, optional
        The label-free drift detector so far (:class:`covviz.diagnosis.detector.DriftView`).
    drift_news : tuple, optional
        Per tracker, this frame's ``(drift probability or None, new alarms)``.
    """

    diagnosis: Any = None
    news: tuple = ()
    counterfactual: tuple = ()
    drift: Any = None
    drift_news: tuple = ()


NOTHING = Findings()


@runtime_checkable
class Observer(Protocol):
    """What the runner calls; subclass it for the no-op defaults.

    Each method is handed the findings of the observers before it in the
    pipeline and returns new findings for those after it (``None``: unchanged).
    """

    def on_start(self, start: RunStart, found: Findings) -> Findings | None:
        return None

    def on_frame(self, frame: Frame, records: Seq[FrameRecord], found: Findings) -> Findings | None:
        return None

    def on_end(self, results: Seq[RunResult], found: Findings) -> Findings | None:
        return None


class ProgressObserver(Observer):
    """An observer that also wants the results so far, at most every ``progress_seconds``."""

    progress_seconds: float = 1.0

    def on_progress(self, results: Seq[RunResult], found: Findings) -> None:
        return None


class Pipeline(Observer):
    """Observers run in order, each handed the findings of those before it (one observer to the runner)."""

    def __init__(self, observers: Iterable) -> None:
        self.observers = list(observers)

    def on_start(self, start, found):
        for ob in self.observers:
            found = ob.on_start(start, found) or found
        return found

    def on_frame(self, frame, records, found):
        for ob in self.observers:
            found = ob.on_frame(frame, records, found) or found
        return found

    def on_end(self, results, found):
        for ob in self.observers:
            found = ob.on_end(results, found) or found
        return found


class ResultCollector(Observer):
    """Keeps the results handed to ``on_end`` (also after an interruption)."""

    def __init__(self) -> None:
        self.results: list[RunResult] = []

    def on_end(self, results, found) -> None:
        self.results = list(results)


class BackgroundObserver(Observer):
    """Runs another observer's ``on_frame`` on a worker thread, behind a bounded queue.

    Tracking goes on while the previous frames are being logged, so an
    observer's cost overlaps the tracker's instead of adding to it. Records and
    frames are never mutated after they are handed over, so nothing is copied.
    ``on_end`` waits until every queued frame is done (an interrupted run keeps
    all of them), then calls the wrapped ``on_end``. An exception in the worker
    is raised again in the tracking thread at the next call; no frame after it is observed.

    Parameters
    ----------
    observer : Observer
        Any observer (often a :class:`Pipeline`: the diagnosis and the recorder after it). Its
        ``on_start`` and ``on_end`` run in the calling thread, so the findings they return reach
        the observers after this one; those of its ``on_frame`` stay inside it.
    maxsize : int
        Frames that may wait in the queue (bounds memory; the tracker blocks
        when the observer is that far behind).
    """

    _STOP = object()

    def __init__(self, observer, maxsize: int = 8) -> None:
        self.observer = observer
        self._queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self._error: BaseException | None = None
        self._failed = False  # stays set once the error is handed over: no frame is observed after it
        self._thread: threading.Thread | None = None

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            try:
                if item is self._STOP:
                    return
                if not self._failed:
                    self.observer.on_frame(*item)
            except BaseException as exc:  # noqa: BLE001 - handed to the tracking thread
                self._failed = True
                self._error = exc
            finally:
                self._queue.task_done()

    def _raise(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            raise err

    def on_start(self, start, found):
        found = self.observer.on_start(start, found) or found
        self._error, self._failed = None, False
        self._thread = threading.Thread(target=self._work, name="covviz-observer", daemon=True)
        self._thread.start()
        return found

    def on_frame(self, frame, records, found) -> None:
        self._raise()
        if self._thread is not None:
            self._queue.put((frame, records, found))

    def on_end(self, results, found):
        if self._thread is not None:
            self._queue.put(self._STOP)
            self._thread.join()
            self._thread = None
        try:
            self._raise()
        finally:
            found = self.observer.on_end(results, found) or found
        return found


class FreeSpaceGuard(ProgressObserver):
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

    def on_progress(self, results, found) -> None:
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
    observers: Iterable[Observer] = (),
    max_frames: int | None = None,
    progress: bool = False,
    seeds: Seq[int | None] | None = None,
    checkpoints: tuple[int, ...] | None = None,
    prefetch: int = AHEAD,
) -> list[RunResult]:
    """Run several trackers side by side on the same frames (each frame read once).

    Parameters
    ----------
    trackers : sequence of Tracker
    sequence : Sequence
    observers : iterable of Observer
        The pipeline, in order: each is handed the :class:`Findings` of those
        before it. :class:`ProgressObserver` s also get ``on_progress`` (the
        results so far, marked interrupted) every ``progress_seconds``.
    max_frames : int, optional
        Stop after this many frames (including the first).
    progress : bool
        Show a progress bar on stderr.
    seeds : sequence of int, optional
        Seeds to write into the results (one per tracker).
    checkpoints : tuple of int, optional
        The :class:`CheckpointRing` arguments (``every, keep[, long_every, long_keep]``) of each
        snapshot-capable tracker's states (in :attr:`RunStart.checkpoints`); None: none kept.
    prefetch : int
        Frames read and decoded ahead on a background thread while the trackers work
        (:class:`covviz.data.prefetch.Prefetcher`: same frames, same order, a broken frame's
        error at that frame); 0: each frame read in this thread when its turn comes. Either way
        ``sequence.frame`` is called once per frame, in order, never twice at a time.

    Returns
    -------
    list of RunResult, one per tracker.
    """
    observers = list(observers)
    for ob in observers:
        if not isinstance(ob, Observer):
            raise TypeError(f"{type(ob).__name__} is not an Observer (on_start, on_frame, on_end)")
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
    infos: list[TrackerInfo] = []
    rings: list[CheckpointRing | None] = []

    def results_so_far(stopped: bool) -> list[RunResult]:
        return [
            RunResult(
                sequence=sequence.name,
                tracker=info.name,
                seed=seeds[j],
                boxes=boxes[j, :done],
                times=times[j, :done],
                groundtruth=gt[:done],
                config=info.config,
                interrupted=stopped,
            )
            for j, info in enumerate(infos)
        ]

    # Observers that want the results so far, each with its own period (a monotonic deadline).
    periodic = [[ob, time.monotonic() + float(ob.progress_seconds)] for ob in observers
                if isinstance(ob, ProgressObserver)]
    bar = None
    started: list[Observer] = []
    found = NOTHING
    frames = Prefetcher(sequence.frame, n, ahead=prefetch, name="covviz-frames")
    try:
        bar = _progress(n, f"{sequence.name}", progress)
        for i in range(n):
            check_signals()  # a Ctrl-C that C code swallowed (covviz.signals) stops here
            frame = next(frames)
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
            if i == 0:
                done = i + 1  # the results so far hold the first frame when the observers start
                infos = [tracker_info(tr) for tr in trackers]
                rings = [CheckpointRing(*checkpoints) if (checkpoints and info.snapshots) else None
                         for info in infos]
                start = RunStart(sequence, tuple(infos), np.asarray(sequence.init_box, dtype=np.float64).copy(),
                                 tuple(seeds), n, tuple(rings))
                # A stop signal while the observers start (the recorder opening its file) waits until
                # they all have, so that each of them also gets its on_end.
                with shielded():
                    for ob in observers:
                        found = ob.on_start(start, found) or found
                        started.append(ob)
            for ring, tr in zip(rings, trackers):
                if ring is not None and ring.due(i):
                    ring.add(i, tr.snapshot())
            # A frame counts as done once every observer has it: a stop signal while one waits
            # (the recorder's queue full) is held until then, so the recording and the results
            # end on the same frame.
            with shielded():
                done = i + 1
                frame_found = found
                for ob in observers:
                    frame_found = ob.on_frame(frame, records, frame_found) or frame_found
            if periodic:
                now = time.monotonic()
                partial = None
                for due in periodic:
                    if now >= due[1]:
                        partial = partial or results_so_far(stopped=True)
                        due[0].on_progress(partial, found)
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
        with shielded():  # the reader thread ends before the observers' on_end (the replays read frames too)
            frames.close()
        if bar is not None:
            bar.close()
        if not infos:  # stopped before the first frame was tracked
            infos = [tracker_info(tr) for tr in trackers]
        results = results_so_far(interrupted)
        _end(started, results, found, failing=stopped_by if interrupted else None)
    return results


def _end(observers, results, found: Findings, failing: BaseException | None) -> None:
    """Every observer's ``on_end`` in order, even when one fails; a stop signal waits until they are done.

    The first failure is raised afterwards, unless the run is already failing (``failing``, the
    exception that stopped it): then that exception goes on, with the observers' failures added
    as notes (``add_note``: a traceback shows them; the command line words them its own way).
    """
    errors: list[BaseException] = []
    with shielded():
        for ob in observers:
            try:
                found = ob.on_end(results, found) or found
            except BaseException as exc:  # noqa: BLE001 - the others still get theirs
                errors.append(exc)
    if not errors:
        return
    if failing is not None:
        for exc in errors:
            failing.add_note(f"{type(exc).__name__}: {exc}")
        return
    raise errors[0]


def run(tracker, sequence: Sequence, observers: Iterable = (), max_frames=None, progress=False, seed=None,
        checkpoints: tuple[int, int] | None = None, prefetch: int = AHEAD):
    """Run one tracker over a sequence; see :func:`run_many`. Returns a :class:`RunResult`."""
    return run_many([tracker], sequence, observers, max_frames, progress, seeds=[seed], checkpoints=checkpoints,
                    prefetch=prefetch)[0]
