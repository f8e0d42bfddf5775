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

import cv2
import numpy as np

from covviz.descriptor import covariance, quadrant_covariances
from covviz.dynamics import KinematicModel, propagate_kinematics, template_walk
from covviz.features import N_FEATURES, patch_features, pose_corners, pose_to_box, warp_patches
from covviz.particles import (
    ParticleSet,
    effective_sample_size,
    log_likelihood,
    mmse,
    multinomial_resample,
    normalize_log_weights,
    systematic_resample,
)
from covviz.records import FrameRecord
from covviz.spd import expm_taylor, jbld, logdet, logm
from covviz.trackers.base import check_init_box, to_gray

__all__ = [
    "ManifoldConfig",
    "ManifoldTracker",
    "quadrant_distances",
    "quadrant_term",
    "riemann_distance_to_templates",
]

#: Particles per descriptor batch (the unit of work of the observation threads).
OBSERVE_CHUNK = 150


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


def riemann_distance_to_templates(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``d(expm(L_i), B_i)`` for log-space templates ``L`` and SPD observations ``B``.

    ``expm(L)^(-1/2) = expm(-L/2) =: E`` exactly, so the generalized
    eigenvalues of the pair are those of ``E B E``: one matrix exponential
    (:func:`covviz.spd.expm_taylor`, batched products only), two products and
    ``eigvalsh``. Equal to ``covviz.spd.distance_riemann(B, expm(L))`` to
    ~1e-12 relative, and cheaper than an ``eigh`` of every template (the
    distances stage at 600 particles, side by side: 4.4–4.5 vs 4.9–5.1 ms a
    frame).
    The Taylor scaling is chosen per batch, so a distance can differ in the
    last bits with the batch it is computed in; the tracker's batches are
    fixed (:data:`OBSERVE_CHUNK`), so its boxes do not.

    Parameters
    ----------
    L : ndarray, shape (n, d, d)
    B : ndarray, shape (n, d, d)

    Returns
    -------
    ndarray, shape (n,)
    """
    E = expm_taylor(-0.5 * np.asarray(L, dtype=np.float64))
    mu = np.linalg.eigvalsh(E @ B @ E)
    return np.sqrt(np.sum(np.log(np.maximum(mu, 1e-300)) ** 2, axis=-1))


def quadrant_distances(Q: np.ndarray, ref: np.ndarray, ref_logdet: np.ndarray) -> np.ndarray:
    """``sqrt(8·J)`` of each particle's quadrants against the reference quadrants.

    Parameters
    ----------
    Q : ndarray, shape (n, 4, d, d)
        Quadrant descriptors (:func:`covviz.descriptor.quadrant_covariances`).
    ref : ndarray, shape (4, d, d)
    ref_logdet : ndarray, shape (4,)
        :func:`covviz.spd.logdet` of ``ref``.

    Returns
    -------
    ndarray, shape (n, 4)
        The affine-invariant distance to second order (:func:`covviz.spd.jbld`).
    """
    return np.sqrt(8.0 * np.maximum(jbld(ref, Q, logdet_a=ref_logdet), 0.0))


def quadrant_term(q: np.ndarray) -> np.ndarray:
    """Mean of the three smallest squared quadrant distances of each row, ``(n,)``.

    Dropping the largest keeps one occluded (or otherwise changed) quadrant
    from dominating a particle's score.
    """
    q2 = np.asarray(q, dtype=np.float64) ** 2
    k = q2.shape[-1]
    if k < 2:
        return q2.sum(axis=-1)
    return (q2.sum(axis=-1) - q2.max(axis=-1)) / (k - 1)


class ManifoldTracker:
    """Particle filter with per-particle covariance templates (the paper's method).

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
    by (``record.distances`` is the paper's template distance alone).
    ``quadrant_reference`` ``(4, 9, 9)`` holds the quadrants observed at init.

    Examples
    --------
    >>> from covviz.sequences import SyntheticSequence
    >>> seq = SyntheticSequence()
    >>> tr = ManifoldTracker(rng=0)
    >>> tr.init(seq.frame(0).image, seq.init_box)
    >>> box = tr.update(seq.frame(1).image)
    """

    name = "manifold"

    def __init__(self, config: ManifoldConfig | None = None, rng=None):
        self.config = config or ManifoldConfig()
        self.rng = np.random.default_rng(rng)
        self.particles: ParticleSet | None = None
        self.last_record: FrameRecord | None = None
        self._sigma = self.config.sigma_matrix
        self._index = 0
        self._pool: ThreadPoolExecutor | None = None
        self.quadrant_reference: np.ndarray | None = None
        self._quadrant_logdet: np.ndarray | None = None

    def config_dict(self) -> dict:
        return self.config.as_dict()

    # ------------------------------------------------------------------ #
    def _prepare(self, frame: np.ndarray) -> np.ndarray:
        g = to_gray(frame)
        if self._step > 1:
            H, W = g.shape
            g = cv2.resize(
                g, (max(1, round(W / self._step)), max(1, round(H / self._step))), interpolation=cv2.INTER_AREA
            )
        if self.config.smooth_sigma > 0:
            g = cv2.GaussianBlur(g, (0, 0), self.config.smooth_sigma)
        return g

    def _observe_chunk(self, gray: np.ndarray, poses: np.ndarray, templates: np.ndarray | None):
        cfg = self.config
        t0 = time.perf_counter()
        P = warp_patches(gray, poses, self.base_wh, cfg.patch_size, 1, self._step_exact)
        t1 = time.perf_counter()
        F = patch_features(P, gain_normalize=cfg.gain_normalize, quadrants=cfg.quadrants)
        t2 = time.perf_counter()
        if cfg.quadrants:
            C, Q = quadrant_covariances(F, cfg.eps)
        else:
            C, Q = covariance(F, cfg.eps), None
        t3 = time.perf_counter()
        d = q = None
        if templates is not None:
            d = riemann_distance_to_templates(templates, C)
            if Q is not None:
                q = quadrant_distances(Q, self.quadrant_reference, self._quadrant_logdet)
        t4 = time.perf_counter()
        return C, Q, d, q, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)

    def _observe(self, gray: np.ndarray, poses: np.ndarray, templates=None, timings: dict | None = None):
        """Descriptors at ``poses`` and, given templates, each one's distance to them.

        The particles are cut into fixed chunks of :data:`OBSERVE_CHUNK` that
        ``config.threads`` threads share. Every chunk is computed the same way
        whatever the thread count (SIMD kernels round an array's tail
        differently, so the split itself must not depend on ``threads``), so
        threads change the speed and never a box. With threads, a stage's
        timing is its summed time divided by the threads (its share of the wall
        time).

        Returns
        -------
        C : ndarray, shape (n, 9, 9)
        Q : ndarray, shape (n, 4, 9, 9), or None without ``config.quadrants``
            The quadrants' descriptors.
        d : ndarray, shape (n,), or None without templates
        q : ndarray, shape (n, 4), or None without templates or quadrants
            :func:`quadrant_distances` to the reference quadrants.
        """
        parts = [slice(i, min(i + OBSERVE_CHUNK, len(poses))) for i in range(0, len(poses), OBSERVE_CHUNK)]
        k = min(self.config.threads, len(parts))

        def work(sl):
            return self._observe_chunk(gray, poses[sl], None if templates is None else templates[sl])

        if k <= 1:
            outs = [work(sl) for sl in parts]
        else:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=self.config.threads, thread_name_prefix="covviz-observe")
            outs = list(self._pool.map(work, parts))

        def cat(j):
            if outs[0][j] is None:
                return None
            return outs[0][j] if len(outs) == 1 else np.concatenate([o[j] for o in outs])

        C, Q, d, q = cat(0), cat(1), cat(2), cat(3)
        if timings is not None:
            st = [sum(o[4][j] for o in outs) / k for j in range(4)]
            timings["warp"], timings["features"], timings["covariance"] = st[:3]
            if templates is not None:
                timings["distances"] = st[3]
        return C, Q, d, q

    def observe(self, frame: np.ndarray, poses) -> np.ndarray:
        """Descriptors the tracker would observe at ``poses`` in ``frame``, ``(n, 9, 9)``.

        The same preprocessing (grey, anti-aliasing, smoothing) and features as
        in :meth:`update`; for diagnostics such as likelihood maps.
        """
        if self.particles is None:
            raise RuntimeError("call init(frame, box) before observe(frame, poses)")
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
        return self._observe(self._prepare(frame), poses)[0]

    def likelihood_distances(self, frame: np.ndarray, poses, template_log) -> np.ndarray:
        """The distance that enters the likelihood, at ``poses``, for one template, ``(n,)``.

        ``d(expm(template_log), C*)`` at each pose, combined with the quadrant
        term when ``config.quadrants`` is on: what :meth:`update` would weigh
        a particle with this template at that pose by. For diagnostics such as
        likelihood maps.
        """
        if self.particles is None:
            raise RuntimeError("call init(frame, box) before likelihood_distances(frame, poses, template_log)")
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
        L = np.broadcast_to(np.asarray(template_log, dtype=np.float64), (len(poses), N_FEATURES, N_FEATURES))
        _, _, d, q = self._observe(self._prepare(frame), poses, np.ascontiguousarray(L))
        return self._likelihood_distance(d, q)

    def _likelihood_distance(self, d: np.ndarray, q: np.ndarray | None) -> np.ndarray:
        """``sqrt(d² + quadrant_weight · quadrant_term(q))``, or ``d`` without quadrants."""
        return d if q is None else np.sqrt(d * d + self.config.quadrant_weight * quadrant_term(q))

    def init(self, frame: np.ndarray, box) -> None:
        """Initialise every particle at ``box`` with the template observed there."""
        cfg = self.config
        t0 = time.perf_counter()
        b = check_init_box(box, np.shape(frame))
        x, y, w, h = b
        self.base_wh = (float(w), float(h))
        self.base_size = float(np.sqrt(w * h))
        per_sample = min(w, h) / cfg.patch_size
        self._step = int(per_sample // 2) if (cfg.antialias and per_sample >= 4) else 1
        gray = self._prepare(frame)
        # Exact x and y factors of the resize (the downsampled size is rounded).
        H, W = np.shape(frame)[:2]
        self._step_exact = (W / gray.shape[1], H / gray.shape[0]) if self._step > 1 else 1.0
        pose = np.array([[x + w / 2, y + h / 2, 1.0, 0.0]])
        C0, Q0 = self._observe(gray, pose)[:2]
        L0 = logm(C0)[0]
        if Q0 is not None:
            self.quadrant_reference = Q0[0]
            self._quadrant_logdet = logdet(Q0[0])
        n = cfg.n_particles
        states = np.zeros((n, 6))
        states[:, 0], states[:, 1], states[:, 4] = pose[0, 0], pose[0, 1], 1.0
        self.initial_template = L0
        self.particles = ParticleSet(states, np.broadcast_to(L0, (n, *L0.shape)).copy(), np.full(n, -np.log(n)))
        self._index = 0
        self.last_record = FrameRecord(
            index=0,
            box=b.copy(),
            tracker=self.name,
            pose=pose[0].copy(),
            corners=pose_corners(pose, self.base_wh)[0],
            estimate_template=L0,
            estimate_descriptor=C0[0],
            timings={"total": time.perf_counter() - t0},
        )

    def update(self, frame: np.ndarray) -> np.ndarray:
        """Track into ``frame``; return the estimated box ``x, y, w, h``."""
        if self.particles is None:
            raise RuntimeError("call init(frame, box) before update(frame)")
        cfg = self.config
        tm: dict[str, float] = {}
        t_start = time.perf_counter()
        ps = self.particles
        self._index += 1

        # 1. propagate kinematics and templates
        states, modes = propagate_kinematics(ps.states, cfg.kinematics, self.base_size, self.rng)
        templates = template_walk(ps.templates, self._sigma, self.rng)
        t = time.perf_counter()
        tm["propagate"] = t - t_start

        # 2. observe descriptors at every particle's pose
        gray = self._prepare(frame)
        poses = states[:, [0, 1, 4, 5]]
        obs, _, d, q = self._observe(gray, poses, templates, tm)

        # 3. weigh
        t2 = time.perf_counter()
        d_eff = self._likelihood_distance(d, q)
        lw = normalize_log_weights(ps.log_weights + log_likelihood(d_eff, cfg.likelihood_sigma))
        ess = effective_sample_size(lw)

        # 4. estimate (MMSE of the pose; weighted log-Euclidean mean of the templates)
        est_state = mmse(states, lw)
        est_pose = est_state[[0, 1, 4, 5]]
        est_template = mmse(templates, lw)
        est_desc = self._observe(gray, est_pose[None])[0][0]
        box = pose_to_box(est_pose[None], self.base_wh)[0]
        t3 = time.perf_counter()
        tm["weights"] = t3 - t2

        # 5. resample
        resampled = ess < cfg.resample_threshold * cfg.n_particles
        idx = None
        new = ParticleSet(states, templates, lw)
        if resampled:
            res = systematic_resample if cfg.resampling == "systematic" else multinomial_resample
            idx = res(lw, self.rng)
            new = new.take(idx)
        self.particles = new
        t4 = time.perf_counter()
        tm["resample"] = t4 - t3
        tm["total"] = t4 - t_start

        self.last_record = FrameRecord(
            index=self._index,
            box=box,
            tracker=self.name,
            pose=est_pose,
            corners=pose_corners(est_pose[None], self.base_wh)[0],
            particle_poses=poses,
            particle_corners=pose_corners(poses, self.base_wh),
            log_weights=lw,
            ess=ess,
            resampled=bool(resampled),
            resample_indices=idx,
            templates=templates,
            descriptors=obs,
            distances=d,
            estimate_template=est_template,
            estimate_descriptor=est_desc,
            timings=tm,
            extras={
                "modes": modes,
                "velocity": est_state[2:4],
                "quadrant_distances": q,
                "likelihood_distances": d_eff,
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
