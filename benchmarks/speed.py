"""Speed of the trackers' update(), side by side in one process.

Prints the machine (CPU model, cores, load), then, for the manifold tracker at
300 / 600 / 1000 particles, with its quadrant term (the default) and without it
(the paper's likelihood), with the compiled kernels and/or the numpy path, the
mean per-frame time of ``update()`` broken down by stage (propagate, warp,
features, covariance, distances, weights, estimate, resample), its frames per
second, and the ratio to OpenCV's CSRT (and the IPCA baseline) run on the same
frames in the same process (frames decoded once, before timing). Last, the
whole ``covviz track --no-save`` process of manifold and CSRT, alternating:
the rate a user sees, start to end.

Usage::

    python benchmarks/speed.py                       # the synthetic 320x240 default
    python benchmarks/speed.py ../shared/sequences/Car1 --frames 200
    python benchmarks/speed.py --threads 1           # pin BLAS/OpenCV to one thread
    python benchmarks/speed.py --quadrants on         # only the default tracker
    python benchmarks/speed.py --jit both             # with and without the compiled kernels
    python benchmarks/speed.py --quadrants on --terms both   # the default with and without issue 14's terms
    python benchmarks/speed.py ../shared/sequences/Car4 --frames 199 --particles 600 --whole 5

These machines are noisy: compare ratios measured side by side in one run, and
use ``--repeat`` to take the best of several passes.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np


def machine() -> str:
    """One line naming the machine: CPU model, logical cores, load average (for absolute figures)."""
    model = "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        import platform

        model = platform.processor() or model
    load = ", load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()) if hasattr(os, "getloadavg") else ""
    return f"machine: {model}, {os.cpu_count()} logical cores{load}"


def _set_threads(n: int | None) -> None:
    """Limit BLAS (threadpoolctl) and OpenCV to ``n`` threads each."""
    if n is None:
        return
    import cv2
    from threadpoolctl import threadpool_limits

    threadpool_limits(n)
    cv2.setNumThreads(n)


def time_tracker(make, frames, box, repeat: int):
    """Best-of-``repeat`` mean update() time (s) and mean stage timings (s)."""
    best, best_stages = np.inf, {}
    for _ in range(repeat):
        tr = make()
        tr.init(frames[0], box)
        stages: dict[str, float] = {}
        t0 = time.perf_counter()
        for f in frames[1:]:
            tr.update(f)
            rec = tr.last_record
            if rec is not None:
                for k, v in rec.timings.items():
                    stages[k] = stages.get(k, 0.0) + v
        dt = (time.perf_counter() - t0) / (len(frames) - 1)
        if dt < best:
            best, best_stages = dt, {k: v / (len(frames) - 1) for k, v in stages.items()}
    return best, best_stages


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", nargs="?", default=None, help="sequence (default: the synthetic 320x240 one)")
    ap.add_argument("--frames", type=int, default=150, help="frames to time (default 150)")
    ap.add_argument("--particles", default="300,600,1000", help="particle counts (default 300,600,1000)")
    ap.add_argument("--repeat", type=int, default=2, help="passes per tracker; the best is kept (default 2)")
    ap.add_argument("--threads", type=int, default=None,
                    help="limit BLAS and OpenCV to this many threads (default: the libraries' own)")
    ap.add_argument("--observe-threads", type=int, default=1,
                    help="ManifoldConfig.threads: threads sharing the particles' descriptors (default 1)")
    ap.add_argument("--quadrants", choices=("both", "on", "off"), default="both",
                    help="time the tracker with its quadrant term (on, the default tracker), without it "
                         "(off, the paper's likelihood) or both, side by side (default both)")
    ap.add_argument("--terms", choices=("both", "on", "off"), default="on",
                    help="time the tracker with the terms added by issue 14 (on: the derivative normalisation "
                         "and the colour term, as configured by default), without them (off: "
                         "manifold.NEW_TERMS_OFF) or both, side by side (default on); --quadrants off --terms "
                         "off is the paper's likelihood")
    ap.add_argument("--whole", type=int, default=3, metavar="K",
                    help="also time the whole 'covviz track SEQ --max-frames N --no-save' process of manifold and "
                         "csrt, K times each, alternating (0: skip; default 3)")
    ap.add_argument("--jit", choices=("on", "off", "both"), default="on",
                    help="time the tracker with the compiled kernels (on, the default when numba is installed), "
                         "with the numpy path (off) or both, side by side (default on)")
    args = ap.parse_args(argv)
    _set_threads(args.threads)

    import cv2

    from covviz.data.sequences import open_sequence
    from covviz.model import kernels
    from covviz.trackers import make_tracker
    from covviz.trackers.manifold import NEW_TERMS_OFF, ManifoldConfig, ManifoldTracker

    seq = open_sequence(args.sequence)
    n = min(args.frames + 1, len(seq))
    frames = [seq.frame(i).image for i in range(n)]
    box = seq.init_box
    H, W = frames[0].shape[:2]
    print(machine())
    print(f"sequence {seq.name}: {W}x{H}, {n - 1} timed frames, best of {args.repeat}; "
          f"{os.cpu_count()} cpus, OpenCV threads {cv2.getNumThreads()}, observe threads {args.observe_threads}")
    jits = {"on": (True,), "off": (False,), "both": (False, True)}[args.jit]
    if True in jits:
        if not kernels.JIT_ENABLED:
            print("  (the compiled kernels are disabled: COVVIZ_NO_JIT=1 or numba missing)")
            jits = (False,)
        else:
            kernels.warmup(lambda: print("  compiling kernels (once)..."))

    peers = {}
    for name in ("csrt", "ipca"):
        try:
            make = lambda name=name: make_tracker(name, rng=0)
            make()
        except (ImportError, ValueError, AttributeError) as exc:
            print(f"  ({name} unavailable: {exc})")
            continue
        peers[name] = time_tracker(make, frames, box, args.repeat)[0]

    stage_names = ("propagate", "colour", "warp", "features", "covariance", "distances", "weights", "estimate",
                   "resample")
    header = f"{'quadrants':>9} {'terms':>5} {'jit':>4} {'particles':>9} {'ms/frame':>9} {'fps':>7} "
    header += " ".join(f"{s:>10}" for s in stage_names)
    header += "".join(f" {'x ' + p:>8}" for p in peers)
    print("\nmanifold tracker, mean ms per update() by stage")
    print(header)
    variants = {"both": (True, False), "on": (True,), "off": (False,)}[args.quadrants]
    term_variants = {"both": (False, True), "on": (True,), "off": (False,)}[args.terms]
    for k in (int(v) for v in args.particles.split(",")):
        for quad in variants:
            for terms in term_variants:
                for jit in jits:
                    cfg = ManifoldConfig().replace(n_particles=k, threads=args.observe_threads, jit=jit,
                                         **{**({} if terms else NEW_TERMS_OFF), "quadrants": quad})
                    dt, st = time_tracker(lambda cfg=cfg: ManifoldTracker(cfg, rng=0), frames, box, args.repeat)
                    _row(k, quad, terms, jit, dt, st, stage_names, peers)
    for p, pt in peers.items():
        print(f"{p}: {1e3 * pt:.2f} ms/frame, {1 / pt:.1f} fps")
    if args.whole:
        whole_process(args.sequence, n, args.whole)
    print("\n'x csrt' = CSRT's time / manifold's time on the same frames (>1: manifold is faster).")
    if True in jits:
        print("jit on: 'features' is the fused warp+features+covariance kernel (warp and covariance read 0).")
    return 0


def whole_process(sequence, n_frames: int, repeat: int) -> None:
    """Frames per second of ``covviz track`` as a user runs it, process start to end, manifold vs CSRT.

    Each run is a fresh process (imports, kernels from numba's cache, decoding, the drift diagnosis,
    results written); the two alternate, ``repeat`` times each, and the ratio is taken pair by pair.
    """
    import subprocess
    import tempfile

    cmd = [sys.executable, "-m", "covviz.cli", "track", *([] if sequence is None else [str(sequence)]),
           "--max-frames", str(n_frames), "--no-save", "--no-progress"]
    walls: dict[str, list[float]] = {"manifold": [], "csrt": []}
    with tempfile.TemporaryDirectory() as out:
        for _ in range(repeat):
            for name, w in walls.items():
                t0 = time.perf_counter()
                subprocess.run([*cmd, "--trackers", name, "--out", out], check=True, capture_output=True)
                w.append(time.perf_counter() - t0)
    ratios = [c / m for m, c in zip(walls["manifold"], walls["csrt"])]
    print(f"\nwhole process, 'covviz track ... --max-frames {n_frames} --no-save' ({repeat} runs each, alternating):")
    for name, w in walls.items():
        print(f"  {name:>8}: {n_frames / np.median(w):6.1f} frames/s (median wall {np.median(w):.2f} s; "
              f"{', '.join(f'{v:.2f}' for v in w)})")
    print(f"  manifold's rate / csrt's, pair by pair: {', '.join(f'{r:.2f}' for r in ratios)} "
          f"(median {np.median(ratios):.2f})")


def _row(k, quad, terms, jit, dt, st, stage_names, peers) -> None:
    """Print one table row: quadrants, terms, jit, particles, ms, fps, stages, ratios to the peers."""
    row = f"{'on' if quad else 'off':>9} {'on' if terms else 'off':>5} {'on' if jit else 'off':>4} {k:>9} "
    row += f"{1e3 * dt:>9.2f} {1 / dt:>7.1f} "
    row += " ".join(f"{1e3 * st.get(s, 0):>10.2f}" for s in stage_names)
    row += "".join(f" {pt / dt:>8.2f}" for pt in peers.values())
    print(row)


if __name__ == "__main__":
    sys.exit(main())
