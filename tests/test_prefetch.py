"""The frame prefetcher (covviz.data.prefetch): order, errors at their item, bounded reading ahead, early close."""

from __future__ import annotations

import gc
import threading
import time

import numpy as np
import pytest

from covviz.data.prefetch import Prefetcher
from covviz.data.sequences import SyntheticConfig, SyntheticSequence


def _threads(name: str) -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == name]


def _gone(name: str, seconds: float = 5.0) -> bool:
    """Whether no thread of that name is left (within ``seconds``: a collected prefetcher's ends on its own)."""
    end = time.monotonic() + seconds
    while _threads(name) and time.monotonic() < end:
        time.sleep(0.01)
    return not _threads(name)


class Reads:
    """A reader that notes every index it is asked for, and the thread that asked, optionally slowly."""

    def __init__(self, fail_at: int | None = None, delay: float = 0.0) -> None:
        self.asked: list[int] = []
        self.threads: set[int] = set()
        self.fail_at, self.delay = fail_at, delay

    def __call__(self, i: int) -> int:
        self.asked.append(i)
        self.threads.add(threading.get_ident())
        if self.delay:
            time.sleep(self.delay)
        if i == self.fail_at:
            raise ValueError(f"frame {i} is broken")
        return 10 * i


@pytest.mark.parametrize("ahead", [0, 1, 4])
def test_items_come_in_order_each_read_once(ahead):
    reads = Reads(delay=0.001)
    with Prefetcher(reads, 30, ahead=ahead, name="t-order") as items:
        assert list(items) == [10 * i for i in range(30)]
    assert reads.asked == list(range(30))
    assert (threading.get_ident() in reads.threads) == (ahead == 0)  # read off the caller's thread when ahead
    assert _gone("t-order")


def test_frames_of_a_sequence_are_those_read_in_place():
    seq = SyntheticSequence(SyntheticConfig(n_frames=12))
    with Prefetcher(seq.frame, len(seq), name="t-frames") as frames:
        for i, f in enumerate(frames):
            ref = seq.frame(i)
            assert f.index == i and np.array_equal(f.image, ref.image) and np.array_equal(f.gt, ref.gt)


@pytest.mark.parametrize("ahead", [0, 2])
def test_an_error_is_raised_at_its_item_after_the_items_before_it(ahead):
    reads = Reads(fail_at=5)
    got = []
    items = Prefetcher(reads, 20, ahead=ahead, name="t-error")
    with pytest.raises(ValueError, match="frame 5 is broken"):
        got.extend(items)  # the items before the error are kept: extend appends as it goes
    assert got == [0, 10, 20, 30, 40]
    assert reads.asked == [0, 1, 2, 3, 4, 5]  # nothing read after the failure
    assert _gone("t-error") and list(items) == []  # closed by the error


def test_reading_ahead_is_bounded():
    reads = Reads()
    items = Prefetcher(reads, 100, ahead=3, name="t-bound")
    try:
        assert next(items) == 0
        time.sleep(0.2)  # time to read everything if nothing held it back
        # 1 taken, 3 in the queue, 1 read and waiting for room
        assert len(reads.asked) <= 1 + 3 + 1
    finally:
        items.close()


def test_close_early_stops_the_thread_blocked_on_a_full_queue():
    reads = Reads()
    with Prefetcher(reads, 1000, ahead=2, name="t-close") as items:
        assert [next(items) for _ in range(3)] == [0, 10, 20]
        time.sleep(0.05)  # the thread is now waiting for room in the queue
        assert len(_threads("t-close")) == 1
    assert not _threads("t-close")  # joined by close, not just told to stop
    asked = len(reads.asked)
    assert asked <= 3 + 2 + 1
    time.sleep(0.05)
    assert len(reads.asked) == asked and list(items) == []  # nothing read after close; iteration ended
    items.close()  # twice is fine


def test_an_exception_in_the_caller_stops_the_thread():
    items = Prefetcher(Reads(delay=0.001), 1000, ahead=4, name="t-interrupt")
    with pytest.raises(KeyboardInterrupt), items:
        for x in items:
            if x == 50:
                raise KeyboardInterrupt  # as a Ctrl-C in the tracking loop
    assert not _threads("t-interrupt")


def test_a_prefetcher_dropped_without_close_does_not_leave_its_thread_waiting():
    items = Prefetcher(Reads(), 1000, ahead=2, name="t-dropped")
    next(items)
    del items
    gc.collect()
    assert _gone("t-dropped")


def test_ahead_must_not_be_negative():
    with pytest.raises(ValueError, match="0 or more"):
        Prefetcher(Reads(), 3, ahead=-1)
