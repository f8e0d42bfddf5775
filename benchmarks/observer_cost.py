"""What an observer's CPU costs the tracker: work that holds the GIL against work that releases it.

Runs the manifold tracker (600 particles) with a background observer
(:class:`covviz.runner.BackgroundObserver`, as ``covviz track`` runs the
diagnosis and the recorder) that spends a fixed CPU time on every frame, either
in pure Python (holding the GIL, as the diagnosis's and the recorder's many small
numpy and Rerun calls mostly do) or in a compiled numba loop that releases the
GIL (as the descriptor kernels do), with one and with two observe threads, and
without the observer. The runs alternate, their order reversed every round, in one
process; it prints each kind's median wall time a frame and what the observer's
work added to it, per millisecond of its CPU.

It says where an observer's cost goes on a machine: on two cores, a millisecond
of Python on the observer's thread costs the tracker about a millisecond of wall
time whatever the threads, while compiled work that releases the GIL beside one
observe thread takes the idle core nearly for free (``docs/tuning.md``, "where the
recorded and the unrecorded run's time goes").

Usage::

    python benchmarks/observer_cost.py                       # the synthetic default, 6 ms a frame, 3 rounds
    python benchmarks/observer_cost.py ../shared/sequences/Car4 --ms 3 --rounds 5
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", nargs="?", help="a sequence folder; default: the synthetic default")
    ap.add_argument("--frames", type=int, default=199, help="frames a run (default 199)")
    ap.add_argument("--ms", type=float, default=6.0, help="the observer's CPU a frame, milliseconds (default 6)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds of every kind (default 3)")
    args = ap.parse_args(argv)
    if not args.ms > 0 or args.frames < 1 or args.rounds < 1:
        ap.error("--ms must be positive, --frames and --rounds at least 1")

    import numba

    from covviz.data.sequences import SyntheticConfig, SyntheticSequence, open_sequence
    from covviz.runner import BackgroundObserver, Observer, run
    from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker

    seq = SyntheticSequence(SyntheticConfig(n_frames=args.frames)) if args.source is None else open_sequence(args.source)
    n = min(args.frames, len(seq))

    @numba.njit(nogil=True, cache=True)
    def _spin(k):  # compiled arithmetic that releases the GIL
        s = 0.0
        for i in range(k):
            s += np.sqrt(i + 1.0)
        return s

    def python_work(sec: float) -> None:
        t = time.thread_time()
        while time.thread_time() - t < sec:
            sum(range(200))

    def compiled_work(sec: float) -> None:
        t = time.thread_time()
        while time.thread_time() - t < sec:
            _spin(20000)

    class Busy(Observer):
        def __init__(self, work):
            self.work = work

        def on_frame(self, frame, records, found):
            self.work(args.ms / 1e3)

    kinds = {
        "no observer": None,
        "Python (holds the GIL)": python_work,
        "compiled (releases the GIL)": compiled_work,
    }
    _spin(10)

    def one(work, threads: int, frames: int) -> float:
        tracker = ManifoldTracker(ManifoldConfig(n_particles=600, threads=threads), rng=0)
        observers = [] if work is None else [BackgroundObserver(Busy(work))]
        t = time.perf_counter()
        run(tracker, seq, observers, max_frames=frames, seed=0)
        return (time.perf_counter() - t) / frames * 1e3

    runs = [(k, th) for th in (1, 2) for k in kinds]
    for k, th in runs:  # untimed: first calls
        one(kinds[k], th, min(10, n))
    walls: dict = {r: [] for r in runs}
    for r in range(args.rounds):
        for key in runs if r % 2 == 0 else runs[::-1]:
            walls[key].append(one(kinds[key[0]], key[1], n))
        print(f"  round {r + 1} done", flush=True)
    print(f"\n{seq.name if hasattr(seq, 'name') else 'synthetic'}, {n} frames, the observer {args.ms:g} ms of CPU a frame")
    print("| observe threads | observer | wall ms/frame, median (range) | added per ms of the observer's CPU |")
    print("|---:|---|---|---:|")
    for k, th in runs:
        w = walls[(k, th)]
        base = statistics.median(walls[("no observer", th)])
        added = "" if kinds[k] is None else f"{(statistics.median(w) - base) / args.ms:.2f}"
        print(f"| {th} | {k} | {statistics.median(w):.2f} ({min(w):.2f}–{max(w):.2f}) | {added} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
