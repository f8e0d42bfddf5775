"""Tests of the event detector (covviz/diagnosis/events.py): storms, loss, drift onset, recovery."""

from __future__ import annotations

import numpy as np
import pytest

from covviz.diagnosis.events import EventConfig, EventDetector, drift_onset


# --------------------------------------------------------------------------- #
# drift onset and events
# --------------------------------------------------------------------------- #
def test_drift_onset_after_a_plateau():
    iou = np.r_[np.full(20, 0.8), np.linspace(0.75, 0.05, 15)]
    frames = np.arange(len(iou)) + 100
    assert drift_onset(frames, iou) == 120  # the first frame below the plateau


def test_drift_onset_finds_the_last_peak_not_the_global_one():
    iou = np.r_[np.full(5, 0.95), np.full(10, 0.6), 0.7, 0.65, 0.5, 0.3, 0.05]
    assert drift_onset(np.arange(len(iou)), iou) == 16  # after the local peak 0.7 at frame 15


def test_drift_onset_of_an_abrupt_loss_is_the_loss_frame():
    iou = np.r_[np.full(10, 0.8), 0.0]
    assert drift_onset(np.arange(11), iou) == 10


def test_drift_onset_of_a_slow_noisy_slide_is_where_the_iou_left_the_good_range(rng):
    """IoU 0.9 for 30 frames, then a noisy slide to loss: not the last local bump before the loss."""
    fall = np.linspace(0.88, 0.05, 40) + rng.uniform(-0.12, 0.12, 40)
    fall[-1] = 0.05
    iou = np.r_[np.full(30, 0.9), np.clip(fall, 0.0, 1.0)]
    onset = drift_onset(np.arange(len(iou)), iou)
    crossing = 30 + np.flatnonzero(np.linspace(0.88, 0.05, 40) < 0.5)[0]  # the trend crosses 0.5 here
    assert crossing - 8 <= onset <= crossing + 3
    assert onset < len(iou) - 10


def test_drift_onset_without_a_good_frame_uses_the_last_climb():
    iou = np.array([0.3, 0.35, 0.3, 0.45, 0.4, 0.3, 0.2, 0.05])
    assert drift_onset(np.arange(len(iou)), iou) == 4  # after the top at frame 3


def test_drift_onset_ignores_noise_below_tolerance():
    iou = np.array([0.8, 0.82, 0.79, 0.81, 0.8, 0.6, 0.4, 0.2, 0.05])
    assert drift_onset(np.arange(len(iou)), iou, tol=0.05) == 5


def test_event_detector_storm_loss_drift_recovery():
    det = EventDetector(EventConfig())
    ious = [0.8] * 10 + [0.6, 0.4, 0.2, 0.05, 0.0, 0.5, 0.5, 0.5, 0.8]
    ess = [0.5] * 3 + [0.01, 0.02, 0.03, 0.2] + [0.5] * 3 + [0.01, 0.02, 0.03, 0.2] + [0.01, 0.01] + [0.5] * 3
    events = []
    for i, (o, e) in enumerate(zip(ious, ess)):
        events += det.update(i, o, e)
    kinds = [(ev.kind, ev.frame) for ev in events]
    # The low run at 3-5 is on track (IoU 0.8): peaked weights, no storm; the one at 10-12 has the IoU
    # falling below 0.5: a storm.
    assert ("storm", 10) in kinds and ("storm_end", 13) in kinds
    assert [k for k, _ in kinds].count("storm") == 1  # the two-frame dip at 14-15 is not a storm either
    assert det.storms == [(10, 13)]
    assert ("lost", 13) in kinds
    assert ("drift", 10) in kinds  # the fall 0.8 -> 0.6 -> ... started on frame 10
    assert ("recovered", 15) in kinds  # 3 frames at IoU >= 0.3 from frame 15
    assert det.losses == [13] and det.drifts == [10] and det.recoveries == [15]
    drift = next(ev for ev in events if ev.kind == "drift")
    assert drift.detected_at == 13 and drift.iou == pytest.approx(0.6)


def test_calm_run_lists_no_storm():
    """The storm rule: low ESS/N on a run that stays on track is not a storm, however long it lasts."""
    det = EventDetector()
    rng = np.random.default_rng(0)
    events = []
    for i in range(300):
        events += det.update(i, 0.85 + 0.1 * rng.random(), 0.01 if (i // 10) % 2 else 0.3)
    assert [e for e in events if e.kind.startswith("storm")] == []
    # Without ground truth, only a long low run is a storm (STORM_FRAMES_UNLABELLED frames).
    det = EventDetector()
    short = [e for i in range(20) for e in det.update(i, None, 0.01)]
    assert short == []
    det = EventDetector()
    long = [e for i in range(40) for e in det.update(i, None, 0.01)]
    assert [(e.kind, e.frame) for e in long] == [("storm", 0)]


def test_event_detector_needs_consecutive_frames_to_recover():
    det = EventDetector(EventConfig(recover_frames=3))
    for i, o in enumerate([0.8, 0.0, 0.5, 0.0, 0.5, 0.5]):
        det.update(i, o)
    assert det.lost and det.recoveries == []


def test_event_detector_skips_frames_without_ground_truth():
    det = EventDetector()
    assert det.update(0, None, None) == []
    assert det.update(1, float("nan"), float("nan")) == []


def test_event_detector_memory_is_bounded():
    det = EventDetector(EventConfig(drift_window=50))
    for i in range(1000):
        det.update(i, 0.8, 0.5)
    assert len(det._hist) == 50


def test_event_config_is_validated():
    with pytest.raises(ValueError):
        EventConfig(lost_iou=0.5, recover_iou=0.3)
