"""``snapshot()`` / ``restore()``: a tracker forked from its state goes on bit for bit (the replays depend on it)."""

from __future__ import annotations

import dataclasses
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from covviz.data.sequences import SyntheticSequence
from covviz.records import FrameRecord
from covviz.trackers import REGISTRY, make_tracker
from covviz.trackers.base import SnapshotUnsupported

SNAPSHOTTING = [name for name, e in REGISTRY.items() if e.snapshots]
N_PARTICLES = 150
FORK_AT, AFTER = 30, 20


def deep_equal(a, b, path="") -> list[str]:
    """Where two records (or any nesting of dataclasses, dicts, arrays and numbers) differ; [] if nowhere."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        if type(a) is not type(b):
            return [f"{path}: {type(a).__name__} vs {type(b).__name__}"]
        out = []
        for f in dataclasses.fields(a):
            if f.name == "timings":
                continue
            out += deep_equal(getattr(a, f.name), getattr(b, f.name), f"{path}.{f.name}")
        return out
    if isinstance(a, dict):
        if set(a) != set(b):
            return [f"{path}: keys {sorted(a)} vs {sorted(b)}"]
        return [d for k in a for d in deep_equal(a[k], b[k], f"{path}[{k}]")]
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        ok = (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape
              and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
        return [] if ok else [f"{path}: arrays differ"]
    if isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b):
        return []
    return [] if a == b else [f"{path}: {a!r} vs {b!r}"]


@pytest.fixture(scope="module")
def frames():
    seq = SyntheticSequence()
    return seq, [seq.frame(i).image for i in range(FORK_AT + AFTER + 1)]


def _track(tr, images, first, last) -> tuple[np.ndarray, list[FrameRecord]]:
    boxes, records = [], []
    for i in range(first, last):
        boxes.append(np.asarray(tr.update(images[i]), dtype=np.float64))
        records.append(tr.last_record)
    return np.array(boxes), records


def resumes_bit_for_bit(tr, fresh, images, first: int, last: int):
    """Snapshot ``tr``, track it on ``images[first:last]``, restore the snapshot (through pickle) into
    ``fresh`` (another seed) and track that too: the same boxes and records. Returns the snapshot."""
    state = tr.snapshot()
    boxes_a, recs_a = _track(tr, images, first, last)
    fresh.restore(pickle.loads(pickle.dumps(state)))  # another seed: restore replaces the stream
    boxes_b, recs_b = _track(fresh, images, first, last)
    assert np.array_equal(boxes_a, boxes_b)
    assert [d for ra, rb in zip(recs_a, recs_b) for d in deep_equal(ra, rb)] == []
    return state


def _started(name, seq, images):
    tr = make_tracker(name, seed=3, n_particles=N_PARTICLES if REGISTRY[name].stochastic else None)
    tr.init(images[0], seq.init_box)
    _track(tr, images, 1, FORK_AT + 1)
    return tr


@pytest.mark.parametrize("name", SNAPSHOTTING)
def test_restore_replays_bit_for_bit(name, frames):
    seq, images = frames
    tr = _started(name, seq, images)
    state = tr.snapshot()
    boxes_a, recs_a = _track(tr, images, FORK_AT + 1, FORK_AT + AFTER + 1)
    tr.restore(state)
    boxes_b, recs_b = _track(tr, images, FORK_AT + 1, FORK_AT + AFTER + 1)
    assert np.array_equal(boxes_a, boxes_b)
    diffs = [d for ra, rb in zip(recs_a, recs_b) for d in deep_equal(ra, rb)]
    assert diffs == []
    # and the replay really went somewhere: the boxes moved over the 20 frames (not a frozen tracker)
    if name != "identity":
        assert np.abs(np.diff(boxes_a[:, :2], axis=0)).sum() > 1.0


@pytest.mark.parametrize("name", SNAPSHOTTING)
def test_restore_into_a_fresh_tracker_through_pickle(name, frames):
    seq, images = frames
    tr = _started(name, seq, images)
    fresh = make_tracker(name, seed=99, n_particles=N_PARTICLES if REGISTRY[name].stochastic else None)
    resumes_bit_for_bit(tr, fresh, images, FORK_AT + 1, FORK_AT + AFTER + 1)


def test_a_state_is_immutable(frames):
    seq, images = frames
    tr = _started("manifold", seq, images)
    state = tr.snapshot()
    with pytest.raises(dataclasses.FrozenInstanceError):
        state.index = 0
    with pytest.raises(ValueError, match="read-only"):
        state.particles.templates[0, 0, 0] = 1.0
    before = state.particles.states.copy()
    _track(tr, images, FORK_AT + 1, FORK_AT + 5)  # the tracker goes on; the state stays as it was
    assert np.array_equal(state.particles.states, before)


def test_restore_refuses_another_config(frames):
    seq, images = frames
    state = _started("manifold", seq, images).snapshot()
    other = make_tracker("manifold-paper", seed=3, n_particles=N_PARTICLES)
    with pytest.raises(ValueError, match="another config"):
        other.restore(state)


@pytest.mark.parametrize("name", ["csrt", "kcf"])
def test_opencv_trackers_say_they_cannot(name, frames):
    seq, images = frames
    tr = make_tracker(name)
    tr.init(images[0], seq.init_box)
    with pytest.raises(SnapshotUnsupported, match="cannot be saved and restored"):
        tr.snapshot()
    assert not REGISTRY[name].snapshots


def test_restore_in_another_process(tmp_path, frames):
    """A state pickled here, restored in a fresh interpreter, tracks the same boxes."""
    seq, images = frames
    tr = _started("manifold", seq, images)
    state = tr.snapshot()
    boxes_a, _ = _track(tr, images, FORK_AT + 1, FORK_AT + 6)
    (tmp_path / "state.pkl").write_bytes(pickle.dumps(state))
    code = (
        "import pickle, sys, numpy as np\n"
        "from covviz.data.sequences import SyntheticSequence\n"
        "from covviz.trackers import make_tracker\n"
        "seq = SyntheticSequence()\n"
        f"tr = make_tracker('manifold', seed=0, n_particles={N_PARTICLES})\n"
        "tr.restore(pickle.load(open(sys.argv[1], 'rb')))\n"
        f"b = [tr.update(seq.frame(i).image) for i in range({FORK_AT + 1}, {FORK_AT + 6})]\n"
        "np.save(sys.argv[2], np.array(b, dtype=np.float64))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "state.pkl"), str(tmp_path / "b.npy")],
                         env=env, capture_output=True, text=True, timeout=300, check=False)
    assert out.returncode == 0, out.stderr
    assert np.array_equal(np.load(tmp_path / "b.npy"), boxes_a)
