"""Costly diagnostics of a run, computed in the observer layer, only when asked for.

Nothing here runs inside the tracker: the logger calls these functions with the
:class:`~covviz.records.FrameRecord` a tracker already filled, the frame, and
(for the observation-based diagnostics) the tracker's own observation model,
so the extra descriptors are computed exactly as the tracker computes its own.
This module does not import rerun: it returns arrays and small dataclasses.

* :class:`ObservationModel` — covariance descriptors at arbitrary poses of a
  frame, with the tracker's patch size, regulariser and anti-aliasing;
* :func:`likelihood_map` — the likelihood of the estimate's template over a
  grid of positions around the estimate (where would the tracker *like* the
  target to be?);
* :func:`background_poses` — regions around the target, for background
  descriptors;
* :func:`template_spread` — the spread of the particles' templates: mean
  geodesic distance to their Karcher mean;
* :func:`template_cloud` — the SPD matrices of one MDS picture (generated
  templates, the target, background, the initial template) with their kinds
  and identities;
* :class:`EventDetector` — resampling storms, loss of track, recovery, and the
  frame where the drift that ended in a loss began.

Thresholds are named constants (saved into the recording's config).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from covviz.records import FrameRecord
from covviz.spd import distance_riemann, expm, expm_taylor, sym

__all__ = [
    "DRIFT_GOOD_IOU",
    "DRIFT_TOL",
    "DRIFT_WINDOW",
    "EVENT_DEFAULTS",
    "LOST_IOU",
    "RECOVER_FRAMES",
    "RECOVER_IOU",
    "STORM_ESS",
    "Event",
    "EventConfig",
    "EventDetector",
    "LikelihoodMap",
    "ObservationModel",
    "TemplateCloud",
    "background_poses",
    "box_to_pose",
    "drift_onset",
    "likelihood_map",
    "template_cloud",
    "template_spread",
    "top_k",
]

#: A resampling storm: ESS/N below this (the weights have collapsed onto a handful of particles) ...
STORM_ESS = 0.05
#: ... on this many consecutive frames (a single collapsed frame is common and harmless).
STORM_FRAMES = 3
#: Loss of track: IoU with the ground truth below this.
LOST_IOU = 0.1
#: Recovery after a loss: IoU at least this ...
RECOVER_IOU = 0.3
#: ... on this many consecutive frames (with ground truth).
RECOVER_FRAMES = 3
#: Where a drift began: after the last frame with IoU at least this before the loss (OTB's success
#: threshold) or, if none, after the top of the last climb (values within DRIFT_TOL of its peak).
DRIFT_GOOD_IOU = 0.5
DRIFT_TOL = 0.05
#: Frames of IoU history kept to find where a drift began (bounded memory).
DRIFT_WINDOW = 500


# --------------------------------------------------------------------------- #
# observation model
# --------------------------------------------------------------------------- #
class ObservationModel:
    """Descriptors at arbitrary poses of a frame, as one tracker observes them.

    Built from a tracker with :meth:`from_tracker`; uses the tracker's own
    frame preparation (grey levels, anti-aliasing downsample) and observation
    (warp → features → regularised covariance), so a descriptor computed here
    at a particle's pose equals the one the tracker computed.

    Parameters
    ----------
    prepare : callable
        ``image (H, W, 3) uint8 -> prepared frame``.
    observe : callable
        ``(prepared frame, poses (n, 4)) -> descriptors (n, d, d)``.
    base_wh : (float, float)
        Width and height of the target region at scale 1, pixels.
    likelihood_distances : callable, optional
        ``(prepared frame, poses (n, 4), template_log (d, d)) -> (n,)``: the
        distance the tracker's likelihood uses (for instance with a quadrant
        term). Without it, the plain ``d(expm(template_log), C*)``.
    """

    def __init__(self, prepare, observe, base_wh, likelihood_distances=None):
        self.prepare = prepare
        self.observe = observe
        self.base_wh = (float(base_wh[0]), float(base_wh[1]))
        self._likelihood_distances = likelihood_distances

    @classmethod
    def from_tracker(cls, tracker) -> ObservationModel | None:
        """The observation model of a covariance tracker, or None if it has none.

        Uses the tracker's public ``observe(image, poses)`` (as
        :meth:`covviz.trackers.manifold.ManifoldTracker.observe`), so the
        diagnostics see exactly the descriptors the tracker sees.
        """
        base_wh = getattr(tracker, "base_wh", None)
        if base_wh is None:
            return None
        public = getattr(tracker, "observe", None)
        if callable(public):
            dist = getattr(tracker, "likelihood_distances", None)
            return cls(lambda image: image, public, base_wh, dist if callable(dist) else None)
        return None

    def descriptors(self, prepared, poses: np.ndarray) -> np.ndarray:
        """Descriptors ``(n, d, d)`` at ``poses`` (``cx, cy, scale, theta``) of a prepared frame."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
        if len(poses) == 0:
            return np.zeros((0, 9, 9))
        return np.asarray(self.observe(prepared, poses), dtype=np.float64)

    def likelihood_distances(self, prepared, poses: np.ndarray, template_log: np.ndarray) -> np.ndarray:
        """The distance entering the tracker's likelihood at ``poses`` for a log-space template, ``(n,)``."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4)
        if self._likelihood_distances is not None:
            return np.asarray(self._likelihood_distances(prepared, poses, template_log), dtype=np.float64)
        C = expm(np.asarray(template_log, dtype=np.float64))
        return distance_riemann(C, self.descriptors(prepared, poses))


def box_to_pose(box: np.ndarray, base_wh) -> np.ndarray:
    """An axis-aligned box ``x, y, w, h`` as a pose ``cx, cy, scale, theta`` for a region of ``base_wh``.

    The scale is the geometric mean ``sqrt(w h / (w0 h0))``; theta is 0 (OTB
    ground truth is unrotated).
    """
    x, y, w, h = np.asarray(box, dtype=np.float64).reshape(4)
    s = float(np.sqrt(max(w * h, 1e-12) / (base_wh[0] * base_wh[1])))
    return np.array([x + w / 2, y + h / 2, s, 0.0])


def top_k(weights: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` largest weights, largest first."""
    w = np.asarray(weights)
    k = min(int(k), len(w))
    if k <= 0:
        return np.zeros(0, dtype=np.intp)
    idx = np.argpartition(-w, k - 1)[:k]
    return idx[np.argsort(-w[idx], kind="stable")]


# --------------------------------------------------------------------------- #
# likelihood map
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class LikelihoodMap:
    """The likelihood of a template over a grid of positions.

    Attributes
    ----------
    distances : ndarray, shape (g, g)
        The distance the tracker's likelihood uses at each grid position
        (``d(C_template, C*(x, y))``, plus the quadrant term when the tracker
        has one); rows run over y.
    log_likelihood : ndarray, shape (g, g)
        ``-(d² - d_min²) / 2σ²``: the log-likelihood relative to the best
        position of the grid (0 at the best, negative elsewhere), nats.
    likelihood : ndarray, shape (g, g)
        ``exp(log_likelihood)`` (1 at the best).
    centers_x, centers_y : ndarray, shape (g,)
        Pixel coordinates of the grid columns and rows.
    best : ndarray, shape (2,)
        ``x, y`` of the best grid position, pixels.
    extent : tuple of float
        ``(x0, y0, x1, y1)``: the rectangle the grid tiles, pixels (cell
        centres are half a cell inside it).
    """

    distances: np.ndarray
    log_likelihood: np.ndarray
    likelihood: np.ndarray
    centers_x: np.ndarray
    centers_y: np.ndarray
    best: np.ndarray
    extent: tuple


def likelihood_map(
    model: ObservationModel,
    prepared,
    pose: np.ndarray,
    template_log: np.ndarray,
    sigma: float,
    grid: int = 21,
    reach: float = 1.0,
) -> LikelihoodMap:
    """Likelihood of the estimate's template over positions around the estimate.

    The region of ``pose`` (same scale and rotation) is moved over a
    ``grid × grid`` lattice of positions spanning ``±reach`` region sizes in x
    and y; at each position the descriptor is observed and compared with the
    template. A peak away from the target shows the background matching the
    template better than the target does: the tracker is about to drift there.

    Parameters
    ----------
    model : ObservationModel
    prepared
        The frame, prepared by ``model.prepare``.
    pose : ndarray, shape (4,)
        ``cx, cy, scale, theta`` of the estimate.
    template_log : ndarray, shape (d, d)
        Log-space template (``C = expm(L)``).
    sigma : float
        The likelihood's σ (the tracker's ``likelihood_sigma``).
    grid : int
        Positions per axis (odd: the estimate is at the centre).
    reach : float
        Half-width of the grid in region sizes.
    """
    if grid < 2:
        raise ValueError(f"grid must be at least 2, got {grid}")
    if not sigma > 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    cx, cy, s, th = np.asarray(pose, dtype=np.float64).reshape(4)
    w, h = model.base_wh[0] * s, model.base_wh[1] * s
    u = np.linspace(-reach, reach, grid)
    xs, ys = cx + u * w, cy + u * h
    X, Y = np.meshgrid(xs, ys)
    poses = np.stack([X.ravel(), Y.ravel(), np.full(X.size, s), np.full(X.size, th)], axis=1)
    d = model.likelihood_distances(prepared, poses, template_log).reshape(grid, grid)
    d2 = d * d
    ll = -(d2 - d2.min()) / (2.0 * sigma * sigma)
    i, j = np.unravel_index(np.argmin(d), d.shape)
    dx, dy = (xs[1] - xs[0]) / 2, (ys[1] - ys[0]) / 2
    return LikelihoodMap(
        distances=d,
        log_likelihood=ll,
        likelihood=np.exp(ll),
        centers_x=xs,
        centers_y=ys,
        best=np.array([xs[j], ys[i]]),
        extent=(xs[0] - dx, ys[0] - dy, xs[-1] + dx, ys[-1] + dy),
    )


# --------------------------------------------------------------------------- #
# background and the template cloud
# --------------------------------------------------------------------------- #
def background_poses(pose: np.ndarray, base_wh, image_shape, n: int = 16, radii=(1.15, 1.9)) -> tuple:
    """Poses of background regions around the target (two rings), and their ring slots.

    Regions have the target's size; slot ``k`` sits at angle ``2πk/n`` on
    alternating rings of ``radii`` region sizes from the target centre (so
    they barely overlap the target). Slots whose centre falls outside the
    frame are dropped.

    Returns
    -------
    poses : ndarray, shape (m, 4)
    slots : ndarray of int, shape (m,)
        Which of the ``n`` slots each pose is (a stable identity from frame to frame).
    """
    cx, cy, s, th = np.asarray(pose, dtype=np.float64).reshape(4)
    w, h = base_wh[0] * s, base_wh[1] * s
    k = np.arange(n)
    a = 2 * np.pi * k / n
    r = np.where(k % 2 == 0, radii[0], radii[1])
    x = cx + r * np.cos(a) * w
    y = cy + r * np.sin(a) * h
    H, W = image_shape[:2]
    keep = (x >= 0) & (x < W) & (y >= 0) & (y < H)
    poses = np.stack([x, y, np.full(n, s), np.full(n, th)], axis=1)[keep]
    return poses, k[keep]


def template_spread(
    templates_log: np.ndarray,
    init: np.ndarray | None = None,
    max_templates: int = 64,
    tol: float = 1e-3,
    maxiter: int = 20,
) -> tuple[float, np.ndarray]:
    """Spread of a cloud of templates: mean geodesic distance to their Karcher mean.

    The Karcher mean by its fixed point ``M <- M^½ expm(mean_i W_i) M^½`` with
    the whitened logs ``W_i = logm(M^-½ C_i M^-½)``, whose norms are the
    distances ``d(M, C_i)``: the spread comes out of the last iteration at no
    extra cost. The cloud is tight (a random walk of small steps), where the
    plain fixed point converges in two or three steps; started from the
    previous frame's mean it often needs one. (For spread-out data use
    :func:`covviz.spd.mean_riemann`, which backtracks.)

    Parameters
    ----------
    templates_log : ndarray, shape (n, d, d)
        Log-space templates (``C_i = expm(L_i)``).
    init : ndarray, shape (d, d), optional
        Starting point (SPD), e.g. the previous frame's mean; default the
        log-Euclidean mean ``expm(mean_i L_i)``.
    max_templates : int
        Use an evenly strided subset of at most this many templates (the mean
        distance of a subset estimates that of the whole cloud).
    tol : float
        Stop when the Frobenius norm of the mean whitened log is below ``tol``
        (the spread is then exact to second order in ``tol``).
    maxiter : int

    Returns
    -------
    spread : float
        Mean affine-invariant distance to the Karcher mean.
    mean : ndarray, shape (d, d)
        The Karcher mean (SPD), to pass as ``init`` on the next frame.
    """
    L = np.asarray(templates_log, dtype=np.float64)
    if L.ndim != 3 or L.shape[-1] != L.shape[-2] or len(L) == 0:
        raise ValueError(f"templates must have shape (n, d, d) with n >= 1, got {L.shape}")
    if not np.all(np.isfinite(L)):
        raise ValueError("templates contain NaN or inf")
    if len(L) > max_templates:
        L = L[np.linspace(0, len(L) - 1, max_templates).round().astype(int)]
    C = expm_taylor(L)
    M = expm(L.mean(axis=0)) if init is None else np.asarray(init, dtype=np.float64)
    for _ in range(maxiter):
        w, V = np.linalg.eigh(M)
        if w.min() <= 0:
            raise ValueError("the Karcher iteration left the SPD cone; check the templates")
        Ms = (V * np.sqrt(w)) @ V.T
        Mis = (V * (1.0 / np.sqrt(w))) @ V.T
        lam, U = np.linalg.eigh(sym(Mis @ C @ Mis))  # logm of the batch, without re-checking it
        if lam.min() <= 0:
            raise ValueError("a template is not positive-definite; check the templates")
        W = (U * np.log(lam)[:, None, :]) @ np.swapaxes(U, -1, -2)
        T = W.mean(axis=0)
        if np.linalg.norm(T) < tol:
            break
        M = sym(Ms @ expm(T) @ Ms)
    spread = float(np.sqrt(np.sum(W * W, axis=(1, 2))).mean())
    return spread, M


#: Kinds of points in a template cloud, in drawing order.
CLOUD_KINDS = ("template", "top", "estimate", "initial", "background", "target")


@dataclass(frozen=True)
class TemplateCloud:
    """The SPD matrices of one MDS picture, with what each one is.

    Attributes
    ----------
    matrices : ndarray, shape (m, d, d)
        SPD matrices (templates after ``expm``, and descriptors).
    kinds : ndarray of str, shape (m,)
        One of :data:`CLOUD_KINDS`.
    keys : list
        Identity of each point across frames (``None`` for particles, which
        are resampled): the anchors of the frame-to-frame alignment.
    particle : ndarray of int, shape (m,)
        Particle index for ``template``/``top`` points, -1 otherwise.
    """

    matrices: np.ndarray
    kinds: np.ndarray
    keys: list
    particle: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))


def template_cloud(
    record: FrameRecord,
    initial_log: np.ndarray | None,
    target: np.ndarray | None,
    background: np.ndarray | None = None,
    background_slots: np.ndarray | None = None,
    k_top: int = 10,
    max_templates: int = 100,
    rng=None,
) -> TemplateCloud:
    """Assemble the points of the template-cloud picture for one frame.

    The generated templates are the particles' templates (``expm`` of
    ``record.templates``): the ``k_top`` highest-weight ones, plus a uniform
    random sample of the others up to ``max_templates`` in all (the pairwise
    distance matrix grows as the square of the count). Then the estimate's
    template, the initial template, the background descriptors and the
    descriptor observed at the ground truth ("target").

    Parameters
    ----------
    record : FrameRecord
    initial_log : ndarray, shape (d, d), optional
        The initial template, log space.
    target : ndarray, shape (d, d), optional
        Descriptor observed at the ground-truth box (SPD).
    background : ndarray, shape (b, d, d), optional
        Descriptors of background regions (SPD).
    background_slots : ndarray of int, shape (b,), optional
        Identity of each background region (see :func:`background_poses`).
    rng : numpy.random.Generator or int, optional
        For the sample of the other templates.
    """
    rng = np.random.default_rng(rng)
    mats, kinds, keys, part = [], [], [], []
    if record.templates is not None and record.log_weights is not None and len(record.templates):
        w = np.exp(record.log_weights)
        top = top_k(w, k_top)
        rest = np.setdiff1d(np.arange(len(w)), top)
        m = max(0, min(len(rest), max_templates - len(top)))
        other = np.sort(rng.choice(rest, size=m, replace=False)) if m else np.zeros(0, dtype=int)
        idx = np.concatenate([other, top])
        mats.append(expm(np.asarray(record.templates, dtype=np.float64)[idx]))
        kinds += ["template"] * len(other) + ["top"] * len(top)
        keys += [None] * len(idx)
        part += list(idx)
    if record.estimate_template is not None:
        mats.append(expm(np.asarray(record.estimate_template, dtype=np.float64))[None])
        kinds.append("estimate")
        keys.append("estimate")
        part.append(-1)
    if initial_log is not None:
        mats.append(expm(np.asarray(initial_log, dtype=np.float64))[None])
        kinds.append("initial")
        keys.append("initial")
        part.append(-1)
    if background is not None and len(background):
        slots = np.arange(len(background)) if background_slots is None else background_slots
        mats.append(np.asarray(background, dtype=np.float64))
        kinds += ["background"] * len(background)
        keys += [("background", int(s)) for s in slots]
        part += [-1] * len(background)
    if target is not None:
        mats.append(np.asarray(target, dtype=np.float64)[None])
        kinds.append("target")
        keys.append("target")
        part.append(-1)
    if not mats:
        return TemplateCloud(np.zeros((0, 9, 9)), np.zeros(0, dtype="<U10"), [], np.zeros(0, dtype=int))
    return TemplateCloud(np.concatenate(mats), np.array(kinds), keys, np.array(part, dtype=int))


# --------------------------------------------------------------------------- #
# events: storms, loss, recovery, drift onset
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class EventConfig:
    """Thresholds of the event detector (defaults: the module constants)."""

    storm_ess: float = STORM_ESS
    storm_frames: int = STORM_FRAMES
    lost_iou: float = LOST_IOU
    recover_iou: float = RECOVER_IOU
    recover_frames: int = RECOVER_FRAMES
    drift_tol: float = DRIFT_TOL
    drift_good_iou: float = DRIFT_GOOD_IOU
    drift_window: int = DRIFT_WINDOW

    def __post_init__(self):
        if not 0 <= self.lost_iou < self.recover_iou <= 1:
            raise ValueError("need 0 <= lost_iou < recover_iou <= 1")
        if self.recover_frames < 1 or self.storm_frames < 1 or self.drift_window < 2:
            raise ValueError("recover_frames and storm_frames must be >= 1, drift_window >= 2")


EVENT_DEFAULTS = EventConfig()


@dataclass(frozen=True)
class Event:
    """Something worth a line in the event log.

    Attributes
    ----------
    frame : int
        The frame the event belongs to (``drift``: where it began; ``recovered``:
        the first frame of the run of good IoU).
    kind : str
        ``storm``, ``storm_end``, ``lost``, ``drift``, ``recovered``.
    level : str
        ``INFO``, ``WARN`` or ``ERROR`` (as Rerun's text log levels).
    text : str
    detected_at : int
        The frame on which the detector saw it (later than ``frame`` for ``drift``
        and ``recovered``).
    iou : float
        IoU on ``frame`` (``nan`` for events that are not about IoU).
    """

    frame: int
    kind: str
    level: str
    text: str
    detected_at: int
    iou: float = float("nan")


def _median3(v: np.ndarray) -> np.ndarray:
    """Centred running median over 3 samples (2 at the ends): a one-frame flicker disappears."""
    return np.array([np.median(v[max(0, i - 1) : i + 2]) for i in range(len(v))])


def drift_onset(
    frames: np.ndarray, ious: np.ndarray, tol: float = DRIFT_TOL, good: float = DRIFT_GOOD_IOU
) -> int:
    """The frame where the run of falling IoU that ends at the last frame (the loss) began.

    The anchor is the last frame before the loss where the IoU, median-filtered
    over 3 frames (so a one-frame flicker does not count), was still good
    (≥ ``good``, OTB's success threshold); if there is none, the top of the
    climb met walking back from the loss (each earlier value at most ``tol``
    below the highest seen). From the anchor, go back while the IoU was
    already falling (each earlier frame higher by more than ``tol / 5``): the drift began on
    the frame after the top of that fall. So a plateau followed by a slide
    gives the end of the plateau, and a noisy slide gives the frame where the
    IoU left the good range (or the last clear fall into it).

    Parameters
    ----------
    frames : ndarray of int, shape (n,)
        Frame indices (increasing; gaps where there was no ground truth).
    ious : ndarray, shape (n,)
        IoU on those frames; the last one is the loss.
    tol : float
    good : float

    Returns
    -------
    int
        The first frame of the fall (a value of ``frames``).
    """
    frames = np.asarray(frames)
    raw = np.asarray(ious, dtype=np.float64)
    if len(raw) == 0:
        raise ValueError("drift_onset needs at least one frame")
    last = len(raw) - 1
    if last == 0:
        return int(frames[0])
    v = _median3(raw)
    above = np.flatnonzero(v[:last] >= good)
    if len(above):
        j = int(above[-1])
    else:
        j, m = last, v[last]
        while j > 0 and v[j - 1] >= m - tol:
            j -= 1
            m = max(m, v[j])
        run = np.arange(j, last + 1)
        j = int(run[v[run] >= m - tol].max())
    while j > 0 and raw[j - 1] > raw[j] + tol / 5:  # a clear step down, not noise
        j -= 1
    return int(frames[min(j + 1, last)])


class EventDetector:
    """Online detection of resampling storms, loss of track, recovery and drift onset.

    Feed it one frame at a time with :meth:`update`; it returns the events
    detected on that frame. A loss is an IoU below ``lost_iou`` while
    tracking; it also reports where the drift began (:func:`drift_onset` over
    the IoU since the last recovery, at most ``drift_window`` frames). A
    recovery needs ``recover_frames`` consecutive frames at IoU ≥
    ``recover_iou`` (hysteresis, so a flicker does not count). A storm is
    ESS/N below ``storm_ess`` on ``storm_frames`` consecutive frames (reported
    on the first of them); it ends when ESS/N is back above twice that.
    """

    def __init__(self, config: EventConfig = EVENT_DEFAULTS):
        self.config = config
        self.lost = False
        self.storm = False
        self._storm_start = -1
        self._storm_min = np.inf
        self._low_run: list[tuple[int, float]] = []
        self._good_run: list[tuple[int, float]] = []
        self._hist: deque = deque(maxlen=config.drift_window)
        self.losses: list[int] = []
        self.drifts: list[int] = []
        self.recoveries: list[int] = []
        self.storms: list[tuple[int, int]] = []

    def update(self, frame: int, iou: float | None = None, ess_frac: float | None = None) -> list[Event]:
        """Events of ``frame``; ``iou`` None when there is no ground truth, ``ess_frac`` None without particles."""
        cfg = self.config
        out: list[Event] = []
        if ess_frac is not None and np.isfinite(ess_frac):
            if not self.storm:
                self._low_run = self._low_run + [(frame, ess_frac)] if ess_frac < cfg.storm_ess else []
                if len(self._low_run) >= cfg.storm_frames:
                    first = self._low_run[0][0]
                    self._storm_min = min(v for _, v in self._low_run)
                    self.storm, self._storm_start, self._low_run = True, first, []
                    out.append(
                        Event(
                            first,
                            "storm",
                            "WARN",
                            f"resampling storm: ESS/N below {cfg.storm_ess:g} for {cfg.storm_frames} frames "
                            f"(lowest {self._storm_min:.3f}): the weights sit on a handful of particles",
                            frame,
                        )
                    )
            else:
                self._storm_min = min(self._storm_min, ess_frac)
                if ess_frac >= 2 * cfg.storm_ess:
                    self.storm = False
                    self.storms.append((self._storm_start, frame))
                    out.append(
                        Event(
                            frame,
                            "storm_end",
                            "INFO",
                            f"storm over after {frame - self._storm_start} frames "
                            f"(from frame {self._storm_start}, lowest ESS/N {self._storm_min:.3f})",
                            frame,
                        )
                    )
        if iou is not None and np.isfinite(iou):
            if not self.lost:
                self._hist.append((frame, float(iou)))
                if iou < cfg.lost_iou:
                    self.lost = True
                    self._good_run = []
                    fr, v = np.array([h[0] for h in self._hist]), np.array([h[1] for h in self._hist])
                    start = drift_onset(fr, v, cfg.drift_tol, cfg.drift_good_iou)
                    before = v[fr < start]
                    peak = before[-1] if len(before) else v[0]
                    v_start = float(v[fr == start][0])
                    self.losses.append(frame)
                    self.drifts.append(start)
                    out.append(
                        Event(
                            frame,
                            "lost",
                            "ERROR",
                            f"lost track: IoU {iou:.2f} < {cfg.lost_iou:g}; the drift began at frame {start} "
                            f"(IoU {peak:.2f} -> {iou:.2f} over {frame - start + 1} frames)",
                            frame,
                            float(iou),
                        )
                    )
                    out.append(
                        Event(
                            start,
                            "drift",
                            "WARN",
                            f"drift began here: IoU falls from {peak:.2f} to {iou:.2f} and the track is lost "
                            f"at frame {frame}",
                            frame,
                            v_start,
                        )
                    )
            else:
                if iou >= cfg.recover_iou:
                    self._good_run.append((frame, float(iou)))
                    if len(self._good_run) >= cfg.recover_frames:
                        first, first_iou = self._good_run[0]
                        self.lost = False
                        self._good_run = []
                        self._hist.clear()
                        self._hist.append((frame, float(iou)))
                        self.recoveries.append(first)
                        out.append(
                            Event(
                                first,
                                "recovered",
                                "INFO",
                                f"recovered: IoU >= {cfg.recover_iou:g} from this frame on "
                                f"(lost at frame {self.losses[-1]}, confirmed at frame {frame})",
                                frame,
                                first_iou,
                            )
                        )
                else:
                    self._good_run = []
        return out
