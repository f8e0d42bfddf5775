"""A position-sensitive last step for the estimate: normalised cross-correlation with the target's grey look.

The covariance descriptor forgives small shifts by design (its features are pooled over the whole
region), which makes the particle filter robust, and its estimate loose: on the dev runs the median
centre error while on track was 0.16–0.22 box sizes on Bolt2, Crossing and Football1, where a box of
the same size at the true centre would have had IoU 0.85–0.89 instead of 0.60–0.65. Once the
filter has chosen the region, a correlation of the grey template with a small neighbourhood
(Lewis 1995's normalised cross-correlation, ``cv2.TM_CCOEFF_NORMED``) says where inside it the target
sits. Pure functions of a float32 grey frame; the template is the target's grey patch at the first
box's size, a running mean over the frames where it matched.

The tracker (``ManifoldConfig.ncc_rate``) moves only the box it reports: the particles, their
templates and everything else the filter learns go on from the filter's own estimate. Moving the
particles too was tried and lost tracks (Car4's exit from the overpass's shadow, where the grey
template matched the road; ``docs/tuning.md``).

* :func:`ncc_shift` — the shift of the estimate's centre to the best-correlating place within
  ``radius`` box sizes, sub-pixel (a parabola through the peak and its neighbours), and the peak's
  correlation; no shift where the peak is below ``min_peak`` (the template no longer matches);
* :func:`update_template` — ``T ← (1 − rate)·T + rate·P`` with ``P`` the patch at the refined box,
  resampled to the template's size.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["NCC_MIN", "NCC_RADIUS", "ncc_shift", "patch", "update_template"]

#: The neighbourhood searched: this many box sizes either way, in x and in y.
NCC_RADIUS = 0.25
#: Below this peak correlation the template is not trusted: no shift, no update.
NCC_MIN = 0.5


def patch(gray: np.ndarray, centre, wh, size) -> np.ndarray:
    """The ``w × h`` region centred at ``centre`` resampled to ``size`` = (width, height), float32, bilinear
    (borders replicated)."""
    cx, cy = float(centre[0]), float(centre[1])
    w, h = float(wh[0]), float(wh[1])
    tw, th = int(size[0]), int(size[1])
    sx, sy = w / tw, h / th
    # output pixel (i, j) centre maps to cx - w/2 + (i + 0.5) sx (pixel-centre convention)
    M = np.array([[sx, 0.0, cx - w / 2 + 0.5 * sx - 0.5], [0.0, sy, cy - h / 2 + 0.5 * sy - 0.5]])
    return cv2.warpAffine(gray, M, (tw, th), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


def _parabola(a: float, b: float, c: float) -> float:
    d = a - 2 * b + c
    return 0.0 if d >= 0 else max(-0.5, min(0.5, 0.5 * (a - c) / d))


def ncc_shift(gray: np.ndarray, centre, wh, template: np.ndarray, radius: float = NCC_RADIUS,
              min_peak: float = NCC_MIN) -> tuple[float, float, float]:
    """``(dx, dy, peak)``: the move of ``centre`` to the best match of ``template`` within ``radius``
    box sizes, and its correlation (``(0, 0, peak)`` below ``min_peak``; ``nan`` peak when the box is too
    small to correlate)."""
    w, h = float(wh[0]), float(wh[1])
    tw, th = round(w), round(h)
    if tw < 4 or th < 4 or not (math.isfinite(centre[0]) and math.isfinite(centre[1])):
        return 0.0, 0.0, float("nan")
    mx, my = max(1, math.ceil(radius * w)), max(1, math.ceil(radius * h))
    tpl = cv2.resize(template, (tw, th), interpolation=cv2.INTER_AREA)
    region = patch(gray, centre, (tw + 2 * mx, th + 2 * my), (tw + 2 * mx, th + 2 * my))
    res = cv2.matchTemplate(region, tpl, cv2.TM_CCOEFF_NORMED)
    _, peak, _, (px, py) = cv2.minMaxLoc(res)
    if not peak >= min_peak:
        return 0.0, 0.0, float(peak)
    sx = _parabola(res[py, px - 1], res[py, px], res[py, px + 1]) if 0 < px < res.shape[1] - 1 else 0.0
    sy = _parabola(res[py - 1, px], res[py, px], res[py + 1, px]) if 0 < py < res.shape[0] - 1 else 0.0
    return float(px - mx + sx), float(py - my + sy), float(peak)


def update_template(template: np.ndarray, gray: np.ndarray, centre, wh, rate: float) -> np.ndarray:
    """The running mean of the target's look: ``(1 − rate)·template + rate·patch`` at the box, float32."""
    p = patch(gray, centre, wh, (template.shape[1], template.shape[0]))
    return ((1.0 - rate) * template + rate * p).astype(np.float32)
