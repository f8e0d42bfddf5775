"""Events of a run — resampling storms, loss of track, drift onset, recovery — from per-frame series.

Pure time-series logic (no Rerun, no tracker): the recorder feeds it one frame
at a time and logs what it returns; ``covviz bench`` and the results use the
same detector, so an event means the same thing everywhere. Thresholds are
named constants, saved with the results and in the recording.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = [
    "DRIFT_GOOD_IOU",
    "DRIFT_TOL",
    "DRIFT_WINDOW",
    "EVENT_DEFAULTS",
    "LOST_IOU",
    "RECOVER_FRAMES",
    "RECOVER_IOU",
    "STORM_ESS",
    "STORM_FRAMES",
    "STORM_FRAMES_UNLABELLED",
    "STORM_IOU",
    "Event",
    "EventConfig",
    "EventDetector",
    "drift_onset",
]

#: A resampling storm: ESS/N below this (the weights have collapsed onto a handful of particles) ...
STORM_ESS = 0.05
#: ... on this many consecutive frames (a single collapsed frame is common and harmless) ...
STORM_FRAMES = 3
#: ... while the track degrades: the IoU below this (off track) on one of those frames. Peaked weights on a
#: run that stays on track are a sharp likelihood doing its job, not a storm (the synthetic default, tracked
#: at IoU 0.9, has ESS/N < 0.05 for 3-17 frames six times).
STORM_IOU = 0.5
#: Without ground truth (no IoU to read) a low-ESS run is a storm only when it lasts this many frames.
STORM_FRAMES_UNLABELLED = 30
#: Loss of track: IoU with the ground truth below this.
LOST_IOU = 0.1
#: Recovery after a loss: IoU at least this ...
RECOVER_IOU = 0.3
#: ... on this many consecutive frames (with ground truth).
RECOVER_FRAMES = 3
#: Where a drift began: after the last frame with IoU at least this before the loss (OTB's success
#: threshold) or, if none, after the top of the last climb (values within DRIFT_TOL of its peak).
DRIFT_GOOD_IOU = 0.5
DRIFT_TOL = 0.05
#: Frames of IoU history kept to find where a drift began (bounded memory).
DRIFT_WINDOW = 500


# --------------------------------------------------------------------------- #
# events: storms, loss, recovery, drift onset
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class EventConfig:
    """Thresholds of the event detector (defaults: the module constants)."""

    storm_ess: float = STORM_ESS
    storm_frames: int = STORM_FRAMES
    storm_iou: float = STORM_IOU
    storm_frames_unlabelled: int = STORM_FRAMES_UNLABELLED
    lost_iou: float = LOST_IOU
    recover_iou: float = RECOVER_IOU
    recover_frames: int = RECOVER_FRAMES
    drift_tol: float = DRIFT_TOL
    drift_good_iou: float = DRIFT_GOOD_IOU
    drift_window: int = DRIFT_WINDOW

    def __post_init__(self):
        if not 0 <= self.lost_iou < self.recover_iou <= 1:
            raise ValueError("need 0 <= lost_iou < recover_iou <= 1")
        if not 0 <= self.storm_iou <= 1:
            raise ValueError("need 0 <= storm_iou <= 1")
        if self.storm_frames_unlabelled < self.storm_frames:
            raise ValueError("storm_frames_unlabelled must be at least storm_frames")
        if self.recover_frames < 1 or self.storm_frames < 1 or self.drift_window < 2:
            raise ValueError("recover_frames and storm_frames must be >= 1, drift_window >= 2")


EVENT_DEFAULTS = EventConfig()


@dataclass(frozen=True)
class Event:
    """Something worth a line in the event log.

    Attributes
    ----------
    frame : int
        The frame the event belongs to (``drift``: where it began; ``recovered``:
        the first frame of the run of good IoU).
    kind : str
        ``storm``, ``storm_end``, ``lost``, ``drift``, ``recovered``.
    level : str
        ``INFO``, ``WARN`` or ``ERROR`` (as Rerun's text log levels).
    text : str
    detected_at : int
        The frame on which the detector saw it (later than ``frame`` for ``drift``
        and ``recovered``).
    iou : float
        IoU on ``frame`` (``nan`` for events that are not about IoU).
    """

    frame: int
    kind: str
    level: str
    text: str
    detected_at: int
    iou: float = float("nan")


def _median3(v: np.ndarray) -> np.ndarray:
    """Centred running median over 3 samples (2 at the ends): a one-frame flicker disappears."""
    return np.array([np.median(v[max(0, i - 1) : i + 2]) for i in range(len(v))])


def drift_onset(
    frames: np.ndarray, ious: np.ndarray, tol: float = DRIFT_TOL, good: float = DRIFT_GOOD_IOU
) -> int:
    """The frame where the run of falling IoU that ends at the last frame (the loss) began.

    The anchor is the last frame before the loss where the IoU, median-filtered
    over 3 frames (so a one-frame flicker does not count), was still good
    (≥ ``good``, OTB's success threshold); if there is none, the top of the
    climb met walking back from the loss (each earlier value at most ``tol``
    below the highest seen). From the anchor, go back while the IoU was
    already falling (each earlier frame higher by more than ``tol / 5``): the drift began on
    the frame after the top of that fall. So a plateau followed by a slide
    gives the end of the plateau, and a noisy slide gives the frame where the
    IoU left the good range (or the last clear fall into it).

    Parameters
    ----------
    frames : ndarray of int, shape (n,)
        Frame indices (increasing; gaps where there was no ground truth).
    ious : ndarray, shape (n,)
        IoU on those frames; the last one is the loss.
    tol : float
    good : float

    Returns
    -------
    int
        The first frame of the fall (a value of ``frames``).
    """
    frames = np.asarray(frames)
    raw = np.asarray(ious, dtype=np.float64)
    if len(raw) == 0:
        raise ValueError("drift_onset needs at least one frame")
    last = len(raw) - 1
    if last == 0:
        return int(frames[0])
    v = _median3(raw)
    above = np.flatnonzero(v[:last] >= good)
    if len(above):
        j = int(above[-1])
    else:
        j, m = last, v[last]
        while j > 0 and v[j - 1] >= m - tol:
            j -= 1
            m = max(m, v[j])
        run = np.arange(j, last + 1)
        j = int(run[v[run] >= m - tol].max())
    while j > 0 and raw[j - 1] > raw[j] + tol / 5:  # a clear step down, not noise
        j -= 1
    return int(frames[min(j + 1, last)])


class EventDetector:
    """Online detection of resampling storms, loss of track, recovery and drift onset.

    Feed it one frame at a time with :meth:`update`; it returns the events
    detected on that frame. A loss is an IoU below ``lost_iou`` while
    tracking; it also reports where the drift began (:func:`drift_onset` over
    the IoU since the last recovery, at most ``drift_window`` frames). A
    recovery needs ``recover_frames`` consecutive frames at IoU ≥
    ``recover_iou`` (hysteresis, so a flicker does not count). A storm is
    ESS/N below ``storm_ess`` on ``storm_frames`` consecutive frames *while
    the track degrades* (IoU below ``storm_iou`` on one of them), or, on
    frames without ground truth, on ``storm_frames_unlabelled`` consecutive
    frames; it is reported on the first frame of the low run and ends when
    ESS/N is back above twice ``storm_ess``. So a calm run, on track
    throughout, lists no storm however peaked its weights.
    """

    def __init__(self, config: EventConfig = EVENT_DEFAULTS):
        self.config = config
        self.lost = False
        self.storm = False
        self._storm_start = -1
        self._storm_min = np.inf
        self._low_run: list[tuple[int, float, float | None]] = []
        self._good_run: list[tuple[int, float]] = []
        self._hist: deque = deque(maxlen=config.drift_window)
        self.losses: list[int] = []
        self.drifts: list[int] = []
        self.recoveries: list[int] = []
        self.storms: list[tuple[int, int]] = []

    def update(self, frame: int, iou: float | None = None, ess_frac: float | None = None) -> list[Event]:
        """Events of ``frame``; ``iou`` None when there is no ground truth, ``ess_frac`` None without particles."""
        cfg = self.config
        out: list[Event] = []
        if ess_frac is not None and np.isfinite(ess_frac):
            if not self.storm:
                if ess_frac < cfg.storm_ess:
                    self._low_run.append((frame, ess_frac, iou if iou is not None and np.isfinite(iou) else None))
                else:
                    self._low_run = []
                run = self._low_run
                off = [v for _, _, v in run if v is not None and v < cfg.storm_iou]
                unlabelled = all(v is None for _, _, v in run)
                if (len(run) >= cfg.storm_frames and off) or (unlabelled and len(run) >= cfg.storm_frames_unlabelled):
                    first = run[0][0]
                    self._storm_min = min(v for _, v, _ in run)
                    why = (f"while the IoU fell to {min(off):.2f}" if off else
                           f"on {len(run)} frames without ground truth")
                    self.storm, self._storm_start, self._low_run = True, first, []
                    out.append(
                        Event(
                            first,
                            "storm",
                            "WARN",
                            f"resampling storm: ESS/N below {cfg.storm_ess:g} from frame {first} {why} "
                            f"(lowest {self._storm_min:.3f}): the weights sit on a handful of particles",
                            frame,
                        )
                    )
            else:
                self._storm_min = min(self._storm_min, ess_frac)
                if ess_frac >= 2 * cfg.storm_ess:
                    self.storm = False
                    self.storms.append((self._storm_start, frame))
                    out.append(
                        Event(
                            frame,
                            "storm_end",
                            "INFO",
                            f"storm over after {frame - self._storm_start} frames "
                            f"(from frame {self._storm_start}, lowest ESS/N {self._storm_min:.3f})",
                            frame,
                        )
                    )
        if iou is not None and np.isfinite(iou):
            if not self.lost:
                self._hist.append((frame, float(iou)))
                if iou < cfg.lost_iou:
                    self.lost = True
                    self._good_run = []
                    fr, v = np.array([h[0] for h in self._hist]), np.array([h[1] for h in self._hist])
                    start = drift_onset(fr, v, cfg.drift_tol, cfg.drift_good_iou)
                    before = v[fr < start]
                    peak = before[-1] if len(before) else v[0]
                    v_start = float(v[fr == start][0])
                    self.losses.append(frame)
                    self.drifts.append(start)
                    out.append(
                        Event(
                            frame,
                            "lost",
                            "ERROR",
                            f"lost track: IoU {iou:.2f} < {cfg.lost_iou:g}; the drift began at frame {start} "
                            f"(IoU {peak:.2f} -> {iou:.2f} over {frame - start + 1} frames)",
                            frame,
                            float(iou),
                        )
                    )
                    out.append(
                        Event(
                            start,
                            "drift",
                            "WARN",
                            f"drift began here: IoU falls from {peak:.2f} to {iou:.2f} and the track is lost "
                            f"at frame {frame}",
                            frame,
                            v_start,
                        )
                    )
            else:
                if iou >= cfg.recover_iou:
                    self._good_run.append((frame, float(iou)))
                    if len(self._good_run) >= cfg.recover_frames:
                        first, first_iou = self._good_run[0]
                        self.lost = False
                        self._good_run = []
                        self._hist.clear()
                        self._hist.append((frame, float(iou)))
                        self.recoveries.append(first)
                        out.append(
                            Event(
                                first,
                                "recovered",
                                "INFO",
                                f"recovered: IoU >= {cfg.recover_iou:g} from this frame on "
                                f"(lost at frame {self.losses[-1]}, confirmed at frame {frame})",
                                frame,
                                first_iou,
                            )
                        )
                else:
                    self._good_run = []
        return out
