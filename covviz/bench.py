"""``covviz bench``: every tracker on every sequence under a folder, results on disk, a report.

The flow is got-10k's (run → results on disk → report)::

    ROOT/<sequence>/...        OTB (img/ + groundtruth_rect.txt) or VOT (groundtruth.txt) folders
        │  one job per (sequence, tracker, seed), longest first, J worker processes
        ▼
    OUT/<sequence>/<tracker>_s<seed>.txt|.json   (covviz.results; deterministic trackers: <tracker>.txt|.json)
    OUT/bench_manifest.json                      what this folder holds: root, trackers, seeds, ...
        │  covviz report OUT (covviz.report): reads the files only
        ▼
    OUT/report.md + OUT/img/bench_*.png

Seeds
    Stochastic trackers (:data:`covviz.trackers.STOCHASTIC`) run with seeds
    ``0 … K-1``; seed ``s`` gives the tracker the stream of
    :func:`covviz.trackers.tracker_rng`, exactly as ``covviz track --seed s``
    does, so any bench run can be replayed (and recorded in the viewer) with
    ``covviz track``. Deterministic
    trackers run once (seed ``None`` in their results).

Processes
    Every job runs in a fresh worker process (J at a time, each with
    ``cpu_count // J`` OpenCV/BLAS threads): OpenCV's MIL and TLD keep random
    state between runs in one process, so this is what makes every result
    independent of job order. Ctrl-C stops the workers; finished results stay.

Resuming
    Every job writes its result atomically (:func:`covviz.results.save_result`)
    as soon as it finishes, in the worker. A job whose result already exists,
    loads, covers the expected frames and was made with the same tracker config is
    skipped, so re-running an interrupted bench runs only what is missing. Running
    again with more trackers or seeds adds them to the same folder and report.

The manifest
    ``bench_manifest.json`` names the run: ``root``, ``max_frames``,
    ``particles`` and the covviz version must match for a folder to be reused;
    otherwise the bench stops with a one-line error (use ``--force`` to re-run
    everything into that folder, or a new ``--out``).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import sys
import time
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path

from covviz import __version__
from covviz.errors import InputError
from covviz.records import frame_number
from covviz.results import MANIFEST_FORMAT, MANIFEST_NAME, read_manifest, write_manifest
from covviz.threads import limit_threads

__all__ = [
    "BenchError",
    "Job",
    "bench",
    "find_sequences",
    "plan_jobs",
    "run_job",
]

log = logging.getLogger("covviz.bench")

#: Manifest fields that define a run: results made with other values are not comparable.
IDENTITY_FIELDS = ("root", "max_frames", "particles", "covviz")


class BenchError(InputError):
    """Bad input to ``bench`` or ``report``: printed as one line, exit code 2."""


# --------------------------------------------------------------------------- #
# sequences and jobs
# --------------------------------------------------------------------------- #
def _is_sequence_dir(p: Path) -> bool:
    return (p / "img").is_dir() or (p / "groundtruth.txt").is_file()


def find_sequences(root: str | Path) -> list[Path]:
    """Every sequence folder under ``root`` (or ``[root]`` if it is one), sorted by name.

    A sequence folder holds ``img/`` (OTB) or ``groundtruth.txt`` (VOT). Folders
    are searched recursively (following symlinks), but not inside a sequence;
    hidden folders are skipped.

    Raises
    ------
    BenchError
        If ``root`` does not exist, holds no sequence, or two sequences share a
        name (results are filed by sequence name).
    """
    root = Path(root)
    if not root.is_dir():
        raise BenchError(f"{root}: no such folder (expected a sequence folder or a folder of sequences)")
    if _is_sequence_dir(root):
        return [root]
    found: list[Path] = []
    seen: set[str] = set()  # real paths: symlinked folders are followed, loops are not
    for dirpath, dirnames, _ in os.walk(root, followlinks=True):
        d = Path(dirpath)
        real = os.path.realpath(d)
        if real in seen:
            dirnames[:] = []
            continue
        seen.add(real)
        dirnames[:] = sorted(n for n in dirnames if not n.startswith("."))
        if d != root and _is_sequence_dir(d):
            found.append(d)
            dirnames[:] = []
    if not found:
        raise BenchError(
            f"{root}: no sequences found (expected OTB folders with img/ + groundtruth_rect.txt, "
            "or VOT folders with groundtruth.txt)"
        )
    by_name: dict[str, list[Path]] = {}
    for p in found:
        by_name.setdefault(p.name, []).append(p)
    dup = {k: v for k, v in by_name.items() if len(v) > 1}
    if dup:
        name, paths = next(iter(dup.items()))
        raise BenchError(
            f"two sequences are called {name!r} ({paths[0]} and {paths[1]}); results are filed by "
            "sequence name, so bench one of them at a time"
        )
    return sorted(found, key=lambda p: p.name.lower())


@dataclass(frozen=True)
class Job:
    """One tracker run: ``tracker`` with ``seed`` on the sequence at ``path``."""

    sequence: str
    path: str
    n_frames: int
    tracker: str
    seed: int | None
    particles: int | None
    max_frames: int | None

    @property
    def label(self) -> str:
        return f"{self.sequence}/{self.tracker}" + ("" if self.seed is None else f"/s{self.seed}")


def plan_jobs(
    sequences: dict[str, tuple[str, int]],
    trackers: Seq[str],
    seeds: int,
    particles: int | None = None,
    max_frames: int | None = None,
) -> list[Job]:
    """Every (sequence, tracker, seed) job, longest first.

    Parameters
    ----------
    sequences : dict
        name -> (path, number of frames).
    trackers : sequence of str
    seeds : int
        Seeds ``0 … seeds-1`` for the stochastic trackers; one run (seed None) for the others.

    Returns
    -------
    list of Job, sorted by frames to run (descending), stochastic trackers first
    among equals (they are the slow ones), then by name: the longest jobs start
    first so that the last to finish are short.
    """
    from covviz.trackers import STOCHASTIC

    jobs = []
    for name, (path, n) in sequences.items():
        n_run = n if max_frames is None else min(n, max_frames)
        for tr in trackers:
            for s in range(seeds) if tr in STOCHASTIC else [None]:
                jobs.append(Job(name, path, n_run, tr, s, particles, max_frames))
    return sorted(
        jobs, key=lambda j: (-j.n_frames, j.tracker not in STOCHASTIC, j.sequence, j.tracker, j.seed or 0)
    )


def _jsonable(obj):
    """What ``obj`` becomes after a round trip through a results JSON (to compare configs)."""
    from covviz.results import _json_default

    return json.loads(json.dumps(obj, default=_json_default, allow_nan=True))


def _canonical(obj) -> str:
    """A config as sorted JSON text: equal configs give equal text (NaN included)."""
    return json.dumps(obj, sort_keys=True, allow_nan=True)


def tracker_configs(trackers: Seq[str], particles: int | None) -> dict[str, dict]:
    """The config each tracker would run with (builds each once; no frame is read)."""
    from covviz.trackers import make_tracker

    out = {}
    for name in trackers:
        try:
            tr = make_tracker(name, rng=0, n_particles=particles)
        except ValueError:
            raise
        except Exception as exc:  # noqa: BLE001 - e.g. a tracker module that does not import
            raise BenchError(f"cannot build tracker {name!r}: {exc.__class__.__name__}: {exc}") from None
        out[name] = _jsonable(tr.config_dict() if hasattr(tr, "config_dict") else {})
    return out


# --------------------------------------------------------------------------- #
# the worker
# --------------------------------------------------------------------------- #
class _FailureCounter:
    """Observer: numbers (1-based) of the frames whose record says ``extras["failed"]`` (OpenCV trackers)."""

    def __init__(self) -> None:
        self.failed: list[int] = []

    def on_frame(self, frame, records) -> None:
        if records and records[0].extras.get("failed"):
            self.failed.append(frame_number(frame.index))


def _init_worker() -> None:
    """Worker start-up: leave Ctrl-C to the parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_job(job: Job, out_dir: str, threads: int | None = None, jobs: int = 1) -> dict:
    """Run one job and write its result (atomically); return a short summary.

    ``threads`` OpenCV/BLAS threads while it runs (None: as they are).

    The JSON gets, besides the standard result fields, the OTB curves (so the
    report can plot them without the sequence), the thresholds they use, the
    frames on which the tracker reported a failure, and the bench settings.
    """
    from covviz.diagnosis import Diagnoser
    from covviz.metrics import (
        IOU_THRESHOLDS,
        ON_TRACK_GAMMA,
        PRECISION_AT,
        PRECISION_THRESHOLDS,
        precision_curve,
        success_curve,
    )
    from covviz.results import save_result
    from covviz.runner import BackgroundObserver, run
    from covviz.sequences import open_sequence
    from covviz.trackers import make_tracker

    seq = open_sequence(job.path)
    tracker = make_tracker(job.tracker, seed=job.seed, n_particles=job.particles)
    failures = _FailureCounter()
    diagnoser = Diagnoser()
    t0 = time.perf_counter()
    with limit_threads(threads), contextlib.closing(tracker) if hasattr(tracker, "close") else contextlib.nullcontext():
        # The drift diagnosis on its own thread, overlapping the tracker (it never changes a box).
        res = run(tracker, seq, [failures, BackgroundObserver(diagnoser)], max_frames=job.max_frames, seed=job.seed)
    wall = time.perf_counter() - t0
    extra = {
        "curves": {
            "iou_thresholds": IOU_THRESHOLDS,
            "success": success_curve(res.boxes, res.groundtruth),
            "precision_thresholds": PRECISION_THRESHOLDS,
            "precision": precision_curve(res.boxes, res.groundtruth),
        },
        "thresholds": {"precision_at": PRECISION_AT, "on_track_gamma": ON_TRACK_GAMMA},
        "failed_frames": failures.failed,
        "diagnosis": diagnoser.report(0),
        "diagnosis_config": diagnoser.config.as_dict(),
        "bench": {"jobs": jobs, "threads": threads, "wall_seconds": round(wall, 3), "path": job.path},
    }
    doc = save_result(res, out_dir, extra)
    return {"label": job.label, "fps": doc["fps"], "auc": doc["metrics"].get("success_auc"), "wall": wall}


# --------------------------------------------------------------------------- #
# manifest and resume
# --------------------------------------------------------------------------- #
def _existing_results(out: Path) -> list[Path]:
    return sorted(out.glob("*/*.json"))


def _merge_manifest(old: dict | None, new: dict, out: Path, force: bool) -> dict:
    """Check that ``out`` belongs to this run and return the manifest to write."""
    if old is None:
        if not force and _existing_results(out):
            raise BenchError(
                f"{out} holds results but no {MANIFEST_NAME} (from 'covviz track' or another tool?); "
                "choose a new --out or use --force"
            )
        return new
    if force:
        return new
    for key in IDENTITY_FIELDS:
        if old.get(key) != new.get(key):
            raise BenchError(
                f"{out} holds results of another run ({key} was {old.get(key)!r}, now {new.get(key)!r}); "
                "choose a new --out or use --force to re-run everything there"
            )
    merged = dict(new)
    merged["trackers"] = list(old.get("trackers", [])) + [
        t for t in new["trackers"] if t not in old.get("trackers", [])
    ]
    merged["seeds"] = max(int(old.get("seeds", 0)), new["seeds"])
    added = [t for t in new["trackers"] if t not in old.get("trackers", [])]
    if added or merged["seeds"] > int(old.get("seeds", 0)):
        log.info(
            "adding to the results in %s: trackers %s, seeds %d",
            out,
            ", ".join(added) or "(none new)",
            merged["seeds"],
        )
    return merged


def _is_done(job: Job, out: Path, config: dict) -> bool:
    """Whether ``job``'s result exists and is complete; raises on a corrupt or foreign one."""
    from covviz.results import load_result, result_paths

    _, js = result_paths(out, job.sequence, job.tracker, job.seed)
    if not js.exists():
        return False
    doc, _ = load_result(js)  # ResultError (a BenchError's sibling ValueError) on a corrupt file
    if doc.get("interrupted") or doc.get("n_frames") != job.n_frames:
        log.info("%s: the result in %s is incomplete; running it again", job.label, js)
        return False
    if _canonical(doc.get("config")) != _canonical(config):
        raise BenchError(
            f"{js}: made with another {job.tracker} config than the current one; delete "
            f"{out}/*/{job.tracker}*.json to re-run {job.tracker}, use --force, or choose a new --out"
        )
    return True


# --------------------------------------------------------------------------- #
# the bench
# --------------------------------------------------------------------------- #
def bench(
    root: str | Path,
    trackers: Seq[str],
    out: str | Path,
    seeds: int = 3,
    jobs: int = 1,
    max_frames: int | None = None,
    particles: int | None = None,
    force: bool = False,
    progress: bool = True,
    report: bool = True,
) -> dict:
    """Run ``trackers`` on every sequence under ``root``; write results and a report to ``out``.

    Parameters
    ----------
    root : path
        A sequence folder or a folder of them (see :func:`find_sequences`).
    trackers : sequence of str
        Names from :data:`covviz.trackers.TRACKERS`.
    out : path
        Results folder (created).
    seeds : int
        Seeds per stochastic tracker (``0 … seeds-1``).
    jobs : int
        Worker processes; every job runs in a fresh one. Each worker gets
        ``max(1, cpu_count // jobs)`` OpenCV/BLAS threads, so fps depend on ``jobs``.
    max_frames : int, optional
        Run only the first frames of each sequence.
    particles : int, optional
        Particle count of the stochastic trackers (default: their own).
    force : bool
        Ignore existing results and the manifest: re-run every job.
    progress : bool
        Progress bar over jobs on stderr.
    report : bool
        Write ``out/report.md`` and its figures at the end.

    Returns
    -------
    dict with ``run`` (count) and ``ran`` (labels) of the jobs done now, ``skipped``, ``failed``
    (list of (label, message)) and ``report`` (path or None).

    Raises
    ------
    BenchError
        Empty root, unknown tracker, a folder from another run, a corrupt result.
    """
    from covviz.sequences import SequenceError, open_sequence
    from covviz.trackers import STOCHASTIC, tracker_names

    try:
        trackers = tracker_names(trackers)
    except ValueError as exc:
        raise BenchError(str(exc)) from None
    if seeds < 1 or jobs < 1:
        raise BenchError("--seeds and --jobs must be at least 1")
    root = Path(root).resolve()
    out = Path(out)

    # Sequences: fail early, with the sequence's name, on a folder that cannot be read.
    sequences: dict[str, tuple[str, int]] = {}
    for p in find_sequences(root):
        try:
            seq = open_sequence(p)
            if len(seq) < 2:
                raise SequenceError(f"{p}: a sequence needs at least 2 frames, found {len(seq)}")
            seq.init_box  # noqa: B018 - raises if the first frame has no ground truth
        except SequenceError as exc:
            raise BenchError(f"sequence {p.name}: {exc}") from None
        sequences[seq.name] = (str(p), len(seq))

    configs = tracker_configs(trackers, particles)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".covviz-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise BenchError(f"cannot write to {out}: {exc.strerror or exc}; choose another --out") from None

    manifest = {
        "format": MANIFEST_FORMAT,
        "covviz": __version__,
        "root": str(root),
        "sequences": {k: v[1] for k, v in sequences.items()},
        "trackers": trackers,
        "stochastic": sorted(set(trackers) & STOCHASTIC),
        "seeds": seeds,
        "seed_rule": "stochastic trackers: seeds 0..seeds-1, "
        "rng = default_rng(SeedSequence(seed).spawn(1)[0]); "
        "others: one run, seed null",
        "max_frames": max_frames,
        "particles": particles,
    }
    old = None if force else read_manifest(out)  # --force also replaces a corrupt manifest
    manifest = _merge_manifest(old, manifest, out, force)
    manifest["stochastic"] = sorted(set(manifest["trackers"]) & STOCHASTIC)
    manifest["configs"] = {**((old or {}).get("configs") or {}), **configs}

    all_jobs = plan_jobs(sequences, trackers, seeds, particles, max_frames)
    todo = all_jobs if force else [j for j in all_jobs if not _is_done(j, out, configs[j.tracker])]
    skipped = len(all_jobs) - len(todo)
    write_manifest(out, manifest)
    if skipped:
        log.info(
            "%d of %d jobs already done in %s; running the other %d", skipped, len(all_jobs), out, len(todo)
        )

    if todo and any(j.tracker.startswith("manifold") for j in todo):
        from covviz import kernels

        # Once here, not in every fresh worker at the same time.
        kernels.warmup(lambda: log.info("compiling kernels (once; about 20-40 s, then cached)..."))
    ran, failed = _run_jobs(todo, out, jobs, progress)
    if failed:
        for label, msg in failed:
            log.error("%s failed: %s", label, msg)
    rep = None
    if report:
        from covviz.report import write_report

        rep = write_report(out)
        log.info("report: %s", rep)
    return {"run": len(ran), "ran": ran, "skipped": skipped, "failed": failed, "report": rep}


def _run_jobs(
    todo: list[Job], out: Path, jobs: int, progress: bool
) -> tuple[list[str], list[tuple[str, str]]]:
    """Run the jobs, each in a fresh worker process; return (labels done, failed as (label, message)).

    One process per job (``max_tasks_per_child=1``): OpenCV's MIL and TLD draw
    from random state that carries over between runs in one process, so a fresh
    process is what makes their results independent of job order (and equal to
    a ``covviz track`` run). Workers are forked from a forkserver that has the
    heavy modules loaded, so a new process costs milliseconds.
    """
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    done_labels: list[str] = []
    failed: list[tuple[str, str]] = []
    if not todo:
        return done_labels, failed
    threads = max(1, (os.cpu_count() or 1) // jobs)
    # forkserver: workers are forked from a clean server process, not from this one
    # (whose OpenCV/BLAS thread pools may already be running).
    ctx = mp.get_context("forkserver")
    ctx.set_forkserver_preload(["covviz.bench", "covviz.runner", "covviz.results", "covviz.trackers.opencv"])
    ex = ProcessPoolExecutor(
        max_workers=min(jobs, len(todo)),
        mp_context=ctx,
        initializer=_init_worker,
        max_tasks_per_child=1,
    )
    bar = tqdm(
        total=len(todo), unit="job", desc="bench", file=sys.stderr, disable=not progress, dynamic_ncols=True
    )
    futures = {}
    try:
        with bar, logging_redirect_tqdm():
            futures = {ex.submit(run_job, job, str(out), threads, jobs): job for job in todo}
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in sorted(finished, key=lambda f: futures[f].label):
                    job = futures[fut]
                    exc = fut.exception()
                    if exc is not None:
                        failed.append((job.label, f"{exc.__class__.__name__}: {exc}"))
                    else:
                        done_labels.append(job.label)
                        log.debug("%s done: %.1f fps", job.label, fut.result()["fps"])
                    bar.set_postfix_str(job.label)
                    bar.update(1)
    except KeyboardInterrupt:
        log.warning("interrupted: finished results are kept in %s; run the same command to resume", out)
        # Python 3.11 has no public way to stop running workers (3.14 adds terminate_workers());
        # they are our own processes, so end them one by one. Futures are not cancelled first:
        # 3.11's pool then fails them itself ("broken pool") without a spurious traceback.
        procs = list((getattr(ex, "_processes", None) or {}).values())
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.join(timeout=5)
        ex.shutdown(wait=False)
        raise
    ex.shutdown(wait=True)
    return done_labels, failed
