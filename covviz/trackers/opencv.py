"""OpenCV's own trackers behind the covviz protocol: the peers of the benchmark.

CSRT, KCF, MIL, MOSSE, MedianFlow and TLD from ``opencv-contrib``. Each is
wrapped by :class:`OpenCVTracker`, which converts frames (RGB → BGR) and boxes
(float ``x, y, w, h`` ↔ what OpenCV's bindings accept), and handles failures:

* When OpenCV reports a failed update (``ok == False``, an empty or non-finite
  box, or a ``cv2.error`` inside ``update``), the tracker **keeps its last box**
  and marks the frame ``FrameRecord.extras["failed"] = True``. OpenCV returns a
  zero box on failure, which would otherwise count as a wild miss on every
  frame the tracker is lost and unfairly ruin its scores. Failures are counted
  in :attr:`OpenCVTracker.n_failures`.
* A tracker missing from the installed OpenCV build raises
  :class:`OpenCVUnavailableError` naming the tracker and the constructors tried.

Reproducibility: CSRT, KCF, MOSSE and MedianFlow are deterministic. MIL and TLD
draw from OpenCV's internal random state, which a run does not reset and which
carries over to the next run *in the same process*; in a fresh process they are
deterministic (whatever ``cv2.setNumThreads``). ``covviz bench`` therefore runs
every job in its own process; a second MIL run inside one Python session may
differ from the first.

In OpenCV 5.0, CSRT, KCF and MIL live in the main API (``cv2.TrackerCSRT.create``,
integer boxes); MOSSE, MedianFlow and TLD only in ``cv2.legacy`` (float boxes).

References
----------
.. [1] A. Lukežič et al., "Discriminative correlation filter with channel and
   spatial reliability", CVPR 2017 (CSRT).
.. [2] J. F. Henriques et al., "High-speed tracking with kernelized correlation
   filters", TPAMI 2015 (KCF).
.. [3] B. Babenko, M.-H. Yang, S. Belongie, "Robust object tracking with online
   multiple instance learning", TPAMI 2011 (MIL).
.. [4] D. S. Bolme et al., "Visual object tracking using adaptive correlation
   filters", CVPR 2010 (MOSSE).
.. [5] Z. Kalal, K. Mikolajczyk, J. Matas, "Forward-backward error: automatic
   detection of tracking failures", ICPR 2010 (MedianFlow); "Tracking-learning-
   detection", TPAMI 2012 (TLD).
"""

from __future__ import annotations

import logging
import time

import cv2
import numpy as np

from covviz.model.image import check_init_box
from covviz.records import FrameRecord
from covviz.trackers.base import SnapshotUnsupported

__all__ = [
    "CONSTRUCTORS",
    "OpenCVTracker",
    "OpenCVUnavailableError",
    "make_csrt",
    "make_kcf",
    "make_medianflow",
    "make_mil",
    "make_mosse",
    "make_tld",
]

log = logging.getLogger(__name__)

#: tracker name -> constructors (attribute paths under ``cv2``), tried in order.
#: Paths under ``legacy.`` take float boxes; the main API takes integer boxes.
CONSTRUCTORS: dict[str, tuple[str, ...]] = {
    "csrt": ("TrackerCSRT.create", "legacy.TrackerCSRT_create"),
    "kcf": ("TrackerKCF.create", "legacy.TrackerKCF_create"),
    "mil": ("TrackerMIL.create", "legacy.TrackerMIL_create"),
    "mosse": ("legacy.TrackerMOSSE_create",),
    "medianflow": ("legacy.TrackerMedianFlow_create",),
    "tld": ("legacy.TrackerTLD_create",),
}


class OpenCVUnavailableError(ValueError):
    """The installed OpenCV build has no constructor for the requested tracker."""


def _resolve(name: str):
    """Return ``(constructor, path)`` for tracker ``name`` or raise :class:`OpenCVUnavailableError`."""
    if name not in CONSTRUCTORS:
        raise ValueError(f"no OpenCV tracker called {name!r}; choose from {', '.join(CONSTRUCTORS)}")
    for path in CONSTRUCTORS[name]:
        obj = cv2
        for part in path.split("."):
            obj = getattr(obj, part, None)
            if obj is None:
                break
        if obj is not None:
            return obj, path
    tried = ", ".join(f"cv2.{p}" for p in CONSTRUCTORS[name])
    raise OpenCVUnavailableError(
        f"tracker {name!r} is not available in this OpenCV build ({cv2.__version__}): "
        f"none of {tried} exists; "
        "install opencv-contrib-python-headless (not opencv-python-headless)"
    )


def _to_bgr(frame: np.ndarray) -> np.ndarray:
    """RGB ``(H, W, 3)`` or gray ``(H, W)`` uint8 → contiguous BGR ``(H, W, 3)`` uint8."""
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise ValueError(f"OpenCV trackers need uint8 frames, got {frame.dtype}")
    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)
    raise ValueError(f"a frame must have shape (H, W) or (H, W, 3), got {frame.shape}")


def _opencv_box(box: np.ndarray, frame_shape, integer: bool) -> tuple:
    """The part of ``box`` inside the frame, as the tuple OpenCV's ``init`` accepts.

    Integer boxes keep the edges nearest to the float ones (``round(x)`` and
    ``round(x + w)``); every box is at least 1 pixel wide and high.
    """
    H, W = frame_shape[:2]
    x, y, w, h = box
    x0, y0 = max(0.0, x), max(0.0, y)
    x1, y1 = min(float(W), x + w), min(float(H), y + h)
    if integer:
        ix0, iy0 = round(x0), round(y0)
        ix1, iy1 = round(x1), round(y1)
        ix0, iy0 = min(ix0, W - 1), min(iy0, H - 1)
        return (ix0, iy0, max(1, ix1 - ix0), max(1, iy1 - iy0))
    return (float(x0), float(y0), float(max(1.0, x1 - x0)), float(max(1.0, y1 - y0)))


class OpenCVTracker:
    """One of OpenCV's trackers behind the covviz protocol.

    Parameters
    ----------
    name : {"csrt", "kcf", "mil", "mosse", "medianflow", "tld"}
        Which tracker (see :data:`CONSTRUCTORS`).

    Attributes
    ----------
    n_failures : int
        Frames since ``init`` on which OpenCV reported a failure (the last box
        was kept).

    Raises
    ------
    OpenCVUnavailableError
        If the installed OpenCV build lacks this tracker.

    Notes
    -----
    OpenCV's trackers are deterministic: there is no ``rng``. A box partly
    outside the first frame is clipped to the frame for OpenCV (the target is
    what is visible); the box returned for frame 0 is the given one.

    Examples
    --------
    >>> from covviz.data.sequences import SyntheticSequence
    >>> seq = SyntheticSequence()
    >>> tr = OpenCVTracker("csrt")
    >>> tr.init(seq.frame(0).image, seq.init_box)
    >>> box = tr.update(seq.frame(1).image)
    """

    snapshots = False
    observation_model = None

    def snapshot(self):
        """OpenCV keeps its trackers' state in C++: raises :class:`~covviz.trackers.base.SnapshotUnsupported`."""
        raise SnapshotUnsupported(
            f"{self.name}: OpenCV's trackers cannot be saved and restored; replays restart it at the truth instead"
        )

    def restore(self, state) -> None:
        """See :meth:`snapshot`."""
        self.snapshot()

    def __init__(self, name: str) -> None:
        self._create, self.constructor = _resolve(name)
        self.name = name
        self.integer_boxes = not self.constructor.startswith("legacy.")
        self._tracker = None
        self._box: np.ndarray | None = None
        self._index = 0
        self.n_failures = 0
        self.last_record: FrameRecord | None = None

    def config_dict(self) -> dict:
        return {
            "opencv": cv2.__version__,
            "constructor": f"cv2.{self.constructor}",
            "integer_boxes": self.integer_boxes,
            "on_failure": "keep the last box",
        }

    def init(self, frame: np.ndarray, box) -> None:
        """Initialise OpenCV's tracker on ``box`` (x, y, w, h, 0-based px) of ``frame``."""
        t0 = time.perf_counter()
        b = check_init_box(box, np.shape(frame))
        bgr = _to_bgr(frame)
        self._tracker = self._create()
        try:
            ok = self._tracker.init(bgr, _opencv_box(b, bgr.shape, self.integer_boxes))
        except cv2.error as exc:
            raise ValueError(
                f"OpenCV {self.name} cannot start on the box {b.tolist()}: {_short(exc)}"
            ) from None
        if ok is False:  # the legacy API returns a bool, the main API None
            raise ValueError(f"OpenCV {self.name} refused to start on the box {b.tolist()}")
        self._box = b.copy()
        self._index = 0
        self.n_failures = 0
        self.last_record = FrameRecord(
            index=0,
            box=b.copy(),
            tracker=self.name,
            timings={"total": time.perf_counter() - t0},
            extras={"failed": False},
        )

    def update(self, frame: np.ndarray) -> np.ndarray:
        """Track into ``frame``; on a reported failure return the last box."""
        if self._tracker is None:
            raise RuntimeError("call init(frame, box) before update(frame)")
        t0 = time.perf_counter()
        self._index += 1
        error = None
        try:
            ok, rect = self._tracker.update(_to_bgr(frame))
        except cv2.error as exc:
            ok, rect, error = False, None, _short(exc)
        box = np.asarray(rect, dtype=np.float64).reshape(-1) if rect is not None else np.full(4, np.nan)
        failed = not (ok and box.shape == (4,) and np.all(np.isfinite(box)) and box[2] > 0 and box[3] > 0)
        extras: dict = {"failed": failed}
        if failed:
            self.n_failures += 1
            box = self._box.copy()
            if error is not None:
                extras["error"] = error
                log.debug("OpenCV %s raised on frame %d: %s", self.name, self._index, error)
        else:
            self._box = box.copy()
        self.last_record = FrameRecord(
            index=self._index,
            box=box.copy(),
            tracker=self.name,
            timings={"total": time.perf_counter() - t0},
            extras=extras,
        )
        return box

    def __repr__(self) -> str:
        return f"OpenCVTracker({self.name!r}, cv2.{self.constructor})"


def _short(exc: BaseException) -> str:
    """The first non-empty line of an OpenCV error."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    return lines[0] if lines else exc.__class__.__name__


# Factories for the tracker registry; (n_particles, rng) are accepted and ignored.
def make_csrt(n_particles=None, rng=None) -> OpenCVTracker:
    return OpenCVTracker("csrt")


def make_kcf(n_particles=None, rng=None) -> OpenCVTracker:
    return OpenCVTracker("kcf")


def make_mil(n_particles=None, rng=None) -> OpenCVTracker:
    return OpenCVTracker("mil")


def make_mosse(n_particles=None, rng=None) -> OpenCVTracker:
    return OpenCVTracker("mosse")


def make_medianflow(n_particles=None, rng=None) -> OpenCVTracker:
    return OpenCVTracker("medianflow")


def make_tld(n_particles=None, rng=None) -> OpenCVTracker:
    return OpenCVTracker("tld")
