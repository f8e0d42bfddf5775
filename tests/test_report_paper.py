"""A report ready for a paper (issue 22, item 8): SVG and PDF beside every PNG, LaTeX tables, no legend over a bar."""

from __future__ import annotations

from pathlib import Path

import cv2
import pytest

from covviz.cli import main
from covviz.data.sequences import SyntheticConfig, SyntheticSequence, write_boxes
from covviz.experiments import report as report_mod
from covviz.experiments.bench import bench


def _write_otb(folder: Path, n_frames: int, seed: int) -> None:
    seq = SyntheticSequence(SyntheticConfig(n_frames=n_frames, width=160, height=120, target_w=24, target_h=30,
                                            seed=seed))
    (folder / "img").mkdir(parents=True)
    for i in range(n_frames):
        cv2.imwrite(str(folder / "img" / f"{i + 1:04d}.png"), cv2.cvtColor(seq.frame(i).image, cv2.COLOR_RGB2BGR))
    write_boxes(folder / "groundtruth_rect.txt", seq.groundtruth)


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("seqs")
    _write_otb(root / "alpha_1", 8, 3)
    _write_otb(root / "beta", 7, 4)
    out = tmp_path_factory.mktemp("bench") / "out"
    s = bench(root, ["identity", "manifold"], out, seeds=2, particles=20, progress=False, report=False)
    assert s["failed"] == []
    return out


def test_every_figure_also_as_svg_and_pdf(results, tmp_path, capsys):
    md = tmp_path / "r.md"
    assert main(["report", str(results), "--out", str(md)]) == 0
    for name in ("bench_success", "bench_precision", "bench_on_track"):
        assert (tmp_path / "img" / f"{name}.png").is_file()
        assert (tmp_path / "img" / f"{name}.svg").read_text().lstrip().startswith("<?xml")
        assert (tmp_path / "img" / f"{name}.pdf").read_bytes().startswith(b"%PDF")
    assert not md.with_suffix(".tex").exists()  # only with --latex


def test_latex_tables(results, tmp_path, capsys):
    md = tmp_path / "r.md"
    assert main(["report", str(results), "--out", str(md), "--latex"]) == 0
    assert "tables in LaTeX" in capsys.readouterr().out
    tex = md.with_suffix(".tex").read_text()
    assert tex.count(r"\begin{tabular}") == 4  # overall, success AUC per sequence, one per sequence
    assert tex.count(r"\begin{table}") == tex.count(r"\end{table}") == 4
    assert r"r\_on\_track $\uparrow$" in tex and r"\texttt{manifold}" in tex and "alpha\\_1" in tex
    assert r"$\pm$" in tex and r"\textbf{" in tex
    rows = [ln for ln in tex.split(r"\midrule")[1].split(r"\bottomrule")[0].splitlines() if ln.strip()]
    assert len(rows) == 2 and all(r.count("&") == 7 for r in rows)  # tracker, runs, 4 metrics, fps, failed
    assert "±" not in tex and "†" not in tex and "_on" not in tex.replace(r"\_on", "")


def test_no_legend_over_a_bar(results, tmp_path, monkeypatch):
    figs = {}
    save = report_mod._save_figure

    def keep(fig, stem):
        figs[stem.name] = fig
        return save(fig, stem)

    monkeypatch.setattr(report_mod, "_save_figure", keep)
    report_mod.write_report(results, tmp_path / "r.md")
    fig = figs["bench_on_track"]
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]
    assert legends
    bars = [p.get_window_extent(renderer) for ax in fig.axes for p in ax.patches]
    assert bars
    for leg in legends:
        box = leg.get_window_extent(renderer)
        assert not any(box.overlaps(b) for b in bars)
