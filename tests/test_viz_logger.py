"""Tests for :mod:`covviz.viz.logger`: a saved recording read back equals the FrameRecords it came from."""

from __future__ import annotations

import numpy as np
import pytest
import rerun as rr
from viz_helpers import boxes, last, read_recording, rrd_verify, scalar_series, static_text, texts

from covviz.data.sequences import SyntheticConfig, SyntheticSequence
from covviz.diagnosis.drift import Diagnoser
from covviz.metrics import center_error, iou
from covviz.records import FrameRecord
from covviz.runner import Observer, Pipeline, run_many
from covviz.trackers.base import IdentityTracker
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
from covviz.viz import paths as P
from covviz.viz.logger import LoggerConfig, RerunLogger, term_shares
from covviz.viz.palette import LUT, weight_levels
from covviz.viz.sinks import attach_sinks, new_recording

N_FRAMES = 12
N_PARTICLES = 50
MDS_EVERY = 4


class Collector(Observer):
    """Keeps every FrameRecord handed to observers."""

    def __init__(self):
        self.records: list[list[FrameRecord]] = []
        self.frames = []

    def on_frame(self, frame, records, found):
        self.records.append(list(records))
        self.frames.append(frame)


def record_run(path, trackers, n_frames=N_FRAMES, config=None, fail_at=None):
    seq = SyntheticSequence(SyntheticConfig(n_frames=n_frames))
    stream = new_recording()
    attach_sinks(stream, save=path)
    cfg = config or LoggerConfig(mds_every=MDS_EVERY, seed=0)
    logger = RerunLogger(stream, cfg)
    col = Collector()
    run_many(trackers, seq, [col, Pipeline([Diagnoser(cfg.diagnosis), logger])])
    return seq, col, logger


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "run.rrd"
    trackers = [ManifoldTracker(ManifoldConfig(n_particles=N_PARTICLES), rng=3), IdentityTracker()]
    seq, col, logger = record_run(path, trackers)
    temporal, static = read_recording(path)
    return {"path": path, "seq": seq, "col": col, "temporal": temporal, "static": static, "logger": logger}


def test_recording_verifies(run):
    res = rrd_verify(run["path"])
    assert res.returncode == 0, res.stderr


def test_entity_paths(run):
    from rerun.chunk import RrdReader

    paths = {p.lstrip("/") for p in RrdReader(str(run["path"])).store().schema().entity_paths()}
    m, i = P.TrackerPaths("manifold"), P.TrackerPaths("identity")
    expected = {
        P.IMAGE,
        P.GROUND_TRUTH,
        P.DESCRIPTION,
        P.CONFIG,
        P.SUMMARY,
        P.LOGGER_TIME,
        m.box,
        m.region,
        m.particles,
        m.top,
        m.centres,
        m.likelihood,
        m.likelihood_peak,
        m.background,
        m.ess,
        m.max_weight,
        m.survivors,
        m.distance_min,
        m.distance_mean,
        m.spread,
        m.iou,
        m.center_error,
        f"{m.heatmap}/image",
        f"{m.heatmap}/axes",
        f"{m.zoom}/patches",
        f"{m.slices}/estimate",
        f"{m.slices}/truth",
        m.why_series("best_truth"),
        m.why_series("best_est"),
        m.why_series("d_truth"),
        m.why_series("reach"),
        *(m.why_series(f"gap_{k}") for k in ("descriptor", "quadrants", "colour")),
        m.term_share("descriptor"),
        m.term_moved("colour"),
        f"{m.cloud_health}/gap",
        f"{m.cloud_health}/stress",
        m.timing("total"),
        m.timing("warp"),
        m.cloud_kind("top"),
        m.cloud_kind("template"),
        m.cloud_kind("target"),
        m.cloud_kind("background"),
        m.cloud_kind("initial"),
        m.cloud_kind("estimate"),
        f"{m.cloud_zoom}/target",
        f"{m.cloud_zoom}/top",
        i.box,
        i.iou,
        i.center_error,
    }
    assert expected <= paths, sorted(expected - paths)
    assert not any(p.startswith(i.particles) for p in paths)  # the identity tracker has no particles


def test_every_frame_is_on_the_frame_timeline(run):
    t = run["temporal"]
    frames = set(range(1, N_FRAMES + 1))  # frame numbers, 1-based: frame 1 is the first image
    assert set(t[P.IMAGE]["EncodedImage:blob"]) == frames
    assert set(boxes(t, P.TrackerPaths("identity").box)) == frames
    # Particles exist from frame 2 (frame 1 is the initialisation).
    assert set(t[P.TrackerPaths("manifold").particles]["LineStrips2D:strips"]) == frames - {1}



def test_time_timeline_is_seconds_at_the_frame_rate(run):
    """Every logged frame also sits on the `time` timeline, at frame / frame_rate seconds."""
    import pyarrow as pa
    from rerun.chunk import RrdReader

    fps = run["seq"].frame_rate
    pairs = {}
    for ch in RrdReader(str(run["path"])).stream():
        if ch.entity_path.lstrip("/") != P.IMAGE or ch.is_static:
            continue
        rb = ch.to_record_batch()
        ns = rb.column(P.TIME_TIMELINE).cast(pa.int64()).to_pylist()  # durations, nanoseconds
        pairs.update(zip(rb.column(P.FRAME_TIMELINE).to_pylist(), ns))
    assert set(pairs) == set(range(1, N_FRAMES + 1))  # frame numbers are 1-based, as users see them
    for f, t in pairs.items():
        assert t == pytest.approx((f - 1) / fps * 1e9, abs=1.0), f


def test_boxes_equal_the_records(run):
    t = run["temporal"]
    for j, name in enumerate(["manifold", "identity"]):
        logged = boxes(t, P.TrackerPaths(name).box)
        for f, recs in enumerate(run["col"].records):
            np.testing.assert_allclose(logged[f + 1], recs[j].box, rtol=1e-5, atol=1e-4)
    gt = boxes(t, P.GROUND_TRUTH)
    for f, frame in enumerate(run["col"].frames):
        np.testing.assert_allclose(gt[f + 1], frame.gt, rtol=1e-5, atol=1e-4)


def test_particles_and_weights_equal_the_records(run):
    t, q = run["temporal"], LoggerConfig().particle_precision
    p = P.TrackerPaths("manifold")
    strips = last(t, p.particles, "LineStrips2D:strips")
    colors = last(t, p.particles, "LineStrips2D:colors")
    top_w = last(t, p.top, "weight")
    top_i = last(t, p.top, "particle")
    top_strips = last(t, p.top, "LineStrips2D:strips")
    top_d, top_dl = last(t, p.top, "distance"), last(t, p.top, "likelihood_distance")
    top_q = [last(t, p.top, f"quadrant_distance_{j}") for j in range(4)]
    dots = last(t, p.particle_dots, "Points2D:positions")
    dot_colors = last(t, p.particle_dots, "Points2D:colors")
    packed = lambda rgba: rgba.astype(np.uint32) @ np.array([1 << 24, 1 << 16, 1 << 8, 1])
    for i in range(1, N_FRAMES):
        rec, f = run["col"].records[i][0], i + 1  # index, frame number
        w = rec.weights
        level = weight_levels(w)
        order = np.argsort(level, kind="stable")
        # Every particle is drawn once: its region if it has box_weight of the largest weight, else a dot.
        heavy = (w / w.max())[order] >= LoggerConfig().box_weight
        boxed, dotted = order[heavy], order[~heavy]
        assert len(boxed) + len(dotted) == N_PARTICLES and len(boxed) >= 1
        expected = np.concatenate([rec.particle_corners, rec.particle_corners[:, :1]], axis=1)[boxed]
        got = np.array(strips[f], dtype=np.float64)
        assert got.shape == (len(boxed), 5, 2)
        np.testing.assert_allclose(got, expected, atol=q / 2 + 1e-4)
        np.testing.assert_array_equal(np.array(colors[f], dtype=np.uint32), packed(LUT[level[boxed]]))
        got_dots = np.array(dots[f], dtype=np.float64).reshape(-1, 2)
        np.testing.assert_allclose(got_dots, rec.particle_corners[dotted].mean(axis=1), atol=q / 2 + 1e-4)
        np.testing.assert_array_equal(np.array(dot_colors[f], dtype=np.uint32), packed(LUT[level[dotted]]))
        # The top-k: the highest weights, exactly, with their particle indices and corners.
        k = LoggerConfig().top_k
        idx = np.argsort(-w, kind="stable")[:k]
        np.testing.assert_allclose(top_w[f], w[idx], rtol=1e-12)
        np.testing.assert_array_equal(top_i[f], idx)
        np.testing.assert_allclose(np.array(top_strips[f])[:, :4], rec.particle_corners[idx], rtol=1e-6)
        # What each top particle was weighed by: the template distance, the likelihood's
        # distance (with the quadrant term) and the four quadrant distances.
        np.testing.assert_allclose(top_d[f], rec.distances[idx], rtol=1e-12)
        np.testing.assert_allclose(top_dl[f], rec.likelihood.distances[idx], rtol=1e-12)
        for j in range(4):
            np.testing.assert_allclose(top_q[j][f], rec.likelihood.quadrant_distances[idx, j], rtol=1e-12)


def test_scalars_equal_the_records(run):
    t = run["temporal"]
    p = P.TrackerPaths("manifold")
    ess, wmax = scalar_series(t, p.ess), scalar_series(t, p.max_weight)
    dmin, dmean = scalar_series(t, p.distance_min), scalar_series(t, p.distance_mean)
    total = scalar_series(t, p.timing("total"))
    ious, ces = scalar_series(t, p.iou), scalar_series(t, p.center_error)
    spread = scalar_series(t, p.spread)
    evidence, redetected = scalar_series(t, p.loss_evidence), scalar_series(t, p.redetected)
    every = LoggerConfig().spread_every  # every k-th frame that has templates (index >= 1)
    assert set(spread) == {i + 1 for i in range(1, N_FRAMES) if i % every == 0}
    for i in range(N_FRAMES):
        rec, frame, f = run["col"].records[i][0], run["col"].frames[i], i + 1
        assert ious[f] == pytest.approx(float(iou(rec.box[None], frame.gt[None])[0]))
        assert ces[f] == pytest.approx(float(center_error(rec.box[None], frame.gt[None])[0]))
        assert total[f] == pytest.approx(rec.timings["total"] * 1e3)
        if i == 0:
            assert f not in ess
            continue
        w = rec.weights
        assert ess[f] == pytest.approx(rec.ess / N_PARTICLES)
        assert wmax[f] == pytest.approx(w.max())
        assert dmin[f] == pytest.approx(rec.distances.min())
        assert dmean[f] == pytest.approx(float(np.dot(w, rec.distances)))
        assert evidence[f] == rec.diffusion.evidence
        assert redetected[f] == pytest.approx(rec.diffusion.redetected / N_PARTICLES)


def test_pull_held_markers_are_the_records_held_frames(tmp_path):
    """A marker below 0 on each frame the observation pull was held by that gate, and on no other."""
    # The synthetic default with its light dip moved to frame 14 (after the pull's 10 warm-up frames).
    seq = SyntheticSequence(SyntheticConfig(n_frames=26, fast_start=0, fast_end=0, illum_start=14, illum_end=40,
                                            occl_start=0, occl_end=0))
    path = tmp_path / "pull.rrd"
    stream = new_recording()
    attach_sinks(stream, save=path)
    logger = RerunLogger(stream, LoggerConfig(mds_every=0, seed=0))
    col = Collector()
    run_many([ManifoldTracker(ManifoldConfig(n_particles=30), rng=3)], seq,
             [col, Pipeline([Diagnoser(logger.config.diagnosis), logger])])
    t, _ = read_recording(path)
    p = P.TrackerPaths("manifold")
    recs = [r[0] for r in col.records]
    assert all(r.pull is not None for r in recs[1:])  # the pull is on by default
    light = {i + 1 for i, r in enumerate(recs) if r.pull is not None and "light" in r.pull.held.split("+")}
    assert light and min(light) > 14  # the dip holds it, and nothing before the dip does
    for reason in ("light", "look"):
        marks = scalar_series(t, p.pull_held(reason))
        held = {i + 1 for i, r in enumerate(recs) if r.pull is not None and reason in r.pull.held.split("+")}
        assert set(marks) == held and all(v == P.PULL_HELD_LEVEL for v in marks.values())


def test_likelihood_terms_equal_the_records(run):
    """Each term of d_eff²: its weighted value on every top particle, its share and the weight it moved."""
    t = run["temporal"]
    p = P.TrackerPaths("manifold")
    sigma = ManifoldConfig().observation.likelihood_sigma
    parts = ("descriptor", "quadrants", "colour")  # the default likelihood's
    share = {k: scalar_series(t, p.term_share(k)) for k in parts}
    moved = {k: scalar_series(t, p.term_moved(k)) for k in parts}
    top_i = last(t, p.top, "particle")
    top_terms = {k: last(t, p.top, f"term_{k}") for k in parts[1:]}
    for i in range(1, N_FRAMES):
        rec, f = run["col"].records[i][0], i + 1
        w, tw = rec.weights, rec.likelihood.term_weights
        contrib = {k: tw[k] * rec.likelihood.terms[k] for k in parts[1:]}
        for k, c in contrib.items():
            np.testing.assert_allclose(top_terms[k][f], c[top_i[f]], rtol=1e-12)
        exp_share, exp_moved = term_shares(w, rec.distances, contrib, sigma)
        assert sum(share[k][f] for k in parts) == pytest.approx(1.0, abs=1e-6)
        for k in parts:
            assert share[k][f] == pytest.approx(exp_share[k], rel=1e-6)
            assert moved[k][f] == pytest.approx(exp_moved[k], rel=1e-6, abs=1e-9)


def test_term_shares_properties():
    rng = np.random.default_rng(0)
    n, sigma = 200, 0.5
    d = rng.uniform(0.5, 1.5, n)
    c_const = np.full(n, 0.7)  # the same for every particle: it moves no weight
    c_var = rng.uniform(0.0, 1.0, n)
    d2 = d**2 + c_const + c_var
    ll = -d2 / (2 * sigma**2)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    share, moved = term_shares(w, d, {"const": c_const, "var": c_var}, sigma)
    assert sum(share.values()) == pytest.approx(1.0)
    assert share["const"] == pytest.approx(0.7 / float(np.dot(w, d2)))
    assert moved["const"] == pytest.approx(0.0, abs=1e-12)
    # Without "var", the weights are those of d² alone (the constant cancels).
    w_wo = np.exp(-(d**2) / (2 * sigma**2))
    w_wo /= w_wo.sum()
    assert moved["var"] == pytest.approx(0.5 * np.abs(w - w_wo).sum())
    assert all(0.0 <= v <= 1.0 for v in moved.values())
    # A term that alone decides (d the same everywhere): without it the weights are uniform.
    ll = -(1 + 40 * c_var) / (2 * sigma**2)
    w2 = np.exp(ll - ll.max())
    w2 /= w2.sum()
    share, moved = term_shares(w2, np.ones(n), {"var": c_var * 40}, sigma)
    assert moved["descriptor"] == pytest.approx(0.0, abs=1e-12)
    assert moved["var"] == pytest.approx(0.5 * np.abs(w2 - 1 / n).sum()) and moved["var"] > 0.9


def test_heatmaps_equal_the_records(run):
    """Template, observed descriptor and difference, in log space, on their fixed colour scales."""
    from covviz.model.spd import logm
    from covviz.viz.why import heatmap_image

    t = run["temporal"]
    p = P.TrackerPaths("manifold")
    logged = last(t, f"{p.heatmap}/image", "Image:buffer")
    assert set(logged) == set(range(1, N_FRAMES + 1))
    for i in (0, 5):
        rec = run["col"].records[i][0]
        expected = heatmap_image(rec.estimate_template, logm(rec.estimate_descriptor))
        assert expected.shape == (9, 3 * 9 + 2 * 2, 3)
        np.testing.assert_array_equal(np.asarray(logged[i + 1], dtype=np.uint8).ravel(), expected.ravel())
    # The colour scales are fixed: a value maps to the same colour on every frame.
    from covviz.viz.why import LOG_RANGE

    lo = heatmap_image(np.full((9, 9), LOG_RANGE[0]), np.full((9, 9), LOG_RANGE[0]))
    hi = heatmap_image(np.full((9, 9), LOG_RANGE[1]), np.full((9, 9), LOG_RANGE[1]))
    assert not np.array_equal(lo[:, :9], hi[:, :9])
    np.testing.assert_array_equal(lo[:, :9], lo[:, 11:20])  # template and observed share one scale
    np.testing.assert_array_equal(lo[:, 22:], hi[:, 22:])  # no difference: the same neutral colour


def test_heatmap_colours_of_nan_and_inf_are_numpys_nan_to_num_then_clip():
    """NaN shows as 0 and ±inf as the scale's ends, as np.clip(np.nan_to_num(v)) would give."""
    from covviz.viz import why

    rng = np.random.default_rng(0)
    v = rng.normal(scale=2.0, size=(9, 9))
    v[rng.random((9, 9)) < 0.1], v[0, :3], v[1, :3] = np.nan, np.inf, -np.inf
    for lo, hi in ((0.0, 1.0), (-1.0, 1.0)):
        np.testing.assert_array_equal(why._clip_nan0(v, lo, hi), np.clip(np.nan_to_num(v), lo, hi))
    with np.errstate(invalid="ignore"):  # inf - inf in the difference panel: NaN, shown as 0
        assert why.heatmap_image(v, v).shape == (9, 3 * 9 + 2 * 2, 3)


def test_costly_diagnostics_only_on_their_frames(run):
    t = run["temporal"]
    p = P.TrackerPaths("manifold")
    mds_frames = {i + 1 for i in range(N_FRAMES) if i % MDS_EVERY == 0}  # frame numbers
    assert set(t[p.cloud_kind("target")]["Points2D:positions"]) == mds_frames
    assert set(t[p.cloud_kind("top")]["Points2D:positions"]) == mds_frames - {1}
    assert set(t[p.likelihood]["Points2D:positions"]) == mds_frames
    # The slices on every frame where the map is.
    assert set(t[f"{p.slices}/estimate"]["LineStrips2D:strips"]) == mds_frames
    # ... and cleared on the next frame, so a stale map never sits on a later frame.
    assert {f + 1 for f in mds_frames if f < N_FRAMES} <= set(t[p.likelihood]["Clear:is_recursive"])
    top = last(t, p.cloud_kind("top"), "Points2D:positions")
    assert all(len(v) == LoggerConfig().top_k for v in top.values())


def test_an_empty_slices_view_says_when_it_is_drawn(run):
    """On the frames after the slices are cleared, the view holds one label saying which frames have them;
    on the frames that draw them, the label is cleared."""
    from covviz.viz.why import slices_note

    t = run["temporal"]
    p = P.TrackerPaths("manifold")
    mds_frames = {i + 1 for i in range(N_FRAMES) if i % MDS_EVERY == 0}
    labels = last(t, f"{p.slices}/note", "Points2D:labels")
    after = {f + 1 for f in mds_frames if f + 1 <= N_FRAMES} - mds_frames
    assert after and after <= set(labels)
    text = slices_note(MDS_EVERY)
    assert all(list(np.ravel(labels[f])) == [text] for f in after)
    assert text == "drawn on frames 1, 5, 9, … and around losses"
    assert mds_frames <= set(t[f"{p.slices}/note"]["Clear:is_recursive"])


def test_static_context(run):
    s = run["static"]
    description = static_text(s, P.DESCRIPTION)
    assert "Reading a drift" in description and "Template cloud" in description
    config = static_text(s, P.CONFIG)
    assert "recording_id" in config and "likelihood_sigma" in config and "mds_every" in config
    assert "| manifold |" in static_text(s, P.SUMMARY) and "| identity |" in static_text(s, P.SUMMARY)


def test_recording_ids_are_unique():
    a, b = new_recording(), new_recording()
    assert a.get_recording_id() != b.get_recording_id()


class _Broken:
    """A tracker whose records carry bad arrays; the logger must skip them, not crash."""

    name = "broken"

    def __init__(self):
        self.last_record = None
        self.i = 0

    def init(self, frame, box):
        self.last_record = FrameRecord(index=0, box=np.array([np.nan, 1.0, 2.0, 3.0]), tracker=self.name)

    def update(self, frame):
        self.i += 1
        n = 5
        self.last_record = FrameRecord(
            index=self.i,
            box=np.array([1.0, 1.0, 10.0, 10.0]),
            tracker=self.name,
            particle_corners=np.zeros((n, 4, 2)),
            log_weights=np.full(n + 1, -np.log(n + 1)),  # mismatched length
            templates=np.full((n, 9, 9), np.inf),
        )
        return self.last_record.box


def test_bad_arrays_are_validated_not_logged(tmp_path):
    path = tmp_path / "bad.rrd"
    record_run(path, [_Broken()], n_frames=4)
    t, _ = read_recording(path)
    p = P.TrackerPaths("broken")
    assert set(boxes(t, p.box)) == {2, 3, 4}  # the NaN box of frame 1 (index 0) was not logged
    assert p.particles not in t
    lines = texts(t, p.events)
    assert any("box has NaN" in x for x in lines)
    assert any("particle_corners has 5 particles" in x for x in lines)
    assert any("templates has NaN" in x for x in lines)


def test_duplicate_tracker_names_get_their_own_paths(tmp_path):
    path = tmp_path / "dup.rrd"
    record_run(path, [IdentityTracker(), IdentityTracker()], n_frames=3)
    t, _ = read_recording(path)
    assert P.TrackerPaths("identity").box in t and P.TrackerPaths("identity-2").box in t


class _FailsAt(ManifoldTracker):
    """A manifold tracker that raises inside ``update`` on one frame."""

    def __init__(self, fail_at, **kw):
        super().__init__(**kw)
        self.fail_at = fail_at

    def update(self, frame):
        if self._index + 1 == self.fail_at:
            raise RuntimeError("boom inside the tracker")
        return super().update(frame)


def test_an_exception_inside_the_tracker_leaves_a_valid_recording(tmp_path):
    path = tmp_path / "interrupted.rrd"
    with pytest.raises(RuntimeError, match="boom"):
        record_run(path, [_FailsAt(6, config=ManifoldConfig(n_particles=30), rng=0)], n_frames=10)
    assert rrd_verify(path).returncode == 0
    t, s = read_recording(path)
    assert set(t[P.IMAGE]["EncodedImage:blob"]) == set(range(1, 7))
    assert set(boxes(t, P.TrackerPaths("manifold").box)) == set(range(1, 7))
    assert "interrupted" in static_text(s, P.SUMMARY)
    assert any("interrupted" in x for x in texts(t, P.TrackerPaths("manifold").events))


def test_logger_config_is_validated():
    with pytest.raises(ValueError):
        LoggerConfig(jpeg_quality=0)
    with pytest.raises(ValueError):
        LoggerConfig(mds_every=-1)
    assert LoggerConfig(mds_every=7).likelihood_period == 7
    assert LoggerConfig(mds_every=7, likelihood_every=0).likelihood_period == 0


def test_weight_levels():
    w = np.array([1.0, 0.5, 1e-3, 1e-6])
    lv = weight_levels(w)
    assert lv[0] == 15 and lv[2] == 0 and lv[3] == 0 and 0 < lv[1] < 15


def test_text_shown_in_the_viewer_has_glyphs_in_its_font():
    """A glyph missing from the viewer's font crashes the viewer (rerun 0.41): keep to the safe set."""
    from covviz.viz.description import DESCRIPTION, MDS_DESCRIPTION, viewer_safe

    for text in (DESCRIPTION, MDS_DESCRIPTION):
        assert viewer_safe(text) == text
    assert viewer_safe("Car ∇ 4 ≥ ∝") == "Car ? 4 ≥ ?"


def test_the_same_boxes_with_and_without_the_recorder(tmp_path):
    """The recorder (and the diagnosis before it, on their own thread) never changes a box, to the last bit."""
    from covviz.runner import BackgroundObserver, run

    seq = SyntheticSequence(SyntheticConfig(n_frames=40))
    bare = run(ManifoldTracker(ManifoldConfig(n_particles=N_PARTICLES), rng=7), seq, [])
    stream = new_recording()
    attach_sinks(stream, save=tmp_path / "r.rrd")
    cfg = LoggerConfig(mds_every=3, seed=0)
    traced = run(ManifoldTracker(ManifoldConfig(n_particles=N_PARTICLES), rng=7), seq,
                 [BackgroundObserver(Pipeline([Diagnoser(cfg.diagnosis), RerunLogger(stream, cfg)]))])
    assert np.array_equal(bare.boxes, traced.boxes)


def test_series_sent_as_columns_keep_their_frames_times_and_order(tmp_path):
    """SeriesBuffer: values added frame by frame, flushed in columns every few frames, read back as logged."""
    from covviz.viz.series import SeriesBuffer

    path = tmp_path / "s.rrd"
    stream = rr.RecordingStream("covviz-test")
    stream.save(str(path))
    buf = SeriesBuffer(stream, every=4)
    for f in range(1, 12):
        buf.at(f, (f - 1) / 25.0)
        buf.add("a/x", f * 0.5)
        if f % 3 == 0:
            buf.add("a/y", -f)
        buf.tick()
    assert 0 < len(buf) < 11  # 11 frames, flushed at 4 and 8: three frames held
    buf.flush()
    assert len(buf) == 0
    stream.flush()
    stream.disconnect()
    t, _ = read_recording(path)
    assert scalar_series(t, "a/x") == {f: f * 0.5 for f in range(1, 12)}
    assert scalar_series(t, "a/y") == {f: -f for f in (3, 6, 9)}
    with pytest.raises(RuntimeError, match="at"):
        SeriesBuffer(stream).add("a/x", 1.0)


def test_images_sent_as_columns_read_back_at_their_frames(tmp_path):
    """SeriesBuffer.add_image: per-frame images (two sizes on one entity, grey and RGB) go out as Image
    columns with the series and read back byte for byte at their frames, with their format."""
    from covviz.viz.series import SeriesBuffer

    path = tmp_path / "i.rrd"
    stream = rr.RecordingStream("covviz-test")
    stream.save(str(path))
    buf = SeriesBuffer(stream, every=3)
    rng = np.random.default_rng(0)
    grey = {f: rng.integers(0, 256, (4, 6) if f < 5 else (5, 7), dtype=np.uint8) for f in range(1, 8)}
    rgb = {f: rng.integers(0, 256, (3, 2, 3), dtype=np.uint8) for f in range(1, 8)}
    for f in range(1, 8):
        buf.at(f, None)
        buf.add_image("g", grey[f], "L")
        buf.add_image("c", rgb[f], "RGB")
        buf.tick()
    assert len(buf) == 2  # frames 7: two images held
    buf.flush()
    stream.flush()
    stream.disconnect()
    t, _ = read_recording(path)
    for ent, imgs in (("g", grey), ("c", rgb)):
        got = last(t, ent, "Image:buffer")
        fmt = last(t, ent, "Image:format")
        assert set(got) == set(imgs)
        for f, img in imgs.items():
            assert bytes(np.asarray(got[f], dtype=np.uint8).ravel()) == img.tobytes()
            (ff,) = fmt[f]
            assert (ff["width"], ff["height"]) == (img.shape[1], img.shape[0])
    with pytest.raises(RuntimeError, match="at"):
        SeriesBuffer(stream).add_image("g", grey[1], "L")


def test_series_flush_once_their_oldest_value_is_seconds_old():
    """The time bound: a flush when the oldest value held reaches ``seconds``, whatever the frame count."""
    from covviz.viz.series import SeriesBuffer

    now = [0.0]
    sent: list[tuple[str, int]] = []

    class Stream:
        def send_columns(self, path, indexes, columns):
            sent.append((path, len(indexes[0].as_arrow_array())))

    buf = SeriesBuffer(Stream(), every=100, seconds=2.0, clock=lambda: now[0])
    for f in range(1, 8):
        buf.at(f, None)
        buf.add("a/x", float(f))
        now[0] += 0.5  # 0.5 s a frame: the value of frame 1 is 2 s old after frame 4
        buf.tick()
    assert sent == [("a/x", 4)] and len(buf) == 3  # frames 1-4 sent; 5-7 held (1.5 s old)
    now[0] += 0.5
    buf.tick()  # a frame without values: the oldest held (frame 5, added at 2 s) is now 2 s old
    assert sent == [("a/x", 4), ("a/x", 3)] and len(buf) == 0
    now[0] += 10.0
    buf.tick()  # nothing held: nothing sent, however long ago
    assert len(sent) == 2
    with pytest.raises(ValueError, match="seconds"):
        SeriesBuffer(Stream(), seconds=-1.0)


@pytest.mark.parametrize("cmap", ["VIRIDIS", "INFERNO"])
def test_colormap_table_gives_opencvs_colours(cmap):
    """The recorder's heatmaps and likelihood map: cv2.applyColorMap's colours, from a table built once."""
    import cv2

    from covviz.viz.palette import colormap_rgb

    code = getattr(cv2, f"COLORMAP_{cmap}")
    u = np.random.default_rng(0).integers(0, 256, (17, 23)).astype(np.uint8)
    np.testing.assert_array_equal(colormap_rgb(u, code), cv2.applyColorMap(u, code)[..., ::-1])
    ramp = np.arange(256, dtype=np.uint8)[:, None]
    np.testing.assert_array_equal(colormap_rgb(ramp, code), cv2.applyColorMap(ramp, code)[..., ::-1])


def test_frame_jpeg_is_opencvs_encoding_of_the_bgr_frame():
    """The recorder's frames: RGB in, the same JPEG bytes as OpenCV's of the BGR image (grey frames too)."""
    import cv2

    from covviz.viz.checks import jpeg_bytes

    rgb = np.random.default_rng(1).integers(0, 256, (48, 64, 3)).astype(np.uint8)
    want = cv2.imencode(".jpg", np.ascontiguousarray(rgb[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 60])[1].tobytes()
    assert jpeg_bytes(rgb, 60) == want
    assert jpeg_bytes(rgb[::2, ::2], 60) == cv2.imencode(  # a strided view
        ".jpg", np.ascontiguousarray(rgb[::2, ::2, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, 60])[1].tobytes()
    grey = rgb[..., 0]
    assert jpeg_bytes(grey, 60) == cv2.imencode(".jpg", grey, [cv2.IMWRITE_JPEG_QUALITY, 60])[1].tobytes()
    with pytest.raises(ValueError, match="shape"):
        jpeg_bytes(np.zeros((4, 4, 2), np.uint8), 60)


def test_views_in_columns_or_one_log_each_record_the_same(tmp_path, run):
    """views_in_columns=False (what covviz track uses for a live viewer) logs the per-frame views one call each;
    the recording holds the same particles, dots, centres, heatmaps and zoom patches frame by frame."""
    path = tmp_path / "live.rrd"
    trackers = [ManifoldTracker(ManifoldConfig(n_particles=N_PARTICLES), rng=3), IdentityTracker()]
    record_run(path, trackers, config=LoggerConfig(mds_every=MDS_EVERY, seed=0, views_in_columns=False))
    live, _ = read_recording(path)
    cols = run["temporal"]
    p = P.TrackerPaths("manifold")
    top_values = [c for c in cols[p.top] if not c.startswith("LineStrips2D:")]
    assert {"weight", "particle", "distance"} <= {c.split(":")[-1] for c in top_values}, top_values
    for entity, column in ((p.particles, "LineStrips2D:strips"), (p.particle_dots, "Points2D:positions"),
                           (p.particle_dots, "Points2D:colors"), (p.centres, "Points2D:positions"),
                           (p.centres, "Points2D:radii"), (f"{p.heatmap}/image", "Image:buffer"),
                           (f"{p.zoom}/patches", "Image:buffer"), (P.IMAGE, "EncodedImage:blob"),
                           (P.IMAGE, "EncodedImage:media_type"), (P.GROUND_TRUTH, "Boxes2D:centers"),
                           (P.GROUND_TRUTH, "Boxes2D:half_sizes"), (p.box, "Boxes2D:centers"),
                           (p.box, "Boxes2D:half_sizes"), (p.region, "LineStrips2D:strips"),
                           (p.top, "LineStrips2D:strips"), *((p.top, c) for c in top_values),
                           *((f"{root}/{kind}", "Points2D:positions") for root in (p.cloud, p.cloud_zoom)
                             for kind in ("template", "top", "estimate", "initial", "target", "margin")),
                           (f"{p.cloud}/background", "Points2D:positions"), (f"{p.cloud_zoom}/target", "Points2D:labels"),
                           (f"{p.cloud_zoom}/estimate_label", "Points2D:positions"),
                           (f"{p.cloud_zoom}/initial_label", "Points2D:labels")):
        a, b = last(cols, entity, column), last(live, entity, column)
        a = {f: v for f, v in a.items() if np.size(v)}  # a frame with none (all particles boxed): no points
        b = {f: v for f, v in b.items() if np.size(v)}
        drawn = N_FRAMES // MDS_EVERY - 1 if "cloud" in entity else N_FRAMES - 2  # the pictures: every k-th frame
        assert set(a) == set(b) and len(b) >= drawn, (entity, column, len(a), len(b))
        for f in b:
            if column.endswith(("media_type", "labels")):
                assert a[f] == b[f] and all(isinstance(t, str) for t in b[f]), (entity, f, a[f], b[f])
                continue
            np.testing.assert_array_equal(np.asarray(a[f], dtype=float), np.asarray(b[f], dtype=float),
                                          err_msg=f"{entity} {column}")
    # the per-frame constants: per row in the live file, static in the batched one
    assert "Points2D:radii" in live[p.particle_dots]
    _, static = run["temporal"], run["static"]
    assert p.particle_dots in static and "Points2D:radii" in static[p.particle_dots]
    assert "EncodedImage:draw_order" in live[P.IMAGE] and "EncodedImage:draw_order" in static[P.IMAGE]
    assert "LineStrips2D:colors" in live[p.top] and "LineStrips2D:colors" in static[p.top]
    for kind in ("template", "target", "estimate_label"):
        assert {"Points2D:colors", "Points2D:radii", "Points2D:draw_order"} <= set(static[f"{p.cloud_zoom}/{kind}"])
