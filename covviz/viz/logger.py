"""The Rerun logger: an observer that turns every FrameRecord into log calls.

``RerunLogger(stream)`` is handed to :func:`covviz.runner.run_many` like any
observer. It never touches a tracker's state: it reads the
:class:`~covviz.records.FrameRecord` of each tracker and, only on the frames
where they are asked for, computes the costly diagnostics of
:mod:`covviz.viz.diagnostics` (MDS of the template cloud, likelihood map,
background descriptors) with the tracker's own observation model.

Several trackers share one recording, each under ``trackers/<name>/`` (see
:mod:`covviz.viz.paths`); the frame and the ground truth are logged once.

Sizes: frames are JPEG-compressed (quality 60) and particle corners are
rounded to ``particle_precision`` pixels (1/2 px by default: invisible at the
frame's scale, and it lets the recording's LZ4 compression work), which keeps
a 600-particle recording of a 320×240 sequence near 28 MB per 1000 frames
(``benchmarks/logging_overhead.py``).
"""

from __future__ import annotations

import json
import logging
import time
from collections import deque
from collections.abc import Sequence as Seq
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np
import rerun as rr

from covviz import __version__
from covviz.diagnosis.drift import Diagnoser, DiagnosisConfig, FrameNews
from covviz.embedding import AlignedMDS, distance_matrix, stress1
from covviz.metrics import center_error, evaluate, iou, nothing_to_score
from covviz.model.features import pose_corners
from covviz.model.observation import ObservationModel, box_to_pose
from covviz.model.particles import effective_sample_size
from covviz.model.spd import logm
from covviz.records import FrameRecord, frame_number
from covviz.runner import Findings, Observer, Pipeline, RunStart
from covviz.threads import limit_threads
from covviz.trackers.base import TrackerInfo
from covviz.viz import paths as P
from covviz.viz import story, why
from covviz.viz.blueprint import build_blueprint
from covviz.viz.checks import checked, closed_strips, jpeg_bytes
from covviz.viz.defaults import MDS_EVERY
from covviz.viz.description import DESCRIPTION, viewer_safe
from covviz.viz.diagnostics import (
    background_poses,
    likelihood_map,
    likelihood_slices,
    template_cloud,
    template_spread,
    top_k,
)
from covviz.viz.palette import (
    BACKGROUND_COLOR,
    GT_COLOR,
    INITIAL_COLOR,
    LIKELIHOOD_RANGE_NATS,
    LUT,
    SERIES_COLORS,
    TEMPLATE_COLOR,
    TOP_COLOR,
    likelihood_rgba,
    tracker_color,
    weight_levels,
    weight_lut,
)
from covviz.viz.series import RECORDER_EVERY, RECORDER_SECONDS, SeriesBuffer
from covviz.viz.sinks import FLUSH_TIMEOUT, close_stream

__all__ = ["LoggerConfig", "RerunLogger"]

log = logging.getLogger("covviz.viz")

#: The frame is drawn first (lowest draw order); overlays must come after it, or the depth test
#: hides the frame behind their transparent pixels.
FRAME_DRAW_ORDER = -20.0
#: Draw order of the top particles' regions.
TOP_DRAW_ORDER = 30.0
#: What held the observation pull (``FrameRecord.pull.held``, one gate or ``look+light``) -> its marker on the
#: weights plot. ``evidence`` has none: it is the loss evidence itself, on the same plot.
PULL_HELD_MARKERS = {"light": "Diamond", "look": "Square"}
#: Radius of the centre of the heaviest particle, pixels (radius ∝ sqrt(w / w_max)).
CENTRE_RADIUS = 3.0
#: Line radius of the particles' regions, and radius of the dots of the light ones (image pixels).
PARTICLE_RADIUS = 0.2
DOT_RADIUS = 0.6
#: Centres smaller than this radius (pixels; w / w_max < 6 %) are sub-pixel dots and not logged.
MIN_CENTRE_RADIUS = 0.75


@dataclass(frozen=True)
class LoggerConfig:
    """What the logger records, and how often the costly diagnostics run.

    Attributes
    ----------
    mds_every : int
        Compute the MDS picture of the template cloud every this many frames
        (0: never).
    likelihood_every : int, optional
        The likelihood map every this many frames (default: ``mds_every``; 0: never).
    series_every : int
        The per-frame scalars (ESS, distances, terms, IoU, timings) are sent as columns once this
        many frames are held (:class:`~covviz.viz.series.SeriesBuffer`; 1: every frame) ...
    series_seconds : float or None
        ... or once the oldest of them is this many seconds old (None: by frames only). Every
        column chunk costs ~1.3 KB of the file whatever it holds: sent every 10 frames, the series
        were a quarter of a Car4 recording.
    spread_every : int
        The template-cloud spread (mean distance to the log-Euclidean mean) every this many frames.
    views_in_columns : bool
        The views drawn anew on every frame (the particles' regions, dots and centres, the heatmaps,
        the zoom patches) go out with the series, as columns (:class:`~covviz.viz.series.SeriesBuffer`):
        about 1.5 ms of the recorder's CPU a frame less on Car4. False: each as its own log call, as
        ``covviz track`` does for a live viewer, whose Frame view would otherwise draw the particles a
        batch (up to a second) behind the image.
    spread_templates : int
        The spread is estimated on an evenly strided subset of this many
        templates (the mean distance of a subset estimates the cloud's).
    top_k : int
        Particles drawn bold, and "top" templates in the cloud (the paper's 10).
    mds_max_templates : int
        Generated templates in the MDS picture (the top-k plus a random sample).
    mds_method : {"classical", "smacof"}
    n_background : int
        Background regions sampled around the target for the MDS picture.
    likelihood_grid : int
        Positions per axis of the likelihood map.
    likelihood_reach : float
        Half-width of the likelihood map, in region sizes.
    jpeg_quality : int
        JPEG quality of the frames (1-100).
    particle_precision : float
        Particle corners and centres are rounded to this many pixels.
    box_weight : float
        Particles with at least this share of the largest weight are drawn as their regions
        (``video/particles``), the others as dots at their centres (``video/particle_dots``);
        0: every particle as its region.
    seed : int
        Seed of the logger's own randomness (the sample of templates in the MDS).
    diagnosis : DiagnosisConfig
        Thresholds of the event detector and of the drift diagnosis.
    dense_before : int
        Frames kept in memory so that, when a loss is diagnosed, the likelihood
        map, the slices and the template cloud are computed back to the drift
        onset (up to this many frames back) ...
    dense_after : int
        ... and for this many frames after the loss and every suspect.
    """

    mds_every: int = MDS_EVERY
    likelihood_every: int | None = None
    spread_every: int = 3
    views_in_columns: bool = True
    series_every: int = RECORDER_EVERY
    series_seconds: float | None = RECORDER_SECONDS
    spread_templates: int = 32
    top_k: int = 10
    mds_max_templates: int = 32
    mds_method: str = "classical"
    n_background: int = 16
    likelihood_grid: int = 17
    likelihood_reach: float = 1.0
    jpeg_quality: int = 60
    particle_precision: float = 0.5
    box_weight: float = 0.1
    seed: int = 0
    diagnosis: DiagnosisConfig = field(default_factory=DiagnosisConfig)
    dense_before: int = 16
    dense_after: int = 3

    def __post_init__(self):
        for name in ("mds_every", "spread_every", "spread_templates", "top_k", "n_background", "series_every"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.series_seconds is not None and not self.series_seconds >= 0:
            raise ValueError(f"series_seconds must be >= 0 or None, got {self.series_seconds}")
        if self.likelihood_every is not None and self.likelihood_every < 0:
            raise ValueError(f"likelihood_every must be >= 0, got {self.likelihood_every}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be in 1..100, got {self.jpeg_quality}")
        if self.mds_max_templates < self.top_k:
            raise ValueError("mds_max_templates must be at least top_k")
        if self.likelihood_grid < 2:
            raise ValueError("likelihood_grid must be at least 2")
        if not self.particle_precision > 0:
            raise ValueError("particle_precision must be positive")
        if self.mds_method not in ("classical", "smacof"):
            raise ValueError(f"mds_method must be 'classical' or 'smacof', got {self.mds_method!r}")

    @property
    def likelihood_period(self) -> int:
        return self.mds_every if self.likelihood_every is None else self.likelihood_every


#: Colours of the counterfactual replays' boxes (faint: they sit over the frame).
REPLAY_COLORS = {
    "none": (220, 220, 220, 90),
    "estimate": (255, 170, 60, 130),
    "search": (80, 200, 255, 130),
    "model": (220, 90, 255, 130),
    "search+model": (120, 255, 140, 130),
    "restart": (80, 200, 255, 130),
}


# --------------------------------------------------------------------------- #
# per-tracker state
# --------------------------------------------------------------------------- #
class _TrackerState:
    def __init__(self, name: str, info: TrackerInfo, color, cfg: LoggerConfig, index: int):
        self.name = name
        self.paths = P.TrackerPaths(name)
        self.info = info
        self.color = color
        self.model: ObservationModel | None = info.model  # the tracker's frozen observation model
        self.mds = AlignedMDS(cfg.mds_method)
        # SMACOF for the cloud alone: classical MDS would flatten it (see covviz.embedding.embed).
        self.mds_zoom = AlignedMDS("smacof", max_iter=20)
        self.index = index
        self.initial_template: np.ndarray | None = None
        self.initial_patch: np.ndarray | None = None
        self.dense_until = -1  # frame index up to which the costly views run on every frame
        self.losses: list[int] = []
        self.drifts: list[int] = []
        self.n_storms = 0
        self.diagnoses: list = []
        self.drawn: deque = deque(maxlen=64)  # recent frames whose costly views are logged
        self.healthy_gap: deque = deque(maxlen=30)  # the target's gap to the cloud on frames on track
        self.last_iou: float | None = None
        self.rng = np.random.default_rng([cfg.seed, index])
        self.had_particles = False
        self.lut = LUT
        self.series_colors = dict(SERIES_COLORS)
        self.clear_next: list[str] = []
        self.stages_seen: set[str] = set()
        self.terms_seen: set[str] = set()
        self.warned: set[str] = set()
        self.prefix = ""  # before series names: the tracker's name when the recording has several
        self.lost = False  # between a loss and its recovery (the story strip's "lost")
        self.story_state: str | None = None


def term_contributions(record: FrameRecord, n: int, problems: list | None = None) -> dict[str, np.ndarray]:
    """``weight_k · term_k`` per particle, ``(n,)`` each, of the extra terms of a record's likelihood.

    ``d_eff² = d² + Σ_k`` of these (:meth:`covviz.records.Likelihood.contributions`);
    ``{}`` for a record without them (the paper's likelihood, another tracker).
    """
    if record.likelihood is None:
        return {}
    out = {}
    for k, c in record.likelihood.contributions().items():
        c = checked(c, (n,), f"terms[{k}]", problems if problems is not None else [])
        if c is not None:
            out[k] = c
    return out


def term_shares(
    w: np.ndarray, dist: np.ndarray, contrib: dict[str, np.ndarray], sigma: float | None
) -> tuple[dict[str, float], dict[str, float]]:
    """How much each part of ``d_eff² = d² + Σ_k c_k`` counted in one frame's weights.

    Returns ``share`` and ``moved``, by name (``descriptor`` for ``d²``, then
    each term): ``share_k = Σ_i w_i c_ik / Σ_i w_i d_eff,i²``, its part of what
    the weighted particles were weighed by (the shares sum to 1); and, given
    the likelihood's ``sigma``, ``moved_k = ½ Σ_i |w_i − w_i^(−k)|``, the total
    variation between the weights and those without that part (0: the weights
    would be the same without it; near 1: it alone decided who carries the
    weight). A large share that moves little is a constant offset; a term
    that moves the weight away from the truth is the one a failure came from.
    """
    w = np.asarray(w, dtype=np.float64)
    parts = {"descriptor": np.asarray(dist, dtype=np.float64) ** 2, **contrib}
    sums = {k: float(np.dot(w, v)) for k, v in parts.items()}
    total = sum(sums.values())
    share = {k: (v / total if total > 0 else float("nan")) for k, v in sums.items()}
    moved = {}
    if sigma is not None and sigma > 0:
        d2 = sum(parts.values())
        for k, v in parts.items():
            lw = -(d2 - v) / (2.0 * sigma * sigma)
            wk = np.exp(lw - lw.max())
            wk /= wk.sum()
            moved[k] = 0.5 * float(np.abs(w / w.sum() - wk).sum())
    return share, moved


# --------------------------------------------------------------------------- #
# the observer
# --------------------------------------------------------------------------- #
class RerunLogger(Observer):
    """Observer that logs a run into a Rerun recording.

    Parameters
    ----------
    stream : rerun.RecordingStream
        Where to log (its sinks already attached, see :func:`attach_sinks`).
    config : LoggerConfig, optional
    run_info : dict, optional
        Written into the recording's config document (seed, command line ...).
    close_on_end : bool
        Flush and disconnect the stream in ``on_end`` (also after an
        interruption), which finalises an ``.rrd`` file.
    diagnoser : covviz.diagnosis.drift.Diagnoser, optional
        The drift diagnosis the logger drives (frame by frame, on its own
        thread) and draws; pass one to read its results after the run (as
        ``covviz track`` does for the results JSON and its summary). Default:
        one of its own, with ``config.diagnosis``.

    Examples
    --------
    >>> from covviz.runner import run
    >>> stream = new_recording()
    >>> attach_sinks(stream, save="recordings/synthetic.rrd")     # doctest: +SKIP
    >>> run(tracker, sequence, [RerunLogger(stream)])              # doctest: +SKIP
    """

    def __init__(
        self,
        stream: rr.RecordingStream,
        config: LoggerConfig | None = None,
        run_info: dict | None = None,
        close_on_end: bool = True,
    ):
        self.stream = stream
        self.config = config or LoggerConfig()
        self._recent: deque = deque(maxlen=max(1, self.config.dense_before))
        self.run_info = dict(run_info or {})
        self.close_on_end = close_on_end
        self._states: list[_TrackerState] = []
        self._last_frame = -1
        self._fps = None
        self._blueprint_args = None
        self.log_seconds = 0.0  # time spent in on_frame, for the overhead benchmark
        #: The per-frame scalars, sent as columns (covviz.viz.series) every ``series_seconds``.
        self.series = SeriesBuffer(stream, self.config.series_every, self.config.series_seconds)
        self._styled: set[str] = set()  # entities whose static style is logged (_style_once)

    # ------------------------------------------------------------------ #
    def on_start(self, start: RunStart, found: Findings) -> None:
        rec, cfg = self.stream, self.config
        sequence = start.sequence
        names: list[str] = []
        for i, info in enumerate(start.trackers):
            # Entity-path friendly, and drawable by the viewer's font.
            base = P.tracker_entity(info.name) or f"tracker{i}"
            name, k = base, 2
            while name in names:
                name, k = f"{base}-{k}", k + 1
            names.append(name)
        self._states = []
        for i, (name, info) in enumerate(zip(names, start.trackers)):
            color = tracker_color(info.name, i)
            self._states.append(_TrackerState(name, info, color, cfg, i))
        self._fps = sequence.frame_rate or None
        with_cloud = [s.name for s in self._states if s.info.model is not None]
        with_particles = [s.name for s in self._states if s.info.particles]
        # Several particle trackers: the second and later get their own colour ramp and series colours.
        # Several trackers: each one's curves in shades of its own colour (a colour of its own everywhere);
        # the second and later particle trackers get their own colour ramp.
        for k, s in enumerate(st for st in self._states if st.name in with_particles):
            if k > 0:
                s.lut = weight_lut(hi=s.color)
        if len(self._states) > 1:
            for s in self._states:
                s.prefix = f"{s.name} "
                s.series_colors = {
                    key: tuple(int(0.3 * a + 0.7 * b) for a, b in zip(col[:3], s.color))
                    for key, col in SERIES_COLORS.items()
                }
        # The blueprint goes out with the first frame, when the image size is known.
        self._blueprint_args = (names, with_cloud, with_particles)
        colours = [int.from_bytes(bytes([*s.color[:3], 255]), "big") for s in self._states]
        rec.log(P.LAYOUT, rr.AnyValues(trackers=names, with_cloud=with_cloud or [""], with_particles=with_particles
                                       or [""], colors=colours), static=True)
        rec.send_recording_name(
            viewer_safe(self.run_info.get("name", f"{sequence.name} · {', '.join(names)}"))
        )

        rec.log(P.DESCRIPTION, rr.TextDocument(DESCRIPTION, media_type=rr.MediaType.MARKDOWN), static=True)
        config_doc = {
            "covviz": __version__,
            "rerun": rr.__version__,
            "recording_id": rec.get_recording_id(),
            "sequence": {
                "name": sequence.name,
                "frames": len(sequence),
                "frame_rate": sequence.frame_rate,
            },
            "run": self.run_info,
            "trackers": {s.name: s.info.config for s in self._states},
            "logger": asdict(cfg),
        }
        text = (
            "# Configuration of this run\n\n```json\n"
            + json.dumps(config_doc, indent=2, default=str)
            + "\n```\n"
        )
        rec.log(P.CONFIG, rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)
        rec.log(
            P.SUMMARY,
            rr.TextDocument("The summary is written when the run ends.", media_type=rr.MediaType.MARKDOWN),
            static=True,
        )

        # Static styles of the time series and overlays.
        rec.log(
            P.GROUND_TRUTH,
            rr.Boxes2D.from_fields(colors=[GT_COLOR], radii=[0.9], show_labels=False, draw_order=40.0),
            static=True,
        )
        for s in self._states:
            p, c = s.paths, s.color
            lines = {p.iou: (c, f"{s.prefix}IoU"), p.center_error: (c, f"{s.prefix}centre error")}
            if s.name in with_particles:
                lines.update(
                    {
                        p.ess: (s.series_colors["ess"], f"{s.prefix}ESS/N"),
                        p.max_weight: (s.series_colors["max"], f"{s.prefix}max weight"),
                        p.survivors: (s.series_colors["survivors"], f"{s.prefix}survivors/N"),
                        p.distance_min: (s.series_colors["min"], f"{s.prefix}min d"),
                        p.distance_mean: (s.series_colors["mean"], f"{s.prefix}mean d"),
                        p.spread: (s.series_colors["spread"], f"{s.prefix}spread"),
                        p.loss_evidence: (s.series_colors["evidence"], f"{s.prefix}loss evidence"),
                        p.redetected: (s.series_colors["redetected"], f"{s.prefix}re-detected/N"),
                    }
                )
                rec.log(
                    p.resampled,
                    rr.SeriesPoints(
                        colors=[s.series_colors["resampled"]],
                        names=[f"{s.prefix}resampled"],
                        markers=["Circle"],
                        marker_sizes=[1.5],
                    ),
                    static=True,
                )
            for path, (col, label) in lines.items():
                rec.log(path, rr.SeriesLines(colors=[col], names=[label], widths=[1.5]), static=True)
            if s.name in with_particles:
                # The observation pull's held frames, a strip of markers below 0 (evidence holds show as the
                # loss evidence itself): when the templates stopped learning the look, and which gate said so.
                for reason, marker in PULL_HELD_MARKERS.items():
                    rec.log(p.pull_held(reason),
                            rr.SeriesPoints(colors=[s.series_colors[f"pull_{reason}"]],
                                            names=[f"{s.prefix}pull held ({reason})"], markers=[marker],
                                            marker_sizes=[2.5]), static=True)
            # Event markers in the tracker's colour, one shape per kind: several trackers on one plot
            # stay apart.
            for kind, marker in (("drift", "Cross"), ("lost", "Down"), ("recovered", "Up")):
                rec.log(
                    p.marker(kind),
                    rr.SeriesPoints(colors=[c], names=[f"{s.prefix}{kind}"], markers=[marker], marker_sizes=[6.0]),
                    static=True,
                )
            why.log_static(rec, p, s.prefix, c, s.name in with_cloud)
            story.log_story_static(rec, p)
            rec.log(
                p.box,
                rr.Boxes2D.from_fields(
                    colors=[c],
                    radii=[0.9],
                    labels=[s.name],
                    show_labels=False,  # the name goes by a corner of its own (p.label), apart from the others'
                    draw_order=45.0,
                ),
                static=True,
            )
            rec.log(
                p.region, rr.LineStrips2D.from_fields(colors=[c], radii=[0.4], draw_order=44.0), static=True
            )
        rec.log(
            P.LOGGER_TIME,
            rr.SeriesLines(colors=[(180, 180, 180)], names=["logger"], widths=[1.0]),
            static=True,
        )

    # ------------------------------------------------------------------ #
    def on_frame(self, frame, records: Seq[FrameRecord], found: Findings) -> None:
        t0 = time.perf_counter()
        # The diagnostics do linear algebra on small matrices (9×9 stacks, a ~80×80 eigh), where
        # BLAS threads only add wake-up latency (10-100× on a loaded 2-core machine).
        with limit_threads(1, opencv=False):
            self._on_frame(frame, records, found.news or (None,) * len(records))
        dt = time.perf_counter() - t0
        self.log_seconds += dt
        self.series.add(P.LOGGER_TIME, dt * 1e3)
        self.series.tick()

    def _on_frame(self, frame, records: Seq[FrameRecord], news: Seq) -> None:
        rec, cfg = self.stream, self.config
        i = int(frame.index)
        self._last_frame = i
        if self._blueprint_args is not None:
            h, w = np.shape(frame.image)[:2]
            if rec.is_enabled():  # a disabled stream has no application to attach a blueprint to
                rec.send_blueprint(build_blueprint(*self._blueprint_args, image_size=(w, h)))
            rec.log(P.LAYOUT, rr.AnyValues(image_size=[int(w), int(h)]), static=True)
            self._blueprint_args = None
        self._set_time(frame)
        self._put_jpeg(P.IMAGE, jpeg_bytes(frame.image, cfg.jpeg_quality), {"draw_order": FRAME_DRAW_ORDER})
        problems: list[str] = []
        gt = checked(frame.gt, (4,), "ground truth", problems)
        if gt is not None:
            self._put_boxes(P.GROUND_TRUTH, gt[None])
        else:
            rec.log(P.GROUND_TRUTH, rr.Clear(recursive=False))
        self._recent.append((frame, list(records)))
        prepared_cache: dict[int, object] = {}
        for s, record, found in zip(self._states, records, news):
            self._log_tracker(s, frame, record, gt, prepared_cache, found)

    def _set_time(self, frame) -> None:
        """Put the stream at ``frame`` on both timelines (``frame``: 1-based numbers; ``time``: seconds)."""
        P.set_frame_time(self.stream, frame)
        self.series.at(frame_number(frame.index), frame.time)

    def _warn(self, s: _TrackerState, problems: list[str]) -> None:
        for msg in problems:
            if msg not in s.warned:
                s.warned.add(msg)
                log.warning("%s: %s; not logged (further occurrences silent)", s.name, msg)
                self.stream.log(s.paths.events, rr.TextLog(viewer_safe(f"not logged: {msg}"), level="WARN"))

    def _log_tracker(self, s: _TrackerState, frame, record: FrameRecord, gt, prepared_cache,
                     found: FrameNews | None) -> None:
        """Everything one tracker's record says about one frame, view by view; ``found``: the diagnosis's news."""
        i = int(frame.index)
        problems: list[str] = []
        self._clear_views(s)
        box = self._log_estimate(s, record, problems)
        self._log_particles(s, record, problems)
        s.last_iou = self._log_quality(s, box, gt)
        self._log_spread(s, record, i, problems)
        est_t = self._log_heatmap(s, record, i, problems)
        self._log_timings(s, record)
        if found is not None:
            why.log_evidence(self.series, s.paths, found.evidence, s.model is not None)
        self._log_zoom(s, frame, record, gt, prepared_cache)
        dense = i <= s.dense_until
        self._log_diagnostics(s, frame, record, box, gt, est_t, prepared_cache, problems, dense)
        if found is not None:
            self._log_events(s, frame, found)
            self._log_story(s, found)
        if i <= s.dense_until and i not in s.drawn:  # an event on this very frame: its views too
            self._log_diagnostics(s, frame, record, box, gt, est_t, prepared_cache, problems, dense=True)
        if problems:
            self._warn(s, problems)

    def _log_estimate(self, s: _TrackerState, record: FrameRecord, problems: list) -> np.ndarray | None:
        """The estimated box and its (rotated) region; returns the box."""
        rec, p = self.stream, s.paths
        box = checked(record.box, (4,), "box", problems)
        if box is not None:
            self._put_boxes(p.box, box[None])
            if len(self._states) > 1:
                # Each tracker's name by its own corner of its box (top-left, bottom-left, top-right,
                # bottom-right, ...): two trackers on the same target do not print on top of each other.
                k = s.index % 4
                corner = (box[0] + box[2] * (k // 2), box[1] + box[3] * (k % 2))
                rec.log(p.label, rr.Points2D([corner], radii=[0.0], labels=[s.name], colors=[s.color],
                                             show_labels=True, draw_order=46.0))
        corners = checked(record.corners, (4, 2), "corners", problems)
        if corners is not None:
            self._put_strips(p.region, closed_strips(corners[None]).astype(np.float32), {})  # styled in on_start
        return box

    def _log_particles(self, s: _TrackerState, record: FrameRecord, problems: list) -> None:
        """Particles coloured by weight, the top ones with their distances, and the weight series."""
        rec, cfg, p = self.stream, self.config, s.paths
        pc = checked(record.particle_corners, (-1, 4, 2), "particle_corners", problems)
        lw = checked(record.log_weights, (-1,), "log_weights", problems)
        n = record.n_particles
        w = None
        if lw is not None:
            w = np.exp(lw)
            if pc is not None and len(pc) != len(w):
                problems.append(f"particle_corners has {len(pc)} particles, log_weights {len(w)}")
                pc = None
        if pc is not None and w is not None and len(w):
            s.had_particles = True
            q = cfg.particle_precision
            wn = w / w.max()
            level = weight_levels(w)
            order = np.argsort(level, kind="stable")  # heavy particles drawn last (on top)
            # Regions for the particles that carry weight; the centres of the others (most of the
            # recording's bytes were 600 rectangles a frame whose weight is invisible at the frame's scale).
            heavy = wn[order] >= cfg.box_weight
            boxed, dotted = order[heavy], order[~heavy]
            strips = (np.round(closed_strips(pc[boxed]) / q) * q).astype(np.float32)
            dots = np.round(pc[dotted].mean(axis=1) / q) * q
            self._put_strips(p.particles, strips, {"radii": [PARTICLE_RADIUS], "draw_order": 20.0},
                             colors=s.lut[level[boxed]])
            self._put_points(p.particle_dots, dots, {"radii": [DOT_RADIUS], "draw_order": 19.0},
                             colors=s.lut[level[dotted]])
            top = top_k(w, cfg.top_k)
            top_any = {"weight": w[top].astype(np.float64), "particle": top.astype(np.int64)}
            dist = checked(record.distances, (len(w),), "distances", problems)
            if dist is not None:
                top_any["distance"] = dist[top]
            # Trackers whose weights use more than d(C, C*) (the manifold tracker's quadrant
            # term) say so in extras: hovering a top particle shows what it was weighed by.
            lik = record.likelihood
            d_lik = None if lik is None else checked(lik.distances, (len(w),), "likelihood_distances", problems)
            if d_lik is not None and d_lik is not dist:
                top_any["likelihood_distance"] = d_lik[top]
            d_quad = None if lik is None or lik.quadrant_distances is None else checked(
                lik.quadrant_distances, (len(w), -1), "quadrant_distances", problems)
            if d_quad is not None:
                for j in range(d_quad.shape[1]):
                    top_any[f"quadrant_distance_{j}"] = d_quad[top, j]
            # Each extra term of d_eff², weighted (d_eff² = d² + Σ term_k): which one a particle lost by.
            contrib = term_contributions(record, len(w), problems)
            for k, c in contrib.items():
                top_any[f"term_{k}"] = c[top]
            self._put_strips(p.top, closed_strips(pc[top]).astype(np.float32),
                             {"colors": [TOP_COLOR], "radii": [0.6], "draw_order": TOP_DRAW_ORDER}, values=top_any)
            radii = np.round(CENTRE_RADIUS * np.sqrt(wn[order]) * 4) / 4
            vis = radii >= MIN_CENTRE_RADIUS
            centres = np.round(pc[order[vis]].mean(axis=1) / q) * q
            self._put_points(p.centres, centres, {"draw_order": 25.0}, colors=s.lut[level[order[vis]]],
                             radii=radii[vis].astype(np.float32))
            ess = float(record.ess) if np.isfinite(record.ess) else effective_sample_size(lw)
            self.series.add(p.ess, ess / n)
            self.series.add(p.max_weight, float(w.max()))
            if record.diffusion is not None:
                self.series.add(p.loss_evidence, float(record.diffusion.evidence))
                self.series.add(p.redetected, record.diffusion.redetected / n)
            if record.pull is not None:
                for reason in PULL_HELD_MARKERS:
                    if reason in record.pull.held.split("+"):
                        self.series.add(p.pull_held(reason), P.PULL_HELD_LEVEL)
            if record.resampled:
                self.series.add(p.resampled, ess / n)
                idx = record.resample_indices
                if idx is not None and len(idx):
                    self.series.add(p.survivors, len(np.unique(idx)) / len(idx))
            else:
                self.series.add(p.survivors, 1.0)
            if dist is not None:
                self.series.add(p.distance_min, float(dist.min()))
                self.series.add(p.distance_mean, float(np.dot(w, dist)))
                if contrib:
                    self._log_terms(s, w, dist, contrib)
        elif s.had_particles:
            for path in (p.particles, p.particle_dots, p.top, p.centres):
                rec.log(path, rr.Clear(recursive=False))  # at this frame, after any columns of earlier ones

    def _log_terms(self, s: _TrackerState, w: np.ndarray, dist: np.ndarray, contrib: dict) -> None:
        """Each likelihood term's share of ``d_eff²`` and the weight it moved (see :func:`term_shares`)."""
        rec, p = self.stream, s.paths
        sigma = s.model.likelihood_sigma if s.model is not None else None
        share, moved = term_shares(w, dist, contrib, sigma)
        for k in share:
            if k not in s.terms_seen:
                s.terms_seen.add(k)
                rec.log(p.term_share(k), rr.SeriesLines(names=[f"{s.prefix}share of d_eff² · {k}"], widths=[2.0]),
                        static=True)
                rec.log(p.term_moved(k), rr.SeriesLines(names=[f"{s.prefix}weight moved by {k}"], widths=[0.8]),
                        static=True)
            self.series.add(p.term_share(k), share[k])
            if k in moved:
                self.series.add(p.term_moved(k), moved[k])

    def _log_quality(self, s: _TrackerState, box, gt) -> float | None:
        """IoU and centre error against the ground truth; returns the IoU (None without ground truth)."""
        p = s.paths
        o = None
        if gt is not None and box is not None:
            o = float(iou(box[None], gt[None])[0])
            self.series.add(p.iou, o)
            self.series.add(p.center_error, float(center_error(box[None], gt[None])[0]))
        return o

    def _log_spread(self, s: _TrackerState, record: FrameRecord, i: int, problems: list) -> None:
        """The template cloud's spread (mean distance to its log-Euclidean mean)."""
        cfg, p = self.config, s.paths
        if not cfg.spread_every or i % cfg.spread_every:
            return
        templates = checked(record.templates, (-1, -1, -1), "templates", problems)
        if templates is not None and len(templates):
            try:
                spread, _ = template_spread(templates, max_templates=cfg.spread_templates)
                self.series.add(p.spread, spread)
            except (ValueError, np.linalg.LinAlgError) as exc:
                problems.append(f"template spread failed ({exc})")

    def _log_heatmap(self, s: _TrackerState, record: FrameRecord, i: int, problems: list) -> np.ndarray | None:
        """The estimate's template, its observation and their difference as labelled heatmaps; returns the template.

        In log space (where the template lives and the random walk steps: entries of order 1,
        readable on one fixed colour scale, and difference = observed - template exactly).
        """
        est_t = checked(record.estimate_template, (-1, -1), "estimate_template", problems)
        est_d = checked(record.estimate_descriptor, (-1, -1), "estimate_descriptor", problems)
        if i == 0 and est_t is not None:
            s.initial_template = est_t.copy()
        if est_t is not None and est_d is not None and est_t.shape == est_d.shape == (9, 9):
            try:
                obs_log = logm(est_d)
            except ValueError as exc:
                problems.append(f"observed descriptor is not SPD ({exc})")
            else:
                self._put_image(f"{s.paths.heatmap}/image", why.heatmap_image(est_t, obs_log), "RGB")
        return est_t

    def _log_zoom(self, s: _TrackerState, frame, record: FrameRecord, gt, prepared_cache) -> None:
        """The warped patches at the estimate, the truth and the initial box, as the tracker samples them."""
        model = s.model
        if model is None or record.pose is None:
            return
        prepared = self._prepared(s, frame, record, prepared_cache)
        poses = [np.asarray(record.pose, dtype=np.float64)]
        if gt is not None:
            poses.append(box_to_pose(gt, model.base_wh))
        patches = list(model.patches(prepared, np.stack(poses)))
        if int(frame.index) == 0:
            s.initial_patch = patches[0]
        truth = patches[1] if gt is not None else None
        self._put_image(f"{s.paths.zoom}/patches", why.zoom_image([patches[0], truth, s.initial_patch]), "L")

    # Per-frame views: with the series' columns (``views_in_columns``), their style -- what is the same on
    # every frame -- logged once per entity as static; or each frame's view in one log call, style and all.
    def _style_once(self, path: str, archetype, style: dict) -> None:
        if style and path not in self._styled:
            self._styled.add(path)
            self.stream.log(path, archetype.from_fields(**style), static=True)

    def _put_points(self, path: str, positions: np.ndarray, style: dict, labels=None, colors=None,
                    radii=None) -> None:
        """One frame's points; ``labels``, ``colors`` and ``radii``, where given, per point (or one for all)."""
        if not self.config.views_in_columns:
            per = {k: v for k, v in (("labels", labels), ("colors", colors), ("radii", radii)) if v is not None}
            self.stream.log(path, rr.Points2D(positions, **style, **per))
            return
        self._style_once(path, rr.Points2D, style)
        self.series.add_points(path, positions, colors, radii, labels=None if labels is None else
                               np.broadcast_to(np.asarray(labels, dtype=object), (len(positions),)))

    def _put_strips(self, path: str, strips: np.ndarray, style: dict, colors=None, values=None) -> None:
        """One frame's line strips, with per-strip ``colors`` and ``values`` (``rr.AnyValues``) where given."""
        if not self.config.views_in_columns:
            extra = [] if values is None else [rr.AnyValues(**values)]
            self.stream.log(path, rr.LineStrips2D(strips, **style, **({} if colors is None else {"colors": colors})),
                            *extra)
            return
        self._style_once(path, rr.LineStrips2D, style)
        self.series.add_strips(path, strips, colors, values)

    def _put_jpeg(self, path: str, jpeg: bytes, style: dict) -> None:
        """One frame's JPEG image."""
        if not self.config.views_in_columns:
            self.stream.log(path, rr.EncodedImage(contents=jpeg, media_type="image/jpeg", **style))
            return
        self._style_once(path, rr.EncodedImage, style)
        self.series.add_encoded_image(path, jpeg, "image/jpeg")

    def _put_boxes(self, path: str, boxes: np.ndarray) -> None:
        """A per-frame ``(n, 4)`` batch of ``x, y, w, h`` boxes: with the series' columns, or its own log call
        (``views_in_columns``); its style is static."""
        if self.config.views_in_columns:
            self.series.add_boxes(path, boxes[:, :2], boxes[:, 2:])
        else:
            self.stream.log(path, rr.Boxes2D(mins=boxes[:, :2], sizes=boxes[:, 2:]))

    def _put_image(self, path: str, image: np.ndarray, color_model: str) -> None:
        """A per-frame image: with the series' columns, or its own log call (``views_in_columns``); its
        draw order and filter, where it has them, are static (:func:`covviz.viz.why.log_static`)."""
        if self.config.views_in_columns:
            self.series.add_image(path, image, color_model)
        else:
            self.stream.log(path, rr.Image(image, color_model=color_model))

    def _prepared(self, s: _TrackerState, frame, record: FrameRecord, prepared_cache):
        """The frame as the tracker's model samples it: the record's own (what update() read), else prepared once."""
        if record.inputs is not None:
            return record.inputs.gray
        key = id(s.model)
        if key not in prepared_cache:
            prepared_cache[key] = s.model.prepare(frame.image)
        return prepared_cache[key]

    def _log_timings(self, s: _TrackerState, record: FrameRecord) -> None:
        """Per-stage times of the update, milliseconds."""
        rec, p = self.stream, s.paths
        for stage, sec in record.timings.items():
            if not np.isfinite(sec):
                continue
            path = p.timing(stage)
            if stage not in s.stages_seen:
                s.stages_seen.add(stage)
                rec.log(
                    path,
                    rr.SeriesLines(names=[f"{s.prefix}{stage}"], widths=[1.0 if stage != "total" else 2.0]),
                    static=True,
                )
            self.series.add(path, float(sec) * 1e3)

    def _log_diagnostics(
        self, s: _TrackerState, frame, record, box, gt, est_t, prepared_cache, problems, dense: bool = False
    ) -> None:
        """The costly views (likelihood map and slices, template cloud), through the model.

        Every k-th frame, and on every frame around each diagnosed loss (``dense``).
        """
        cfg = self.config
        i = int(frame.index)
        want_mds = est_t is not None and (dense or (cfg.mds_every and i % cfg.mds_every == 0))
        want_lik = est_t is not None and (dense or (cfg.likelihood_period and i % cfg.likelihood_period == 0))
        model = s.model
        if not (want_mds or want_lik) or model is None:
            return
        s.drawn.append(i)
        prepared = self._prepared(s, frame, record, prepared_cache)
        pose = checked(record.pose, (4,), "pose", problems)
        if pose is None and box is not None:
            pose = box_to_pose(box, model.base_wh)
        if pose is None:
            return
        try:
            if want_lik:
                # Every term update() weighed this frame by (the colour map, the quadrant state).
                inputs = record.inputs.likelihood_kwargs() if record.inputs is not None else {}
                self._log_likelihood(s, model, prepared, pose, est_t, inputs)
                truth = None if gt is None else box_to_pose(gt, model.base_wh)
                self._log_slices(s, model, prepared, pose, truth, est_t, inputs)
            if want_mds:
                self._log_cloud(s, model, prepared, frame, record, pose, gt)
        except (ValueError, np.linalg.LinAlgError) as exc:
            problems.append(f"diagnostics failed on frame {frame_number(i)} ({exc})")

    def _log_slices(self, s: _TrackerState, model, prepared, pose, truth_pose, est_t, inputs) -> None:
        at_est = likelihood_slices(model, prepared, pose, est_t, **inputs)
        at_truth = None
        if truth_pose is not None:
            # At the truth's centre, at its scale and the estimate's rotation: what the likelihood says there.
            tp = np.array([truth_pose[0], truth_pose[1], truth_pose[2], pose[3]])
            at_truth = likelihood_slices(model, prepared, tp, est_t, **inputs)
        why.log_slices(self.stream, s.paths, at_est, at_truth, s.color, GT_COLOR)
        s.clear_next.append(f"{s.paths.slices}/estimate")
        s.clear_next.append(f"{s.paths.slices}/truth")

    def _clear_views(self, s: _TrackerState) -> None:
        """Clear the last costly views (``s.clear_next``) at the current time; where that empties the
        slices view, it says when it is drawn instead (a blank panel explains nothing)."""
        for path in s.clear_next:
            self.stream.log(path, rr.Clear(recursive=False))
        if f"{s.paths.slices}/estimate" in s.clear_next:
            why.log_slices_note(self.stream, s.paths, why.slices_note(self.config.likelihood_period))
        s.clear_next = []

    def _redo_around(self, s: _TrackerState, first: int, last: int) -> None:
        """The costly views of frames ``first..last`` (0-based indices) kept in memory, logged at their frames."""
        here = self._recent[-1][0]
        pending = list(s.clear_next)  # what this frame's own views need cleared on the next frame
        s.clear_next = []
        for frame, records in list(self._recent):
            i = int(frame.index)
            if not first <= i <= last or i == int(here.index):
                continue
            record = records[s.index]
            if i in s.drawn:
                continue  # already drawn on its own frame
            self._set_time(frame)
            problems: list[str] = []
            gt = checked(frame.gt, (4,), "ground truth", problems)
            box = checked(record.box, (4,), "box", problems)
            est_t = checked(record.estimate_template, (-1, -1), "estimate_template", problems)
            self._log_diagnostics(s, frame, record, box, gt, est_t, {}, problems, dense=True)
            # The views of a past frame show on that frame only: cleared on the next one, unless that
            # frame's own views are already logged (a clear logged after them would wipe them out).
            if i + 1 not in s.drawn:
                self.stream.set_time(P.FRAME_TIMELINE, sequence=frame_number(i) + 1)
                self._clear_views(s)
            s.clear_next = []
        s.clear_next = pending
        self._set_time(here)

    def _log_events(self, s: _TrackerState, frame, found: FrameNews) -> None:
        """Events, diagnoses and suspects of the diagnoser, each on the frame it belongs to.

        Every Events row leads with its kind, frame and cause (:func:`covviz.viz.story.headline`); a loss
        and its diagnosis are one row (``LOST 84 · OCCLUSION · drift began 70``), the loss's numbers and
        the diagnosis's card below it.
        """
        rec, p = self.stream, s.paths
        number = frame_number(frame.index)
        diagnosed = {d.lost_at: d for d in found.diagnoses}
        lost_text = {}
        for ev in found.events:
            if ev.frame != number:  # a drift is reported on the frame where it began
                self._at_number(ev.frame)
            if ev.kind == "lost" and ev.frame in diagnosed:
                lost_text[ev.frame] = ev.text  # one row with its diagnosis, below
            else:
                rec.log(p.events, rr.TextLog(viewer_safe(story.row(self._event_head(s, ev), f"[{s.name}] {ev.text}")),
                                             level=ev.level))
            if ev.kind in ("drift", "lost", "recovered") and np.isfinite(ev.iou):
                rec.log(p.marker(ev.kind), rr.Scalars(ev.iou))
            self._event_record(s, ev.kind, ev.frame, ev.level, ev.text)
            if ev.frame != number:
                self._set_time(frame)
            if ev.kind == "lost":
                s.losses.append(ev.frame)
                s.lost = True
            elif ev.kind == "recovered":
                s.lost = False
            elif ev.kind == "drift":
                s.drifts.append(ev.frame)
            elif ev.kind == "storm":
                s.n_storms += 1
        for d in found.diagnoses:
            s.diagnoses.append(d)
            head = story.headline(f"{self._who(s)}LOST {d.lost_at}", d.cause.replace("_", " ").upper(),
                                  f"drift began {d.drift_began}")
            body = "\n".join(t for t in (lost_text.get(d.lost_at, ""), d.text) if t)
            rec.log(p.events, rr.TextLog(viewer_safe(story.row(head, f"[{s.name}] {body}")), level="ERROR"))
            self._event_record(s, "diagnosis", d.lost_at, "ERROR", d.text, cause=d.cause, evidence=d.as_dict())
            # The views back to the drift onset, and on for a few frames.
            self._redo_around(s, d.drift_began - 1 - self.config.diagnosis.look_before, d.lost_at - 1)
            s.dense_until = max(s.dense_until, int(frame.index) + self.config.dense_after)
        # The old label-free suspects are inputs of the drift detector now (its alarms replace them in
        # Events, covviz.viz.drift); they stay in the results JSON (diagnosis.suspects), not as rows here.

    def _who(self, s: _TrackerState) -> str:
        """``[name] `` before a headline in a recording of several trackers (the Events' path column is cut)."""
        return f"[{s.name}] " if len(self._states) > 1 else ""

    def _event_head(self, s: _TrackerState, ev) -> str:
        """The first line of an event's row: kind, frame, what it was."""
        who = self._who(s)
        iou_txt = f"IoU {ev.iou:.2f}" if np.isfinite(ev.iou) else ""
        if ev.kind == "lost":
            return story.headline(f"{who}LOST {ev.frame}", iou_txt)
        if ev.kind == "drift":
            return story.headline(f"{who}DRIFT {ev.frame}", iou_txt, f"lost at {ev.detected_at}")
        if ev.kind == "recovered":
            return story.headline(f"{who}RECOVERED {ev.frame}", iou_txt, f"confirmed at {ev.detected_at}")
        if ev.kind == "storm":
            return story.headline(f"{who}STORM {ev.frame}", "weights on a handful of particles")
        if ev.kind == "storm_end":
            return story.headline(f"{who}storm over {ev.frame}")
        return story.headline(f"{who}{ev.kind.upper()} {ev.frame}")

    def _log_story(self, s: _TrackerState, found: FrameNews) -> None:
        """The track lane of the story strip, on the frames where its state changes."""
        state = story.track_state(found.evidence.label, s.lost, float(found.evidence.iou),
                                  self.config.diagnosis.on_track_iou)
        if state != s.story_state:
            s.story_state = state
            self.stream.log(s.paths.story_lane("track"), rr.StateChange(state=state))

    def _at_number(self, number: int) -> None:
        self.stream.set_time(P.FRAME_TIMELINE, sequence=int(number))
        if self._fps:
            self.stream.set_time(P.TIME_TIMELINE, duration=(int(number) - 1) / self._fps)

    def _event_record(self, s: _TrackerState, kind: str, number: int, level: str, text: str, cause: str = "",
                      evidence: dict | None = None) -> None:
        """One row per event, with its fields (``covviz events`` reads these back)."""
        self.stream.log(
            s.paths.event_records,
            rr.AnyValues(
                tracker=[s.name], kind=[kind], frame_number=[int(number)], level=[level], text=[viewer_safe(text)],
                cause=[cause], details=[json.dumps(evidence or {}, default=float)],
            ),
        )

    def _log_likelihood(self, s: _TrackerState, model, prepared, pose, est_t, inputs) -> None:
        """The likelihood map as a heat overlay over the searched region, its outline, colour bar and peak.

        The colours span the map's own range, from the best position down to the worst, on a square-root
        scale (the likelihood at σ = 0.3 is one bright cell on a linear one), so the whole searched region
        is coloured; the best position is a thin ring, no label, so the target under
        it stays visible.
        """
        cfg, rec, p = self.config, self.stream, s.paths
        lm = likelihood_map(model, prepared, pose, est_t, cfg.likelihood_grid, cfg.likelihood_reach, **inputs)
        x0, y0, x1, y1 = lm.extent
        g = cfg.likelihood_grid
        L = np.asarray(lm.log_likelihood, dtype=np.float64)
        finite = L[np.isfinite(L)]
        span = float(max(-finite.min(), 1.0)) if finite.size else LIKELIHOOD_RANGE_NATS
        # Heat cells as overlapping discs in the frame's own pixels (no transform to go wrong): one per
        # position of the map, coloured by its log-likelihood on a square-root scale of the map's range.
        # Square cells (a tall or wide region gets more of them, the map interpolated bilinearly), so the
        # discs cover the region without spilling over its outline.
        cell = min(x1 - x0, y1 - y0) / g
        nx = int(np.clip(round((x1 - x0) / cell), 2, 4 * g))
        ny = int(np.clip(round((y1 - y0) / cell), 2, 4 * g))
        cw, ch = (x1 - x0) / nx, (y1 - y0) / ny
        gx, gy = np.meshgrid(x0 + (np.arange(nx) + 0.5) * cw, y0 + (np.arange(ny) + 0.5) * ch)
        Lf = np.nan_to_num(L, nan=-span, neginf=-span)
        if (ny, nx) != Lf.shape:
            Lf = cv2.resize(Lf.astype(np.float32), (nx, ny), interpolation=cv2.INTER_LINEAR).astype(np.float64)
        shown = -span * np.sqrt(np.clip(-Lf, 0.0, span) / span)
        rgba = likelihood_rgba(shown, span, floor_alpha=60).reshape(-1, 4)
        rgba[:, 3] = (0.55 * rgba[:, 3]).astype(np.uint8)
        rec.log(p.likelihood, rr.Points2D(np.stack([gx.ravel(), gy.ravel()], 1), radii=[0.6 * max(cw, ch)],
                                          colors=rgba, draw_order=5.0))
        # The searched region's outline and, above it, the colour bar: best (bright) .. span nats below (dark).
        rec.log(p.likelihood_region, rr.LineStrips2D([[(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]],
                                                    colors=[(255, 170, 60, 160)], radii=[0.3], draw_order=6.0))
        nb = 24
        yb = y0 - max(3.0, 0.05 * (y1 - y0))
        bx = x0 + (np.arange(nb) + 0.5) * (x1 - x0) / nb
        bar = likelihood_rgba(np.linspace(-span, 0.0, nb)[None, :], span, floor_alpha=255).reshape(-1, 4)
        rec.log(p.likelihood_bar, rr.Points2D(np.stack([bx, np.full(nb, yb)], 1), radii=[0.55 * (x1 - x0) / nb],
                                              colors=bar, draw_order=41.0))
        rec.log(p.likelihood_bar_labels,
                rr.Points2D([(x0, yb), (x1, yb)], radii=[0.0],
                            labels=[f"-{span:.0f} nats (sqrt)", "best"], colors=[(230, 230, 230)], show_labels=True,
                            draw_order=41.0))
        ring = lm.best + 0.03 * (x1 - x0) * np.stack([np.cos(t := np.linspace(0, 2 * np.pi, 17)), np.sin(t)], 1)
        rec.log(p.likelihood_peak, rr.LineStrips2D([ring], colors=[(255, 255, 255)], radii=[0.35], draw_order=40.0))
        s.clear_next += [p.likelihood, p.likelihood_peak, p.likelihood_region, p.likelihood_bar, p.likelihood_bar_labels]

    def _log_cloud(self, s: _TrackerState, model, prepared, frame, record, pose, gt) -> None:
        cfg, rec, p = self.config, self.stream, s.paths
        bg_poses, slots = background_poses(pose, model.base_wh, np.shape(frame.image), cfg.n_background)
        poses = bg_poses
        if gt is not None:
            poses = np.concatenate([bg_poses, box_to_pose(gt, model.base_wh)[None]])
        obs = model.descriptors(prepared, poses) if len(poses) else np.zeros((0, 9, 9))
        target = obs[-1] if gt is not None else None
        background = obs[: len(bg_poses)]
        cloud = template_cloud(
            record, s.initial_template, target, background, slots, cfg.top_k, cfg.mds_max_templates, s.rng
        )
        if len(cloud.matrices) < 3:
            # Nothing to embed: say so in the picture, rather than leave it empty (or stale).
            for root in (p.cloud, p.cloud_zoom):
                rec.log(f"{root}", rr.Clear(recursive=True))
                rec.log(f"{root}/note", rr.TextLog(f"frame {frame_number(frame.index)}: only {len(cloud.matrices)} "
                                                   "matrices (no templates or no target): no picture", level="WARN"))
            return
        D = distance_matrix(cloud.matrices)
        i = int(frame.index)
        # Two pictures from one distance matrix: the neighbourhood (with the background; classical
        # MDS), where the template cloud is often a dot, and the cloud alone (the submatrix
        # without the background; SMACOF, which keeps the cloud open), where its structure and
        # the target's place in it show.
        self._log_picture(s, p.cloud, s.mds, D, cloud.kinds, cloud.keys, i, labels=False)
        keep = cloud.kinds != "background"
        stress_zoom = None
        if keep.sum() >= 3:
            keys = [k for k, m in zip(cloud.keys, keep) if m]
            stress_zoom = self._log_picture(
                s, p.cloud_zoom, s.mds_zoom, D[np.ix_(keep, keep)], cloud.kinds[keep], keys, i, labels=True
            )
        self._log_cloud_health(s, D, cloud.kinds, stress_zoom)
        if len(bg_poses):
            c = closed_strips(pose_corners(bg_poses, model.base_wh)).astype(np.float32)
            rec.log(
                p.background,
                rr.LineStrips2D(c, colors=[BACKGROUND_COLOR + (60,)], radii=0.25, draw_order=15.0),
            )
            s.clear_next.append(p.background)

    def _log_cloud_health(self, s: _TrackerState, D, kinds, stress_zoom) -> None:
        """The target's gap to the template cloud, the background's margin, and the cloud picture's stress.

        The gap is the target's distance to its nearest generated template. On track it is
        the ordinary distance between a template and a fresh observation (~1, far larger than
        the cloud's width), so it is logged relative to its own median over the last frames on
        track: 1 is as healthy as usual, 2 and more says the target has left the cloud's reach.
        The margin is the nearest background region's gap minus the target's: positive while
        the target is nearer the cloud than any background region, negative when some
        background would match the templates better.
        """
        rec, p = self.stream, s.paths
        gen = np.flatnonzero((kinds == "template") | (kinds == "top"))
        tgt = np.flatnonzero(kinds == "target")
        bg = np.flatnonzero(kinds == "background")
        if stress_zoom is not None:
            rec.log(f"{p.cloud_health}/stress", rr.Scalars(float(stress_zoom)))
        if not len(gen) or not len(tgt):
            return
        gap = float(D[tgt[0], gen].min())
        if s.last_iou is not None and s.last_iou >= self.config.diagnosis.on_track_iou:
            s.healthy_gap.append(gap)
        level = float(np.median(s.healthy_gap)) if len(s.healthy_gap) >= 3 else float("nan")
        if np.isfinite(level) and level > 0:
            rec.log(f"{p.cloud_health}/gap", rr.Scalars(gap / level))
        if len(bg):
            rec.log(f"{p.cloud_health}/margin", rr.Scalars(float(D[np.ix_(bg, gen)].min(axis=1).min() - gap)))

    def _log_picture(
        self, s: _TrackerState, root: str, mds, D, kinds, keys, frame_index: int, labels: bool
    ) -> float:
        """MDS of ``D`` aligned to ``mds``'s previous picture, one Points2D per kind under ``root``; its stress-1."""
        rec = self.stream
        X = mds.fit(D, keys)

        def lab(text):
            return {"labels": [text]} if labels else {}

        style = {
            "template": {"colors": [TEMPLATE_COLOR], "radii": [-2.5]},
            "top": {"colors": [TOP_COLOR], "radii": [-4.0]},
            "background": {"colors": [BACKGROUND_COLOR], "radii": [-4.0]},
            "estimate": {"colors": [s.color], "radii": [-5.0], **lab("estimate")},
            "initial": {"colors": [INITIAL_COLOR], "radii": [-5.0], **lab("initial")},
            "target": {"colors": [GT_COLOR], "radii": [-5.5], "labels": [f"target (frame {frame_number(frame_index)})"]},
        }
        lo, hi = X.min(axis=0), X.max(axis=0)
        # The estimate's and the initial template's labels sit apart (above, below their points): the two
        # are often close, and labels at their points would print on top of each other.
        nudge = {"estimate": -0.07, "initial": 0.07}
        for order, kind in enumerate(style):
            m = kinds == kind
            path = f"{root}/{kind}"
            if m.any():
                st = dict(style[kind])
                text = st.pop("labels", None)
                if kind in nudge:
                    self._put_points(path, X[m], {**st, "draw_order": float(order)})
                    if text:
                        at = X[m][:1] + np.array([0.0, nudge[kind] * float((hi - lo).max() + 1e-9)])
                        self._put_points(f"{path}_label", at, {"radii": [0.0], "colors": st["colors"],
                                                               "show_labels": True, "draw_order": 20.0}, text)
                else:
                    self._put_points(path, X[m], {**st, "draw_order": float(order)}, text)
            else:
                rec.log(path, rr.Clear(recursive=False))
                if kind in nudge:
                    rec.log(f"{path}_label", rr.Clear(recursive=False))
        # Two invisible points a margin outside the picture, so the view's automatic bounds leave
        # room for the labels of points on the edge.
        pad = 0.15 * (hi - lo).max() + 1e-6
        self._put_points(f"{root}/margin", np.stack([lo - pad, hi + pad]), {"radii": [0.0], "colors": [(0, 0, 0, 0)]})
        return stress1(X, D)

    # ------------------------------------------------------------------ #
    def on_end(self, results, found: Findings) -> None:
        rec = self.stream
        self.series.flush()
        try:
            last = frame_number(self._last_frame) if self._last_frame >= 0 else 0
            lines = ["# Summary of the run", ""]
            interrupted = any(r.interrupted for r in results)
            if interrupted:
                lines += [
                    (
                        f"**The run was interrupted** after frame {last}; "
                        "the recording holds every frame done until then."
                    ),
                    "",
                ]
            lines += [
                "| tracker | frames | fps | success AUC | P@20 | mean IoU | lost at (cause) | drift began at | storms |",
                "|---|---|---|---|---|---|---|---|---|",
            ]
            for s, r in zip(self._states, results):
                if len(r.boxes) and not nothing_to_score(r.groundtruth):
                    m = evaluate(r.boxes, r.groundtruth)
                    auc, p20, miou = f"{m.success_auc:.3f}", f"{m.precision_20:.3f}", f"{m.mean_iou:.3f}"
                else:
                    auc = p20 = miou = "–"
                causes = {d.lost_at: d.cause for d in s.diagnoses}
                lost = ", ".join(f"{f} ({causes.get(f, '?').replace('_', ' ')})" for f in s.losses) or "none"
                lines.append(
                    f"| {s.name} | {len(r.boxes)} | {r.fps:.1f} | {auc} | {p20} | {miou} | "
                    f"{lost} | {', '.join(map(str, s.drifts)) or '–'} | {s.n_storms} |"
                )
            lines += [
                "",
                ("*frames*: frames tracked. *lost at*: IoU < 0.1 (the IoU rule); the paper's r_on_track counts a frame "
                "on track while the centre error is within the truth's size, so a box of the wrong size can be "
                "lost by IoU and on track by centre. A loss's card counts its off-track frames (model / search / "
                "estimate) from its drift to the loss; the story strip shows them over the whole run. *storms*: "
                "ESS/N < 0.05 on 3 frames while the IoU fell below 0.5 (or 30 frames without ground truth); peaked "
                "weights on a run that stays on track are not one."),
            ]
            replays = found.counterfactual
            for s, rp in zip(self._states, replays):
                self._log_replays(s, rp, results[s.index])
            cards = [f"* **{s.name}** {d.text}" + (f" **{replays[s.index][d.lost_at].line()}**"
                                                     if s.index < len(replays) and d.lost_at in replays[s.index]
                                                     else "")
                     for s in self._states for d in s.diagnoses]
            if cards:
                lines += ["", "## Why it was lost", "", *cards]
            rec.log(
                P.SUMMARY,
                rr.TextDocument(viewer_safe("\n".join(lines) + "\n"), media_type=rr.MediaType.MARKDOWN),
                static=True,
            )
            if interrupted and self._last_frame >= 0:
                rec.set_time(P.FRAME_TIMELINE, sequence=last)
                for s in self._states:
                    rec.log(s.paths.events, rr.TextLog("run interrupted after this frame", level="WARN"))
        except Exception as exc:  # noqa: BLE001 - never let the summary hide the run's own outcome
            log.warning("could not write the recording summary: %s", exc)
        finally:
            if self.close_on_end:
                self.close()

    def _log_replays(self, s: _TrackerState, replays: dict, result) -> None:
        """Each loss's counterfactual replays: faint boxes and an IoU series per fix on its window, the verdict."""
        rec, p = self.stream, s.paths
        truth = result.groundtruth
        for lost_at, rp in sorted(replays.items()):
            for kind, o in rp.outcomes.items():
                col = REPLAY_COLORS.get(kind, (200, 200, 200, 110))
                rec.log(p.replay_iou(kind), rr.SeriesLines(names=[f"{s.prefix}replay: {kind}"], colors=[col[:3]],
                                                          widths=[1.0]), static=True)
                for k, box in enumerate(o.boxes):
                    n = rp.start + k
                    rec.set_time(P.FRAME_TIMELINE, sequence=n)
                    rec.log(p.replay_box(kind), rr.Boxes2D(mins=[box[:2]], sizes=[box[2:]], colors=[col],
                                                            labels=[kind], show_labels=False, radii=0.5,
                                                            draw_order=12.0))
                    if n - 1 < len(truth) and np.all(np.isfinite(truth[n - 1])):
                        rec.log(p.replay_iou(kind), rr.Scalars(float(iou(box[None], truth[n - 1][None])[0])))
                rec.set_time(P.FRAME_TIMELINE, sequence=rp.end + 1)
                rec.log(p.replay_box(kind), rr.Clear(recursive=False))
            rec.set_time(P.FRAME_TIMELINE, sequence=lost_at)
            cause = next((d.cause for d in s.diagnoses if d.lost_at == lost_at), "")
            marks = " ".join(f"{k} {'kept' if o.kept else 'lost'}" for k, o in rp.outcomes.items() if k != "none")
            head = story.headline(f"{self._who(s)}LOST {lost_at}", cause.replace("_", " ").upper(),
                                  f"verdict {rp.verdict.upper()}", marks)
            rec.log(p.events, rr.TextLog(viewer_safe(story.row(head, f"[{s.name}] frame {lost_at}: {rp.line()}")),
                                         level="INFO"))
            # The verdict lane: from the loss to the end of its replay.
            rec.log(p.story_lane("verdict"), rr.StateChange(state=rp.verdict))
            rec.set_time(P.FRAME_TIMELINE, sequence=max(rp.end, lost_at) + 1)
            rec.log(p.story_lane("verdict"), story.clear_state())
            rec.set_time(P.FRAME_TIMELINE, sequence=lost_at)
            details = {k: v for k, v in rp.as_dict().items() if k != "replay"}
            details["replay"] = {k: v for k, v in rp.as_dict()["replay"].items() if k != "boxes"}
            self._event_record(s, "verdict", lost_at, "INFO", rp.line(), cause=rp.verdict, evidence=details)

    def close(self) -> None:
        """Send everything logged so far and disconnect the stream (finalises an ``.rrd`` file).

        A live viewer that went away cannot take the rest: that is a warning, not an error
        (the file sink, if any, has everything). A file cut short (a full disk) raises
        :class:`~covviz.errors.WriteError` (see :func:`~covviz.viz.sinks.close_stream`).
        """
        close_stream(self.stream, timeout=FLUSH_TIMEOUT)


def recorder(stream: rr.RecordingStream, config: LoggerConfig | None = None, run_info: dict | None = None,
             close_on_end: bool = True) -> Pipeline:
    """The drift diagnosis and the Rerun logger after it: what ``covviz track`` records, as one observer."""
    config = config or LoggerConfig()
    return Pipeline([Diagnoser(config.diagnosis),
                     RerunLogger(stream, config, run_info=run_info, close_on_end=close_on_end)])
