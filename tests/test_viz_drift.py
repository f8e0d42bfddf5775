"""The drift detector in the recording and in the results of ``covviz track`` (issue 21)."""

from __future__ import annotations

import json

import numpy as np

from covviz.cli import main
from covviz.diagnosis.detector import DriftModel, Hysteresis, feature_names
from covviz.diagnosis.signals import SIGNALS


def test_track_logs_the_drift_probability_and_alarm_rows(tmp_path, capsys):
    k = len(feature_names(SIGNALS))
    # A model whose probability is 0.5 on every frame and whose threshold is 0.4: one alarm, on frame 1.
    m = DriftModel("manifold", SIGNALS, np.zeros(k), np.ones(k), np.zeros(k), 0.0, Hysteresis(0.4, 0.3, 3))
    det = m.save(tmp_path / "det.json")
    rrd = tmp_path / "run.rrd"
    code = main(["track", "--max-frames", "12", "--particles", "100", "--no-progress", "--detector", str(det),
                 "--save", str(rrd), "--out", str(tmp_path / "runs")])
    assert code == 0
    doc = json.loads(next((tmp_path / "runs").glob("*/manifold_s0.json")).read_text())
    dg = doc["diagnosis"]
    assert dg["drift_probability"] == [0.5] * 12
    assert [a["frame"] for a in dg["alarms"]] == [1]
    assert set(dg["alarms"][0]["signals"]) == set(SIGNALS)
    assert len(dg["signals"]["fb_error"]) == 12
    assert "1 label-free drift alarm(s) (first at frame 1)" in capsys.readouterr().out
    assert main(["events", str(rrd), "--json", "--kind", "alarm"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["frame"] for r in rows] == [1]
    assert "likely off track, p 0.50" in rows[0]["text"]
    # The probability on every frame, and the alarm threshold as a flat line under it (frames 1, 11 and the last).
    from viz_helpers import read_recording

    from covviz.viz.drift import probability_path, threshold_path

    temporal, static = read_recording(rrd)
    prob = temporal[probability_path("manifold")]["Scalars:scalars"]
    assert sorted(prob) == list(range(1, 13)) and all(v[-1] == [0.5] for v in prob.values())
    th = temporal[threshold_path("manifold")]["Scalars:scalars"]
    assert {f: v[-1] for f, v in th.items()} == {1: [0.4], 11: [0.4], 12: [0.4]}
    assert static[threshold_path("manifold")]["SeriesLines:names"] == ["alarm threshold"]
