"""The story strip, the Events rows' headlines, per-tracker panels and ``snapshot --tracker`` (issue 22).

What the recording holds is tested (read back with ``rerun.chunk.RrdReader``), not how the
viewer draws it: ``StateTimelineView`` is marked unstable in Rerun 0.41.
"""

from __future__ import annotations

import contextlib
import io
import itertools
from dataclasses import replace

import numpy as np
import pytest
from viz_helpers import read_recording

from covviz import cli
from covviz.data.sequences import SyntheticConfig, SyntheticSequence
from covviz.diagnosis.counterfactual import Outcome, Replay
from covviz.diagnosis.drift import Diagnoser
from covviz.runner import Observer, Pipeline, run_many
from covviz.trackers.base import IdentityTracker
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
from covviz.viz import paths as P
from covviz.viz import story
from covviz.viz.blueprint import build_blueprint, layout_blueprint
from covviz.viz.logger import LoggerConfig, RerunLogger
from covviz.viz.readback import read_layout
from covviz.viz.sinks import attach_sinks, new_recording

N_FRAMES = 40


def run_main(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    return code, out.getvalue(), err.getvalue()


class FakeReplays(Observer):
    """Stands in for the counterfactual replays: a verdict for every loss of the diagnosis, at the end."""

    def on_end(self, results, found):
        out = []
        for j, _ in enumerate(results):
            rep = {}
            for d in found.diagnosis.report(j)["diagnoses"]:
                boxes = np.zeros((3, 4))
                outcomes = {"none": Outcome(False, 0.0, 0, boxes, True), "search": Outcome(True, 0.8, 3, boxes)}
                rep[d["lost_at"]] = Replay(d["lost_at"], d["drift_began"], d["lost_at"] - 2, d["lost_at"] + 2, 2,
                                           outcomes, "search", ("search",), d["drift_began"])
            out.append(rep)
        return replace(found, counterfactual=tuple(out))


@pytest.fixture(scope="module")
def two(tmp_path_factory):
    """A recording of two trackers: the manifold tracker and the identity tracker (which loses the target)."""
    path = tmp_path_factory.mktemp("story") / "two.rrd"
    seq = SyntheticSequence(SyntheticConfig(n_frames=N_FRAMES))
    stream = new_recording()
    attach_sinks(stream, save=path)
    cfg = LoggerConfig(mds_every=10, seed=0)
    trackers = [ManifoldTracker(ManifoldConfig(n_particles=40), rng=1), IdentityTracker()]
    run_many(trackers, seq, [Pipeline([Diagnoser(cfg.diagnosis), FakeReplays(), RerunLogger(stream, cfg)])])
    temporal, static = read_recording(path)
    return {"path": path, "temporal": temporal, "static": static}


def test_the_recording_holds_the_state_lanes(two):
    t, s = two["temporal"], two["static"]
    for name in ("manifold", "identity"):
        p = P.TrackerPaths(name)
        # Every lane exists with its labels and colours, the alarm lane too (empty: no alarms given).
        for lane, states in (("track", story.TRACK_STATES), ("verdict", story.VERDICT_STATES),
                             ("alarm", story.ALARM_STATES)):
            cfg = s[p.story_lane(lane)]
            assert cfg["StateConfiguration:values"] == list(states)
            assert cfg["StateConfiguration:labels"] == [v[0] for v in states.values()]
        assert p.story_lane("alarm") not in t
        # The track lane: a state on the first frame, then only on the frames where it changes.
        changes = {f: v[-1] for f, v in t[p.story_lane("track")]["StateChange:state"].items()}
        frames = sorted(changes)
        assert frames[0] == 1 and changes[1] == ["ok"]
        assert all(changes[a] != changes[b] for a, b in itertools.pairwise(frames))
        assert {v[0] for v in changes.values()} <= set(story.TRACK_STATES)
    # The identity tracker stays where it started while the target moves: off track, then lost.
    ident = {v[-1][0] for v in t[P.TrackerPaths("identity").story_lane("track")]["StateChange:state"].values()}
    assert "lost" in ident


def test_the_verdict_lane_holds_each_loss_verdict_until_its_replay_ends(two):
    t = two["temporal"]
    p = P.TrackerPaths("identity")
    lost = [f for f, v in t[p.story_lane("track")]["StateChange:state"].items() if v[-1] == ["lost"]]
    verdict = {f: v[-1] for f, v in t[p.story_lane("verdict")]["StateChange:state"].items()}
    assert verdict[lost[0]] == ["search"]
    assert verdict[lost[0] + 3] == []  # a null state after the replay's last frame: a gap in the lane
    rows = [r[0] for v in t[p.events]["TextLog:text"].values() for r in v if " · verdict " in r[0].split("\n")[0]]
    assert rows and rows[0].split("\n")[0].startswith(f"[identity] LOST {lost[0]} · ")
    assert "verdict SEARCH" in rows[0].split("\n")[0]


def test_events_rows_lead_with_kind_and_frame_in_80_characters(two):
    t = two["temporal"]
    rows = [r[0] if isinstance(r, list) else r for name in ("manifold", "identity")
            for v in t[P.TrackerPaths(name).events].get("TextLog:text", {}).values() for r in v]
    rows = [r for r in rows if not r.startswith("not logged")]
    assert rows, "the identity tracker's loss gives events"
    for r in rows:
        head, _, body = r.partition("\n")
        assert len(head) <= story.HEADLINE_CHARS, head
        assert head.startswith("[") and head.split("] ")[1].split(" ")[0] in {"LOST", "DRIFT", "RECOVERED", "STORM",
                                                                              "storm", "SUSPECT"}, head
        assert body, "the full text follows the headline"
    lost = [r for r in rows if r.startswith("[identity] LOST")]
    assert lost and lost[0].split("\n")[0].split(" · ")[1].isupper()  # its cause, e.g. LOST 23 · FAST MOTION


def test_headline_cuts_on_a_part_boundary():
    h = story.headline("LOST 84", "OCCLUSION", "verdict MODEL", "x" * 90)
    assert h == "LOST 84 · OCCLUSION · verdict MODEL"
    assert len(story.headline(*(["abcdefghij"] * 20))) <= story.HEADLINE_CHARS


def _find(container, pred):
    out = []
    if pred(container):
        out.append(container)
    for c in getattr(container, "contents", None) or []:
        if hasattr(c, "kind") or hasattr(c, "origin"):
            out += _find(c, pred)
    return out


def test_every_tracker_has_its_own_panels_in_the_blueprint():
    names = ["manifold", "manifold-paper"]
    bp = build_blueprint(names, names, names, image_size=(320, 240), focus="manifold-paper")
    tabs = _find(bp.root_container, lambda c: type(c).__name__ == "Tabs"
                 and [getattr(x, "name", None) for x in c.contents] == names)
    assert len(tabs) == 1 and tabs[0].active_tab == 1  # focus: the second tracker's panels open
    for name, panel in zip(names, tabs[0].contents):
        p = P.TrackerPaths(name)
        origins = {str(v.origin) for v in _find(panel, lambda c: hasattr(c, "origin"))}
        assert {f"/{p.zoom}", f"/{p.slices}", f"/{p.cloud_zoom}", f"/{p.cloud}", f"/{p.heatmap}"} <= origins
        terms = _find(panel, lambda c: str(getattr(c, "name", "")).startswith("Likelihood terms"))
        assert len(terms) == 1
    strip = _find(bp.root_container, lambda c: type(c).__name__ == "StateTimelineView")
    assert len(strip) == 1
    assert build_blueprint(names, names, names).root_container is not None  # default focus: the first


def test_the_layout_in_a_two_tracker_recording(two):
    layout = read_layout(two["path"])
    assert layout["trackers"] == ["manifold", "identity"]
    assert layout["with_cloud"] == ["manifold"] and layout["image_size"] == [320, 240]
    assert layout_blueprint(layout, focus="identity") is not None


def test_snapshot_tracker_must_be_one_of_the_recording(two, capsys):
    code, _, err = run_main(["snapshot", str(two["path"]), "--tracker", "ipca", "--out",
                               str(two["path"].with_suffix(".png"))])
    assert code == 2 and "--tracker ipca: the recording's trackers are manifold, identity" in err
    assert not two["path"].with_suffix(".png").exists()


def test_snapshot_focus_opens_the_trackers_tab_and_its_likelihood_map():
    """``snapshot --tracker`` edits the viewer's blueprint: the tracker's tab active, its map alone shown."""
    from covviz.viz.snapshot import _apply_focus

    ov = "/view/frame/ViewContents/overrides/trackers/{}/video/particles/visualizers"
    bp = {
        "/container/a": {"ContainerBlueprint": {"container_kind": "Vertical", "display_name": "manifold"}},
        "/container/b": {"ContainerBlueprint": {"container_kind": "Vertical", "display_name": "manifold-paper"}},
        "/container/t": {"ContainerBlueprint": {"container_kind": "Tabs", "contents": ["/container/a", "/container/b"],
                                                "active_tab": "/container/a"}},
        ov.format("manifold"): {"EntityBehavior": {"visible": False}},
    }

    class Client:
        def get_blueprint(self):
            return type("B", (), {"blueprint": bp})()

        def set_blueprint(self, d, of=None):
            self.sent, self.of = d, of

    c = Client()
    _apply_focus(c, {"with_cloud": ["manifold", "manifold-paper"]}, "manifold-paper")
    assert c.of == "recording"
    assert c.sent["/container/t"]["ContainerBlueprint"]["active_tab"] == "/container/b"
    vis = "/view/frame/ViewContents/overrides/trackers/{}/video/likelihood/visualizers"
    assert c.sent[vis.format("manifold-paper")] == {"EntityBehavior": {"visible": True}}
    assert c.sent[vis.format("manifold")] == {"EntityBehavior": {"visible": False}}
