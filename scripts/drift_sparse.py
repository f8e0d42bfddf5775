"""A drift model of a few signals, chosen inside each fold, against the full model and the flow gap alone.

The shipped model reads every signal (48 standardised features for a particle filter) and, on unseen
sequences, lost to the flow gap alone (``docs/tuning.md``). Here the model reads only ``k`` signals,
chosen by greedy forward selection on each fold's training sequences (the signal whose addition gives
the best training alarms by the alarm rule's own order, :func:`covviz.diagnosis.calibrate.choose_alarm`),
then fitted there with the ``levels`` design and the episodes target; the held-out sequence is scored.
Everything else is as ``scripts/drift_eval.py`` (leave-one-sequence-out, rules chosen on training runs
only). The held-out alarms are pooled over set A and set B of ``scripts/dev_sweep.py`` separately, so
``k`` chosen by looking at A is confirmed on B.

Usage::

    python scripts/drift_sparse.py /tmp/b21/dev --k 1 2 3
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dev_sweep import ab_cells


def forward(train, family, candidates, k, cal):
    """The ``k`` signals chosen greedily on ``train`` (training alarms), in the order chosen."""
    chosen: list[str] = []
    for _ in range(k):
        best, best_key = None, None
        for s in candidates:
            if s in chosen:
                continue
            sig = (*chosen, s)
            try:
                m = cal.fit_model(train, family, sig, design="levels")
            except cal.InputError:
                continue
            feats = cal._design(train, sig, "levels")
            counts = [cal.score_alarms(cal.alarm_frames(m.probability(f), m.alarm), r) for f, r in zip(feats, train)]
            key = cal._rule_key(cal._pool(counts))
            if best_key is None or key > best_key:
                best, best_key = s, key
        if best is None:
            break
        chosen.append(best)
    return tuple(chosen)


def main(argv=None) -> int:
    from covviz.diagnosis import calibrate as cal
    from covviz.diagnosis.detector import family_of

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bench_dir")
    ap.add_argument("--k", type=int, nargs="+", default=[1, 2, 3], help="numbers of signals to try")
    ap.add_argument("--tracker", default="manifold")
    ap.add_argument("--seeds", default="0,1,2,3,4,5")
    ap.add_argument("--no-base", action="store_true", help="skip the full model and the flow gap (about 8 min)")
    args = ap.parse_args(argv)
    runs = cal.load_runs(args.bench_dir, trackers=[args.tracker], seeds=[int(s) for s in args.seeds.split(",")])
    family = family_of(args.tracker)
    pool = cal.family_runs(runs, family)
    candidates = cal.signals_for(sorted({r.tracker for r in pool}))
    print(f"{args.tracker}: {len(runs)} runs, {sum(len(r.losses) for r in runs)} losses; "
          f"candidates: {', '.join(candidates)}")
    seqs = sorted({r.sequence for r in pool if r.tracker == args.tracker})
    kmax = max(args.k)
    res: dict[int, dict] = {k: {} for k in args.k}
    picks: dict[int, Counter] = {k: Counter() for k in args.k}
    t0 = time.perf_counter()
    for q in seqs:
        train = [r for r in pool if r.sequence != q]
        test = [r for r in pool if r.sequence == q and r.tracker == args.tracker]
        order = forward(train, family, candidates, kmax, cal)
        for k in args.k:
            sig = order[:k]
            picks[k][sig] += 1
            m = cal.fit_model(train, family, sig, design="levels")
            res[k][q] = cal.held_out_model(m, cal._design(test, sig, "levels"), test)
        print(f"  {q}: {', '.join(order)} ({time.perf_counter() - t0:.0f} s)", flush=True)
    base = None if args.no_base else cal.loso(runs, args.tracker)
    print("| method | A: precision / recall | B: precision / recall | all 14 |")
    print("|---|---:|---:|---:|")
    rows = [(f"{k} signal{'s' if k > 1 else ''}", res[k]) for k in args.k]
    if base is not None:
        rows += [("full model", base["model"]), ("flow gap", base["flow gap"])]
    for name, per in rows:
        print(f"| {name} | " + " | ".join(ab_cells(per)) + " |")
    for k in args.k:
        print(f"k = {k}: " + "; ".join(f"{'+'.join(s)} ×{n}" for s, n in picks[k].most_common()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
