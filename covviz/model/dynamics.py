"""The dynamical model of the paper (section 3.1): kinematics and the template walk.

Kinematics. The state of a particle is ``s = [x, y, vx, vy, scale, theta]``
(centre in pixels, velocity in pixels per frame, scale relative to the initial
box, rotation in radians). It moves by a near-constant-velocity linear model
``s_t = A s_{t-1} + u_t``: the velocity is damped by ``velocity_decay`` and
perturbed first, then moves the centre (``v_t = a·v_{t-1} + u_v``,
``x_t = x_{t-1} + v_t + u_x``); scale is updated multiplicatively (``scale *= exp(u)``),
the first-order equivalent of an additive step that can never turn negative.
The noise ``u_t`` comes from two interacting Gaussian modes: every particle,
every frame, draws mode 0 (small, everyday motion) with probability 0.9 or
mode 1 (wide, sudden pose change) with probability 0.1. Positional and velocity
noise are in units of the target's current size ``sqrt(w·h)·scale``, so the
defaults transfer from small to large targets.

Template. Each particle carries its own template in log space, a symmetric
``L`` with ``C = expm(L)``; it walks by ``L_t = L_{t-1} + W``, ``W`` symmetric
with independent entries ``W_ij = W_ji ~ N(0, σ_ij²)`` (the paper's eq. 11).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from covviz.config import ConfigError, Spec, check, from_mapping

__all__ = [
    "POSE",
    "SCALE",
    "THETA",
    "VX",
    "VY",
    "KinematicModel",
    "X",
    "Y",
    "propagate_kinematics",
    "symmetric_noise",
    "template_walk",
]

#: Columns of a particle's state ``[x, y, vx, vy, scale, theta]``.
X, Y, VX, VY, SCALE, THETA = range(6)
#: The columns of the state that make a pose ``cx, cy, scale, theta``.
POSE = [X, Y, SCALE, THETA]


@dataclass(frozen=True)
class KinematicModel:
    """Parameters of the kinematic model; index 0 / 1 of each pair is mode 0 / 1.

    Attributes
    ----------
    mode_probs : (float, float)
        Probability of each noise mode (the paper: 0.9 / 0.1).
    pos_sigma : (float, float)
        Std of the position noise, fraction of the target size per frame.
    vel_sigma : (float, float)
        Std of the velocity noise, fraction of the target size per frame.
    scale_sigma : (float, float)
        Std of the log-scale noise per frame.
    rot_sigma : (float, float)
        Std of the rotation noise, radians per frame.
    velocity_decay : float
        Factor applied to the velocity each frame (1 = constant velocity).
    scale_range : (float, float)
        Scales are clipped to this range.
    max_rotation : float
        Rotations are clipped to ``[-max_rotation, max_rotation]`` radians.
    """

    mode_probs: tuple[float, float] = (0.9, 0.1)
    pos_sigma: tuple[float, float] = (0.04, 0.20)
    vel_sigma: tuple[float, float] = (0.02, 0.10)
    scale_sigma: tuple[float, float] = (0.01, 0.04)
    rot_sigma: tuple[float, float] = (0.01, 0.06)
    velocity_decay: float = 0.9
    scale_range: tuple[float, float] = (0.2, 5.0)
    max_rotation: float = np.pi / 2

    def __post_init__(self):
        check(self, KINEMATIC_SPECS)
        if abs(sum(self.mode_probs) - 1) > 1e-9:
            raise ConfigError(f"KinematicModel.mode_probs must be two probabilities summing to 1, got {self.mode_probs}")
        lo, hi = self.scale_range
        if not 0 < lo < 1 < hi:
            raise ConfigError(f"KinematicModel.scale_range must satisfy 0 < lo < 1 < hi, got {self.scale_range}")

    @classmethod
    def from_dict(cls, d: dict) -> KinematicModel:
        """The model of a JSON object of its fields (the rest default); unknown keys refused."""
        return from_mapping(cls, d, KINEMATIC_SPECS)


#: Each field of :class:`KinematicModel`: its type and range (:mod:`covviz.config`).
KINEMATIC_SPECS: dict[str, Spec] = {
    "mode_probs": Spec("pair", 0, 1),
    "pos_sigma": Spec("pair", 0),
    "vel_sigma": Spec("pair", 0),
    "scale_sigma": Spec("pair", 0),
    "rot_sigma": Spec("pair", 0),
    "velocity_decay": Spec("float", 0, 1),
    "scale_range": Spec("pair", 0, lo_open=True),
    "max_rotation": Spec("float", 0, lo_open=True),
}


def propagate_kinematics(states: np.ndarray, model: KinematicModel, base_size: float, rng):
    """One step of the kinematic model for every particle.

    Parameters
    ----------
    states : ndarray, shape (n, 6)
        ``x, y, vx, vy, scale, theta`` per particle. Not modified.
    model : KinematicModel
    base_size : float
        ``sqrt(w·h)`` of the initial box, pixels.
    rng : numpy.random.Generator or seed

    Returns
    -------
    new_states : ndarray, shape (n, 6)
    modes : ndarray, shape (n,), int8
        The noise mode each particle drew (0 or 1).
    """
    rng = np.random.default_rng(rng)
    s = np.asarray(states, dtype=np.float64)
    n = len(s)
    modes = (rng.random(n) < model.mode_probs[1]).astype(np.int8)
    z = rng.standard_normal((n, 5))
    pick = lambda pair: np.asarray(pair, dtype=np.float64)[modes]
    size = base_size * s[:, SCALE]
    out = np.empty_like(s)
    out[:, VX] = model.velocity_decay * s[:, VX] + pick(model.vel_sigma) * size * z[:, 0]
    out[:, VY] = model.velocity_decay * s[:, VY] + pick(model.vel_sigma) * size * z[:, 1]
    out[:, X] = s[:, X] + out[:, VX] + pick(model.pos_sigma) * size * z[:, 2]
    out[:, Y] = s[:, Y] + out[:, VY] + pick(model.pos_sigma) * size * z[:, 3]
    out[:, SCALE] = np.clip(s[:, SCALE] * np.exp(pick(model.scale_sigma) * z[:, 4]), *model.scale_range)
    rot = rng.standard_normal(n)
    out[:, THETA] = np.clip(s[:, THETA] + pick(model.rot_sigma) * rot, -model.max_rotation, model.max_rotation)
    return out, modes


def symmetric_noise(n: int, sigma, rng) -> np.ndarray:
    """``n`` random symmetric matrices with ``W_ij = W_ji ~ N(0, σ_ij²)``.

    Parameters
    ----------
    n : int
    sigma : ndarray, shape (d, d)
        Symmetric, non-negative standard deviations.
    rng : numpy.random.Generator or seed

    Returns
    -------
    ndarray, shape (n, d, d)
    """
    rng = np.random.default_rng(rng)
    sigma = np.asarray(sigma, dtype=np.float64)
    d = sigma.shape[0]
    iu, full = _upper(d)
    Z = rng.standard_normal((n, len(iu[0]))) * sigma[iu]
    return Z[:, full].reshape(n, d, d)  # each entry from its upper-triangle draw: one gather


@functools.lru_cache(maxsize=8)
def _upper(d: int) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray]:
    """The upper triangle's indices of a ``d x d`` matrix, and for each of its ``d²`` entries (row-major) the
    index of its upper-triangle twin in that list."""
    iu = np.triu_indices(d)
    k = np.empty((d, d), dtype=np.intp)
    k[iu] = np.arange(len(iu[0]))
    k[iu[1], iu[0]] = k[iu]
    for a in (*iu, k):
        a.setflags(write=False)
    return iu, k.ravel()


def template_walk(L: np.ndarray, sigma, rng, anchor: np.ndarray | None = None, pull: float = 0.0) -> np.ndarray:
    """The paper's template random walk in log space: ``L + W`` (a new array).

    With an ``anchor`` (a log-space template, ``(d, d)``) and ``pull > 0``, the
    walk reverts towards it: ``L + pull·(anchor − L) + W`` (an
    Ornstein–Uhlenbeck step in log space), so the templates wander around the
    anchor instead of away from it.
    """
    L = np.asarray(L)
    if anchor is not None and pull > 0:
        L = L + pull * (np.asarray(anchor, dtype=np.float64) - L)
    return L + symmetric_noise(len(L), sigma, rng)
