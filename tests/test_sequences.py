"""Tests for :mod:`covviz.data.sequences`.

All test data is built in ``tmp_path``: tiny PNG frames whose pixel values
encode their index (PNG is lossless, so a frame read back can be identified
exactly), JPG frames for the real-world file type, ground-truth text files in
the OTB and VOT conventions, and a small MJPG video. Tests on the real
sequences in ``../shared/sequences`` skip when that folder is absent.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from covviz.data.sequences import (
    Frame,
    OTBSequence,
    Sequence,
    SequenceError,
    SyntheticConfig,
    SyntheticSequence,
    VideoSequence,
    VOTSequence,
    open_sequence,
    read_boxes,
    write_boxes,
)

H, W = 24, 32  # size of the test frames, pixels
SHARED_SEQUENCES = Path(__file__).parents[2] / "shared" / "sequences"

# Tolerance for writing boxes with 2 decimals and reading them back.
BOX_ROUND_TRIP_ATOL = 0.005 + 1e-9


# --------------------------------------------------------------------------- #
# helpers
# --------------------------------------------------------------------------- #
@pytest.fixture
def rng():
    return np.random.default_rng(20240611)


def bgr_of(i: int) -> tuple[int, int, int]:
    """A BGR colour that encodes frame index ``i`` (distinct per channel)."""
    return (i % 256, (3 * i + 50) % 256, 255 - (i % 256))


def rgb_of(i: int) -> np.ndarray:
    b, g, r = bgr_of(i)
    return np.array([r, g, b], dtype=np.uint8)


def make_frame(i: int) -> np.ndarray:
    """A BGR frame (for cv2.imwrite) whose pixels encode ``i``; one corner pixel is marked."""
    img = np.empty((H, W, 3), np.uint8)
    img[:] = bgr_of(i)
    img[0, 0] = (7, 7, 7)  # a non-uniform pixel, so orientation/cropping errors show
    return img


def expected_rgb(i: int) -> np.ndarray:
    img = np.empty((H, W, 3), np.uint8)
    img[:] = rgb_of(i)
    img[0, 0] = (7, 7, 7)
    return img


def write_frames(folder: Path, names: list[str]) -> None:
    """Write frame ``k`` of ``names`` (in that order) as an index-encoded image."""
    folder.mkdir(parents=True, exist_ok=True)
    for k, name in enumerate(names):
        assert cv2.imwrite(str(folder / name), make_frame(k))


def make_otb(root: Path, n_frames: int = 5, gt_text: str | None = None, name: str = "Seq") -> Path:
    """An OTB folder with PNG frames 0001.png… and a 1-based ground truth."""
    folder = root / name
    write_frames(folder / "img", [f"{k + 1:04d}.png" for k in range(n_frames)])
    if gt_text is None:
        gt_text = "".join(f"{10 + k},{5 + k},8,6\n" for k in range(n_frames))
    (folder / "groundtruth_rect.txt").write_text(gt_text)
    return folder


# --------------------------------------------------------------------------- #
# OTB folders
# --------------------------------------------------------------------------- #
def test_otb_frames_sorted_numerically_not_lexically(tmp_path):
    folder = tmp_path / "Num"
    # Unpadded names: lexical order would be 1, 10, 11, 2, …
    order = [f"{k}.png" for k in range(1, 13)]
    write_frames(folder / "img", order)
    (folder / "groundtruth_rect.txt").write_text("1,1,4,4\n" * 12)
    seq = OTBSequence(folder)
    assert [p.name for p in seq.files] == order
    for k in (0, 1, 9, 11):
        np.testing.assert_array_equal(seq.frame(k).image, expected_rgb(k))


def test_otb_groundtruth_is_converted_to_zero_based(tmp_path):
    seq = OTBSequence(make_otb(tmp_path, n_frames=3, gt_text="70,51,107,87\n10.5,20.25,3,4\n1,1,2,2\n"))
    np.testing.assert_array_equal(
        seq.groundtruth, [[69, 50, 107, 87], [9.5, 19.25, 3, 4], [0, 0, 2, 2]]
    )
    np.testing.assert_array_equal(seq.init_box, [69, 50, 107, 87])
    np.testing.assert_array_equal(seq.frame(1).gt, [9.5, 19.25, 3, 4])


@pytest.mark.parametrize(
    "line",
    ["11,21,30,40", "11\t21\t30\t40", "11 21 30 40", "11, 21,\t30  40", "  11,21,30,40,  ", "11;21;30;40"],
    ids=["comma", "tab", "space", "mixed", "padded", "semicolon"],
)
def test_otb_groundtruth_separators(tmp_path, line):
    seq = OTBSequence(make_otb(tmp_path, n_frames=2, gt_text=f"{line}\n{line}\n"))
    np.testing.assert_array_equal(seq.groundtruth, [[10, 20, 30, 40]] * 2)


def test_otb_groundtruth_shorter_than_frames(tmp_path):
    gt = "".join(f"{k + 1},{k + 1},5,5\n" for k in range(3))
    seq = OTBSequence(make_otb(tmp_path, n_frames=5, gt_text=gt))
    assert len(seq) == 5  # the frames decide the length, not the ground truth
    assert seq.n_gt_lines == 3
    assert np.all(np.isfinite(seq.groundtruth[:3]))
    assert np.all(np.isnan(seq.groundtruth[3:]))
    assert seq.frame(2).gt is not None
    assert seq.frame(3).gt is None and seq.frame(4).gt is None
    # The frames without ground truth are still readable.
    np.testing.assert_array_equal(seq.frame(4).image, expected_rgb(4))


def test_otb_groundtruth_longer_than_frames_is_refused_by_number_and_truncated_by_order(tmp_path):
    gt = "".join(f"{k + 1},1,5,5\n" for k in range(7))
    folder = make_otb(tmp_path, n_frames=4, gt_text=gt)
    with pytest.raises(SequenceError, match="7 rows for 4 frames .*--frames-by order"):
        OTBSequence(folder)
    seq = OTBSequence(folder, frames_by="order")
    assert len(seq) == 4 and seq.groundtruth.shape == (4, 4)
    assert seq.n_gt_lines == 7
    np.testing.assert_array_equal(seq.groundtruth[:, 0], [0, 1, 2, 3])


@pytest.mark.parametrize(
    "missing_line", ["0,0,0,0", "NaN,NaN,NaN,NaN", "nan nan nan nan", "5,5,0,7", "5,5,7,-1", "inf,2,3,4"]
)
def test_otb_invalid_rows_become_missing(tmp_path, missing_line):
    seq = OTBSequence(make_otb(tmp_path, n_frames=3, gt_text=f"2,2,5,5\n{missing_line}\n3,3,5,5\n"))
    assert np.all(np.isnan(seq.groundtruth[1]))
    assert seq.frame(1).gt is None
    np.testing.assert_array_equal(seq.frame(2).gt, [2, 2, 5, 5])


def test_init_box_raises_when_first_frame_has_no_groundtruth(tmp_path):
    seq = OTBSequence(make_otb(tmp_path, n_frames=2, gt_text="0,0,0,0\n2,2,5,5\n"))
    with pytest.raises(SequenceError, match="first frame has no ground-truth box"):
        _ = seq.init_box


def test_init_box_is_a_copy(tmp_path):
    seq = OTBSequence(make_otb(tmp_path, n_frames=2))
    box = seq.init_box
    box[:] = -1
    np.testing.assert_array_equal(seq.init_box, [9, 4, 8, 6])
    frame_gt = seq.frame(0).gt
    frame_gt[:] = -1
    np.testing.assert_array_equal(seq.groundtruth[0], [9, 4, 8, 6])


def test_otb_frames_are_read_lazily(tmp_path):
    folder = make_otb(tmp_path, n_frames=6)
    seq = OTBSequence(folder)
    # No frame pixels are held by the sequence …
    held = [v for v in vars(seq).values() if isinstance(v, np.ndarray) and v.ndim == 3]
    assert held == []
    assert all(isinstance(p, Path) for p in seq.files)
    # … reading frame i returns frame i's pixels, in any order …
    for k in (3, 0, 5, 1):
        f = seq.frame(k)
        assert isinstance(f, Frame) and f.index == k
        assert f.image.dtype == np.uint8 and f.image.shape == (H, W, 3)
        np.testing.assert_array_equal(f.image, expected_rgb(k))
    # … and the file is read when the frame is asked for, not before.
    assert cv2.imwrite(str(folder / "img" / "0003.png"), make_frame(99))
    np.testing.assert_array_equal(seq.frame(2).image, expected_rgb(99))


def test_images_are_rgb(tmp_path):
    folder = tmp_path / "Rgb"
    (folder / "img").mkdir(parents=True)
    bgr = np.zeros((H, W, 3), np.uint8)
    bgr[:] = (10, 20, 30)  # B, G, R
    assert cv2.imwrite(str(folder / "img" / "0001.png"), bgr)
    (folder / "groundtruth_rect.txt").write_text("1,1,4,4\n")
    img = OTBSequence(folder).frame(0).image
    np.testing.assert_array_equal(img[0, 0], [30, 20, 10])


def test_otb_jpg_frames(tmp_path):
    folder = tmp_path / "Jpg"
    write_frames(folder / "img", [f"{k + 1:04d}.jpg" for k in range(3)])
    (folder / "groundtruth_rect.txt").write_text("1,1,4,4\n" * 3)
    seq = OTBSequence(folder)
    assert len(seq) == 3
    for k in range(3):
        # JPEG is lossy: compare the median colour with a tolerance.
        med = np.median(seq.frame(k).image.reshape(-1, 3), axis=0)
        np.testing.assert_allclose(med, rgb_of(k), atol=6)


def test_iteration_indices_and_out_of_range(tmp_path):
    seq = OTBSequence(make_otb(tmp_path, n_frames=4))
    frames = list(seq)
    assert [f.index for f in frames] == [0, 1, 2, 3]
    assert all(f.time is None for f in frames)  # OTB folders have no frame rate
    for bad in (-1, 4):
        with pytest.raises(IndexError, match="out of range"):
            seq.frame(bad)
    assert "4 frames" in repr(seq) and "Seq" in repr(seq)


def test_otb_explicit_and_alternative_groundtruth_file(tmp_path):
    folder = make_otb(tmp_path, n_frames=2)
    (folder / "groundtruth_rect.txt").unlink()
    (folder / "groundtruth_rect.1.txt").write_text("3,3,5,5\n3,3,5,5\n")
    (folder / "groundtruth_rect.2.txt").write_text("9,9,5,5\n9,9,5,5\n")
    np.testing.assert_array_equal(OTBSequence(folder).init_box, [2, 2, 5, 5])
    seq2 = OTBSequence(folder, groundtruth="groundtruth_rect.2.txt")
    np.testing.assert_array_equal(seq2.init_box, [8, 8, 5, 5])


# --------------------------------------------------------------------------- #
# VOT folders
# --------------------------------------------------------------------------- #
POLYGON = "10,20,30,15,35,40,12,45"  # bounding box x 10..35, y 15..45


@pytest.mark.parametrize("layout", ["color", "flat"])
def test_vot_layouts_polygon_and_rect(tmp_path, layout):
    folder = tmp_path / "bag"
    frames_dir = folder / "color" if layout == "color" else folder
    write_frames(frames_dir, [f"{k + 1:08d}.png" for k in range(3)])
    (folder / "groundtruth.txt").write_text(f"{POLYGON}\n5.5,6.5,7,8\n0,0,0,0\n")
    seq = VOTSequence(folder)
    assert seq.name == "bag" and len(seq) == 3
    # VOT regions are 0-based: no shift; a polygon becomes its bounding box.
    np.testing.assert_array_equal(seq.groundtruth[0], [10, 15, 25, 30])
    np.testing.assert_array_equal(seq.groundtruth[1], [5.5, 6.5, 7, 8])
    assert seq.frame(2).gt is None
    for k in range(3):
        np.testing.assert_array_equal(seq.frame(k).image, expected_rgb(k))


def test_vot_color_folder_wins_over_images_beside_groundtruth(tmp_path):
    folder = tmp_path / "v"
    write_frames(folder / "color", [f"{k + 1:08d}.png" for k in range(4)])
    assert cv2.imwrite(str(folder / "thumbnail.png"), make_frame(200))  # not a frame
    (folder / "groundtruth.txt").write_text("1,1,5,5\n" * 4)
    seq = VOTSequence(folder)
    assert len(seq) == 4
    assert all(p.parent.name == "color" for p in seq.files)


def test_vot_without_groundtruth_raises(tmp_path):
    write_frames(tmp_path / "v" / "color", ["00000001.png"])
    with pytest.raises(SequenceError, match="no groundtruth.txt"):
        VOTSequence(tmp_path / "v")


# --------------------------------------------------------------------------- #
# videos and image globs
# --------------------------------------------------------------------------- #
def test_video_sequence_from_glob(tmp_path):
    write_frames(tmp_path / "frames", [f"{k:03d}.png" for k in range(5)])
    seq = VideoSequence(str(tmp_path / "frames" / "*.png"), (3, 4, 10, 12))
    assert len(seq) == 5 and seq.name == "frames"
    np.testing.assert_array_equal(seq.init_box, [3, 4, 10, 12])
    np.testing.assert_array_equal(seq.frame(0).gt, [3, 4, 10, 12])
    assert all(seq.frame(k).gt is None for k in range(1, 5))
    for k in (4, 1, 2):
        np.testing.assert_array_equal(seq.frame(k).image, expected_rgb(k))


def test_video_sequence_glob_sorts_unpadded_numbers(tmp_path):
    # ffmpeg's default "%d.png" naming: lexical order would put 10 before 2.
    order = [f"{k}.png" for k in range(1, 12)]
    write_frames(tmp_path / "f", order)
    seq = VideoSequence(str(tmp_path / "f" / "*.png"), (0, 0, 4, 4))
    assert [p.name for p in seq.files] == order
    np.testing.assert_array_equal(seq.frame(9).image, expected_rgb(9))


def test_video_sequence_glob_ignores_non_images(tmp_path):
    write_frames(tmp_path / "f", ["1.png", "2.png"])
    (tmp_path / "f" / "notes.txt").write_text("hello")
    seq = VideoSequence(str(tmp_path / "f" / "*"), (0, 0, 4, 4))
    assert len(seq) == 2


def test_video_sequence_bad_input(tmp_path):
    with pytest.raises(SequenceError, match="matches no image files"):
        VideoSequence(str(tmp_path / "nothing" / "*.png"), (0, 0, 4, 4))
    with pytest.raises(SequenceError, match="no such file"):
        VideoSequence(tmp_path / "missing.avi", (0, 0, 4, 4))
    write_frames(tmp_path / "f", ["1.png"])
    with pytest.raises(SequenceError, match="4 numbers"):
        VideoSequence(str(tmp_path / "f" / "*.png"), (0, 0, 4))
    garbage = tmp_path / "garbage.avi"
    garbage.write_bytes(b"this is not a video\n" * 50)
    with pytest.raises(SequenceError, match="garbage.avi"):
        VideoSequence(garbage, (0, 0, 4, 4))


VIDEO_FPS = 12.0
VIDEO_FRAMES = 10


def video_value(i: int) -> int:
    """Grey level of video frame ``i``: far apart so MJPG loss cannot confuse them."""
    return 20 + 22 * i


@pytest.fixture
def mjpg_video(tmp_path) -> Path:
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), VIDEO_FPS, (W, H))
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG .avi videos (no codec / video I/O backend)")
    for i in range(VIDEO_FRAMES):
        writer.write(np.full((H, W, 3), video_value(i), np.uint8))
    writer.release()
    cap = cv2.VideoCapture(str(path))
    ok = cap.isOpened()
    cap.release()
    if not ok:
        pytest.skip("this OpenCV build wrote an MJPG .avi but cannot read it back")
    return path


def frame_value(seq: Sequence, i: int) -> float:
    return float(np.median(seq.frame(i).image))


def identify(value: float) -> int:
    return int(np.argmin([abs(value - video_value(k)) for k in range(VIDEO_FRAMES)]))


def test_video_file_metadata(mjpg_video):
    seq = VideoSequence(mjpg_video, (2, 3, 10, 8))
    assert len(seq) == VIDEO_FRAMES
    assert seq.frame_rate == pytest.approx(VIDEO_FPS)
    assert seq.name == "clip"
    np.testing.assert_array_equal(seq.init_box, [2, 3, 10, 8])
    f = seq.frame(3)
    assert f.image.shape == (H, W, 3) and f.image.dtype == np.uint8
    assert f.time == pytest.approx(3 / VIDEO_FPS)
    assert f.gt is None


def test_video_file_frames_in_order_and_out_of_order(mjpg_video):
    seq = VideoSequence(mjpg_video, (2, 3, 10, 8))
    # Sequential read.
    assert [identify(float(np.median(f.image))) for f in seq] == list(range(VIDEO_FRAMES))
    # Random access: backwards jumps, repeats, forward jumps, then sequential again.
    for k in (7, 2, 2, 0, 9, 4, 5, 6):
        value = frame_value(seq, k)
        assert identify(value) == k
        assert value == pytest.approx(video_value(k), abs=6)


# --------------------------------------------------------------------------- #
# open_sequence dispatch
# --------------------------------------------------------------------------- #
def test_open_sequence_synthetic_default():
    for source in (None, "synthetic"):
        seq = open_sequence(source)
        assert isinstance(seq, SyntheticSequence)
        assert len(seq) == SyntheticConfig().n_frames


def test_open_sequence_otb_and_vot(tmp_path):
    otb = open_sequence(make_otb(tmp_path, n_frames=3))
    assert isinstance(otb, OTBSequence) and len(otb) == 3
    vot = tmp_path / "vot"
    write_frames(vot / "color", [f"{k + 1:08d}.png" for k in range(2)])
    (vot / "groundtruth.txt").write_text(f"{POLYGON}\n{POLYGON}\n")
    seq = open_sequence(str(vot))
    assert isinstance(seq, VOTSequence)
    np.testing.assert_array_equal(seq.init_box, [10, 15, 25, 30])


def test_open_sequence_box_overrides_first_otb_box(tmp_path):
    folder = make_otb(tmp_path, n_frames=3)
    original = OTBSequence(folder).groundtruth
    seq = open_sequence(folder, box=[1, 2, 3, 4])
    np.testing.assert_array_equal(seq.init_box, [1, 2, 3, 4])
    np.testing.assert_array_equal(seq.groundtruth[1:], original[1:])
    with pytest.raises(SequenceError, match="4 numbers"):
        open_sequence(folder, box=[1, 2, 3])


def test_open_sequence_glob(tmp_path):
    write_frames(tmp_path / "frames", ["1.png", "2.png", "3.png"])
    pattern = str(tmp_path / "frames" / "*.png")
    with pytest.raises(SequenceError, match="needs --box"):
        open_sequence(pattern)
    seq = open_sequence(pattern, box=(1, 1, 5, 5))
    assert isinstance(seq, VideoSequence) and len(seq) == 3


def test_open_sequence_video_needs_box(mjpg_video):
    with pytest.raises(SequenceError, match="video needs --box"):
        open_sequence(mjpg_video)
    seq = open_sequence(str(mjpg_video), box=(1, 1, 5, 5))
    assert isinstance(seq, VideoSequence) and len(seq) == VIDEO_FRAMES


def test_open_sequence_video_needs_box_without_codec(tmp_path):
    # The box check comes before decoding, so it needs no codec.
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"\x00" * 64)
    with pytest.raises(SequenceError, match="video needs --box"):
        open_sequence(video)


def test_open_sequence_bad_sources(tmp_path):
    with pytest.raises(SequenceError, match="no such file or folder"):
        open_sequence(tmp_path / "nope")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(SequenceError, match="not a sequence folder"):
        open_sequence(tmp_path / "empty_dir")
    (tmp_path / "notes.txt").write_text("hi")
    with pytest.raises(SequenceError, match="not a video file"):
        open_sequence(tmp_path / "notes.txt")


# --------------------------------------------------------------------------- #
# bad input
# --------------------------------------------------------------------------- #
def test_missing_folder(tmp_path):
    with pytest.raises(SequenceError, match="no such folder"):
        OTBSequence(tmp_path / "absent")
    with pytest.raises(SequenceError, match="no such folder"):
        VOTSequence(tmp_path / "absent")


def test_folder_without_img_or_groundtruth(tmp_path):
    (tmp_path / "a").mkdir()
    with pytest.raises(SequenceError, match="no img/ folder"):
        OTBSequence(tmp_path / "a")
    write_frames(tmp_path / "b" / "img", ["0001.png"])
    with pytest.raises(SequenceError, match="no groundtruth_rect.txt"):
        OTBSequence(tmp_path / "b")


def test_folder_with_no_frames(tmp_path):
    folder = tmp_path / "Empty"
    (folder / "img").mkdir(parents=True)
    (folder / "img" / "readme.txt").write_text("no frames here")
    (folder / "groundtruth_rect.txt").write_text("1,1,5,5\n")
    with pytest.raises(SequenceError, match="no frames found"):
        OTBSequence(folder)
    with pytest.raises(SequenceError, match="no frames found"):
        open_sequence(folder)


def test_unreadable_image_raises_on_that_frame(tmp_path):
    folder = make_otb(tmp_path, n_frames=3)
    bad = folder / "img" / "0002.jpg"
    (folder / "img" / "0002.png").unlink()
    bad.write_text("this is not a JPEG, just some garbage text\n" * 10)
    seq = OTBSequence(folder)  # lazy: opening succeeds
    np.testing.assert_array_equal(seq.frame(0).image, expected_rgb(0))
    with pytest.raises(SequenceError, match=r"cannot read image .*0002\.jpg"):
        seq.frame(1)
    np.testing.assert_array_equal(seq.frame(2).image, expected_rgb(2))


@pytest.mark.parametrize("line", ["1,2,3", "1,2,3,4,5", "1,2,3,4,5,6,7", "1"])
def test_groundtruth_wrong_number_of_columns(tmp_path, line):
    folder = make_otb(tmp_path, n_frames=3, gt_text=f"1,1,5,5\n{line}\n1,1,5,5\n")
    n = len(line.split(","))
    with pytest.raises(SequenceError, match=rf"groundtruth_rect\.txt:2: expected 4 columns.*got {n}"):
        OTBSequence(folder)


@pytest.mark.parametrize("line", ["1,2,abc,4", "x y w h", "1,2,3,4px"])
def test_groundtruth_not_numbers(tmp_path, line):
    folder = make_otb(tmp_path, n_frames=2, gt_text=f"{line}\n1,1,5,5\n")
    with pytest.raises(SequenceError, match=r"groundtruth_rect\.txt:1: not numbers"):
        OTBSequence(folder)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 12).filter(lambda k: k not in (4, 8)))
def test_read_boxes_rejects_any_other_column_count(tmp_path, n):
    path = tmp_path / "boxes.txt"  # overwritten by every example
    path.write_text(",".join(["1"] * n) + "\n")
    with pytest.raises(SequenceError, match=f"got {n}"):
        read_boxes(path)


# --------------------------------------------------------------------------- #
# read_boxes / write_boxes
# --------------------------------------------------------------------------- #
def test_write_boxes_is_one_based_on_disk(tmp_path):
    path = tmp_path / "res.txt"
    write_boxes(path, np.array([[0, 0, 10, 20], [4.5, 9.25, 3, 4]]))
    assert path.read_text().splitlines() == ["1.00,1.00,10.00,20.00", "5.50,10.25,3.00,4.00"]
    write_boxes(path, np.array([[0, 0, 10, 20]]), one_based=False)
    assert path.read_text() == "0.00,0.00,10.00,20.00\n"


def test_write_boxes_does_not_mutate_input(tmp_path):
    boxes = np.array([[1.0, 2.0, 3.0, 4.0]])
    write_boxes(tmp_path / "r.txt", boxes)
    np.testing.assert_array_equal(boxes, [[1, 2, 3, 4]])


def test_read_write_round_trip_with_missing_rows(tmp_path, rng):
    boxes = np.column_stack([rng.uniform(-5, 300, (20, 2)), rng.uniform(1, 100, (20, 2))])
    boxes[[3, 11]] = np.nan
    for one_based in (True, False):
        path = tmp_path / f"r{one_based}.txt"
        write_boxes(path, boxes, one_based=one_based)
        back = read_boxes(path, one_based=one_based)
        assert back.shape == boxes.shape
        np.testing.assert_allclose(back, boxes, atol=BOX_ROUND_TRIP_ATOL, equal_nan=True)


finite = {"allow_nan": False, "allow_infinity": False}
box_strategy = st.tuples(
    st.floats(-1000, 5000, **finite),
    st.floats(-1000, 5000, **finite),
    st.floats(0.5, 5000, **finite),
    st.floats(0.5, 5000, **finite),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=st.lists(box_strategy, min_size=1, max_size=20), one_based=st.booleans())
def test_read_write_round_trip_property(tmp_path, rows, one_based):
    boxes = np.array(rows, dtype=np.float64)
    path = tmp_path / "boxes.txt"  # overwritten by every example
    write_boxes(path, boxes, one_based=one_based)
    back = read_boxes(path, one_based=one_based)
    assert back.shape == boxes.shape
    np.testing.assert_allclose(back, boxes, rtol=0, atol=BOX_ROUND_TRIP_ATOL)


def test_read_boxes_polygons(tmp_path):
    path = tmp_path / "poly.txt"
    # An axis-aligned rectangle as a polygon, a rotated square, a degenerate (flat) polygon.
    path.write_text("1,2,11,2,11,22,1,22\n5,0,10,5,5,10,0,5\n0,0,4,0,4,0,0,0\n")
    got = read_boxes(path, one_based=False)
    np.testing.assert_allclose(got[0], [1, 2, 10, 20])
    np.testing.assert_allclose(got[1], [0, 0, 10, 10])
    assert np.all(np.isnan(got[2]))  # zero height: missing
    np.testing.assert_allclose(read_boxes(path, one_based=True)[0], [0, 1, 10, 20])


point = st.tuples(st.floats(-500, 500, **finite), st.floats(-500, 500, **finite))


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pts=st.lists(point, min_size=4, max_size=4))
def test_read_boxes_polygon_is_bounding_box_property(tmp_path, pts):
    path = tmp_path / "poly.txt"
    path.write_text(",".join(f"{v:.3f}" for p in pts for v in p) + "\n")
    xy = np.round(np.array(pts), 3)
    x, y, w, h = read_boxes(path, one_based=False)[0]
    if np.isnan(x):
        assert np.ptp(xy[:, 0]) <= 0 or np.ptp(xy[:, 1]) <= 0
    else:
        np.testing.assert_allclose([x, y, x + w, y + h], [*xy.min(0), *xy.max(0)], atol=1e-9)


@pytest.mark.parametrize("text, line", [("\n1,1,5,5\n2,2,5,5\n", 1), ("1,1,5,5\n\n   \n2,2,5,5\n", 2),
                                        ("1,1,5,5\n \t\n2,2,5,5", 2)])
def test_read_boxes_refuses_a_blank_line_before_the_last_box(tmp_path, text, line):
    path = tmp_path / "b.txt"
    path.write_text(text)
    with pytest.raises(SequenceError, match=f"b.txt:{line}: a blank line .*NaN,NaN,NaN,NaN"):
        read_boxes(path)


def test_read_boxes_reads_trailing_blank_lines_and_empty_files(tmp_path):
    path = tmp_path / "b.txt"
    path.write_text("1,1,5,5\n2,2,5,5\n\n  \n")
    np.testing.assert_array_equal(read_boxes(path), [[0, 0, 5, 5], [1, 1, 5, 5]])
    path.write_text("")
    assert read_boxes(path).shape == (0, 4)


# --------------------------------------------------------------------------- #
# the synthetic sequence
# --------------------------------------------------------------------------- #
SYN_CHECK_FRAMES = (0, 60, 120, 200, 250, 299)


@pytest.fixture(scope="module")
def synthetic() -> SyntheticSequence:
    return SyntheticSequence()


def test_synthetic_is_deterministic(synthetic):
    other = SyntheticSequence(SyntheticConfig())
    np.testing.assert_array_equal(other.groundtruth, synthetic.groundtruth)
    np.testing.assert_array_equal(other.poses, synthetic.poses)
    for k in SYN_CHECK_FRAMES:
        a, b = synthetic.frame(k).image, other.frame(k).image
        assert a.tobytes() == b.tobytes()
    # Reading a frame twice (or out of order) gives the same pixels too.
    assert synthetic.frame(120).image.tobytes() == other.frame(120).image.tobytes()


def test_synthetic_seed_changes_frames(synthetic):
    other = SyntheticSequence(SyntheticConfig(seed=8))
    for k in (0, 150):
        assert not np.array_equal(other.frame(k).image, synthetic.frame(k).image)


def test_synthetic_shape_dtype_and_time(synthetic):
    assert len(synthetic) == 300 and synthetic.groundtruth.shape == (300, 4)
    assert synthetic.name == "synthetic"
    for k in (0, 299):
        f = synthetic.frame(k)
        assert f.image.shape == (240, 320, 3) and f.image.dtype == np.uint8
        assert f.time == pytest.approx(k / 30.0)
        assert f.gt is not None
    assert np.all(np.isfinite(synthetic.groundtruth))


def test_synthetic_groundtruth_matches_poses(synthetic):
    cfg = synthetic.config
    poses = synthetic.poses
    cx, cy, s = poses[:, 0], poses[:, 1], poses[:, 2]
    x, y, w, h = synthetic.groundtruth.T
    np.testing.assert_allclose(x + w / 2, cx, atol=1e-9)
    np.testing.assert_allclose(y + h / 2, cy, atol=1e-9)
    np.testing.assert_allclose(w, cfg.target_w * s, atol=1e-9)
    np.testing.assert_allclose(h, cfg.target_h * s, atol=1e-9)
    assert np.all((x < cx) & (cx < x + w) & (y < cy) & (cy < y + h))
    # The poses are a copy: the sequence's own state cannot be changed from outside.
    poses[:] = 0
    assert np.all(synthetic.poses[:, 2] > 0)


def test_synthetic_target_is_drawn_where_the_groundtruth_says(synthetic):
    # Frame 0 (theta = 0, scale = 1) against a frame where the target is far away:
    # the pixels that changed are the target, and they sit inside the ground-truth box.
    cx, cy = synthetic.poses[0, :2]
    far = int(np.argmax(np.hypot(*(synthetic.poses[:100, :2] - [cx, cy]).T)))
    assert np.hypot(*(synthetic.poses[far, :2] - [cx, cy])) > 80
    a = synthetic.frame(0).image[..., 0].astype(int)
    b = synthetic.frame(far).image[..., 0].astype(int)
    ys, xs = np.nonzero(np.abs(a - b) > 25)
    near = (np.abs(xs + 0.5 - cx) < 60) & (np.abs(ys + 0.5 - cy) < 60)
    xs, ys = xs[near] + 0.5, ys[near] + 0.5
    assert len(xs) > 0.5 * 40 * 52
    x, y, w, h = synthetic.groundtruth[0]
    assert xs.min() >= x - 1 and xs.max() <= x + w + 1
    assert ys.min() >= y - 1 and ys.max() <= y + h + 1
    assert abs(xs.mean() - cx) < 3 and abs(ys.mean() - cy) < 3


def test_synthetic_target_stays_inside_the_frame(synthetic):
    cfg = synthetic.config
    cx, cy, s, th = synthetic.poses.T
    # Corners of the rotated target region, in pixels.
    hw, hh = cfg.target_w * s / 2, cfg.target_h * s / 2
    for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        u, v = du * hw, dv * hh
        px = cx + np.cos(th) * u - np.sin(th) * v
        py = cy + np.sin(th) * u + np.cos(th) * v
        assert np.all((px >= 0) & (px <= cfg.width) & (py >= 0) & (py <= cfg.height))
    x, y, w, h = synthetic.groundtruth.T
    assert np.all((x >= 0) & (y >= 0) & (x + w <= cfg.width) & (y + h <= cfg.height))


def test_synthetic_illumination_dip(synthetic):
    cfg = synthetic.config
    before = synthetic.frame(cfg.illum_start - 1).image.mean()
    middle = synthetic.frame((cfg.illum_start + cfg.illum_end) // 2).image.mean()
    early = synthetic.frame(cfg.illum_start + 5).image.mean()
    after = synthetic.frame(cfg.illum_end).image.mean()
    assert middle < 0.7 * before  # the gain goes down to 0.55
    assert middle < early < before
    assert after > 0.9 * before  # and comes back


def test_synthetic_occluder_is_grey(synthetic):
    cfg = synthetic.config
    k = (cfg.occl_start + cfg.occl_end) // 2
    cx, cy, s, _ = synthetic.poses[k]
    # A patch well inside the occluder: left edge of the target, vertical centre.
    x_left = cx - cfg.target_w * s / 2
    bw = cfg.occl_fraction * cfg.target_w * s
    x0, x1 = int(x_left + 1), int(x_left + bw - 1)
    y0, y1 = int(cy - 0.5 * cfg.target_h * s), int(cy + 0.5 * cfg.target_h * s)
    assert x1 - x0 >= 8 and y1 - y0 >= 20
    patch = synthetic.frame(k).image[y0:y1, x0:x1].astype(float)
    np.testing.assert_allclose(np.median(patch[..., 0]), 120, atol=2)
    np.testing.assert_allclose(np.median(patch[..., 2]), 112, atol=2)  # the blue tint
    assert patch[..., 0].std() < 2 * cfg.noise_std
    # The same place before the occlusion is not a flat grey.
    assert synthetic.frame(cfg.occl_start - 1).image[y0:y1, x0:x1, 0].std() > 10


def test_synthetic_fast_stretch(synthetic):
    cfg = synthetic.config
    step = np.hypot(*np.diff(synthetic.poses[:, :2], axis=0).T)  # step[k]: frame k -> k+1
    fast = step[cfg.fast_start : cfg.fast_end - 1]
    slow = np.concatenate([step[: cfg.fast_start - 1], step[cfg.fast_end :]])
    assert fast.mean() > 2.5 * slow.mean()
    assert np.median(fast) > np.percentile(slow, 90)
    gt_centres = synthetic.groundtruth[:, :2] + synthetic.groundtruth[:, 2:] / 2
    gt_step = np.hypot(*np.diff(gt_centres, axis=0).T)
    assert gt_step[cfg.fast_start : cfg.fast_end - 1].mean() > 2.5 * gt_step[: cfg.fast_start - 1].mean()


def test_synthetic_short_sequence(synthetic):
    seq = SyntheticSequence(SyntheticConfig(n_frames=40))
    assert len(seq) == 40
    np.testing.assert_allclose(seq.groundtruth, synthetic.groundtruth[:40])
    assert seq.frame(39).image.tobytes() == synthetic.frame(39).image.tobytes()
    with pytest.raises(IndexError):
        seq.frame(40)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_frames": 1}, "at least 2 frames"),
        ({"n_frames": 0}, "at least 2 frames"),
        ({"target_w": 8}, "target size"),
        ({"target_h": 15}, "target size"),
        ({"target_w": 160}, "target size"),
        ({"target_h": 120}, "target size"),
    ],
)
def test_synthetic_config_validation(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SyntheticConfig(**kwargs)


def test_synthetic_config_is_frozen():
    cfg = SyntheticConfig()
    with pytest.raises(AttributeError):
        cfg.seed = 3  # type: ignore[misc]
    assert cfg.seed == 7


# --------------------------------------------------------------------------- #
# the real sequences (skipped when ../shared/sequences is absent)
# --------------------------------------------------------------------------- #
def real_sequence(name: str) -> Path:
    folder = SHARED_SEQUENCES / name
    if not folder.is_dir():
        pytest.skip(f"real sequence {name} not available at {folder}")
    return folder


def test_real_football1_groundtruth_shorter_than_frames():
    seq = open_sequence(real_sequence("Football1"))
    assert isinstance(seq, OTBSequence)
    assert len(seq) == 81
    assert int(np.all(np.isfinite(seq.groundtruth), axis=1).sum()) == 74
    assert seq.frame(73).gt is not None
    last = seq.frame(80)
    assert last.gt is None
    assert last.image.shape == (288, 352, 3) and last.image.dtype == np.uint8
    assert seq.files[0].name == "0001.jpg" and seq.files[-1].name == "0081.jpg"


def test_real_car4_first_box_is_zero_based():
    seq = OTBSequence(real_sequence("Car4"))
    np.testing.assert_array_equal(seq.init_box, [69, 50, 107, 87])
    np.testing.assert_array_equal(seq.frame(0).gt, [69, 50, 107, 87])
    assert seq.frame(0).image.shape == (240, 360, 3)


def test_real_vot15_bag_loads_as_otb():
    folder = real_sequence("VOT15_bag")
    seq = open_sequence(folder)
    assert isinstance(seq, OTBSequence)
    assert len(seq) == 196 and np.all(np.isfinite(seq.groundtruth))
    assert seq.frame(0).image.shape == (360, 480, 3)
    # groundtruth_rect.txt is the axis-aligned hull of VOT's polygons (groundtruth_orig.txt, 0-based
    # pixels), written 1-based like every OTB file: read as 1-based it is the hull, as 0-based it is
    # the hull shifted by one pixel right and down.
    hull = read_boxes(folder / "groundtruth_orig.txt", one_based=False)
    rect = read_boxes(folder / "groundtruth_rect.txt", one_based=True)
    assert hull.shape == rect.shape == (196, 4)
    np.testing.assert_allclose(rect, hull, atol=0.01)
    np.testing.assert_allclose(seq.groundtruth, hull, atol=0.01)
    raw = read_boxes(folder / "groundtruth_rect.txt", one_based=False)
    np.testing.assert_allclose(raw - rect, np.tile([1.0, 1.0, 0.0, 0.0], (196, 1)), atol=1e-9)
