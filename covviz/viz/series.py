"""Time series sent in columns: one ``rr.send_columns`` per series every second or two, not a log call per value.

Small per-frame images too (the recorder's heatmaps and zoom patches, :meth:`SeriesBuffer.add_image`): a
``log`` of a 9×31 image cost 0.23 ms of CPU, its share of a column chunk 0.007 ms. And per-frame point and
rectangle batches of any length (the particles, :meth:`SeriesBuffer.add_points`, :meth:`SeriesBuffer.add_strips`):
a ``log`` of 540 coloured points 0.14 ms, its column share 0.04; of 60 rectangles 0.13 and 0.01. And the
frame's JPEG (:meth:`SeriesBuffer.add_encoded_image`), boxes (:meth:`SeriesBuffer.add_boxes`, stored as
``rr.Boxes2D(mins=, sizes=)`` stores them) and ``rr.AnyValues`` beside a batch of strips (the top particles'
weights and distances): with them, the MDS pictures' points, the recorder's Rerun calls per frame fell from ~9
to ~2 and its CPU on Car4 by a third.

Rerun's per-call cost (~0.1–0.2 ms of CPU for each ``log``, whatever its size) made the
two dozen scalars the recorder writes per tracker and frame (ESS, weights, distances,
each likelihood term, IoU, stage timings, …) cost more than the particles. A
:class:`SeriesBuffer` keeps each series' values with the frame (and, when the sequence has
a frame rate, the time) they belong to and sends them as one column chunk per series at
:meth:`flush`: what the viewer shows is the same rows at the same times, arriving up to
``every`` frames or ``seconds`` later in a live viewer.

Each column chunk costs ~1.3 KB of the recording whatever it holds (its schema and
metadata): sent every 10 frames, the recorder's ~60 series were a quarter of a Car4
recording (~9 MB per 1000 frames). Sent once the oldest value held is ``seconds`` old (as
the file sink writes its batches), they cost a few hundred bytes per second.
"""

from __future__ import annotations

import time

import numpy as np
import pyarrow as pa
import rerun as rr

from covviz.viz import paths as P

__all__ = ["RECORDER_EVERY", "RECORDER_SECONDS", "SeriesBuffer"]

#: The recorders' series (:class:`covviz.viz.logger.LoggerConfig`, :class:`covviz.viz.drift.DriftRecorder`):
#: sent once the oldest value held is this many seconds old ...
RECORDER_SECONDS = 2.0
#: ... or this many frames are held.
RECORDER_EVERY = 250


class SeriesBuffer:
    """Scalars of many entity paths, sent as columns.

    Parameters
    ----------
    stream : rerun.RecordingStream
    every : int
        :meth:`tick` flushes once this many frames are held (1: every frame).
    seconds : float, optional
        ... or once the oldest value held is this many seconds old (None: frames only).
    clock : callable
        Seconds (monotonic), for ``seconds``.
    """

    def __init__(self, stream, every: int = 10, seconds: float | None = None, clock=time.monotonic):
        if seconds is not None and not seconds >= 0:
            raise ValueError(f"seconds must be >= 0 or None, got {seconds}")
        self.stream = stream
        self.every = max(1, int(every))
        self.seconds = None if seconds is None else float(seconds)
        self._clock = clock
        self._rows: dict[str, tuple[list, list, list]] = {}
        self._images: dict[tuple, tuple[list, list, list]] = {}  # (path, shape, colour model) -> rows
        self._batches: dict[tuple, tuple[list, list, list]] = {}  # (path, kind) -> frames, seconds, {field: array}
        self._encoded: dict[tuple, tuple[list, list, list]] = {}  # (path, media type) -> frames, seconds, bytes
        self._frame: int | None = None
        self._seconds: float | None = None
        self._ticks = 0  # frames since the last flush
        self._since: float | None = None  # the clock when the oldest value held was added

    def at(self, frame: int, seconds: float | None) -> None:
        """The time of the values :meth:`add` takes next (the frame's 1-based number, its seconds)."""
        self._frame, self._seconds = int(frame), None if seconds is None else float(seconds)

    def add(self, path: str, value: float) -> None:
        """One value of the series at ``path``, at the time of the last :meth:`at`."""
        self._hold(self._rows, path, float(value), "add")

    def add_image(self, path: str, image: np.ndarray, color_model: str) -> None:
        """One image of the entity at ``path`` (``(H, W)`` or ``(H, W, C)`` ``uint8``), at the time of the last
        :meth:`at`; sent with the series as ``rr.Image`` columns. What does not change per frame (draw
        order, filter, placement) is the caller's to log once, static."""
        img = np.ascontiguousarray(image, dtype=np.uint8)
        self._hold(self._images, (path, img.shape, color_model), img, "add_image")

    def add_points(self, path: str, positions: np.ndarray, colors: np.ndarray | None = None,
                   radii: np.ndarray | None = None, labels=None) -> None:
        """One frame's ``Points2D`` of the entity at ``path`` (``(n, 2)`` positions; optional ``(n, 4)`` uint8
        colours, ``(n,)`` radii and ``n`` labels, where absent the entity's static ones; ``n`` may be 0: the
        frame shows none), sent with the series."""
        fields = {"positions": np.asarray(positions, np.float32).reshape(-1, 2)}
        if colors is not None:
            fields["colors"] = np.asarray(colors, np.uint8).reshape(-1, 4)
        if radii is not None:
            fields["radii"] = np.asarray(radii, np.float32).reshape(-1)
        if labels is not None:
            fields["labels"] = np.asarray(labels, dtype=object).reshape(-1)
        self._hold(self._batches, (path, "points"), fields, "add_points")

    def add_strips(self, path: str, strips: np.ndarray, colors: np.ndarray | None = None,
                   values: dict | None = None) -> None:
        """One frame's ``LineStrips2D`` of ``(n, k, 2)`` strips of ``k`` points each (``n`` may be 0), with
        ``(n, 4)`` uint8 colours (None: the entity's static ones), sent with the series; ``values``: ``rr.AnyValues``
        of the same rows (name -> ``(n,)`` array), sent beside them."""
        strips = np.asarray(strips, np.float32)
        if strips.ndim != 3 or strips.shape[2] != 2:
            raise ValueError(f"strips must be (n, k, 2), got shape {strips.shape}")
        fields = {"strips": strips}
        if colors is not None:
            fields["colors"] = np.asarray(colors, np.uint8).reshape(-1, 4)
        self._hold(self._batches, (path, "strips"), {**fields, **_any_fields(values, len(strips))}, "add_strips")

    def add_boxes(self, path: str, mins: np.ndarray, sizes: np.ndarray) -> None:
        """One frame's ``Boxes2D`` of ``(n, 2)`` corners and sizes, sent with the series. Stored as
        ``rr.Boxes2D(mins=..., sizes=...)`` stores them: float32 centres and half sizes, bit for bit."""
        half = np.asarray(sizes, np.float32).reshape(-1, 2) / 2.0
        centers = np.asarray(mins, np.float32).reshape(-1, 2) + half
        self._hold(self._batches, (path, "boxes"), {"centers": centers, "half_sizes": half}, "add_boxes")

    def add_encoded_image(self, path: str, contents: bytes, media_type: str) -> None:
        """One frame's ``rr.EncodedImage`` (e.g. the frame's JPEG), sent with the series. Its draw order, if any,
        is the caller's to log once, static."""
        self._hold(self._encoded, (path, media_type), bytes(contents), "add_encoded_image")

    def _hold(self, store: dict, key, item, caller: str) -> None:
        """Keep ``item`` (a value, an image, a frame's batch) under ``key`` at the time of the last :meth:`at`."""
        if self._frame is None:
            raise RuntimeError(f"SeriesBuffer.at(frame, seconds) must come before {caller}()")
        if self._since is None:
            self._since = self._clock()
        frames, seconds, items = store.setdefault(key, ([], [], []))
        frames.append(self._frame)
        seconds.append(self._seconds)
        items.append(item)

    def tick(self) -> None:
        """A frame is done: flush once ``every`` frames are held or the oldest value is ``seconds`` old."""
        self._ticks += 1
        if self._ticks >= self.every or (
            self.seconds is not None and self._since is not None and self._clock() - self._since >= self.seconds
        ):
            self.flush()

    def flush(self) -> None:
        """Send what is held, one column chunk per series (and per image entity and size)."""
        rows, self._rows = self._rows, {}
        images, self._images = self._images, {}
        batches, self._batches = self._batches, {}
        encoded, self._encoded = self._encoded, {}
        self._ticks, self._since = 0, None
        for path, (frames, seconds, values) in rows.items():
            self.stream.send_columns(path, indexes=_indexes(frames, seconds),
                                     columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))
        for (path, shape, model), (frames, seconds, imgs) in images.items():
            fmt = rr.components.ImageFormat(width=shape[1], height=shape[0], color_model=model, channel_datatype="U8")
            self.stream.send_columns(
                path, indexes=_indexes(frames, seconds),
                columns=rr.Image.columns(buffer=np.stack(imgs).reshape(len(imgs), -1), format=[fmt] * len(imgs)),
            )
        for (path, media_type), (frames, seconds, blobs) in encoded.items():
            self.stream.send_columns(
                path, indexes=_indexes(frames, seconds),
                columns=rr.EncodedImage.columns(blob=blobs, media_type=[media_type] * len(blobs)),
            )
        for (path, kind), (frames, seconds, rows) in batches.items():
            for group in _same_shape(rows, kind):
                fr = [frames[i] for i in group]
                sec = [seconds[i] for i in group]
                cat = {k: np.concatenate([rows[i][k] for i in group]) for k in rows[group[0]]}
                lengths = [len(rows[i][_COUNT[kind]]) for i in group]
                anys = {k[len(_ANY):]: cat.pop(k) for k in list(cat) if k.startswith(_ANY)}
                cols = list(_ARCHETYPE[kind].columns(**cat).partition(lengths))
                if anys:
                    cols += list(rr.AnyValues.columns(**{k: _arrow(v) for k, v in anys.items()}).partition(lengths))
                self.stream.send_columns(path, indexes=_indexes(fr, sec), columns=cols)

    def __len__(self) -> int:
        """Values (and images) held, not yet sent."""
        return sum(len(v[2]) for d in (self._rows, self._images, self._batches, self._encoded) for v in d.values())


#: The field whose rows a batch's length counts, and the archetype of its columns, by kind.
_COUNT = {"points": "positions", "strips": "strips", "boxes": "centers"}
_ARCHETYPE = {"points": rr.Points2D, "strips": rr.LineStrips2D, "boxes": rr.Boxes2D}
#: Prefix of the fields of a batch that go out as ``rr.AnyValues`` beside its archetype.
_ANY = "any:"


def _any_fields(values: dict | None, n: int) -> dict:
    """``values`` (name -> ``(n,)``) as batch fields (:data:`_ANY`-prefixed), checked to have ``n`` rows each."""
    out = {}
    for k, v in (values or {}).items():
        a = np.asarray(v).reshape(-1)
        if len(a) != n:
            raise ValueError(f"value {k!r} has {len(a)} rows, the batch {n}")
        out[_ANY + k] = a
    return out


def _arrow(a: np.ndarray):
    """A numeric column as an Arrow array (pyarrow comes with rerun-sdk): Rerun then skips its per-value Python (it wraps each value of a
    numpy column in a list of its own, ~0.16 ms per 1000 values, ~7% of the recorder's Python on Car4).
    Floats as float64 and integers as int64, the types Rerun registers for them from numpy; anything
    else is left to Rerun."""
    kind = a.dtype.kind
    if kind == "f":
        return pa.array(a.astype(np.float64, copy=False))
    if kind in "iu":
        return pa.array(a.astype(np.int64, copy=False))
    if kind == "b":
        return pa.array(a)
    return a


def _same_shape(rows: list[dict], kind: str) -> list[list[int]]:
    """Indices of ``rows`` grouped so that one column chunk can hold each group: the same fields and, for
    strips, the same points per strip."""
    groups: dict[tuple, list[int]] = {}
    for i, r in enumerate(rows):
        key = tuple(sorted(r)) + ((r["strips"].shape[1],) if kind == "strips" else ())
        groups.setdefault(key, []).append(i)
    return list(groups.values())


def _indexes(frames: list, seconds: list) -> list:
    """The time columns of held rows: the frame numbers, and the seconds when every row has them."""
    out = [rr.TimeColumn(P.FRAME_TIMELINE, sequence=np.asarray(frames, dtype=np.int64))]
    if all(s is not None for s in seconds):
        out.append(rr.TimeColumn(P.TIME_TIMELINE, duration=np.asarray(seconds, dtype=np.float64)))
    return out
