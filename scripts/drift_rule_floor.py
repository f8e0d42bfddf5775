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

``--order`` sets how the rule ranks the candidates at the floor (``calibrate.RULE_ORDER``): ``losses`` (today's:
the losses found less the weighed false alarms), ``alarms`` (the right alarms in place of the losses found) or
``recall`` (the first order: the most recall).

``--rule-on fit,held-out`` also runs each floor with a many-signal model's rule chosen on its own fitted
probabilities (``fit``, as before ``calibrate.RULE_ON_HELD_OUT``) and on its training sequences' held-out ones
(``held-out``, today's); ``--models-only`` leaves the single-signal designs out of each fold's choice, so the
model in the table is one of many signals whatever a fold would have chosen (the rule's effect on those models
is otherwise hidden wherever a single signal wins the choice).

Usage::

    python scripts/drift_rule_floor.py BENCH_DIR --tracker manifold --seeds 0-5 --floors 0.5,0.6,0.7 --jobs 2
    python scripts/drift_rule_floor.py BENCH_DIR --floors 0.5 --rule-on fit,held-out --models-only --jobs 2
    python scripts/drift_rule_floor.py BENCH_DIR --floors 0.5 --order losses,alarms,recall --jobs 2

``BENCH_DIR``: runs of ``covviz bench`` (with their ``diagnosis.signals``), e.g. ``covviz bench
../shared/sequences --trackers manifold --seeds 6 --jobs 2 --out runs/bench-drift --no-report``.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from drift_eval import TRACKERS, goals, loso_tables  # this folder is on sys.path when run as a script


def _one(bench_dir: str, tracker: str, seeds: set[int], floor: float, rule_on: str = "held-out",
         models_only: bool = False, order: str = "losses") -> tuple[str, list[str], list[str]]:
    """drift_eval's main and single-signal tables and goal lines for ``tracker`` with the rule's floor at
    ``floor`` and a many-signal model's rule chosen on ``rule_on`` probabilities (``fit`` or ``held-out``)."""
    from covviz.diagnosis import calibrate
    from covviz.threads import limit_threads

    calibrate.MIN_PRECISION = floor  # read by the rule's order (calibrate._rule_key) at each call
    calibrate.RULE_ON_HELD_OUT = rule_on == "held-out"  # read by calibrate.loso at each fold
    calibrate.RULE_ORDER = order  # read by calibrate._rule_key at each call
    if models_only:
        every = calibrate.candidates
        calibrate.candidates = lambda signals, designs=calibrate.DESIGNS: tuple(
            d for d in every(signals, designs) if not d.startswith("signal"))
    runs = calibrate.load_runs(bench_dir, seeds=seeds)
    with limit_threads(1):
        res = calibrate.loso(runs, tracker)
    main, base, found = loso_tables([r for r in runs if r.tracker == tracker], np.random.default_rng(0),
                                    results={(tracker, None): res})
    return f"floor {floor:g}, order {order}, rule on {rule_on}" + (", models of many signals only" if models_only else ""), \
        main + [""] + base, goals(found)


def main(argv=None) -> int:
    from covviz.diagnosis.calibrate import RULE_ORDERS, parse_seeds

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bench_dir")
    ap.add_argument("--tracker", default="manifold", choices=TRACKERS)
    ap.add_argument("--seeds", default="0-5", help="the runs' seeds to use (default 0-5)")
    ap.add_argument("--floors", default="0.5,0.6,0.7", help="the rule's precision floors (default 0.5,0.6,0.7)")
    ap.add_argument("--rule-on", default="held-out",
                    help="what a many-signal model's rule is chosen on: fit, held-out or both, comma-separated "
                         "(default held-out, as calibrate does)")
    ap.add_argument("--models-only", action="store_true",
                    help="leave the single-signal designs out of each fold's choice")
    ap.add_argument("--order", default="losses",
                    help="how the rule ranks the candidates at the floor: losses, alarms or recall, or several "
                         "comma-separated (calibrate.RULE_ORDER; default losses, as calibrate does)")
    ap.add_argument("--jobs", type=int, default=1, help="settings evaluated at a time, each in a process")
    args = ap.parse_args(argv)
    floors = [float(v) for v in args.floors.split(",")]
    if any(not 0 < f < 1 for f in floors):
        ap.error("--floors: each floor must be between 0 and 1")
    rule_on = args.rule_on.split(",")
    if not rule_on or set(rule_on) - {"fit", "held-out"}:
        ap.error(f"--rule-on: give fit, held-out or fit,held-out, not {args.rule_on!r}")
    orders = args.order.split(",")
    if not orders or set(orders) - set(RULE_ORDERS):
        ap.error(f"--order: give {', '.join(RULE_ORDERS)} (or several, comma-separated), not {args.order!r}")
    seeds = parse_seeds(args.seeds)
    jobs = [(args.bench_dir, args.tracker, seeds, f, r, args.models_only, o) for f in floors for r in rule_on
            for o in orders]
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as ex:
        done = list(ex.map(_one, *zip(*jobs)))
    print(f"{args.tracker}, seeds {args.seeds}, leave one sequence out, the rule's precision floor for the model "
          "and every signal alike:")
    for name, tables, said in done:
        print(f"\n{name}:")
        print("\n".join(tables + said))
    return 0


if __name__ == "__main__":
    sys.exit(main())
