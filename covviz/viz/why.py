"""The views that explain a failure: evidence series, frame labels, zoom, likelihood slices, heatmaps.

Everything here draws what :mod:`covviz.diagnosis.drift` and :mod:`covviz.viz.diagnostics`
computed; the logger (:mod:`covviz.viz.logger`) decides when. Static parts
(series styles, axis labels, colour bars) are logged once per tracker by
:func:`log_static`.

Coordinates of the small 2-D "plots" (slices, heatmaps) are their own: each
lives in its own Spatial2D view (see :mod:`covviz.viz.blueprint`).
"""

from __future__ import annotations

import cv2
import numpy as np
import rerun as rr

from covviz.diagnosis.drift import FrameEvidence
from covviz.model.features import FEATURE_NAMES
from covviz.viz import paths as P
from covviz.viz.diagnostics import LikelihoodSlices
from covviz.viz.palette import colormap_rgb

__all__ = [
    "DIFF_RANGE",
    "LABEL_STYLE",
    "LOG_RANGE",
    "SERIES",
    "heatmap_image",
    "log_evidence",
    "log_slices",
    "log_static",
    "zoom_image",
]

#: Evidence series on the "why off track" plot: name -> (label, line width, brightness of the tracker colour).
SERIES = {
    "best_truth": ("best d at truth", 2.0, 1.0),
    "best_est": ("best d at estimate", 2.0, 0.55),
    "d_truth": ("est. template at truth", 1.0, 1.0),
    "d_est": ("est. template at estimate", 1.0, 0.55),
}
#: Frame labels as markers on that plot (only off-track frames): label -> (marker, colour).
LABEL_STYLE = {
    "model": ("Cross", (255, 80, 80)),
    "search": ("Up", (90, 170, 255)),
    "estimate": ("Diamond", (255, 200, 60)),
}
#: Colour scale of the template and observed heatmaps (log-space entries) ...
LOG_RANGE = (-4.0, 3.0)
#: ... and of their difference (diverging, 0 in the middle).
DIFF_RANGE = (-1.5, 1.5)
#: Cells of gap between the three heatmaps, and screen pixels per cell in the view's underlay.
GAP = 2.0
HEAT_CELL = 16
#: Colour of the text of axis labels (a label is drawn in its point's colour).
TEXT_COLOR = (200, 200, 200)
#: Slices plot: x extent of each panel and the d_eff drawn at the bottom (y grows downwards).
SLICE_WIDTH = 100.0
SLICE_GAP = 30.0
SLICE_D_MAX = 10.0
SLICE_HEIGHT = 60.0


def _shade(color, k: float) -> tuple:
    return tuple(round(c * k) for c in color[:3])


# --------------------------------------------------------------------------- #
# static parts
# --------------------------------------------------------------------------- #
def log_static(rec: rr.RecordingStream, p: P.TrackerPaths, name: str, color, with_model: bool) -> None:
    """Series styles, label markers, heatmap axes and colour bars, slice axes of one tracker.

    ``name`` goes before each series name: ``""`` alone, ``"<tracker> "`` in a recording of several.
    """
    rec.log(p.why_series("reach"), rr.SeriesLines(colors=[_shade(color, 0.8)], names=[f"{name}best particle IoU"],
                                                   widths=[1.0]), static=True)
    if not with_model:
        return
    for key, (label, width, k) in SERIES.items():
        rec.log(p.why_series(key), rr.SeriesLines(colors=[_shade(color, k)], names=[f"{name}{label}"], widths=[width]),
                static=True)
    for label, (marker, col) in LABEL_STYLE.items():
        rec.log(p.why_label(label), rr.SeriesPoints(colors=[col], names=[f"{name}{label} failure"], markers=[marker],
                                                    marker_sizes=[4.0]), static=True)
    for key, label in (("gap", "target gap / usual"), ("margin", "bg margin (>0 ok)"), ("stress", "MDS stress")):
        rec.log(f"{p.cloud_health}/{key}", rr.SeriesLines(colors=[_shade(color, 0.6 if key != "gap" else 1.0)],
                                                           names=[f"{name}{label}"], widths=[1.5]), static=True)
    _log_heatmap_axes(rec, p)
    _log_slice_axes(rec, p, color)


def heatmap_underlay() -> tuple[np.ndarray, tuple[float, float]]:
    """The static part of the heatmap view, drawn once: titles, feature names, colour bars and their ticks.

    Text drawn into an image scales with the view (labels logged as points keep their screen size
    and pile up on nine rows of small cells). Returns the RGB image and the pixel offset where
    the per-frame heatmaps (:func:`heatmap_image`, one image pixel per cell) go, scaled by
    :data:`HEAT_CELL`.
    """
    n = len(FEATURE_NAMES)
    c, gap = HEAT_CELL, int(GAP * HEAT_CELL)
    left, top = 78, 26
    w_panels = 3 * n * c + 2 * gap
    H, W = top + n * c + 50, left + w_panels + 12
    img = np.full((H, W, 3), 14, np.uint8)
    font, white = cv2.FONT_HERSHEY_SIMPLEX, (215, 215, 215)
    for k, title in enumerate(("template logm(C)", "observed logm(C*)", "difference")):
        x0 = left + k * (n * c + gap)
        (tw, _), _ = cv2.getTextSize(title, font, 0.42, 1)
        cv2.putText(img, title, (x0 + (n * c - tw) // 2, top - 9), font, 0.42, white, 1, cv2.LINE_AA)
    for i, f in enumerate(FEATURE_NAMES):
        (tw, th), _ = cv2.getTextSize(f, font, 0.38, 1)
        cv2.putText(img, f, (left - 6 - tw, top + i * c + (c + th) // 2), font, 0.38, white, 1, cv2.LINE_AA)
    y_bar = top + n * c + 8
    w_log = 2 * n * c + gap
    img[y_bar : y_bar + 8, left : left + w_log] = _viridis(np.linspace(0, 1, w_log))[None]
    x_diff = left + 2 * (n * c + gap)
    img[y_bar : y_bar + 8, x_diff : x_diff + n * c] = _diverging(np.linspace(-1, 1, n * c))[None]
    for x, t in ((left, f"{LOG_RANGE[0]:g}"), (left + w_log, f"{LOG_RANGE[1]:g}"), (x_diff, f"{DIFF_RANGE[0]:g}"),
                 (x_diff + n * c // 2, "0"), (x_diff + n * c, f"+{DIFF_RANGE[1]:g}")):
        (tw, _), _ = cv2.getTextSize(t, font, 0.38, 1)
        cv2.putText(img, t, (int(np.clip(x - tw // 2, 0, W - tw)), y_bar + 24), font, 0.38, white, 1, cv2.LINE_AA)
    cv2.putText(img, "rows and columns: the 9 features, in this order", (left, H - 6), font, 0.36, (150, 150, 150), 1,
                cv2.LINE_AA)
    return img, (float(left), float(top))


def _log_heatmap_axes(rec, p: P.TrackerPaths) -> None:
    under, (x0, y0) = heatmap_underlay()
    rec.log(f"{p.heatmap}/axes", rr.Image(under, color_model="RGB", draw_order=-10.0), static=True)
    rec.log(f"{p.heatmap}/image", rr.Transform3D(translation=[x0, y0, 0.0], scale=[HEAT_CELL, HEAT_CELL, 1.0]),
            static=True)
    rec.log(f"{p.heatmap}/image", rr.Image.from_fields(draw_order=0.0, magnification_filter="Nearest"), static=True)


#: The slices' underlay: its extent in the view's units and pixels per unit (text drawn into an image
#: scales with the view, so a small panel shrinks its labels instead of piling them up).
SLICE_UNDERLAY = (-22.0, -20.0, 2 * SLICE_WIDTH + SLICE_GAP + 12.0, SLICE_HEIGHT + 20.0)
SLICE_PX = 4


def slice_underlay(color=(255, 196, 0), truth_color=(235, 64, 52)) -> np.ndarray:
    """The static part of the slices view as an RGB image: axes' names, the d scale, and the colour key."""
    x0, y0, x1u, y1u = SLICE_UNDERLAY
    k = SLICE_PX
    W, H = int((x1u - x0) * k), int((y1u - y0) * k)
    img = np.full((H, W, 3), 14, np.uint8)
    font, white = cv2.FONT_HERSHEY_SIMPLEX, (215, 215, 215)

    def px(x, y):
        return int((x - x0) * k), int((y - y0) * k)

    def text(t, x, y, col=white, centre=True, size=0.9):
        (tw, th), _ = cv2.getTextSize(t, font, size, 2)
        u, v = px(x, y)
        cv2.putText(img, t, (u - (tw // 2 if centre else 0), v + th // 2), font, size, col, 2, cv2.LINE_AA)

    xr = SLICE_WIDTH + SLICE_GAP
    text("scale x0.6 .. x1.67", SLICE_WIDTH / 2, SLICE_HEIGHT + 10)
    text("rotation -20 .. +20 deg", xr + SLICE_WIDTH / 2, SLICE_HEIGHT + 10)
    text("d 10", -11, 2)
    text("d 0", -11, SLICE_HEIGHT - 2)
    for label, col, x in (("at the estimate's centre", color, 0.0), ("at the truth's centre", truth_color, xr)):
        u, v = px(x, -12)
        cv2.line(img, (u, v), (u + 12 * k, v), tuple(int(c) for c in col[:3]), 4, cv2.LINE_AA)
        text(label, x + 15, -12, centre=False)
    return img


def _log_slice_axes(rec, p: P.TrackerPaths, color=(255, 196, 0), truth_color=(235, 64, 52)) -> None:
    x1 = SLICE_WIDTH + SLICE_GAP
    axes = [
        [(0, SLICE_HEIGHT), (SLICE_WIDTH, SLICE_HEIGHT)], [(0, 0), (0, SLICE_HEIGHT)],
        [(x1, SLICE_HEIGHT), (x1 + SLICE_WIDTH, SLICE_HEIGHT)], [(x1, 0), (x1, SLICE_HEIGHT)],
        [(SLICE_WIDTH / 2, 0), (SLICE_WIDTH / 2, SLICE_HEIGHT)], [(x1 + SLICE_WIDTH / 2, 0), (x1 + SLICE_WIDTH / 2, SLICE_HEIGHT)],
    ]
    rec.log(f"{p.slices}/axes", rr.LineStrips2D(axes, colors=[(110, 110, 110)], radii=[0.3], draw_order=1.0), static=True)
    ux, uy = SLICE_UNDERLAY[:2]
    rec.log(f"{p.slices}/underlay", rr.Transform3D(translation=[ux, uy, 0.0], scale=[1 / SLICE_PX, 1 / SLICE_PX, 1.0]),
            rr.Image(slice_underlay(color, truth_color), color_model="RGB", draw_order=-10.0), static=True)


# --------------------------------------------------------------------------- #
# per frame
# --------------------------------------------------------------------------- #
def log_evidence(series, p: P.TrackerPaths, ev: FrameEvidence, with_model: bool) -> None:
    """The per-frame evidence of the diagnosis: the likelihood at the truth and the estimate, reach, label.

    ``series`` is the recorder's :class:`~covviz.viz.series.SeriesBuffer` (the values go out with its
    other per-frame scalars, as columns).
    """
    if np.isfinite(ev.reach):
        series.add(p.why_series("reach"), ev.reach)
    if not with_model:
        return
    for key in SERIES:
        v = getattr(ev, key)
        if np.isfinite(v):
            series.add(p.why_series(key), float(v))
    # Each part of d_eff² at the truth minus at the estimate (> 0: that part preferred the estimate's place).
    for k, v in (ev.term_gaps or {}).items():
        if np.isfinite(v):
            series.add(p.why_series(f"gap_{k}"), float(v))
    if ev.label in LABEL_STYLE and np.isfinite(ev.best_truth):
        series.add(p.why_label(ev.label), float(ev.best_truth))


def zoom_image(patches: list[np.ndarray | None], gap: int = 2) -> np.ndarray:
    """Grey patches (``[0, 1]`` floats, each ``(S, S)`` or None) side by side, uint8, with dark gaps."""
    S = next((q.shape[0] for q in patches if q is not None), 32)
    cols = []
    for q in patches:
        tile = np.zeros((S, S), np.uint8) if q is None else np.clip(np.asarray(q) * 255.0, 0, 255).astype(np.uint8)
        cols += [tile, np.full((S, gap), 24, np.uint8)]
    return np.concatenate(cols[:-1], axis=1)


def _clip_nan0(v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """``np.clip(np.nan_to_num(v), lo, hi)`` (NaN -> 0, ±inf -> the bounds) without nan_to_num's Python (~6 µs a call)."""
    u = np.clip(v, lo, hi)
    u[np.isnan(u)] = 0.0
    return u


def _viridis(v: np.ndarray) -> np.ndarray:
    u = _clip_nan0(v, 0.0, 1.0)
    return colormap_rgb((u * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)


def _diverging(v: np.ndarray) -> np.ndarray:
    """-1 .. 1 -> blue .. light grey .. red."""
    u = _clip_nan0(v, -1.0, 1.0)[..., None]
    blue, mid, red = np.array([40, 90, 255.0]), np.array([225, 225, 225.0]), np.array([255, 60, 40.0])
    out = np.where(u < 0, mid + (blue - mid) * (-u), mid + (red - mid) * u)
    return out.astype(np.uint8)


def heatmap_image(template_log: np.ndarray, observed_log: np.ndarray) -> np.ndarray:
    """Template, observation and difference (log space) as one RGB image, 9 rows, fixed colour scales."""
    lo, hi = LOG_RANGE
    a = _viridis((template_log - lo) / (hi - lo))
    b = _viridis((observed_log - lo) / (hi - lo))
    c = _diverging((observed_log - template_log) / DIFF_RANGE[1])
    g = np.zeros((template_log.shape[0], int(GAP), 3), np.uint8)
    return np.concatenate([a, g, b, g, c], axis=1)


def slices_note(every: int) -> str:
    """What the slices view says on the frames it has no curves (``every``: the likelihood map's period)."""
    when = f"frames 1, {1 + every}, {1 + 2 * every}, …" if every > 0 else "no regular frame"
    return f"drawn on {when} and around losses"  # short: the view is narrow


def log_slices_note(rec: rr.RecordingStream, p: P.TrackerPaths, text: str) -> None:
    """The note of an empty slices view, at its centre (cleared by :func:`log_slices`)."""
    rec.log(f"{p.slices}/note", rr.Points2D([[SLICE_WIDTH + SLICE_GAP / 2, SLICE_HEIGHT / 2]], labels=[text],
                                            radii=[0.0], colors=[(200, 200, 200, 255)], show_labels=True))


def _slice_curve(x0: float, values: np.ndarray) -> np.ndarray:
    x = x0 + np.linspace(0.0, SLICE_WIDTH, len(values))
    y = SLICE_HEIGHT * (1.0 - np.clip(np.asarray(values, dtype=np.float64) / SLICE_D_MAX, 0.0, 1.0))
    return np.stack([x, y], axis=1)


def log_slices(
    rec: rr.RecordingStream, p: P.TrackerPaths, at_estimate: LikelihoodSlices | None, at_truth: LikelihoodSlices | None,
    color, truth_color,
) -> None:
    """Curves of ``d_eff`` along scale (left) and rotation (right), at the estimate and at the truth."""
    x1 = SLICE_WIDTH + SLICE_GAP
    rec.log(f"{p.slices}/note", rr.Clear(recursive=False))  # the curves are here: no note of their absence
    for key, sl, col in (("estimate", at_estimate, color), ("truth", at_truth, truth_color)):
        path = f"{p.slices}/{key}"
        if sl is None:
            rec.log(path, rr.Clear(recursive=False))
            continue
        strips = [_slice_curve(0.0, sl.d_scale), _slice_curve(x1, sl.d_angle)]
        rec.log(path, rr.LineStrips2D(strips, colors=[col], radii=[0.6], draw_order=5.0))
