"""Where and how a run's losses happen, from its boxes and the truth alone (no tracker, no recording).

Each loss is the event detector's (:func:`covviz.diagnosis.calibrate.losses_of`: the IoU below
``LOST_IOU`` after being on track), described by what the boxes say about it:

* ``found_again``: the first later frame whose IoU is at least ``found_iou`` (OTB's success threshold,
  0.5), or None: a brief excursion the filter recovers from by itself, or a target lost for good;
* ``size_ratio``: ``√(area of the box / area of the truth)`` at the loss — a box that grew onto its
  surroundings (Car1's slow growth) against one that slid off at the target's size;
* ``drift_frames`` (a property): the frames from the drift's start to the loss — 0 to 2 for a jump the
  particles did not follow (lost before anything label-free could react), more for a slow slide;
* ``centre_offset``: the distance between the box's and the truth's centres at the loss, in truth sizes
  (``√(w·h)``) — small for a box still on the spot (a target hidden behind an occluder, a box grown around
  it), large for one that followed something else.

:func:`recurring` groups the losses of many seeds of one sequence by where they happen: a loss on the
same frames on most seeds is the scene's, not chance's, and the place to look first.
"""

from __future__ import annotations

from bisect import bisect_left
from dataclasses import dataclass

import numpy as np

from covviz.metrics import iou

__all__ = ["FOUND_IOU", "JUMP_FRAMES", "Loss", "describe_losses", "recurring"]

#: A lost target counts as found again from the first later frame with at least this IoU (OTB's success threshold).
FOUND_IOU = 0.5
#: A loss at most this many frames after its drift began is a jump (:attr:`Loss.drift_frames`): the particles did
#: not follow the target, and no evidence read from a frame can act before the next one.
JUMP_FRAMES = 2


@dataclass(frozen=True)
class Loss:
    """One loss of a run (frames 1-based, as everywhere a user sees them)."""

    drift_began: int
    lost_at: int
    found_again: int | None
    size_ratio: float
    centre_offset: float

    @property
    def drift_frames(self) -> int:
        """Frames from the drift's start to the loss: 0 for a box that lost the target on the frame its IoU
        began to fall (a jump the search did not follow), more for a slide the label-free evidence could
        catch before the loss."""
        return self.lost_at - self.drift_began

    @property
    def frames_lost(self) -> int | None:
        """Frames from the loss until found again (None: never, within the run)."""
        return None if self.found_again is None else self.found_again - self.lost_at


def _centre(b: np.ndarray) -> np.ndarray:
    return b[:2] + b[2:] / 2


def describe_losses(boxes, groundtruth, found_iou: float = FOUND_IOU) -> list[Loss]:
    """Every loss of a run whose boxes are ``boxes`` (``(n, 4)``, ``x, y, w, h``) against ``groundtruth``.

    Frames where the truth is missing (non-finite, or not a positive size) have no IoU, as in the event
    detector, and are never the frame a target is found again on.

    Raises
    ------
    ValueError
        If the two are not ``(n, 4)`` arrays of the same length.
    """
    from covviz.diagnosis.calibrate import losses_of

    b = np.asarray(boxes, dtype=np.float64)
    g = np.asarray(groundtruth, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 4 or b.shape != g.shape:
        raise ValueError(f"boxes and groundtruth must both be (n, 4) arrays, got {b.shape} and {g.shape}")
    v = iou(b, g)
    out = []
    for began, lost in losses_of(v):
        i = lost - 1
        later = np.flatnonzero(np.nan_to_num(v[i + 1:], nan=-1.0) >= found_iou)
        size_b = np.sqrt(max(b[i, 2] * b[i, 3], 0.0))
        size_g = np.sqrt(g[i, 2] * g[i, 3])
        out.append(Loss(
            drift_began=int(began),
            lost_at=int(lost),
            found_again=None if not len(later) else int(lost + 1 + later[0]),
            size_ratio=float(size_b / size_g),
            centre_offset=float(np.hypot(*(_centre(b[i]) - _centre(g[i]))) / size_g),
        ))
    return out


def recurring(losses_per_seed: dict, window: int = 10, min_share: float = 1 / 3) -> list[tuple[int, int, int]]:
    """Where the losses of many seeds of one sequence recur: ``[(first, last, seeds), ...]``, most seeds first.

    ``losses_per_seed`` maps each seed to its run's losses: :class:`Loss` objects, or the 1-based frames they
    were lost at. Greedily, the ``window`` frames
    in which the most seeds lose the target (each seed counted once) are a place, ``first``–``last``
    being the earliest and latest of those losses; their losses are set aside and the next place is
    sought, while one holds at least ``min_share`` of the seeds (and at least two).
    """
    if window < 1:
        raise ValueError(f"window must be at least 1, got {window}")
    need = max(2, min_share * len(losses_per_seed))
    left = sorted((int(getattr(ls, "lost_at", ls)), seed) for seed, losses in losses_per_seed.items() for ls in losses)
    places = []
    while left:
        frames = [f for f, _ in left]
        best, best_n = 0, 0
        for j, start in enumerate(frames):
            n = len({sd for _, sd in left[j:bisect_left(frames, start + window)]})
            if n > best_n:
                best, best_n = j, n
        if best_n < need:
            break
        end = bisect_left(frames, frames[best] + window)
        places.append((frames[best], frames[end - 1], best_n))
        left = left[:best] + left[end:]
    return places
