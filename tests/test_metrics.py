"""Tests for :mod:`covviz.metrics` against hand-computed cases.

Every expected number below is worked out by hand in the comment next to it.
Inputs are passed read-only (``writeable=False``) wherever possible, so a metric
that modified its input would raise.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from covviz.metrics import (
    IOU_THRESHOLDS,
    PRECISION_AT,
    PRECISION_THRESHOLDS,
    SequenceMetrics,
    center_error,
    evaluate,
    iou,
    normalized_center_error,
    on_track,
    precision_curve,
    success_curve,
    valid_rows,
)


def ro(a) -> np.ndarray:
    """A read-only float64 copy."""
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


# --------------------------------------------------------------------------- #
# constants
# --------------------------------------------------------------------------- #
def test_threshold_constants_follow_otb():
    assert len(IOU_THRESHOLDS) == 21
    np.testing.assert_allclose(IOU_THRESHOLDS, np.arange(21) * 0.05, atol=1e-12)
    np.testing.assert_array_equal(PRECISION_THRESHOLDS, np.arange(51))
    assert PRECISION_AT == 20


# --------------------------------------------------------------------------- #
# IoU and centre error
# --------------------------------------------------------------------------- #
def test_iou_hand_computed():
    a = ro(
        [
            [0, 0, 10, 10],  # identical                               -> 1
            [0, 0, 10, 10],  # disjoint                                -> 0
            [0, 0, 10, 10],  # half overlap: inter 50, union 150       -> 1/3
            [0, 0, 10, 10],  # contained 5x5: inter 25, union 100      -> 1/4
            [0, 0, 10, 10],  # touching edge: inter 0                  -> 0
            [0, 0, 10, 10],  # zero-size box inside                    -> 0
            [0, 0, 0, 0],  # both empty                                -> 0
            [0, 0, 2, 1],  # 1x1 inside 2x1: inter 1, union 2          -> 1/2
            [2, 3, 4, 6],  # offset (1, 1): inter 3·5 = 15, union 24+24-15 = 33
        ]
    )
    b = ro(
        [
            [0, 0, 10, 10],
            [20, 20, 5, 5],
            [5, 0, 10, 10],
            [2, 2, 5, 5],
            [10, 0, 10, 10],
            [3, 3, 0, 5],
            [0, 0, 0, 0],
            [1, 0, 1, 1],
            [3, 4, 4, 6],
        ]
    )
    expected = [1, 0, 1 / 3, 1 / 4, 0, 0, 0, 1 / 2, 15 / 33]
    np.testing.assert_allclose(iou(a, b), expected, atol=1e-12)
    np.testing.assert_allclose(iou(b, a), expected, atol=1e-12)


def test_iou_single_boxes_and_shape_errors():
    assert iou(ro([0, 0, 4, 4]), ro([2, 0, 4, 4])).tolist() == pytest.approx([8 / 24])
    with pytest.raises(ValueError):
        iou(np.zeros((3, 4)), np.zeros((2, 4)))
    with pytest.raises(ValueError):
        iou(np.zeros((3, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError):
        iou(np.zeros((2, 4, 1)), np.zeros((2, 4, 1)))


def test_center_error_hand_computed():
    a = ro([[0, 0, 10, 10], [0, 0, 10, 20], [5, 5, 2, 2]])
    b = ro([[3, 4, 10, 10], [0, 0, 30, 20], [5, 5, 2, 2]])
    # centres: (5,5)-(8,9): 5;  (5,10)-(15,10): 10;  identical: 0
    np.testing.assert_allclose(center_error(a, b), [5, 10, 0])


def test_center_error_shape_errors():
    with pytest.raises(ValueError):
        center_error(np.zeros((3, 5)), np.zeros((3, 5)))
    with pytest.raises(ValueError):
        center_error(np.zeros((3, 4)), np.zeros((2, 4)))


def test_center_error_rejects_length_mismatch_that_broadcasts():
    with pytest.raises(ValueError):
        center_error(np.zeros((1, 4)), np.zeros((3, 4)))


def test_normalized_center_error_hand_computed():
    boxes = ro([[4, 8, 10, 20], [0, 0, 4, 4]])
    gt = ro([[0, 0, 10, 20], [0, 0, 8, 2]])
    # (9,18)-(5,10): |e| = (4, 8) / (10, 20) = (0.4, 0.4);  (2,2)-(4,1): (2, 1)/(8, 2) = (0.25, 0.5)
    np.testing.assert_allclose(normalized_center_error(boxes, gt), [[0.4, 0.4], [0.25, 0.5]])


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-1e3, 1e3), min_size=4, max_size=4),
    st.lists(st.floats(-1e3, 1e3), min_size=4, max_size=4),
)
def test_iou_symmetric_and_bounded(a, b):
    a = ro(a)
    b = ro(b)
    ab, ba = iou(a, b), iou(b, a)
    assert ab.shape == (1,)
    # Rounding could push IoU above 1 by about ulp(|x| + w) / w; iou clips, and this allows only that.
    sizes = np.r_[a[2:], b[2:]]
    slack = 0.0
    if sizes.min() > 0:
        # A subnormal width would overflow the ratio; past 1e-3 the allowance means nothing anyway.
        with np.errstate(over="ignore"):
            slack = min(8 * np.finfo(float).eps * np.abs(np.r_[a, b]).max() / sizes.min(), 1e-3)
    assert np.isfinite(ab[0]) and 0.0 <= ab[0] <= 1.0 + slack
    assert ab[0] == pytest.approx(ba[0], abs=1e-12)


def test_iou_never_exceeds_one_and_identical_boxes_fail_threshold_one():
    box = ro([[161.87, 384.99, 72.13, 47.93]])  # an ordinary box; ~40% of random 2-decimal boxes do this
    assert iou(box, box)[0] <= 1.0
    assert success_curve(box, box)[-1] == 0.0  # "IoU > 1" never holds


@settings(max_examples=200, deadline=None)
@given(
    st.floats(-1e4, 1e4),
    st.floats(-1e4, 1e4),
    st.floats(1e-3, 1e4),
    st.floats(1e-3, 1e4),
)
def test_iou_of_identical_boxes_is_one(x, y, w, h):
    box = ro([x, y, w, h])
    slack = 8 * np.finfo(float).eps * (abs(x) + abs(y) + w + h) / min(w, h)  # rounding of x + w - x
    assert iou(box, box)[0] == pytest.approx(1.0, abs=slack)
    assert center_error(box, box)[0] == 0.0


# --------------------------------------------------------------------------- #
# success and precision
# --------------------------------------------------------------------------- #
def test_success_curve_and_auc_hand_computed():
    gt = ro([[0, 0, 2, 1], [0, 0, 2, 1], [0, 0, 2, 1]])
    boxes = ro([[0, 0, 2, 1], [0, 0, 1, 1], [5, 5, 1, 1]])  # IoU 1, 1/2, 0
    curve = success_curve(boxes, gt)
    assert curve.shape == (21,)
    # Strictly greater than the threshold: IoU 1 passes t < 1 (20 of 21 thresholds),
    # IoU 0.5 passes t = 0 .. 0.45 (10 thresholds), IoU 0 passes none.
    expected = (np.r_[np.ones(20), 0] + np.r_[np.ones(10), np.zeros(11)]) / 3
    np.testing.assert_allclose(curve, expected)
    assert curve[10] == pytest.approx(1 / 3)  # t = 0.5 exactly: the IoU-0.5 frame does not count
    m = evaluate(boxes, gt)
    assert m.success_auc == pytest.approx(30 / 63)  # mean of the curve


def test_precision_curve_and_p20_hand_computed():
    gt = ro(np.tile([0, 0, 10, 10], (4, 1)))
    # centre errors 0, 20 (a 12-16-20 triangle), 20.5, 100
    boxes = ro([[0, 0, 10, 10], [12, 16, 10, 10], [20.5, 0, 10, 10], [100, 0, 10, 10]])
    np.testing.assert_allclose(center_error(boxes, gt), [0, 20, 20.5, 100])
    curve = precision_curve(boxes, gt)
    assert curve.shape == (51,)
    assert curve[0] == pytest.approx(0.25)  # error <= 0: the perfect frame
    assert curve[19] == pytest.approx(0.25)
    assert curve[20] == pytest.approx(0.5)  # <= 20 includes the error of exactly 20
    assert curve[50] == pytest.approx(0.75)
    assert evaluate(boxes, gt).precision_20 == pytest.approx(0.5)


def test_curves_skip_invalid_ground_truth():
    gt = ro([[0, 0, 10, 10], [np.nan] * 4, [0, 0, 0, 10], [0, 0, 10, -1], [0, 0, 10, 10]])
    boxes = ro(np.tile([0, 0, 10, 10], (5, 1)))
    # Only rows 0 and 4 count; both perfect.
    np.testing.assert_allclose(precision_curve(boxes, gt), 1.0)
    assert success_curve(boxes, gt)[0] == 1.0
    np.testing.assert_array_equal(valid_rows(gt), [True, False, False, False, True])


def test_curves_with_no_valid_ground_truth_are_nan():
    gt = ro(np.full((3, 4), np.nan))
    boxes = ro(np.zeros((3, 4)))
    assert np.all(np.isnan(success_curve(boxes, gt)))
    assert np.all(np.isnan(precision_curve(boxes, gt)))
    r, rms = on_track(boxes, gt)
    assert np.isnan(r) and np.isnan(rms)
    m = evaluate(boxes, gt)
    assert m.n_evaluated == 0 and m.n_skipped == 3 and np.isnan(m.success_auc)


# --------------------------------------------------------------------------- #
# the paper's on-track measures
# --------------------------------------------------------------------------- #
def on_track_example():
    """Ground truth 10x20 centred at (5, 10); boxes offset by (e_x, e_y):

    ======  =========  ==========================  ========  ================
    frame   (ex, ey)   γ = ½(|ex|/10 + |ey|/20)     on track  ½((ex/10)²+(ey/20)²)
    ======  =========  ==========================  ========  ================
    0       (4, 8)     ½(0.4 + 0.4) = 0.4          yes       0.16
    1       (10, -20)  ½(1 + 1) = 1  (boundary)    yes       1.0
    2       (-15, 0)   ½(1.5 + 0) = 0.75           yes       1.125
    3       (20, 20)   ½(2 + 1) = 1.5              no        —
    4       nan gt     invalid: skipped
    5       zero-width gt: skipped
    ======  =========  ==========================  ========  ================

    r = 3 on-track / 4 valid; rms = sqrt((0.16 + 1 + 1.125) / 3).
    """
    g = [0.0, 0.0, 10.0, 20.0]
    gt = [g, g, g, g, [np.nan] * 4, [0.0, 0.0, 0.0, 20.0]]
    off = [(4, 8), (10, -20), (-15, 0), (20, 20), (0, 0), (0, 0)]
    boxes = [[ex, ey, 10.0, 20.0] for ex, ey in off]
    return ro(boxes), ro(gt)


def test_on_track_hand_computed():
    boxes, gt = on_track_example()
    r, rms = on_track(boxes, gt)
    assert r == pytest.approx(3 / 4)
    assert rms == pytest.approx(np.sqrt((0.16 + 1.0 + 1.125) / 3))


def test_on_track_uses_ground_truth_size_not_box_size():
    gt = ro([[0, 0, 10, 20]])
    # Box centre (13, 10): e = (8, 0); a huge box must not change γ = ½·8/10 = 0.4.
    boxes = ro([[-37, -40, 100, 100]])
    r, rms = on_track(boxes, gt)
    assert r == 1.0 and rms == pytest.approx(np.sqrt(0.5 * 0.8**2))


def test_on_track_all_off_track():
    gt = ro([[0, 0, 10, 10]] * 2)
    boxes = ro([[100, 100, 10, 10]] * 2)
    r, rms = on_track(boxes, gt)
    assert r == 0.0 and np.isnan(rms)


def test_evaluate_hand_computed_example():
    boxes, gt = on_track_example()
    m = evaluate(boxes, gt)
    assert isinstance(m, SequenceMetrics)
    assert m.n_frames == 6 and m.n_evaluated == 4 and m.n_skipped == 2
    assert m.r_on_track == pytest.approx(3 / 4)
    assert m.rms_on_track == pytest.approx(np.sqrt((0.16 + 1.0 + 1.125) / 3))
    ce = [np.hypot(4, 8), np.hypot(10, 20), 15.0, np.hypot(20, 20)]
    assert m.mean_center_error == pytest.approx(np.mean(ce))
    assert m.precision_20 == pytest.approx(2 / 4)  # 8.94 and 15 are <= 20; 22.4 and 28.3 are not
    # IoU of same-size boxes offset by (ex, ey): (10-|ex|)(20-|ey|) / (400 - inter)
    inter = [6 * 12, 0, 0, 0]
    ious = [i / (400 - i) for i in inter]
    assert m.mean_iou == pytest.approx(np.mean(ious))
    assert m.mean_iou_nonzero == pytest.approx(ious[0])
    d = m.as_dict()
    assert set(d) >= {"success_auc", "precision_20", "r_on_track", "rms_on_track", "n_skipped"}


def test_evaluate_skip_first():
    gt = ro([[0, 0, 10, 10], [0, 0, 10, 10]])
    boxes = ro([[0, 0, 10, 10], [50, 50, 10, 10]])
    assert evaluate(boxes, gt).r_on_track == 0.5
    m = evaluate(boxes, gt, skip_first=True)
    assert m.r_on_track == 0.0 and m.n_frames == 1


def test_evaluate_length_mismatch_raises():
    with pytest.raises(ValueError, match="differ"):
        evaluate(np.zeros((3, 4)), np.ones((4, 4)))
    with pytest.raises(ValueError):
        evaluate(np.zeros((3, 5)), np.ones((3, 5)))


def test_metrics_never_mutate_inputs(rng):
    boxes = np.column_stack([rng.uniform(-50, 200, 30), rng.uniform(-50, 200, 30), rng.uniform(-5, 60, (30, 2))])
    gt = np.column_stack([rng.uniform(0, 200, 30), rng.uniform(0, 200, 30), rng.uniform(-5, 60, (30, 2))])
    gt[3] = np.nan
    b0, g0 = boxes.copy(), gt.copy()
    boxes.setflags(write=False)
    gt.setflags(write=False)
    for fn in (iou, center_error, normalized_center_error, success_curve, precision_curve, on_track, evaluate):
        fn(boxes, gt)
    valid_rows(gt)
    np.testing.assert_array_equal(boxes, b0)
    np.testing.assert_array_equal(gt, g0)


def _iou_clip_reference(a, b):
    """IoU as np.clip and np.nan_to_num write it (the function's earlier body): the oracle of its rewrite."""
    a, b = np.atleast_2d(np.asarray(a, float)), np.atleast_2d(np.asarray(b, float))
    x1, y1 = np.maximum(a[:, 0], b[:, 0]), np.maximum(a[:, 1], b[:, 1])
    x2 = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2])
    y2 = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    union = np.clip(a[:, 2], 0, None) * np.clip(a[:, 3], 0, None) + np.clip(b[:, 2], 0, None) * np.clip(
        b[:, 3], 0, None) - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(union > 0, inter / union, 0.0)
    return np.clip(np.nan_to_num(out, nan=0.0), 0.0, 1.0)


def test_iou_equals_the_clip_formula_bit_for_bit_on_odd_boxes():
    rng = np.random.default_rng(7)
    odd = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, -1.0, 1e-300, 1e300, 1e-320])
    for _ in range(300):
        n = int(rng.integers(1, 40))
        a, b = rng.normal(50, 30, (n, 4)), rng.normal(50, 30, (n, 4))
        b[:, 2:] = np.abs(b[:, 2:])
        for m, x in ((rng.random((n, 4)) < 0.15, a), (rng.random((n, 4)) < 0.05, b)):
            x[m] = rng.choice(odd, int(m.sum()))
        if rng.random() < 0.2:
            b = a.copy()
        with np.errstate(all="ignore"):
            got, want = iou(a, b), _iou_clip_reference(a, b)
        assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
