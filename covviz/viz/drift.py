"""The label-free drift detector in the recording: a ``drift probability`` series per tracker and
its alarms in Events, with the signals that drove them.

:class:`DriftRecorder` is an observer that runs a :class:`~covviz.diagnosis.detector.DriftWatch` and logs
what it found on the recorder's stream; it is separate from :class:`covviz.viz.logger.RerunLogger` (it
runs before it, on the same background thread in ``covviz track``). The two series go out as columns
(:class:`~covviz.viz.series.SeriesBuffer`, every ``series_seconds``), the alarms as they come. Entity paths:

    trackers/<name>/drift/probability   Scalars: the drift probability, every frame
    trackers/<name>/drift/threshold     Scalars: the model's alarm threshold (every THRESHOLD_EVERY frames
                                        and the last: a flat line under the curve, in the IoU plot)
    trackers/<name>/events              TextLog: "drift alarm" rows (WARN)
    trackers/<name>/event_records       AnyValues: kind "alarm" (``covviz events`` reads them back)
    trackers/<name>/story/alarm         StateChange: "alarm" from an alarm's first frame, a null state on the
                                        first frame past its "until" (the last at or above the release level
                                        before its hysteresis released it; the story strip's alarm lane)
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import rerun as rr

from covviz.diagnosis.detector import describe_alarm
from covviz.records import frame_number
from covviz.runner import Observer
from covviz.viz import paths as P
from covviz.viz import story
from covviz.viz.description import viewer_safe
from covviz.viz.series import RECORDER_EVERY, RECORDER_SECONDS, SeriesBuffer

__all__ = ["DriftRecorder", "probability_path", "threshold_path"]

#: The threshold's line is drawn through a point every this many frames (and the last).
THRESHOLD_EVERY = 10


def probability_path(tracker: str) -> str:
    return f"{P.TrackerPaths(tracker).root}/drift/probability"


def threshold_path(tracker: str) -> str:
    return f"{P.TrackerPaths(tracker).root}/drift/threshold"


class DriftRecorder(Observer):
    """Observer after a :class:`~covviz.diagnosis.detector.DriftWatch`: its probability and alarms logged to ``stream``.

    ``series_seconds``: the probability and threshold series are sent every this many seconds
    (:class:`~covviz.viz.series.SeriesBuffer`; the rest at ``on_end``); alarms at once.
    """

    def __init__(self, stream: rr.RecordingStream, series_seconds: float | None = RECORDER_SECONDS) -> None:
        self.stream = stream
        self.series = SeriesBuffer(stream, every=RECORDER_EVERY, seconds=series_seconds)
        self._paths: list[P.TrackerPaths] = []
        self._thresholds: list[float | None] = []
        self._open: list[dict | None] = []  # per tracker, the alarm the story's alarm lane shows now
        self._gap: list[tuple | None] = []  # per tracker, the (index, time) of the open alarm's gap in the lane
        self._last = None

    def on_start(self, start, found) -> None:
        self._paths = [P.TrackerPaths(P.tracker_entity(info.name)) for info in start.trackers]
        view = found.drift
        self._thresholds = [None if view is None else view.threshold(j) for j in range(len(self._paths))]
        self._open = [None] * len(self._paths)
        self._gap = [None] * len(self._paths)
        for paths, th in zip(self._paths, self._thresholds):
            if th is not None:
                self.stream.log(threshold_path(paths.name), rr.SeriesLines(
                    names=["alarm threshold"], colors=[(150, 150, 150)], widths=[0.8]), static=True)

    def on_frame(self, frame, records, found) -> None:
        rec = self.stream
        self._last = frame
        n = frame_number(frame.index)
        self.series.at(n, frame.time)
        timed = False
        for j, (paths, th, (p, new)) in enumerate(zip(self._paths, self._thresholds, found.drift_news)):
            if p is None:
                continue
            self.series.add(probability_path(paths.name), p)
            if th is not None and frame.index % THRESHOLD_EVERY == 0:
                self.series.add(threshold_path(paths.name), th)
            # The watch extends an open alarm's "until" on every frame its probability is at or above the release
            # level, and releases it after its cooldown below. The lane's gap goes on the first frame past
            # "until"; if the alarm is extended again before its release, the gap is overwritten (the same
            # frame, logged later), so the lane spans the alarm's first frame to its "until" as the text does.
            cur = self._open[j]
            below = cur is not None and self._gap[j] is None and cur["until"] < n
            back = cur is not None and self._gap[j] is not None and cur["until"] >= frame_number(self._gap[j][0])
            if (new or below or back) and not timed:
                P.set_frame_time(rec, frame)  # this thread's own time, for the alarms' rows and lane
                timed = True
            if below:
                rec.log(paths.story_lane("alarm"), story.clear_state())
                self._gap[j] = (frame.index, frame.time)
            if back:
                index, time = self._gap[j]
                P.set_frame_time(rec, SimpleNamespace(index=index, time=time))
                rec.log(paths.story_lane("alarm"), rr.StateChange(state="alarm"))
                P.set_frame_time(rec, frame)
                self._gap[j] = None
            for a in new:
                # The row's frame column says where; the body leads with what (its width cuts the end off).
                text = f"drift alarm: {describe_alarm(a, span=False)} (label-free)"
                rec.log(paths.events, rr.TextLog(viewer_safe(f"[{paths.name}] {text}"),
                                                  level="WARN"))
                rec.log(paths.event_records, rr.AnyValues(
                    tracker=[paths.name], kind=["alarm"], frame_number=[a["frame"]], level=["WARN"],
                    text=[viewer_safe(text)], cause=["drift"], details=[json.dumps(a, default=float)]))
                rec.log(paths.story_lane("alarm"), rr.StateChange(state="alarm"))
                self._open[j], self._gap[j] = a, None

        self.series.tick()

    def on_end(self, results, found) -> None:
        frame = self._last
        if frame is not None and frame.index % THRESHOLD_EVERY != 0:
            self.series.at(frame_number(frame.index), frame.time)
            for paths, th in zip(self._paths, self._thresholds):
                if th is not None:
                    self.series.add(threshold_path(paths.name), th)
        self.series.flush()
