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

``--plain-csrt K`` is a mode of its own (nothing else is timed): the user's
baseline. K pairs, alternating (the order swapped every pair), of the whole
process ``covviz track SEQ --tracker manifold --max-frames N --no-save`` (every
other default on: progress bar, drift diagnosis, replays of the losses, results
written to a temporary --out) and of the plain script a user writes without
covviz (``benchmarks/plain_csrt.py``: cv2.imread and cv2.TrackerCSRT over the
same frames); each pair's ratio (the plain script's wall time / covviz's: > 1,
covviz is faster) and their median. Before the pairs, the kernels are warmed
(compiled or loaded) once in a process of their own and by one untimed run of
the covviz command, and the fused warp+features+covariance kernel's time per
frame is measured in another process (the tracker's ``features`` stage over
the same frames, one observe thread).
``--cpu haswell`` runs all of it for a CPU with AVX2 and no AVX-512 (see
:func:`cpu_env`); ``--cpu both`` runs the host and haswell side by side, their
pairs interleaved.

Usage::

    python benchmarks/speed.py                       # the synthetic 320x240 default
    python benchmarks/speed.py ../shared/sequences/Car1 --frames 200
    python benchmarks/speed.py --threads 1           # pin BLAS/OpenCV to one thread
    python benchmarks/speed.py --quadrants on         # only the default tracker
    python benchmarks/speed.py --jit both             # with and without the compiled kernels
    python benchmarks/speed.py --quadrants on --terms both   # the default with and without issue 14's terms
    python benchmarks/speed.py ../shared/sequences/Car4 --frames 199 --particles 600 --whole 5
    python benchmarks/speed.py ../shared/sequences/Car4 --frames 199 --plain-csrt 5 --cpu both

These machines are noisy: compare ratios measured side by side in one run, and
use ``--repeat`` to take the best of several passes.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

BENCHMARKS = Path(__file__).resolve().parent
REPO = BENCHMARKS.parent


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
    ap.add_argument("--plain-csrt", type=int, default=0, metavar="K",
                    help="only time the whole 'covviz track SEQ --tracker manifold --max-frames N --no-save' process "
                         "against a plain cv2.imread + cv2.TrackerCSRT script (benchmarks/plain_csrt.py), K pairs "
                         "alternating, N = --frames + 1; needs an OTB folder (default 0: not this mode)")
    ap.add_argument("--cpu", choices=("host", "haswell", "both"), default="host",
                    help="with --plain-csrt: the kernels and OpenCV as built for this machine (host), for a CPU with "
                         "AVX2 and no AVX-512 (haswell: NUMBA_CPU_NAME, NUMBA_CPU_FEATURES, a numba cache of its "
                         "own, OPENCV_CPU_DISABLE=AVX512-SKX), or both side by side (default host)")
    ap.add_argument("--haswell-cache", default=None, metavar="DIR",
                    help="with --cpu haswell/both: the numba cache of the haswell build, kept for the next run "
                         "(default: a temporary folder, compiled afresh, ~30-60 s)")
    ap.add_argument("--jit", choices=("on", "off", "both"), default="on",
                    help="time the tracker with the compiled kernels (on, the default when numba is installed), "
                         "with the numpy path (off) or both, side by side (default on)")
    args = ap.parse_args(argv)
    if args.plain_csrt:
        return plain_csrt(args.sequence, args.frames + 1, args.plain_csrt,
                          ("host", "haswell") if args.cpu == "both" else (args.cpu,), args.haswell_cache)
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
    default = ManifoldConfig().replace(n_particles=600)  # what covviz track --no-save runs (its threads too)
    default_dt = None
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
                    if cfg == default:
                        default_dt = dt
    for p, pt in peers.items():
        print(f"{p}: {1e3 * pt:.2f} ms/frame, {1 / pt:.1f} fps")
    if args.whole:
        if default_dt is None and True in jits:  # not a row of the table: timed here, as covviz track runs it
            default_dt = time_tracker(lambda: ManifoldTracker(default, rng=0), frames, box, args.repeat)[0]
            print(f"the default tracker's update() as covviz track runs it ({default.threads} observe threads): "
                  f"{1e3 * default_dt:.2f} ms/frame")
        whole_process(args.sequence, n, args.whole, default_dt)
    print("\n'x csrt' = CSRT's time / manifold's time on the same frames (>1: manifold is faster).")
    if True in jits:
        print("jit on: 'features' is the fused warp+features+covariance kernel (warp and covariance read 0).")
    return 0


def whole_process(sequence, n_frames: int, repeat: int, update_dt: float | None = None) -> None:
    """Frames per second of ``covviz track`` as a user runs it, process start to end, manifold vs CSRT.

    Each run is a fresh process (imports, kernels from numba's cache, decoding, the drift diagnosis,
    results written); the two alternate, ``repeat`` times each, and the ratio is taken pair by pair.
    ``update_dt``: the default tracker's ``update()`` alone, seconds a frame, timed above in this run
    (600 particles, the default config): then each manifold run's wall time per tracked frame is
    also given as a multiple of it (issue 23's goal: at most 1.25), start-up included, and without the
    start-up (a run of the same command tracking one frame, after each pair). covviz's bytecode is
    cached as in an installed package (:func:`installed_env`), written by one untimed run first.
    """
    cmd = [sys.executable, "-m", "covviz.cli", "track", *([] if sequence is None else [str(sequence)]),
           "--max-frames", str(n_frames), "--no-save", "--no-progress"]
    walls: dict[str, list[float]] = {"manifold": [], "csrt": []}
    starts: list[float] = []  # the manifold process with one tracked frame: start-up, init and the end
    short = [*cmd[: cmd.index("--max-frames") + 1], "2", *cmd[cmd.index("--max-frames") + 2 :]]
    with tempfile.TemporaryDirectory() as out:
        env = installed_env(dict(os.environ), str(Path(out) / "pycache"))
        subprocess.run([*short, "--trackers", "manifold", "--out", out], check=True, capture_output=True, env=env)
        for _ in range(repeat):
            for name, w in walls.items():
                t0 = time.perf_counter()
                subprocess.run([*cmd, "--trackers", name, "--out", out], check=True, capture_output=True, env=env)
                w.append(time.perf_counter() - t0)
            if update_dt is not None:
                t0 = time.perf_counter()
                subprocess.run([*short, "--trackers", "manifold", "--out", out], check=True, capture_output=True,
                               env=env)
                starts.append(time.perf_counter() - t0)
    ratios = [c / m for m, c in zip(walls["manifold"], walls["csrt"])]
    print(f"\nwhole process, 'covviz track ... --max-frames {n_frames} --no-save' ({repeat} runs each, alternating):")
    for name, w in walls.items():
        print(f"  {name:>8}: {n_frames / np.median(w):6.1f} frames/s (median wall {np.median(w):.2f} s; "
              f"{', '.join(f'{v:.2f}' for v in w)})")
    print(f"  manifold's rate / csrt's, pair by pair: {', '.join(f'{r:.2f}' for r in ratios)} "
          f"(median {np.median(ratios):.2f})")
    if update_dt is not None:
        per = [w / (n_frames - 1) / update_dt for w in walls["manifold"]]  # the first frame is init's
        print(f"  manifold's whole process per tracked frame / its update() alone ({1e3 * update_dt:.2f} ms): "
              f"{', '.join(f'{r:.2f}' for r in per)} (median {np.median(per):.2f}; goal <= 1.25, start-up included)")
        rest = [(w - s0) / (n_frames - 2) / update_dt for w, s0 in zip(walls["manifold"], starts)]
        print(f"  start-up (the same process tracking 1 frame): median {np.median(starts):.2f} s; the other frames "
              f"/ update() alone: {', '.join(f'{r:.2f}' for r in rest)} (median {np.median(rest):.2f}; "
              f"the end's loss replays included)")


#: What LLVM's "haswell" CPU has: AVX2 and FMA, no AVX-512. ``NUMBA_CPU_NAME=haswell`` alone is not enough:
#: numba then still passes the host's feature list, and on an AVX-512 host LLVM emits zmm code for it.
HASWELL_FEATURES = frozenset({
    "64bit", "aes", "avx", "avx2", "bmi", "bmi2", "cmov", "crc32", "cx16", "cx8", "f16c", "fma", "fsgsbase", "fxsr",
    "invpcid", "lzcnt", "mmx", "movbe", "pclmul", "popcnt", "rdrnd", "sahf", "sse", "sse2", "sse3", "sse4.1",
    "sse4.2", "ssse3", "xsave", "xsaveopt",
})


def installed_env(env: dict, pycache: str | None) -> dict:
    """``env`` with Python's bytecode cache on, in ``pycache`` (``PYTHONPYCACHEPREFIX``), as an installed covviz runs.

    ``pip install`` byte-compiles a package, and Python writes the bytecode of an editable one at its first
    import; a machine with ``PYTHONDONTWRITEBYTECODE=1`` (these development machines) instead compiles
    covviz's ~55 modules from source in every process (~0.08 s of start-up that no user pays, and that
    the plain script's cv2 and numpy, byte-compiled in site-packages, do not pay either). The prefix keeps
    the bytecode out of the checkout; the untimed warm-up run writes it. ``pycache`` None: ``env`` as it is.
    """
    if pycache is None:
        return env
    env = {k: v for k, v in env.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = pycache
    return env


def cpu_env(cpu: str, cache: str | None = None, pycache: str | None = None) -> dict:
    """The environment of a benchmark process for ``cpu``: this checkout first on the path, and the CPU's build.

    ``"host"``: the kernels and OpenCV as they are built for this machine (numba's cache in the package).
    ``"haswell"``: as on a CPU with AVX2 and no AVX-512: the kernels compiled for LLVM's haswell
    (``NUMBA_CPU_NAME=haswell`` and ``NUMBA_CPU_FEATURES``, the host's features with everything haswell
    lacks turned off) into a numba cache of their own (``cache``: NUMBA_CACHE_DIR, so the host's is
    neither used nor overwritten), and OpenCV's AVX-512 code paths off (``OPENCV_CPU_DISABLE=AVX512-SKX``;
    OpenCV 5 spells it with a hyphen and ignores ``AVX512_SKX``, with a warning). ``pycache``: see
    :func:`installed_env`.
    """
    env = installed_env(dict(os.environ), pycache)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [env.get("PYTHONPATH")])])
    if cpu == "host":
        return env
    if cpu != "haswell" or cache is None:
        raise ValueError(f"cpu {cpu!r}: host, or haswell with a cache folder")
    import llvmlite.binding as llvm

    host = llvm.get_host_cpu_features()
    env["NUMBA_CPU_NAME"] = "haswell"
    env["NUMBA_CPU_FEATURES"] = ",".join(("+" if on and f in HASWELL_FEATURES else "-") + f for f, on in host.items())
    env["NUMBA_CACHE_DIR"] = cache
    env["OPENCV_CPU_DISABLE"] = "AVX512-SKX"
    return env


def _python(code: str, env: dict) -> str:
    """Run ``code`` in a fresh interpreter with ``env``; its stdout (the benchmark stops on a failure)."""
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False)
    if out.returncode:
        raise SystemExit(f"a benchmark process failed:\n{out.stderr.strip()[-2000:]}")
    return out.stdout


def fused_kernel_times(sequence, n_frames: int, repeat: int = 2) -> dict:
    """The default manifold tracker's mean ``update()`` and fused-kernel (``features`` stage) seconds per frame.

    One observe thread (``threads=1``) and one BLAS/OpenCV thread, so the stage is the kernel's own
    time, not shared with another thread; best of ``repeat`` passes over the first ``n_frames``
    frames, decoded before timing. Run in a subprocess by :func:`plain_csrt` (each CPU's build).
    """
    from numba.core import config as numba_config

    from covviz.data.sequences import open_sequence
    from covviz.model import kernels
    from covviz.threads import limit_threads
    from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker

    seq = open_sequence(sequence)
    frames = [seq.frame(i).image for i in range(min(n_frames, len(seq)))]
    kernels.warmup()
    cfg = ManifoldConfig().replace(threads=1)
    with limit_threads(1):
        dt, st = time_tracker(lambda: ManifoldTracker(cfg, rng=0), frames, seq.init_box, repeat)
    return {"update": dt, "fused": st.get("features", float("nan")), "particles": cfg.n_particles,
            "cpu_name": numba_config.CPU_NAME or "host"}


_FPS = re.compile(r"frames, ([\d.]+) fps")
_RUN_WALL = re.compile(r"\(([\d.]+) s wall\)")
_LOOP = re.compile(r"loop ([\d.]+) s")


def _timed(cmd: list[str], env: dict) -> tuple[float, str]:
    """Wall seconds of a whole process, start to end, and its stdout (the benchmark stops on a failure)."""
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if out.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed (exit {out.returncode}):\n{out.stderr.strip()[-2000:]}")
    return wall, out.stdout


def _found(pattern: re.Pattern, text: str) -> float:
    m = pattern.search(text)
    return float(m.group(1)) if m else float("nan")


def plain_csrt(sequence, n_frames: int, pairs: int, cpus: tuple[str, ...], haswell_cache: str | None = None) -> int:
    """``covviz track``'s whole process against the plain CSRT script's, pair by pair, for each CPU build.

    Per CPU: the kernels warmed once in a process of their own (compiled into the haswell build's
    cache the first time) and by one untimed run of the covviz command, the fused kernel timed in
    another process (:func:`fused_kernel_times`), then
    ``pairs`` pairs, the order within a pair swapped every pair (and the CPUs' pairs interleaved),
    each pair's ratio plain wall / covviz wall (> 1: covviz is faster) and the median.
    ``haswell_cache``: the haswell build's numba cache (None: a temporary folder).
    """
    if sequence is None or not (Path(sequence) / "img").is_dir():
        print("--plain-csrt needs an OTB folder (img/ + groundtruth_rect.txt): the plain script reads its frames "
              "with cv2.imread", file=sys.stderr)
        return 2
    sequence = str(Path(sequence).resolve())
    print(machine())
    with tempfile.TemporaryDirectory(prefix="covviz-speed-") as tmp:
        cache = str(Path(haswell_cache).resolve()) if haswell_cache else str(Path(tmp) / "numba-haswell")
        envs = {cpu: cpu_env(cpu, cache, str(Path(tmp) / "pycache")) for cpu in cpus}
        covviz = [sys.executable, "-m", "covviz.cli", "track", sequence, "--tracker", "manifold",
                  "--max-frames", str(n_frames), "--no-save", "--out", str(Path(tmp) / "runs")]
        plain = [sys.executable, str(BENCHMARKS / "plain_csrt.py"), sequence, "--max-frames", str(n_frames)]
        print(f"covviz: {' '.join(covviz)}\nplain:  {' '.join(plain)}")
        fused = {}
        for cpu, env in envs.items():
            extra = " ".join(f"{k}={env[k]}" for k in ("NUMBA_CPU_NAME", "NUMBA_CACHE_DIR", "OPENCV_CPU_DISABLE")
                             if k in env)
            if "NUMBA_CPU_FEATURES" in env:
                extra += " NUMBA_CPU_FEATURES=(haswell's, no AVX-512)"
            # 256: OpenCV's CV_CPU_AVX512_SKX, which OPENCV_CPU_DISABLE turns off for the haswell build
            cached, took, avx512 = _python("import cv2; from covviz.model import kernels; c = kernels.kernels_cached(); "
                                           "print(c, kernels.warmup(), cv2.checkHardwareSupport(256))", env).split()
            # kernels.warmup() leaves signatures the run compiles at its first frames (the distances' on
            # the tracker's arrays, ~2.5 s): one untimed run of the command itself caches them too.
            warm, _ = _timed(covviz, env)
            print(f"[{cpu}] {extra or 'the environment as it is'}; OpenCV's AVX-512 code "
                  f"{'on' if avx512 == 'True' else 'off'}; kernels "
                  f"{'loaded from the cache' if cached == 'True' else 'compiled'} in {float(took):.1f} s, then one "
                  f"untimed covviz track run ({warm:.1f} s)")
            code = (f"import json, sys; sys.path.insert(0, {str(BENCHMARKS)!r}); import speed; "
                    f"print(json.dumps(speed.fused_kernel_times({sequence!r}, {n_frames})))")
            fused[cpu] = json.loads(_python(code, env).strip().splitlines()[-1])
        walls: dict[str, list[tuple]] = {cpu: [] for cpu in cpus}
        for k in range(pairs):
            for cpu, env in envs.items():
                order = ("covviz", "plain") if k % 2 == 0 else ("plain", "covviz")
                got = {name: _timed(covviz if name == "covviz" else plain, env) for name in order}
                (cw, cout), (pw, pout) = got["covviz"], got["plain"]
                walls[cpu].append((cw, pw))
                print(f"[{cpu}] pair {k + 1} ({order[0]} first): covviz {cw:.2f} s (its run {_found(_RUN_WALL, cout):.2f}"
                      f" s, update() {_found(_FPS, cout):.0f} fps), plain CSRT {pw:.2f} s (its loop "
                      f"{_found(_LOOP, pout):.2f} s): ratio {pw / cw:.2f}")
    print(f"\nwhole process, {n_frames} frames of {Path(sequence).name}, {pairs} pairs alternating; ratio = plain CSRT "
          "script's wall time / covviz track's (> 1: covviz is faster)")
    for cpu in cpus:
        cw, pw = (np.array(v) for v in zip(*walls[cpu]))
        ratios = pw / cw
        f = fused[cpu]
        print(f"  [{cpu}] covviz track: median {np.median(cw):.2f} s ({n_frames / np.median(cw):.1f} frames/s); plain "
              f"CSRT: median {np.median(pw):.2f} s ({n_frames / np.median(pw):.1f} frames/s)")
        print(f"  [{cpu}] ratio pair by pair: {', '.join(f'{r:.2f}' for r in ratios)} (median {np.median(ratios):.2f})")
        print(f"  [{cpu}] fused warp+features+covariance kernel: {1e3 * f['fused']:.2f} ms per frame at "
              f"{f['particles']} particles (update() {1e3 * f['update']:.2f} ms; one observe thread, "
              f"numba CPU {f['cpu_name']})")
    if len(cpus) > 1:
        print(f"  fused kernel, haswell / host: {fused['haswell']['fused'] / fused['host']['fused']:.2f}; update(): "
              f"{fused['haswell']['update'] / fused['host']['update']:.2f}")
    return 0


def _row(k, quad, terms, jit, dt, st, stage_names, peers) -> None:
    """Print one table row: quadrants, terms, jit, particles, ms, fps, stages, ratios to the peers."""
    row = f"{'on' if quad else 'off':>9} {'on' if terms else 'off':>5} {'on' if jit else 'off':>4} {k:>9} "
    row += f"{1e3 * dt:>9.2f} {1 / dt:>7.1f} "
    row += " ".join(f"{1e3 * st.get(s, 0):>10.2f}" for s in stage_names)
    row += "".join(f" {pt / dt:>8.2f}" for pt in peers.values())
    print(row)


if __name__ == "__main__":
    sys.exit(main())
