"""Costly diagnostics of a run, computed in the observer layer, only when asked for.

Nothing here runs inside the tracker or calls it: the logger calls these
functions with the :class:`~covviz.records.FrameRecord` a tracker already
filled, the frame, and (for the observation-based diagnostics) the tracker's
frozen :class:`~covviz.model.observation.ObservationModel` from its init record, so
extra descriptors and distances are exactly what the tracker would compute.
This module does not import rerun: it returns arrays and small dataclasses.

* :func:`likelihood_map` — the likelihood of the estimate's template over a
  grid of positions around the estimate (where would the tracker *like* the
  target to be?);
* :func:`background_poses` — regions around the target, for background
  descriptors;
* :func:`template_spread` — the spread of the particles' templates: mean
  geodesic distance to their log-Euclidean mean;
* :func:`template_cloud` — the SPD matrices of one MDS picture (generated
  templates, the target, background, the initial template) with their kinds
  and identities.

Events (storms, loss, drift onset, recovery) are time-series logic and live
in :mod:`covviz.diagnosis.events`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from covviz.model.observation import ObservationModel
from covviz.model.spd import distance_riemann_log, expm
from covviz.records import FrameRecord

__all__ = [
    "CLOUD_KINDS",
    "LikelihoodMap",
    "TemplateCloud",
    "background_poses",
    "likelihood_map",
    "template_cloud",
    "template_spread",
    "top_k",
]


# --------------------------------------------------------------------------- #
# helpers
# --------------------------------------------------------------------------- #
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
    grid: int = 21,
    reach: float = 1.0,
    **inputs,
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
        The tracker's; its ``likelihood_sigma`` is the likelihood's σ.
    prepared
        The frame, prepared by ``model.prepare``.
    pose : ndarray, shape (4,)
        ``cx, cy, scale, theta`` of the estimate.
    template_log : ndarray, shape (d, d)
        Log-space template (``C = expm(L)``).
    grid : int
        Positions per axis (odd: the estimate is at the centre).
    reach : float
        Half-width of the grid in region sizes.
    **inputs
        What the frame's likelihood depends on besides pose and template
        (:meth:`ObservationModel.frame_inputs`: the colour map, the quadrant
        state), so the map weighs by every term ``update()`` did.
    """
    if grid < 2:
        raise ValueError(f"grid must be at least 2, got {grid}")
    sigma = model.likelihood_sigma
    cx, cy, s, th = np.asarray(pose, dtype=np.float64).reshape(4)
    w, h = model.base_wh[0] * s, model.base_wh[1] * s
    u = np.linspace(-reach, reach, grid)
    xs, ys = cx + u * w, cy + u * h
    X, Y = np.meshgrid(xs, ys)
    poses = np.stack([X.ravel(), Y.ravel(), np.full(X.size, s), np.full(X.size, th)], axis=1)
    d = model.likelihood_distances(prepared, poses, template_log, **inputs).reshape(grid, grid)
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


def template_spread(templates_log: np.ndarray, max_templates: int = 64) -> tuple[float, np.ndarray]:
    """Spread of a cloud of templates: mean geodesic distance to their log-Euclidean mean.

    ``mean_i d(expm(L_i), expm(L̄))`` with ``L̄`` the mean of (an evenly strided subset
    of) the log-space templates ``L_i`` — the log-Euclidean mean, exact in the space
    the templates live and walk in. For a cloud as tight as a tracker's (a random walk
    of small steps) it is the Karcher mean to second order in the spread: on Car4,
    Human3 and DragonBaby (every third frame of 200) the two spreads agree to 0.25%
    (median 0.01-0.06%; ``tests/test_viz_diagnostics.py`` checks the agreement on a
    synthetic cloud). The distances run in the compiled kernel
    (:func:`covviz.model.kernels.template_distances_fast`, GIL-free) where numba is
    installed; the recorder computes this on its thread beside the tracker, where
    the Karcher mean's iterations (a dozen small numpy calls each) cost ~1.3 ms a call.

    Parameters
    ----------
    templates_log : ndarray, shape (n, d, d)
        Log-space templates (``C_i = expm(L_i)``), symmetric.
    max_templates : int
        Use an evenly strided subset of at most this many templates (the mean
        distance of a subset estimates that of the whole cloud).

    Returns
    -------
    spread : float
    mean : ndarray, shape (d, d)
        The log-Euclidean mean ``expm(L̄)`` (SPD).
    """
    L = np.asarray(templates_log, dtype=np.float64)
    if L.ndim != 3 or L.shape[-1] != L.shape[-2] or len(L) == 0:
        raise ValueError(f"templates must have shape (n, d, d) with n >= 1, got {L.shape}")
    if not np.all(np.isfinite(L)):
        raise ValueError("templates contain NaN or inf")
    if len(L) > max_templates:
        L = L[np.linspace(0, len(L) - 1, max_templates).round().astype(int)]
    mean = expm(L.mean(axis=0))
    from covviz.model import kernels

    # d(expm(L_i), mean) as the tracker computes its template distances
    # (ObservationModel._template_distances): the compiled kernel, else spd's log-space distance.
    if kernels.JIT_ENABLED and L.shape[1:] == (9, 9):
        d = kernels.template_distances_fast(L, np.broadcast_to(mean, L.shape))
    else:
        d = distance_riemann_log(L, mean)
    return float(d.mean()), mean


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
# likelihood along scale and rotation
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class LikelihoodSlices:
    """The likelihood distance of one template along scale and rotation about one centre.

    Attributes
    ----------
    scales : ndarray, shape (k,)
        Scales tried (multiples of the centre pose's scale).
    d_scale : ndarray, shape (k,)
        ``d_eff`` at each scale (rotation as the pose's).
    angles : ndarray, shape (m,)
        Rotations tried, radians (added to the pose's).
    d_angle : ndarray, shape (m,)
        ``d_eff`` at each rotation (scale as the pose's).
    """

    scales: np.ndarray
    d_scale: np.ndarray
    angles: np.ndarray
    d_angle: np.ndarray

    @property
    def best_scale(self) -> float:
        return float(self.scales[int(np.argmin(self.d_scale))])

    @property
    def scale_flatness(self) -> float:
        """Range of ``d_eff`` over the scales (small: the likelihood cannot tell the size)."""
        return float(np.ptp(self.d_scale))


#: Relative scales (log-spaced, x0.6 to x1.67) and rotations (±0.35 rad) of the slices.
SLICE_SCALES = np.exp(np.linspace(np.log(0.6), np.log(1 / 0.6), 13))
SLICE_ANGLES = np.linspace(-0.35, 0.35, 11)


def likelihood_slices(
    model: ObservationModel,
    prepared,
    pose: np.ndarray,
    template_log: np.ndarray,
    scales: np.ndarray = SLICE_SCALES,
    angles: np.ndarray = SLICE_ANGLES,
    **inputs,
) -> LikelihoodSlices:
    """``d_eff`` of ``template_log`` about ``pose``'s centre along scale and along rotation.

    Two 1-D slices of the likelihood (through the tracker's own model): a
    curve flat across scale says the likelihood cannot tell a box too large
    from the right one; a minimum away from 1 says it prefers another size.
    ``inputs`` as for :func:`likelihood_map`.
    """
    cx, cy, s, th = np.asarray(pose, dtype=np.float64).reshape(4)
    sc = np.asarray(scales, dtype=np.float64)
    an = np.asarray(angles, dtype=np.float64)
    poses = np.concatenate(
        [
            np.stack([np.full(len(sc), cx), np.full(len(sc), cy), s * sc, np.full(len(sc), th)], axis=1),
            np.stack([np.full(len(an), cx), np.full(len(an), cy), np.full(len(an), s), th + an], axis=1),
        ]
    )
    d = model.likelihood_distances(prepared, poses, template_log, **inputs)
    return LikelihoodSlices(sc, d[: len(sc)], an, d[len(sc) :])
