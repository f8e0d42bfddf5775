"""Tests for :mod:`covviz.model.particles`: log-weights, ESS, resampling, the particle set.

Resampling is checked for what a particle filter needs: indices in range,
unbiased counts (mean count of particle ``i`` is ``n·w_i``, within 5 standard
errors over many draws), systematic counts within ``floor/ceil(n·w_i)``, and
determinism given the seed.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp

from covviz.model.particles import (
    ParticleSet,
    effective_sample_size,
    log_likelihood,
    mmse,
    multinomial_resample,
    normalize_log_weights,
    systematic_resample,
)
from covviz.model.particles import (
    logsumexp as cv_logsumexp,
)

Z = 5.0  # tolerance in standard errors
RESAMPLERS = [systematic_resample, multinomial_resample]


def make_set(rng, n=6, d=3):
    A = rng.standard_normal((n, d, d))
    return ParticleSet(
        states=rng.standard_normal((n, 6)),
        templates=A + np.swapaxes(A, 1, 2),
        log_weights=normalize_log_weights(rng.standard_normal(n)),
    )


# --------------------------------------------------------------------------- #
# normalisation
# --------------------------------------------------------------------------- #
@given(
    st.lists(st.floats(-1e300, 1e300, allow_nan=False) | st.just(-np.inf), min_size=1, max_size=50)
)
@settings(max_examples=200, deadline=None)
def test_logsumexp_matches_scipy(values):
    x = np.array(values)
    ours, ref = cv_logsumexp(x), float(logsumexp(x))
    if np.isneginf(ref):
        assert np.isneginf(ours)
    else:
        assert ours == pytest.approx(ref, rel=1e-13, abs=1e-13)


@pytest.mark.parametrize(
    "x, expected",
    [([], -np.inf), ([-np.inf, -np.inf], -np.inf), ([0.0, np.inf], np.inf), ([0.0, np.nan], np.nan), ([1000.0, 1000.0], 1000.0 + np.log(2))],
)
def test_logsumexp_edge_cases(x, expected):
    out = cv_logsumexp(np.array(x))
    if np.isnan(expected):
        assert np.isnan(out)
    else:
        assert out == pytest.approx(expected)


def test_normalize_gives_logsumexp_zero(rng):
    lw = rng.normal(0, 30, 100)
    out = normalize_log_weights(lw)
    assert logsumexp(out) == pytest.approx(0.0, abs=1e-12)
    # Only a shift: differences preserved.
    np.testing.assert_allclose(np.diff(out), np.diff(lw), atol=1e-9)


@pytest.mark.parametrize("offset", [-1e6, -1e10, 1e6, 0.0])
def test_normalize_huge_magnitudes_do_not_underflow(offset):
    lw = np.array([0.0, -1.0, -2.0]) + offset
    w = np.exp(normalize_log_weights(lw))
    expected = np.exp([0.0, -1.0, -2.0]) / np.exp([0.0, -1.0, -2.0]).sum()
    # The inputs themselves carry float64 rounding of ~1e-16·|offset|: nothing more is lost.
    np.testing.assert_allclose(w, expected, rtol=1e-12 + 1e-15 * abs(offset))


def test_normalize_handles_minus_inf_and_nan():
    out = normalize_log_weights([-np.inf, np.log(0.25), np.nan, np.log(0.75)])
    np.testing.assert_allclose(np.exp(out), [0.0, 0.25, 0.0, 0.75], atol=1e-15)
    # Every weight impossible: fall back to uniform rather than NaN.
    for bad in ([-np.inf] * 4, [np.nan] * 4, [np.nan, -np.inf, np.nan, -np.inf]):
        np.testing.assert_allclose(normalize_log_weights(bad), np.full(4, -np.log(4)))


def test_normalize_does_not_modify_input():
    lw = np.array([1.0, np.nan, -np.inf, 3.0])
    lw.setflags(write=False)
    normalize_log_weights(lw)
    assert np.isnan(lw[1]) and lw[0] == 1.0


# --------------------------------------------------------------------------- #
# effective sample size
# --------------------------------------------------------------------------- #
def test_ess_one_hot_and_uniform():
    assert effective_sample_size(normalize_log_weights([0.0, -np.inf, -np.inf, -np.inf])) == pytest.approx(1.0)
    for n in (1, 7, 1000):
        assert effective_sample_size(np.full(n, -np.log(n))) == pytest.approx(n, rel=1e-12)


def test_ess_hand_computed():
    w = np.array([0.5, 0.25, 0.25])
    assert effective_sample_size(np.log(w)) == pytest.approx(1 / (0.25 + 0.0625 + 0.0625))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6) | st.just(-np.inf), min_size=1, max_size=50))
def test_ess_is_between_one_and_n(lw):
    ess = effective_sample_size(normalize_log_weights(np.array(lw)))
    assert 1.0 - 1e-9 <= ess <= len(lw) * (1 + 1e-9)


# --------------------------------------------------------------------------- #
# resampling
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("resample", RESAMPLERS)
def test_resample_indices_in_range_sorted_and_int(rng, resample):
    lw = normalize_log_weights(rng.normal(0, 2, 50))
    idx = resample(lw, rng)
    assert idx.shape == (50,) and np.issubdtype(idx.dtype, np.integer)
    assert idx.min() >= 0 and idx.max() < 50
    assert np.all(np.diff(idx) >= 0)


@pytest.mark.parametrize("resample", RESAMPLERS)
def test_resample_never_picks_zero_weight(rng, resample):
    lw = normalize_log_weights([-np.inf, 0.0, -np.inf, 0.5, -np.inf, -np.inf])
    for _ in range(200):
        assert set(resample(lw, rng)) <= {1, 3}


@pytest.mark.parametrize("resample", RESAMPLERS)
def test_resample_one_hot_picks_that_particle(rng, resample):
    lw = normalize_log_weights([-np.inf, -np.inf, 0.0, -np.inf])
    np.testing.assert_array_equal(resample(lw, rng), [2, 2, 2, 2])


def _counts(idx, n):
    return np.bincount(idx, minlength=n)


def test_systematic_counts_within_floor_and_ceil(rng):
    for _ in range(300):
        n = int(rng.integers(2, 40))
        w = rng.dirichlet(np.full(n, 0.5))
        lw = np.log(w)
        c = _counts(systematic_resample(lw, rng), n)
        assert c.sum() == n
        assert np.all(c >= np.floor(n * w) - 1e-9) and np.all(c <= np.ceil(n * w) + 1e-9), (n * w, c)


@pytest.mark.parametrize("resample", RESAMPLERS)
def test_resampling_is_unbiased(rng, resample):
    n, reps = 8, 4000
    w = np.array([0.31, 0.005, 0.2, 0.0745, 0.12, 0.0005, 0.25, 0.04])
    lw = np.log(w)
    counts = np.array([_counts(resample(lw, rng), n) for _ in range(reps)])
    mean = counts.mean(axis=0)
    if resample is multinomial_resample:
        se = np.sqrt(n * w * (1 - w) / reps)  # binomial count variance
    else:
        se = np.full(n, 0.5 / np.sqrt(reps))  # a count in {floor, ceil}: variance <= 1/4
    assert np.all(np.abs(mean - n * w) <= Z * se + 1e-12), (mean, n * w)


@pytest.mark.parametrize("resample", RESAMPLERS)
def test_resample_deterministic_given_seed(rng, resample):
    lw = normalize_log_weights(rng.normal(0, 1, 100))
    a = resample(lw, np.random.default_rng(11))
    b = resample(lw, np.random.default_rng(11))
    c = resample(lw, 11)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    draws = {tuple(resample(lw, np.random.default_rng(s))) for s in range(10)}
    assert len(draws) > 1


def test_resample_accepts_unnormalised_log_weights(rng):
    lw = rng.normal(0, 1, 30)
    np.testing.assert_array_equal(
        systematic_resample(lw - 1e6, np.random.default_rng(1)),
        systematic_resample(normalize_log_weights(lw), np.random.default_rng(1)),
    )


# --------------------------------------------------------------------------- #
# the particle set
# --------------------------------------------------------------------------- #
def test_particle_set_take_applies_indices_to_every_array(rng):
    ps = make_set(rng)
    idx = np.array([0, 0, 2, 5, 5, 5])
    new = ps.take(idx)
    np.testing.assert_array_equal(new.states, ps.states[idx])
    np.testing.assert_array_equal(new.templates, ps.templates[idx])
    np.testing.assert_allclose(new.log_weights, np.full(6, -np.log(6)))
    assert len(new) == 6 and new is not ps


def test_particle_set_take_leaves_original_untouched(rng):
    ps = make_set(rng)
    states, templates, lw = ps.states.copy(), ps.templates.copy(), ps.log_weights.copy()
    new = ps.take(np.array([1, 1, 1, 1, 1, 1]))
    new.states[0, 0] = 1e9  # fancy indexing made copies
    np.testing.assert_array_equal(ps.states, states)
    np.testing.assert_array_equal(ps.templates, templates)
    np.testing.assert_array_equal(ps.log_weights, lw)


def test_particle_set_can_change_size(rng):
    ps = make_set(rng, n=6)
    small = ps.take(np.array([3, 4]))
    assert len(small) == 2
    np.testing.assert_allclose(small.log_weights, np.log([0.5, 0.5]))


def test_particle_set_is_frozen(rng):
    ps = make_set(rng)
    with pytest.raises(dataclasses.FrozenInstanceError):
        ps.states = np.zeros((6, 6))  # type: ignore[misc]


@pytest.mark.parametrize(
    "states, templates, lw",
    [
        (np.zeros((5, 6)), np.zeros((4, 3, 3)), np.zeros(5)),
        (np.zeros((5, 6)), np.zeros((5, 3, 3)), np.zeros(4)),
        (np.zeros((5, 4)), np.zeros((5, 3, 3)), np.zeros(5)),
        (np.zeros((5, 6)), np.zeros((5, 3, 3)), np.zeros((5, 1))),
    ],
)
def test_particle_set_rejects_inconsistent_arrays(states, templates, lw):
    with pytest.raises(ValueError, match="inconsistent"):
        ParticleSet(states, templates, lw)


# --------------------------------------------------------------------------- #
# estimate and likelihood
# --------------------------------------------------------------------------- #
def test_mmse_is_weighted_mean(rng):
    v = rng.standard_normal((5, 6))
    w = np.array([0.1, 0.2, 0.3, 0.15, 0.25])
    np.testing.assert_allclose(mmse(v, np.log(w)), w @ v, atol=1e-12)
    # Unnormalised log weights give the same estimate.
    np.testing.assert_allclose(mmse(v, np.log(w) + 123.0), w @ v, atol=1e-12)


def test_mmse_of_matrices_and_one_hot(rng):
    T = rng.standard_normal((4, 3, 3))
    lw = normalize_log_weights([-np.inf, 0.0, -np.inf, -np.inf])
    np.testing.assert_allclose(mmse(T, lw), T[1], atol=1e-15)
    est = mmse(T, np.full(4, -np.log(4)))
    assert est.shape == (3, 3)
    np.testing.assert_allclose(est, T.mean(axis=0), atol=1e-12)


def test_log_likelihood_values():
    d = np.array([0.0, 0.3, 1.0, 2.0])
    sigma = 0.5
    np.testing.assert_allclose(log_likelihood(d, sigma), -(d**2) / (2 * sigma**2))
    assert log_likelihood(np.array([0.0]), 0.1)[0] == 0.0
    # Monotone decreasing in the distance, and weights from it normalise to the Gaussian kernel.
    ll = log_likelihood(np.linspace(0, 3, 20), 0.7)
    assert np.all(np.diff(ll) < 0)
    w = np.exp(normalize_log_weights(log_likelihood(d, sigma)))
    k = np.exp(-(d**2) / (2 * sigma**2))
    np.testing.assert_allclose(w, k / k.sum())


def test_log_likelihood_does_not_underflow_for_far_particles():
    ll = log_likelihood(np.array([50.0, 51.0]), 0.1)  # exp(-125000) would be 0
    assert np.all(np.isfinite(ll))
    w = np.exp(normalize_log_weights(ll))
    assert w[0] == pytest.approx(1.0) and 0 <= w[1] < 1e-100


def test_heaviest_are_the_fewest_particles_holding_the_mass():
    from covviz.model.particles import heaviest

    lw = np.log(np.array([0.1, 0.5, 0.05, 0.3, 0.05]))
    assert heaviest(lw, 0.85).tolist() == [1, 3, 0]  # 0.5 + 0.3 fall short of 0.85, + 0.1 reach it
    assert heaviest(lw, 0.5).tolist() == [1] and len(heaviest(lw, 1.0)) == 5
