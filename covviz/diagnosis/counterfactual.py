"""Every verdict an experiment: replay a loss with the search, the model or the estimate fixed.

A rule read from single frames says *what happened in the scene* (fast motion,
occlusion, a distractor; :mod:`covviz.diagnosis.drift`). Which part of the
tracker failed is a different question, and the one way to answer it is to run
the tracker again with that part fixed — TIDE's oracle fixes for detection
(Bolya et al., ECCV 2020), here per loss, because covviz's trackers are
deterministic given their seed and can be forked from a snapshot.

For each loss (``lost_at``, whose drift began at ``drift_began``; 1-based frame
numbers) the replay starts from the newest checkpoint the runner kept before
frame ``s = drift_began − before`` (:class:`covviz.runner.CheckpointRing`),
tracks unchanged up to ``s``, then from ``s`` to ``lost_at + horizon`` under each
intervention (:class:`~covviz.trackers.base.Intervention`), acting after
propagation and before observing:

``none``
    No change: it must give the original boxes bit for bit (``identical``,
    computed with ``np.array_equal``; a mismatch is reported, never hidden).
``search``
    A fraction of the particles (``search_fraction``) is moved to the truth's
    pose on every replayed frame, keeping their templates: if the particles had
    reached the truth, would the likelihood have kept it?
``model``
    The appearance is known: every particle's template (and the colour
    histograms and quadrant references) is set from the truth's observation in
    that frame; IPCA's update is fed the truth's patch.
``estimate``
    The estimate is replaced, before anything uses it, by the particle nearest
    the truth among those holding 90% of the weight.
``search+model``
    Both: the ceiling.

An outcome is *kept* when the IoU at the loss frame is at least ``kept_iou``
and the mean IoU over the frames after it is too. The **verdict** is the
smallest fix that keeps the track, in the order ``estimate < search < model <
search+model``, or ``none helps``. OpenCV's trackers cannot be forked; for them
the one experiment is a ``restart`` at the truth at the drift onset. The
interventions' own random draws (which particles move) come from a generator
seeded by (seed, loss, intervention); the tracker's stream is used exactly as
in ``none``. The replays read the ground truth: without it there is no verdict.
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from covviz.metrics import iou
from covviz.runner import Findings, Observer, RunStart
from covviz.trackers.base import Intervention

__all__ = [
    "FIXES",
    "INTERVENTIONS",
    "CounterfactualConfig",
    "Counterfactuals",
    "Outcome",
    "Replay",
    "TruthIntervention",
    "replay_loss",
    "restart_loss",
    "verdict_of",
    "with_replays",
]

#: The interventions of a replay, in the order they run.
INTERVENTIONS = ("none", "estimate", "search", "model", "search+model")
#: The fixes, smallest first: the verdict is the first that keeps the track.
FIXES = ("estimate", "search", "model", "search+model")
#: Which part of the tracker each fix says failed (for the cards).
FIX_MEANING = {
    "estimate": "a better estimator would have sufficed",
    "search": "with particles at the truth the likelihood keeps it: the search failed",
    "model": "with the target's true look the particles it had keep it: the appearance model failed",
    "search+model": "only fixing both keeps it",
    "restart": "restarted at the truth at the drift onset it holds on",
    "none helps": "no fix keeps it",
}


@dataclass(frozen=True)
class CounterfactualConfig:
    """How the replays run.

    Attributes
    ----------
    before : int
        Start this many frames before the drift began (clamped to frame 2: frame 1 is the init).
    horizon : int
        Replay this many frames after the loss (clipped to the frames the run tracked).
    search_fraction : float
        Share of the particles the search fix moves to the truth on each frame.
    kept_iou : float
        The track is kept when the IoU at the loss and the mean IoU after it are at least this.
    every, keep, long_every, long_keep : int
        The runner's checkpoints: every ``every`` frames the last ``keep``, and every ``long_every``
        frames the last ``long_keep`` (memory bound: see :class:`covviz.runner.CheckpointRing`).
    max_cache_bytes : int
        The window's frames are decoded once and kept for the five replays up to this size.
    """

    before: int = 3
    horizon: int = 20
    search_fraction: float = 0.1
    kept_iou: float = 0.5
    every: int = 5
    keep: int = 64
    long_every: int = 50
    long_keep: int = 64
    max_cache_bytes: int = 512_000_000

    def __post_init__(self):
        if self.before < 0 or self.horizon < 0 or self.every < 1 or self.keep < 1:
            raise ValueError("before, horizon must be >= 0 and every, keep >= 1")
        if not 0 < self.search_fraction <= 1 or not 0 < self.kept_iou <= 1:
            raise ValueError("search_fraction and kept_iou must be in (0, 1]")

    @property
    def checkpoints(self) -> tuple[int, int, int, int]:
        return self.every, self.keep, self.long_every, self.long_keep


@dataclass(frozen=True, eq=False)
class Outcome:
    """What one intervention's replay did.

    Attributes
    ----------
    kept : bool
    mean_iou : float
        Over the replayed frames (``start`` to ``end``).
    frames_kept : int
        Frames of ``[lost_at, end]`` with IoU ≥ ``kept_iou``.
    boxes : ndarray, shape (m, 4)
        The replayed boxes of frames ``start..end`` (0-based pixels).
    identical : bool or None
        ``none`` only: whether its boxes equal the original run's, bit for bit.
    """

    kept: bool
    mean_iou: float
    frames_kept: int
    boxes: np.ndarray
    identical: bool | None = None

    def as_dict(self) -> dict:
        d = {"kept": bool(self.kept), "mean_iou": _round(self.mean_iou), "frames_kept": int(self.frames_kept)}
        if self.identical is not None:
            d["identical"] = bool(self.identical)
        return d


@dataclass(frozen=True, eq=False)
class Replay:
    """The replays of one loss and their verdict.

    Attributes
    ----------
    lost_at, drift_began : int
        1-based frame numbers.
    start, end : int
        The frames the interventions acted on (1-based, inclusive).
    frames_after_loss : int
        How many of the ``horizon`` frames after the loss the run had tracked.
    outcomes : dict of str to Outcome
        By intervention name (``restart`` for trackers that cannot be forked).
    verdict : str
        The smallest fix that keeps the track, or ``"none helps"``.
    keeps : tuple of str
        Every fix that keeps it.
    checkpoint : int
        1-based frame of the state the replay was forked from (0: none, a restart).
    seconds : float
        Wall time of all the replays of this loss.
    """

    lost_at: int
    drift_began: int
    start: int
    end: int
    frames_after_loss: int
    outcomes: dict = field(default_factory=dict)
    verdict: str = "none helps"
    keeps: tuple = ()
    checkpoint: int = 0
    seconds: float = 0.0

    def as_dict(self) -> dict:
        """The results JSON's fields of a diagnosis (``counterfactual``, ``verdict``, ``replay``)."""
        return {
            "counterfactual": {k: o.as_dict() for k, o in self.outcomes.items()},
            "verdict": self.verdict,
            "replay": {
                "from": self.start, "to": self.end, "frames_after_loss": self.frames_after_loss,
                "checkpoint": self.checkpoint, "seconds": round(self.seconds, 3),
                "boxes": {k: np.round(o.boxes, 2).tolist() for k, o in self.outcomes.items()},
            },
        }

    def line(self) -> str:
        """One line for cards and the terminal: ``verdict search · fixes: estimate ✗ 0.12 · search ✓ 0.71 …``."""
        parts = []
        for k in (*FIXES, "restart"):
            if k in self.outcomes:
                o = self.outcomes[k]
                parts.append(f"{k} {'KEPT' if o.kept else 'lost'} {o.mean_iou:.2f}")
        head = f"verdict {self.verdict.upper()}"
        none = self.outcomes.get("none")
        check = "" if none is None or none.identical else " (the unchanged replay did NOT reproduce the run)"
        return (f"{head} · fixes (mean IoU of the replay): {' · '.join(parts)} · replayed frames "
                f"{self.start}-{self.end}, {self.frames_after_loss} after the loss{check}")


def verdict_of(outcomes: dict) -> tuple[str, tuple[str, ...]]:
    """The smallest fix that keeps the track (or ``"none helps"``), and every fix that does."""
    keeps = tuple(k for k in (*FIXES, "restart") if k in outcomes and outcomes[k].kept)
    return (keeps[0] if keeps else "none helps"), keeps


#: The per-frame label (:data:`covviz.diagnosis.drift.LABELS`) each verdict agrees with.
VERDICT_LABEL = {"search": "search", "model": "model", "search+model": "model", "estimate": "estimate"}


def with_replays(report: dict, replays: dict, tie_ratio: float = 1.2) -> dict:
    """A diagnosis report (``Diagnoser.report``) with each loss's replays and verdict added, in place.

    Each diagnosis also says whether its per-frame labels (model / search / estimate failures)
    agree with the verdict (``labels_agree``, and ``verdict_note`` in words when they do not),
    and a tie between its two strongest causes is broken by the verdict
    (:func:`covviz.diagnosis.drift.rerank`; ``tie_broken_by``).
    """
    from covviz.diagnosis.drift import rerank

    for diag in report["diagnoses"]:
        rp = replays.get(diag["lost_at"])
        if rp is None:
            continue
        diag.update(rp.as_dict())
        before = diag.get("cause")
        rerank(diag, rp.verdict, tie_ratio)
        notes = []
        if diag.get("tie_broken_by"):
            notes.append(f"{before.replace('_', ' ')} and {diag['cause'].replace('_', ' ')} held about equally; "
                         f"the verdict ({rp.verdict}) favours {diag['cause'].replace('_', ' ')}")
        labels = {k: v for k, v in (diag.get("labels") or {}).items() if v}
        top = max(labels, key=labels.get) if labels else None
        want = VERDICT_LABEL.get(rp.verdict)
        diag["labels_agree"] = bool(want is None or top is None or top == want)
        if not diag["labels_agree"]:
            notes.append(f"the per-frame labels said {top} ({labels[top]} frames), the replays say {rp.verdict}")
        if notes:
            diag["verdict_note"] = "; ".join(notes)
    return report


class TruthIntervention(Intervention):
    """The oracle fixes of a replay, from the ground truth (0-based ``truth`` rows, ``nan`` where unknown).

    Parameters
    ----------
    kind : str
        One of :data:`INTERVENTIONS`.
    truth : ndarray, shape (n, 4)
    first : int
        0-based index of the first frame it acts on (earlier frames replay unchanged).
    fraction : float
        Share of the particles the search fix moves.
    rng : numpy.random.Generator
        Its own draws (which particles move).
    """

    def __init__(self, kind: str, truth: np.ndarray, first: int, fraction: float, rng) -> None:
        if kind not in INTERVENTIONS:
            raise ValueError(f"unknown intervention {kind!r}; choose from {', '.join(INTERVENTIONS)}")
        self.kind, self.truth, self.first, self.fraction = kind, truth, int(first), float(fraction)
        self.rng = np.random.default_rng(rng)

    def _box(self, index: int) -> np.ndarray | None:
        if index < self.first or index >= len(self.truth) or not np.all(np.isfinite(self.truth[index])):
            return None
        return self.truth[index]

    def to_truth(self, index, n):
        box = self._box(index) if "search" in self.kind else None
        if box is None:
            return None
        k = max(1, round(self.fraction * n))
        idx = np.sort(self.rng.choice(n, size=min(k, n), replace=False))
        prev = self.truth[index - 1] if index > 0 else box
        velocity = (box[:2] + box[2:] / 2) - (prev[:2] + prev[2:] / 2)
        return idx, box, velocity if np.all(np.isfinite(velocity)) else np.zeros(2)

    def appearance(self, index):
        return self._box(index) if "model" in self.kind else None

    def estimate(self, index, boxes):
        box = self._box(index) if self.kind == "estimate" else None
        if box is None or not len(boxes):
            return None
        overlap = iou(boxes, np.broadcast_to(box, boxes.shape))
        centre = np.hypot(*((boxes[:, :2] + boxes[:, 2:] / 2) - (box[:2] + box[2:] / 2)).T)
        return int(np.lexsort((centre, -overlap))[0])  # the highest IoU; the nearest centre among ties


def _round(v: float) -> float | None:
    return None if not np.isfinite(v) else round(float(v), 4)


def _outcome(boxes: np.ndarray, truth: np.ndarray, first: int, lost: int, cfg: CounterfactualConfig,
             identical: bool | None = None) -> Outcome:
    """Score replayed ``boxes`` of indices ``first..`` against the truth (``lost``: 0-based loss index)."""
    m = len(boxes)
    t = truth[first : first + m]
    ok = np.all(np.isfinite(t), axis=1) & np.all(np.isfinite(boxes), axis=1)
    v = np.full(m, np.nan)
    if ok.any():
        v[ok] = iou(boxes[ok], t[ok])
    at = lost - first
    after = v[at + 1 :]
    at_loss = v[at] if 0 <= at < m else np.nan
    mean_after = np.nanmean(after) if np.isfinite(after).any() else at_loss
    kept = bool(np.isfinite(at_loss) and at_loss >= cfg.kept_iou and mean_after >= cfg.kept_iou)
    window = v[max(at, 0) :]
    frames_kept = int(np.sum(window[np.isfinite(window)] >= cfg.kept_iou))
    mean = float(np.nanmean(v)) if np.isfinite(v).any() else float("nan")
    return Outcome(kept, mean, frames_kept, boxes, identical)


class _Frames:
    """The window's frames, decoded once when they fit in ``max_bytes``, else read again each time."""

    def __init__(self, sequence, first: int, last: int, max_bytes: int) -> None:
        self.sequence, self.first = sequence, first
        self.cache: list | None = None
        img = sequence.frame(first).image
        if img.nbytes * (last - first + 1) <= max_bytes:
            self.cache = [img] + [sequence.frame(i).image for i in range(first + 1, last + 1)]

    def __getitem__(self, i: int) -> np.ndarray:
        return self.cache[i - self.first] if self.cache is not None else self.sequence.frame(i).image


def _seed_of(seed, lost_at: int, kind: str) -> list[int]:
    return [0 if seed is None else int(seed), int(lost_at), zlib.crc32(kind.encode())]


def replay_loss(tracker, ring, sequence, boxes: np.ndarray, truth: np.ndarray, lost_at: int, drift_began: int,
                seed, cfg: CounterfactualConfig | None = None, interventions=INTERVENTIONS) -> Replay | None:
    """Replay one loss under each intervention (see the module docstring); None if no checkpoint reaches it.

    Parameters
    ----------
    tracker : Tracker
        A snapshot-capable tracker, idle (its run is over); it is restored for each replay.
    ring : CheckpointRing
    sequence : Sequence
    boxes : ndarray, shape (n, 4)
        The run's boxes (0-based), ``n`` the frames it tracked.
    truth : ndarray, shape (>= n, 4)
        Ground truth, 0-based pixels, ``nan`` rows where unknown.
    lost_at, drift_began : int
        1-based frame numbers of the loss and of its drift onset.
    """
    cfg = cfg or CounterfactualConfig()
    t0 = time.perf_counter()
    n = len(boxes)
    lost = lost_at - 1
    first = max(1, drift_began - 1 - cfg.before)  # 0-based index of the first frame acted on
    ck = ring.at_or_before(first - 1)
    if ck is None:
        ck = ring.at_or_before(lost - 1)  # the oldest state newer than the onset: start there
        if ck is None:
            return None
        first = ck[0] + 1
    ci, state = ck
    last = min(lost + cfg.horizon, n - 1)
    frames = _Frames(sequence, ci + 1, last, cfg.max_cache_bytes)
    outcomes = {}
    try:
        for kind in interventions:
            tracker.restore(state)
            hook = None if kind == "none" else TruthIntervention(
                kind, truth, first, cfg.search_fraction, _seed_of(seed, lost_at, kind))
            tracker.intervention = hook
            out = np.array([np.asarray(tracker.update(frames[i]), dtype=np.float64)
                            for i in range(ci + 1, last + 1)]).reshape(-1, 4)
            same = bool(np.array_equal(out, boxes[ci + 1 : last + 1])) if kind == "none" else None
            outcomes[kind] = _outcome(out[first - ci - 1 :], truth, first, lost, cfg, same)
    finally:
        tracker.intervention = None
    verdict, keeps = verdict_of(outcomes)
    return Replay(lost_at, drift_began, first + 1, last + 1, last - lost, outcomes, verdict, keeps, ci + 1,
                  time.perf_counter() - t0)


def restart_loss(make: Callable[[], object], sequence, boxes: np.ndarray, truth: np.ndarray, lost_at: int,
                 drift_began: int, cfg: CounterfactualConfig | None = None) -> Replay | None:
    """A tracker that cannot be forked, restarted at the truth at the drift onset: would it have held from there?"""
    cfg = cfg or CounterfactualConfig()
    t0 = time.perf_counter()
    n = len(boxes)
    first = max(0, drift_began - 1)
    while first < lost_at - 1 and not np.all(np.isfinite(truth[first])):
        first += 1
    if not np.all(np.isfinite(truth[first])):
        return None
    lost, last = lost_at - 1, min(lost_at - 1 + cfg.horizon, n - 1)
    tracker = make()
    try:
        tracker.init(sequence.frame(first).image, truth[first])
        out = [truth[first].copy()] + [np.asarray(tracker.update(sequence.frame(i).image), dtype=np.float64)
                                       for i in range(first + 1, last + 1)]
    finally:
        if callable(getattr(tracker, "close", None)):
            tracker.close()
    outcomes = {"restart": _outcome(np.array(out).reshape(-1, 4), truth, first, lost, cfg)}
    verdict, keeps = verdict_of(outcomes)
    return Replay(lost_at, drift_began, first + 1, last + 1, last - lost, outcomes, verdict, keeps, 0,
                  time.perf_counter() - t0)


class Counterfactuals(Observer):
    """Observer that replays every loss the diagnosis before it found, once the run is over.

    Put it after :class:`~covviz.diagnosis.drift.Diagnoser` and before the observers that show
    its results (the recorder, the results writer): its ``on_end`` hands them
    :attr:`covviz.runner.Findings.counterfactual` (per tracker, ``{lost_at: Replay}``). It runs
    the replays after the last frame, so it never slows the tracker; an interrupted run is not
    replayed. The command that made the trackers hands them over (the replays fork them through
    their snapshots; it asks them nothing while they run) with a factory of fresh ones for
    trackers that cannot be forked. Run with ``checkpoints=config.checkpoints``.
    """

    def __init__(self, trackers, factories, config: CounterfactualConfig | None = None) -> None:
        self.trackers = list(trackers)
        self.factories = list(factories)
        self.config = config or CounterfactualConfig()
        self.losses: list[list[tuple[int, int]]] = []
        self.replays: list[dict[int, Replay]] = []
        self.skipped = ""
        self._start: RunStart | None = None

    def on_start(self, start: RunStart, found: Findings) -> None:
        self._start = start
        self.losses = [[] for _ in start.trackers]

    def on_frame(self, frame, records, found: Findings) -> None:
        for j, news in enumerate(found.news):
            for d in news.diagnoses:
                self.losses[j].append((d.lost_at, d.drift_began))

    def on_end(self, results, found: Findings) -> Findings | None:
        start = self._start
        if start is None or not results:
            return None
        if results[0].interrupted:
            self.skipped = "the run was interrupted: no replays"
            return None
        truth = np.asarray(start.sequence.groundtruth, dtype=np.float64)
        self.replays = []
        for j, res in enumerate(results):
            out: dict[int, Replay] = {}
            ring = start.checkpoints[j] if j < len(start.checkpoints) else None
            forkable = ring is not None and start.trackers[j].interventions
            for lost_at, began in self.losses[j] if j < len(self.losses) else ():
                if forkable:
                    rp = replay_loss(self.trackers[j], ring, start.sequence, res.boxes, truth, lost_at, began,
                                     res.seed, self.config)
                elif self.factories[j] is not None:
                    rp = restart_loss(self.factories[j], start.sequence, res.boxes, truth, lost_at, began,
                                      self.config)
                else:
                    rp = None  # a tracker of the user's that can neither be forked nor made again
                if rp is not None:
                    out[lost_at] = rp
            self.replays.append(out)
        return replace(found, counterfactual=tuple(self.replays))
