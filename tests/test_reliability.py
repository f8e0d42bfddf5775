"""Nothing silently wrong (issue 19): frames matched to their ground truth, one writer per output, one-line errors.

Each test here failed before the fix it names (the issue's defect number in its
docstring). Frames are tiny PNG/JPEG folders in ``tmp_path``; the dev sequences
are read from ``../shared/sequences`` when present (skipped otherwise).
"""

from __future__ import annotations

import contextlib
import io
import json
import logging
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from covviz import cli
from covviz.data.sequences import SequenceError, VOTSequence, open_sequence, read_boxes

SHARED_SEQUENCES = Path(__file__).resolve().parents[2] / "shared" / "sequences"
H, W = 24, 32


def run_main(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


def one_error_line(err: str, command: str = "track") -> str:
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("INFO:")]
    assert len(lines) == 1, err
    assert lines[0].startswith(f"covviz {command}: error:"), err
    assert "Traceback" not in err
    return lines[0]


def frame_image(k: int) -> np.ndarray:
    """A BGR frame whose colour encodes ``k``."""
    img = np.empty((H, W, 3), np.uint8)
    img[:] = (k % 256, (3 * k + 50) % 256, 255 - k % 256)
    return img


def gt_line(k: int) -> str:
    """Ground-truth row of frame number ``k`` (1-based x encodes k)."""
    return f"{k},3,8,6"


def make_seq(root: Path, names: list[str], gt_lines: list[str], name: str = "Seq") -> Path:
    folder = root / name
    (folder / "img").mkdir(parents=True)
    for k, n in enumerate(names):
        assert cv2.imwrite(str(folder / "img" / n), frame_image(k))
    (folder / "groundtruth_rect.txt").write_text("".join(line + "\n" for line in gt_lines))
    return folder


def numbered(n: int, ext: str = ".png") -> list[str]:
    return [f"{k:04d}{ext}" for k in range(1, n + 1)]


def track(seq_dir: Path, tmp_path: Path, *extra: str) -> tuple[int, str, str]:
    return run_main(["track", str(seq_dir), "--trackers", "identity", "--no-progress", "--no-save",
                     "--out", str(tmp_path / "runs"), *extra])


# --------------------------------------------------------------------------- #
# defects 1-4: frames and ground-truth rows matched by one rule, by number
# --------------------------------------------------------------------------- #
def test_a_blank_line_in_the_ground_truth_is_refused_naming_it(tmp_path):
    """Defect 1: a blank line used to be skipped, moving every later row onto the frame before its own."""
    lines = [gt_line(k) for k in range(1, 11)]
    seq_dir = make_seq(tmp_path, numbered(10), lines[:3] + [""] + lines[3:9])
    code, _, err = track(seq_dir, tmp_path)
    assert code == 2
    line = one_error_line(err)
    assert "groundtruth_rect.txt:4: a blank line" in line and "NaN,NaN,NaN,NaN" in line
    assert not (tmp_path / "runs").exists()


def test_two_files_of_one_number_are_refused(tmp_path):
    """Defect 2: img/0005.png beside img/0005.jpg made 31 frames and turned the numbering check off."""
    seq_dir = make_seq(tmp_path, numbered(10), [gt_line(k) for k in range(1, 11)])
    assert cv2.imwrite(str(seq_dir / "img" / "0005.jpg"), frame_image(99))
    code, _, err = track(seq_dir, tmp_path)
    assert code == 2
    line = one_error_line(err)
    assert "two files for frame number 5" in line and "0005.jpg" in line and "0005.png" in line
    assert "--frames-by order" in line


def test_an_unnumbered_image_among_the_frames_is_refused(tmp_path):
    """Defect 3: 0010 deleted plus a cover.jpg: the gap check switched off and cover.jpg became the last frame."""
    seq_dir = make_seq(tmp_path, numbered(12), [gt_line(k) for k in range(1, 13)])
    (seq_dir / "img" / "0010.png").unlink()
    assert cv2.imwrite(str(seq_dir / "img" / "cover.png"), frame_image(50))
    code, _, err = track(seq_dir, tmp_path)
    assert code == 2
    line = one_error_line(err)
    assert "cover.png: an image without a frame number" in line and "--frames-by order" in line
    (seq_dir / "img" / "cover.png").unlink()
    code, _, err = track(seq_dir, tmp_path)  # then the gap is named
    assert code == 2 and "0010.png: frame missing" in one_error_line(err)


def test_a_missing_first_frame_is_refused_not_shifted(tmp_path):
    """Defect 4: with 0001 deleted, 0002.jpg was scored against row 1."""
    seq_dir = make_seq(tmp_path, numbered(10), [gt_line(k) for k in range(1, 11)])
    (seq_dir / "img" / "0001.png").unlink()
    with pytest.raises(SequenceError, match=r"0001.png: frame missing .*--frames-by order"):
        open_sequence(seq_dir).check_frames(10)
    code, _, err = track(seq_dir, tmp_path)
    assert code == 2 and "0001.png: frame missing" in one_error_line(err)


def test_more_rows_than_frames_is_refused_and_fewer_are_reported(tmp_path, caplog):
    """Defect 4: 30 rows for 29 frames drew no word; fewer rows than frames is fine and said."""
    caplog.set_level(logging.INFO, logger="covviz")
    seq_dir = make_seq(tmp_path, numbered(6), [gt_line(k) for k in range(1, 8)])
    code, _, err = track(seq_dir, tmp_path)
    assert code == 2
    assert "7 rows for 6 frames" in one_error_line(err)
    short = make_seq(tmp_path, numbered(6), [gt_line(k) for k in range(1, 5)], name="Short")
    code, _out, err = track(short, tmp_path)
    assert code == 0, err
    assert "4 rows for 6 frames: frames 5-6 are tracked but not scored" in caplog.text


def test_frames_by_order_takes_the_files_in_name_order(tmp_path):
    """``--frames-by order``: the k-th file in natural name order gets row k, extra rows are dropped."""
    names = ["f1.png", "f2.png", "f10.png", "f11.png", "cover.png"]
    seq_dir = make_seq(tmp_path, names, [gt_line(k) for k in range(1, 8)])
    with pytest.raises(SequenceError):
        open_sequence(seq_dir)
    seq = open_sequence(seq_dir, frames_by="order")
    assert [p.name for p in seq.files] == ["cover.png", "f1.png", "f2.png", "f10.png", "f11.png"]
    np.testing.assert_array_equal(seq.groundtruth[:, 0], [0, 1, 2, 3, 4])
    code, out, err = track(seq_dir, tmp_path, "--frames-by", "order")
    assert code == 0, err
    assert "5 frames" in out


def test_macos_resource_files_are_not_frames(tmp_path):
    """``._0001.jpg`` (macOS AppleDouble files on a shared drive) are ignored, not refused nor tracked."""
    seq_dir = make_seq(tmp_path, numbered(5), [gt_line(k) for k in range(1, 6)])
    for n in numbered(5):
        (seq_dir / "img" / f"._{n}").write_bytes(b"\x00\x05\x16\x07AppleDouble")
    seq = open_sequence(seq_dir)
    assert [p.name for p in seq.files] == numbered(5) and seq.missing == []


def test_a_byte_order_mark_is_accepted(tmp_path):
    """Smaller one: a ground truth saved with a UTF-8 byte-order mark was refused as 'not numbers'."""
    seq_dir = make_seq(tmp_path, numbered(3), [])
    (seq_dir / "groundtruth_rect.txt").write_bytes("\ufeff1,3,8,6\n2,3,8,6\n3,3,8,6\n".encode())
    seq = open_sequence(seq_dir)
    np.testing.assert_array_equal(seq.groundtruth[:, 0], [0, 1, 2])


def _numbering_case(rng: np.random.Generator, n: int):
    """A numbered folder broken in one random way, and what the rule must say about it."""
    kind = rng.choice(["missing", "duplicate", "unnumbered", "blank", "extra_rows", "short_rows", "clean"])
    names = numbered(n)
    lines = [gt_line(k) for k in range(1, n + 1)]
    extra: list[str] = []
    expect = None
    if kind == "missing":
        k = int(rng.integers(0, n))
        # The last file missing leaves more rows than frames.
        expect = f"{names[k]}: frame missing" if k < n - 1 else f"{n} rows for {n - 1} frames"
        names = names[:k] + names[k + 1:]
    elif kind == "duplicate":
        k = int(rng.integers(1, n + 1))
        extra = [f"{k:04d}.jpg"]
        expect = f"two files for frame number {k}"
    elif kind == "unnumbered":
        extra = [str(rng.choice(["cover.png", "thumb.jpg", "poster.bmp"]))]
        expect = f"{extra[0]}: an image without a frame number"
    elif kind == "blank":
        k = int(rng.integers(0, n - 1))
        lines = lines[:k] + [str(rng.choice(["", "  ", "\t"]))] + lines[k:]
        expect = f"groundtruth_rect.txt:{k + 1}: a blank line"
    elif kind == "extra_rows":
        lines = lines + [gt_line(k) for k in range(n + 1, n + 1 + int(rng.integers(1, 4)))]
        expect = f"{len(lines)} rows for {n} frames"
    elif kind == "short_rows":
        lines = lines[: int(rng.integers(1, n))]
    return str(kind), names, extra, lines, expect


@pytest.mark.parametrize("case", range(24))
def test_the_numbering_rule_on_generated_folders(tmp_path, case):
    """Generated cases: every break is refused with its file or line; a clean or short folder keeps row k on frame k."""
    rng = np.random.default_rng([19, case])
    n = int(rng.integers(4, 12))
    _kind, names, extra, lines, expect = _numbering_case(rng, n)
    folder = make_seq(tmp_path, names, lines)
    for e in extra:
        assert cv2.imwrite(str(folder / "img" / e), frame_image(77))
    if expect is not None:
        with pytest.raises(SequenceError, match=expect.replace(".", r"\.")):
            open_sequence(folder).check_frames(n)
        return
    seq = open_sequence(folder)
    seq.check_frames(len(seq))
    assert len(seq) == n and [p.name for p in seq.files] == numbered(n)
    rows = len(lines)
    # Frame k (0-based) gets row k, whose x (1-based) encodes its number k + 1.
    np.testing.assert_array_equal(seq.groundtruth[:rows, 0], np.arange(rows))
    assert np.all(np.isnan(seq.groundtruth[rows:]))
    for k in (0, n - 1):
        np.testing.assert_array_equal(seq.frame(k).image, cv2.cvtColor(frame_image(k), cv2.COLOR_BGR2RGB))


def test_the_generated_folders_cover_every_kind_of_break():
    kinds = set()
    for case in range(24):  # as the test above draws them
        rng = np.random.default_rng([19, case])
        kinds.add(_numbering_case(rng, int(rng.integers(4, 12)))[0])
    assert kinds == {"missing", "duplicate", "unnumbered", "blank", "extra_rows", "short_rows", "clean"}


def test_vot_frames_follow_the_same_rule(tmp_path):
    folder = tmp_path / "vot"
    folder.mkdir()
    for k, n in enumerate([f"{k:08d}.jpg" for k in (1, 2, 4)]):
        assert cv2.imwrite(str(folder / n), frame_image(k))
    (folder / "groundtruth.txt").write_text("1,1,5,5\n2,2,5,5\n3,3,5,5\n")
    seq = VOTSequence(folder)
    assert seq.missing == [2]
    with pytest.raises(SequenceError, match="00000003.jpg: frame missing"):
        seq.check_frames(3)


@pytest.mark.skipif(not SHARED_SEQUENCES.is_dir(), reason="the dev sequences are not on this machine")
def test_every_dev_sequence_loads_frame_k_with_row_k():
    """All 14 dev sequences load as before: every image file a frame, in number order, row k from line k."""
    folders = sorted(p for p in SHARED_SEQUENCES.iterdir() if p.is_dir())
    assert len(folders) == 14
    for folder in folders:
        seq = open_sequence(folder)
        files = sorted((folder / "img").glob("*.jpg"))
        assert [p.name for p in seq.files] == [p.name for p in files], folder.name
        assert seq.missing == []
        seq.check_frames(len(seq))
        text = (folder / "groundtruth_rect.txt").read_text().splitlines()
        rows = np.array([[float(v) for v in line.replace(",", " ").split()] for line in text if line.strip()])
        assert len(seq) == len(files) and seq.n_gt_lines == len(rows) <= len(files), folder.name
        rows[:, :2] -= 1
        np.testing.assert_array_equal(seq.groundtruth[: len(rows)], rows, err_msg=folder.name)
        assert np.all(np.isnan(seq.groundtruth[len(rows):]))
    assert open_sequence(SHARED_SEQUENCES / "Football1").n_gt_lines == 74


# --------------------------------------------------------------------------- #
# defect 9: a ground truth that is not a file
# --------------------------------------------------------------------------- #
def test_a_ground_truth_folder_or_dangling_link_is_one_line(tmp_path):
    seq_dir = make_seq(tmp_path, numbered(4), [gt_line(k) for k in range(1, 5)])
    gt = seq_dir / "groundtruth_rect.txt"
    gt.unlink()
    gt.mkdir()
    code, _, err = track(seq_dir, tmp_path)
    assert code == 2 and "groundtruth_rect.txt: is a folder, not a box file" in one_error_line(err)
    gt.rmdir()
    gt.symlink_to(tmp_path / "elsewhere.txt")
    code, _, err = track(seq_dir, tmp_path)
    assert code == 2 and "elsewhere.txt, which does not exist" in one_error_line(err)
    with pytest.raises(SequenceError):
        read_boxes(gt)


# --------------------------------------------------------------------------- #
# defect 7: one writer per output
# --------------------------------------------------------------------------- #
REPO = Path(__file__).resolve().parents[1]


def test_a_second_run_on_the_same_outputs_is_refused_before_it_writes(tmp_path):
    """Defect 7: two tracks with one --save and --out both exited 0, with a broken recording and mixed results."""
    from covviz.experiments.results import result_paths
    from covviz.locks import hold_outputs, lock_path

    seq_dir = make_seq(tmp_path, numbered(6), [gt_line(k) for k in range(1, 7)])
    out, rrd = tmp_path / "runs", tmp_path / "same.rrd"
    rrd.write_bytes(b"the other run's recording")
    stem = result_paths(out, "Seq", "identity", 0)[1]
    stem.parent.mkdir(parents=True)
    with hold_outputs([(rrd, "choose another --save")]):  # as a run in another process holds it
        code, _, err = run_main(["track", str(seq_dir), "--trackers", "identity", "--no-progress",
                                 "--save", str(rrd), "--out", str(out)])
    assert code == 2
    line = one_error_line(err)
    assert f"is writing {rrd}" in line and "another --save" in line and "pid " in line
    assert rrd.read_bytes() == b"the other run's recording"  # never opened
    assert not list(stem.parent.glob("*.json"))
    with hold_outputs([(stem, "choose another --out")]):
        code, _, err = track(seq_dir, tmp_path)
    assert code == 2 and f"is writing {stem}" in one_error_line(err)
    code, _, err = track(seq_dir, tmp_path)  # both released: the run goes, and leaves no lock behind
    assert code == 0, err
    assert not lock_path(stem).exists() and not lock_path(rrd).exists()


def test_two_processes_on_one_recording(tmp_path):
    """Defect 7, as it happened: a run in another process holds the recording, the second is refused."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from covviz.locks import lock_path

    rrd = tmp_path / "same.rrd"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    first = subprocess.Popen(
        [sys.executable, "-m", "covviz.cli", "track", "--trackers", "identity", "--no-progress", "--save", str(rrd),
         "--out", str(tmp_path / "a")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        cwd=tmp_path)
    try:
        deadline = time.monotonic() + 60
        while not lock_path(rrd).exists() and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.01)
        os.kill(first.pid, signal.SIGSTOP)  # holding its locks, while the second one starts
        try:
            assert first.poll() is None, first.communicate()
            code, _, err = run_main(["track", "--trackers", "identity", "--no-progress", "--save", str(rrd),
                                     "--out", str(tmp_path / "b")])
        finally:
            os.kill(first.pid, signal.SIGCONT)
        _, err1 = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 0, err1
    assert code == 2 and f"another covviz run (pid {first.pid}" in one_error_line(err)
    assert not (tmp_path / "b" / "synthetic").exists()
    rerun = shutil.which("rerun")
    if rerun is not None:  # the first run's recording is whole
        verify = subprocess.run([rerun, "rrd", "verify", str(rrd)], capture_output=True, timeout=120, check=False)
        assert verify.returncode == 0, verify.stderr
    assert not lock_path(rrd).exists()


# --------------------------------------------------------------------------- #
# defects 8, 10, 11: one line, not a traceback
# --------------------------------------------------------------------------- #
def test_frames_of_one_pixel_are_one_line_and_leave_no_recording(tmp_path):
    """Defect 8: 1x1 frames raised 'ValueError: gray must have shape …' and left an empty 139 KB recording."""
    folder = tmp_path / "Tiny"
    (folder / "img").mkdir(parents=True)
    for k in range(1, 6):
        assert cv2.imwrite(str(folder / "img" / f"{k:04d}.png"), np.full((1, 1, 3), 20 * k, np.uint8))
    (folder / "groundtruth_rect.txt").write_text("1,1,1,1\n" * 5)
    rrd = tmp_path / "tiny.rrd"
    code, _, err = run_main(["track", str(folder), "--no-progress", "--save", str(rrd), "--out", str(tmp_path / "r")])
    assert code == 2
    assert "the frames are 1x1 pixels" in one_error_line(err)
    assert not rrd.exists() and not (tmp_path / "r").exists()


@pytest.mark.parametrize("length", [251, 300])
def test_a_recording_name_too_long_is_one_line(tmp_path, length):
    """Defect 10: --save with a 300-character file name raised 'OSError: File name too long'."""
    rrd = tmp_path / ("a" * (length - 4) + ".rrd")
    code, _, err = run_main(["track", "--trackers", "identity", "--no-progress", "--save", str(rrd),
                             "--out", str(tmp_path / "r")])
    assert code == 2
    assert f"the file name is {length} bytes" in one_error_line(err)


def test_a_sequence_path_too_long_is_one_line_and_a_long_name_gets_a_recording(tmp_path, monkeypatch):
    """Defect 10: a 300-character sequence path raised 'OSError'; a 250-character folder name made a
    default recording name too long to create."""
    code, _, err = run_main(["track", str(tmp_path / ("x" * 300)), "--no-progress", "--no-save"])
    assert code == 2 and "File name too long" in one_error_line(err)
    long = make_seq(tmp_path, numbered(3), [gt_line(k) for k in range(1, 4)], name="L" * 250)
    monkeypatch.chdir(tmp_path)
    code, _out, err = run_main(["track", str(long), "--trackers", "identity", "--no-progress", "--out", "r"])
    assert code == 0, err
    (rrd,) = (tmp_path / "recordings").glob("*.rrd")
    assert len(rrd.name) <= 250 and rrd.name.endswith("-identity-s0.rrd") and rrd.stat().st_size > 0


def test_the_viewer_beside_python_is_found_without_path(monkeypatch):
    """Defect 11: --spawn from a venv's covviz, the venv not activated, found no viewer though it sat beside covviz."""
    import sys

    from covviz.viz import snapshot

    beside = Path(sys.executable).parent / "rerun"
    if not beside.is_file():
        pytest.skip("no rerun beside this Python")
    monkeypatch.setenv("PATH", "/nonexistent")
    monkeypatch.delenv("RERUN_CLI_PATH", raising=False)
    monkeypatch.setitem(sys.modules, "rerun_cli", None)  # as if its native binary were not there
    assert snapshot.find_viewer() == str(beside)


def test_spawn_starts_the_viewer_it_found(monkeypatch):
    """Defect 11: attach_sinks handed the search to rerun, which looks in PATH only."""
    import rerun as rr

    from covviz.viz import sinks

    calls = []
    monkeypatch.setattr(rr, "spawn", lambda **kw: calls.append(kw))
    monkeypatch.setattr(sinks, "find_viewer", lambda: "/opt/venv/bin/rerun")
    stream = sinks.new_recording()
    sinks.attach_sinks(stream, spawn=True, port=9911)
    assert calls and calls[0]["executable_path"] == "/opt/venv/bin/rerun" and calls[0]["connect"] is False
    monkeypatch.setattr(sinks, "find_viewer", lambda: None)
    code, _, err = run_main(["track", "--trackers", "identity", "--no-progress", "--no-save", "--spawn"])
    assert code == 2 and "--spawn: no Rerun viewer found" in one_error_line(err)


# --------------------------------------------------------------------------- #
# defect 12: snapshot on a full disk, and a busy viewer
# --------------------------------------------------------------------------- #
class _FakeViewer:
    """A viewer client whose save_screenshot fails as rerun 0.41's does."""

    def __init__(self, errors):
        self.errors = list(errors)
        self.calls = 0

    def save_screenshot(self, path):
        self.calls += 1
        if self.errors:
            raise self.errors.pop(0)
        Path(path).write_bytes(b"png")


def test_a_full_disk_under_the_screenshot_is_one_line(tmp_path):
    """Defect 12: 'ConnectionError … No space left on device' escaped as a traceback."""
    from covviz.viz.snapshot import SnapshotError, save_screenshot

    viewer = _FakeViewer([ConnectionError("status: Internal, message: \"No space left on device (os error 28)\"")])
    with pytest.raises(SnapshotError, match=r"no space left on the device while writing .*shot.png .*MB free"):
        save_screenshot(viewer, tmp_path / "shot.png")


def test_a_busy_viewer_is_retried_then_said(tmp_path, monkeypatch):
    """Defect 12: under load a 'TimeoutError: Deadline expired' traceback came from the viewer."""
    from covviz.viz import snapshot

    monkeypatch.setattr(snapshot.time, "sleep", lambda s: None)
    viewer = _FakeViewer([TimeoutError("Deadline expired before operation could complete")])
    snapshot.save_screenshot(viewer, tmp_path / "shot.png")  # the second try succeeds
    assert viewer.calls == 2 and (tmp_path / "shot.png").read_bytes() == b"png"
    viewer = _FakeViewer([TimeoutError("Deadline expired")] * snapshot.VIEWER_CALL_TRIES)
    with pytest.raises(snapshot.SnapshotError, match="did not take the screenshot in time, 3 tries .*--timeout"):
        snapshot.save_screenshot(viewer, tmp_path / "other.png")


def test_snapshot_refuses_a_disk_without_room_before_the_viewer_starts(tmp_path, monkeypatch):
    import shutil as sh

    from covviz.viz import snapshot

    rrd = tmp_path / "r.rrd"
    rrd.write_bytes(b"x")
    monkeypatch.setattr(snapshot, "vulkan_available", lambda: True)
    monkeypatch.setattr(snapshot, "find_viewer", lambda: "/bin/false")
    monkeypatch.setattr(snapshot.shutil, "disk_usage", lambda p: sh._ntuple_diskusage(10**9, 10**9, 10**5))
    started = []
    monkeypatch.setattr(snapshot.subprocess, "Popen", lambda *a, **k: started.append(a))
    code, _, err = run_main(["snapshot", str(rrd), "--out", str(tmp_path / "s.png")])
    assert code == 2
    assert "not enough free space for the screenshot" in one_error_line(err, "snapshot")
    assert not started


# --------------------------------------------------------------------------- #
# defect 15: bench from the folder that holds the clone
# --------------------------------------------------------------------------- #
def test_bench_from_the_folder_holding_a_clone_runs_this_covviz(tmp_path, monkeypatch, capsys):
    """Defect 15: 'cd ..; covviz bench' after 'git clone … covviz': every job failed with
    "ImportError: cannot import name '__version__' from 'covviz' (unknown location)"."""
    import covviz
    from covviz.experiments.bench import bench

    make_seq(tmp_path / "seqs", numbered(4), [gt_line(k) for k in range(1, 5)])
    (tmp_path / "covviz" / "tests").mkdir(parents=True)  # the clone: a folder called covviz, no __init__.py
    (tmp_path / "covviz" / "README.md").write_text("# covviz\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("PYTHONPATH", raising=False)  # as a user has it
    summary = bench(tmp_path / "seqs", ["identity"], tmp_path / "out", seeds=1, jobs=1, progress=False, report=False)
    assert summary["failed"] == [] and summary["run"] == 1
    doc = json.loads((tmp_path / "out" / "Seq" / "identity.json").read_text())
    assert doc["versions"]["covviz"] == covviz.__version__


# --------------------------------------------------------------------------- #
# defect 16: error exits leave nothing behind; report reads only its own files
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("case", ["trials0", "storage"])
def test_tune_that_fails_at_once_leaves_nothing(tmp_path, monkeypatch, case):
    """Defect 16: --trials 0 left a 114 KB study.db, a bad --storage left empty folders."""
    pytest.importorskip("optuna")
    make_seq(tmp_path / "seqs", numbered(4), [gt_line(k) for k in range(1, 5)])
    monkeypatch.chdir(tmp_path)
    extra = ["--trials", "0"] if case == "trials0" else ["--trials", "1", "--storage", "bogus://nowhere"]
    code, _, err = run_main(["tune", str(tmp_path / "seqs"), "--out", "made/tune", "--no-progress", *extra])
    assert code == 2
    line = one_error_line(err, "tune")
    assert ("--trials 0 reports on an existing study" in line) if case == "trials0" else ("bogus://nowhere" in line)
    assert not (tmp_path / "made").exists()


def test_a_storage_error_is_one_line():
    from covviz.experiments.tune import TuneError, _storage

    optuna = pytest.importorskip("optuna")
    with pytest.raises(TuneError) as info:
        _storage(optuna, "sqlite:////nonexistent/folder/x.db")
    assert "\n" not in str(info.value) and "unable to open database file" in str(info.value)


def test_mds_on_a_truncated_frame_leaves_no_folder(tmp_path, monkeypatch):
    """Defect 16: 'covviz mds' on a truncated JPEG left an empty recordings/ folder."""
    folder = tmp_path / "Seq"
    (folder / "img").mkdir(parents=True)
    rng = np.random.default_rng(3)
    for k in range(1, 9):
        assert cv2.imwrite(str(folder / "img" / f"{k:04d}.jpg"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    (folder / "groundtruth_rect.txt").write_text("20,12,16,14\n" * 8)
    jpg = folder / "img" / "0003.jpg"
    jpg.write_bytes(jpg.read_bytes()[:400])
    monkeypatch.chdir(tmp_path)
    code, _, err = run_main(["mds", str(folder), "--no-progress"])
    assert code == 2 and "0003.jpg" in one_error_line(err, "mds")
    assert not (tmp_path / "recordings").exists()


def test_report_skips_json_that_covviz_did_not_write(tmp_path, caplog):
    """Defect 16: 'covviz report /tmp' told the user to delete another tool's JSON."""
    from covviz.experiments.report import load_runs
    from covviz.experiments.results import ResultError

    seq_dir = make_seq(tmp_path, numbered(4), [gt_line(k) for k in range(1, 5)])
    assert track(seq_dir, tmp_path)[0] == 0
    (tmp_path / "runs" / "other").mkdir()
    (tmp_path / "runs" / "other" / "model.json").write_text('{"format": "someone-else/2"}')
    (tmp_path / "runs" / "other" / "notes.json").write_text("not json at all")
    _, runs, _ = load_runs(tmp_path / "runs")
    assert [(r.sequence, r.tracker) for r in runs] == [("Seq", "identity")]
    assert "skipped 2 JSON file(s) that are not covviz results" in caplog.text
    ours = tmp_path / "runs" / "Seq" / "identity_s0.json"
    ours.write_text(ours.read_text()[:120])  # a covviz result cut short is still ours: named, not skipped
    with pytest.raises(ResultError, match="identity_s0.json: corrupt results file"):
        load_runs(tmp_path / "runs")


# --------------------------------------------------------------------------- #
# defect 14 and a smaller one: a recording cut mid-message, another app's recording
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module")
def small_recording(tmp_path_factory) -> Path:
    """A covviz recording of 60 synthetic frames (identity tracker: it loses the target, so it has events)."""
    d = tmp_path_factory.mktemp("rec")
    rrd = d / "run.rrd"
    code, _, err = run_main(["track", "--trackers", "identity", "--max-frames", "60", "--no-progress",
                             "--save", str(rrd), "--out", str(d / "runs")])
    assert code == 0, err
    return rrd


@pytest.mark.parametrize("share", [0.5, 0.8])
def test_events_of_a_recording_cut_mid_message_are_read_up_to_the_cut(small_recording, tmp_path, share, caplog):
    """Defect 14: 'covviz events' on a cut recording failed with 'payload exceeds file size'."""
    from covviz.viz.readback import last_frame, read_events, readable_length

    data = small_recording.read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: int(len(data) * share)])
    assert readable_length(cut) < cut.stat().st_size  # it does end inside a message
    events = read_events(cut)
    whole = read_events(small_recording)
    assert events == [e for e in whole if e["index"] < len(events)]  # a prefix of the whole recording's
    assert "was cut short" in caplog.text and f"rerun rrd migrate {cut}" in caplog.text
    assert 1 <= last_frame(cut) <= last_frame(small_recording)
    code, out, err = run_main(["events", str(cut)])
    assert code == 0 and "Traceback" not in err
    assert len(out.splitlines()) == max(1, len(events))  # one line an event (or "no events")


def test_the_readable_part_of_a_cut_recording_is_a_valid_recording(small_recording, tmp_path):
    """Defect 14 (snapshot): the viewer opens the copy of the whole messages (it opened nothing of the cut file)."""
    import subprocess

    from covviz.viz.readback import readable_file

    data = small_recording.read_bytes()
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: len(data) // 2])
    with readable_file(cut) as (src, kept):
        assert src != cut and kept == (src.stat().st_size, cut.stat().st_size)
        assert cut.read_bytes().startswith(src.read_bytes())
        rerun = shutil.which("rerun")
        if rerun is not None:
            ok = subprocess.run([rerun, "rrd", "verify", "--check-footers", "false", str(src)], capture_output=True,
                                timeout=120, check=False)
            assert ok.returncode == 0, ok.stderr
    assert not src.exists()  # the copy goes with the block
    with readable_file(small_recording) as (same, kept):
        assert same == small_recording and kept is None


def test_events_of_another_apps_recording_says_so(tmp_path):
    """Smaller one: 'covviz events' on another app's .rrd said 'no events', exit 0."""
    import rerun as rr

    other = tmp_path / "other.rrd"
    stream = rr.RecordingStream("someone-else")
    stream.save(str(other))
    stream.log("points", rr.Points2D([[0, 0]]))
    stream.flush()
    stream.disconnect()
    code, _, err = run_main(["events", str(other)])
    assert code == 2
    assert "not a covviz recording (application someone-else)" in one_error_line(err, "events")
    (tmp_path / "text.rrd").write_text("hello")
    code, _, err = run_main(["events", str(tmp_path / "text.rrd")])
    assert code == 2 and "not a Rerun recording" in one_error_line(err, "events")


# --------------------------------------------------------------------------- #
# the smaller ones
# --------------------------------------------------------------------------- #
def test_a_truncated_video_names_its_frame_from_1(tmp_path):
    """Smaller one: the error for a truncated video gave a 0-based frame number."""
    from covviz.data.sequences import VideoSequence

    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    rng = np.random.default_rng(5)
    for _ in range(30):
        writer.write(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    writer.release()
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    seq = VideoSequence(path, (5, 5, 10, 10))
    read = 0
    with pytest.raises(SequenceError) as info:
        for _ in seq:
            read += 1
    assert 0 < read < 30
    assert f"cannot decode frame {read + 1} (frames count from 1" in str(info.value)
    assert f"--max-frames {read}" in str(info.value)


def test_track_dot_names_the_sequence_after_its_folder(tmp_path, monkeypatch):
    """Smaller one: 'covviz track .' gave an empty sequence name and wrote results straight into --out."""
    seq_dir = make_seq(tmp_path, numbered(4), [gt_line(k) for k in range(1, 5)], name="Here")
    monkeypatch.chdir(seq_dir)
    code, _, err = run_main(["track", ".", "--trackers", "identity", "--no-progress", "--no-save",
                               "--out", str(tmp_path / "runs")])
    assert code == 0, err
    assert (tmp_path / "runs" / "Here" / "identity_s0.json").is_file()
    assert not list((tmp_path / "runs").glob("*.json"))
    monkeypatch.chdir(seq_dir / "img")
    assert open_sequence("..").name == "Here"


def test_max_frames_1_is_refused_in_one_line(tmp_path):
    """Smaller one: '--max-frames 1' printed 'nan fps' and 'no ground truth' (only the given box was 'tracked')."""
    code, out, err = run_main(["track", "--trackers", "identity", "--max-frames", "1", "--no-progress", "--no-save",
                               "--out", str(tmp_path / "runs")])
    assert code == 2 and "nan" not in out
    assert "--max-frames 1 tracks nothing" in one_error_line(err)
    code, out, err = run_main(["track", "--trackers", "identity", "--max-frames", "2", "--no-progress", "--no-save",
                               "--out", str(tmp_path / "runs")])
    assert code == 0 and "nan fps" not in out and "2 frames" in out


def test_after_ctrl_c_the_recording_holds_every_frame_of_the_results():
    """Smaller one: after Ctrl-C the recording was one frame short of the results (the signal landed while the
    tracking thread waited to hand the frame to the recorder's queue, after the frame was counted done)."""
    import os
    import signal
    import threading
    import time

    from covviz.data.synthetic import SyntheticConfig, SyntheticSequence
    from covviz.runner import BackgroundObserver, Observer, ResultCollector, run_many
    from covviz.signals import stop_signals
    from covviz.trackers.base import IdentityTracker

    class SlowRecorder(Observer):
        def __init__(self):
            self.frames = []

        def on_frame(self, frame, records, found):
            time.sleep(0.02)  # slower than the tracker: the queue is full, the tracking thread waits on it
            self.frames.append(frame.index)

    for attempt in range(5):
        recorder, collector = SlowRecorder(), ResultCollector()
        seq = SyntheticSequence(SyntheticConfig(n_frames=400))
        timer = threading.Timer(0.3 + 0.037 * attempt, os.kill, (os.getpid(), signal.SIGINT))
        with stop_signals():
            timer.start()
            with pytest.raises(KeyboardInterrupt):
                run_many([IdentityTracker()], seq, [BackgroundObserver(recorder, maxsize=1), collector])
        timer.join()
        n = len(collector.results[0].boxes)
        assert 0 < n < 400
        assert recorder.frames == list(range(n)), (attempt, n, recorder.frames[-3:])


def test_patch_size_has_an_upper_bound():
    """Smaller one: patch_size had no upper bound (2000 took 180 s for 2 frames)."""
    from covviz.trackers.manifold import ManifoldConfig

    for bad in (129, 2000):
        with pytest.raises(ValueError, match=r"patch_size must be an integer in \[4, 128\]"):
            ManifoldConfig().replace(patch_size=bad)
    assert ManifoldConfig().replace(patch_size=128).observation.patch_size == 128


def test_a_huge_patch_size_in_a_config_file_is_one_line(tmp_path):
    cfg = tmp_path / "c.json"
    cfg.write_text('{"patch_size": 2000}')
    code, _, err = run_main(["track", "--no-progress", "--no-save", "--config", str(cfg), "--out", str(tmp_path / "r")])
    assert code == 2 and "patch_size must be an integer in [4, 128]" in one_error_line(err)


# --------------------------------------------------------------------------- #
# defects 5-6: configuration recorded as if it ran (the architecture issue's declarative validation
# fixes them; these flip green when it lands)
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("field, value", [("quadrants", "false"), ("jit", "no"), ("gain_normalize", 1),
                                          ("antialias", "true")])
def test_a_boolean_field_of_another_type_is_refused(field, value):
    """Defect 5: {"quadrants": "false"} ran with quadrants on and wrote "false" into the results."""
    from covviz.trackers.manifold import ManifoldConfig

    with pytest.raises(ValueError, match=field):
        ManifoldConfig.from_dict({field: value})


def test_a_config_file_with_a_string_boolean_does_not_run(tmp_path):
    """Defect 5, from the command line: no such file runs (exit 2, one line, no results written)."""
    cfg = tmp_path / "c.json"
    cfg.write_text('{"quadrants": "false"}')
    code, _, err = run_main(["track", "--no-progress", "--no-save", "--max-frames", "3", "--config", str(cfg),
                             "--out", str(tmp_path / "r")])
    assert code == 2 and "quadrants" in one_error_line(err)
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize("value", [5, "fast", [1, 2]])
def test_kinematics_of_another_type_is_refused_before_the_run(value):
    """Defect 6: {"kinematics": 5} was accepted and failed mid-run with AttributeError."""
    from covviz.trackers.manifold import ManifoldConfig

    with pytest.raises(ValueError, match="kinematics"):
        ManifoldConfig.from_dict({"kinematics": value})


def test_the_memory_estimate_is_above_what_runs_took():
    """Smaller one: the estimate behind the --particles guard said 161/280 MB where a run on Car4 took 231/482 MB
    (RSS, 600 particles, unrecorded/recorded), so it could let an out-of-memory run through. Measured again:
    238/457 MB at 600 particles and 283/623 MB at 4000 (300 frames)."""
    from covviz.resources import run_memory

    car4 = (240, 360, 3)
    for particles, frames, plain, recorded in [(600, 659, 231e6, 482e6), (600, 300, 238e6, 457e6),
                                               (4000, 300, 283e6, 623e6)]:
        assert run_memory(particles, car4, 1, False, frames) > plain
        assert run_memory(particles, car4, 1, True, frames) > recorded
        assert run_memory(particles, car4, 1, True, frames) < 1.25 * recorded  # an estimate, not a refusal
    assert run_memory(600, car4, 1, True, 10_000) > run_memory(600, car4, 1, True, 1000)


def _container_sizes(obj, prefix: str) -> dict[str, tuple[int, int | None]]:
    """``(length, maxlen)`` of every list, dict, set or deque attribute of ``obj`` (one level), by name."""
    from collections import deque

    return {f"{prefix}.{k}": (len(v), getattr(v, "maxlen", None)) for k, v in vars(obj).items()
            if isinstance(v, (list, dict, set, deque))}


def test_what_the_recorder_and_the_diagnosis_keep_stays_bounded(tmp_path):
    """The memory leak of a recorded run (~16-25 MB per 1000 frames): no structure of the recorder or of the
    drift diagnosis grows with the frames (only the lists of events, one entry an event). The growth is in
    Rerun's native recording stream (flat with the stream disabled; Python heap, arrow pool and object
    counts flat): see the issue 19 notes."""
    from covviz.data.synthetic import SyntheticConfig, SyntheticSequence
    from covviz.diagnosis.drift import Diagnoser
    from covviz.runner import Observer, Pipeline, run
    from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
    from covviz.viz.logger import LoggerConfig, RerunLogger
    from covviz.viz.sinks import attach_sinks, close_stream, new_recording

    per_event = {"logger.losses", "logger.drifts", "logger.diagnoses", "diag.events", "diag.diagnoses",
                 "diag.suspects"}
    diag = Diagnoser()
    stream = new_recording()
    attach_sinks(stream, save=tmp_path / "b.rrd")
    logger = RerunLogger(stream, LoggerConfig(mds_every=10, seed=0, diagnosis=diag.config))
    seen: dict[int, dict[str, int]] = {}

    class Probe(Observer):
        def on_frame(self, frame, records, found):
            if frame.index in (60, 199):
                sizes = {**_container_sizes(logger, "rerun_logger"), **_container_sizes(diag, "diagnoser")}
                for s in logger._states:
                    sizes.update(_container_sizes(s, "logger"))
                for s in diag.states:
                    sizes.update(_container_sizes(s, "diag"))
                seen[frame.index] = sizes

    seq = SyntheticSequence(SyntheticConfig(n_frames=200))
    run(ManifoldTracker(ManifoldConfig(n_particles=60), rng=0), seq, [Pipeline([diag, logger]), Probe()], seed=0)
    close_stream(stream)
    early, late = seen[60], seen[199]
    assert early.keys() == late.keys() and len(early) >= 10
    # What grew is a deque with a bound (recent frames: history, drawn, healthy gap), within it.
    grew = {k: (early[k], late[k]) for k in early if late[k][0] > early[k][0] and k not in per_event
            and not (late[k][1] is not None and late[k][0] <= late[k][1])}
    assert not grew, grew
    assert {k for k in early if late[k][0] > early[k][0] and k not in per_event} <= {
        "diag.history", "logger.drawn", "logger.healthy_gap"}
    n_events = sum(late[k][0] for k in per_event if k in late)
    assert n_events < 40  # events, not frames
