"""``covviz tune``: an Optuna study over ManifoldConfig on tiny synthetic sequences.

Two ``covviz tune`` processes share one SQLite study (3 trials in all, 1 tuning
seed, 1 held-out seed, 20 particles, 8 and 6 frames); the pruning logic is
checked with a fake executor and a fake trial.
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

optuna = pytest.importorskip("optuna")

from helpers import write_otb

import covviz
from covviz.cli import main
from covviz.experiments.jobs import Job, JobOutput, Outcome
from covviz.experiments.tune import TuneSettings, score_config
from covviz.trackers.manifold import SEARCH_SPACE, ManifoldConfig

ENV = {**os.environ, "PYTHONPATH": str(Path(covviz.__file__).resolve().parent.parent)}
FRAMES = {"alpha": 8, "beta": 6}
TRIALS = 3


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    r = tmp_path_factory.mktemp("tuneseq")
    for k, (name, n) in enumerate(FRAMES.items()):
        write_otb(r / name, n, seed=21 + k)
    return r


def tune_argv(root: Path, out: Path, db: Path, *extra: str) -> list[str]:
    return ["tune", str(root), "--trials", str(TRIALS), "--seeds", "1", "--holdout-seeds", "1", "--particles", "20",
            "--storage", f"sqlite:///{db}", "--study", "t", "--out", str(out), "--no-progress", *extra]


def test_two_processes_share_one_sqlite_study(root, tmp_path, monkeypatch, capsys):
    db = tmp_path / "study.db"
    # the second process leaves the held-out check to the first (both would run it)
    procs = [
        subprocess.Popen([sys.executable, "-m", "covviz.cli", *tune_argv(root, tmp_path / f"out{i}", db, *extra)],
                         env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i, extra in enumerate([(), ("--holdout-seeds", "0")])
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    for p, (out, err) in zip(procs, outs, strict=True):
        assert p.returncode == 0, err
        assert "best: trial" in out, out
    assert "held-out seeds 1:" in outs[0][0]
    study = optuna.load_study(study_name="t", storage=f"sqlite:///{db}")
    states = [t.state for t in study.trials]
    finished = [s for s in states if s in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)]
    # --trials is the study's total; two processes may each start the last one at once
    assert TRIALS <= len(finished) <= TRIALS + 1 and len(states) == len(finished)
    assert study.trials[0].user_attrs.get("base") is True  # the base config runs first
    assert set(study.best_trial.params) == set(SEARCH_SPACE)
    for i in range(2):
        out = tmp_path / f"out{i}"
        report = (out / "tune_report.md").read_text()
        assert "## Best configuration" in report and f"--config {out / 'best.json'}" in report
        assert "## Parameter importance" in report
        assert ("## Does it hold on held-out seeds?" in report) == (i == 0)
        assert (out / "img" / "tune_history.png").read_bytes()[:4] == b"\x89PNG"
        best = ManifoldConfig.from_dict(json.loads((out / "best.json").read_text()))
        assert best.n_particles == 20
    # the held-out scores are kept in the study: a second report (--trials 0) reruns nothing
    assert main(tune_argv(root, tmp_path / "out2", db, "--trials", "0")) == 0
    first = capsys.readouterr().out
    monkeypatch.setattr("covviz.experiments.tune.score_config", lambda *a, **k: pytest.fail("re-ran a configuration"))
    assert main(tune_argv(root, tmp_path / "out2", db, "--trials", "0")) == 0
    assert capsys.readouterr().out == first and "held-out seeds 1:" in first
    # the best config is ready for covviz track
    monkeypatch.chdir(tmp_path)
    argv = ["track", str(root / "beta"), "--config", str(tmp_path / "out0" / "best.json"), "--no-progress",
            "--out", str(tmp_path / "runs"), "--no-save"]
    assert main(argv) == 0
    doc = json.loads((tmp_path / "runs" / "beta" / "manifold_s0.json").read_text())
    assert doc["config"] == json.loads((tmp_path / "out0" / "best.json").read_text())
    with sqlite3.connect(db) as c:  # a real SQLite file, shared
        assert c.execute("select count(*) from trials").fetchone()[0] == len(states)
    # a study made for another objective is refused, in one line
    capsys.readouterr()
    assert main(tune_argv(root, tmp_path / "out2", db, "--trials", "0", "--max-frames", "5")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "was made with other max_frames" in err[0] and "--study" in err[0]


class FakeExecutor:
    """Yields the jobs in order with a fixed AUC per sequence; records how far it got and that it was closed."""

    name, slots, threads, retries = "fake", 1, 1, 0

    def __init__(self, auc: dict[str, float]):
        self.auc = auc
        self.events: list[str] = []
        self.yielded: list[str] = []
        self.closed = False

    def run(self, jobs):
        try:
            for job in jobs:
                self.yielded.append(job.label)
                yield Outcome(job, output=FakeOutput(self.auc[job.sequence]))
        finally:
            self.closed = True

    def close(self):
        pass


class FakeOutput(JobOutput):
    def __init__(self, auc):
        object.__setattr__(self, "_auc", auc)

    @property
    def success_auc(self):
        return self._auc


class FakeTrial:
    def __init__(self, prune_at: int | None):
        self.prune_at = prune_at
        self.reports: list[tuple[int, float]] = []

    def report(self, value, step):
        self.reports.append((step, value))

    def should_prune(self):
        return self.prune_at is not None and self.reports[-1][0] >= self.prune_at


def settings(n_seq: int = 3, seeds: int = 2) -> TuneSettings:
    seqs = {f"s{i}": (f"/nowhere/s{i}", 10) for i in range(n_seq)}
    return TuneSettings("manifold", seqs, seeds, None, 20, ManifoldConfig().as_dict())


def test_score_is_the_mean_over_sequences_reported_after_each():
    ex = FakeExecutor({"s0": 0.2, "s1": 0.4, "s2": 0.9})
    trial = FakeTrial(None)
    score = score_config(ex, settings(), ManifoldConfig().as_dict(), range(2), trial, progress=False)
    assert score["mean"] == pytest.approx(0.5) and score["per_sequence"] == {"s0": 0.2, "s1": 0.4, "s2": 0.9}
    assert [s for s, _ in trial.reports] == [0, 1, 2]
    assert [v for _, v in trial.reports] == pytest.approx([0.2, 0.3, 0.5])
    assert ex.closed and len(ex.yielded) == 6


def test_a_hopeless_trial_is_pruned_and_its_other_jobs_stopped():
    ex = FakeExecutor({"s0": 0.1, "s1": 0.1, "s2": 0.9})
    with pytest.raises(optuna.TrialPruned):
        score_config(ex, settings(), ManifoldConfig().as_dict(), range(2), FakeTrial(prune_at=1), progress=False)
    assert ex.closed and ex.yielded == ["s0/manifold/s0", "s0/manifold/s1", "s1/manifold/s0", "s1/manifold/s1"]


def test_jobs_of_a_trial_carry_its_config_and_the_seed_rule():
    cfg = ManifoldConfig().replace(likelihood_sigma=0.7).as_dict()
    jobs = settings(2, 2).jobs(cfg, [3, 4])
    assert [j.label for j in jobs] == ["s0/manifold/s3", "s0/manifold/s4", "s1/manifold/s3", "s1/manifold/s4"]
    assert all(isinstance(j, Job) and json.loads(j.config) == cfg and j.particles == 20 for j in jobs)
    tr = jobs[0].make_tracker()
    assert tr.config.observation.likelihood_sigma == 0.7 and tr.config.n_particles == 20
