"""Helpers of the viz tests: read a saved recording back into plain Python values."""

from __future__ import annotations

import subprocess
from collections import defaultdict
from pathlib import Path

import numpy as np


def read_recording(path: str | Path) -> tuple[dict, dict]:
    """All temporal and static data of an ``.rrd``, by entity and column.

    Returns
    -------
    temporal : dict
        ``temporal[entity][column][frame]`` -> list of the values logged on that
        frame (in log order), for rows on the ``frame`` timeline.
    static : dict
        ``static[entity][column]`` -> the value.
    """
    from rerun.chunk import RrdReader

    temporal: dict = defaultdict(lambda: defaultdict(lambda: defaultdict(list)))
    static: dict = defaultdict(dict)
    rows = []
    for ch in RrdReader(str(path)).stream():
        rb = ch.to_record_batch()
        entity = ch.entity_path.lstrip("/")
        names = rb.schema.names
        cols = [
            c for c in names if c not in ("rerun.controls.RowId", "frame", "time", "log_time", "log_tick")
        ]
        if ch.is_static:
            for c in cols:
                static[entity][c] = rb.column(c).to_pylist()[-1]
            continue
        if "frame" not in names:
            continue
        row_ids = [bytes(r) for r in rb.column("rerun.controls.RowId").to_pylist()]
        frames = rb.column("frame").to_pylist()
        values = {c: rb.column(c).to_pylist() for c in cols}
        for k, f in enumerate(frames):
            rows.append((row_ids[k], entity, f, {c: values[c][k] for c in cols}))
    rows.sort(key=lambda r: r[0])  # row ids (big-endian, time first) grow with log order
    for _, entity, f, vals in rows:
        for c, v in vals.items():
            if v is not None:
                temporal[entity][c][f].append(v)
    return temporal, static


def last(temporal: dict, entity: str, column: str) -> dict:
    """``{frame: last value}`` of one column."""
    return {f: vs[-1] for f, vs in temporal[entity][column].items()}


def boxes(temporal: dict, entity: str) -> dict:
    """``{frame: (x, y, w, h)}`` of a one-box ``Boxes2D`` entity (stored as centres and half sizes)."""
    c, h = last(temporal, entity, "Boxes2D:centers"), last(temporal, entity, "Boxes2D:half_sizes")
    return {f: np.r_[np.ravel(c[f]) - np.ravel(h[f]), 2 * np.ravel(h[f])] for f in c}


def texts(temporal: dict, entity: str) -> list[str]:
    """Every ``TextLog`` line of an entity, in frame order."""
    col = temporal[entity]["TextLog:text"]
    return [x for f in sorted(col) for batch in col[f] for x in batch]


def static_text(static: dict, entity: str) -> str:
    """The text of a static ``TextDocument``."""
    return static[entity]["TextDocument:text"][0]


def scalar_series(temporal: dict, entity: str) -> dict:
    """``{frame: float}`` of a ``Scalars`` entity."""
    return {f: float(np.ravel(v)[0]) for f, v in last(temporal, entity, "Scalars:scalars").items()}


def rrd_verify(path: str | Path) -> subprocess.CompletedProcess:
    """``rerun rrd verify PATH``."""
    return subprocess.run(
        ["rerun", "rrd", "verify", str(path)], check=False, capture_output=True, text=True, timeout=120
    )
