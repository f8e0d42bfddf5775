"""The moving-camera proposal (``ManifoldConfig.camera_share``) and the scene shift it reads (:mod:`covviz.model.flow`)."""

from __future__ import annotations

import numpy as np
import pytest

from covviz.config import ConfigError
from covviz.data.sequences import SyntheticSequence
from covviz.model.dynamics import X, Y
from covviz.model.flow import CAMERA_SIDE, camera_frame, camera_shift
from covviz.trackers import make_tracker
from covviz.trackers.manifold import CameraState, ManifoldConfig, ManifoldTracker
from tests.test_snapshot import resumes_bit_for_bit

N = 120
BOX = np.array([140.0, 100.0, 40.0, 30.0])


def _scene(rng, h=320, w=400):
    import cv2

    return cv2.GaussianBlur((rng.random((h, w, 3)) * 255).astype(np.uint8), (0, 0), 2.0)


def _shaken(rng, offsets):
    """Frames (240 x 320) of one textured scene seen through a window that moves by ``offsets`` (x, y) pixels."""
    big = _scene(rng)
    return [np.ascontiguousarray(big[40 + dy : 40 + dy + 240, 40 + dx : 40 + dx + 320]) for dx, dy in offsets]


def test_camera_shift_measures_a_known_jump_at_full_resolution(rng):
    a, b = _shaken(rng, [(0, 0), (-12, 7)])  # the window moves 12 px left, 7 down: the scene 12 right, 7 up
    (pa, fa), (pb, fb) = camera_frame(a), camera_frame(b)
    assert fa == fb == pytest.approx(CAMERA_SIDE / 320) and pa.shape == (120, 160) and pa.dtype == np.float32
    dx, dy, response = camera_shift(pa, pb, fa)
    # to about a pixel of the downscaled frame (2 px here): the window and the subpixel peak fit's bias
    assert (dx, dy) == pytest.approx((12.0, -7.0), abs=1.0 / fa)
    assert response > 0.5
    _, _, unrelated = camera_shift(pa, camera_frame(_scene(rng)[:240, :320])[0], fa)
    assert unrelated < 0.3


def _run(cfg, seq, images, seed=5, last=30):
    tr = ManifoldTracker(cfg, rng=seed)
    tr.init(images[0], seq.init_box)
    return tr, np.array([tr.update(images[i]) for i in range(1, last + 1)])


@pytest.fixture(scope="module")
def synthetic():
    seq = SyntheticSequence()
    return seq, [seq.frame(i).image for i in range(31)]


def test_off_by_default_and_in_manifold_paper(synthetic):
    assert ManifoldConfig().camera_share == 0.0
    paper = make_tracker("manifold-paper", seed=0, n_particles=N, config=ManifoldConfig(camera_share=0.5))
    assert paper.config.camera_share == 0.0
    seq, images = synthetic
    tr, _ = _run(ManifoldConfig(n_particles=N), seq, images, last=2)
    assert tr.camera is None and tr.snapshot().camera is None and "camera" not in tr.last_record.timings


def test_a_still_camera_changes_nothing_and_draws_nothing(synthetic):
    # The synthetic default's camera stands still: no frame's scene shift passes the gate, so the run is
    # the one without the proposal, bit for bit (no particle moved, no random number drawn).
    seq, images = synthetic
    tr, on = _run(ManifoldConfig(n_particles=N, camera_share=0.5), seq, images)
    _, off = _run(ManifoldConfig(n_particles=N), seq, images)
    assert np.array_equal(on, off)
    # it keeps the filter's own box (the reported one may differ by the position step, not in size)
    assert "camera" in tr.last_record.timings and np.array_equal(tr.camera.box[2:], on[-1][2:])


@pytest.mark.parametrize("share", [1.0, 0.5])
def test_a_share_of_the_particles_jumps_with_the_scene(rng, share):
    images = _shaken(rng, [(0, 0)] * 4 + [(-30, 10)] * 3)  # the camera jumps at frame 4: the scene 30 px right, 10 up
    tr = ManifoldTracker(ManifoldConfig(n_particles=N, camera_share=share), rng=2)
    tr.init(images[0], BOX)
    for i in (1, 2, 3):
        tr.update(images[i])
    before = tr.particles
    state = tr.rng.bit_generator.state
    small, factor = camera_frame(images[4])
    after = tr._camera_shift(before, small, factor).states
    assert (tr.rng.bit_generator.state != state) == (share < 1)  # which particles move: drawn for a share
    d = after[:, [X, Y]] - before.states[:, [X, Y]]
    hit = np.abs(d).sum(axis=1) > 0
    assert hit.sum() == round(share * N)
    assert d[hit] == pytest.approx(np.tile([30.0, -10.0], (hit.sum(), 1)), abs=1.0 / factor)
    assert np.array_equal(np.delete(after, [X, Y], axis=1), np.delete(before.states, [X, Y], axis=1))
    # between two frames of a still camera nothing moves and nothing is drawn
    still = tr.rng.bit_generator.state
    tr.camera = CameraState(camera_frame(images[5])[0], factor, tr.camera.box)
    assert tr._camera_shift(tr.particles, *camera_frame(images[6])) is tr.particles
    assert tr.rng.bit_generator.state == still


def test_snapshot_carries_the_camera_state_bit_for_bit(rng):
    images = _shaken(rng, [(0, 0)] * 3 + [(-20, 0)] * 3 + [(-20, 15)] * 6)
    cfg = ManifoldConfig(n_particles=N, camera_share=0.5)
    tr = ManifoldTracker(cfg, rng=4)
    tr.init(images[0], BOX)
    for i in range(1, 5):
        tr.update(images[i])
    state = resumes_bit_for_bit(tr, ManifoldTracker(cfg, rng=99), images, 5, 12)
    assert state.camera is not None and not state.camera.frame.flags.writeable


@pytest.mark.parametrize("bad", [-0.1, 1.5, "half"])
def test_camera_share_out_of_range_is_refused(bad):
    with pytest.raises(ConfigError, match="camera_share"):
        ManifoldConfig.from_dict({"camera_share": bad})
