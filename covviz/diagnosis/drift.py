"""Why did it drift? Per-frame evidence, a cause for every loss, and label-free suspects.

:class:`Diagnoser` is an observer (``on_start`` / ``on_frame`` / ``on_end``,
no Rerun) that reads each tracker's :class:`~covviz.records.FrameRecord`, the
frame and its ground truth, and computes through the tracker's own frozen
:class:`~covviz.model.observation.ObservationModel` (or, for trackers without one, a
probe model built the same way on the first frame):

1. **Model or search failure, every frame** (with ground truth). The distance
   the likelihood would give at the true pose and at the estimate — for the
   estimate's template and for the best template of the cloud — and whether any
   particle reached the truth. A frame off track is a *model* failure when the
   likelihood prefers the wrong place (the truth scores no better than the
   estimate), a *search* failure when the truth would score better but no
   particle reached it, and an *estimate* failure when particles did reach the
   better-scoring truth and the estimate still lies elsewhere (:data:`LABELS`).
2. **A cause for every loss.** When the event detector (:mod:`covviz.diagnosis.events`)
   reports a loss, the frames from a little before the drift began to the loss
   are read against the target's look before it (the *baseline*) and the
   first cause of :data:`CAUSES` whose rule holds is named, with the numbers
   behind it and the frames it looked at (:class:`Diagnosis`).
3. **Suspects without ground truth** (:data:`SUSPECTS`): weights collapsing,
   the best distance leaving its running range, a second mode of the weights,
   the scale running away. ``covviz bench`` scores them against the losses.

Every threshold is a field of :class:`DiagnosisConfig` whose default is a named
module constant; the config is saved with the results and in the recording.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, field, fields, replace

import numpy as np

from covviz.config import ConfigError, Spec, check
from covviz.diagnosis.events import EVENT_DEFAULTS, Event, EventConfig, EventDetector
from covviz.metrics import iou
from covviz.model.features import pose_to_box
from covviz.model.image import to_gray
from covviz.model.observation import ObservationModel, box_to_pose
from covviz.model.particles import effective_sample_size
from covviz.model.spd import distance_jbld, distance_riemann, logdet, mean_logeuclid
from covviz.model.stats import median
from covviz.runner import Findings, Observer, RunStart

__all__ = [
    "CAUSES",
    "LABELS",
    "SUSPECTS",
    "Diagnoser",
    "Diagnosis",
    "DiagnosisConfig",
    "FrameEvidence",
    "Suspect",
    "diagnose",
    "score_suspects",
]

#: Frame labels: on track, or which part of the filter failed (see the module docstring).
LABELS = ("ok", "model", "search", "estimate")
#: The causes a loss is diagnosed with, in the order their rules are tried (the first that holds is
#: the cause; the others that hold too are listed as contributing). ``unknown``: none held.
CAUSES = ("fast_motion", "scale", "illumination", "distractor", "occlusion", "appearance", "impoverishment")
#: Kinds of label-free suspect events.
SUSPECTS = ("collapse", "distance_jump", "second_mode", "scale_runaway")



@dataclass(frozen=True)
class DiagnosisConfig:
    """Every threshold of the diagnosis, with its default (each field's range: :data:`DIAGNOSIS_SPECS`)."""

    #: ---- per-frame evidence ------------------------------------------------------------------------
    #: A frame is on track (label ``ok``) when its IoU with the ground truth is at least this.
    on_track_iou: float = 0.5
    #: A particle has reached the truth when its box has at least this IoU with the ground-truth box.
    near_iou: float = 0.5
    #: Templates of the cloud scored at the truth and the estimate (an evenly strided subset plus the top ones).
    cloud_templates: int = 64
    #: The heaviest templates always among them.
    cloud_top: int = 20
    #: Frames of evidence kept per tracker (bounds memory; a diagnosis looks back at most this far).
    history: int = 300
    #: Particles farther than this (target sizes) from the estimate count towards a second mode.
    mode_distance: float = 0.75
    #: ---- the causes --------------------------------------------------------------------------------
    #: Frames before the drift onset (and after it) that the diagnosis reads.
    look_before: int = 3
    #: Frames before that window that define the target's baseline look.
    baseline_frames: int = 8
    #: fast motion: the truth's centre moved at least this many target sizes in one frame ...
    fast_motion: float = 0.5
    #: ... and (particle trackers) ended farther than this (target sizes) from the nearest particle.
    fast_outside: float = 0.5
    #: scale: the estimate's size over the truth's (or its inverse) at least this at the loss ...
    scale_ratio: float = 1.6
    #: ... with the smaller box at least this much inside the larger (the centre held, the size wrong).
    scale_contain: float = 0.7
    #: Changes of the target's look are measured against the baseline and compared with thresholds that are
    #: at least NOISE_FACTOR times the baseline's own spread (real targets vary from frame to frame).
    noise_factor: float = 2.0
    #: illumination: a quadrant of the target at least this factor darker or brighter than its baseline.
    light_ratio: float = 2.0
    #: occlusion: on some frame, a quadrant's descriptor moved at least this far (sqrt(8 J)) from its baseline ...
    quadrant_jump: float = 3.0
    #: ... while another stayed within this of its own, or changed at most 1/PARTIAL_RATIO as much (an occluder
    #: entering from one side); or (a static occluder hiding all of it) the region
    #: shows what stood at that place before the target came: a descriptor within TARGET_HOLD of the scene's
    #: there, and at most half as far from it as from the target's baseline.
    quadrant_hold: float = 2.0
    partial_ratio: float = 2.0
    #: Frames kept to look up the scene at the target's place before it came (the most recent one where the
    #: target's box overlapped today's by at most SCENE_IOU).
    scene_frames: int = 30
    scene_iou: float = 0.1
    #: distractor: at the loss, the target still looks as before (d of the whole region, gain-normalised,
    #: from its baseline, at most this) ...
    target_hold: float = 2.5
    #: ... and the region the tracker followed looks like the target too (at most this from the baseline) ...
    distractor_look: float = 2.0
    #: ... and the likelihood scores that region at least as well as the truth (d_eff margin) ...
    distractor_margin: float = 0.0
    #: ... and it looks like the target clearly more than the scene around the target does: at most this
    #: share of the nearest surrounding region's distance (median over the baseline frames). A street of
    #: textured regions is not a look-alike.
    distractor_background: float = 0.75
    #: The surrounding regions are measured every this many frames.
    scene_every: int = 4
    #: Two causes whose rules held this close (strength ratio) are a tie; the replays' verdict breaks it.
    tie_ratio: float = 1.2
    #: appearance: on some frame, the target's look moved at least this far from its baseline ...
    appearance_change: float = 2.5
    #: ... and every quadrant at least this far: a change of the whole target, not of a part.
    appearance_quadrant: float = 2.0
    #: impoverishment: ESS/N below this on at least IMPOVERISHED_FRAMES frames of the window.
    impoverished_ess: float = 0.02
    impoverished_frames: int = 3
    #: ---- suspects (no ground truth) ----------------------------------------------------------------
    #: collapse: ESS/N below this ...
    suspect_ess: float = 0.01
    #: ... on this many consecutive frames.
    suspect_ess_frames: int = 3
    #: distance jump: the best particle distance above its running median by this many running MADs ...
    suspect_mads: float = 6.0
    #: ... over a running window of this many frames (and at least this many frames seen).
    suspect_window: int = 30
    #: second mode: at least this share of the weight sits MODE_DISTANCE or more from the estimate ...
    suspect_mode_mass: float = 0.25
    #: ... on this many consecutive frames.
    suspect_mode_frames: int = 2
    #: scale runaway: the estimate's scale changed by this factor within SUSPECT_WINDOW frames.
    suspect_scale: float = 1.8
    #: A suspect matches a loss when it is raised between MATCH_BEFORE frames before the drift began and
    #: MATCH_AFTER frames after the loss.
    match_before: int = 10
    match_after: int = 5
    events: EventConfig = field(default_factory=lambda: EVENT_DEFAULTS)

    def __post_init__(self):
        check(self, DIAGNOSIS_SPECS)
        if self.history < self.baseline_frames + self.look_before + 2:
            raise ConfigError("DiagnosisConfig.history must hold the baseline and the look-back frames")

    def as_dict(self) -> dict:
        return asdict(self)


def _diagnosis_specs() -> dict[str, Spec]:
    """Every threshold non-negative (IoUs and shares in [0, 1]; counts at least 1 where 0 means nothing)."""
    unit = {"on_track_iou", "near_iou", "scene_iou", "impoverished_ess", "suspect_ess", "suspect_mode_mass",
            "scale_contain"}
    at_least_one = {"cloud_templates", "history", "suspect_window", "suspect_ess_frames", "suspect_mode_frames"}
    specs: dict[str, Spec] = {}
    for f in fields(DiagnosisConfig):
        if f.name == "events":
            specs[f.name] = Spec("config", cls=EventConfig)
        elif f.type in ("int", int):
            specs[f.name] = Spec("int", 1 if f.name in at_least_one else 0)
        else:
            specs[f.name] = Spec("float", 0, 1 if f.name in unit else None)
    return specs


#: Each field of :class:`DiagnosisConfig`: its type and range (:mod:`covviz.config`).
DIAGNOSIS_SPECS: dict[str, Spec] = _diagnosis_specs()


# --------------------------------------------------------------------------- #
# per-frame evidence
# --------------------------------------------------------------------------- #
@dataclass(frozen=True, eq=False)
class FrameEvidence:
    """What the diagnosis measured on one frame of one tracker (``nan`` / None where it cannot).

    Attributes
    ----------
    frame : int
        1-based frame number (as shown to users).
    iou, centre_error : float
        Against the ground truth; the centre error in target sizes (``sqrt(w h)`` of the truth).
    scale_ratio : float
        ``sqrt`` of the estimate's area over the truth's.
    truth_motion : float
        The true centre's motion since the previous frame, target sizes.
    reach : float
        The best IoU of a particle's box with the truth (nan without particles).
    nearest : float
        Distance from the true centre to the nearest particle's centre, target sizes.
    ess_frac, max_weight, survivors : float
        Of the weights (survivors: distinct ancestors / N after resampling).
    mode_mass : float
        Share of the weight on particles at least ``mode_distance`` target sizes from the estimate.
    d_min : float
        The best particle's likelihood distance (no ground truth needed).
    scale : float
        The estimate's scale.
    d_est, d_truth : float
        ``d_eff`` of the estimate's template at the estimate and at the truth.
    best_est, best_truth : float
        The best ``d_eff`` of any template of the cloud at the estimate and at the truth.
    label : str
        One of :data:`LABELS`, or "" without ground truth or a model.
    brightness : ndarray, shape (4,)
        Mean grey level of each quadrant of the true box (raw, not gain-normalised).
    ring_brightness : float
        Mean grey level of a ring one box wide around the true box.
    truth_C, truth_Q : ndarray
        Descriptor (9, 9) and quadrant descriptors (4, 9, 9) at the truth (probe model).
    truth_box : ndarray, shape (4,)
    estimate_C : ndarray, shape (9, 9)
        Descriptor at the estimate's box (probe model): what the tracker followed.
    scene_C : ndarray, shape (9, 9)
        Descriptor at today's true box in the latest kept frame where the target was
        elsewhere: the scene that stands at the target's place.
    contain : float
        Share of the smaller of the estimate's and the truth's boxes inside the larger.
    term_gaps : dict of str to float, or None
        Each part of ``d_eff²`` of the estimate's template at the truth minus at
        the estimate, by name (``descriptor`` for ``d²``, then each term of the
        likelihood, weighted): positive parts are those that made the
        likelihood prefer the estimate's place to the truth's.
    """

    frame: int
    iou: float = float("nan")
    centre_error: float = float("nan")
    scale_ratio: float = float("nan")
    truth_motion: float = float("nan")
    reach: float = float("nan")
    nearest: float = float("nan")
    ess_frac: float = float("nan")
    max_weight: float = float("nan")
    survivors: float = float("nan")
    mode_mass: float = float("nan")
    d_min: float = float("nan")
    scale: float = float("nan")
    d_est: float = float("nan")
    d_truth: float = float("nan")
    best_est: float = float("nan")
    best_truth: float = float("nan")
    label: str = ""
    brightness: np.ndarray | None = None
    ring_brightness: float = float("nan")
    truth_C: np.ndarray | None = None
    truth_Q: np.ndarray | None = None
    truth_box: np.ndarray | None = None
    estimate_C: np.ndarray | None = None
    #: The nearest of the regions around the truth (same size, 1.5 boxes away), as far from the target's
    #: look as it is (whole-region ``d``): how much the scene around it resembles the target. Every
    #: ``scene_every``-th frame; ``nan`` on the others.
    background_look: float = float("nan")
    scene_C: np.ndarray | None = None
    contain: float = float("nan")
    term_gaps: dict | None = None

    def series(self) -> dict[str, float]:
        """The scalar evidence of this frame, by name (for logging and results)."""
        out = {
            k: float(getattr(self, k))
            for k in (
                "iou", "centre_error", "scale_ratio", "truth_motion", "reach", "nearest", "ess_frac",
                "max_weight", "survivors", "mode_mass", "d_min", "scale", "d_est", "d_truth", "best_est",
                "best_truth", "ring_brightness",
            )
        }
        if self.brightness is not None:
            out["brightness"] = float(np.mean(self.brightness))
        for k, v in (self.term_gaps or {}).items():
            out[f"gap_{k}"] = float(v)
        return out


def _box_quadrant_means(gray: np.ndarray, box) -> tuple[np.ndarray, float]:
    """Mean grey of the four quadrants of an axis-aligned box, and of a ring one box wide around it."""
    H, W = gray.shape
    x, y, w, h = (float(v) for v in box)
    if not all(map(math.isfinite, (x, y, w, h))):
        return np.full(4, np.nan), float("nan")

    def mean(x0, y0, x1, y1):
        # Python's min/max and math.floor/ceil: np.clip on scalars cost more than the means (6 per frame).
        a, b = min(max(math.floor(x0), 0), W), min(max(math.ceil(x1), 0), W)
        c, d = min(max(math.floor(y0), 0), H), min(max(math.ceil(y1), 0), H)
        if b <= a or d <= c:
            return np.nan, 0
        r = gray[c:d, a:b]
        return float(r.mean()), r.size

    xm, ym = x + w / 2, y + h / 2
    q = np.array([mean(x, y, xm, ym)[0], mean(xm, y, x + w, ym)[0], mean(x, ym, xm, y + h)[0],
                  mean(xm, ym, x + w, y + h)[0]])
    big, nb = mean(x - w, y - h, x + 2 * w, y + 2 * h)
    inner, ni = mean(x, y, x + w, y + h)
    ring = (big * nb - inner * ni) / (nb - ni) if nb > ni and np.isfinite(big) and np.isfinite(inner) else np.nan
    return q, float(ring)


def _containment(a: np.ndarray, b: np.ndarray) -> float:
    """Share of the smaller of two boxes ``x, y, w, h`` that lies inside the larger."""
    x1, y1 = max(a[0], b[0]), max(a[1], b[1])
    x2, y2 = min(a[0] + a[2], b[0] + b[2]), min(a[1] + a[3], b[1] + b[3])
    inter = max(0.0, x2 - x1) * max(0.0, y2 - y1)
    small = min(a[2] * a[3], b[2] * b[3])
    return float(inter / small) if small > 0 else float("nan")


def _cloud_subset(weights: np.ndarray, n: int, top: int) -> np.ndarray:
    """Indices of at most ``n`` templates: the ``top`` heaviest and an even stride over the rest (deterministic)."""
    m = len(weights)
    if m <= n:
        return np.arange(m)
    heavy = np.argsort(-weights, kind="stable")[:top]
    stride = np.linspace(0, m - 1, max(1, n - len(heavy))).round().astype(int)
    return np.unique(np.concatenate([heavy, stride]))


# --------------------------------------------------------------------------- #
# diagnoses and suspects
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class Diagnosis:
    """The cause named for one loss of track, with its evidence.

    Attributes
    ----------
    cause : str
        One of :data:`CAUSES`, or ``unknown``.
    also : tuple of str
        Other causes whose rules held too (later in :data:`CAUSES`' order).
    lost_at, drift_began : int
        1-based frames of the loss and of the drift onset.
    frames : (int, int)
        First and last frame the diagnosis read (1-based).
    baseline : (int, int)
        Frames that defined the target's baseline look (1-based; ``(0, 0)`` if none).
    evidence : dict
        The numbers the rules compared with their thresholds, by name.
    labels : dict
        How many frames of the window were ``model`` / ``search`` / ``estimate`` failures.
    text : str
        A one-paragraph card: the cause, why, and where to look.
    """

    cause: str
    also: tuple
    lost_at: int
    drift_began: int
    frames: tuple
    baseline: tuple
    evidence: dict
    labels: dict
    text: str

    def as_dict(self) -> dict:
        d = asdict(self)
        d["also"], d["frames"], d["baseline"] = list(self.also), list(self.frames), list(self.baseline)
        return d


@dataclass(frozen=True)
class Suspect:
    """A label-free warning: something in the filter's own numbers looks like trouble."""

    frame: int
    kind: str
    text: str
    value: float

    def as_dict(self) -> dict:
        return asdict(self)


def _finite(v) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    return a[np.isfinite(a)]


def _fmt(v: float, digits: int = 2) -> str:
    return "–" if not np.isfinite(v) else f"{v:.{digits}f}"


class _LookChanges:
    """How the target's look (at the truth, probe model) moved from its baseline over the window."""

    def __init__(self):
        self.frames: list[int] = []
        self.c = np.zeros(0)  # whole region, affine-invariant d from the baseline mean
        self.q = np.zeros((0, 4))  # quadrants, sqrt(8 J)
        self.light = np.zeros((0, 4))  # log2 brightness ratio per quadrant
        self.est = np.zeros(0)  # the estimate's region against the target's baseline
        self.scene = np.zeros(0)  # the target's region against the scene that stood there before
        self.noise_c = self.noise_q = 0.0
        self.evidence: dict[str, float] = {}

    @classmethod
    def of(cls, base: list[FrameEvidence], win: list[FrameEvidence]) -> _LookChanges:
        out = cls()
        nan = float("nan")
        out.evidence = {"target_change_max": nan, "target_change_at_loss": nan, "estimate_look_at_loss": nan,
                        "quadrant_change_max": nan, "quadrant_change_min": nan, "light_log2_max": nan,
                        "baseline_noise": nan, "background_look": nan}
        rows = [h for h in win if h.truth_C is not None]
        if len(base) < 1 or not rows:
            return out
        C0 = mean_logeuclid(np.stack([h.truth_C for h in base]))
        Q0 = np.stack([mean_logeuclid(np.stack([h.truth_Q[k] for h in base])) for k in range(4)])
        ld0 = logdet(Q0)
        b0 = np.nanmean(np.stack([h.brightness for h in base]), axis=0)
        out.noise_c = float(max(distance_riemann(C0, h.truth_C) for h in base))
        out.noise_q = float(max(distance_jbld(Q0, h.truth_Q, logdet_a=ld0).max() for h in base))
        out.frames = [h.frame for h in rows]
        out.c = np.array([float(distance_riemann(C0, h.truth_C)) for h in rows])
        out.q = np.stack([distance_jbld(Q0, h.truth_Q, logdet_a=ld0) for h in rows])
        with np.errstate(divide="ignore", invalid="ignore"):
            out.light = np.stack([np.log2(np.maximum(h.brightness, 1e-3) / np.maximum(b0, 1e-3)) for h in rows])
        out.est = np.array([float(distance_riemann(C0, h.estimate_C)) if h.estimate_C is not None else nan
                            for h in rows])
        out.scene = np.array([float(distance_riemann(h.scene_C, h.truth_C)) if h.scene_C is not None else nan
                              for h in rows])
        k = int(np.argmax(out.q.max(axis=1)))
        out.evidence = {
            "target_change_max": float(out.c.max()),
            "target_change_at_loss": float(out.c[-1]),
            "estimate_look_at_loss": float(out.est[-1]),
            "quadrant_change_max": float(out.q[k].max()),
            "quadrant_change_min": float(out.q[k].min()),
            "light_log2_max": float(np.nanmax(np.abs(out.light))) if np.isfinite(out.light).any() else nan,
            "baseline_noise": out.noise_c,
            "background_look": _nanmedian([h.background_look for h in base + rows[:1]]),
        }
        return out

    @property
    def light_max(self) -> float:
        return self.evidence["light_log2_max"]

    @property
    def last_c(self) -> float:
        return self.evidence["target_change_at_loss"]

    @property
    def last_est(self) -> float:
        return self.evidence["estimate_look_at_loss"]

    @property
    def background(self) -> float:
        """How close the scene around the target came to its look (``nan`` if never measured)."""
        return self.evidence["background_look"]

    def partial(self, jump: float, hold: float, ratio: float) -> int | None:
        """The first frame where some quadrant moved at least ``jump`` while another stayed within ``hold``
        or moved at most ``1/ratio`` as far."""
        for f, q in zip(self.frames, self.q):
            if q.max() >= jump and (q.min() <= hold or q.max() >= ratio * q.min()):
                self.evidence["partial_frame"] = float(f)
                self.evidence["quadrant_change_max"], self.evidence["quadrant_change_min"] = float(q.max()), float(q.min())
                return f
        return None

    def scene_in_front(self, change: float, near: float) -> int | None:
        """The first frame where the region changed at least ``change`` from the target's look but shows
        the scene that stood there before (within ``near``, and at most half as far as from the target)."""
        for f, c, sc in zip(self.frames, self.c, self.scene):
            if np.isfinite(sc) and c >= change and sc <= near and sc <= c / 2:
                self.evidence["scene_frame"] = float(f)
                self.evidence["scene_distance"] = float(sc)
                return f
        return None

    def whole(self, change: float, each: float) -> int | None:
        """The first frame where the whole region moved at least ``change`` and every quadrant at least ``each``."""
        for f, c, q in zip(self.frames, self.c, self.q):
            if c >= change and q.min() >= each:
                self.evidence["whole_frame"] = float(f)
                return f
        return None


def diagnose(history: list[FrameEvidence], lost_at: int, drift_began: int, cfg: DiagnosisConfig) -> Diagnosis:
    """Name the cause of a loss from the evidence of the frames before it.

    Parameters
    ----------
    history : list of FrameEvidence
        In frame order, ending at (or after) the loss.
    lost_at, drift_began : int
        1-based frames of the loss and the drift onset (:class:`covviz.diagnosis.events.EventDetector`).
    cfg : DiagnosisConfig

    Returns
    -------
    Diagnosis
    """
    lo = drift_began - cfg.look_before
    win = [h for h in history if lo <= h.frame <= lost_at]
    base = [h for h in history if lo - cfg.baseline_frames <= h.frame < lo and h.truth_C is not None]
    if len(base) < 2:  # a drift from the very start: the earliest frames with ground truth stand in
        base = [h for h in history if h.truth_C is not None and h.frame < lost_at][:2]
    ev: dict[str, float] = {}
    held: list[str] = []
    if not win:
        win = [h for h in history if h.frame <= lost_at][-1:]
    last = win[-1]

    # ---- fast motion: the truth jumped out of the particles' reach --------------------------
    motion = _finite([h.truth_motion for h in win])
    ev["truth_motion_max"] = float(motion.max()) if len(motion) else float("nan")
    fast_frame = win[int(np.nanargmax([h.truth_motion if np.isfinite(h.truth_motion) else -1 for h in win]))]
    outside = fast_frame.nearest
    ev["nearest_particle_at_jump"] = float(outside)
    if ev["truth_motion_max"] >= cfg.fast_motion and (not np.isfinite(outside) or outside >= cfg.fast_outside):
        held.append("fast_motion")

    # ---- scale: centre held, size wrong (on some frame before the loss: the size went wrong first) ----
    ev["scale_ratio_at_loss"] = float(last.scale_ratio)
    ev["centre_error_at_loss"] = float(last.centre_error)
    ratios = _finite([max(h.scale_ratio, 1 / h.scale_ratio) for h in win if h.scale_ratio > 0])
    ev["scale_ratio_max"] = float(ratios.max()) if len(ratios) else float("nan")
    for h in win:
        r = h.scale_ratio
        if np.isfinite(r) and r > 0 and max(r, 1 / r) >= cfg.scale_ratio and h.contain >= cfg.scale_contain:
            ev["scale_frame"], ev["scale_ratio"], ev["containment"] = float(h.frame), float(r), float(h.contain)
            held.append("scale")
            break

    # ---- the target's look against its baseline ---------------------------------------------
    look = _LookChanges.of(base, win)
    ev.update(look.evidence)
    hold_c = max(cfg.target_hold, cfg.noise_factor * look.noise_c)
    # illumination: part of the target much darker or brighter than before
    if np.isfinite(look.light_max) and look.light_max >= np.log2(cfg.light_ratio):
        held.append("illumination")
    # distractor: at the loss the target still looks like itself, and the tracker sits on a look-alike
    # that the likelihood scores at least as well
    margin = last.best_truth - last.best_est if np.isfinite(last.best_truth) else float("nan")
    ev["truth_minus_estimate_best_d"] = float(margin)
    if (
        np.isfinite(look.last_c)
        and look.last_c <= hold_c
        and look.last_est <= max(cfg.distractor_look, cfg.noise_factor * look.noise_c)
        and (not np.isfinite(margin) or margin >= cfg.distractor_margin)
        and last.iou < cfg.on_track_iou
        and not (look.background > 0 and look.last_est > cfg.distractor_background * look.background)
    ):
        held.append("distractor")
    # occlusion: on some frame, some quadrants changed while another held
    jump = max(cfg.quadrant_jump, cfg.noise_factor * look.noise_q)
    hold = max(cfg.quadrant_hold, cfg.noise_factor * look.noise_q / 1.5)
    if look.partial(jump, hold, cfg.partial_ratio) is not None or look.scene_in_front(
        max(cfg.appearance_change, cfg.noise_factor * look.noise_c), hold_c
    ) is not None:
        held.append("occlusion")
    # appearance: on some frame, the whole target changed
    if look.whole(max(cfg.appearance_change, cfg.noise_factor * look.noise_c), cfg.appearance_quadrant) is not None:
        held.append("appearance")
    ev.update(look.evidence)  # with the frames the partial / whole changes were found on

    # ---- impoverishment: the weights sat on a handful of particles --------------------------
    ess = _finite([h.ess_frac for h in win])
    ev["ess_frac_min"] = float(ess.min()) if len(ess) else float("nan")
    n_low = int((ess < cfg.impoverished_ess).sum())
    ev["frames_ess_low"] = float(n_low)
    if n_low >= cfg.impoverished_frames:
        held.append("impoverishment")

    # ---- which part of the likelihood preferred the wrong place (model failures) --------------
    model_frames = [h for h in win if h.label == "model" and h.term_gaps]
    if model_frames:
        for k in model_frames[-1].term_gaps:
            ev[f"gap_{k}"] = float(np.mean([h.term_gaps.get(k, 0.0) for h in model_frames]))

    labels = {k: sum(1 for h in win if h.label == k) for k in LABELS[1:]}
    strength = _strengths(ev, look, cfg, hold_c, jump)
    ev.update({f"strength_{c}": s for c, s in strength.items()})
    # every rule that held: the causes in the scene first, the one whose evidence passed its threshold by
    # the most first; the filter's own state (impoverishment) only when nothing in the scene explains it
    ordered = sorted((c for c in CAUSES if c in held),
                     key=lambda c: (c in FILTER_STATES, -strength.get(c, 1.0), CAUSES.index(c)))
    cause = ordered[0] if ordered else "unknown"
    if not ordered:  # the nearest miss, for the card
        near = [(c, s) for c, s in strength.items() if np.isfinite(s) and s > 0]
        if near:
            c, s = max(near, key=lambda cs: cs[1])
            ev["nearest_rule"], ev["nearest_rule_share"] = CAUSES.index(c), float(s)
    text = _card(cause, ordered[1:], lost_at, drift_began, ev, labels, last)
    window = (int(win[0].frame), int(win[-1].frame))
    baseline = (int(base[0].frame), int(base[-1].frame)) if base else (0, 0)
    return Diagnosis(cause, tuple(ordered[1:]), int(lost_at), int(drift_began), window, baseline, ev, labels, text)


#: Offsets (box widths, box heights) of the regions around the truth that say how target-like the scene is.
SURROUND = ((-1.5, 0.0), (1.5, 0.0), (0.0, -1.2), (0.0, 1.2), (-1.5, -1.2), (1.5, 1.2), (-1.5, 1.2), (1.5, -1.2))


def _surrounding_boxes(gt: np.ndarray, shape) -> np.ndarray:
    """The regions of the truth's size around it (:data:`SURROUND`) that lie inside the frame, ``(m, 4)``."""
    x, y, w, h = gt
    H, W = shape[:2]
    boxes = np.array([[x + dx * w, y + dy * h, w, h] for dx, dy in SURROUND])
    ok = (boxes[:, 0] >= 0) & (boxes[:, 1] >= 0) & (boxes[:, 0] + w <= W) & (boxes[:, 1] + h <= H)
    return boxes[ok]


def scale_ratio_of(ev: dict) -> float:
    """The largest size ratio (estimate over truth, or its inverse) of the window."""
    r = ev.get("scale_ratio", float("nan"))
    held = max(r, 1 / r) if np.isfinite(r) and r > 0 else float("nan")
    return _nanmax(held, ev.get("scale_ratio_max", float("nan")))


def _nanmax(*values: float) -> float:
    """The largest finite value, ``nan`` if none is."""
    v = [x for x in values if np.isfinite(x)]
    return float(max(v)) if v else float("nan")


def _nanmedian(values) -> float:
    v = np.asarray([x for x in values if x is not None], dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(median(v)) if len(v) else float("nan")


def _strengths(ev: dict, look, cfg: DiagnosisConfig, hold_c: float, jump: float) -> dict[str, float]:
    """How far each cause's evidence went past its threshold, ``1 + (value - threshold) / threshold`` (> 1: the
    rule's main test passed; for a distance that had to stay below its threshold, ``1 + (threshold - value) /
    threshold``).

    The ranking of the causes that held, and the nearest miss when none did. One number per rule,
    its main comparison: fast motion the truth's jump over ``fast_motion``; scale the size ratio over
    ``scale_ratio``; illumination the brightness change over ``light_ratio`` (in log2); distractor
    how much closer the estimate's look is to the target's than the threshold it had to beat; occlusion
    the quadrant change over the jump it had to reach; appearance the whole region's change over
    ``appearance_change``; impoverishment the low-ESS frames over ``impoverished_frames``.
    """
    def ratio(v, thr):
        return float(v / thr) if np.isfinite(v) and thr > 0 else float("nan")

    scale = scale_ratio_of(ev)
    look_thr = max(cfg.distractor_look, cfg.noise_factor * look.noise_c)
    if look.background > 0:
        look_thr = min(look_thr, cfg.distractor_background * look.background)
    est = ev.get("estimate_look_at_loss", float("nan"))
    return {
        "fast_motion": ratio(ev.get("truth_motion_max", float("nan")), cfg.fast_motion),
        "scale": ratio(scale, cfg.scale_ratio),
        "illumination": ratio(ev.get("light_log2_max", float("nan")), np.log2(cfg.light_ratio)),
        # a distance that had to stay below its threshold: 1 + its relative margin, at most 2
        "distractor": 2.0 - est / look_thr if np.isfinite(est) and look_thr > 0 else float("nan"),
        # some quadrants changed while another held; or the scene that stood there before shows at the
        # target's place (a distance that had to stay below hold_c)
        "occlusion": _nanmax(
            ratio(ev.get("quadrant_change_max", float("nan")), jump),
            2.0 - ev["scene_distance"] / hold_c if ("scene_frame" in ev and hold_c > 0) else float("nan"),
        ),
        "appearance": ratio(ev.get("target_change_max", float("nan")),
                            max(cfg.appearance_change, cfg.noise_factor * look.noise_c)),
        "impoverishment": ratio(ev.get("frames_ess_low", float("nan")), cfg.impoverished_frames),
    }


#: Causes that describe the filter rather than the scene: named only when no cause in the scene held.
FILTER_STATES = ("impoverishment",)

#: Which causes each verdict of the replays favours when two causes tie (a search failure: the target
#: went where the particles did not; a model failure: the target's look, or a look-alike, misled it).
VERDICT_FAVOURS = {
    "search": ("fast_motion", "impoverishment"),
    "model": ("occlusion", "distractor", "appearance", "illumination"),
    "search+model": ("occlusion", "distractor", "appearance", "illumination"),
}


def rerank(diagnosis: dict, verdict: str, tie_ratio: float) -> dict:
    """A diagnosis's causes re-ranked with the replays' verdict: a tie between the first two broken by it.

    ``diagnosis``: the dict of :meth:`Diagnosis.as_dict`. Returns it (changed in place): ``cause`` and
    ``also`` swapped and ``tie_broken_by`` set to the verdict when the first two causes held within
    ``tie_ratio`` of each other's strength and the verdict favours the second, not the first.
    """
    also = list(diagnosis.get("also") or [])
    cause = diagnosis.get("cause")
    ev = diagnosis.get("evidence") or {}
    favoured = VERDICT_FAVOURS.get(verdict, ())
    if not also or cause in favoured or also[0] not in favoured:
        return diagnosis
    s1, s2 = ev.get(f"strength_{cause}", float("nan")), ev.get(f"strength_{also[0]}", float("nan"))
    if np.isfinite(s1) and np.isfinite(s2) and s2 > 0 and s1 / s2 <= tie_ratio:
        diagnosis["cause"], diagnosis["also"] = also[0], [cause, *also[1:]]
        diagnosis["tie_broken_by"] = verdict
    return diagnosis


def _card(cause, also, lost_at, drift_began, ev, labels, last: FrameEvidence) -> str:
    """The diagnosis in words: what happened, the numbers, and where to look."""
    why = {
        "fast_motion": f"the target jumped {_fmt(ev['truth_motion_max'])} target sizes in one frame, "
        f"beyond the particles (nearest {_fmt(ev['nearest_particle_at_jump'])} sizes away)",
        "scale": f"the size went wrong while the centre held: at frame {int(ev.get('scale_frame', 0))} the estimate "
        f"was {_fmt(ev.get('scale_ratio', np.nan))}x the truth's size with {_fmt(ev.get('containment', np.nan))} of the "
        "smaller box inside the larger",
        "illumination": f"part of the target became {_fmt(2 ** ev['light_log2_max'], 1)}x darker or brighter "
        "than before the drift",
        "occlusion": (
            f"some quadrants of the target changed (up to d = {_fmt(ev['quadrant_change_max'])}) while another held "
            f"(d = {_fmt(ev['quadrant_change_min'])})"
            if "partial_frame" in ev
            else f"the target's place shows the scene that stood there before (d = {_fmt(ev.get('scene_distance', np.nan))}"
            f" from it, {_fmt(ev['target_change_max'])} from the target's look): something static hides it"
        ),
        "distractor": f"the target still looks as before (d = {_fmt(ev['target_change_at_loss'])}) but the tracker "
        f"follows a look-alike (d = {_fmt(ev['estimate_look_at_loss'])} from the target's look) that the likelihood "
        f"scores as well (truth - estimate = {_fmt(ev['truth_minus_estimate_best_d'])})",
        "appearance": f"the whole target changed its look (d up to {_fmt(ev['target_change_max'])} from before) "
        "faster than the templates follow",
        "impoverishment": f"the weights sat on a handful of particles (ESS/N down to {_fmt(ev['ess_frac_min'], 3)} "
        f"on {int(ev['frames_ess_low'])} frames)",
        "unknown": "no rule of the vocabulary held; read the views and the replays' verdict",
    }[cause]
    fails = ", ".join(f"{v} {k}" for k, v in labels.items() if v) or "none labelled"
    s = (
        f"LOST at frame {lost_at} (drift began at {drift_began}): {cause.replace('_', ' ').upper()} - {why}. "
        f"Frames off track from the drift to the loss: {fails}."
    )
    if also:
        s += " Also held (by strength): " + ", ".join(
            f"{a.replace('_', ' ')} {ev.get(f'strength_{a}', float('nan')):.2f}x" for a in also) + "."
        s += f" {cause.replace('_', ' ')} held by {ev.get(f'strength_{cause}', float('nan')):.2f}x."
    if cause == "unknown" and "nearest_rule" in ev:
        near = CAUSES[int(ev["nearest_rule"])]
        share = ev["nearest_rule_share"]
        if share >= 1:  # its measure passed, a second condition of the rule did not: say which
            other = (f": a particle was {_fmt(ev.get('nearest_particle_at_jump', np.nan))} target sizes from the "
                     "jump, within the particles' reach" if near == "fast_motion"
                     else " (read the rule's other conditions in the evidence)")
            s += (f" Nearest: {near.replace('_', ' ')}: its measure passed its threshold ({share:.0%}) but the rule "
                  f"did not hold{other}.")
        else:
            s += (f" Nearest: {near.replace('_', ' ')} at {share:.0%} of its threshold"
                  + (f" (the box {_fmt(scale_ratio_of(ev))}x the truth's size)" if near == "scale" else "") + ".")
    gaps = {k[4:]: v for k, v in ev.items() if k.startswith("gap_") and np.isfinite(v)}
    if len(gaps) > 1:  # the likelihood has terms: say which preferred the estimate's place
        parts = sorted(gaps.items(), key=lambda kv: -kv[1])
        s += (
            " On the model failures the likelihood preferred the estimate's place through "
            + ", ".join(f"{k} {v:+.2f}" for k, v in parts)
            + " (d_eff² at the truth - at the estimate, mean)."
        )
    return s


# --------------------------------------------------------------------------- #
# the observer
# --------------------------------------------------------------------------- #
class _State:
    def __init__(self, name: str, cfg: DiagnosisConfig):
        self.name = name
        self.model: ObservationModel | None = None
        self.probe: ObservationModel | None = None
        self.history: deque = deque(maxlen=cfg.history)
        self.detector = EventDetector(cfg.events)
        self.events: list[Event] = []
        self.diagnoses: list[Diagnosis] = []
        self.suspects: list[Suspect] = []
        self.latest: FrameEvidence | None = None
        self.prev_truth: np.ndarray | None = None
        self.past: deque = deque(maxlen=cfg.scene_frames)  # (prepared frame, true box) of recent frames
        self.label_counts: dict[str, int] = {k: 0 for k in LABELS}
        self.d_run: deque = deque(maxlen=cfg.suspect_window)
        self.scale_run: deque = deque(maxlen=cfg.suspect_window)
        self.low_ess = 0
        self.mode_run = 0
        self.in_suspect: dict[str, bool] = {k: False for k in SUSPECTS}


@dataclass(frozen=True, slots=True)
class FrameNews:
    """What the diagnosis found for one tracker on one frame (handed down the observer pipeline).

    Attributes
    ----------
    evidence : FrameEvidence
    events : tuple of Event
        Events that this frame ended (storms, drift onsets, losses, recoveries).
    diagnoses : tuple of Diagnosis
        The diagnosis of each loss this frame confirmed.
    suspects : tuple of Suspect
        Label-free suspects raised on this frame.
    """

    evidence: FrameEvidence
    events: tuple = ()
    diagnoses: tuple = ()
    suspects: tuple = ()


class DiagnosisView:
    """Read-only access to a running diagnosis, for the observers after it (results writer, recorder)."""

    def __init__(self, diagnoser: Diagnoser) -> None:
        self._d = diagnoser

    @property
    def config(self) -> DiagnosisConfig:
        return self._d.config

    def report(self, index: int = 0) -> dict:
        """Events, diagnoses and suspects of tracker ``index`` so far, as plain data (for results JSON)."""
        return self._d.report(index)


class Diagnoser(Observer):
    """Observer computing the evidence, events, diagnoses and suspects of every tracker of a run.

    Put it in the observer pipeline before those that read it (the Rerun
    recorder, the results writer): its ``on_start`` hands them a
    :class:`DiagnosisView` (:attr:`Findings.diagnosis`), and each ``on_frame``
    the :class:`FrameNews` of every tracker (:attr:`Findings.news`).
    """

    def __init__(self, config: DiagnosisConfig | None = None, on_track_scores: bool = True):
        self.config = config or DiagnosisConfig()
        #: Whether the template cloud is scored at the truth and at the estimate (``d_truth``, ``d_est``,
        #: ``best_truth``, ``best_est``, ``term_gaps``) on frames where the estimate is on track (IoU at least
        #: ``on_track_iou``) too. Only a recorder shows them there (the "why" view's series); the labels,
        #: events, diagnoses and results read them off track only, so a run without a recorder leaves them
        #: ``nan`` on track and saves the two scorings (~0.7 ms of CPU a frame at 600 particles).
        self.on_track_scores = bool(on_track_scores)
        self.states: list[_State] = []
        self._view = DiagnosisView(self)
        self._init_box: np.ndarray | None = None

    # ------------------------------------------------------------------ #
    def on_start(self, start: RunStart, found: Findings) -> Findings:
        self.states = [_State(info.name, self.config) for info in start.trackers]
        for s, info in zip(self.states, start.trackers):
            s.model = info.model
        self._init_box = np.asarray(start.init_box, dtype=np.float64)
        return replace(found, diagnosis=self._view)

    def on_frame(self, frame, records, found: Findings) -> Findings:
        news = []
        gray = to_gray(frame.image)  # the frame's grey at full resolution (brightness), once for every tracker
        for s, rec in zip(self.states, records):
            if s.probe is None and int(frame.index) == 0:
                # Trackers without a covariance model are probed with the default tracker's model.
                s.probe = s.model if s.model is not None else ObservationModel.build(frame.image, self._init_box)
            ev = self._evidence(s, frame, rec, gray)
            if ev.label:
                s.label_counts[ev.label] += 1
            s.latest = ev
            s.history.append(ev)
            events, diagnoses = [], []
            for e in s.detector.update(ev.frame, ev.iou if np.isfinite(ev.iou) else None,
                                       ev.ess_frac if np.isfinite(ev.ess_frac) else None):
                s.events.append(e)
                events.append(e)
                if e.kind == "lost":
                    d = diagnose(list(s.history), e.frame, s.detector.drifts[-1], self.config)
                    s.diagnoses.append(d)
                    diagnoses.append(d)
            suspects = self._suspects(s, ev, rec)
            s.suspects.extend(suspects)
            news.append(FrameNews(ev, tuple(events), tuple(diagnoses), tuple(suspects)))
        return replace(found, diagnosis=self._view, news=tuple(news))

    # ------------------------------------------------------------------ #
    def _evidence(self, s: _State, frame, rec, gray: np.ndarray) -> FrameEvidence:
        cfg = self.config
        number = int(frame.index) + 1
        kw: dict = {"frame": number}
        box = np.asarray(rec.box, dtype=np.float64) if rec.box is not None else None
        lw = rec.log_weights
        w = None if lw is None else np.exp(np.asarray(lw, dtype=np.float64))
        if w is not None and len(w):
            n = len(w)
            ess = float(rec.ess) if np.isfinite(rec.ess) else effective_sample_size(lw)
            kw["ess_frac"] = ess / n
            kw["max_weight"] = float(w.max())
            idx = rec.resample_indices
            kw["survivors"] = len(np.unique(idx)) / len(idx) if (rec.resampled and idx is not None and len(idx)) else 1.0
            if rec.particle_poses is not None and rec.pose is not None and s.model is not None:
                size = s.model.base_size * float(rec.pose[2])
                dist = np.hypot(*(rec.particle_poses[:, :2] - rec.pose[:2]).T) / max(size, 1e-9)
                kw["mode_mass"] = float(w[dist >= cfg.mode_distance].sum())
        d_lik = rec.likelihood.distances if rec.likelihood is not None else None
        if d_lik is not None and len(d_lik):
            kw["d_min"] = float(np.min(d_lik))
        if rec.pose is not None:
            kw["scale"] = float(rec.pose[2])
        gt = frame.gt
        if gt is None or box is None or not np.all(np.isfinite(box)):
            return FrameEvidence(**kw)
        gt = np.asarray(gt, dtype=np.float64)
        size = float(np.sqrt(gt[2] * gt[3]))
        c_gt = gt[:2] + gt[2:] / 2
        c_est = box[:2] + box[2:] / 2
        kw["iou"] = float(iou(box[None], gt[None])[0])
        kw["centre_error"] = float(np.hypot(*(c_est - c_gt)) / size)
        kw["scale_ratio"] = float(np.sqrt(max(box[2] * box[3], 1e-12) / (gt[2] * gt[3])))
        kw["contain"] = _containment(box, gt)
        kw["truth_box"] = gt
        if s.prev_truth is not None:
            kw["truth_motion"] = float(np.hypot(*(c_gt - s.prev_truth)) / size)
        s.prev_truth = c_gt
        q, ring = _box_quadrant_means(gray, gt)
        kw["brightness"], kw["ring_brightness"] = q, ring
        if rec.particle_poses is not None and s.model is not None and len(rec.particle_poses):
            pb = pose_to_box(np.asarray(rec.particle_poses), s.model.base_wh)
            kw["reach"] = float(iou(pb, np.broadcast_to(gt, pb.shape)).max())
            kw["nearest"] = float(np.hypot(*(rec.particle_poses[:, :2] - c_gt).T).min() / size)
        probe = s.probe
        if probe is not None:
            pg = rec.inputs.gray if (probe is s.model and rec.inputs is not None) else probe.prepare(frame.image)
            truth_pose = box_to_pose(gt, probe.base_wh)
            poses = np.stack([truth_pose, box_to_pose(box, probe.base_wh)])
            C, Q = probe.quadrant_descriptors(pg, poses)
            kw["truth_C"], kw["truth_Q"], kw["estimate_C"] = C[0], Q[0], C[1]
            if number % cfg.scene_every == 0:
                ring = _surrounding_boxes(gt, frame.image.shape)
                if len(ring):
                    around = probe.descriptors(pg, np.stack([box_to_pose(b, probe.base_wh) for b in ring]))
                    kw["background_look"] = float(distance_riemann(np.broadcast_to(C[0], around.shape), around).min())
            if s.past:
                boxes = np.stack([b for _, b in s.past])
                apart = np.flatnonzero(iou(boxes, np.broadcast_to(gt, boxes.shape)) <= cfg.scene_iou)
                if len(apart):  # the latest frame where the target stood elsewhere
                    kw["scene_C"] = probe.descriptors(s.past[int(apart[-1])][0], truth_pose[None])[0]
            s.past.append((pg, gt))
        model = s.model
        if model is not None and rec.estimate_template is not None and rec.pose is not None:
            if not self.on_track_scores and kw["iou"] >= cfg.on_track_iou:
                kw["label"] = self._label(kw)  # "ok" on track: the rule reads no score there
                return FrameEvidence(**kw)
            mg = rec.inputs.gray if rec.inputs is not None else model.prepare(frame.image)
            truth_pose = box_to_pose(gt, model.base_wh)
            est_pose = np.asarray(rec.pose, dtype=np.float64)
            cloud = [np.asarray(rec.estimate_template, dtype=np.float64)[None]]
            if rec.templates is not None and w is not None and len(rec.templates) == len(w):
                sub = _cloud_subset(w, cfg.cloud_templates, cfg.cloud_top)
                cloud.append(np.asarray(rec.templates, dtype=np.float64)[sub])
            L = np.concatenate(cloud)
            inputs = rec.inputs.likelihood_kwargs() if rec.inputs is not None else {}  # what update() weighed by
            # The truth (row 0) and the estimate (row 1), observed in one call.
            scores, parts = model.template_scores(mg, np.stack([truth_pose, est_pose]), L, **inputs, parts=True)
            at_truth, at_est = scores
            parts_truth, parts_est = ({k: v[r] for k, v in parts.items()} for r in (0, 1))
            kw["d_truth"], kw["d_est"] = float(at_truth[0]), float(at_est[0])
            kw["best_truth"] = float(at_truth.min())
            kw["best_est"] = float(at_est.min())
            # Each part of d_eff² of the estimate's template (L[0]), at the truth minus at the estimate.
            kw["term_gaps"] = {k: float(parts_truth[k][0] - parts_est[k][0]) for k in parts_truth}
            kw["label"] = self._label(kw)
        return FrameEvidence(**kw)

    def _label(self, kw: dict) -> str:
        cfg = self.config
        if kw["iou"] >= cfg.on_track_iou:
            return "ok"
        if kw["best_truth"] >= kw["best_est"]:
            return "model"
        reach = kw.get("reach", float("nan"))
        if not np.isfinite(reach) or reach < cfg.near_iou:
            return "search"
        return "estimate"

    def _suspects(self, s: _State, ev: FrameEvidence, rec) -> list[Suspect]:
        cfg = self.config
        out: list[Suspect] = []

        def raise_once(kind: str, on: bool, text: str, value: float):
            if on and not s.in_suspect[kind]:
                out.append(Suspect(ev.frame, kind, text, float(value)))
            s.in_suspect[kind] = on

        if np.isfinite(ev.ess_frac):
            s.low_ess = s.low_ess + 1 if ev.ess_frac < cfg.suspect_ess else 0
            raise_once("collapse", s.low_ess >= cfg.suspect_ess_frames,
                       f"weights collapsed: ESS/N below {cfg.suspect_ess:g} for {cfg.suspect_ess_frames} frames",
                       ev.ess_frac)
        if np.isfinite(ev.d_min):
            run = np.array(s.d_run)
            jump = False
            if len(run) >= max(5, cfg.suspect_window // 2):
                med = float(median(run))
                mad = float(median(np.abs(run - med))) + 1e-6
                jump = ev.d_min > med + cfg.suspect_mads * mad
                value = (ev.d_min - med) / mad
            # The text only where it is raised (formatting it on every frame was a median and a string a frame).
            raise_once("distance_jump", jump,
                       f"best distance {ev.d_min:.2f} left its running range (median {med:.2f})" if jump else "",
                       value if jump else 0.0)
            if not jump:
                s.d_run.append(ev.d_min)
        if np.isfinite(ev.mode_mass):
            s.mode_run = s.mode_run + 1 if ev.mode_mass >= cfg.suspect_mode_mass else 0
            raise_once("second_mode", s.mode_run >= cfg.suspect_mode_frames,
                       f"second mode: {ev.mode_mass:.0%} of the weight sits away from the estimate", ev.mode_mass)
        if np.isfinite(ev.scale):
            s.scale_run.append(ev.scale)
            sc = np.array(s.scale_run)
            ratio = float(sc.max() / sc.min()) if len(sc) else 1.0
            raise_once("scale_runaway", ratio >= cfg.suspect_scale,
                       f"scale ran away: x{ratio:.2f} within {len(sc)} frames", ratio)
        return out

    # ------------------------------------------------------------------ #
    def report(self, index: int = 0) -> dict:
        """Events, diagnoses and suspects of tracker ``index`` as plain data (for results JSON)."""
        s = self.states[index]
        return {
            "events": [asdict(e) for e in s.events],
            "diagnoses": [d.as_dict() for d in s.diagnoses],
            "suspects": [sp.as_dict() for sp in s.suspects],
            "labels": dict(s.label_counts),
        }


def score_suspects(suspects: list[dict], drifts: list[tuple[int, int]], cfg: DiagnosisConfig | None = None):
    """Precision and recall of label-free suspects against the ground-truth losses.

    Parameters
    ----------
    suspects : list of dict
        ``{"frame": int, ...}`` (1-based).
    drifts : list of (int, int)
        ``(drift_began, lost_at)`` of each loss (1-based).

    Returns
    -------
    dict with ``true_positives`` (suspects within a loss's window: from
    ``match_before`` frames before the drift began to ``match_after`` after
    the loss), ``suspects``, ``losses``, ``losses_found`` (losses with at least
    one suspect in their window).
    """
    cfg = cfg or DiagnosisConfig()
    windows = [(d - cfg.match_before, lost + cfg.match_after) for d, lost in drifts]
    tp = sum(1 for sp in suspects if any(a <= sp["frame"] <= b for a, b in windows))
    found = sum(1 for a, b in windows if any(a <= sp["frame"] <= b for sp in suspects))
    return {"true_positives": tp, "suspects": len(suspects), "losses": len(drifts), "losses_found": found}
