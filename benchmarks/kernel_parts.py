"""Where the fused warp + features + covariance kernel's time goes, compiled for this CPU and for AVX2 (issue 23).

The tracker's observation kernel (:func:`covviz.model.kernels.warp_descriptors_fast`) does three things
per particle: the bilinear warp of a (S+2)² grid (four scalar taps a sample: LLVM does not gather),
the nine features of each pixel, and their 45 float64 moments quadrant by quadrant. This script times
each stage alone over the same particles (the tracker's own, from a short run on the sequence), then
the whole kernel, in a fresh process per CPU target — this machine's, and LLVM's haswell (AVX2, no
AVX-512: :func:`benchmarks.speed.cpu_env`, kernels compiled into a cache of their own) — on one thread,
best of ``--repeat`` passes. It prints milliseconds per frame and nanoseconds per sample, and the
stages' sum against the whole (the rest: the per-particle set-up, the descriptors' assembly and
regularisation). The stage drivers call the kernel's own compiled functions; nothing is re-implemented.
The features and moments stages read the patches and features of 16 particles over and over (the
kernel keeps one particle's in scratch buffers that stay in L1; all 600 would time the memory).

Usage::

    python benchmarks/kernel_parts.py ../shared/sequences/Car4
    python benchmarks/kernel_parts.py ../shared/sequences/Car4 --cpu host --particles 600 --repeat 7
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed import _python, cpu_env, machine

CHILD = r"""
import json, time, numpy as np, numba
from covviz.data.sequences import open_sequence
from covviz.model import kernels as K
from covviz.trackers import make_tracker

seq = open_sequence({sequence!r})
tr = make_tracker("manifold", seed=0, n_particles={particles})
tr.init(seq.frame(0).image, seq.init_box)
for i in range(1, 11):
    tr.update(seq.frame(i).image)
rec = tr.last_record
model = tr.model
gray = np.ascontiguousarray(rec.inputs.gray, dtype=np.float32)
A = K._affine(rec.particle_poses, model.base_wh, model._sample_step())
S = model.patch_size
q = (np.arange(-1, S + 1, dtype=np.float64) + 0.5) / S - 0.5
u = K._coordinates(S)
n = len(A)

@numba.njit(nogil=True)
def warp(gray, A, q, reps):
    g = q.shape[0]; H, W = gray.shape; flat = gray.ravel()
    B = np.empty((g, g), np.float32); idx = np.empty(g, np.int32); dx = np.empty(g, np.int32)
    dy = np.empty(g, np.int32); al = np.empty(g, np.float32); be = np.empty(g, np.float32); s = 0.0
    for r in range(reps):
        for i in range(A.shape[0]):
            K._warp_patch(flat, H, W, A[i], q, B, idx, dx, dy, al, be)
            s += B[1, 1]
    return s

@numba.njit(nogil=True)
def patches(gray, A, q):
    g = q.shape[0]; H, W = gray.shape; flat = gray.ravel()
    P = np.empty((A.shape[0], g, g), np.float32); idx = np.empty(g, np.int32); dx = np.empty(g, np.int32)
    dy = np.empty(g, np.int32); al = np.empty(g, np.float32); be = np.empty(g, np.float32)
    for i in range(A.shape[0]):
        K._warp_patch(flat, H, W, A[i], q, P[i], idx, dx, dy, al, be)
    return P

@numba.njit(nogil=True)
def features(P, u, reps):
    g = P.shape[1]; S = g - 2; h = S // 2
    F = np.empty((7, h * h), np.float32); s = 0.0
    for r in range(reps):
        for i in range(P.shape[0]):
            for k in range(4):
                K._region_features(P[i % 16], h * (k // 2), h * (k % 2), h, h, np.float32(0.5), np.float32(2.0), F)
                s += F[3, 0]
    return s

@numba.njit(nogil=True)
def all_features(P, u):
    g = P.shape[1]; S = g - 2; h = S // 2
    F = np.empty((P.shape[0], 4, 7, h * h), np.float32)
    for i in range(P.shape[0]):
        for k in range(4):
            K._region_features(P[i], h * (k // 2), h * (k % 2), h, h, np.float32(0.5), np.float32(2.0), F[i, k])
    return F

@numba.njit(nogil=True)
def moments(F, XY, xyc, reps):
    S9 = np.empty(9); mean = np.empty(9); M = np.empty((9, 9)); s = 0.0
    for r in range(reps):
        for i in range(F.shape[0]):
            for k in range(4):
                K._region_moments(F[i % 16, k], XY[k], xyc[k], F.shape[3], S9, mean, M)
                s += M[2, 3]
    return s

def best(f, *args, repeat={repeat}):
    f(*args, 1)
    t = []
    for _ in range(repeat):
        t0 = time.perf_counter(); f(*args, 1); t.append(time.perf_counter() - t0)
    return min(t) * 1e3

P = patches(gray, A, q)
F = all_features(P, u)
XY = np.empty((4, 2, F.shape[3])); xyc = np.empty((4, 5)); K._region_coords(u, S, XY, xyc)
C, Q = K._outputs(n, True)
args = (gray, A, q, u, model.eps, model.gain_normalize, True, C, Q, model.grad_normalize, model.grad_floor)
whole = lambda reps: [K._descriptors_from_frame(*args) for _ in range(reps)]
out = {{
    "cpu": numba.config.CPU_NAME or "host", "n": n, "S": int(S),
    "warp": best(warp, gray, A, q), "features": best(features, P, u), "moments": best(moments, F, XY, xyc),
    "whole": best(whole),
}}
print(json.dumps(out))
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sequence")
    ap.add_argument("--particles", type=int, default=600)
    ap.add_argument("--repeat", type=int, default=5, help="passes per stage; the best is kept (default 5)")
    ap.add_argument("--cpu", choices=("host", "haswell", "both"), default="both")
    args = ap.parse_args(argv)
    print(machine())
    cpus = ("host", "haswell") if args.cpu == "both" else (args.cpu,)
    code = CHILD.format(sequence=str(args.sequence), particles=args.particles, repeat=args.repeat)
    rows = []
    with tempfile.TemporaryDirectory(prefix="covviz-haswell-") as cache:
        for cpu in cpus:
            env = cpu_env(cpu, cache if cpu == "haswell" else None)
            env["NUMBA_NUM_THREADS"] = "1"
            rows.append((cpu, json.loads(_python(code, env).strip().splitlines()[-1])))
    n, S = rows[0][1]["n"], rows[0][1]["S"]
    samples = {"warp": n * (S + 2) ** 2, "features": n * S * S, "moments": n * S * S, "whole": n * S * S}
    print(f"{n} particles, {S}x{S} patches: {n * S * S:,} samples a frame; one thread, best of {args.repeat}")
    print(f"{'stage':<22}" + "".join(f"{cpu + ' ms':>12}{'ns/sample':>11}" for cpu, _ in rows))
    for stage in ("warp", "features", "moments"):
        print(f"{stage:<22}" + "".join(f"{r[stage]:12.2f}{r[stage] * 1e6 / samples[stage]:11.2f}" for _, r in rows))
    print(f"{'sum of the stages':<22}" + "".join(f"{r['warp'] + r['features'] + r['moments']:12.2f}{'':>11}"
                                               for _, r in rows))
    print(f"{'the whole kernel':<22}" + "".join(f"{r['whole']:12.2f}{r['whole'] * 1e6 / samples['whole']:11.2f}"
                                              for _, r in rows))
    if len(rows) == 2:
        print("haswell / host: " + ", ".join(f"{k} {rows[1][1][k] / rows[0][1][k]:.2f}x"
                                               for k in ("warp", "features", "moments", "whole")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
