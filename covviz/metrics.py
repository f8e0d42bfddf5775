"""Tracking metrics: IoU, centre error, the OTB curves and the paper's on-track measures.

All functions take ``(n, 4)`` arrays of boxes ``x, y, w, h`` in pixels and never
modify their inputs. Rows of ground truth that are not finite or have a
non-positive size are *invalid*: they are skipped and counted
(``n_skipped``), as OTB does for frames where the target is absent.

References
----------
.. [1] Y. Wu, J. Lim, M.-H. Yang, "Online object tracking: a benchmark",
   CVPR 2013 (success and precision plots).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "IOU_THRESHOLDS",
    "PRECISION_AT",
    "PRECISION_THRESHOLDS",
    "SequenceMetrics",
    "center_error",
    "evaluate",
    "iou",
    "normalized_center_error",
    "nothing_to_score",
    "on_track",
    "precision_curve",
    "success_curve",
    "valid_rows",
]

#: IoU thresholds of the OTB success plot (0, 0.05, ..., 1: 21 values).
IOU_THRESHOLDS = np.linspace(0.0, 1.0, 21)
#: Centre-error thresholds of the OTB precision plot, pixels (0..50).
PRECISION_THRESHOLDS = np.arange(0, 51, dtype=np.float64)
#: The precision reported as a single number: at 20 pixels.
PRECISION_AT = 20.0
#: The paper's on-track threshold on gamma.
ON_TRACK_GAMMA = 1.0


def _boxes(b, name: str) -> np.ndarray:
    b = np.asarray(b, dtype=np.float64)
    if b.ndim == 1:
        b = b[None, :]
    if b.ndim != 2 or b.shape[1] != 4:
        raise ValueError(f"{name} must have shape (n, 4) as x, y, w, h; got {np.shape(b)}")
    return b


def valid_rows(gt: np.ndarray) -> np.ndarray:
    """Boolean mask of ground-truth rows that are finite with positive size, ``(n,)``."""
    gt = _boxes(gt, "gt")
    return np.all(np.isfinite(gt), axis=1) & (gt[:, 2] > 0) & (gt[:, 3] > 0)


def nothing_to_score(gt: np.ndarray) -> bool:
    """True if no frame after the first has ground truth.

    The first frame's box is the one the tracker was given, so metrics over it
    alone (success AUC 0.95, P@20 1.0 …) would only score the user's own box:
    a video with ``--box``, or ``--max-frames 1``.
    """
    return not bool(valid_rows(gt)[1:].any())


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Intersection over union of paired boxes, shape ``(n,)``; 0 where a box is empty."""
    a, b = _pair(a, b)
    x1 = np.maximum(a[:, 0], b[:, 0])
    y1 = np.maximum(a[:, 1], b[:, 1])
    x2 = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2])
    y2 = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3])
    # np.maximum / np.minimum, not np.clip: the same values (NaN stays NaN), at half the cost of a call
    # (the diagnosis calls this three times a frame).
    inter = np.maximum(x2 - x1, 0.0) * np.maximum(y2 - y1, 0.0)
    union = np.maximum(a[:, 2], 0.0) * np.maximum(a[:, 3], 0.0) + np.maximum(b[:, 2], 0.0) * np.maximum(
        b[:, 3], 0.0
    ) - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(union > 0, inter / union, 0.0)
    # NaN to 0 (fmax takes the number), and into [0, 1]: rounding can push inter/union of identical
    # boxes a hair above 1.
    return np.minimum(np.fmax(out, 0.0), 1.0)


def _pair(a, b, na: str = "a", nb: str = "b") -> tuple[np.ndarray, np.ndarray]:
    a, b = _boxes(a, na), _boxes(b, nb)
    if a.shape != b.shape:
        raise ValueError(f"box arrays differ in shape: {a.shape} vs {b.shape}")
    return a, b


def center_error(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance between box centres, pixels, shape ``(n,)``."""
    a, b = _pair(a, b)
    ca = a[:, :2] + a[:, 2:] / 2
    cb = b[:, :2] + b[:, 2:] / 2
    return np.hypot(*(ca - cb).T)


def normalized_center_error(boxes: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """The paper's per-axis normalised errors ``(|e_x|/W_gt, |e_y|/H_gt)``, shape ``(n, 2)``."""
    boxes, gt = _pair(boxes, gt, "boxes", "gt")
    e = np.abs((boxes[:, :2] + boxes[:, 2:] / 2) - (gt[:, :2] + gt[:, 2:] / 2))
    return e / gt[:, 2:]


def success_curve(boxes: np.ndarray, gt: np.ndarray, thresholds=IOU_THRESHOLDS) -> np.ndarray:
    """OTB success curve: fraction of valid frames with IoU > threshold.

    The AUC is the mean of this curve over the 21 thresholds (as OTB's toolkit).
    """
    m = valid_rows(gt)
    if not m.any():
        return np.full(len(thresholds), np.nan)
    o = iou(_boxes(boxes, "boxes")[m], _boxes(gt, "gt")[m])
    return (o[:, None] > np.asarray(thresholds)[None, :]).mean(axis=0)


def precision_curve(boxes: np.ndarray, gt: np.ndarray, thresholds=PRECISION_THRESHOLDS) -> np.ndarray:
    """OTB precision curve: fraction of valid frames with centre error <= threshold."""
    m = valid_rows(gt)
    if not m.any():
        return np.full(len(thresholds), np.nan)
    e = center_error(_boxes(boxes, "boxes")[m], _boxes(gt, "gt")[m])
    return (e[:, None] <= np.asarray(thresholds)[None, :]).mean(axis=0)


def on_track(boxes: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    """The paper's track-duration rate and on-track accuracy.

    A frame is *on track* when ``gamma(t) = ½ (|e_x|/W_gt(t) + |e_y|/H_gt(t)) <= 1``,
    with ``e`` the centre error and ``W_gt, H_gt`` the ground-truth size at ``t``.

    * ``r_on_track`` = on-track frames / valid frames (the sequence length less
      frames without ground truth).
    * ``rms_on_track`` = ``sqrt(mean over on-track frames of ½((e_x/W_gt)² + (e_y/H_gt)²))``,
      the RMS of the normalised centre error.

    The paper prints ``r = gamma / l`` and an RMS with square roots in place of
    squares; both are typos for the definitions above (a ratio of frame counts,
    and a root-mean-square).

    Returns
    -------
    (r_on_track, rms_on_track) : tuple of float
        ``rms_on_track`` is ``nan`` when no frame is on track.
    """
    m = valid_rows(gt)
    if not m.any():
        return float("nan"), float("nan")
    ne = normalized_center_error(_boxes(boxes, "boxes")[m], _boxes(gt, "gt")[m])
    ne = np.nan_to_num(ne, nan=np.inf)
    gamma = ne.mean(axis=1)
    ok = gamma <= ON_TRACK_GAMMA
    r = float(ok.mean())
    rms = float(np.sqrt(np.mean(0.5 * (ne[ok] ** 2).sum(axis=1)))) if ok.any() else float("nan")
    return r, rms


@dataclass(frozen=True)
class SequenceMetrics:
    """Every metric of one run on one sequence (what ``covviz track`` prints and saves)."""

    success_auc: float
    precision_20: float
    mean_iou: float
    mean_iou_nonzero: float
    r_on_track: float
    rms_on_track: float
    mean_center_error: float
    n_frames: int
    n_evaluated: int
    n_skipped: int

    def as_dict(self) -> dict:
        return asdict(self)


def evaluate(boxes: np.ndarray, gt: np.ndarray, skip_first: bool = False) -> SequenceMetrics:
    """All metrics of a run.

    Parameters
    ----------
    boxes, gt : ndarray, shape (n, 4)
    skip_first : bool
        Leave out frame 0 (where the tracker was given the ground truth).
        Off by default, as OTB's one-pass evaluation counts it.
    """
    boxes, gt = _boxes(boxes, "boxes"), _boxes(gt, "gt")
    if boxes.shape != gt.shape:
        raise ValueError(f"boxes {boxes.shape} and ground truth {gt.shape} differ in length")
    if skip_first:
        boxes, gt = boxes[1:], gt[1:]
    m = valid_rows(gt)
    n_eval = int(m.sum())
    o = iou(boxes[m], gt[m]) if n_eval else np.array([])
    ce = center_error(boxes[m], gt[m]) if n_eval else np.array([])
    r, rms = on_track(boxes, gt)
    pc = precision_curve(boxes, gt)
    return SequenceMetrics(
        success_auc=float(np.mean(success_curve(boxes, gt))),
        precision_20=float(pc[int(np.searchsorted(PRECISION_THRESHOLDS, PRECISION_AT))]),
        mean_iou=float(o.mean()) if n_eval else float("nan"),
        mean_iou_nonzero=float(o[o > 0].mean()) if (o > 0).any() else float("nan"),
        r_on_track=r,
        rms_on_track=rms,
        mean_center_error=float(np.nanmean(np.where(np.isfinite(ce), ce, np.nan))) if n_eval else float("nan"),
        n_frames=len(gt),
        n_evaluated=n_eval,
        n_skipped=len(gt) - n_eval,
    )
