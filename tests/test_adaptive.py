"""Adaptive diffusion and re-detection (covviz.model.adaptive): the equations, and the tracker's use of them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from covviz.config import ConfigError
from covviz.data.scenarios import open_scenario
from covviz.data.sequences import SyntheticSequence
from covviz.model.adaptive import AdaptiveDiffusion, AdaptState, adapted_kinematics, evidence, redetect
from covviz.model.dynamics import KinematicModel
from covviz.trackers.manifold import PAPER_LIKELIHOOD, ManifoldConfig, ManifoldTracker

CFG = AdaptiveDiffusion()
POSE = np.array([50.0, 40.0, 1.0, 0.0])
L = np.eye(9) * 0.1


def _fill(values, cfg=CFG):
    st = AdaptState.start(POSE, L)
    for v in values:
        st = evidence(st, v, POSE, L, cfg)
    return st


def test_evidence_is_the_robust_z_score_of_the_best_distance():
    rng = np.random.default_rng(0)
    calm = 4.0 + 0.05 * rng.standard_normal(40)
    st = _fill(calm)
    win = np.array(st.window)
    m = np.median(win)
    s = 1.4826 * np.median(np.abs(win - m)) + 1e-3 * m
    best = m + 6.0 * s
    after = evidence(st, best, POSE + 1, L + 1, CFG)
    assert after.z == pytest.approx(6.0, rel=1e-9)
    assert after.evidence == pytest.approx((6.0 - CFG.z_lo) / (CFG.z_hi - CFG.z_lo))
    # a frame with evidence keeps the last confident pose and template, and counts the frames lost
    assert after.lost == 1 and np.array_equal(after.good_pose, st.good_pose)
    assert np.array_equal(after.good_template, L)


def test_calm_tracking_gives_no_evidence_and_warmup_holds_it_at_zero():
    rng = np.random.default_rng(1)
    st = _fill(4.0 + 0.05 * rng.standard_normal(60))
    assert st.evidence == 0.0 and st.lost == 0
    # during the warm-up even a far outlier gives none
    early = _fill([4.0, 4.01, 3.99, 4.02, 50.0])
    assert early.frames < CFG.warmup and early.evidence == 0.0


def test_an_outlier_enters_the_window_clipped_and_a_lasting_change_becomes_the_norm():
    rng = np.random.default_rng(2)
    st = _fill(4.0 + 0.05 * rng.standard_normal(40))
    st = evidence(st, 100.0, POSE, L, CFG)
    assert st.evidence == 1.0 and max(st.window) < 5.0  # clipped at the edge of the usual range
    for _ in range(CFG.window):
        st = evidence(st, 6.0 + 0.05 * rng.standard_normal(), POSE, L, CFG)
    assert st.evidence == 0.0  # the new level is the norm now


def test_kinematics_widen_with_evidence_and_are_untouched_without():
    km = KinematicModel()
    assert adapted_kinematics(km, 0.0, CFG) is km
    full = adapted_kinematics(km, 1.0, CFG)
    assert full.mode_probs == pytest.approx((1 - CFG.jump_prob, CFG.jump_prob))
    assert full.pos_sigma == pytest.approx((km.pos_sigma[0], km.pos_sigma[1] * CFG.jump_spread))
    assert full.vel_sigma == pytest.approx((km.vel_sigma[0], km.vel_sigma[1] * CFG.jump_spread))
    half = adapted_kinematics(km, 0.5, CFG)
    assert km.mode_probs[1] < half.mode_probs[1] < full.mode_probs[1]


def _lost_state(e: float, lost: int = 3) -> AdaptState:
    return dataclasses.replace(AdaptState.start(POSE, L), evidence=e, lost=lost)


def test_redetection_draws_a_share_around_the_last_good_pose_with_its_template():
    n = 500
    states = np.tile([10.0, 10.0, 1.0, 1.0, 1.0, 0.2], (n, 1))
    templates = np.zeros((n, 9, 9))
    modes = np.zeros(n, dtype=np.int8)
    st = _lost_state(1.0, lost=3)
    s2, t2, m2 = redetect(states, templates, modes, st, CFG, 20.0, KinematicModel(), np.random.default_rng(0))
    drawn = m2 == 3
    assert drawn.sum() == round(CFG.redetect_fraction * n)
    r = np.hypot(s2[drawn, 0] - POSE[0], s2[drawn, 1] - POSE[1])
    assert r.max() <= CFG.redetect_radius * 20.0 * np.sqrt(1 + 3) + 1e-9
    assert np.all(s2[drawn, 2:4] == 0.0) and np.all(s2[drawn, 5] == POSE[3])
    assert np.array_equal(t2[drawn], np.broadcast_to(L, t2[drawn].shape))
    assert np.array_equal(s2[~drawn], states[~drawn]) and not np.any(t2[~drawn])
    assert np.all(states[:, 0] == 10.0)  # inputs untouched


def test_no_redetection_and_no_random_draw_below_its_evidence():
    n = 50
    states, templates, modes = np.zeros((n, 6)), np.zeros((n, 9, 9)), np.zeros(n, dtype=np.int8)
    rng = np.random.default_rng(0)
    before = rng.bit_generator.state
    out = redetect(states, templates, modes, _lost_state(0.4), CFG, 20.0, KinematicModel(), rng)
    assert out[0] is states and out[1] is templates and out[2] is modes
    assert rng.bit_generator.state == before


@pytest.mark.parametrize("kwargs, match", [
    ({"z_lo": 5.0, "z_hi": 4.0}, "z_lo < z_hi"),
    ({"jump_prob": 1.5}, "jump_prob"),
    ({"jump_spread": 0.5}, "jump_spread"),
    ({"window": 1}, "window"),
])
def test_config_is_validated(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        AdaptiveDiffusion(**kwargs)


def test_config_round_trips_through_json_and_is_off_in_the_paper_variant():
    cfg = ManifoldConfig()
    assert cfg.adaptive.enabled
    assert ManifoldConfig.from_dict(cfg.as_dict()) == cfg
    assert not cfg.replace(**PAPER_LIKELIHOOD).adaptive.enabled
    with pytest.raises(ConfigError, match="AdaptiveDiffusion.enabled"):
        ManifoldConfig.from_dict({"adaptive": {"enabled": "yes"}})


def _run(config, seq, n, seed=0):
    boxes = []
    with ManifoldTracker(config, rng=seed) as tr:
        tr.init(seq.frame(0).image, seq.init_box)
        for i in range(1, n):
            boxes.append(tr.update(seq.frame(i).image))
        return np.array(boxes), tr


def test_while_the_evidence_stays_zero_the_boxes_are_those_of_the_constant_noise():
    """No evidence, no change: the adaptive filter draws exactly what the paper's constant noise draws."""
    seq = SyntheticSequence()
    on = ManifoldConfig(n_particles=80)
    off = on.replace(adaptive=AdaptiveDiffusion(enabled=False))
    n = 25
    b_off, _ = _run(off, seq, n)
    boxes, evid = [], []
    with ManifoldTracker(on, rng=0) as tr:
        tr.init(seq.frame(0).image, seq.init_box)
        for i in range(1, n):
            boxes.append(tr.update(seq.frame(i).image))
            evid.append(tr.adapt.evidence)
    assert max(evid) == 0.0
    assert np.array_equal(np.array(boxes), b_off)


def test_fast_motion_raises_the_evidence_and_redetection_particles_appear():
    seq = open_scenario("fast-motion")
    truth = seq.scenario_truth
    cfg = ManifoldConfig(n_particles=200)
    seen = []
    with ManifoldTracker(cfg, rng=0) as tr:
        tr.init(seq.frame(0).image, seq.init_box)
        for i in range(1, len(seq)):
            tr.update(seq.frame(i).image)
            seen.append((tr.adapt.evidence, int(np.sum(tr.last_record.modes == 3))))
    assert truth is not None
    ev = np.array([e for e, _ in seen])
    assert ev.max() > 0.5, "the leap should leave no particle explaining the frame"
    assert any(k > 0 for _, k in seen)


# --------------------------------------------------------------------------- #
# the observation pull
# --------------------------------------------------------------------------- #
def _sym(rng, n, scale=0.1):
    A = rng.normal(scale=scale, size=(n, 9, 9))
    return (A + A.transpose(0, 2, 1)) / 2


def test_observation_pull_steps_every_template_along_the_log_euclidean_geodesic():
    from covviz.model.adaptive import PullState, observation_pull

    rng = np.random.default_rng(0)
    L, obs, init = _sym(rng, 40), _sym(rng, 1)[0], _sym(rng, 1)[0]
    out, st = observation_pull(L, obs, init, PullState(), 0.25, 2.0, 30)
    np.testing.assert_allclose(out, 0.75 * L + 0.25 * obs, rtol=1e-12, atol=1e-15)
    # each stays on the segment from its template to the observation, a quarter of the way
    np.testing.assert_allclose(np.linalg.norm(out - L, axis=(1, 2)), 0.25 * np.linalg.norm(obs - L, axis=(1, 2)))
    assert st.window == (pytest.approx(float(np.linalg.norm(obs - init))),)


def test_observation_pull_gate_holds_a_sudden_change_and_the_window_keeps_its_length():
    from covviz.model.adaptive import PULL_WARMUP, PullState, observation_pull

    rng = np.random.default_rng(1)
    L, init = _sym(rng, 5), np.zeros((9, 9))
    st = PullState()
    for _ in range(PULL_WARMUP + 5):  # a steady look: always stepped
        obs = 0.2 * np.eye(9) + _sym(rng, 1, 0.01)[0]
        out, st = observation_pull(L, obs, init, st, 0.1, 2.0, 12)
        assert out is not None
    assert len(st.window) == 12
    jump = 0.2 * np.eye(9) + 0.5 * np.ones((9, 9))  # a shadow: far from the initial look all at once
    out, st2 = observation_pull(L, jump, init, st, 0.1, 2.0, 12)
    assert out is None and len(st2.window) == 12 and st2.window[-1] == pytest.approx(np.linalg.norm(jump))
    assert st.held == "" and st2.held == "look"  # what held it, for the frame's record
    out, _ = observation_pull(L, jump, init, st, 0.1, 0.0, 12)  # gate 0: no gate
    assert out is not None


def test_box_brightness_is_the_mean_grey_level_of_the_box_in_the_models_frame():
    from covviz.model.adaptive import box_brightness

    gray = np.arange(20 * 30, dtype=np.float32).reshape(20, 30)
    # corners truncated to whole pixels; the right and bottom edges' pixels included
    assert box_brightness(gray, (2.7, 3.2, 4.0, 5.0)) == pytest.approx(float(gray[3:9, 2:7].mean()))
    # a frame downsampled 2x: the box in its pixels
    assert box_brightness(gray, (4.0, 6.0, 8.0, 10.0), step=2) == pytest.approx(float(gray[3:9, 2:7].mean()))
    # clipped to the frame; nothing inside: NaN
    assert box_brightness(gray, (-5.0, -5.0, 8.0, 8.0)) == pytest.approx(float(gray[0:4, 0:4].mean()))
    assert np.isnan(box_brightness(gray, (40.0, 2.0, 5.0, 5.0)))
    assert np.isnan(box_brightness(gray, (np.nan, 2.0, 5.0, 5.0)))
    assert np.isnan(box_brightness(gray, (2.0, 2.0, np.inf, 5.0)))


def test_observation_pull_light_gate_holds_a_change_of_light_either_way_and_keeps_the_look_from_before():
    from covviz.model.adaptive import PULL_WARMUP, PullState, observation_pull

    rng = np.random.default_rng(2)
    L, init = _sym(rng, 5), np.zeros((9, 9))
    obs = 0.2 * np.eye(9)  # the descriptor does not move: the gain-normalised look of a shadowed target
    st = PullState()
    for k in range(PULL_WARMUP + 5):
        out, st = observation_pull(L, obs, init, st, 0.1, 2.0, 12, 0.5 + 0.01 * rng.standard_normal(), 2.5)
        assert out is not None
    assert len(st.light) == 12
    for level in (0.2, 0.9):  # darker, brighter
        out, st2 = observation_pull(L, obs, init, st, 0.1, 2.0, 12, level, 2.5)
        assert out is None and st2.held == "light"
        assert st2.light == st.light  # a held level does not become the norm ...
        assert len(st2.window) == 12 and st2.window[-1] == pytest.approx(np.linalg.norm(obs))
    st3 = st
    for _ in range(40):  # ... however long it lasts: the pull waits for the light to come back
        out, st3 = observation_pull(L, obs, init, st3, 0.1, 2.0, 12, 0.2, 2.5)
        assert out is None
    out, _ = observation_pull(L, obs, init, st3, 0.1, 2.0, 12, 0.5, 2.5)
    assert out is not None
    # no light gate, or no level: the pull without it, bit for bit, and the level is not remembered
    plain, sp = observation_pull(L, obs, init, st, 0.1, 2.0, 12)
    for args in ((0.2, 0.0), (float("nan"), 2.5)):
        out, s2 = observation_pull(L, obs, init, st, 0.1, 2.0, 12, *args)
        assert np.array_equal(out, plain) and s2.window == sp.window
    assert observation_pull(L, obs, init, st, 0.1, 2.0, 12, float("nan"), 2.5)[1].light == st.light


def test_observation_pull_on_by_default_off_in_the_paper_variant_and_replays_bit_for_bit():
    seq = SyntheticSequence()
    on = ManifoldConfig(n_particles=60)
    assert on.observation_pull == 0.05 and on.observation_pull_light_gate == 2.5
    assert on.replace(**PAPER_LIKELIHOOD).observation_pull == 0.0
    cfg = on.replace(observation_pull=0.0)
    assert ManifoldConfig.from_dict(on.as_dict()) == on
    b_off, tr_off = _run(cfg, seq, 12)
    assert tr_off.pull is None
    with ManifoldTracker(on, rng=0) as tr:
        tr.init(seq.frame(0).image, seq.init_box)
        for i in range(1, 6):
            tr.update(seq.frame(i).image)
        assert len(tr.pull.window) == 5  # a frame without evidence takes a step
        assert len(tr.pull.light) == 5  # and its box's grey level is remembered (the light gate is on)
        state = tr.snapshot()
        a = [tr.update(seq.frame(i).image) for i in range(6, 12)]
        tr.restore(state)
        b = [tr.update(seq.frame(i).image) for i in range(6, 12)]
    assert np.array_equal(np.array(a), np.array(b))
    assert not np.array_equal(np.array(a), b_off[5:])  # it does change the track
