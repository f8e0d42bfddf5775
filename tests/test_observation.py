"""Tests of the frozen observation model (covviz/model/observation.py) and its use by the manifold tracker."""

from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from covviz.data.sequences import SyntheticSequence
from covviz.model import spd
from covviz.model.descriptor import quadrant_covariances
from covviz.model.features import normalize_gradients, patch_features, warp_patches
from covviz.model.observation import (
    OBSERVE_CHUNK,
    ObservationConfig,
    ObservationModel,
    box_to_pose,
    quadrant_term,
)
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker


@pytest.fixture(scope="module")
def seq():
    return SyntheticSequence()


@pytest.fixture(scope="module")
def model(seq):
    return ObservationModel.build(seq.frame(0).image, seq.init_box, (ManifoldConfig()).observation)


def poses_around(box, n, rng, spread=0.3):
    x, y, w, h = box
    c = np.array([x + w / 2, y + h / 2])
    size = np.sqrt(w * h)
    return np.column_stack(
        [
            c[0] + spread * size * rng.standard_normal(n),
            c[1] + spread * size * rng.standard_normal(n),
            np.exp(0.1 * rng.standard_normal(n)),
            0.1 * rng.standard_normal(n),
        ]
    )


# --------------------------------------------------------------------------- #
# building the model
# --------------------------------------------------------------------------- #
def test_build_fixes_size_and_quadrant_references(seq, model):
    x, y, w, h = seq.init_box
    assert model.base_wh == (w, h) and model.base_size == pytest.approx(np.sqrt(w * h))
    assert model.step == 1 and model.step_xy == (1.0, 1.0)
    # The references are the quadrants observed at the initial box, by the plain pipeline.
    gray = model.prepare(seq.frame(0).image)
    P = warp_patches(gray, [[x + w / 2, y + h / 2, 1.0, 0.0]], (w, h), 32, 1, 1.0)
    _, Q = quadrant_covariances(normalize_gradients(patch_features(P, gain_normalize=True, quadrants=True)), 1e-3)
    numpy_model = ObservationModel.build(seq.frame(0).image, seq.init_box, (ManifoldConfig().replace(jit=False)).observation)
    np.testing.assert_array_equal(numpy_model.quadrant_reference, Q[0])  # the numpy path, bit for bit
    # The compiled kernels (when there) observe the same, up to the numpy path's float32 moments.
    np.testing.assert_allclose(model.quadrant_reference, Q[0], rtol=1e-4, atol=1e-9)
    np.testing.assert_allclose(model.quadrant_logdet, np.linalg.slogdet(model.quadrant_reference)[1], rtol=1e-12)
    assert model.quadrants and "quadrant term" in model.describe()


def test_model_is_frozen_and_its_arrays_read_only(model):
    with pytest.raises(dataclasses.FrozenInstanceError):
        model.eps = 1.0
    with pytest.raises(ValueError, match="read-only"):
        model.quadrant_reference[0, 0, 0] = 1.0


def test_large_target_downsamples_with_exact_factors(seq):
    frame = seq.frame(0).image  # 320 x 240
    m = ObservationModel.build(frame, [60, 40, 150, 140])
    assert m.step == 2  # 140 / 32 = 4.4 pixels per sample -> step floor(4.4 / 2)
    g = m.prepare(frame)
    assert g.shape == (120, 160)
    assert m.step_xy == (320 / 160, 240 / 120)
    assert "downsampled" in m.describe()
    # No anti-aliasing when asked: the full-resolution frame.
    assert ObservationModel.build(frame, [60, 40, 150, 140], ObservationConfig(antialias=False)).prepare(frame).shape == (240, 320)


def test_build_refuses_a_bad_box_and_an_odd_patch_for_quadrants(seq):
    from covviz.errors import InputError

    with pytest.raises(InputError, match="outside"):
        ObservationModel.build(seq.frame(0).image, [1000, 1000, 10, 10])
    with pytest.raises(ValueError, match="even patch_size"):
        ObservationModel.build(seq.frame(0).image, seq.init_box, ObservationConfig(patch_size=31))


def test_paper_likelihood_has_no_quadrants(seq):
    m = ObservationModel.build(seq.frame(0).image, seq.init_box, (ManifoldConfig().replace(quadrants=False)).observation)
    assert not m.quadrants and m.quadrant_reference is None and m.quadrant_logdet is None
    gray = m.prepare(seq.frame(1).image)
    rng = np.random.default_rng(1)
    poses = poses_around(seq.init_box, 20, rng)
    L = spd.logm(m.descriptors(gray, poses[:1]))[0]
    ob = m.observe(gray, poses, L)
    assert ob.quadrants is None and ob.quadrant_distances is None
    np.testing.assert_array_equal(ob.likelihood_distances, ob.distances)


# --------------------------------------------------------------------------- #
# observing
# --------------------------------------------------------------------------- #
def test_distances_are_the_papers_and_the_quadrant_term(seq, model, rng):
    gray = model.prepare(seq.frame(3).image)
    poses = poses_around(seq.init_box, 40, rng)
    L = spd.logm(model.descriptors(gray, poses[:1]))[0] + 0.01 * spd.sym(rng.standard_normal((9, 9)))
    ob = model.observe(gray, poses, L)
    # Independent route for d: expm of the template, then the generalized eigenvalues.
    np.testing.assert_allclose(ob.distances, spd.distance_riemann(spd.expm(L), ob.descriptors), rtol=1e-9)
    q_ref = np.sqrt(8 * spd.jbld(model.quadrant_reference[None], ob.quadrants))
    np.testing.assert_allclose(ob.quadrant_distances, q_ref, rtol=1e-10)
    q2 = np.sort(ob.quadrant_distances**2, axis=1)[:, :3].mean(axis=1)  # the three smallest
    np.testing.assert_allclose(ob.likelihood_distances, np.sqrt(ob.distances**2 + q2), rtol=1e-12)
    np.testing.assert_allclose(model.log_likelihood(ob.likelihood_distances), -(ob.likelihood_distances**2) / 0.5,
                               rtol=1e-12)
    # The template observed at the initial box is at distance 0 there (frame 0).
    g0 = model.prepare(seq.frame(0).image)
    x, y, w, h = seq.init_box
    at_box = np.array([[x + w / 2, y + h / 2, 1.0, 0.0]])
    L0 = spd.logm(model.descriptors(g0, at_box))[0]
    ob0 = model.observe(g0, at_box, L0)
    assert ob0.distances[0] < 1e-6 and ob0.likelihood_distances[0] < 1e-6


def test_chunks_and_threads_never_change_a_bit(seq, model, rng):
    gray = model.prepare(seq.frame(5).image)
    n = 2 * OBSERVE_CHUNK + 37
    poses = poses_around(seq.init_box, n, rng)
    L = np.broadcast_to(spd.logm(model.descriptors(gray, poses[:1]))[0], (n, 9, 9)) + 0.01 * spd.sym(
        rng.standard_normal((n, 9, 9))
    )
    serial = model.observe(gray, poses, L)
    with ThreadPoolExecutor(2) as ex:
        threaded = model.observe(gray, poses, L, executor=ex, threads=2)
    by_chunk = [model.observe(gray, poses[i : i + OBSERVE_CHUNK], L[i : i + OBSERVE_CHUNK]) for i in
                range(0, n, OBSERVE_CHUNK)]
    for field in ("descriptors", "quadrants", "distances", "quadrant_distances", "likelihood_distances"):
        a = getattr(serial, field)
        np.testing.assert_array_equal(a, getattr(threaded, field), err_msg=field)
        np.testing.assert_array_equal(a, np.concatenate([getattr(c, field) for c in by_chunk]), err_msg=field)


def test_timings_and_empty_batches(seq, model, rng):
    gray = model.prepare(seq.frame(2).image)
    tm: dict = {}
    poses = poses_around(seq.init_box, 10, rng)
    model.observe(gray, poses, np.zeros((9, 9)), timings=tm)
    assert set(tm) == {"warp", "features", "covariance", "distances"} and all(v >= 0 for v in tm.values())
    ob = model.observe(gray, np.zeros((0, 4)), np.zeros((9, 9)))
    assert ob.descriptors.shape == (0, 9, 9) and ob.likelihood_distances.shape == (0,)
    with pytest.raises(ValueError, match="templates must have shape"):
        model.observe(gray, poses, np.zeros((3, 9, 9)))


def test_quadrant_term_drops_the_largest():
    q = np.array([[1.0, 2.0, 3.0, 10.0], [0.0, 0.0, 0.0, 0.0], [2.0, 2.0, 2.0, 2.0]])
    np.testing.assert_allclose(quadrant_term(q), [(1 + 4 + 9) / 3, 0.0, 4.0])


def test_box_to_pose():
    np.testing.assert_allclose(box_to_pose([10, 20, 40, 10], (20, 20)), [30, 25, 1.0, 0.0])
    np.testing.assert_allclose(box_to_pose([0, 0, 20, 20], (10, 10)), [10, 10, 2.0, 0.0])


# --------------------------------------------------------------------------- #
# the tracker is a shell over the model
# --------------------------------------------------------------------------- #
def test_the_tracker_exposes_the_model_it_weighs_with(seq):
    frames = [seq.frame(i).image for i in range(3)]
    with ManifoldTracker(ManifoldConfig(n_particles=60), rng=2) as tr:
        tr.init(frames[0], seq.init_box)
        m = tr.observation_model
        assert m is tr.model
        ref = ObservationModel.build(frames[0], seq.init_box, tr.config.observation)
        assert dataclasses.asdict(m).keys() == dataclasses.asdict(ref).keys()
        for k, v in dataclasses.asdict(ref).items():
            np.testing.assert_array_equal(getattr(m, k), v, err_msg=k)
        tr.update(frames[1])
        rec = tr.last_record
        # What the model says at the particles' poses is what the tracker weighed them by.
        cmap = m.colour_map(frames[1], rec.inputs.colour_state)
        ob = m.observe(m.prepare(frames[1]), rec.particle_poses, rec.templates, colour=cmap)
        np.testing.assert_array_equal(ob.descriptors, rec.descriptors)
        np.testing.assert_array_equal(ob.likelihood_distances, rec.likelihood.distances)


def test_close_shuts_the_threads_and_refuses_more_work(seq):
    tr = ManifoldTracker(ManifoldConfig(n_particles=20, threads=2), rng=0)
    pool = tr._pool
    assert pool is not None
    tr.init(seq.frame(0).image, seq.init_box)
    tr.update(seq.frame(1).image)
    tr.close()
    assert pool._shutdown
    with pytest.raises(RuntimeError, match="closed"):
        tr.update(seq.frame(2).image)
    with ManifoldTracker(ManifoldConfig(n_particles=20, threads=1), rng=0) as one:
        assert one._pool is None
        one.init(seq.frame(0).image, seq.init_box)
    with pytest.raises(RuntimeError, match="closed"):
        one.init(seq.frame(0).image, seq.init_box)
