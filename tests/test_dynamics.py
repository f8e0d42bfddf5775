"""Tests for :mod:`covviz.model.dynamics`: the kinematic model and the template random walk.

Statistical tests use many draws and a tolerance of 5 standard deviations of
the estimator (binomial for frequencies, ``σ/√(2n)`` for a sample standard
deviation of Gaussian draws), so they fail by chance about once in 10⁶ runs,
and they use a fixed seed anyway.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from covviz.model.dynamics import KinematicModel, propagate_kinematics, symmetric_noise, template_walk

X, Y, VX, VY, SCALE, THETA = range(6)
Z = 5.0  # tolerance in standard deviations of the estimator

# A model with distinct, explicit numbers (the defaults are being tuned elsewhere).
MODEL = KinematicModel(
    mode_probs=(0.7, 0.3),
    pos_sigma=(0.05, 0.30),
    vel_sigma=(0.02, 0.15),
    scale_sigma=(0.01, 0.08),
    rot_sigma=(0.02, 0.10),
    velocity_decay=1.0,
    scale_range=(1e-3, 1e3),
    max_rotation=100.0,
)
ZERO_NOISE = dataclasses.replace(
    MODEL, pos_sigma=(0, 0), vel_sigma=(0, 0), scale_sigma=(0, 0), rot_sigma=(0, 0)
)


def random_states(rng, n):
    return np.column_stack(
        [
            rng.uniform(0, 300, n),
            rng.uniform(0, 200, n),
            rng.normal(0, 3, n),
            rng.normal(0, 3, n),
            rng.uniform(0.5, 2, n),
            rng.uniform(-0.5, 0.5, n),
        ]
    )


def sd_tolerance(n: int) -> float:
    """Z standard deviations of a sample std's relative error, ``1/√(2n)``."""
    return Z / np.sqrt(2 * n)


# --------------------------------------------------------------------------- #
# kinematics
# --------------------------------------------------------------------------- #
def test_propagate_does_not_mutate_input(rng):
    s = random_states(rng, 100)
    s.setflags(write=False)
    before = s.copy()
    out, modes = propagate_kinematics(s, MODEL, 20.0, rng)
    np.testing.assert_array_equal(s, before)
    assert out.shape == (100, 6) and modes.shape == (100,)
    assert not np.shares_memory(out, s)


def test_zero_noise_is_constant_velocity_map(rng):
    s = random_states(rng, 50)
    out, _ = propagate_kinematics(s, ZERO_NOISE, 20.0, rng)
    # velocity_decay = 1: x += vx, y += vy, everything else unchanged.
    A = np.eye(6)
    A[X, VX] = A[Y, VY] = 1.0
    np.testing.assert_allclose(out, s @ A.T, atol=1e-12)


def test_zero_noise_with_velocity_decay(rng):
    """The velocity decays by ``velocity_decay`` and the position moves by the decayed velocity.

    That is ``A = [[1, d], [0, d]]`` per axis: ``v_t = d·v_{t-1}``, ``x_t = x_{t-1} + v_t``.
    """
    d = 0.6
    model = dataclasses.replace(ZERO_NOISE, velocity_decay=d)
    s = random_states(rng, 50)
    out, _ = propagate_kinematics(s, model, 20.0, rng)
    np.testing.assert_allclose(out[:, [VX, VY]], d * s[:, [VX, VY]], atol=1e-12)
    np.testing.assert_allclose(out[:, [X, Y]], s[:, [X, Y]] + out[:, [VX, VY]], atol=1e-12)
    np.testing.assert_array_equal(out[:, [SCALE, THETA]], s[:, [SCALE, THETA]])
    # Iterating with d = 0 stops the target after one step.
    still = dataclasses.replace(ZERO_NOISE, velocity_decay=0.0)
    out0, _ = propagate_kinematics(s, still, 20.0, rng)
    np.testing.assert_array_equal(out0[:, [X, Y]], s[:, [X, Y]])


def test_mode_frequencies_match_mode_probs(rng):
    n = 40_000
    s = np.tile([100.0, 100.0, 0, 0, 1.0, 0], (n, 1))
    for probs in [(0.7, 0.3), (0.9, 0.1), (1.0, 0.0)]:
        model = dataclasses.replace(MODEL, mode_probs=probs)
        _, modes = propagate_kinematics(s, model, 20.0, rng)
        assert set(np.unique(modes)) <= {0, 1}
        p1 = probs[1]
        sd = np.sqrt(n * p1 * (1 - p1))
        assert abs(int(modes.sum()) - n * p1) <= Z * sd + 1e-9


def test_noise_std_per_mode_in_size_units(rng):
    """Each mode's noise has the configured std, in units of ``base_size · scale`` (pixels)."""
    n = 60_000
    base_size, scale = 10.0, 2.0
    size = base_size * scale
    s = np.tile([100.0, 80.0, 0.0, 0.0, scale, 0.0], (n, 1))
    out, modes = propagate_kinematics(s, MODEL, base_size, rng)
    vel = out[:, VX]
    pos_only = out[:, X] - s[:, X] - out[:, VX]  # x_t - x_{t-1} - v_t: the position noise alone
    log_scale = np.log(out[:, SCALE] / scale)
    dtheta = out[:, THETA] - s[:, THETA]
    for m in (0, 1):
        sel = modes == m
        k = int(sel.sum())
        tol = sd_tolerance(k)
        checks = {
            "vel": (vel[sel], MODEL.vel_sigma[m] * size),
            "vy": (out[sel, VY], MODEL.vel_sigma[m] * size),
            "pos": (pos_only[sel], MODEL.pos_sigma[m] * size),
            "pos_y": (out[sel, Y] - s[sel, Y] - out[sel, VY], MODEL.pos_sigma[m] * size),
            "log_scale": (log_scale[sel], MODEL.scale_sigma[m]),
            "theta": (dtheta[sel], MODEL.rot_sigma[m]),
        }
        for name, (v, sigma) in checks.items():
            assert np.std(v) == pytest.approx(sigma, rel=tol), f"mode {m} {name}"
            # zero mean: Z standard errors of the mean
            assert abs(np.mean(v)) <= Z * sigma / np.sqrt(k), f"mode {m} {name} mean"


def test_noise_scales_with_each_particles_scale(rng):
    n = 40_000
    model = dataclasses.replace(MODEL, mode_probs=(1.0, 0.0))
    for scale in (0.5, 3.0):
        s = np.tile([0.0, 0.0, 0.0, 0.0, scale, 0.0], (n, 1))
        out, _ = propagate_kinematics(s, model, 8.0, rng)
        assert np.std(out[:, VX]) == pytest.approx(model.vel_sigma[0] * 8.0 * scale, rel=sd_tolerance(n))


def test_scale_is_clipped(rng):
    model = dataclasses.replace(MODEL, scale_range=(0.5, 2.0), scale_sigma=(1.0, 1.0))
    s = np.tile([0, 0, 0, 0, 1.0, 0.0], (5000, 1))
    out, _ = propagate_kinematics(s, model, 10.0, rng)
    assert out[:, SCALE].min() == 0.5 and out[:, SCALE].max() == 2.0
    # Starting outside the range is brought back into it.
    s[:, SCALE] = 10.0
    out, _ = propagate_kinematics(s, dataclasses.replace(model, scale_sigma=(0, 0)), 10.0, rng)
    np.testing.assert_array_equal(out[:, SCALE], 2.0)


def test_rotation_is_clipped(rng):
    model = dataclasses.replace(MODEL, rot_sigma=(2.0, 2.0), max_rotation=0.5)
    s = np.tile([0, 0, 0, 0, 1.0, 0.0], (5000, 1))
    out, _ = propagate_kinematics(s, model, 10.0, rng)
    assert out[:, THETA].min() == -0.5 and out[:, THETA].max() == 0.5


def test_propagate_is_deterministic_given_seed(rng):
    s = random_states(rng, 200)
    a = propagate_kinematics(s, MODEL, 15.0, np.random.default_rng(3))
    b = propagate_kinematics(s, MODEL, 15.0, np.random.default_rng(3))
    c = propagate_kinematics(s, MODEL, 15.0, np.random.default_rng(4))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])


# --------------------------------------------------------------------------- #
# model validation
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"mode_probs": (0.5, 0.6)}, "mode_probs"),
        ({"mode_probs": (1.2, -0.2)}, "mode_probs"),
        ({"mode_probs": (0.3, 0.3, 0.4)}, "mode_probs"),
        ({"pos_sigma": (-0.1, 0.2)}, "pos_sigma"),
        ({"vel_sigma": (0.1,)}, "vel_sigma"),
        ({"scale_sigma": (0.1, -1.0)}, "scale_sigma"),
        ({"rot_sigma": (0.1, 0.2, 0.3)}, "rot_sigma"),
        ({"velocity_decay": 1.5}, "velocity_decay"),
        ({"velocity_decay": -0.1}, "velocity_decay"),
        ({"scale_range": (0.0, 2.0)}, "scale_range"),
        ({"scale_range": (1.2, 2.0)}, "scale_range"),
        ({"scale_range": (0.5, 0.9)}, "scale_range"),
    ],
)
def test_kinematic_model_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        KinematicModel(**kwargs)


@pytest.mark.parametrize(
    "kwargs",
    [{"mode_probs": (float("nan"), float("nan"))}, {"pos_sigma": (float("nan"), 0.1)}, {"max_rotation": -1.0}],
)
def test_kinematic_model_rejects_nan_and_negative_rotation(kwargs):
    with pytest.raises(ValueError):
        KinematicModel(**kwargs)


def test_kinematic_model_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        MODEL.velocity_decay = 0.5  # type: ignore[misc]


# --------------------------------------------------------------------------- #
# symmetric noise and the template walk
# --------------------------------------------------------------------------- #
def sigma_matrix(d: int) -> np.ndarray:
    """Distinct symmetric σ_ij, with one zero pair and a zero diagonal entry."""
    i, j = np.meshgrid(np.arange(d), np.arange(d), indexing="ij")
    s = 0.01 * (1 + i + j) + 0.003 * np.abs(i - j)
    s[0, 3] = s[3, 0] = 0.0
    s[2, 2] = 0.0
    return s


def test_symmetric_noise_is_symmetric_with_shape(rng):
    W = symmetric_noise(100, np.full((9, 9), 0.1), rng)
    assert W.shape == (100, 9, 9)
    np.testing.assert_array_equal(W, np.swapaxes(W, 1, 2))


def test_symmetric_noise_per_entry_std_honours_full_sigma(rng):
    d, n = 5, 40_000
    sigma = sigma_matrix(d)
    W = symmetric_noise(n, sigma, rng)
    tol = sd_tolerance(n)
    for i in range(d):
        for j in range(d):
            if sigma[i, j] == 0:
                np.testing.assert_array_equal(W[:, i, j], 0.0)
            else:
                assert np.std(W[:, i, j]) == pytest.approx(sigma[i, j], rel=tol), (i, j)
                assert abs(W[:, i, j].mean()) <= Z * sigma[i, j] / np.sqrt(n)


def test_symmetric_noise_upper_entries_are_independent(rng):
    d, n = 4, 40_000
    W = symmetric_noise(n, np.full((d, d), 0.2), rng)
    iu = np.triu_indices(d)
    R = np.corrcoef(W[:, iu[0], iu[1]].T)
    off = R[~np.eye(len(iu[0]), dtype=bool)]
    # Sample correlations of independent variables: standard error 1/√n.
    assert np.abs(off).max() <= Z / np.sqrt(n)


def test_symmetric_noise_deterministic_given_seed():
    a = symmetric_noise(10, np.full((9, 9), 0.1), 7)
    b = symmetric_noise(10, np.full((9, 9), 0.1), np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)


def test_template_walk_returns_new_array(rng):
    A = rng.standard_normal((20, 9, 9))
    L = A + np.swapaxes(A, 1, 2)
    L.setflags(write=False)
    before = L.copy()
    out = template_walk(L, np.full((9, 9), 0.05), rng)
    np.testing.assert_array_equal(L, before)
    assert out.shape == L.shape and not np.shares_memory(out, L)
    np.testing.assert_allclose(out, np.swapaxes(out, 1, 2), atol=1e-15)
    assert not np.allclose(out, L)


def test_template_walk_with_zero_sigma_is_identity(rng):
    A = rng.standard_normal((5, 9, 9))
    L = A + np.swapaxes(A, 1, 2)
    out = template_walk(L, np.zeros((9, 9)), rng)
    np.testing.assert_array_equal(out, L)
    assert out is not L


def test_template_walk_step_has_configured_std(rng):
    n = 20_000
    L = np.zeros((n, 3, 3))
    sigma = np.array([[0.1, 0.02, 0.05], [0.02, 0.3, 0.0], [0.05, 0.0, 0.01]])
    out = template_walk(L, sigma, rng)
    np.testing.assert_allclose(np.std(out, axis=0), sigma, rtol=sd_tolerance(n), atol=0)
