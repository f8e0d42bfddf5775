"""Run results on disk: per-frame boxes in the OTB results format plus a JSON.

For a run of tracker ``T`` with seed ``S`` on sequence ``Q`` the files are::

    DIR/Q/T_sS.txt    one "x,y,w,h" line per frame, 1-based pixels (OTB results format)
    DIR/Q/T_sS.json   metrics, per-frame times, config, seed, versions

Reports and plots read these files, so nothing is recomputed (run → results on
disk → report). Files are written to a temporary name and renamed, so an
interrupted run never leaves a half-written result; a write that fails (a full
disk) removes its temporary file and raises a one-line
:class:`~covviz.errors.WriteError`.

:class:`ResultWriter` writes a run's files while it goes: every second the
frames done so far (``"interrupted": true``), and the final files at the end.
A run killed with SIGKILL (an out-of-memory kill) keeps the results of all but
its last second. The JSON is written after the boxes and is what counts: a
kill between the two renames leaves boxes the JSON does not count yet, and
:func:`load_result` reads only the ``n_frames`` it names.

A folder of many results (``covviz bench``) also holds ``bench_manifest.json``,
which names the run it belongs to (:func:`read_manifest`, :func:`write_manifest`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from covviz import __version__
from covviz.data.sequences import read_boxes, write_boxes
from covviz.errors import InputError, WriteError
from covviz.metrics import evaluate, nothing_to_score
from covviz.records import RunResult
from covviz.runner import ProgressObserver

__all__ = [
    "FORMAT",
    "MANIFEST_FORMAT",
    "MANIFEST_NAME",
    "ResultError",
    "ResultWriter",
    "box_lines",
    "load_result",
    "read_manifest",
    "result_paths",
    "save_result",
    "write_manifest",
]

#: Format tag written into every JSON (bumped whenever a result's fields change; ``docs/formats.md``).
FORMAT = "covviz-result/2"
#: Older tags :func:`load_result` still reads (their missing fields are absent from the dict).
READABLE_FORMATS = ("covviz-result/1", FORMAT)
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


#: What a user can do when results cannot be written.
WRITE_HINT = "choose another --out"


def _atomic_write_with(path: Path, write) -> None:
    """``write(tmp)`` to ``PATH.part``, then rename it to ``path``; no ``.part`` is left if it fails."""
    tmp = path.with_name(path.name + ".part")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass
        raise


def _atomic_write(path: Path, text: str) -> None:
    _atomic_write_with(path, lambda tmp: tmp.write_text(text))


def box_lines(boxes: np.ndarray) -> list[str]:
    """The lines of a boxes file for 0-based ``boxes``, exactly as :func:`~covviz.data.sequences.write_boxes` writes them."""
    b = np.array(boxes, dtype=np.float64, copy=True).reshape(-1, 4)
    b[:, :2] += 1.0
    return [",".join(f"{v:.2f}" for v in row) + "\n" for row in b]


def boxes_sha256(boxes: np.ndarray) -> str:
    """SHA-256 of the float64 boxes (little-endian, row-major): bit-identity at a glance (the ``.txt`` has 2 decimals)."""
    b = np.ascontiguousarray(np.asarray(boxes, dtype="<f8").reshape(-1, 4))
    return hashlib.sha256(b.tobytes()).hexdigest()


def versions() -> dict:
    """What produced a result: covviz, numpy, Python, and the compiled kernels' numba, llvmlite and CPU target.

    Boxes are bit-identical for a seed on one machine (any thread count, any observers); the kernels
    are compiled for the host CPU (``cpu_target``, or ``NUMBA_CPU_NAME`` when set, with a note when
    ``NUMBA_CPU_FEATURES`` sets the features too), so another CPU
    may differ in the last bits. ``cpu_target`` is None when this process ran no compiled kernel.
    """
    from importlib import metadata

    out = {"covviz": __version__, "numpy": np.__version__, "python": platform.python_version()}
    for name in ("numba", "llvmlite"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:  # pragma: no cover - numba is a dependency
            out[name] = None
    out["cpu_target"] = _cpu_target() if "numba" in sys.modules else None
    return out


@functools.lru_cache(maxsize=1)
def _cpu_target() -> str:
    from llvmlite import binding

    name = os.environ.get("NUMBA_CPU_NAME") or binding.get_host_cpu_name()
    features = os.environ.get("NUMBA_CPU_FEATURES")
    if features:  # a name alone keeps the host's features (AVX-512 included): say which were turned off
        off = sorted(f[1:] for f in features.split(",") if f.startswith("-"))
        name += f" (features set: {len(off)} off{', e.g. ' + ', '.join(off[:3]) if off else ''})"
    return name


def save_result(result: RunResult, out_dir: str | Path, extra: dict | None = None, *,
                box_text: str | None = None) -> dict:
    """Write a run's boxes and JSON (metrics, times, config); return the JSON dict.

    ``box_text`` is the boxes file's text if it is already formatted (``"".join(box_lines(boxes))``).

    Raises
    ------
    WriteError
        If a file cannot be written (a full disk, a read-only folder); no
        ``.part`` file is left and the files of an earlier save stay as they were.
    """
    txt, js = result_paths(out_dir, result.sequence, result.tracker, result.seed)
    gt = result.groundtruth
    if len(gt) and nothing_to_score(gt):
        # No ground truth after the first frame (a video with --box): the first box is the one the
        # tracker was given, and scoring it alone would report a perfect run. Nothing is scored.
        gt = np.full_like(gt, np.nan)
    metrics = evaluate(result.boxes, gt).as_dict() if len(result.boxes) else {}
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
        "boxes_sha256": boxes_sha256(result.boxes),
        "versions": versions(),
        **(extra or {}),
    }
    text = json.dumps(doc, indent=1, default=_json_default, allow_nan=True)
    try:
        txt.parent.mkdir(parents=True, exist_ok=True)
        if box_text is None:
            _atomic_write_with(txt, lambda tmp: write_boxes(tmp, result.boxes))
        else:
            _atomic_write(txt, box_text)
        _atomic_write(js, text)  # last: the JSON says how many of the boxes count
    except OSError as exc:
        raise WriteError.from_os_error(txt, exc, WRITE_HINT) from None
    return doc


class ResultWriter(ProgressObserver):
    """Observer that keeps a run's results on disk while it goes (see the module docstring).

    Put it after the drift diagnosis in the pipeline: the diagnosis so far
    (:attr:`covviz.runner.Findings.diagnosis`) goes into every write as
    ``diagnosis`` and ``diagnosis_config``.

    Parameters
    ----------
    out_dir : path
        Results folder (as :func:`save_result`).
    extra : dict, optional
        Extra JSON fields of every run (as :func:`save_result`).
    progress_seconds : float
        How often the runner hands over the results so far (``on_progress``).

    Attributes
    ----------
    docs : list of dict
        The JSON documents of the final write (empty until ``on_end``).
    saved_frames : int
        Frames in the files on disk now (0 before the first write).
    """

    #: A write may take at most this share of the run: long runs are written less often.
    MAX_SHARE = 0.02

    def __init__(self, out_dir, extra=None, progress_seconds: float = 1.0) -> None:
        self.out_dir = out_dir
        self.extra = extra
        self.period = float(progress_seconds)
        # The first write comes with the first tracked frame: results of an earlier run under the
        # same names are replaced at once, not a second later (a kill then would leave them).
        self.progress_seconds = 0.0
        self.docs: list[dict] = []
        self.saved_frames = 0
        self._failed = False
        self._lines: dict[int, list[str]] = {}  # per run: the formatted boxes so far (they never change)
        self._diagnosis = None
        self._drift = None
        self._replays: tuple = ()

    def on_start(self, start, found) -> None:
        self._diagnosis, self._drift = found.diagnosis, found.drift

    def on_progress(self, results, found) -> None:
        t0 = time.perf_counter()
        if self._save(results):
            self.progress_seconds = max(self.period, (time.perf_counter() - t0) / self.MAX_SHARE)

    def on_end(self, results, found) -> None:
        self._diagnosis = found.diagnosis or self._diagnosis
        self._replays = found.counterfactual
        try:
            self.docs = self._save(results)
        except WriteError:
            if not (results and results[0].interrupted):
                raise
            # A stopped run (often stopped by this very disk): the files of the last good write
            # stay, and saved_frames says how many frames they hold.

    def _save(self, results) -> list[dict]:
        if self._failed or not results or not len(results[0].boxes):
            return []
        if results[0].interrupted and len(results[0].boxes) < 2:
            return []  # stopped before tracking anything: the one box is the one given
        try:
            docs = [save_result(r, self.out_dir, self._extra(j), box_text=self._box_text(j, r.boxes))
                    for j, r in enumerate(results)]
        except WriteError:
            self._failed = True  # once is enough: the files of the last good write stay
            raise
        self.saved_frames = len(results[0].boxes)
        return docs

    def _extra(self, j: int) -> dict:
        """The JSON fields beyond the standard ones of run ``j``: the static extras and the diagnosis so far."""
        out = dict(self.extra or {})
        d = self._diagnosis
        if d is not None:
            out["diagnosis"] = report = d.report(j)
            out["diagnosis_config"] = d.config.as_dict()
            if self._drift is not None:  # the label-free signals, drift probability and alarms
                report.update(self._drift.report(j))
                out["diagnosis_config"] = {**out["diagnosis_config"], **self._drift.config_dict()}
            if j < len(self._replays):  # each loss's replays and verdict
                from covviz.diagnosis.counterfactual import with_replays

                with_replays(report, self._replays[j], d.config.tie_ratio)
        return out

    def _box_text(self, j: int, boxes: np.ndarray) -> str:
        lines = self._lines.setdefault(j, [])
        if len(lines) > len(boxes):
            lines.clear()
        lines.extend(box_lines(boxes[len(lines):]))
        return "".join(lines)


def load_result(json_path: str | Path) -> tuple[dict, np.ndarray]:
    """Read a result's JSON and its boxes (0-based). Raises :class:`ResultError`."""
    js = Path(json_path)
    try:
        doc = json.loads(js.read_text())
    except FileNotFoundError:
        raise ResultError(f"{js}: no such results file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ResultError(f"{js}: corrupt results file ({exc.__class__.__name__}); delete it and re-run") from None
    if not isinstance(doc, dict) or doc.get("format") not in READABLE_FORMATS:
        raise ResultError(f"{js}: not a covviz result (format {doc.get('format') if isinstance(doc, dict) else None!r})")
    txt = js.with_suffix(".txt")
    try:
        boxes = read_boxes(txt, one_based=True)
    except (OSError, ValueError) as exc:
        raise ResultError(f"{txt}: cannot read the boxes of this result ({exc})") from None
    if doc.get("interrupted") and isinstance(doc.get("n_frames"), int) and len(boxes) > doc["n_frames"]:
        boxes = boxes[: doc["n_frames"]]  # killed between the two renames: the JSON counts
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
            f"{p}: corrupt bench manifest ({exc.__class__.__name__}); run the 'covviz bench …' that made it "
            "again (it rebuilds the manifest from the results and runs only what is missing), or "
            "'covviz bench … --force' to re-run everything into this folder"
        ) from None
    if not isinstance(m, dict) or m.get("format") != MANIFEST_FORMAT:
        raise ResultError(f"{p}: not a covviz bench manifest; choose a new --out")
    return m


def write_manifest(out: str | Path, manifest: dict) -> None:
    """Write a results folder's manifest atomically."""
    _atomic_write(Path(out) / MANIFEST_NAME, json.dumps(manifest, indent=1) + "\n")
