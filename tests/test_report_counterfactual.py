"""``covviz report`` on counterfactual replays (issue 20, item 5): losses by verdict, what fixing each kind of
failure would gain (ΔAUC), verdict stability across seeds, cause × verdict; on hand-built result files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from covviz.cli import main
from covviz.data.sequences import write_boxes
from covviz.diagnosis.counterfactual import Outcome, Replay
from covviz.experiments.report import load_runs, summarize
from covviz.experiments.report_counterfactual import (
    MATCH_FRAMES,
    NO_REPLAYS,
    LossReplay,
    match_losses,
    patched_boxes,
)
from covviz.experiments.results import ResultError, save_result
from covviz.metrics import evaluate
from covviz.records import RunResult

N = 60  # frames of the synthetic sequence


def _truth() -> np.ndarray:
    """A target of 20×16 px moving right by 1.37 px a frame (0-based pixels)."""
    t = np.arange(N, dtype=float)
    return np.column_stack([10 + 1.37 * t, 20 + 0.41 * t, np.full(N, 20.0), np.full(N, 16.0)])


def _otb(root: Path, name: str) -> Path:
    """An OTB folder the report can read the ground truth of (its frames are empty files: never decoded)."""
    folder = root / name
    (folder / "img").mkdir(parents=True)
    for i in range(N):
        (folder / "img" / f"{i + 1:04d}.jpg").write_bytes(b"")
    write_boxes(folder / "groundtruth_rect.txt", _truth())
    return folder


def _drifting(rng, off_from: int) -> np.ndarray:
    """The truth with a little noise (not on the 2-decimal grid), sliding away from frame ``off_from`` (0-based)."""
    b = _truth() + rng.normal(0, 0.8, (N, 4)) * [1, 1, 0.2, 0.2]
    b[0] = _truth()[0]
    b[off_from:, 0] += 6.0 * np.arange(1, N - off_from + 1)
    return b


def _replay(run: np.ndarray, lost_at: int, start: int, end: int, fixes: dict, verdict: str,
            identical: bool = True) -> Replay:
    """A loss's replays as :mod:`covviz.diagnosis.counterfactual` builds them; ``fixes``: name -> boxes of start..end."""
    none = run[start - 1: end].copy()
    if not identical:
        none[2, 0] += 9.0
    outcomes = {"none": Outcome(False, 0.1, 0, none, identical)}
    for name, boxes in fixes.items():
        outcomes[name] = Outcome(name == verdict, 0.7, 5, np.asarray(boxes, dtype=float))
    return Replay(lost_at, start + 3, start, end, end - lost_at, outcomes, verdict, (verdict,), start - 1, 1.5)


def _diagnosis(losses: list[tuple[int, str, Replay | None]]) -> dict:
    diags, events = [], []
    for lost_at, cause, rp in losses:
        d = {"cause": cause, "lost_at": lost_at, "drift_began": lost_at - 4, "text": f"LOST at {lost_at}"}
        if rp is not None:
            d.update(rp.as_dict())
        diags.append(d)
        events += [{"kind": "drift", "frame": lost_at - 4}, {"kind": "lost", "frame": lost_at}]
    return {"events": events, "diagnoses": diags, "suspects": [], "labels": {}}


def _save(out: Path, seq: Path, tracker: str, seed, boxes: np.ndarray, losses, bench_path: bool = True) -> None:
    res = RunResult(seq.name, tracker, seed, boxes, np.full(N, 0.01), _truth())
    extra = {"diagnosis": _diagnosis(losses)}
    if bench_path:
        extra["bench"] = {"jobs": 1, "threads": 1, "path": str(seq)}
    save_result(res, out, extra=extra)


def _saved(b: np.ndarray) -> np.ndarray:
    """Boxes as the results file keeps them (2 decimals)."""
    return np.round(np.asarray(b, dtype=float), 2)


def _auc(b: np.ndarray) -> float:
    return evaluate(b, _truth()).success_auc


@pytest.fixture
def bench_dir(tmp_path):
    """Two seeds of `manifold` on one sequence with replayed losses, and an OpenCV-like tracker with a restart.

    Seed 0: losses at 22 (window 15-30) and 28 (window 25-40, overlapping the first); seed 1: a loss at 26
    (window 20-35). Returns the folder and, per run, its boxes and losses (for the direct computation).
    """
    rng = np.random.default_rng(7)
    seq = _otb(tmp_path / "seqs", "Walk")
    out = tmp_path / "bench"
    truth = _truth()
    runs = {}

    b0 = _drifting(rng, 18)
    near = truth + rng.normal(0, 0.3, truth.shape)  # a replay that held on, off the 2-decimal grid
    l0 = [
        (22, "occlusion", _replay(b0, 22, 15, 30, {"estimate": b0[14:30] + 1.5, "search": near[14:30],
                                                   "model": near[14:30], "search+model": truth[14:30]}, "search")),
        (28, "fast_motion", _replay(b0, 28, 25, 40, {"estimate": b0[24:40], "search": b0[24:40] - 3.0,
                                                     "model": near[24:40], "search+model": truth[24:40]}, "model")),
    ]
    _save(out, seq, "manifold", 0, b0, l0)
    runs[("manifold", 0)] = (b0, l0)

    b1 = _drifting(rng, 22)
    l1 = [(26, "occlusion", _replay(b1, 26, 20, 35, {"estimate": b1[19:35], "search": near[19:35],
                                                     "model": b1[19:35] + 2.0, "search+model": truth[19:35]},
                                    "search"))]
    _save(out, seq, "manifold", 1, b1, l1)
    runs[("manifold", 1)] = (b1, l1)

    bc = _drifting(rng, 10)
    lc = [(14, "scale", _replay(bc, 14, 7, 34, {"restart": near[6:34]}, "restart"))]
    # an OpenCV tracker's replay has no `none`
    lc[0][2].outcomes.pop("none")
    _save(out, seq, "csrt", None, bc, lc)
    runs[("csrt", None)] = (bc, lc)
    return out, runs


def _direct_patch(boxes: np.ndarray, losses, fix: str) -> np.ndarray:
    """The definition, written out: each loss in frame order overwrites its window with its replay's boxes."""
    b = _saved(boxes)
    for _, _, rp in sorted(losses, key=lambda x: x[0]):
        if fix in rp.outcomes:
            b[rp.start - 1: rp.end] = _saved(rp.outcomes[fix].boxes)
    return b


def test_delta_auc_matches_a_direct_computation(bench_dir):
    out, runs = bench_dir
    s = summarize(out)
    for tracker, fixes in (("manifold", ("estimate", "search", "model", "search+model")), ("csrt", ("restart",))):
        mine = [(b, losses) for (t, _), (b, losses) in runs.items() if t == tracker]
        base = [_auc(_saved(b)) for b, _ in mine]
        rep = s.replays[tracker]
        assert rep.auc == pytest.approx(np.mean(base), abs=1e-12)
        for fix in fixes:
            want = np.mean([_auc(_direct_patch(b, losses, fix)) - a for (b, losses), a in zip(mine, base)])
            assert rep.gains[fix] == pytest.approx(want, abs=1e-12), (tracker, fix)
        assert set(rep.gains) == ({"none", *fixes} if tracker == "manifold" else set(fixes))
    gains = s.replays["manifold"].gains
    # the fixtures make the fixes differ: the ceiling gains most, a replay that stayed off gains little
    assert gains["search+model"] > gains["search"] > 0
    assert gains["search+model"] > gains["estimate"]


def test_a_later_window_overrides_an_earlier_one(bench_dir):
    out, runs = bench_dir
    b0, l0 = runs[("manifold", 0)]
    run = next(r for r in load_runs(out)[1] if r.tracker == "manifold" and r.seed == 0)
    patched = patched_boxes(_saved(b0), run.loss_replays, "search")
    # frames 25-30 are in both windows: the loss at 28 (the later) wins
    np.testing.assert_array_equal(patched[24:30], _saved(l0[1][2].outcomes["search"].boxes[:6]))
    np.testing.assert_array_equal(patched[14:24], _saved(l0[0][2].outcomes["search"].boxes[:10]))
    np.testing.assert_array_equal(patched[40:], _saved(b0[40:]))
    # order of the losses as given does not matter; the input is not changed
    before = _saved(b0)
    again = patched_boxes(before, run.loss_replays[::-1], "search")
    np.testing.assert_array_equal(again, patched)
    np.testing.assert_array_equal(before, _saved(b0))


def test_the_unchanged_replay_gains_exactly_zero(bench_dir):
    out, _ = bench_dir
    s = summarize(out)
    rep = s.replays["manifold"]
    assert rep.gains["none"] == 0.0  # exactly: the same boxes, not nearly
    for r in s.runs:
        if r.tracker == "manifold":
            assert r.fixed_auc["none"] == r.auc
    assert (rep.none_identical, rep.none_replays, rep.not_identical) == (3, 3, ())
    text = out / "r.md"
    assert main(["report", str(out), "--out", str(text)]) == 0
    md = text.read_text()
    assert "reproduced its run bit for bit on 3 of 3 replayed losses" in md
    gains_md = md.split("### What fixing each kind of failure would gain")[1].split("###")[0]
    assert "| tracker | runs | AUC | ΔAUC none | ΔAUC estimate |" in gains_md
    row = next(ln for ln in gains_md.splitlines() if ln.startswith("| `manifold` |"))
    assert row.split("|")[4].strip() == "0"  # the ΔAUC none column: exactly 0


def test_a_none_replay_that_differs_is_reported(tmp_path):
    rng = np.random.default_rng(3)
    seq = _otb(tmp_path / "seqs", "Walk")
    out = tmp_path / "bench"
    b = _drifting(rng, 18)
    _save(out, seq, "manifold", 0, b,
          [(22, "occlusion", _replay(b, 22, 15, 30, {"search": _truth()[14:30]}, "search", identical=False))])
    s = summarize(out)
    rep = s.replays["manifold"]
    assert (rep.none_identical, rep.none_replays, rep.not_identical) == (0, 1, (("Walk", 0, 22),))
    assert main(["report", str(out), "--out", str(tmp_path / "r.md")]) == 0
    md = (tmp_path / "r.md").read_text()
    assert "bit for bit on 0 of 1 replayed losses" in md
    assert "Not on `manifold` Walk s0 at 22" in md and "cannot be trusted" in md


def test_match_losses_pairs_the_same_loss_across_seeds():
    by_seed = {0: [(50, "model"), (120, "search")], 1: [(55, "model"), (300, "none helps")],
               2: [(52, "search"), (58, "search")]}
    pairs, unmatched = match_losses(by_seed)
    got = sorted((a[:2], b[:2]) for a, b in pairs)
    # seeds 0-1: 50~55; seeds 0-2: 50~52 (nearest first, so 58 stays free); seeds 1-2: 55~52 (3 frames; 58 also 3)
    assert got == [((0, 50), (1, 55)), ((0, 50), (2, 52)), ((1, 55), (2, 52))]
    assert sum(a[2] == b[2] for a, b in pairs) == 1
    assert sorted(unmatched) == [(0, 120, "search"), (1, 300, "none helps"), (2, 58, "search")]


def test_match_losses_window_is_inclusive():
    w = MATCH_FRAMES
    pairs, unmatched = match_losses({0: [(100, "model")], 1: [(100 + w, "model")], 2: [(100 - w - 1, "search")]})
    assert [(a[:2], b[:2]) for a, b in pairs] == [((0, 100), (1, 100 + w))]
    assert unmatched == [(2, 100 - w - 1, "search")]
    assert match_losses({0: [(5, "model")]}) == ([], [(0, 5, "model")])


def test_report_stability_and_cause_by_verdict(bench_dir):
    out, _ = bench_dir
    s = summarize(out)
    rep = s.replays["manifold"]
    # seed 0 lost at 22 (search) and 28 (model), seed 1 at 26 (search): 26 pairs with 28 (2 frames) first
    assert (rep.stability_losses, rep.pairs, rep.same, rep.unmatched) == (3, 1, 0, 1)
    assert s.replays["csrt"].pairs is None
    assert rep.cause_verdict == {("occlusion", "search"): 2, ("fast_motion", "model"): 1}
    assert rep.verdicts == {"search": 2, "model": 1}
    assert main(["report", str(out), "--out", str(out / "r.md")]) == 0
    md = (out / "r.md").read_text()
    assert "| `manifold` | 3 | 1 | 0/1 (0%) | 1 |" in md
    assert "`csrt`: one run per sequence, nothing to compare." in md
    assert rep.disagreements == (("Walk", (0, 28, "model"), (1, 26, "search")),)
    assert "Verdicts that differ, `manifold`: Walk s0 at 28 model / s1 at 26 search." in md
    cv = md.split("### Cause × verdict")[1]
    assert "| cause | search | model |" in cv and "| occlusion | 2 | · |" in cv and "| fast motion | · | 1 |" in cv
    verdicts = md.split("### Losses by verdict")[1].split("###")[0]
    assert "| tracker | losses | replayed | `none` identical | search | model | restart |" in verdicts
    assert "| `manifold` | 3 | 3 | 3/3 | 2 | 1 | · |" in verdicts
    assert "| `csrt` | 1 | 1 | — | · | · | 1 |" in verdicts


def test_old_results_without_replays(tmp_path):
    rng = np.random.default_rng(5)
    seq = tmp_path / "nowhere" / "Walk"  # no sequence on disk: old results must not need one
    out = tmp_path / "bench"
    for seed in (0, 1):
        _save(out, seq, "manifold", seed, _drifting(rng, 18), [(22, "occlusion", None)], bench_path=False)
    s = summarize(out)
    assert not s.replays["manifold"].replayed and s.replays["manifold"].losses == 2
    assert all(np.isnan(r.auc) and r.fixed_auc == {} for r in s.runs)
    assert main(["report", str(out), "--out", str(tmp_path / "r.md")]) == 0
    md = (tmp_path / "r.md").read_text()
    assert f"No replays in these results: {NO_REPLAYS}." in md
    assert "ΔAUC" not in md


def test_losses_without_replays_beside_replayed_ones(bench_dir):
    out, _ = bench_dir
    seq = out.parent / "seqs" / "Walk"
    _save(out, seq, "ipca", 0, _drifting(np.random.default_rng(1), 30), [(33, "appearance", None)])
    md_path = out / "r.md"
    assert main(["report", str(out), "--out", str(md_path)]) == 0
    md = md_path.read_text()
    assert f"`ipca`: losses but none replayed — {NO_REPLAYS}, or no checkpoint reached them." in md
    # a tracker with replays and a loss without: that loss is named
    _save(out, seq, "manifold", 2, _drifting(np.random.default_rng(4), 40), [(44, "scale", None)])
    assert main(["report", str(out), "--out", str(md_path)]) == 0
    md = md_path.read_text()
    assert "Not replayed, `manifold`: Walk s2 at 44." in md
    assert "| `manifold` | 4 | 3 | 3/3 |" in md


def test_a_replay_that_does_not_fit_its_window_is_refused(tmp_path):
    rng = np.random.default_rng(2)
    seq = _otb(tmp_path / "seqs", "Walk")
    out = tmp_path / "bench"
    b = _drifting(rng, 18)
    rp = _replay(b, 22, 15, 30, {"search": _truth()[14:29]}, "search")  # 15 boxes for 16 frames
    _save(out, seq, "manifold", 0, b, [(22, "occlusion", rp)])
    with pytest.raises(ResultError, match=r"manifold_s0.json: the 'search' replay of the loss at 22 has 15 boxes"):
        load_runs(out)


def test_runs_without_ground_truth_are_left_out_of_the_gains(bench_dir, tmp_path):
    out, runs = bench_dir
    b, losses = runs[("manifold", 1)]
    _save(out, tmp_path / "gone" / "Walk", "manifold", 2, b, losses)  # its sequence is nowhere
    s = summarize(out)
    rep = s.replays["manifold"]
    assert (rep.scored_runs, rep.runs, rep.replayed) == (2, 3, 4)
    assert rep.unreplayed == ()
    assert main(["report", str(out), "--out", str(out / "r.md")]) == 0
    assert "| `manifold` | 2 of 3 |" in (out / "r.md").read_text()


def test_loss_replay_identical_reads_the_none_outcome():
    assert LossReplay(5, "scale").identical is None
    assert LossReplay(5, "scale", "search", {"none": {"kept": False, "identical": True}}).identical is True
    assert LossReplay(5, "scale", "restart", {"restart": {"kept": True}}).identical is None


def test_latex_has_the_replays_tables(bench_dir):
    out, _ = bench_dir
    assert main(["report", str(out), "--out", str(out / "r.md"), "--latex"]) == 0
    tex = (out / "r.tex").read_text()
    verdicts = tex.split(r"\label{tab:covviz-auc}")[1].split(r"\label{tab:covviz-verdicts}")[0]
    assert r"\texttt{manifold} & 3 & 3 & 3/3 & 2 & 1 & 0 \\" in verdicts
    assert r"\texttt{csrt} & 1 & 1 & -- & 0 & 0 & 1 \\" in verdicts
    gains = tex.split(r"\label{tab:covviz-verdicts}")[1].split(r"\label{tab:covviz-gains}")[0]
    row = next(ln for ln in gains.splitlines() if ln.startswith(r"\texttt{manifold}"))
    assert row.split(" & ")[3] == "0"  # ΔAUC none, exactly 0, the column after tracker, runs, AUC
    assert tex.count(r"\begin{table}") == tex.count(r"\end{table}") == 2 + 2 + 1  # overall, AUC, replays, 1 sequence


def test_where_losses_recur_over_three_seeds(bench_dir):
    """Two seeds: no recurrence table (too few to tell the scene from chance). A third seed losing elsewhere:
    the place 22-28 holds 2 of 3 seeds (each counted once), with the verdicts and causes of its three losses."""
    from covviz.experiments.report import recurring_losses

    out, _ = bench_dir
    assert recurring_losses(summarize(out)) == {}
    assert main(["report", str(out), "--out", str(out / "r.md")]) == 0
    assert "### Where the losses recur" not in (out / "r.md").read_text()

    seq = Path(out).parent / "seqs" / "Walk"
    b2 = _drifting(np.random.default_rng(3), 40)
    _save(out, seq, "manifold", 2, b2, [(45, "scale", None)])
    places = recurring_losses(summarize(out))
    assert list(places) == ["manifold"]  # csrt ran once
    assert places["manifold"] == [("Walk", 22, 28, 2, 3, {"search": 2, "model": 1}, {"occlusion": 2, "fast_motion": 1})]
    assert main(["report", str(out), "--out", str(out / "r.md")]) == 0
    md = (out / "r.md").read_text().split("### Where the losses recur over the seeds")[1]
    assert "| `manifold` | Walk | 22–28 | 2/3 | search 2, model 1 | occlusion 2, fast motion 1 |" in md
    assert "*share*: `manifold` 3 of 4." in md
