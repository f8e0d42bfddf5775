"""The runner's observer plumbing: BackgroundObserver and interruption semantics."""

from __future__ import annotations

import threading

import pytest

from covviz.data.sequences import SyntheticConfig, SyntheticSequence
from covviz.runner import BackgroundObserver, ResultCollector, run
from covviz.trackers.base import IdentityTracker


class Recorder:
    def __init__(self, fail_at=None):
        self.frames, self.threads, self.ended = [], set(), None
        self.fail_at = fail_at

    def on_start(self, sequence, trackers):
        self.started = True

    def on_frame(self, frame, records):
        if frame.index == self.fail_at:
            raise RuntimeError("observer broke")
        self.frames.append(frame.index)
        self.threads.add(threading.get_ident())

    def on_end(self, results):
        self.ended = [len(r.boxes) for r in results]


@pytest.fixture(scope="module")
def seq():
    return SyntheticSequence(SyntheticConfig(n_frames=25))


def test_background_observer_sees_every_frame_in_order_off_the_main_thread(seq):
    inner = Recorder()
    res = run(IdentityTracker(), seq, [BackgroundObserver(inner, maxsize=2)])
    assert inner.frames == list(range(len(seq)))  # drained before on_end, in order
    assert inner.ended == [len(seq)] and len(res.boxes) == len(seq)
    assert threading.get_ident() not in inner.threads


def test_background_observer_error_reaches_the_tracking_thread_and_on_end_still_runs(seq):
    inner = Recorder(fail_at=5)
    collector = ResultCollector()
    with pytest.raises(RuntimeError, match="observer broke"):
        run(IdentityTracker(), seq, [BackgroundObserver(inner, maxsize=1), collector])
    assert inner.frames == [0, 1, 2, 3, 4]  # nothing logged after the failure
    assert inner.ended is not None  # on_end (flush/close a recording) ran anyway
    assert collector.results and collector.results[0].interrupted


def test_tracker_error_drains_the_queue_first(seq):
    class Breaks(IdentityTracker):
        def update(self, frame):
            if self._index == 9:
                raise ValueError("tracker broke")
            return super().update(frame)

    inner = Recorder()
    with pytest.raises(ValueError, match="tracker broke"):
        run(Breaks(), seq, [BackgroundObserver(inner)])
    assert inner.frames == list(range(10))  # every frame before the error was observed
    assert inner.ended == [10]
    assert threading.get_ident() not in inner.threads


def test_every_observer_ends_even_when_one_fails_at_the_end(seq):
    # The failing observer comes first: the collector after it must still get the results.
    class FailsAtEnd(Recorder):
        def on_end(self, results):
            raise OSError("disk full")

    collector = ResultCollector()
    with pytest.raises(OSError, match="disk full"):
        run(IdentityTracker(), seq, [FailsAtEnd(), collector])
    assert collector.results and len(collector.results[0].boxes) == len(seq)
