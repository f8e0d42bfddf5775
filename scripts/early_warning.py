"""Which label-free evidence rises before a loss, and how long before (issue 24's losses, read from a bench).

A loss the filter could still keep is one whose drift lasts: a jump (the box lost on the frame its IoU
began to fall, or the next) is over before anything computed from that frame can act on the next. For
every loss of a ``covviz bench`` folder's runs (the event detector's drift onset and loss,
:func:`covviz.diagnosis.calibrate.losses_of`, on each run's saved per-frame IoU), this prints how many
were jumps and, for the others, which of the given conditions held on some frame from the drift's start to
the frame before the loss, and how many frames ahead of the loss it first did.

A condition is a Python expression over the run's saved signals (``covviz/diagnosis/signals.py``:
``colour``, ``flow_gap``, ``fb_fail``, ``slip``, ``dmin_z``, ...) and ``p``, the saved drift probability;
NaN counts as false. Ground truth is used only to find the losses, never in a condition.

Usage::

    python scripts/early_warning.py runs/bench --tracker manifold
    python scripts/early_warning.py runs/bench --jump 2 'p > 0.5' 'colour > 0.8' 'slip > 0.5' 'dmin_z > 3'
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from covviz.experiments.losses import JUMP_FRAMES

DEFAULT_CONDITIONS = ("p > 0.5", "colour > 0.8", "slip > 0.5", "dmin_z > 3",
                      "(colour > 0.8) & ((flow_gap > 0.3) | (fb_fail > 0.3))")


def _series(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=np.float64)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bench", help="a covviz bench --out folder (SEQ/TRACKER_sS.json with diagnosis signals)")
    ap.add_argument("conditions", nargs="*", default=list(DEFAULT_CONDITIONS),
                    help="expressions over the saved signals and p (default: %(default)s)")
    ap.add_argument("--tracker", default="manifold", help="whose runs (default: %(default)s)")
    ap.add_argument("--jump", type=int, default=JUMP_FRAMES,
                    help="a loss at most this many frames after its drift began is a jump (default: %(default)s)")
    args = ap.parse_args(argv)

    from covviz.diagnosis.calibrate import losses_of

    files = sorted(Path(args.bench).glob(f"*/{args.tracker}_s*.json")) or sorted(
        Path(args.bench).glob(f"*/{args.tracker}.json"))
    if not files:
        print(f"{args.bench}: no {args.tracker} results (SEQ/{args.tracker}_sS.json)", file=sys.stderr)
        return 2
    jumps, slides = 0, []
    for f in files:
        doc = json.loads(f.read_text())
        diag = doc.get("diagnosis") or {}
        if "signals" not in diag or "frame_iou" not in diag:
            print(f"{f}: no diagnosis signals or frame_iou; skipped", file=sys.stderr)
            continue
        env = {k: _series(v) for k, v in diag["signals"].items()}
        v = _series(diag["frame_iou"])
        env["p"] = _series(diag.get("drift_probability") or [None] * len(v))
        for began, lost in losses_of(v):
            if lost - began <= args.jump:
                jumps += 1
                continue
            row = []
            for c in args.conditions:
                with np.errstate(invalid="ignore"):
                    hit = np.nan_to_num(np.asarray(eval(c, {"np": np}, env), dtype=np.float64), nan=0.0) > 0
                w = hit[began - 1: lost - 1]  # frames began .. lost-1 (1-based)
                row.append(int(lost - began - np.argmax(w)) if w.any() else None)
            slides.append((f.parent.name, f.stem, began, lost, row))
    n = jumps + len(slides)
    print(f"{args.tracker}: {n} losses in {len(files)} runs; {jumps} jumps (lost within {args.jump} frames of the "
          f"drift's start), {len(slides)} slides")
    print("\n| condition | slides it rose before the loss on | frames ahead (median) |\n|---|---:|---:|")
    for j, c in enumerate(args.conditions):
        ahead = [r[j] for *_, r in slides if r[j] is not None]
        med = f"{np.median(ahead):.0f}" if ahead else "—"
        print(f"| `{c}` | {len(ahead)} of {len(slides)} | {med} |")
    print("\n| sequence | run | drift began | lost at | " + " | ".join(f"`{c}`" for c in args.conditions) + " |")
    print("|---|---|---:|---:|" + "---:|" * len(args.conditions))
    for q, run, began, lost, row in slides:
        print(f"| {q} | {run} | {began} | {lost} | " + " | ".join("·" if a is None else str(a) for a in row) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
