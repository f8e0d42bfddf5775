"""Reading ahead: the next frames read and decoded on one background thread while the tracker works.

:class:`Prefetcher` calls ``read(0), read(1), …`` in order on a thread of its
own and hands the items over in the same order, at most ``ahead`` of them
waiting at a time, so a JPEG's decoding (``cv2.imdecode`` and the colour
conversion release the GIL) overlaps the tracker's ``update`` instead of adding
to it. What the caller sees is what reading in place gives:

* the same items in the same order (one reader thread, a FIFO queue): the boxes
  of a run do not change;
* an exception of ``read(k)`` raised where item ``k`` is asked for, after items
  ``0 … k - 1``, and nothing read after it: a broken frame stops a run at that
  frame with the same one-line error;
* :meth:`Prefetcher.close` (after the last item, on leaving a ``with`` block, on
  an early stop or a Ctrl-C in the caller) stops the thread and waits for it,
  which takes at most the one ``read`` under way; the items not taken are dropped.

Memory is bounded: ``ahead`` items in the queue and one being read, besides the
one the caller holds. ``read`` runs on another thread than the caller's, but
never at the same time as another ``read`` of this prefetcher; a reader that
must stay on the caller's thread takes ``ahead=0`` (each item read when asked for).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

__all__ = ["AHEAD", "Prefetcher"]

#: Items (frames) read ahead of the one in use by default: enough to ride out a slow read, few
#: enough that a 4K frame's 25 MB times ``AHEAD + 1`` is not a memory concern.
AHEAD = 4

T = TypeVar("T")


class Prefetcher(Generic[T]):
    """``read(0) … read(n - 1)``, called in order on one background thread, at most ``ahead`` ahead of their use.

    Iterate it for the items, in order. It starts reading when it is made; use it in a ``with``
    block (or call :meth:`close`) so that the thread ends with its user, whatever stops it.

    Parameters
    ----------
    read : callable
        ``read(i) -> item``, for ``i`` from 0 to ``n - 1``.
    n : int
        Items to read.
    ahead : int
        Items read but not yet taken, at most (bounds memory); 0: no thread, each item read in
        the caller's thread when it is asked for.
    name : str
        Name of the thread.

    Examples
    --------
    >>> with Prefetcher(lambda i: i * i, 5, ahead=2) as items:
    ...     list(items)
    [0, 1, 4, 9, 16]
    """

    def __init__(self, read: Callable[[int], T], n: int, ahead: int = AHEAD, name: str = "covviz-prefetch") -> None:
        if int(ahead) < 0:
            raise ValueError(f"ahead={ahead}: a prefetcher reads 0 or more items ahead")
        self._read = read
        self.n = max(0, int(n))
        self._taken = 0
        self._closed = False
        self._stop = threading.Event()
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, int(ahead)))
        self._thread: threading.Thread | None = None
        if ahead and self.n:
            # The thread holds the queue and the stop flag, not the prefetcher: one dropped without
            # close() is collected, and its __del__ stops the thread.
            self._thread = threading.Thread(target=_work, args=(read, self.n, self._queue, self._stop),
                                            name=name, daemon=True)
            self._thread.start()

    def __iter__(self) -> Iterator[T]:
        return self

    def __next__(self) -> T:
        if self._closed or self._taken >= self.n:
            self.close()
            raise StopIteration
        if self._thread is None:
            item, exc = self._read_here()
        else:
            item, exc = self._get()
        self._taken += 1
        if exc is not None:
            self.close()
            raise exc
        if self._taken == self.n:
            self.close()  # the thread has ended: nothing more to read
        return item

    def _read_here(self):
        try:
            return self._read(self._taken), None
        except BaseException as exc:  # noqa: BLE001 - raised by __next__, after the state is updated
            return None, exc

    def _get(self):
        """The next item from the queue; an error rather than a wait forever if the thread is gone without it."""
        while True:
            try:
                return self._queue.get(timeout=1.0)
            except queue.Empty:
                if not self._thread.is_alive() and self._queue.empty():
                    return None, RuntimeError(f"the prefetch thread ended before item {self._taken} of {self.n}")

    def close(self) -> None:
        """Stop reading and wait for the thread (at most the ``read`` under way); the items not taken are dropped.

        Idempotent. After it, iterating stops.
        """
        self._closed = True
        if self._thread is None:
            return
        self._stop.set()
        self._drain()  # a thread blocked on a full queue puts its item and then sees the stop
        self._thread.join()
        self._thread = None
        self._drain()

    def _drain(self) -> None:
        while True:
            try:
                self._queue.get_nowait()
            except queue.Empty:
                return

    def __enter__(self) -> Prefetcher[T]:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # dropped without close(): the thread must not wait on a full queue forever
        if getattr(self, "_thread", None) is not None:
            self._stop.set()
            self._drain()


def _work(read: Callable, n: int, out: queue.Queue, stop: threading.Event) -> None:
    """The reader thread: ``(item, None)`` for each item in order, then ``(None, error)`` if a read fails."""
    try:
        for i in range(n):
            if stop.is_set():
                return
            out.put((read(i), None))
    except BaseException as exc:  # noqa: BLE001 - raised again in the caller, at the item it stopped
        out.put((None, exc))
