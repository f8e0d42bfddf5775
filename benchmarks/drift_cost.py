"""CPU cost of the label-free drift detector and of the drift diagnosis per frame, side by side for several trackers.

Each tracker runs once over the frames through the runner (its ``update()`` CPU time is measured around
each call); its records are kept, then the detector (:class:`covviz.diagnosis.detector.DriftWatch`: the
signals — forward-backward LK, the looks, the particle signals — then the model and the alarm rule) is
replayed over them ``--repeats`` times, its thread CPU read once before and once after the whole replay
(the clock is a system call on some machines). The best replay is shown. The drift diagnosis
(:class:`covviz.diagnosis.drift.Diagnoser`, which reads the ground truth) is replayed the same way, as
``covviz track --no-save`` and ``covviz bench`` run it (the template cloud scored off track only) and as a
recording runs it (scored on every frame, for the recorder's why-view). In ``covviz track`` / ``covviz
bench`` both run on one thread of their own (:class:`covviz.runner.BackgroundObserver`), beside the
tracker's threads on the same cores.

Usage::

    python benchmarks/drift_cost.py ../shared/sequences/Car4 --frames 200 --trackers manifold,csrt --threads 1
"""

from __future__ import annotations

import argparse
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequence")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--trackers", default="manifold,csrt")
    ap.add_argument("--particles", type=int, default=600)
    ap.add_argument("--threads", type=int, default=1, help="BLAS/OpenCV threads (default 1)")
    ap.add_argument("--repeats", type=int, default=3, help="replays of the detector; the best is shown")
    args = ap.parse_args(argv)

    from covviz.data.sequences import open_sequence
    from covviz.diagnosis.detector import DriftWatch
    from covviz.diagnosis.drift import Diagnoser
    from covviz.runner import NOTHING, Observer, run
    from covviz.threads import limit_threads
    from covviz.trackers import STOCHASTIC, make_tracker

    seq = open_sequence(args.sequence)
    h, w = seq.frame(0).image.shape[:2]
    print(f"{seq.name}: {min(args.frames, len(seq))} frames of {w}x{h}, {args.threads} thread(s), best of "
          f"{args.repeats}")
    print("| tracker | particles | signals (ms CPU / frame) | model + alarms | detector, whole replay | "
          "diagnosis, no recorder | diagnosis, recorded | tracker run (process CPU / frame, decoding included) |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    class Capture(Observer):
        def __init__(self):
            self.items, self.cpu = [], []
            self._t = None
            self.start = None

        def on_start(self, start, found):
            self.start = start

        def on_frame(self, frame, records, found):
            self.items.append((frame, records))

    with limit_threads(args.threads):
        for name in args.trackers.split(","):
            n = args.particles if name in STOCHASTIC else None
            tracker = make_tracker(name, seed=0, n_particles=n)
            cap = Capture()
            t0 = time.process_time()
            run(tracker, seq, [cap], max_frames=args.frames, seed=0)
            track_cpu = (time.process_time() - t0) / len(cap.items)
            best = None
            for _ in range(args.repeats):
                watch = DriftWatch()
                found = watch.on_start(cap.start, NOTHING)
                t0 = time.thread_time()
                for frame, records in cap.items:
                    watch.on_frame(frame, records, found)
                total = (time.thread_time() - t0) / len(cap.items)
                cpu = watch.cpu_ms()
                if best is None or total < best[0]:
                    best = (total, cpu)
            total, cpu = best
            diag = {}
            for scores in (False, True):
                for _ in range(args.repeats):
                    dg = Diagnoser(on_track_scores=scores)
                    found = dg.on_start(cap.start, NOTHING)
                    t0 = time.thread_time()
                    for frame, records in cap.items:
                        dg.on_frame(frame, records, found)
                    t = (time.thread_time() - t0) / len(cap.items)
                    diag[scores] = min(diag.get(scores, t), t)
            print(f"| `{name}` | {n or '—'} | {cpu['signals']:.2f} | {cpu['model']:.3f} | {1e3 * total:.2f} | "
                  f"{1e3 * diag[False]:.2f} | {1e3 * diag[True]:.2f} | {1e3 * track_cpu:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
