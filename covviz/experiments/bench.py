"""``covviz bench``: every tracker on every sequence under a folder, results on disk, a report.

The flow is got-10k's (run → results on disk → report)::

    ROOT/<sequence>/...        OTB (img/ + groundtruth_rect.txt) or VOT (groundtruth.txt) folders
        │  one job per (sequence, tracker, seed), longest first, each in a fresh process
        │  (covviz.experiments.jobs), J at a time here or on a Dask cluster (covviz.experiments.cluster); results come back
        ▼
    OUT/<sequence>/<tracker>_s<seed>.txt|.json   (covviz.experiments.results; deterministic trackers: <tracker>.txt|.json)
    OUT/bench_manifest.json                      what this folder holds: root, trackers, seeds, ...
        │  covviz report OUT (covviz.experiments.report): reads the files only
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
    Every job runs in a fresh process (:mod:`covviz.experiments.jobs`): OpenCV's MIL and TLD
    keep random state between runs in one process, so this is what makes every
    result independent of job order and placement. Locally (the default),
    J jobs at a time, each with ``cpu_count // J`` OpenCV/BLAS threads; on a
    Dask cluster (``cluster=``, :mod:`covviz.experiments.cluster`), one job per worker
    thread, each with one. A job whose process dies (killed by a signal, e.g.
    the OOM killer, or lost with its worker) is run again up to ``retries``
    times; after that only that job fails, the others run. Ctrl-C ends the
    running jobs within seconds; finished results stay.

Resuming
    Every job returns its boxes and metrics to this process, which writes its
    result atomically (:func:`covviz.experiments.results.save_result`) as soon as it
    finishes: workers need no access to the results folder. A job whose result already exists,
    loads, covers the expected frames and was made with the same tracker config is
    skipped, so re-running an interrupted bench runs only what is missing. Running
    again with more trackers or seeds adds them to the same folder and report.

The manifest
    ``bench_manifest.json`` names the run: ``root``, ``max_frames``,
    ``particles`` and the covviz version must match for a folder to be reused;
    otherwise the bench stops with a one-line error (use ``--force`` to re-run
    everything into that folder, or a new ``--out``). One bench at a time
    writes into a folder (a lock on ``OUT/.covviz-bench.lock``); a second one
    stops with a one-line error.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import sys
from collections import deque
from collections.abc import Iterator
from collections.abc import Sequence as Seq
from dataclasses import replace
from pathlib import Path

from covviz import __version__
from covviz.errors import InputError
from covviz.experiments.jobs import (
    Job,
    JobError,
    JobOutput,
    JobProcess,
    JobProcessDied,
    Outcome,
    sigint_deferred,
)
from covviz.experiments.results import MANIFEST_FORMAT, MANIFEST_NAME, read_manifest, write_manifest

__all__ = [
    "BenchError",
    "Job",
    "LocalExecutor",
    "bench",
    "find_sequences",
    "lock_results_folder",
    "make_executor",
    "plan_jobs",
    "read_sequences",
    "save_output",
]

log = logging.getLogger("covviz.experiments.bench")

#: Manifest fields that define a run: results made with other values are not comparable.
IDENTITY_FIELDS = ("root", "max_frames", "particles", "covviz")


class BenchError(InputError):
    """Bad input to ``bench`` or ``report``: printed as one line, exit code 2."""


# --------------------------------------------------------------------------- #
# sequences and jobs
# --------------------------------------------------------------------------- #
def _is_sequence_dir(p: Path) -> bool:
    return (p / "img").is_dir() or (p / "groundtruth.txt").is_file()


def _is_results_dir(p: Path) -> bool:
    """A bench's results folder (its report's ``img/`` would make it look like an OTB sequence)."""
    return (p / MANIFEST_NAME).is_file()


def find_sequences(root: str | Path, exclude: Seq[str | Path] = ()) -> list[Path]:
    """Every sequence folder under ``root`` (or ``[root]`` if it is one), sorted by name.

    A sequence folder holds ``img/`` (OTB) or ``groundtruth.txt`` (VOT). Folders
    are searched recursively (following symlinks), but not inside a sequence;
    hidden folders, bench results folders (with a ``bench_manifest.json``) and
    the folders in ``exclude`` (a bench's ``--out`` inside ``root``) are skipped.

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
    seen: set[str] = {os.path.realpath(p) for p in exclude}  # real paths: symlinks followed, loops not
    seen.discard(os.path.realpath(root))
    for dirpath, dirnames, _ in os.walk(root, followlinks=True):
        d = Path(dirpath)
        real = os.path.realpath(d)
        if real in seen or (d != root and _is_results_dir(d)):
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


def read_sequences(root: str | Path, exclude: Seq[str | Path] = ()) -> dict[str, tuple[str, int]]:
    """name -> (path, number of frames) of every sequence under ``root`` (:func:`find_sequences`).

    Fails early, with the sequence's name, on a folder that cannot be read.

    Raises
    ------
    BenchError
    """
    from covviz.data.sequences import SequenceError, open_sequence

    sequences: dict[str, tuple[str, int]] = {}
    for p in find_sequences(root, exclude=exclude):
        try:
            seq = open_sequence(p)
            if len(seq) < 2:
                raise SequenceError(f"{p}: a sequence needs at least 2 frames, found {len(seq)}")
            seq.init_box  # noqa: B018 - raises if the first frame has no ground truth
        except SequenceError as exc:
            raise BenchError(f"sequence {p.name}: {exc}") from None
        sequences[seq.name] = (str(p), len(seq))
    return sequences


def plan_jobs(
    sequences: dict[str, tuple[str, int]],
    trackers: Seq[str],
    seeds: int,
    particles: int | None = None,
    max_frames: int | None = None,
    config: dict | None = None,
    variant_configs: dict[str, dict] | None = None,
    counterfactual: bool = False,
) -> list[Job]:
    """Every (sequence, tracker, seed) job, longest first.

    Parameters
    ----------
    sequences : dict
        name -> (path, number of frames).
    trackers : sequence of str
    seeds : int
        Seeds ``0 … seeds-1`` for the stochastic trackers; one run (seed None) for the others.
    config : dict, optional
        A ManifoldConfig's ``as_dict()`` for the trackers of :data:`covviz.trackers.CONFIGURABLE`.
    variant_configs : dict, optional
        Variant name (``manifold@b``) -> the ``as_dict()`` of its own config file, used instead of ``config``.

    Returns
    -------
    list of Job, sorted by frames to run (descending), stochastic trackers first
    among equals (they are the slow ones), then by name: the longest jobs start
    first so that the last to finish are short.
    """
    from covviz.trackers import STOCHASTIC
    from covviz.trackers.variants import base_name

    jobs = []
    for name, (path, n) in sequences.items():
        n_run = n if max_frames is None else min(n, max_frames)
        for tr in trackers:
            text = _config_text(tr, config, variant_configs)
            for s in range(seeds) if base_name(tr) in STOCHASTIC else [None]:
                jobs.append(Job(name, path, n_run, tr, s, particles, max_frames, text, counterfactual))
    return sorted(
        jobs, key=lambda j: (-j.n_frames, base_name(j.tracker) not in STOCHASTIC, j.sequence, j.tracker, j.seed or 0)
    )


def _config_text(tracker: str, config: dict | None, variant_configs: dict[str, dict] | None) -> str | None:
    """The config (JSON text) a job of ``tracker`` runs with: its variant's file, else ``config`` if it takes one."""
    from covviz.trackers import CONFIGURABLE
    from covviz.trackers.variants import base_name

    own = (variant_configs or {}).get(tracker)
    if own is not None:
        return _canonical(own)
    return _canonical(config) if config is not None and base_name(tracker) in CONFIGURABLE else None


def _jsonable(obj):
    """What ``obj`` becomes after a round trip through a results JSON (to compare configs)."""
    from covviz.experiments.results import _json_default

    return json.loads(json.dumps(obj, default=_json_default, allow_nan=True))


def _canonical(obj) -> str:
    """A config as sorted JSON text: equal configs give equal text (NaN included)."""
    return json.dumps(obj, sort_keys=True, allow_nan=True)


def _same_config(saved, current) -> bool:
    """Whether a saved result's config is ``current``: equal once the fields of
    :data:`covviz.trackers.manifold.NEUTRAL_FIELDS` at their neutral value are left out of both (a result
    saved before such a field existed, or after it was removed, was made by the same tracker)."""
    from covviz.trackers.manifold import NEUTRAL_FIELDS

    def strip(c):
        if not isinstance(c, dict):
            return c
        return {k: v for k, v in c.items() if not (k in NEUTRAL_FIELDS and v == NEUTRAL_FIELDS[k])}

    return _canonical(strip(saved)) == _canonical(strip(current))


def tracker_configs(
    trackers: Seq[str], particles: int | None, config: dict | None = None, variant_configs: dict | None = None
) -> dict[str, dict]:
    """The config each tracker would run with (builds each once; no frame is read)."""
    out = {}
    for name in trackers:
        job = Job("", "", 0, name, 0, particles, None, _config_text(name, config, variant_configs))
        try:
            tr = job.make_tracker()
        except ValueError:
            raise
        except Exception as exc:  # noqa: BLE001 - e.g. a tracker module that does not import
            raise BenchError(f"cannot build tracker {name!r}: {exc.__class__.__name__}: {exc}") from None
        out[name] = _jsonable(tr.config_dict() if hasattr(tr, "config_dict") else {})
    return out


# --------------------------------------------------------------------------- #
# running jobs: the local executor (covviz.experiments.cluster has the Dask one)
# --------------------------------------------------------------------------- #
def save_output(output: JobOutput, out_dir: str | Path) -> dict:
    """Write a job's result (atomically, Ctrl-C held back for the rename); return its JSON dict."""
    from covviz.experiments.results import save_result

    with sigint_deferred():
        return save_result(output.result, out_dir, output.extra)


class LocalExecutor:
    """``slots`` jobs at a time on this machine, each in a fresh process (:class:`covviz.experiments.jobs.JobProcess`).

    Each job gets ``max(1, cpu_count // slots)`` OpenCV/BLAS threads. A job whose
    process dies (a signal: the OOM killer, a kill by hand) is run again up to
    ``retries`` times, then reported as failed; the other jobs are not affected.
    """

    def __init__(self, slots: int = 1, retries: int = 1):
        self.slots = int(slots)
        self.threads = max(1, (os.cpu_count() or 1) // self.slots)
        self.retries = int(retries)
        self.name = f"local:{self.slots}"
        self.events: list[str] = []

    def run(self, jobs: list[Job]) -> Iterator[Outcome]:
        import select

        queue = deque((job, 1) for job in jobs)
        running: dict[JobProcess, int] = {}  # process -> attempt
        try:
            while queue or running:
                while queue and len(running) < self.slots:
                    job, attempt = queue.popleft()
                    running[JobProcess(job, self.threads, self.name, self.slots)] = attempt
                ready = select.select(list(running), [], [], 1.0)[0]
                for proc in sorted(ready, key=lambda p: p.job.label):
                    attempt = running.pop(proc)
                    try:
                        output = proc.collect()
                    except JobProcessDied as exc:
                        if attempt <= self.retries:
                            msg = f"{proc.job.label}: {exc}; running it again (attempt {attempt + 1})"
                            log.warning("%s", msg)
                            self.events.append(msg)
                            queue.appendleft((proc.job, attempt + 1))
                            continue
                        yield Outcome(proc.job, error=f"{exc.__class__.__name__}: {exc}", lost=True, attempts=attempt)
                    except JobError as exc:
                        yield Outcome(proc.job, error=str(exc), attempts=attempt)
                    else:
                        yield Outcome(proc.job, output=output, attempts=attempt, worker="local")
        finally:
            _end_processes(list(running))

    def close(self) -> None:
        pass


def _end_processes(procs: list[JobProcess]) -> None:
    """Kill the running job processes and reap them; a second Ctrl-C meanwhile is ignored."""
    if not procs:
        return
    import signal
    import threading

    main = threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        for proc in procs:
            proc.kill()
    finally:
        if main:
            signal.signal(signal.SIGINT, old)


def make_executor(cluster: str | None = None, jobs: int = 1, retries: int = 1):
    """The executor of ``--cluster`` (:func:`covviz.experiments.cluster.dask_executor`), or the local pool of ``--jobs``."""
    if cluster is None:
        return LocalExecutor(jobs, retries=retries)
    from covviz.experiments.cluster import dask_executor

    return dask_executor(cluster, retries=retries)


@contextlib.contextmanager
def lock_results_folder(out: Path):
    """Hold ``out/.covviz-bench.lock`` for the block: one bench at a time writes into a folder.

    The lock (``flock``) goes with the process, so a killed bench leaves none behind.

    Raises
    ------
    BenchError
        If another process holds it.
    """
    import fcntl

    path = out / ".covviz-bench.lock"
    fh = open(path, "a+")  # noqa: SIM115 - held for the block
    try:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            fh.seek(0)
            who = fh.read().strip() or "another process"
            raise BenchError(
                f"another covviz bench is writing into {out} ({who}); wait for it to finish, "
                "or choose another --out"
            ) from None
        fh.seek(0)
        fh.truncate()
        fh.write(f"pid {os.getpid()}\n")
        fh.flush()
        yield
    finally:
        fh.close()


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


def _read_or_rebuild_manifest(out: Path, new: dict, sequences: dict[str, tuple[str, int]]) -> dict | None:
    """The manifest of ``out``; a corrupt or deleted one rebuilt from the bench results it describes.

    Every result a bench writes names its sequence's path, its tracker, seed,
    config and covviz version, which is all a manifest holds besides the
    settings of the command; so when those results are all of this command's
    sequences and covviz version, the manifest is rebuilt from them (the
    corrupt file kept as ``bench_manifest.json.corrupt``) and the finished jobs
    are not run again. Results from ``covviz track`` or of other sequences
    leave the folder as it was, with the error saying why.
    """
    from covviz.experiments.results import FORMAT, ResultError

    try:
        found = read_manifest(out)
        if found is not None or not _existing_results(out):
            return found
        corrupt = f"{out} holds results but no {MANIFEST_NAME}"
    except ResultError as exc:
        if "corrupt" not in str(exc):
            raise
        corrupt = f"{out / MANIFEST_NAME}: corrupt bench manifest"
    docs = []
    for js in _existing_results(out):
        try:
            doc = json.loads(js.read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError):
            doc = None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT or "bench" not in doc:
            raise BenchError(f"{corrupt}, and it cannot be rebuilt: {js} is not a bench result (from 'covviz track' "
                             "or another tool?); choose a new --out or use --force")
        path = (doc.get("bench") or {}).get("path")
        if doc.get("sequence") not in sequences or path != sequences[doc["sequence"]][0]:
            raise BenchError(f"{corrupt}, and it cannot be rebuilt: {js} is of {path}, not a sequence under {new['root']} "
                             "(choose a new --out, or use --force)")
        if (doc.get("versions") or {}).get("covviz") != new["covviz"]:
            raise BenchError(f"{corrupt}, and it cannot be rebuilt: {js} was made by covviz "
                             f"{(doc.get('versions') or {}).get('covviz')} (choose a new --out, or use --force)")
        docs.append(doc)
    if not docs:
        log.warning("%s: corrupt, and no results beside it; starting afresh", out / MANIFEST_NAME)
        return None
    trackers = list(dict.fromkeys(d["tracker"] for d in sorted(docs, key=lambda d: d["tracker"])))
    seeds = [d["seed"] for d in docs if d.get("seed") is not None]
    rebuilt = {**new, "trackers": trackers, "seeds": max(seeds) + 1 if seeds else 1,
               "configs": {d["tracker"]: d.get("config") for d in docs}}
    how = "it was missing"
    if (out / MANIFEST_NAME).exists():
        try:
            os.replace(out / MANIFEST_NAME, out / (MANIFEST_NAME + ".corrupt"))
            how = f"the corrupt file is kept as {MANIFEST_NAME}.corrupt"
        except OSError:
            how = "the corrupt file is replaced"
    log.warning("%s: rebuilt from the %d results it describes (%s); finished jobs are not run again",
                out / MANIFEST_NAME, len(docs), how)
    return rebuilt


def _is_done(job: Job, out: Path, config: dict) -> bool:
    """Whether ``job``'s result exists and is complete; raises on a corrupt or foreign one."""
    from covviz.experiments.results import load_result, result_paths

    _, js = result_paths(out, job.sequence, job.tracker, job.seed)
    if not js.exists():
        return False
    doc, _ = load_result(js)  # ResultError (a BenchError's sibling ValueError) on a corrupt file
    if doc.get("interrupted") or doc.get("n_frames") != job.n_frames:
        log.info("%s: the result in %s is incomplete; running it again", job.label, js)
        return False
    if not _same_config(doc.get("config"), config):
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
    config: dict | None = None,
    cluster: str | None = None,
    retries: int = 1,
    executor=None,
    counterfactual: bool = False,
    detector: str | None = None,
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
        Jobs at a time on this machine, each in a fresh process with
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
    config : dict, optional
        A ManifoldConfig's fields (``as_dict()``, or a subset) for the trackers of
        :data:`covviz.trackers.CONFIGURABLE` (``--config``); ``particles`` overrides its count.
    cluster : str, optional
        Run the jobs on a Dask cluster (:func:`covviz.experiments.cluster.dask_executor`:
        ``tcp://host:8786``, a scheduler file, or ``local:N``); ``jobs`` is then unused.
    retries : int
        Times a job whose process died is run again before it counts as failed.
    executor : Executor, optional
        Run the jobs with this one (:class:`LocalExecutor`, a Dask one) instead of
        making one from ``jobs``/``cluster``; it is not closed.
    counterfactual : bool
        Replay every loss inside its job (:mod:`covviz.diagnosis.counterfactual`).
    detector : str, optional
        A drift model's JSON text (``covviz calibrate``) for every job; None: the shipped models.

    Returns
    -------
    dict with ``run`` (count) and ``ran`` (labels) of the jobs done now, ``skipped``, ``failed``
    (list of (label, message)), ``events`` (lost workers, retried jobs) and ``report`` (path or None).

    Raises
    ------
    BenchError
        Empty root, unknown tracker, a folder from another run, a corrupt result.
    """
    from covviz.trackers.variants import VARIANT_SEP, parse_specs

    try:
        specs = parse_specs(trackers)
        # a variant (manifold@b.json) runs with its own file, named manifold@b in results and report
        variant_configs = {s.name: s.config_dict() for s in specs if s.config_path is not None}
    except ValueError as exc:
        raise BenchError(str(exc)) from None
    trackers = [s.name for s in specs]
    if seeds < 1 or jobs < 1 or retries < 0:
        raise BenchError("--seeds and --jobs must be at least 1, --retries at least 0")
    root = Path(root).resolve()
    out = Path(out)
    if config is not None:
        from covviz.trackers import CONFIGURABLE

        if not {t for t in trackers if VARIANT_SEP not in t} & CONFIGURABLE:
            raise BenchError(f"--config sets a ManifoldConfig: it needs one of {', '.join(sorted(CONFIGURABLE))} "
                             "without an @FILE.json of its own")

    sequences = read_sequences(root, exclude=[out])

    configs = tracker_configs(trackers, particles, config, variant_configs)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".covviz-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise BenchError(f"cannot write to {out}: {exc.strerror or exc}; choose another --out") from None
    with lock_results_folder(out):
        return _bench_locked(
            root, out, sequences, trackers, configs, seeds, jobs, max_frames, particles, force, progress,
            report, config, cluster, retries, executor, variant_configs, counterfactual, detector,
        )


def _bench_locked(
    root, out, sequences, trackers, configs, seeds, jobs, max_frames, particles, force, progress, report,
    config, cluster, retries, executor, variant_configs=None, counterfactual=False, detector=None,
) -> dict:
    from covviz.trackers import STOCHASTIC
    from covviz.trackers.variants import base_name

    manifest = {
        "format": MANIFEST_FORMAT,
        "covviz": __version__,
        "root": str(root),
        "sequences": {k: v[1] for k, v in sequences.items()},
        "trackers": trackers,
        "stochastic": sorted(t for t in trackers if base_name(t) in STOCHASTIC),
        "seeds": seeds,
        "seed_rule": "stochastic trackers: seeds 0..seeds-1, "
        "rng = default_rng(SeedSequence(seed).spawn(1)[0]); "
        "others: one run, seed null",
        "max_frames": max_frames,
        "particles": particles,
    }
    old = None if force else _read_or_rebuild_manifest(out, manifest, sequences)  # --force replaces a corrupt one
    manifest = _merge_manifest(old, manifest, out, force)
    manifest["stochastic"] = sorted(t for t in manifest["trackers"] if base_name(t) in STOCHASTIC)
    manifest["configs"] = {**((old or {}).get("configs") or {}), **configs}

    all_jobs = plan_jobs(sequences, trackers, seeds, particles, max_frames, config, variant_configs, counterfactual)
    if detector is not None:  # every job's drift model (a covviz calibrate file's text)
        all_jobs = [replace(j, detector=detector) for j in all_jobs]
    todo = all_jobs if force else [j for j in all_jobs if not _is_done(j, out, configs[j.tracker])]
    skipped = len(all_jobs) - len(todo)
    write_manifest(out, manifest)
    if skipped:
        log.info(
            "%d of %d jobs already done in %s; running the other %d", skipped, len(all_jobs), out, len(todo)
        )

    if todo and any(j.tracker.startswith("manifold") for j in todo) and (cluster is None or cluster.startswith("local:")):
        from covviz.model import kernels

        # Once here, not in every fresh job process at the same time (the compiled code is cached on disk).
        kernels.warmup(lambda: log.info("compiling kernels (once; about 20-40 s, then cached)..."))
    from covviz.signals import check as check_signals

    check_signals()  # a Ctrl-C while numba compiled is swallowed by its ctypes callback: it stops here
    ran: list[str] = []
    failed: list[tuple[str, str]] = []
    events: list[str] = []
    if todo:
        ex = executor if executor is not None else make_executor(cluster, min(jobs, len(todo)), retries)
        try:
            with contextlib.closing(run_with_progress(ex, todo, progress, "bench")) as outcomes:
                for outcome in outcomes:
                    check_signals()
                    if outcome.output is not None:
                        save_output(outcome.output, out)
                        ran.append(outcome.job.label)
                    else:
                        failed.append((outcome.job.label, outcome.error or "unknown error"))
                        log.error("%s failed: %s", outcome.job.label, outcome.error)
        except KeyboardInterrupt:
            log.warning("interrupted: finished results are kept in %s; run the same command to resume", out)
            raise
        finally:
            events = list(ex.events)
            if executor is None:
                ex.close()
    rep = None
    if report:
        from covviz.experiments.report import write_report

        rep = write_report(out)
        log.info("report: %s", rep)
    return {"run": len(ran), "ran": ran, "skipped": skipped, "failed": failed, "events": events, "report": rep}


def run_with_progress(executor, jobs: list[Job], progress: bool = True, desc: str = "bench") -> Iterator[Outcome]:
    """``executor.run(jobs)`` with a progress bar over jobs on stderr; stops the jobs on any exit."""
    from tqdm import tqdm
    from tqdm.contrib.logging import logging_redirect_tqdm

    bar = tqdm(total=len(jobs), unit="job", desc=desc, file=sys.stderr, disable=not progress, dynamic_ncols=True)
    with bar, logging_redirect_tqdm(), contextlib.closing(executor.run(jobs)) as outcomes:
        for outcome in outcomes:
            bar.set_postfix_str(outcome.job.label)
            bar.update(1)
            yield outcome
