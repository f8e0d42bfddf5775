"""The Rerun side of the command line: ``track --save/--no-save``, ``mds``, ``snapshot``, interruptions."""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
import time
from collections import namedtuple
from pathlib import Path

import cv2
import pytest
from viz_helpers import boxes, read_recording, rrd_verify

from covviz import cli
from covviz.cli.common import default_recording_path
from covviz.data.sequences import SyntheticConfig, SyntheticSequence, write_boxes
from covviz.viz import paths as P

FAST = ["--no-progress", "--particles", "30"]


def run_main(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture
def no_tracking(monkeypatch):
    """Fail the test if tracking starts."""
    import covviz.runner

    def boom(*a, **k):
        raise AssertionError("tracking started although the recording cannot be written")

    monkeypatch.setattr(covviz.runner, "run_many", boom)


def test_track_saves_a_recording(tmp_path):
    rrd = tmp_path / "sub" / "run.rrd"
    code, out, err = run_main(
        [
            "track",
            "--max-frames",
            "5",
            *FAST,
            "--out",
            str(tmp_path / "runs"),
            "--save",
            str(rrd),
            "--mds-every",
            "2",
        ]
    )
    assert code == 0, err
    assert f"recording in {rrd}" in out
    assert rrd_verify(rrd).returncode == 0
    t, s = read_recording(rrd)
    assert set(t[P.IMAGE]["EncodedImage:blob"]) == set(range(1, 6))  # frame numbers are 1-based
    assert set(t[P.TrackerPaths("manifold").cloud_kind("target")]["Points2D:positions"]) == {1, 3, 5}  # every 2nd frame from frame 1
    assert "covviz track" in s[P.CONFIG]["TextDocument:text"][0]


def test_track_default_recording_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_main(["track", "--max-frames", "3", *FAST, "--out", "runs", "--seed", "2"])
    assert code == 0, err
    assert (tmp_path / "recordings" / "synthetic-manifold-s2.rrd").is_file()
    assert default_recording_path("a b/c", ["manifold", "ipca"], 1) == Path(
        "recordings/a_b_c-manifold+ipca-s1.rrd"
    )


def test_no_save_writes_no_recording(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run_main(["track", "--max-frames", "3", *FAST, "--out", "runs", "--no-save"])
    assert code == 0, err
    assert not (tmp_path / "recordings").exists()


@pytest.mark.parametrize(
    "save, message",
    [
        ("afile/run.rrd", "cannot write the recording"),  # the parent is a regular file
        ("run.txt", "must end in .rrd"),
        ("adir.rrd", "is a folder"),
    ],
)
def test_unwritable_recording_fails_before_tracking(tmp_path, no_tracking, save, message):
    (tmp_path / "afile").write_text("not a folder")
    (tmp_path / "adir.rrd").mkdir()
    code, _, err = run_main(["track", *FAST, "--out", str(tmp_path / "runs"), "--save", str(tmp_path / save)])
    assert code == 2
    assert message in err
    assert len(err.strip().splitlines()) == 1  # one line that says what to fix


def test_full_disk_fails_before_tracking(tmp_path, monkeypatch, no_tracking):
    import shutil

    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: Usage(10**9, 10**9 - 10**5, 10**5))
    code, _, err = run_main(
        ["track", *FAST, "--out", str(tmp_path / "runs"), "--save", str(tmp_path / "x.rrd")]
    )
    assert code == 2
    assert "not enough free space" in err and len(err.strip().splitlines()) == 1


def test_save_and_no_save_contradict(tmp_path, no_tracking):
    code, _, err = run_main(
        ["track", *FAST, "--out", str(tmp_path), "--save", str(tmp_path / "x.rrd"), "--no-save"]
    )
    assert code == 2 and "contradict" in err


def test_viewer_flags_are_exclusive(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["track", "--spawn", "--serve-web"])
    assert exc.value.code == 2


def test_ctrl_c_leaves_a_recording_with_every_frame_before_it(tmp_path):
    """A real SIGINT to a running ``covviz track``: exit 130 and a valid recording of frames 0..k."""
    rrd = tmp_path / "int.rrd"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "covviz.cli",
            "track",
            "--no-progress",
            "--particles",
            "1500",  # slow enough (~20 s for the 300 frames) that the signal lands mid-run
            "--mds-every",
            "3",
            "--save",
            str(rrd),
            "--out",
            str(tmp_path / "runs"),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        cwd=tmp_path,
    )
    try:
        # Wait until frames are being written (the first batch of chunks reaches the file, a
        # few seconds into the run), then interrupt.
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if rrd.is_file() and rrd.stat().st_size > 150_000:
                break
            time.sleep(0.1)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err.decode()
    assert rrd_verify(rrd).returncode == 0
    t, s = read_recording(rrd)
    frames = set(t[P.IMAGE]["EncodedImage:blob"])
    assert frames and frames == set(range(1, max(frames) + 1))  # every frame up to the interruption
    assert set(boxes(t, P.TrackerPaths("manifold").box)) == frames
    assert "interrupted" in s[P.SUMMARY]["TextDocument:text"][0]


def _tiny_otb(root: Path, n: int = 12) -> Path:
    seq = SyntheticSequence(SyntheticConfig(n_frames=n))
    (root / "img").mkdir(parents=True)
    for i in range(n):
        cv2.imwrite(str(root / "img" / f"{i + 1:04d}.png"), seq.frame(i).image[..., ::-1])
    write_boxes(root / "groundtruth_rect.txt", seq.groundtruth, one_based=True)
    return root


def test_mds_writes_a_recording_and_pngs(tmp_path):
    seq = _tiny_otb(tmp_path / "Tiny")
    rrd, png = tmp_path / "mds.rrd", tmp_path / "png"
    code, out, err = run_main(
        [
            "mds",
            str(seq),
            "--frames",
            "1,6,11,400",
            "--particles",
            "30",
            "--max-target",
            "8",
            "--n-background",
            "2",
            "--save",
            str(rrd),
            "--png-dir",
            str(png),
            "--no-progress",
        ]
    )
    assert code == 0, err
    assert "templates at frames 1, 6, 11" in out
    assert rrd_verify(rrd).returncode == 0
    _, static = read_recording(rrd)
    assert len(static[f"{P.FIGURE_SEPARATION}/target"]["Points2D:positions"]) == 6  # 12 frames, stride 2
    assert len(static[f"{P.FIGURE_SEPARATION}/background"]["Points2D:positions"]) == 12
    assert f"{P.FIGURE_RANDOM_WALK}/frame_0006/near" in static  # the paper's caption: most similar to the truth
    assert f"{P.FIGURE_RANDOM_WALK}/initial" in static
    for name in ("Tiny-mds-separation.png", "Tiny-mds-random-walk.png"):
        img = cv2.imread(str(png / name))
        assert img is not None and img.std() > 10


def test_mds_default_frames_are_the_papers_as_far_as_the_sequence_goes(tmp_path):
    """Without --frames: 1, 101, 201, 501, 801 (the parser leaves them to the command, which imports the
    figures only when it runs), cut to the sequence's length."""
    seq = _tiny_otb(tmp_path / "Tiny")
    code, out, err = run_main(
        ["mds", str(seq), "--particles", "20", "--max-target", "6", "--n-background", "2", "--no-save", "--no-png",
         "--no-progress"]
    )
    assert code == 0, err
    assert out.rstrip().endswith("templates at frames 1"), out  # 101, 201, ... are past the 12 frames


def test_mds_frames_must_be_one_based(capsys):
    with pytest.raises(SystemExit):
        cli.main(["mds", "--frames", "0,5"])


def test_snapshot_of_a_missing_file(tmp_path):
    code, _, err = run_main(["snapshot", str(tmp_path / "none.rrd")])
    assert code == 2 and "no such recording" in err


def test_snapshot_size_is_validated(tmp_path):
    f = tmp_path / "x.rrd"
    f.write_bytes(b"")
    code, _, err = run_main(["snapshot", str(f), "--size", "big"])
    assert code == 2 and "--size" in err


def test_connect_to_no_viewer_fails_before_tracking(tmp_path, no_tracking):
    import socket

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    code, _, err = run_main(["track", *FAST, "--out", str(tmp_path), "--no-save", "--connect", url])
    assert code == 2 and "no viewer listens" in err and len(err.strip().splitlines()) == 1
