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
* :class:`SyntheticSequence` (:mod:`covviz.data.synthetic`) — the embedded
  default: a deterministic textured target on a cluttered background, with
  translation, scale and rotation, a stretch of fast pose change, an
  illumination change and a partial occlusion; ``synthetic:NAME`` is one of
  its controlled failures (:mod:`covviz.data.scenarios`).

:class:`Frame`, :class:`Sequence` and :class:`SequenceError` live in
:mod:`covviz.data.frames` and are re-exported here, with the synthetic classes.

Boxes are returned in 0-based pixels (see :mod:`covviz.records`); rows of
ground truth that are missing or invalid are ``nan``.
"""

from __future__ import annotations

import glob as _glob
import logging
import os
import re
from pathlib import Path

import cv2
import numpy as np

from covviz.data.frames import Frame, Sequence, SequenceError
from covviz.data.synthetic import SyntheticConfig, SyntheticSequence

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
#: How frames are matched to ground-truth rows: ``number`` (the default: the file numbered k is frame k and gets
#: row k; a gap, a duplicate, an unnumbered file or more rows than frames is refused) or ``order`` (the k-th
#: image file in natural name order gets row k, whatever the numbers; extra rows are dropped).
FRAMES_BY = ("number", "order")
log = logging.getLogger("covviz")
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".mpg", ".mpeg", ".m4v")


# --------------------------------------------------------------------------- #
# reading and writing boxes
# --------------------------------------------------------------------------- #
_SEP = re.compile(r"[,\s;]+")


def read_boxes(path: str | Path, one_based: bool = True) -> np.ndarray:
    """Read a box file (OTB ground truth or results) into ``(n, 4)`` 0-based boxes, row k for line k.

    Lines hold ``x,y,w,h`` separated by commas, tabs or spaces; lines with 8
    numbers are polygons ``x1,y1,…,x4,y4`` and become their axis-aligned
    bounding box. ``NaN`` fields or non-positive sizes mark a missing box and
    become a ``nan`` row. A UTF-8 byte-order mark is accepted; blank lines at
    the end are not rows. Line k is frame k's box, so a blank line before the
    last box would move every later box onto the frame before its own: it is
    refused.

    Raises
    ------
    SequenceError
        If the file cannot be read, a line does not hold 4 (or 8) numbers, or a
        blank line comes before the last box.
    """
    path = Path(path)
    text = _read_box_text(path)
    rows = []
    lines = text.splitlines()
    while lines and not lines[-1].strip():
        lines.pop()
    for lineno, line in enumerate(lines, 1):
        line = line.strip()
        if not line:
            raise SequenceError(
                f"{path}:{lineno}: a blank line (line k is frame k's box, so it would shift every later box "
                "one frame early); write NaN,NaN,NaN,NaN there for a frame without a box, or delete the line"
            )
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


def _read_box_text(path: Path) -> str:
    """The text of a box file (a UTF-8 byte-order mark dropped); :class:`SequenceError` if it is not a readable file."""
    try:
        return path.read_text(encoding="utf-8-sig", errors="replace")
    except IsADirectoryError:
        raise SequenceError(f"{path}: is a folder, not a box file; put the boxes in a file of that name") from None
    except FileNotFoundError:
        if path.is_symlink():
            raise SequenceError(
                f"{path}: a symbolic link to {os.readlink(path)}, which does not exist; fix or replace the link"
            ) from None
        raise SequenceError(f"{path}: no such file") from None
    except OSError as exc:
        raise SequenceError(f"cannot read {path}: {exc.strerror or exc}") from None


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
    """RGB pixels of an image file; :class:`SequenceError` naming the file if it cannot be read whole."""
    try:
        # read() releases the GIL while it waits for the disk (np.fromfile holds it), and the
        # JPEG check reads these bytes without a copy: the prefetch thread costs the tracker less.
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise SequenceError(f"cannot read image {path}: the file is missing") from None
    except OSError as exc:
        raise SequenceError(f"cannot read image {path}: {exc.strerror or exc}") from None
    if data[:2] == b"\xff\xd8" and not _jpeg_complete(data):
        # libjpeg would decode it with grey bottom rows and only warn "Premature end of JPEG file".
        raise SequenceError(f"cannot read image {path}: the JPEG file is truncated ({len(data)} bytes)")
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR) if data else None
    if img is None:
        raise SequenceError(f"cannot read image {path}: the file is empty or not an image")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def _jpeg_complete(data: bytes) -> bool:
    """Whether a JPEG file holds its end-of-image marker after its first scan.

    Walks the marker segments up to the first start-of-scan (skipping an EXIF
    thumbnail, which has its own end marker), then looks for FFD9 after it:
    inside entropy-coded data a 0xFF byte is always followed by 0x00 or a
    restart marker, so FFD9 there can only be the end. Trailing bytes after the
    end (some cameras append data) are fine.
    """
    pos, n = 2, len(data)
    while pos + 4 <= n:
        if data[pos] != 0xFF:
            return True  # not a layout we understand: leave it to the decoder
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker == 0xD9:
            return True
        if marker == 0xDA:  # start of scan: the end marker must come after it
            return data.find(b"\xff\xd9", pos + 2) >= 0
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            pos += 2
            continue
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
    return False


#: A frame file name ending in its number: "0001.jpg", "frame_12.png".
_NUMBERED = re.compile(r"^(.*?)(\d+)$")


def _natural_key(p: Path):
    """Name order with numbers compared as numbers: 2.png before 10.png."""
    return [(0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", p.name) if t]


def _list_images(folder: Path) -> list[Path]:
    """The image files of a frame folder in natural name order; hidden files (macOS ``._0001.jpg``) are not frames."""
    files = [p for p in folder.iterdir()
             if not p.name.startswith(".") and p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]
    return sorted(files, key=_natural_key)


def _number_frames(files: list[Path], by: str = "number") -> tuple[list[Path], list[int]]:
    """Frames by number: one path per number from the first to the last, and the 0-based positions of the gaps.

    OTB and VOT frames are numbered (img/0001.jpg …) and ground-truth row k
    belongs to frame number k (number 0 is frame 1 when a file is numbered 0),
    so a file missing anywhere must not shift every later frame onto the row
    before its own. The gaps are returned as the paths their files would have
    (the run is refused before it reaches one, :meth:`Sequence.check_frames`).
    A file without a number, two files of one number, or a file named unlike
    the others is refused here. ``by="order"`` takes the files as they are, in
    natural name order.

    Raises
    ------
    SequenceError
        Naming the file that breaks the numbering and the two ways out.
    """
    if by == "order" or not files:
        return list(files), []
    out_of_order = "; or --frames-by order to match the image files to the ground-truth rows in name order"
    parts = {}
    for p in files:
        m = _NUMBERED.match(p.stem)
        if m is None:
            raise SequenceError(f"{p}: an image without a frame number among the numbered frames; move it out "
                                f"of {p.parent}{out_of_order}")
        parts[p] = (m.group(1), int(m.group(2)), len(m.group(2)))
    prefixes: dict[str, list[Path]] = {}
    for p, (prefix, _, _) in parts.items():
        prefixes.setdefault(prefix, []).append(p)
    if len(prefixes) > 1:
        common = max(prefixes.values(), key=len)
        odd = next(v for v in prefixes.values() if v is not common)
        raise SequenceError(f"{odd[0]}: named unlike the other frames (such as {common[0].name}); move it out of "
                            f"{odd[0].parent}{out_of_order}")
    by_number: dict[int, Path] = {}
    for p, (_, k, _) in parts.items():
        if k in by_number:
            raise SequenceError(f"{by_number[k]} and {p.name}: two files for frame number {k}; keep one"
                                f"{out_of_order}")
        by_number[k] = p
    first = 0 if 0 in by_number else 1
    last = max(by_number)
    widths = {w for (_, _, w) in parts.values()}
    width = widths.pop() if len(widths) == 1 else 0
    prefix, suffix, folder = next(iter(parts.values()))[0], files[0].suffix, files[0].parent
    out, missing = [], []
    for k in range(first, last + 1):
        if k not in by_number:
            missing.append(k - first)
        out.append(by_number.get(k, folder / f"{prefix}{k:0{width}d}{suffix}"))
    return out, missing


class _ImageFilesSequence(Sequence):
    def __init__(self, name: str, files: list[Path], groundtruth: np.ndarray, frame_rate=None,
                 gt_path: Path | None = None, frames_by: str = "number"):
        if not files:
            raise SequenceError(f"{name}: no frames found (expected image files such as 0001.jpg)")
        if frames_by not in FRAMES_BY:
            raise SequenceError(f"frames by {frames_by!r}: expected one of {', '.join(FRAMES_BY)}")
        self.name = name
        self.frames_by = frames_by
        #: One path per frame number; the files of the numbers in ``missing`` do not exist.
        self.files, self.missing = _number_frames(files, frames_by)
        self.frame_rate = frame_rate
        n = len(self.files)
        if len(groundtruth) > n:
            where = gt_path or "the ground truth"
            if frames_by == "number":
                raise SequenceError(
                    f"{where}: {len(groundtruth)} rows for {n} frames ({self.files[0].name} … "
                    f"{self.files[-1].name}): frames after {self.files[-1].name} are missing or the file has "
                    "extra rows; restore the frames, delete the extra rows, or --frames-by order to drop them"
                )
            log.warning("%s: %d rows for %d frames; the last %d rows are not used (--frames-by order)",
                        where, len(groundtruth), n, len(groundtruth) - n)
        gt = np.full((n, 4), np.nan)
        m = min(n, len(groundtruth))
        gt[:m] = groundtruth[:m]
        self.groundtruth = gt
        #: Rows in the ground-truth file; frames after them are tracked but not scored.
        self.n_gt_lines = len(groundtruth)
        self._shape: tuple[tuple, Path] | None = None

    def check_frames(self, n_frames: int) -> None:
        """Refuse a run over a gap in the numbered frames, naming the first missing file.

        Tracking across a gap would score every later frame against the wrong
        row, and the OTB results format has no way to skip a frame.
        """
        missing = [i for i in self.missing if i < n_frames]
        if not missing:
            return
        first = self.files[missing[0]]
        more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
        before = (f"track the {missing[0]} frames before it with --max-frames {missing[0]}" if missing[0]
                  else "if the ground truth's first row is for the first file there, --frames-by order")
        raise SequenceError(
            f"{first}: frame missing{more} (frames are matched to the ground truth by number); restore it, "
            f"or {before}"
        )

    def _read(self, i: int) -> np.ndarray:
        return _same_size(self, _read_image(self.files[i]), self.files[i])


def _same_size(seq, img: np.ndarray, path: Path) -> np.ndarray:
    """``img``, or :class:`SequenceError` if its size differs from the sequence's first frame read."""
    if seq._shape is None:
        seq._shape = (img.shape, path)
    elif img.shape != seq._shape[0]:
        (h, w), (h0, w0) = img.shape[:2], seq._shape[0][:2]
        raise SequenceError(
            f"{path}: the frame is {w}x{h} but the sequence's frames are {w0}x{h0} ({seq._shape[1].name}); "
            "every frame of a sequence must have the same size"
        )
    return img


class OTBSequence(_ImageFilesSequence):
    """An OTB folder: ``img/*.jpg`` and ``groundtruth_rect.txt`` (1-based)."""

    def __init__(self, folder: str | Path, groundtruth: str | None = None, frames_by: str = "number"):
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
        super().__init__(_folder_name(folder), _list_images(img), read_boxes(gt_path, one_based=True),
                         gt_path=gt_path, frames_by=frames_by)


class VOTSequence(_ImageFilesSequence):
    """A VOT folder: frames in ``color/`` (or the folder) and ``groundtruth.txt``.

    VOT regions are rectangles or polygons in 0-based pixel coordinates; a
    polygon becomes its axis-aligned bounding box.
    """

    def __init__(self, folder: str | Path, frames_by: str = "number"):
        folder = Path(folder)
        if not folder.is_dir():
            raise SequenceError(f"{folder}: no such folder")
        gt_path = folder / "groundtruth.txt"
        if not gt_path.is_file():
            raise SequenceError(f"{folder}: no groundtruth.txt (VOT layout)")
        frames_dir = folder / "color" if (folder / "color").is_dir() else folder
        super().__init__(_folder_name(folder), _list_images(frames_dir), read_boxes(gt_path, one_based=False),
                         gt_path=gt_path, frames_by=frames_by)


def _folder_name(folder: Path) -> str:
    """A sequence folder's name, also when given as ``.`` or ``..`` (the name of the folder it is)."""
    name = folder.name if folder.name not in ("", ".", "..") else folder.resolve().name
    return name or "sequence"


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
        # The name is what comes before the first "*" (frames/img_*.png: "img_"), not counting the
        # folders that exist as written (a folder may be called a*b).
        head = _existing_head(source) if is_glob(source) else None
        skip = len(str(head)) if head is not None else 0
        prefix = source[:skip] + source[skip:].split("*")[0]
        self.name = Path(prefix).stem or Path(source).parent.name or "video"
        self._cap = None
        self._shape = None
        if is_glob(source):
            files = [Path(p) for p in _glob.glob(_escape_existing(source))
                     if Path(p).suffix.lower() in IMAGE_EXTENSIONS]
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
            return _same_size(self, _read_image(self.files[i]), self.files[i])
        if self._cap is None or i != self._next:
            if self._cap is not None:
                self._cap.release()
            self._cap = cv2.VideoCapture(str(self._path))
            self._cap.set(cv2.CAP_PROP_POS_FRAMES, i)
        ok, img = self._cap.read()
        if not ok:
            before = f"; track the {i} frames before it with --max-frames {i}" if i >= 2 else ""
            raise SequenceError(f"{self._path}: cannot decode frame {i + 1} (frames count from 1; the video may "
                                f"be truncated){before}")
        self._next = i + 1
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# --------------------------------------------------------------------------- #
# dispatch
# --------------------------------------------------------------------------- #
def is_glob(source: str) -> bool:
    """Whether ``source`` is an image glob: it has ``*``, ``?`` or ``[`` and is not an existing path.

    A folder named ``br[1]`` or ``q?x`` is a folder.
    """
    return any(c in source for c in "*?[") and not Path(source).exists()


def _existing_head(pattern: str) -> Path | None:
    """The longest folder at the start of a glob pattern that exists as it is written."""
    p = Path(pattern)
    for k in range(len(p.parts) - 1, 0, -1):
        head = Path(*p.parts[:k])
        if head.is_dir():
            return head
    return None


def _escape_existing(pattern: str) -> str:
    """``pattern`` with its longest existing folder prefix escaped: ``br[1]/*.png`` globs inside ``br[1]``."""
    head = _existing_head(pattern)
    if head is None:
        return pattern
    return str(Path(_glob.escape(str(head)), *Path(pattern).parts[len(head.parts):]))


def open_sequence(source: str | Path | None = None, box=None, frames_by: str = "number") -> Sequence:
    """Open a sequence from a path, guessing its layout.

    Parameters
    ----------
    source : str or Path, optional
        ``None`` or ``"synthetic"``: the embedded synthetic default;
        ``"synthetic:NAME"``: one of its failure scenarios
        (:data:`covviz.data.scenarios.SCENARIOS`). A folder
        with ``img/``: OTB. A folder with ``groundtruth.txt``: VOT. A video file
        or an image glob: needs ``box``.
    box : array-like, shape (4,), optional
        Initial box (0-based pixels) for videos and globs; for OTB/VOT folders
        it overrides the first ground-truth box.
    frames_by : {"number", "order"}
        How an OTB/VOT folder's frames are matched to its ground-truth rows
        (:data:`FRAMES_BY`).

    Raises
    ------
    SequenceError
        With a one-line message saying what is wrong.
    """
    try:
        seq = _open(source, box, frames_by)
    except OSError as exc:  # a name too long for the file system, a folder we may not read …
        raise SequenceError(f"cannot open {_short(source)}: {exc.strerror or exc}") from None
    if isinstance(seq, VideoSequence):
        return seq
    if box is not None:
        b = np.asarray(box, dtype=np.float64).reshape(-1)
        if b.shape != (4,):
            raise SequenceError(f"--box must be 4 numbers x,y,w,h; got {box!r}")
        seq.groundtruth = seq.groundtruth.copy()
        seq.groundtruth[0] = b
    return seq


def _short(path, keep: int = 80) -> str:
    """A path for a one-line message: a very long one is cut in the middle."""
    s = str(path)
    return s if len(s) <= keep else f"{s[: keep // 2]}…{s[-keep // 2:]} ({len(s)} characters)"


def _open(source, box, frames_by: str) -> Sequence:
    """:func:`open_sequence` before its ``box`` is applied to a folder's first row."""
    if source is None or str(source) == "synthetic":
        seq: Sequence = SyntheticSequence()
    elif str(source).startswith("synthetic:"):
        from covviz.data.scenarios import open_scenario

        seq = open_scenario(str(source).partition(":")[2])
    else:
        s = str(source)
        p = Path(s)
        if is_glob(s):
            if box is None:
                raise SequenceError(f"{s}: an image glob needs --box x,y,w,h")
            return VideoSequence(s, box)
        if p.is_dir():
            if (p / "img").is_dir():
                seq = OTBSequence(p, frames_by=frames_by)
            elif (p / "groundtruth.txt").is_file():
                seq = VOTSequence(p, frames_by=frames_by)
            else:
                raise SequenceError(
                    f"{p}: not a sequence folder (expected img/ + groundtruth_rect.txt, "
                    "or groundtruth.txt with frames)"
                )
        elif p.is_file():
            if p.suffix.lower() in IMAGE_EXTENSIONS:
                raise SequenceError(
                    f"{p}: one image, not a sequence; for a folder of frames give a quoted glob such as "
                    f"'{p.parent / ('*' + p.suffix)}' with --box x,y,w,h"
                )
            if p.suffix.lower() not in VIDEO_EXTENSIONS:
                raise SequenceError(f"{p}: not a video file ({', '.join(VIDEO_EXTENSIONS)}) or sequence folder")
            if box is None:
                raise SequenceError(f"{p}: a video needs --box x,y,w,h")
            return VideoSequence(p, box)
        else:
            raise SequenceError(f"{s}: no such file or folder")
    return seq
