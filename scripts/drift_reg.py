"""The drift model's regularisation, chosen on half of the dev sequences and confirmed on the other half.

Leave-one-sequence-out over all 14 dev sequences of one tracker, exactly as ``scripts/drift_eval.py``
(the design and fit target chosen inside each fold), once per value of the logistic regression's
inverse strength ``C`` (:data:`covviz.diagnosis.calibrate.C_REG`); the held-out alarms are then pooled
over set A and over set B of ``scripts/dev_sweep.py`` separately, so a value chosen by looking at A is
confirmed on B. Prints precision and recall of the model and of the flow gap and the slip alone (the
strongest single signals).

Usage::

    python scripts/drift_reg.py /tmp/b21/dev --C 1 0.001
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dev_sweep import ab_cells


def main(argv=None) -> int:
    from covviz.diagnosis import calibrate as cal

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bench_dir")
    ap.add_argument("--C", type=float, nargs="+", default=[cal.C_REG], help="values of C to evaluate")
    ap.add_argument("--tracker", default="manifold")
    ap.add_argument("--seeds", default="0,1,2,3,4,5")
    args = ap.parse_args(argv)
    runs = cal.load_runs(args.bench_dir, trackers=[args.tracker], seeds=[int(s) for s in args.seeds.split(",")])
    print(f"{args.tracker}: {len(runs)} runs, {sum(len(r.losses) for r in runs)} losses")
    print("| C | method | A: precision / recall | B: precision / recall | all 14 |")
    print("|---:|---|---:|---:|---:|")
    for c in args.C:
        cal.C_REG = c
        t0 = time.perf_counter()
        res = cal.loso(runs, args.tracker)
        for name in ("model", "flow gap", "slip"):
            print(f"| {c:g} | {name} | " + " | ".join(ab_cells(res[name])) + " |", flush=True)
        print(f"(C = {c:g}: {time.perf_counter() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
