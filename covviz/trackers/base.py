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

import numpy as np

from covviz.model.image import check_init_box
from covviz.records import FrameRecord

__all__ = ["IdentityTracker", "Tracker"]


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
