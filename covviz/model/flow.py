"""The image motion of a box's content: forward–backward checked pyramidal Lucas–Kanade (Median Flow).

A grid of points inside the box is tracked from frame ``t−1`` to ``t`` and back
(``cv2.calcOpticalFlowPyrLK``); the median forward displacement of the points
that survive both ways is the content's motion, and the median distance
between a point and its round trip, the forward–backward error (Kalal,
Mikolajczyk and Matas, ICPR 2010), says how far to trust it.

Two users: the tracker's motion prior (``ManifoldConfig.flow_share``: a share of
the particles moves with the measured motion, :mod:`covviz.trackers.manifold`)
and the label-free drift signals (``fb_error``, ``fb_fail``, ``flow_gap``:
:mod:`covviz.diagnosis.signals`). Pure functions of two ``uint8`` frames and a
box; deterministic.

The camera's motion, last: the whole scene's shift between two frames by phase
correlation (:func:`camera_frame`, :func:`camera_shift`), for the moving-camera
proposal (``ManifoldConfig.camera_share``).
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from covviz.model.stats import median

__all__ = [
    "FB_GRID", "FLOW_FAIL_MAX", "FLOW_FB_MAX", "LK_LEVELS", "LK_WINDOW", "ROI_MARGIN", "gray8", "median_flow", "trusted",
]

#: Points per side of the grid inside the box.
FB_GRID = 8
#: LK window (pixels) and pyramid levels.
LK_WINDOW = 11
LK_LEVELS = 2
#: The LK region of interest: the box grown by this many box sizes on each side.
ROI_MARGIN = 0.75
#: The motion prior trusts a flow whose forward–backward error (box sizes) is below this ...
FLOW_FB_MAX = 0.5
#: ... and that lost fewer than this share of its points.
FLOW_FAIL_MAX = 0.5


def gray8(frame: np.ndarray) -> np.ndarray:
    """A frame as the ``uint8`` grey image LK reads (RGB is converted; floats in [0, 1] or [0, 255] scaled)."""
    f = np.asarray(frame)
    if f.ndim == 3:
        f = cv2.cvtColor(f if f.dtype == np.uint8 else np.clip(f, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
    elif f.dtype != np.uint8:
        f = np.clip(f * (255.0 if f.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    return f


def median_flow(
    prev: np.ndarray, cur: np.ndarray, box, grid: int = FB_GRID, window: int = LK_WINDOW, levels: int = LK_LEVELS,
    roi_margin: float = ROI_MARGIN,
) -> tuple[float, float, np.ndarray]:
    """Forward–backward LK error and median flow of a point grid inside ``box``.

    Parameters
    ----------
    prev, cur : ndarray, shape (H, W), uint8
        Consecutive grey frames (:func:`gray8`).
    box : array_like, shape (4,)
        ``x, y, w, h`` in ``prev``, pixels (0-based).
    grid, window, levels, roi_margin
        Points per side (placed 10% in from the box's edges), LK window, pyramid
        levels, and the region LK reads: the box grown by ``roi_margin`` box sizes.

    Returns
    -------
    fb : float
        Median forward-backward error of the tracked points, in box sizes ``sqrt(w h)`` (``nan`` if none).
    fail : float
        Share of the points lost forward or backward (1 if the box is off the frame).
    flow : ndarray, shape (2,)
        Median forward displacement of the tracked points, pixels (``nan`` if none).
    """
    nan2 = np.full(2, np.nan)
    x, y, w, h = (float(v) for v in np.asarray(box, dtype=np.float64).reshape(4))
    H, W = prev.shape[:2]
    if not all(map(math.isfinite, (x, y, w, h))) or w <= 1 or h <= 1:
        return float("nan"), 1.0, nan2
    m = roi_margin
    x0, y0 = max(0, math.floor(x - m * w)), max(0, math.floor(y - m * h))
    x1, y1 = min(W, math.ceil(x + w + m * w)), min(H, math.ceil(y + h + m * h))
    # the grid: points inside the box, 10% in from its edges, clipped to the frame
    u = (np.arange(grid) + 0.5) / grid
    gx = np.clip(x + w * (0.1 + 0.8 * u), 0, W - 1)
    gy = np.clip(y + h * (0.1 + 0.8 * u), 0, H - 1)
    pts = np.stack(np.meshgrid(gx, gy), -1).reshape(-1, 2)
    inside = (pts[:, 0] >= x0) & (pts[:, 0] < x1 - 1) & (pts[:, 1] >= y0) & (pts[:, 1] < y1 - 1)
    if x1 - x0 < 8 or y1 - y0 < 8 or inside.sum() < 4:
        return float("nan"), 1.0, nan2
    pts = pts[inside]
    a, b = prev[y0:y1, x0:x1], cur[y0:y1, x0:x1]
    p0 = (pts - (x0, y0)).astype(np.float32).reshape(-1, 1, 2)
    lk = {"winSize": (window, window), "maxLevel": levels,
          "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)}
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(a, b, p0, None, **lk)
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(b, a, p1, None, **lk)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1)
    fail = 1.0 - ok.sum() / (grid * grid)
    if not ok.any():
        return float("nan"), float(fail), nan2
    size = math.sqrt(w * h)
    err = np.hypot(*(p0[ok, 0] - p0b[ok, 0]).T)
    moved = (p1[ok, 0] - p0[ok, 0]).astype(np.float64)
    flow = np.array([median(moved[:, 0]), median(moved[:, 1])])  # np.median(moved, axis=0), bit for bit
    return float(median(err) / size), float(fail), flow


def trusted(fb: float, fail: float, flow: np.ndarray) -> bool:
    """Whether the motion prior may use a :func:`median_flow` result (finite, FB error and losses low)."""
    return bool(np.all(np.isfinite(flow)) and fb < FLOW_FB_MAX and fail < FLOW_FAIL_MAX)


# --------------------------------------------------------------------------- #
# the camera's motion: the whole frame's shift (phase correlation)
# --------------------------------------------------------------------------- #
#: The camera-motion estimate reads the frame downscaled to this many pixels on its longest side.
CAMERA_SIDE = 160
#: It is trusted when phase correlation's peak response is at least this
CAMERA_MIN_RESPONSE = 0.3
#: (on the dev set's frames where the scene shifts by 0.15 target sizes or more, the shift predicts the
#: target's motion better than standing still on 141 of Surfer's 147 such frames and 66 of Couple's 72,
#: at responses of 0.4-0.9) ...
#: ... and the shift is at least this many target sizes (smaller ones the kinematic noise covers).
CAMERA_MIN_SHIFT = 0.15


def camera_frame(frame: np.ndarray) -> tuple[np.ndarray, float]:
    """A frame as the camera-motion estimate reads it: grey, float32, downscaled (area) to :data:`CAMERA_SIDE`
    pixels on its longest side (never upscaled), and the factor from full-resolution pixels to it."""
    g = gray8(frame)
    f = min(1.0, CAMERA_SIDE / max(g.shape[:2]))
    if f < 1.0:
        g = cv2.resize(g, (max(8, round(g.shape[1] * f)), max(8, round(g.shape[0] * f))), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(g, dtype=np.float32), f


@functools.lru_cache(maxsize=8)
def _hanning(width: int, height: int) -> np.ndarray:
    """Phase correlation's window for frames of this size (cached)."""
    return cv2.createHanningWindow((width, height), cv2.CV_32F)


def camera_shift(prev: np.ndarray, cur: np.ndarray, factor: float) -> tuple[float, float, float]:
    """The whole scene's shift from ``prev`` to ``cur`` (:func:`camera_frame` outputs of one size), in
    full-resolution pixels, and phase correlation's peak response (``cv2.phaseCorrelate``, Hanning window).
    Accurate to about a pixel of the downscaled frames (the window and the subpixel fit of the peak bias it)."""
    (dx, dy), response = cv2.phaseCorrelate(prev, cur, _hanning(cur.shape[1], cur.shape[0]))
    return float(dx) / factor, float(dy) / factor, float(response)
