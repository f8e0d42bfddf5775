"""Tests for :mod:`covviz.experiments.results`: run results on disk (OTB boxes + JSON)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from covviz.experiments.results import FORMAT, ResultError, load_result, result_paths, save_result
from covviz.metrics import evaluate
from covviz.records import RunResult

# Boxes are written with 2 decimals: half a unit of the last place, plus float slack.
BOX_ATOL = 0.005 + 1e-9


def make_result(rng, n=12, seed=5, tracker="manifold", sequence="seqA") -> RunResult:
    gt = np.column_stack([rng.uniform(0, 100, n), rng.uniform(0, 100, n), rng.uniform(10, 40, (n, 2))])
    boxes = gt + rng.normal(0, 2, (n, 4))
    boxes[0] = gt[0]
    if n > 4:
        gt[4] = np.nan  # a frame without ground truth
    return RunResult(
        sequence=sequence,
        tracker=tracker,
        seed=seed,
        boxes=boxes,
        times=rng.uniform(0.001, 0.01, n),
        groundtruth=gt,
        config={"n_particles": 100, "kinematics": {"mode_probs": (0.9, 0.1)}, "eps": 1e-3},
    )


def test_round_trip(tmp_path, rng):
    res = make_result(rng)
    doc = save_result(res, tmp_path)
    txt, js = result_paths(tmp_path, "seqA", "manifold", 5)
    assert txt == tmp_path / "seqA" / "manifold_s5.txt" and js.with_suffix(".txt") == txt
    assert txt.is_file() and js.is_file()
    loaded, boxes = load_result(js)
    np.testing.assert_allclose(boxes, res.boxes, atol=BOX_ATOL)
    assert loaded["format"] == FORMAT
    assert loaded["seed"] == 5 and loaded["tracker"] == "manifold" and loaded["sequence"] == "seqA"
    assert loaded["n_frames"] == 12 and loaded["interrupted"] is False
    assert loaded["config"] == {"n_particles": 100, "kinematics": {"mode_probs": [0.9, 0.1]}, "eps": 1e-3}
    assert loaded["metrics"] == pytest.approx(evaluate(res.boxes, res.groundtruth).as_dict(), nan_ok=True)
    assert loaded["metrics"]["n_skipped"] == 1
    np.testing.assert_allclose(loaded["times"], res.times, atol=1e-6)
    assert loaded["fps"] == pytest.approx(res.fps)
    assert loaded == json.loads(json.dumps(doc, default=list))


def test_boxes_file_is_otb_one_based(tmp_path, rng):
    res = make_result(rng, n=3)
    res.boxes[:] = [[0.0, 0.0, 10.0, 20.0], [5.5, 6.25, 1.0, 2.0], [-3.0, 4.0, 7.0, 8.0]]
    save_result(res, tmp_path)
    txt, _ = result_paths(tmp_path, "seqA", "manifold", 5)
    lines = txt.read_text().splitlines()
    assert len(lines) == 3
    rows = np.array([[float(v) for v in line.split(",")] for line in lines])
    np.testing.assert_allclose(rows, res.boxes + [1, 1, 0, 0], atol=BOX_ATOL)


def test_save_does_not_modify_result(tmp_path, rng):
    res = make_result(rng)
    boxes = res.boxes.copy()
    res.boxes.setflags(write=False)
    res.groundtruth.setflags(write=False)
    save_result(res, tmp_path)
    np.testing.assert_array_equal(res.boxes, boxes)


def test_no_seed_and_extra_fields(tmp_path, rng):
    res = make_result(rng, seed=None, tracker="identity")
    save_result(res, tmp_path, extra={"note": "hello"})
    _txt, js = result_paths(tmp_path, "seqA", "identity", None)
    assert js.name == "identity.json"
    doc, _ = load_result(js)
    assert doc["seed"] is None and doc["note"] == "hello"


def test_atomic_writes_leave_no_part_files(tmp_path, rng):
    for seed in range(3):
        save_result(make_result(rng, seed=seed), tmp_path)
    save_result(make_result(rng, seed=0), tmp_path)  # overwrite an existing result
    assert list(tmp_path.rglob("*.part")) == []
    assert sorted(p.name for p in (tmp_path / "seqA").iterdir()) == sorted(
        f"manifold_s{s}.{e}" for s in range(3) for e in ("txt", "json")
    )


def test_all_nan_ground_truth_round_trips(tmp_path, rng):
    res = make_result(rng, n=4)
    res.groundtruth[:] = np.nan
    save_result(res, tmp_path)
    doc, boxes = load_result(result_paths(tmp_path, "seqA", "manifold", 5)[1])
    assert np.isnan(doc["metrics"]["success_auc"]) and doc["metrics"]["n_skipped"] == 4
    assert boxes.shape == (4, 4)


# --------------------------------------------------------------------------- #
# refusing bad files
# --------------------------------------------------------------------------- #
@pytest.fixture
def saved(tmp_path, rng):
    save_result(make_result(rng), tmp_path)
    return result_paths(tmp_path, "seqA", "manifold", 5)


def test_missing_file_raises(tmp_path):
    with pytest.raises(ResultError, match="no such"):
        load_result(tmp_path / "nothing.json")


@pytest.mark.parametrize("text", ["{not json", "", '{"format": "covviz-result/1", ', "\udcff"])
def test_corrupt_json_raises(saved, text):
    _, js = saved
    js.write_text(text, errors="surrogateescape")
    with pytest.raises(ResultError, match="corrupt"):
        load_result(js)


@pytest.mark.parametrize("doc", [{"format": "covviz-result/0"}, {"format": None}, {}, [1, 2], "covviz-result/1"])
def test_wrong_format_tag_raises(saved, doc):
    _, js = saved
    js.write_text(json.dumps(doc))
    with pytest.raises(ResultError, match="not a covviz result"):
        load_result(js)


def test_box_count_mismatch_raises(saved):
    txt, js = saved
    lines = txt.read_text().splitlines()
    txt.write_text("\n".join(lines[:-1]) + "\n")
    with pytest.raises(ResultError, match="11 boxes"):
        load_result(js)


def test_missing_or_bad_boxes_file_raises(saved):
    txt, js = saved
    txt.write_text("1,2,3\n")
    with pytest.raises(ResultError, match="cannot read"):
        load_result(js)
    txt.unlink()
    with pytest.raises(ResultError, match="cannot read"):
        load_result(js)


def test_result_error_is_a_value_error():
    assert issubclass(ResultError, ValueError)
