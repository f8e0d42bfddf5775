"""``--config FILE.json`` of ``covviz track`` and ``covviz bench``: a ManifoldConfig from a file (or inline JSON)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import write_otb

from covviz.cli import main
from covviz.experiments.bench import bench
from covviz.experiments.results import load_result, result_paths
from covviz.trackers.manifold import PAPER_LIKELIHOOD, ManifoldConfig


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    r = tmp_path_factory.mktemp("cfgseq")
    write_otb(r / "alpha", 6, seed=31)
    return r


def write_config(path: Path, **fields) -> Path:
    path.write_text(json.dumps(fields))
    return path


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("tracker", ["manifold", "manifold-paper"])
def test_track_runs_the_config_of_the_file(root, tmp_path, monkeypatch, tracker):
    monkeypatch.chdir(tmp_path)
    cfg = write_config(tmp_path / "c.json", likelihood_sigma=0.7, n_particles=30, kinematics={"velocity_decay": 0.8})
    argv = ["track", str(root / "alpha"), "--trackers", f"{tracker},identity", "--config", str(cfg), "--no-save",
            "--no-progress", "--out", str(tmp_path / "runs")]
    assert main(argv) == 0
    doc, _ = load_result(result_paths(tmp_path / "runs", "alpha", tracker, 0)[1])
    paper = {} if tracker == "manifold" else PAPER_LIKELIHOOD
    expect = ManifoldConfig().replace(likelihood_sigma=0.7, n_particles=30, **paper)
    expect = ManifoldConfig.from_dict({**expect.as_dict(), "kinematics": {"velocity_decay": 0.8}})
    assert doc["config"] == expect.as_dict()
    # --particles overrides the file's n_particles
    assert main([*argv, "--particles", "12"]) == 0
    assert load_result(result_paths(tmp_path / "runs", "alpha", tracker, 0)[1])[0]["config"]["n_particles"] == 12


def test_track_takes_the_config_inline_as_from_a_file(root, tmp_path, monkeypatch):
    """``--config '{"likelihood_sigma": 0.7}'``, as the README writes the options: the run and its results are
    those of the same JSON in a file; bad inline JSON is a one-line error naming it, and a missing file says both
    forms."""
    monkeypatch.chdir(tmp_path)
    fields = {"likelihood_sigma": 0.7, "n_particles": 30, "camera_share": 0.5}
    cfg = write_config(tmp_path / "c.json", **fields)
    base = ["track", str(root / "alpha"), "--trackers", "manifold", "--no-save", "--no-progress"]
    assert main([*base, "--config", str(cfg), "--out", str(tmp_path / "f")]) == 0
    assert main([*base, "--config", " " + json.dumps(fields), "--out", str(tmp_path / "i")]) == 0
    (a, boxes_a), (b, boxes_b) = (load_result(result_paths(tmp_path / d, "alpha", "manifold", 0)[1])
                                  for d in ("f", "i"))
    assert a["config"] == b["config"] and a["config"]["camera_share"] == 0.5
    assert np.array_equal(boxes_a, boxes_b)


def test_bad_inline_config_and_missing_file_are_one_line_errors(root, tmp_path, capsys):
    base = ["track", str(root / "alpha"), "--no-save", "--no-progress", "--out", str(tmp_path / "o")]
    assert main([*base, "--config", '{"camera_share": 0.5']) == 2
    msg = one_line_error(capsys)
    assert msg.startswith("covviz track: error: --config: not JSON"), msg
    assert main([*base, "--config", '{"camera_share": 2}']) == 2
    assert "camera_share must be a number in [0, 1]" in one_line_error(capsys)
    assert main([*base, "--config", str(tmp_path / "none.json")]) == 2
    assert "give a JSON file, or a JSON object in quotes" in one_line_error(capsys)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "No such file"),
        ("{not json", "not JSON"),
        ('{"sigma": 1}', "unknown ManifoldConfig field(s) sigma"),
        ('{"likelihood_sigma": -1}', "likelihood_sigma must be a number > 0"),
        ("[1, 2]", "must be a JSON object"),
        # a wrong type is never taken as true, nor written into results as if it ran
        ('{"quadrants": "false"}', "ObservationConfig.quadrants must be true or false, got 'false'"),
        ('{"jit": 0}', "ObservationConfig.jit must be true or false"),
        ('{"gain_normalize": "yes"}', "ObservationConfig.gain_normalize must be true or false"),
        ('{"antialias": null}', "ObservationConfig.antialias must be true or false"),
        ('{"kinematics": 5}', "ManifoldConfig.kinematics must be a JSON object of KinematicModel fields, got 5"),
        ('{"kinematics": {"pos_sigma": [0.1]}}', "KinematicModel.pos_sigma must be two numbers"),
        ('{"kinematics": {"speed": 1}}', "unknown KinematicModel field(s) speed"),
        ('{"n_particles": 12.5}', "ManifoldConfig.n_particles must be an integer"),
        ('{"patch_size": 2000}', "ObservationConfig.patch_size must be an integer in [4, 128]"),
        ('{"observation": {"colour_weight": -1}}', "ObservationConfig.colour_weight must be a number >= 0"),
        ('{"quadrants": false, "observation": {"quadrants": true}}', "given both flat and inside"),
    ],
)
def test_bad_config_files_are_one_line_errors(root, tmp_path, capsys, content, message):
    cfg = tmp_path / "c.json"
    if content is not None:
        cfg.write_text(content)
    for command in ("track", "bench"):
        argv = [command, str(root / "alpha"), "--config", str(cfg), "--no-progress", "--out", str(tmp_path / "o")]
        argv += ["--no-save"] if command == "track" else ["--trackers", "manifold"]
        assert main(argv) == 2
        msg = one_line_error(capsys)
        assert "--config" in msg and message in msg, msg
        assert not (tmp_path / "o").exists()  # refused before anything ran: nothing written


def test_config_needs_a_manifold_tracker(root, tmp_path, capsys):
    cfg = write_config(tmp_path / "c.json", likelihood_sigma=0.7)
    assert main(["track", str(root / "alpha"), "--trackers", "identity", "--config", str(cfg), "--no-save"]) == 2
    assert "needs one of the trackers manifold, manifold-paper" in one_line_error(capsys)


def test_bench_config_goes_into_results_and_guards_resume(root, tmp_path, capsys):
    out = tmp_path / "out"
    s = bench(root, ["manifold", "identity"], out, seeds=1, particles=20, progress=False, report=False,
              config={"likelihood_sigma": 0.7})
    assert s["run"] == 2
    assert load_result(result_paths(out, "alpha", "manifold", 0)[1])[0]["config"]["observation"]["likelihood_sigma"] == 0.7
    manifest = json.loads((out / "bench_manifest.json").read_text())
    assert manifest["configs"]["manifold"]["observation"]["likelihood_sigma"] == 0.7
    # the same config resumes; another one is refused (the results were made with the first)
    cfg = write_config(tmp_path / "c.json", likelihood_sigma=0.7)
    argv = ["bench", str(root), "--out", str(out), "--trackers", "manifold,identity", "--seeds", "1",
            "--particles", "20", "--no-progress", "--no-report", "--config", str(cfg)]
    assert main(argv) == 0
    assert "0 runs done, 2 already done" in capsys.readouterr().out
    write_config(cfg, likelihood_sigma=0.9)
    assert main(argv) == 2
    assert "made with another manifold config" in one_line_error(capsys)
