"""Tests of the likelihood's extra terms and online state (issue 14): colour fg/bg term, quadrant
reliabilities, the anchored template walk, two-stage particles and the pose search."""

from __future__ import annotations

import numpy as np
import pytest

from covviz.data.sequences import SyntheticSequence
from covviz.model import fgbg
from covviz.model.dynamics import template_walk
from covviz.model.observation import ObservationModel, QuadrantState, quadrant_term, update_quadrant_state
from covviz.model.particles import logsumexp
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker, _parabolic_step, make_paper

D = 9


@pytest.fixture(scope="module")
def synth():
    seq = SyntheticSequence()
    return seq, [seq.frame(i).image for i in range(8)]


def two_colour_frame(box, fg=(200, 30, 30), bg=(30, 30, 200), shape=(120, 160)):
    """A frame of one colour with a rectangle ``box`` of another (uint8 RGB)."""
    f = np.empty((*shape, 3), dtype=np.uint8)
    f[:] = bg
    x, y, w, h = box
    f[y : y + h, x : x + w] = fg
    return f


def scaled(box, r):
    x, y, w, h = box
    cx, cy = x + w / 2, y + h / 2
    return np.array([cx - r * w / 2, cy - r * h / 2, r * w, r * h])


# --------------------------------------------------------------------------- #
# the colour term
# --------------------------------------------------------------------------- #
def test_colour_bins_cover_their_range_and_detect_grey():
    rng = np.random.default_rng(0)
    f = rng.integers(0, 256, (20, 30, 3), dtype=np.uint8)
    b = fgbg.colour_bins(f, grey=False)
    assert b.shape == (20, 30) and b.min() >= 0 and b.max() < fgbg.COLOUR_BINS**3
    g = fgbg.colour_bins(f[..., 0], grey=True)
    assert g.min() >= 0 and g.max() < fgbg.GREY_BINS
    # float frames in [0, 1] bin like their uint8 counterparts
    np.testing.assert_array_equal(fgbg.colour_bins(f[..., 0] / 255.0, grey=True), g)
    assert fgbg._is_grey(np.repeat(f[..., :1], 3, axis=2)) and not fgbg._is_grey(f)


def test_box_sums_equal_brute_force_sums():
    rng = np.random.default_rng(1)
    V = rng.standard_normal((30, 40))
    integral = np.zeros((31, 41))
    integral[1:, 1:] = V.cumsum(0).cumsum(1)
    origin = (5, 7)  # the window's top-left in frame pixels
    boxes = np.array([[5, 7, 40, 30], [10, 12, 5, 3], [0, 0, 12, 14], [40, 30, 20, 20], [100, 100, 5, 5]], float)
    got = fgbg.box_sums(integral, origin, boxes)
    for b, s in zip(boxes, got):
        x0, y0 = int(max(b[0] - 5, 0)), int(max(b[1] - 7, 0))
        x1, y1 = int(min(b[0] + b[2] - 5, 40)), int(min(b[1] + b[3] - 7, 30))
        want = V[y0:y1, x0:x1].sum() if (x1 > x0 and y1 > y0) else 0.0
        assert s == pytest.approx(want, abs=1e-9)


def test_colour_term_is_zero_at_the_target_and_grows_off_it():
    box = (60, 40, 30, 24)
    frame = two_colour_frame(box)
    state = fgbg.init_colour_model(frame, box)
    assert 0.9 < state.contrast <= 1.0
    np.testing.assert_allclose([state.fg.sum(), state.bg.sum()], 1.0)
    cmap = fgbg.colour_map(frame, state)
    t = fgbg.colour_term(cmap, np.array([box, scaled(box, 1.4), scaled(box, 0.7), [box[0] + 12, *box[1:]]], float))
    assert np.all(t >= 0)
    assert t[0] == pytest.approx(0.0, abs=1e-9)
    assert t[1] > 0.1 and t[2] > 0.1 and t[3] > 0.1  # too large, too small, shifted


def test_colour_term_is_neutral_when_colour_cannot_tell():
    frame = np.full((100, 100, 3), 90, dtype=np.uint8)
    frame[:, :, 0] = 10
    state = fgbg.init_colour_model(frame, (40, 40, 20, 20))
    assert state.contrast == pytest.approx(0.0, abs=1e-9)
    cmap = fgbg.colour_map(frame, state)
    t = fgbg.colour_term(cmap, np.array([[40, 40, 20, 20], [30, 30, 40, 40], [10, 60, 10, 10]], float))
    np.testing.assert_allclose(t, 0.0, atol=1e-12)


def test_colour_update_blends_towards_the_new_box():
    box = (60, 40, 30, 24)
    frame = two_colour_frame(box)
    s0 = fgbg.init_colour_model(frame, box)
    other = two_colour_frame(box, fg=(30, 200, 30))
    same = fgbg.update_colour_model(s0, other, box, 0.0)
    np.testing.assert_array_equal(same.fg, s0.fg)
    full = fgbg.update_colour_model(s0, other, box, 1.0)
    np.testing.assert_allclose(full.fg, fgbg.init_colour_model(other, box).fg)
    half = fgbg.update_colour_model(s0, other, box, 0.5)
    np.testing.assert_allclose(half.fg, 0.5 * s0.fg + 0.5 * full.fg)
    with pytest.raises(ValueError):
        half.fg[0] = 1.0  # the state is read-only


# --------------------------------------------------------------------------- #
# the likelihood with its terms, through the tracker
# --------------------------------------------------------------------------- #
def run(cfg, synth, n_frames=4, rng=3):
    seq, frames = synth
    tr = ManifoldTracker(cfg, rng=rng)
    tr.init(frames[0], seq.init_box)
    boxes = [tr.update(f) for f in frames[1:n_frames]]
    return tr, np.array(boxes)


def test_d_eff_is_the_template_distance_plus_the_weighted_terms(synth):
    cfg = ManifoldConfig().replace(n_particles=40, colour_weight=4.0, quadrant_weight=0.7, threads=1)
    tr, _ = run(cfg, synth)
    rec = tr.last_record
    terms, w = rec.likelihood.terms, rec.likelihood.term_weights
    assert set(terms) == {"quadrants", "colour"} and w == {"quadrants": 0.7, "colour": 4.0}
    assert all(v.shape == (40,) and np.all(v >= 0) for v in terms.values())
    np.testing.assert_allclose(terms["quadrants"], quadrant_term(rec.likelihood.quadrant_distances), rtol=1e-12)
    d2 = rec.distances**2 + 0.7 * terms["quadrants"] + 4.0 * terms["colour"]
    np.testing.assert_allclose(rec.likelihood.distances ** 2, d2, rtol=1e-12)
    ll = -d2 / (2 * cfg.observation.likelihood_sigma**2)
    np.testing.assert_allclose(rec.log_weights, ll - logsumexp(ll), atol=1e-9)
    # The model, given the frame and the state the record carries, says the same at a particle.
    _seq, frames = synth
    cmap = tr.model.colour_map(frames[3], rec.inputs.colour_state)
    gray = tr.model.prepare(frames[3])
    for i in (0, 21):
        di = tr.model.likelihood_distances(gray, rec.particle_poses[i], rec.templates[i], colour=cmap)
        np.testing.assert_allclose(di, rec.likelihood.distances[i : i + 1], rtol=1e-9)


def test_new_terms_keep_boxes_independent_of_threads(synth):
    kw = {"n_particles": 320, "colour_weight": 3.0, "quadrant_reliability": 0.05, "quadrant_ref_rate": 0.02,
              "anchor_pull": 0.05, "anchor_rate": 0.02, "refine_fraction": 0.25, "scale_steps": 2, "rotation_steps": 1}
    _, b1 = run(ManifoldConfig(threads=1).replace(**kw), synth, 5)
    _, b2 = run(ManifoldConfig(threads=2).replace(**kw), synth, 5)
    np.testing.assert_array_equal(b1, b2)


def test_manifold_paper_has_none_of_the_new_terms(synth):
    tr = make_paper(n_particles=30, rng=1)
    c = tr.config
    assert not c.observation.quadrants and c.observation.colour_weight == 0
    assert c.quadrant_reliability == 0 and c.anchor_pull == 0
    assert c.refine_fraction == 0 and c.scale_steps == 0 and c.rotation_steps == 0
    seq, frames = synth
    tr.init(frames[0], seq.init_box)
    tr.update(frames[1])
    rec = tr.last_record
    assert rec.likelihood.terms == {} and rec.likelihood.term_weights == {}
    np.testing.assert_array_equal(rec.likelihood.distances, rec.distances)
    tr.close()


# --------------------------------------------------------------------------- #
# quadrant reliabilities
# --------------------------------------------------------------------------- #
def test_reliability_weighted_quadrant_term():
    q = np.array([[1.0, 2.0, 3.0, 4.0]])
    assert quadrant_term(q)[0] == pytest.approx((1 + 4 + 9) / 3)  # worst dropped
    assert quadrant_term(q, np.ones(4))[0] == pytest.approx(30 / 4)  # equal weights: the plain mean
    assert quadrant_term(q, np.array([1.0, 0, 0, 0]))[0] == pytest.approx(1.0)
    # the weights' scale does not matter
    assert quadrant_term(q, np.array([1, 2, 3, 4.0]))[0] == pytest.approx(quadrant_term(q, np.array([2, 4, 6, 8.0]))[0])


def test_quadrant_state_downweights_the_quadrant_that_keeps_changing():
    ref = np.broadcast_to(np.eye(D), (4, D, D)).copy()
    st = QuadrantState(ref, np.zeros(4), np.ones(4))
    for _ in range(200):
        st = update_quadrant_state(st, np.array([1.0, 1.0, 1.0, 3.0]), ref, rate=0.05)
    r = st.reliability
    assert r[3] < r[0] and r[0] == pytest.approx(r[1]) == pytest.approx(r[2])
    assert r[3] == pytest.approx(r[0] / 9, rel=0.05) or r[3] == pytest.approx(0.25)


def test_quadrant_references_step_only_when_the_match_is_good():
    ref = np.broadcast_to(np.eye(D), (4, D, D)).copy()
    st = QuadrantState(ref, np.zeros(4), np.ones(4))
    Q = np.broadcast_to(2.0 * np.eye(D), (4, D, D))
    new = update_quadrant_state(st, np.array([0.5, 0.5, 2.0, 2.0]), Q, rate=0.1, ref_rate=0.5, gate=1.0)
    # good quadrants: the log-Euclidean midpoint sqrt(2)·I; the others untouched
    np.testing.assert_allclose(new.reference[:2], np.sqrt(2) * np.broadcast_to(np.eye(D), (2, D, D)), rtol=1e-10)
    np.testing.assert_array_equal(new.reference[2:], ref[2:])
    np.testing.assert_allclose(new.logdet, np.linalg.slogdet(new.reference)[1], atol=1e-10)


# --------------------------------------------------------------------------- #
# anchored walk, two stages, pose search
# --------------------------------------------------------------------------- #
def test_anchored_walk_reverts_to_the_anchor(rng):
    L = np.broadcast_to(np.eye(D), (5, D, D)).copy()
    A = np.zeros((D, D))
    free = template_walk(L, np.zeros((D, D)), rng)
    np.testing.assert_array_equal(free, L)
    pulled = template_walk(L, np.zeros((D, D)), rng, anchor=A, pull=0.25)
    np.testing.assert_allclose(pulled, 0.75 * L)
    # Without a pull, the same random stream gives the same walk as the paper's.
    r1, r2 = np.random.default_rng(5), np.random.default_rng(5)
    np.testing.assert_array_equal(template_walk(L, np.full((D, D), 0.1), r1),
                                  template_walk(L, np.full((D, D), 0.1), r2, anchor=A, pull=0.0))


def test_anchor_state_follows_good_estimates(synth):
    cfg = ManifoldConfig(n_particles=40, anchor_pull=0.1, anchor_rate=0.5, anchor_gate=1e9, threads=1)
    tr, _ = run(cfg, synth)
    assert not np.allclose(tr.anchor.template, tr.initial_template)
    cfg = ManifoldConfig(n_particles=40, anchor_pull=0.1, anchor_rate=0.5, anchor_gate=0.0, threads=1)
    tr, _ = run(cfg, synth)
    np.testing.assert_array_equal(tr.anchor.template, tr.initial_template)  # never good: never moves


def test_second_stage_children_sit_near_the_best_particles(synth):
    cfg = ManifoldConfig(n_particles=200, refine_fraction=0.25, refine_top=5, threads=1)
    tr, _ = run(cfg, synth, 3)
    rec = tr.last_record
    modes = rec.modes
    assert (modes[-50:] == 2).all() and (modes[:150] != 2).all()
    assert len(rec.log_weights) == 200 and np.isfinite(rec.log_weights).all()
    # children are close to each other (a few parents, shrunken noise) compared with the first stage
    spread = lambda p: np.std(p[:, :2], axis=0).mean()
    assert spread(rec.particle_poses[-50:]) < spread(rec.particle_poses[:150])


def test_parabolic_step_finds_a_parabola_minimum():
    ks = np.arange(-3, 4)
    d = np.sqrt((ks - 0.3) ** 2 + 1.0)  # d² is a parabola with its minimum at +0.3
    assert _parabolic_step(d) == pytest.approx(0.3)
    assert _parabolic_step(np.sqrt(np.arange(7.0) + 1)) == -3  # at the edge: the edge


def test_pose_search_scores_what_the_likelihood_says(synth):
    seq, frames = synth
    model = ObservationModel.build(frames[0], seq.init_box, (ManifoldConfig()).observation)
    gray = model.prepare(frames[0])
    x, y, w, h = seq.init_box
    pose = np.array([x + w / 2, y + h / 2, 1.0, 0.0])
    from covviz.model.spd import logm

    L0 = logm(model.descriptors(gray, pose[None]))[0]
    sp, sd, _rp, rd = model.pose_search(gray, pose, L0, scales=[0.8, 1.0, 1.25], rotations=[-0.1, 0.0, 0.1])
    np.testing.assert_allclose(sp[:, 2], [0.8, 1.0, 1.25])
    np.testing.assert_allclose(sd, model.likelihood_distances(gray, sp, L0), rtol=1e-12)
    assert np.argmin(sd) == 1 and np.argmin(rd) == 1  # at the initial box, the initial template is best
    assert sd[1] == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"colour_weight": -1.0}, "colour_weight"),
        ({"colour_rate": 1.5}, "colour_rate"),
        ({"quadrant_reliability": -0.1}, "quadrant_reliability"),
        ({"anchor_pull": 2.0}, "anchor_pull"),
        ({"refine_fraction": 1.0}, "refine_fraction"),
        ({"refine_top": 0}, "refine_top"),
        ({"scale_step": 1.0}, "scale_step"),
        ({"scale_steps": -1}, "scale_steps"),
        ({"context_scale": 0.9}, "context_scale"),
        ({"context_weight": 1.0, "quadrants": False}, "quadrants"),
        ({"colour_weight": float("nan")}, "colour_weight"),
        ({"grad_floor": -0.1}, "grad_floor"),
        ({"grad_floor": float("inf")}, "grad_floor"),
    ],
)
def test_new_config_fields_are_validated(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ManifoldConfig.from_dict(kwargs)


# --------------------------------------------------------------------------- #
# derivative normalisation
# --------------------------------------------------------------------------- #
def test_normalized_gradients_have_unit_mean_in_both_layouts(rng):
    from covviz.model.features import normalize_gradients, patch_features

    P = rng.random((3, 18, 18), dtype=np.float32)
    for quadrants in (False, True):
        F = normalize_gradients(patch_features(P, gain_normalize=True, quadrants=quadrants))
        G = F if quadrants else F[:, None]
        np.testing.assert_allclose(G[:, :, 5].mean(axis=(1, 2)), 1.0, rtol=1e-5)
        np.testing.assert_allclose(G[:, :, 7:9].mean(axis=(1, 2, 3)), 1.0, rtol=1e-5)
    # contrast no longer moves the derivative block: P and 0.5 + 0.5·(P − mean) differ only in I
    from covviz.model.descriptor import covariance

    F1 = normalize_gradients(patch_features(P, gain_normalize=False))
    F2 = normalize_gradients(patch_features(0.5 * P + 0.25, gain_normalize=False))
    C1, C2 = covariance(F1, 1e-9), covariance(F2, 1e-9)
    np.testing.assert_allclose(C1[:, 3:, 3:], C2[:, 3:, 3:], rtol=2e-3, atol=1e-6)


def test_gradient_normalisation_kernel_matches_the_numpy_path(synth):
    seq, frames = synth
    mj = ObservationModel.build(frames[0], seq.init_box, (ManifoldConfig().replace(grad_normalize=1.0)).observation)
    mn = ObservationModel.build(frames[0], seq.init_box, (ManifoldConfig().replace(grad_normalize=1.0, jit=False)).observation)
    gray = mj.prepare(frames[2])
    x, y, w, h = seq.init_box
    poses = np.array([[x + w / 2, y + h / 2, s, t] for s, t in ((1.0, 0.0), (0.8, 0.1), (1.3, -0.2))])
    a, b = mj.observe(gray, poses), mn.observe(gray, poses)
    np.testing.assert_allclose(a.descriptors, b.descriptors, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(a.quadrants, b.quadrants, rtol=1e-4, atol=1e-6)
    plain = ObservationModel.build(frames[0], seq.init_box, (ManifoldConfig().replace(grad_normalize=0.0)).observation).observe(gray, poses)
    assert not np.allclose(plain.descriptors, a.descriptors)


@pytest.mark.parametrize("extra", [{}, {"quadrant_reliability": 0.05, "quadrant_ref_rate": 0.02}])
def test_frame_inputs_say_what_update_weighed_by(synth, extra):
    """The model, given a frame and its record's extras, gives every particle's d_eff exactly: what the
    recorder's likelihood map and slices and the diagnosis ask through it."""
    cfg = ManifoldConfig(n_particles=40, threads=1).replace(**extra)
    tr, _ = run(cfg, synth, n_frames=5)
    rec = tr.last_record
    _seq, frames = synth
    inputs = rec.inputs.likelihood_kwargs()
    assert set(inputs) == ({"colour", "quadrant_state"} if extra else {"colour"})
    gray = tr.model.prepare(frames[4])
    d = tr.model.likelihood_distances(gray, rec.particle_poses, rec.templates, **inputs)
    np.testing.assert_allclose(d, rec.likelihood.distances, rtol=1e-9)
    for i in (0, 17):
        one = tr.model.template_scores(gray, rec.particle_poses[i], rec.templates[i][None], **inputs)
        np.testing.assert_allclose(one, rec.likelihood.distances[i : i + 1], rtol=1e-9)
        # The parts of d_eff²: the template distance² and each weighted term, as update() weighed them.
        d_eff, parts = tr.model.template_scores(gray, rec.particle_poses[i], rec.templates[i][None], **inputs,
                                                parts=True)
        np.testing.assert_array_equal(d_eff, one)
        assert set(parts) == {"descriptor", *rec.likelihood.terms}
        np.testing.assert_allclose(sum(parts.values()), d_eff**2, rtol=1e-12)
        np.testing.assert_allclose(parts["descriptor"], rec.distances[i] ** 2, rtol=1e-9)
        for k, t in rec.likelihood.terms.items():
            np.testing.assert_allclose(parts[k], rec.likelihood.term_weights[k] * t[i], rtol=1e-9, atol=1e-12)
    # Several poses in one call (the diagnosis asks the truth and the estimate so): each row bit for bit
    # what its pose alone gives, parts too.
    L = rec.templates[:7]
    both, parts2 = tr.model.template_scores(gray, rec.particle_poses[[3, 11]], L, **inputs, parts=True)
    assert both.shape == (2, 7)
    for r, i in enumerate((3, 11)):
        alone, parts1 = tr.model.template_scores(gray, rec.particle_poses[i], L, **inputs, parts=True)
        np.testing.assert_array_equal(both[r], alone)
        assert set(parts2) == set(parts1)
        for k in parts1:
            np.testing.assert_array_equal(parts2[k][r], parts1[k])
    tr.close()


def test_frame_inputs_of_the_papers_likelihood_are_empty(synth):
    tr = make_paper(n_particles=20, rng=1)
    seq, frames = synth
    tr.init(frames[0], seq.init_box)
    tr.update(frames[1])
    rec = tr.last_record
    assert rec.inputs.likelihood_kwargs() == {} and rec.extras == {}
    np.testing.assert_array_equal(rec.inputs.gray, tr.model.prepare(frames[1]))  # the frame update() read
    tr.close()


def test_manifold_records_carry_nothing_in_extras(synth):
    """Everything the manifold trackers emit has a typed field: extras is only for what a baseline adds."""
    seq, frames = synth
    for make_one in (make_paper, lambda **kw: ManifoldTracker(ManifoldConfig(n_particles=kw["n_particles"]),
                                                            rng=kw["rng"])):
        tr = make_one(n_particles=20, rng=1)
        tr.init(frames[0], seq.init_box)
        assert tr.last_record.extras == {}
        for f in frames[1:4]:
            tr.update(f)
            rec = tr.last_record
            assert rec.extras == {}
            assert rec.likelihood is not None and rec.inputs is not None and rec.modes.shape == (20,)
        tr.close()


def test_gradient_floor_bounds_the_normaliser(rng):
    """``floor``: a patch whose mean ``|grad I|`` is below it has its first derivatives divided by the floor."""
    from covviz.model.features import normalize_gradients, patch_features

    P = rng.random((3, 18, 18), dtype=np.float32)
    F = patch_features(P, gain_normalize=True, quadrants=True)
    m1 = F[:, :, 5].astype(np.float64).mean(axis=(1, 2))
    np.testing.assert_array_equal(normalize_gradients(F, 1.0, 0.0), normalize_gradients(F))
    floor = 2.0 * m1.max()  # above every mean: the floor binds
    G, G0 = normalize_gradients(F, 1.0, floor), normalize_gradients(F)
    np.testing.assert_allclose(G[:, :, 3:6], F[:, :, 3:6] / np.float32(floor), rtol=1e-6)
    np.testing.assert_array_equal(G[:, :, [0, 1, 2, 6, 7, 8]], G0[:, :, [0, 1, 2, 6, 7, 8]])  # second derivatives too
    # below every mean: the floor changes nothing
    np.testing.assert_array_equal(normalize_gradients(F, 1.0, 0.5 * m1.min()), G0)


def test_gradient_floor_kernel_matches_the_numpy_path(synth):
    """With a floor that binds at some poses, the kernel and the numpy path agree (as without a floor)."""
    from covviz.model.features import patch_features, warp_patches

    seq, frames = synth
    x, y, w, h = seq.init_box
    poses = np.array([[x + w / 2, y + h / 2, s, t] for s, t in ((1.0, 0.0), (0.8, 0.1), (1.3, -0.2))])
    m0 = ObservationModel.build(frames[0], seq.init_box, (ManifoldConfig().replace(grad_normalize=0.0)).observation)
    gray = m0.prepare(frames[2])
    F = patch_features(warp_patches(gray, poses, m0.base_wh, 32, 1, m0._sample_step()), gain_normalize=True, quadrants=True)
    levels = F[:, :, 5].astype(np.float64).mean(axis=(1, 2))
    floor = float(np.median(levels))  # binds at some poses, not at others
    assert levels.min() < floor < levels.max() or np.ptp(levels) == 0
    cfg = {"grad_normalize": 1.0, "grad_floor": floor}
    mj = ObservationModel.build(frames[0], seq.init_box, (ManifoldConfig().replace(**cfg)).observation)
    mn = ObservationModel.build(frames[0], seq.init_box, (ManifoldConfig().replace(**cfg, jit=False)).observation)
    assert mj.grad_floor == floor and mj.compiled and not mn.compiled
    a, b = mj.observe(gray, poses), mn.observe(gray, poses)
    np.testing.assert_allclose(a.descriptors, b.descriptors, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(a.quadrants, b.quadrants, rtol=1e-4, atol=1e-6)
    unfloored = ObservationModel.build(frames[0], seq.init_box, (ManifoldConfig().replace(grad_floor=0.0)).observation).observe(
        gray, poses)
    assert not np.allclose(unfloored.descriptors, a.descriptors)


def test_zero_gradient_floor_is_the_normalisation_of_before(synth):
    """``grad_floor=0`` is the floor of 1e-6 of before: the same boxes as a tiny explicit floor."""
    _, b0 = run(ManifoldConfig().replace(n_particles=60, grad_floor=0.0), synth, 5)
    _, b1 = run(ManifoldConfig().replace(n_particles=60, grad_floor=1e-7), synth, 5)
    np.testing.assert_array_equal(b0, b1)
