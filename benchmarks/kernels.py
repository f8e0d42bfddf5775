"""The compiled kernels (covviz.model.kernels) against the numpy path, stage by stage, side by side.

Prints the machine, then:

1. **stages** at ``--particles`` particles on a real frame (poses around the
   ground truth, templates scattered around the descriptor there, as the
   tracker's are): the numpy stage and its kernel, interleaved call for call
   ``--repeat`` times in this process; the best of each and their ratio;
2. **update()** of ``manifold`` (quadrants on) and ``manifold-paper``
   (quadrants off), with and without the kernels, and OpenCV's CSRT, on the
   same decoded frames: passes interleaved, the best pass of each, and the
   ratio CSRT time / tracker time (> 1: faster than CSRT), in wall-clock time
   and in process CPU time (the work, all threads: other jobs on a shared
   machine inflate it much less than the wall-clock time);
3. with ``--accuracy``, the largest errors of the kernels and of the numpy
   path against the definition evaluated in float64, on 10 real frames;
4. with ``--cold``, the cold compile time: a fresh process with an empty numba
   cache running :func:`covviz.model.kernels.warmup`.

The machine is usually shared and noisy: quote the ratios, and an absolute
figure only with the CPU line printed above it.

Usage::

    python benchmarks/kernels.py                                  # Car4, 600 particles
    python benchmarks/kernels.py ../shared/sequences/Crossing --frames 60 --repeat 30
    python benchmarks/kernels.py --no-update --cold               # stages and the compile time only
    python benchmarks/kernels.py --no-update --accuracy           # stages and the errors against float64
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed import _set_threads, machine

DEFAULT_SEQUENCE = Path(__file__).resolve().parents[2] / "shared" / "sequences" / "Car4"


def interleaved(fns: dict, repeat: int) -> dict:
    """Best time (s) of each callable over ``repeat`` rounds, the callables alternating within a round."""
    best = dict.fromkeys(fns, np.inf)
    for _ in range(repeat):
        for k, f in fns.items():
            t0 = time.perf_counter()
            f()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def stage_inputs(seq, frame: int, n: int, rng):
    """Grey frame, ``n`` poses around the ground truth, base size, templates and quadrant reference."""
    from covviz.model import spd
    from covviz.model.descriptor import quadrant_covariances
    from covviz.model.features import patch_features, warp_patches
    from covviz.model.image import to_gray

    f = seq.frame(frame)
    gray = to_gray(f.image)
    x, y, w, h = seq.init_box if f.gt is None else f.gt
    wh = (float(w), float(h))
    base = np.array([x + w / 2, y + h / 2, 1.0, 0.0])
    jit = rng.normal(0.0, [0.1 * w, 0.1 * h, 0.05, 0.05], (n, 4))
    poses = base + jit
    P = warp_patches(gray, base[None], wh, 32, 1, 1.0)
    C0, Q0 = quadrant_covariances(patch_features(P, gain_normalize=True, quadrants=True), 1e-3)
    W = rng.normal(0.0, 0.05, (n, 9, 9))
    L = spd.logm(C0[0]) + 0.5 * (W + np.swapaxes(W, 1, 2))
    return gray, poses, wh, L, Q0[0], spd.logdet(Q0[0])


def print_stages(seq, n: int, repeat: int, rng) -> None:
    from covviz.model import kernels
    from covviz.model.descriptor import covariance, quadrant_covariances
    from covviz.model.features import patch_features, warp_patches
    from covviz.trackers.manifold import quadrant_distances, riemann_distance_to_templates

    gray, poses, wh, L, ref, ref_ld = stage_inputs(seq, min(10, len(seq) - 1), n, rng)
    P = warp_patches(gray, poses, wh, 32, 1, 1.0)
    F = patch_features(P, gain_normalize=True, quadrants=True)
    C, Q = quadrant_covariances(F, 1e-3)
    F1 = patch_features(P, gain_normalize=True)
    kernels.warmup()

    rows = [
        # (stage, numpy callable, kernel callable or None)
        ("warp (cv2.remap + maps)", lambda: warp_patches(gray, poses, wh, 32, 1, 1.0), None),
        ("features", lambda: patch_features(P, gain_normalize=True, quadrants=True), None),
        ("covariance (+quadrants)", lambda: quadrant_covariances(F, 1e-3), None),
        ("warp+features+covariance", lambda: quadrant_covariances(
            patch_features(warp_patches(gray, poses, wh, 32, 1, 1.0), gain_normalize=True, quadrants=True), 1e-3),
         lambda: kernels.warp_descriptors_fast(gray, poses, wh, 32, 1.0, 1e-3, True, True)),
        ("  from patches (no warp)", lambda: quadrant_covariances(
            patch_features(P, gain_normalize=True, quadrants=True), 1e-3),
         lambda: kernels.descriptors_fast(P, 1e-3, True, True)),
        ("  without quadrants", lambda: covariance(
            patch_features(warp_patches(gray, poses, wh, 32, 1, 1.0), gain_normalize=True), 1e-3),
         lambda: kernels.warp_descriptors_fast(gray, poses, wh, 32, 1.0, 1e-3, True, False)),
        ("template distances", lambda: riemann_distance_to_templates(L, C),
         lambda: kernels.template_distances_fast(L, C)),
        ("quadrant distances", lambda: quadrant_distances(Q, ref, ref_ld),
         lambda: kernels.quadrant_distances_fast(Q, ref, ref_ld)),
    ]
    fns = {}
    for name, ref_fn, fast_fn in rows:
        fns[(name, "numpy")] = ref_fn
        if fast_fn is not None:
            fns[(name, "kernel")] = fast_fn
    best = interleaved(fns, repeat)
    del F1
    print(f"\nstages at {n} particles, one call each, best of {repeat} interleaved (ms, one thread)")
    print(f"{'stage':<28} {'numpy':>8} {'kernel':>8} {'ratio':>7}")
    for name, _, fast_fn in rows:
        t_ref = 1e3 * best[(name, "numpy")]
        if fast_fn is None:
            print(f"{name:<28} {t_ref:>8.2f} {'(fused)':>8}")
        else:
            t_fast = 1e3 * best[(name, "kernel")]
            print(f"{name:<28} {t_ref:>8.2f} {t_fast:>8.2f} {t_ref / t_fast:>6.1f}x")


def timed_pass(make, images, box):
    """One pass of ``update()`` over ``images``: mean wall and process-CPU seconds per frame, mean stage timings.

    Process CPU time (all threads) is the work done, which other jobs on a
    shared machine inflate much less than the wall-clock time.
    """
    tr = make()
    tr.init(images[0], box)
    stages: dict[str, float] = {}
    w0, c0 = time.perf_counter(), time.process_time()
    for f in images[1:]:
        tr.update(f)
        rec = tr.last_record
        if rec is not None:
            for k, v in rec.timings.items():
                stages[k] = stages.get(k, 0.0) + v
    m = len(images) - 1
    wall, cpu = (time.perf_counter() - w0) / m, (time.process_time() - c0) / m
    return wall, cpu, {k: v / m for k, v in stages.items()}


def print_updates(seq, n: int, frames: int, repeat: int, observe_threads: int) -> None:
    from covviz.model import kernels
    from covviz.trackers import make_tracker
    from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker

    m = min(frames + 1, len(seq))
    images = [seq.frame(i).image for i in range(m)]
    box = seq.init_box
    kernels.warmup()
    variants = {}
    for quad, label in ((True, "manifold"), (False, "manifold-paper")):
        cfg = ManifoldConfig().replace(n_particles=n, threads=observe_threads, quadrants=quad)
        for jit in (False, True):
            variants[(label, jit)] = (lambda cfg=cfg: ManifoldTracker(cfg, rng=0), jit)
    best = {k: (np.inf, np.inf, {}) for k in [*variants, "csrt"]}  # best wall pass, best CPU pass
    saved = kernels.JIT_ENABLED
    try:
        for _ in range(repeat):
            w, c, st = timed_pass(lambda: make_tracker("csrt", rng=0), images, box)
            best["csrt"] = (min(best["csrt"][0], w), min(best["csrt"][1], c), st)
            for key, (make, jit) in variants.items():
                kernels.JIT_ENABLED = jit
                w, c, st = timed_pass(make, images, box)
                b = best[key]
                best[key] = (min(b[0], w), min(b[1], c), st if w < b[0] else b[2])
    finally:
        kernels.JIT_ENABLED = saved
    csrt_w, csrt_c, _ = best["csrt"]
    stages = ("propagate", "warp", "features", "covariance", "distances", "weights", "resample")
    print(f"\nupdate() on {m - 1} frames of {seq.name}, {n} particles, observe threads {observe_threads}, "
          f"best of {repeat} interleaved passes (ms per frame; CPU = process time, all threads)")
    print(f"{'tracker':<15} {'jit':>4} {'wall':>7} {'fps':>6} {'x csrt':>7} {'CPU':>7} {'x csrt':>7}  "
          + " ".join(f"{s:>9}" for s in stages))
    for (label, jit), (w, c, st) in ((k, best[k]) for k in variants):
        print(f"{label:<15} {'on' if jit else 'off':>4} {1e3 * w:>7.2f} {1 / w:>6.0f} {csrt_w / w:>7.2f} "
              f"{1e3 * c:>7.2f} {csrt_c / c:>7.2f}  " + " ".join(f"{1e3 * st.get(s, 0.0):>9.2f}" for s in stages))
    print(f"{'csrt':<15} {'':>4} {1e3 * csrt_w:>7.2f} {1 / csrt_w:>6.0f} {1.0:>7.2f} {1e3 * csrt_c:>7.2f} {1.0:>7.2f}")
    print("'x csrt': CSRT's time / the tracker's (> 1: faster than CSRT). Stages: wall-clock shares of the best "
          "wall pass; with the kernels, 'features' is the fused warp+features+covariance kernel (warp, covariance: 0)")


ACCURACY_FRAMES = (("Car4", 180), ("Car4", 300), ("Car4", 420), ("Crossing", 40), ("Crossing", 100),
                   ("Jogging-1", 50), ("Bolt2", 100), ("Couple", 60), ("Football1", 30), ("Human3", 100))


def oracle64(P: np.ndarray, eps: float):
    """Float64 descriptors ``(C, Q)`` of bordered patches from the definition (gain-normalised, quadrants)."""
    from covviz.model import spd
    from covviz.model.features import FEATURE_SCALE

    P = np.asarray(P, dtype=np.float64)
    P = P / np.maximum(P[:, 1:-1, 1:-1].mean(axis=(1, 2), keepdims=True), 1e-3)
    c = P[:, 1:-1, 1:-1]
    ix, iy = (P[:, 1:-1, 2:] - P[:, 1:-1, :-2]) / 2, (P[:, 2:, 1:-1] - P[:, :-2, 1:-1]) / 2
    ixx, iyy = P[:, 1:-1, 2:] - 2 * c + P[:, 1:-1, :-2], P[:, 2:, 1:-1] - 2 * c + P[:, :-2, 1:-1]
    n, S = len(P), c.shape[1]
    xx, yy = np.meshgrid((np.arange(S) + 0.5) / S - 0.5, (np.arange(S) + 0.5) / S - 0.5)
    F = np.stack([np.broadcast_to(xx, c.shape), np.broadcast_to(yy, c.shape), c, np.abs(ix), np.abs(iy),
                  np.hypot(ix, iy), np.arctan2(np.abs(ix), np.abs(iy)), np.abs(ixx), np.abs(iyy)], 1)
    F = F * np.asarray(FEATURE_SCALE, dtype=np.float64)[None, :, None, None]

    def cov(X):
        X = X - X.mean(axis=-1, keepdims=True)
        return spd.regularize(X @ np.swapaxes(X, -1, -2) / (X.shape[-1] - 1), eps)

    h = S // 2
    Q = np.stack([cov(F[:, :, r : r + h, k : k + h].reshape(n, 9, -1)) for r, k in ((0, 0), (0, h), (h, 0), (h, h))],
                 axis=1)
    return cov(F.reshape(n, 9, -1)), Q


def print_accuracy(folder: Path, rng) -> None:
    """Largest errors against :func:`oracle64` on real frames: the kernels and the numpy path."""
    from covviz.data.sequences import open_sequence
    from covviz.model import kernels, spd
    from covviz.model.descriptor import quadrant_covariances
    from covviz.model.features import patch_features, warp_patches
    from covviz.model.image import to_gray
    from covviz.trackers.manifold import quadrant_distances, riemann_distance_to_templates

    def frob(A, B):
        return float((np.linalg.norm(A - B, axis=(-1, -2)) / np.linalg.norm(B, axis=(-1, -2))).max())

    worst: dict[str, list[float]] = {}
    npatch = 0
    for name, k in ACCURACY_FRAMES:
        if not (folder / name).is_dir():
            continue
        f = open_sequence(folder / name).frame(k)
        gray, (x, y, w, h) = to_gray(f.image), f.gt
        H, W = gray.shape
        near = np.array([x + w / 2, y + h / 2, 1.0, 0.0]) + rng.normal(0, [0.15 * w, 0.15 * h, 0.1, 0.15], (300, 4))
        cand = np.column_stack([rng.uniform(0, W, 400), rng.uniform(0, H, 400), rng.uniform(0.4, 1.5, 400),
                                rng.uniform(-0.5, 0.5, 400)])
        Pc = warp_patches(gray, cand, (w, h), 32, 1, 1.0)[:, 1:-1, 1:-1]
        dark = cand[np.argsort(Pc.mean(axis=(1, 2)))[:15]]
        flat = cand[np.argsort(np.abs(np.diff(Pc, axis=2)).mean(axis=(1, 2)))[:15]]
        border = np.column_stack([rng.choice([-0.3 * w, W + 0.3 * w], 10), rng.uniform(-h, H + h, 10),
                                  rng.uniform(0.5, 2.0, 10), rng.uniform(-1, 1, 10)])
        poses = np.concatenate([near, dark, flat, border])
        P = warp_patches(gray, poses, (w, h), 32, 1, 1.0)
        Co, Qo = oracle64(P, 1e-3)
        Wn = rng.normal(0, 0.05, (len(P), 9, 9))
        L = spd.logm(Co[0]) + 0.5 * (Wn + np.swapaxes(Wn, 1, 2))
        ref, ref_ld = Qo[0], spd.logdet(Qo[0])
        do, qo = riemann_distance_to_templates(L, Co), quadrant_distances(Qo, ref, ref_ld)
        F = patch_features(P, gain_normalize=True, quadrants=True)
        paths = {
            "kernels": kernels.warp_descriptors_fast(gray, poses, (w, h), 32, 1.0, 1e-3, True, True),
            "numpy (the tracker's: float32 moments)": quadrant_covariances(F, 1e-3),
            "numpy features, float64 moments": quadrant_covariances(F.astype(np.float64), 1e-3),
        }
        for label, (C, Q) in paths.items():
            d = riemann_distance_to_templates(L, C) if label != "kernels" else kernels.template_distances_fast(L, C)
            q = quadrant_distances(Q, ref, ref_ld) if label != "kernels" else kernels.quadrant_distances_fast(
                Q, ref, ref_ld)
            e = [frob(C, Co), frob(Q, Qo), float(np.abs(d - do).max()), float(np.abs(q - qo).max())]
            worst[label] = [max(a, b) for a, b in zip(worst.get(label, [0.0] * 4), e, strict=True)]
        npatch += len(P)
    if not worst:
        print(f"\n(accuracy: no sequences under {folder})")
        return
    print(f"\naccuracy against float64 (the definition evaluated in float64), {npatch} patches of "
          f"{len(ACCURACY_FRAMES)} real frames (around the ground truth, dark, flat, over the border): largest")
    print(f"{'path':<40} {'C rel':>8} {'Q rel':>8} {'d abs':>8} {'q abs':>8}")
    for label, e in worst.items():
        print(f"{label:<40} " + " ".join(f"{v:>8.1e}" for v in e))
    print("C, Q rel: ||ΔC||_F / ||C||_F per matrix; d: template distance, q: quadrant distance")


def cold_compile_seconds() -> float:
    """Seconds a fresh process with an empty numba cache spends in :func:`covviz.model.kernels.warmup`."""
    code = "from covviz.model import kernels; print(kernels.kernels_cached(), kernels.warmup())"
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1]) + os.pathsep + env.get("PYTHONPATH", "")
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        cached, seconds = out.stdout.split()
        assert cached == "False"
        # and a second process loads from that cache
        out2 = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        cached2, seconds2 = out2.stdout.split()
    print(f"\ncold compile (fresh numba cache): {float(seconds):.1f} s; next process, from the cache "
          f"(kernels_cached() = {cached2}): {float(seconds2):.2f} s")
    return float(seconds)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", nargs="?", default=str(DEFAULT_SEQUENCE), help="sequence (default: shared Car4)")
    ap.add_argument("--particles", type=int, default=600, help="particles (default 600)")
    ap.add_argument("--frames", type=int, default=60, help="frames of update() to time (default 60)")
    ap.add_argument("--repeat", type=int, default=15, help="interleaved rounds of the stages (default 15)")
    ap.add_argument("--passes", type=int, default=3, help="interleaved passes of each update() (default 3)")
    ap.add_argument("--threads", type=int, default=1, help="BLAS and OpenCV threads (default 1)")
    ap.add_argument("--observe-threads", type=int, default=2, help="ManifoldConfig.threads (default 2)")
    ap.add_argument("--no-update", action="store_true", help="skip the update() comparison")
    ap.add_argument("--cold", action="store_true", help="also measure the cold compile time (~20-60 s)")
    ap.add_argument("--accuracy", action="store_true",
                    help="also print the largest errors against float64 on 10 real frames (needs ../shared)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    _set_threads(args.threads)

    import cv2
    import numba

    from covviz.data.sequences import open_sequence

    seq = open_sequence(args.sequence)
    print(machine())
    print(f"numpy {np.__version__}, numba {numba.__version__}, OpenCV {cv2.__version__}; "
          f"BLAS/OpenCV threads {args.threads}; sequence {seq.name}")
    print_stages(seq, args.particles, args.repeat, np.random.default_rng(args.seed))
    if not args.no_update:
        print_updates(seq, args.particles, args.frames, args.passes, args.observe_threads)
    if args.accuracy:
        print_accuracy(Path(args.sequence).resolve().parent, np.random.default_rng(args.seed))
    if args.cold:
        cold_compile_seconds()
    return 0


if __name__ == "__main__":
    sys.exit(main())
