"""The Python API (issue 22, item 7): ``covviz.track``, ``covviz.read_events``, ``covviz.show``."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import covviz
from covviz.data.synthetic import SyntheticConfig, SyntheticSequence
from covviz.records import FrameRecord, RunResult


def test_import_covviz_loads_no_api_until_used():
    code = ("import sys, covviz\n"
            "heavy = [m for m in ('covviz.api', 'covviz.runner', 'numpy', 'rerun', 'scipy') if m in sys.modules]\n"
            "assert not heavy, heavy\n"
            "covviz.track\n"
            "assert 'covviz.api' in sys.modules and 'rerun' not in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_track_returns_a_run_result_per_tracker_with_metrics_and_diagnosis():
    runs = covviz.track("synthetic:occlusion", trackers="identity,manifold", seed=1, max_frames=90, particles=60)
    assert [r.tracker for r in runs] == ["identity", "manifold"]
    for r in runs:
        assert isinstance(r, RunResult) and r.seed == 1 and r.boxes.shape == (90, 4)
        assert 0 <= r.metrics["success_auc"] <= 1 and r.recording is None
        assert set(r.diagnosis) >= {"events", "diagnoses", "suspects", "labels"}
    assert runs[0].diagnosis["diagnoses"], "the identity tracker loses the moving target: a diagnosed loss"


def test_same_seed_same_boxes_as_covviz_track(tmp_path, monkeypatch):
    from covviz import cli
    from covviz.data.sequences import read_boxes

    monkeypatch.chdir(tmp_path)
    assert cli.main(["track", "--max-frames", "8", "--particles", "30", "--seed", "2", "--no-save",
                     "--no-progress"]) == 0
    cli_boxes = read_boxes("runs/synthetic/manifold_s2.txt")  # 1-based on disk
    api = covviz.track(None, trackers=["manifold"], seed=2, max_frames=8, particles=30)[0]
    np.testing.assert_allclose(api.boxes, cli_boxes, atol=0.006)  # the file keeps 2 decimals


def test_a_recorded_run_on_two_cores_observes_with_one_thread_as_covviz_track(tmp_path, monkeypatch):
    import os

    from covviz.trackers.manifold import ManifoldConfig

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    kw = {"trackers": ["manifold"], "seed": 2, "max_frames": 8, "particles": 30, "counterfactual": False}
    recorded = covviz.track(None, save=tmp_path / "r.rrd", **kw)[0]
    plain = covviz.track(None, **kw)[0]
    own = covviz.track(None, save=tmp_path / "c.rrd", config=ManifoldConfig(n_particles=30, threads=2), **kw)[0]
    assert (recorded.config["threads"], plain.config["threads"], own.config["threads"]) == (1, 2, 2)
    np.testing.assert_array_equal(recorded.boxes, plain.boxes)  # threads change the speed only


class StillTracker:
    """A tracker of our own, following the protocol only (no registry)."""

    name = "still"

    def __init__(self):
        self.last_record = None
        self._box = None
        self._i = 0

    def config_dict(self) -> dict:
        return {"kind": "still"}

    def init(self, frame, box):
        self._box, self._i = np.asarray(box, dtype=float), 0
        self.last_record = FrameRecord(index=0, box=self._box.copy(), tracker=self.name)

    def update(self, frame):
        self._i += 1
        self.last_record = FrameRecord(index=self._i, box=self._box.copy(), tracker=self.name)
        return self._box.copy()


def test_bring_your_own_tracker_and_sequence_object(tmp_path):
    seq = SyntheticSequence(SyntheticConfig(n_frames=12, seed=2))
    rrd = tmp_path / "own.rrd"
    (r,) = covviz.track(seq, trackers=[StillTracker()], max_frames=12, save=rrd)
    assert r.tracker == "still" and r.config == {"kind": "still"}
    np.testing.assert_array_equal(r.boxes, np.repeat(seq.groundtruth[:1], 12, axis=0))
    assert r.recording == rrd and rrd.is_file()
    events = covviz.read_events(rrd)
    assert isinstance(events, list) and all({"tracker", "frame", "kind", "text"} <= set(e) for e in events)


def test_bad_trackers_are_refused():
    with pytest.raises(TypeError, match="not a tracker"):
        covviz.track(None, trackers=[object()], max_frames=3)
    with pytest.raises(ValueError, match="did you mean 'manifold'"):
        covviz.track(None, trackers="manifol", max_frames=3)
    with pytest.raises(ValueError, match="given twice"):
        covviz.track(None, trackers=["manifold", "manifold"], max_frames=3)


def test_show_says_what_to_install_without_the_notebook_package(tmp_path):
    from rerun.notebook import HAS_NOTEBOOK

    with pytest.raises(FileNotFoundError):
        covviz.show(tmp_path / "none.rrd")
    if not HAS_NOTEBOOK:
        (tmp_path / "x.rrd").write_bytes(b"")
        with pytest.raises(ImportError, match="rerun-notebook"):
            covviz.show(tmp_path / "x.rrd")
