"""Tests of the IVT / IPCA baseline: affine warp, sequential KL update, tracker."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.linalg import subspace_angles
from scipy.ndimage import map_coordinates
from scipy.special import logsumexp

from covviz.data.sequences import OTBSequence, SyntheticConfig, SyntheticSequence
from covviz.metrics import evaluate
from covviz.runner import run
from covviz.trackers.base import IdentityTracker
from covviz.trackers.ipca import (
    AppearanceModel,
    IPCAConfig,
    IPCATracker,
    affine_matrices,
    box_to_state,
    reconstruction_errors,
    resample_indices,
    sample_templates,
    sklm,
    state_corners,
    state_to_box,
    template_grid,
    update_model,
)

CAR4 = Path(__file__).resolve().parents[2] / "shared" / "sequences" / "Car4"

#: cv2.remap quantises sample positions to 1/32 pixel: the interpolation error is at most
#: (1/64 px) x (the largest intensity step between neighbouring pixels).
REMAP_STEP = 1.0 / 32.0


@pytest.fixture
def rng():
    return np.random.default_rng(20080101)


def _reference_affparam2mat(p):
    """The reference MATLAB formula (affparam2mat.m), transcribed as an independent oracle."""
    s, th, r, phi = p[2], p[3], p[4], p[5]
    cth, sth, cph, sph = math.cos(th), math.sin(th), math.cos(phi), math.sin(phi)
    ccc, ccs, css = cth * cph * cph, cth * cph * sph, cth * sph * sph
    scc, scs, sss = sth * cph * cph, sth * cph * sph, sth * sph * sph
    return np.array(
        [
            [s * (ccc + scs + r * (css - scs)), s * (r * (ccs - scc) - ccs - sss)],
            [s * (scc - ccs + r * (ccs + sss)), s * (r * (ccc + scs) - scs + css)],
        ]
    )


def _random_states(rng, n, centre=(160.0, 120.0)):
    s = np.empty((n, 6))
    s[:, 0] = centre[0] + rng.uniform(-20, 20, n)
    s[:, 1] = centre[1] + rng.uniform(-20, 20, n)
    s[:, 2] = rng.uniform(0.6, 2.5, n)
    s[:, 3] = rng.uniform(-np.pi, np.pi, n)
    s[:, 4] = rng.uniform(0.5, 1.8, n)
    s[:, 5] = rng.uniform(-0.6, 0.6, n)
    return s


# --------------------------------------------------------------------------- #
# affine geometry and warping
# --------------------------------------------------------------------------- #
def test_affine_matrices_match_reference_affparam2mat(rng):
    states = _random_states(rng, 50)
    M = affine_matrices(states)
    assert M.shape == (50, 2, 3)
    for st, m in zip(states, M):
        np.testing.assert_allclose(m[:, :2], _reference_affparam2mat(st), atol=1e-12)
        np.testing.assert_array_equal(m[:, 2], st[:2])


def test_box_state_round_trip(rng):
    boxes = np.column_stack(
        [
            rng.uniform(-50, 300, 40),
            rng.uniform(-50, 200, 40),
            rng.uniform(5, 200, 40),
            rng.uniform(5, 200, 40),
        ]
    )
    states = box_to_state(boxes)
    np.testing.assert_allclose(states[:, 2], boxes[:, 2] / 32)
    np.testing.assert_allclose(states[:, 4], boxes[:, 3] / boxes[:, 2])
    np.testing.assert_allclose(state_to_box(states), boxes, atol=1e-9)
    np.testing.assert_allclose(box_to_state(state_to_box(states)), states, atol=1e-9)
    # Corners of the identity state are the box corners, TL, TR, BR, BL.
    x, y, w, h = boxes[0]
    np.testing.assert_allclose(
        state_corners(states[:1])[0], [[x, y], [x + w, y], [x + w, y + h], [x, y + h]], atol=1e-9
    )


def test_state_to_box_of_rotated_states():
    # A 40x20 region turned by 90 degrees covers 20x40; a square turned by 45 degrees grows by sqrt(2).
    st = box_to_state([[80.0, 90.0, 40.0, 20.0]])
    st[0, 3] = np.pi / 2
    np.testing.assert_allclose(state_to_box(st)[0], [90.0, 80.0, 20.0, 40.0], atol=1e-9)
    sq = box_to_state([[0.0, 0.0, 32.0, 32.0]])
    sq[0, 3] = np.pi / 4
    b = state_to_box(sq)[0]
    np.testing.assert_allclose(b[2:], [32 * math.sqrt(2)] * 2, atol=1e-9)
    np.testing.assert_allclose(b[:2] + b[2:] / 2, [16.0, 16.0], atol=1e-9)
    # Positive rotation turns the region clockwise on screen (y down): the top-left corner goes to the top.
    np.testing.assert_allclose(state_corners(sq)[0, 0], [16.0, 16.0 - 16.0 * math.sqrt(2)], atol=1e-9)


def test_template_grids():
    u = template_grid(32, "centred")
    assert u[0] == -15.5 and u[-1] == 15.5
    np.testing.assert_allclose(u, -u[::-1])
    np.testing.assert_array_equal(template_grid(32, "reference"), np.arange(1, 33) - 16)  # MATLAB (1:32)-16
    with pytest.raises(ValueError, match="grid"):
        template_grid(32, "matlab")


def _sample_points(M, grid):
    """Continuous image points sampled for each template pixel: (px, py), each (n, 32, 32)."""
    u = template_grid(32, grid)
    U, V = np.meshgrid(u, u)  # U[k, l] = u[l] (column offset), V[k, l] = u[k] (row offset)
    extra = 0.5 if grid == "reference" else 0.0
    px = M[:, 0, 0, None, None] * U + M[:, 0, 1, None, None] * V + M[:, 0, 2, None, None] + extra
    py = M[:, 1, 0, None, None] * U + M[:, 1, 1, None, None] * V + M[:, 1, 2, None, None] + extra
    return px, py


def _smooth_image(h=120, w=160):
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    img = 0.5 + 0.3 * np.sin(xx / 9.0) * np.cos(yy / 7.0) + 0.002 * xx
    return img.astype(np.float32)


def test_warp_identity_state_is_a_bilinear_resize_of_the_box():
    img = _smooth_image()
    # Integer-aligned boxes at least 32 px wide (cv2.resize then never reads beyond the crop).
    for x, y, w, h in [(37, 21, 64, 48), (10, 30, 100, 70), (50, 40, 32, 32)]:
        patch = sample_templates(img, box_to_state([[x, y, w, h]]), grid="centred")[0]
        ref = cv2.resize(img[y : y + h, x : x + w], (32, 32), interpolation=cv2.INTER_LINEAR)
        step = np.abs(np.diff(img, axis=0)).max() + np.abs(np.diff(img, axis=1)).max()
        np.testing.assert_allclose(patch, ref, atol=step * REMAP_STEP)


@pytest.mark.parametrize("grid", ["centred", "reference"])
def test_warp_samples_a_linear_image_exactly_at_the_affine_points(rng, grid):
    # Bilinear interpolation reproduces a linear image exactly, so every sample can be predicted
    # analytically from the state: this pins the convention (pixel centres at j + 0.5, rows vs
    # columns, rotation sense, skew, aspect) for arbitrary states.
    H, W = 240, 320
    a, b, c0 = 0.0011, -0.0007, 0.4
    yy, xx = np.mgrid[0:H, 0:W]
    img = (a * (xx + 0.5) + b * (yy + 0.5) + c0).astype(np.float32)
    states = _random_states(rng, 30)
    patches = sample_templates(img, states, grid=grid)
    px, py = _sample_points(affine_matrices(states), grid)
    inside = (px > 0.5) & (px < W - 0.5) & (py > 0.5) & (py < H - 0.5)
    assert inside.mean() > 0.9
    expect = a * px + b * py + c0
    tol = (abs(a) + abs(b)) * REMAP_STEP + 1e-6
    np.testing.assert_allclose(patches[inside], expect[inside], atol=tol)


@pytest.mark.parametrize("grid", ["centred", "reference"])
def test_warp_matches_an_exact_bilinear_oracle(rng, grid):
    img = rng.random((100, 130)).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), 1.5)
    states = _random_states(rng, 8, centre=(65.0, 50.0))
    states[:, 2] *= 0.6  # some regions cross the border
    patches = sample_templates(img, states, grid=grid)
    PX, PY = _sample_points(affine_matrices(states), grid)
    step = np.abs(np.diff(img, axis=0)).max() + np.abs(np.diff(img, axis=1)).max()
    for p, px, py in zip(patches, PX, PY):
        # map_coordinates indexes pixels by their 0-based index = continuous coordinate - 0.5;
        # "grid-constant" blends with 0 beyond the border, as OpenCV's BORDER_CONSTANT.
        ref = map_coordinates(img, [py - 0.5, px - 0.5], order=1, mode="grid-constant", cval=0.0)
        np.testing.assert_allclose(p, ref, atol=step * REMAP_STEP + 1e-6)


def test_warp_rotated_state_samples_rotated_content(rng):
    img = rng.random((80, 90)).astype(np.float32)
    # A 32x32 box centred on a pixel corner: every sample lands on a pixel centre, also at 90 degrees.
    st = box_to_state([[20.0, 15.0, 32.0, 32.0]])
    p0 = sample_templates(img, st, grid="centred")[0]
    np.testing.assert_array_equal(p0, img[15:47, 20:52])
    for quarter in (1, 2, 3):
        s = st.copy()
        s[0, 3] = quarter * np.pi / 2
        # The region turns clockwise on screen, so its content turns counter-clockwise in the patch.
        np.testing.assert_allclose(sample_templates(img, s, grid="centred")[0], np.rot90(p0, quarter), atol=1e-6)
    # The reference convention models the region 0.5 + 0.5 * scale = 1 px right of and below the box.
    np.testing.assert_array_equal(sample_templates(img, st, grid="reference")[0], img[16:48, 21:53])


def test_reference_grid_is_the_centred_grid_shifted(rng):
    # "reference" at state c equals "centred" at c + A (0.5, 0.5) + (0.5, 0.5): an offset of half a
    # template pixel (it turns with the region) plus half an image pixel.
    img = cv2.GaussianBlur(rng.random((120, 160)).astype(np.float32), (0, 0), 1.0)
    states = _random_states(rng, 20, centre=(80.0, 60.0))
    moved = states.copy()
    moved[:, :2] += affine_matrices(states)[:, :, :2] @ np.array([0.5, 0.5]) + 0.5
    np.testing.assert_allclose(
        sample_templates(img, states, grid="reference"), sample_templates(img, moved, grid="centred"), atol=2e-3
    )


def test_warp_pixels_outside_the_image_are_zero(rng):
    img = (0.2 + 0.8 * rng.random((60, 70))).astype(np.float32)
    far = box_to_state([[500.0, -300.0, 40.0, 30.0]])
    assert np.all(sample_templates(img, far) == 0)
    assert np.all(sample_templates(img, far, grid="centred") == 0)
    # Box from x = -16 to 16: its left half samples x < 0 (outside), its right half pixel columns 0..15.
    st = box_to_state([[-16.0, 10.0, 32.0, 32.0]])
    p = sample_templates(img, st, grid="centred")[0]
    assert np.all(p[:, :16] == 0)
    np.testing.assert_array_equal(p[:, 16:], img[10:42, 0:16])


def test_warp_many_particles_in_chunks(rng):
    img = rng.random((50, 60)).astype(np.float32)
    states = _random_states(rng, 1100, centre=(30.0, 25.0))  # 1100 * 32 rows > OpenCV's SHRT_MAX
    p = sample_templates(img, states)
    assert p.shape == (1100, 32, 32) and p.dtype == np.float32
    np.testing.assert_array_equal(p[1050:], sample_templates(img, states[1050:]))


# --------------------------------------------------------------------------- #
# sequential Karhunen-Loeve
# --------------------------------------------------------------------------- #
def _run_sklm(batches, ff, maxbasis=None):
    U, D, mu, n = None, None, None, 0.0
    history = []
    for X in batches:
        U, D, mu, n = sklm(X, U, D, mu, n, ff, maxbasis)
        history.append((U, D, mu, n))
    return history


def test_sklm_with_ff_1_equals_the_batch_svd_of_all_data(rng):
    N, nb, T = 40, 5, 6
    batches = [rng.normal(size=(N, nb)) + rng.normal(size=(N, 1)) for _ in range(T)]
    U, D, mu, n = _run_sklm(batches, ff=1.0)[-1]
    X = np.hstack(batches)
    mean = X.mean(axis=1)
    Ub, Db, _ = np.linalg.svd(X - mean[:, None], full_matrices=False)
    k = nb * T - 1  # rank of the centred data
    assert n == nb * T
    np.testing.assert_allclose(mu, mean, atol=1e-12)
    assert U.shape == (N, k)
    np.testing.assert_allclose(D, Db[:k], rtol=1e-9)
    np.testing.assert_allclose(U.T @ U, np.eye(k), atol=1e-10)
    assert np.max(subspace_angles(U, Ub[:, :k])) < 1e-8
    np.testing.assert_allclose(U @ U.T, Ub[:, :k] @ Ub[:, :k].T, atol=1e-9)


def test_sklm_forgetting_old_subspace_decays_as_ff_per_update(rng):
    N, nb, ff = 30, 8, 0.8
    Q, _ = np.linalg.qr(rng.normal(size=(N, 6)))
    S1, S2 = Q[:, :3], Q[:, 3:]

    def batch(S):
        X = S @ (rng.normal(size=(3, nb)) * np.array([[3.0], [2.0], [1.0]]))
        return X - X.mean(axis=1, keepdims=True)  # zero mean: the mean column of sklm vanishes

    U, D, mu, n = _run_sklm([batch(S1) for _ in range(4)], ff)[-1]
    e1_0 = np.linalg.norm(S1.T @ U * D)  # sqrt of the S1 energy of the scatter U D^2 U^T
    counts = [n]
    for t in range(1, 61):
        U, D, mu, n = sklm(batch(S2), U, D, mu, n, ff)
        counts.append(n)
        e1 = np.linalg.norm(S1.T @ U * D)
        if U.shape[1] == 6:  # while nothing of S1 has been cut off, the decay is exactly ff^t
            np.testing.assert_allclose(e1, ff**t * e1_0, rtol=1e-8)
    # The effective count follows n <- nb + ff n, towards nb / (1 - ff).
    np.testing.assert_allclose(np.diff(counts), nb + (ff - 1.0) * np.array(counts[:-1]))
    assert abs(counts[-1] - nb / (1 - ff)) < 1e-3
    # After 60 batches (ff^120 ~ 2e-12 of the energy) S1 is cut off; the basis is S2.
    assert U.shape[1] == 3
    assert np.max(subspace_angles(U, S2)) < 1e-6
    np.testing.assert_allclose(mu, 0.0, atol=1e-12)


def test_sklm_mean_update_with_forgetting(rng):
    N, ff = 20, 0.9
    sizes = [5, 5, 3, 7, 5, 4]
    batches = [rng.normal(size=(N, m)) + 3 * rng.normal(size=(N, 1)) for m in sizes]
    hist = _run_sklm(batches, ff)
    for t in range(len(batches)):
        # Batch j carries weight ff^(t - j) * n_j.
        w = np.array([ff ** (t - j) * sizes[j] for j in range(t + 1)])
        means = np.array([batches[j].mean(axis=1) for j in range(t + 1)])
        _, _, mu, n = hist[t]
        np.testing.assert_allclose(n, w.sum(), rtol=1e-12)
        np.testing.assert_allclose(mu, w @ means / w.sum(), atol=1e-12)


def test_sklm_truncates_to_maxbasis_and_drops_null_directions(rng):
    N = 30
    batches = [rng.normal(size=(N, 6)) for _ in range(3)]
    full = _run_sklm(batches, ff=0.95)
    U0, D0, mu0, n0 = full[-2]
    X = batches[-1]
    Uf, Df, _, _ = sklm(X, U0, D0, mu0, n0, 0.95)
    Ut, Dt, _, _ = sklm(X, U0, D0, mu0, n0, 0.95, maxbasis=4)
    assert Ut.shape == (N, 4) and Dt.shape == (4,)
    np.testing.assert_allclose(Dt, Df[:4], rtol=1e-12)
    assert np.max(subspace_angles(Ut, Uf[:, :4])) < 1e-8
    assert np.all(np.diff(Df) <= 0)
    # Exact rank 2 data: the 1e-6 energy cutoff leaves 2 components, whatever maxbasis.
    B = rng.normal(size=(N, 2)) @ rng.normal(size=(2, 5))
    U, D, _, _ = sklm(B, None, None, None, 0, 1.0, maxbasis=10)
    assert U.shape == (N, 2)
    U, D, _, _ = sklm(rng.normal(size=(N, 2)) @ rng.normal(size=(2, 5)), U, D, B.mean(axis=1), 5, 1.0, 10)
    assert U.shape[1] <= 4
    # One observation and no model: a mean and no basis.
    U, D, mu, n = sklm(B[:, :1], None, None, None, 0, 1.0)
    assert U.shape == (N, 0) and n == 1
    np.testing.assert_array_equal(mu, B[:, 0])


def test_sklm_rejects_bad_input(rng):
    with pytest.raises(ValueError, match="ff"):
        sklm(rng.normal(size=(5, 3)), None, None, None, 0, ff=1.5)
    with pytest.raises(ValueError, match="non-finite"):
        sklm(np.full((5, 3), np.nan), None, None, None, 0)
    U, D, mu, n = sklm(rng.normal(size=(5, 3)), None, None, None, 0)
    with pytest.raises(ValueError, match="shapes"):
        sklm(rng.normal(size=(6, 3)), U, D, mu, n)


def test_reconstruction_errors_project_out_the_basis(rng):
    N = 50
    basis, _ = np.linalg.qr(rng.normal(size=(N, 4)))
    mean = rng.normal(size=N)
    inside = mean + rng.normal(size=(10, 4)) @ basis.T
    off = rng.normal(size=(10, N))
    np.testing.assert_allclose(reconstruction_errors(inside, mean, basis), 0.0, atol=1e-10)
    r = (off - mean) - (off - mean) @ basis @ basis.T
    np.testing.assert_allclose(reconstruction_errors(off, mean, basis), (r * r).sum(axis=1), rtol=1e-10)
    np.testing.assert_allclose(
        reconstruction_errors(off, mean, np.zeros((N, 0))), ((off - mean) ** 2).sum(axis=1), rtol=1e-12
    )


def test_update_model_wraps_sklm(rng):
    m = AppearanceModel.from_template(rng.random((32, 32)))
    assert m.basis.shape == (1024, 0) and m.n_eff == 0
    m = update_model(m, rng.random((5, 32, 32)), ff=0.95, maxbasis=16)
    assert m.basis.shape == (1024, 4) and m.n_eff == 5


def test_resample_indices_follow_the_weights(rng):
    lw = np.log(np.array([0.5, 0.0, 0.3, 0.2]) + 1e-300)
    assert resample_indices(lw, rng).shape == (4,)
    # 4000 particles in 4 groups of 1000 equal weights: the groups are drawn in proportion.
    idx = resample_indices(np.repeat(lw, 1000), rng)
    freq = np.bincount(idx // 1000, minlength=4) / 4000
    np.testing.assert_allclose(freq, [0.5, 0.0, 0.3, 0.2], atol=0.025)
    assert freq[1] == 0


# --------------------------------------------------------------------------- #
# configuration
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    "kwargs",
    [
        {"n_particles": 0},
        {"n_particles": 10.5},
        {"condenssig": 0.0},
        {"condenssig": float("nan")},
        {"ff": 0.0},
        {"ff": 1.2},
        {"batchsize": 0},
        {"maxbasis": -1},
        {"affsig": (1, 2, 3)},
        {"affsig": (4, 4, 0.01, 0, -0.005, 0)},
        {"affsig": "four"},
        {"patch_size": 1},
        {"grid": "matlab"},
    ],
)
def test_bad_config_raises(kwargs):
    with pytest.raises(ValueError, match="IPCAConfig"):
        IPCAConfig(**kwargs)


def test_config_defaults_and_dict():
    cfg = IPCAConfig()
    assert (cfg.n_particles, cfg.condenssig, cfg.ff, cfg.batchsize, cfg.maxbasis, cfg.patch_size) == (
        600,
        0.75,
        0.95,
        5,
        16,
        32,
    )
    assert cfg.affsig == (4.0, 4.0, 0.01, 0.0, 0.005, 0.0)
    assert cfg.grid == "reference"
    d = json.loads(json.dumps(IPCATracker(cfg).config_dict()))
    assert IPCAConfig(**d) == cfg


def test_update_before_init_raises():
    with pytest.raises(RuntimeError, match="init"):
        IPCATracker().update(np.zeros((40, 40, 3), np.uint8))


# --------------------------------------------------------------------------- #
# the tracker
# --------------------------------------------------------------------------- #
@pytest.fixture(scope="module")
def synthetic():
    return SyntheticSequence(SyntheticConfig(n_frames=60))


@pytest.fixture(scope="module")
def synthetic_runs(synthetic):
    return {seed: run(IPCATracker(rng=seed), synthetic, seed=seed) for seed in (0, 1)}


def test_tracker_stays_on_the_synthetic_target(synthetic, synthetic_runs):
    # The target travels ~100 px and turns by up to 20 degrees in 60 frames: a box that stands still
    # keeps 0.10 mean IoU. IVT (which does not sample rotation at the default affsig) keeps its
    # axis-aligned box on the target: 0.80-0.87 mean IoU over seeds 0-5 with the reference grid (whose
    # 1-2 px offset costs a little against this exact ground truth), 0.84-0.88 with the centred one.
    still = evaluate(run(IdentityTracker(), synthetic).boxes, synthetic.groundtruth)
    for res in synthetic_runs.values():
        m = evaluate(res.boxes, res.groundtruth)
        assert m.mean_iou > 0.75
        assert m.mean_iou > still.mean_iou + 0.4
        assert m.precision_20 == 1.0


def test_tracker_is_deterministic_given_a_seed(synthetic, synthetic_runs):
    again = run(IPCATracker(rng=0), synthetic, seed=0)
    np.testing.assert_array_equal(again.boxes, synthetic_runs[0].boxes)
    assert not np.array_equal(synthetic_runs[0].boxes, synthetic_runs[1].boxes)
    # A Generator works as well as a seed, and global numpy randomness is left alone.
    np.random.seed(3)
    before = np.random.get_state()[1].copy()
    gen = run(IPCATracker(rng=np.random.default_rng(0)), synthetic, max_frames=10)
    np.testing.assert_array_equal(gen.boxes, synthetic_runs[0].boxes[:10])
    np.testing.assert_array_equal(np.random.get_state()[1], before)


def test_tracker_fills_its_frame_record(synthetic):
    cfg = IPCAConfig(n_particles=50, batchsize=3)
    tr = IPCATracker(cfg, rng=5)
    tr.init(synthetic.frame(0).image, synthetic.init_box)
    rec = tr.last_record
    assert rec.index == 0 and rec.tracker == "ipca"
    np.testing.assert_allclose(rec.pose[2:], [1.0, 0.0])
    np.testing.assert_allclose(rec.box, synthetic.init_box)
    for i in range(1, 8):
        box = tr.update(synthetic.frame(i).image)
        rec = tr.last_record
        n = cfg.n_particles
        assert rec.index == i
        np.testing.assert_array_equal(rec.box, box)
        assert rec.particle_poses.shape == (n, 4) and rec.particle_corners.shape == (n, 4, 2)
        assert rec.corners.shape == (4, 2) and rec.pose.shape == (4,)
        assert abs(logsumexp(rec.log_weights)) < 1e-9
        assert 1.0 <= rec.ess <= n
        assert rec.resampled and rec.resample_indices.shape == (n,)
        assert rec.distances.shape == (n,) and np.all(rec.distances >= 0)
        best = int(np.argmax(rec.log_weights))
        np.testing.assert_allclose(rec.corners, rec.particle_corners[best])
        np.testing.assert_allclose(box, [*rec.corners.min(0), *np.ptp(rec.corners, axis=0)])
        # weights are exp(-distance^2 / condenssig), normalised
        np.testing.assert_allclose(
            rec.log_weights,
            -(rec.distances**2) / cfg.condenssig - logsumexp(-(rec.distances**2) / cfg.condenssig),
        )
        assert set(rec.timings) >= {"propagate", "warp", "weights", "model_update", "total"}
        assert rec.extras["mean"].shape == (32, 32)
        k = rec.extras["n_basis"]
        assert rec.extras["basis"].shape == (32, 32, k)
    # 8 patches in batches of 3 (the init patch counts): two updates so far. The first leaves
    # 3 - 1 = 2 components (3 centred patches); the second adds the 2 of the new centred batch
    # and 1 for the shift of the mean.
    assert tr.model.n_eff == pytest.approx(3 + cfg.ff * 3)
    assert rec.extras["n_basis"] == 5
    np.testing.assert_allclose(tr.model.basis.T @ tr.model.basis, np.eye(5), atol=1e-10)


@pytest.mark.skipif(not CAR4.is_dir(), reason=f"{CAR4} is absent")
def test_tracker_on_car4_prefix():
    # The first 200 frames of Car4: the car drives away and shrinks (a box that stays put keeps
    # 0.66 mean IoU); IVT follows it, measured 0.92-0.93 mean IoU over seeds 0-2. The full-sequence
    # OTB record is 0.88.
    n = 200
    seq = OTBSequence(CAR4)
    res = run(IPCATracker(rng=0), seq, max_frames=n, seed=0)
    m = evaluate(res.boxes, res.groundtruth)
    still = evaluate(np.repeat(seq.init_box[None], n, axis=0), seq.groundtruth[:n])
    assert m.mean_iou > 0.85
    assert m.mean_iou > still.mean_iou + 0.15
    assert m.precision_20 == 1.0
