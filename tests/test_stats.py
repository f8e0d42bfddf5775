"""``covviz.model.stats.median``: ``np.median``'s value and type, to the last bit, on what the per-frame code feeds it."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from covviz.model.stats import median


def _np_median(x):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # np.median of an empty array warns
        return np.median(x)


def _same(a, b) -> bool:
    """Equal values of the same type, signed zeros told apart, NaN equal to NaN."""
    if type(a) is not type(b):
        return False
    if np.isnan(a):
        return bool(np.isnan(b))
    return bool(a == b and np.signbit(a) == np.signbit(b))


def _cases(rng, dtype, n, trial):
    x = rng.normal(size=n)
    if trial % 3 == 1:
        x = np.round(x)  # ties, and zeros of both signs
    if n and trial % 7 == 2:
        x[rng.integers(n)] = np.nan
    if n and trial % 5 == 3:
        x[rng.integers(n)] = np.inf
    if n and trial % 11 == 4:
        x[rng.integers(n)] = -np.inf
    if np.issubdtype(dtype, np.integer):
        return np.nan_to_num(np.round(x * 5), nan=0, posinf=7, neginf=-7).astype(dtype)
    return x.astype(dtype)


@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int64])
def test_median_is_numpys_bit_for_bit(rng, dtype):
    for n in range(40):
        for trial in range(12):
            x = _cases(rng, dtype, n, trial)
            got, want = median(x), _np_median(x)
            assert _same(got, want), (dtype, n, x, got, want)


def test_median_takes_lists_and_deques_and_zeros_of_both_signs():
    from collections import deque

    assert _same(median([3.0, 1.0, 2.0]), np.median([3.0, 1.0, 2.0]))
    assert _same(median(deque([0.5, -2.0, 4.0, 1.0])), np.median([0.5, -2.0, 4.0, 1.0]))
    # np.median's mean starts its sum from +0.0: a median of negative zeros is +0.0, and so is ours
    for x in ([-0.0], [-0.0, -0.0], [-0.0, -0.0, -0.0], [1.0, -0.0, -1.0]):
        assert _same(median(x), _np_median(np.array(x)))
    assert not np.signbit(median([-0.0, -0.0]))


def test_median_of_each_column_is_numpys_axis_0_median(rng):
    """``median_flow``'s per-column medians of the points' displacements (float32 points, float64 medians)."""
    for n in range(1, 40):
        d = rng.normal(size=(n, 2)).astype(np.float32).astype(np.float64)
        if n % 2:
            d = np.round(d)
        want = np.median(d, axis=0)
        got = np.array([median(d[:, 0]), median(d[:, 1])])
        assert all(_same(a, b) for a, b in zip(got, want))
