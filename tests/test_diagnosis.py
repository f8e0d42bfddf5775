"""Tests of the drift diagnosis (covviz/diagnosis/drift.py): labels, rules, suspects, scoring.

The rules are checked on hand-made evidence (each rule alone, and the order in which they are
tried); the whole pipeline on the synthetic failure scenarios is tested in test_scenarios.py.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from covviz.data.sequences import SyntheticConfig, SyntheticSequence
from covviz.diagnosis.drift import (
    LABELS,
    Diagnoser,
    DiagnosisConfig,
    FrameEvidence,
    diagnose,
    score_suspects,
)
from covviz.model import spd
from covviz.runner import NOTHING, RunStart, run_many
from covviz.trackers.base import IdentityTracker, tracker_info
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker

CFG = DiagnosisConfig()


def look(rng, scale=0.02, base=None):
    """A target's descriptor and quadrants near ``base`` (identity by default)."""
    b = np.eye(9) if base is None else base
    C = spd.exp_map(b, spd.sym(rng.standard_normal((9, 9))) * scale)
    Q = np.stack([spd.exp_map(b, spd.sym(rng.standard_normal((9, 9))) * scale) for _ in range(4)])
    return C, Q


def calm_history(rng, n=20, **kw):
    """``n`` frames on track: IoU 0.85, the target's look steady."""
    out = []
    for f in range(1, n + 1):
        C, Q = look(rng)
        fields = {"frame": f, "iou": 0.85, "centre_error": 0.05, "scale_ratio": 1.0, "truth_motion": 0.02, "nearest": 0.01,
                      "reach": 0.95, "ess_frac": 0.3, "brightness": np.full(4, 0.5), "truth_C": C, "truth_Q": Q, "estimate_C": C,
                      "best_truth": 1.0, "best_est": 1.0, "label": "ok"}
        fields.update(kw)
        out.append(FrameEvidence(**fields))
    return out


def frame(f, rng, base=None, **kw):
    C, Q = look(rng, base=base)
    fields = {"frame": f, "iou": 0.05, "centre_error": 1.2, "scale_ratio": 1.0, "truth_motion": 0.02, "nearest": 0.01, "reach": 0.9,
                  "ess_frac": 0.3, "brightness": np.full(4, 0.5), "truth_C": C, "truth_Q": Q, "estimate_C": C, "best_truth": 3.0,
                  "best_est": 2.0, "label": "model"}
    fields.update(kw)
    return FrameEvidence(**fields)


# --------------------------------------------------------------------------- #
# the rules, one at a time
# --------------------------------------------------------------------------- #
def test_fast_motion_is_a_jump_beyond_the_particles(rng):
    h = calm_history(rng) + [frame(21, rng, truth_motion=1.4, nearest=1.1, label="search", best_truth=1.2)]
    d = diagnose(h, lost_at=21, drift_began=21, cfg=CFG)
    assert d.cause == "fast_motion" and d.evidence["truth_motion_max"] == pytest.approx(1.4)
    assert d.frames == (18, 21) and d.baseline == (10, 17) and d.labels["search"] == 1
    # The same jump with a particle right there is not a search failure of reach: no fast motion.
    h2 = calm_history(rng) + [frame(21, rng, truth_motion=1.4, nearest=0.05)]
    assert diagnose(h2, 21, 21, CFG).cause != "fast_motion"


def test_scale_is_the_centre_held_and_the_size_wrong(rng):
    h = calm_history(rng) + [frame(21, rng, scale_ratio=3.3, contain=0.95)]
    d = diagnose(h, 21, 21, CFG)
    assert d.cause == "scale" and d.evidence["containment"] == pytest.approx(0.95) and d.evidence["scale_frame"] == 21
    # A box of the wrong size off the truth is not a scale failure.
    h2 = calm_history(rng) + [frame(21, rng, scale_ratio=3.3, contain=0.2)]
    assert diagnose(h2, 21, 21, CFG).cause != "scale"


def test_illumination_is_a_strong_change_of_brightness(rng):
    dark = np.array([0.5 / 6, 0.5 / 6, 0.5, 0.5])  # the top quadrants six times darker
    h = calm_history(rng) + [frame(21, rng, brightness=dark)]
    d = diagnose(h, 21, 21, CFG)
    assert d.cause == "illumination" and d.evidence["light_log2_max"] == pytest.approx(np.log2(6), rel=1e-6)


def test_occlusion_is_some_quadrants_changing_while_another_holds(rng):
    h = calm_history(rng)
    _C, Q = look(rng)
    far = spd.exp_map(np.eye(9), 1.5 * np.eye(9))  # d = sqrt(9) * 1.5 = 4.5 from the baseline
    Q = Q.copy()
    Q[[1, 3]] = far
    ev = frame(21, rng, truth_Q=Q, truth_C=far, estimate_C=far)  # the target's look changed too
    d = diagnose(h + [ev], 21, 21, CFG)
    assert d.cause == "occlusion" and d.evidence["partial_frame"] == 21
    assert d.evidence["quadrant_change_min"] < CFG.quadrant_hold <= CFG.quadrant_jump < d.evidence["quadrant_change_max"]


def test_occlusion_by_something_static_in_front(rng):
    # The whole region changed, but into what stood at that place before the target came.
    scene = spd.exp_map(np.eye(9), 1.2 * np.eye(9))
    near_scene = spd.exp_map(scene, 0.05 * spd.sym(rng.standard_normal((9, 9))))
    ev = frame(21, rng, truth_C=near_scene, truth_Q=np.stack([near_scene] * 4), estimate_C=np.eye(9) * 3.0,
               scene_C=scene)
    d = diagnose(calm_history(rng) + [ev], 21, 21, CFG)
    assert d.cause == "occlusion" and d.evidence["scene_frame"] == 21 and "appearance" in d.also
    assert "scene that stood there" in d.text


def test_appearance_is_the_whole_target_changing(rng):
    far = spd.exp_map(np.eye(9), 1.2 * np.eye(9))
    ev = frame(21, rng, truth_C=far, truth_Q=np.stack([far] * 4), estimate_C=np.eye(9) * 3.0)
    d = diagnose(calm_history(rng) + [ev], 21, 21, CFG)
    assert d.cause == "appearance" and "occlusion" not in d.also


def test_distractor_is_the_target_unchanged_and_a_look_alike_followed(rng):
    # At the loss the target looks as before, and so does the region the tracker follows.
    ev = frame(21, rng, best_truth=3.0, best_est=1.5)
    d = diagnose(calm_history(rng) + [ev], 21, 21, CFG)
    assert d.cause == "distractor" and d.evidence["truth_minus_estimate_best_d"] == pytest.approx(1.5)
    # If the likelihood prefers the truth, it is not the look-alike that won.
    ev2 = frame(21, rng, best_truth=1.0, best_est=2.5)
    assert diagnose(calm_history(rng) + [ev2], 21, 21, CFG).cause != "distractor"


def test_impoverishment_and_unknown(rng):
    h = calm_history(rng)
    h[-1] = FrameEvidence(**{**h[-1].__dict__, "ess_frac": 0.005})
    h[-2] = FrameEvidence(**{**h[-2].__dict__, "ess_frac": 0.005})
    ev = frame(21, rng, ess_frac=0.004, best_truth=1.0, best_est=2.0)
    d = diagnose(h + [ev], 21, 19, CFG)
    assert d.cause == "impoverishment" and d.evidence["frames_ess_low"] == 3
    d2 = diagnose(calm_history(rng) + [frame(21, rng, best_truth=1.0, best_est=2.0)], 21, 21, CFG)
    assert d2.cause == "unknown" and "no rule" in d2.text


def test_causes_are_ranked_by_how_far_their_evidence_passed_its_threshold(rng):
    # A jump of 1.4 sizes (2.8x the threshold) that also shrinks the box 3x (1.9x its threshold).
    ev = frame(21, rng, truth_motion=1.4, nearest=1.1, scale_ratio=3.0, contain=0.9)
    d = diagnose(calm_history(rng) + [ev], 21, 21, CFG)
    assert d.cause == "fast_motion" and "scale" in d.also
    s = d.evidence
    assert s["strength_fast_motion"] == pytest.approx(1.4 / CFG.fast_motion)
    assert s["strength_scale"] == pytest.approx(3.0 / CFG.scale_ratio)
    ranked = [d.cause, *d.also]
    assert [s[f"strength_{c}"] for c in ranked] == sorted((s[f"strength_{c}"] for c in ranked), reverse=True)
    assert "by strength" in d.text
    # a smaller jump (1.1x its threshold) ranks below the same size change
    ev2 = frame(21, rng, truth_motion=0.55, nearest=1.1, scale_ratio=3.0, contain=0.9)
    d2 = diagnose(calm_history(rng) + [ev2], 21, 21, CFG)
    assert [d2.cause, *d2.also].index("scale") < [d2.cause, *d2.also].index("fast_motion")


def test_the_verdict_breaks_a_tie_and_only_a_tie():
    from covviz.diagnosis.drift import rerank

    tie = {"cause": "scale", "also": ["occlusion"], "evidence": {"strength_scale": 1.5, "strength_occlusion": 1.4}}
    out = rerank(dict(tie), "model", 1.2)
    assert out["cause"] == "occlusion" and out["also"] == ["scale"] and out["tie_broken_by"] == "model"
    assert rerank(dict(tie), "search", 1.2)["cause"] == "scale"  # a search verdict does not favour occlusion
    clear = {"cause": "scale", "also": ["occlusion"], "evidence": {"strength_scale": 2.5, "strength_occlusion": 1.4}}
    assert rerank(dict(clear), "model", 1.2)["cause"] == "scale"  # not a tie
    assert "tie_broken_by" not in rerank(dict(clear), "model", 1.2)


def test_a_street_is_not_a_look_alike(rng):
    """A distractor needs the followed region to resemble the target clearly more than the scene around it."""
    # the estimate's region as far from the target's look as the nearest surrounding region: no distractor
    base = calm_history(rng)
    ev = frame(21, rng, best_truth=3.0, best_est=1.5)
    alike = diagnose(base + [ev], 21, 21, CFG)
    assert alike.cause == "distractor"
    d_est = alike.evidence["estimate_look_at_loss"]
    street = diagnose([replace(h, background_look=d_est / CFG.distractor_background * 0.9) for h in base] + [ev],
                      21, 21, CFG)
    assert street.cause != "distractor" and "distractor" not in street.also
    # ... and one that resembles it twice as much as the street does is one
    near = diagnose([replace(h, background_look=2 * d_est / CFG.distractor_background) for h in base] + [ev],
                    21, 21, CFG)
    assert near.cause == "distractor"


def test_diagnosis_is_json_ready(rng):
    d = diagnose(calm_history(rng) + [frame(21, rng)], 21, 21, CFG)
    back = json.loads(json.dumps(d.as_dict()))
    assert back["lost_at"] == 21 and back["cause"] == d.cause and set(back["labels"]) == set(LABELS[1:])


# --------------------------------------------------------------------------- #
# the observer
# --------------------------------------------------------------------------- #
def test_labels_of_a_frame():
    dg = Diagnoser()
    base = {"iou": 0.2, "best_truth": 2.0, "best_est": 1.0, "reach": 0.8}
    assert dg._label({**base, "iou": 0.7}) == "ok"
    assert dg._label(base) == "model"  # the truth scores worse than the estimate
    assert dg._label({**base, "best_truth": 0.5, "reach": 0.2}) == "search"  # better, never reached
    assert dg._label({**base, "best_truth": 0.5, "reach": 0.8}) == "estimate"  # better, reached, yet elsewhere


def test_diagnoser_on_a_tracker_without_a_model_uses_a_probe():
    seq = SyntheticSequence(SyntheticConfig(n_frames=6))
    dg = Diagnoser()
    run_many([IdentityTracker()], seq, [dg])
    s = dg.states[0]
    ev = s.latest
    assert s.model is None and s.probe is not None
    assert ev.truth_C.shape == (9, 9) and ev.label == "" and np.isnan(ev.best_truth)
    assert ev.frame == 6 and 0 <= ev.iou <= 1
    json.dumps(dg.report(0))


def test_diagnoser_scores_the_truth_through_the_trackers_own_model():
    seq = SyntheticSequence(SyntheticConfig(n_frames=5))
    tr = ManifoldTracker(ManifoldConfig(n_particles=40), rng=1)
    dg = Diagnoser(DiagnosisConfig(cloud_templates=1000))  # every template of the cloud
    run_many([tr], seq, [dg])
    ev, rec = dg.states[0].latest, tr.last_record
    assert dg.states[0].model is tr.model and ev.label in LABELS
    m = tr.model
    g = m.prepare(seq.frame(4).image)
    from covviz.model.observation import box_to_pose

    # Every term update() weighed by: the default likelihood has the colour term, whose map
    # comes from the frame and the colour state the record carries.
    inputs = rec.inputs.likelihood_kwargs()
    assert "colour" in inputs and m.term_weights["colour"] > 0
    truth = np.repeat(box_to_pose(seq.frame(4).gt, m.base_wh)[None], 40, 0)
    at_truth = m.likelihood_distances(g, truth, rec.templates, **inputs)
    assert ev.best_truth == pytest.approx(at_truth.min(), rel=1e-9)
    d_est = float(m.likelihood_distances(g, rec.pose, rec.estimate_template, **inputs)[0])
    assert ev.d_est == pytest.approx(d_est, rel=1e-9)
    # Without the colour map the model would say something else here: the inputs matter.
    assert not np.allclose(m.likelihood_distances(g, truth, rec.templates), at_truth)
    # The parts of d_eff² at the truth minus at the estimate add up to the whole difference.
    d_truth = float(m.likelihood_distances(g, truth[0], rec.estimate_template, **inputs)[0])
    assert set(ev.term_gaps) == {"descriptor", *m.term_weights}
    assert sum(ev.term_gaps.values()) == pytest.approx(d_truth**2 - d_est**2, rel=1e-9, abs=1e-12)
    assert ev.d_truth == pytest.approx(d_truth, rel=1e-9)


@pytest.mark.parametrize("name", ["illumination", "distractor"])
def test_without_on_track_scores_the_diagnosis_is_the_same(name):
    # covviz track without a recorder (and bench) skip the template cloud's scores at the truth and the
    # estimate on on-track frames: nothing but a recorder reads them there. The labels, events,
    # diagnoses and report are the same as with them, and so is every other piece of evidence.
    from dataclasses import fields

    from covviz.data.scenarios import SCENARIOS, open_scenario

    seq = open_scenario(name)
    tr = ManifoldTracker(ManifoldConfig(n_particles=60), rng=0)
    full, lazy = Diagnoser(), Diagnoser(on_track_scores=False)
    run_many([tr], seq, [full, lazy], max_frames=SCENARIOS[name].onset + 40)
    assert full.report(0) == lazy.report(0) and full.report(0)["diagnoses"]
    scores = {"d_truth", "d_est", "best_truth", "best_est", "term_gaps"}
    a, b = full.states[0].history, lazy.states[0].history
    labels = {ev.label for ev in a}
    assert "ok" in labels and len(labels) > 1
    for ea, eb in zip(a, b, strict=True):
        assert ea.label == eb.label
        for f in fields(ea):
            x, y = getattr(ea, f.name), getattr(eb, f.name)
            if f.name in scores and ea.label == "ok":
                assert y is None or np.isnan(y), (ea.frame, f.name)
                assert x is not None and (isinstance(x, dict) or np.isfinite(x))
            elif isinstance(x, (np.ndarray, float)):
                assert np.array_equal(x, y, equal_nan=True), (ea.frame, f.name)
            else:
                assert x == y, (ea.frame, f.name)


def test_track_scores_on_track_frames_only_when_recording(monkeypatch, tmp_path):
    from covviz.cli import main

    made = []
    real = Diagnoser.__init__

    def spy(self, *a, **k):
        real(self, *a, **k)
        made.append(self.on_track_scores)

    monkeypatch.setattr(Diagnoser, "__init__", spy)
    assert main(["track", "--max-frames", "3", "--no-save", "--no-progress", "--out", str(tmp_path)]) == 0
    assert made == [False]
    rrd = tmp_path / "r.rrd"
    assert main(["track", "--max-frames", "3", "--save", str(rrd), "--no-progress", "--out", str(tmp_path / "b")]) == 0
    assert made[1] is True and rrd.exists()


def test_suspects_without_ground_truth(rng):
    dg = Diagnoser()
    seq = SyntheticSequence(SyntheticConfig(n_frames=3))
    dg.on_start(RunStart(seq, (tracker_info(IdentityTracker()),), seq.init_box, (None,), 3), NOTHING)
    s = dg.states[0]
    raised = []
    for f in range(1, 40):
        ess = 0.5 if f < 30 else 0.005
        d_min = 1.0 + 0.01 * np.sin(f) if f != 35 else 5.0
        ev = FrameEvidence(frame=f, ess_frac=ess, d_min=d_min, mode_mass=0.4 if f in (20, 21) else 0.0,
                           scale=1.0 if f < 25 else 2.0)
        raised += [(sp.frame, sp.kind) for sp in dg._suspects(s, ev, None)]
    assert (32, "collapse") in raised  # the third frame in a row below SUSPECT_ESS
    assert (21, "second_mode") in raised  # two frames in a row
    assert (25, "scale_runaway") in raised
    assert (35, "distance_jump") in raised
    assert len(raised) == 4  # each raised once, not again while it holds


def test_score_suspects():
    sus = [{"frame": 5}, {"frame": 48}, {"frame": 90}]
    res = score_suspects(sus, [(50, 60), (100, 120)])
    # frame 48 is in [50 - 10, 60 + 5]; frame 90 is in [100 - 10, 120 + 5]; frame 5 in none
    assert res == {"true_positives": 2, "suspects": 3, "losses": 2, "losses_found": 2}
    assert score_suspects([], [(50, 60)])["losses_found"] == 0


def test_a_nearest_miss_whose_measure_passed_says_which_condition_failed():
    """'fast motion at 164% of its threshold' read as if the rule had held: the card says what did not."""
    from covviz.diagnosis.drift import CAUSES, _card

    class Evidence(dict):  # the card words every cause; the ones not under test read as nan
        def __missing__(self, key):
            return float("nan")

    ev = Evidence(nearest_rule=CAUSES.index("fast_motion"), nearest_rule_share=1.64, nearest_particle_at_jump=0.31,
                  frames_ess_low=0)
    text = _card("unknown", (), 105, 102, ev, {"model": 1}, None)
    assert "fast motion: its measure passed its threshold (164%) but the rule did not hold" in text
    assert "0.31 target sizes from the jump" in text and "at 164% of its threshold" not in text
    ev["nearest_rule_share"] = 0.8
    assert "Nearest: fast motion at 80% of its threshold." in _card("unknown", (), 105, 102, ev, {"model": 1}, None)
