"""The observation model: what a covariance tracker sees at any pose of a frame.

One frozen object, built once when a tracker starts (:meth:`ObservationModel.build`,
from the first frame, the initial box and the tracker's config), holds
everything that turns a frame and a pose into the number the particle filter
weighs by:

* the target's base size ``(w, h)`` at scale 1, the anti-aliasing downsample
  (an integer step and its exact ``(sx, sy)`` factors), the smoothing;
* the patch size, the descriptor regulariser and the gain normalisation of
  the features (:mod:`covviz.model.features`, :mod:`covviz.model.descriptor`);
* the quadrant references observed at the initial box and their log-dets,
  the quadrant weight and the likelihood's σ.

Its methods are pure: :meth:`~ObservationModel.prepare` a frame once, then
:meth:`~ObservationModel.observe` descriptors (and, given templates, their
distances) at any poses. The tracker weighs its particles with exactly these
methods, and so do the diagnostics (likelihood maps, the drift diagnosis) and
the paper's MDS figures, which receive the model in the tracker's init record
(:attr:`covviz.records.FrameRecord.model`): they never call the live tracker.

The likelihood
    ``p(z | x, C) ∝ exp(-d_eff² / 2σ²)`` with ``d_eff² = d(C, C*)² + Σ_k w_k ·
    term_k`` (:meth:`ObservationModel.likelihood_distance`): the paper's
    ``d(C, C*)²`` plus named, separately weighted terms, each reported per
    pose in :attr:`Observation.terms` (weights: :attr:`ObservationModel.term_weights`):

    * ``"quadrants"``: the mean of the three smallest ``q_k²``, ``q_k =
      sqrt(8·J)`` (:func:`covviz.model.spd.distance_jbld`) of each quadrant of the
      region against the one observed at the initial box (Porikli, Tuzel and
      Meer, CVPR 2006). Dropping the worst quadrant keeps a partial occlusion
      from dominating a particle's score. (Or, given a :class:`QuadrantState`,
      a reliability-weighted mean against online references.)
    * ``"colour"``: the foreground/background colour term of
      :mod:`covviz.model.fgbg`, given the frame's :meth:`ObservationModel.colour_map`
      (its histograms are the tracker's online state).
    * ``"context"``: :meth:`ObservationModel.context_terms`.

    Which terms a model has is fixed when it is built (``manifold-paper``:
    none). With ``grad_normalize`` the descriptors themselves change (the
    derivative features are divided by their patch mean,
    :func:`covviz.model.features.normalize_gradients`): then the template, the
    quadrants and the references all see sampling-invariant features.

Determinism
    Poses are cut into fixed chunks of :data:`OBSERVE_CHUNK`, computed the same
    way whatever executor (and however many threads) runs them, so results do
    not depend on the thread count: SIMD kernels round an array's tail
    differently, and the Taylor scaling of :func:`covviz.model.spd.distance_riemann_log`
    is chosen per batch, so the split itself must never depend on the threads.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from covviz.config import ConfigError, Spec, check, from_mapping
from covviz.model import fgbg
from covviz.model.descriptor import covariance, quadrant_covariances
from covviz.model.features import N_FEATURES, normalize_gradients, patch_features, pose_to_box, warp_patches
from covviz.model.image import check_init_box, to_gray
from covviz.model.particles import log_likelihood
from covviz.model.spd import distance_jbld, distance_riemann_log, logdet

__all__ = [
    "OBSERVATION_SPECS",
    "OBSERVE_CHUNK",
    "Observation",
    "ObservationConfig",
    "ObservationModel",
    "QuadrantState",
    "box_to_pose",
    "quadrant_term",
    "update_quadrant_state",
]

#: Poses per descriptor batch: the unit of work of the observation threads (fixed: see the module docstring).
OBSERVE_CHUNK = 150
#: Anti-aliasing: downsample the frame when a patch sample covers at least this many pixels ...
ANTIALIAS_MIN_PIXELS = 4
#: ... by an integer step, ``floor(pixels per sample / ANTIALIAS_DIVISOR)``.
ANTIALIAS_DIVISOR = 2


def quadrant_term(q: np.ndarray, reliability: np.ndarray | None = None) -> np.ndarray:
    """Mean of the three smallest squared quadrant distances of each row, ``(n,)``.

    Dropping the largest keeps one occluded (or otherwise changed) quadrant
    from dominating a particle's score. Given per-quadrant ``reliability``
    weights ``(4,)`` instead (:class:`QuadrantState`), the reliability-weighted
    mean ``Σ r_k q_k² / Σ r_k`` of all four.
    """
    q2 = np.asarray(q, dtype=np.float64) ** 2
    if reliability is not None:
        r = np.asarray(reliability, dtype=np.float64)
        return q2 @ (r / r.sum())
    k = q2.shape[-1]
    if k < 2:
        return q2.sum(axis=-1)
    return (q2.sum(axis=-1) - q2.max(axis=-1)) / (k - 1)


@dataclass(frozen=True, slots=True, eq=False)
class QuadrantState:
    """Online state of the quadrant term: references and reliabilities, replaced every frame.

    Without it the model scores quadrants against the references observed at
    the initial box and drops the worst (the default). With it (see
    :func:`update_quadrant_state`), each quadrant's reference may follow the
    target slowly, and its weight in the term is its *reliability*: the
    inverse of its recent mismatch at the estimate (CSRT weighs its channels
    by reliability in the same spirit), so a quadrant that changes with every
    stride, or stays occluded, counts less than one that holds still.

    Attributes
    ----------
    reference : ndarray, shape (4, 9, 9)
    logdet : ndarray, shape (4,)
    noise : ndarray, shape (4,)
        Running mean of each quadrant's ``q_k²`` at the estimate.
    """

    reference: np.ndarray
    logdet: np.ndarray
    noise: np.ndarray

    @property
    def reliability(self) -> np.ndarray:
        """``mean(noise) / noise_k``, clipped to [1/4, 4]: the quadrants' weights (their scale is irrelevant)."""
        n = np.maximum(self.noise, 1e-12)
        return np.clip(n.mean() / n, 0.25, 4.0)


def update_quadrant_state(
    state: QuadrantState, q_est: np.ndarray, Q_est: np.ndarray, rate: float, ref_rate: float = 0.0,
    gate: float = np.inf,
) -> QuadrantState:
    """The state after an estimate whose quadrants ``Q_est`` (4, 9, 9) are at distances ``q_est`` (4,).

    ``noise ← (1 − rate)·noise + rate·q_est²``. With ``ref_rate > 0``, each
    reference whose ``q_k²`` is below ``gate · noise_k`` (a good match) takes a
    log-Euclidean step of ``ref_rate`` towards ``Q_est[k]``.
    """
    q2 = np.asarray(q_est, dtype=np.float64) ** 2
    noise = (1 - rate) * state.noise + rate * q2
    ref, ld = state.reference, state.logdet
    if ref_rate > 0:
        good = q2 < gate * state.noise
        if good.any():
            from covviz.model.spd import expm, logm

            new = expm((1 - ref_rate) * logm(ref[good]) + ref_rate * logm(np.asarray(Q_est)[good]))
            ref = ref.copy()
            ref[good] = new
            ld = logdet(ref)
    return QuadrantState(_frozen(ref), _frozen(ld), _frozen(noise))


def box_to_pose(box, base_wh) -> np.ndarray:
    """An axis-aligned box ``x, y, w, h`` as a pose ``cx, cy, scale, theta`` for a region of ``base_wh``.

    The scale is the geometric mean ``sqrt(w h / (w0 h0))``; theta is 0 (OTB
    ground truth is unrotated).
    """
    x, y, w, h = np.asarray(box, dtype=np.float64).reshape(4)
    s = float(np.sqrt(max(w * h, 1e-12) / (base_wh[0] * base_wh[1])))
    return np.array([x + w / 2, y + h / 2, s, 0.0])


@dataclass(frozen=True, slots=True, eq=False)
class Observation:
    """What the model observed at a batch of poses.

    Attributes
    ----------
    descriptors : ndarray, shape (n, 9, 9)
        ``C*`` at each pose (SPD).
    quadrants : ndarray, shape (n, 4, 9, 9), or None
        The quadrants' descriptors (None without quadrants).
    distances : ndarray, shape (n,), or None
        ``d(C_i, C*_i)`` of each pose's template (None without templates).
    quadrant_distances : ndarray, shape (n, 4), or None
        ``sqrt(8·J)`` of each quadrant against the reference (None without
        templates or quadrants).
    likelihood_distances : ndarray, shape (n,), or None
        ``d_eff``, what the likelihood weighs by (None without templates).
    terms : dict of str to ndarray, shape (n,)
        The likelihood's extra terms at each pose, unweighted, by name
        (:meth:`ObservationModel.term_weights` holds their weights):
        ``"quadrants"`` (:func:`quadrant_term`), ``"colour"``
        (:func:`covviz.model.fgbg.colour_term`), those the model has. With them
        ``d_eff² = d² + Σ_k weight_k · terms[k]``.
    """

    descriptors: np.ndarray
    quadrants: np.ndarray | None = None
    distances: np.ndarray | None = None
    quadrant_distances: np.ndarray | None = None
    likelihood_distances: np.ndarray | None = None
    terms: dict = field(default_factory=dict)


def _frozen(a: np.ndarray | None) -> np.ndarray | None:
    if a is None:
        return None
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class ObservationConfig:
    """How a covariance tracker observes and weighs: every observation field, with its default, once.

    :class:`ObservationModel` is built from it (:meth:`ObservationModel.build`);
    ``ManifoldConfig.observation`` holds the tracker's, and the drift diagnosis
    probes trackers without a covariance model with the default one (the default
    tracker's model). Each field's type and range is in :data:`OBSERVATION_SPECS`.

    Attributes
    ----------
    patch_size : int
        Side of the warped patch (32 in the paper).
    eps : float
        Shrinkage of each descriptor towards ``(tr C / d)·I``.
    gain_normalize : bool
        Divide each patch's intensity and derivative features by its mean
        intensity (descriptors invariant to illumination gain). Not in the paper.
    grad_normalize : float
        Divide the derivative features by their patch mean to this power, 0 to 1
        (:func:`covviz.model.features.normalize_gradients`): descriptors that do not
        depend on how finely a region is sampled. Not in the paper.
    grad_floor : float
        Floor of the patch mean ``|grad I|`` that ``grad_normalize`` divides the first
        derivatives by (0: only 1e-6): a textureless target keeps its small absolute
        derivatives rather than amplified noise.
    smooth_sigma : float
        Gaussian pre-smoothing of the (downsampled) frame, pixels; 0: none.
    antialias : bool
        Downsample the frame (area averaging) when a patch sample spans
        ``ANTIALIAS_MIN_PIXELS`` or more pixels.
    quadrants : bool
        The quadrant term in ``d_eff²`` (Porikli, Tuzel, Meer 2006). Not in the paper.
    quadrant_weight : float
    likelihood_sigma : float
        σ of the likelihood ``exp(-d_eff² / 2σ²)``.
    colour_weight : float
        Weight of the foreground/background colour term (:mod:`covviz.model.fgbg`); 0: off.
    colour_reliability : float
        Exponent of the colour term's reliability gain; 0: a fixed weight.
    context_weight : float
        Weight of the context term (needs ``quadrants``); 0: off.
    context_scale : float
        The context term's reference: the initial box grown by this factor.
    jit : bool
        Observe with the compiled kernels (:mod:`covviz.model.kernels`) when numba is
        installed and ``COVVIZ_NO_JIT`` is not set; ``False``: the numpy path.
    """

    patch_size: int = 32
    eps: float = 1e-3
    gain_normalize: bool = True
    grad_normalize: float = 1.0
    grad_floor: float = 0.3
    smooth_sigma: float = 0.0
    antialias: bool = True
    quadrants: bool = True
    quadrant_weight: float = 1.0
    likelihood_sigma: float = 0.5
    colour_weight: float = 10.0
    colour_reliability: float = 0.0
    context_weight: float = 0.0
    context_scale: float = 1.25
    jit: bool = True

    def __post_init__(self):
        check(self, OBSERVATION_SPECS)
        if self.quadrants and self.patch_size % 2:
            raise ConfigError(f"ObservationConfig.patch_size: quadrants need an even patch_size, got {self.patch_size}")
        if self.context_weight > 0 and not self.quadrants:
            raise ConfigError("ObservationConfig.context_weight needs quadrants=true (it compares quadrants)")

    @classmethod
    def from_dict(cls, d: dict) -> ObservationConfig:
        """The config of a JSON object of its fields (the rest default); unknown keys refused."""
        return from_mapping(cls, d, OBSERVATION_SPECS)


#: Each field of :class:`ObservationConfig`: its type and range (:mod:`covviz.config`).
OBSERVATION_SPECS: dict[str, Spec] = {
    "patch_size": Spec("int", 4, 128),  # the cost grows as its square: 2000 took 90 s a frame
    "eps": Spec("float", 0, 1, lo_open=True),
    "gain_normalize": Spec("bool"),
    "grad_normalize": Spec("float", 0, 1),
    "grad_floor": Spec("float", 0),
    "smooth_sigma": Spec("float", 0, 20),
    "antialias": Spec("bool"),
    "quadrants": Spec("bool"),
    "quadrant_weight": Spec("float", 0),
    "likelihood_sigma": Spec("float", 0, lo_open=True),
    "colour_weight": Spec("float", 0),
    "colour_reliability": Spec("float", 0),
    "context_weight": Spec("float", 0),
    "context_scale": Spec("float", 1, lo_open=True),
    "jit": Spec("bool"),
}


@dataclass(frozen=True, eq=False)
class ObservationModel:
    """The frozen observation model of a covariance tracker (see the module docstring).

    Build it with :meth:`build`; every attribute is fixed from then on and its
    arrays are read-only, so one model can be shared by threads (the
    tracker's, the recorder's).

    Attributes
    ----------
    base_wh : (float, float)
        Width and height of the target region at scale 1, pixels.
    step : int
        Integer anti-aliasing downsample of the frame (1: none).
    step_xy : (float, float)
        Its exact x and y factors (the downsampled size is rounded).
    patch_size : int
    eps : float
        Descriptor regulariser.
    gain_normalize : bool
    grad_normalize : float
        Divide the derivative features by the patch's mean derivative to
        this power (:func:`covviz.model.features.normalize_gradients`; 1: fully,
        0: not): descriptors that do not depend on how finely a region is
        sampled.
    grad_floor : float
        The floor of the mean ``|grad I|`` that divides the first derivatives
        (:func:`covviz.model.features.normalize_gradients`' ``floor``; 0: only
        1e-6): a textureless patch keeps its small absolute derivatives.
    smooth_sigma : float
        Gaussian smoothing of the (downsampled) frame, pixels; 0: none.
    likelihood_sigma : float
        σ of the likelihood ``exp(-d_eff² / 2σ²)``.
    quadrant_weight : float
    quadrant_reference : ndarray, shape (4, 9, 9), or None
        The quadrants observed at the initial box (None: the paper's
        likelihood, without the quadrant term).
    quadrant_logdet : ndarray, shape (4,), or None
        Their log-determinants.
    colour_reliability : float
        Exponent of the colour term's reliability gain
        (:attr:`covviz.model.fgbg.ColourMap.gain`); 0: none.
    colour_weight : float
        Weight of the foreground/background colour term
        (:func:`covviz.model.fgbg.colour_term`) in ``d_eff²``; 0: no colour term.
        Its online state (the histograms) is the tracker's
        (:class:`covviz.model.fgbg.ColourModel`), passed in through
        :meth:`colour_map`.
    jit : bool
        Observe with the compiled kernels (:mod:`covviz.model.kernels`) when they are
        available (``COVVIZ_NO_JIT=1`` or no numba: the numpy path, always).
        The kernels fuse the warp, the features and the moments per pose and
        agree with the numpy path to ~1e-3 in a distance (they are closer to
        float64 arithmetic than it is); the timings then report the fused
        kernel under ``features``.
    """

    base_wh: tuple[float, float]
    step: int = 1
    step_xy: tuple[float, float] = (1.0, 1.0)
    patch_size: int = 32
    eps: float = 1e-3
    gain_normalize: bool = True
    grad_normalize: float = 0.0
    grad_floor: float = 0.0
    smooth_sigma: float = 0.0
    likelihood_sigma: float = 0.5
    quadrant_weight: float = 1.0
    quadrant_reference: np.ndarray | None = field(default=None, repr=False)
    quadrant_logdet: np.ndarray | None = field(default=None, repr=False)
    colour_weight: float = 0.0
    colour_reliability: float = 0.0
    context_weight: float = 0.0
    context_reference: np.ndarray | None = field(default=None, repr=False)
    context_logdet: np.ndarray | None = field(default=None, repr=False)
    jit: bool = True

    def __post_init__(self):
        object.__setattr__(self, "grad_normalize", float(self.grad_normalize))
        object.__setattr__(self, "grad_floor", float(self.grad_floor))
        object.__setattr__(self, "base_wh", (float(self.base_wh[0]), float(self.base_wh[1])))
        object.__setattr__(self, "step_xy", (float(self.step_xy[0]), float(self.step_xy[1])))
        object.__setattr__(self, "quadrant_reference", _frozen(self.quadrant_reference))
        object.__setattr__(self, "quadrant_logdet", _frozen(self.quadrant_logdet))
        object.__setattr__(self, "context_reference", _frozen(self.context_reference))
        object.__setattr__(self, "context_logdet", _frozen(self.context_logdet))
        if (self.quadrant_reference is None) != (self.quadrant_logdet is None):
            raise ValueError("quadrant_reference and quadrant_logdet come together")

    # ------------------------------------------------------------------ #
    @classmethod
    def build(cls, frame: np.ndarray, box, config: ObservationConfig | None = None) -> ObservationModel:
        """The model of a tracker started on ``frame`` at ``box`` (``x, y, w, h``, 0-based pixels).

        Fixes the base size, the anti-aliasing step (frames are downsampled by
        an integer step when a patch sample spans ``ANTIALIAS_MIN_PIXELS`` or
        more pixels) and, with ``quadrants``, observes the quadrant references
        at the box. ``config`` defaults to :class:`ObservationConfig`'s defaults
        (the default tracker's).
        """
        c = config or ObservationConfig()
        x, y, w, h = check_init_box(box, np.shape(frame))
        per_sample = min(w, h) / c.patch_size
        step = int(per_sample // ANTIALIAS_DIVISOR) if (c.antialias and per_sample >= ANTIALIAS_MIN_PIXELS) else 1
        H, W = np.shape(frame)[:2]
        step_xy = (1.0, 1.0)
        if step > 1:
            shape = _downsampled_shape(H, W, step)
            step_xy = (W / shape[1], H / shape[0])
        model = cls(
            base_wh=(w, h),
            step=step,
            step_xy=step_xy,
            patch_size=c.patch_size,
            eps=c.eps,
            gain_normalize=c.gain_normalize,
            grad_normalize=c.grad_normalize,
            grad_floor=c.grad_floor,
            smooth_sigma=c.smooth_sigma,
            likelihood_sigma=c.likelihood_sigma,
            quadrant_weight=c.quadrant_weight,
            colour_weight=c.colour_weight,
            colour_reliability=c.colour_reliability,
            jit=c.jit,
        )
        if c.quadrants:
            g0 = model.prepare(frame)
            Q0 = model._observe_quadrants(g0, np.array([[x + w / 2, y + h / 2, 1.0, 0.0]]))[0]
            extra = {}
            if c.context_weight > 0:
                Qc = model._observe_quadrants(g0, np.array([[x + w / 2, y + h / 2, c.context_scale, 0.0]]))[0]
                extra = {"context_reference": Qc, "context_logdet": logdet(Qc), "context_weight": c.context_weight}
            model = cls(**{**model._fields(), "quadrant_reference": Q0, "quadrant_logdet": logdet(Q0), **extra})
        return model

    def _fields(self) -> dict:
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    @property
    def quadrants(self) -> bool:
        """Whether the likelihood has the quadrant term."""
        return self.quadrant_reference is not None

    @property
    def colour(self) -> bool:
        """Whether the likelihood has the foreground/background colour term."""
        return self.colour_weight > 0

    @property
    def term_weights(self) -> dict[str, float]:
        """The weight of each extra term of ``d_eff²`` the model has, by name (see :class:`Observation`)."""
        w = {}
        if self.quadrants:
            w["quadrants"] = self.quadrant_weight
        if self.colour:
            w["colour"] = self.colour_weight
        if self.context:
            w["context"] = self.context_weight
        return w

    @property
    def context(self) -> bool:
        """Whether the likelihood has the context term (quadrants nearer the initial box's surroundings)."""
        return self.context_reference is not None and self.context_weight > 0

    def context_terms(self, Q: np.ndarray, q: np.ndarray) -> np.ndarray:
        """``max(0, mean_k (q_k² − c_k²))`` per pose, ``(n,)``: how much more each pose's quadrants ``Q``
        resemble those of the initial box grown by ``context_scale`` (``c_k``) than the references
        (``q_k``, the quadrant distances).

        Positive when a box has taken in the target's surroundings: the
        quadrant term alone barely rises as a box grows past the target (its
        quadrants keep the target's part), this one does.
        """
        if self.compiled:
            c = _kernels().quadrant_distances_fast(Q, self.context_reference, self.context_logdet)
        else:
            c = distance_jbld(self.context_reference, Q, logdet_a=self.context_logdet)
        return np.maximum(np.mean(np.asarray(q) ** 2 - c**2, axis=-1), 0.0)

    @property
    def base_size(self) -> float:
        """``sqrt(w·h)`` of the initial box, pixels."""
        return float(np.sqrt(self.base_wh[0] * self.base_wh[1]))

    def describe(self) -> str:
        """One line naming the model's settings (for figure captions and recordings)."""
        w, h = self.base_wh
        aa = f"frame downsampled ×{self.step_xy[0]:.2f}×{self.step_xy[1]:.2f}" if self.step > 1 else "full resolution"
        return (
            f"{self.patch_size}×{self.patch_size} patches of a {w:.0f}×{h:.0f} region at scale 1, {aa}, "
            f"{'gain-normalised' if self.gain_normalize else 'raw'} features"
            f"{f' (derivatives normalised, power {self.grad_normalize:g}' if self.grad_normalize else ''}"
            f"{f', floor {self.grad_floor:g}' if (self.grad_normalize and self.grad_floor) else ''}"
            f"{')' if self.grad_normalize else ''}"
            f", ε={self.eps:g}, "
            f"σ={self.likelihood_sigma:g}, "
            + (f"quadrant term (weight {self.quadrant_weight:g})" if self.quadrants else "the paper's likelihood")
            + (f", colour term (weight {self.colour_weight:g})" if self.colour else "")
        )

    # ------------------------------------------------------------------ #
    def prepare(self, frame: np.ndarray) -> np.ndarray:
        """A frame as the model samples it: float32 grey in ``[0, 1]``, downsampled and smoothed as set."""
        g = to_gray(frame)
        if self.step > 1:
            H, W = g.shape
            h, w = _downsampled_shape(H, W, self.step)
            g = cv2.resize(g, (w, h), interpolation=cv2.INTER_AREA)
        if self.smooth_sigma > 0:
            g = cv2.GaussianBlur(g, (0, 0), self.smooth_sigma)
        return g

    def colour_map(self, frame: np.ndarray, state: fgbg.ColourModel | None) -> fgbg.ColourMap | None:
        """The foreground probability of a (raw, colour) ``frame`` given the colour state; None without the term."""
        if not self.colour or state is None:
            return None
        return fgbg.colour_map(frame, state, self.colour_reliability, compiled=self.compiled)

    def colour_terms(self, cmap: fgbg.ColourMap, poses) -> np.ndarray:
        """The colour term (unweighted) of each pose's axis-aligned box (:func:`covviz.model.features.pose_to_box`), ``(n,)``."""
        return fgbg.colour_term(cmap, pose_to_box(np.asarray(poses, dtype=np.float64).reshape(-1, 4), self.base_wh))

    def _sample_step(self):
        return self.step_xy if self.step > 1 else 1.0

    @property
    def compiled(self) -> bool:
        """Whether this model observes with the compiled kernels (``jit`` and available)."""
        return self.jit and _kernels().JIT_ENABLED

    def _observe_quadrants(self, gray: np.ndarray, poses: np.ndarray) -> np.ndarray:
        return self.quadrant_descriptors(gray, poses)[1]

    def _template_distances(self, L: np.ndarray, C: np.ndarray) -> np.ndarray:
        if self.compiled:
            return _kernels().template_distances_fast(L, np.broadcast_to(C, L.shape))
        return distance_riemann_log(L, C)

    def initial_quadrant_state(self) -> QuadrantState | None:
        """The :class:`QuadrantState` of the initial box: its references, equal reliabilities; None without quadrants."""
        if not self.quadrants:
            return None
        return QuadrantState(self.quadrant_reference, self.quadrant_logdet, _frozen(np.ones(4)))

    def quadrant_distances(self, Q: np.ndarray, state: QuadrantState | None = None) -> np.ndarray:
        """``sqrt(8·J)`` of quadrants ``Q`` (n, 4, 9, 9) against the references (the state's, if given), ``(n, 4)``."""
        ref, ld = (self.quadrant_reference, self.quadrant_logdet) if state is None else (state.reference, state.logdet)
        if self.compiled:
            return _kernels().quadrant_distances_fast(Q, ref, ld)
        return distance_jbld(ref, Q, logdet_a=ld)

    def _chunk(self, gray: np.ndarray, poses: np.ndarray, templates: np.ndarray | None, qstate=None, out=None):
        """One chunk: descriptors (and distances), with the seconds of its four stages.

        ``out``: the batch's ``(C, Q)`` rows of this chunk, which the compiled kernel writes into.
        """
        if self.compiled:
            return self._chunk_compiled(gray, poses, templates, qstate, out)
        t0 = time.perf_counter()
        P = warp_patches(gray, poses, self.base_wh, self.patch_size, 1, self._sample_step())
        t1 = time.perf_counter()
        F = patch_features(P, gain_normalize=self.gain_normalize, quadrants=self.quadrants)
        if self.grad_normalize > 0:
            F = normalize_gradients(F, self.grad_normalize, self.grad_floor)
        t2 = time.perf_counter()
        if self.quadrants:
            C, Q = quadrant_covariances(F, self.eps)
        else:
            C, Q = covariance(F, self.eps), None
        t3 = time.perf_counter()
        d = q = None
        if templates is not None:
            d = distance_riemann_log(templates, C)
            if Q is not None:
                q = self.quadrant_distances(Q, qstate)
        t4 = time.perf_counter()
        return C, Q, d, q, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)

    def _chunk_compiled(self, gray: np.ndarray, poses: np.ndarray, templates: np.ndarray | None, qstate=None,
                        out=None):
        """:meth:`_chunk` with the compiled kernels: warp, features and covariance in one (timed as ``features``)."""
        t0 = time.perf_counter()
        C, Q = _kernels().warp_descriptors_fast(
            gray, poses, self.base_wh, self.patch_size, self._sample_step(), self.eps, self.gain_normalize,
            self.quadrants, self.grad_normalize, self.grad_floor, out=out,
        )
        t1 = time.perf_counter()
        d = q = None
        if templates is not None:
            d = _kernels().template_distances_fast(templates, C)
            if Q is not None:
                q = self.quadrant_distances(Q, qstate)
        t2 = time.perf_counter()
        return C, Q, d, q, (0.0, t1 - t0, 0.0, t2 - t1)

    def observe(
        self,
        gray: np.ndarray,
        poses,
        templates: np.ndarray | None = None,
        executor=None,
        threads: int = 1,
        timings: dict | None = None,
        colour: fgbg.ColourMap | None = None,
        quadrant_state: QuadrantState | None = None,
    ) -> Observation:
        """Descriptors at ``poses`` of a prepared frame and, given templates, their distances.

        Parameters
        ----------
        gray : ndarray, shape (H, W), float32
            A frame from :meth:`prepare`.
        poses : ndarray, shape (n, 4)
            ``cx, cy, scale, theta`` in the frame's (full-resolution) pixels.
        templates : ndarray, shape (n, 9, 9) or (9, 9), optional
            Log-space templates, one per pose or one for all.
        executor : concurrent.futures.Executor, optional
            Runs the chunks (:data:`OBSERVE_CHUNK` poses each); None: in this thread.
        threads : int
            The executor's workers (for the stage timings: a stage's summed
            time is divided by the workers that shared it).
        timings : dict, optional
            Filled with the seconds of ``warp``, ``features``, ``covariance``
            and (with templates) ``distances``.
        colour : ColourMap, optional
            The frame's :meth:`colour_map`: with templates and a colour
            weight, the colour term joins ``d_eff``.
        quadrant_state : QuadrantState, optional
            Online quadrant references and reliabilities; None: the initial
            references, worst quadrant dropped.

        Returns
        -------
        Observation
        """
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
        n = len(poses)
        t_colour = None
        if templates is not None and colour is not None and self.colour:
            t_colour = self.colour_terms(colour, poses)
        if templates is not None:
            L = np.asarray(templates, dtype=np.float64)
            if L.shape == (N_FEATURES, N_FEATURES):
                L = np.broadcast_to(L, (n, N_FEATURES, N_FEATURES))
            if L.shape != (n, N_FEATURES, N_FEATURES):
                raise ValueError(f"templates must have shape ({n}, 9, 9) or (9, 9); got {L.shape}")
            templates = np.ascontiguousarray(L)
        if n == 0:
            empty = np.zeros((0, N_FEATURES, N_FEATURES))
            return Observation(empty, np.zeros((0, 4, N_FEATURES, N_FEATURES)) if self.quadrants else None,
                               None if templates is None else np.zeros(0),
                               np.zeros((0, 4)) if (templates is not None and self.quadrants) else None,
                               None if templates is None else np.zeros(0),
                               {} if templates is None else self.terms(np.zeros((0, 4)) if self.quadrants else None,
                                                                       t_colour, quadrant_state,
                                                                       np.zeros(0) if self.context else None))
        parts = [slice(i, min(i + OBSERVE_CHUNK, n)) for i in range(0, n, OBSERVE_CHUNK)]
        # The compiled kernel writes each chunk's descriptors into its rows of the batch's arrays
        # (no concatenation after: 1.9 MB a frame at 600 particles).
        into = None
        if self.compiled and len(parts) > 1:
            into = (np.empty((n, N_FEATURES, N_FEATURES)),
                    np.empty((n, 4, N_FEATURES, N_FEATURES)) if self.quadrants else None)

        def work(sl):
            out = None if into is None else (into[0][sl], None if into[1] is None else into[1][sl])
            return self._chunk(gray, poses[sl], None if templates is None else templates[sl], quadrant_state, out)

        if executor is None or len(parts) == 1:
            outs = [work(sl) for sl in parts]
            share = 1
        else:
            outs = list(executor.map(work, parts))
            share = max(1, min(int(threads), len(parts)))

        def cat(j):
            if into is not None and j < 2:
                return into[j]
            if outs[0][j] is None:
                return None
            return outs[0][j] if len(outs) == 1 else np.concatenate([o[j] for o in outs])

        C, Q, d, q = cat(0), cat(1), cat(2), cat(3)
        if timings is not None:
            st = [sum(o[4][j] for o in outs) / share for j in range(4)]
            timings["warp"], timings["features"], timings["covariance"] = st[:3]
            if templates is not None:
                timings["distances"] = st[3]
        if d is None:
            return Observation(C, Q)
        t_context = self.context_terms(Q, q) if (self.context and q is not None) else None
        terms = self.terms(q, t_colour, quadrant_state, t_context)
        return Observation(C, Q, d, q, self.likelihood_distance(d, terms=terms), terms)

    def quadrant_descriptors(self, gray: np.ndarray, poses) -> tuple[np.ndarray, np.ndarray]:
        """The whole region's and its four quadrants' descriptors at ``poses``, with or without the quadrant term.

        Returns ``(C (n, 9, 9), Q (n, 4, 9, 9))``: what the tracker observes (``C``
        equals :meth:`descriptors` when the model has quadrants) and the quadrant
        descriptors a diagnosis compares over time (occlusion hides some
        quadrants and not others).
        """
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
        if self.compiled:
            return _kernels().warp_descriptors_fast(
                gray, poses, self.base_wh, self.patch_size, self._sample_step(), self.eps, self.gain_normalize, True,
                self.grad_normalize, self.grad_floor,
            )
        P = warp_patches(gray, poses, self.base_wh, self.patch_size, 1, self._sample_step())
        F = patch_features(P, gain_normalize=self.gain_normalize, quadrants=True)
        if self.grad_normalize > 0:
            F = normalize_gradients(F, self.grad_normalize, self.grad_floor)
        return quadrant_covariances(F, self.eps)

    def patches(self, gray: np.ndarray, poses) -> np.ndarray:
        """The warped ``patch_size``² patches (without their border) at ``poses``, float32 ``(n, S, S)``."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
        return warp_patches(gray, poses, self.base_wh, self.patch_size, 1, self._sample_step())[:, 1:-1, 1:-1]

    def template_scores(
        self, gray: np.ndarray, pose, templates, colour: fgbg.ColourMap | None = None,
        quadrant_state: QuadrantState | None = None, parts: bool = False,
    ):
        """``d_eff`` of many log-space templates at one pose, ``(m,)``: what each would be weighed by there.

        One observation at ``pose``, then each template's distance to it (in
        :data:`OBSERVE_CHUNK` batches) combined with that pose's quadrant term
        (and, given the frame's ``colour`` map, its colour term).
        Equal to :meth:`likelihood_distances` with the pose repeated, without
        observing it ``m`` times (the diagnosis asks this at the truth and the
        estimate, for the whole template cloud).

        With ``parts``, also the parts of ``d_eff²`` by name, ``(m,)`` each:
        ``descriptor`` (``d²``), then each term, weighted (they add up to ``d_eff²``).

        ``pose`` may also be ``(k, 4)``, several poses observed in one call: then ``(k, m)`` (and parts
        ``(k, m)`` each), row ``j`` bit for bit what ``pose[j]`` alone gives.
        """
        poses = np.asarray(pose, dtype=np.float64)
        single = poses.ndim == 1
        poses = poses.reshape(-1, 4)
        L = np.asarray(templates, dtype=np.float64).reshape(-1, N_FEATURES, N_FEATURES)
        ob = self.observe(gray, poses)
        weights = self.term_weights
        scores, split = [], []
        for j in range(len(poses)):
            C = ob.descriptors[j]
            d = np.concatenate(
                [self._template_distances(L[i : i + OBSERVE_CHUNK], C) for i in range(0, len(L), OBSERVE_CHUNK)]
            ) if len(L) else np.zeros(0)
            q = t = c = None
            if self.quadrants:
                Qj = ob.quadrants[j : j + 1]
                q1 = self.quadrant_distances(Qj, quadrant_state)
                q = np.broadcast_to(q1, (len(L), 4))
                if self.context:
                    c = np.broadcast_to(self.context_terms(Qj, q1), (len(L),))
            if colour is not None and self.colour:
                t = np.broadcast_to(self.colour_terms(colour, poses[j : j + 1]), (len(L),))
            terms = self.terms(q, t, quadrant_state, c)
            scores.append(self.likelihood_distance(d, terms=terms))
            if parts:
                split.append({"descriptor": d * d, **{k: weights[k] * np.asarray(v) for k, v in terms.items()}})
        if single:
            return (scores[0], split[0]) if parts else scores[0]
        d_eff = np.stack(scores)
        if not parts:
            return d_eff
        return d_eff, {k: np.stack([sp[k] for sp in split]) for k in split[0]}

    def descriptors(self, gray: np.ndarray, poses, executor=None, threads: int = 1) -> np.ndarray:
        """Descriptors ``(n, 9, 9)`` at ``poses`` of a prepared frame."""
        return self.observe(gray, poses, executor=executor, threads=threads).descriptors

    def likelihood_distances(
        self, gray: np.ndarray, poses, templates, executor=None, threads: int = 1, colour: fgbg.ColourMap | None = None,
        quadrant_state: QuadrantState | None = None,
    ):
        """``d_eff`` at ``poses`` of a prepared frame for log-space templates (one per pose, or one), ``(n,)``.

        What :class:`covviz.trackers.manifold.ManifoldTracker` weighs a
        particle with that template at that pose by (given the frame's
        ``colour`` map when the model has the colour term).
        """
        return self.observe(
            gray, poses, templates, executor=executor, threads=threads, colour=colour, quadrant_state=quadrant_state
        ).likelihood_distances

    def pose_search(
        self,
        gray: np.ndarray,
        pose,
        template: np.ndarray,
        scales=(),
        rotations=(),
        colour: fgbg.ColourMap | None = None,
        quadrant_state: QuadrantState | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``d_eff`` of one template at ``pose`` rescaled and rotated: what the likelihood says of each.

        First the scales (factors of ``pose``'s scale, at its rotation), then
        the rotations (offsets, radians) at the best of those scales: a
        scale pyramid and a rotation fan at one centre, as a correlation
        filter searches its scale after locating the centre (CSRT, DSST).

        Parameters
        ----------
        gray : ndarray, shape (H, W)
            A frame from :meth:`prepare`.
        pose : ndarray, shape (4,)
        template : ndarray, shape (9, 9)
            Log-space template.
        scales, rotations : sequence of float
            Factors (include 1) and offsets (include 0).
        colour : ColourMap, optional

        Returns
        -------
        scale_poses : ndarray, shape (len(scales), 4)
        scale_d : ndarray, shape (len(scales),)
        rot_poses : ndarray, shape (len(rotations), 4)
        rot_d : ndarray, shape (len(rotations),)
        """
        pose = np.asarray(pose, dtype=np.float64).reshape(4)
        sp = np.tile(pose, (len(scales), 1))
        sp[:, 2] *= np.asarray(scales, dtype=np.float64)
        kw = {"colour": colour, "quadrant_state": quadrant_state}
        sd = self.observe(gray, sp, template, **kw).likelihood_distances if len(sp) else np.zeros(0)
        best = sp[int(np.argmin(sd))] if len(sp) else pose
        rp = np.tile(best, (len(rotations), 1))
        rp[:, 3] += np.asarray(rotations, dtype=np.float64)
        rd = self.observe(gray, rp, template, **kw).likelihood_distances if len(rp) else np.zeros(0)
        return sp, sd, rp, rd

    def terms(
        self, q: np.ndarray | None, colour: np.ndarray | None = None, quadrant_state: QuadrantState | None = None,
        context: np.ndarray | None = None,
    ) -> dict[str, np.ndarray]:
        """The unweighted extra terms of ``d_eff²`` by name, from the quadrant distances and the colour term."""
        out = {}
        if q is not None:
            out["quadrants"] = quadrant_term(q, None if quadrant_state is None else quadrant_state.reliability)
        if colour is not None:
            out["colour"] = np.asarray(colour, dtype=np.float64)
        if context is not None:
            out["context"] = np.asarray(context, dtype=np.float64)
        return out

    def likelihood_distance(self, d: np.ndarray, q: np.ndarray | None = None, terms: dict | None = None) -> np.ndarray:
        """``d_eff = sqrt(d² + Σ_k weight_k · term_k)``; ``d`` itself without terms.

        Give the quadrant distances ``q`` (then ``d_eff² = d² + quadrant_weight ·
        quadrant_term(q)``) or the named ``terms`` of :meth:`terms`.
        """
        if terms is None:
            terms = self.terms(q)
        if not terms:
            return d
        w = self.term_weights
        acc = d * d
        for name, t in terms.items():
            acc = acc + w[name] * t
        return np.sqrt(acc)

    def log_likelihood(self, d_eff: np.ndarray) -> np.ndarray:
        """``-d_eff² / 2σ²``, the log-likelihood up to a constant (:func:`covviz.model.particles.log_likelihood`)."""
        return log_likelihood(d_eff, self.likelihood_sigma)


def _kernels():
    """:mod:`covviz.model.kernels`, imported on first use: commands that never observe (``report``,
    ``events``, every ``--help``) do not pay for importing numba."""
    from covviz.model import kernels

    return kernels


def _downsampled_shape(H: int, W: int, step: int) -> tuple[int, int]:
    """``(h, w)`` of a frame downsampled by ``step`` (rounded, at least 1)."""
    return max(1, round(H / step)), max(1, round(W / step))
