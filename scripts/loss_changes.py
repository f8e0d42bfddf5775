"""What a change of the tracker did to each loss: two `covviz bench --counterfactual` folders, loss by loss.

Each loss of BEFORE is matched one to one with a loss of AFTER in the same sequence and seed lost within
``--within`` frames of it, nearest first (the report's matching of losses across seeds,
:func:`covviz.experiments.report_counterfactual.match_losses`); a loss with no match was kept by the change, a
loss of AFTER left unmatched is new. Prints the fate of BEFORE's losses by verdict (kept, or still lost with which verdict), the new losses by
verdict, and every kept and new loss. How docs/tuning.md's "the observation pull becomes the default" counted::

    covviz bench ../shared/sequences --trackers manifold --seeds 3 --counterfactual \
        --config '{"observation_pull": 0.0}' --out runs/bench-prevdefault
    python scripts/loss_changes.py runs/bench-prevdefault runs/bench --seeds 0,1,2
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from covviz.experiments.report import load_runs
from covviz.experiments.report_counterfactual import MATCH_FRAMES, match_losses


def losses(folder: str, tracker: str, seeds: set[int] | None) -> dict[tuple[str, int], list[tuple[int, str]]]:
    """``(sequence, seed) -> [(lost_at, verdict), ...]`` of one tracker's runs in a bench folder."""
    _, runs, _ = load_runs(folder)
    out: dict[tuple[str, int], list[tuple[int, str]]] = {}
    for r in runs:
        if r.tracker != tracker or (seeds is not None and r.seed not in seeds):
            continue
        out[(r.sequence, r.seed)] = [(lr.lost_at, lr.verdict or "not replayed") for lr in r.loss_replays]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", help="bench folder of the tracker before the change")
    ap.add_argument("after", help="bench folder of the tracker after it")
    ap.add_argument("--tracker", default="manifold", help="tracker name in both folders (default manifold)")
    ap.add_argument("--seeds", default=None, help="comma-separated seeds to compare (default: every seed)")
    ap.add_argument("--within", type=int, default=MATCH_FRAMES,
                    help=f"frames between two losses that match (default {MATCH_FRAMES})")
    a = ap.parse_args(argv)
    seeds = None if a.seeds is None else {int(s) for s in a.seeds.split(",")}
    old, new = losses(a.before, a.tracker, seeds), losses(a.after, a.tracker, seeds)
    missing = sorted(set(old) ^ set(new))
    if missing:
        print(f"error: runs in only one folder: {missing[:5]}{' ...' if len(missing) > 5 else ''}", file=sys.stderr)
        return 2
    fate: Counter = Counter()
    added: Counter = Counter()
    rows = []
    for key in sorted(old):
        pairs, unmatched = match_losses({"before": old[key], "after": new[key]}, a.within)
        for x, y in pairs:
            (_, _, was), (_, _, now) = sorted((x, y), key=lambda t: t[0] != "before")
            fate[(was, f"still lost: {now}")] += 1
        for side, frame, verdict in unmatched:
            if side == "before":
                fate[(verdict, "kept")] += 1
                rows.append((*key, frame, f"kept (was {verdict})"))
            else:
                added[verdict] += 1
                rows.append((*key, frame, f"new ({verdict})"))
    n_old = sum(len(v) for v in old.values())
    n_new = sum(len(v) for v in new.values())
    print(f"{a.tracker}: {n_old} losses before, {n_new} after, {len(old)} runs")
    print("| before | after | losses |\n|---|---|---:|")
    for (v, what), c in sorted(fate.items()):
        print(f"| {v} | {what} | {c} |")
    print(f"new losses by verdict: {dict(sorted(added.items()))}")
    for seq, seed, frame, what in rows:
        print(f"  {seq} s{seed} at {frame}: {what}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
