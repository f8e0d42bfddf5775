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
* :class:`SyntheticSequence` — the embedded default: a deterministic textured
  target on a cluttered background, with translation, scale and rotation, a
  stretch of fast pose change, an illumination change and a partial occlusion.

Boxes are returned in 0-based pixels (see :mod:`covviz.records`); rows of
ground truth that are missing or invalid are ``nan``.
"""

from __future__ import annotations

import glob as _glob
import math
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from covviz.errors import InputError

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


class SequenceError(InputError):
    """A sequence cannot be read; the message says what to fix."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame of a sequence.

    Attributes
    ----------
    index : int
        0-based position in the sequence.
    image : ndarray, shape (H, W, 3), uint8
        RGB pixels.
    gt : ndarray, shape (4,), optional
        Ground-truth box ``x, y, w, h`` (0-based pixels), or None if unknown.
    time : float, optional
        Seconds since the first frame, when the sequence has a frame rate.
    """

    index: int
    image: np.ndarray
    gt: np.ndarray | None = None
    time: float | None = None


class Sequence:
    """Base class: a named, indexable, lazily read list of frames.

    Subclasses set ``name``, ``groundtruth`` (``(n, 4)``, ``nan`` rows where
    unknown), ``frame_rate`` (or None) and implement :meth:`_read`.
    """

    name: str = "sequence"
    frame_rate: float | None = None
    groundtruth: np.ndarray

    def __len__(self) -> int:
        return len(self.groundtruth)

    def _read(self, i: int) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def init_box(self) -> np.ndarray:
        """The box to initialise a tracker with (ground truth of frame 0)."""
        b = self.groundtruth[0]
        if not np.all(np.isfinite(b)):
            raise SequenceError(f"{self.name}: the first frame has no ground-truth box; pass --box x,y,w,h")
        return b.copy()

    def frame(self, i: int) -> Frame:
        """Read frame ``i`` (0-based)."""
        if not 0 <= i < len(self):
            raise IndexError(f"frame {i} out of range for {self.name} ({len(self)} frames)")
        gt = self.groundtruth[i]
        return Frame(
            index=i,
            image=self._read(i),
            gt=gt.copy() if np.all(np.isfinite(gt)) else None,
            time=None if not self.frame_rate else i / self.frame_rate,
        )

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self.frame(i)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {len(self)} frames)"


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
    """RGB pixels of an image file; :class:`SequenceError` naming the file if it cannot be read whole."""
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except FileNotFoundError:
        raise SequenceError(f"cannot read image {path}: the file is missing") from None
    except OSError as exc:
        raise SequenceError(f"cannot read image {path}: {exc.strerror or exc}") from None
    if data[:2].tobytes() == b"\xff\xd8" and not _jpeg_complete(data.tobytes()):
        # libjpeg would decode it with grey bottom rows and only warn "Premature end of JPEG file".
        raise SequenceError(f"cannot read image {path}: the JPEG file is truncated ({data.size} bytes)")
    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
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


def _list_images(folder: Path) -> list[Path]:
    files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS and p.is_file()]
    return sorted(files, key=lambda p: (len(p.stem), p.stem))


def _number_frames(files: list[Path]) -> tuple[list[Path], list[int]]:
    """Frames by number: the files with the missing numbers put back (as the paths they would have).

    OTB and VOT frames are numbered (img/0001.jpg …) and ground-truth row k
    belongs to the k-th number from the first; a file missing in the middle
    must not shift every later frame onto the row before its own. Returns the
    files, one per number from the first to the last, and the 0-based
    positions of the missing ones. Files not all numbered alike (one prefix,
    one extension, distinct numbers) are left as they are.
    """
    if len(files) < 2:
        return files, []
    parts = [_NUMBERED.match(p.stem) for p in files]
    if not all(parts):
        return files, []
    numbers = [int(m.group(2)) for m in parts]
    if (len({m.group(1) for m in parts}) != 1 or len({p.suffix for p in files}) != 1
            or len(set(numbers)) != len(numbers)):
        return files, []
    first, last = min(numbers), max(numbers)
    if last - first + 1 == len(files):
        return sorted(files, key=lambda p: int(_NUMBERED.match(p.stem).group(2))), []
    by_number = dict(zip(numbers, files))
    widths = {len(m.group(2)) for m in parts}
    width = widths.pop() if len(widths) == 1 else 0
    prefix, suffix, folder = parts[0].group(1), files[0].suffix, files[0].parent
    out, missing = [], []
    for k in range(first, last + 1):
        if k not in by_number:
            missing.append(k - first)
        out.append(by_number.get(k, folder / f"{prefix}{k:0{width}d}{suffix}"))
    return out, missing


class _ImageFilesSequence(Sequence):
    def __init__(self, name: str, files: list[Path], groundtruth: np.ndarray, frame_rate=None):
        if not files:
            raise SequenceError(f"{name}: no frames found (expected image files such as 0001.jpg)")
        self.name = name
        #: One path per frame number; the files of the numbers in ``missing`` do not exist.
        self.files, self.missing = _number_frames(files)
        self.frame_rate = frame_rate
        n = len(self.files)
        gt = np.full((n, 4), np.nan)
        m = min(n, len(groundtruth))
        gt[:m] = groundtruth[:m]
        self.groundtruth = gt
        self.n_gt_lines = len(groundtruth)
        self._shape: tuple[tuple, Path] | None = None

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
            raise SequenceError(f"{self._path}: cannot decode frame {i}")
        self._next = i + 1
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


# --------------------------------------------------------------------------- #
# the embedded synthetic default
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class SyntheticConfig:
    """Parameters of the synthetic sequence (all defaults in one place).

    Frame indices of the events are 0-based; every event lies inside
    ``n_frames`` for the default length and is skipped if the sequence is shorter.
    """

    n_frames: int = 300
    width: int = 320
    height: int = 240
    target_w: int = 40
    target_h: int = 52
    seed: int = 7
    noise_std: float = 3.0  # sensor noise, grey levels
    fast_start: int = 110  # stretch of fast pose change
    fast_end: int = 135
    illum_start: int = 170  # illumination ramps down to illum_gain and back
    illum_end: int = 230
    illum_gain: float = 0.55
    occl_start: int = 245  # an occluder covers part of the target
    occl_end: int = 270
    occl_fraction: float = 0.35  # fraction of the target width it covers
    frame_rate: float = 30.0

    def __post_init__(self):
        if self.n_frames < 2:
            raise ValueError("a synthetic sequence needs at least 2 frames")
        if not (16 <= self.target_w < self.width / 2 and 16 <= self.target_h < self.height / 2):
            raise ValueError("target size must be at least 16 px and below half the frame")


class SyntheticSequence(Sequence):
    """Deterministic textured target on a cluttered background, with ground truth.

    The target follows a smooth path with a slow scale change and rotation
    (±20°); during ``fast_start..fast_end`` it moves and turns several times
    faster; during ``illum_*`` the whole frame dims to ``illum_gain``; during
    ``occl_*`` a grey bar covers part of the target. The same config gives the
    same frames, bit for bit. Ground truth is the unrotated box of the target's
    size at its centre (how OTB annotates), in 0-based pixels.
    """

    def __init__(self, config: SyntheticConfig | None = None):
        self.config = cfg = config or SyntheticConfig()
        self.name = "synthetic"
        self.frame_rate = cfg.frame_rate
        rng = np.random.default_rng(cfg.seed)
        self._background = _clutter(rng, cfg.height, cfg.width)
        self._texture = _target_texture(rng, cfg.target_h, cfg.target_w)
        self._poses = self._trajectory()
        cx, cy, s = self._poses[:, 0], self._poses[:, 1], self._poses[:, 2]
        w, h = cfg.target_w * s, cfg.target_h * s
        self.groundtruth = np.stack([cx - w / 2, cy - h / 2, w, h], axis=1)

    @property
    def poses(self) -> np.ndarray:
        """True ``cx, cy, scale, theta`` per frame, shape ``(n, 4)``."""
        return self._poses.copy()

    def _trajectory(self) -> np.ndarray:
        cfg = self.config
        t = np.arange(cfg.n_frames, dtype=np.float64)
        # "phase" runs faster inside the fast stretch: pose changes ~4x quicker there.
        speed = np.ones_like(t)
        speed[(t >= cfg.fast_start) & (t < cfg.fast_end)] = 4.0
        phase = np.concatenate([[0.0], np.cumsum(speed[:-1])])
        W, H = cfg.width, cfg.height
        mx, my = 0.30 * W, 0.28 * H
        cx = W / 2 + mx * np.sin(2 * np.pi * phase / 260.0)
        cy = H / 2 + my * np.sin(2 * np.pi * phase / 170.0 + 0.6)
        scale = 1.0 + 0.22 * np.sin(2 * np.pi * phase / 300.0)
        theta = np.deg2rad(20.0) * np.sin(2 * np.pi * phase / 140.0)
        return np.stack([cx, cy, scale, theta], axis=1)

    def _read(self, i: int) -> np.ndarray:
        cfg = self.config
        cx, cy, s, th = self._poses[i]
        img = self._background.copy()
        # Target: rotate+scale the texture about its centre onto the frame.
        th_, tw_ = self._texture.shape
        c, si = math.cos(th), math.sin(th)
        # maps texture coords (u, v) -> image: p = R(th) * s * ((u, v) - centre) + (cx, cy)
        A = np.array([[s * c, -s * si], [s * si, s * c]])
        centre = np.array([tw_ / 2.0, th_ / 2.0])
        t = np.array([cx, cy]) - A @ centre
        M = np.hstack([A, (t + A @ np.array([0.5, 0.5]) - 0.5)[:, None]])
        tex = cv2.warpAffine(self._texture, M, (cfg.width, cfg.height), flags=cv2.INTER_LINEAR)
        mask = cv2.warpAffine(np.ones_like(self._texture), M, (cfg.width, cfg.height), flags=cv2.INTER_LINEAR)
        img = img * (1 - mask) + tex * mask
        # Partial occlusion: a vertical grey bar over the target's left part.
        if cfg.occl_start <= i < cfg.occl_end:
            bw = cfg.occl_fraction * cfg.target_w * s
            x0 = cx - cfg.target_w * s / 2 - 2
            y0, y1 = cy - 0.8 * cfg.target_h * s, cy + 0.8 * cfg.target_h * s
            img[max(0, int(y0)) : max(0, int(y1)), max(0, int(x0)) : max(0, int(x0 + bw + 2))] = 120.0
        # Illumination: a smooth dip of the global gain.
        if cfg.illum_start <= i < cfg.illum_end:
            u = (i - cfg.illum_start) / (cfg.illum_end - cfg.illum_start)
            img = img * (1.0 - (1.0 - cfg.illum_gain) * math.sin(math.pi * u))
        noise = np.random.default_rng([cfg.seed, i]).normal(0.0, cfg.noise_std, img.shape)
        gray = np.clip(img + noise, 0, 255).astype(np.uint8)
        # Mild colour tint so the frames are RGB like real ones.
        return np.stack([gray, gray, np.clip(gray.astype(np.int16) - 8, 0, 255).astype(np.uint8)], axis=2)


def _clutter(rng: np.random.Generator, H: int, W: int) -> np.ndarray:
    """Cluttered background: smooth shading plus random rectangles, ellipses and lines."""
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    img = 90 + 40 * np.sin(xx / W * 3.1 + 0.4) * np.cos(yy / H * 2.3)
    for _ in range(70):
        kind = rng.integers(3)
        val = float(rng.uniform(20, 235))
        x, y = int(rng.integers(0, W)), int(rng.integers(0, H))
        if kind == 0:
            w, h = int(rng.integers(6, 50)), int(rng.integers(6, 50))
            cv2.rectangle(img, (x, y), (x + w, y + h), val, -1)
        elif kind == 1:
            ax = (int(rng.integers(4, 30)), int(rng.integers(4, 30)))
            cv2.ellipse(img, (x, y), ax, float(rng.uniform(0, 180)), 0, 360, val, -1)
        else:
            x2, y2 = int(rng.integers(0, W)), int(rng.integers(0, H))
            cv2.line(img, (x, y), (x2, y2), val, int(rng.integers(1, 4)))
    return cv2.GaussianBlur(img.astype(np.float32), (3, 3), 0.8)


def _target_texture(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """A face-like textured target: bright oval, dark blobs, fine stripes."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = (xx + 0.5) / w - 0.5, (yy + 0.5) / h - 0.5
    tex = 200 - 120 * (u**2 + v**2)  # bright, vignetted
    for _ in range(5):
        bx, by = rng.uniform(-0.35, 0.35), rng.uniform(-0.35, 0.35)
        r = rng.uniform(0.06, 0.14)
        tex -= rng.uniform(60, 140) * np.exp(-((u - bx) ** 2 + (v - by) ** 2) / (2 * r * r))
    tex += 25 * np.sin(2 * np.pi * (3.0 * u + 2.0 * v) * 2)
    tex[:, :2] = tex[:, -2:] = 40  # dark rim gives the target strong edges
    tex[:2, :] = tex[-2:, :] = 40
    return np.clip(tex, 0, 255).astype(np.float32)


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


def open_sequence(source: str | Path | None = None, box=None) -> Sequence:
    """Open a sequence from a path, guessing its layout.

    Parameters
    ----------
    source : str or Path, optional
        ``None`` or ``"synthetic"``: the embedded synthetic default. A folder
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
    else:
        s = str(source)
        p = Path(s)
        if is_glob(s):
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
    if box is not None:
        b = np.asarray(box, dtype=np.float64).reshape(-1)
        if b.shape != (4,):
            raise SequenceError(f"--box must be 4 numbers x,y,w,h; got {box!r}")
        seq.groundtruth = seq.groundtruth.copy()
        seq.groundtruth[0] = b
    return seq
