"""Label-free per-frame drift signals for every tracker (no ground truth is ever read here).

:class:`SignalObserver` is an observer (``on_start`` / ``on_frame`` / ``on_end``)
that turns each tracker's :class:`~covviz.records.FrameRecord` and the frame into
one row of :data:`SIGNALS`, ``nan`` where a signal does not apply:

Any tracker (OpenCV's included):

* ``fb_error`` — the forward–backward error of a grid of points inside the
  previous box (pyramidal Lucas–Kanade, frame t−1 → t → t−1; Kalal, Mikolajczyk
  and Matas, ICPR 2010), median, in box sizes ``sqrt(w h)``;
* ``fb_fail`` — the share of those points LK lost on the way;
* ``flow_gap`` — how far the box's motion is from the median flow of its own
  content, box sizes;
* ``slip`` — the box's motion against its content's flow, as a signed vector summed
  over the last :attr:`SignalConfig.slip_frames` frames whose flow is trusted
  (:func:`covviz.model.flow.trusted`), in box sizes: a box sliding off its target onto a
  look-alike moves a little more than its content on every frame, always the same way, so
  the slide adds up here where each frame's ``flow_gap`` stays small; the jitter of a box
  on track cancels;
* ``colour`` — how much of its colour contrast with its surroundings the box has lost:
  ``1 − c_t / c_ref``, where ``c_t`` is the mean of ``P − ½`` inside the box minus its mean over the
  ring around it (the box grown by :data:`covviz.model.fgbg.RING_PAD` of its mean side on every side,
  both clipped to the frame), ``P`` each pixel's foreground probability under colour histograms of the
  *initial* box and its ring (:func:`covviz.model.fgbg.init_colour_model`, fixed for the run), and
  ``c_ref`` the median of ``c`` over the :attr:`SignalConfig.colour_ref` frames after the first (over
  those so far before then; floored at :data:`COLOUR_FLOOR`). 0: the box stands out from its
  surroundings as the target did; 1 and more: it is no more target-coloured than they are
  (:class:`ColourSignal`);
* ``motion`` — the box centre's motion, box sizes; ``scale_rate`` — ``|log|`` of
  the box size's change over :attr:`SignalConfig.scale_lag` frames;
* ``d_first`` / ``d_recent`` — the log-Euclidean distance of the box content's
  covariance descriptor to its first look and to the mean of its last
  :attr:`SignalConfig.recent` looks. Covariance trackers use their own
  observation (``estimate_descriptor``); the others a probe built like the
  default tracker's :class:`~covviz.model.observation.ObservationModel` on the
  *initial box* (not on ground truth);
* ``psr`` — a peak-to-sidelobe ratio of the likelihood around the estimate
  (Bolme et al., MOSSE, CVPR 2010), with distances ``d`` (lower is better):
  ``(mean d_side − d_peak) / std d_side``. Particle filters use their particles'
  own scores (sidelobe: particles at least :attr:`SignalConfig.psr_side` sizes
  from the best); the others a 3×3 coarse map of ``d_first`` around the box.

Particle filters only:

* ``ess`` — ESS/N; ``dmin_z`` — the best particle distance's robust z-score
  against its last :attr:`SignalConfig.z_window` values (median, 1.4826 MAD);
* ``mode_mass`` — the weight at least :attr:`SignalConfig.mode_distance`
  target sizes from the estimate;
* ``cloud_gap`` — the observed descriptor's log-Euclidean distance to the
  template cloud's weighted mean over the cloud's weighted RMS spread (floored at
  :attr:`SignalConfig.spread_floor`).

Records are read only through the accessors ``_rec_*`` below (one place per
field), so a change of :class:`~covviz.records.FrameRecord` is a change here.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

from covviz.model import fgbg
from covviz.model.adaptive import robust_z
from covviz.model.flow import FB_GRID, LK_LEVELS, LK_WINDOW, ROI_MARGIN, gray8, median_flow, trusted

__all__ = ["GENERIC_SIGNALS", "PARTICLE_SIGNALS", "SIGNALS", "ColourSignal", "SignalConfig", "SignalObserver",
           "colour_contrast", "fb_flow", "psr", "saved_value", "slip"]

#: Signals of every tracker.
GENERIC_SIGNALS = ("fb_error", "fb_fail", "flow_gap", "motion", "scale_rate", "d_first", "d_recent", "psr", "slip",
                   "colour")
#: Signals of particle filters only (``nan`` for the others).
PARTICLE_SIGNALS = ("ess", "dmin_z", "mode_mass", "cloud_gap")
#: Every signal, in the order they are saved.
SIGNALS = GENERIC_SIGNALS + PARTICLE_SIGNALS

#: Looks averaged into ``d_recent``.
RECENT = 10
#: Running window (frames) and the fewest frames of ``dmin_z``.
Z_WINDOW = 30
Z_MIN = 5
#: Target sizes from the estimate from which weight counts towards a second mode.
MODE_DISTANCE = 0.75
#: Sidelobe of the particles' PSR: particles at least this many sizes from the best one ...
PSR_SIDE = 0.5
#: ... at least this many of them, else the farthest quarter.
PSR_MIN_SIDE = 10
#: Floor of the template cloud's spread in ``cloud_gap`` (log-Euclidean): below the usual spread (1st
#: percentile 0.08 on Car4), above a cloud collapsed onto one ancestor by resampling, or frozen by the
#: adaptive diffusion, whose ratio would otherwise reach 10^5-10^6 (seen on the dev runs).
SPREAD_FLOOR = 0.05
#: Offset (box sizes) of the coarse map's 8 outer cells for trackers without particles.
COARSE_OFFSET = 0.5
#: Frames over which ``scale_rate`` compares the box size.
SCALE_LAG = 5
#: Frames whose box-against-content motion ``slip`` sums (5: of 5 / 10 / 20, the best alarm alone when it was
#: measured offline on the dev runs' boxes, ``docs/tuning.md``).
SLIP_FRAMES = 5
#: Frames after the first whose median colour contrast is ``colour``'s reference ...
COLOUR_REF = 10
#: ... floored here (a target whose colours never stood out: ``colour`` stays near 1 - c / floor, unusable
#: but finite).
COLOUR_FLOOR = 1e-3


@dataclass(frozen=True)
class SignalConfig:
    """Every parameter of the signals (defaults: the module constants)."""

    fb_grid: int = FB_GRID
    lk_window: int = LK_WINDOW
    lk_levels: int = LK_LEVELS
    roi_margin: float = ROI_MARGIN
    recent: int = RECENT
    z_window: int = Z_WINDOW
    z_min: int = Z_MIN
    mode_distance: float = MODE_DISTANCE
    psr_side: float = PSR_SIDE
    psr_min_side: int = PSR_MIN_SIDE
    coarse_offset: float = COARSE_OFFSET
    spread_floor: float = SPREAD_FLOOR
    scale_lag: int = SCALE_LAG
    slip_frames: int = SLIP_FRAMES
    colour_ref: int = COLOUR_REF

    def __post_init__(self):
        if self.fb_grid < 2 or self.lk_window < 3 or self.lk_levels < 0:
            raise ValueError("need fb_grid >= 2, lk_window >= 3, lk_levels >= 0")
        if self.recent < 1 or self.z_window < self.z_min or self.z_min < 2 or self.scale_lag < 1:
            raise ValueError("need recent >= 1, z_window >= z_min >= 2, scale_lag >= 1")
        if self.slip_frames < 1 or self.colour_ref < 1:
            raise ValueError("need slip_frames >= 1 and colour_ref >= 1")

    def as_dict(self) -> dict:
        return asdict(self)


# --------------------------------------------------------------------------- #
# the record, read in one place per field
# --------------------------------------------------------------------------- #
def _rec_box(rec) -> np.ndarray:
    return np.asarray(rec.box, dtype=np.float64).reshape(4)


def _rec_particle_poses(rec) -> np.ndarray | None:
    return None if rec.particle_poses is None else np.asarray(rec.particle_poses, dtype=np.float64)


def _rec_log_weights(rec) -> np.ndarray | None:
    return None if rec.log_weights is None else np.asarray(rec.log_weights, dtype=np.float64)


def _rec_ess(rec) -> float:
    return float(rec.ess)


def _rec_scores(rec) -> np.ndarray | None:
    """The distances the particles were weighed by (the likelihood's, else the descriptor's)."""
    d = rec.likelihood.distances if rec.likelihood is not None else rec.distances
    return None if d is None else np.asarray(d, dtype=np.float64)


def _rec_templates(rec) -> np.ndarray | None:
    return None if rec.templates is None else np.asarray(rec.templates, dtype=np.float64)


def _rec_descriptor(rec) -> np.ndarray | None:
    """The covariance descriptor the tracker observed at its estimate, if it has one."""
    return None if rec.estimate_descriptor is None else np.asarray(rec.estimate_descriptor, dtype=np.float64)


def _rec_pose(rec) -> np.ndarray | None:
    return None if rec.pose is None else np.asarray(rec.pose, dtype=np.float64)


# --------------------------------------------------------------------------- #
# pure helpers
# --------------------------------------------------------------------------- #
def _logm_spd(C: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(C)
    return (V * np.log(np.maximum(w, 1e-12))) @ V.T


def fb_flow(prev: np.ndarray, cur: np.ndarray, box, cfg: SignalConfig | None = None) -> tuple[float, float, np.ndarray]:
    """Forward-backward LK error, share of lost points and median flow of a grid inside ``box``
    (:func:`covviz.model.flow.median_flow` with the grid, window, levels and margin of ``cfg``)."""
    cfg = cfg or SignalConfig()
    return median_flow(prev, cur, box, cfg.fb_grid, cfg.lk_window, cfg.lk_levels, cfg.roi_margin)


def slip(gaps, size: float) -> float:
    """``slip``: the length of the sum of the trusted frames' ``motion − flow`` vectors (pixels; ``None`` for a
    frame whose flow is not trusted) over ``size`` pixels; ``nan`` if none is trusted."""
    ok = [g for g in gaps if g is not None]
    if not ok:
        return float("nan")
    return float(np.hypot(*np.sum(ok, axis=0)) / max(size, 1e-9))


def psr(d: np.ndarray, peak: int, side: np.ndarray) -> float:
    """Peak-to-sidelobe ratio of distances (lower is better): ``(mean d[side] - d[peak]) / std d[side]``.

    Parameters
    ----------
    d : ndarray, shape (n,)
    peak : int
        Index of the peak (the best score).
    side : ndarray of bool or int, the sidelobe's members (at least 2).
    """
    s = np.asarray(d, dtype=np.float64)[side]
    if len(s) < 2:
        return float("nan")
    return float((s.mean() - d[peak]) / (s.std() + 1e-6))


def saved_value(v: float) -> float | None:
    """A signal's value as results save it: 5 significant digits, None where undefined."""
    return None if not np.isfinite(v) else float(f"{v:.5g}")


def colour_contrast(frame: np.ndarray, lut: np.ndarray, grey: bool, box, compiled: bool = False) -> float:
    """Mean of ``lut`` (``P − ½`` per colour bin, :func:`covviz.model.fgbg.foreground_lut`) over ``box``'s pixels
    minus its mean over the ring around it (the box grown by :data:`covviz.model.fgbg.RING_PAD` of its mean
    side on every side); both clipped to the frame, edges rounded to whole pixels. ``nan`` if the box holds
    no pixel; an empty ring counts 0. ``compiled``: the window's values by a kernel (the same bits)."""
    x, y, w, h = (float(v) for v in box)
    if not (np.isfinite([x, y, w, h]).all() and w > 0 and h > 0):
        return float("nan")
    H, W = np.shape(frame)[:2]
    pad = fgbg.RING_PAD * (w + h) / 2
    X0, X1 = (int(np.clip(np.rint(v), 0, W)) for v in (x - pad, x + w + pad))
    Y0, Y1 = (int(np.clip(np.rint(v), 0, H)) for v in (y - pad, y + h + pad))
    x0, x1 = (int(np.clip(np.rint(v), X0, X1)) for v in (x, x + w))
    y0, y1 = (int(np.clip(np.rint(v), Y0, Y1)) for v in (y, y + h))
    a_in = (x1 - x0) * (y1 - y0)
    if a_in <= 0:
        return float("nan")
    P = fgbg.window_probabilities(frame, (X0, Y0, X1, Y1), lut, grey, compiled)
    s_in = float(P[y0 - Y0 : y1 - Y0, x0 - X0 : x1 - X0].sum())
    ring = (X1 - X0) * (Y1 - Y0) - a_in
    return s_in / a_in - ((float(P.sum()) - s_in) / ring if ring > 0 else 0.0)


class ColourSignal:
    """``colour`` of one tracker, frame by frame (module docstring): :meth:`step` with each frame and box,
    the first being the initial box. Its own class so that saved boxes can be scored the same way."""

    def __init__(self, ref_frames: int = COLOUR_REF):
        self.ref_frames = ref_frames
        self.lut: np.ndarray | None = None
        self.grey = False
        self.ref: list[float] = []
        self._ref_value: float | None = None  # the reference, once its frames are all in

    def step(self, image: np.ndarray, box) -> float:
        if self.lut is None:  # the initial box: the colour model, no value
            model = fgbg.init_colour_model(image, box, compiled=True)
            self.lut, self.grey = fgbg.foreground_lut(model), model.grey
            return float("nan")
        c = colour_contrast(image, self.lut, self.grey, box, compiled=True)
        if not np.isfinite(c):
            return float("nan")
        if self._ref_value is None:
            self.ref.append(c)
            ref = max(float(np.median(self.ref)), COLOUR_FLOOR)
            if len(self.ref) == self.ref_frames:
                self._ref_value = ref
        else:
            ref = self._ref_value
        return float(1.0 - c / ref)


# --------------------------------------------------------------------------- #
# the observer
# --------------------------------------------------------------------------- #
class _State:
    def __init__(self, cfg: SignalConfig):
        self.rows: list[np.ndarray] = []
        self.probe = None  # ObservationModel for trackers without a descriptor of their own
        self.own = False  # the tracker observes its own descriptor
        self.L0: np.ndarray | None = None  # log of the first look
        self.recent: deque = deque(maxlen=cfg.recent)
        self.boxes: deque = deque(maxlen=cfg.scale_lag + 1)
        self.d_run: deque = deque(maxlen=cfg.z_window)
        self.slip: deque = deque(maxlen=cfg.slip_frames)  # motion − flow (pixels) of recent frames, None: untrusted
        self.base_size = float("nan")
        self.colour = ColourSignal(cfg.colour_ref)


class SignalObserver:
    """Computes :data:`SIGNALS` for every tracker of a run, frame by frame, without ground truth
    (driven by :class:`covviz.diagnosis.detector.DriftWatch`, the observer).

    Attributes
    ----------
    latest : list of dict
        Each tracker's signals on the last frame, by name.
    """

    def __init__(self, config: SignalConfig | None = None):
        self.config = config or SignalConfig()
        self.states: list[_State] = []
        self.latest: list[dict] = []
        self._prev_gray: np.ndarray | None = None

    def on_start(self, n_trackers: int) -> None:
        self.states = [_State(self.config) for _ in range(n_trackers)]
        self.latest = [{} for _ in range(n_trackers)]
        self._prev_gray = None

    def on_frame(self, frame, records) -> None:
        gray = gray8(frame.image)
        for j, (s, rec) in enumerate(zip(self.states, records)):
            row = self._row(s, frame, rec, gray, int(frame.index))
            s.rows.append(row)
            self.latest[j] = dict(zip(SIGNALS, row.tolist()))
        self._prev_gray = gray

    # ------------------------------------------------------------------ #
    def _look(self, s: _State, frame, rec, box, index: int) -> tuple[np.ndarray | None, np.ndarray | None, object]:
        """Log of the content's descriptor at the estimate (and the prepared probe frame, if a probe is used)."""
        C = _rec_descriptor(rec)
        if index == 0:
            s.own = C is not None
            if not s.own:
                from covviz.model.observation import ObservationModel

                s.probe = ObservationModel.build(frame.image, box)  # the default tracker's model
        if s.own:
            return (None if C is None else _logm_spd(C)), None, None
        from covviz.model.observation import box_to_pose

        if not np.all(np.isfinite(box)) or box[2] <= 0 or box[3] <= 0:
            return None, None, None
        pg = s.probe.prepare(frame.image)
        pose = box_to_pose(box, s.probe.base_wh)
        off = self.config.coarse_offset * float(np.sqrt(box[2] * box[3]))
        grid = np.array([(dx, dy) for dy in (-off, 0.0, off) for dx in (-off, 0.0, off)])
        poses = np.repeat(pose[None], 9, axis=0)
        poses[:, :2] += grid
        Cs = s.probe.descriptors(pg, poses)
        logs = np.stack([_logm_spd(c) for c in Cs])
        return logs[4], logs, pg

    def _row(self, s: _State, frame, rec, gray: np.ndarray, index: int) -> np.ndarray:
        cfg = self.config
        out = dict.fromkeys(SIGNALS, float("nan"))
        box = _rec_box(rec)
        if index == 0:
            s.base_size = float(np.sqrt(max(box[2] * box[3], 1e-12)))
        # ---- motion, scale, forward-backward flow ---------------------------------------
        if s.boxes:
            prev_box = s.boxes[-1]
            size = float(np.sqrt(max(prev_box[2] * prev_box[3], 1e-12)))
            motion = (box[:2] + box[2:] / 2) - (prev_box[:2] + prev_box[2:] / 2)
            out["motion"] = float(np.hypot(*motion) / size)
            old = s.boxes[0]
            out["scale_rate"] = float(abs(0.5 * math.log(max(box[2] * box[3], 1e-12) / max(old[2] * old[3], 1e-12))))
            if self._prev_gray is not None and self._prev_gray.shape == gray.shape:
                fb, fail, flow = fb_flow(self._prev_gray, gray, prev_box, cfg)
                out["fb_error"], out["fb_fail"] = fb, fail
                if np.all(np.isfinite(flow)):
                    out["flow_gap"] = float(np.hypot(*(motion - flow)) / size)
                s.slip.append(motion - flow if trusted(fb, fail, flow) else None)
                out["slip"] = slip(s.slip, size)
        s.boxes.append(box)
        out["colour"] = s.colour.step(frame.image, box)
        # ---- the content's look against its first and recent looks -------------------------
        L, coarse, _ = self._look(s, frame, rec, box, index)
        if L is not None:
            if s.L0 is None:
                s.L0 = L
            out["d_first"] = float(np.linalg.norm(L - s.L0))
            if s.recent:
                out["d_recent"] = float(np.linalg.norm(L - np.mean(np.stack(s.recent), axis=0)))
            s.recent.append(L)
            if coarse is not None:
                d = np.linalg.norm((coarse - s.L0).reshape(9, -1), axis=1)
                out["psr"] = psr(d, 4, np.arange(9) != 4)
        # ---- particle filters ------------------------------------------------------------
        lw = _rec_log_weights(rec)
        if lw is not None and len(lw) and index > 0:
            n = len(lw)
            w = np.exp(lw - lw.max())
            w /= w.sum()
            ess = _rec_ess(rec)
            out["ess"] = (ess if np.isfinite(ess) else 1.0 / float(np.sum(w * w))) / n
            poses = _rec_particle_poses(rec)
            pose = _rec_pose(rec)
            d = _rec_scores(rec)
            if poses is not None and pose is not None:
                size = s.base_size * float(pose[2])
                dist = np.hypot(*(poses[:, :2] - pose[:2]).T) / max(size, 1e-9)
                out["mode_mass"] = float(w[dist >= cfg.mode_distance].sum())
                if d is not None and len(d) == n:
                    k = int(np.argmin(d))
                    far = np.hypot(*(poses[:, :2] - poses[k, :2]).T) / max(size, 1e-9)
                    side = far >= cfg.psr_side
                    if side.sum() < cfg.psr_min_side:
                        side = np.argsort(far)[-max(2, n // 4):]
                    out["psr"] = psr(d, k, side)
            if d is not None and len(d):
                dmin = float(np.min(d))
                run = np.asarray(s.d_run)
                if len(run) >= cfg.z_min:
                    out["dmin_z"] = robust_z(dmin, run)[0]
                s.d_run.append(dmin)
            T = _rec_templates(rec)
            if T is not None and L is not None and len(T) == n:
                flat = T.reshape(n, -1)
                mean = w @ flat
                spread = math.sqrt(max(float(w @ np.sum((flat - mean) ** 2, axis=1)), 0.0))
                out["cloud_gap"] = float(np.linalg.norm(L.ravel() - mean) / max(spread, cfg.spread_floor))
        return np.array([out[k] for k in SIGNALS])

    # ------------------------------------------------------------------ #
    def columns(self, index: int = 0) -> dict[str, np.ndarray]:
        """Tracker ``index``'s signals so far, one array per name, in frame order."""
        s = self.states[index]
        a = np.stack(s.rows) if s.rows else np.zeros((0, len(SIGNALS)))
        return {k: a[:, i] for i, k in enumerate(SIGNALS)}

    def report(self, index: int = 0) -> dict:
        """Tracker ``index``'s signals as plain data for the results JSON (``diagnosis.signals``)."""
        cols = self.columns(index)
        return {
            "signals": {k: [saved_value(v) for v in col] for k, col in cols.items()},
        }
