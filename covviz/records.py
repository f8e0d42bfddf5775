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

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["STAGES", "FrameRecord", "RunResult", "frame_number"]

def frame_number(index: int) -> int:
    """The 1-based frame number users see for a 0-based frame index."""
    return int(index) + 1


#: Names of the timed stages of a manifold-tracker update, in execution order.
STAGES = ("propagate", "colour", "warp", "features", "covariance", "distances", "weights", "estimate", "resample")


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
    extras : dict[str, Any]
        Tracker-specific arrays (for example the IPCA mean and basis, or an
        OpenCV tracker's failure flag). The manifold tracker puts the
        likelihood's factors here: ``terms`` (name → per-particle values) and
        ``term_weights`` (name → weight), with ``likelihood_distances² =
        distances² + Σ weight·term``, and the online state they used (see
        :class:`covviz.trackers.manifold.ManifoldTracker`).
    model : object, optional
        On the init record (index 0) of a covariance tracker: its frozen
        :class:`~covviz.model.observation.ObservationModel`, which observers use to
        compute what the tracker would observe at other poses (likelihood
        maps, the drift diagnosis) without calling the tracker.
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
    extras: dict[str, Any] = field(default_factory=dict)
    model: Any = None

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
