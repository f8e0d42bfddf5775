"""Tests for :mod:`covviz.trackers.manifold` (and the protocol of :mod:`covviz.trackers.base`).

The tracker runs on the embedded synthetic sequence with small particle counts
(fast); assertions on tracking quality are deliberately loose (the defaults are
being tuned), while everything about the :class:`FrameRecord` contract,
determinism and validation is exact.
"""

from __future__ import annotations

import copy
import dataclasses
import json

import numpy as np
import pytest
from scipy.special import logsumexp

from covviz.data.sequences import SyntheticSequence
from covviz.metrics import iou
from covviz.model import refine, spd
from covviz.model.features import pose_corners, pose_to_box
from covviz.model.image import check_init_box
from covviz.model.observation import quadrant_term
from covviz.records import STAGES, FrameRecord
from covviz.trackers.base import IdentityTracker, Tracker
from covviz.trackers.manifold import PAPER_LIKELIHOOD, ManifoldConfig, ManifoldTracker, make

D = 9
N_TRACK = 60  # frames of the tracking-quality test


@pytest.fixture(scope="module")
def synth():
    """The synthetic sequence and its first frames (read once per module)."""
    seq = SyntheticSequence()
    frames = [seq.frame(i).image for i in range(N_TRACK)]
    return seq, frames


def run_frames(tracker, synth, n_frames):
    seq, frames = synth
    tracker.init(frames[0], seq.init_box)
    boxes = [np.asarray(seq.init_box, dtype=float)]
    records = [tracker.last_record]
    for f in frames[1:n_frames]:
        boxes.append(tracker.update(f))
        records.append(tracker.last_record)
    return np.array(boxes), records


def random_sym(rng, n, norm):
    A = rng.standard_normal((n, D, D))
    S = A + np.swapaxes(A, 1, 2)
    return S * (norm / np.abs(S).sum(axis=-1).max(axis=-1))[:, None, None]


def random_spd(rng, n, cond):
    Q, _ = np.linalg.qr(rng.standard_normal((n, D, D)))
    w = np.exp(rng.uniform(0, np.log(cond), (n, D)))
    w[:, 0], w[:, -1] = 1.0, cond
    return spd.sym((Q * w[:, None, :]) @ np.swapaxes(Q, 1, 2)) * rng.uniform(0.01, 10, (n, 1, 1))


# --------------------------------------------------------------------------- #
# protocol, init and validation
# --------------------------------------------------------------------------- #
def test_tracker_protocol_and_config_dict():
    tr = ManifoldTracker(ManifoldConfig(n_particles=10), rng=0)
    assert isinstance(tr, Tracker) and isinstance(IdentityTracker(), Tracker)
    assert tr.name == "manifold"
    d = tr.config_dict()
    assert d["n_particles"] == 10 and "kinematics" in d
    json.dumps(d)  # written next to results: must be JSON-serialisable


def test_make_factory():
    assert make(n_particles=37, rng=1).config.n_particles == 37
    assert make(rng=1).config == ManifoldConfig()


def test_update_before_init_raises(synth):
    with pytest.raises(RuntimeError, match="init"):
        ManifoldTracker(ManifoldConfig(n_particles=10), rng=0).update(synth[1][1])
    with pytest.raises(RuntimeError, match="init"):
        IdentityTracker().update(synth[1][1])


@pytest.mark.parametrize(
    "box, match",
    [
        ([400, 10, 20, 20], "outside"),  # right of the 320x240 frame
        ([10, 300, 20, 20], "outside"),  # below
        ([-50, 10, 20, 20], "outside"),  # left: x + w <= 0
        ([10, -20, 20, 20], "outside"),  # above: y + h <= 0
        ([10, 10, 0, 20], "size"),
        ([10, 10, 20, 0], "size"),
        ([10, 10, -5, 20], "size"),
        ([10, 10, np.nan, 20], "finite"),
        ([10, 10, 20], "4"),
    ],
)
def test_init_rejects_bad_boxes(synth, box, match):
    frame = synth[1][0]
    for tr in (ManifoldTracker(ManifoldConfig(n_particles=10), rng=0), IdentityTracker()):
        with pytest.raises(ValueError, match=match):
            tr.init(frame, box)


def test_partly_outside_box_is_accepted(synth):
    frame = synth[1][0]
    np.testing.assert_array_equal(check_init_box([-10, -10, 30, 30], frame.shape), [-10, -10, 30, 30])
    tr = ManifoldTracker(ManifoldConfig(n_particles=10), rng=0)
    tr.init(frame, [-10, -10, 30, 30])
    assert np.all(np.isfinite(tr.update(synth[1][1])))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"n_particles": 1}, "n_particles"),
        ({"likelihood_sigma": 0.0}, "likelihood_sigma"),
        ({"likelihood_sigma": float("nan")}, "likelihood_sigma"),
        ({"template_sigma": -0.1}, "template_sigma"),
        ({"template_sigma_matrix": ((0.1,) * 8,) * 8}, "template_sigma_matrix"),
        ({"template_sigma_matrix": tuple(tuple(r) for r in np.triu(np.ones((9, 9))))}, "template_sigma_matrix"),
        ({"template_sigma_matrix": tuple(tuple(r) for r in -np.ones((9, 9)))}, "template_sigma_matrix"),
        ({"patch_size": 3}, "patch_size"),
        ({"eps": 0.0}, "eps"),
        ({"resample_threshold": 1.5}, "resample_threshold"),
        ({"resample_threshold": -0.1}, "resample_threshold"),
        ({"smooth_sigma": -1.0}, "smooth_sigma"),
        ({"resampling": "stratified-ish"}, "resampling"),
        ({"quadrant_weight": -1.0}, "quadrant_weight"),
        ({"quadrant_weight": float("nan")}, "quadrant_weight"),
        ({"patch_size": 31}, "even patch_size"),
    ],
)
def test_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ManifoldConfig.from_dict(kwargs)


@pytest.mark.parametrize("kwargs", [{"template_sigma": float("nan")}, {"smooth_sigma": float("nan")}])
def test_config_rejects_nan(kwargs):
    with pytest.raises(ValueError):
        ManifoldConfig.from_dict(kwargs)


def test_config_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        ManifoldConfig().n_particles = 5  # type: ignore[misc]


def test_init_record_and_particles(synth):
    seq, frames = synth
    tr = ManifoldTracker(ManifoldConfig(n_particles=20), rng=0)
    tr.init(frames[0], seq.init_box)
    rec = tr.last_record
    assert isinstance(rec, FrameRecord) and rec.index == 0 and rec.tracker == "manifold"
    np.testing.assert_allclose(rec.box, seq.init_box)
    x, y, w, h = seq.init_box
    np.testing.assert_allclose(rec.pose, [x + w / 2, y + h / 2, 1.0, 0.0])
    assert rec.corners.shape == (4, 2)
    assert np.linalg.eigvalsh(rec.estimate_descriptor).min() > 0
    np.testing.assert_allclose(rec.estimate_template, spd.logm(rec.estimate_descriptor), atol=1e-10)
    ps = tr.particles
    assert len(ps) == 20
    np.testing.assert_allclose(ps.states[:, [0, 1]], np.tile([x + w / 2, y + h / 2], (20, 1)))
    np.testing.assert_array_equal(ps.states[:, [2, 3, 5]], 0.0)
    np.testing.assert_array_equal(ps.states[:, 4], 1.0)
    np.testing.assert_allclose(ps.templates, np.broadcast_to(rec.estimate_template, (20, D, D)))
    assert logsumexp(ps.log_weights) == pytest.approx(0.0, abs=1e-12)


# --------------------------------------------------------------------------- #
# the FrameRecord of an update
# --------------------------------------------------------------------------- #
def check_record(rec: FrameRecord, tr: ManifoldTracker, index: int):
    n = tr.config.n_particles
    assert rec.index == index and rec.tracker == "manifold"
    assert rec.n_particles == n
    assert rec.box.shape == (4,) and np.all(np.isfinite(rec.box))
    assert rec.pose.shape == (4,) and rec.corners.shape == (4, 2)
    assert rec.particle_poses.shape == (n, 4)
    assert rec.particle_corners.shape == (n, 4, 2)
    assert rec.log_weights.shape == (n,)
    assert rec.templates.shape == (n, D, D) and rec.descriptors.shape == (n, D, D)
    assert rec.distances.shape == (n,) and rec.estimate_template.shape == (D, D)
    assert rec.estimate_descriptor.shape == (D, D)
    # Templates symmetric (log space), descriptors SPD.
    np.testing.assert_allclose(rec.templates, np.swapaxes(rec.templates, 1, 2), atol=1e-12)
    assert np.linalg.eigvalsh(rec.descriptors).min() > 0
    assert np.linalg.eigvalsh(rec.estimate_descriptor).min() > 0
    # Normalised log-weights and the ESS they give.
    assert logsumexp(rec.log_weights) == pytest.approx(0.0, abs=1e-9)
    w = rec.weights
    assert rec.ess == pytest.approx(1.0 / np.sum(w**2), rel=1e-9)
    assert 1.0 - 1e-9 <= rec.ess <= n * (1 + 1e-9)
    # Distances are d(expm(template), descriptor), per particle.
    np.testing.assert_allclose(rec.distances, spd.distance_riemann(rec.descriptors, spd.expm(rec.templates)),
                               rtol=1e-7, atol=1e-9)
    # The filter's estimate is the MMSE pose; the reported pose is it, or (the position step, ncc_rate > 0) it
    # with its centre moved within the search radius (a quarter of the box's size, whole pixels, at least 1,
    # plus the sub-pixel parabola's half pixel); the box/corners are the reported pose's geometry.
    mmse = rec.pose if rec.filter_pose is None else rec.filter_pose
    assert (rec.filter_pose is not None) == (tr.config.ncc_rate > 0)
    np.testing.assert_allclose(mmse, w @ rec.particle_poses, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(rec.pose[2:], mmse[2:])
    reach = np.maximum(1, np.ceil(refine.NCC_RADIUS * rec.box[2:])) + 0.5
    assert np.all(np.abs(rec.pose[:2] - mmse[:2]) <= reach + 1e-9)
    np.testing.assert_allclose(rec.box, pose_to_box(rec.pose, tr.model.base_wh)[0], atol=1e-9)
    np.testing.assert_allclose(rec.corners, pose_corners(rec.pose, tr.model.base_wh)[0], atol=1e-9)
    np.testing.assert_allclose(rec.particle_corners, pose_corners(rec.particle_poses, tr.model.base_wh), atol=1e-9)
    # Timings of every expensive stage.
    assert {"warp", "features", "covariance", "distances", "resample", "total"} <= set(rec.timings)
    assert set(rec.timings) <= set(STAGES) | {"total"}
    assert all(isinstance(v, float) and v >= 0 for v in rec.timings.values())
    # resample_indices present iff resampled, and the next set is that resampling.
    assert (rec.resample_indices is not None) == rec.resampled
    assert rec.resampled == (rec.ess < tr.config.resample_threshold * n)


def check_next_set(rec: FrameRecord, tr: ManifoldTracker):
    """The particle set after the update is the record's weighed set, resampled by its indices (and its
    templates stepped by the observation pull where the record's ``pull`` says so)."""
    ps = tr.particles
    n = tr.config.n_particles
    T = rec.templates
    if rec.resampled:
        idx = rec.resample_indices
        assert idx.shape == (n,) and idx.min() >= 0 and idx.max() < n
        np.testing.assert_array_equal(ps.states[:, [0, 1, 4, 5]], rec.particle_poses[idx])
        T = T[idx]
        np.testing.assert_allclose(ps.log_weights, -np.log(n))
    else:
        np.testing.assert_array_equal(ps.states[:, [0, 1, 4, 5]], rec.particle_poses)
        np.testing.assert_array_equal(ps.log_weights, rec.log_weights)
    assert (rec.pull is None) == (tr.config.observation_pull == 0)
    if rec.pull is not None and rec.pull.target is not None:
        assert rec.pull.held == ""
        T = T + rec.pull.rate * (rec.pull.target - T)
    np.testing.assert_array_equal(ps.templates, T)


@pytest.mark.parametrize("pull", [0.0, 0.05])
@pytest.mark.parametrize("threshold", [0.0, 0.5, 1.0])
def test_update_record_contract(synth, threshold, pull):
    seq, frames = synth
    tr = ManifoldTracker(ManifoldConfig(n_particles=48, resample_threshold=threshold, observation_pull=pull), rng=1)
    tr.init(frames[0], seq.init_box)
    resampled, stepped = [], []
    for i in range(1, 6):
        box = tr.update(frames[i])
        rec = tr.last_record
        np.testing.assert_array_equal(box, rec.box)
        check_record(rec, tr, i)
        check_next_set(rec, tr)
        resampled.append(rec.resampled)
        stepped.append(rec.pull is not None and rec.pull.target is not None)
    assert any(stepped) == (pull > 0)  # the pull's step is part of the contract checked above
    if threshold == 0.0:
        assert not any(resampled)  # ESS < 0 never holds
    if threshold == 1.0:
        assert all(resampled)  # ESS < n unless the weights are exactly uniform


def test_zero_template_sigma_keeps_templates(synth):
    # the random walk alone: the observation pull (on by default) is the one other step of the templates
    seq, frames = synth
    tr = ManifoldTracker(ManifoldConfig(n_particles=16, template_sigma=0.0, observation_pull=0.0), rng=2)
    tr.init(frames[0], seq.init_box)
    L0 = tr.last_record.estimate_template
    for f in frames[1:4]:
        tr.update(f)
        np.testing.assert_allclose(tr.last_record.templates, np.broadcast_to(L0, (16, D, D)), atol=1e-14)


def test_template_sigma_matrix_is_honoured(synth):
    seq, frames = synth
    sig = np.zeros((D, D))
    sig[2, 3] = sig[3, 2] = 0.05  # only the (I, |Ix|) entry walks
    cfg = ManifoldConfig(n_particles=16, template_sigma_matrix=tuple(map(tuple, sig)))
    np.testing.assert_array_equal(cfg.sigma_matrix, sig)
    tr = ManifoldTracker(cfg, rng=3)
    tr.init(frames[0], seq.init_box)
    L0 = tr.last_record.estimate_template
    tr.update(frames[1])
    step = tr.last_record.templates - L0
    mask = sig > 0
    np.testing.assert_allclose(step[:, ~mask], 0.0, atol=1e-14)
    assert np.all(np.abs(step[:, 2, 3]) > 0)
    np.testing.assert_array_equal(step[:, 2, 3], step[:, 3, 2])


def test_large_target_is_downsampled_and_still_spd(synth):
    """A box of > 4 px per patch sample goes through the anti-aliasing path."""
    _seq, frames = synth
    tr = ManifoldTracker(ManifoldConfig(n_particles=16), rng=4)
    tr.init(frames[0], [60, 40, 150, 140])
    assert tr.model.step > 1
    box = tr.update(frames[1])
    assert np.all(np.isfinite(box))
    check_record(tr.last_record, tr, 1)


def test_gray_frames_are_accepted(synth):
    seq, frames = synth
    tr = ManifoldTracker(ManifoldConfig(n_particles=16), rng=5)
    tr.init(frames[0][..., 1], seq.init_box)
    box = tr.update(frames[1][..., 1])
    assert box.shape == (4,) and np.all(np.isfinite(box))


# --------------------------------------------------------------------------- #
# determinism and immutability of records
# --------------------------------------------------------------------------- #
def test_same_seed_same_boxes_bit_for_bit(synth):
    cfg = ManifoldConfig(n_particles=100)
    a, _ = run_frames(ManifoldTracker(cfg, rng=123), synth, 20)
    b, _ = run_frames(ManifoldTracker(cfg, rng=np.random.default_rng(123)), synth, 20)
    c, _ = run_frames(ManifoldTracker(cfg, rng=124), synth, 20)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a[1:], c[1:])


def test_threads_do_not_change_the_boxes(synth):
    # The observation stage splits particles into fixed chunks whatever the thread count, and
    # avoids kernels whose rounding depends on concurrency, so threads change speed only.
    one, _ = run_frames(ManifoldTracker(ManifoldConfig(n_particles=400, threads=1), rng=5), synth, 12)
    for _ in range(2):
        two, _ = run_frames(ManifoldTracker(ManifoldConfig(n_particles=400, threads=2), rng=5), synth, 12)
        np.testing.assert_array_equal(one, two)


def test_set_threads_before_init_changes_the_pool_not_the_boxes(synth):
    """``set_threads`` (what covviz track calls when it records on two cores): the config says what ran."""
    two, _ = run_frames(ManifoldTracker(ManifoldConfig(n_particles=400, threads=2), rng=5), synth, 12)
    tr = ManifoldTracker(ManifoldConfig(n_particles=400, threads=2), rng=5)
    tr.set_threads(1)
    assert tr.config.threads == 1 and tr.config_dict()["threads"] == 1 and tr._pool is None
    one, _ = run_frames(tr, synth, 12)
    np.testing.assert_array_equal(one, two)
    with pytest.raises(RuntimeError, match="before init"):
        tr.set_threads(2)
    with pytest.raises(ValueError, match="at least 1"):
        ManifoldTracker().set_threads(0)


def test_blas_threads_do_not_change_the_boxes(synth):
    # BLAS splits long sums by thread count; the hot path keeps such sums out of
    # BLAS, so `covviz bench` (BLAS threads = cores / jobs) replays `covviz track`
    # (one BLAS thread) and a notebook with the library's defaults gets the same boxes.
    threadpoolctl = pytest.importorskip("threadpoolctl")
    runs = []
    for k in (1, 2):
        with threadpoolctl.threadpool_limits(k, user_api="blas"):
            runs.append(run_frames(ManifoldTracker(ManifoldConfig(n_particles=600), rng=5), synth, 12))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1][-1].templates, runs[1][1][-1].templates)


def _fields(rec: FrameRecord) -> dict:
    return {f.name: getattr(rec, f.name) for f in dataclasses.fields(rec)}


def _assert_same(x, y, path="record"):
    if isinstance(x, np.ndarray):
        assert isinstance(y, np.ndarray), path
        np.testing.assert_array_equal(x, y, err_msg=path)
    elif isinstance(x, dict):
        assert set(x) == set(y), path
        for k in x:
            _assert_same(x[k], y[k], f"{path}.{k}")
    elif dataclasses.is_dataclass(x) and not isinstance(x, type):  # the frozen observation model
        assert type(x) is type(y), path
        _assert_same(dataclasses.asdict(x), dataclasses.asdict(y), path)
    elif isinstance(x, float) and np.isnan(x):
        assert np.isnan(y), path
    else:
        assert x == y, path


@pytest.mark.parametrize("threshold", [0.0, 1.0])  # never / always resample: arrays shared or not
def test_records_are_not_mutated_by_later_updates(synth, threshold):
    seq, frames = synth
    tr = ManifoldTracker(ManifoldConfig(n_particles=32, resample_threshold=threshold), rng=6)
    tr.init(frames[0], seq.init_box)
    held = [tr.last_record]
    snaps = [copy.deepcopy(_fields(tr.last_record))]
    for f in frames[1:4]:
        tr.update(f)
        held.append(tr.last_record)
        snaps.append(copy.deepcopy(_fields(tr.last_record)))
    for f in frames[4:9]:
        tr.update(f)
    for rec, snap in zip(held, snaps):
        _assert_same(_fields(rec), snap)


# --------------------------------------------------------------------------- #
# it tracks
# --------------------------------------------------------------------------- #
def test_tracks_the_synthetic_target(synth):
    seq, _ = synth
    boxes, _ = run_frames(ManifoldTracker(ManifoldConfig(n_particles=200), rng=0), synth, N_TRACK)
    o = iou(boxes, seq.groundtruth[:N_TRACK])
    assert np.mean(o > 0.5) >= 0.9, o.round(2)


def test_identity_tracker_returns_the_initial_box(synth):
    seq, frames = synth
    tr = IdentityTracker()
    tr.init(frames[0], seq.init_box)
    for i, f in enumerate(frames[1:3], 1):
        b = tr.update(f)
        np.testing.assert_array_equal(b, seq.init_box)
        assert tr.last_record.index == i and tr.last_record.n_particles == 0
        b[0] = -1  # the caller's copy: the tracker's state is unaffected
    np.testing.assert_array_equal(tr.update(frames[3]), seq.init_box)


# --------------------------------------------------------------------------- #
# the quadrant term of the likelihood
# --------------------------------------------------------------------------- #
def test_weights_follow_the_likelihood_distances(synth):
    """log w = normalise(-d_eff² / 2σ²) with d_eff² = d² + weight · quadrant_term(q), and the
    diagnostics' likelihood_distances gives the same d_eff at a particle's pose and template.
    (The colour term's share is tested in tests/test_quality.py; here it is off.)"""
    seq, frames = synth
    cfg = ManifoldConfig().replace(n_particles=40, quadrant_weight=0.7, colour_weight=0.0)
    tr = ManifoldTracker(cfg, rng=3)
    tr.init(frames[0], seq.init_box)
    assert tr.model.quadrant_reference.shape == (4, D, D)
    tr.update(frames[1])  # resamples: the next frame starts from uniform weights
    tr.update(frames[2])
    rec = tr.last_record
    q, d_eff = rec.likelihood.quadrant_distances, rec.likelihood.distances
    assert q.shape == (40, 4) and np.all(q >= 0)
    np.testing.assert_allclose(d_eff, np.sqrt(rec.distances**2 + 0.7 * quadrant_term(q)), rtol=1e-12)
    ll = -(d_eff**2) / (2 * cfg.observation.likelihood_sigma**2)
    np.testing.assert_allclose(rec.log_weights, ll - logsumexp(ll), atol=1e-9)
    gray = tr.model.prepare(frames[2])
    for i in (0, 17, 39):
        di = tr.model.likelihood_distances(gray, rec.particle_poses[i], rec.templates[i])
        np.testing.assert_allclose(di, d_eff[i : i + 1], rtol=1e-9)


def test_quadrants_off_is_the_papers_likelihood(synth):
    seq, frames = synth
    tr = ManifoldTracker(ManifoldConfig(n_particles=30).replace(**PAPER_LIKELIHOOD), rng=3)
    tr.init(frames[0], seq.init_box)
    tr.update(frames[1])
    rec = tr.last_record
    assert tr.model.quadrant_reference is None and rec.likelihood.quadrant_distances is None
    np.testing.assert_array_equal(rec.likelihood.distances, rec.distances)
    np.testing.assert_allclose(
        tr.model.likelihood_distances(tr.model.prepare(frames[1]), rec.particle_poses[:3], rec.templates[0]),
        spd.distance_riemann(spd.expm(rec.templates[0]), rec.descriptors[:3]),
        rtol=1e-9,
    )


def test_manifold_paper_is_the_tracker_without_quadrants(synth):
    from covviz.trackers import STOCHASTIC, make_tracker

    seq, frames = synth
    tr = make_tracker("manifold-paper", rng=5, n_particles=30)
    assert tr.name == "manifold-paper" and "manifold-paper" in STOCHASTIC
    assert tr.config == ManifoldConfig(n_particles=30).replace(**PAPER_LIKELIHOOD) and not tr.config.observation.quadrants
    ref = ManifoldTracker(ManifoldConfig(n_particles=30).replace(**PAPER_LIKELIHOOD), rng=5)
    for t in (tr, ref):
        t.init(frames[0], seq.init_box)
    for f in frames[1:4]:
        np.testing.assert_array_equal(tr.update(f), ref.update(f))
    assert tr.last_record.tracker == "manifold-paper"


def test_config_round_trips_through_json():
    import json

    from covviz.model.dynamics import KinematicModel

    cfg = ManifoldConfig(
        n_particles=123,
        kinematics=KinematicModel(pos_sigma=(0.05, 0.3)),
        template_sigma_matrix=tuple(tuple(0.01 for _ in range(9)) for _ in range(9)),
    ).replace(quadrants=False)
    d = json.loads(json.dumps(cfg.as_dict()))
    assert ManifoldConfig.from_dict(d) == cfg
    assert ManifoldConfig.from_dict({}) == ManifoldConfig()
    assert ManifoldConfig.from_dict({"likelihood_sigma": 0.7}).observation.likelihood_sigma == 0.7
    with pytest.raises(ValueError, match="unknown ManifoldConfig field.*likelihood_sgima"):
        ManifoldConfig.from_dict({"likelihood_sgima": 0.7})
    with pytest.raises(ValueError, match="unknown KinematicModel field"):
        ManifoldConfig.from_dict({"kinematics": {"pos_sigmaa": [0.1, 0.2]}})
    with pytest.raises(ValueError, match="likelihood_sigma must be a number > 0"):
        ManifoldConfig.from_dict({"likelihood_sigma": -1})
