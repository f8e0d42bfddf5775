"""Counterfactual replays (:mod:`covviz.diagnosis.counterfactual`): every verdict an experiment.

Unit tests of the pieces (the oracle interventions, scoring, the verdict's order, the self-check of
the unchanged replay), then the synthetic scenarios with the defaults (3 frames before the drift,
20 after the loss, 10% of the particles) and nothing tuned per scenario: seed 0 here, seeds 1-2 slow.
"""

from __future__ import annotations

import numpy as np
import pytest

from covviz.data.scenarios import SCENARIOS, open_scenario
from covviz.diagnosis.counterfactual import (
    FIXES,
    INTERVENTIONS,
    CounterfactualConfig,
    Counterfactuals,
    Outcome,
    TruthIntervention,
    _outcome,
    replay_loss,
    verdict_of,
)
from covviz.diagnosis.drift import Diagnoser
from covviz.runner import Observer, Pipeline, run
from covviz.trackers import make_tracker, tracker_rng
from covviz.trackers.manifold import make

CFG = CounterfactualConfig()


def test_the_verdict_is_the_smallest_fix_that_keeps_the_track():
    def o(kept):
        return Outcome(kept, 0.5, 0, np.zeros((0, 4)))

    assert FIXES == ("estimate", "search", "model", "search+model")
    assert verdict_of({"none": o(False), "estimate": o(False), "search": o(True), "model": o(True),
                       "search+model": o(True)}) == ("search", ("search", "model", "search+model"))
    assert verdict_of({"none": o(False), "estimate": o(True), "search+model": o(True)})[0] == "estimate"
    assert verdict_of({k: o(False) for k in INTERVENTIONS}) == ("none helps", ())
    assert verdict_of({"restart": o(True)}) == ("restart", ("restart",))


def test_outcome_scores_the_loss_frame_and_the_frames_after_it():
    truth = np.tile([10.0, 10, 20, 20], (10, 1))
    good, bad = truth.copy(), truth + [30, 30, 0, 0]  # bad: no overlap at all
    # frames 3..9 replayed (0-based 3..), loss at index 5
    kept = _outcome(good[3:], truth, 3, 5, CFG)
    assert kept.kept and kept.mean_iou == pytest.approx(1.0) and kept.frames_kept == 5  # indices 5..9
    lost_at_loss = np.concatenate([good[3:5], bad[5:6], good[6:]])
    o = _outcome(lost_at_loss, truth, 3, 5, CFG)
    assert not o.kept and o.frames_kept == 4  # kept needs the loss frame itself on track
    drifted_after = np.concatenate([good[3:6], bad[6:]])
    o = _outcome(drifted_after, truth, 3, 5, CFG)
    assert not o.kept and o.frames_kept == 1 and o.mean_iou == pytest.approx(3 / 7)


def test_truth_intervention_moves_a_fraction_with_its_own_generator():
    truth = np.tile([50.0, 40, 20, 30], (20, 1))
    truth[10] = [60, 40, 20, 30]
    a = TruthIntervention("search", truth, 5, 0.1, [0, 7, 1])
    b = TruthIntervention("search", truth, 5, 0.1, [0, 7, 1])
    assert a.to_truth(4, 600) is None  # before the first frame it acts on
    idx, box, vel = a.to_truth(10, 600)
    assert len(idx) == 60 and len(np.unique(idx)) == 60 and np.array_equal(idx, b.to_truth(10, 600)[0])
    np.testing.assert_array_equal(box, truth[10]) and np.testing.assert_allclose(vel, [10, 0])
    assert a.appearance(10) is None and a.estimate(10, truth[:3]) is None  # search only
    m = TruthIntervention("model", truth, 5, 0.1, 0)
    np.testing.assert_array_equal(m.appearance(12), truth[12]) and m.to_truth(12, 10) is None
    e = TruthIntervention("estimate", truth, 5, 0.1, 0)
    cands = np.array([[0.0, 0, 10, 10], [55, 40, 20, 30], [60, 41, 20, 30]])
    assert e.estimate(10, cands) == 2  # the candidate with the highest IoU against the truth
    with pytest.raises(ValueError, match="unknown intervention"):
        TruthIntervention("magic", truth, 0, 0.1, 0)


class _Start(Observer):
    """Keeps the RunStart (and so the runner's checkpoint rings)."""

    def on_start(self, start, found):
        self.start = start


def test_the_unchanged_replay_checks_itself():
    """``identical`` is computed, never set: a run whose boxes differ in one bit of one box is seen to differ."""
    sc = SCENARIOS["fast-motion"]
    seq = open_scenario("fast-motion")
    keep, replays = _Start(), None
    with make(rng=tracker_rng(0)) as tracker:
        replays = Counterfactuals([tracker], [None])
        res = run(tracker, seq, [keep, Pipeline([Diagnoser(), replays])], seed=0, checkpoints=CFG.checkpoints,
                  max_frames=sc.onset + sc.window + CFG.horizon)
        (rp,) = replays.replays[0].values()
        assert rp.outcomes["none"].identical is True
        ring = keep.start.checkpoints[0]
        tampered = res.boxes.copy()
        tampered[rp.end - 1, 0] = np.nextafter(tampered[rp.end - 1, 0], np.inf)  # one box, one bit
        again = replay_loss(tracker, ring, seq, res.boxes, seq.groundtruth, rp.lost_at, rp.drift_began, 0, CFG,
                            interventions=("none",))
        bad = replay_loss(tracker, ring, seq, tampered, seq.groundtruth, rp.lost_at, rp.drift_began, 0, CFG,
                          interventions=("none",))
    assert again.outcomes["none"].identical is True and bad.outcomes["none"].identical is False
    assert "did NOT reproduce" in bad.line()
    # the replay starts 3 frames before the drift began, from a checkpoint at or before it
    assert rp.start == max(2, rp.drift_began - CFG.before) and rp.checkpoint <= rp.start - 1
    assert rp.frames_after_loss == min(CFG.horizon, len(res.boxes) - rp.lost_at)


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_scenario_verdicts_seed_0(name):
    check_scenario(name, 0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("name", list(SCENARIOS))
def test_scenario_verdicts_more_seeds(name, seed):
    check_scenario(name, seed)


#: What the replays must find, with the defaults: fast motion is a search failure; an occlusion and a
#: change of appearance are the model's (the ceiling, search+model, is stated when that is what it takes).
EXPECTED = {"fast-motion": {"search"}, "occlusion": {"model", "search+model"},
            "appearance": {"model", "search+model"}}


def check_scenario(name: str, seed: int) -> None:
    sc = SCENARIOS[name]
    seq = open_scenario(name)
    tracker = make_tracker("manifold", seed=seed)
    replays = Counterfactuals([tracker], [None])
    with tracker:
        run(tracker, seq, [Pipeline([Diagnoser(), replays])], seed=seed,
            max_frames=min(len(seq), sc.onset + sc.window + CFG.horizon + 1), checkpoints=CFG.checkpoints)
    found = replays.replays[0]
    assert found, f"{name} seed {seed}: no loss replayed"
    first = found[min(found)]
    for rp in found.values():
        assert rp.outcomes["none"].identical, f"{name} seed {seed}: the unchanged replay differs from the run"
        assert set(rp.outcomes) == set(INTERVENTIONS)
    if name in EXPECTED:
        assert first.verdict in EXPECTED[name], f"{name} seed {seed}: {first.line()}"
    else:  # a look-alike, a shadow, a size change: the replays say what they found; nothing is expected
        assert first.verdict in (*FIXES, "none helps")
