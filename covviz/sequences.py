"""Tracking sequences behind one interface.

Every source yields the same :class:`Frame` records, lazily (one image in
memory at a time):

* :class:`OTBSequence` — an OTB folder: ``img/0001.jpg …`` and
  ``groundtruth_rect.txt`` (``x,y,w,h`` per line, 1-based, separated by commas,
  tabs or spaces; it may be shorter than the frames, as in OTB's Football1).
* :class:`VOTSequence` — a VOT folder: frames in ``color/`` (or the folder
  itself) and ``groundtruth.txt`` with rectangles or polygons (8 numbers); a
  polygon becomes its axis-aligned bounding box.
* :class:`VideoSequence` — a video file or an image glob, with the initial box
  given by the user (``--box x,y,w,h``, 0-based pixels).
* :class:`SyntheticSequence` (:mod:`covviz.synthetic`) — the embedded
  default: a deterministic textured target on a cluttered background, with
  translation, scale and rotation, a stretch of fast pose change, an
  illumination change and a partial occlusion; ``synthetic:NAME`` is one of
  its controlled failures (:mod:`covviz.scenarios`).

:class:`Frame`, :class:`Sequence` and :class:`SequenceError` live in
:mod:`covviz.frames` and are re-exported here, with the synthetic classes.

Boxes are returned in 0-based pixels (see :mod:`covviz.records`); rows of
ground truth that are missing or invalid are ``nan``.
"""

from __future__ import annotations

import glob as _glob
import re
from pathlib import Path

import cv2
import numpy as np

from covviz.frames import Frame, Sequence, SequenceError
from covviz.synthetic import SyntheticConfig, SyntheticSequence

__all__ = [
    "Frame",
    "OTBSequence",
    "Sequence",
    "SequenceError",
    "SyntheticConfig",
    "SyntheticSequence",
    "VOTSequence",
    "VideoSequence",
    "open_sequence",
    "read_boxes",
    "write_boxes",
]

IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".mpg", ".mpeg", ".m4v")


# --------------------------------------------------------------------------- #
# reading and writing boxes
# --------------------------------------------------------------------------- #
_SEP = re.compile(r"[,\s;]+")


def read_boxes(path: str | Path, one_based: bool = True) -> np.ndarray:
    """Read a box file (OTB ground truth or results) into ``(n, 4)`` 0-based boxes.

    Lines hold ``x,y,w,h`` separated by commas, tabs or spaces; lines with 8
    numbers are polygons ``x1,y1,…,x4,y4`` and become their axis-aligned
    bounding box. ``NaN`` fields or non-positive sizes mark a missing box and
    become a ``nan`` row.

    Raises
    ------
    SequenceError
        If a line does not hold 4 (or 8) numbers.
    """
    path = Path(path)
    rows = []
    for lineno, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        parts = [p for p in _SEP.split(line) if p]
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise SequenceError(f"{path}:{lineno}: not numbers: {line[:60]!r}") from None
        if len(vals) == 8:
            xs, ys = vals[0::2], vals[1::2]
            vals = [min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys)]
        elif len(vals) != 4:
            raise SequenceError(
                f"{path}:{lineno}: expected 4 columns x,y,w,h (or 8 for a polygon), got {len(vals)}"
            )
        rows.append(vals)
    boxes = np.array(rows, dtype=np.float64).reshape(-1, 4)
    bad = ~np.all(np.isfinite(boxes), axis=1) | (boxes[:, 2] <= 0) | (boxes[:, 3] <= 0)
    boxes[bad] = np.nan
    if one_based:
        boxes[:, :2] -= 1.0
    return boxes


def write_boxes(path: str | Path, boxes: np.ndarray, one_based: bool = True) -> None:
    """Write ``(n, 4)`` 0-based boxes in the OTB results format (``x,y,w,h`` per line)."""
    b = np.array(boxes, dtype=np.float64, copy=True)
    if one_based:
        b[:, :2] += 1.0
    Path(path).write_text("".join(",".join(f"{v:.2f}" for v in row) + "\n" for row in b))


# --------------------------------------------------------------------------- #
# image-file sequences
# --------------------------------------------------------------------------- #
def _read_image(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise SequenceError(f"cannot read image {path}: the file is missing, empty or not an image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _list_images(folder: Path) -> list[Path]:
    files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]
    return sorted(files, key=lambda p: (len(p.stem), p.stem))


class _ImageFilesSequence(Sequence):
    def __init__(self, name: str, files: list[Path], groundtruth: np.ndarray, frame_rate=None):
        if not files:
            raise SequenceError(f"{name}: no frames found (expected image files such as 0001.jpg)")
        self.name = name
        self.files = files
        self.frame_rate = frame_rate
        n = len(files)
        gt = np.full((n, 4), np.nan)
        m = min(n, len(groundtruth))
        gt[:m] = groundtruth[:m]
        self.groundtruth = gt
        self.n_gt_lines = len(groundtruth)

    def _read(self, i: int) -> np.ndarray:
        return _read_image(self.files[i])


class OTBSequence(_ImageFilesSequence):
    """An OTB folder: ``img/*.jpg`` and ``groundtruth_rect.txt`` (1-based)."""

    def __init__(self, folder: str | Path, groundtruth: str | None = None):
        folder = Path(folder)
        if not folder.is_dir():
            raise SequenceError(f"{folder}: no such folder")
        img = folder / "img"
        if not img.is_dir():
            raise SequenceError(f"{folder}: no img/ folder (OTB layout is img/0001.jpg … + groundtruth_rect.txt)")
        if groundtruth is None:
            cands = sorted(folder.glob("groundtruth_rect*.txt"))
            if not cands:
                raise SequenceError(f"{folder}: no groundtruth_rect.txt")
            gt_path = cands[0]
        else:
            gt_path = folder / groundtruth
        super().__init__(folder.name, _list_images(img), read_boxes(gt_path, one_based=True))


class VOTSequence(_ImageFilesSequence):
    """A VOT folder: frames in ``color/`` (or the folder) and ``groundtruth.txt``.

    VOT regions are rectangles or polygons in 0-based pixel coordinates; a
    polygon becomes its axis-aligned bounding box.
    """

    def __init__(self, folder: str | Path):
        folder = Path(folder)
        if not folder.is_dir():
            raise SequenceError(f"{folder}: no such folder")
        gt_path = folder / "groundtruth.txt"
        if not gt_path.is_file():
            raise SequenceError(f"{folder}: no groundtruth.txt (VOT layout)")
        frames_dir = folder / "color" if (folder / "color").is_dir() else folder
        super().__init__(folder.name, _list_images(frames_dir), read_boxes(gt_path, one_based=False))


class VideoSequence(Sequence):
    """A video file or an image glob, with the initial box given by the user.

    Parameters
    ----------
    source : str or Path
        A video file (``.mp4``, ``.avi`` …) or a glob such as ``frames/*.png``.
    box : array-like, shape (4,)
        Initial box ``x, y, w, h`` in 0-based pixels.
    """

    def __init__(self, source: str | Path, box):
        source = str(source)
        self.name = Path(source.split("*")[0]).stem or Path(source).parent.name or "video"
        self._cap = None
        if any(c in source for c in "*?["):
            files = [Path(p) for p in _glob.glob(source) if Path(p).suffix.lower() in IMAGE_EXTENSIONS]
            # Same numeric order as folders (1.png, 2.png, 10.png), not lexical.
            self.files = sorted(files, key=lambda p: (str(p.parent), len(p.stem), p.stem))
            if not self.files:
                raise SequenceError(f"{source}: the glob matches no image files")
            n = len(self.files)
        else:
            p = Path(source)
            if not p.is_file():
                raise SequenceError(f"{source}: no such file")
            self.files = None
            self._path = p
            cap = cv2.VideoCapture(str(p))
            if not cap.isOpened():
                raise SequenceError(f"{source}: OpenCV cannot open this video")
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            fps = cap.get(cv2.CAP_PROP_FPS)
            cap.release()
            if n <= 0:
                raise SequenceError(f"{source}: the video has no frames")
            self.frame_rate = float(fps) if fps and fps > 0 else None
            self._next = 0
        b = np.asarray(box, dtype=np.float64).reshape(-1)
        if b.shape != (4,):
            raise SequenceError(f"--box must be 4 numbers x,y,w,h; got {box!r}")
        self.groundtruth = np.full((n, 4), np.nan)
        self.groundtruth[0] = b

    def _read(self, i: int) -> np.ndarray:
        if self.files is not None:
            return _read_image(self.files[i])
        if self._cap is None or i != self._next:
            if self._cap is not None:
                self._cap.release()
            self._cap = cv2.VideoCapture(str(self._path))
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, i)
        ok, img = self._cap.read()
        if not ok:
            raise SequenceError(f"{self._path}: cannot decode frame {i}")
        self._next = i + 1
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# --------------------------------------------------------------------------- #
# dispatch
# --------------------------------------------------------------------------- #
def open_sequence(source: str | Path | None = None, box=None) -> Sequence:
    """Open a sequence from a path, guessing its layout.

    Parameters
    ----------
    source : str or Path, optional
        ``None`` or ``"synthetic"``: the embedded synthetic default;
        ``"synthetic:NAME"``: one of its failure scenarios
        (:data:`covviz.scenarios.SCENARIOS`). A folder
        with ``img/``: OTB. A folder with ``groundtruth.txt``: VOT. A video file
        or an image glob: needs ``box``.
    box : array-like, shape (4,), optional
        Initial box (0-based pixels) for videos and globs; for OTB/VOT folders
        it overrides the first ground-truth box.

    Raises
    ------
    SequenceError
        With a one-line message saying what is wrong.
    """
    if source is None or str(source) == "synthetic":
        seq: Sequence = SyntheticSequence()
    elif str(source).startswith("synthetic:"):
        from covviz.scenarios import open_scenario

        seq = open_scenario(str(source).partition(":")[2])
    else:
        s = str(source)
        p = Path(s)
        if any(c in s for c in "*?["):
            if box is None:
                raise SequenceError(f"{s}: an image glob needs --box x,y,w,h")
            return VideoSequence(s, box)
        if p.is_dir():
            if (p / "img").is_dir():
                seq = OTBSequence(p)
            elif (p / "groundtruth.txt").is_file():
                seq = VOTSequence(p)
            else:
                raise SequenceError(
                    f"{p}: not a sequence folder (expected img/ + groundtruth_rect.txt, "
                    "or groundtruth.txt with frames)"
                )
        elif p.is_file():
            if p.suffix.lower() not in VIDEO_EXTENSIONS:
                raise SequenceError(f"{p}: not a video file ({', '.join(VIDEO_EXTENSIONS)}) or sequence folder")
            if box is None:
                raise SequenceError(f"{p}: a video needs --box x,y,w,h")
            return VideoSequence(p, box)
        else:
            raise SequenceError(f"{s}: no such file or folder")
    if box is not None:
        b = np.asarray(box, dtype=np.float64).reshape(-1)
        if b.shape != (4,):
            raise SequenceError(f"--box must be 4 numbers x,y,w,h; got {box!r}")
        seq.groundtruth = seq.groundtruth.copy()
        seq.groundtruth[0] = b
    return seq
