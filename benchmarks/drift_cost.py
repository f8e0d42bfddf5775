"""CPU cost of the label-free drift detector per frame (issue 21), side by side for several trackers.

For each tracker the run goes through the runner with the detector (:class:`covviz.diagnosis.detector.DriftWatch`)
inline, so its thread CPU time is its own: the signals (forward-backward LK, the looks, the particle
signals), then the model and the alarm rule. The tracker's own ``update()`` time is printed beside it
for scale. In ``covviz track`` / ``covviz bench`` the detector runs on its own thread
(:class:`covviz.runner.BackgroundObserver`), off the tracker's critical path.

Usage::

    python benchmarks/drift_cost.py ../shared/sequences/Car4 --frames 300 --trackers manifold,csrt --threads 1
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequence")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--trackers", default="manifold,csrt")
    ap.add_argument("--particles", type=int, default=600)
    ap.add_argument("--threads", type=int, default=1, help="BLAS/OpenCV threads (default 1)")
    ap.add_argument("--repeats", type=int, default=2, help="runs per tracker; the best is shown")
    args = ap.parse_args(argv)

    from covviz.data.sequences import open_sequence
    from covviz.diagnosis.detector import DriftWatch
    from covviz.runner import run
    from covviz.threads import limit_threads
    from covviz.trackers import STOCHASTIC, make_tracker

    seq = open_sequence(args.sequence)
    h, w = seq.frame(0).image.shape[:2]
    print(f"{seq.name}: {min(args.frames, len(seq))} frames of {w}x{h}, {args.threads} thread(s), best of "
          f"{args.repeats}")
    print("| tracker | particles | signals ms CPU / frame | model + alarms ms | detector total ms | "
          "tracker update ms |")
    print("|---|---:|---:|---:|---:|---:|")
    with limit_threads(args.threads):
        for name in args.trackers.split(","):
            best = None
            for _ in range(args.repeats):
                n = args.particles if name in STOCHASTIC else None
                watch = DriftWatch()
                t0 = time.perf_counter()
                res = run(make_tracker(name, seed=0, n_particles=n), seq, [watch], max_frames=args.frames, seed=0)
                _ = time.perf_counter() - t0
                rep = watch.report(0)
                row = (rep["signals_cpu_ms"], rep["model_cpu_ms"], 1e3 * float(np.median(res.times[1:])))
                if best is None or row[0] + row[1] < best[0] + best[1]:
                    best = row
            sig, mod, upd = best
            print(f"| `{name}` | {args.particles if name in STOCHASTIC else '—'} | {sig:.2f} | {mod:.3f} | "
                  f"{sig + mod:.2f} | {upd:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
