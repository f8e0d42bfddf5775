"""Tests for :mod:`covviz.viz.diagnostics` (no rerun involved)."""

from __future__ import annotations

import numpy as np
import pytest

from covviz.data.sequences import SyntheticConfig, SyntheticSequence
from covviz.model.observation import box_to_pose
from covviz.model.spd import distance_riemann, expm, logm, spread_riemann
from covviz.records import FrameRecord
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
from covviz.viz.diagnostics import (
    background_poses,
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
# geometry helpers
# --------------------------------------------------------------------------- #
def test_top_k_orders_by_weight():
    w = np.array([0.1, 0.5, 0.05, 0.3, 0.05])
    np.testing.assert_array_equal(top_k(w, 3), [1, 3, 0])
    assert len(top_k(w, 10)) == 5 and len(top_k(w, 0)) == 0


def test_background_poses_stay_in_the_frame_and_keep_their_slots():
    poses, slots = background_poses(np.array([10.0, 10.0, 1.0, 0.0]), (20.0, 20.0), (100, 100), n=16)
    assert len(poses) < 16  # the corner drops the slots outside the frame
    assert np.all((poses[:, 0] >= 0) & (poses[:, 1] >= 0))
    full, all_slots = background_poses(np.array([50.0, 50.0, 1.0, 0.0]), (10.0, 10.0), (100, 100), n=16)
    np.testing.assert_array_equal(all_slots, np.arange(16))
    assert set(slots) <= set(all_slots)
    # Every region is at least ~one size away from the target centre.
    assert np.all(np.hypot(full[:, 0] - 50, full[:, 1] - 50) >= 10.0)


@pytest.mark.parametrize("d", [4, 9])  # 9: the compiled kernel's path; 4: numpy's
def test_template_spread_is_the_mean_distance_to_the_log_euclidean_mean(rng, d):
    import scipy.linalg

    A = rng.normal(scale=0.2, size=(30, d, d))
    L = A + A.transpose(0, 2, 1)
    spread, M = template_spread(L)
    M_ref = scipy.linalg.expm(L.mean(axis=0))
    np.testing.assert_allclose(M, M_ref, rtol=1e-10, atol=1e-12)
    # The distances from scipy's generalized eigenvalues, independently of covviz.model.
    ref = np.mean([np.sqrt(np.sum(np.log(scipy.linalg.eigh(scipy.linalg.expm(x), M_ref, eigvals_only=True)) ** 2))
                   for x in L])
    assert spread == pytest.approx(ref, rel=1e-10)
    # Identical templates: no spread.
    assert template_spread(np.repeat(L[:1], 5, axis=0))[0] == pytest.approx(0.0, abs=1e-7)


def test_template_spread_agrees_with_the_karcher_spread_on_a_tight_cloud(rng):
    # A tracker's cloud: small steps around one template (its spread ~0.1-0.4). There the
    # log-Euclidean mean is the Karcher mean to second order, and the spreads agree closely.
    A = rng.normal(scale=0.3, size=(9, 9))
    B = rng.normal(scale=0.02, size=(64, 9, 9))
    L = (A + A.T) / 2 + (B + B.transpose(0, 2, 1)) / 2
    spread, M = template_spread(L)
    karcher, K = spread_riemann(expm(L), tol=1e-12)
    assert 0.05 < karcher < 0.5
    assert spread == pytest.approx(karcher, rel=5e-3)
    # The Karcher mean is the one nearest the cloud in the squared sense.
    C = expm(L)
    assert np.mean(distance_riemann(M, C) ** 2) >= np.mean(distance_riemann(K, C) ** 2) * (1 - 1e-12)


def test_template_spread_subsamples_large_clouds(rng):
    A = rng.normal(scale=0.2, size=(400, 3, 3))
    L = A + A.transpose(0, 2, 1)
    full, _ = template_spread(L, max_templates=400)
    sub, _ = template_spread(L, max_templates=100)
    assert sub == pytest.approx(full, rel=0.1)


def test_template_spread_refuses_bad_shapes():
    with pytest.raises(ValueError, match="shape"):
        template_spread(np.zeros((0, 3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        template_spread(np.full((3, 9, 9), np.nan))


# --------------------------------------------------------------------------- #
# observation model, likelihood map, template cloud
# --------------------------------------------------------------------------- #
def test_likelihood_map_finds_the_target_off_centre(tracked):
    """Template = the descriptor observed at the true box; the grid is centred half a region away from it.

    The best grid cell must then be the cell on the true centre (where the distance is 0, by the
    model's own observation), not the grid's centre; the map's log-likelihood is -(d² - d²_min)/2σ²
    with the model's σ.
    """
    _, tr, _rec, frame = tracked
    model = tr.model
    prepared = model.prepare(frame.image)
    gt_pose = box_to_pose(frame.gt, model.base_wh)
    L = logm(model.descriptors(prepared, gt_pose[None]))[0]
    grid, reach = 11, 1.0
    cell = model.base_wh[0] * gt_pose[2] * 2 * reach / (grid - 1)
    centre = gt_pose.copy()
    centre[0] -= 2 * cell  # the true centre falls on a grid column two cells right of the middle
    lm = likelihood_map(model, prepared, centre, L, grid=grid, reach=reach)
    assert lm.distances.shape == lm.likelihood.shape == (grid, grid)
    np.testing.assert_allclose(lm.best, gt_pose[:2], atol=1e-9)
    at_truth = model.observe(prepared, gt_pose[None], L)
    assert at_truth.distances[0] < 1e-6  # the template part vanishes there; the quadrant term remains
    assert lm.distances.min() == pytest.approx(at_truth.likelihood_distances[0], rel=1e-9)
    assert lm.distances[grid // 2, grid // 2] > 0.5  # the grid's own centre is not where the target is
    d2 = lm.distances**2
    np.testing.assert_allclose(lm.log_likelihood, -(d2 - d2.min()) / (2 * model.likelihood_sigma**2), rtol=1e-12)


def test_likelihood_map_validates_arguments(tracked):
    _, tr, rec, frame = tracked
    with pytest.raises(ValueError, match="grid"):
        likelihood_map(tr.model, tr.model.prepare(frame.image), rec.pose, rec.estimate_template, grid=1)


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
