"""The tracker protocol shared by every tracker in covviz.

A tracker is initialised on the first frame with a box and then asked for a box
on every later frame. After ``init`` and after each ``update`` its
``last_record`` holds the :class:`~covviz.records.FrameRecord` of that frame,
which the runner hands to observers.

Frames are ``uint8`` arrays of shape ``(H, W, 3)`` (RGB) or ``(H, W)`` (gray);
boxes are ``x, y, w, h`` in 0-based pixels (see :mod:`covviz.records`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import cv2
import numpy as np

from covviz.errors import InputError
from covviz.records import FrameRecord

__all__ = ["IdentityTracker", "Tracker", "check_init_box", "to_gray"]


@runtime_checkable
class Tracker(Protocol):
    """What the runner needs from a tracker."""

    name: str
    last_record: FrameRecord | None

    def init(self, frame: np.ndarray, box: np.ndarray) -> None:
        """Start tracking the region ``box`` (x, y, w, h) of ``frame``."""

    def update(self, frame: np.ndarray) -> np.ndarray:
        """Return the box (x, y, w, h) of the target in the next ``frame``."""

    def config_dict(self) -> dict:
        """The tracker's configuration, JSON-serialisable."""


def to_gray(frame: np.ndarray) -> np.ndarray:
    """``uint8`` RGB or gray frame -> float32 gray in ``[0, 1]``, shape ``(H, W)``."""
    frame = np.asarray(frame)
    if frame.ndim == 3:
        if frame.shape[2] != 3:
            raise ValueError(f"colour frames must have 3 channels, got shape {frame.shape}")
        # ITU-R BT.601 luma; cv2.cvtColor is ~3x faster than the same sum in numpy.
        g = cv2.cvtColor(frame.astype(np.float32), cv2.COLOR_RGB2GRAY)
    elif frame.ndim == 2:
        g = frame.astype(np.float32)
    else:
        raise ValueError(f"a frame must have shape (H, W) or (H, W, 3), got {frame.shape}")
    if frame.dtype == np.uint8:
        g *= np.float32(1.0 / 255.0)
    return g


def check_init_box(box, frame_shape) -> np.ndarray:
    """Validate an initial box against a frame; return it as float64 ``(4,)``.

    Raises
    ------
    covviz.errors.InputError
        (a ``ValueError``) If the box is not 4 finite numbers, has zero or
        negative size, lies entirely outside the frame or is more than
        :data:`MAX_BOX_FRAMES` times its size.
    """
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.shape != (4,) or not np.all(np.isfinite(b)):
        raise InputError(f"the initial box must be 4 finite numbers x,y,w,h; got {box!r}")
    x, y, w, h = b
    if w <= 0 or h <= 0:
        raise InputError(f"the initial box has zero or negative size (w={w:g}, h={h:g})")
    H, W = frame_shape[:2]
    if x >= W or y >= H or x + w <= 0 or y + h <= 0:
        raise InputError(
            f"the initial box {x:g},{y:g},{w:g},{h:g} lies outside the {W}x{H} frame"
        )
    if w > MAX_BOX_FRAMES * W or h > MAX_BOX_FRAMES * H:
        raise InputError(
            f"the initial box {x:g},{y:g},{w:g},{h:g} is more than {MAX_BOX_FRAMES:g} times the size of the "
            f"{W}x{H} frame; give the box around the target"
        )
    return b


#: An initial box may be at most this many times the frame's width and height (a target partly
#: outside the frame is fine; a box of 1e308 pixels overflows the warp).
MAX_BOX_FRAMES = 2.0


class IdentityTracker:
    """Returns the initial box on every frame: exercises the harness in tests."""

    name = "identity"

    def __init__(self, config=None, rng=None) -> None:
        self._box: np.ndarray | None = None
        self._index = 0
        self.last_record: FrameRecord | None = None

    def config_dict(self) -> dict:
        return {}

    def init(self, frame: np.ndarray, box: np.ndarray) -> None:
        self._box = check_init_box(box, np.shape(frame))
        self._index = 0
        self.last_record = FrameRecord(index=0, box=self._box.copy(), tracker=self.name)

    def update(self, frame: np.ndarray) -> np.ndarray:
        if self._box is None:
            raise RuntimeError("call init(frame, box) before update(frame)")
        self._index += 1
        self.last_record = FrameRecord(index=self._index, box=self._box.copy(), tracker=self.name)
        return self._box.copy()


def make_identity(n_particles=None, rng=None) -> IdentityTracker:
    """Factory for the tracker registry."""
    return IdentityTracker()
