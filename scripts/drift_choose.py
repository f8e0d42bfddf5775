"""Choose, inside each fold, between the drift model and each single signal's own alarm.

On unseen sequences the default tracker's drift model lost to the flow gap alone (``docs/tuning.md``),
and a model of fewer signals did not help (``scripts/drift_sparse.py``). Here the single signals of
:data:`covviz.diagnosis.calibrate.BASELINES` join the candidates that the nested choice weighs: for each
outer fold (one held-out sequence), a leave-one-sequence-out over its training sequences scores every
model (each feature design and fit target, as :func:`covviz.diagnosis.calibrate.choose_fit` does) and
every single signal (its alarm rule chosen on the inner training sequences by the same rule); the
candidate whose pooled inner held-out alarms rank first by the alarm rule's own order is then fitted
(or its rule chosen) on all the training sequences and scores the held-out one. Nothing of the held-out
sequence is seen. Pooled over set A and set B of ``scripts/dev_sweep.py`` and over all 14.

Usage::

    python scripts/drift_choose.py /tmp/b21/dev
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dev_sweep import ab_cells


def main(argv=None) -> int:
    from covviz.diagnosis import calibrate as cal
    from covviz.diagnosis.detector import DESIGNS, family_of

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bench_dir")
    ap.add_argument("--tracker", default="manifold")
    ap.add_argument("--seeds", default="0,1,2,3,4,5")
    args = ap.parse_args(argv)
    runs = cal.load_runs(args.bench_dir, trackers=[args.tracker], seeds=[int(s) for s in args.seeds.split(",")])
    family = family_of(args.tracker)
    pool = cal.family_runs(runs, family)
    signals = cal.signals_for(sorted({r.tracker for r in pool}))
    feats = {d: dict(zip(map(id, pool), cal._design(pool, signals, d))) for d in DESIGNS}
    print(f"{args.tracker}: {len(runs)} runs, {sum(len(r.losses) for r in runs)} losses")

    def model(d, t, train, test):
        try:
            m = cal.fit_model(train, family, signals, [feats[d][id(r)] for r in train], design=d, target=t)
        except cal.InputError:
            return None
        return cal.held_out_model(m, [feats[d][id(r)] for r in test], test)

    cands = [("model", d, t) for d in DESIGNS for t in cal.TARGETS] + [("signal", b, None) for b in cal.BASELINES]
    seqs = sorted({r.sequence for r in pool if r.tracker == args.tracker})
    chosen: dict = {}
    picks = Counter()
    t0 = time.perf_counter()
    for q in seqs:
        train = [r for r in pool if r.sequence != q]
        test = [r for r in pool if r.sequence == q and r.tracker == args.tracker]
        inner = sorted({r.sequence for r in train})
        keys = {}
        for c in cands:
            counts = []
            for p in inner:
                tr = [r for r in train if r.sequence != p]
                te = [r for r in train if r.sequence == p]
                got = model(c[1], c[2], tr, te) if c[0] == "model" else cal.held_out_signal(c[1], tr, te)
                counts += [cnt for _, cnt, _ in (got or [])]
            if counts:
                keys[c] = (*cal._rule_key(cal._pool(counts)), c == ("model", "changes", cal.FIT_TARGET))
        best = max(keys, key=keys.get)
        picks[best] += 1
        chosen[q] = model(best[1], best[2], train, test) if best[0] == "model" else cal.held_out_signal(best[1], train, test)
        print(f"  {q}: {' '.join(x for x in best if x)} (held out: {len(test)} runs; "
              f"{time.perf_counter() - t0:.0f} s)", flush=True)
    print("| method | A: precision / recall | B: precision / recall | all 14 |")
    print("|---|---:|---:|---:|")
    print("| chosen in each fold | " + " | ".join(ab_cells(chosen)) + " |")
    print("chosen: " + "; ".join(f"{' '.join(x for x in c if x)} ×{n}" for c, n in picks.most_common()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
