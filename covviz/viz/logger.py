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
import re
import time
from collections.abc import Sequence as Seq
from dataclasses import asdict, dataclass, field

import numpy as np
import rerun as rr

from covviz import __version__
from covviz.embedding import AlignedMDS, distance_matrix
from covviz.features import pose_corners
from covviz.metrics import center_error, evaluate, iou, nothing_to_score
from covviz.records import FrameRecord
from covviz.spd import logm
from covviz.threads import limit_threads
from covviz.viz import paths as P
from covviz.viz.blueprint import build_blueprint
from covviz.viz.checks import checked, closed_strips, jpeg_bytes
from covviz.viz.description import DESCRIPTION, viewer_safe
from covviz.viz.diagnostics import (
    EVENT_DEFAULTS,
    EventConfig,
    EventDetector,
    ObservationModel,
    background_poses,
    box_to_pose,
    likelihood_map,
    template_cloud,
    template_spread,
    top_k,
)
from covviz.viz.palette import (
    BACKGROUND_COLOR,
    GT_COLOR,
    INITIAL_COLOR,
    LUT,
    SERIES_COLORS,
    TEMPLATE_COLOR,
    TOP_COLOR,
    likelihood_rgba,
    tracker_color,
    weight_levels,
    weight_lut,
)
from covviz.viz.sinks import FLUSH_TIMEOUT, close_stream

__all__ = ["LoggerConfig", "RerunLogger"]

log = logging.getLogger("covviz.viz")

#: The frame is drawn first (lowest draw order); overlays must come after it, or the depth test
#: hides the frame behind their transparent pixels.
FRAME_DRAW_ORDER = -20.0
#: Radius of the centre of the heaviest particle, pixels (radius ∝ sqrt(w / w_max)).
CENTRE_RADIUS = 3.0
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
    spread_every : int
        The template-cloud spread (a Karcher mean) every this many frames.
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
    seed : int
        Seed of the logger's own randomness (the sample of templates in the MDS).
    events : EventConfig
        Thresholds of the event detector.
    """

    mds_every: int = 10
    likelihood_every: int | None = None
    spread_every: int = 1
    spread_templates: int = 32
    top_k: int = 10
    mds_max_templates: int = 48
    mds_method: str = "classical"
    n_background: int = 16
    likelihood_grid: int = 17
    likelihood_reach: float = 1.0
    jpeg_quality: int = 60
    particle_precision: float = 0.5
    seed: int = 0
    events: EventConfig = field(default_factory=lambda: EVENT_DEFAULTS)

    def __post_init__(self):
        for name in ("mds_every", "spread_every", "spread_templates", "top_k", "n_background"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
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


#: Dimension names of the estimate's tensor; slices of the first are TENSOR_SLICES.
TENSOR_DIMS = ("matrix", "feature i", "feature j")
TENSOR_SLICES = ("template", "observed", "difference")


def _has_templates(tracker) -> bool:
    """Whether a tracker carries covariance templates (the manifold tracker and its variants)."""
    return hasattr(getattr(tracker, "config", None), "template_sigma")


def _has_particles(tracker) -> bool:
    """Whether a tracker is a particle filter (its records carry weights)."""
    cfg = getattr(tracker, "config", None)
    return _has_templates(tracker) or hasattr(cfg, "n_particles") or hasattr(cfg, "particles")


# --------------------------------------------------------------------------- #
# per-tracker state
# --------------------------------------------------------------------------- #
class _TrackerState:
    def __init__(self, name: str, tracker, color, cfg: LoggerConfig, index: int):
        self.name = name
        self.paths = P.TrackerPaths(name)
        self.tracker = tracker
        self.color = color
        self.model: ObservationModel | None = None
        self.model_checked = False
        self.sigma = float(getattr(getattr(tracker, "config", None), "likelihood_sigma", 0.3) or 0.3)
        self.mds = AlignedMDS(cfg.mds_method)
        # SMACOF for the cloud alone: classical MDS would flatten it (see covviz.embedding.embed).
        self.mds_zoom = AlignedMDS("smacof", max_iter=30)
        self.spread_mean: np.ndarray | None = None
        self.events = EventDetector(cfg.events)
        self.initial_template: np.ndarray | None = None
        self.rng = np.random.default_rng([cfg.seed, index])
        self.had_particles = False
        self.lut = LUT
        self.series_colors = dict(SERIES_COLORS)
        self.clear_next: list[str] = []
        self.stages_seen: set[str] = set()
        self.warned: set[str] = set()


# --------------------------------------------------------------------------- #
# the observer
# --------------------------------------------------------------------------- #
class RerunLogger:
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
        self.run_info = dict(run_info or {})
        self.close_on_end = close_on_end
        self._states: list[_TrackerState] = []
        self._last_frame = -1
        self._fps = None
        self._blueprint_args = None
        self.log_seconds = 0.0  # time spent in on_frame, for the overhead benchmark

    # ------------------------------------------------------------------ #
    def on_start(self, sequence, trackers: Seq) -> None:
        rec, cfg = self.stream, self.config
        names: list[str] = []
        for i, tr in enumerate(trackers):
            # Entity-path friendly, and drawable by the viewer's font.
            base = re.sub(r"[^A-Za-z0-9_.+-]", "_", str(getattr(tr, "name", "") or "")) or f"tracker{i}"
            name, k = base, 2
            while name in names:
                name, k = f"{base}-{k}", k + 1
            names.append(name)
        self._states = []
        for i, (name, tr) in enumerate(zip(names, trackers)):
            color = tracker_color(getattr(tr, "name", ""), i)
            self._states.append(_TrackerState(name, tr, color, cfg, i))
        self._fps = getattr(sequence, "frame_rate", None) or None
        with_cloud = [s.name for s in self._states if _has_templates(s.tracker)]
        with_particles = [s.name for s in self._states if _has_particles(s.tracker)]
        # Several particle trackers: the second and later get their own colour ramp and series colours.
        for k, s in enumerate(st for st in self._states if st.name in with_particles):
            if k > 0:
                s.lut = weight_lut(hi=s.color)
                s.series_colors = {
                    key: tuple(int(0.4 * a + 0.6 * b) for a, b in zip(col[:3], s.color))
                    for key, col in SERIES_COLORS.items()
                }
        # The blueprint goes out with the first frame, when the image size is known.
        self._blueprint_args = (names, with_cloud, with_particles)
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
                "frame_rate": getattr(sequence, "frame_rate", None),
            },
            "run": self.run_info,
            "trackers": {
                s.name: (s.tracker.config_dict() if hasattr(s.tracker, "config_dict") else {})
                for s in self._states
            },
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
            lines = {p.iou: (c, f"{s.name} IoU"), p.center_error: (c, f"{s.name} centre error")}
            if s.name in with_particles:
                lines.update(
                    {
                        p.ess: (s.series_colors["ess"], f"{s.name} ESS/N"),
                        p.max_weight: (s.series_colors["max"], f"{s.name} max weight"),
                        p.survivors: (s.series_colors["survivors"], f"{s.name} survivors/N"),
                        p.distance_min: (s.series_colors["min"], f"{s.name} min d"),
                        p.distance_mean: (s.series_colors["mean"], f"{s.name} mean d (weighted)"),
                        p.spread: (s.series_colors["spread"], f"{s.name} template spread"),
                    }
                )
                rec.log(
                    p.resampled,
                    rr.SeriesPoints(
                        colors=[s.series_colors["resampled"]],
                        names=[f"{s.name} resampled"],
                        markers=["Circle"],
                        marker_sizes=[1.5],
                    ),
                    static=True,
                )
            for path, (col, label) in lines.items():
                rec.log(path, rr.SeriesLines(colors=[col], names=[label], widths=[1.5]), static=True)
            for kind, marker in (("drift", "Cross"), ("lost", "Down"), ("recovered", "Up")):
                rec.log(
                    p.marker(kind),
                    rr.SeriesPoints(
                        colors=[SERIES_COLORS[kind]],
                        names=[f"{s.name} {kind}"],
                        markers=[marker],
                        marker_sizes=[6.0],
                    ),
                    static=True,
                )
            rec.log(
                p.box,
                rr.Boxes2D.from_fields(
                    colors=[c],
                    radii=[0.9],
                    labels=[s.name],
                    show_labels=len(self._states) > 1,
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
    def on_frame(self, frame, records: Seq[FrameRecord]) -> None:
        t0 = time.perf_counter()
        # The diagnostics do linear algebra on small matrices (9×9 stacks, a ~80×80 eigh), where
        # BLAS threads only add wake-up latency (10-100× on a loaded 2-core machine).
        with limit_threads(1, opencv=False):
            self._on_frame(frame, records)
        dt = time.perf_counter() - t0
        self.log_seconds += dt
        self.stream.log(P.LOGGER_TIME, rr.Scalars(dt * 1e3))

    def _on_frame(self, frame, records: Seq[FrameRecord]) -> None:
        rec, cfg = self.stream, self.config
        i = int(frame.index)
        self._last_frame = i
        if self._blueprint_args is not None:
            if rec.is_enabled():  # a disabled stream has no application to attach a blueprint to
                h, w = np.shape(frame.image)[:2]
                rec.send_blueprint(build_blueprint(*self._blueprint_args, image_size=(w, h)))
            self._blueprint_args = None
        rec.set_time(P.FRAME_TIMELINE, sequence=i)
        if frame.time is not None:
            rec.set_time(P.TIME_TIMELINE, duration=float(frame.time))
        rec.log(
            P.IMAGE,
            rr.EncodedImage(
                contents=jpeg_bytes(frame.image, cfg.jpeg_quality),
                media_type="image/jpeg",
                draw_order=FRAME_DRAW_ORDER,
            ),
        )
        problems: list[str] = []
        gt = checked(frame.gt, (4,), "ground truth", problems)
        if gt is not None:
            rec.log(P.GROUND_TRUTH, rr.Boxes2D(mins=[gt[:2]], sizes=[gt[2:]]))
        else:
            rec.log(P.GROUND_TRUTH, rr.Clear(recursive=False))
        prepared_cache: dict[int, object] = {}
        for s, record in zip(self._states, records):
            self._log_tracker(s, frame, record, gt, prepared_cache)

    def _warn(self, s: _TrackerState, problems: list[str]) -> None:
        for msg in problems:
            if msg not in s.warned:
                s.warned.add(msg)
                log.warning("%s: %s; not logged (further occurrences silent)", s.name, msg)
                self.stream.log(s.paths.events, rr.TextLog(viewer_safe(f"not logged: {msg}"), level="WARN"))

    def _log_tracker(self, s: _TrackerState, frame, record: FrameRecord, gt, prepared_cache) -> None:
        rec, cfg, p = self.stream, self.config, s.paths
        i = int(frame.index)
        problems: list[str] = []
        for path in s.clear_next:
            rec.log(path, rr.Clear(recursive=False))
        s.clear_next = []

        # --- estimate -------------------------------------------------
        box = checked(record.box, (4,), "box", problems)
        if box is not None:
            rec.log(p.box, rr.Boxes2D(mins=[box[:2]], sizes=[box[2:]]))
        corners = checked(record.corners, (4, 2), "corners", problems)
        if corners is not None:
            rec.log(p.region, rr.LineStrips2D(closed_strips(corners[None]).astype(np.float32)))

        # --- particles ------------------------------------------------
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
            strips = (np.round(closed_strips(pc[order]) / q) * q).astype(np.float32)
            rec.log(
                p.particles, rr.LineStrips2D(strips, colors=s.lut[level[order]], radii=0.2, draw_order=20.0)
            )
            top = top_k(w, cfg.top_k)
            top_any = {"weight": w[top].astype(np.float64), "particle": top.astype(np.int64)}
            dist = checked(record.distances, (len(w),), "distances", problems)
            if dist is not None:
                top_any["distance"] = dist[top]
            # Trackers whose weights use more than d(C, C*) (the manifold tracker's quadrant
            # term) say so in extras: hovering a top particle shows what it was weighed by.
            d_lik = checked(record.extras.get("likelihood_distances"), (len(w),), "likelihood_distances", problems)
            if d_lik is not None and d_lik is not dist:
                top_any["likelihood_distance"] = d_lik[top]
            d_quad = checked(record.extras.get("quadrant_distances"), (len(w), -1), "quadrant_distances", problems)
            if d_quad is not None:
                for j in range(d_quad.shape[1]):
                    top_any[f"quadrant_distance_{j}"] = d_quad[top, j]
            rec.log(
                p.top,
                rr.LineStrips2D(
                    closed_strips(pc[top]).astype(np.float32), colors=[TOP_COLOR], radii=0.6, draw_order=30.0
                ),
                rr.AnyValues(**top_any),
            )
            radii = np.round(CENTRE_RADIUS * np.sqrt(wn[order]) * 4) / 4
            vis = radii >= MIN_CENTRE_RADIUS
            centres = pc[order[vis]].mean(axis=1)
            rec.log(
                p.centres,
                rr.Points2D(
                    np.round(centres / q) * q,
                    radii=radii[vis].astype(np.float32),
                    colors=s.lut[level[order[vis]]],
                    draw_order=25.0,
                ),
            )
            ess = float(record.ess) if np.isfinite(record.ess) else float(1.0 / np.sum(w * w))
            rec.log(p.ess, rr.Scalars(ess / n))
            rec.log(p.max_weight, rr.Scalars(float(w.max())))
            if record.resampled:
                rec.log(p.resampled, rr.Scalars(ess / n))
                idx = record.resample_indices
                if idx is not None and len(idx):
                    rec.log(p.survivors, rr.Scalars(len(np.unique(idx)) / len(idx)))
            else:
                rec.log(p.survivors, rr.Scalars(1.0))
            if dist is not None:
                rec.log(p.distance_min, rr.Scalars(float(dist.min())))
                rec.log(p.distance_mean, rr.Scalars(float(np.dot(w, dist))))
        elif s.had_particles:
            for path in (p.particles, p.top, p.centres):
                rec.log(path, rr.Clear(recursive=False))

        # --- quality against ground truth ---------------------------------
        o = None
        if gt is not None and box is not None:
            o = float(iou(box[None], gt[None])[0])
            rec.log(p.iou, rr.Scalars(o))
            rec.log(p.center_error, rr.Scalars(float(center_error(box[None], gt[None])[0])))

        # --- template cloud spread ---------------------------------------
        templates = checked(record.templates, (-1, -1, -1), "templates", problems)
        if templates is not None and len(templates) and cfg.spread_every and i % cfg.spread_every == 0:
            try:
                spread, s.spread_mean = template_spread(
                    templates, init=s.spread_mean, max_templates=cfg.spread_templates
                )
                rec.log(p.spread, rr.Scalars(spread))
            except (ValueError, np.linalg.LinAlgError) as exc:
                problems.append(f"template spread failed ({exc})")
                s.spread_mean = None

        # --- tensors ---------------------------------------------------------
        est_t = checked(record.estimate_template, (-1, -1), "estimate_template", problems)
        est_d = checked(record.estimate_descriptor, (-1, -1), "estimate_descriptor", problems)
        if i == 0 and est_t is not None:
            s.initial_template = est_t.copy()
        # One (3, d, d) tensor: template, observed, difference, in log space (where the template
        # lives and the random walk steps: entries of order 1, readable on one colour scale, and
        # difference = observed - template exactly). One tensor instead of three saves 1 ms a
        # frame of conversion.
        if est_t is not None and est_d is not None and est_t.shape == est_d.shape:
            try:
                obs_log = logm(est_d)
            except ValueError as exc:
                problems.append(f"observed descriptor is not SPD ({exc})")
            else:
                stack = np.stack([est_t, obs_log, obs_log - est_t]).astype(np.float32)
                rec.log(p.tensors, rr.Tensor(stack, dim_names=list(TENSOR_DIMS)))

        # --- timings -----------------------------------------------------
        for stage, sec in record.timings.items():
            if not np.isfinite(sec):
                continue
            path = p.timing(stage)
            if stage not in s.stages_seen:
                s.stages_seen.add(stage)
                rec.log(
                    path,
                    rr.SeriesLines(names=[f"{s.name} {stage}"], widths=[1.0 if stage != "total" else 2.0]),
                    static=True,
                )
            rec.log(path, rr.Scalars(float(sec) * 1e3))

        # --- costly diagnostics (only on their frames) ----------------------------
        want_mds = cfg.mds_every and i % cfg.mds_every == 0 and est_t is not None
        want_lik = cfg.likelihood_period and i % cfg.likelihood_period == 0 and est_t is not None
        if want_mds or want_lik:
            model = self._model(s)
            if model is not None:
                key = id(s.tracker)
                if key not in prepared_cache:
                    prepared_cache[key] = model.prepare(frame.image)
                prepared = prepared_cache[key]
                pose = checked(record.pose, (4,), "pose", problems)
                if pose is None and box is not None:
                    pose = box_to_pose(box, model.base_wh)
                if pose is not None:
                    try:
                        if want_lik:
                            self._log_likelihood(s, model, prepared, pose, est_t)
                        if want_mds:
                            self._log_cloud(s, model, prepared, frame, record, pose, gt)
                    except (ValueError, np.linalg.LinAlgError) as exc:
                        problems.append(f"diagnostics failed on frame {i} ({exc})")

        # --- events ------------------------------------------------------
        ess_frac = float(record.ess) / n if n and np.isfinite(record.ess) else None
        for ev in s.events.update(i, o, ess_frac):
            if ev.frame != i:  # a drift is reported on the frame where it began
                rec.set_time(P.FRAME_TIMELINE, sequence=ev.frame)
                if frame.time is not None and self._fps:
                    rec.set_time(P.TIME_TIMELINE, duration=ev.frame / self._fps)
            rec.log(p.events, rr.TextLog(f"[{s.name}] frame {ev.frame}: {ev.text}", level=ev.level))
            if ev.kind in ("drift", "lost", "recovered") and np.isfinite(ev.iou):
                rec.log(p.marker(ev.kind), rr.Scalars(ev.iou))
            if ev.frame != i:
                rec.set_time(P.FRAME_TIMELINE, sequence=i)
                if frame.time is not None:
                    rec.set_time(P.TIME_TIMELINE, duration=float(frame.time))
        if problems:
            self._warn(s, problems)

    def _model(self, s: _TrackerState) -> ObservationModel | None:
        if not s.model_checked:
            s.model_checked = True
            s.model = ObservationModel.from_tracker(s.tracker)
        return s.model

    def _log_likelihood(self, s: _TrackerState, model, prepared, pose, est_t) -> None:
        cfg, rec, p = self.config, self.stream, s.paths
        lm = likelihood_map(model, prepared, pose, est_t, s.sigma, cfg.likelihood_grid, cfg.likelihood_reach)
        x0, y0, x1, y1 = lm.extent
        g = cfg.likelihood_grid
        rec.log(
            p.likelihood,
            rr.Transform3D(translation=[x0, y0, 0.0], scale=[(x1 - x0) / g, (y1 - y0) / g, 1.0]),
            # An opacity below 1 puts the image in the viewer's blended pass; at the default (1)
            # its transparent pixels would hide the frame (checked with rerun 0.41).
            rr.Image(
                likelihood_rgba(lm.log_likelihood),
                color_model="RGBA",
                draw_order=5.0,
                opacity=0.9,
                magnification_filter="Linear",
            ),
        )
        rec.log(
            p.likelihood_peak,
            rr.Points2D(
                [lm.best], radii=[-5.0], colors=[(255, 255, 255)], labels=["best match"], draw_order=40.0
            ),
        )
        s.clear_next += [p.likelihood, p.likelihood_peak]

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
            return
        D = distance_matrix(cloud.matrices)
        i = int(frame.index)
        # Two pictures from one distance matrix: the neighbourhood (with the background; classical
        # MDS), where the template cloud is often a dot, and the cloud alone (the submatrix
        # without the background; SMACOF, which keeps the cloud open), where its structure and
        # the target's place in it show.
        self._log_picture(s, p.cloud, s.mds, D, cloud.kinds, cloud.keys, i, labels=False)
        keep = cloud.kinds != "background"
        if keep.sum() >= 3:
            keys = [k for k, m in zip(cloud.keys, keep) if m]
            self._log_picture(
                s, p.cloud_zoom, s.mds_zoom, D[np.ix_(keep, keep)], cloud.kinds[keep], keys, i, labels=True
            )
        if len(bg_poses):
            c = closed_strips(pose_corners(bg_poses, model.base_wh)).astype(np.float32)
            rec.log(
                p.background,
                rr.LineStrips2D(c, colors=[BACKGROUND_COLOR + (60,)], radii=0.25, draw_order=15.0),
            )
            s.clear_next.append(p.background)

    def _log_picture(
        self, s: _TrackerState, root: str, mds, D, kinds, keys, frame_index: int, labels: bool
    ) -> None:
        """MDS of ``D`` aligned to ``mds``'s previous picture, logged as one Points2D per kind under ``root``."""
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
            "target": {"colors": [GT_COLOR], "radii": [-5.5], "labels": [f"target (frame {frame_index})"]},
        }
        for order, kind in enumerate(style):
            m = kinds == kind
            path = f"{root}/{kind}"
            if m.any():
                rec.log(path, rr.Points2D(X[m], draw_order=float(order), **style[kind]))
            else:
                rec.log(path, rr.Clear(recursive=False))
        # Two invisible points a margin outside the picture, so the view's automatic bounds leave
        # room for the labels of points on the edge.
        lo, hi = X.min(axis=0), X.max(axis=0)
        pad = 0.15 * (hi - lo).max() + 1e-6
        rec.log(f"{root}/margin", rr.Points2D([lo - pad, hi + pad], radii=[0.0], colors=[(0, 0, 0, 0)]))

    # ------------------------------------------------------------------ #
    def on_end(self, results) -> None:
        rec = self.stream
        try:
            lines = ["# Summary of the run", ""]
            interrupted = any(getattr(r, "interrupted", False) for r in results)
            if interrupted:
                lines += [
                    (
                        f"**The run was interrupted** after frame {self._last_frame}; "
                        "the recording holds every frame done until then."
                    ),
                    "",
                ]
            lines += [
                "| tracker | frames | fps | success AUC | P@20 | mean IoU | losses | drift began at | storms |",
                "|---|---|---|---|---|---|---|---|---|",
            ]
            for s, r in zip(self._states, results):
                if len(r.boxes) and not nothing_to_score(r.groundtruth):
                    m = evaluate(r.boxes, r.groundtruth)
                    auc, p20, miou = f"{m.success_auc:.3f}", f"{m.precision_20:.3f}", f"{m.mean_iou:.3f}"
                else:
                    auc = p20 = miou = "–"
                ev = s.events
                lines.append(
                    f"| {s.name} | {len(r.boxes)} | {r.fps:.1f} | {auc} | {p20} | {miou} | "
                    f"{', '.join(map(str, ev.losses)) or 'none'} | {', '.join(map(str, ev.drifts)) or '–'} | "
                    f"{len(ev.storms) + int(ev.storm)} |"
                )
            rec.log(
                P.SUMMARY,
                rr.TextDocument(viewer_safe("\n".join(lines) + "\n"), media_type=rr.MediaType.MARKDOWN),
                static=True,
            )
            if interrupted and self._last_frame >= 0:
                rec.set_time(P.FRAME_TIMELINE, sequence=self._last_frame)
                for s in self._states:
                    rec.log(s.paths.events, rr.TextLog("run interrupted after this frame", level="WARN"))
        except Exception as exc:  # noqa: BLE001 - never let the summary hide the run's own outcome
            log.warning("could not write the recording summary: %s", exc)
        finally:
            if self.close_on_end:
                self.close()

    def close(self) -> None:
        """Send everything logged so far and disconnect the stream (finalises an ``.rrd`` file).

        A live viewer that went away cannot take the rest: that is a warning, not an error
        (the file sink, if any, has everything). A file cut short (a full disk) raises
        :class:`~covviz.errors.WriteError` (see :func:`~covviz.viz.sinks.close_stream`).
        """
        close_stream(self.stream, timeout=FLUSH_TIMEOUT)
