"""The runner's observer plumbing: BackgroundObserver, interruption semantics, frames read ahead."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from covviz.data.sequences import SyntheticConfig, SyntheticSequence
from covviz.runner import (
    NOTHING,
    BackgroundObserver,
    Findings,
    Observer,
    Pipeline,
    ResultCollector,
    run,
    run_many,
)
from covviz.trackers.base import IdentityTracker


class Recorder(Observer):
    def __init__(self, fail_at=None):
        self.frames, self.threads, self.ended = [], set(), None
        self.fail_at = fail_at

    def on_start(self, start, found):
        self.started = True

    def on_frame(self, frame, records, found):
        if frame.index == self.fail_at:
            raise RuntimeError("observer broke")
        self.frames.append(frame.index)
        self.threads.add(threading.get_ident())

    def on_end(self, results, found):
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
        def on_end(self, results, found):
            raise OSError("disk full")

    collector = ResultCollector()
    with pytest.raises(OSError, match="disk full"):
        run(IdentityTracker(), seq, [FailsAtEnd(), collector])
    assert collector.results and len(collector.results[0].boxes) == len(seq)


def test_observers_are_told_the_trackers_once_after_init(seq):
    class Start(Observer):
        def on_start(self, start, found):
            self.start = start

    ob = Start()
    run_many([IdentityTracker(), IdentityTracker()], seq, [ob], max_frames=5, seeds=[1, 2])
    infos = ob.start.trackers
    assert [i.name for i in infos] == ["identity", "identity"] and ob.start.seeds == (1, 2)
    assert ob.start.n_frames == 5 and all(i.model is None and i.snapshots for i in infos)


def test_findings_flow_down_the_pipeline_in_order(seq):
    """Each observer is handed what those before it found; the first one sees nothing."""
    seen = []

    class Finder(Observer):
        def on_start(self, start, found):
            seen.append(("start-finder", found))
            return Findings(diagnosis="view")

        def on_frame(self, frame, records, found):
            return Findings(diagnosis=found.diagnosis, news=(frame.index,))

    class Reader(Observer):
        def on_start(self, start, found):
            seen.append(("start-reader", found.diagnosis))

        def on_frame(self, frame, records, found):
            seen.append(("frame", found.news))

        def on_end(self, results, found):
            seen.append(("end", found.diagnosis))

    run(IdentityTracker(), seq, [Pipeline([Finder(), Reader()])], max_frames=3)
    assert seen[0] == ("start-finder", NOTHING) and seen[1] == ("start-reader", "view")
    assert [s for s in seen if s[0] == "frame"] == [("frame", (0,)), ("frame", (1,)), ("frame", (2,))]
    assert seen[-1] == ("end", "view")


def test_an_object_that_is_not_an_observer_is_refused(seq):
    class Duck:
        def on_frame(self, frame, records):
            pass

    with pytest.raises(TypeError, match="not an Observer"):
        run(IdentityTracker(), seq, [Duck()])


def test_the_checkpoint_ring_is_dense_recently_and_sparse_far_back():
    from covviz.runner import CheckpointRing

    ring = CheckpointRing(every=5, keep=4, long_every=50, long_keep=3)
    for i in range(400):
        if ring.due(i):
            ring.add(i, f"s{i}")
    assert len(ring) == 4 + 3  # bounded: 4 recent, 3 far
    assert ring.at_or_before(399) == (395, "s395") and ring.at_or_before(381) == (380, "s380")
    assert ring.at_or_before(379) == (350, "s350")  # older than the dense ring: the sparse one reaches it
    assert ring.at_or_before(260) == (250, "s250") and ring.at_or_before(249) is None  # beyond both
    assert not ring.due(7) and ring.due(10) and ring.due(50)


class _BreaksAt(SyntheticSequence):
    """A synthetic sequence whose frame ``k`` cannot be read; notes the frames read and the threads reading them."""

    def __init__(self, k: int, n: int = 25) -> None:
        super().__init__(SyntheticConfig(n_frames=n))
        self.k, self.read, self.readers = k, [], set()

    def _read(self, i):
        from covviz.data.frames import SequenceError

        self.read.append(i)
        self.readers.add(threading.get_ident())
        if i == self.k:
            raise SequenceError(f"cannot read image {i + 1:04d}.jpg: the JPEG file is truncated")
        return super()._read(i)


def _frame_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "covviz-frames"]


@pytest.mark.parametrize("prefetch", [0, 4])
def test_a_broken_frame_stops_the_run_at_that_frame_with_its_error(prefetch):
    from covviz.data.frames import SequenceError

    seq = _BreaksAt(7)
    inner, collector = Recorder(), ResultCollector()
    with pytest.raises(SequenceError, match=r"^cannot read image 0008\.jpg: the JPEG file is truncated$"):
        run(IdentityTracker(), seq, [BackgroundObserver(inner), collector], prefetch=prefetch)
    assert inner.frames == list(range(7)) and inner.ended == [7]  # the frames before it, all observed
    assert len(collector.results[0].boxes) == 7 and collector.results[0].interrupted
    assert seq.read == list(range(8))  # nothing read past it
    assert not _frame_threads()
    assert (threading.get_ident() in seq.readers) == (prefetch == 0)  # decoded off the tracking thread


def test_prefetched_frames_give_the_boxes_of_frames_read_in_place():
    from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker

    seq = SyntheticSequence(SyntheticConfig(n_frames=15))
    cfg = ManifoldConfig().replace(n_particles=60, threads=1)
    boxes = [run(ManifoldTracker(cfg, rng=0), seq, prefetch=p).boxes for p in (0, 1, 4)]
    assert all(np.array_equal(b, boxes[0]) for b in boxes[1:])


def test_an_interrupted_run_leaves_no_reader_thread():
    class Interrupts(IdentityTracker):
        def update(self, frame):
            if self._index == 4:
                raise KeyboardInterrupt
            return super().update(frame)

    collector = ResultCollector()
    with pytest.raises(KeyboardInterrupt):
        run(Interrupts(), SyntheticSequence(SyntheticConfig(n_frames=200)), [collector], prefetch=2)
    assert not _frame_threads()  # joined before on_end, not left reading the other 190 frames
    assert len(collector.results[0].boxes) == 5 and collector.results[0].interrupted
