"""Compiled (numba) kernels for the manifold tracker's hot path.

The numpy functions of :mod:`covviz.model.features`, :mod:`covviz.model.descriptor` and
:mod:`covviz.trackers.manifold` stay the reference; these kernels compute the
same quantities with less work:

* :func:`warp_descriptors_fast` — from the grey frame to the descriptors in
  one pass per particle: the bilinear warp (bit for bit what
  :func:`covviz.model.features.warp_patches` gives), the 9 features and their
  moments, quadrant by quadrant, all in scratch buffers that stay in the L1
  cache. Nothing of size ``n x 34 x 34`` (patches, sampling maps) or
  ``n x 9 x 1024`` (feature planes) is ever written to memory.
  :func:`descriptors_fast` does the same from already warped patches.
* :func:`template_distances_fast` — ``d(expm(L_i), C_i)`` for every particle:
  the same Taylor exponential as :func:`covviz.model.spd.expm_taylor` and a cyclic
  Jacobi eigensolver, vectorised *across particles* (blocks of at most
  :data:`LANES` particles, structure-of-arrays, particle index innermost).
* :func:`quadrant_distances_fast` — ``sqrt(8·JBLD)`` of the quadrants by
  Cholesky factorisations, vectorised across particles the same way.
* :func:`pair_distances_fast` — the affine-invariant distance of given pairs of
  SPD matrices (the recorder's and ``covviz mds``'s distance matrices), by the
  same Jacobi on blocks of pairs.
* :func:`colour_window_fast`, :func:`colour_counts_fast` — the colour term's
  window (:mod:`covviz.model.fgbg`): each pixel's colour bin, its foreground
  probability and the integral image in one pass, and the box's and ring's
  histograms; the same values as the numpy path bit for bit, without its
  window-sized temporaries (whose fresh pages were most of its time).

Precision
---------
Features are float32, as in the numpy path, but each is rounded once
(differences of the unscaled patch, scaled after; see
:func:`_region_features`); their moments are float64 (products of float32
values are exact in float64). Distances are float64 throughout. Against a
float64 evaluation of the same definitions, on 10 real frames, the
descriptors agree to 2e-7 (relative, per matrix) and the distances to 1e-6;
the numpy path's own float32 moments and features put it up to ~8e-3 and
~5e-5 away. Each kernel states its ``fastmath`` flags and why; none uses
``nnan``/``ninf``/``arcp``/``afn``, so divisions, square roots and logarithms
are IEEE:

=========================  =========  ============================  ==========
kernel                     precision  fastmath                      why
=========================  =========  ============================  ==========
warp (``_warp_patch``)     float32    ``contract``                  cv2.remap's FMAs, bit for bit
features                   float32    none                          every rounding as written
sums, moments              float64    ``contract reassoc nsz``      vectorised sums (order fixed per patch)
distances (lanes)          float64    ``contract``                  no reassociation: lanes stay independent
=========================  =========  ============================  ==========

Determinism
-----------
Every particle's result depends on its inputs only: the per-particle loops
run the same code whatever the batch, and the across-particle (lane) loops
compute each lane with the same sequence of IEEE operations (fused
multiply-adds included) whether a lane falls in the vectorised body or in the
scalar remainder, and without a reduction across lanes. Results are bit for
bit the same for any chunking, thread count or repetition (tested). One
caveat: with Intel's SVML installed (``icc_rt``; numba reports it as
``numba.config.USING_SVML``), numba may vectorise the per-lane logarithms with
SVML in a loop body and call libm in its remainder, which differ in the last
bit; the chunking tests would then fail. It is not installed here.

Switches
--------
``COVVIZ_NO_JIT=1`` (or numba missing) sets :data:`JIT_ENABLED` to False; the
tracker then takes the numpy path. The kernels compile on first use and are
cached on disk (``cache=True``; numba's ``__pycache__``); :func:`kernels_cached`
tells a CLI whether a first call will compile, :func:`warmup` compiles (or
loads) everything.
"""

from __future__ import annotations

import importlib.abc
import math
import os
import sys
import threading
import time
from collections.abc import Callable

import numpy as np

from covviz.model.features import FEATURE_SCALE, N_FEATURES

#: ``COVVIZ_NO_JIT=1`` (or ``true``/``yes``): the numpy path, and numba is not even imported.
_DISABLED = os.environ.get("COVVIZ_NO_JIT", "").strip().lower() in ("1", "true", "yes")
numba = None


class _NoScipyLinalg(importlib.abc.MetaPathFinder):
    """Refuses ``scipy.linalg`` (and its ``cython_blas``) to the thread that made it, while it is on ``sys.meta_path``."""

    def __init__(self) -> None:
        self.owner = threading.get_ident()

    def find_spec(self, name, path=None, target=None):
        if name in ("scipy.linalg", "scipy.linalg.cython_blas") and threading.get_ident() == self.owner:
            raise ImportError(f"{name}: not imported at start-up (covviz.model.kernels)")


def _import_numba_arraymath() -> None:
    """Import ``numba.np.arraymath`` without its BLAS probe importing ``scipy.linalg`` (~0.15-0.25 s of start-up).

    numba builds its target registries at the first load of a cached kernel, and one of them,
    ``numba.np.arraymath``, asks at import whether BLAS is there by importing
    ``scipy.linalg.cython_blas`` — all of ``scipy.linalg``, which nothing on ``covviz track``'s path
    needs: these kernels use no ``np.dot`` and no ``np.linalg``. Refused while arraymath is
    imported, the probe finds no BLAS, and the one thing that changes in this process is that a
    jitted ``np.dot`` of two vectors uses numba's own loop instead of BLAS (its other linear algebra
    imports scipy when it is compiled, as before). Nothing is refused if scipy.linalg or arraymath
    are already imported (the recorder's MDS imports scipy.linalg; then the probe costs nothing).
    """
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        return
    finder = _NoScipyLinalg()
    sys.meta_path.insert(0, finder)
    try:
        import numba.np.arraymath  # noqa: F401
    finally:
        sys.meta_path.remove(finder)


if not _DISABLED:
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is a dependency; the numpy path must not need it
        numba = None
    else:
        try:
            _import_numba_arraymath()
        except ImportError:  # pragma: no cover - an arraymath that will not import alone: the registries import it
            pass

__all__ = [
    "JIT_ENABLED",
    "LANES",
    "descriptors_fast",
    "kernels_cached",
    "pair_distances_fast",
    "quadrant_distances_fast",
    "template_distances_fast",
    "warmup",
    "warp_descriptors_fast",
]

#: True when the tracker should use these kernels: numba is importable and
#: the environment variable ``COVVIZ_NO_JIT`` is not set to ``1``. (Without
#: numba the functions below still run, as plain and very slow Python.)
JIT_ENABLED = numba is not None

#: Particles per structure-of-arrays block in :func:`template_distances_fast`
#: (its loops over particles are the vectorised ones). 64: 9x9 matrices of 64
#: lanes (41 KB each) stay in L2 and the loops are long enough to amortise
#: their set-up; results do not depend on it.
LANES = 64

_ENTRY_POINTS = []  # the kernels called from Python, for kernels_cached()
_THREAD = threading.local()


def _workspace(kind: str, d: int, mats: int, vecs: int):
    """This thread's scratch for a lane kernel: ``mats`` (d, d, LANES) and ``vecs`` (LANES,) arrays and more.

    Allocated once per thread, kind and size.

    Fresh allocations on every call cost more than the distances themselves:
    ~300 KB of scratch freed and re-allocated per chunk went back to the
    operating system and came back as page faults (0.25 ms per 600
    particles). Results never depend on the scratch's previous content.
    """
    key = (kind, d)
    ws = getattr(_THREAD, "ws", None)
    if ws is None:
        ws = _THREAD.ws = {}
    if key not in ws:
        ws[key] = (np.zeros((mats, d, d, LANES)), np.zeros((vecs, LANES)), np.zeros(LANES, dtype=np.int64),
                   np.zeros(LANES, dtype=np.bool_))
    return ws[key]


def _jit(fastmath, entry=False):
    """``numba.njit`` with the project's settings (or the plain function when numba is missing).

    ``cache=True`` (compile once per machine), ``nogil=True`` (the tracker runs
    chunks on threads), ``error_model="numpy"`` (a float division by zero
    gives inf/nan instead of a Python exception check in every loop, which
    also keeps loops vectorisable) and an explicit ``fastmath`` set.
    """

    def wrap(f):
        if numba is None:  # pragma: no cover
            return f
        d = numba.njit(cache=True, nogil=True, error_model="numpy", fastmath=fastmath)(f)
        if entry:
            _ENTRY_POINTS.append(d)
        return d

    return wrap


# --------------------------------------------------------------------------- #
# descriptors: warp, features, moments
# --------------------------------------------------------------------------- #
# fastmath sets. The warp must reproduce cv2.remap bit for bit, which computes
# p00 + a·(p01 − p00) with fused multiply-adds: "contract" and nothing else.
_FM_WARP = {"contract"}
# Features: no fastmath at all, every operation rounds as written (see
# _region_features). With "reassoc", LLVM rewrote the gain scaling and the
# second differences and moved nearly flat patches' angles by up to 5e-3
# (tiny gradients rounded differently point elsewhere). These loops have no
# reductions, so they vectorise without it.
_FM_FEAT = False
# Sums and moments: "reassoc" (the float64 sums over a quadrant's pixels
# vectorise; their order is fixed by the patch size, the same for every
# particle), "contract" (FMA), "nsz". No sum ever spans two particles.
_FM_SUM = {"contract", "reassoc", "nsz"}

# atan(t)·2/π ≈ t·Σ c_k t^(2k) on [0, 1]: least squares on Chebyshev nodes
# refined to near-minimax (Lawson); max error 2.4e-8 in float64 and 1.0e-7
# evaluated in float32 (numpy's float32 arctan2 scaled alike: 1.1e-7).
_ATAN_C = (
    0.6366193493840409,
    -0.21218448386436656,
    0.126983780900303,
    -0.08854508593397271,
    0.06138413486692744,
    -0.03559489280142916,
    0.013918391212490978,
    -0.002581217622318485,
)

# The kernels hard-code the feature scales the numpy path uses (the doubling
# trick of covviz.model.features._fill_features and the 2/π of the angle).
_EXPECTED_SCALE = np.array([1.0, 1.0, 1.0, 4.0, 4.0, 4.0, 2.0 / np.pi, 2.0, 2.0], dtype=np.float32)
if not np.array_equal(FEATURE_SCALE, _EXPECTED_SCALE) or N_FEATURES != 9:  # pragma: no cover
    raise ImportError("covviz.model.kernels assumes the feature scales of covviz.model.features; update both together")


@_jit(_FM_WARP)
def _warp_patch(flat, H, W, a, q, B, idx, dx, dy, al, be):
    """Bilinear samples of one pose's grid into ``B`` (g, g), float32, BORDER_REPLICATE.

    ``a`` (6,): ``x = a0 + a1·q[u] + a2·q[v]``, ``y = a3 + a4·q[u] + a5·q[v]``
    in pixel-centre coordinates (what :func:`covviz.model.features.sample_grid`
    gives cv2.remap), rounded to float32 as there; then OpenCV 5's float
    bilinear interpolation: ``f0 = p00 + α(p01 − p00)``, ``f1 = p10 + α(p11 −
    p10)``, ``f0 + β(f1 − f0)``, each a fused multiply-add. ``idx``, ``dx``,
    ``dy`` (g,) int32 and ``al``, ``be`` (g,) float32 are scratch. A row is
    two loops: the coordinates (vectorised), then the four taps and the
    interpolation (scalar loads: LLVM will not gather from an array it cannot
    prove distinct from the one the loop stores to). The tap indices are int32:
    AVX2 converts 8 float32 to int32 in one instruction but has no packed
    float-to-int64 conversion (AVX-512DQ's), so int64 indices made the
    coordinate loop scalar there (the warp took 1.85x the host's time compiled
    for haswell; 1.02x now: ``benchmarks/kernel_parts.py``). The frame must
    then have fewer than 2**31 pixels (:func:`warp_descriptors_fast` checks).
    """
    g = q.shape[0]
    W32 = np.int32(W)
    lo = np.float32(-2.0)
    xmax = np.float32(W + 1)
    ymax = np.float32(H + 1)
    a0, a1, a2, a3, a4, a5 = a[0], a[1], a[2], a[3], a[4], a[5]
    # Is every tap inside the frame (no clamping needed)? The grid is an
    # affine image of a square, so its extreme points are the four corners;
    # one pixel of margin, as interior samples could round past a corner by
    # an ulp.
    inside = True
    for v in (0, g - 1):
        for u in (0, g - 1):
            x = np.float32(a0 + a1 * q[u] + a2 * q[v])
            y = np.float32(a3 + a4 * q[u] + a5 * q[v])
            if not (x >= 0.0 and x < W - 2 and y >= 0.0 and y < H - 2):
                inside = False
    for v in range(g):
        row = B[v]
        if inside:
            for u in range(g):
                x = np.float32(a0 + a1 * q[u] + a2 * q[v])
                y = np.float32(a3 + a4 * q[u] + a5 * q[v])
                fx = np.floor(x)
                fy = np.floor(y)
                al[u] = x - fx
                be[u] = y - fy
                idx[u] = np.int32(fy) * W32 + np.int32(fx)
            for u in range(g):
                k = idx[u]
                p00 = flat[k]
                p01 = flat[k + 1]
                p10 = flat[k + W]
                p11 = flat[k + W + 1]
                f0 = p00 + al[u] * (p01 - p00)
                f1 = p10 + al[u] * (p11 - p10)
                row[u] = f0 + be[u] * (f1 - f0)
        else:
            for u in range(g):
                x = np.float32(a0 + a1 * q[u] + a2 * q[v])
                y = np.float32(a3 + a4 * q[u] + a5 * q[v])
                # Far outside, every tap is the same border pixel: clamping the
                # coordinate first keeps the integer conversion in range and
                # changes no value (α·(p01 − p00) = α·0).
                x = min(max(x, lo), xmax)
                y = min(max(y, lo), ymax)
                fx = np.floor(x)
                fy = np.floor(y)
                al[u] = x - fx
                be[u] = y - fy
                ix = np.int64(fx)
                iy = np.int64(fy)
                x0 = min(max(ix, 0), W - 1)
                x1 = min(max(ix + 1, 0), W - 1)
                y0 = min(max(iy, 0), H - 1)
                y1 = min(max(iy + 1, 0), H - 1)
                idx[u] = y0 * W + x0
                dx[u] = x1 - x0
                dy[u] = (y1 - y0) * W
            for u in range(g):
                k = idx[u]
                p00 = flat[k]
                p01 = flat[k + dx[u]]
                p10 = flat[k + dy[u]]
                p11 = flat[k + dy[u] + dx[u]]
                f0 = p00 + al[u] * (p01 - p00)
                f1 = p10 + al[u] * (p11 - p10)
                row[u] = f0 + be[u] * (f1 - f0)


@_jit(_FM_FEAT)
def _region_features(B, r0, c0, hr, hc, mean32, kf, F):
    """The 7 scaled image features of the ``hr x hc`` region at interior offset ``(r0, c0)`` of ``B`` into ``F``.

    ``B`` (S+2, S+2) float32 is the bordered patch *before* gain
    normalisation, ``mean32`` the mean of its interior and ``kf`` its gain
    factor (1 without normalisation); ``F`` (7, ≥ hr·hc) float32, pixels
    row-major: features 2..8 (``I, |Ix|, |Iy|, |grad I|, angle, |Ixx|,
    |Iyy|``). The coordinates (features 0 and 1) are the same for every
    patch: :func:`_region_coords` gives them once per call. (Storing the
    features as float64, which spares :func:`_region_moments` its
    conversions, made this stage 30% slower than the conversions cost.)

    The features of :func:`covviz.model.features.patch_features`, each rounded
    once: differences of neighbouring pixels are taken on the unscaled patch
    (exact in float32 when the pixels are within a factor 2) and scaled
    after, and second differences as ``(r − c) + (l − c)``. The numpy path
    scales the patch first and forms ``(r + l) − 2c``, whose rounding errors
    are relative to the *intensity*: on nearly flat patches they are a large
    part of small derivatives, the angle of two such derivatives is noise,
    and that path's descriptors (hence distances, by up to 5e-5 on real
    frames) depend on the last bit of the gain. Here every feature is within
    a few float32 roundings of its float64 value. The angle is a float32
    polynomial (:data:`_ATAN_C`, 1e-7) of the exact differences. Several
    short loops, each writing few arrays: LLVM vectorises a loop only when it
    can check the overlap of its arrays with few run-time tests.
    """
    one = np.float32(1.0)
    zero = np.float32(0.0)
    k2 = kf * np.float32(2.0)  # the derivative scale: 0.5·FEATURE_SCALE[3] == FEATURE_SCALE[7] == 2 (exact)
    for rr in range(hr):
        R = r0 + rr + 1
        o = rr * hc
        row = B[R, c0 : c0 + hc + 2]
        o2 = F[0, o : o + hc]
        o3 = F[1, o : o + hc]
        o7 = F[5, o : o + hc]
        for cc in range(hc):
            ctr = row[cc + 1]
            left = row[cc]
            right = row[cc + 2]
            o2[cc] = np.float32((ctr - mean32) * kf)
            o3[cc] = np.float32(abs(right - left))  # unscaled until the angle is taken
            o7[cc] = np.float32(abs((right - ctr) + (left - ctr)) * k2)
        up = B[R - 1, c0 + 1 : c0 + hc + 1]
        mid = B[R, c0 + 1 : c0 + hc + 1]
        dn = B[R + 1, c0 + 1 : c0 + hc + 1]
        o4 = F[2, o : o + hc]
        o8 = F[6, o : o + hc]
        for cc in range(hc):
            t = up[cc]
            b = dn[cc]
            m = mid[cc]
            o4[cc] = np.float32(abs(b - t))
            o8[cc] = np.float32(abs((b - m) + (t - m)) * k2)
    c0f = np.float32(_ATAN_C[0])
    c1f = np.float32(_ATAN_C[1])
    c2f = np.float32(_ATAN_C[2])
    c3f = np.float32(_ATAN_C[3])
    c4f = np.float32(_ATAN_C[4])
    c5f = np.float32(_ATAN_C[5])
    c6f = np.float32(_ATAN_C[6])
    c7f = np.float32(_ATAN_C[7])
    N = hr * hc
    gx = F[1, :N]
    gy = F[2, :N]
    o5 = F[3, :N]
    o6 = F[4, :N]
    for j in range(N):
        ix = np.float32(gx[j])  # exact: a float32 value
        iy = np.float32(gy[j])
        # atan2(|Ix|, |Iy|) in [0, π/2], scaled to [0, 1]; 0 where both vanish (as arctan2).
        mn = min(ix, iy)
        mx = max(ix, iy)
        t = mn / mx if mx > zero else zero
        z = t * t
        p = ((((((c7f * z + c6f) * z + c5f) * z + c4f) * z + c3f) * z + c2f) * z + c1f) * z + c0f
        p = p * t
        o6[j] = one - p if ix > iy else p
        ix = ix * k2
        iy = iy * k2
        gx[j] = ix
        gy[j] = iy
        o5[j] = np.float32(math.sqrt(ix * ix + iy * iy))


@_jit(_FM_SUM)
def _cross3(a0, a1, a2, b0, b1, b2, N, M, i, j):
    """``M[i+p, j+q] = Σ_k a_p[k]·b_q[k]`` for ``p, q < 3``: nine float64 dot products in one pass.

    Six rows loaded per pixel for nine products; the nine sums stay in vector
    registers (with the six rows, 15 of AVX2's 16).
    """
    s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
    for k in range(N):
        x0 = np.float64(a0[k])
        x1 = np.float64(a1[k])
        x2 = np.float64(a2[k])
        y0 = np.float64(b0[k])
        y1 = np.float64(b1[k])
        y2 = np.float64(b2[k])
        s00 += x0 * y0
        s01 += x0 * y1
        s02 += x0 * y2
        s10 += x1 * y0
        s11 += x1 * y1
        s12 += x1 * y2
        s20 += x2 * y0
        s21 += x2 * y1
        s22 += x2 * y2
    M[i, j] = s00
    M[i, j + 1] = s01
    M[i, j + 2] = s02
    M[i + 1, j] = s10
    M[i + 1, j + 1] = s11
    M[i + 1, j + 2] = s12
    M[i + 2, j] = s20
    M[i + 2, j + 1] = s21
    M[i + 2, j + 2] = s22


@_jit(_FM_SUM)
def _sym3(a0, a1, a2, N, M, S, i):
    """The upper triangle of ``M[i:i+3, i:i+3]`` (six dot products) and the sums ``S[i:i+3]``, in one pass."""
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0
    t0 = t1 = t2 = 0.0
    for k in range(N):
        x0 = np.float64(a0[k])
        x1 = np.float64(a1[k])
        x2 = np.float64(a2[k])
        s00 += x0 * x0
        s01 += x0 * x1
        s02 += x0 * x2
        s11 += x1 * x1
        s12 += x1 * x2
        s22 += x2 * x2
        t0 += x0
        t1 += x1
        t2 += x2
    M[i, i] = s00
    M[i, i + 1] = s01
    M[i, i + 2] = s02
    M[i + 1, i + 1] = s11
    M[i + 1, i + 2] = s12
    M[i + 2, i + 2] = s22
    S[i] = t0
    S[i + 1] = t1
    S[i + 2] = t2


@_jit(_FM_SUM)
def _xyi_cross3(x, y, f, b0, b1, b2, N, M, S):
    """Rows 0–2 (``x, y, I``) against features 3–5, and ``Σ x·I``, ``Σ y·I``, ``Σ I²``, ``Σ I``, in one pass.

    :func:`_cross3` with four more sums (13 accumulators): the intensity's
    own products ride along instead of a pass of their own. (A pass of four
    sums alone got another interleave from LLVM: the same values, summed in
    another order, a last bit apart from the previous kernels' Σ I².)
    """
    s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
    sx = sy = sf = t = 0.0
    for k in range(N):
        x0 = x[k]
        x1 = y[k]
        x2 = np.float64(f[k])
        y0 = np.float64(b0[k])
        y1 = np.float64(b1[k])
        y2 = np.float64(b2[k])
        s00 += x0 * y0
        s01 += x0 * y1
        s02 += x0 * y2
        s10 += x1 * y0
        s11 += x1 * y1
        s12 += x1 * y2
        s20 += x2 * y0
        s21 += x2 * y1
        s22 += x2 * y2
        sx += x0 * x2
        sy += x1 * x2
        sf += x2 * x2
        t += x2
    M[0, 3] = s00
    M[0, 4] = s01
    M[0, 5] = s02
    M[1, 3] = s10
    M[1, 4] = s11
    M[1, 5] = s12
    M[2, 3] = s20
    M[2, 4] = s21
    M[2, 5] = s22
    M[0, 2] = sx
    M[1, 2] = sy
    M[2, 2] = sf
    S[2] = t


@_jit(_FM_SUM)
def _region_moments(F, XY, xyc, N, S, mean, M):
    """Mean ``mean`` (9,) and centred second moments ``M`` (9, 9), float64, of one region's features.

    ``F`` (7, ≥ N) float32: the image features (:func:`_region_features`);
    ``XY`` (2, ≥ N) float64: the region's coordinates and ``xyc`` (5,) their
    sums ``Σx, Σy, Σx², Σxy, Σy²`` (:func:`_region_coords`, once per call:
    they are the same for every patch). ``S`` (9,) float64 scratch.

    Raw moments and sums in float64 (products of float32 values are exact),
    then ``M = Σ f fᵀ − N·m mᵀ``. Each of the 45 distinct products is formed
    once, and the 5 that involve only the coordinates not at all: 40 fused
    multiply-adds, 7 additions and 20 float32-to-float64 conversions a pixel,
    in five passes over the rows of three features (:func:`_xyi_cross3`,
    :func:`_cross3`, :func:`_sym3`); the sums come out bit for bit those of
    the previous layout (full 3x3 blocks of the 9 rows: 54 products, 18 sums
    and 36 conversions a pixel; the moments stage 1.2-1.5x slower). In float64 the
    cancellation costs ~1e-16·(mean/std)² relative, nothing for these
    features (centred coordinates and intensity, derivatives whose mean is of
    the order of their spread). (float32 sums, even of centred features, were
    not enough: ``|grad I|`` is nearly a function of ``|Ix|`` and ``|Iy|``,
    and the affine-invariant distance magnifies an error in that thin
    direction ~100x; float32 dot products put 1e-5 to 1e-4 into the distances
    of real patches. A two-pass float64 version, centring first, was 25%
    slower for no accuracy that shows.)
    """
    d = 9
    x = XY[0, :N]
    y = XY[1, :N]
    f2 = F[0, :N]
    f3 = F[1, :N]
    f4 = F[2, :N]
    f5 = F[3, :N]
    f6 = F[4, :N]
    f7 = F[5, :N]
    f8 = F[6, :N]
    S[0] = xyc[0]
    S[1] = xyc[1]
    M[0, 0] = xyc[2]
    M[0, 1] = xyc[3]
    M[1, 1] = xyc[4]
    _xyi_cross3(x, y, f2, f3, f4, f5, N, M, S)
    _cross3(x, y, f2, f6, f7, f8, N, M, 0, 6)
    _sym3(f3, f4, f5, N, M, S, 3)
    _cross3(f3, f4, f5, f6, f7, f8, N, M, 3, 6)
    _sym3(f6, f7, f8, N, M, S, 6)
    for a in range(d):
        mean[a] = S[a] / N
    for a in range(d):
        for b in range(a, d):
            v = M[a, b] - S[a] * S[b] / N
            M[a, b] = v
            M[b, a] = v


@_jit(_FM_SUM)
def _region_coords(u, S, XY, xyc):
    """The coordinates (features 0 and 1) of each region of an ``S x S`` patch, and their sums.

    ``XY`` (regions, 2, pixels of a region) float64 and ``xyc`` (regions, 5):
    ``Σx, Σy, Σx², Σxy, Σy²`` over the region. The regions of
    :func:`_patch_descriptors`: four quadrants (row-major) for an even ``S``,
    the whole patch for an odd one. The same for every patch of a call.
    """
    if S % 2 == 0:
        h = S // 2
        nreg = 4
    else:
        h = S
        nreg = 1
    for k in range(nreg):
        r0 = h * (k // 2) if nreg == 4 else 0
        c0 = h * (k % 2) if nreg == 4 else 0
        sx = sy = sxx = sxy = syy = 0.0
        for rr in range(h):
            for cc in range(h):
                xv = np.float64(u[c0 + cc])
                yv = np.float64(u[r0 + rr])
                XY[k, 0, rr * h + cc] = xv
                XY[k, 1, rr * h + cc] = yv
                sx += xv
                sy += yv
                sxx += xv * xv
                sxy += xv * yv
                syy += yv * yv
        xyc[k, 0] = sx
        xyc[k, 1] = sy
        xyc[k, 2] = sxx
        xyc[k, 3] = sxy
        xyc[k, 4] = syy


@_jit(_FM_SUM)
def _interior_sum(B):
    """Sum of the interior of a bordered patch ``B`` (S+2, S+2) float32, in float64."""
    g = B.shape[0]
    s = 0.0
    for rr in range(1, g - 1):
        row = B[rr, 1 : g - 1]
        for cc in range(g - 2):
            s += row[cc]
    return s


@_jit(_FM_FEAT)
def _regularize(C, eps):
    """``C + eps·(tr C / d + 1e-12)·I`` in place (:func:`covviz.model.spd.regularize`)."""
    d = C.shape[0]
    tr = 0.0
    for a in range(d):
        tr += C[a, a]
    add = eps * (tr / d + 1e-12)
    for a in range(d):
        C[a, a] += add


@_jit(_FM_FEAT)
def _patch_descriptors(B, XY, xyc, eps, gain_normalize, quadrants, F, mq, Mq, r, C, Q, grad_normalize=0.0,
                       grad_floor=0.0):
    """Descriptors of one bordered patch ``B`` (S+2, S+2) float32.

    Writes ``C`` (9, 9) and, with ``quadrants``, ``Q`` (4, 9, 9). ``XY``
    and ``xyc``: the regions' coordinates and their sums
    (:func:`_region_coords`). ``F`` (7, pixels of a region) float32, ``mq``
    (4, 9), ``Mq`` (4, 9, 9), ``r`` (9,): scratch. With ``grad_normalize`` (a power ``a`` > 0), the
    first-derivative features are divided by the patch's mean ``|grad I|``
    to the power ``a`` and the second derivatives by theirs, as a congruence
    of the moments before regularisation (the numpy path's
    :func:`covviz.model.features.normalize_gradients`); the mean ``|grad I|`` is
    floored at ``grad_floor`` (and 1e-6), the second derivatives' at 1e-6.
    """
    g = B.shape[0]
    S = g - 2
    d = 9
    mean = _interior_sum(B) / (S * S)
    mean32 = np.float32(mean)
    kf = np.float32(1.0)
    if gain_normalize:
        # The numpy path's factor 1 / max(gain, 1e-3), in float32; applied to
        # each feature rather than to the patch (see _region_features).
        kf = np.float32(1.0) / max(mean32, np.float32(1e-3))
    if S % 2 == 0:
        h = S // 2
        nreg = 4
        N = h * h
        for k in range(4):
            r0 = h * (k // 2)
            c0 = h * (k % 2)
            _region_features(B, r0, c0, h, h, mean32, kf, F)
            _region_moments(F, XY[k], xyc[k], N, r, mq[k], Mq[k])
    else:
        nreg = 1
        N = S * S
        _region_features(B, 0, 0, S, S, mean32, kf, F)
        _region_moments(F, XY[0], xyc[0], N, r, mq[0], Mq[0])
    # The whole patch: the regions' centred moments plus the spread of their means.
    for a in range(d):
        m = 0.0
        for k in range(nreg):
            m += mq[k, a]
        r[a] = m / nreg
    tot = nreg * N
    for a in range(d):
        for b in range(a, d):
            acc = 0.0
            for k in range(nreg):
                acc += Mq[k, a, b] + N * (mq[k, a] - r[a]) * (mq[k, b] - r[b])
            v = acc / (tot - 1)
            C[a, b] = v
            C[b, a] = v
    g1 = 1.0
    g2 = 1.0
    if grad_normalize > 0:
        g1 = max(r[5], max(grad_floor, 1e-6)) ** -grad_normalize
        g2 = max(0.5 * (r[7] + r[8]), 1e-6) ** -grad_normalize
        for a in range(d):
            ka = g1 if (a >= 3 and a <= 5) else (g2 if a >= 7 else 1.0)
            for b in range(d):
                kb = g1 if (b >= 3 and b <= 5) else (g2 if b >= 7 else 1.0)
                C[a, b] *= ka * kb
    _regularize(C, eps)
    if quadrants:
        for k in range(4):
            for a in range(d):
                ka = g1 if (a >= 3 and a <= 5) else (g2 if a >= 7 else 1.0)
                for b in range(d):
                    kb = g1 if (b >= 3 and b <= 5) else (g2 if b >= 7 else 1.0)
                    Q[k, a, b] = Mq[k, a, b] / (N - 1) * (ka * kb)
            _regularize(Q[k], eps)


@_jit(_FM_FEAT, entry=True)
def _descriptors_from_patches(P, u, eps, gain_normalize, quadrants, C, Q, grad_normalize, grad_floor):
    n, g, _ = P.shape
    S = g - 2
    npix = S * S if S % 2 else (S // 2) ** 2
    F = np.empty((7, npix), dtype=np.float32)
    XY = np.empty((1 if S % 2 else 4, 2, npix))
    xyc = np.empty((1 if S % 2 else 4, 5))
    _region_coords(u, S, XY, xyc)
    mq = np.empty((4, 9))
    Mq = np.empty((4, 9, 9))
    r = np.empty(9)
    for i in range(n):
        _patch_descriptors(P[i], XY, xyc, eps, gain_normalize, quadrants, F, mq, Mq, r, C[i], Q[i] if quadrants else Q[0],
                           grad_normalize, grad_floor)


@_jit(_FM_FEAT, entry=True)
def _descriptors_from_frame(gray, A, q, u, eps, gain_normalize, quadrants, C, Q, grad_normalize, grad_floor):
    n = A.shape[0]
    g = q.shape[0]
    S = g - 2
    H, W = gray.shape
    flat = gray.ravel()
    B = np.empty((g, g), dtype=np.float32)
    npix = S * S if S % 2 else (S // 2) ** 2
    F = np.empty((7, npix), dtype=np.float32)
    XY = np.empty((1 if S % 2 else 4, 2, npix))
    xyc = np.empty((1 if S % 2 else 4, 5))
    _region_coords(u, S, XY, xyc)
    mq = np.empty((4, 9))
    Mq = np.empty((4, 9, 9))
    r = np.empty(9)
    idx = np.empty(g, dtype=np.int32)
    dx = np.empty(g, dtype=np.int32)
    dy = np.empty(g, dtype=np.int32)
    al = np.empty(g, dtype=np.float32)
    be = np.empty(g, dtype=np.float32)
    for i in range(n):
        _warp_patch(flat, H, W, A[i], q, B, idx, dx, dy, al, be)
        _patch_descriptors(B, XY, xyc, eps, gain_normalize, quadrants, F, mq, Mq, r, C[i], Q[i] if quadrants else Q[0],
                           grad_normalize, grad_floor)


def _coordinates(S: int) -> np.ndarray:
    """The centred pixel coordinates of :func:`covviz.model.features.patch_features`, ``(S,)`` float32."""
    return (np.arange(S, dtype=np.float32) + 0.5) / S - 0.5


def _outputs(n: int, quadrants: bool):
    C = np.empty((n, 9, 9))
    Q = np.empty((n, 4, 9, 9)) if quadrants else np.empty((1, 4, 9, 9))
    return C, Q


def descriptors_fast(patches, eps: float, gain_normalize: bool = True, quadrants: bool = True,
                     grad_normalize: float = 0.0, grad_floor: float = 0.0):
    """Descriptors of warped patches, as the numpy path computes them.

    Equal (within the tolerances of ``tests/test_kernels.py``) to
    ``quadrant_covariances(patch_features(patches, gain_normalize=...,
    quadrants=True), eps)``, or to ``covariance(patch_features(...), eps)``
    and ``None`` without ``quadrants``.

    Parameters
    ----------
    patches : ndarray, shape (n, S + 2, S + 2), float32
        Bordered patches (:func:`covviz.model.features.warp_patches`).
    eps : float
        Shrinkage of :func:`covviz.model.spd.regularize`.
    gain_normalize, quadrants : bool
        As in :class:`covviz.trackers.manifold.ManifoldConfig`.
    grad_normalize, grad_floor : float
        As in :class:`covviz.trackers.manifold.ManifoldConfig`
        (:func:`covviz.model.features.normalize_gradients`' ``power`` and ``floor``).

    Returns
    -------
    C : ndarray, shape (n, 9, 9), float64
    Q : ndarray, shape (n, 4, 9, 9), float64, or None without ``quadrants``
        Top-left, top-right, bottom-left, bottom-right.

    Notes
    -----
    float32 features, centred float32 dot products over each quadrant
    (256 pixels at ``S = 32``) finished in float64; the numpy path's raw float32
    moments are the less accurate of the two against a float64 oracle.
    """
    P = np.ascontiguousarray(patches, dtype=np.float32)
    if P.ndim != 3 or P.shape[1] != P.shape[2] or P.shape[1] < 4:
        raise ValueError(f"patches must have shape (n, S+2, S+2) with S >= 2; got {P.shape}")
    S = P.shape[1] - 2
    if quadrants and S % 2:
        raise ValueError(f"quadrants need an even patch side, got {S}")
    C, Q = _outputs(len(P), quadrants)
    _descriptors_from_patches(P, _coordinates(S), float(eps), bool(gain_normalize), bool(quadrants), C, Q,
                              float(grad_normalize), float(grad_floor))
    return C, (Q if quadrants else None)


def _check_out(a, shape: tuple, name: str) -> None:
    """``a`` can take a kernel's output of ``shape``: float64, C-contiguous, writeable."""
    if not (isinstance(a, np.ndarray) and a.shape == shape and a.dtype == np.float64 and a.flags.c_contiguous
            and a.flags.writeable):
        got = (getattr(a, "shape", None), getattr(a, "dtype", None))
        raise ValueError(f"out {name} must be a writeable C-contiguous float64 array of shape {shape}; got {got}")


def _affine(poses, base_wh, step) -> np.ndarray:
    """Per-pose coefficients of the sampling grid, ``(n, 6)``: those of :func:`covviz.model.features.sample_grid`."""
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim == 1:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 4:
        raise ValueError(f"poses must have shape (n, 4) as cx, cy, scale, theta; got {np.shape(poses)}")
    sx, sy = (step, step) if np.isscalar(step) else step
    c, s = np.cos(p[:, 3]), np.sin(p[:, 3])
    sw, sh = base_wh[0] * p[:, 2], base_wh[1] * p[:, 2]
    return np.stack(
        [p[:, 0] / sx - 0.5, c * sw / sx, -s * sh / sx, p[:, 1] / sy - 0.5, s * sw / sy, c * sh / sy], axis=1
    )


def warp_descriptors_fast(
    gray, poses, base_wh, size: int = 32, step=1.0, eps: float = 1e-3, gain_normalize: bool = True,
    quadrants: bool = True, grad_normalize: float = 0.0, grad_floor: float = 0.0, out=None,
):
    """Descriptors at ``poses`` straight from the frame: warp, features and moments fused.

    The same as ``descriptors_fast(warp_patches(gray, poses, base_wh, size, 1,
    step), ...)``; the warp is bit for bit :func:`covviz.model.features.warp_patches`
    (OpenCV 5's float bilinear interpolation with BORDER_REPLICATE).

    Parameters
    ----------
    gray : ndarray, shape (H, W), float32
    poses : ndarray, shape (n, 4)
        ``cx, cy, scale, theta`` in pixels of the full-size frame.
    base_wh : (float, float)
    size : int
        Patch side ``S``.
    step : float or (float, float)
        Downsampling factor of ``gray`` (see :func:`covviz.model.features.sample_grid`).
    eps, gain_normalize, quadrants, grad_normalize, grad_floor
        As in :func:`descriptors_fast`.
    out : (C, Q), optional
        Arrays to write the descriptors into (C-contiguous float64 of the shapes returned; ``Q``
        None without ``quadrants``), e.g. rows of a larger batch's arrays: no copy after.

    Returns
    -------
    C : ndarray, shape (n, 9, 9), float64
    Q : ndarray, shape (n, 4, 9, 9), float64, or None without ``quadrants``
    """
    g32 = np.ascontiguousarray(gray, dtype=np.float32)
    if g32.ndim != 2 or min(g32.shape) < 2:
        raise ValueError(f"gray must have shape (H, W) with H, W >= 2; got {g32.shape}")
    if g32.size >= 2**31:  # the warp's tap indices are int32 (see _warp_patch)
        raise ValueError(f"a frame of {g32.shape[1]}x{g32.shape[0]} has 2**31 pixels or more: too large to observe")
    if size < 2 or (quadrants and size % 2):
        raise ValueError(f"size must be at least 2 (and even with quadrants), got {size}")
    A = _affine(poses, base_wh, step)
    if not np.isfinite(A).all():
        raise ValueError("poses, base_wh or step contain NaN or inf")
    q = (np.arange(-1, size + 1, dtype=np.float64) + 0.5) / size - 0.5  # features._unit_grid's coordinates
    if out is None:
        C, Q = _outputs(len(A), quadrants)
    else:
        C, Q = out
        _check_out(C, (len(A), 9, 9), "C")
        if quadrants:
            _check_out(Q, (len(A), 4, 9, 9), "Q")
        else:
            Q = np.empty((1, 4, 9, 9))  # the kernel's unused scratch argument, as _outputs gives it
    _descriptors_from_frame(g32, A, q, _coordinates(size), float(eps), bool(gain_normalize), bool(quadrants), C, Q,
                            float(grad_normalize), float(grad_floor))
    return C, (Q if quadrants else None)


# --------------------------------------------------------------------------- #
# distances
# --------------------------------------------------------------------------- #
# Distances are float64 with "contract" only: fused multiply-adds, no
# reassociation, so a lane's result is the same in the vectorised body of a
# loop over particles as in its scalar remainder.
_FM_DIST = {"contract"}
_INVFACT = tuple(1.0 / math.factorial(j) for j in range(12))


@_jit(_FM_DIST)
def _lanes_upper_abt(A, B, out, m):
    """The upper triangle of ``A @ B.T`` for each of ``m`` lanes of (9, 9, ·) arrays, into ``out``.

    ``out[i, j] = Σ_k A[i, k]·B[j, k]`` for ``j ≥ i`` (rows of both, contiguous); the lower
    triangle is left as it was. ``A @ B`` when ``B`` is symmetric.
    """
    for i in range(9):
        a = A[i]
        for j in range(i, 9):
            b = B[j]
            o = out[i, j]
            for l in range(m):
                o[l] = (
                    a[0, l] * b[0, l] + a[1, l] * b[1, l] + a[2, l] * b[2, l] + a[3, l] * b[3, l]
                    + a[4, l] * b[4, l] + a[5, l] * b[5, l] + a[6, l] * b[6, l] + a[7, l] * b[7, l]
                    + a[8, l] * b[8, l]
                )


@_jit(_FM_DIST)
def _lanes_symmul(A, B, out, m):
    """``out = A @ B`` for each of ``m`` lanes of (9, 9, ·) arrays, ``A``, ``B`` symmetric and commuting.

    ``A @ B`` is then symmetric: the upper triangle (:func:`_lanes_upper_abt`) is mirrored.
    """
    _lanes_upper_abt(A, B, out, m)
    for i in range(9):
        for j in range(i):
            o = out[i, j]
            src = out[j, i]
            for l in range(m):
                o[l] = src[l]


@_jit(_FM_DIST)
def _lanes_mul(A, B, out, m):
    """``out = A @ B`` for each of ``m`` lanes, ``B`` symmetric (``out[i, j] = Σ_k A[i, k]·B[j, k]``)."""
    for i in range(9):
        a = A[i]
        for j in range(9):
            b = B[j]
            o = out[i, j]
            for l in range(m):
                o[l] = (
                    a[0, l] * b[0, l] + a[1, l] * b[1, l] + a[2, l] * b[2, l] + a[3, l] * b[3, l]
                    + a[4, l] * b[4, l] + a[5, l] * b[5, l] + a[6, l] * b[6, l] + a[7, l] * b[7, l]
                    + a[8, l] * b[8, l]
                )


@_jit(_FM_DIST)
def _lanes_expm_shifted(X, X2, X3, E, T, c, k, sc, m):
    """``E = expm(X − c·I)`` per lane, without the factor ``e^c``; ``X`` (9, 9, ·) symmetric, overwritten.

    :func:`covviz.model.spd.expm_taylor`'s algorithm with the scaling chosen per
    lane (the numpy function chooses it per batch): shift by ``c = tr X / 9``
    (returned in ``c``), scale by ``2^-k`` until the inf-norm is at most 1/4,
    degree-11 Taylor polynomial by Paterson–Stockmeyer (Horner in ``X³``),
    ``k`` squarings. A lane needing fewer squarings than another keeps its
    value through the extra ones (a select, not a product), so its result
    does not depend on its neighbours.
    """
    for l in range(m):
        s = 0.0
        for i in range(9):
            s += X[i, i, l]
        c[l] = s / 9.0
    for i in range(9):
        xi = X[i, i]
        for l in range(m):
            xi[l] -= c[l]
    kmax = 0
    for l in range(m):
        norm = 0.0
        for i in range(9):
            rs = 0.0
            for j in range(9):
                rs += abs(X[i, j, l])
            norm = max(norm, rs)
        kl = 0
        f = 1.0
        while norm > 0.25 and kl < 64:  # smallest k with norm / 2^k <= 1/4 (exact halvings)
            norm *= 0.5
            f *= 0.5
            kl += 1
        k[l] = kl
        sc[l] = f
        kmax = max(kmax, kl)
    for i in range(9):
        for j in range(9):
            x = X[i, j]
            for l in range(m):
                x[l] = x[l] * sc[l]
    _lanes_symmul(X, X, X2, m)
    _lanes_symmul(X2, X, X3, m)
    for i in range(9):
        for j in range(9):
            e = E[i, j]
            x = X[i, j]
            x2 = X2[i, j]
            c0 = _INVFACT[9] if i == j else 0.0
            for l in range(m):
                e[l] = (_INVFACT[10] * x[l] + _INVFACT[11] * x2[l]) + c0
    for blk in range(2, -1, -1):
        _lanes_symmul(X3, E, T, m)
        f1 = _INVFACT[3 * blk + 1]
        f2 = _INVFACT[3 * blk + 2]
        for i in range(9):
            for j in range(9):
                e = E[i, j]
                t = T[i, j]
                x = X[i, j]
                x2 = X2[i, j]
                c0 = _INVFACT[3 * blk] if i == j else 0.0
                for l in range(m):
                    e[l] = t[l] + ((f1 * x[l] + f2 * x2[l]) + c0)
    for it in range(kmax):
        _lanes_symmul(E, E, T, m)
        for i in range(9):
            for j in range(9):
                e = E[i, j]
                t = T[i, j]
                for l in range(m):
                    e[l] = t[l] if it < k[l] else e[l]


@_jit(_FM_DIST)
def _lanes_jacobi(A, m, tol, max_sweeps, t_, s_, tau_, act):
    """Eigenvalues of symmetric (9, 9, ·) matrices, ``m`` lanes, left on the diagonal of ``A``.

    Cyclic Jacobi on the upper triangle. A lane rotates ``(p, q)`` only where
    ``a_pq² > tol²·|a_pp·a_qq|`` (relative accuracy for positive-definite
    matrices) and is otherwise left exactly as it is (``t = s = τ = 0``), so a
    converged lane is unchanged by the sweeps its neighbours still need.
    Returns the sweeps run.
    """
    tol2 = tol * tol
    sweeps = 0
    for _ in range(max_sweeps):
        any_rot = False
        for p in range(8):
            for q in range(p + 1, 9):
                app = A[p, p]
                aqq = A[q, q]
                apq = A[p, q]
                nact = 0
                for l in range(m):
                    a = apq[l]
                    big = a * a > tol2 * abs(app[l] * aqq[l])
                    # t = tan of the rotation angle, the smaller root of
                    # t² + 2θt − 1 = 0 with θ = d / 2a (Rutishauser), written
                    # without θ: one square root and one division.
                    d = aqq[l] - app[l]
                    ad = abs(d)
                    t = 2.0 * (a if d >= 0.0 else -a) / (ad + math.sqrt(d * d + 4.0 * (a * a)))
                    t = t if big else 0.0
                    # s = sin = t / r, tau = s / (1 + cos) = t / (1 + r), r = sqrt(1 + t²):
                    # one division for both.
                    r = math.sqrt(t * t + 1.0)
                    w = t / (r * (1.0 + r))
                    t_[l] = t
                    s_[l] = w * (1.0 + r)
                    tau_[l] = w * r
                    act[l] = big
                    nact += big
                if nact == 0:
                    continue
                any_rot = True
                for l in range(m):
                    ta = t_[l] * apq[l]
                    app[l] -= ta
                    aqq[l] += ta
                    apq[l] = 0.0 if act[l] else apq[l]
                for rr in range(9):
                    if rr == p or rr == q:
                        continue
                    arp = A[min(rr, p), max(rr, p)]
                    arq = A[min(rr, q), max(rr, q)]
                    for l in range(m):
                        g = arp[l]
                        h = arq[l]
                        arp[l] = g - s_[l] * (h + g * tau_[l])
                        arq[l] = h + s_[l] * (g - h * tau_[l])
        sweeps += 1
        if not any_rot:
            break
    return sweeps


@_jit(_FM_DIST)
def _block_size(n, lanes):
    """Items per block when ``n`` are cut into equal blocks of at most ``lanes`` (150 -> 3 x 50, not
    64 + 64 + 22): the lane kernels' loops over blocks."""
    nb = max(1, -(-n // lanes))
    return max(1, -(-n // nb))


@_jit(_FM_DIST, entry=True)
def _template_distances(L, C, out, mats, vecs, k, act):
    """The kernel of :func:`template_distances_fast`; ``mats`` (6, 9, 9, lanes), ``vecs`` (5, lanes),
    ``k`` (lanes,) int64 and ``act`` (lanes,) bool are its workspace."""
    n = L.shape[0]
    lanes = mats.shape[3]
    X, X2, X3, E, T, Cb = mats[0], mats[1], mats[2], mats[3], mats[4], mats[5]
    c, sc, t_, s_, tau_ = vecs[0], vecs[1], vecs[2], vecs[3], vecs[4]
    size = _block_size(n, lanes)
    for i0 in range(0, n, size):
        m = min(size, n - i0)
        for l in range(m):
            for a in range(9):
                for b in range(9):
                    X[a, b, l] = -0.5 * L[i0 + l, a, b]
                    Cb[a, b, l] = C[i0 + l, a, b]
        # E' = expm(-L/2 - cI): the whitening expm(-L/2) = e^c E' up to the scalar,
        # which only shifts every log-eigenvalue by 2c (added below).
        _lanes_expm_shifted(X, X2, X3, E, T, c, k, sc, m)
        _lanes_mul(E, Cb, T, m)  # T = E' C
        # M = T E' = E' C E' (symmetric): upper triangle, into X (free now); Jacobi reads only that
        _lanes_upper_abt(T, E, X, m)
        _lanes_jacobi(X, m, 1e-14, 30, t_, s_, tau_, act)
        for l in range(m):
            acc = 0.0
            for a in range(9):
                lw = math.log(max(X[a, a, l], 1e-300)) + 2.0 * c[l]
                acc += lw * lw
            out[i0 + l] = math.sqrt(acc)


def template_distances_fast(L, C) -> np.ndarray:
    """``d(expm(L_i), C_i)`` for every particle: :func:`covviz.trackers.manifold.riemann_distance_to_templates`.

    Parameters
    ----------
    L : ndarray, shape (n, 9, 9)
        Log-space templates (symmetric).
    C : ndarray, shape (n, 9, 9)
        SPD observations.

    Returns
    -------
    ndarray, shape (n,), float64

    Notes
    -----
    The generalized eigenvalues of ``(C, expm(L))`` are those of ``E C E``
    with ``E = expm(-L/2)`` (Taylor, :func:`_lanes_expm_shifted`), found by
    cyclic Jacobi (:func:`_lanes_jacobi`); both run on blocks of
    :data:`LANES` particles with the particle index innermost, so that the
    compiler vectorises across particles (no 9x9 loop is long enough to
    vectorise well on its own). Agrees with the numpy function to ~1e-14.
    """
    L = np.ascontiguousarray(L, dtype=np.float64)
    C = np.ascontiguousarray(C, dtype=np.float64)
    if L.ndim != 3 or L.shape[1:] != (9, 9) or C.shape != L.shape:
        raise ValueError(f"L and C must both have shape (n, 9, 9); got {L.shape} and {C.shape}")
    if not (np.isfinite(L).all() and np.isfinite(C).all()):
        raise ValueError("L or C contains NaN or inf; check the inputs that produced it")
    out = np.empty(len(L))
    _template_distances(L, C, out, *_workspace("template", 9, 6, 5))
    return out


@_jit(_FM_DIST, entry=True)
def _pair_distances(W, C, I, J, out, mats, vecs, act):
    """The kernel of :func:`pair_distances_fast`; ``mats`` (6, 9, 9, lanes), ``vecs`` (5, lanes) and
    ``act`` (lanes,) bool are its workspace (:func:`_template_distances`'s, whose last two steps it shares)."""
    n = I.shape[0]
    lanes = mats.shape[3]
    X, T, E, Cb = mats[0], mats[4], mats[3], mats[5]
    t_, s_, tau_ = vecs[2], vecs[3], vecs[4]
    size = _block_size(n, lanes)
    for i0 in range(0, n, size):
        m = min(size, n - i0)
        for l in range(m):
            wi = I[i0 + l]
            cj = J[i0 + l]
            for a in range(9):
                for b in range(9):
                    E[a, b, l] = W[wi, a, b]
                    Cb[a, b, l] = C[cj, a, b]
        _lanes_mul(E, Cb, T, m)  # T = W_i C_j
        _lanes_upper_abt(T, E, X, m)  # W_i C_j W_i (symmetric): the upper triangle
        _lanes_jacobi(X, m, 1e-14, 30, t_, s_, tau_, act)
        for l in range(m):
            acc = 0.0
            for a in range(9):
                lw = math.log(max(X[a, a, l], 1e-300))
                acc += lw * lw
            out[i0 + l] = math.sqrt(acc)


def pair_distances_fast(W, C, I, J) -> np.ndarray:
    """``d(X_I[k], C_J[k])`` for pairs ``k``, given the whitening matrices ``W = X^{-1/2}``.

    Parameters
    ----------
    W : ndarray, shape (n, 9, 9)
        ``X_i^{-1/2}`` (symmetric), e.g. :func:`covviz.model.spd.invsqrtm` of the first set.
    C : ndarray, shape (m, 9, 9)
        SPD matrices of the second set.
    I, J : ndarray, shape (p,), int
        The pairs: rows of ``W`` and of ``C``.

    Returns
    -------
    ndarray, shape (p,), float64

    Notes
    -----
    The affine-invariant distance ``sqrt(Σ ln² λ)`` over the eigenvalues of
    ``W_i C_j W_i``, found by the cyclic Jacobi of :func:`template_distances_fast`
    on blocks of :data:`LANES` pairs. Agrees with
    :func:`covviz.model.spd.pairwise_distance` (LAPACK's ``eigvalsh``) to
    ~1e-13. :func:`covviz.embedding.distance_matrix` uses it for the recorder's
    and ``covviz mds``'s distance matrices.
    """
    W = np.ascontiguousarray(W, dtype=np.float64)
    C = np.ascontiguousarray(C, dtype=np.float64)
    I = np.ascontiguousarray(I, dtype=np.int64)
    J = np.ascontiguousarray(J, dtype=np.int64)
    if W.ndim != 3 or W.shape[1:] != (9, 9) or C.ndim != 3 or C.shape[1:] != (9, 9):
        raise ValueError(f"W and C must have shape (n, 9, 9); got {W.shape} and {C.shape}")
    if I.shape != J.shape or I.ndim != 1:
        raise ValueError(f"I and J must be 1-D of one length; got {I.shape} and {J.shape}")
    if len(I) and (I.min() < 0 or I.max() >= len(W) or J.min() < 0 or J.max() >= len(C)):
        raise ValueError("I or J indexes past W or C")
    if not (np.isfinite(W).all() and np.isfinite(C).all()):
        raise ValueError("W or C contains NaN or inf; check the inputs that produced it")
    out = np.empty(len(I))
    mats, vecs, _, act = _workspace("template", 9, 6, 5)
    _pair_distances(W, C, I, J, out, mats, vecs, act)
    return out


_BIG = 2.0**500  # rescaling step of the pivot products (a power of two: exact)


@_jit(_FM_DIST)
def _lanes_cholesky_logdet(A, W, s, out, m):
    """``out[l] = log det A_l`` by Cholesky for ``m`` lanes of (d, d, ·) SPD matrices (lower triangle read).

    ``W`` (d, d, ·) and ``s`` (·,) scratch. The product of the pivots is kept
    within ``2^±500`` by exact power-of-two rescaling, so one logarithm per
    matrix suffices whatever the scale. NaN where a matrix is not
    positive-definite.
    """
    d = A.shape[0]
    prod = out  # the product of the pivots, then the log
    cnt = W[0, d - 1]  # the upper triangle of W is free: the rescaling counts
    for l in range(m):
        prod[l] = 1.0
        cnt[l] = 0.0
    for j in range(d):
        wj = W[j]
        djj = wj[j]
        ajj = A[j, j]
        for l in range(m):
            s[l] = ajj[l]
        for k in range(j):
            wjk = wj[k]
            for l in range(m):
                s[l] -= wjk[l] * wjk[l]
        for l in range(m):
            piv = math.sqrt(s[l]) if s[l] > 0.0 else math.nan
            djj[l] = piv
            p = prod[l] * piv
            c = cnt[l]
            c = c - 1.0 if p < 1.0 / _BIG else (c + 1.0 if p > _BIG else c)
            p = p * _BIG if p < 1.0 / _BIG else (p / _BIG if p > _BIG else p)
            prod[l] = p
            cnt[l] = c
        for i in range(j + 1, d):
            wi = W[i]
            aij = A[i, j]
            for l in range(m):
                s[l] = aij[l]
            for k in range(j):
                wik = wi[k]
                wjk = wj[k]
                for l in range(m):
                    s[l] -= wik[l] * wjk[l]
            wij = wi[j]
            for l in range(m):
                wij[l] = s[l] / djj[l]
    for l in range(m):
        out[l] = 2.0 * (math.log(prod[l]) + cnt[l] * (500.0 * math.log(2.0)))


@_jit(_FM_DIST, entry=True)
def _quadrant_distances(Q, ref, ref_logdet, out, mats, vecs):
    """The kernel of :func:`quadrant_distances_fast`; ``mats`` (2, d, d, lanes), ``vecs`` (3, lanes): workspace."""
    n, nq, d, _ = Q.shape
    lanes = mats.shape[3]
    A, W = mats[0], mats[1]
    ldq, ldm, sc = vecs[0], vecs[1], vecs[2]
    size = _block_size(n, lanes)
    for i0 in range(0, n, size):
        m = min(size, n - i0)
        for k in range(nq):
            for a in range(d):
                for b in range(a + 1):
                    for l in range(m):
                        A[a, b, l] = Q[i0 + l, k, a, b]
            _lanes_cholesky_logdet(A, W, sc, ldq, m)
            for a in range(d):
                for b in range(a + 1):
                    r = ref[k, a, b]
                    for l in range(m):
                        A[a, b, l] = 0.5 * (r + Q[i0 + l, k, a, b])
            _lanes_cholesky_logdet(A, W, sc, ldm, m)
            for l in range(m):
                J = ldm[l] - 0.5 * (ref_logdet[k] + ldq[l])
                out[i0 + l, k] = math.sqrt(8.0 * max(J, 0.0))


def quadrant_distances_fast(Q, ref, ref_logdet) -> np.ndarray:
    """``sqrt(8·JBLD)`` of each particle's quadrants: :func:`covviz.trackers.manifold.quadrant_distances`.

    Parameters
    ----------
    Q : ndarray, shape (n, 4, d, d)
    ref : ndarray, shape (4, d, d)
    ref_logdet : ndarray, shape (4,)

    Returns
    -------
    ndarray, shape (n, 4), float64
        NaN where a descriptor is not positive-definite (the numpy function raises).

    Notes
    -----
    Cholesky log-determinants (:func:`_lanes_cholesky_logdet`) on blocks of
    :data:`LANES` particles, particle index innermost. Agrees with the numpy
    function to ~1e-13 in ``J``; near ``J = 0`` the square root magnifies that
    to ~1e-6 in the distance (as it does the numpy function's own rounding).
    """
    Q = np.ascontiguousarray(Q, dtype=np.float64)
    ref = np.ascontiguousarray(ref, dtype=np.float64)
    ref_logdet = np.ascontiguousarray(ref_logdet, dtype=np.float64)
    if Q.ndim != 4 or ref.shape != Q.shape[1:] or ref_logdet.shape != Q.shape[1:2]:
        raise ValueError(f"shapes do not match: Q {Q.shape}, ref {ref.shape}, ref_logdet {ref_logdet.shape}")
    out = np.empty(Q.shape[:2])
    mats, vecs, _, _ = _workspace("quadrant", Q.shape[2], 2, 3)
    _quadrant_distances(Q, ref, ref_logdet, out, mats, vecs)
    return out


# --------------------------------------------------------------------------- #
# the colour term's window (covviz.model.fgbg)
# --------------------------------------------------------------------------- #
@_jit(_FM_FEAT)
def _colour_bin(frame, y, x, grey, cshift, gshift):
    """The histogram bin of pixel ``(y, x)`` of an ``(H, W, 3)`` uint8 frame (:func:`covviz.model.fgbg.colour_bins`)."""
    if grey:
        return np.int64(frame[y, x, 0] >> gshift)
    k = 8 - cshift
    return ((np.int64(frame[y, x, 0] >> cshift) << (2 * k)) | (np.int64(frame[y, x, 1] >> cshift) << k)
            | np.int64(frame[y, x, 2] >> cshift))


@_jit(_FM_FEAT, entry=True)
def _colour_window(frame, X0, Y0, grey, cshift, gshift, lut, P, integral):
    """``P[y, x] = lut[bin(frame[Y0 + y, X0 + x])]`` over ``P``'s shape, and its integral image.

    ``integral`` (h + 1, w + 1) float64 is summed as ``cv2.integral`` sums a
    float64 image: a running sum along each row added to the row above, so the
    values are the same bits (no fastmath: every addition as written). An
    empty ``integral`` (0, 0): the probabilities only.
    """
    h, w = P.shape
    if integral.shape[0] == 0:
        for y in range(h):
            pr = P[y]
            for x in range(w):
                pr[x] = lut[_colour_bin(frame, Y0 + y, X0 + x, grey, cshift, gshift)]
        return
    for x in range(w + 1):
        integral[0, x] = 0.0
    for y in range(h):
        up = integral[y]
        row = integral[y + 1]
        pr = P[y]
        row[0] = 0.0
        s = 0.0
        for x in range(w):
            v = lut[_colour_bin(frame, Y0 + y, X0 + x, grey, cshift, gshift)]
            pr[x] = v
            s += v
            row[x + 1] = up[x + 1] + s


@_jit(_FM_FEAT, entry=True)
def _colour_counts(frame, X0, Y0, X1, Y1, x0, y0, x1, y1, grey, cshift, gshift, inner, total):
    """Pixel counts per colour bin of ``[y0:y1, x0:x1]`` (``inner``) and of ``[Y0:Y1, X0:X1]`` (``total``), int64."""
    inner[:] = 0
    total[:] = 0
    for y in range(Y0, Y1):
        for x in range(X0, X1):
            b = _colour_bin(frame, y, x, grey, cshift, gshift)
            total[b] += 1
            if y >= y0 and y < y1 and x >= x0 and x < x1:
                inner[b] += 1


def colour_window_fast(frame, X0: int, Y0: int, X1: int, Y1: int, grey: bool, cshift: int, gshift: int,
                       lut, with_integral: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """``(P, integral)`` of :func:`covviz.model.fgbg.colour_map` over ``frame[Y0:Y1, X0:X1]`` in one pass.

    ``frame`` (H, W, 3) uint8; ``lut`` (bins,) float64. ``P`` (h, w) and ``integral`` (h + 1, w + 1), float64,
    the same bits as ``lut[colour_bins(...)]`` and ``cv2.integral`` of it; ``with_integral`` False: ``P`` and
    None (no integral image made).
    """
    P = np.empty((Y1 - Y0, X1 - X0))
    integral = np.empty((Y1 - Y0 + 1, X1 - X0 + 1) if with_integral else (0, 0))
    _colour_window(frame, int(X0), int(Y0), bool(grey), int(cshift), int(gshift), lut, P, integral)
    return P, integral if with_integral else None


def colour_counts_fast(frame, outer: tuple, inner: tuple, grey: bool, cshift: int, gshift: int,
                       n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Counts per bin of the ``inner`` rectangle and of the ``outer`` one (``x0, y0, x1, y1`` each), int64."""
    a = np.empty(n_bins, dtype=np.int64)
    t = np.empty(n_bins, dtype=np.int64)
    _colour_counts(frame, *(int(v) for v in outer), *(int(v) for v in inner), bool(grey), int(cshift), int(gshift),
                   a, t)
    return a, t


# --------------------------------------------------------------------------- #
# cold start
# --------------------------------------------------------------------------- #
def _warmup_calls():
    """One small call of every public kernel with the argument types the tracker uses."""
    rng = np.random.default_rng(0)
    gray = rng.random((40, 40), dtype=np.float32)
    poses = np.array([[20.0, 20.0, 1.0, 0.1], [5.0, 30.0, 0.8, -0.2]])
    for quadrants in (True, False):
        C, Q = warp_descriptors_fast(gray, poses, (16.0, 16.0), 8, 1.0, 1e-3, True, quadrants)
    P = rng.random((2, 10, 10), dtype=np.float32)
    descriptors_fast(P, 1e-3, True, True)
    C, Q = warp_descriptors_fast(gray, poses, (16.0, 16.0), 8, 1.0, 1e-3, True, True)
    template_distances_fast(np.zeros((2, 9, 9)), C)
    quadrant_distances_fast(Q, Q[0], np.zeros(4))
    pair_distances_fast(np.broadcast_to(np.eye(9), (2, 9, 9)), C, np.array([0, 1]), np.array([1, 0]))
    # The frozen model's quadrant references and a restored snapshot's templates are read-only
    # arrays, which numba compiles as another signature: warm those too, or the first frames compile.
    ro = lambda a: np.frombuffer(np.ascontiguousarray(a).tobytes(), dtype=a.dtype).reshape(a.shape)
    template_distances_fast(ro(np.zeros((2, 9, 9))), C)
    quadrant_distances_fast(Q, ro(Q[0]), ro(np.zeros(4)))
    f = rng.integers(0, 256, (6, 7, 3), dtype=np.uint8)
    for frame in (f, ro(f)):  # a caller's frames may be read-only
        for grey in (True, False):
            for with_integral in (True, False):
                colour_window_fast(frame, 1, 1, 6, 5, grey, 4, 3, np.zeros(4096), with_integral)
            colour_counts_fast(frame, (0, 0, 7, 6), (1, 1, 4, 4), grey, 4, 3, 4096)


def kernels_cached() -> bool:
    """Whether every kernel can be loaded from numba's on-disk cache (no compilation).

    False when numba is missing, the cache is absent or stale (the source
    changed), or numba's cache layout is not the one this function knows: then
    a first call compiles (tens of seconds; see :func:`warmup`).
    """
    if numba is None:
        return False
    try:
        for disp in _ENTRY_POINTS:
            if disp.overloads:
                continue
            cache = disp._cache
            index = cache._cache_file._load_index()
            magic = disp.targetctx.codegen().magic_tuple()
            if not any(key[1] == magic for key in index):
                return False
    except Exception:  # noqa: BLE001 - numba internals: any surprise means "don't know", so "no"
        return False
    return True


def warmup(callback: Callable[[], None] | None = None) -> float:
    """Compile (or load from the cache) every kernel; return the seconds it took.

    Parameters
    ----------
    callback : callable, optional
        Called once, before anything else, when the kernels are not all cached
        (e.g. to print "compiling kernels (once)…").

    Does nothing (and returns 0) when :data:`JIT_ENABLED` is False.
    """
    if not JIT_ENABLED:
        return 0.0
    t0 = time.perf_counter()
    if callback is not None and not kernels_cached():
        callback()
    _warmup_calls()
    return time.perf_counter() - t0
