"""One tracker run as a job, run in a fresh process: the unit of work of ``covviz bench`` and ``covviz tune``.

A :class:`Job` names a tracker, a seed and a sequence path; :func:`compute_job`
runs it and returns its boxes and metrics as a :class:`JobOutput`, which the
caller (the bench's client) writes to disk. Nothing here writes results, so a
job can run on a machine that does not see the results folder.

Every job runs in a fresh Python process, ``python -m covviz.experiments.jobs LABEL``
(:class:`JobProcess`): OpenCV's MIL and TLD keep random state between runs in
one process, so a fresh process is what makes a result independent of which
jobs ran before it and where (a local slot or any Dask worker). The process

* reads its job from stdin (a pickle) and writes its output to stdout (a
  pickle; anything the job prints goes to stderr);
* runs in its own process group, so a Ctrl-C at the terminal reaches only the
  command that started it, which then ends its jobs;
* ends itself when its parent goes away (stdin closes), so a killed bench or a
  lost Dask worker leaves no job running.

Starting a fresh interpreter costs ~0.5 s (numpy, OpenCV and scipy imports), and
~1 s more for the manifold trackers (numba, and their kernels from its cache): small
against a real job, not against a test's 10-frame one. The executors that run many jobs (a local pool, a Dask cluster)
share one interface, :class:`Executor`.
"""

from __future__ import annotations

import contextlib
import json
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from covviz.runner import Observer

__all__ = [
    "Executor",
    "Job",
    "JobError",
    "JobOutput",
    "JobProcess",
    "JobProcessDied",
    "Outcome",
    "compute_job",
    "run_job_process",
    "sigint_deferred",
]

#: Lines of a failed job's stderr kept in its error message.
STDERR_TAIL_LINES = 5


@dataclass(frozen=True)
class Job:
    """One tracker run: ``tracker`` with ``seed`` on the sequence at ``path``.

    ``config``: the tracker's config as JSON text (a ManifoldConfig's
    ``as_dict()``; trackers of :data:`covviz.trackers.CONFIGURABLE` only), or
    None for the tracker's defaults. ``counterfactual``: replay every loss
    (:mod:`covviz.diagnosis.counterfactual`) after the run, inside the job.
    """

    sequence: str
    path: str
    n_frames: int
    tracker: str
    seed: int | None
    particles: int | None
    max_frames: int | None
    config: str | None = None
    counterfactual: bool = False
    detector: str | None = None  # a drift model's JSON text (covviz bench --detector), None: the shipped ones

    @property
    def label(self) -> str:
        return f"{self.sequence}/{self.tracker}" + ("" if self.seed is None else f"/s{self.seed}")

    def make_tracker(self):
        """The job's tracker, with the stream of its seed (:func:`covviz.trackers.tracker_rng`)."""
        from covviz.trackers import make_tracker
        from covviz.trackers.variants import base_name

        config = None
        if self.config is not None:
            from covviz.trackers.manifold import ManifoldConfig

            config = ManifoldConfig.from_dict(json.loads(self.config))
        # a variant (manifold@b) is its registry tracker with its own config, under its own name
        tr = make_tracker(base_name(self.tracker), seed=self.seed, n_particles=self.particles, config=config)
        if base_name(self.tracker) != self.tracker:
            tr.name = self.tracker
        return tr


@dataclass(frozen=True)
class JobOutput:
    """What a job returns: its :class:`~covviz.records.RunResult` and the extra JSON fields of its result."""

    result: object  # covviz.records.RunResult
    extra: dict

    @property
    def success_auc(self) -> float:
        """The run's success AUC (as in its results JSON)."""
        from covviz.metrics import evaluate

        return evaluate(self.result.boxes, self.result.groundtruth).success_auc


@dataclass(frozen=True)
class Outcome:
    """A finished job: ``output`` or ``error`` (``"ExceptionClass: message"``).

    ``lost``: the job's process died (killed by a signal, e.g. the OOM killer, or
    its worker was lost) on its last allowed attempt; ``attempts``: processes it took.
    """

    job: Job
    output: JobOutput | None = None
    error: str | None = None
    lost: bool = False
    attempts: int = 1
    worker: str | None = None


class Executor(Protocol):
    """Runs jobs, each in a fresh process (:class:`JobProcess`); a local pool or a Dask cluster."""

    #: What runs the jobs, written into every result (``local:2``, ``dask:tcp://host:8786``).
    name: str
    #: Jobs at a time.
    slots: int
    #: OpenCV/BLAS threads of each job.
    threads: int
    #: Times a job whose process died is run again before it counts as failed.
    retries: int
    #: Messages about the run (a lost worker, a retried job), for the summary.
    events: list[str]

    def run(self, jobs: list[Job]) -> Iterator[Outcome]:
        """Run ``jobs`` (started in this order), yield each as it finishes.

        Closing the iterator (or an exception, Ctrl-C included) stops the jobs
        still running within a few seconds.
        """
        ...

    def close(self) -> None: ...


class JobError(Exception):
    """A job raised an exception (the message is ``"ExceptionClass: message"``)."""


class JobProcessDied(JobError):
    """A job's process ended without an output: killed by a signal or lost with its worker."""


# --------------------------------------------------------------------------- #
# the job itself
# --------------------------------------------------------------------------- #
class _FailureCounter(Observer):
    """Observer: numbers (1-based) of the frames whose record says ``extras["failed"]`` (OpenCV trackers)."""

    def __init__(self) -> None:
        self.failed: list[int] = []

    def on_frame(self, frame, records, found) -> None:
        from covviz.records import frame_number

        if records and records[0].extras.get("failed"):
            self.failed.append(frame_number(frame.index))


def compute_job(job: Job, threads: int | None = None, executor: str = "local:1", slots: int = 1) -> JobOutput:
    """Run one job in this process and return its output (nothing is written).

    ``threads`` OpenCV/BLAS threads while it runs (None: as they are);
    ``executor`` and ``slots`` (jobs at a time) are recorded in the output's
    ``bench`` field, as the bench's settings.

    The extra fields are, besides the standard result fields: the OTB curves (so
    the report can plot them without the sequence), the thresholds they use, the
    frames on which the tracker reported a failure, the bench settings and the
    versions of this process.
    """


    from covviz.data.sequences import open_sequence
    from covviz.diagnosis.counterfactual import with_replays
    from covviz.diagnosis.detector import DriftModel, drift_watch
    from covviz.diagnosis.drift import Diagnoser
    from covviz.experiments.results import versions
    from covviz.metrics import (
        IOU_THRESHOLDS,
        ON_TRACK_GAMMA,
        PRECISION_AT,
        PRECISION_THRESHOLDS,
        precision_curve,
        success_curve,
    )
    from covviz.runner import BackgroundObserver, Pipeline, run
    from covviz.threads import limit_threads

    seq = open_sequence(job.path)
    seq.check_frames(len(seq) if job.max_frames is None else min(len(seq), job.max_frames))
    tracker = job.make_tracker()
    failures = _FailureCounter()
    diagnoser = Diagnoser(on_track_scores=False)  # nothing here shows the cloud's scores on on-track frames
    stages: list = [diagnoser]
    replays = None
    if job.counterfactual:
        from covviz.diagnosis.counterfactual import Counterfactuals

        replays = Counterfactuals([tracker], [job.make_tracker])
        stages.append(replays)
    watch = drift_watch(None if job.detector is None else DriftModel.from_dict(json.loads(job.detector)))
    t0 = time.perf_counter()
    with limit_threads(threads), contextlib.closing(tracker) if hasattr(tracker, "close") else contextlib.nullcontext():
        # The label-free detector and the drift diagnosis on one thread of their own, overlapping the
        # tracker (neither changes a box); the replays of the diagnosed losses after the last frame.
        res = run(tracker, seq, [failures, BackgroundObserver(Pipeline([watch, *stages]))],
                  max_frames=job.max_frames, seed=job.seed,
                  checkpoints=None if replays is None else replays.config.checkpoints)
    wall = time.perf_counter() - t0
    report = diagnoser.report(0)
    if replays is not None and replays.replays:
        with_replays(report, replays.replays[0], diagnoser.config.tie_ratio)
    extra = {
        "curves": {
            "iou_thresholds": IOU_THRESHOLDS,
            "success": success_curve(res.boxes, res.groundtruth),
            "precision_thresholds": PRECISION_THRESHOLDS,
            "precision": precision_curve(res.boxes, res.groundtruth),
        },
        "thresholds": {"precision_at": PRECISION_AT, "on_track_gamma": ON_TRACK_GAMMA},
        "failed_frames": failures.failed,
        "diagnosis": {**report, **watch.report(0, res)},
        "diagnosis_config": {**diagnoser.config.as_dict(), **watch.config_dict()},
        "bench": {
            "jobs": slots,
            "threads": threads,
            "wall_seconds": round(wall, 3),
            "path": job.path,
            "executor": executor,
        },
        "versions": versions(),
    }
    return JobOutput(res, extra)


# --------------------------------------------------------------------------- #
# a job in a fresh process
# --------------------------------------------------------------------------- #
def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def sigint_deferred():
    """Hold Ctrl-C (SIGINT) back for the block; it is raised right after, if it came.

    For the few steps that must not be cut in half: starting a process (so it
    is always known and can be ended), renaming a result into place. Only in
    the main thread (where Python handles signals); elsewhere a no-op.
    """
    if not _in_main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def describe_exit(code: int | None) -> str:
    """``"killed by SIGKILL (the OOM killer?)"`` / ``"exit code 3"`` for a process's return code."""
    if code is None:
        return "still running"
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        hint = " (the OOM killer, or killed by hand)" if -code == signal.SIGKILL else ""
        return f"killed by {name}{hint}"
    return f"exit code {code}"


def job_environment(env: dict | None = None) -> dict:
    """The environment of a job process: ``env`` (default: this one's) with this covviz first on its path.

    The folder that holds the ``covviz`` package this process imported goes
    first on ``PYTHONPATH`` (unless it is a site-packages folder, already on
    every path), so a job runs the same code as the command that started it:
    from a source tree, an editable install, or with a clone in the current
    folder.
    """
    import site

    import covviz

    env = dict(os.environ if env is None else env)
    root = str(Path(covviz.__file__).resolve().parents[1])
    sites = {str(Path(p).resolve()) for p in [*site.getsitepackages(), site.getusersitepackages()]}
    if root not in sites:
        rest = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and p != root]
        env["PYTHONPATH"] = os.pathsep.join([root, *rest])
    return env


class JobProcess:
    """One job in a fresh ``python -m covviz.experiments.jobs`` process (see the module docstring).

    Start it, wait until :meth:`fileno` is readable (or poll :meth:`done`), then
    :meth:`collect` its output. :meth:`kill` ends it at once.
    """

    def __init__(self, job: Job, threads: int | None, executor: str, slots: int, env: dict | None = None):
        self.job = job
        self.started = time.monotonic()
        self._stderr = tempfile.TemporaryFile()  # noqa: SIM115 - closed in _stderr_tail()
        with sigint_deferred():
            # -P: not the current folder first on the path, where a clone's folder called covviz would
            # be imported as an empty package; the covviz this process runs comes first instead.
            self._proc = subprocess.Popen(
                [sys.executable, "-P", "-m", "covviz.experiments.jobs", job.label],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=self._stderr,
                env=job_environment(env),
                process_group=0,  # a terminal's Ctrl-C reaches the command, which ends its jobs
                close_fds=True,
            )
        # The job, then stdin stays open: the process ends itself when it closes (we went away).
        try:
            self._proc.stdin.write(pickle.dumps((job, threads, executor, slots), protocol=pickle.HIGHEST_PROTOCOL))
            self._proc.stdin.flush()
        except OSError:  # it died at once (killed); collect() says how
            pass

    @property
    def pid(self) -> int:
        return self._proc.pid

    def fileno(self) -> int:
        """Readable when the output arrives or the process ends (for ``select``/``wait``)."""
        return self._proc.stdout.fileno()

    def done(self) -> bool:
        return self._proc.poll() is not None

    def collect(self) -> JobOutput:
        """The job's output, once :meth:`fileno` is readable (blocks until the process ends).

        Raises
        ------
        JobError
            If the job raised (the message is the exception's).
        JobProcessDied
            If the process ended without an output (the message says how).
        """
        data = self._proc.stdout.read()
        self._finish()
        msg = None
        if data:
            try:
                msg = pickle.loads(data)
            except Exception:  # noqa: BLE001 - a truncated output: the process died while writing
                msg = None
        if msg is None:
            raise JobProcessDied(f"its process ended without a result: {describe_exit(self._proc.returncode)}"
                                 f"{self._stderr_tail()}")
        kind, value = msg
        if kind == "ok":
            return value
        raise JobError(value)

    def kill(self) -> None:
        """End the process now (SIGKILL) and reap it."""
        with contextlib.suppress(ProcessLookupError):
            self._proc.kill()
        self._finish(timeout=5)

    def _finish(self, timeout: float = 30) -> None:
        for pipe in (self._proc.stdin, self._proc.stdout):
            with contextlib.suppress(OSError):
                pipe.close()
        try:
            self._proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()

    def _stderr_tail(self) -> str:
        try:
            self._stderr.seek(0)
            lines = self._stderr.read().decode(errors="replace").strip().splitlines()
        except OSError:
            return ""
        finally:
            self._stderr.close()
        tail = [ln for ln in lines if ln.strip()][-STDERR_TAIL_LINES:]
        return ("; its last output: " + " | ".join(tail)) if tail else ""


def run_job_process(job: Job, threads: int | None, executor: str, slots: int, poll: float = 0.2) -> JobOutput:
    """Run ``job`` in a fresh process and return its output (blocking): the task of a Dask worker.

    Raises :class:`JobError` or :class:`JobProcessDied` as :meth:`JobProcess.collect`.
    """
    import select

    proc = JobProcess(job, threads, executor, slots)
    try:
        while not select.select([proc], [], [], poll)[0]:
            pass
        return proc.collect()
    finally:
        if not proc.done():
            proc.kill()


# --------------------------------------------------------------------------- #
# the process side: python -m covviz.experiments.jobs LABEL
# --------------------------------------------------------------------------- #
def _exit_when_parent_goes(stdin) -> None:
    """Block until stdin closes (the parent ended or went away), then end this process."""
    with contextlib.suppress(Exception):
        while stdin.read(65536):
            pass
    os._exit(3)


def _main() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides when a job ends
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # whatever the job prints goes to stderr, not into the output
    stdin = sys.stdin.buffer
    job, threads, executor, slots = pickle.load(stdin)
    threading.Thread(target=_exit_when_parent_goes, args=(stdin,), daemon=True).start()
    try:
        msg = ("ok", compute_job(job, threads, executor, slots))
    except BaseException as exc:  # noqa: BLE001 - reported to the parent as the job's error
        msg = ("error", f"{exc.__class__.__name__}: {exc}")
    out.write(pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL))
    out.flush()
    os._exit(0)  # no interpreter shutdown: nothing is left to flush, and the tracker's threads need no join


if __name__ == "__main__":
    # Run the imported module's _main, not this __main__ copy's: the output's classes
    # must pickle as covviz.experiments.jobs.*, which the parent can load.
    from covviz.experiments.jobs import _main as main

    main()
