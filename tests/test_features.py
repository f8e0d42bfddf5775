"""Tests for :mod:`covviz.model.features`: pose geometry, the warp and the 9 per-pixel features.

Oracles are independent of the implementation: explicit crops of the image
(on integer-aligned boxes the warp is an exact crop), features recomputed here
with plain float64 numpy, and hand-built images whose derivatives are known in
closed form (a ramp, a one-pixel checkerboard, a sinusoid).
"""

from __future__ import annotations

import numpy as np
import pytest

from covviz.model.features import (
    FEATURE_NAMES,
    FEATURE_SCALE,
    N_FEATURES,
    patch_features,
    pose_corners,
    pose_to_box,
    sample_grid,
    warp_patches,
)

S = 32  # the paper's patch side
# float32 features against a float64 oracle: relative accuracy of float32 arithmetic, with headroom.
F32_ATOL = 1e-5

XC, YC, I_, GX, GY, GMAG, ANGLE, GXX, GYY = range(9)


# --------------------------------------------------------------------------- #
# an independent oracle for the features
# --------------------------------------------------------------------------- #
def oracle_features(patch: np.ndarray) -> np.ndarray:
    """The paper's 9 features of the interior of one ``(S+2, S+2)`` patch, float64, ``(9, S*S)``.

    Written from the paper's definition (central differences [-1, 0, 1]/2 and
    [1, -2, 1]), independent of the implementation's buffer tricks. Coordinates
    are ``(k + ½)/S − ½`` and the intensity is centred, as the module documents
    (shifts do not change any covariance).
    """
    P = np.asarray(patch, dtype=np.float64)
    n = P.shape[0] - 2
    inner = P[1:-1, 1:-1]
    ix = (P[1:-1, 2:] - P[1:-1, :-2]) / 2.0
    iy = (P[2:, 1:-1] - P[:-2, 1:-1]) / 2.0
    ixx = P[1:-1, 2:] - 2.0 * inner + P[1:-1, :-2]
    iyy = P[2:, 1:-1] - 2.0 * inner + P[:-2, 1:-1]
    u = (np.arange(n) + 0.5) / n - 0.5
    xx, yy = np.meshgrid(u, u)  # xx varies along columns, yy along rows
    feats = [
        xx,
        yy,
        inner - inner.mean(),
        np.abs(ix),
        np.abs(iy),
        np.sqrt(ix**2 + iy**2),
        np.arctan2(np.abs(ix), np.abs(iy)),
        np.abs(ixx),
        np.abs(iyy),
    ]
    F = np.stack([f.reshape(-1) for f in feats])
    return F * np.asarray(FEATURE_SCALE, dtype=np.float64)[:, None]


def aligned_pose(x: int, y: int, w: int = S, h: int = S) -> np.ndarray:
    """The unrotated, scale-1 pose of the integer box ``x, y, w, h``."""
    return np.array([[x + w / 2, y + h / 2, 1.0, 0.0]])


# --------------------------------------------------------------------------- #
# constants
# --------------------------------------------------------------------------- #
def test_feature_names_follow_the_paper_order():
    assert N_FEATURES == 9
    assert FEATURE_NAMES == ("x", "y", "I", "|Ix|", "|Iy|", "|grad I|", "atan(|Ix|/|Iy|)", "|Ixx|", "|Iyy|")


def test_feature_scale_constants():
    k = np.asarray(FEATURE_SCALE)
    assert k.shape == (9,)
    np.testing.assert_allclose(k, [1, 1, 1, 4, 4, 4, 2 / np.pi, 2, 2], rtol=1e-6)
    # The gradient magnitude is only exact if |Ix|, |Iy| and |grad I| share one scale.
    assert k[GX] == k[GY] == k[GMAG]


# --------------------------------------------------------------------------- #
# pose geometry
# --------------------------------------------------------------------------- #
def test_pose_corners_unrotated_box():
    c = pose_corners([50.0, 40.0, 2.0, 0.0], (10.0, 6.0))
    assert c.shape == (1, 4, 2)
    # TL, TR, BR, BL of a 20 x 12 box centred on (50, 40).
    np.testing.assert_allclose(c[0], [[40, 34], [60, 34], [60, 46], [40, 46]], atol=1e-12)


def test_positive_theta_turns_clockwise_on_screen():
    """records.py: R(θ) = [[cos, -sin], [sin, cos]] in image axes (y down) ⇒ θ > 0 is clockwise."""
    c = pose_corners([0.0, 0.0, 1.0, np.pi / 2], (4.0, 2.0))[0]
    # The top-left corner (-2, -1) turns clockwise by 90°: it ends up top-right, (1, -2).
    np.testing.assert_allclose(c[0], [1.0, -2.0], atol=1e-12)
    # The "up" direction (TL -> BL is down) now points left: BL - TL = R·(0, 2) = (-2, 0).
    np.testing.assert_allclose(c[3] - c[0], [-2.0, 0.0], atol=1e-12)
    # A small positive angle moves the top-right corner down (y grows), i.e. clockwise.
    c_small = pose_corners([0.0, 0.0, 1.0, 0.1], (4.0, 2.0))[0]
    assert c_small[1, 1] > -1.0 and c_small[0, 1] < -1.0


def test_pose_corners_rotation_preserves_centre_and_sides(rng):
    poses = np.column_stack(
        [rng.uniform(0, 100, 50), rng.uniform(0, 100, 50), rng.uniform(0.3, 3, 50), rng.uniform(-3, 3, 50)]
    )
    w, h = 12.0, 7.0
    c = pose_corners(poses, (w, h))
    assert c.shape == (50, 4, 2)
    np.testing.assert_allclose(c.mean(axis=1), poses[:, :2], atol=1e-9)
    side_w = np.linalg.norm(c[:, 1] - c[:, 0], axis=1)
    side_h = np.linalg.norm(c[:, 3] - c[:, 0], axis=1)
    np.testing.assert_allclose(side_w, w * poses[:, 2], rtol=1e-12)
    np.testing.assert_allclose(side_h, h * poses[:, 2], rtol=1e-12)
    # The TL -> TR edge points along (cos θ, sin θ).
    e = (c[:, 1] - c[:, 0]) / side_w[:, None]
    np.testing.assert_allclose(e, np.column_stack([np.cos(poses[:, 3]), np.sin(poses[:, 3])]), atol=1e-12)


def test_pose_to_box_is_axis_aligned_and_ignores_rotation():
    poses = np.array([[50.0, 40.0, 2.0, 0.0], [50.0, 40.0, 2.0, 0.7]])
    b = pose_to_box(poses, (10.0, 6.0))
    np.testing.assert_allclose(b, [[40, 34, 20, 12], [40, 34, 20, 12]])


def test_pose_to_box_round_trips_a_box(rng):
    boxes = np.column_stack([rng.uniform(-20, 200, 30), rng.uniform(-20, 200, 30), np.full(30, 17.0), np.full(30, 9.0)])
    poses = np.column_stack([boxes[:, 0] + 8.5, boxes[:, 1] + 4.5, np.ones(30), np.zeros(30)])
    np.testing.assert_allclose(pose_to_box(poses, (17.0, 9.0)), boxes, atol=1e-12)


@pytest.mark.parametrize("bad", [np.zeros((3, 3)), np.zeros(5), np.zeros((2, 4, 1))])
def test_bad_pose_shapes_raise(bad):
    with pytest.raises(ValueError, match="poses"):
        pose_corners(bad, (10, 10))
    with pytest.raises(ValueError, match="poses"):
        sample_grid(bad, (10, 10))


def test_sample_grid_unrotated_spacing_and_centre():
    mx, my = sample_grid([[50.0, 40.0, 1.0, 0.0]], (64.0, 32.0), size=S, border=1)
    g = S + 2
    assert mx.shape == my.shape == (1, g, g) and mx.dtype == np.float32
    # Columns step by w/S = 2 px, rows by h/S = 1 px; x constant down a column, y along a row.
    np.testing.assert_allclose(np.diff(mx[0], axis=1), 2.0)
    np.testing.assert_allclose(np.diff(my[0], axis=0), 1.0)
    np.testing.assert_allclose(np.diff(mx[0], axis=0), 0.0)
    # The interior tiles the region: its centre is the pose centre (in pixel-centre coordinates, −½).
    np.testing.assert_allclose(mx[0, 1:-1, 1:-1].mean(), 50.0 - 0.5, atol=1e-4)
    np.testing.assert_allclose(my[0, 1:-1, 1:-1].mean(), 40.0 - 0.5, atol=1e-4)
    # First interior sample sits half a sample inside the left edge x = 50 - 32 = 18: continuous 19.
    assert mx[0, 1, 1] == pytest.approx(19.0 - 0.5)


def test_sample_grid_step_divides_coordinates():
    pose = [[50.0, 40.0, 1.3, 0.4]]
    mx1, my1 = sample_grid(pose, (20.0, 30.0))
    mx2, my2 = sample_grid(pose, (20.0, 30.0), step=2.0)
    # continuous coordinate = map + ½; downsampling by 2 halves it.
    np.testing.assert_allclose(mx2 + 0.5, (mx1 + 0.5) / 2, atol=1e-5)
    np.testing.assert_allclose(my2 + 0.5, (my1 + 0.5) / 2, atol=1e-5)


def test_sample_grid_rotation_matches_corners():
    """The grid's outer interior samples lie half a sample inside the rotated corners."""
    pose = np.array([[60.0, 50.0, 1.5, 0.6]])
    wh = (20.0, 12.0)
    mx, my = sample_grid(pose, wh, size=S, border=0)
    c = pose_corners(pose, wh)[0]
    # Bilinear interpolation of the corners at the sample's normalised position reproduces it.
    for (r, col) in [(0, 0), (0, S - 1), (S - 1, S - 1), (S - 1, 0), (5, 17)]:
        a, b = (col + 0.5) / S, (r + 0.5) / S
        p = (1 - a) * (1 - b) * c[0] + a * (1 - b) * c[1] + a * b * c[2] + (1 - a) * b * c[3]
        np.testing.assert_allclose([mx[0, r, col] + 0.5, my[0, r, col] + 0.5], p, atol=1e-4)


# --------------------------------------------------------------------------- #
# the warp
# --------------------------------------------------------------------------- #
def test_warp_of_integer_aligned_box_is_an_exact_crop_with_border(rng):
    gray = rng.random((60, 80)).astype(np.float32)
    for x, y in [(20, 10), (1, 1), (47, 27)]:
        P = warp_patches(gray, aligned_pose(x, y), (S, S))
        assert P.shape == (1, S + 2, S + 2) and P.dtype == np.float32
        np.testing.assert_array_equal(P[0], gray[y - 1 : y + S + 1, x - 1 : x + S + 1])


def test_warp_of_downsampled_frame_is_a_crop_of_the_small_frame(rng):
    """A 64x64 box on a frame downsampled by 2 samples the small frame's pixels exactly."""
    small = rng.random((40, 50)).astype(np.float32)
    x, y = 20, 14  # box in full-resolution pixels (even, so it aligns on the small frame)
    P = warp_patches(small, aligned_pose(x, y, 64, 64), (64.0, 64.0), step=2.0)
    np.testing.assert_array_equal(P[0], small[y // 2 - 1 : y // 2 + S + 1, x // 2 - 1 : x // 2 + S + 1])


def test_warp_batches_poses_independently(rng):
    gray = rng.random((70, 90)).astype(np.float32)
    poses = np.array([[30.0, 30.0, 1.0, 0.0], [55.3, 41.7, 0.8, 0.3], [20.0, 50.0, 1.2, -1.0]])
    batch = warp_patches(gray, poses, (24.0, 18.0))
    for i, p in enumerate(poses):
        np.testing.assert_array_equal(batch[i], warp_patches(gray, p[None], (24.0, 18.0))[0])


def test_warp_outside_frame_replicates_border():
    gray = np.full((20, 20), 0.25, dtype=np.float32)
    P = warp_patches(gray, [[-100.0, -100.0, 1.0, 0.3]], (16.0, 16.0))
    assert np.all(np.isfinite(P))
    np.testing.assert_allclose(P, 0.25, atol=1e-6)


def test_warp_at_quarter_turn_is_the_rotated_crop(rng):
    """θ = +π/2 on an image equals θ = 0 on the image rotated a quarter turn counter-clockwise (np.rot90).

    Continuous coordinates: ``rot90(g)`` at ``(x', y')`` is ``g`` at ``(W − y', x')``, so its
    axis-aligned region centred at ``c'`` is ``g``'s region centred at ``(W − c'_y, c'_x)``
    turned by ``R(π/2)``: positive θ, clockwise on screen.
    """
    H = W = 80
    g = rng.random((H, W)).astype(np.float32)
    gr = np.ascontiguousarray(np.rot90(g))
    cxp, cyp = 36.0, 44.0  # region centre on the rotated image
    P_rot_img = warp_patches(gr, [[cxp, cyp, 1.0, 0.0]], (S, S))[0]
    P_pos = warp_patches(g, [[W - cyp, cxp, 1.0, np.pi / 2]], (S, S))[0]
    P_neg = warp_patches(g, [[W - cyp, cxp, 1.0, -np.pi / 2]], (S, S))[0]
    np.testing.assert_allclose(P_pos, P_rot_img, atol=1e-5)
    assert np.abs(P_neg - P_rot_img).max() > 0.1  # the other direction is a different patch


# --------------------------------------------------------------------------- #
# the features
# --------------------------------------------------------------------------- #
def test_patch_features_match_independent_oracle(rng):
    patches = rng.random((5, S + 2, S + 2)).astype(np.float32)
    F = patch_features(patches)
    assert F.shape == (5, 9, S * S) and F.dtype == np.float32
    for i in range(5):
        np.testing.assert_allclose(F[i], oracle_features(patches[i]), atol=F32_ATOL, rtol=1e-5)


def test_patch_features_other_patch_size(rng):
    patches = rng.random((2, 10, 10)).astype(np.float32)
    F = patch_features(patches)
    assert F.shape == (2, 9, 64)
    np.testing.assert_allclose(F[1], oracle_features(patches[1]), atol=F32_ATOL)


def test_features_of_horizontal_ramp():
    """I = a·column: |Ix| = a, |Iy| = 0, |∇I| = a, angle = π/2, |Ixx| = |Iyy| = 0."""
    a = 0.01
    P = np.tile(a * np.arange(S + 2, dtype=np.float32), (S + 2, 1))[None]
    F = patch_features(P)[0].astype(np.float64)
    k = np.asarray(FEATURE_SCALE, dtype=np.float64)
    np.testing.assert_allclose(F[GX], a * k[GX], rtol=1e-5)
    np.testing.assert_array_equal(F[GY], 0.0)
    np.testing.assert_allclose(F[GMAG], a * k[GMAG], rtol=1e-5)
    np.testing.assert_allclose(F[ANGLE], np.pi / 2 * k[ANGLE], rtol=1e-6)  # = 1 with the default scale
    np.testing.assert_allclose(F[GXX], 0.0, atol=1e-6)
    np.testing.assert_array_equal(F[GYY], 0.0)
    # Intensity is centred: a ramp of columns 1..S, minus its mean.
    np.testing.assert_allclose(F[I_].reshape(S, S)[0], a * (np.arange(S) - (S - 1) / 2), atol=1e-6)


def test_features_of_one_pixel_checkerboard():
    """I = (i + j) mod 2: central differences vanish, |Ixx| = |Iyy| = 2 everywhere."""
    i, j = np.mgrid[0 : S + 2, 0 : S + 2]
    P = ((i + j) % 2).astype(np.float32)[None]
    F = patch_features(P)[0]
    k = np.asarray(FEATURE_SCALE)
    for f in (GX, GY, GMAG):
        np.testing.assert_array_equal(F[f], 0.0)
    np.testing.assert_allclose(F[GXX], 2 * k[GXX])
    np.testing.assert_allclose(F[GYY], 2 * k[GYY])
    np.testing.assert_allclose(np.abs(F[I_]), 0.5)


def test_coordinate_features_tile_the_patch(rng):
    F = patch_features(rng.random((1, S + 2, S + 2)).astype(np.float32))[0]
    u = (np.arange(S) + 0.5) / S - 0.5
    np.testing.assert_allclose(F[XC].reshape(S, S), np.tile(u, (S, 1)), atol=1e-7)  # x along columns
    np.testing.assert_allclose(F[YC].reshape(S, S), np.tile(u[:, None], (1, S)), atol=1e-7)  # y along rows


def test_constant_patch_has_zero_derivatives():
    F = patch_features(np.full((1, S + 2, S + 2), 0.7, dtype=np.float32))[0]
    assert np.all(np.isfinite(F))
    for f in (I_, GX, GY, GMAG, ANGLE, GXX, GYY):
        np.testing.assert_allclose(F[f], 0.0, atol=1e-6)


def test_patch_features_does_not_modify_input(rng):
    P = rng.random((3, S + 2, S + 2)).astype(np.float32)
    P.setflags(write=False)
    before = P.copy()
    patch_features(P)
    np.testing.assert_array_equal(P, before)


@pytest.mark.parametrize("shape", [(S + 2, S + 2), (2, S + 2, S + 3), (1, 2, 2)])
def test_patch_features_rejects_bad_shapes(shape):
    with pytest.raises(ValueError, match="patches"):
        patch_features(np.zeros(shape, dtype=np.float32))


def test_patch_features_needs_one_pixel_border():
    with pytest.raises(ValueError, match="border"):
        patch_features(np.zeros((1, S + 4, S + 4), dtype=np.float32), border=2)


@pytest.mark.parametrize("gain_normalize", [False, True])
def test_quadrant_layout_holds_the_same_values_pixel_for_pixel(rng, gain_normalize):
    P = rng.random((3, S + 2, S + 2)).astype(np.float32)
    F = patch_features(P, gain_normalize=gain_normalize)
    Fq = patch_features(P, gain_normalize=gain_normalize, quadrants=True)
    h = S // 2
    assert Fq.shape == (3, 4, 9, h * h)
    regrouped = F.reshape(3, 9, 2, h, 2, h).transpose(0, 2, 4, 1, 3, 5).reshape(3, 4, 9, h * h)
    np.testing.assert_array_equal(Fq, regrouped)


def test_quadrant_layout_needs_an_even_side():
    with pytest.raises(ValueError, match="even"):
        patch_features(np.zeros((1, 9, 9), dtype=np.float32), quadrants=True)


def test_feature_scales_are_the_ones_the_doubling_shortcut_assumes():
    """_fill_features gets the four scaled derivative planes from one doubled patch."""
    k = FEATURE_SCALE
    assert 0.5 * k[3] == 0.5 * k[4] == k[7] == k[8] == 2.0
    assert k[3] == k[5] and k[2] == 1.0
