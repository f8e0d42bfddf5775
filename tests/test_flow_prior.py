"""The motion prior from the image (``ManifoldConfig.flow_share``) and the flow it reads (:mod:`covviz.model.flow`)."""

from __future__ import annotations

import numpy as np
import pytest

from covviz.config import ConfigError
from covviz.data.sequences import SyntheticSequence
from covviz.model.dynamics import VX, VY
from covviz.model.flow import gray8, median_flow, trusted
from covviz.trackers import make_tracker
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
from tests.test_snapshot import resumes_bit_for_bit

N = 150


def _texture(rng, h=120, w=160):
    import cv2

    return cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.uint8), (0, 0), 1.5)


def test_median_flow_measures_a_known_shift(rng):
    a = _texture(rng)
    b = np.roll(a, (2, -3), axis=(0, 1))  # content moves 3 px left, 2 px down
    fb, fail, f = median_flow(a, b, (50, 40, 40, 30))
    assert f == pytest.approx([-3.0, 2.0], abs=0.05)
    assert fb < 0.01 and fail == 0.0
    assert trusted(fb, fail, f)


def test_flow_of_unrelated_frames_is_not_trusted(rng):
    fb, fail, f = median_flow(_texture(rng), _texture(rng), (50, 40, 40, 30))
    assert not trusted(fb, fail, f)
    assert not trusted(*median_flow(_texture(rng), _texture(rng), (500, 400, 10, 10)))  # off the frame: nan


def test_gray8_of_rgb_and_of_float_frames():
    rgb = np.zeros((4, 5, 3), np.uint8)
    rgb[..., 1] = 200
    g = gray8(rgb)
    assert g.dtype == np.uint8 and g.shape == (4, 5) and int(g[0, 0]) == round(0.587 * 200)
    assert gray8(np.full((3, 3), 0.5)).tolist() == [[127] * 3] * 3


@pytest.fixture(scope="module")
def frames():
    seq = SyntheticSequence()
    return seq, [seq.frame(i).image for i in range(41)]


def _run(cfg, seq, images, seed=5, last=40):
    tr = ManifoldTracker(cfg, rng=seed)
    tr.init(images[0], seq.init_box)
    return tr, np.array([tr.update(images[i]) for i in range(1, last + 1)])


def test_off_by_default_and_in_manifold_paper():
    assert ManifoldConfig().flow_share == 0.0
    paper = make_tracker("manifold-paper", seed=0, n_particles=N, config=ManifoldConfig(flow_share=0.5))
    assert paper.config.flow_share == 0.0


def test_off_the_tracker_keeps_no_frame(frames):
    seq, images = frames
    cfg = ManifoldConfig(n_particles=N)
    tr, _ = _run(cfg, seq, images, last=3)
    assert tr.flow is None and tr.snapshot().flow is None
    assert "flow" not in tr.last_record.timings


def test_a_share_of_the_particles_moves_with_the_measured_flow(frames):
    """The synthetic target moves: with flow_share=1 every particle's velocity is the box's flow / decay
    before the kinematic step, so the propagated velocities scatter around the flow, not the old velocities."""
    seq, images = frames
    cfg = ManifoldConfig(n_particles=N, flow_share=1.0)
    tr, _ = _run(cfg, seq, images, last=10)
    prev8, box = tr.flow.frame, tr.flow.box
    cur8 = gray8(images[11])
    fb, fail, f = median_flow(prev8, cur8, box)
    assert trusted(fb, fail, f) and np.hypot(*f) > 0.5  # the target moves, and the flow sees it
    ps = tr._flow_velocities(tr.particles, cur8)
    a = cfg.kinematics.velocity_decay
    assert np.allclose(ps.states[:, VX], f[0] / a) and np.allclose(ps.states[:, VY], f[1] / a)
    half = ManifoldTracker(cfg.replace(flow_share=0.5), rng=1)
    half.init(images[0], seq.init_box)
    half.flow = tr.flow
    moved = half._flow_velocities(tr.particles, cur8).states
    hit = np.isclose(moved[:, VX], f[0] / a) & np.isclose(moved[:, VY], f[1] / a)
    assert hit.sum() == round(0.5 * N)
    assert np.array_equal(moved[~hit], tr.particles.states[~hit])  # the rest keep their own velocity


def test_snapshot_carries_the_flow_state_bit_for_bit(frames):
    seq, images = frames
    cfg = ManifoldConfig(n_particles=N, flow_share=0.5)
    tr, _ = _run(cfg, seq, images, last=20)
    assert "flow" in tr.last_record.timings  # its own stage in the record's timings (and the recording's)
    state = resumes_bit_for_bit(tr, ManifoldTracker(cfg, rng=99), images, 21, 31)
    assert state.flow is not None and not state.flow.frame.flags.writeable


def test_the_flow_changes_the_run_and_the_seed_still_decides_it(frames):
    seq, images = frames
    _, off = _run(ManifoldConfig(n_particles=N), seq, images)
    _, on = _run(ManifoldConfig(n_particles=N, flow_share=0.5), seq, images)
    _, again = _run(ManifoldConfig(n_particles=N, flow_share=0.5), seq, images)
    assert not np.array_equal(off, on)
    assert np.array_equal(on, again)


@pytest.mark.parametrize("bad", [-0.1, 1.5, "half"])
def test_flow_share_out_of_range_is_refused(bad):
    with pytest.raises(ConfigError, match="flow_share"):
        ManifoldConfig.from_dict({"flow_share": bad})
