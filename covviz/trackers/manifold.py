"""The paper's tracker: a particle filter over kinematics *and* templates on the SPD manifold.

Each particle carries a pose ``[x, y, vx, vy, scale, theta]`` and its own
template ``C = expm(L)`` (kept in log space). Every frame:

1. **propagate** the kinematics (near-constant velocity, two-mode noise) and the
   templates (random walk ``L += W``), see :mod:`covviz.dynamics`;
2. **observe**: warp each particle's region to 32×32, compute the 9 features and
   the covariance descriptor ``C*`` (:mod:`covviz.features`, :mod:`covviz.descriptor`);
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
(:func:`covviz.spd.jbld`), which equals the affine-invariant distance to
second order and costs Cholesky factorisations instead of eigensolvers. The
paper's per-particle templates are unchanged; ``quadrants=False`` gives the
paper's likelihood exactly (the tracker ``manifold-paper``).

Reference: the paper in ``shared/paper.tex``, sections 2–3.
"""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, fields
from typing import Self

import numpy as np

from covviz.dynamics import POSE, SCALE, VX, VY, KinematicModel, X, Y, propagate_kinematics, template_walk
from covviz.features import N_FEATURES, pose_corners, pose_to_box
from covviz.observation import ObservationModel
from covviz.particles import (
    ParticleSet,
    effective_sample_size,
    mmse,
    multinomial_resample,
    normalize_log_weights,
    systematic_resample,
)
from covviz.records import FrameRecord
from covviz.spd import logm
from covviz.trackers.base import check_init_box

__all__ = ["ManifoldConfig", "ManifoldTracker"]


@dataclass(frozen=True)
class ManifoldConfig:
    """Every parameter of :class:`ManifoldTracker`, with its default.

    How the defaults were chosen (sweeps, seeds, what moved the score) is in
    ``docs/tuning.md``.

    Attributes
    ----------
    n_particles : int
        Particles (each with its own template).
    likelihood_sigma : float
        σ of ``exp(-d²/2σ²)``. A particle's distance to its observation is
        ~0.8–1.5 on target and ~2–5 on background.
    template_sigma : float
        Std of every entry of the symmetric log-space step ``W`` of the template
        walk (``σ_ij``, the same for all ``i, j``), unless ``template_sigma_matrix``
        is given.
    template_sigma_matrix : tuple of tuples, optional
        A full symmetric 9×9 matrix of ``σ_ij``.
    kinematics : KinematicModel
        Kinematic model and its two-mode noise.
    patch_size : int
        Side of the warped patch (32 in the paper).
    eps : float
        Shrinkage of each descriptor towards ``(tr C / d)·I``.
    resample_threshold : float
        Resample when ESS < threshold · n (1.0: every frame, as plain SIR).
    resampling : {"systematic", "multinomial"}
    antialias : bool
        Downsample the frame (area averaging) when the target is more than
        ~2 pixels per patch sample, so that the 32×32 warp does not alias.
    threads : int
        Threads that share the particles' descriptors and distances (2: the
        cores of the machines we target). Results never depend on it.
    smooth_sigma : float
        Gaussian pre-smoothing of the frame (pixels of the possibly
        downsampled frame) before warping: tames sensor noise in the
        derivative features. 0 disables it.
    gain_normalize : bool
        Divide each patch's intensity and derivative features by its mean
        intensity: descriptors become invariant to illumination gain
        (see :func:`covviz.features.patch_features`). Not in the paper.
    quadrants : bool
        Add the quadrant term to each particle's distance (see the module
        docstring). Not in the paper; ``False`` gives the paper's likelihood.
    quadrant_weight : float
        Weight of the quadrant term in ``d²``.
    jit : bool
        Observe with the compiled kernels (:mod:`covviz.kernels`) when numba is
        installed and ``COVVIZ_NO_JIT`` is not set; ``False``: the numpy path.
    """

    n_particles: int = 600
    likelihood_sigma: float = 0.5
    template_sigma: float = 0.005
    template_sigma_matrix: tuple | None = None
    kinematics: KinematicModel = field(default_factory=KinematicModel)
    patch_size: int = 32
    eps: float = 1e-3
    resample_threshold: float = 1.0
    resampling: str = "systematic"
    antialias: bool = True
    threads: int = 2
    smooth_sigma: float = 0.0
    gain_normalize: bool = True
    quadrants: bool = True
    quadrant_weight: float = 1.0
    jit: bool = True

    def __post_init__(self):
        for name in (
            "likelihood_sigma",
            "template_sigma",
            "eps",
            "smooth_sigma",
            "resample_threshold",
            "quadrant_weight",
        ):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not np.isfinite(v):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        # Every bad config value is a ValueError (one kind for callers and the CLI to report).
        if not isinstance(self.n_particles, (int, np.integer)):
            raise ValueError(f"n_particles must be an integer, got {self.n_particles!r}")  # noqa: TRY004
        if self.n_particles < 2:
            raise ValueError(f"n_particles must be at least 2, got {self.n_particles}")
        if not self.likelihood_sigma > 0:
            raise ValueError(f"likelihood_sigma must be positive, got {self.likelihood_sigma}")
        if self.template_sigma < 0:
            raise ValueError(f"template_sigma must be non-negative, got {self.template_sigma}")
        if self.template_sigma_matrix is not None:
            m = np.asarray(self.template_sigma_matrix, dtype=float)
            if m.shape != (N_FEATURES, N_FEATURES) or not np.allclose(m, m.T) or (m < 0).any():
                raise ValueError("template_sigma_matrix must be a symmetric non-negative 9x9 matrix")
        if not isinstance(self.threads, (int, np.integer)) or self.threads < 1:
            raise ValueError(f"threads must be a positive integer, got {self.threads!r}")
        if self.patch_size < 4:
            raise ValueError(f"patch_size must be at least 4, got {self.patch_size}")
        if not self.eps > 0:
            raise ValueError(f"eps must be positive (it keeps descriptors SPD), got {self.eps}")
        if not 0 <= self.resample_threshold <= 1:
            raise ValueError(f"resample_threshold must be in [0, 1], got {self.resample_threshold}")
        if self.quadrant_weight < 0:
            raise ValueError(f"quadrant_weight must be non-negative, got {self.quadrant_weight}")
        if self.quadrants and self.patch_size % 2:
            raise ValueError(f"quadrants need an even patch_size, got {self.patch_size}")
        if self.smooth_sigma < 0:
            raise ValueError(f"smooth_sigma must be non-negative, got {self.smooth_sigma}")
        if self.resampling not in ("systematic", "multinomial"):
            raise ValueError(f"resampling must be 'systematic' or 'multinomial', got {self.resampling!r}")

    @property
    def sigma_matrix(self) -> np.ndarray:
        """The 9×9 matrix of template-walk standard deviations ``σ_ij``."""
        if self.template_sigma_matrix is not None:
            return np.asarray(self.template_sigma_matrix, dtype=float)
        return np.full((N_FEATURES, N_FEATURES), self.template_sigma)

    def as_dict(self) -> dict:
        """The fields as a JSON-serialisable dict (nested dataclasses as dicts, tuples as lists)."""
        return json.loads(json.dumps(asdict(self), default=list))

    @classmethod
    def from_dict(cls, d: dict) -> ManifoldConfig:
        """The config of :meth:`as_dict`'s output (or any subset of its fields; the rest default).

        Raises
        ------
        ValueError
            On an unknown field or a value the config refuses (the message names it).
        """
        if not isinstance(d, dict):
            raise ValueError(f"a ManifoldConfig must be a JSON object of fields, got {type(d).__name__}")  # noqa: TRY004 - config errors are ValueError
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown ManifoldConfig field(s) {', '.join(unknown)}; known: {', '.join(sorted(names))}")
        kw = dict(d)
        if isinstance(kw.get("kinematics"), dict):
            km = kw["kinematics"]
            known = {f.name for f in fields(KinematicModel)}
            bad = sorted(set(km) - known)
            if bad:
                raise ValueError(f"unknown kinematics field(s) {', '.join(bad)}; known: {', '.join(sorted(known))}")
            kw["kinematics"] = KinematicModel(**{k: tuple(v) if isinstance(v, list) else v for k, v in km.items()})
        if isinstance(kw.get("template_sigma_matrix"), list):
            kw["template_sigma_matrix"] = tuple(tuple(r) for r in kw["template_sigma_matrix"])
        return cls(**kw)


# --------------------------------------------------------------------------- #
# what `covviz tune` searches (covviz.tune runs the study)
# --------------------------------------------------------------------------- #
#: The search space of ``covviz tune``, declared next to the config it searches:
#: field -> (low, high, scale), scale ``"log"`` or ``"linear"`` (floats) or ``"int"``.
#: A dotted name reaches into a nested field (``kinematics.pos_sigma.0``: mode 0 of the
#: position noise). Every range holds the default, which a new study runs first; the
#: ranges span what docs/tuning.md found to matter, about 3× either side of the default.
SEARCH_SPACE: dict[str, tuple[float, float, str]] = {
    "likelihood_sigma": (0.25, 1.0, "log"),
    "template_sigma": (0.001, 0.03, "log"),
    "quadrant_weight": (0.0, 2.0, "linear"),
    "resample_threshold": (0.3, 1.0, "linear"),
    "smooth_sigma": (0.0, 1.5, "linear"),
    "eps": (1e-4, 1e-2, "log"),
    "kinematics.pos_sigma.0": (0.01, 0.12, "log"),
    "kinematics.scale_sigma.0": (0.003, 0.03, "log"),
    "kinematics.velocity_decay": (0.5, 1.0, "linear"),
}


def _field_path(d: dict, name: str) -> tuple:
    """The container and key of the dotted ``name`` inside ``as_dict()``'s output."""
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
    :class:`~covviz.observation.ObservationModel` (built at :meth:`init`), the
    :class:`~covviz.particles.ParticleSet` it steps, and a pool of
    ``config.threads`` threads for the observations, which :meth:`close`
    (or leaving a ``with`` block) shuts down.

    Parameters
    ----------
    config : ManifoldConfig, optional
    rng : numpy.random.Generator or int, optional
        All randomness comes from ``np.random.default_rng(rng)``.

    Notes
    -----
    Besides the standard fields, ``last_record.extras`` holds ``modes``
    ``(n,)`` (the noise mode each particle drew), ``velocity`` ``(2,)`` (of the
    estimate), ``quadrant_distances`` ``(n, 4)`` (None without quadrants) and
    ``likelihood_distances`` ``(n,)``, the distance each particle was weighed
    by (``record.distances`` is the paper's template distance alone). The
    init record's ``model`` is the observation model.

    Examples
    --------
    >>> from covviz.sequences import SyntheticSequence
    >>> seq = SyntheticSequence()
    >>> with ManifoldTracker(rng=0) as tr:
    ...     tr.init(seq.frame(0).image, seq.init_box)
    ...     box = tr.update(seq.frame(1).image)
    """

    name = "manifold"

    def __init__(self, config: ManifoldConfig | None = None, rng=None):
        self.config = config or ManifoldConfig()
        self.rng = np.random.default_rng(rng)
        self.model: ObservationModel | None = None
        self.particles: ParticleSet | None = None
        self.initial_template: np.ndarray | None = None
        self.last_record: FrameRecord | None = None
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
        self.model = model = ObservationModel.from_config(frame, b, cfg)
        x, y, w, h = b
        pose = np.array([[x + w / 2, y + h / 2, 1.0, 0.0]])
        C0 = self._observe(model.prepare(frame), pose).descriptors
        L0 = logm(C0)[0]
        n = cfg.n_particles
        states = np.zeros((n, 6))
        states[:, X], states[:, Y], states[:, SCALE] = pose[0, 0], pose[0, 1], 1.0
        self.initial_template = L0
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
            model=model,
        )

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

        # 1. propagate kinematics and templates
        states, modes = propagate_kinematics(ps.states, cfg.kinematics, model.base_size, self.rng)
        templates = template_walk(ps.templates, self._sigma, self.rng)
        t1 = time.perf_counter()
        tm["propagate"] = t1 - t_start

        # 2. observe descriptors, and each template's distance, at every particle's pose
        gray = model.prepare(frame)
        poses = states[:, POSE]
        ob = self._observe(gray, poses, templates, tm)

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
        est_desc = self._observe(gray, est_pose[None]).descriptors[0]
        box = pose_to_box(est_pose[None], model.base_wh)[0]
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
        self.particles = new
        t5 = time.perf_counter()
        tm["resample"] = t5 - t4
        tm["total"] = t5 - t_start

        self.last_record = FrameRecord(
            index=self._index,
            box=box,
            tracker=self.name,
            pose=est_pose,
            corners=pose_corners(est_pose[None], model.base_wh)[0],
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
            extras={
                "modes": modes,
                "velocity": est_state[[VX, VY]],
                "quadrant_distances": ob.quadrant_distances,
                "likelihood_distances": ob.likelihood_distances,
            },
        )
        return box


def make(n_particles: int | None = None, rng=None, config: ManifoldConfig | None = None) -> ManifoldTracker:
    """Factory for the tracker registry: ``config`` (default: the defaults), optionally another particle count."""
    from dataclasses import replace

    cfg = config or ManifoldConfig()
    if n_particles is not None:
        cfg = replace(cfg, n_particles=n_particles)
    return ManifoldTracker(cfg, rng)


def make_paper(n_particles: int | None = None, rng=None, config: ManifoldConfig | None = None) -> ManifoldTracker:
    """Factory for ``manifold-paper``: ``config`` without the quadrant term (the paper's likelihood)."""
    from dataclasses import replace

    tr = make(n_particles, rng, replace(config or ManifoldConfig(), quadrants=False))
    tr.name = "manifold-paper"
    return tr
