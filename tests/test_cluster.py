"""``covviz bench --cluster``: a real Dask scheduler and two workers on localhost.

The scheduler and the workers are the ``dask scheduler`` / ``dask worker``
commands, started once for the module (with the worktree's covviz on their
PYTHONPATH). What is compared with the local run (``--jobs 2``):

* every ``.txt`` box file, byte for byte;
* every result JSON, field by field, without ``fps``, ``times`` and ``bench``
  (timings, and the bench's settings: executor, jobs at a time, threads, wall time).

MIL is among the trackers because OpenCV's MIL keeps random state within a
process: equal results whatever worker ran a job (and after what) show that
every job runs in a fresh process.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from helpers import descendants, write_otb

import covviz
from covviz.cli import main
from covviz.experiments.bench import bench

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

PARTICLES = 20
FRAMES = {"alpha": 14, "beta": 10}
SEEDS = 2
TRACKERS = ["identity", "mil", "manifold"]
N_JOBS = len(FRAMES) * (2 + SEEDS)
ENV = {**os.environ, "PYTHONPATH": str(Path(covviz.__file__).resolve().parent.parent)}
#: Fields of a result JSON that are timings or the bench's settings (not compared).
TIMING_FIELDS = ("fps", "times", "bench")


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    r = tmp_path_factory.mktemp("clusterseq")
    for k, (name, n) in enumerate(FRAMES.items()):
        write_otb(r / name, n, seed=11 + k)
    return r


@pytest.fixture(scope="module")
def local(root, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("local") / "out"
    s = bench(root, TRACKERS, out, seeds=SEEDS, jobs=2, particles=PARTICLES, progress=False, report=False)
    assert s["run"] == N_JOBS and not s["failed"]
    return out


class DaskProcesses:
    """A scheduler and two single-thread workers (each a nanny and its worker process)."""

    def __init__(self, folder: Path):
        self.file = folder / "scheduler.json"
        self.log = open(folder / "dask.log", "w")  # noqa: SIM115 - closed in stop()
        self.scheduler = self._start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                     "--scheduler-file", str(self.file))
        # Dask writes the file in place (not by rename): it may exist before it holds the address.
        deadline = time.monotonic() + 60
        while (address := self._address()) is None:
            assert time.monotonic() < deadline and self.scheduler.poll() is None, "no scheduler"
            time.sleep(0.05)
        self.address = address
        self.workers = [
            self._start("worker", self.address, "--nthreads", "1", "--no-dashboard", "--name", f"w{i}",
                        "--host", "127.0.0.1")
            for i in range(2)
        ]
        from distributed import Client

        with Client(self.address, timeout=60) as c:
            c.wait_for_workers(2, timeout=60)

    def _address(self) -> str | None:
        try:
            return json.loads(self.file.read_text())["address"]
        except (OSError, ValueError, KeyError):  # not there yet, or half written
            return None

    def _start(self, *args: str) -> subprocess.Popen:
        return subprocess.Popen([sys.executable, "-m", "dask", *args], env=ENV, stdout=self.log,
                                stderr=subprocess.STDOUT, start_new_session=True)

    def worker_processes(self) -> list[int]:
        """The worker processes (children of the nannies)."""
        return [pid for w in self.workers for pid, cmd in descendants(w.pid).items()
                if "covviz.experiments.jobs" not in cmd and _ppid(pid) == w.pid]

    def stop(self) -> None:
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in [*self.workers, self.scheduler]:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        self.log.close()


def _ppid(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return -1


@pytest.fixture(scope="module")
def dask_procs(tmp_path_factory):
    d = DaskProcesses(tmp_path_factory.mktemp("dask"))
    yield d
    d.stop()


def comparable(out: Path) -> dict[str, object]:
    """Every .txt as bytes and every result JSON without its timing/settings fields."""
    got: dict[str, object] = {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.glob("*/*.txt"))}
    for js in sorted(out.glob("*/*.json")):
        doc = json.loads(js.read_text())
        got[str(js.relative_to(out))] = {k: v for k, v in doc.items() if k not in TIMING_FIELDS}
    return got


def test_cluster_bench_equals_the_local_one(root, local, dask_procs, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["bench", str(root), "--out", str(out), "--trackers", ",".join(TRACKERS), "--particles",
            str(PARTICLES), "--seeds", str(SEEDS), "--no-progress", "--no-report"]
    assert main([*argv, "--cluster", dask_procs.address]) == 0
    assert f"{N_JOBS} runs done" in capsys.readouterr().out
    assert comparable(out) == comparable(local)
    doc = json.loads((out / "alpha" / "mil.json").read_text())
    assert doc["bench"]["executor"] == f"dask:{dask_procs.address}" and doc["bench"]["threads"] == 1
    assert doc["bench"]["jobs"] == 2
    # the scheduler file works as an address; resuming skips everything
    assert main([*argv, "--cluster", str(dask_procs.file)]) == 0
    assert f"0 runs done, {N_JOBS} already done" in capsys.readouterr().out
    # and so does a report of the folder, as of a local bench
    assert main(["report", str(out)]) == 0


def test_a_worker_killed_mid_run(root, local, dask_procs, tmp_path):
    """SIGKILL one worker process while it runs a job: Dask runs its job elsewhere; every job finishes."""
    killed: list[int] = []
    stop = threading.Event()

    def killer():
        while not stop.is_set() and not killed:
            for pid in dask_procs.worker_processes():
                if any("covviz.experiments.jobs" in cmd for cmd in descendants(pid).values()):
                    time.sleep(0.2)
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                    return
            time.sleep(0.02)

    t = threading.Thread(target=killer, daemon=True)
    t.start()
    out = tmp_path / "out"
    try:
        s = bench(root, TRACKERS, out, seeds=SEEDS, particles=PARTICLES, progress=False, report=False,
                  cluster=dask_procs.address)
    finally:
        stop.set()
        t.join(5)
    assert killed, "no worker was killed"
    assert s["failed"] == [] and s["run"] == N_JOBS
    assert any("left the cluster" in e for e in s["events"]), s["events"]
    assert comparable(out) == comparable(local)
    # the nanny brings the worker back
    from distributed import Client

    with Client(dask_procs.address, timeout=30) as c:
        c.wait_for_workers(2, timeout=60)


def test_local_cluster(root, local, tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["bench", str(root), "--out", str(out), "--trackers", ",".join(TRACKERS), "--particles",
            str(PARTICLES), "--seeds", str(SEEDS), "--no-progress", "--no-report", "--cluster", "local:2"]
    assert main(argv) == 0
    assert comparable(out) == comparable(local)
    assert json.loads((out / "beta" / "identity.json").read_text())["bench"]["executor"] == "dask:local:2"


def test_cluster_errors_are_one_line(root, tmp_path, capsys, monkeypatch):
    import covviz.experiments.cluster as cl

    monkeypatch.setattr(cl, "CONNECT_TIMEOUT", 2)
    argv = ["bench", str(root), "--out", str(tmp_path / "o"), "--trackers", "identity", "--no-progress"]
    for cluster, msg in [("tcp://127.0.0.1:9", "no Dask scheduler answers"), ("local:0", "expected local:N"),
                         (str(tmp_path / "none.json"), "no such scheduler file")]:
        assert main([*argv, "--cluster", cluster]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0], err
