"""Reading a covviz recording back: its events and diagnoses (``covviz events``), the last frame.

The recorder logs one row per event under ``trackers/<name>/event_records``
(:meth:`covviz.viz.logger.RerunLogger._event_record`): kind, 1-based frame
number, level, text and, for diagnoses, the cause and its evidence as JSON.
These are read back here, from the file alone, for scripts and for
``covviz snapshot --event``.
"""

from __future__ import annotations

import contextlib
import json
import logging
from pathlib import Path

from covviz.errors import InputError
from covviz.viz import paths as P

__all__ = ["RecordingError", "application_id", "last_frame", "open_recording", "read_events", "read_layout",
           "readable_length"]

log = logging.getLogger("covviz")

#: Fields of an event row, in the order ``covviz events`` prints them.
FIELDS = ("tracker", "frame", "kind", "level", "cause", "text")


class RecordingError(InputError):
    """A file that is not a readable covviz recording; the message says what is wrong."""


#: The application id every covviz recording carries (:data:`covviz.viz.sinks.APPLICATION_ID`).
COVVIZ_APPLICATION = "covviz"
#: An .rrd file: the header (``RRF2``, version, options), then messages of a 16-byte header
#: (kind, payload length; little-endian u64) and their payload, then (rerun 0.41) a footer.
RRD_HEADER_BYTES = 12
RRD_MESSAGE_HEADER_BYTES = 16


def readable_length(path: str | Path) -> int | None:
    """Bytes of ``path`` up to the end of its last whole message, or None if it is not an .rrd file.

    A recording cut mid-message (a full disk, a file copied in part) makes
    rerun's reader refuse the whole file; everything before the cut message is
    still a valid recording without its footer (as after SIGKILL).
    """
    import struct

    with open(path, "rb") as fh:
        if fh.read(4) != b"RRF2":
            return None
        size = fh.seek(0, 2)
        pos = RRD_HEADER_BYTES
        while pos + RRD_MESSAGE_HEADER_BYTES <= size:
            fh.seek(pos)
            _, length = struct.unpack("<QQ", fh.read(RRD_MESSAGE_HEADER_BYTES))
            if pos + RRD_MESSAGE_HEADER_BYTES + length > size:
                return pos
            pos += RRD_MESSAGE_HEADER_BYTES + length
        return pos


class _Opened:
    """A recording opened for reading: the reader, and what was left out of a file cut short."""

    def __init__(self, path: Path, reader, cut: tuple[int, int] | None):
        self.path, self.reader, self.cut = path, reader, cut

    def note(self) -> str | None:
        return None if self.cut is None else cut_note(self.path, self.cut)


@contextlib.contextmanager
def open_recording(path: str | Path, covviz_only: bool = True):
    """The recording at ``path`` for reading (:class:`_Opened`); a file cut mid-message is read up to the cut.

    Raises
    ------
    RecordingError
        No such file, not a Rerun recording, or (``covviz_only``) a recording of
        another application.
    """
    import warnings

    from rerun.chunk import RrdReader

    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{p}: no such recording")
    try:
        kept = readable_length(p)
    except OSError as exc:
        raise RecordingError(f"{p}: cannot read it ({exc.strerror or exc})") from None
    if kept is None:
        raise RecordingError(f"{p}: not a Rerun recording (no RRF2 header); give an .rrd file written by covviz")
    with readable_file(p, kept) as (src, cut):
        try:
            with warnings.catch_warnings():  # "RRD file has no footer": said once, by note()
                warnings.simplefilter("ignore")
                reader = RrdReader(str(src))
                stores = reader.recordings()
        except Exception as exc:  # noqa: BLE001 - rerun raises various types for a bad file
            raise RecordingError(f"{p}: not a readable Rerun recording ({' '.join(str(exc).split())})") from None
        if covviz_only and not any(st.application_id == COVVIZ_APPLICATION for st in stores):
            apps = ", ".join(sorted({st.application_id for st in stores})) or "none"
            raise RecordingError(f"{p}: not a covviz recording (application {apps}); give an .rrd file written by "
                                 "'covviz track'")
        yield _Opened(p, reader, cut)


@contextlib.contextmanager
def readable_file(path: Path, kept: int | None = None):
    """``(file, cut)``: ``path`` itself, or, if it was cut mid-message, a temporary copy of its whole messages.

    ``cut`` is None, or ``(bytes kept, file size)``. The copy lives for the block.
    """
    import shutil
    import tempfile

    path = Path(path)
    kept = readable_length(path) if kept is None else kept
    size = path.stat().st_size
    if kept is None or kept >= size or _has_footer(path):
        yield path, None
        return
    with tempfile.TemporaryDirectory(prefix="covviz-cut-") as tmp:
        copy = Path(tmp) / path.name
        with open(path, "rb") as fin, open(copy, "wb") as fout:
            shutil.copyfileobj(_Limited(fin, kept), fout)
        yield copy, (kept, size)


def cut_note(path: Path, cut: tuple[int, int]) -> str:
    """What a reader of a recording cut short says, once."""
    kept, size = cut
    return (f"{path} was cut short (a message at byte {kept:,} runs past its end, {size:,}): read what comes "
            f"before; 'rerun rrd migrate {path}' writes the readable part as a whole recording")


def _has_footer(path: Path) -> bool:
    from covviz.viz.sinks import recording_complete

    return bool(recording_complete(path))


class _Limited:
    """The first ``n`` bytes of a binary file, for ``shutil.copyfileobj``."""

    def __init__(self, fh, n: int):
        self.fh, self.left = fh, n

    def read(self, size: int = -1) -> bytes:
        size = self.left if size < 0 else min(size, self.left)
        data = self.fh.read(size)
        self.left -= len(data)
        return data


def _stream(opened: _Opened):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return opened.reader.stream()


def _first(v):
    return v[0] if isinstance(v, list) and v else v


def read_events(path: str | Path) -> list[dict]:
    """Every event of a tracking recording, in frame order (then as logged).

    Returns
    -------
    list of dict
        ``tracker``, ``frame`` (1-based), ``kind`` (``drift``, ``lost``,
        ``recovered``, ``storm``, ``storm_end``, ``diagnosis``, ``suspect``),
        ``level``, ``cause`` (diagnoses: the cause; suspects: their kind),
        ``text``, ``details`` (diagnoses: the evidence, a dict), ``index``
        (position in this list, as ``covviz snapshot --event`` counts).
    """
    rows = []
    with open_recording(path) as rec:
        note = rec.note()
        try:
            for ch in _stream(rec):
                if ch.is_static or not ch.entity_path.rstrip("/").endswith("/event_records"):
                    continue
                rb = ch.to_record_batch()
                names = set(rb.schema.names)
                cols = {c: rb.column(c).to_pylist() for c in ("tracker", "frame_number", "kind", "level", "text",
                                                               "cause", "details", "rerun.controls.RowId")
                        if c in names}
                for k in range(rb.num_rows):
                    details = _first(cols.get("details", [None] * rb.num_rows)[k]) or "{}"
                    rows.append(
                        {
                            "tracker": _first(cols["tracker"][k]),
                            "frame": int(_first(cols["frame_number"][k])),
                            "kind": _first(cols["kind"][k]),
                            "level": _first(cols["level"][k]),
                            "cause": _first(cols.get("cause", [None] * rb.num_rows)[k]) or "",
                            "text": _first(cols["text"][k]),
                            "details": json.loads(details),
                            "_row": bytes(cols["rerun.controls.RowId"][k]),
                        }
                    )
        except Exception as exc:  # noqa: BLE001 - a damaged file
            raise RecordingError(f"{path}: cannot read its events ({exc.__class__.__name__}: "
                                 f"{' '.join(str(exc).split())})") from None
    if note:
        log.warning("%s", note)
    rows.sort(key=lambda r: (r["frame"], r["_row"]))
    for i, r in enumerate(rows):
        del r["_row"]
        r["index"] = i
    return rows


def last_frame(path: str | Path) -> int | None:
    """The last frame number on the recording's ``frame`` timeline (None if it has none)."""
    last = None
    with open_recording(path, covviz_only=False) as rec:
        for ch in _stream(rec):
            if ch.is_static:
                continue
            rb = ch.to_record_batch()
            if P.FRAME_TIMELINE in rb.schema.names:
                v = [f for f in rb.column(P.FRAME_TIMELINE).to_pylist() if f is not None]
                if v:
                    last = max(v) if last is None else max(last, max(v))
    return last


def read_layout(path: str | Path) -> dict | None:
    """What the recording's blueprint was built from: ``trackers``, ``with_cloud``, ``with_particles``,
    ``image_size`` (None for a recording without it: ``covviz mds``, or one from before it was logged)."""
    out: dict = {}
    with open_recording(path, covviz_only=False) as rec:
        batches = [ch.to_record_batch() for ch in _stream(rec)
                   if ch.is_static and ch.entity_path.strip("/") == P.LAYOUT]
    for rb in batches:
        for c in ("trackers", "with_cloud", "with_particles", "image_size"):
            if c in rb.schema.names:
                v = rb.column(c).to_pylist()[-1]
                out[c] = [x for x in v if x != ""] if c != "image_size" else v
    return out if "trackers" in out else None


def application_id(path: str | Path) -> str | None:
    """The application id of the recording in ``path`` (a blueprint for it must carry the same)."""
    try:
        with open_recording(path, covviz_only=False) as rec:
            for store in rec.reader.recordings():
                return str(store.application_id)
    except Exception:  # noqa: BLE001 - older files, foreign files
        return None
    return None
