"""Run results on disk: per-frame boxes in the OTB results format plus a JSON.

For a run of tracker ``T`` with seed ``S`` on sequence ``Q`` the files are::

    DIR/Q/T_sS.txt    one "x,y,w,h" line per frame, 1-based pixels (OTB results format)
    DIR/Q/T_sS.json   metrics, per-frame times, config, seed, versions

Reports and plots read these files, so nothing is recomputed (run → results on
disk → report). Files are written to a temporary name and renamed, so an
interrupted run never leaves a half-written result.

A folder of many results (``covviz bench``) also holds ``bench_manifest.json``,
which names the run it belongs to (:func:`read_manifest`, :func:`write_manifest`).
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import numpy as np

from covviz import __version__
from covviz.errors import InputError
from covviz.metrics import evaluate
from covviz.records import RunResult
from covviz.sequences import read_boxes, write_boxes

__all__ = [
    "FORMAT",
    "MANIFEST_FORMAT",
    "MANIFEST_NAME",
    "ResultError",
    "load_result",
    "read_manifest",
    "result_paths",
    "save_result",
    "write_manifest",
]

#: Format tag written into every JSON; a folder from another tool or version is refused.
FORMAT = "covviz-result/1"
#: File name of the manifest inside a bench's results folder.
MANIFEST_NAME = "bench_manifest.json"
#: Format tag of the manifest; a folder with another tag is refused.
MANIFEST_FORMAT = "covviz-bench/1"


class ResultError(InputError):
    """A results file is missing, corrupt or from another run; the message says which."""


def result_paths(out_dir: str | Path, sequence: str, tracker: str, seed: int | None) -> tuple[Path, Path]:
    stem = f"{tracker}_s{seed}" if seed is not None else tracker
    d = Path(out_dir) / sequence
    return d / f"{stem}.txt", d / f"{stem}.json"


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(text)
    os.replace(tmp, path)


def save_result(result: RunResult, out_dir: str | Path, extra: dict | None = None) -> dict:
    """Write a run's boxes and JSON (metrics, times, config); return the JSON dict."""
    txt, js = result_paths(out_dir, result.sequence, result.tracker, result.seed)
    txt.parent.mkdir(parents=True, exist_ok=True)
    metrics = evaluate(result.boxes, result.groundtruth).as_dict() if len(result.boxes) else {}
    doc = {
        "format": FORMAT,
        "sequence": result.sequence,
        "tracker": result.tracker,
        "seed": result.seed,
        "n_frames": len(result.boxes),
        "interrupted": bool(result.interrupted),
        "fps": result.fps,
        "metrics": metrics,
        "times": [round(float(t), 6) for t in result.times],
        "config": result.config,
        "versions": {"covviz": __version__, "numpy": np.__version__, "python": platform.python_version()},
        **(extra or {}),
    }
    tmp = txt.with_name(txt.name + ".part")
    write_boxes(tmp, result.boxes)
    os.replace(tmp, txt)
    _atomic_write(js, json.dumps(doc, indent=1, default=_json_default, allow_nan=True))
    return doc


def load_result(json_path: str | Path) -> tuple[dict, np.ndarray]:
    """Read a result's JSON and its boxes (0-based). Raises :class:`ResultError`."""
    js = Path(json_path)
    try:
        doc = json.loads(js.read_text())
    except FileNotFoundError:
        raise ResultError(f"{js}: no such results file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ResultError(f"{js}: corrupt results file ({exc.__class__.__name__}); delete it and re-run") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ResultError(f"{js}: not a covviz result (format {doc.get('format') if isinstance(doc, dict) else None!r})")
    txt = js.with_suffix(".txt")
    try:
        boxes = read_boxes(txt, one_based=True)
    except (OSError, ValueError) as exc:
        raise ResultError(f"{txt}: cannot read the boxes of this result ({exc})") from None
    if len(boxes) != doc.get("n_frames"):
        raise ResultError(f"{txt}: {len(boxes)} boxes but the JSON says {doc.get('n_frames')}; delete and re-run")
    return doc, boxes


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, (set, frozenset, tuple)):
        return list(o)
    return str(o)


def read_manifest(out: str | Path) -> dict | None:
    """The bench manifest of a results folder, or None if it has none.

    Raises
    ------
    ResultError
        If the manifest is corrupt or not a covviz bench manifest.
    """
    p = Path(out) / MANIFEST_NAME
    if not p.exists():
        return None
    try:
        m = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, OSError) as exc:
        raise ResultError(
            f"{p}: corrupt bench manifest ({exc.__class__.__name__}); delete it, or run "
            "'covviz bench … --force' to re-run everything into this folder"
        ) from None
    if not isinstance(m, dict) or m.get("format") != MANIFEST_FORMAT:
        raise ResultError(f"{p}: not a covviz bench manifest; choose a new --out")
    return m


def write_manifest(out: str | Path, manifest: dict) -> None:
    """Write a results folder's manifest atomically."""
    _atomic_write(Path(out) / MANIFEST_NAME, json.dumps(manifest, indent=1) + "\n")
