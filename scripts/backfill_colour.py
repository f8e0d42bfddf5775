"""Add the ``colour`` signal to bench results made before it existed, from their saved boxes
(:mod:`covviz.diagnosis.backfill` says how, and how far the values can differ from a run's own).

Usage::

    python scripts/backfill_colour.py runs/bench-drift               # sequences under ../shared/sequences
    python scripts/backfill_colour.py runs/bench-drift --root DIR --force
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from covviz.diagnosis.backfill import backfill_colour


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bench", type=Path, help="a covviz bench --out folder")
    ap.add_argument("--root", type=Path, default=Path("../shared/sequences"), help="the sequences' folder")
    ap.add_argument("--force", action="store_true", help="recompute results that already have the signal")
    args = ap.parse_args(argv)
    if not args.bench.is_dir():
        ap.error(f"{args.bench}: no such folder")
    done, kept = backfill_colour(args.bench, args.root, args.force, progress=True)
    print(f"backfilled {done} result(s), kept {kept}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
