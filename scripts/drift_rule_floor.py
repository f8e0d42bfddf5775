"""Does the detector's verdict against the single signals depend on the alarm rule's precision floor?

Issue 21 asks that the default tracker's alarms be ahead of every single signal on both event precision and
recall, leave one sequence out, with the model's and each signal's alarm rule chosen inside each fold by the
same rule: the most event recall at a training precision of at least ``calibrate.MIN_PRECISION`` (0.5). That
rule puts every method at the far end of its own precision-recall curve, where a signal whose recall runs out
early can end with a higher precision than a better model that goes on finding losses. This script runs the
same leave-one-sequence-out evaluation (:func:`covviz.diagnosis.calibrate.loso`, every fold's design, fit,
gate and thresholds chosen on its training sequences only) with the floor at each level given, the same for
the model and for every signal, and prints the held-out precision and recall of each. It changes nothing that
ships: a floor other than 0.5 would be a decision of its own, made on other seeds than the ones it is read on.

Usage::

    python scripts/drift_rule_floor.py BENCH_DIR --tracker manifold --seeds 0-5 --floors 0.5,0.6,0.7 --jobs 2

``BENCH_DIR``: runs of ``covviz bench`` (with their ``diagnosis.signals``), e.g. ``covviz bench
../shared/sequences --trackers manifold --seeds 6 --jobs 2 --out runs/bench-drift --no-report``.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from drift_eval import TRACKERS, goals, loso_tables  # this folder is on sys.path when run as a script


def _one(bench_dir: str, tracker: str, seeds: set[int], floor: float) -> tuple[float, list[str], list[str]]:
    """drift_eval's single-signal table and goal lines for ``tracker`` with the rule's floor at ``floor``."""
    from covviz.diagnosis import calibrate
    from covviz.threads import limit_threads

    calibrate.MIN_PRECISION = floor  # read by the rule's order (calibrate._rule_key) at each call
    runs = calibrate.load_runs(bench_dir, seeds=seeds)
    with limit_threads(1):
        res = calibrate.loso(runs, tracker)
    _, base, found = loso_tables([r for r in runs if r.tracker == tracker], np.random.default_rng(0),
                                 results={(tracker, None): res})
    return floor, base, goals(found)


def main(argv=None) -> int:
    from covviz.diagnosis.calibrate import parse_seeds

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bench_dir")
    ap.add_argument("--tracker", default="manifold", choices=TRACKERS)
    ap.add_argument("--seeds", default="0-5", help="the runs' seeds to use (default 0-5)")
    ap.add_argument("--floors", default="0.5,0.6,0.7", help="the rule's precision floors (default 0.5,0.6,0.7)")
    ap.add_argument("--jobs", type=int, default=1, help="floors evaluated at a time, each in a process")
    args = ap.parse_args(argv)
    floors = [float(v) for v in args.floors.split(",")]
    if any(not 0 < f < 1 for f in floors):
        ap.error("--floors: each floor must be between 0 and 1")
    seeds = parse_seeds(args.seeds)
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as ex:
        done = list(ex.map(_one, *zip(*[(args.bench_dir, args.tracker, seeds, f) for f in floors])))
    print(f"{args.tracker}, seeds {args.seeds}, leave one sequence out, the rule's precision floor for the model "
          "and every signal alike:")
    for floor, base, said in done:
        print(f"\nfloor {floor:g}:")
        print("\n".join(base + said))
    return 0


if __name__ == "__main__":
    sys.exit(main())
