"""Adaptive diffusion and re-detection: the filter's search follows its own label-free evidence.

The paper's conclusion leaves open "how should the diffusion speed be adjusted and can
the diffusion process be better constrained". With constant noise the filter searches
as narrowly after the target leaps as when it stands still, and keeps diffusing
templates through an occlusion as through a calm stretch. Here every frame's noise is
set from one number, the *loss evidence* ``e_t ∈ [0, 1]``, computed from what the
filter itself saw on the previous frame (never from ground truth).

Evidence. Let ``b_t = min_i d_eff,i`` be the best particle's likelihood distance on
frame ``t``, and ``R_t`` a window of the last ``window`` values of ``b`` (see below).
With ``m = median(R_t)`` and ``s = 1.4826 · MAD(R_t)`` (a robust standard deviation),

    z_t = (b_t − m) / (s + 1e-3·m)                       (the best distance's robust z-score)
    e_t = clip((z_t − z_lo) / (z_hi − z_lo), 0, 1)        (0: as usual; 1: nothing matches)

the same score as the drift detector's ``dmin_z`` signal. The window takes
``min(b_t, m + z_hi·s)``: a frame no particle explains enters it only at the edge of
the usual range, so an occlusion does not become the norm at once, while a lasting
change of look (a light turned off) lifts the median within about ``window / 2``
frames and the evidence falls back. Before ``warmup`` frames the evidence is 0.

What it drives (frame ``t + 1``, every particle):

* **Jumps.** The probability of the wide mode is ``p₁ + e·(jump_prob − p₁)`` and its
  position and velocity spreads are multiplied by ``1 + e·(jump_spread − 1)``: when the
  likelihood has lost the target the filter searches wider and more often.
* **Template walk.** ``σ_ij ← σ_ij · (1 − e·template_slow)``: when the observation looks
  unlike every template (an occlusion, a drift onto background) the templates stop
  walking towards what is in the box, so the target's look is kept for its return.
* **Re-detection.** When ``e ≥ redetect_evidence``, a share ``redetect_fraction·e`` of
  the particles is drawn afresh, uniformly in a disc of radius
  ``redetect_radius · (1 + frames lost)^½`` target sizes around the last confidently
  tracked centre (``e = 0``), at its scale (times ``exp(N(0, 0.1²))``), at rest, each
  carrying the template of that frame. The observation model scores them as any
  particle, so the cost of a frame does not change; a target that leapt or came out
  from behind an occluder is found again where the particles' own spread never reaches.

With ``enabled=False`` (``manifold-paper``) nothing here runs and no random number is
drawn: its boxes are those of the constant noise, bit for bit. Enabled, a frame after
one with ``e = 0`` draws exactly what the constant noise draws.

**The observation pull** (:func:`observation_pull`; ``ManifoldConfig.observation_pull``,
0.05 by default, off in ``manifold-paper``). The template walk lets the likelihood choose
among random steps; it never steps *towards* what the tracker sees, so a target whose
look changes steadily (a surfer in spray, a car turning and shrinking) is followed only
as fast as selection among random steps allows. With the pull, on a frame whose evidence
is 0, after resampling, every particle's log-template takes a step of length ``α`` along
the log-Euclidean geodesic towards the observation at the estimate:

    L_i ← L_i + α · (log C_obs − L_i),     C_obs = the descriptor at (x, y, κ·s, θ)

where ``(x, y, s, θ)`` is the estimate's pose and ``κ < 1`` takes the box's inner part:
an observation of the whole box teaches the templates the background at its border once
the box is a little loose, and the box then grows (Car1). The step is skipped where the
look has changed suddenly: ``d_t = ‖log C_obs − L_0‖_F`` (the log-Euclidean distance to
the initial template) has a robust z-score (as above, against its last ``W`` values, once
there are :data:`PULL_WARMUP`) above the gate ``g`` — a shadow or an occluder should not
become the template. The window takes every ``d_t``, so a lasting change is followed
after about ``W/2`` frames.

The descriptor is gain-normalised, so a shadow hardly moves ``d_t`` (through Car4's bridge
shadow that gate held 8 of 46 frames, and the templates learnt the car in the dark). The
*light gate* looks at what gain normalisation hides: ``b_t``, the mean grey level of the
estimate's box (:func:`box_brightness`). The step is also skipped when

    |b_t − median(B_t)| / scale(B_t) > g_b      (the robust z-score above, two-sided)

against ``B_t``, the last ``W`` values of ``b`` on frames whose step this gate let through
(once there are :data:`PULL_WARMUP`). A held value does not enter ``B_t``: the templates
keep the look from before the light changed for as long as it stays changed, and the
tracker is then the one without the pull (Car4's shadow exit: 17 losses over fifteen
seeds without the gate, 0 with it; docs/tuning.md). No random number is drawn: with
``α = 0`` the tracker is the one without the pull, bit for bit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from covviz.config import ConfigError, Spec, check, from_mapping
from covviz.model.dynamics import SCALE, THETA, VX, VY, KinematicModel, X, Y
from covviz.model.stats import median

__all__ = ["ADAPTIVE_SPECS", "PULL_WARMUP", "AdaptState", "AdaptiveDiffusion", "PullState", "adapted_kinematics",
           "box_brightness", "evidence", "observation_pull", "redetect", "robust_z"]


@dataclass(frozen=True)
class AdaptiveDiffusion:
    """Parameters of the adaptive diffusion and re-detection (module docstring: the equations).

    Attributes
    ----------
    enabled : bool
        Off: the paper's constant noise, and nothing below is used.
    window : int
        Frames of the running range of the best distance.
    warmup : int
        Frames before the evidence may rise above 0.
    z_lo, z_hi : float
        The robust z-scores at which the evidence starts to rise and reaches 1.
    jump_prob : float
        The wide mode's probability at full evidence.
    jump_spread : float
        Factor on the wide mode's position and velocity spreads at full evidence.
    template_slow : float
        Fraction of the template walk's σ removed at full evidence (1: frozen).
    redetect_evidence : float
        Evidence from which re-detection particles are drawn (> 1: never).
    redetect_fraction : float
        Share of the particles drawn afresh at full evidence.
    redetect_radius : float
        Radius of the disc they are drawn in, target sizes (grows as ``√(1 + frames lost)``).
    """

    enabled: bool = True
    window: int = 30
    warmup: int = 10
    z_lo: float = 3.0
    z_hi: float = 8.0
    jump_prob: float = 0.4
    jump_spread: float = 2.5
    template_slow: float = 1.0
    redetect_evidence: float = 0.5
    redetect_fraction: float = 0.2
    redetect_radius: float = 2.0

    def __post_init__(self):
        check(self, ADAPTIVE_SPECS)
        if not self.z_lo < self.z_hi:
            raise ConfigError(f"AdaptiveDiffusion needs z_lo < z_hi, got {self.z_lo} and {self.z_hi}")

    @classmethod
    def from_dict(cls, d: dict) -> AdaptiveDiffusion:
        """The parameters of a JSON object of its fields (the rest default); unknown keys refused."""
        return from_mapping(cls, d, ADAPTIVE_SPECS)


#: Each field of :class:`AdaptiveDiffusion`: its type and range (:mod:`covviz.config`).
ADAPTIVE_SPECS: dict[str, Spec] = {
    "enabled": Spec("bool"),
    "window": Spec("int", 3, 10_000),
    "warmup": Spec("int", 0),
    "z_lo": Spec("float"),
    "z_hi": Spec("float"),
    "jump_prob": Spec("float", 0, 1),
    "jump_spread": Spec("float", 1),
    "template_slow": Spec("float", 0, 1),
    "redetect_evidence": Spec("float", 0),
    "redetect_fraction": Spec("float", 0, 1),
    "redetect_radius": Spec("float", 0),
}


@dataclass(frozen=True, slots=True, eq=False)
class AdaptState:
    """The online state of the adaptive diffusion (part of the tracker's snapshot).

    Attributes
    ----------
    window : tuple of float
        The running range of the best distance (clipped values, oldest first).
    evidence : float
        ``e`` of the last frame: what the next frame's noise follows.
    z : float
        The last frame's robust z-score (nan during the warm-up).
    frames : int
        Frames seen.
    lost : int
        Frames since the evidence was last 0.
    good_pose : ndarray, shape (4,)
        ``cx, cy, scale, theta`` of the last frame with evidence 0.
    good_template : ndarray, shape (9, 9)
        The estimate's log-space template on that frame (read-only).
    """

    window: tuple
    evidence: float
    z: float
    frames: int
    lost: int
    good_pose: np.ndarray
    good_template: np.ndarray

    @staticmethod
    def start(pose: np.ndarray, template: np.ndarray) -> AdaptState:
        return AdaptState((), 0.0, float("nan"), 0, 0, _ro(pose), _ro(template))


def _ro(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


def robust_z(x: float, window) -> tuple[float, float, float]:
    """``(z, m, scale)``: ``x``'s robust z-score against ``window`` (module docstring), its median and scale.

    ``scale = 1.4826 · MAD + 10⁻³ · max(|m|, 10⁻³)``; the drift detector's ``dmin_z`` signal is the same score.
    """
    win = np.asarray(window, dtype=np.float64)
    m = float(median(win))
    s = 1.4826 * float(median(np.abs(win - m)))
    scale = s + 1e-3 * max(abs(m), 1e-3)
    return (x - m) / scale, m, scale


#: Values of the observation pull's window before its gate acts.
PULL_WARMUP = 10


@dataclass(frozen=True, slots=True, eq=False)
class PullState:
    """The observation pull's memory (part of the tracker's snapshot), oldest first (module docstring):
    ``window``, the last distances ``d_t`` of the observation to the initial template; ``light``, the last
    brightnesses ``b_t`` the light gate let through; ``held``, what held the last step (``""``: nothing,
    ``"look"``, ``"light"`` or ``"look+light"``)."""

    window: tuple = ()
    light: tuple = ()
    held: str = ""


def box_brightness(gray: np.ndarray, box, step: float = 1.0) -> float:
    """``b_t`` of the light gate: the mean grey level of ``box`` (x, y, w, h in frame pixels) in ``gray``.

    ``gray`` is the observation model's frame, downsampled ``step`` times (the box is divided by
    ``max(step, 1)``); the box's corners are truncated to whole pixels and clipped to the frame.
    NaN when nothing of the box is inside, or the box is not finite.
    """
    b = np.asarray(box, dtype=np.float64) / max(float(step), 1.0)
    if not np.all(np.isfinite(b)):
        return float("nan")
    x0, y0 = max(int(b[0]), 0), max(int(b[1]), 0)
    x1, y1 = min(int(b[0] + b[2]) + 1, gray.shape[1]), min(int(b[1] + b[3]) + 1, gray.shape[0])
    if x1 <= x0 or y1 <= y0:
        return float("nan")
    return float(gray[y0:y1, x0:x1].mean())


def observation_pull(templates: np.ndarray, observed_log: np.ndarray, initial_log: np.ndarray, state: PullState,
                     rate: float, gate: float, window: int, brightness: float = float("nan"),
                     light_gate: float = 0.0) -> tuple[np.ndarray | None, PullState]:
    """One frame of the observation pull (module docstring): the stepped templates, or None where a gate
    holds them, and the next state.

    Parameters
    ----------
    templates : ndarray, shape (n, d, d)
        The particles' log-templates after resampling.
    observed_log : ndarray, shape (d, d)
        ``log C_obs``, the observation at the estimate's inner region.
    initial_log : ndarray, shape (d, d)
        ``L_0``, the initial template.
    state : PullState
    rate, gate : float
        ``α`` and ``g`` (``g = 0``: no gate).
    window : int
        ``W`` (of both gates' windows).
    brightness : float
        ``b_t`` (:func:`box_brightness`); NaN: the light gate neither holds nor remembers this frame.
    light_gate : float
        ``g_b`` (0: no light gate).
    """
    d = float(np.linalg.norm(observed_log - initial_log))
    held = False
    if gate > 0 and len(state.window) >= PULL_WARMUP:
        z, _, _ = robust_z(d, state.window)
        held = z > gate
    dark = False
    if light_gate > 0 and len(state.light) >= PULL_WARMUP and np.isfinite(brightness):
        zb, _, _ = robust_z(brightness, state.light)
        dark = abs(zb) > light_gate
    light = (*state.light, float(brightness))[-window:] if (np.isfinite(brightness) and not dark) else state.light
    nxt = PullState((*state.window, d)[-window:], light, "+".join(k for k, v in (("look", held), ("light", dark)) if v))
    if held or dark:
        return None, nxt
    return templates + rate * (observed_log - templates), nxt


def evidence(state: AdaptState, best: float, pose, template, cfg: AdaptiveDiffusion) -> AdaptState:
    """The state after a frame whose best likelihood distance was ``best`` and estimate ``pose`` / ``template``."""
    z, e, clipped = float("nan"), 0.0, best
    if len(state.window) >= 3:
        z, m, scale = robust_z(best, state.window)
        clipped = min(best, m + cfg.z_hi * scale)
        if state.frames >= cfg.warmup:
            e = float(np.clip((z - cfg.z_lo) / (cfg.z_hi - cfg.z_lo), 0.0, 1.0))
    window = (*state.window, float(clipped))[-cfg.window:]
    if e == 0.0:
        return AdaptState(window, e, z, state.frames + 1, 0, _ro(pose), _ro(template))
    return AdaptState(window, e, z, state.frames + 1, state.lost + 1, state.good_pose, state.good_template)


def adapted_kinematics(km: KinematicModel, e: float, cfg: AdaptiveDiffusion) -> KinematicModel:
    """The kinematic model of a frame after one of evidence ``e`` (``km`` itself at ``e = 0``)."""
    if e <= 0.0:
        return km
    p1 = km.mode_probs[1] + e * (max(cfg.jump_prob, km.mode_probs[1]) - km.mode_probs[1])
    f = 1.0 + e * (cfg.jump_spread - 1.0)
    return dataclasses.replace(
        km,
        mode_probs=(1.0 - p1, p1),
        pos_sigma=(km.pos_sigma[0], km.pos_sigma[1] * f),
        vel_sigma=(km.vel_sigma[0], km.vel_sigma[1] * f),
    )


def redetect(states, templates, modes, state: AdaptState, cfg: AdaptiveDiffusion, base_size: float,
             km: KinematicModel, rng):
    """Re-detection: a share of the particles drawn afresh around the last confident pose (new arrays).

    Returns ``states, templates, modes`` with the drawn particles' mode set to 3, or the inputs
    unchanged when the evidence is below ``redetect_evidence``.
    """
    e = state.evidence
    n = len(states)
    k = round(cfg.redetect_fraction * e * n)
    if e < cfg.redetect_evidence or k == 0:
        return states, templates, modes
    idx = rng.choice(n, size=k, replace=False)
    gp = state.good_pose
    size = base_size * gp[2]
    radius = cfg.redetect_radius * size * np.sqrt(1.0 + state.lost)
    r = radius * np.sqrt(rng.random(k))
    a = 2 * np.pi * rng.random(k)
    scale = np.clip(gp[2] * np.exp(0.1 * rng.standard_normal(k)), *km.scale_range)
    states = states.copy()
    states[idx, X] = gp[0] + r * np.cos(a)
    states[idx, Y] = gp[1] + r * np.sin(a)
    states[idx, VX] = 0.0
    states[idx, VY] = 0.0
    states[idx, SCALE] = scale
    states[idx, THETA] = gp[3]
    templates = templates.copy()
    templates[idx] = state.good_template
    modes = modes.copy()
    modes[idx] = 3
    return states, templates, modes
