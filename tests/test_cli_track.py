"""Tests for ``covviz track``: results on disk, determinism, one-line errors with exit code 2.

The command runs in-process through :func:`covviz.cli.main` (fast, and
``capsys`` sees its output); one test runs the installed ``covviz`` console
script in a subprocess to check the real exit code. Test sequences are tiny
PNG folders built in ``tmp_path``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from covviz import cli
from covviz.data.sequences import SyntheticSequence

FRAMES = 15
PARTICLES = 100


def track_flags() -> set[str]:
    """Option strings of ``covviz track`` as the parser defines them right now."""
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {s for a in sub.choices["track"]._actions for s in a.option_strings}


def quiet_flags() -> list[str]:
    """Flags that keep a run fast and silent: no progress bar, no recording if the CLI makes one."""
    flags = ["--no-progress"]
    if "--no-save" in track_flags():
        flags.append("--no-save")
    return flags


def track(*args: str) -> list[str]:
    return ["track", *args, *quiet_flags()]


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


# --------------------------------------------------------------------------- #
# tiny OTB folders
# --------------------------------------------------------------------------- #
def make_otb(root: Path, n_frames=3, gt_lines=("5,5,10,8",) * 3, bad_first=False, size=(24, 32)) -> Path:
    img = root / "img"
    img.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(1, n_frames + 1):
        p = img / f"{i:04d}.png"
        if bad_first and i == 1:
            p.write_bytes(b"this is not an image")
        else:
            cv2.imwrite(str(p), rng.integers(0, 255, (*size, 3), dtype=np.uint8))
    (root / "groundtruth_rect.txt").write_text("".join(f"{line}\n" for line in gt_lines))
    return root


# --------------------------------------------------------------------------- #
# a successful run on the synthetic default
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Three in-process runs on the synthetic sequence: seed 3 twice, seed 4 once."""
    base = tmp_path_factory.mktemp("track")
    out = {}
    for name, seed in [("a", 3), ("b", 3), ("c", 4)]:
        d = base / name
        argv = track("--max-frames", str(FRAMES), "--particles", str(PARTICLES), "--seed", str(seed), "--out", str(d))
        code, stdout, stderr = run_main(argv)
        out[name] = {"dir": d, "code": code, "stdout": stdout, "stderr": stderr, "seed": seed}
    return out


def test_track_synthetic_succeeds_and_prints_metrics(runs):
    r = runs["a"]
    assert r["code"] == 0, r["stderr"]
    for word in ("success AUC", "P@20", "r_on_track", "rms_on_track", "fps", "synthetic"):
        assert word in r["stdout"]
    assert str(r["dir"]) in r["stdout"]


def test_track_writes_otb_boxes_and_json(runs):
    d = runs["a"]["dir"] / "synthetic"
    txt, js = d / "manifold_s3.txt", d / "manifold_s3.json"
    assert txt.is_file() and js.is_file()
    lines = txt.read_text().splitlines()
    assert len(lines) == FRAMES
    rows = np.array([[float(v) for v in line.split(",")] for line in lines])
    assert rows.shape == (FRAMES, 4) and np.all(np.isfinite(rows))
    # OTB results are 1-based: the first row is the initial box + (1, 1).
    gt0 = SyntheticSequence().groundtruth[0]
    np.testing.assert_allclose(rows[0], gt0 + [1, 1, 0, 0], atol=0.005 + 1e-9)
    doc = json.loads(js.read_text())
    assert doc["seed"] == 3 and doc["tracker"] == "manifold" and doc["sequence"] == "synthetic"
    assert doc["n_frames"] == FRAMES
    assert doc["config"]["n_particles"] == PARTICLES
    m = doc["metrics"]
    for key in ("success_auc", "precision_20", "r_on_track", "rms_on_track", "n_skipped"):
        assert key in m
    assert 0.0 <= m["success_auc"] <= 1.0 and m["n_skipped"] == 0
    assert f"success AUC {m['success_auc']:.3f}" in runs["a"]["stdout"]
    assert doc["fps"] > 0
    assert list(d.rglob("*.part")) == []


def test_same_seed_gives_identical_box_files(runs):
    a = (runs["a"]["dir"] / "synthetic" / "manifold_s3.txt").read_bytes()
    b = (runs["b"]["dir"] / "synthetic" / "manifold_s3.txt").read_bytes()
    c = (runs["c"]["dir"] / "synthetic" / "manifold_s4.txt").read_bytes()
    assert a == b
    assert a != c


def test_identity_tracker_on_otb_folder(tmp_path):
    seq = make_otb(tmp_path / "Tiny")
    code, _stdout, stderr = run_main(track(str(seq), "--tracker", "identity", "--out", str(tmp_path / "out")))
    assert code == 0, stderr
    rows = (tmp_path / "out" / "Tiny" / "identity_s0.txt").read_text().splitlines()
    assert rows == ["5.00,5.00,10.00,8.00"] * 3  # 1-based in, 1-based out
    doc = json.loads((tmp_path / "out" / "Tiny" / "identity_s0.json").read_text())
    assert doc["metrics"]["success_auc"] == pytest.approx(20 / 21)  # IoU 1 passes every threshold but 1


# --------------------------------------------------------------------------- #
# bad input: exit code 2, one line on stderr that says what to fix
# --------------------------------------------------------------------------- #
def _missing(tmp):
    return [str(tmp / "no_such_sequence")], "no such"


def _no_frames(tmp):
    root = tmp / "Empty"
    (root / "img").mkdir(parents=True)
    (root / "groundtruth_rect.txt").write_text("5,5,10,8\n")
    return [str(root)], "no frames"


def _empty_folder(tmp):
    (tmp / "Nothing").mkdir()
    return [str(tmp / "Nothing")], "not a sequence folder"


def _unreadable_first(tmp):
    return [str(make_otb(tmp / "Bad", bad_first=True))], "cannot read image"


def _unreadable_later(tmp):
    """A frame that fails mid-run: still a one-line error and exit 2, not a traceback."""
    root = make_otb(tmp / "Later")
    (root / "img" / "0002.png").write_bytes(b"")
    return [str(root), "--tracker", "identity"], "cannot read image"


def _gt_columns(tmp):
    return [str(make_otb(tmp / "Cols", gt_lines=("5,5,10",) * 3))], "4 columns"


def _box_outside(tmp):
    return [str(make_otb(tmp / "Out", gt_lines=("100,100,10,8",) * 3))], "outside"


def _box_flag_outside(tmp):
    return ["--box", "1000,1000,10,10"], "outside"


def _zero_size(tmp):
    return ["--box", "10,10,0,5"], "size"


def _one_frame(tmp):
    return [str(make_otb(tmp / "One", n_frames=1, gt_lines=("5,5,10,8",)))], "at least 2 frames"


BAD_INPUTS = [_missing, _no_frames, _empty_folder, _unreadable_first, _unreadable_later, _gt_columns, _box_outside,
              _box_flag_outside, _zero_size, _one_frame]


@pytest.mark.parametrize("case", BAD_INPUTS, ids=lambda f: f.__name__.strip("_"))
def test_bad_input_exit_2_with_one_line(tmp_path, case):
    args, hint = case(tmp_path)
    out = tmp_path / "results"
    particles = [] if "identity" in args else ["--particles", "10"]  # identity has none: --particles is refused
    code, _stdout, stderr = run_main(track(*args, "--out", str(out), *particles))
    assert code == 2
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1, stderr
    assert lines[0].startswith("covviz track: error:")
    assert hint in lines[0]
    assert "Traceback" not in stderr
    assert not out.exists() or not any(out.rglob("*.txt"))  # nothing written


@pytest.mark.parametrize(
    "args, hint",
    [(["--tracker", "nope"], "unknown tracker"), (["--particles", "0"], "positive integer"),
     (["--box", "1,2,3"], "4 numbers")],
)
def test_bad_arguments_exit_2(tmp_path, capsys, args, hint):
    with pytest.raises(SystemExit) as exc:
        cli.main(track(*args, "--out", str(tmp_path)))
    assert exc.value.code == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error:" in line]
    assert len(errors) == 1 and hint in errors[0], err
    if args[0] == "--tracker":
        assert "manifold" in errors[0]  # lists the valid names


def test_console_script_exit_code(tmp_path):
    exe = shutil.which("covviz") or str(Path(sys.executable).with_name("covviz"))
    assert Path(exe).exists(), "the covviz console script is not installed"
    p = subprocess.run(
        [exe, *track(str(tmp_path / "missing"), "--out", str(tmp_path / "o"))],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert p.returncode == 2
    lines = [line for line in p.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "no such" in lines[0], p.stderr


# --------------------------------------------------------------------------- #
# help
# --------------------------------------------------------------------------- #
def test_help(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "track" in out and "--help" in out


def test_track_help_shows_examples(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "examples:" in out
    assert "covviz track" in out and "--box" in out and "--seed" in out
    for flag in ("--tracker", "--particles", "--max-frames", "--out"):
        assert flag in out


def test_top_level_help_shows_an_example(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    assert "covviz track" in out


def test_error_inside_tracker_keeps_the_frames_done(tmp_path, monkeypatch):
    # A tracker that breaks on its 6th update: the error propagates (it is a bug, not bad input),
    # but the boxes of the frames before it are on disk, readable, and marked interrupted.
    from covviz import trackers
    from covviz.experiments.results import load_result
    from covviz.trackers.base import IdentityTracker

    class Breaks(IdentityTracker):
        def update(self, frame):
            if self._index == 5:
                raise RuntimeError("tracker blew up")
            return super().update(frame)

    monkeypatch.setattr(trackers, "make_tracker", lambda name, **kw: Breaks())
    with pytest.raises(RuntimeError, match="blew up"):
        cli.main(track("--out", str(tmp_path), "--max-frames", "20"))
    doc, boxes = load_result(tmp_path / "synthetic" / "identity_s0.json")
    assert doc["interrupted"] is True and doc["n_frames"] == 6 and len(boxes) == 6


def test_value_error_inside_tracker_is_a_bug_not_bad_input(tmp_path, monkeypatch):
    # Only validation errors (covviz.errors.InputError) are "bad input, exit 2": a ValueError raised
    # by a tracker in the middle of a run escapes main() (traceback, exit 1), results kept.
    from covviz import trackers
    from covviz.experiments.results import load_result
    from covviz.trackers.base import IdentityTracker

    class Breaks(IdentityTracker):
        def update(self, frame):
            if self._index == 3:
                raise ValueError("operands could not be broadcast together")
            return super().update(frame)

    monkeypatch.setattr(trackers, "make_tracker", lambda name, **kw: Breaks())
    with pytest.raises(ValueError, match="broadcast"):
        cli.main(track("--out", str(tmp_path), "--max-frames", "20"))
    doc, _ = load_result(tmp_path / "synthetic" / "identity_s0.json")
    assert doc["interrupted"] is True and doc["n_frames"] == 4


def test_value_error_exit_code_through_the_console(tmp_path):
    # The same as a user sees it: a bad config value is exit 2 with one line; a crash is exit 1.
    p = subprocess.run(
        [sys.executable, "-m", "covviz.cli", "track", "--out", str(tmp_path), "--particles", "1", "--no-save",
         "--max-frames", "3", "--no-progress"],
        capture_output=True, text=True, timeout=120, check=False,
    )
    assert p.returncode == 2, p.stderr
    assert p.stderr.strip().count("\n") == 0 and "n_particles must be an integer in [2" in p.stderr


@pytest.mark.parametrize(("cores", "save", "config", "want"), [
    (2, True, None, 1),  # a recording on two cores: one observation thread
    (2, False, None, 2),  # no recording: the default two
    (2, True, {"threads": 2}, 2),  # --config says so: kept
    (8, True, None, 2),  # more cores: the default
])
def test_a_recorded_run_on_two_cores_observes_with_one_thread(tmp_path, monkeypatch, cores, save, config, want):
    import os

    from covviz.cli.track import _threads_for_recording
    from covviz.trackers.manifold import ManifoldTracker

    monkeypatch.setattr(os, "cpu_count", lambda: cores)
    path = None
    if config is not None:
        path = tmp_path / "c.json"
        path.write_text(json.dumps(config))
    args = argparse.Namespace(spawn=False, connect=None, serve_web=False, no_save=not save, config=path,
                              trackers=["manifold", "identity"])
    trackers = [ManifoldTracker(), object()]  # a tracker without threads is left alone
    _threads_for_recording(args, trackers)
    assert trackers[0].config.threads == want
