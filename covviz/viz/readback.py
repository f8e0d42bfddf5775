"""Reading a covviz recording back: its events and diagnoses (``covviz events``), the last frame.

The recorder logs one row per event under ``trackers/<name>/event_records``
(:meth:`covviz.viz.logger.RerunLogger._event_record`): kind, 1-based frame
number, level, text and, for diagnoses, the cause and its evidence as JSON.
These are read back here, from the file alone, for scripts and for
``covviz snapshot --event``.
"""

from __future__ import annotations

import json
from pathlib import Path

from covviz.errors import InputError
from covviz.viz import paths as P

__all__ = ["RecordingError", "application_id", "last_frame", "read_events", "read_layout"]

#: Fields of an event row, in the order ``covviz events`` prints them.
FIELDS = ("tracker", "frame", "kind", "level", "cause", "text")


class RecordingError(InputError):
    """A file that is not a readable covviz recording; the message says what is wrong."""


def _reader(path: str | Path):
    from rerun.chunk import RrdReader

    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{p}: no such recording")
    try:
        return RrdReader(str(p))
    except Exception as exc:  # noqa: BLE001 - rerun raises various types for a bad file
        raise RecordingError(f"{p}: not a readable Rerun recording ({exc})") from None


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
    try:
        for ch in _reader(path).stream():
            if ch.is_static or not ch.entity_path.rstrip("/").endswith("/event_records"):
                continue
            rb = ch.to_record_batch()
            names = set(rb.schema.names)
            cols = {c: rb.column(c).to_pylist() for c in ("tracker", "frame_number", "kind", "level", "text",
                                                           "cause", "details", "rerun.controls.RowId") if c in names}
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
    except RecordingError:
        raise
    except Exception as exc:  # noqa: BLE001 - a truncated or foreign file
        raise RecordingError(f"{path}: cannot read its events ({exc.__class__.__name__}: {exc})") from None
    rows.sort(key=lambda r: (r["frame"], r["_row"]))
    for i, r in enumerate(rows):
        del r["_row"]
        r["index"] = i
    return rows


def last_frame(path: str | Path) -> int | None:
    """The last frame number on the recording's ``frame`` timeline (None if it has none)."""
    last = None
    for ch in _reader(path).stream():
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
    for ch in _reader(path).stream():
        if not ch.is_static or ch.entity_path.strip("/") != P.LAYOUT:
            continue
        rb = ch.to_record_batch()
        for c in ("trackers", "with_cloud", "with_particles", "image_size"):
            if c in rb.schema.names:
                v = rb.column(c).to_pylist()[-1]
                out[c] = [x for x in v if x != ""] if c != "image_size" else v
    return out if "trackers" in out else None


def application_id(path: str | Path) -> str | None:
    """The application id of the recording in ``path`` (a blueprint for it must carry the same)."""
    try:
        for rec in _reader(path).recordings():
            return str(rec.application_id)
    except Exception:  # noqa: BLE001 - older files, foreign files
        return None
    return None
