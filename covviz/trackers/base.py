"""The tracker protocol shared by every tracker in covviz.

A tracker is initialised on the first frame with a box and then asked for a box
on every later frame. After ``init`` and after each ``update`` its
``last_record`` holds the :class:`~covviz.records.FrameRecord` of that frame,
which the runner hands to observers. ``snapshot()`` returns an immutable,
picklable state between two frames and ``restore(state)`` puts it back (the
counterfactual replays fork trackers through them); a tracker that cannot
(OpenCV's) raises :class:`SnapshotUnsupported`.

Frames are ``uint8`` arrays of shape ``(H, W, 3)`` (RGB) or ``(H, W)`` (gray);
boxes are ``x, y, w, h`` in 0-based pixels (see :mod:`covviz.records`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from covviz.model.image import check_init_box
from covviz.records import FrameRecord

__all__ = ["IdentityTracker", "Intervention", "SnapshotUnsupported", "Snapshottable", "Tracker", "TrackerInfo", "tracker_info"]


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


@runtime_checkable
class Snapshottable(Protocol):
    """A tracker whose state can be saved and restored (set ``snapshots = True`` to say so)."""

    def snapshot(self) -> Any:
        """An immutable, picklable state between two frames (raise :class:`SnapshotUnsupported` if impossible)."""

    def restore(self, state: Any) -> None:
        """Put a :meth:`snapshot` back: the next ``update()`` continues from it, bit for bit."""


class Intervention:
    """An experiment's hand inside ``update()`` (the counterfactual replays); trackers run without one.

    A tracker with an ``intervention`` asks it, on each frame (0-based ``index``), after
    propagating its particles and before observing:

    * :meth:`to_truth` — which particles to move to the truth's pose (the *search* fix);
    * :meth:`appearance` — a box whose look the appearance model should take this frame, every
      particle's template and the online parts of the likelihood included (the *model* fix);
    * and, once the particles are weighed, :meth:`estimate` — which candidate to report instead of
      the estimator's choice, before anything uses it (the *estimate* fix).

    Each returns None for "no change". The tracker's own random stream is used exactly as
    without the intervention; an intervention that draws takes its own generator.
    """

    def to_truth(self, index: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``(indices, box, velocity)``: particles to put at ``box`` (x, y, w, h) moving at ``velocity`` (2,)."""
        return None

    def appearance(self, index: int) -> np.ndarray | None:
        """A box (x, y, w, h) whose observation this frame the appearance model should take."""
        return None

    def estimate(self, index: int, boxes: np.ndarray) -> int | None:
        """The row of ``boxes`` (the candidates, ``(m, 4)``) to report as the estimate."""
        return None


#: The estimate fix (:meth:`Intervention.estimate`) chooses among the particles that hold this share of the weight.
ESTIMATE_MASS = 0.9


class SnapshotUnsupported(RuntimeError):
    """This tracker's state cannot be saved and restored (OpenCV's trackers keep theirs in C++)."""


@dataclass(frozen=True, slots=True)
class TrackerInfo:
    """What observers are told about a tracker once, when the run starts (after ``init``).

    Attributes
    ----------
    name : str
    config : dict
        Its configuration, JSON-ready (written next to the results).
    model : ObservationModel or None
        The frozen observation model of a covariance tracker (None for the others):
        what observers use to score other poses without calling the tracker.
    snapshots : bool
        Whether ``snapshot()``/``restore()`` work (the counterfactual replays need them).
    particles : bool
        Whether it is a particle filter (its records carry weights).
    interventions : bool
        Whether it takes an :class:`Intervention` (an ``intervention`` attribute read by ``update()``):
        the counterfactual replays fix its search, model or estimate.
    """

    name: str
    config: dict
    model: Any = None
    snapshots: bool = False
    particles: bool = False
    interventions: bool = False


def tracker_info(tracker) -> TrackerInfo:
    """The :class:`TrackerInfo` of an initialised tracker (covviz's, or any object with ``init``/``update``)."""
    config = tracker.config_dict() if callable(getattr(tracker, "config_dict", None)) else {}
    return TrackerInfo(
        name=str(getattr(tracker, "name", type(tracker).__name__)),
        config=config,
        model=getattr(tracker, "observation_model", None),
        snapshots=bool(getattr(tracker, "snapshots", False)),
        particles=bool(getattr(tracker, "particle_filter", False)),
        interventions=hasattr(tracker, "intervention"),
    )




class IdentityTracker:
    """Returns the initial box on every frame: exercises the harness in tests."""

    name = "identity"
    snapshots = True
    observation_model = None
    intervention = None  # nothing to fix: it never moves

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

    def snapshot(self) -> tuple:
        if self._box is None:
            raise RuntimeError("call init(frame, box) before snapshot()")
        return (self._box.copy(), self._index)

    def restore(self, state: tuple) -> None:
        box, index = state
        self._box, self._index = np.array(box, dtype=np.float64), int(index)
        self.last_record = None


def make_identity(n_particles=None, rng=None) -> IdentityTracker:
    """Factory for the tracker registry."""
    return IdentityTracker()
