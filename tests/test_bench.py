"""Tests for ``covviz bench`` and ``covviz report`` on a tiny synthetic set.

Two OTB folders are written once per module from :class:`SyntheticSequence`
frames (160x120, 15 and 12 frames). One bench (identity + csrt + manifold with
20 particles and 2 seeds, 2 worker processes) is shared by the tests, which
work on copies of its results folder; resume tests check which jobs a second
bench ran (its summary) and that no other result file was rewritten (mtimes).
"""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers import write_otb

from covviz.cli import main
from covviz.data.sequences import read_boxes
from covviz.experiments import jobs as jobs_mod
from covviz.experiments.bench import BenchError, Job, bench, find_sequences, plan_jobs
from covviz.experiments.report import Stat, write_report
from covviz.experiments.results import load_result, result_paths

TRACKERS = ["identity", "csrt", "manifold"]
SEEDS = 2
PARTICLES = 20
FRAMES = {"alpha": 15, "beta": 12}
N_JOBS = len(FRAMES) * (2 + SEEDS)  # identity and csrt once, manifold per seed


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    r = tmp_path_factory.mktemp("sequences")
    for k, (name, n) in enumerate(FRAMES.items()):
        write_otb(r / name, n, seed=3 + k)
    return r


@pytest.fixture(scope="module")
def benched(root, tmp_path_factory) -> Path:
    """Results folder of one bench run in 2 worker processes (do not modify: copy it)."""
    out = tmp_path_factory.mktemp("bench") / "out"
    summary = bench(root, TRACKERS, out, seeds=SEEDS, jobs=2, particles=PARTICLES, progress=False)
    assert summary["failed"] == [] and summary["run"] == N_JOBS and summary["skipped"] == 0
    return out


@pytest.fixture
def results(benched, tmp_path) -> Path:
    """A private copy of the bench results."""
    dst = tmp_path / "results"
    shutil.copytree(benched, dst)
    return dst


def rerun(root, out, trackers=TRACKERS, **kw):
    """The bench again (one worker); the summary lists the jobs it ran."""
    args = {"seeds": SEEDS, "jobs": 1, "particles": PARTICLES, "progress": False}
    args.update(kw)
    return bench(root, trackers, out, **args)


def result_mtimes(out: Path) -> dict[str, int]:
    files = [*out.glob("*/*.json"), *out.glob("*/*.txt")]
    return {str(p.relative_to(out)): p.stat().st_mtime_ns for p in sorted(files)}


def track_argv(*args: str) -> list[str]:
    """``covviz track`` arguments, quiet and without a Rerun recording if the CLI makes one."""
    import argparse

    from covviz.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    flags = {s for a in sub.choices["track"]._actions for s in a.option_strings}
    return ["track", *args, "--no-progress", *(["--no-save"] if "--no-save" in flags else [])]


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


# --------------------------------------------------------------------------- #
# sequences and jobs
# --------------------------------------------------------------------------- #
def test_find_sequences(root, tmp_path):
    assert [p.name for p in find_sequences(root)] == ["alpha", "beta"]
    assert find_sequences(root / "alpha") == [root / "alpha"]  # ROOT itself a sequence
    nested = tmp_path / "nested"
    (nested / "set1" / "alpha" / "img").mkdir(parents=True)
    (nested / "set2" / "vot").mkdir(parents=True)
    (nested / "set2" / "vot" / "groundtruth.txt").write_text("1,2,3,4\n")
    (nested / ".hidden" / "x" / "img").mkdir(parents=True)
    assert [p.name for p in find_sequences(nested)] == ["alpha", "vot"]
    (nested / "set2" / "alpha" / "img").mkdir(parents=True)
    with pytest.raises(BenchError, match="two sequences are called 'alpha'"):
        find_sequences(nested)
    (tmp_path / "empty").mkdir()
    with pytest.raises(BenchError, match="no sequences found"):
        find_sequences(tmp_path / "empty")
    with pytest.raises(BenchError, match="no such folder"):
        find_sequences(tmp_path / "missing")


def test_plan_jobs_seeds_and_order():
    jobs = plan_jobs({"short": ("/s", 10), "long": ("/l", 30)}, ["csrt", "manifold"], seeds=3, max_frames=20)
    assert len(jobs) == 2 * (1 + 3)
    assert {j.seed for j in jobs if j.tracker == "csrt"} == {None}
    assert sorted(j.seed for j in jobs if j.tracker == "manifold" and j.sequence == "long") == [0, 1, 2]
    assert [j.n_frames for j in jobs] == sorted((j.n_frames for j in jobs), reverse=True)  # longest first
    assert jobs[0].sequence == "long" and jobs[0].n_frames == 20 and jobs[0].tracker == "manifold"
    assert Job("Car4", "/c", 5, "ipca", 2, None, None).label == "Car4/ipca/s2"


# --------------------------------------------------------------------------- #
# the bench and its report
# --------------------------------------------------------------------------- #
def test_bench_writes_every_result_manifest_and_report(benched, root):
    for seq, n in FRAMES.items():
        for tracker in TRACKERS:
            for seed in range(SEEDS) if tracker == "manifold" else [None]:
                _, js = result_paths(benched, seq, tracker, seed)
                doc, boxes = load_result(js)
                assert boxes.shape == (n, 4) and doc["n_frames"] == n
                assert doc["seed"] == seed and doc["tracker"] == tracker and not doc["interrupted"]
                assert len(doc["curves"]["success"]) == 21 and len(doc["curves"]["precision"]) == 51
                assert doc["thresholds"] == {"precision_at": 20.0, "on_track_gamma": 1.0}
                assert doc["failed_frames"] == [] and doc["bench"]["jobs"] == 2
                if tracker == "manifold":
                    assert doc["config"]["n_particles"] == PARTICLES
    assert not list(benched.rglob("*.part"))
    manifest = json.loads((benched / "bench_manifest.json").read_text())
    assert manifest["root"] == str(root.resolve())
    assert manifest["trackers"] == TRACKERS and manifest["seeds"] == SEEDS
    assert manifest["stochastic"] == ["manifold"] and manifest["sequences"] == FRAMES
    assert manifest["covviz"] and manifest["particles"] == PARTICLES

    md = (benched / "report.md").read_text()
    assert "## Overall" in md and "### alpha (15 frames tracked)" in md and "### beta (12 frames tracked)" in md
    overall = md.split("## Overall")[1].split("##")[0]
    assert (
        "| tracker | runs | success AUC ↑ | P@20 ↑ | r_on_track ↑ | rms_on_track ↓ | fps | failed frames |"
        in overall
    )
    assert re.search(r"\| `manifold` \| 4/4 \| \**\d\.\d{3} ± \d\.\d{3}", overall)
    assert re.search(r"\| `csrt` \| 2/2 \| \**\d\.\d{3}\**? \|", overall)
    assert "`PRECISION_AT` = 20 px" in md and "`ON_TRACK_GAMMA` = 1" in md and "21 values" in md
    for png in ("bench_success.png", "bench_precision.png", "bench_on_track.png"):
        p = benched / "img" / png
        assert p.stat().st_size > 5000 and p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"](img/{png})" in md


def test_trackers_rank_as_expected(benched):
    """The harness measures something: trackers beat standing still on a moving target."""
    auc = {}
    for tracker, seed in [("identity", None), ("csrt", None), ("manifold", 0)]:
        auc[tracker] = np.mean(
            [
                load_result(result_paths(benched, s, tracker, seed)[1])[0]["metrics"]["success_auc"]
                for s in FRAMES
            ]
        )
    assert auc["csrt"] > auc["identity"] + 0.2 and auc["manifold"] > auc["identity"] + 0.2


def test_bench_seed_replays_with_covviz_track(benched, root, tmp_path, monkeypatch):
    """Seed s of a bench equals 'covviz track SEQ --tracker manifold --seed s' (also across processes)."""
    monkeypatch.chdir(tmp_path)  # whatever track writes by default stays in tmp_path
    argv = track_argv(
        str(root / "beta"), "--tracker", "manifold", "--particles", str(PARTICLES), "--seed", "1"
    )
    assert main([*argv, "--out", str(tmp_path)]) == 0
    ours = read_boxes(result_paths(tmp_path, "beta", "manifold", 1)[0])
    theirs = read_boxes(result_paths(benched, "beta", "manifold", 1)[0])
    np.testing.assert_array_equal(ours, theirs)
    other_seed = read_boxes(result_paths(benched, "beta", "manifold", 0)[0])
    assert not np.array_equal(ours, other_seed)


@pytest.mark.parametrize("order", ["csrt,manifold", "manifold,csrt"])
def test_one_seed_rule_whatever_the_order_of_trackers(benched, root, tmp_path, monkeypatch, order):
    """A tracker gets the stream of its seed whatever the other --trackers and their order (one rule)."""
    monkeypatch.chdir(tmp_path)
    argv = track_argv(str(root / "beta"), "--trackers", order, "--particles", str(PARTICLES), "--seed", "1")
    assert main([*argv, "--out", str(tmp_path)]) == 0
    for name, seed in (("manifold", 1), ("csrt", None)):
        ours = (result_paths(tmp_path, "beta", name, 1)[0]).read_bytes()
        theirs = (result_paths(benched, "beta", name, seed)[0]).read_bytes()
        assert ours == theirs, name


def test_tracker_rng_is_the_documented_rule():
    from covviz.trackers import make_tracker, tracker_rng

    a = tracker_rng(3).random(5)
    b = np.random.default_rng(np.random.SeedSequence(3).spawn(1)[0]).random(5)
    np.testing.assert_array_equal(a, b)
    assert tracker_rng(None) is None
    assert not np.array_equal(tracker_rng(4).random(5), a)
    tr = make_tracker("manifold", seed=3, n_particles=PARTICLES)
    np.testing.assert_array_equal(tr.rng.random(5), b)
    with pytest.raises(ValueError, match="not both"):
        make_tracker("manifold", seed=3, rng=0)


def test_report_rebuilds_the_same_report_from_files(results, monkeypatch):
    before = (results / "report.md").read_text()
    (results / "report.md").unlink()
    shutil.rmtree(results / "img")

    def no_running(*a, **k):
        raise AssertionError("report must not run a tracker")

    monkeypatch.setattr("covviz.runner.run_many", no_running)
    assert main(["report", str(results)]) == 0
    assert (results / "report.md").read_text() == before
    assert all(
        (results / "img" / p).exists()
        for p in ("bench_success.png", "bench_precision.png", "bench_on_track.png")
    )


def test_report_out_elsewhere_links_figures_relatively(results, tmp_path):
    md = tmp_path / "docs" / "results.md"
    assert write_report(results, md) == md
    text = md.read_text()
    links = re.findall(r"\]\(([^)]+\.png)\)", text)
    assert len(links) == 3
    for link in links:
        assert link.startswith("img/") and (md.parent / link).is_file()
    # No absolute path of this machine: the results and the sequences' root are named relative to it.
    assert "/tmp" not in text and str(tmp_path) not in text and str(Path.home()) not in text
    manifest = json.loads((results / "bench_manifest.json").read_text())
    rel_root = re.search(r"sequences from `([^`]+)`", text).group(1)
    assert (md.parent / rel_root).resolve() == Path(manifest["root"]).resolve()


def test_report_appends_markdown_files_as_they_are(results, tmp_path, capsys):
    extra = tmp_path / "ablation.md"
    extra.write_text("## Ablation\n\n| a | b |\n|---|---|\n| 1 | 2 |\n")
    md = tmp_path / "out.md"
    assert main(["report", str(results), "--out", str(md), "--append", str(extra)]) == 0
    text = md.read_text()
    plain = write_report(results, tmp_path / "plain.md").read_text()
    assert text == plain.rstrip("\n") + "\n\n" + extra.read_text().strip() + "\n"
    # A missing file is an error before anything is written: the report stays as it was.
    assert main(["report", str(results), "--out", str(md), "--append", str(tmp_path / "nope.md")]) == 2
    assert "nope.md" in capsys.readouterr().err and md.read_text() == text


# --------------------------------------------------------------------------- #
# resuming
# --------------------------------------------------------------------------- #
def test_second_run_skips_finished_jobs(results, root):
    mtimes = result_mtimes(results)
    summary = rerun(root, results)
    assert summary["ran"] == [] and summary["skipped"] == N_JOBS and summary["run"] == 0
    assert result_mtimes(results) == mtimes  # no result file was rewritten


def test_interrupted_bench_reruns_only_the_missing_result(results, root, benched):
    # An interrupted bench leaves the finished results and no file of the unfinished job
    # (results are written atomically): remove one result to simulate that.
    txt, js = result_paths(results, "alpha", "manifold", 1)
    js.unlink()
    txt.unlink()
    mtimes = result_mtimes(results)
    summary = rerun(root, results)
    assert summary["ran"] == ["alpha/manifold/s1"] and summary["skipped"] == N_JOBS - 1
    after = result_mtimes(results)
    assert {k: v for k, v in after.items() if k in mtimes} == mtimes
    assert load_result(js)[0]["n_frames"] == FRAMES["alpha"]
    # the same seed gives the same boxes as the first bench (a fresh process per job)
    theirs = read_boxes(result_paths(benched, "alpha", "manifold", 1)[0])
    np.testing.assert_array_equal(read_boxes(txt), theirs)


def test_more_trackers_and_seeds_extend_the_folder(results, root):
    summary = rerun(root, results, trackers=["mosse", "manifold"], seeds=SEEDS + 1, jobs=2)
    assert sorted(summary["ran"]) == ["alpha/manifold/s2", "alpha/mosse", "beta/manifold/s2", "beta/mosse"]
    assert summary["skipped"] == 4
    manifest = json.loads((results / "bench_manifest.json").read_text())
    assert manifest["trackers"] == [*TRACKERS, "mosse"] and manifest["seeds"] == SEEDS + 1
    md = (results / "report.md").read_text()
    assert "| `manifold` | 6/6 |" in md and "| `mosse` | 2/2 |" in md


def test_force_reruns_everything(results, root):
    summary = rerun(root, results, trackers=["identity"], force=True, particles=None)
    assert sorted(summary["ran"]) == ["alpha/identity", "beta/identity"] and summary["skipped"] == 0


def test_a_failing_job_does_not_lose_the_others(root, tmp_path, capsys):
    broken = tmp_path / "broken"
    shutil.copytree(root, broken)
    (broken / "alpha" / "img" / "0005.png").write_bytes(b"not an image")  # fails mid-sequence
    out = tmp_path / "out"
    assert (
        main(["bench", str(broken), "--trackers", "identity,mosse", "--out", str(out), "--no-progress"]) == 1
    )
    err = capsys.readouterr().err
    assert (
        "2 runs failed (first: alpha/identity: SequenceError: cannot read image" in err and "0005.png" in err
    )
    for tracker in ("identity", "mosse"):
        assert not result_paths(out, "alpha", tracker, None)[1].exists()
        assert load_result(result_paths(out, "beta", tracker, None)[1])[0]["n_frames"] == FRAMES["beta"]
    assert "| `identity` | 1/2 |" in (out / "report.md").read_text()


# --------------------------------------------------------------------------- #
# bad input: one line, exit code 2
# --------------------------------------------------------------------------- #
def bench_cli(root, out, *extra):
    return main(["bench", str(root), "--out", str(out), "--no-progress", *extra])


def test_unknown_tracker(root, tmp_path, capsys):
    assert bench_cli(root, tmp_path / "o", "--trackers", "csrt,nosuch") == 2
    assert "unknown tracker 'nosuch'" in one_line_error(capsys)


def test_empty_root(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert bench_cli(tmp_path / "empty", tmp_path / "o", "--trackers", "identity") == 2
    assert "no sequences found" in one_line_error(capsys)


def test_results_folder_from_another_run(results, root, capsys):
    # another root (a single sequence of the same set)
    assert bench_cli(root / "alpha", results, "--trackers", "identity", "--particles", str(PARTICLES)) == 2
    msg = one_line_error(capsys)
    assert "results of another run (root was" in msg and "--force" in msg and "--out" in msg
    # other settings
    assert (
        bench_cli(root, results, "--trackers", "identity", "--particles", str(PARTICLES), "--max-frames", "5")
        == 2
    )
    assert "max_frames was None, now 5" in one_line_error(capsys)


def test_results_of_covviz_track_without_manifest(root, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "runs"
    assert main([*track_argv(str(root / "beta"), "--tracker", "identity"), "--out", str(out)]) == 0
    capsys.readouterr()
    assert bench_cli(root, out, "--trackers", "identity") == 2
    assert "no bench_manifest.json" in one_line_error(capsys)


def test_result_with_another_config(results, root, capsys):
    js = result_paths(results, "beta", "manifold", 0)[1]
    doc = json.loads(js.read_text())
    doc["config"]["observation"]["likelihood_sigma"] = 123.0
    js.write_text(json.dumps(doc))
    assert (
        bench_cli(
            root, results, "--trackers", "manifold", "--seeds", str(SEEDS), "--particles", str(PARTICLES)
        )
        == 2
    )
    assert "made with another manifold config" in one_line_error(capsys)


@pytest.mark.parametrize("edit, kept", [
    ({"drop": "ncc_rate"}, False),  # saved before the position step existed (off), which is now on
    ({"set": ("flow_guard", 0.0)}, True),  # saved while the (since removed) guard existed, off
    ({"set": ("flow_guard", 0.05)}, False),  # the guard on: another tracker
    ({"set": ("ncc_rate", 0.0)}, False),  # the position step off: another tracker than the default
])
def test_result_saved_before_a_neutral_field(results, root, capsys, edit, kept):
    js = result_paths(results, "beta", "manifold", 0)[1]
    before = js.read_bytes()
    doc = json.loads(before)
    if "drop" in edit:
        del doc["config"][edit["drop"]]
    else:
        doc["config"][edit["set"][0]] = edit["set"][1]
    js.write_text(json.dumps(doc))
    edited = js.read_bytes()
    rc = bench_cli(root, results, "--trackers", "manifold", "--seeds", str(SEEDS), "--particles", str(PARTICLES))
    if kept:
        assert rc == 0
        assert js.read_bytes() == edited  # kept as it was, not run again
    else:
        assert rc == 2
        assert "made with another manifold config" in one_line_error(capsys)


@pytest.mark.parametrize("command", ["bench", "report"])
def test_corrupt_results_file(results, root, capsys, command):
    js = result_paths(results, "alpha", "csrt", None)[1]
    js.write_text('{"format": "covviz-result/1", "seq')
    argv = [command, str(root if command == "bench" else results)]
    if command == "bench":
        argv += ["--out", str(results), "--trackers", "csrt", "--particles", str(PARTICLES), "--no-progress"]
    assert main(argv) == 2
    msg = one_line_error(capsys)
    assert str(js) in msg and "corrupt results file" in msg


@pytest.mark.parametrize("damage", ["corrupt", "deleted"])
def test_a_corrupt_or_deleted_manifest_is_rebuilt_from_the_results(results, root, damage):
    """Issue 19, defect 13: every finished result ran again (after 'delete it, or --force')."""
    manifest = results / "bench_manifest.json"
    before_doc = json.loads(manifest.read_text())
    if damage == "corrupt":
        manifest.write_text("{")
    else:
        manifest.unlink()
    before = result_mtimes(results)
    summary = rerun(root, results)
    assert summary["run"] == 0 and summary["skipped"] == N_JOBS and summary["failed"] == []
    assert result_mtimes(results) == before
    after = json.loads(manifest.read_text())
    for key in ("root", "sequences", "seeds", "stochastic", "max_frames", "particles", "configs"):
        assert after[key] == before_doc[key], key
    assert sorted(after["trackers"]) == sorted(before_doc["trackers"])
    assert (results / "bench_manifest.json.corrupt").exists() == (damage == "corrupt")


def test_a_corrupt_manifest_beside_foreign_results_is_not_rebuilt(results, root, capsys):
    (results / "bench_manifest.json").write_text("{")
    js = result_paths(results, "beta", "identity", None)[1]
    doc = json.loads(js.read_text())
    del doc["bench"]  # as covviz track writes it
    js.write_text(json.dumps(doc))
    assert bench_cli(root, results, "--trackers", "identity") == 2
    line = one_line_error(capsys)
    assert "corrupt bench manifest, and it cannot be rebuilt" in line and "not a bench result" in line
    assert (results / "bench_manifest.json").read_text() == "{"


def test_report_on_a_corrupt_manifest_names_the_command_that_has_force(results, capsys):
    (results / "bench_manifest.json").write_text("{")
    assert main(["report", str(results)]) == 2
    msg = one_line_error(capsys)
    assert "corrupt bench manifest" in msg and "covviz bench" in msg


def test_report_of_a_folder_without_results(tmp_path, capsys):
    (tmp_path / "nothing").mkdir()
    assert main(["report", str(tmp_path / "nothing")]) == 2
    assert "no results to report" in one_line_error(capsys)
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "no such results folder" in one_line_error(capsys)


# --------------------------------------------------------------------------- #
# pieces
# --------------------------------------------------------------------------- #
def test_stat_mean_std_over_seeds():
    s = Stat.of([0.5, 0.7, float("nan")])
    assert (
        s.n == 2 and s.partial and np.isclose(s.mean, 0.6) and np.isclose(s.std, np.std([0.5, 0.7], ddof=1))
    )
    assert s.fmt() == "0.600 ± 0.141†"
    assert Stat.of([0.25]).fmt() == "0.250"  # one run: no ± part
    assert Stat.of([float("nan")]).fmt() == "—"
    assert Stat.of([]).fmt() == "—"


def test_failure_counter_reads_record_extras():
    from covviz.data.sequences import Frame
    from covviz.records import FrameRecord
    from covviz.runner import NOTHING

    fc = jobs_mod._FailureCounter()
    for i, failed in enumerate([False, True, False, True]):
        fc.on_frame(
            Frame(i, np.zeros((2, 2, 3), np.uint8)), [FrameRecord(i, np.zeros(4), extras={"failed": failed})], NOTHING
        )
    fc.on_frame(Frame(4, np.zeros((2, 2, 3), np.uint8)), [FrameRecord(4, np.zeros(4))], NOTHING)
    assert fc.failed == [2, 4]  # frame numbers (1-based) of the indices 1 and 3


def test_paper_figure_with_ours_and_ipca(results):
    """The bar charts pair manifold with ipca (fake ipca results: renamed manifold files)."""
    for js in results.glob("*/manifold_s*.json"):
        doc = json.loads(js.read_text())
        doc["tracker"] = "ipca"
        doc["metrics"]["r_on_track"] *= 0.5
        js.with_name(js.name.replace("manifold", "ipca")).write_text(json.dumps(doc))
        txt = js.with_suffix(".txt")
        shutil.copy(txt, txt.with_name(txt.name.replace("manifold", "ipca")))
    manifest = json.loads((results / "bench_manifest.json").read_text())
    manifest["trackers"].append("ipca")
    (results / "bench_manifest.json").write_text(json.dumps(manifest))
    md = write_report(results).read_text()
    assert "No `ipca` results yet" not in md
    assert "![track duration rate and accuracy](img/bench_on_track.png)" in md
    assert "| `ipca` | 4/4 |" in md
    assert (results / "img" / "bench_on_track.png").stat().st_size > 5000


def test_report_counts_losses_by_cause_and_scores_the_suspects(results):
    """The failure section reads each result's drift diagnosis (here written by hand into one result)."""
    js = result_paths(results, "alpha", "manifold", 0)[1]
    doc = json.loads(js.read_text())
    doc["diagnosis"] = {
        "events": [{"kind": "drift", "frame": 3}, {"kind": "lost", "frame": 5}],
        "diagnoses": [{"cause": "occlusion", "lost_at": 5}],
        "suspects": [{"frame": 4, "kind": "collapse"}, {"frame": 40, "kind": "second_mode"}],
    }
    js.write_text(json.dumps(doc))
    md = write_report(results).read_text()
    section = md[md.index("## Failures and their causes") : md.index("## Success AUC per sequence")]
    row = next(line for line in section.splitlines() if line.startswith("| `manifold` | 1 |"))
    assert "| 1 |" in row  # one loss, of cause occlusion
    assert "| alpha | " in section and "occlusion 1" in section
    # Suspects: frame 4 is in [3 - 10, 5 + 5] (right), frame 40 is not: precision 50%, the loss found.
    assert "| `manifold` | 2 | 50% | 1 | 100% |" in section


def _near_half_pixel(box) -> bool:
    """Whether a saved (two-decimal) box has an edge of :func:`covviz.diagnosis.signals.colour_contrast` (the box's
    and its ring's, rounded to whole pixels there) so near a half pixel that the tracker's box, before saving,
    could round it the other way: each coordinate is within 0.005 px of the tracker's, so ``x`` within 0.005,
    ``x + w`` within 0.01, the ring's pad ``RING_PAD·(w + h)/2`` within ``RING_PAD·0.01``."""
    from covviz.model.fgbg import RING_PAD

    x, y, w, h = (float(v) for v in box)
    pad, dpad = RING_PAD * (w + h) / 2, RING_PAD * 0.01
    edges = ((x, 0.005), (y, 0.005), (x + w, 0.01), (y + h, 0.01),
             (x - pad, 0.005 + dpad), (y - pad, 0.005 + dpad), (x + w + pad, 0.01 + dpad), (y + h + pad, 0.01 + dpad))
    return any(abs(e - math.floor(e) - 0.5) <= tol + 1e-9 for e, tol in edges)


def _half_digit(v: float) -> float:
    """Half a unit of the last of 5 significant digits of ``v`` (how the results save a signal)."""
    return 0.5 * 10.0 ** (math.floor(math.log10(abs(v))) - 4) if v else 0.0


def test_backfilled_colour_is_the_signal_the_run_logged(benched, root, tmp_path):
    """scripts/backfill_colour.py on results that have the signal: the same values from the saved boxes,
    exactly for whole-pixel boxes. The manifold tracker's boxes are saved to two decimals, which may round an
    edge the other way where it sits within rounding of a half pixel: on that frame the contrast may differ, and
    through the run's reference (the median of the first COLOUR_REF frames' contrasts) every later value may
    be scaled. So every difference must come from such an edge, and after the reference, on the frames without
    one, the online and backfilled values must be one scaling apart: ``1 − value`` is contrast / reference."""
    from covviz.diagnosis.backfill import backfill_colour
    from covviz.diagnosis.signals import COLOUR_REF

    dst = tmp_path / "again"
    shutil.copytree(benched, dst)
    assert backfill_colour(dst, root) == (0, N_JOBS)  # every result has it: kept
    assert backfill_colour(dst, root, force=True) == (N_JOBS, 0)
    scaled = 0
    for js in sorted(benched.glob("*/*.json")):
        doc = json.loads(js.read_text())
        if "diagnosis" not in doc:
            continue
        a = doc["diagnosis"]["signals"]["colour"]
        again = json.loads((dst / js.relative_to(benched)).read_text())
        b = again["diagnosis"]["signals"]["colour"]
        assert again["diagnosis"]["backfilled"] == {"colour": "scripts/backfill_colour.py"}
        assert len(a) == len(b) and a[0] is None and b[0] is None
        if doc["tracker"] != "manifold":
            assert a == b
            continue
        _, boxes = load_result(js)
        near = [_near_half_pixel(bx) for bx in boxes]
        ratios = []
        for i, (x, y) in enumerate(zip(a, b)):
            if i <= COLOUR_REF:  # the reference is the median of the frames so far
                assert x == y or any(near[1 : i + 1]), (js.name, i, x, y)
            elif not near[i] and x is not None and y is not None and abs(1 - y) > 1e-3:
                # the ratio and its relative error from the saved values' 5 significant digits
                ratios.append(((1 - x) / (1 - y), _half_digit(x) / abs(1 - x) + _half_digit(y) / abs(1 - y)))
            else:
                assert x == y or near[i] or any(near[1 : COLOUR_REF + 1]), (js.name, i, x, y)
        if ratios:
            # One scaling (the two references' ratio): each frame's ratio agrees with the best-determined one
            # within their two rounding errors.
            k, ek = min(ratios, key=lambda t: t[1])
            for r, e in ratios:
                assert abs(r - k) <= k * (e + ek) * (1 + 1e-9), (js.name, r, k, e, ek)
            scaled += len(ratios)
            if not any(near[1 : COLOUR_REF + 1]):
                assert all(r == 1.0 for r, _ in ratios)
    assert scaled  # the manifold runs had frames after their reference to compare
