"""Render a recording in the real Rerun viewer, headless, and check the PNG shows something.

Needs a Vulkan driver (``apt-get install -y mesa-vulkan-drivers libvulkan1``, as ``.ci/run``
does); skips with the reason otherwise.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from covviz.data.sequences import SyntheticConfig, SyntheticSequence
from covviz.runner import run
from covviz.trackers.manifold import ManifoldConfig, ManifoldTracker
from covviz.viz.logger import LoggerConfig, RerunLogger
from covviz.viz.sinks import attach_sinks, new_recording
from covviz.viz.snapshot import SnapshotError, find_viewer, snapshot, vulkan_available

pytestmark = pytest.mark.viewer


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("render") / "r.rrd"
    stream = new_recording()
    attach_sinks(stream, save=path)
    seq = SyntheticSequence(SyntheticConfig(n_frames=8))
    run(
        ManifoldTracker(ManifoldConfig(n_particles=40), rng=0),
        seq,
        [RerunLogger(stream, LoggerConfig(mds_every=3))],
    )
    return path


def _skip_without_viewer():
    if not vulkan_available():
        pytest.skip(
            "no Vulkan driver for the headless viewer (apt-get install mesa-vulkan-drivers libvulkan1)"
        )
    if find_viewer() is None:
        pytest.skip("the rerun viewer binary is not installed")


def test_headless_snapshot_is_not_blank(recording, tmp_path):
    _skip_without_viewer()
    out = tmp_path / "shot.png"
    try:
        snapshot(recording, out, frame=6, size=(1280, 720), timeout=90)
    except SnapshotError as exc:
        if "exited" in str(exc) or "did not answer" in str(exc):
            pytest.skip(f"the headless viewer cannot run here: {exc}")
        raise
    img = cv2.imread(str(out))
    assert img is not None
    assert img.shape[1] >= 1280 and img.shape[0] >= 720
    # Not blank: many distinct colours and real contrast, in the frame view (left half) too.
    left = img[:, : img.shape[1] // 2]
    assert img.std() > 20 and left.std() > 20
    assert len(np.unique(img.reshape(-1, 3) // 16, axis=0)) > 200
    # The particles' green is there (the default layout opens on the frame with its particles).
    b, g, r = (left[..., k].astype(int) for k in range(3))
    assert ((g > 150) & (g > r + 60) & (g > b + 40)).sum() > 200


def test_snapshot_refuses_a_frame_outside_the_recording(recording, tmp_path):
    _skip_without_viewer()
    with pytest.raises(SnapshotError, match="outside"):
        snapshot(recording, tmp_path / "x.png", frame=999, size=(800, 600), timeout=90)
