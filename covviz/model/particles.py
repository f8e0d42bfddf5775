"""Particle-filter steps as pure functions (filterpy's ``monte_carlo`` style).

Weights live in log space and are normalised with ``logsumexp``, so nothing
underflows however peaked the likelihood. Resampling returns *indices*; the
caller applies the same indices to every array of the particle set
(kinematics and templates alike).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "ParticleSet",
    "effective_sample_size",
    "heaviest",
    "log_likelihood",
    "logsumexp",
    "mmse",
    "multinomial_resample",
    "normalize_log_weights",
    "systematic_resample",
]


@dataclass(frozen=True, slots=True, eq=False)
class ParticleSet:
    """The tracker's particle set: arrays that are replaced, never mutated.

    Attributes
    ----------
    states : ndarray, shape (n, 6)
        ``x, y, vx, vy, scale, theta`` per particle.
    templates : ndarray, shape (n, d, d)
        Log-space templates (symmetric).
    log_weights : ndarray, shape (n,)
        Normalised log-weights.
    """

    states: np.ndarray
    templates: np.ndarray
    log_weights: np.ndarray

    def __post_init__(self):
        n = len(self.states)
        if self.states.shape != (n, 6) or len(self.templates) != n or self.log_weights.shape != (n,):
            raise ValueError(
                f"inconsistent particle arrays: states {self.states.shape}, "
                f"templates {self.templates.shape}, log_weights {self.log_weights.shape}"
            )

    def __len__(self) -> int:
        return len(self.states)

    def take(self, idx: np.ndarray) -> ParticleSet:
        """The particles at ``idx`` (with uniform weights): applies a resampling."""
        n = len(idx)
        return ParticleSet(self.states[idx], self.templates[idx], np.full(n, -np.log(n)))


def logsumexp(x: np.ndarray) -> float:
    """``log Σ exp(x_i)`` of a 1-D array, without overflow or underflow.

    The max-shifted sum, as :func:`scipy.special.logsumexp` computes it, without
    its generality: that function's argument handling costs more than the sum
    for the particle filter's few hundred weights.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        return -np.inf
    m = x.max()
    if not np.isfinite(m):  # all -inf (-> -inf), or an inf / nan entry (-> it)
        return float(m) if not np.isnan(x).any() else np.nan
    return float(m + np.log(np.sum(np.exp(x - m))))


def normalize_log_weights(lw: np.ndarray) -> np.ndarray:
    """``lw - logsumexp(lw)``; uniform weights if every entry is ``-inf`` or nan."""
    lw = np.asarray(lw, dtype=np.float64)
    lw = np.where(np.isnan(lw), -np.inf, lw)
    z = logsumexp(lw)
    if not np.isfinite(z):
        return np.full(len(lw), -np.log(len(lw)))
    return lw - z


def effective_sample_size(lw: np.ndarray) -> float:
    """``1 / Σ w_i²`` of normalised log-weights: between 1 and ``n``."""
    return float(np.exp(-logsumexp(2.0 * np.asarray(lw))))


def heaviest(lw: np.ndarray, mass: float) -> np.ndarray:
    """Indices of the fewest particles that hold ``mass`` of the weight, heaviest first (ties by index)."""
    w = np.exp(np.asarray(lw, dtype=np.float64) - np.max(lw))
    order = np.argsort(-w, kind="stable")
    return order[: int(np.searchsorted(np.cumsum(w[order]) / w.sum(), mass)) + 1]


def log_likelihood(d: np.ndarray, sigma: float) -> np.ndarray:
    """The paper's observation model in log space: ``-d² / (2σ²)``."""
    d = np.asarray(d, dtype=np.float64)
    return -(d * d) / (2.0 * sigma * sigma)


def systematic_resample(lw: np.ndarray, rng) -> np.ndarray:
    """Systematic resampling: one uniform offset, ``n`` evenly spaced pointers.

    Returns
    -------
    ndarray, shape (n,), int
        Ancestor indices, sorted.
    """
    rng = np.random.default_rng(rng)
    n = len(lw)
    c = np.cumsum(np.exp(normalize_log_weights(lw)))
    c[-1] = 1.0
    u = (rng.random() + np.arange(n)) / n
    return np.searchsorted(c, u, side="right").clip(0, n - 1)


def multinomial_resample(lw: np.ndarray, rng) -> np.ndarray:
    """Multinomial resampling: ``n`` independent draws by weight (indices, sorted)."""
    rng = np.random.default_rng(rng)
    n = len(lw)
    c = np.cumsum(np.exp(normalize_log_weights(lw)))
    c[-1] = 1.0
    return np.searchsorted(c, np.sort(rng.random(n)), side="right").clip(0, n - 1)


def mmse(values: np.ndarray, lw: np.ndarray) -> np.ndarray:
    """Minimum-mean-square-error estimate ``Σ w_i x_i`` over axis 0."""
    w = np.exp(normalize_log_weights(lw))
    return np.tensordot(w, np.asarray(values, dtype=np.float64), axes=(0, 0))
