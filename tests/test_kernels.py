"""Tests for :mod:`covviz.model.kernels`: the compiled fast path against references.

References, in order of strictness:

* the warp: bit for bit :func:`covviz.model.features.warp_patches` (cv2.remap);
* the distance kernels, fed the same descriptors: the numpy functions, 1e-10;
* the descriptors: a float64 oracle written here from the definition (the
  features of :func:`covviz.model.features.patch_features` in float64, gain
  normalisation in float64, two-pass float64 covariances), to 1e-5 relative
  (per matrix, Frobenius) and the distances they give to 1e-5 absolute. The
  numpy path is compared too, at its own accuracy: its float32 raw moments
  move distances by up to ~8e-3 from float64 on real frames, and its float32
  features (the patch scaled before differencing) by up to ~5e-5; the
  kernels stay within ~1e-6.

Real patches come from frames of ``../shared/sequences`` at poses perturbed
around the ground truth, plus the darkest and flattest of many random poses
and poses over the border; those tests skip when the folder is absent.
"""

from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from helpers import real_sequence

from covviz.data.sequences import open_sequence
from covviz.model import kernels, spd
from covviz.model.descriptor import covariance, quadrant_covariances
from covviz.model.features import FEATURE_SCALE, patch_features, warp_patches
from covviz.model.image import to_gray
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker

pytestmark = pytest.mark.skipif(kernels.numba is None, reason="numba is not installed")

EPS = 1e-3
# Tolerances of the fast path against the float64 numpy path (see the module docstring).
DESC_RTOL = 1e-5  # per matrix, ||ΔC||_F / ||C||_F
DIST_ATOL = 1e-5  # distances, absolute


# --------------------------------------------------------------------------- #
# helpers
# --------------------------------------------------------------------------- #
def oracle(P: np.ndarray, quadrants: bool = True, gain_normalize: bool = True):
    """Float64 descriptors of bordered patches from the definition: ``(C, Q)`` (``Q`` None without quadrants).

    The features of :func:`covviz.model.features.patch_features` (coordinates in
    ``[-½, ½]``, intensity, ``|Ix|, |Iy|``, magnitude, ``atan(|Ix|/|Iy|)``,
    ``|Ixx|, |Iyy|``, central differences, scaled by ``FEATURE_SCALE``),
    computed in float64 from the float32 patch, and two-pass covariances
    regularised as :func:`covviz.model.spd.regularize`.
    """
    P = np.asarray(P, dtype=np.float64)
    if gain_normalize:
        P = P / np.maximum(P[:, 1:-1, 1:-1].mean(axis=(1, 2), keepdims=True), 1e-3)
    c = P[:, 1:-1, 1:-1]
    ix = (P[:, 1:-1, 2:] - P[:, 1:-1, :-2]) / 2
    iy = (P[:, 2:, 1:-1] - P[:, :-2, 1:-1]) / 2
    ixx = P[:, 1:-1, 2:] - 2 * c + P[:, 1:-1, :-2]
    iyy = P[:, 2:, 1:-1] - 2 * c + P[:, :-2, 1:-1]
    n, S = len(P), c.shape[1]
    u = (np.arange(S) + 0.5) / S - 0.5
    xx, yy = np.meshgrid(u, u)
    feats = [np.broadcast_to(xx, c.shape), np.broadcast_to(yy, c.shape), c, np.abs(ix), np.abs(iy),
             np.hypot(ix, iy), np.arctan2(np.abs(ix), np.abs(iy)), np.abs(ixx), np.abs(iyy)]
    F = np.stack(feats, 1) * np.asarray(FEATURE_SCALE, dtype=np.float64)[None, :, None, None]

    def cov(X):
        X = X - X.mean(axis=-1, keepdims=True)
        return spd.regularize(X @ np.swapaxes(X, -1, -2) / (X.shape[-1] - 1), EPS)

    C = cov(F.reshape(n, 9, -1))
    if not quadrants:
        return C, None
    h = S // 2
    return C, np.stack([cov(F[:, :, r : r + h, k : k + h].reshape(n, 9, -1))
                        for r, k in ((0, 0), (0, h), (h, 0), (h, h))], axis=1)


def numpy_path(P: np.ndarray, quadrants: bool = True, gain_normalize: bool = True):
    """What the tracker's numpy path computes: ``(C, Q)``."""
    if quadrants:
        return quadrant_covariances(patch_features(P, gain_normalize=gain_normalize, quadrants=True), EPS)
    return covariance(patch_features(P, gain_normalize=gain_normalize), EPS), None


def frob_rel(A: np.ndarray, B: np.ndarray) -> float:
    """Largest ``||A − B||_F / ||B||_F`` over the matrices of a batch."""
    return float((np.linalg.norm(A - B, axis=(-1, -2)) / np.linalg.norm(B, axis=(-1, -2))).max())


def walk(L: np.ndarray, n: int, sigma: float, rng) -> np.ndarray:
    """``n`` symmetric log-space templates scattered around ``L``."""
    W = rng.normal(0.0, sigma, (n, *L.shape))
    return L + 0.5 * (W + np.swapaxes(W, 1, 2))


def real_poses(name: str, frame: int, n: int, rng):
    """A grey frame of a real sequence and poses around its ground truth, plus dark, flat and border ones.

    Returns ``gray, poses (n + 40, 4), base_wh``.
    """
    seq = open_sequence(real_sequence(name))
    f = seq.frame(frame)
    gray = to_gray(f.image)
    x, y, w, h = f.gt
    H, W = gray.shape
    base = np.array([x + w / 2, y + h / 2, 1.0, 0.0])
    jitter = rng.normal(0.0, [0.15 * w, 0.15 * h, 0.12, 0.15], (n, 4))
    jitter[:, 2] = np.exp(jitter[:, 2]) - 1.0
    near = base + jitter
    # Many random poses over the frame; keep the darkest and the flattest.
    cand = np.column_stack([rng.uniform(0, W, 400), rng.uniform(0, H, 400), rng.uniform(0.4, 1.5, 400),
                            rng.uniform(-0.5, 0.5, 400)])
    P = warp_patches(gray, cand, (w, h), 32, 1, 1.0)
    inner = P[:, 1:-1, 1:-1]
    dark = cand[np.argsort(inner.mean(axis=(1, 2)))[:15]]
    flat = cand[np.argsort(np.abs(np.diff(inner, axis=2)).mean(axis=(1, 2)))[:15]]
    border = np.column_stack([rng.choice([-0.3 * w, W + 0.3 * w], 10), rng.uniform(-h, H + h, 10),
                              rng.uniform(0.5, 2.0, 10), rng.uniform(-1, 1, 10)])
    return gray, np.concatenate([near, dark, flat, border]), (float(w), float(h))


def synthetic_patches(rng) -> np.ndarray:
    """Bordered 34x34 float32 patches: noise, ramps, a checkerboard, edges, dark, flat and black ones."""
    g = 34
    yy, xx = np.mgrid[0:g, 0:g].astype(np.float64)
    out = [
        rng.random((g, g)),  # noise
        0.2 + 0.01 * xx + 0.005 * yy,  # ramp
        0.5 + 0.3 * ((xx + yy) % 2),  # one-pixel checkerboard
        np.where(xx > 17, 0.8, 0.1) + 0.01 * rng.random((g, g)),  # a vertical edge
        np.sin(xx / 3.0) * np.cos(yy / 5.0) * 0.4 + 0.5,
        0.004 + 0.002 * rng.random((g, g)),  # dark
        0.6 + 1e-3 * np.sin(xx / 7.0 + yy / 11.0),  # nearly flat
        np.full((g, g), 0.37),  # flat
        np.zeros((g, g)),  # black
        np.round(rng.random((g, g)) * 255) / 255,  # 8-bit levels
    ]
    return np.ascontiguousarray(np.stack(out), dtype=np.float32)


# --------------------------------------------------------------------------- #
# switches, cold start, validation
# --------------------------------------------------------------------------- #
def test_no_jit_environment_selects_the_numpy_path():
    """``COVVIZ_NO_JIT=1``: JIT_ENABLED is False and the tracker's descriptors are the numpy path's, bit for bit."""
    code = (
        "import numpy as np\n"
        "from covviz.model import kernels\n"
        "from covviz.data.sequences import SyntheticSequence\n"
        "from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker\n"
        "from covviz.model.features import warp_patches, patch_features, normalize_gradients\n"
        "from covviz.model.descriptor import quadrant_covariances\n"
        "from covviz.model.image import to_gray\n"
        "import sys\n"
        "assert kernels.JIT_ENABLED is False and 'numba' not in sys.modules\n"
        "seq = SyntheticSequence()\n"
        "tr = ManifoldTracker(ManifoldConfig(n_particles=8), rng=0)\n"
        "tr.init(seq.frame(0).image, seq.init_box)\n"
        "poses = tr.last_record.pose[None] + np.array([[1.5, -2.0, 0.05, 0.1]])\n"
        "m = tr.model\n"
        "assert m.jit and not m.compiled\n"
        "C = m.descriptors(m.prepare(seq.frame(1).image), poses)\n"
        "P = warp_patches(to_gray(seq.frame(1).image), poses, m.base_wh, 32, 1, 1.0)\n"
        "F = normalize_gradients(patch_features(P, gain_normalize=True, quadrants=True))\n"
        "ref = quadrant_covariances(F, 1e-3)[0]\n"
        "assert np.array_equal(C, ref)\n"
        "print('numpy path')\n"
    )
    env = dict(os.environ, COVVIZ_NO_JIT="1")
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", code], check=False, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert "numpy path" in out.stdout


def test_kernels_load_without_importing_scipy_linalg_and_it_still_imports_after():
    # numba's BLAS probe (numba.np.arraymath) would import all of scipy.linalg at the first cached kernel's
    # load; covviz.model.kernels refuses it for that import only. The kernels still load and agree with the
    # numpy reference, jitted linear algebra still works (it imports scipy when compiled), and scipy.linalg
    # imports normally afterwards.
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from covviz.model import kernels\n"
        "from covviz.model.spd import distance_riemann_log\n"
        "assert kernels.JIT_ENABLED\n"
        "rng = np.random.default_rng(0)\n"
        "A = rng.normal(size=(3, 9, 9)); L = 0.1 * (A + A.transpose(0, 2, 1))\n"
        "B = rng.normal(size=(3, 9, 20)); C = B @ B.transpose(0, 2, 1) / 20 + np.eye(9)\n"
        "d = kernels.template_distances_fast(L, C)\n"
        "assert 'scipy.linalg' not in sys.modules, 'scipy.linalg imported with the kernels'\n"
        "assert np.allclose(d, [distance_riemann_log(L[i:i+1], C[i])[0] for i in range(3)], rtol=1e-10)\n"
        "import numba\n"
        "assert np.allclose(numba.njit(lambda m: np.linalg.inv(m))(C[0]) @ C[0], np.eye(9), atol=1e-8)\n"
        "import scipy.linalg\n"
        "assert not any(type(f).__name__ == '_NoScipyLinalg' for f in sys.meta_path)\n"
        "print('ok', scipy.linalg.eigh(C[0])[0].min() > 0)\n"
    )
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", code], check=False, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["ok", "True"]


def test_warmup_compiles_everything_and_reports_the_cache(monkeypatch):
    assert kernels.warmup() >= 0.0
    assert kernels.kernels_cached()  # every entry point is now in numba's on-disk cache
    calls = []
    monkeypatch.setattr(kernels, "kernels_cached", lambda: False)
    kernels.warmup(lambda: calls.append(1))
    assert calls == [1]


def test_warmup_callback_is_not_called_when_cached(monkeypatch):
    monkeypatch.setattr(kernels, "kernels_cached", lambda: True)
    calls = []
    kernels.warmup(lambda: calls.append(1))
    assert calls == []


@pytest.mark.parametrize(
    "call",
    [
        lambda: kernels.descriptors_fast(np.zeros((2, 34, 30), np.float32), EPS),
        lambda: kernels.descriptors_fast(np.zeros((2, 35, 35), np.float32), EPS, quadrants=True),
        lambda: kernels.warp_descriptors_fast(np.zeros((10, 10), np.float32), np.zeros((2, 3)), (5, 5)),
        lambda: kernels.warp_descriptors_fast(np.zeros(10, np.float32), np.zeros((2, 4)), (5, 5)),
        lambda: kernels.template_distances_fast(np.zeros((2, 9, 9)), np.zeros((3, 9, 9))),
        lambda: kernels.template_distances_fast(np.full((1, 9, 9), np.nan), np.eye(9)[None]),
        lambda: kernels.quadrant_distances_fast(np.zeros((2, 4, 9, 9)), np.zeros((3, 9, 9)), np.zeros(4)),
    ],
)
def test_bad_inputs_raise_value_error(call):
    with pytest.raises(ValueError):
        call()


# --------------------------------------------------------------------------- #
# the warp: bit for bit cv2.remap
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("step", [1.0, (1.7, 1.9)])
def test_fused_warp_equals_warp_patches_bit_for_bit(rng, step):
    gray = rng.random((120, 160), dtype=np.float32)
    n = 60
    poses = np.column_stack([rng.uniform(-80, 240, n), rng.uniform(-60, 180, n), rng.uniform(0.05, 3.0, n),
                             rng.uniform(-3.2, 3.2, n)])
    poses = np.concatenate([poses, [[1e5, -1e5, 1.0, 0.3], [80.0, 60.0, 1e-4, 0.0]]])
    P = warp_patches(gray, poses, (37.0, 23.0), 32, 1, step)
    fused = kernels.warp_descriptors_fast(gray, poses, (37.0, 23.0), 32, step, EPS, True, True)
    from_patches = kernels.descriptors_fast(P, EPS, True, True)
    np.testing.assert_array_equal(fused[0], from_patches[0])
    np.testing.assert_array_equal(fused[1], from_patches[1])


# --------------------------------------------------------------------------- #
# descriptors against the numpy path
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("gain_normalize", [True, False])
def test_descriptors_on_synthetic_patches(rng, gain_normalize):
    P = synthetic_patches(rng)
    C, Q = kernels.descriptors_fast(P, EPS, gain_normalize, True)
    Cr, Qr = oracle(P, True, gain_normalize)
    assert frob_rel(C, Cr) < DESC_RTOL
    assert frob_rel(Q, Qr) < DESC_RTOL
    C1, none = kernels.descriptors_fast(P, EPS, gain_normalize, False)
    assert none is None
    assert frob_rel(C1, oracle(P, False, gain_normalize)[0]) < DESC_RTOL
    Cn, Qn = numpy_path(P, True, gain_normalize)  # at its own accuracy
    assert frob_rel(C, Cn) < 1e-3 and frob_rel(Q, Qn) < 1e-3
    # Symmetric, positive-definite, exactly as regularised.
    np.testing.assert_array_equal(C, np.swapaxes(C, 1, 2))
    np.testing.assert_array_equal(Q, np.swapaxes(Q, 2, 3))
    assert np.linalg.eigvalsh(Q).min() > 0


def test_flat_and_black_patches_keep_only_the_coordinates(rng):
    P = synthetic_patches(rng)[[7, 8]]  # flat, black
    C, Q = kernels.descriptors_fast(P, EPS, True, True)
    Cr, Qr = oracle(P)
    np.testing.assert_allclose(C, Cr, rtol=1e-7, atol=1e-15)
    np.testing.assert_allclose(Q, Qr, rtol=1e-7, atol=1e-15)
    assert np.all(C[:, 2:, 2:] == np.diag(np.diag(C[0, 2:, 2:])))  # nothing but the regulariser


def test_odd_patch_side_without_quadrants(rng):
    P = rng.random((5, 33, 33), dtype=np.float32)
    C, Q = kernels.descriptors_fast(P, EPS, True, False)
    assert Q is None
    assert frob_rel(C, oracle(P, False)[0]) < DESC_RTOL


@pytest.mark.parametrize(("name", "frame"), [("Car4", 180), ("Crossing", 100), ("Jogging-1", 50)])
def test_descriptors_and_distances_on_real_patches(rng, name, frame):
    gray, poses, wh = real_poses(name, frame, 120, rng)
    P = warp_patches(gray, poses, wh, 32, 1, 1.0)
    C, Q = kernels.warp_descriptors_fast(gray, poses, wh, 32, 1.0, EPS, True, True)
    Co, Qo = oracle(P)
    assert frob_rel(C, Co) < DESC_RTOL
    assert frob_rel(Q, Qo) < DESC_RTOL
    # Distances the tracker would weigh these particles by: templates around the
    # first pose's descriptor, quadrants against its quadrants.
    L = walk(spd.logm(Co[0]), len(C), 0.05, rng)
    ref, ref_ld = Qo[0], spd.logdet(Qo[0])
    d = kernels.template_distances_fast(L, C)
    q = kernels.quadrant_distances_fast(Q, ref, ref_ld)
    np.testing.assert_allclose(d, spd.distance_riemann_log(L, Co), rtol=0, atol=DIST_ATOL)
    np.testing.assert_allclose(q, spd.distance_jbld(ref, Qo, logdet_a=ref_ld), rtol=0, atol=DIST_ATOL)
    # The tracker's numpy path, at its own accuracy (see the module docstring).
    Cn, Qn = numpy_path(P)
    assert frob_rel(C, Cn) < 1e-3 and frob_rel(Q, Qn) < 1e-3
    np.testing.assert_allclose(d, spd.distance_riemann_log(L, Cn), rtol=0, atol=2e-2)
    np.testing.assert_allclose(q, spd.distance_jbld(ref, Qn, logdet_a=ref_ld), rtol=0, atol=2e-2)
    # Without quadrants (manifold-paper).
    C1, _ = kernels.warp_descriptors_fast(gray, poses, wh, 32, 1.0, EPS, True, False)
    assert frob_rel(C1, oracle(P, False)[0]) < DESC_RTOL


# --------------------------------------------------------------------------- #
# distances against the numpy functions (same descriptors)
# --------------------------------------------------------------------------- #
def random_spd(rng, n, spread):
    """SPD matrices with log-eigenvalues spread over ``[-spread, spread/4]``."""
    A = rng.normal(size=(n, 9, 9))
    Qm = np.linalg.qr(A)[0]
    w = np.exp(rng.uniform(-spread, spread / 4, (n, 9)))
    return spd.sym((Qm * w[:, None, :]) @ np.swapaxes(Qm, 1, 2))


@pytest.mark.parametrize("n", [0, 1, 2, 63, 64, 65, 150])
def test_template_distances_match_numpy(rng, n):
    # Spreads like the tracker's: descriptors' log-eigenvalues over ~[-8, 0]
    # (the regulariser bounds their condition), templates' alike.
    C = random_spd(rng, n, 8.0)
    L = spd.logm(random_spd(rng, n, 8.0)) if n else np.zeros((0, 9, 9))
    d = kernels.template_distances_fast(L, C)
    assert d.shape == (n,)
    if n:
        np.testing.assert_allclose(d, spd.distance_riemann_log(L, C), rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(d, spd.distance_riemann(C, spd.expm(L)), rtol=1e-10, atol=1e-10)


def test_template_distance_to_itself_is_zero(rng):
    C = random_spd(rng, 5, 8.0)
    np.testing.assert_allclose(kernels.template_distances_fast(spd.logm(C), C), 0.0, atol=1e-9)


def test_template_distances_on_large_and_zero_logs(rng):
    """Far templates: against 50-digit arithmetic (mpmath), where LAPACK's absolute accuracy shows."""
    mpmath = pytest.importorskip("mpmath")
    C = random_spd(rng, 3, 4.0)
    L = np.stack([np.zeros((9, 9)), 3.0 * spd.sym(rng.normal(size=(9, 9))), np.diag(np.linspace(-12, 2, 9))])
    exact = []
    with mpmath.workdps(50):
        for Li, Ci in zip(L, C, strict=True):
            E = mpmath.expm(-mpmath.matrix(Li.tolist()) / 2)
            M = E * mpmath.matrix(Ci.tolist()) * E
            w = mpmath.eigsy((M + M.T) / 2)[0]
            exact.append(float(mpmath.sqrt(sum(mpmath.log(x) ** 2 for x in w))))
    d = kernels.template_distances_fast(L, C)
    # The second template is very far (d = 25; the tracker's are 1-5): the
    # kernel is 4e-8 off there, numpy's function 4e-8 too (realistic ones: 1e-10).
    np.testing.assert_allclose(d, exact, rtol=1e-7)
    np.testing.assert_allclose(d, spd.distance_riemann_log(L, C), rtol=1e-6)


@pytest.mark.parametrize("n", [0, 1, 3])
def test_quadrant_distances_match_numpy(rng, n):
    Q = random_spd(rng, 4 * n, 8.0).reshape(n, 4, 9, 9)
    ref = random_spd(rng, 4, 8.0)
    q = kernels.quadrant_distances_fast(Q, ref, spd.logdet(ref))
    assert q.shape == (n, 4)
    if n:
        np.testing.assert_allclose(q, spd.distance_jbld(ref, Q, logdet_a=spd.logdet(ref)), rtol=1e-10, atol=1e-10)
    # sqrt(8·J) magnifies rounding near J = 0: the two log-dets of ref (LAPACK's,
    # passed in, and the kernel's) differ by ~1e-13, which gives ~1e-6.
    np.testing.assert_allclose(kernels.quadrant_distances_fast(ref[None], ref, spd.logdet(ref)), 0.0, atol=1e-5)


def test_quadrant_distances_nan_for_a_non_spd_descriptor(rng):
    Q = random_spd(rng, 4, 3.0).reshape(1, 4, 9, 9)
    Q[0, 2] = -np.eye(9)
    q = kernels.quadrant_distances_fast(Q, Q[0], np.zeros(4))
    assert np.isnan(q[0, 2]) and np.isfinite(q[0, [0, 1, 3]]).all()


# --------------------------------------------------------------------------- #
# determinism: no particle's result depends on its batch, thread or run
# --------------------------------------------------------------------------- #
def chunked(fn, n, sizes):
    """Concatenate ``fn(slice)`` over consecutive chunks of the given sizes (cycled)."""
    parts, i, k = [], 0, 0
    while i < n:
        j = min(n, i + sizes[k % len(sizes)])
        parts.append(fn(slice(i, j)))
        i, k = j, k + 1
    return parts


def frame_and_poses(rng, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A random 120x100 grey frame and ``n`` poses over it (some partly outside)."""
    gray = rng.random((100, 120), dtype=np.float32)
    poses = np.column_stack([rng.uniform(0, 120, n), rng.uniform(0, 100, n), rng.uniform(0.5, 1.5, n),
                             rng.uniform(-0.3, 0.3, n)])
    return gray, poses


@pytest.mark.parametrize("sizes", [[1], [7, 64, 3], [150], [65, 200]])
def test_results_do_not_depend_on_chunking(rng, sizes):
    n = 203
    gray, poses = frame_and_poses(rng, n)
    C, Q = kernels.warp_descriptors_fast(gray, poses, (30.0, 24.0), 32, 1.0, EPS, True, True)
    L = walk(spd.logm(C[0]), n, 0.05, rng)
    d = kernels.template_distances_fast(L, C)
    q = kernels.quadrant_distances_fast(Q, Q[0], spd.logdet(Q[0]))
    parts = chunked(lambda s: kernels.warp_descriptors_fast(gray, poses[s], (30.0, 24.0), 32, 1.0, EPS, True, True),
                    n, sizes)
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), C)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), Q)
    np.testing.assert_array_equal(np.concatenate(chunked(lambda s: kernels.template_distances_fast(L[s], C[s]),
                                                         n, sizes)), d)
    np.testing.assert_array_equal(
        np.concatenate(chunked(lambda s: kernels.quadrant_distances_fast(Q[s], Q[0], spd.logdet(Q[0])), n, sizes)), q)


@pytest.mark.parametrize("quadrants", [True, False])
def test_descriptors_written_into_rows_of_a_batch_equal_the_returned_ones(rng, quadrants):
    """``out=``: each chunk writes its rows of the batch's arrays (ObservationModel.observe's use)."""
    n = 97
    gray, poses = frame_and_poses(rng, n)
    C, Q = kernels.warp_descriptors_fast(gray, poses, (30.0, 24.0), 32, 1.0, EPS, True, quadrants)
    Cb, Qb = np.full((n, 9, 9), np.nan), (np.full((n, 4, 9, 9), np.nan) if quadrants else None)
    for s in (slice(0, 40), slice(40, 41), slice(41, n)):
        got = kernels.warp_descriptors_fast(gray, poses[s], (30.0, 24.0), 32, 1.0, EPS, True, quadrants,
                                            out=(Cb[s], None if Qb is None else Qb[s]))
        assert np.shares_memory(got[0], Cb)
    np.testing.assert_array_equal(Cb, C)
    if quadrants:
        np.testing.assert_array_equal(Qb, Q)
    with pytest.raises(ValueError, match="out C"):
        kernels.warp_descriptors_fast(gray, poses, (30.0, 24.0), 32, 1.0, EPS, True, quadrants,
                                      out=(np.empty((n, 9, 9), np.float32), Qb))
    with pytest.raises(ValueError, match="out C"):
        kernels.warp_descriptors_fast(gray, poses, (30.0, 24.0), 32, 1.0, EPS, True, quadrants,
                                      out=(np.empty((n, 9, 9))[:, ::-1], Qb))


def test_results_are_the_same_on_threads_and_repeats(rng):
    n = 300
    gray, poses = frame_and_poses(rng, n)
    L = walk(np.zeros((9, 9)) - 3 * np.eye(9), n, 0.3, rng)

    def work(s):
        C, Q = kernels.warp_descriptors_fast(gray, poses[s], (30.0, 24.0), 32, 1.0, EPS, True, True)
        return C, kernels.template_distances_fast(L[s], C), kernels.quadrant_distances_fast(Q, Q[0] * 0 + np.eye(9),
                                                                                            np.zeros(4))

    whole = work(slice(0, n))
    again = work(slice(0, n))
    with ThreadPoolExecutor(2) as pool:
        halves = list(pool.map(work, [slice(0, 150), slice(150, n)]))
    for j in range(3):
        np.testing.assert_array_equal(whole[j], again[j])
        np.testing.assert_array_equal(np.concatenate([h[j] for h in halves]), whole[j])


# --------------------------------------------------------------------------- #
# the tracker with and without the kernels
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("quadrants", [True, False])
def test_tracker_observes_the_same_with_and_without_jit(monkeypatch, quadrants):
    from covviz.data.sequences import SyntheticSequence

    seq = SyntheticSequence()
    out = {}
    for jit in (True, False):  # the config switch (COVVIZ_NO_JIT=1 is tested in a subprocess above)
        tr = ManifoldTracker(ManifoldConfig().replace(n_particles=40, quadrants=quadrants, jit=jit), rng=3)
        assert tr.config.observation.jit == jit
        tr.init(seq.frame(0).image, seq.init_box)
        tr.update(seq.frame(1).image)
        out[jit] = tr.last_record
    a, b = out[True], out[False]
    np.testing.assert_array_equal(a.particle_poses, b.particle_poses)  # the same draws
    assert frob_rel(a.descriptors, b.descriptors) < 1e-4  # b's raw float32 moments
    np.testing.assert_allclose(a.distances, b.distances, atol=2e-3)
    if quadrants:
        np.testing.assert_allclose(a.likelihood.quadrant_distances, b.likelihood.quadrant_distances, atol=2e-3)
    assert a.timings["warp"] == 0.0 and a.timings["features"] > 0.0


def test_warmup_compiles_every_signature_the_tracker_and_a_restore_use():
    """After warmup(), tracking (read-only quadrant references) and a restored snapshot (read-only
    templates) compile nothing more: the first frames of a run are not slowed by a compilation."""
    if not kernels.JIT_ENABLED:
        pytest.skip("the compiled kernels are off")
    from covviz.data.sequences import SyntheticSequence

    kernels.warmup()
    before = {d.__name__: set(d.signatures) for d in kernels._ENTRY_POINTS}
    seq = SyntheticSequence()
    with ManifoldTracker(ManifoldConfig(n_particles=40), rng=0) as tr:
        tr.init(seq.frame(0).image, seq.init_box)
        for i in range(1, 4):
            tr.update(seq.frame(i).image)
        tr.restore(tr.snapshot())
        tr.update(seq.frame(4).image)
    new = {d.__name__: set(d.signatures) - before[d.__name__] for d in kernels._ENTRY_POINTS}
    assert not any(new.values()), new


def test_pair_distances_check_their_inputs():
    W = np.broadcast_to(np.eye(9), (2, 9, 9))
    with pytest.raises(ValueError, match="shape"):
        kernels.pair_distances_fast(np.eye(9), W, [0], [0])
    with pytest.raises(ValueError, match="one length"):
        kernels.pair_distances_fast(W, W, [0, 1], [0])
    with pytest.raises(ValueError, match="indexes past"):
        kernels.pair_distances_fast(W, W, [0], [2])
    with pytest.raises(ValueError, match="NaN"):
        kernels.pair_distances_fast(W, np.full((2, 9, 9), np.nan), [0], [1])
    # the identity against 2I: sqrt(9 ln²2)
    assert kernels.pair_distances_fast(W, 2 * W, [0], [1])[0] == pytest.approx(3 * np.log(2.0), rel=1e-14)


# --------------------------------------------------------------------------- #
# the colour term's window (covviz.model.fgbg, compiled=True)
# --------------------------------------------------------------------------- #
def _random_frames(rng):
    """A colour frame, a grey one (three equal channels, as decoders give grey JPEGs) and a tiny one."""
    c = rng.integers(0, 256, (37, 53, 3), dtype=np.uint8)
    g = np.repeat(rng.integers(0, 256, (41, 29, 1), dtype=np.uint8), 3, axis=2)
    return [c, g, rng.integers(0, 256, (2, 3, 3), dtype=np.uint8)]


def _states(frame, rng, fgbg):
    """Colour states with random densities (every bin a different probability) for ``frame``."""
    st = fgbg.init_colour_model(frame, (1, 0, 2, 2))
    n = len(st.fg)
    fg, bg = rng.random(n), rng.random(n)
    return fgbg.ColourModel(fg / fg.sum(), bg / bg.sum(), np.array([0.3, 0.7, 1.5, 1.2]), st.grey)


def test_compiled_colour_map_is_the_numpy_map_bit_for_bit(rng):
    """Probabilities, integral image and F* of the compiled window equal the numpy path's (cv2.integral's
    summation order), for colour and grey frames, windows clipped at every edge and one-pixel windows."""
    from covviz.model import fgbg

    for frame in _random_frames(rng):
        H, W = frame.shape[:2]
        for _ in range(25):
            st = _states(frame, rng, fgbg)
            w, h = rng.uniform(0.2, 1.5) * W, rng.uniform(0.2, 1.5) * H
            box = np.array([rng.uniform(-w, W), rng.uniform(-h, H), w, h])
            st = fgbg.ColourModel(st.fg, st.bg, box, st.grey)
            a = fgbg.colour_map(frame, st, compiled=False)
            b = fgbg.colour_map(frame, st, compiled=True)
            assert a.origin == b.origin
            assert a.integral.shape == b.integral.shape
            assert np.array_equal(a.integral, b.integral)
            assert a.best == b.best and a.area == b.area and a.gain == b.gain


def test_compiled_colour_counts_and_updates_are_the_numpy_ones(rng):
    from covviz.model import fgbg

    for frame in _random_frames(rng):
        H, W = frame.shape[:2]
        for _ in range(25):
            box = np.array([rng.uniform(-5, W), rng.uniform(-5, H), rng.uniform(0.5, W), rng.uniform(0.5, H)])
            grey = fgbg._is_grey(frame)
            for a, b in zip(fgbg._box_and_ring_histograms(frame, box, grey, False),
                            fgbg._box_and_ring_histograms(frame, box, grey, True)):
                assert a.dtype == b.dtype and np.array_equal(a, b)
            s0 = fgbg.init_colour_model(frame, box, compiled=False)
            s1 = fgbg.init_colour_model(frame, box, compiled=True)
            assert np.array_equal(s0.fg, s1.fg) and np.array_equal(s0.bg, s1.bg) and s0.grey == s1.grey
            u0 = fgbg.update_colour_model(s0, frame, box[[1, 0, 3, 2]], 0.04, compiled=False)
            u1 = fgbg.update_colour_model(s1, frame, box[[1, 0, 3, 2]], 0.04, compiled=True)
            assert np.array_equal(u0.fg, u1.fg) and np.array_equal(u0.bg, u1.bg)


def test_the_detectors_colour_contrast_is_the_same_either_way(rng):
    from covviz.diagnosis.signals import colour_contrast
    from covviz.model import fgbg

    for frame in _random_frames(rng):
        H, W = frame.shape[:2]
        lut = rng.random(fgbg._n_bins(fgbg._is_grey(frame))) - 0.5
        for _ in range(20):
            box = (rng.uniform(-3, W), rng.uniform(-3, H), rng.uniform(0.5, W), rng.uniform(0.5, H))
            a = colour_contrast(frame, lut, fgbg._is_grey(frame), box, compiled=False)
            b = colour_contrast(frame, lut, fgbg._is_grey(frame), box, compiled=True)
            assert (np.isnan(a) and np.isnan(b)) or a == b


def test_compiled_colour_falls_back_to_numpy_for_frames_it_does_not_read(rng):
    """Float, two-dimensional and non-contiguous frames take the numpy path (same result, no error)."""
    from covviz.model import fgbg

    frame = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    st = _states(frame, rng, fgbg)
    st = fgbg.ColourModel(st.fg, st.bg, np.array([5.0, 5.0, 12.0, 9.0]), st.grey)
    ref = fgbg.colour_map(frame, st, compiled=True)
    for other in (frame.astype(np.float32) / 255.0, np.ascontiguousarray(frame[:, ::-1])[:, ::-1]):
        assert fgbg._kernels_for(other, True) is None
        m = fgbg.colour_map(other, st, compiled=True)
        assert np.array_equal(m.integral, ref.integral) and m.best == ref.best
    assert fgbg._kernels_for(frame[..., 0], True) is None
    assert fgbg._kernels_for(frame, False) is None


def test_compiled_colour_on_real_frames_is_the_numpy_path():
    """Car4 (grey) and Human3 (colour): the tracker's colour map and update around the truth, both paths."""
    from covviz.model import fgbg

    for name in ("Car4", "Human3"):
        seq = open_sequence(real_sequence(name))
        st = fgbg.init_colour_model(seq.frame(0).image, seq.init_box)
        for i in (1, 30, 61):
            fr = seq.frame(i).image
            a, b = fgbg.colour_map(fr, st, compiled=False), fgbg.colour_map(fr, st, compiled=True)
            assert np.array_equal(a.integral, b.integral) and a.best == b.best
            box = seq.groundtruth[i]
            u0 = fgbg.update_colour_model(st, fr, box, 0.04, compiled=False)
            u1 = fgbg.update_colour_model(st, fr, box, 0.04, compiled=True)
            assert np.array_equal(u0.fg, u1.fg) and np.array_equal(u0.bg, u1.bg)
            st = u1
