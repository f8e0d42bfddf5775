"""The label-free drift detector in the recording: a ``drift probability`` series per tracker and
its alarms in Events, with the signals that drove them.

:class:`DriftRecorder` is an observer that runs a :class:`~covviz.diagnosis.detector.DriftWatch` and logs
what it found on the recorder's stream; it is separate from :class:`covviz.viz.logger.RerunLogger` so that
the detector's cost stays on its own thread. Entity paths:

    trackers/<name>/drift/probability   Scalars: the drift probability, every frame
    trackers/<name>/events              TextLog: "drift alarm" rows (WARN)
    trackers/<name>/event_records       AnyValues: kind "alarm" (``covviz events`` reads them back)
"""

from __future__ import annotations

import json

import rerun as rr

from covviz.diagnosis.detector import describe_alarm
from covviz.records import frame_number
from covviz.runner import Observer
from covviz.viz import paths as P
from covviz.viz.description import viewer_safe

__all__ = ["DriftRecorder", "probability_path"]


def probability_path(tracker: str) -> str:
    return f"{P.TrackerPaths(tracker).root}/drift/probability"


class DriftRecorder(Observer):
    """Observer after a :class:`~covviz.diagnosis.detector.DriftWatch`: its probability and alarms logged to ``stream``."""

    def __init__(self, stream: rr.RecordingStream) -> None:
        self.stream = stream
        self._paths: list[P.TrackerPaths] = []

    def on_start(self, start, found) -> None:
        self._paths = [P.TrackerPaths(P.tracker_entity(info.name)) for info in start.trackers]

    def on_frame(self, frame, records, found) -> None:
        rec = self.stream
        rec.set_time(P.FRAME_TIMELINE, sequence=frame_number(frame.index))  # this thread's own time
        if frame.time is not None:
            rec.set_time(P.TIME_TIMELINE, duration=float(frame.time))
        for paths, (p, new) in zip(self._paths, found.drift_news):
            if p is None:
                continue
            rec.log(probability_path(paths.name), rr.Scalars(p))
            for a in new:
                text = f"drift alarm: {describe_alarm(a)} (label-free; drivers {', '.join(a['drivers']) or '-'})"
                rec.log(paths.events, rr.TextLog(viewer_safe(f"[{paths.name}] {text}"),
                                                  level="WARN"))
                rec.log(paths.event_records, rr.AnyValues(
                    tracker=[paths.name], kind=["alarm"], frame_number=[a["frame"]], level=["WARN"],
                    text=[viewer_safe(text)], cause=["drift"], details=[json.dumps(a, default=float)]))


