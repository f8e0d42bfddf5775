"""The story strip (a state timeline, one set of lanes per tracker) and the Events rows' headlines.

The strip reads the whole run at a glance: per tracker a ``track`` lane (on
track, or which part of the filter failed on the frame — model, search,
estimate — or lost), a ``verdict`` lane (each loss's counterfactual verdict,
from the loss to the end of its replay) and an ``alarm`` lane (label-free
drift alarms, from each alarm's first frame to the frame its hysteresis releases it; drawn by
:class:`covviz.viz.drift.DriftRecorder`, empty in a recording without the detector). Each lane is one
entity (:meth:`covviz.viz.paths.TrackerPaths.story_lane`) with a static
``StateConfiguration`` (labels, colours) and a ``StateChange`` on every frame
where its state changes; Rerun's ``StateTimelineView`` draws them as coloured
bands and a click moves the time cursor there.

An Events row leads with its kind, frame and cause in at most
:data:`HEADLINE_CHARS` characters (``LOST 84 · OCCLUSION · drift began 70``),
which the default 1600×900 layout shows whole; the full text follows on the
lines below, shown when the row is expanded (or hovered).
"""

from __future__ import annotations

import math

import rerun as rr

from covviz.viz import paths as P

__all__ = [
    "HEADLINE_CHARS",
    "TRACK_STATES",
    "VERDICT_STATES",
    "clear_state",
    "headline",
    "log_story_static",
    "row",
    "track_state",
]

#: The longest first line of an Events row.
HEADLINE_CHARS = 80

#: The track lane: state value -> (label, RGBA).
TRACK_STATES = {
    "ok": ("on track", 0x3FA34DFF),
    "model": ("model failure", 0xE53935FF),
    "search": ("search failure", 0x1E88E5FF),
    "estimate": ("estimate failure", 0xFFB300FF),
    "off": ("off track", 0xEF6C00FF),
    "lost": ("LOST", 0x8E24AAFF),
    "none": ("no ground truth", 0x616161FF),
}
#: The verdict lane: the smallest fix that keeps the track (covviz.diagnosis.counterfactual.FIXES).
VERDICT_STATES = {
    "estimate": ("verdict ESTIMATE", 0xFFB300FF),
    "search": ("verdict SEARCH", 0x1E88E5FF),
    "model": ("verdict MODEL", 0xE53935FF),
    "search+model": ("verdict SEARCH+MODEL", 0xD81B60FF),
    "restart": ("verdict RESTART", 0x00ACC1FF),
    "none helps": ("verdict: no fix helps", 0x9E9E9EFF),
}
#: The alarm lane (label-free drift alarms).
ALARM_STATES = {"alarm": ("drift alarm", 0xFF6F00FF)}


def _config(states: dict) -> rr.StateConfiguration:
    return rr.StateConfiguration(
        values=list(states), labels=[v[0] for v in states.values()], colors=[v[1] for v in states.values()]
    )


def log_story_static(rec: rr.RecordingStream, p: P.TrackerPaths) -> None:
    """The three lanes' labels and colours (static), so each lane exists from the start, even if empty."""
    rec.log(p.story_lane("track"), _config(TRACK_STATES), static=True)
    rec.log(p.story_lane("verdict"), _config(VERDICT_STATES), static=True)
    rec.log(p.story_lane("alarm"), _config(ALARM_STATES), static=True)


def track_state(label: str, lost: bool, iou: float = float("nan"), on_track_iou: float = 0.5) -> str:
    """The track lane's state of a frame: ``lost`` while lost, else the diagnosis's label.

    A tracker without a covariance model has no failure label: its frames are ``ok`` or ``off`` by the IoU;
    ``none`` without ground truth.
    """
    if lost:
        return "lost"
    if label in TRACK_STATES:
        return label
    if not math.isnan(iou):
        return "ok" if iou >= on_track_iou else "off"
    return "none"


def clear_state() -> rr.StateChange:
    """A null state: a gap in the lane."""
    return rr.StateChange.from_fields(clear_unset=True)


def headline(*parts: str) -> str:
    """``KIND frame · cause · …`` joined, cut at :data:`HEADLINE_CHARS` on a part boundary."""
    out = ""
    for part in (str(q) for q in parts if q):
        nxt = part if not out else f"{out} · {part}"
        if len(nxt) > HEADLINE_CHARS:
            break
        out = nxt
    return out[:HEADLINE_CHARS]


def row(head: str, body: str) -> str:
    """An Events row: the headline, then the full text on the next line (shown on expansion)."""
    return f"{head}\n{body}" if body else head
