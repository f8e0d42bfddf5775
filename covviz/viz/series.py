"""Time series sent in columns: one ``rr.send_columns`` per series every few frames, not a log call per value.

Rerun's per-call cost (~0.1–0.2 ms of CPU for each ``log``, whatever its size) made the
two dozen scalars the recorder writes per tracker and frame (ESS, weights, distances,
each likelihood term, IoU, stage timings, …) cost more than the particles. A
:class:`SeriesBuffer` keeps each series' values with the frame (and, when the sequence has
a frame rate, the time) they belong to and sends them as one column chunk per series at
:meth:`flush`: what the viewer shows is the same rows at the same times, arriving up to
``every`` frames later in a live viewer.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from covviz.viz import paths as P

__all__ = ["SeriesBuffer"]


class SeriesBuffer:
    """Scalars of many entity paths, sent as columns.

    Parameters
    ----------
    stream : rerun.RecordingStream
    every : int
        :meth:`tick` flushes every ``every`` frames (1: every frame).
    """

    def __init__(self, stream, every: int = 10):
        self.stream = stream
        self.every = max(1, int(every))
        self._rows: dict[str, tuple[list, list, list]] = {}
        self._frame: int | None = None
        self._seconds: float | None = None
        self._ticks = 0

    def at(self, frame: int, seconds: float | None) -> None:
        """The time of the values :meth:`add` takes next (the frame's 1-based number, its seconds)."""
        self._frame, self._seconds = int(frame), None if seconds is None else float(seconds)

    def add(self, path: str, value: float) -> None:
        """One value of the series at ``path``, at the time of the last :meth:`at`."""
        if self._frame is None:
            raise RuntimeError("SeriesBuffer.at(frame, seconds) must come before add()")
        frames, seconds, values = self._rows.setdefault(path, ([], [], []))
        frames.append(self._frame)
        seconds.append(self._seconds)
        values.append(float(value))

    def tick(self) -> None:
        """A frame is done: flush every ``every`` frames."""
        self._ticks += 1
        if self._ticks % self.every == 0:
            self.flush()

    def flush(self) -> None:
        """Send what is held, one column chunk per series."""
        rows, self._rows = self._rows, {}
        for path, (frames, seconds, values) in rows.items():
            indexes = [rr.TimeColumn(P.FRAME_TIMELINE, sequence=np.asarray(frames, dtype=np.int64))]
            if all(s is not None for s in seconds):
                indexes.append(rr.TimeColumn(P.TIME_TIMELINE, duration=np.asarray(seconds, dtype=np.float64)))
            self.stream.send_columns(path, indexes=indexes,
                                     columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))

    def __len__(self) -> int:
        """Values held, not yet sent."""
        return sum(len(v[2]) for v in self._rows.values())
