"""What the Rerun recorder costs: tracking time with and without it, recording size, memory.

Runs the manifold tracker on the synthetic default (320×240) at 600 particles,
alternately as ``covviz track --no-save`` runs it ("untraced": the label-free
drift detector and the drift diagnosis on a background thread; ``--bare``: no
observer at all) and as ``covviz track`` records it ("traced": the same two,
the logger of the detector's probability and :class:`RerunLogger` writing an
``.rrd``, with the MDS and likelihood map every 10 frames, on one background
thread), with
the same seed, so both runs do the same tracking work (the script reports how
far the boxes of the two runs differ: the logger never touches the tracker,
but float32 results depend on heap alignment in their last bits, which any
observer that allocates memory changes). Then one long
traced run samples the process's resident memory every 50 frames.

Prints, and writes as JSON with ``--json``:

* wall-clock and CPU time per frame (CPU = ``time.process_time``: all threads
  of the process, including Rerun's encoder and writer, and BLAS worker
  threads) of the two kinds of run, and the traced/untraced ratios (target ≤
  1.3), as the ratio of the arms' medians and pair by pair (the two runs of a
  pair back to back, their order swapped every pair; the median of the pairs'
  ratios is the figure to read: it cancels the machine's drift between pairs).
  On a shared machine these swing with other load, so the script also
  accounts CPU inside each run: the tracker's ``init``/``update``, the two
  recorders' ``on_frame`` (their thread's CPU time; the detector and the
  diagnosis, which run untraced too, are not counted) and the extra CPU of the
  other threads (Rerun's encoder and writer), and reports ``1 + (recorders +
  extra threads) / untraced CPU``;
* recording size per 1000 frames (target ≤ 30 MB);
* RSS over the long run and its slope in MB per 1000 frames over the second
  half (flat: no growth per frame beyond the recording stream's buffer).

With ``--attribute ROUNDS``, instead of the pairs: the untraced run, the traced run and
variants of each with one part changed (:data:`ATTRIBUTION`: no observers at all, the
observers on the tracking thread, one or two observe threads, no on-track scores, no
likelihood map / slices / cloud, no recorders), all in this process, their order reversed
every round, and each part's share of the traced run's wall time. CPU timers cannot give
that share: on two cores an observer's Python, which holds the GIL, costs the tracker
about its CPU time in wall time, while compiled work that releases the GIL costs far
less (``benchmarks/observer_cost.py``).

Usage::

    python benchmarks/logging_overhead.py                 # ~3-10 min on 2 cores
    python benchmarks/logging_overhead.py --frames 100 --long 300 --repeats 1   # quick look
    python benchmarks/logging_overhead.py ../shared/sequences/Car4 --frames 200 --long 659   # a real sequence
    python benchmarks/logging_overhead.py ../shared/sequences/Car4 --frames 199 --attribute 6   # ~4 min
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

from covviz.api import RECORDING_ONE_THREAD_CORES
from covviz.data.sequences import SyntheticConfig, SyntheticSequence
from covviz.diagnosis.detector import drift_watch
from covviz.diagnosis.drift import Diagnoser
from covviz.runner import BackgroundObserver, Observer, Pipeline, run
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
from covviz.viz.drift import DriftRecorder
from covviz.viz.logger import LoggerConfig, RerunLogger
from covviz.viz.sinks import attach_sinks, new_recording

TARGET_RATIO = 1.3  # issue 23 (it was 1.5)
TARGET_MB_PER_1000 = 30.0


class RSSSampler(Observer):
    """Observer sampling the process's resident set size every ``every`` frames."""

    def __init__(self, every: int = 50):
        self.every = every
        self.proc = psutil.Process()
        self.samples: list[tuple[int, float]] = []

    def on_frame(self, frame, records, found):
        if frame.index % self.every == 0:
            self.samples.append((int(frame.index), self.proc.memory_info().rss / 1e6))


class TimedTracker:
    """Proxy measuring the main-thread CPU time of a tracker's ``init`` and ``update``."""

    def __init__(self, tracker):
        self._tracker = tracker
        self.cpu = 0.0

    def __getattr__(self, name):  # name, config, last_record, base_wh ... of the real tracker
        return getattr(self._tracker, name)

    def init(self, frame, box):
        t = time.thread_time()
        self._tracker.init(frame, box)
        self.cpu += time.thread_time() - t

    def update(self, frame):
        t = time.thread_time()
        box = self._tracker.update(frame)
        self.cpu += time.thread_time() - t
        return box


class TimedObserver(Observer):
    """Wraps an observer and measures the main-thread CPU time of its ``on_frame``."""

    def __init__(self, inner):
        self.inner = inner
        self.cpu = 0.0

    def on_start(self, start, found):
        return self.inner.on_start(start, found)

    def on_frame(self, frame, records, found):
        t = time.thread_time()
        out = self.inner.on_frame(frame, records, found)
        self.cpu += time.thread_time() - t
        return out

    def on_end(self, results, found):
        return self.inner.on_end(results, found)


#: ``--attribute``: the traced run with one part taken out at a time (a throwaway of nothing: each is a
#: real switch of the recorded run), and the untraced run on one observe thread. Name -> (traced?, changes).
ATTRIBUTION = {
    "untraced": (False, {}),
    "untraced, no observers (tracking alone)": (False, {"bare": True}),
    "untraced, observers on the tracking thread": (False, {"background": False}),
    "untraced, one observe thread": (False, {"threads": 1}),
    "traced": (True, {}),
    "traced, two observe threads": (True, {"threads": 2}),
    "traced, no on-track scores": (True, {"on_track_scores": False}),
    "traced, no likelihood map, slices or cloud": (True, {"costly_views": False}),
    "traced, no recorders (diagnosis with on-track scores)": (True, {"recorders": False}),
}


def one_run(seq, n_frames: int, particles: int, seed: int, rrd: Path | None, mds_every: int, extra=(),
            background: bool = True, bare: bool = False, threads: int | None = None,
            on_track_scores: bool | None = None, costly_views: bool = True, recorders: bool = True):
    """One timed run; the keywords after ``bare`` change one part of it (``--attribute``, :data:`ATTRIBUTION`)."""
    inner = ManifoldTracker(ManifoldConfig(n_particles=particles), rng=seed)
    if threads is not None:
        inner.set_threads(threads)
    elif rrd is not None and (os.cpu_count() or 1) <= RECORDING_ONE_THREAD_CORES:
        inner.set_threads(1)  # as `covviz track` records on two cores (its boxes are the same)
    tracker = TimedTracker(inner)
    observers = list(extra)
    if rrd is None and not bare:  # as `covviz track --no-save`: the detector and the diagnosis on their thread
        # (the diagnosis without the template cloud's scores on on-track frames, which only a recorder shows)
        pipe = Pipeline([drift_watch(None), Diagnoser(on_track_scores=bool(on_track_scores))])
        observers.append(BackgroundObserver(pipe) if background else pipe)
    logger = drift = None
    if rrd is not None:
        # As `covviz track` does: the detector and the logger of its probability, the diagnosis, then
        # the recorder that shows what they found, on one thread of their own (BackgroundObserver).
        # Only the recorders are timed (the detector and the diagnosis run untraced too; the diagnosis's
        # scores of the cloud on on-track frames, for the recorder's why-view, are in the wall time only).
        stages = [drift_watch(None), Diagnoser(on_track_scores=on_track_scores is not False)]
        if recorders:
            stream = new_recording()
            attach_sinks(stream, save=rrd)
            views = {"mds_every": mds_every} if costly_views else {"mds_every": 0, "likelihood_every": 0}
            rerun_logger = RerunLogger(stream, LoggerConfig(seed=seed, **views))
            logger = TimedObserver(rerun_logger)
            drift = TimedObserver(DriftRecorder(stream))
            stages = [stages[0], drift, stages[1], logger]
        pipe = Pipeline(stages)
        observers.append(BackgroundObserver(pipe) if background else pipe)
    w0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
    res = run(tracker, seq, observers, max_frames=n_frames, seed=seed)
    wall, cpu, main = time.perf_counter() - w0, time.process_time() - c0, time.thread_time() - m0
    per = 1e3 / n_frames
    return {
        "wall_ms": wall * per,
        "cpu_ms": cpu * per,
        "tracker_cpu_ms": tracker.cpu * per,
        "logger_cpu_ms": ((logger.cpu + drift.cpu) * per) if logger else 0.0,
        "logger_wall_ms": (rerun_logger.log_seconds * per) if logger else 0.0,
        "other_threads_cpu_ms": (cpu - main) * per,
        "mb_per_1000": (rrd.stat().st_size / n_frames * 1000 / 1e6) if logger is not None else None,
        "boxes": res.boxes,
        "observe_threads": inner.config.threads,
    }


def attribute(seq, args, tmp: Path) -> dict:
    """``--attribute``: every variant of :data:`ATTRIBUTION` in turn, ``args.attribute`` rounds; the table."""
    def go(name, n_frames, k=0):
        traced, changes = ATTRIBUTION[name]
        rrd = tmp / f"a{k}.rrd" if traced else None
        return one_run(seq, n_frames, args.particles, args.seed, rrd, args.mds_every, **changes)["wall_ms"]

    names = list(ATTRIBUTION)
    for name in names:  # untimed: first calls of each kind
        go(name, min(10, args.frames))
    walls: dict[str, list[float]] = {name: [] for name in names}
    for r in range(args.attribute):
        for name in names if r % 2 == 0 else names[::-1]:
            walls[name].append(go(name, args.frames, r))
        print(f"  round {r + 1}: " + ", ".join(f"{walls[n][-1]:.1f}" for n in names), flush=True)
    med = {n: statistics.median(w) for n, w in walls.items()}
    base, full = med["untraced"], med["traced"]
    print()
    print("| run | wall ms/frame, median (range) | / untraced | the part's share of the traced run |")
    print("|---|---|---:|---|")
    for n in names:
        share = ""
        if ATTRIBUTION[n][0] and n != "traced":
            share = f"{full - med[n]:+.2f} ms ({(full - med[n]) / base:+.3f} of the ratio)"
        print(f"| {n} | {med[n]:.2f} ({min(walls[n]):.2f}–{max(walls[n]):.2f}) | {med[n] / base:.3f} | {share} |")
    print(f"\n{args.attribute} rounds of {args.frames} frames; a part's share is the traced run's median minus the "
          "median without that part (negative: taking it out did not help)")
    return {"frames": args.frames, "rounds": args.attribute, "wall_ms": walls, "median_wall_ms": med}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=300, help="frames per timed run (default 300)")
    ap.add_argument("--particles", type=int, default=600)
    ap.add_argument("--mds-every", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=2, help="untraced/traced pairs (default 2)")
    ap.add_argument("--long", type=int, default=3000, help="frames of the memory run (default 3000; 0: skip)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--blas-threads", type=int, help="limit BLAS to this many threads for the whole benchmark"
    )
    ap.add_argument("--foreground", action="store_true",
                    help="log on the tracking thread (the default, like covviz track, is a background thread)")
    ap.add_argument("--bare", action="store_true",
                    help="untraced runs without the drift diagnosis (tracking alone) instead of as covviz track "
                         "--no-save runs")
    ap.add_argument("--attribute", type=int, metavar="ROUNDS", default=0,
                    help="instead of the pairs: ROUNDS rounds of the untraced run, the traced run and the traced "
                         "run with one part off at a time (the on-track scores, the costly views, the recorders; "
                         "one or two observe threads), their order reversed every round, in this process; prints "
                         "each part's share of the traced run's wall time (what a CPU timer cannot say: work that "
                         "holds the GIL costs the tracker more than its CPU time)")
    ap.add_argument("--json", type=Path, help="also write the numbers here")
    ap.add_argument("source", nargs="?", default=None,
                    help="a sequence folder (e.g. ../shared/sequences/Car4); default: the synthetic default. "
                         "--long is capped at its length")
    args = ap.parse_args(argv)
    if args.blas_threads:
        from threadpoolctl import threadpool_limits

        threadpool_limits(args.blas_threads, user_api="blas")

    n_seq = max(args.frames, args.long)
    if args.source is None:
        seq = SyntheticSequence(SyntheticConfig(n_frames=n_seq))
        what = f"synthetic {seq.config.width}x{seq.config.height}"
    else:
        from covviz.data.sequences import open_sequence

        seq = open_sequence(args.source)
        h, w = seq.frame(0).image.shape[:2]
        what = f"{seq.name} {w}x{h} ({len(seq)} frames)"
        args.frames = min(args.frames, len(seq))
        args.long = min(args.long, len(seq))
    tmp = Path(tempfile.mkdtemp(prefix="covviz-bench-"))
    print(
        f"{what}, {args.particles} particles, "
        f"MDS + likelihood map every {args.mds_every} frames, {args.frames} frames per run, "
        f"BLAS threads: {args.blas_threads or 'default'}; load average {os.getloadavg()[0]:.1f} "
        f"on {os.cpu_count()} cores; observe threads: untraced 2, traced "
        f"{1 if (os.cpu_count() or 1) <= RECORDING_ONE_THREAD_CORES else 2} (as covviz track --no-save / records)",
        flush=True,
    )

    if args.attribute:
        return _finish(args, attribute(seq, args, tmp), tmp)

    # The memory run first, in a fresh process (no leftovers of earlier runs in the heap).
    long_out: dict = {}
    if args.long:
        sampler = RSSSampler(every=50)
        t = one_run(seq, args.long, args.particles, args.seed, tmp / "long.rrd", args.mds_every, [sampler],
                    background=not args.foreground)
        xs = np.array([s[0] for s in sampler.samples], dtype=float)
        ys = np.array([s[1] for s in sampler.samples])
        half = xs >= xs.max() / 2
        slope = float(np.polyfit(xs[half], ys[half], 1)[0] * 1000) if half.sum() >= 2 else float("nan")
        long_out.update(
            {
                "long_frames": args.long,
                "long_mb_per_1000_frames": t["mb_per_1000"],
                "long_traced_wall_ms": t["wall_ms"],
                "rss_mb": [[int(a), round(float(b), 1)] for a, b in zip(xs, ys)],
                "rss_slope_mb_per_1000_frames_second_half": slope,
            }
        )

    # One short run of each kind first, untimed: the first run in a process pays for first calls
    # (kernels' dispatch, Rerun's stream, imports inside the observers), which would bias its pair.
    one_run(seq, min(10, args.frames), args.particles, args.seed, None, args.mds_every, bare=args.bare)
    one_run(seq, min(10, args.frames), args.particles, args.seed, tmp / "warm.rrd", args.mds_every,
            background=not args.foreground)
    untraced, traced = [], []
    for k in range(args.repeats):
        # The order swapped every pair, so that neither arm always runs on the warmer (or the more loaded)
        # machine; each pair's ratio is read from its two runs back to back.
        def untraced_run():
            return one_run(seq, args.frames, args.particles, args.seed, None, args.mds_every, bare=args.bare)

        def traced_run(k=k):
            return one_run(seq, args.frames, args.particles, args.seed, tmp / f"t{k}.rrd", args.mds_every,
                           background=not args.foreground)

        if k % 2 == 0:
            u = untraced_run()
            t = traced_run()
        else:
            t = traced_run()
            u = untraced_run()
        # The logger never touches the tracker's state or random generator, but any observer that
        # allocates memory moves the tracker's arrays on the heap, and float32 BLAS results depend
        # on alignment in the last bits; a particle filter can amplify that. Report, don't fail.
        t["box_diff_px"] = float(np.abs(u["boxes"] - t["boxes"]).max())
        untraced.append(u)
        traced.append(t)
        print(
            f"  pair {k + 1}: untraced {u['wall_ms']:.1f} ms/frame wall, {u['cpu_ms']:.1f} CPU "
            f"(tracker {u['tracker_cpu_ms']:.1f}); traced {t['wall_ms']:.1f} wall, {t['cpu_ms']:.1f} CPU "
            f"(tracker {t['tracker_cpu_ms']:.1f}, logger {t['logger_cpu_ms']:.1f}, other threads "
            f"{t['other_threads_cpu_ms']:.1f} vs {u['other_threads_cpu_ms']:.1f}); "
            f"max box difference {t['box_diff_px']:.2g} px; wall ratio {t['wall_ms'] / u['wall_ms']:.2f}"
            f" ({'untraced' if k % 2 == 0 else 'traced'} first)",
            flush=True,
        )

    def med(runs, key):
        return statistics.median(r[key] for r in runs)

    out = {
        "frames": args.frames,
        "particles": args.particles,
        "mds_every": args.mds_every,
        "untraced_wall_ms": med(untraced, "wall_ms"),
        "traced_wall_ms": med(traced, "wall_ms"),
        "untraced_cpu_ms": med(untraced, "cpu_ms"),
        "traced_cpu_ms": med(traced, "cpu_ms"),
        "tracker_cpu_ms": med(untraced + traced, "tracker_cpu_ms"),
        "traced_observe_threads": traced[0]["observe_threads"],
        "untraced_observe_threads": untraced[0]["observe_threads"],
        "logger_cpu_ms": med(traced, "logger_cpu_ms"),
        "logger_wall_ms": med(traced, "logger_wall_ms"),
        # Threads other than the tracking thread: with the background logger its
        # thread is among them, so its CPU is taken out here (it is counted as "logger").
        # On two cores the traced tracker observes on its own thread (as covviz track
        # records), the untraced one on two observe threads: the work those did is in the
        # untraced run's other threads and in the traced run's tracker CPU, so the
        # difference of the trackers' CPU is added back.
        "rerun_threads_cpu_ms": max(
            0.0,
            med(traced, "other_threads_cpu_ms") - med(untraced, "other_threads_cpu_ms")
            + med(traced, "tracker_cpu_ms") - med(untraced, "tracker_cpu_ms")
            - (0.0 if args.foreground else med(traced, "logger_cpu_ms")),
        ),
        "mb_per_1000_frames": med(traced, "mb_per_1000"),
    }
    out.update(long_out)
    out["max_box_difference_px"] = max(r["box_diff_px"] for r in traced)
    out["ratio_wall"] = out["traced_wall_ms"] / out["untraced_wall_ms"]
    out["ratio_wall_pairs"] = [t["wall_ms"] / u["wall_ms"] for u, t in zip(untraced, traced)]
    out["ratio_wall_pair_median"] = statistics.median(out["ratio_wall_pairs"])
    out["ratio_cpu"] = out["traced_cpu_ms"] / out["untraced_cpu_ms"]
    # The same, from CPU time accounted inside the runs (less sensitive to other load on the
    # machine): the untraced run's CPU plus what the logger (its own thread, or the main thread
    # with --foreground) and the extra threads (Rerun's encoder and writer) add, over the
    # untraced run's CPU.
    out["ratio_cpu_accounted"] = (
        1.0 + (out["logger_cpu_ms"] + out["rerun_threads_cpu_ms"]) / out["untraced_cpu_ms"]
    )

    print()
    print("| | untraced | traced | ratio | target |")
    print("|---|---|---|---|---|")
    print(
        f"| wall ms/frame | {out['untraced_wall_ms']:.1f} | {out['traced_wall_ms']:.1f} | "
        f"{out['ratio_wall']:.2f} | ≤ {TARGET_RATIO} |"
    )
    pairs = out["ratio_wall_pairs"]
    print(
        f"| wall, pair by pair (median; range) | | | {out['ratio_wall_pair_median']:.2f} "
        f"({min(pairs):.2f}–{max(pairs):.2f}) | ≤ {TARGET_RATIO} |"
    )
    print(
        f"| CPU ms/frame | {out['untraced_cpu_ms']:.1f} | {out['traced_cpu_ms']:.1f} | "
        f"{out['ratio_cpu']:.2f} | ≤ {TARGET_RATIO} |"
    )
    print(
        f"| CPU accounted: untraced / + logger + extra threads | {out['untraced_cpu_ms']:.1f} | "
        f"{out['untraced_cpu_ms'] + out['logger_cpu_ms'] + out['rerun_threads_cpu_ms']:.1f} | "
        f"{out['ratio_cpu_accounted']:.2f} | ≤ {TARGET_RATIO} |"
    )
    print(
        f"\nlogger on_frame: {out['logger_cpu_ms']:.1f} ms CPU ({out['logger_wall_ms']:.1f} ms wall) per frame, "
        f"Rerun's threads {out['rerun_threads_cpu_ms']:.1f} ms CPU per frame; recording "
        f"{out['mb_per_1000_frames']:.1f} MB per 1000 frames (target ≤ {TARGET_MB_PER_1000:.0f})"
    )
    if args.long:
        print(
            f"long run: {args.long} frames, {out['long_mb_per_1000_frames']:.1f} MB per 1000 frames; RSS (MB) "
            "by frame: " + ", ".join(f"{a}:{b:.0f}" for a, b in out["rss_mb"] if a % 250 == 0)
        )
        print(
            f"RSS slope over the second half: {out['rss_slope_mb_per_1000_frames_second_half']:+.1f} MB "
            "per 1000 frames"
        )
    return _finish(args, out, tmp)


def _finish(args, out: dict, tmp: Path) -> int:
    """Write the numbers (``--json``) and remove the run's recordings."""
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    for f in tmp.glob("*.rrd"):
        f.unlink()
    tmp.rmdir()
    return 0


if __name__ == "__main__":
    sys.exit(main())
