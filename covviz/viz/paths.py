"""Every entity path of a covviz recording, in one place.

The entity tree::

    description                      TextDocument (markdown): what each view shows, how to read drift
    config                           TextDocument: run, trackers, logger settings, thresholds
    summary                          TextDocument: metrics and events at the end of the run
    video/image                      EncodedImage (JPEG): the frame
    video/ground_truth               Boxes2D: the ground-truth box
    trackers/<name>/video/box        Boxes2D: the estimate as scored (axis-aligned)
    trackers/<name>/video/region     LineStrips2D: the estimated (rotated) region
    trackers/<name>/video/particles  LineStrips2D: the region of every particle with at least
                                     LoggerConfig.box_weight of the largest weight, coloured by weight
    trackers/<name>/video/particle_dots  Points2D: the centres of the lighter ones, coloured the same way
    trackers/<name>/video/top        LineStrips2D: the top-k particles, bold
    trackers/<name>/video/centres    Points2D: particle centres, sized by weight
    trackers/<name>/video/likelihood Image: the likelihood map around the estimate (placed by a Transform3D)
    trackers/<name>/video/likelihood_peak  LineStrips2D: a ring at the best position of that map
    trackers/<name>/video/likelihood_region  LineStrips2D: the region the map searched
    trackers/<name>/video/likelihood_bar(_labels)  Image + Points2D: its colour bar, above the region
    trackers/<name>/video/label      Points2D: the tracker's name by its box (several trackers)
    trackers/<name>/video/background LineStrips2D: regions sampled as background for the MDS picture
    trackers/<name>/video/replay/<fix> Boxes2D: a loss's counterfactual replay under each fix (faint)
    trackers/<name>/weights/...      Scalars: ess (ESS/N), max, survivors, loss_evidence (the adaptive diffusion's
                                     e), redetected (share drawn afresh); SeriesPoints: resampled,
                                     pull_held/<light|look> (a strip below 0: the observation pull held by
                                     that gate)
    trackers/<name>/distance/...     Scalars: min, mean (weighted), spread (template cloud)
    trackers/<name>/metrics/...      Scalars: iou, center_error; SeriesPoints: drift, lost, recovered;
                                     replay/<fix>: IoU of each counterfactual replay
    trackers/<name>/terms/share/<term>  Scalars: each likelihood term's share of d_eff² (weighted mean)
    trackers/<name>/terms/moved/<term>  Scalars: weight the term moved (total variation, with vs without it)
    trackers/<name>/why/<series>     Scalars: the diagnosis per frame: d at the truth and the estimate, reach,
                                     gap_<part> (each part of d_eff² at the truth minus at the estimate)
    trackers/<name>/why/label/<label>  SeriesPoints: model / search / estimate failure frames
    trackers/<name>/timings/<stage>  Scalars: milliseconds per stage of the update
    trackers/<name>/tensors          Tensor (3, 9, 9): template, observed, difference, log space
    trackers/<name>/cloud/<kind>     Points2D: MDS of the template cloud (template, top, estimate, initial,
                                     background, target)
    trackers/<name>/cloud_zoom/<kind> Points2D: the same without the background (the cloud's structure)
    trackers/<name>/events           TextLog: storms, loss, drift onset, recovery
    trackers/<name>/story/track      StateChange: the story strip's lane: on track / model / search /
                                     estimate failure / lost / no truth (StateConfiguration static)
    trackers/<name>/story/verdict    StateChange: each loss's counterfactual verdict, from the loss to the
                                     end of its replay
    trackers/<name>/story/alarm      StateChange: label-free drift alarms, each from its first frame to its release
    layout                           AnyValues (static): what the blueprint was built from (``snapshot --tracker``)
    logger/time                      Scalars: milliseconds the logger spent on the frame

Timelines: ``frame`` (0-based frame index) and, when the sequence has a frame
rate, ``time`` (seconds since the first frame).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from covviz.records import frame_number

__all__ = [
    "CONFIG",
    "DESCRIPTION",
    "FRAME_TIMELINE",
    "GROUND_TRUTH",
    "IMAGE",
    "LAYOUT",
    "LOGGER_TIME",
    "STORY_LANES",
    "SUMMARY",
    "TIME_TIMELINE",
    "TRACKERS",
    "VIDEO",
    "TrackerPaths",
    "set_frame_time",
]

FRAME_TIMELINE = "frame"
TIME_TIMELINE = "time"


def set_frame_time(stream, frame) -> None:
    """Put ``stream`` (this thread's time of it) at ``frame``: its 1-based number, and its seconds if it has them."""
    stream.set_time(FRAME_TIMELINE, sequence=frame_number(frame.index))
    if frame.time is not None:
        stream.set_time(TIME_TIMELINE, duration=float(frame.time))

DESCRIPTION = "description"
CONFIG = "config"
SUMMARY = "summary"
VIDEO = "video"
IMAGE = "video/image"
GROUND_TRUTH = "video/ground_truth"
TRACKERS = "trackers"
LOGGER_TIME = "logger/time"
#: The value of the observation pull's held-frame markers on the weights plot: a strip below its 0.
PULL_HELD_LEVEL = -0.04
#: The blueprint's inputs (tracker names, which have templates / particles, image size), static.
LAYOUT = "layout"
#: Lanes of the story strip, per tracker, in the order they are drawn.
STORY_LANES = ("track", "verdict", "alarm")

#: Entities of the MDS figures of ``covviz mds`` (see :mod:`covviz.viz.mds_figures`).
FIGURE_SEPARATION = "figures/separation"
FIGURE_RANDOM_WALK = "figures/random_walk"


def tracker_entity(name: str) -> str:
    """A tracker's name as an entity path part (and one the viewer's font draws): ``manifold@b`` -> ``manifold_b``."""
    return re.sub(r"[^A-Za-z0-9_.+-]", "_", str(name))


@dataclass(frozen=True)
class TrackerPaths:
    """The entity paths of one tracker, under ``trackers/<name>``."""

    name: str

    @property
    def root(self) -> str:
        return f"{TRACKERS}/{self.name}"

    # drawn on the frame
    @property
    def video(self) -> str:
        return f"{self.root}/video"

    @property
    def box(self) -> str:
        return f"{self.video}/box"

    @property
    def region(self) -> str:
        return f"{self.video}/region"

    @property
    def particles(self) -> str:
        return f"{self.video}/particles"

    @property
    def particle_dots(self) -> str:
        return f"{self.video}/particle_dots"

    @property
    def top(self) -> str:
        return f"{self.video}/top"

    @property
    def centres(self) -> str:
        return f"{self.video}/centres"

    @property
    def likelihood(self) -> str:
        return f"{self.video}/likelihood"

    @property
    def likelihood_peak(self) -> str:
        return f"{self.video}/likelihood_peak"

    @property
    def likelihood_region(self) -> str:
        """The outline of the region the likelihood map searched."""
        return f"{self.video}/likelihood_region"

    @property
    def likelihood_bar(self) -> str:
        """The map's colour bar, above the searched region (placed by a Transform3D) ..."""
        return f"{self.video}/likelihood_bar"

    @property
    def likelihood_bar_labels(self) -> str:
        """... and its end labels (``-R nats``, ``best``)."""
        return f"{self.video}/likelihood_bar_labels"

    @property
    def label(self) -> str:
        """The tracker's name beside its box (placed apart from the other trackers')."""
        return f"{self.video}/label"

    @property
    def background(self) -> str:
        return f"{self.video}/background"

    # time series
    @property
    def weights(self) -> str:
        return f"{self.root}/weights"

    @property
    def ess(self) -> str:
        return f"{self.weights}/ess"

    @property
    def max_weight(self) -> str:
        return f"{self.weights}/max"

    @property
    def survivors(self) -> str:
        return f"{self.weights}/survivors"

    @property
    def loss_evidence(self) -> str:
        return f"{self.weights}/loss_evidence"

    @property
    def redetected(self) -> str:
        return f"{self.weights}/redetected"

    def pull_held(self, reason: str) -> str:
        """SeriesPoints at :data:`PULL_HELD_LEVEL` on the frames the observation pull was held by ``reason``
        (``light``, ``look``)."""
        return f"{self.weights}/pull_held/{reason}"

    @property
    def resampled(self) -> str:
        return f"{self.weights}/resampled"

    @property
    def distance(self) -> str:
        return f"{self.root}/distance"

    @property
    def distance_min(self) -> str:
        return f"{self.distance}/min"

    @property
    def distance_mean(self) -> str:
        return f"{self.distance}/mean"

    @property
    def spread(self) -> str:
        return f"{self.distance}/spread"

    @property
    def metrics(self) -> str:
        return f"{self.root}/metrics"

    @property
    def iou(self) -> str:
        return f"{self.metrics}/iou"

    @property
    def center_error(self) -> str:
        return f"{self.metrics}/center_error"

    def marker(self, kind: str) -> str:
        """Event markers on the IoU plot: ``drift``, ``lost``, ``recovered``."""
        return f"{self.metrics}/{kind}"

    @property
    def timings(self) -> str:
        return f"{self.root}/timings"

    def timing(self, stage: str) -> str:
        return f"{self.timings}/{stage}"

    # tensors, cloud, events
    @property
    def tensors(self) -> str:
        return f"{self.root}/tensors"

    @property
    def cloud(self) -> str:
        return f"{self.root}/cloud"

    def cloud_kind(self, kind: str) -> str:
        return f"{self.cloud}/{kind}"

    @property
    def cloud_zoom(self) -> str:
        return f"{self.root}/cloud_zoom"

    @property
    def events(self) -> str:
        return f"{self.root}/events"

    @property
    def story(self) -> str:
        """The tracker's lanes of the story strip (a StateTimelineView)."""
        return f"{self.root}/story"

    def story_lane(self, lane: str) -> str:
        """One lane: ``track`` (on track / failure kind / lost), ``verdict``, ``alarm``."""
        return f"{self.story}/{lane}"

    def replay_box(self, kind: str) -> str:
        """A counterfactual replay's boxes (``none``, ``search``, ``model``, ``estimate``, ``search+model``,
        ``restart``) on the frames of its window; ``trackers/<name>/video/replay`` toggles them all."""
        return f"{self.video}/replay/{kind.replace('+', '_')}"

    def replay_iou(self, kind: str) -> str:
        """IoU with the truth of a replay's boxes, frame by frame (on the IoU plot)."""
        return f"{self.metrics}/replay/{kind.replace('+', '_')}"

    @property
    def event_records(self) -> str:
        """One row per event, its fields as values (``covviz events`` reads them back)."""
        return f"{self.root}/event_records"

    # why it drifts (covviz.diagnosis.drift)
    @property
    def why(self) -> str:
        return f"{self.root}/why"

    def why_series(self, name: str) -> str:
        """A per-frame series of the diagnosis (``d_truth``, ``best_est``, ``reach`` ...)."""
        return f"{self.why}/{name}"

    def why_label(self, label: str) -> str:
        """Markers of the frames labelled ``model`` / ``search`` / ``estimate``."""
        return f"{self.why}/label/{label}"

    @property
    def zoom(self) -> str:
        """The warped patches at the estimate, the truth and the initial box, side by side."""
        return f"{self.root}/zoom"

    @property
    def slices(self) -> str:
        """The likelihood along scale and rotation at the estimate's and the truth's centres."""
        return f"{self.root}/slices"

    @property
    def heatmap(self) -> str:
        """The estimate's template, its observation and their difference as labelled 9x9 heatmaps."""
        return f"{self.root}/heatmap"

    @property
    def terms(self) -> str:
        """Series of the likelihood's terms: each one's share of ``d_eff²`` and the weight it moved."""
        return f"{self.root}/terms"

    def term_share(self, name: str) -> str:
        """``Σ w_i c_i / Σ w_i d_eff,i²`` of one term ``c`` (``descriptor`` = ``d²``): its share of what was weighed."""
        return f"{self.terms}/share/{name}"

    def term_moved(self, name: str) -> str:
        """Total-variation distance between the weights and the weights without that term, in [0, 1]."""
        return f"{self.terms}/moved/{name}"

    @property
    def cloud_health(self) -> str:
        """Series of the template cloud: the target's gap to it, the background's margin, MDS stress."""
        return f"{self.root}/cloud_health"
