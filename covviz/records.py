"""The typed records that flow from the tracker core to observers.

:class:`FrameRecord` is the only contract between a tracker and the
instrumentation (Rerun logger, metrics collectors). Trackers fill it with arrays
they already hold, without copies of images; observers must treat every array
as read-only.

Conventions
-----------
* Boxes are ``x, y, w, h`` in pixels, top-left origin, **0-based** continuous
  coordinates: pixel ``(i, j)`` covers ``[j, j+1) x [i, i+1)``. OTB files are
  1-based; :mod:`covviz.data.sequences` converts on read and on write.
* Poses are ``cx, cy, scale, theta``: the centre in pixels, a scale factor
  relative to the initial box and a rotation in radians. Offsets ``(u, v)`` of
  the region are mapped to the image by ``R(theta) = [[cos, -sin], [sin, cos]]``
  in image axes (x right, y down), so a positive ``theta`` turns the region
  clockwise on screen.
* Corners are ``(n, 4, 2)``: top-left, top-right, bottom-right, bottom-left of
  the (possibly rotated) region, in pixels.
* Frames have a 0-based *index* in code (``Frame.index``, ``FrameRecord.index``)
  and a 1-based *number* wherever a user sees them — the recording's ``frame``
  timeline, events and diagnoses, ``covviz snapshot --frame``, ``covviz mds
  --frames``, results files — so frame 1 is ``img/0001.jpg``, as OTB numbers them
  (:func:`frame_number`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the types of the online state; records import nothing of the model at run time
    from covviz.model.fgbg import ColourMap, ColourModel
    from covviz.model.observation import QuadrantState

__all__ = ["STAGES", "Diffusion", "FrameInputs", "FrameRecord", "Likelihood", "PoseSearch", "Pull", "RunResult",
           "frame_number"]

def frame_number(index: int) -> int:
    """The 1-based frame number users see for a 0-based frame index."""
    return int(index) + 1


#: Names of the timed stages of a manifold-tracker update, in execution order.
STAGES = ("propagate", "colour", "warp", "features", "covariance", "distances", "weights", "estimate", "resample")


@dataclass(frozen=True, slots=True, eq=False)
class Likelihood:
    """What every weighed particle's likelihood was made of on one frame.

    Attributes
    ----------
    distances : ndarray, shape (n,)
        ``d_eff``, the distance each particle was weighed by:
        ``log w ∝ −d_eff² / 2σ²`` and ``d_eff² = d² + Σ_k term_weights[k]·terms[k]``
        with ``d`` the template distance (``FrameRecord.distances``).
    sigma : float
        σ of the likelihood.
    quadrant_distances : ndarray, shape (n, 4), optional
        ``sqrt(8·J)`` of each quadrant against its reference (None without the quadrant term).
    terms : mapping of str to ndarray, shape (n,)
        Each extra term of ``d_eff²`` per particle, unweighted (``"quadrants"``,
        ``"colour"``, ``"context"``: those the model has; empty for the paper's likelihood).
    term_weights : mapping of str to float
        The weight of each term.
    """

    distances: np.ndarray
    sigma: float
    quadrant_distances: np.ndarray | None = None
    terms: Mapping[str, np.ndarray] = field(default_factory=dict)
    term_weights: Mapping[str, float] = field(default_factory=dict)

    def contributions(self) -> dict[str, np.ndarray]:
        """``weight_k · term_k`` per particle, ``(n,)`` each, by term name."""
        return {k: self.term_weights[k] * np.asarray(v, dtype=np.float64) for k, v in self.terms.items()}


@dataclass(frozen=True, slots=True, eq=False)
class FrameInputs:
    """What ``update()`` weighed by besides the particles' poses and templates.

    With these, :class:`~covviz.model.observation.ObservationModel`'s
    ``template_scores``, ``likelihood_distances`` and ``pose_search`` say exactly
    what the tracker's likelihood said, every term included, without the tracker.

    Attributes
    ----------
    gray : ndarray, shape (h, w), float32
        The frame as the model samples it (``ObservationModel.prepare``:
        grey in ``[0, 1]``, downsampled and smoothed as configured).
    colour_map : ColourMap, optional
        The foreground probability of this frame the colour term used (None without it).
    colour_state : ColourModel, optional
        The colour histograms it was computed from (before this frame's update).
    quadrant_state : QuadrantState, optional
        The quadrant references and reliabilities (None: the initial references, fixed).
    """

    gray: np.ndarray
    colour_map: ColourMap | None = None
    colour_state: ColourModel | None = None
    quadrant_state: QuadrantState | None = None

    def likelihood_kwargs(self) -> dict:
        """Keyword arguments (``colour``, ``quadrant_state``) of the model's scoring methods."""
        out: dict = {}
        if self.colour_map is not None:
            out["colour"] = self.colour_map
        if self.quadrant_state is not None:
            out["quadrant_state"] = self.quadrant_state
        return out


@dataclass(frozen=True, slots=True, eq=False)
class PoseSearch:
    """The scale and rotation candidates scored at the estimate (``ManifoldConfig.scale_steps``).

    Attributes
    ----------
    scale_poses : ndarray, shape (k, 4)
    scale_distances : ndarray, shape (k,)
    rotation_poses : ndarray, shape (m, 4)
    rotation_distances : ndarray, shape (m,)
    """

    scale_poses: np.ndarray
    scale_distances: np.ndarray
    rotation_poses: np.ndarray
    rotation_distances: np.ndarray


@dataclass(frozen=True, slots=True, eq=False)
class Diffusion:
    """How the adaptive diffusion searched on a frame (:mod:`covviz.model.adaptive`).

    Attributes
    ----------
    evidence_in : float
        The loss evidence ``e`` of the frame before, which this frame's noise followed.
    jump_prob : float
        The wide mode's probability on this frame.
    sigma_factor : float
        The factor on the template walk's σ on this frame.
    redetected : int
        Particles drawn afresh around the last confident pose (their ``modes`` are 3).
    evidence : float
        ``e`` after this frame (what the next frame follows).
    z : float
        This frame's robust z-score of the best distance (nan during the warm-up).
    lost : int
        Frames since the evidence was last 0.
    """

    evidence_in: float
    jump_prob: float
    sigma_factor: float
    redetected: int
    evidence: float
    z: float
    lost: int


@dataclass(frozen=True, slots=True, eq=False)
class Pull:
    """The observation pull on a frame (:mod:`covviz.model.adaptive`; ``ManifoldConfig.observation_pull``).

    The next particle set's templates are the record's ``templates`` taken by ``resample_indices``
    and then, where ``target`` is given, stepped: ``T ← T + rate · (target − T)``.

    Attributes
    ----------
    held : str
        ``""``: every template stepped; ``"evidence"``: not considered (the frame had loss
        evidence); ``"look"``, ``"light"`` or ``"look+light"``: the gate(s) that held the step.
    rate : float
        ``α``.
    target : ndarray, shape (d, d), or None
        ``log C_obs``, what the templates stepped towards (None when nothing stepped).
    brightness : float
        ``b_t``, the estimate box's mean grey level (nan without the light gate, or not considered).
    """

    held: str
    rate: float
    target: np.ndarray | None
    brightness: float


@dataclass(frozen=True, slots=True, eq=False)
class FrameRecord:
    """What one tracker did on one frame.

    Attributes
    ----------
    index : int
        0-based frame index within the sequence.
    box : ndarray, shape (4,)
        The estimate, ``x, y, w, h`` in pixels (0-based).
    tracker : str
        Name of the tracker that produced the record.
    pose : ndarray, shape (4,), optional
        Estimated ``cx, cy, scale, theta``.
    corners : ndarray, shape (4, 2), optional
        Corners of the estimated (rotated) region, pixels.
    particle_poses : ndarray, shape (n, 4), optional
        ``cx, cy, scale, theta`` of every particle *before* resampling (the
        particles that were weighed on this frame).
    particle_corners : ndarray, shape (n, 4, 2), optional
        Corners of every particle's region, pixels.
    log_weights : ndarray, shape (n,), optional
        Normalised log-weights (``logsumexp == 0``) of the weighed particles.
    ess : float
        Effective sample size ``1 / sum w_i^2`` of those weights (``nan`` if none).
    resampled : bool
        Whether the particle set was resampled after weighing.
    resample_indices : ndarray, shape (n,), optional
        Ancestor index of each particle of the next set, if resampled.
    templates : ndarray, shape (n, d, d), optional
        Each particle's template in log space (symmetric ``L``, ``C = expm(L)``).
    descriptors : ndarray, shape (n, d, d), optional
        Covariance descriptor observed at each particle's pose (SPD).
    distances : ndarray, shape (n,), optional
        ``d(C_i, C*_i)``, the Riemannian distance between each particle's
        template and its observation.
    estimate_template : ndarray, shape (d, d), optional
        Log-space template of the estimate (weighted log-Euclidean mean).
    estimate_descriptor : ndarray, shape (d, d), optional
        Descriptor observed at the estimated pose.
    timings : dict[str, float]
        Seconds spent in each stage (see :data:`STAGES`) plus ``"total"``.
    modes : ndarray, shape (n,), optional
        The noise mode each weighed particle drew (0: everyday, 1: the wide jump;
        2: a second-stage particle).
    velocity : ndarray, shape (2,), optional
        The estimate's velocity, pixels per frame.
    likelihood : Likelihood, optional
        What each particle was weighed by: ``d_eff`` and its terms.
    inputs : FrameInputs, optional
        What the likelihood depended on besides poses and templates.
    pose_search : PoseSearch, optional
        The scale/rotation search at the estimate, when the config asks for one.
    diffusion : Diffusion, optional
        The adaptive diffusion's evidence and what it did, when the config has it on.
    pull : Pull, optional
        The observation pull's step or what held it, when the config has it on.
    filter_pose : ndarray, shape (4,), optional
        The filter's own MMSE estimate ``cx, cy, scale, theta`` (the weighted mean of
        ``particle_poses``), when the reported ``pose`` is not it: the position step of the
        manifold tracker (``ManifoldConfig.ncc_rate``) moves only the reported centre, and the
        filter goes on from this one. None when ``pose`` is the MMSE estimate itself.
    extras : dict[str, Any]
        Only what a baseline adds of its own (IPCA's mean and basis, an OpenCV
        tracker's failure flag); empty for the manifold trackers.
    """

    index: int
    box: np.ndarray
    tracker: str = ""
    pose: np.ndarray | None = None
    corners: np.ndarray | None = None
    particle_poses: np.ndarray | None = None
    particle_corners: np.ndarray | None = None
    log_weights: np.ndarray | None = None
    ess: float = float("nan")
    resampled: bool = False
    resample_indices: np.ndarray | None = None
    templates: np.ndarray | None = None
    descriptors: np.ndarray | None = None
    distances: np.ndarray | None = None
    estimate_template: np.ndarray | None = None
    estimate_descriptor: np.ndarray | None = None
    timings: dict[str, float] = field(default_factory=dict)
    modes: np.ndarray | None = None
    velocity: np.ndarray | None = None
    likelihood: Likelihood | None = None
    inputs: FrameInputs | None = None
    pose_search: PoseSearch | None = None
    diffusion: Diffusion | None = None
    pull: Pull | None = None
    filter_pose: np.ndarray | None = None
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def n_particles(self) -> int:
        """Number of particles (0 for trackers without particles)."""
        return 0 if self.log_weights is None else len(self.log_weights)

    @property
    def weights(self) -> np.ndarray | None:
        """Normalised weights ``exp(log_weights)``, shape ``(n,)``."""
        return None if self.log_weights is None else np.exp(self.log_weights)


@dataclass(frozen=True, slots=True, eq=False)
class RunResult:
    """The outcome of running one tracker over one sequence.

    Attributes
    ----------
    sequence : str
    tracker : str
    seed : int or None
    boxes : ndarray, shape (n, 4)
        Estimated boxes, 0-based pixels; row 0 is the initial box.
    times : ndarray, shape (n,)
        Seconds spent in ``init`` (row 0) and ``update`` (later rows).
    groundtruth : ndarray, shape (n, 4)
        Ground truth (``nan`` rows where there is none).
    config : dict
        The tracker's configuration, as written next to the results.
    interrupted : bool
        True if the run stopped early (Ctrl-C or an error inside the tracker).
    """

    sequence: str
    tracker: str
    seed: int | None
    boxes: np.ndarray
    times: np.ndarray
    groundtruth: np.ndarray
    config: dict = field(default_factory=dict)
    interrupted: bool = False

    @property
    def fps(self) -> float:
        """Frames per second of ``update`` (the init frame excluded)."""
        t = self.times[1:]
        return float(len(t) / t.sum()) if len(t) and t.sum() > 0 else float("nan")
