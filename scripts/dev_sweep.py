"""Quick dev-set runs of a manifold variant: the bare tracker, no diagnosis, two processes.

How issue 24 chose its variants (docs/tuning.md): each variant is a JSON object of
``ManifoldConfig`` fields, run on a half of the dev set with the bench's seed rule
(:func:`covviz.trackers.tracker_rng`), so seed ``s`` gives the boxes of ``covviz bench
--seeds`` (checked: the success AUCs equal the bench's to the last bit). The halves were
fixed before any run, by alternating alphabetical order of the 14 dev sequences:
choose on ``A``, confirm on ``B`` and on seeds 3–5. Results (one JSON and the boxes per
run) go to ``OUT/NAME/``; a second run skips what is there.

Usage::

    python scripts/dev_sweep.py run static '{"adaptive": {"enabled": false}}' --set AB --seeds 0,1,2
    python scripts/dev_sweep.py run adaptive '{}' --set A --seeds 0,1,2
    python scripts/dev_sweep.py table static adaptive          # per sequence, both seed sets
    python scripts/dev_sweep.py pair adaptive static --seeds 0,1,2 3,4,5   # paired difference per seed set
    python scripts/dev_sweep.py run chaos '{}' --set AB --seeds 0,1,2 --perturb   # the placebo: another stream only
    python scripts/dev_sweep.py bysequence default chaos --seeds 0,1,2     # how far the stream alone moves each
    python scripts/dev_sweep.py losses default --seeds 0,1,2,3,4,5        # where the losses recur, and how
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import sys
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

A = ["Bolt2", "Car4", "Crossing", "Dudek_first20", "Human3", "Jogging-2", "Surfer"]
B = ["Car1", "Couple", "DragonBaby", "Football1", "Jogging-1", "MotorRolling", "VOT15_bag"]
SETS = {"A": A, "B": B, "AB": A + B}


def ab_cells(per_seq: dict) -> list[str]:
    """Precision / recall (found of losses) of held-out alarms (``{sequence: [(scores, counts, run), ...]}``,
    as :func:`covviz.diagnosis.calibrate.loso` gives them) pooled over A, over B and over both: table cells."""
    from covviz.diagnosis.calibrate import summarise

    cells = []
    for qs in (A, B, A + B):
        s = summarise({q: v for q, v in per_seq.items() if q in qs and v}, np.random.default_rng(0), 10)
        cells.append(f"{100 * s['precision']:.0f}% / {100 * s['recall']:.0f}% ({s['found']} of {s['losses']})")
    return cells


def _job(args):
    root, out_dir, cfgd, seq, seed, perturb = args
    out = Path(out_dir) / f"{seq}_s{seed}.json"
    if out.exists():
        return json.loads(out.read_text())
    from covviz.data.sequences import open_sequence, write_boxes
    from covviz.diagnosis.calibrate import losses_of
    from covviz.metrics import evaluate, iou
    from covviz.trackers import tracker_rng
    from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker

    s = open_sequence(str(Path(root) / seq))
    cfg = ManifoldConfig.from_dict({**cfgd, "threads": 1})  # results never depend on the thread count
    boxes = [s.init_box]
    t0 = time.process_time()
    with ManifoldTracker(cfg, rng=tracker_rng(seed)) as tr:
        tr.init(s.frame(0).image, s.init_box)
        if perturb:
            tr.rng.random()  # the placebo: one draw more, so the run's random stream is another, nothing else
        for i in range(1, len(s)):
            boxes.append(tr.update(s.frame(i).image))
    boxes = np.array(boxes)
    res = {
        "seq": seq, "seed": seed, "auc": evaluate(boxes, s.groundtruth).success_auc,
        "losses": len(losses_of(iou(boxes, s.groundtruth))), "cpu_seconds": time.process_time() - t0,
        "boxes_sha256": hashlib.sha256(boxes.tobytes()).hexdigest(),
    }
    write_boxes(out.with_suffix(".txt"), boxes)
    out.write_text(json.dumps(res))
    return res


def run(args) -> int:
    cfgd = json.loads(args.config)
    from covviz.trackers.manifold import ManifoldConfig

    ManifoldConfig.from_dict(cfgd)  # refuse a bad config before starting any process
    out = Path(args.out) / args.name
    out.mkdir(parents=True, exist_ok=True)
    meta, wanted = out / "config.json", {**cfgd, **({"perturb": True} if args.perturb else {})}
    if meta.exists() and json.loads(meta.read_text()) != wanted:
        raise SystemExit(f"{out} holds runs of another config (or --perturb): choose another name")
    meta.write_text(json.dumps(wanted))
    seeds = [int(x) for x in args.seeds.split(",")]
    jobs = [(args.root, str(out), cfgd, q, sd, args.perturb) for q in SETS[args.set] for sd in seeds]
    with ProcessPoolExecutor(args.jobs) as ex:
        res = list(ex.map(_job, jobs))
    print(f"{args.name}: mean success AUC {np.mean([r['auc'] for r in res]):.4f}, "
          f"{sum(r['losses'] for r in res)} losses in {len(res)} runs")
    return 0


def table(args) -> int:
    def agg(name, seqs, seeds):
        v = []
        for q in seqs:
            for sd in seeds:
                f = Path(args.out) / name / f"{q}_s{sd}.json"
                if not f.exists():
                    return None
                r = json.loads(f.read_text())
                v.append((r["auc"], r["losses"]))
        return np.mean([a for a, _ in v]), sum(n for _, n in v)

    cell = lambda x: "—" if x is None else f"{x[0]:.3f} ({x[1]})"
    sets = ((0, 1, 2), (3, 4, 5))
    print("| sequence | set | " + " | ".join(f"{n}, seeds {s[0]}–{s[-1]}" for s in sets for n in args.names) + " |")
    print("|---|---|" + "---:|" * (len(sets) * len(args.names)))
    for q in A + B:
        print(f"| {q} | {'A' if q in A else 'B'} | "
              + " | ".join(cell(agg(n, [q], s)) for s in sets for n in args.names) + " |")
    for label, seqs in (("A", A), ("B", B), ("all 14", A + B)):
        print(f"| **mean, {label}** | | " + " | ".join(cell(agg(n, seqs, s)) for s in sets for n in args.names) + " |")
    return 0


def _load(out: str, name: str, q: str, sd: int) -> dict:
    """One run's result (``OUT/NAME/SEQ_sSEED.json``)."""
    return json.loads((Path(out) / name / f"{q}_s{sd}.json").read_text())


def _sequences(out: str, names, seeds) -> list[str]:
    """The dev sequences (set A's, then B's) with a result for every variant in ``names`` at every seed: a variant
    run with ``--set A`` or ``--set B`` is compared on its half. Says which were left out; exits if none is left."""
    have = [q for q in A + B if all((Path(out) / n / f"{q}_s{sd}.json").exists() for n in names for sd in seeds)]
    if not have:
        raise SystemExit(f"no sequence has results for {', '.join(names)} at seeds {seeds} under {out}")
    left = [q for q in A + B if q not in have]
    if left:
        print(f"(compared on {len(have)} sequences; without results for every seed: {', '.join(left)})")
    return have


def pair(args) -> int:
    """Mean success AUC of two variants on the same sequences and seeds, their paired difference with a 95%
    interval from resampling the sequences (the 14, or the half both were run on), and the losses, for each seed set given and all of them pooled."""
    load = functools.partial(_load, args.out)
    groups = [[int(x) for x in g.split(",")] for g in args.seeds]
    if len(groups) > 1:
        groups.append(sorted({sd for g in groups for sd in g}))
    a_name, b_name = args.names
    seqs = _sequences(args.out, args.names, groups[-1])
    print(f"| seeds | {a_name} | {b_name} | difference [95%] | losses |")
    print("|---|---:|---:|---:|---:|")
    rng = np.random.default_rng(0)
    for g in groups:
        a = np.array([[load(a_name, q, sd)["auc"] for sd in g] for q in seqs])
        b = np.array([[load(b_name, q, sd)["auc"] for sd in g] for q in seqs])
        d = (b - a).mean(axis=1)
        boot = [d[rng.integers(0, len(d), len(d))].mean() for _ in range(4000)]
        la, lb = (sum(load(n, q, sd)["losses"] for q in seqs for sd in g) for n in (a_name, b_name))
        lo, hi = np.percentile(boot, [2.5, 97.5])
        print(f"| {','.join(map(str, g))} | {a.mean():.3f} | {b.mean():.3f} | {d.mean():+.3f} [{lo:+.3f}, {hi:+.3f}] "
              f"| {la} → {lb} |")
    return 0


def bysequence(args) -> int:
    """Per sequence: two variants' mean success AUC over the seeds, their paired difference (mean ± standard
    error over the seeds) and losses; with a ``--perturb`` run as the second, how far the random stream alone
    moves each sequence — the yardstick for a variant's per-sequence difference."""
    load = functools.partial(_load, args.out)
    seeds = [int(x) for x in args.seeds.split(",")]
    a_name, b_name = args.names
    seqs = _sequences(args.out, args.names, seeds)
    print(f"| sequence | {a_name} | {b_name} | difference (± s.e., {len(seeds)} seeds) | losses |")
    print("|---|---:|---:|---:|---:|")
    for q in seqs:
        a = np.array([load(a_name, q, sd)["auc"] for sd in seeds])
        b = np.array([load(b_name, q, sd)["auc"] for sd in seeds])
        d = b - a
        se = d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else float("nan")
        la, lb = (sum(load(n, q, sd)["losses"] for sd in seeds) for n in (a_name, b_name))
        print(f"| {q} | {a.mean():.3f} | {b.mean():.3f} | {d.mean():+.3f} ± {se:.3f} | {la} → {lb} |")
    return 0


def losses(args) -> int:
    """Per sequence: where a variant's losses recur over the seeds and what its boxes did there
    (:mod:`covviz.experiments.losses`), from the saved boxes and the truth under ``--root``. The boxes are
    saved to two decimals (the OTB results format), so an IoU near a threshold may fall the other way: a
    variant's total may differ from ``run``'s by a few (267 against 261 in 210 runs, the most seen)."""
    from covviz.data.sequences import open_sequence
    from covviz.experiments.losses import JUMP_FRAMES, describe_losses, recurring

    seeds = [int(x) for x in args.seeds.split(",")]
    print(f"| sequence | losses ({len(seeds)} seeds) | found again (median frames) | recurring: lost at (seeds) "
          f"| box / truth size at the loss (median; > 1.6, < 0.6) | centre within 0.75 sizes "
          f"| drift to loss (median frames; within {JUMP_FRAMES}) |")
    print("|---|---:|---:|---|---:|---:|---:|")
    total = Counter()
    for q in A + B:
        gt = open_sequence(str(Path(args.root) / q)).groundtruth
        per_seed = {}
        for sd in seeds:
            f = Path(args.out) / args.name / f"{q}_s{sd}.txt"
            if not f.exists():
                raise SystemExit(f"{f}: no such run (run it first: dev_sweep.py run {args.name} ...)")
            b = np.loadtxt(f, delimiter=",", ndmin=2)
            per_seed[sd] = describe_losses(b, gt[: len(b)])
        ls = [x for v in per_seed.values() for x in v]
        found = [x.frames_lost for x in ls if x.found_again is not None]
        places = ", ".join(f"{a}–{b_} ({c})" for a, b_, c in recurring(per_seed)) or "—"
        r = np.array([x.size_ratio for x in ls])
        near = sum(x.centre_offset < 0.75 for x in ls)
        drift = [x.drift_frames for x in ls]
        jumps = sum(f <= JUMP_FRAMES for f in drift)
        total.update(losses=len(ls), found=len(found), grew=int((r > 1.6).sum()), shrank=int((r < 0.6).sum()),
                     near=near, jumps=jumps)
        size = f"{np.median(r):.2f}; {(r > 1.6).sum()}, {(r < 0.6).sum()}" if len(ls) else "—"
        slide = f"{np.median(drift):.0f}; {jumps}" if ls else "—"
        print(f"| {q} | {len(ls)} | {len(found)}" + (f" ({np.median(found):.0f})" if found else "")
              + f" | {places} | {size} | {near} | {slide} |")
    print(f"| **all** | {total['losses']} | {total['found']} | | {total['grew']}, {total['shrank']} | {total['near']} "
          f"| {total['jumps']} |")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run one variant")
    r.add_argument("name")
    r.add_argument("config", help="a JSON object of ManifoldConfig fields ('{}': the defaults)")
    r.add_argument("--set", choices=sorted(SETS), default="A")
    r.add_argument("--seeds", default="0,1,2")
    r.add_argument("--jobs", type=int, default=2)
    r.add_argument("--perturb", action="store_true",
                   help="a placebo: the tracker draws one random number more after init, so each run follows "
                        "another random stream and nothing else changes; 'pair BASE NAME' then shows how far "
                        "the stream alone moves each sequence (and 'bysequence BASE NAME', per sequence)")
    t = sub.add_parser("table", help="a markdown table of variants already run")
    t.add_argument("names", nargs="+")
    pr = sub.add_parser("pair", help="the paired difference of two variants already run (the second minus the first)")
    pr.add_argument("names", nargs=2)
    pr.add_argument("--seeds", nargs="+", required=True, help="seed sets, e.g. 0,1,2 3,4,5 (pooled too)")
    bs = sub.add_parser("bysequence", help="per sequence: the paired difference of two variants already run")
    bs.add_argument("names", nargs=2)
    bs.add_argument("--seeds", required=True, help="e.g. 0,1,2,3,4,5")
    lo = sub.add_parser("losses", help="per sequence: where a variant's losses recur over the seeds, and how")
    lo.add_argument("name")
    lo.add_argument("--seeds", required=True, help="e.g. 0,1,2,3,4,5")
    for p in (r, lo):
        p.add_argument("--root", default=os.environ.get("COVVIZ_SEQUENCES", "../shared/sequences"))
    for p in (r, t, pr, bs, lo):
        p.add_argument("--out", default="runs/sweep", help="results folder (default runs/sweep, outside git)")
    args = ap.parse_args(argv)
    return {"run": run, "table": table, "pair": pair, "bysequence": bysequence,
            "losses": losses}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
