"""Score candidate drift-model files for one tracker side by side: on a bench folder's runs of the seeds they
were not fitted on, and by their false alarms on the synthetic default (no failure, 300 frames a seed).

What decides between a fitted model and a fixed design (docs/tuning.md): the same numbers as
``scripts/drift_eval.py``'s shipped-model table, for files that are not (yet) shipped.

Usage::

    python scripts/compare_drift_models.py runs/bench-drift --seeds 6-8 A.json B.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from drift_eval import (  # this folder is on sys.path when run as a script
    _seeds,
    model_scores,
    synthetic_alarms,
)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bench_dir", type=Path, help="a covviz bench folder with the diagnosis' signals saved")
    ap.add_argument("models", nargs="+", type=Path, help="drift model files (covviz calibrate --out)")
    ap.add_argument("--tracker", default="manifold", help="whose runs to score (default manifold)")
    ap.add_argument("--seeds", default="6-8", type=_seeds, help="the seeds to score on (default 6-8)")
    ap.add_argument("--synthetic-seeds", default=10, type=int, help="synthetic default runs (default 10; 0: none)")
    args = ap.parse_args(argv)
    for f in args.models:
        if not f.is_file():
            ap.error(f"no model file {f}")

    from covviz.diagnosis.calibrate import load_runs
    from covviz.diagnosis.detector import DriftModel

    runs = load_runs(args.bench_dir, trackers=[args.tracker], seeds=args.seeds)
    if not runs:
        ap.error(f"no {args.tracker} runs of seeds {sorted(args.seeds)} in {args.bench_dir}")
    print(f"{len(runs)} {args.tracker} runs of seeds {sorted(args.seeds)}; synthetic default seeds 0-{args.synthetic_seeds - 1}")
    for f in args.models:
        m = DriftModel.load(f)
        _, c, pr, rc, fa = model_scores(m, runs)
        lines, total = synthetic_alarms(range(args.synthetic_seeds), detector=m, tracker=args.tracker)
        print(f"{f}: {m.design} design; {c['losses']} losses, {c['found']} found, {c['alarms']} alarms, "
              f"precision {100 * pr:.0f}%, recall {100 * rc:.0f}%, {fa:.1f} false per 1000 on-track; "
              f"synthetic: {total} alarm(s)")
        for line in lines:
            print(f"  {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
