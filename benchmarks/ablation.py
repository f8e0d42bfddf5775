"""Ablation of the default tracker's likelihood: each change alone and together, per sequence, with its cost.

Runs ``covviz bench`` once per variant of ``ManifoldConfig`` (the results stay on
disk under ``--out``, one folder per variant, and a second run resumes), then
prints and writes a markdown report: success AUC per sequence on the seeds that
chose the default (0-2) and on the seeds that confirm it (3-5, never used to
choose), and the ms per ``update()`` of each variant at 600 particles, timed
side by side in one process.

Usage:
    python benchmarks/ablation.py ../shared/sequences --out runs/ablation --md docs/ablation.md
    python benchmarks/ablation.py ../shared/sequences --seeds 3          # only the deciding seeds
    python benchmarks/ablation.py ../shared/sequences --no-cost          # AUC only

The variants (``VARIANTS``): the default of before issue 14 (the quadrant term:
``NEW_TERMS_OFF``), that plus each new term alone, all of them (the default,
``ManifoldConfig()``), the default without the gradient floor, the default without the
position step of the reported box (``ncc_rate`` 0: the filter's own estimate), the default with the paper's
constant noise (no adaptive diffusion, issue 24), the default without the observation pull, the default
without all three of issue 24's additions (``issue24``: what its cost bar is measured against), ``manifold-paper``
(``PAPER_LIKELIHOOD``), and the default with the motion prior from the image
(``flow_share``, off by default: docs/tuning.md). ``--cost-only`` times ``update()``
without running the bench, e.g. ``--variants default,flow --cost-only``. These
machines are noisy: the costs are ratios measured in one run; the absolute
figures name the machine they ran on.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed import machine, time_tracker

from covviz.experiments.bench import bench
from covviz.experiments.report import load_runs
from covviz.trackers.manifold import NEW_TERMS_OFF, ManifoldConfig, make, make_paper

DEFAULT = ManifoldConfig()

#: key -> (column title, tracker, ManifoldConfig fields over the defaults).
VARIANTS: dict[str, tuple[str, str, dict]] = {
    "previous": ("previous default (quadrant term)", "manifold", dict(NEW_TERMS_OFF)),
    "grad": ("+ derivative normalisation (floored)", "manifold",
             {**NEW_TERMS_OFF, "grad_normalize": DEFAULT.observation.grad_normalize}),
    "colour": ("+ colour term", "manifold", {**NEW_TERMS_OFF, "colour_weight": DEFAULT.observation.colour_weight}),
    "default": ("both: the default", "manifold", {}),
    "nofloor": ("the default, gradient floor off", "manifold", {"grad_floor": 0.0}),
    "noncc": ("the default, position step off (ncc_rate 0)", "manifold", {"ncc_rate": 0.0}),
    "static": ("the default, constant noise (no adaptive diffusion)", "manifold",
               {"adaptive": {"enabled": False}}),
    "nopull": ("the default, observation pull off", "manifold", {"observation_pull": 0.0}),
    "issue24": ("the default without issue 24's additions (adaptive diffusion, position step, observation pull)",
                "manifold", {"adaptive": {"enabled": False}, "ncc_rate": 0.0, "observation_pull": 0.0}),
    "paper": ("manifold-paper", "manifold-paper", {}),
    "flow": ("the default + the flow prior (flow_share 0.5, off by default)", "manifold", {"flow_share": 0.5}),
}
SEED_SETS = {"Seeds 0–2 (decision)": (0, 1, 2), "Seeds 3–5 (confirmation)": (3, 4, 5)}


def run_variants(root: Path, out: Path, seeds: int, jobs: int, keys) -> dict[str, Path]:
    dirs = {}
    for key in keys:
        title, tracker, cfg = VARIANTS[key]
        d = out / key
        print(f"== {title}: covviz bench {root} --trackers {tracker} --seeds {seeds} --out {d}"
              + (f" --config '{json.dumps(cfg)}'" if cfg else ""), flush=True)
        t0 = time.perf_counter()
        res = bench(root, [tracker], d, seeds=seeds, jobs=jobs, config=cfg or None, report=False)
        print(f"   {res['run']} jobs run, {res['skipped']} kept from before, {len(res['failed'])} failed "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
        if res["failed"]:
            raise SystemExit(f"failed jobs in {d}: {res['failed']}")
        dirs[key] = d
    return dirs


def auc_table(dirs: dict[str, Path]) -> dict[str, dict[tuple[str, int], float]]:
    """variant -> {(sequence, seed): success AUC}."""
    out = {}
    for key, d in dirs.items():
        _, runs, _ = load_runs(d)
        out[key] = {(r.sequence, int(r.seed)): float(r.metrics["success_auc"]) for r in runs}
    return out


def _cell(values) -> str:
    v = np.asarray(values, dtype=float)
    return f"{v.mean():.3f} ± {v.std(ddof=1):.3f}" if len(v) > 1 else f"{v.mean():.3f}"


def markdown_tables(auc: dict, seeds_avail: set[int]) -> list[str]:
    keys = list(auc)
    sequences = sorted({s for a in auc.values() for s, _ in a}, key=str.lower)
    lines = []
    for title, seeds in SEED_SETS.items():
        seeds = [s for s in seeds if s in seeds_avail]
        if not seeds:
            continue
        lines += [f"### {title}", "", "| sequence | " + " | ".join(VARIANTS[k][0] for k in keys) + " |",
                  "|---|" + "---:|" * len(keys)]
        # The mean row: the mean over the sequences per seed, then its mean ± std over the seeds.
        row = []
        for k in keys:
            per_seed = [np.mean([auc[k][(s, sd)] for s in sequences]) for sd in seeds]
            row.append(f"**{_cell(per_seed)}**")
        lines.append("| **mean** | " + " | ".join(row) + " |")
        for s in sequences:
            lines.append(f"| {s} | " + " | ".join(_cell([auc[k][(s, sd)] for sd in seeds]) for k in keys) + " |")
        lines.append("")
    return lines


def cost_table(sequences: list[str], keys, frames: int, repeat: int) -> list[str]:
    """ms per update() of each variant at 600 particles, side by side (variants alternate within each pass)."""
    from covviz.data.sequences import open_sequence

    # What each change adds to the default's update(): the default against the variant without it.
    what = {"previous": "the new terms", "static": "the adaptive diffusion", "noncc": "the position step",
            "nopull": "the observation pull", "issue24": "issue 24's additions"}
    bases = [b for b in what if b in keys] if "default" in keys else []
    flow = not bases and "flow" in keys and "default" in keys  # the flow prior adds to the default
    added_cols = [f"added by {what[b]}, share of the default's update()" for b in bases] or (
        ["added by the flow prior, share of the default's update()"] if flow else ["added, share of the default's update()"])
    lines = ["| sequence (frame) | " + " | ".join(VARIANTS[k][0] for k in keys)
             + "".join(f" | {c}" for c in added_cols) + " |",
             "|---|" + "---:|" * (len(keys) + len(added_cols))]
    for name in sequences:
        seq = open_sequence(name)
        n = min(frames, len(seq))
        imgs = [seq.frame(i).image for i in range(n)]
        best = {k: np.inf for k in keys}
        for _ in range(repeat):
            for k in keys:
                _, tracker, cfg = VARIANTS[k]
                factory = make_paper if tracker == "manifold-paper" else make  # as the bench builds them
                c = ManifoldConfig.from_dict(cfg)
                dt, _ = time_tracker(lambda f=factory, c=c: f(600, rng=0, config=c), imgs, seq.init_box, 1)
                best[k] = min(best[k], dt)
        h, w = imgs[0].shape[:2]
        added = [1 - best[b] / best["default"] for b in bases] or (
            [best["flow"] / best["default"] - 1] if flow else [float("nan")])
        label = Path(name).name if not name.startswith("synthetic") else "synthetic"
        lines.append(f"| {label} ({w}×{h}) | " + " | ".join(f"{1e3 * best[k]:.2f}" for k in keys)
                     + "".join(f" | {100 * a:+.0f}%" if np.isfinite(a) else " | —" for a in added) + " |")
        print(lines[-1], flush=True)
    return lines


def _auc_section(args, keys) -> list[str]:
    """Run the variants' benches and return the AUC tables (markdown lines)."""
    dirs = run_variants(Path(args.root), Path(args.out), args.seeds, args.jobs, keys)
    auc = auc_table(dirs)
    md = ["## Ablation of the default likelihood (manifold tracker)", "",
          ("Success AUC (OTB), mean ± standard deviation over the seeds; the **mean** row is the mean over the "
          f"{len({s for a in auc.values() for s, _ in a})} sequences per seed, ± its standard deviation over the seeds. "
          "Each column is `covviz bench` of one `ManifoldConfig` (`benchmarks/ablation.py`, results in "
          f"`{args.out}/<variant>`): the previous default is `NEW_TERMS_OFF` (the quadrant term only), each change "
          "alone is that plus one change, *both* is `ManifoldConfig()` (derivative normalisation with its floor "
          "`grad_floor`, and the colour term), and `manifold-paper` is `PAPER_LIKELIHOOD`."),
          ""]
    return md + markdown_tables(auc, set(range(args.seeds)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("root", help="folder of OTB sequences (e.g. ../shared/sequences)")
    ap.add_argument("--out", default="runs/ablation", help="results folder, one subfolder per variant")
    ap.add_argument("--seeds", type=int, default=6, help="seeds 0..N-1 (default 6: 0-2 decide, 3-5 confirm)")
    ap.add_argument("--jobs", type=int, default=2, help="bench jobs at a time (default 2)")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"subset of {','.join(VARIANTS)}")
    ap.add_argument("--md", default=None, help="write the markdown report here (e.g. docs/ablation.md)")
    ap.add_argument("--no-cost", action="store_true", help="skip the timing of update()")
    ap.add_argument("--cost-only", action="store_true", help="only the timing of update(): no bench, no AUC tables")
    ap.add_argument("--cost-sequences", default="Bolt2,Human3,synthetic",
                    help="sequences (names under ROOT, or 'synthetic') to time at 600 particles")
    ap.add_argument("--cost-frames", type=int, default=150)
    ap.add_argument("--cost-repeat", type=int, default=3, help="passes; each variant's best is kept")
    args = ap.parse_args(argv)
    root = Path(args.root)
    keys = [k.strip() for k in args.variants.split(",") if k.strip()]
    unknown = [k for k in keys if k not in VARIANTS]
    if unknown:
        ap.error(f"unknown variant(s) {unknown}; choose from {list(VARIANTS)}")
    md = []
    if not args.cost_only:
        md += _auc_section(args, keys)
    if args.cost_only or not args.no_cost:
        seqs = [("synthetic" if s == "synthetic" else str(root / s)) for s in args.cost_sequences.split(",")]
        ck = [k for k in keys if k in VARIANTS]
        md += ["### Cost at 600 particles", "",
               (f"ms per `update()` (best of {args.cost_repeat} passes of {args.cost_frames} frames, the variants "
               f"alternating in one process, `ManifoldConfig.threads` = {DEFAULT.threads}); {machine()}."), ""]
        md += cost_table(seqs, ck, args.cost_frames, args.cost_repeat)
        md.append("")
    text = "\n".join(md)
    print(text)
    if args.md:
        Path(args.md).write_text(text + "\n")
        print(f"wrote {args.md}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
