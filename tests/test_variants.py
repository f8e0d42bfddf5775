"""Variants of one tracker (issue 22, item 3): ``--trackers manifold,manifold@b.json`` in track and bench."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

from covviz import cli
from covviz.data.sequences import SyntheticConfig, SyntheticSequence, write_boxes
from covviz.experiments.bench import BenchError, bench
from covviz.trackers.variants import TrackerSpec, parse_specs


def test_a_variant_is_named_after_its_file(tmp_path):
    specs = parse_specs(["manifold", f" Manifold-Paper@{tmp_path / 'cfg' / 'fast.json'} ", ""])
    assert [s.name for s in specs] == ["manifold", "manifold-paper@fast"]
    assert specs[1] == TrackerSpec("manifold-paper@fast", "manifold-paper", tmp_path / "cfg" / "fast.json")
    assert specs[1].stochastic and specs[1].configurable


@pytest.mark.parametrize(
    ("items", "message"),
    [
        (["manifold", "manifold"], "manifold@other.json"),  # not silently collapsed: says how to compare configs
        (["manifold@a.json", "manifold@x/a.json"], "given twice"),
        (["csrt@a.json"], "takes no config"),
        (["manifold@a.yaml"], "NAME@FILE.json"),
        (["manfold"], "did you mean 'manifold'?"),
        ([" ", ""], "no trackers"),
    ],
)
def test_bad_tracker_lists_are_refused(items, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace("?", r"\?")):
        parse_specs(items)


def test_a_bad_variant_file_is_one_line(tmp_path, capsys):
    (tmp_path / "b.json").write_text('{"n_particle": 5}')
    code = cli.main(["track", "--trackers", f"manifold,manifold@{tmp_path / 'b.json'}", "--no-save", "--no-progress",
                     "--out", str(tmp_path / "runs"), "--max-frames", "3"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "n_particle" in err[0] and "b.json" in err[0]


def test_track_runs_two_configs_of_one_tracker_apart(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Path("b.json").write_text(json.dumps({"n_particles": 24}))
    Path("a.json").write_text(json.dumps({"n_particles": 16}))
    code = cli.main(["track", "--trackers", "manifold@a.json,manifold@b.json", "--max-frames", "6", "--no-progress",
                     "--save", "two.rrd", "--mds-every", "0"])
    assert code == 0
    out = capsys.readouterr().out
    assert "manifold@a (seed 0)" in out and "manifold@b (seed 0)" in out
    docs = {n: json.loads(Path(f"runs/synthetic/{n}_s0.json").read_text()) for n in ("manifold@a", "manifold@b")}
    assert docs["manifold@a"]["config"]["n_particles"] == 16 and docs["manifold@b"]["config"]["n_particles"] == 24
    assert docs["manifold@a"]["tracker"] == "manifold@a"
    from rerun.chunk import RrdReader

    paths = {str(p) for p in RrdReader("two.rrd").store().schema().entity_paths()}
    roots = {p.split("/")[2] for p in paths if p.startswith("/trackers/")}
    assert len(roots) == 2, roots  # each variant under its own trackers/<name>


def _write_otb(folder: Path, n_frames: int) -> None:
    seq = SyntheticSequence(SyntheticConfig(n_frames=n_frames, width=160, height=120, target_w=24, target_h=30, seed=3))
    (folder / "img").mkdir(parents=True)
    for i in range(n_frames):
        cv2.imwrite(str(folder / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(seq.frame(i).image, cv2.COLOR_RGB2BGR))
    write_boxes(folder / "groundtruth_rect.txt", seq.groundtruth)


def test_bench_keeps_variants_apart_and_resumes_them(tmp_path):
    _write_otb(tmp_path / "seqs" / "alpha", 8)
    (tmp_path / "fast.json").write_text(json.dumps({"n_particles": 12}))
    trackers = ["manifold", f"manifold@{tmp_path / 'fast.json'}"]
    out = tmp_path / "out"
    s = bench(tmp_path / "seqs", trackers, out, seeds=1, jobs=1, particles=None, progress=False)
    assert s["failed"] == [] and s["run"] == 2
    fast = json.loads((out / "alpha" / "manifold@fast_s0.json").read_text())
    base = json.loads((out / "alpha" / "manifold_s0.json").read_text())
    assert fast["config"]["n_particles"] == 12 and base["config"]["n_particles"] != 12
    manifest = json.loads((out / "bench_manifest.json").read_text())
    assert manifest["stochastic"] == ["manifold", "manifold@fast"]
    assert "manifold@fast" in (out / "report.md").read_text()
    again = bench(tmp_path / "seqs", trackers, out, seeds=1, jobs=1, progress=False, report=False)
    assert again["run"] == 0 and again["skipped"] == 2
    with pytest.raises(BenchError, match="given twice"):
        bench(tmp_path / "seqs", ["manifold", "manifold"], out, seeds=1, progress=False)
