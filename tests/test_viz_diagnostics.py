"""Tests for :mod:`covviz.viz.diagnostics` (no rerun involved)."""

from __future__ import annotations

import numpy as np
import pytest

from covviz.records import FrameRecord
from covviz.sequences import SyntheticConfig, SyntheticSequence
from covviz.spd import distance_riemann, expm, mean_riemann
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
from covviz.viz.diagnostics import (
    EventConfig,
    EventDetector,
    ObservationModel,
    background_poses,
    box_to_pose,
    drift_onset,
    likelihood_map,
    template_cloud,
    template_spread,
    top_k,
)


@pytest.fixture(scope="module")
def tracked():
    """A manifold tracker 4 frames into a short synthetic sequence, with its last record and frame."""
    seq = SyntheticSequence(SyntheticConfig(n_frames=6))
    tr = ManifoldTracker(ManifoldConfig(n_particles=40), rng=1)
    tr.init(seq.frame(0).image, seq.init_box)
    for i in range(1, 5):
        tr.update(seq.frame(i).image)
    return seq, tr, tr.last_record, seq.frame(4)


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
    ess = [0.5] * 3 + [0.01, 0.02, 0.03, 0.2] + [0.01, 0.01] + [0.5] * (len(ious) - 9)
    events = []
    for i, (o, e) in enumerate(zip(ious, ess)):
        events += det.update(i, o, e)
    kinds = [(ev.kind, ev.frame) for ev in events]
    assert ("storm", 3) in kinds and ("storm_end", 6) in kinds
    assert [k for k, _ in kinds].count("storm") == 1  # the two-frame dip at 7-8 is not a storm
    assert det.storms == [(3, 6)]
    assert ("lost", 13) in kinds
    assert ("drift", 10) in kinds  # the fall 0.8 -> 0.6 -> ... started on frame 10
    assert ("recovered", 15) in kinds  # 3 frames at IoU >= 0.3 from frame 15
    assert det.losses == [13] and det.drifts == [10] and det.recoveries == [15]
    drift = next(ev for ev in events if ev.kind == "drift")
    assert drift.detected_at == 13 and drift.iou == pytest.approx(0.6)


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


# --------------------------------------------------------------------------- #
# geometry helpers
# --------------------------------------------------------------------------- #
def test_top_k_orders_by_weight():
    w = np.array([0.1, 0.5, 0.05, 0.3, 0.05])
    np.testing.assert_array_equal(top_k(w, 3), [1, 3, 0])
    assert len(top_k(w, 10)) == 5 and len(top_k(w, 0)) == 0


def test_box_to_pose_round_trip():
    pose = box_to_pose(np.array([10.0, 20.0, 40.0, 60.0]), (20.0, 30.0))
    np.testing.assert_allclose(pose, [30.0, 50.0, 2.0, 0.0])


def test_background_poses_stay_in_the_frame_and_keep_their_slots():
    poses, slots = background_poses(np.array([10.0, 10.0, 1.0, 0.0]), (20.0, 20.0), (100, 100), n=16)
    assert len(poses) < 16  # the corner drops the slots outside the frame
    assert np.all((poses[:, 0] >= 0) & (poses[:, 1] >= 0))
    full, all_slots = background_poses(np.array([50.0, 50.0, 1.0, 0.0]), (10.0, 10.0), (100, 100), n=16)
    np.testing.assert_array_equal(all_slots, np.arange(16))
    assert set(slots) <= set(all_slots)
    # Every region is at least ~one size away from the target centre.
    assert np.all(np.hypot(full[:, 0] - 50, full[:, 1] - 50) >= 10.0)


def test_template_spread_matches_the_karcher_mean(rng):
    A = rng.normal(scale=0.2, size=(30, 4, 4))
    L = A + A.transpose(0, 2, 1)
    spread, M = template_spread(L, tol=1e-10)
    M_ref = mean_riemann(expm(L), tol=1e-12)
    np.testing.assert_allclose(M, M_ref, atol=1e-8)
    assert spread == pytest.approx(float(distance_riemann(M_ref, expm(L)).mean()), rel=1e-6)
    # Identical templates: no spread.
    assert template_spread(np.repeat(L[:1], 5, axis=0))[0] == pytest.approx(0.0, abs=1e-9)


def test_template_spread_subsamples_large_clouds(rng):
    A = rng.normal(scale=0.2, size=(400, 3, 3))
    L = A + A.transpose(0, 2, 1)
    full, _ = template_spread(L, max_templates=400)
    sub, _ = template_spread(L, max_templates=100)
    assert sub == pytest.approx(full, rel=0.1)


def test_template_spread_refuses_bad_shapes():
    with pytest.raises(ValueError, match="shape"):
        template_spread(np.zeros((0, 3, 3)))


# --------------------------------------------------------------------------- #
# observation model, likelihood map, template cloud
# --------------------------------------------------------------------------- #
def test_observation_model_reproduces_the_trackers_descriptors(tracked):
    _, tr, rec, frame = tracked
    model = ObservationModel.from_tracker(tr)
    assert model is not None
    C = model.descriptors(model.prepare(frame.image), rec.particle_poses[:5])
    np.testing.assert_allclose(C, rec.descriptors[:5], rtol=1e-6, atol=1e-10)


def test_observation_model_absent_for_trackers_without_one():
    from covviz.trackers.base import IdentityTracker

    assert ObservationModel.from_tracker(IdentityTracker()) is None


def test_likelihood_map_peaks_on_the_target(tracked):
    _, tr, rec, frame = tracked
    model = ObservationModel.from_tracker(tr)
    gt_pose = box_to_pose(frame.gt, model.base_wh)
    # The true target's own descriptor as the template: the best match is where the target is.
    L = np.asarray(rec.estimate_template)
    lm = likelihood_map(model, model.prepare(frame.image), gt_pose, L, sigma=0.3, grid=11, reach=1.0)
    assert lm.distances.shape == lm.likelihood.shape == (11, 11)
    assert lm.likelihood.max() == pytest.approx(1.0) and lm.log_likelihood.max() == pytest.approx(0.0)
    step = model.base_wh[0] * gt_pose[2] * 2 / 10
    assert np.hypot(*(lm.best - gt_pose[:2])) <= 2.5 * step
    x0, y0, x1, y1 = lm.extent
    assert x0 < gt_pose[0] < x1 and y0 < gt_pose[1] < y1


def test_likelihood_map_validates_arguments(tracked):
    _, tr, rec, frame = tracked
    model = ObservationModel.from_tracker(tr)
    with pytest.raises(ValueError, match="sigma"):
        likelihood_map(model, model.prepare(frame.image), rec.pose, rec.estimate_template, sigma=0.0)


def test_template_cloud_contents(tracked):
    _, tr, rec, _ = tracked
    bg = rec.descriptors[:4]
    cloud = template_cloud(
        rec,
        tr.initial_template,
        rec.estimate_descriptor,
        bg,
        np.array([0, 2, 4, 6]),
        k_top=5,
        max_templates=20,
        rng=0,
    )
    kinds = list(cloud.kinds)
    assert kinds.count("top") == 5 and kinds.count("template") == 15
    assert kinds.count("background") == 4 and kinds.count("target") == 1
    assert kinds.count("initial") == 1 and kinds.count("estimate") == 1
    assert ("background", 6) in cloud.keys and "target" in cloud.keys
    top = cloud.particle[cloud.kinds == "top"]
    np.testing.assert_array_equal(np.sort(top), np.sort(top_k(rec.weights, 5)))
    np.testing.assert_allclose(cloud.matrices[cloud.kinds == "top"], expm(rec.templates[top]))


def test_template_cloud_of_a_record_without_particles():
    rec = FrameRecord(index=0, box=np.zeros(4), estimate_template=np.zeros((9, 9)))
    cloud = template_cloud(rec, np.zeros((9, 9)), None)
    assert list(cloud.kinds) == ["estimate", "initial"]
