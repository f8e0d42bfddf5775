"""``covviz bench`` under faults: a killed job process, Ctrl-C, its own results inside ROOT, two benches.

Real processes and real signals: a job process is SIGKILLed as the OOM killer
would, the bench gets SIGINT at its process group as a terminal's Ctrl-C
sends it. Sequences are small synthetic OTB folders (tests/test_bench.py).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from helpers import descendants, write_otb

import covviz
from covviz.cli import main
from covviz.experiments.bench import BenchError, bench, lock_results_folder
from covviz.experiments.results import load_result

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

PARTICLES = 20
FRAMES = {"alpha": 14, "beta": 10}
SEEDS = 2
TRACKERS = ["identity", "manifold"]
N_JOBS = len(FRAMES) * (1 + SEEDS)
#: The worktree's package for subprocesses (as for `covviz track` in a test).
ENV = {**os.environ, "PYTHONPATH": str(Path(covviz.__file__).resolve().parent.parent)}


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    r = tmp_path_factory.mktemp("faultseq")
    for k, (name, n) in enumerate(FRAMES.items()):
        write_otb(r / name, n, seed=7 + k)
    return r


@pytest.fixture(scope="module")
def reference(root, tmp_path_factory) -> Path:
    """The bench without faults."""
    out = tmp_path_factory.mktemp("ref") / "out"
    s = bench(root, TRACKERS, out, seeds=SEEDS, jobs=2, particles=PARTICLES, progress=False, report=False)
    assert s["run"] == N_JOBS and not s["failed"]
    return out


# --------------------------------------------------------------------------- #
# processes, from /proc
# --------------------------------------------------------------------------- #
def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


class Killer(threading.Thread):
    """SIGKILLs the job process of ``label`` (``python -m covviz.experiments.jobs LABEL``) the first ``times`` it appears."""

    def __init__(self, label: str, times: int = 1, after: float = 0.2):
        super().__init__(daemon=True)
        self.label, self.times, self.after = label, times, after
        self.killed: list[int] = []
        self.stop = threading.Event()

    def run(self) -> None:
        me = os.getpid()
        seen: dict[int, float] = {}
        while not self.stop.is_set() and len(self.killed) < self.times:
            for pid, cmd in descendants(me).items():
                if cmd.rstrip().endswith(f"covviz.experiments.jobs {self.label}") and pid not in self.killed:
                    seen.setdefault(pid, time.monotonic())
                    if time.monotonic() - seen[pid] >= self.after:
                        os.kill(pid, signal.SIGKILL)
                        self.killed.append(pid)
            time.sleep(0.02)


def txt_files(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.glob("*/*.txt"))}


# --------------------------------------------------------------------------- #
# issue 11.6: one killed job process
# --------------------------------------------------------------------------- #
def test_a_killed_job_fails_alone_and_the_rest_run(root, reference, tmp_path):
    """As by the OOM killer, without retries: only that job fails; the other jobs all finish."""
    out = tmp_path / "out"
    killer = Killer("alpha/manifold/s1")
    killer.start()
    try:
        s = bench(root, TRACKERS, out, seeds=SEEDS, jobs=2, particles=PARTICLES, progress=False, report=False,
                  retries=0)
    finally:
        killer.stop.set()
    assert len(killer.killed) == 1
    assert [label for label, _ in s["failed"]] == ["alpha/manifold/s1"]
    assert "killed by SIGKILL" in s["failed"][0][1]
    assert s["run"] == N_JOBS - 1
    ref = txt_files(reference)
    got = txt_files(out)
    assert set(ref) - set(got) == {"alpha/manifold_s1.txt"}
    assert all(got[k] == ref[k] for k in got)


def test_a_killed_job_is_run_again(root, reference, tmp_path):
    """With the default retry, a job whose process was killed once runs again and gives the same boxes."""
    out = tmp_path / "out"
    killer = Killer("beta/manifold/s0")
    killer.start()
    try:
        s = bench(root, TRACKERS, out, seeds=SEEDS, jobs=2, particles=PARTICLES, progress=False, report=False)
    finally:
        killer.stop.set()
    assert len(killer.killed) == 1
    assert s["failed"] == [] and s["run"] == N_JOBS
    assert any("beta/manifold/s0" in e and "killed by SIGKILL" in e for e in s["events"])
    assert txt_files(out) == txt_files(reference)


# --------------------------------------------------------------------------- #
# issue 11.7: Ctrl-C
# --------------------------------------------------------------------------- #
def start_bench(root: Path, out: Path, *extra: str) -> subprocess.Popen:
    """``covviz bench`` in its own session, as a terminal's foreground process group."""
    return subprocess.Popen(
        [sys.executable, "-m", "covviz.cli", "bench", str(root), "--out", str(out), "--trackers",
         ",".join(TRACKERS), "--particles", str(PARTICLES), "--seeds", str(SEEDS), "--jobs", "2",
         "--no-report", *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV, start_new_session=True, text=True,
    )


def wait_for_start(proc: subprocess.Popen, out: Path) -> None:
    """Until the bench's code runs (its manifest is written just before the first job starts).

    Earlier, a Ctrl-C lands in the interpreter's own start-up (imports), before any covviz code.
    """
    deadline = time.monotonic() + 30
    while not (out / "bench_manifest.json").exists():
        assert proc.poll() is None and time.monotonic() < deadline, "the bench did not start"
        time.sleep(0.005)


@pytest.mark.parametrize("delay", [0.0, 0.15, 0.5, 1.0, 1.8])
def test_ctrl_c_ends_the_bench_within_seconds(root, tmp_path, delay):
    """SIGINT to the process group at any moment (as no job process exists yet, between and during
    jobs): exit 130 within seconds, no traceback, no job process left, every finished result readable."""
    out = tmp_path / "out"
    proc = start_bench(root, out)
    wait_for_start(proc, out)
    time.sleep(delay)
    jobs_then = descendants(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    t0 = time.monotonic()
    try:
        _, err = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail(f"the bench was still running 15 s after Ctrl-C (sent {delay} s after the start)")
    took = time.monotonic() - t0
    assert took < 6, f"Ctrl-C took {took:.1f} s"
    if proc.returncode == 0:  # it finished before the signal arrived
        return
    assert proc.returncode == 130, err
    assert "Traceback" not in err, err
    deadline = time.monotonic() + 5
    while any(alive(p) for p in jobs_then | descendants(proc.pid)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [p for p in jobs_then if alive(p)], "job processes outlived the bench"
    for js in out.glob("*/*.json"):
        load_result(js)  # finished results are whole
    assert not list(out.rglob("*.part"))


def test_a_second_ctrl_c_prints_no_traceback(root, tmp_path):
    out = tmp_path / "out"
    proc = start_bench(root, out)
    wait_for_start(proc, out)
    time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=15)
    # 130 (handled), or -SIGINT when the second one lands after covviz returned (Python then ends by
    # the signal, as a shell expects), or 0 if it had finished
    assert proc.returncode in (130, -signal.SIGINT, 0), err
    assert "Traceback" not in err, err


def test_resume_after_ctrl_c_runs_only_what_is_missing(root, reference, tmp_path):
    out = tmp_path / "out"
    proc = start_bench(root, out)
    wait_for_start(proc, out)
    time.sleep(1.0)
    os.killpg(proc.pid, signal.SIGINT)
    proc.communicate(timeout=15)
    done = {str(p.relative_to(out)) for p in out.glob("*/*.json")}
    s = bench(root, TRACKERS, out, seeds=SEEDS, jobs=2, particles=PARTICLES, progress=False, report=False)
    assert s["skipped"] == len(done) and s["run"] == N_JOBS - len(done) and not s["failed"]
    assert txt_files(out) == txt_files(reference)


# --------------------------------------------------------------------------- #
# issue 11.16 and two benches on one folder
# --------------------------------------------------------------------------- #
def test_results_folder_inside_root_resumes(root, tmp_path, capsys):
    """`--out ROOT/results` twice: its report's img/ does not make it a sequence."""
    r = tmp_path / "root"
    shutil.copytree(root, r)
    argv = ["bench", str(r), "--out", str(r / "results"), "--trackers", "identity", "--no-progress"]
    assert main(argv) == 0
    assert (r / "results" / "img").is_dir()  # the report: what looked like an OTB sequence
    capsys.readouterr()
    assert main(argv) == 0
    assert "0 runs done, 2 already done" in capsys.readouterr().out
    # another bench's results folder inside ROOT is skipped too
    shutil.copytree(r / "results", r / "old-results")
    assert main([*argv[:3], str(r / "other"), *argv[4:]]) == 0


def test_two_benches_on_one_folder(root, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    with lock_results_folder(out):
        with pytest.raises(BenchError, match="another covviz bench is writing into"):
            bench(root, ["identity"], out, progress=False)
        assert main(["bench", str(root), "--out", str(out), "--trackers", "identity", "--no-progress"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "another covviz bench" in err[0] and f"pid {os.getpid()}" in err[0]
    # released with the block (and with the process, whatever ends it)
    assert bench(root, ["identity"], out, progress=False, report=False)["run"] == 2


def test_a_second_bench_process_is_refused_while_the_first_runs(root, tmp_path):
    out = tmp_path / "out"
    first = start_bench(root, out)
    try:
        deadline = time.monotonic() + 20
        while not (out / "bench_manifest.json").exists() and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        if first.poll() is not None:
            pytest.skip("the first bench finished before the second could start")
        with pytest.raises(BenchError, match="another covviz bench"):
            bench(root, TRACKERS, out, seeds=SEEDS, particles=PARTICLES, progress=False)
    finally:
        first.communicate(timeout=60)
    assert first.returncode == 0
    assert len(list(out.glob("*/*.json"))) == N_JOBS
