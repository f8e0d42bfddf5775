"""``--cluster``: run the jobs of ``covviz bench`` and ``covviz tune`` on a Dask distributed cluster.

The cluster is given as

* ``tcp://host:8786``: a running scheduler (``dask scheduler``), with workers
  started by ``dask worker tcp://host:8786 --nthreads 1`` on each machine;
* ``path/to/scheduler.json``: its scheduler file (``dask scheduler --scheduler-file``);
* ``local:N``: a :class:`distributed.LocalCluster` of N worker processes on this machine.

Each Dask task runs one job in a fresh process (:func:`covviz.experiments.jobs.run_job_process`,
with one OpenCV/BLAS thread), so a result does not depend on which worker ran it
nor on what ran there before. The task returns the job's boxes and metrics; the
client (``covviz bench``) writes them, so workers need neither the results
folder nor a shared filesystem. They need covviz (the same version) and the
sequences at the path the client gives (the same path as on the client).

A worker that dies has its task run again by Dask on another worker (the
scheduler's ``distributed.scheduler.allowed-failures``, 3 by default); a job whose
own process died (the OOM killer) is submitted again up to ``retries`` times.
Workers that leave or join are logged and listed in the summary.

Dask and Optuna are the optional extra ``cluster`` (``pip install 'covviz[cluster]'``),
imported only here and in :mod:`covviz.experiments.tune`, only when asked for.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import uuid
from collections.abc import Iterator
from pathlib import Path

from covviz.errors import InputError
from covviz.experiments.jobs import Job, JobError, JobProcessDied, Outcome, run_job_process

__all__ = ["ClusterError", "DaskExecutor", "dask_executor", "require"]

log = logging.getLogger("covviz.experiments.cluster")

#: Seconds to wait for a scheduler to answer and for its first worker.
CONNECT_TIMEOUT = 30
#: The pip extra that brings Dask and Optuna.
EXTRA = "cluster"


class ClusterError(InputError):
    """A cluster that cannot be used (missing extra, no scheduler, no workers): one line, exit code 2."""


def require(module: str, what: str):
    """Import ``module`` of the ``cluster`` extra, or raise a one-line :class:`ClusterError` naming it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ClusterError(
            f"{what} needs the optional extra '{EXTRA}' ({module.split('.')[0]} is not installed): "
            f"pip install 'covviz[{EXTRA}]'"
        ) from None


def _task(job: Job, threads: int, executor: str, slots: int):
    """What a Dask worker runs: the job in a fresh process; returns (output, worker address)."""
    from distributed import get_worker

    output = run_job_process(job, threads, executor, slots)
    return output, get_worker().address


class DaskExecutor:
    """Runs jobs as Dask tasks, one per worker thread (see the module docstring).

    Parameters
    ----------
    client : distributed.Client
    retries : int
        Times a job whose process died (or whose worker Dask gave up on) is submitted again.
    cluster : distributed.LocalCluster, optional
        Closed with the executor (``local:N``).
    name : str
        Written into every result's ``bench.executor``.
    """

    threads = 1

    def __init__(self, client, retries: int = 1, cluster=None, name: str = "dask"):
        self.client = client
        self.cluster = cluster
        self.retries = int(retries)
        self.name = name
        self.events: list[str] = []
        self._workers = dict(client.nthreads())
        self.slots = max(1, sum(self._workers.values()))

    def _watch_workers(self) -> None:
        """Log the workers that left or joined since the last look."""
        try:
            now = dict(self.client.nthreads())
        except Exception:  # noqa: BLE001 - the scheduler may be busy; look again next time
            return
        for addr in sorted(set(self._workers) - set(now)):
            msg = f"worker {addr} left the cluster ({len(now)} left); Dask runs its jobs elsewhere"
            log.warning("%s", msg)
            self.events.append(msg)
        for addr in sorted(set(now) - set(self._workers)):
            log.info("worker %s joined the cluster (%d now)", addr, len(now))
        self._workers = now

    def run(self, jobs: list[Job]) -> Iterator[Outcome]:
        import distributed
        from distributed.scheduler import KilledWorker

        run_id = uuid.uuid4().hex[:8]
        futures: dict = {}  # future -> (job, attempt)

        def submit(job: Job, attempt: int, priority: int):
            fut = self.client.submit(
                _task, job, self.threads, self.name, self.slots,
                key=f"covviz-{run_id}-{job.label}-a{attempt}", pure=False, priority=priority,
            )
            futures[fut] = (job, attempt)
            return fut

        priorities = {job: len(jobs) - i for i, job in enumerate(jobs)}  # the order given: longest first
        pending = {submit(job, 1, priorities[job]) for job in jobs}
        try:
            while pending:
                try:
                    done, pending = distributed.wait(pending, timeout=1.0, return_when="FIRST_COMPLETED")
                except TimeoutError:
                    self._watch_workers()
                    continue
                self._watch_workers()
                pending = set(pending)
                for fut in sorted(done, key=lambda f: futures[f][0].label):
                    job, attempt = futures.pop(fut)
                    if fut.status == "finished":
                        output, worker = fut.result()
                        yield Outcome(job, output=output, attempts=attempt, worker=worker)
                        continue
                    exc = fut.exception() if fut.status == "error" else JobProcessDied("cancelled on the cluster")
                    lost = isinstance(exc, (KilledWorker, JobProcessDied))
                    if lost and attempt <= self.retries:
                        msg = f"{job.label}: {exc}; running it again (attempt {attempt + 1})"
                        log.warning("%s", msg)
                        self.events.append(msg)
                        pending.add(submit(job, attempt + 1, priorities[job]))
                    elif isinstance(exc, JobError) and not lost:
                        yield Outcome(job, error=str(exc), attempts=attempt)
                    else:
                        yield Outcome(job, error=f"{exc.__class__.__name__}: {exc}", lost=lost, attempts=attempt)
        finally:
            if futures:
                # Tasks not yet started are dropped; a started one finishes on its worker (its
                # process ends with the worker, or when the job is done) and its result is dropped.
                with contextlib.suppress(Exception):
                    self.client.cancel(list(futures), force=True)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.client.close()
        if self.cluster is not None:
            with contextlib.suppress(Exception):
                self.cluster.close()


@contextlib.contextmanager
def _sigint_ignored():
    """Ignore SIGINT while the block starts processes (main thread only).

    A process started meanwhile keeps SIGINT ignored (Python installs no
    KeyboardInterrupt handler then), so the LocalCluster's workers, in our process
    group, do not die with tracebacks on a terminal's Ctrl-C; this process
    handles it and closes them.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def dask_executor(spec: str, retries: int = 1) -> DaskExecutor:
    """Connect to the cluster ``spec`` (see the module docstring) and wait for a worker.

    Raises
    ------
    ClusterError
        Without the ``cluster`` extra, on a bad ``local:N``, or when no scheduler
        or no worker answers within :data:`CONNECT_TIMEOUT` seconds.
    """
    require("distributed", "--cluster")
    from distributed import Client, LocalCluster

    if not log.isEnabledFor(logging.DEBUG):  # Dask's own INFO lines (nannies, comms) drown the bench's
        logging.getLogger("distributed").setLevel(logging.WARNING)

    cluster = None
    spec = str(spec).strip()
    try:
        if spec.startswith("local:"):
            try:
                n = int(spec.split(":", 1)[1])
                if n < 1:
                    raise ValueError
            except ValueError:
                raise ClusterError(f"--cluster {spec}: expected local:N with N >= 1 worker processes") from None
            # One thread per worker (each runs one job process at a time); the scheduler's HTTP server
            # (always started) on a free loopback port, so that two of these never clash on 8787.
            with _sigint_ignored():  # the workers inherit it: a terminal's Ctrl-C is ours to handle
                cluster = LocalCluster(
                    n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                    dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR,
                )
            client = Client(cluster)
            name = f"dask:local:{n}"
        elif spec.endswith(".json"):
            if not Path(spec).is_file():
                raise ClusterError(f"--cluster {spec}: no such scheduler file")
            client = Client(scheduler_file=spec, timeout=CONNECT_TIMEOUT)
            name = f"dask:{client.scheduler.address}"
        else:
            address = spec if "://" in spec else f"tcp://{spec}"
            client = Client(address, timeout=CONNECT_TIMEOUT)
            name = f"dask:{address}"
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        raise ClusterError(
            f"--cluster {spec}: no Dask scheduler answers ({exc.__class__.__name__}); start one with "
            "'dask scheduler' and workers with 'dask worker ADDRESS --nthreads 1', or use --cluster local:N"
        ) from None
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
    except (TimeoutError, OSError):
        client.close()
        if cluster is not None:
            cluster.close()
        raise ClusterError(
            f"--cluster {spec}: the scheduler has no worker after {CONNECT_TIMEOUT} s; start some with "
            f"'dask worker {spec} --nthreads 1'"
        ) from None
    ex = DaskExecutor(client, retries=retries, cluster=cluster, name=name)
    log.info("cluster %s: %d workers, %d jobs at a time", name, len(ex._workers), ex.slots)
    return ex
