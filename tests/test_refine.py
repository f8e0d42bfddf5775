"""The position step of the reported box (``ManifoldConfig.ncc_rate``, :mod:`covviz.model.refine`)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from covviz.config import ConfigError
from covviz.data.sequences import SyntheticSequence
from covviz.model import refine
from covviz.trackers import make_tracker
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
from tests.test_snapshot import resumes_bit_for_bit

N = 150


def _texture(rng, h=120, w=160) -> np.ndarray:
    img = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.5)
    return (img - img.min()) / (img.max() - img.min())


def test_patch_of_the_whole_box_at_its_own_size_is_the_crop(rng):
    g = _texture(rng)
    p = refine.patch(g, (50 + 20, 40 + 15), (40, 30), (40, 30))  # integer box: no interpolation
    np.testing.assert_allclose(p, g[40:70, 50:90], atol=1e-6)


@pytest.mark.parametrize("shift", [(3.0, -2.0), (-4.5, 1.5), (0.0, 0.0)])
def test_ncc_shift_finds_where_the_template_went(rng, shift):
    g = _texture(rng)
    centre, wh = np.array([80.0, 60.0]), (40.0, 30.0)
    tpl = refine.patch(g, centre, wh, (40, 30))
    M = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    moved = cv2.warpAffine(g, M, (g.shape[1], g.shape[0]), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    dx, dy, peak = refine.ncc_shift(moved, centre, wh, tpl)
    assert (dx, dy) == pytest.approx(shift, abs=0.3)
    assert peak > 0.9


def test_no_shift_where_the_template_does_not_match_and_beyond_the_radius(rng):
    g, other = _texture(rng), _texture(rng)
    tpl = refine.patch(other, (80, 60), (40, 30), (40, 30))
    dx, dy, peak = refine.ncc_shift(g, (80, 60), (40, 30), tpl)
    assert peak < refine.NCC_MIN and (dx, dy) == (0.0, 0.0)
    # a move never leaves the searched neighbourhood: radius box sizes either way
    tpl = refine.patch(g, (80, 60), (40, 30), (40, 30))
    dx, dy, _ = refine.ncc_shift(g, (100, 60), (40, 30), tpl)
    assert abs(dx) <= refine.NCC_RADIUS * 40 + 0.5 and dy == pytest.approx(0.0, abs=0.5)
    assert np.isnan(refine.ncc_shift(g, (80, 60), (3, 3), tpl[:3, :3])[2])  # too small to correlate


def test_update_template_is_a_running_mean(rng):
    g = _texture(rng)
    tpl = np.zeros((30, 40), np.float32)
    assert np.array_equal(refine.update_template(tpl, g, (80, 60), (40, 30), 0.0), tpl)
    np.testing.assert_allclose(refine.update_template(tpl, g, (80, 60), (40, 30), 1.0),
                               refine.patch(g, (80, 60), (40, 30), (40, 30)))


@pytest.fixture(scope="module")
def frames():
    seq = SyntheticSequence()
    return seq, [seq.frame(i).image for i in range(31)]


def _run(cfg, seq, images, last=30):
    tr = ManifoldTracker(cfg, rng=5)
    tr.init(images[0], seq.init_box)
    boxes = np.array([tr.update(images[i]) for i in range(1, last + 1)])
    return tr, boxes


def test_the_step_moves_only_the_reported_box_and_the_filter_goes_on_as_without_it(frames):
    seq, images = frames
    off, b_off = _run(ManifoldConfig(n_particles=N, ncc_rate=0.0), seq, images)
    on, b_on = _run(ManifoldConfig(n_particles=N, ncc_rate=0.02), seq, images)
    assert np.array_equal(off.particles.states, on.particles.states)
    assert np.array_equal(off.particles.templates, on.particles.templates)
    assert np.array_equal(b_off[:, 2:], b_on[:, 2:])  # the same sizes: only centres move
    moved = np.hypot(*(b_on[:, :2] - b_off[:, :2]).T)
    assert moved.max() > 0 and np.all(moved <= refine.NCC_RADIUS * np.hypot(*b_off[:, 2:].T) + 1e-9)
    rec = on.last_record
    assert np.array_equal(rec.box, b_on[-1]) and rec.pose[:2] == pytest.approx(b_on[-1, :2] + b_on[-1, 2:] / 2)


def test_snapshot_carries_the_template_bit_for_bit(frames):
    seq, images = frames
    cfg = ManifoldConfig(n_particles=N, ncc_rate=0.02)
    tr, _ = _run(cfg, seq, images, last=15)
    state = resumes_bit_for_bit(tr, ManifoldTracker(cfg, rng=99), images, 16, 26)
    assert state.ncc is not None and not state.ncc.template.flags.writeable


def test_off_in_the_paper_tracker_and_range_checked():
    paper = make_tracker("manifold-paper", seed=0, n_particles=N, config=ManifoldConfig(ncc_rate=0.5))
    assert paper.config.ncc_rate == 0.0
    with pytest.raises(ConfigError, match="ncc_rate"):
        ManifoldConfig.from_dict({"ncc_rate": 1.5})
