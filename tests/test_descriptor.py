"""Tests for :mod:`covviz.model.descriptor`: the regularised 9×9 region covariance.

Oracles: ``np.cov`` of features recomputed here in float64 from an explicit
crop of the image, and hand-built images whose feature statistics are known in
closed form. Hypothesis checks that every descriptor is finite and SPD for any
image (constant, saturated, tiny) and any pose, including off-frame ones.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from covviz.model.descriptor import DEFAULT_EPS, QUADRANTS, covariance, descriptors, quadrant_covariances
from covviz.model.features import FEATURE_SCALE, patch_features, warp_patches

S = 32
D = 9
K = np.asarray(FEATURE_SCALE, dtype=np.float64)
XC, YC, I_, GX, GY, GMAG, ANGLE, GXX, GYY = range(9)
N = S * S
UNBIASED = N / (N - 1)  # population -> unbiased variance over the N pixels of a patch


def crop_features(gray: np.ndarray, x: int, y: int) -> np.ndarray:
    """The paper's features of the 32x32 crop at integer ``(x, y)``, straight from the image, ``(9, N)``.

    Derivatives are central differences on the image itself (the crop's
    one-pixel border supplies the neighbours), float64.
    """
    g = np.asarray(gray, dtype=np.float64)
    rows, cols = np.mgrid[y : y + S, x : x + S]
    I = g[rows, cols]
    ix = (g[rows, cols + 1] - g[rows, cols - 1]) / 2
    iy = (g[rows + 1, cols] - g[rows - 1, cols]) / 2
    ixx = g[rows, cols + 1] - 2 * I + g[rows, cols - 1]
    iyy = g[rows + 1, cols] - 2 * I + g[rows - 1, cols]
    feats = [
        (cols - x + 0.5) / S,
        (rows - y + 0.5) / S,
        I,
        np.abs(ix),
        np.abs(iy),
        np.hypot(ix, iy),
        np.arctan2(np.abs(ix), np.abs(iy)),
        np.abs(ixx),
        np.abs(iyy),
    ]
    return np.stack([f.ravel() for f in feats]) * K[:, None]


def desc_at(gray, x, y, eps=DEFAULT_EPS, theta=0.0, w=S, h=S):
    """Descriptor of the box ``x, y, w, h`` (turned by ``theta`` about its centre)."""
    return descriptors(gray, [[x + w / 2, y + h / 2, 1.0, theta]], (w, h), size=S, eps=eps)[0]


def cov_tol(C: np.ndarray) -> float:
    """Absolute tolerance for float32 features against a float64 oracle."""
    return 2e-5 * float(np.abs(C).max())


# --------------------------------------------------------------------------- #
# covariance
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_covariance_eps0_equals_np_cov(rng, dtype):
    F = (rng.standard_normal((4, D, 200)) * rng.uniform(0.1, 2, (1, D, 1)) + 0.3).astype(dtype)
    C = covariance(F, eps=0.0)
    assert C.shape == (4, D, D) and C.dtype == np.float64
    for i in range(4):
        ref = np.cov(F[i].astype(np.float64))
        np.testing.assert_allclose(C[i], ref, atol=1e-5 * np.abs(ref).max() if dtype == np.float32 else 1e-12)
    np.testing.assert_array_equal(C, np.swapaxes(C, 1, 2))


def test_regularisation_adds_eps_times_mean_variance(rng):
    F = rng.standard_normal((3, D, 100))
    C0 = covariance(F, eps=0.0)
    eps = 0.05
    C = covariance(F, eps=eps)
    shift = eps * np.trace(C0, axis1=1, axis2=2) / D
    np.testing.assert_allclose(C - C0, shift[:, None, None] * np.eye(D), atol=1e-10)


@pytest.mark.parametrize("shape", [(D, 100), (2, D, 1), (2, D)])
def test_covariance_rejects_bad_shapes(shape):
    with pytest.raises(ValueError, match="features"):
        covariance(np.zeros(shape))


def test_covariance_does_not_modify_input(rng):
    F = rng.standard_normal((2, D, 50)).astype(np.float32)
    F.setflags(write=False)
    before = F.copy()
    covariance(F)
    np.testing.assert_array_equal(F, before)


def test_default_eps_is_positive():
    assert DEFAULT_EPS > 0


# --------------------------------------------------------------------------- #
# the descriptor of an explicitly cropped patch
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("xy", [(20, 10), (1, 1), (40, 25)])
def test_descriptor_equals_np_cov_of_explicit_crop(rng, xy):
    x, y = xy
    # A smooth image plus noise: realistic derivative statistics, all features non-degenerate.
    yy, xx = np.mgrid[0:60, 0:75]
    gray = (0.5 + 0.3 * np.sin(xx / 7.0) * np.cos(yy / 5.0) + 0.05 * rng.standard_normal((60, 75)))
    gray = np.clip(gray, 0, 1).astype(np.float32)
    # The warp is an exact crop here, including the one-pixel border.
    P = warp_patches(gray, [[x + S / 2, y + S / 2, 1.0, 0.0]], (S, S), size=S)
    np.testing.assert_array_equal(P[0], gray[y - 1 : y + S + 1, x - 1 : x + S + 1])
    C = desc_at(gray, x, y, eps=0.0)
    ref = np.cov(crop_features(gray, x, y))
    np.testing.assert_allclose(C, ref, atol=cov_tol(ref))
    # And with the default regulariser: the same matrix shrunk towards (tr/d)·I.
    Cr = desc_at(gray, x, y, eps=DEFAULT_EPS)
    np.testing.assert_allclose(Cr, ref + DEFAULT_EPS * np.trace(ref) / D * np.eye(D), atol=cov_tol(ref))


def test_descriptors_is_warp_features_covariance(rng):
    gray = rng.random((50, 60)).astype(np.float32)
    poses = np.array([[30.0, 25.0, 1.0, 0.0], [28.3, 22.1, 0.7, 0.5]])
    expected = covariance(patch_features(warp_patches(gray, poses, (20.0, 14.0))), DEFAULT_EPS)
    np.testing.assert_allclose(descriptors(gray, poses, (20.0, 14.0)), expected, rtol=1e-12, atol=1e-15)


def test_coordinate_block_is_known_for_any_patch(rng):
    """x, y tile the patch: var = 1/12 each (unbiased over S² pixels, exactly), cov(x, y) = 0."""
    gray = rng.random((50, 50)).astype(np.float32)
    C = desc_at(gray, 9, 9)
    C0 = desc_at(gray, 9, 9, eps=0.0)
    np.testing.assert_allclose(C0[:2, :2], np.eye(2) / 12, atol=1e-7)
    assert C[XC, XC] > C0[XC, XC]  # the regulariser only adds


# --------------------------------------------------------------------------- #
# hand-built images
# --------------------------------------------------------------------------- #
def test_descriptor_of_horizontal_ramp():
    """I = a·column: |Ix| = a, angle = π/2 constant; |Iy| = Ixx = Iyy = 0; I perfectly correlated with x."""
    a = 1.0 / 128
    gray = np.tile(a * np.arange(80, dtype=np.float32), (60, 1))
    C = desc_at(gray, 20, 14, eps=0.0)
    assert np.all(np.isfinite(C))
    # var(I) = a²·S²/12 (columns k = 0..S-1, each S times, unbiased), cov(x, I) = a·S/12.
    assert C[I_, I_] == pytest.approx(a**2 * S**2 / 12, rel=1e-5)
    assert C[XC, I_] == pytest.approx(a * S / 12, rel=1e-5)
    assert C[YC, I_] == pytest.approx(0.0, abs=1e-9)
    # Every derivative and angle feature is constant: zero rows and columns.
    for f in (GX, GY, GMAG, ANGLE, GXX, GYY):
        np.testing.assert_allclose(C[f], 0.0, atol=1e-9)
    # With the regulariser it is SPD even though six features are constant.
    Cr = desc_at(gray, 20, 14)
    assert np.linalg.eigvalsh(Cr).min() > 0


def test_descriptor_of_constant_image_is_finite_and_spd():
    gray = np.full((48, 64), 0.42, dtype=np.float32)
    C = desc_at(gray, 10, 8)
    assert np.all(np.isfinite(C))
    np.testing.assert_array_equal(C, C.T)
    assert np.linalg.eigvalsh(C).min() > 0
    shift = DEFAULT_EPS * (2 / 12) / D  # eps · tr/d, the trace being the coordinates' 2/12
    np.testing.assert_allclose(C[:2, :2], np.eye(2) * (1 / 12 + shift), rtol=1e-5)
    # Intensity and every derivative feature: only the regulariser on the diagonal.
    inner = C[2:, 2:]
    np.testing.assert_allclose(inner, shift * np.eye(D - 2), atol=1e-9)
    np.testing.assert_allclose(C[:2, 2:], 0.0, atol=1e-9)


@pytest.mark.parametrize("value", [0.0, 1.0])
def test_descriptor_of_saturated_image(value):
    gray = np.full((40, 40), value, dtype=np.float32)
    C = descriptors(gray, [[20.0, 20.0, 1.0, 0.3], [-50.0, 90.0, 2.0, 1.0]], (16.0, 16.0))
    assert np.all(np.isfinite(C)) and np.linalg.eigvalsh(C).min() > 0


def test_descriptor_of_sinusoid_has_known_derivative_statistics():
    """I = ½ + A·sin(2π(c + ½)/8) along columns c: closed-form derivative statistics.

    Central differences: Ix = A sin(π/4) cos(2π(c+½)/8), so |Ix| alternates
    between A sin(π/4) cos(π/8) and A sin(π/4) cos(3π/8) on half the pixels each;
    Ixx = −4A sin²(π/8) sin(2π(c+½)/8), so |Ixx| alternates between
    4A sin²(π/8)·{sin(π/8), sin(3π/8)}, high where |Ix| is low. Iy = Iyy = 0 and
    the angle is π/2 everywhere (|Ix| never vanishes).
    """
    A = 0.3
    c = np.arange(96)
    row = (0.5 + A * np.sin(2 * np.pi * (c + 0.5) / 8)).astype(np.float32)
    gray = np.tile(row, (64, 1))
    C = desc_at(gray, 16, 16, eps=0.0)

    def two_valued_var(v1, v2):  # half the pixels at each value
        return UNBIASED * ((v1 - v2) / 2) ** 2

    ix_hi, ix_lo = A * np.sin(np.pi / 4) * np.cos(np.pi / 8), A * np.sin(np.pi / 4) * np.cos(3 * np.pi / 8)
    ixx_lo, ixx_hi = 4 * A * np.sin(np.pi / 8) ** 2 * np.sin(np.pi / 8), 4 * A * np.sin(np.pi / 8) ** 2 * np.sin(
        3 * np.pi / 8
    )
    var_ix = K[GX] ** 2 * two_valued_var(ix_hi, ix_lo)
    var_ixx = K[GXX] ** 2 * two_valued_var(ixx_hi, ixx_lo)
    tol = 1e-4
    assert C[I_, I_] == pytest.approx(UNBIASED * A**2 / 2, rel=tol)  # mean of sin² over whole periods
    assert C[GX, GX] == pytest.approx(var_ix, rel=tol)
    assert C[GMAG, GMAG] == pytest.approx(var_ix, rel=tol)  # |∇I| = |Ix| as Iy = 0
    assert C[GX, GMAG] == pytest.approx(var_ix, rel=tol)
    assert C[GXX, GXX] == pytest.approx(var_ixx, rel=tol)
    # |Ix| high exactly where |Ixx| is low: correlation −1.
    assert C[GX, GXX] == pytest.approx(-np.sqrt(var_ix * var_ixx), rel=tol)
    # Constant features: zero rows (to the float32 accuracy of the raw second moments).
    for f in (GY, ANGLE, GYY):
        np.testing.assert_allclose(C[f], 0.0, atol=cov_tol(C))


def test_intensity_offset_does_not_change_the_descriptor(rng):
    gray = (0.5 * rng.random((50, 50))).astype(np.float32)
    C1 = desc_at(gray, 8, 8)
    C2 = desc_at(gray + np.float32(0.25), 8, 8)
    np.testing.assert_allclose(C1, C2, atol=1e-6 * np.abs(C1).max())


# --------------------------------------------------------------------------- #
# rotation: a quarter turn swaps |Ix| and |Iy|
# --------------------------------------------------------------------------- #
SWAP = np.array([XC, YC, I_, GY, GX, GMAG, ANGLE, GYY, GXX])  # feature permutation of a quarter turn


def _assert_quarter_turn(C_turned, C0):
    """Variances of a quarter-turned patch: |Ix| <-> |Iy|, |Ixx| <-> |Iyy|; I and |∇I| unchanged."""
    tol = cov_tol(C0)
    d0 = np.diag(C0)[SWAP]
    np.testing.assert_allclose(np.diag(C_turned)[2:], d0[2:], rtol=1e-4, atol=tol)
    np.testing.assert_allclose(C_turned[GX, GY], C0[GX, GY], rtol=1e-4, atol=tol)
    np.testing.assert_allclose(C_turned[GXX, GYY], C0[GXX, GYY], rtol=1e-4, atol=tol)
    np.testing.assert_allclose(C_turned[GX, GMAG], C0[GY, GMAG], rtol=1e-4, atol=tol)
    np.testing.assert_allclose(C_turned[GY, GMAG], C0[GX, GMAG], rtol=1e-4, atol=tol)


def test_quarter_turn_pose_swaps_ix_and_iy(rng):
    # Anisotropic texture (stronger horizontal gradients) so that swapping is visible.
    yy, xx = np.mgrid[0:80, 0:80]
    gray = (0.5 + 0.3 * np.sin(xx / 1.7) + 0.05 * np.sin(yy / 6.0) + 0.02 * rng.standard_normal((80, 80)))
    gray = gray.astype(np.float32)
    C0 = desc_at(gray, 24, 24, eps=0.0)
    assert C0[GX, GX] > 3 * C0[GY, GY]
    for theta in (np.pi / 2, -np.pi / 2):
        _assert_quarter_turn(desc_at(gray, 24, 24, eps=0.0, theta=theta), C0)


def test_rotated_image_swaps_ix_and_iy_and_matches_positive_theta(rng):
    W = 80
    _yy, xx = np.mgrid[0:W, 0:W]
    gray = (0.5 + 0.3 * np.sin(xx / 1.7) + 0.02 * rng.standard_normal((W, W))).astype(np.float32)
    rot = np.ascontiguousarray(np.rot90(gray))  # a quarter turn counter-clockwise on screen
    C0 = desc_at(gray, 24, 30, eps=0.0)
    # The region of rot at centre c' is gray's region at (W - c'_y, c'_x): box (30, 24) of rot.
    C_rot = desc_at(rot, 30, W - 24 - S, eps=0.0)
    _assert_quarter_turn(C_rot, C0)
    # θ = +π/2 on gray sees exactly what θ = 0 sees on rot (positive θ is clockwise on screen).
    C_pos = desc_at(gray, 24, 30, eps=0.0, theta=np.pi / 2)
    np.testing.assert_allclose(C_pos[2:, 2:], C_rot[2:, 2:], atol=cov_tol(C_rot))


# --------------------------------------------------------------------------- #
# properties: always finite and SPD
# --------------------------------------------------------------------------- #
@st.composite
def images(draw):
    h = draw(st.integers(1, 40))
    w = draw(st.integers(1, 40))
    kind = draw(st.sampled_from(["random", "constant", "saturated", "binary", "tiny"]))
    if kind == "constant":
        return np.full((h, w), draw(st.floats(0, 1)), dtype=np.float32)
    if kind == "saturated":
        return np.full((h, w), draw(st.sampled_from([0.0, 1.0])), dtype=np.float32)
    if kind == "binary":
        return draw(hnp.arrays(np.float32, (h, w), elements=st.sampled_from([0.0, 1.0])))
    if kind == "tiny":
        return draw(hnp.arrays(np.float32, (h, w), elements=st.floats(0, float(np.float32(1e-6)), width=32)))
    return draw(hnp.arrays(np.float32, (h, w), elements=st.floats(0, 1, width=32)))


pose_st = st.tuples(
    st.floats(-30, 70), st.floats(-30, 70), st.floats(0.05, 4.0), st.floats(-np.pi, np.pi)
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    gray=images(),
    poses=st.lists(pose_st, min_size=1, max_size=4),
    wh=st.tuples(st.floats(1.0, 60.0), st.floats(1.0, 60.0)),
)
def test_descriptors_are_always_finite_and_spd(gray, poses, wh):
    C = descriptors(gray, np.array(poses), wh)
    assert C.shape == (len(poses), D, D)
    assert np.all(np.isfinite(C))
    np.testing.assert_array_equal(C, np.swapaxes(C, 1, 2))
    assert np.linalg.eigvalsh(C).min() > 0
    # Cholesky succeeds: what the tracker's distance needs.
    np.linalg.cholesky(C)


def test_gain_normalisation_makes_descriptors_illumination_invariant(rng):
    # I -> g·I rescales intensity and derivative features; with gain_normalize every one of them is
    # divided by the patch mean, so the descriptor must not move (up to float32 rounding), while the
    # paper's plain features move by a large Riemannian distance.
    from covviz.model.descriptor import descriptors
    from covviz.model.spd import distance_riemann

    img = (0.2 + 0.6 * rng.random((120, 160))).astype(np.float32)
    poses = np.array([[80.0, 60.0, 1.0, 0.0], [70.0, 50.0, 1.2, 0.3]])
    for g in (0.5, 1.7):
        a = descriptors(img, poses, (40, 40), gain_normalize=True)
        b = descriptors(g * img, poses, (40, 40), gain_normalize=True)
        assert np.all(distance_riemann(a, b) < 1e-3)
        plain = distance_riemann(descriptors(img, poses, (40, 40)), descriptors(g * img, poses, (40, 40)))
        assert np.all(plain > 0.5)


# --------------------------------------------------------------------------- #
# quadrant (sub-region) covariances
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("xy", [(20, 10), (1, 1)])
def test_quadrant_covariances_equal_np_cov_of_explicit_sub_crops(rng, xy):
    x, y = xy
    yy, xx = np.mgrid[0:60, 0:75]
    gray = (0.5 + 0.3 * np.sin(xx / 7.0) * np.cos(yy / 5.0) + 0.05 * rng.standard_normal((60, 75)))
    gray = np.clip(gray, 0, 1).astype(np.float32)
    F = patch_features(warp_patches(gray, [[x + S / 2, y + S / 2, 1.0, 0.0]], (S, S), size=S))
    whole, quads = quadrant_covariances(F, eps=0.0)
    assert whole.shape == (1, D, D) and quads.shape == (1, 4, D, D)
    feats = crop_features(gray, x, y).reshape(D, S, S)
    ref_whole = np.cov(feats.reshape(D, -1))
    np.testing.assert_allclose(whole[0], ref_whole, atol=cov_tol(ref_whole))
    h = S // 2
    origins = {"top-left": (0, 0), "top-right": (0, h), "bottom-left": (h, 0), "bottom-right": (h, h)}
    for q, name in enumerate(QUADRANTS):
        r, c = origins[name]
        ref = np.cov(feats[:, r : r + h, c : c + h].reshape(D, -1))
        np.testing.assert_allclose(quads[0, q], ref, atol=cov_tol(ref), err_msg=name)


def test_quadrant_whole_matches_covariance_and_quadrants_are_spd(rng):
    P = rng.random((6, S + 2, S + 2)).astype(np.float32)
    F = patch_features(P)
    whole, quads = quadrant_covariances(F)
    ref = covariance(F)
    np.testing.assert_allclose(whole, ref, atol=cov_tol(ref))
    # The quadrant layout of patch_features gives the same matrices without the copy.
    wq, qq = quadrant_covariances(patch_features(P, quadrants=True))
    np.testing.assert_array_equal(wq, whole)
    np.testing.assert_array_equal(qq, quads)
    assert np.all(np.linalg.eigvalsh(quads) > 0)
    # A constant patch: regularised, finite, SPD (no NaN from zero variances).
    whole, quads = quadrant_covariances(patch_features(np.full((1, S + 2, S + 2), 0.3, np.float32)))
    assert np.isfinite(quads).all() and np.all(np.linalg.eigvalsh(quads) > 0)


def test_quadrants_see_where_things_are_and_the_whole_does_not(rng):
    """A bright square in the top-left or the bottom-right quadrant. The whole-patch
    descriptors tell them apart only through the coordinate covariances
    (d ≈ 1.6); the quadrants that hold the square in one patch and not in the
    other differ ten times more (d ≈ 17)."""
    from covviz.model.spd import distance_riemann

    P = np.full((2, S + 2, S + 2), 0.2, np.float32)
    P += 0.01 * rng.random(P.shape).astype(np.float32)
    P[0, 3:13, 3:13] += 0.6  # top-left quadrant
    P[1, 21:31, 21:31] += 0.6  # bottom-right: the same square turned by 180 degrees about the centre
    whole, quads = quadrant_covariances(patch_features(P))
    d_whole = distance_riemann(whole[0], whole[1])
    d_quads = distance_riemann(quads[0], quads[1])
    assert d_quads[0] > 5 * d_whole and d_quads[3] > 5 * d_whole


def test_quadrant_covariances_reject_odd_or_non_square_patches():
    with pytest.raises(ValueError, match="even"):
        quadrant_covariances(np.zeros((1, D, 9 * 9), np.float32))
    with pytest.raises(ValueError, match="even"):
        quadrant_covariances(np.zeros((1, D, 30), np.float32))


def test_float32_cancellation_never_leaves_a_descriptor_short_of_spd(rng):
    """Raw float32 moments of a nearly constant feature far from zero cancel badly; a small shrinkage
    alone can leave the covariance a hair short of positive-definite. The result must stay SPD, and
    the descriptors that were fine must not change."""
    n, d, N = 64, 9, 256
    F = rng.standard_normal((n, d, N)).astype(np.float32) * 0.1
    F[:, 2] = (1000.0 + 1e-4 * rng.standard_normal((n, N))).astype(np.float32)  # ~constant, far from 0
    C = covariance(F, eps=1e-7)
    assert np.all(np.linalg.eigvalsh(C)[:, 0] > 0)
    np.linalg.cholesky(C)
    healthy = rng.standard_normal((8, d, N)).astype(np.float32)
    from covviz.model.descriptor import _finish, _moments

    M, s = _moments(healthy)
    mu = s / N
    raw = (M - N * mu[..., :, None] * mu[..., None, :]) / (N - 1)
    raw = 0.5 * (raw + np.swapaxes(raw, -1, -2))
    from covviz.model.spd import regularize

    np.testing.assert_array_equal(_finish(M, s, N, 1e-3), regularize(raw, 1e-3))
