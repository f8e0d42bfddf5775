"""The paper's tracker: a particle filter over kinematics *and* templates on the SPD manifold.

Each particle carries a pose ``[x, y, vx, vy, scale, theta]`` and its own
template ``C = expm(L)`` (kept in log space). Every frame:

1. **propagate** the kinematics (near-constant velocity, two-mode noise) and the
   templates (random walk ``L += W``), see :mod:`covviz.model.dynamics`;
2. **observe**: warp each particle's region to 32×32, compute the 9 features and
   the covariance descriptor ``C*`` (:mod:`covviz.model.features`, :mod:`covviz.model.descriptor`);
3. **weigh**: ``w ∝ w_prev · exp(-d(C, C*)² / 2σ²)`` with the affine-invariant distance
   (by default ``d²`` also carries a quadrant term, see below);
4. **estimate** the pose by MMSE (the weighted mean);
5. **resample** (systematic) when the effective sample size falls below
   ``resample_threshold · n``.

Quadrants (not in the paper). One covariance of the whole region says what
the region holds but little of where: a box slid down a pedestrian's body, or
grown over a car's surroundings, keeps much the same descriptor, and the
estimate drifts along those directions (on the benchmark, vertical error on
Crossing and Football1 was 3–6× CSRT's while on track). Following Porikli,
Tuzel and Meer (CVPR 2006), each particle is also scored by the four quadrants
of its region against the quadrants observed at the initial box: with ``q_k``
their distances, the weight uses
``d² = d(C, C*)² + quadrant_weight · mean of the three smallest q_k²``
(dropping the worst quadrant keeps a partial occlusion from dominating). The
``q_k`` are ``sqrt(8·J)`` with ``J`` the Jensen–Bregman LogDet divergence
(:func:`covviz.model.spd.jbld`), which equals the affine-invariant distance to
second order and costs Cholesky factorisations instead of eigensolvers. The
paper's per-particle templates are unchanged.

Two more terms, not in the paper, are on by default (measured in
``docs/tuning.md`` and the ablation of ``docs/results.md``):

* **Derivative normalisation** (``grad_normalize``): the derivative
  features are divided by their patch mean. A derivative per patch sample
  depends on how finely the region is sampled, so without it a box kept the
  sampling density of the initial box: shrinking targets kept boxes too
  large (Car1, Car4), growing ones too small (Surfer). The mean ``|grad I|``
  is floored (``grad_floor``) so that a textureless target's noise is not
  magnified to unit scale (VOT15_bag).
* **A foreground/background colour term** (``colour_weight``,
  :mod:`covviz.model.fgbg`): Staple-style colour histograms of the box and a ring
  around it, a separate factor of the likelihood.

Also implemented, measured and left off: a scale/rotation search at the
estimate, quadrant reliabilities with online references, an anchored
template walk, two-stage particles and a context term (their config fields).
:data:`PAPER_LIKELIHOOD` turns everything covviz added off: the paper's
likelihood exactly (the tracker ``manifold-paper``).

Reference: the paper in ``shared/paper.tex``, sections 2–3.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Self

import numpy as np

from covviz.config import ConfigError, Spec, as_plain, check, from_mapping
from covviz.model import fgbg, refine
from covviz.model.adaptive import (
    AdaptiveDiffusion,
    AdaptState,
    PullState,
    adapted_kinematics,
    box_brightness,
    observation_pull,
    redetect,
)
from covviz.model.adaptive import evidence as adapt_evidence
from covviz.model.dynamics import (
    POSE,
    SCALE,
    THETA,
    VX,
    VY,
    KinematicModel,
    X,
    Y,
    propagate_kinematics,
    template_walk,
)
from covviz.model.features import N_FEATURES, pose_corners, pose_to_box
from covviz.model.flow import (
    CAMERA_MIN_RESPONSE,
    CAMERA_MIN_SHIFT,
    camera_frame,
    camera_shift,
    gray8,
    median_flow,
    trusted,
)
from covviz.model.image import check_init_box, to_gray
from covviz.model.observation import (
    OBSERVATION_SPECS,
    ObservationConfig,
    ObservationModel,
    QuadrantState,
    box_to_pose,
    update_quadrant_state,
)
from covviz.model.particles import (
    ParticleSet,
    effective_sample_size,
    heaviest,
    mmse,
    multinomial_resample,
    normalize_log_weights,
    systematic_resample,
)
from covviz.model.spd import logdet, logm
from covviz.records import Diffusion, FrameInputs, FrameRecord, Likelihood, PoseSearch, Pull
from covviz.trackers.base import ESTIMATE_MASS, Intervention

__all__ = ["MANIFOLD_SPECS", "ManifoldConfig", "ManifoldState", "ManifoldTracker"]


@dataclass(frozen=True)
class ManifoldConfig:
    """Every parameter of :class:`ManifoldTracker`, with its default (observation fields in ``observation``).

    How the defaults were chosen (sweeps, seeds, what moved the score) is in
    ``docs/tuning.md``; each field's type and range is in :data:`MANIFOLD_SPECS`.

    Attributes
    ----------
    n_particles : int
        Particles (each with its own template).
    template_sigma : float
        Std of every entry of the symmetric log-space step ``W`` of the template
        walk (``σ_ij``, the same for all ``i, j``), unless ``template_sigma_matrix``
        is given.
    template_sigma_matrix : tuple of tuples, optional
        A full symmetric 9×9 matrix of ``σ_ij``.
    kinematics : KinematicModel
        Kinematic model and its two-mode noise.
    resample_threshold : float
        Resample when ESS < threshold · n (1.0: every frame, as plain SIR).
    resampling : {"systematic", "multinomial"}
    threads : int
        Threads that share the particles' descriptors and distances (2: the
        cores of the machines we target). Results never depend on it.
    colour_rate : float
        Learning rate of the colour histograms (Staple's 0.04).
    quadrant_reliability : float
        Rate of the running mean of each quadrant's mismatch at the estimate;
        > 0 weighs the quadrants by their reliability (the inverse of that
        mean) instead of dropping the worst
        (:class:`~covviz.model.observation.QuadrantState`). 0: drop the worst.
    quadrant_ref_rate : float
        With reliabilities, each quadrant reference takes a log-Euclidean
        step of this size towards the estimate's quadrant when it matches
        well (``q_k² < quadrant_ref_gate · its running mean``). 0: fixed.
    quadrant_ref_gate : float
    anchor_pull : float
        Each frame, every particle's template moves this fraction of the way
        to the anchor before its random step (:func:`covviz.model.dynamics.template_walk`);
        0: the paper's free walk.
    anchor_rate : float
        The anchor (a log-space template: the initial one at first) takes a
        step of this size towards the estimate's template after each frame
        whose match is good (``d² < anchor_gate ·`` its running mean), as
        IVT's mean forgets old observations.
    anchor_gate : float
    refine_fraction : float
        Two-stage particles (coarse to fine): this fraction of the particles
        is not propagated by the dynamics but restarted around the best of
        the others once those are weighed (``_refine``); 0: one stage.
    refine_top : int
        The second stage's parents are drawn among this many best particles.
    refine_noise : float
        The second stage's pose noise, as a fraction of the everyday (mode-0) noise.
    scale_steps : int
        After the MMSE estimate, score ``2·scale_steps + 1`` scales
        ``scale_step**k`` at the estimated centre with the estimate's template
        (:meth:`~covviz.model.observation.ObservationModel.pose_search`), as CSRT
        searches its scale pyramid once the centre is found; 0: no search.
    scale_step : float
        Ratio of neighbouring scales of the search (CSRT: 1.02).
    rotation_steps : int
        Then ``2·rotation_steps`` rotations ``± k·rotation_step`` at the best
        scale; 0: none.
    rotation_step : float
        Radians.
    search_blend : float
        The estimate moves this fraction of the way (in log-scale and angle)
        to the best candidate, interpolated between the grid's steps.
    search_pull : float
        And every particle's scale and angle move by this fraction of the
        estimate's move (1: the whole cloud follows).
    observation : ObservationConfig
        How the tracker observes and weighs (patch size, features, the
        likelihood's σ and terms, the compiled kernels):
        :class:`~covviz.model.observation.ObservationConfig`. Its fields may
        also be given flat in :meth:`from_dict` and :meth:`replace`
        (``{"quadrants": false}``).
    adaptive : AdaptiveDiffusion
        The jump noise, the template walk's σ and re-detection following the
        filter's own loss evidence (:mod:`covviz.model.adaptive`); off in
        ``manifold-paper``.
    flow_share : float
        A motion prior from the image: each frame, this share of the particles
        (drawn at random) takes as its velocity the median Lucas–Kanade flow of
        the last estimate's box from the previous frame to this one
        (:func:`covviz.model.flow.median_flow`, forward–backward checked, used
        only when :func:`covviz.model.flow.trusted`), before the kinematic
        step; the others keep their own. 0: off (the default, and always in
        ``manifold-paper``; docs/tuning.md has why it is not on yet).
    camera_share : float
        A proposal for a moving camera: on a frame where the whole scene
        shifts (phase correlation of the downscaled frames,
        :func:`covviz.model.flow.camera_shift`, trusted at a peak response of
        at least :data:`~covviz.model.flow.CAMERA_MIN_RESPONSE`, and a shift of
        at least :data:`~covviz.model.flow.CAMERA_MIN_SHIFT` of the last box's
        size), this share of the particles, drawn at random, is moved by that
        shift before the kinematic step, their velocities kept: a camera that
        jumps takes the target with it. Other frames draw nothing, so a still
        camera's run is the one without it, bit for bit. 0: off (the default,
        and always in ``manifold-paper``). 0.5 keeps Couple's camera jumps
        (its losses over 15 seeds 24 → 0) and changes no other dev sequence's
        mean measurably; docs/tuning.md has why it is not the default.
    ncc_rate : float
        A position-sensitive last step for the reported box
        (:mod:`covviz.model.refine`): its centre moves to where the target's
        grey template correlates best within a quarter of a box size, and the
        template takes this step towards the look there. The filter itself
        (particles, templates, the colour model, the evidence) goes on from its
        own estimate, so the step cannot lead it astray. 0: off (always in
        ``manifold-paper``); the default 0.02 was chosen on half the dev set
        and confirmed on the other half and on fresh seeds (docs/tuning.md).
    observation_pull : float
        ``α`` of the observation pull (:mod:`covviz.model.adaptive`, "the observation pull"):
        on a frame without loss evidence, every particle's log-template steps this far along
        the log-Euclidean geodesic towards the observation at the estimate's inner region,
        unless that observation's look or its light changed suddenly. 0: off (always in
        ``manifold-paper``). The default 0.05, with its light gate, scored +0.032 [+0.014, +0.052]
        over the tracker without it on the dev set's thirty seeds, fifteen of them fresh
        (docs/tuning.md, "a light gate for the observation pull").
    observation_pull_scale : float
        ``κ``: the observation is taken at the estimate's scale times this (its inner part).
    observation_pull_gate : float
        ``g``: no step when the observation's distance to the initial template has a robust
        z-score above this; 0: no gate.
    observation_pull_window : int
        ``W``: the frames of that z-score's window (and of the light gate's).
    observation_pull_light_gate : float
        ``g_b``: no step either when the mean grey level of the estimate's box has a robust
        z-score beyond ±this against the last ``W`` levels the gate let through (a shadow, a
        light turned on: gain normalisation hides them from ``g``'s distance); 0: no light gate.
    """

    n_particles: int = 600
    template_sigma: float = 0.005
    template_sigma_matrix: tuple | None = None
    kinematics: KinematicModel = field(default_factory=KinematicModel)
    resample_threshold: float = 1.0
    resampling: str = "systematic"
    threads: int = 2
    colour_rate: float = 0.04
    quadrant_reliability: float = 0.0
    quadrant_ref_rate: float = 0.0
    quadrant_ref_gate: float = 1.0
    anchor_pull: float = 0.0
    anchor_rate: float = 0.0
    anchor_gate: float = 1.0
    refine_fraction: float = 0.0
    refine_top: int = 10
    refine_noise: float = 0.5
    scale_steps: int = 0
    scale_step: float = 1.02
    rotation_steps: int = 0
    rotation_step: float = 0.03
    search_blend: float = 1.0
    search_pull: float = 1.0
    observation: ObservationConfig = field(default_factory=ObservationConfig)
    adaptive: AdaptiveDiffusion = field(default_factory=AdaptiveDiffusion)
    flow_share: float = 0.0
    camera_share: float = 0.0
    ncc_rate: float = 0.02
    observation_pull: float = 0.05
    observation_pull_scale: float = 0.9
    observation_pull_gate: float = 2.0
    observation_pull_window: int = 30
    observation_pull_light_gate: float = 2.5

    def __post_init__(self):
        check(self, MANIFOLD_SPECS)
        if self.template_sigma_matrix is not None:
            m = np.asarray(self.template_sigma_matrix, dtype=float)
            if m.shape != (N_FEATURES, N_FEATURES) or not np.allclose(m, m.T):
                raise ConfigError("ManifoldConfig.template_sigma_matrix must be a symmetric non-negative 9x9 matrix")
        if self.quadrant_reliability > 0 and not self.observation.quadrants:
            raise ConfigError("ManifoldConfig.quadrant_reliability needs observation.quadrants=true")

    @property
    def sigma_matrix(self) -> np.ndarray:
        """The 9×9 matrix of template-walk standard deviations ``σ_ij``."""
        if self.template_sigma_matrix is not None:
            return np.asarray(self.template_sigma_matrix, dtype=float)
        return np.full((N_FEATURES, N_FEATURES), self.template_sigma)

    def as_dict(self) -> dict:
        """The fields as a JSON-serialisable dict (nested configs as dicts, tuples as lists)."""
        return as_plain(self)

    @classmethod
    def from_dict(cls, d: dict) -> ManifoldConfig:
        """The config of :meth:`as_dict`'s output (or any subset of its fields; the rest default).

        Observation fields may be given flat (``{"quadrants": false}``) or inside
        ``"observation"``, not both.

        Raises
        ------
        covviz.config.ConfigError
            On an unknown field or a value of the wrong type or out of range (the message names it).
        """
        return from_mapping(cls, d, MANIFOLD_SPECS, aliases=OBSERVATION_ALIASES)

    def replace(self, **changes) -> ManifoldConfig:
        """A copy with ``changes``; observation fields by their flat names (``replace(quadrants=False)``)."""
        obs = {k: changes.pop(k) for k in list(changes) if k in OBSERVATION_ALIASES}
        if obs:
            changes["observation"] = dataclasses.replace(changes.get("observation", self.observation), **obs)
        return dataclasses.replace(self, **changes)


#: Flat names of the observation fields (``{"quadrants": false}`` sets ``observation.quadrants``).
OBSERVATION_ALIASES = {name: "observation" for name in OBSERVATION_SPECS}

#: Each field of :class:`ManifoldConfig`: its type and range (:mod:`covviz.config`).
MANIFOLD_SPECS: dict[str, Spec] = {
    "n_particles": Spec("int", 2, 1_000_000),
    "template_sigma": Spec("float", 0, 1),
    "template_sigma_matrix": Spec("matrix", 0, optional=True),
    "kinematics": Spec("config", cls=KinematicModel),
    "resample_threshold": Spec("float", 0, 1),
    "resampling": Spec("str", choices=("systematic", "multinomial")),
    "threads": Spec("int", 1, 64),
    "colour_rate": Spec("float", 0, 1),
    "quadrant_reliability": Spec("float", 0, 1),
    "quadrant_ref_rate": Spec("float", 0, 1),
    "quadrant_ref_gate": Spec("float", 0),
    "anchor_pull": Spec("float", 0, 1),
    "anchor_rate": Spec("float", 0, 1),
    "anchor_gate": Spec("float", 0),
    "refine_fraction": Spec("float", 0, 1, hi_open=True),
    "refine_top": Spec("int", 1),
    "refine_noise": Spec("float", 0),
    "scale_steps": Spec("int", 0, 50),
    "scale_step": Spec("float", 1, 2, lo_open=True),
    "rotation_steps": Spec("int", 0, 50),
    "rotation_step": Spec("float", 0, 1),
    "search_blend": Spec("float", 0, 1),
    "search_pull": Spec("float", 0, 1),
    "observation": Spec("config", cls=ObservationConfig),
    "adaptive": Spec("config", cls=AdaptiveDiffusion),
    "flow_share": Spec("float", 0, 1),
    "camera_share": Spec("float", 0, 1),
    "ncc_rate": Spec("float", 0, 1),
    "observation_pull": Spec("float", 0, 1),
    "observation_pull_scale": Spec("float", 0.1, 1.5),
    "observation_pull_gate": Spec("float", 0),
    "observation_pull_window": Spec("int", 3, 100_000),
    "observation_pull_light_gate": Spec("float", 0),
}

#: Top-level fields added to (or removed from) the config after results were first saved, each with the
#: value at which the tracker does exactly what it did without the field (every one was added off:
#: ``ncc_rate`` 0 is bit for bit the tracker before the position step, ``flow_guard`` 0 the tracker after
#: the guard's removal, ``camera_share`` 0 the tracker before the moving-camera proposal). A saved config that lacks such a field, or holds it at this value, is the same
#: config as one without it: ``covviz bench`` keeps those results instead of refusing the folder.
NEUTRAL_FIELDS: dict[str, float] = {"ncc_rate": 0.0, "flow_guard": 0.0, "camera_share": 0.0, "observation_pull": 0.0,
                                    # the pull's own settings, which change nothing while it is off
                                    "observation_pull_scale": 0.9, "observation_pull_gate": 2.0,
                                    "observation_pull_window": 30, "observation_pull_light_gate": 2.5}


# --------------------------------------------------------------------------- #
# what `covviz tune` searches (covviz.experiments.tune runs the study)
# --------------------------------------------------------------------------- #
#: The search space of ``covviz tune``, declared next to the config it searches:
#: field -> (low, high, scale), scale ``"log"`` or ``"linear"`` (floats) or ``"int"``.
#: A dotted name reaches into a nested field (``kinematics.pos_sigma.0``: mode 0 of the
#: position noise). Every range holds the default, which a new study runs first; the
#: ranges span what docs/tuning.md found to matter, about 3× either side of the default.
SEARCH_SPACE: dict[str, tuple[float, float, str]] = {
    "observation.likelihood_sigma": (0.25, 1.0, "log"),
    "template_sigma": (0.001, 0.03, "log"),
    "observation.quadrant_weight": (0.0, 2.0, "linear"),
    "resample_threshold": (0.3, 1.0, "linear"),
    "observation.smooth_sigma": (0.0, 1.5, "linear"),
    "observation.eps": (1e-4, 1e-2, "log"),
    "kinematics.pos_sigma.0": (0.01, 0.12, "log"),
    "kinematics.scale_sigma.0": (0.003, 0.03, "log"),
    "kinematics.velocity_decay": (0.5, 1.0, "linear"),
    "observation.colour_weight": (0.0, 30.0, "linear"),  # 0: off (as in the paper)
    "observation.grad_floor": (0.0, 0.9, "linear"),  # 0: no floor
    # the adaptive diffusion (covviz.model.adaptive): where the evidence starts, what it drives
    "adaptive.z_lo": (1.5, 6.0, "linear"),  # z_hi stays 8: always above
    "adaptive.jump_prob": (0.1, 0.8, "linear"),
    "adaptive.jump_spread": (1.0, 5.0, "linear"),
    "adaptive.template_slow": (0.0, 1.0, "linear"),
    "adaptive.redetect_fraction": (0.0, 0.5, "linear"),
    "adaptive.redetect_radius": (0.5, 5.0, "log"),
    # the observation pull (covviz.model.adaptive): its rate (0: off) and its light gate (dev sweeps tried 2-3)
    "observation_pull": (0.0, 0.15, "linear"),
    "observation_pull_light_gate": (1.5, 4.0, "linear"),
}


def _field_path(d: dict, name: str) -> tuple:
    """The container and key of the dotted ``name`` inside ``as_dict()``'s output."""
    if name.split(".")[0] in OBSERVATION_ALIASES:  # a flat observation name: observation.<name>
        name = f"observation.{name}"
    *path, last = name.split(".")
    for key in path:
        d = d[int(key)] if isinstance(d, list) else d[key]
    return d, int(last) if isinstance(d, list) else last


def search_params(config: ManifoldConfig | None = None) -> dict[str, float]:
    """The values of :data:`SEARCH_SPACE`'s names in ``config`` (default: the defaults)."""
    d = (config or ManifoldConfig()).as_dict()
    out = {}
    for name in SEARCH_SPACE:
        node, key = _field_path(d, name)
        out[name] = node[key]
    return out


def config_from_params(params: dict, base: ManifoldConfig | None = None) -> ManifoldConfig:
    """``base`` (default: the defaults) with the values of ``params`` (dotted names) set.

    Raises
    ------
    ValueError
        On an unknown name or a value the config refuses.
    """
    d = (base or ManifoldConfig()).as_dict()
    for name, value in params.items():
        try:
            node, key = _field_path(d, name)
            node[key]  # an unknown name raises here, not on assignment
        except (KeyError, IndexError, ValueError, TypeError):
            raise ValueError(f"unknown ManifoldConfig parameter {name!r}") from None
        node[key] = value
    return ManifoldConfig.from_dict(d)


def suggest_config(trial, base: ManifoldConfig | None = None) -> ManifoldConfig:
    """The config an Optuna ``trial`` proposes: one ``suggest_*`` per entry of :data:`SEARCH_SPACE`."""
    params = {}
    for name, (low, high, scale) in SEARCH_SPACE.items():
        if scale == "int":
            params[name] = trial.suggest_int(name, int(low), int(high))
        else:
            params[name] = trial.suggest_float(name, low, high, log=scale == "log")
    return config_from_params(params, base)


class ManifoldTracker:
    """Particle filter with per-particle covariance templates (the paper's method).

    A thin shell over the pure pieces: the frozen
    :class:`~covviz.model.observation.ObservationModel` (built at :meth:`init`), the
    :class:`~covviz.model.particles.ParticleSet` it steps, and a pool of
    ``config.threads`` threads for the observations, which :meth:`close`
    (or leaving a ``with`` block) shuts down.

    Parameters
    ----------
    config : ManifoldConfig, optional
    rng : numpy.random.Generator or int, optional
        All randomness comes from ``np.random.default_rng(rng)``.

    Notes
    -----
    Every record fills the typed fields of :class:`~covviz.records.FrameRecord`:
    the particles (poses, log-weights, templates, ancestry, ``modes``), the
    :class:`~covviz.records.Likelihood` (``d_eff`` and each term of ``d_eff²``)
    and the :class:`~covviz.records.FrameInputs` ``update()`` weighed by (the
    prepared grey frame, the colour map and state, the quadrant state); its
    ``extras`` stay empty. The frozen :attr:`model` reaches observers through
    the runner's ``on_start``.

    :meth:`snapshot` returns a :class:`ManifoldState` (what ``update()`` changes,
    plus a reference to the frozen model); :meth:`restore` puts it back, also
    into a fresh tracker of the same config in another process, and ``update()``
    then gives bit-identical boxes and records.

    Examples
    --------
    >>> from covviz.data.sequences import SyntheticSequence
    >>> seq = SyntheticSequence()
    >>> with ManifoldTracker(rng=0) as tr:
    ...     tr.init(seq.frame(0).image, seq.init_box)
    ...     box = tr.update(seq.frame(1).image)
    """

    name = "manifold"
    snapshots = True
    particle_filter = True

    def __init__(self, config: ManifoldConfig | None = None, rng=None):
        self.config = config or ManifoldConfig()
        self.rng = np.random.default_rng(rng)
        self.model: ObservationModel | None = None
        self.particles: ParticleSet | None = None
        self.initial_template: np.ndarray | None = None
        self.colour: fgbg.ColourModel | None = None
        self.quadrant_state: QuadrantState | None = None
        self.anchor: AnchorState | None = None
        self.adapt: AdaptState | None = None
        self.flow: FlowState | None = None
        self.camera: CameraState | None = None
        self.ncc: NccState | None = None
        self.pull: PullState | None = None
        self.last_record: FrameRecord | None = None
        #: An experiment's hand in update() (covviz.diagnosis.counterfactual); None in normal runs.
        self.intervention: Intervention | None = None
        self._sigma = self.config.sigma_matrix
        self._index = 0
        self._closed = False
        # Made here, once, by the thread that builds the tracker (no lazy creation to race on).
        self._pool = (
            ThreadPoolExecutor(max_workers=self.config.threads, thread_name_prefix="covviz-observe")
            if self.config.threads > 1
            else None
        )

    def config_dict(self) -> dict:
        return self.config.as_dict()

    def set_threads(self, n: int) -> None:
        """Observe with ``n`` threads (``config.threads``) from now on; before :meth:`init`.

        Boxes never depend on it (the observation's chunks are fixed, see
        :mod:`covviz.model.observation`); only the speed does, and that depends on what
        else the process runs (``covviz track`` takes one thread on two cores when it
        records: the recorder's thread is then the busier one).
        """
        n = int(n)
        if n < 1:
            raise ValueError(f"threads must be at least 1, got {n}")
        if self.particles is not None or self._closed:
            raise RuntimeError("set the threads before init() (and before close())")
        if n == self.config.threads:
            return
        if self._pool is not None:
            self._pool.shutdown(wait=True)
        self.config = self.config.replace(threads=n)
        self._pool = ThreadPoolExecutor(max_workers=n, thread_name_prefix="covviz-observe") if n > 1 else None

    @property
    def observation_model(self) -> ObservationModel | None:
        """The frozen observation model (built at :meth:`init`), for observers."""
        return self.model

    def close(self) -> None:
        """Shut the observation threads down; the tracker cannot be used after this."""
        self._closed = True
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def snapshot(self) -> ManifoldState:
        """What ``update()`` changes, frozen: particles, templates, the online state, the rng, the frame counter."""
        if self.particles is None:
            raise RuntimeError("call init(frame, box) before snapshot()")
        ps = self.particles
        return ManifoldState(
            config=self.config,
            model=self.model,
            particles=ParticleSet(_ro(ps.states), _ro(ps.templates), _ro(ps.log_weights)),
            initial_template=self.initial_template,
            colour=self.colour,
            quadrant_state=self.quadrant_state,
            anchor=self.anchor,
            adapt=self.adapt,
            flow=self.flow,
            rng_state=copy.deepcopy(self.rng.bit_generator.state),
            index=self._index,
            ncc=self.ncc,
            camera=self.camera,
            pull=self.pull,
        )

    def restore(self, state: ManifoldState) -> None:
        """Put a :meth:`snapshot` back: the next ``update()`` continues from it, bit for bit."""
        if self._closed:
            raise RuntimeError("this tracker was closed; make a new one")
        if not isinstance(state, ManifoldState):
            raise TypeError(f"restore() takes a ManifoldState, got {type(state).__name__}")
        if state.config != self.config:
            raise ValueError("this state was taken from a tracker of another config; make one with state.config")
        self.model = state.model
        self.particles = state.particles
        self.initial_template = state.initial_template
        self.colour = state.colour
        self.quadrant_state = state.quadrant_state
        self.anchor = state.anchor
        self.adapt = state.adapt
        self.flow = state.flow
        self.camera = state.camera
        self.ncc = state.ncc
        self.pull = state.pull
        self.rng.bit_generator.state = copy.deepcopy(state.rng_state)
        self._index = state.index
        self.last_record = None

    # ------------------------------------------------------------------ #
    def _observe(self, gray: np.ndarray, poses: np.ndarray, templates=None, timings=None):
        return self.model.observe(gray, poses, templates, self._pool, self.config.threads, timings)

    def init(self, frame: np.ndarray, box) -> None:
        """Initialise every particle at ``box`` with the template observed there."""
        if self._closed:
            raise RuntimeError("this tracker was closed; make a new one")
        cfg = self.config
        t0 = time.perf_counter()
        b = check_init_box(box, np.shape(frame))
        self.model = model = ObservationModel.build(frame, b, cfg.observation)
        x, y, w, h = b
        pose = np.array([[x + w / 2, y + h / 2, 1.0, 0.0]])
        g0 = model.prepare(frame)
        C0 = self._observe(g0, pose).descriptors
        L0 = logm(C0)[0]
        n = cfg.n_particles
        states = np.zeros((n, 6))
        states[:, X], states[:, Y], states[:, SCALE] = pose[0, 0], pose[0, 1], 1.0
        self.initial_template = L0
        self.colour = fgbg.init_colour_model(frame, b, compiled=model.compiled) if model.colour else None
        self.quadrant_state = model.initial_quadrant_state() if cfg.quadrant_reliability > 0 else None
        self.anchor = AnchorState(_ro(L0), 1.0) if cfg.anchor_pull > 0 else None
        self.adapt = AdaptState.start(pose[0], L0) if cfg.adaptive.enabled else None
        self.flow = FlowState(_ro(gray8(frame), np.uint8), _ro(b)) if cfg.flow_share > 0 else None
        self.camera = CameraState(*camera_frame(frame), _ro(b)) if cfg.camera_share > 0 else None
        self.pull = PullState() if cfg.observation_pull > 0 else None
        self.ncc = None
        if cfg.ncc_rate > 0:
            size = (max(4, round(w)), max(4, round(h)))
            self.ncc = NccState(_ro(refine.patch(to_gray(frame), pose[0, :2], (w, h), size), np.float32))
        self.particles = ParticleSet(states, np.broadcast_to(L0, (n, *L0.shape)).copy(), np.full(n, -np.log(n)))
        self._index = 0
        self.last_record = FrameRecord(
            index=0,
            box=b.copy(),
            tracker=self.name,
            pose=pose[0].copy(),
            corners=pose_corners(pose, model.base_wh)[0],
            estimate_template=L0,
            estimate_descriptor=C0[0],
            timings={"total": time.perf_counter() - t0},
            inputs=FrameInputs(g0, None, self.colour, self.quadrant_state),
        )

    def _flow_velocities(self, ps: ParticleSet, cur8: np.ndarray) -> ParticleSet:
        """``flow_share`` of the particles with the velocity that moves them by the last box's median flow.

        The kinematic step damps the velocity (``v ← a·v + u``) before it moves the centre, so
        the velocity set is ``flow / a``: a chosen particle lands at ``x + flow`` plus its noise.
        An untrusted flow (:func:`covviz.model.flow.trusted`) changes nothing and draws nothing.
        """
        fb, fail, f = median_flow(self.flow.frame, cur8, self.flow.box)
        if not trusted(fb, fail, f):
            return ps
        st = np.array(ps.states)
        n = len(st)
        k = round(self.config.flow_share * n)
        idx = np.arange(n) if k == n else self.rng.permutation(n)[:k]
        a = self.config.kinematics.velocity_decay
        st[idx, VX] = f[0] / a
        st[idx, VY] = f[1] / a
        return ParticleSet(st, ps.templates, ps.log_weights)

    def _camera_shift(self, ps: ParticleSet, small: np.ndarray, factor: float) -> ParticleSet:
        """``camera_share`` of the particles moved by the whole scene's shift since the last frame, where it
        is trusted (:data:`CAMERA_MIN_RESPONSE`) and at least :data:`CAMERA_MIN_SHIFT` target sizes (the last
        box's); otherwise nothing changes and nothing is drawn. Their velocities are kept: a jump of the
        camera moves the target once."""
        cam = self.camera
        if small.shape != cam.frame.shape or factor != cam.factor:
            return ps
        dx, dy, response = camera_shift(cam.frame, small, factor)
        size = math.sqrt(cam.box[2] * cam.box[3])
        if not (response >= CAMERA_MIN_RESPONSE and math.hypot(dx, dy) >= CAMERA_MIN_SHIFT * size):
            return ps  # (a flat frame's NaN fails both tests too)
        st = np.array(ps.states)
        n = len(st)
        k = round(self.config.camera_share * n)
        idx = np.arange(n) if k == n else self.rng.permutation(n)[:k]
        st[idx, X] += dx
        st[idx, Y] += dy
        return ParticleSet(st, ps.templates, ps.log_weights)

    def _intervene(self, hook: Intervention, frame, gray, states, templates):
        """The search and model fixes of a replay: particles moved to the truth, the appearance set from it.

        Returns the states, the templates and the model to observe this frame with (the frozen
        model, or a copy whose quadrant references are the truth's).
        """
        model = self.model
        moved = hook.to_truth(self._index, len(states))
        if moved is not None:
            idx, box, velocity = moved
            x, y, w, h = np.asarray(box, dtype=np.float64)
            states = states.copy()
            states[idx, X], states[idx, Y] = x + w / 2, y + h / 2
            states[idx, SCALE] = np.sqrt(max(w * h, 1e-12) / (model.base_wh[0] * model.base_wh[1]))
            states[idx, THETA] = 0.0
            states[idx, VX], states[idx, VY] = velocity[0], velocity[1]
        look = hook.appearance(self._index)
        if look is not None:
            truth = box_to_pose(look, model.base_wh)[None]
            ob = model.observe(gray, truth)
            templates = np.broadcast_to(logm(ob.descriptors)[0], templates.shape).copy()
            if model.colour:
                self.colour = fgbg.init_colour_model(frame, np.asarray(look, dtype=np.float64),
                                                     compiled=model.compiled)
            if model.quadrants:
                Q = ob.quadrants[0]
                model = dataclasses.replace(model, quadrant_reference=Q, quadrant_logdet=logdet(Q))
        return states, templates, model

    def _refine(self, states, templates, modes, log_weights, ob, n1):
        """Second-stage particles: children of the first stage's best, with shrunken noise (coarse to fine).

        The parents are drawn by weight among the ``refine_top`` best of the
        first ``n1`` particles; each child takes its parent's template and
        its pose moved by ``refine_noise`` times the everyday (mode-0) noise.
        Their mode is recorded as 2.
        """
        cfg = self.config
        km = cfg.kinematics
        n = len(states)
        n2 = n - n1
        w1 = log_weights[:n1] + self.model.log_likelihood(ob.likelihood_distances)
        k = min(cfg.refine_top, n1)
        top = np.argsort(-w1, kind="stable")[:k]
        p = np.exp(normalize_log_weights(w1[top]))
        parents = top[self.rng.choice(k, size=n2, p=p)]
        z = self.rng.standard_normal((n2, 4))
        child = states[parents].copy()
        size = self.model.base_size * child[:, SCALE]
        f = cfg.refine_noise
        child[:, X] += f * km.pos_sigma[0] * size * z[:, 0]
        child[:, Y] += f * km.pos_sigma[0] * size * z[:, 1]
        child[:, SCALE] = np.clip(child[:, SCALE] * np.exp(f * km.scale_sigma[0] * z[:, 2]), *km.scale_range)
        child[:, THETA] = np.clip(child[:, THETA] + f * km.rot_sigma[0] * z[:, 3], -km.max_rotation, km.max_rotation)
        states = np.concatenate([states[:n1], child])
        templates = np.concatenate([templates[:n1], templates[parents]])
        modes = np.concatenate([modes[:n1], np.full(n2, 2, dtype=modes.dtype)])
        return states, templates, modes

    def _search(self, gray, est_pose, est_template, states, cmap, qstate):
        """Scale, then rotation, search at the estimate; the estimate and the particles move towards the best."""
        cfg, model = self.config, self.model
        ks = np.arange(-cfg.scale_steps, cfg.scale_steps + 1)
        kr = np.arange(-cfg.rotation_steps, cfg.rotation_steps + 1)
        sp, sd, rp, rd = model.pose_search(
            gray, est_pose, est_template, cfg.scale_step ** ks.astype(float), kr * cfg.rotation_step, colour=cmap,
            quadrant_state=qstate,
        )
        dlog = _parabolic_step(sd) * np.log(cfg.scale_step) if len(sd) > 1 else 0.0
        dtheta = _parabolic_step(rd) * cfg.rotation_step if len(rd) > 1 else 0.0
        new = est_pose.copy()
        new[2] = est_pose[2] * np.exp(cfg.search_blend * dlog)
        new[3] = est_pose[3] + cfg.search_blend * dtheta
        km = cfg.kinematics
        states = states.copy()
        states[:, SCALE] = np.clip(
            states[:, SCALE] * np.exp(cfg.search_pull * cfg.search_blend * dlog), *km.scale_range
        )
        states[:, THETA] = np.clip(
            states[:, THETA] + cfg.search_pull * cfg.search_blend * dtheta, -km.max_rotation, km.max_rotation
        )
        return new, states, PoseSearch(sp, sd, rp, rd)

    def _ncc_step(self, g, est_pose):
        """The pose to report: the estimate's centre moved to the grey template's best match nearby
        (:func:`covviz.model.refine.ncc_shift`) in the full-resolution grey frame ``g``; the template
        updated there when it matched."""
        wh = np.asarray(self.model.base_wh, dtype=np.float64) * est_pose[2]
        dx, dy, peak = refine.ncc_shift(g, est_pose[:2], wh, self.ncc.template)
        out = est_pose.copy()
        out[0] += dx
        out[1] += dy
        if peak >= refine.NCC_MIN:
            self.ncc = NccState(_ro(refine.update_template(self.ncc.template, g, out[:2], wh, self.config.ncc_rate),
                                    np.float32))
        return out

    def update(self, frame: np.ndarray) -> np.ndarray:
        """Track into ``frame``; return the estimated box ``x, y, w, h``."""
        if self._closed:
            raise RuntimeError("this tracker was closed; make a new one")
        if self.particles is None:
            raise RuntimeError("call init(frame, box) before update(frame)")
        cfg, model = self.config, self.model
        tm: dict[str, float] = {}
        t_start = time.perf_counter()
        ps = self.particles
        self._index += 1
        cur8 = None
        t_prop = t_start
        if self.flow is not None:
            # 0. the motion prior: a share of the particles moves with the last box's content
            cur8 = gray8(frame)
            ps = self._flow_velocities(ps, cur8)
            t_prop = time.perf_counter()
            tm["flow"] = t_prop - t_start
        small = None
        if self.camera is not None:
            # 0b. the camera's motion: a share of the particles moves with the whole scene's jump
            t_cam = time.perf_counter()
            small, factor = camera_frame(frame if cur8 is None else cur8)  # the flow's grey, if it made one
            ps = self._camera_shift(ps, small, factor)
            t_prop = time.perf_counter()
            tm["camera"] = t_prop - t_cam

        # 1. propagate kinematics and templates (their noise following the last frame's evidence)
        adapt = self.adapt
        e = 0.0 if adapt is None else adapt.evidence
        km = adapted_kinematics(cfg.kinematics, e, cfg.adaptive)
        states, modes = propagate_kinematics(ps.states, km, model.base_size, self.rng)
        anchor = self.anchor
        walk_factor = 1.0 - cfg.adaptive.template_slow * e  # on the template walk's sigma (1: no evidence)
        sigma = self._sigma if e == 0.0 else self._sigma * walk_factor
        templates = template_walk(
            ps.templates, sigma, self.rng, None if anchor is None else anchor.template, cfg.anchor_pull
        )
        n_fresh = 0
        if e > 0.0:
            states, templates, modes = redetect(
                states, templates, modes, adapt, cfg.adaptive, model.base_size, km, self.rng
            )
            n_fresh = int(np.count_nonzero(modes == 3))
        t1 = time.perf_counter()
        tm["propagate"] = t1 - t_prop
        gray = model.prepare(frame)
        hook = self.intervention
        if hook is not None:
            states, templates, model = self._intervene(hook, frame, gray, states, templates)

        # 2. observe descriptors, and each template's distance, at every particle's pose
        poses = states[:, POSE]
        colour_state, qstate = self.colour, self.quadrant_state
        tc = time.perf_counter()
        cmap = model.colour_map(frame, colour_state)
        tm["colour"] = time.perf_counter() - tc
        n2 = round(cfg.refine_fraction * len(states)) if cfg.refine_fraction > 0 else 0
        n1 = len(states) - n2
        ob = model.observe(
            gray, poses[:n1], templates[:n1], self._pool, cfg.threads, tm, colour=cmap, quadrant_state=qstate
        )
        if n2:
            # 2b. second stage: the last n2 particles restart around the best of the first stage
            states, templates, modes = self._refine(states, templates, modes, ps.log_weights, ob, n1)
            poses = states[:, POSE]
            tm2: dict[str, float] = {}
            ob2 = model.observe(
                gray, poses[n1:], templates[n1:], self._pool, cfg.threads, tm2, colour=cmap, quadrant_state=qstate
            )
            ob = _concat_observations(ob, ob2)
            for k, v in tm2.items():
                tm[k] = tm.get(k, 0.0) + v

        # 3. weigh
        t2 = time.perf_counter()
        lw = normalize_log_weights(ps.log_weights + model.log_likelihood(ob.likelihood_distances))
        ess = effective_sample_size(lw)
        t3 = time.perf_counter()
        tm["weights"] = t3 - t2

        # 4. estimate (MMSE of the pose; weighted log-Euclidean mean of the templates)
        est_state = mmse(states, lw)
        est_pose = est_state[POSE]
        est_template = mmse(templates, lw)
        if hook is not None:
            chosen = _chosen_estimate(hook, self._index, states, lw, model.base_wh)
            if chosen is not None:
                est_state, est_pose, est_template = states[chosen], states[chosen, POSE], templates[chosen]
        search = None
        if cfg.scale_steps > 0 or cfg.rotation_steps > 0:
            est_pose, states, search = self._search(gray, est_pose, est_template, states, cmap, qstate)
        est_ob = self._observe(gray, est_pose[None], None if anchor is None else est_template)
        est_desc = est_ob.descriptors[0]
        if anchor is not None:
            d2 = float(est_ob.distances[0] ** 2)
            good = d2 < cfg.anchor_gate * anchor.noise
            self.anchor = AnchorState(
                _ro((1 - cfg.anchor_rate) * anchor.template + cfg.anchor_rate * est_template) if good
                else anchor.template,
                0.95 * anchor.noise + 0.05 * d2,
            )
        if qstate is not None:
            q_est = model.quadrant_distances(est_ob.quadrants, qstate)[0]
            self.quadrant_state = update_quadrant_state(
                qstate, q_est, est_ob.quadrants[0], cfg.quadrant_reliability, cfg.quadrant_ref_rate,
                cfg.quadrant_ref_gate,
            )
        if adapt is not None:
            self.adapt = adapt_evidence(adapt, float(np.min(ob.likelihood_distances)), est_pose, est_template,
                                        cfg.adaptive)
        box = est_box = pose_to_box(est_pose[None], model.base_wh)[0]  # est_box: the filter's, after the ncc step too
        if colour_state is not None:
            self.colour = fgbg.update_colour_model(colour_state, frame, box, cfg.colour_rate, compiled=model.compiled)
        if cur8 is not None:
            self.flow = FlowState(_ro(cur8, np.uint8), _ro(box))
        if small is not None:
            self.camera = CameraState(_ro(small, np.float32), factor, _ro(box))
        out_pose = est_pose
        if self.ncc is not None:  # the reported box only: the filter goes on from its own estimate
            same = model.step <= 1 and model.smooth_sigma <= 0  # then the model's grey is the frame's own
            out_pose = self._ncc_step(gray if same else to_gray(frame), est_pose)
            box = pose_to_box(out_pose[None], model.base_wh)[0]
        t4 = time.perf_counter()
        tm["estimate"] = t4 - t3

        # 5. resample
        resampled = ess < cfg.resample_threshold * cfg.n_particles
        idx = None
        new = ParticleSet(states, templates, lw)
        if resampled:
            res = systematic_resample if cfg.resampling == "systematic" else multinomial_resample
            idx = res(lw, self.rng)
            new = new.take(idx)
        pull_rec = None if self.pull is None else Pull("evidence", cfg.observation_pull, None, float("nan"))
        if self.pull is not None and (self.adapt is None or self.adapt.evidence == 0.0):
            # 6. the observation pull (covviz.model.adaptive): the templates step towards what the estimate sees
            obs = est_desc
            if cfg.observation_pull_scale != 1.0:
                inner = np.array(est_pose, dtype=np.float64)
                inner[2] *= cfg.observation_pull_scale
                obs = self._observe(gray, inner[None]).descriptors[0]
            light = float("nan")
            if cfg.observation_pull_light_gate > 0:
                light = box_brightness(gray, est_box, model.step)
            target = logm(obs)
            stepped, self.pull = observation_pull(
                new.templates, target, self.initial_template, self.pull, cfg.observation_pull,
                cfg.observation_pull_gate, cfg.observation_pull_window, light, cfg.observation_pull_light_gate,
            )
            pull_rec = Pull(self.pull.held, cfg.observation_pull, None if stepped is None else _ro(target), light)
            if stepped is not None:
                new = ParticleSet(new.states, stepped, new.log_weights)
        self.particles = new
        t5 = time.perf_counter()
        tm["resample"] = t5 - t4
        tm["total"] = t5 - t_start

        self.last_record = FrameRecord(
            index=self._index,
            box=box,
            tracker=self.name,
            pose=out_pose,
            corners=pose_corners(out_pose[None], model.base_wh)[0],
            particle_poses=poses,
            particle_corners=pose_corners(poses, model.base_wh),
            log_weights=lw,
            ess=ess,
            resampled=bool(resampled),
            resample_indices=idx,
            templates=templates,
            descriptors=ob.descriptors,
            distances=ob.distances,
            estimate_template=est_template,
            estimate_descriptor=est_desc,
            timings=tm,
            modes=modes,
            velocity=est_state[[VX, VY]],
            likelihood=Likelihood(
                ob.likelihood_distances, model.likelihood_sigma, ob.quadrant_distances, ob.terms, model.term_weights
            ),
            inputs=FrameInputs(gray, cmap, colour_state, qstate),
            pose_search=search,
            diffusion=None if adapt is None else Diffusion(
                e, km.mode_probs[1], walk_factor, n_fresh, self.adapt.evidence,
                self.adapt.z, self.adapt.lost,
            ),
            pull=pull_rec,
            filter_pose=None if self.ncc is None else est_pose,
        )
        return box


@dataclass(frozen=True, slots=True, eq=False)
class AnchorState:
    """The anchored template walk's online state (see ``ManifoldConfig.anchor_pull``).

    Attributes
    ----------
    template : ndarray, shape (9, 9)
        The anchor, log space: the initial template, then a running
        log-Euclidean mean of it and the estimates' templates that matched well.
    noise : float
        Running mean (rate 0.05) of ``d²`` of the estimate's template at the
        estimate: a frame matches well when its ``d²`` is below ``anchor_gate``
        times this.
    """

    template: np.ndarray
    noise: float


@dataclass(frozen=True, slots=True, eq=False)
class NccState:
    """The position step's template (``ManifoldConfig.ncc_rate``): the target's grey look, float32, at the
    first box's size (read-only)."""

    template: np.ndarray


@dataclass(frozen=True, slots=True, eq=False)
class FlowState:
    """The motion prior's memory (``ManifoldConfig.flow_share``): the last frame, grey ``uint8``, and
    the box estimated on it. Read-only arrays."""

    frame: np.ndarray
    box: np.ndarray


@dataclass(frozen=True, slots=True, eq=False)
class CameraState:
    """The camera-motion proposal's memory (``ManifoldConfig.camera_share``): the last frame as
    :func:`covviz.model.flow.camera_frame` reads it, its downscale factor, and the box estimated on it
    (read-only arrays)."""

    frame: np.ndarray
    factor: float
    box: np.ndarray


@dataclass(frozen=True, slots=True, eq=False)
class ManifoldState:
    """A :class:`ManifoldTracker`'s state between two frames (:meth:`ManifoldTracker.snapshot`).

    Immutable and picklable: its arrays are read-only copies, its online parts
    frozen dataclasses, and the frozen observation model is shared by reference.

    Attributes
    ----------
    config : ManifoldConfig
    model : ObservationModel
    particles : ParticleSet
        Kinematics ``(n, 6)``, log-space templates ``(n, 9, 9)``, log-weights ``(n,)``.
    initial_template : ndarray, shape (9, 9)
    colour : ColourModel or None
    quadrant_state : QuadrantState or None
    anchor : AnchorState or None
    adapt : AdaptState or None
        The adaptive diffusion's evidence and last confident pose (None when off).
    flow : FlowState or None
        The motion prior's last frame and box (None when off).
    camera : CameraState or None
        The moving-camera proposal's last (downscaled) frame and box (None when off).
    pull : PullState or None
        The observation pull's window (None when off).
    rng_state : dict
        The bit generator's state (``Generator.bit_generator.state``).
    index : int
        0-based index of the last frame tracked.
    """

    config: ManifoldConfig
    model: ObservationModel
    particles: ParticleSet
    initial_template: np.ndarray
    colour: fgbg.ColourModel | None
    quadrant_state: QuadrantState | None
    anchor: AnchorState | None
    adapt: AdaptState | None
    flow: FlowState | None
    rng_state: dict
    index: int
    ncc: NccState | None = None
    camera: CameraState | None = None
    pull: PullState | None = None


def _ro(a: np.ndarray, dtype=np.float64) -> np.ndarray:
    """A read-only copy of ``a`` as ``dtype`` (what a frozen state holds)."""
    a = np.array(a, dtype=dtype)
    a.flags.writeable = False
    return a


def _concat_observations(a, b):
    """One :class:`~covviz.model.observation.Observation` of two batches, in order."""
    from covviz.model.observation import Observation

    def cat(x, y):
        return None if x is None else np.concatenate([x, y])

    return Observation(
        cat(a.descriptors, b.descriptors),
        cat(a.quadrants, b.quadrants),
        cat(a.distances, b.distances),
        cat(a.quadrant_distances, b.quadrant_distances),
        cat(a.likelihood_distances, b.likelihood_distances),
        {k: np.concatenate([v, b.terms[k]]) for k, v in a.terms.items()},
    )


def _chosen_estimate(hook: Intervention, index: int, states, lw, base_wh) -> int | None:
    """The particle an intervention reports instead of the MMSE estimate, among those holding
    :data:`~covviz.trackers.base.ESTIMATE_MASS` of the weight (None: the estimator's own)."""
    cand = heaviest(lw, ESTIMATE_MASS)
    j = hook.estimate(index, pose_to_box(states[cand][:, POSE], base_wh))
    return None if j is None else int(cand[j])


def _parabolic_step(d: np.ndarray) -> float:
    """Offset (in grid steps, from the centre of the odd-length grid ``d``) of the minimum of ``d²``.

    The best grid point, refined by the parabola through it and its two
    neighbours (when it has both and the parabola opens upwards).
    """
    c = np.asarray(d, dtype=np.float64) ** 2
    j = int(np.argmin(c))
    off = 0.0
    if 0 < j < len(c) - 1:
        den = c[j - 1] - 2 * c[j] + c[j + 1]
        if den > 0:
            off = float(np.clip(0.5 * (c[j - 1] - c[j + 1]) / den, -0.5, 0.5))
    return j - (len(c) - 1) / 2 + off


def make(n_particles: int | None = None, rng=None, config: ManifoldConfig | None = None) -> ManifoldTracker:
    """Factory for the tracker registry: ``config`` (default: the defaults), optionally another particle count."""
    from dataclasses import replace

    cfg = config or ManifoldConfig()
    if n_particles is not None:
        cfg = replace(cfg, n_particles=n_particles)
    return ManifoldTracker(cfg, rng)


#: What makes ``manifold-paper`` the paper's likelihood: every term and step covviz added to it, off
#: (gain normalisation and anti-aliasing stay: they are part of how covviz observes, also for the paper).
PAPER_LIKELIHOOD = {
    "quadrants": False,
    "grad_normalize": 0.0,
    "colour_weight": 0.0,
    "context_weight": 0.0,
    "quadrant_reliability": 0.0,
    "anchor_pull": 0.0,
    "refine_fraction": 0.0,
    "scale_steps": 0,
    "rotation_steps": 0,
    "adaptive": AdaptiveDiffusion(enabled=False),
    "flow_share": 0.0,
    "camera_share": 0.0,
    "ncc_rate": 0.0,
    "observation_pull": 0.0,
}
#: The derivative normalisation and the colour term off, the quadrant term (and the adaptive diffusion and the
#: reported box's position step) kept: the likelihood of before issue 14 on today's dynamics (for ablations
#: and speed; the ablation's ladder from it to the default then differs by likelihood terms alone).
NEW_TERMS_OFF = {k: v for k, v in PAPER_LIKELIHOOD.items() if k not in ("quadrants", "adaptive", "ncc_rate")}


def make_paper(n_particles: int | None = None, rng=None, config: ManifoldConfig | None = None) -> ManifoldTracker:
    """Factory for ``manifold-paper``: ``config`` (default: the defaults) with :data:`PAPER_LIKELIHOOD`."""
    tr = make(n_particles, rng, (config or ManifoldConfig()).replace(**PAPER_LIKELIHOOD))
    tr.name = "manifold-paper"
    return tr
