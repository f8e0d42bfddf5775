"""A foreground/background colour term: how well a box separates the target's colours from its surroundings.

The discriminative half of Staple (Bertinetto et al., CVPR 2016) and CSR-DCF
(Lukežič et al., CVPR 2017), as a separate factor of the manifold tracker's
likelihood. Two colour histograms are kept online: one of the target box (the
foreground), one of a ring around it (the background). Their per-class
densities give every pixel near the target the probability that its colour is
the target's,

    ``P(x) = h_fg(b(x)) / (h_fg(b(x)) + h_bg(b(x)))``

(``b(x)`` the colour bin of pixel ``x``; 0.5 where neither histogram has
seen the colour). A box ``B`` is scored by the foreground mass it gathers
minus the background it takes in,

    ``F(B) = Σ_{x ∈ B} (P(x) − ½)``,

which is largest for the box that holds exactly the pixels more likely
target than background: a box that is too large takes in background
(``P < ½``), one that is too small leaves target outside. The term of the
likelihood is ``t(B) = (F* − F(B)) / A``, ``F* = Σ_window max(P − ½, 0)`` the
best any box could gather in the window around the previous estimate and
``A`` the previous estimate's area: ``t ≥ 0``, 0 for a box that gathers every
target-coloured pixel and nothing else, and the same for every box when the
histograms cannot tell target from background (``P ≈ ½`` everywhere).

Everything here is a pure function of a frame and a :class:`ColourModel`, the
tracker's online state (the histograms and the window), which is a frozen
dataclass replaced every frame: a diagnosis given the state can ask what the
term would say at any pose.

Grey frames (and colour frames whose channels are equal) use an intensity
histogram; colour frames a joint RGB histogram of ``bins³`` cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    "ColourMap",
    "ColourModel",
    "box_sums",
    "colour_bins",
    "colour_map",
    "colour_term",
    "foreground_lut",
    "init_colour_model",
    "update_colour_model",
    "window_probabilities",
]

#: Histogram bins per colour channel (joint RGB: ``bins³`` cells) ...
COLOUR_BINS = 16
#: ... and of the intensity of grey frames.
GREY_BINS = 32
#: The background ring: the box grown by this factor of its size on each side (Staple pads by (w+h)/2 in all).
RING_PAD = 0.5
#: The window the term is computed over: the previous estimate grown to this multiple of its size.
WINDOW_FACTOR = 4.0
_COLOUR_SHIFT = 8 - int(np.log2(COLOUR_BINS))
_GREY_SHIFT = 8 - int(np.log2(GREY_BINS))
if 2 ** (8 - _COLOUR_SHIFT) != COLOUR_BINS or 2 ** (8 - _GREY_SHIFT) != GREY_BINS:  # pragma: no cover
    raise ImportError("COLOUR_BINS and GREY_BINS must be powers of two (colour_bins shifts)")
#: The contrast (total-variation distance of the histograms) at which a reliability-scaled term has gain 1.
CONTRAST_REF = 0.5
#: Prior density added to both classes in every bin, so a colour neither has seen gets P = ½.
PRIOR = 1e-6


def _is_grey(frame: np.ndarray) -> bool:
    f = np.asarray(frame)
    if f.ndim == 2:
        return True
    if f.ndim == 3 and f.shape[2] == 1:
        return True
    # Decoders give grey JPEGs three equal channels; a sparse check is enough to tell.
    s = f[::7, ::7]
    return bool(np.array_equal(s[..., 0], s[..., 1]) and np.array_equal(s[..., 0], s[..., 2]))


def colour_bins(frame: np.ndarray, grey: bool) -> np.ndarray:
    """The histogram bin of every pixel, ``(H, W)`` int32.

    Parameters
    ----------
    frame : ndarray, shape (H, W) or (H, W, 3), uint8 (or float in [0, 1])
    grey : bool
        Intensity bins (:data:`GREY_BINS`) instead of joint RGB bins
        (:data:`COLOUR_BINS` per channel).
    """
    f = np.asarray(frame)
    if f.dtype != np.uint8:
        f = np.clip(np.asarray(f, dtype=np.float32) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    if grey:
        g = f if f.ndim == 2 else f[..., 0]
        return (g >> _GREY_SHIFT).astype(np.intp)
    # (r·b >> 8, g·b >> 8, b·b >> 8) for b = 2^k bins: shifts, in 16 bits (half the time of int32 products).
    q = f >> _COLOUR_SHIFT
    k = 8 - _COLOUR_SHIFT
    return ((q[..., 0].astype(np.uint16) << (2 * k)) | (q[..., 1].astype(np.uint16) << k) | q[..., 2]).astype(np.intp)


def _n_bins(grey: bool) -> int:
    return GREY_BINS if grey else COLOUR_BINS**3


def _kernels_for(frame, compiled: bool):
    """The compiled kernels module when ``compiled`` and the frame is what they read (a C-contiguous
    ``(H, W, 3)`` uint8 image), else None (the numpy path: the same values, bit for bit)."""
    if not compiled:
        return None
    f = frame
    if not (isinstance(f, np.ndarray) and f.dtype == np.uint8 and f.ndim == 3 and f.shape[2] == 3
            and f.flags.c_contiguous):
        return None
    from covviz.model import kernels

    return kernels if kernels.JIT_ENABLED else None


@dataclass(frozen=True, slots=True, eq=False)
class ColourModel:
    """The colour term's online state: replaced (never mutated) every frame.

    Attributes
    ----------
    fg, bg : ndarray, shape (bins,)
        Foreground and background colour densities (each sums to 1, or is 0
        when its region was empty).
    box : ndarray, shape (4,)
        The estimate they were last updated at, ``x, y, w, h`` pixels: the
        window of the next frame's term is centred on it.
    grey : bool
        Intensity histogram (grey frames) instead of RGB.
    """

    fg: np.ndarray
    bg: np.ndarray
    box: np.ndarray
    grey: bool

    @property
    def contrast(self) -> float:
        """Total-variation distance of the two densities, in [0, 1]: 0 when colour cannot tell them apart."""
        return float(0.5 * np.abs(self.fg - self.bg).sum())


def _readonly(a):
    a = np.array(a, dtype=np.float64)
    a.flags.writeable = False
    return a


def _box_and_ring_histograms(frame: np.ndarray, box, grey: bool, compiled: bool = False):
    """Colour counts of ``box`` and of the ring around it (the box grown by :data:`RING_PAD`), clipped to the frame.

    Only the ring's bounding rectangle of ``frame`` is binned; ``compiled``: in one pass of a compiled
    kernel (:func:`covviz.model.kernels.colour_counts_fast`: the same counts).
    """
    H, W = np.shape(frame)[:2]
    x, y, w, h = (float(v) for v in box)
    pad = RING_PAD * (w + h) / 2
    X0, Y0 = int(np.clip(round(x - pad), 0, W)), int(np.clip(round(y - pad), 0, H))
    X1, Y1 = int(np.clip(round(x + w + pad), 0, W)), int(np.clip(round(y + h + pad), 0, H))
    x0, y0 = int(np.clip(round(x), X0, X1)), int(np.clip(round(y), Y0, Y1))
    x1, y1 = int(np.clip(round(x + w), X0, X1)), int(np.clip(round(y + h), Y0, Y1))
    n_bins = _n_bins(grey)
    k = _kernels_for(frame, compiled)
    if k is not None:
        a, t = k.colour_counts_fast(frame, (X0, Y0, X1, Y1), (x0, y0, x1, y1), grey, _COLOUR_SHIFT, _GREY_SHIFT,
                                    n_bins)
        fg = a.astype(np.float64)
        return fg, np.maximum(t.astype(np.float64) - fg, 0.0)
    bins = colour_bins(np.asarray(frame)[Y0:Y1, X0:X1], grey)
    inner = bins[y0 - Y0 : y1 - Y0, x0 - X0 : x1 - X0].ravel()
    outer = bins.ravel()
    fg = np.bincount(inner, minlength=n_bins).astype(np.float64)
    bg = np.bincount(outer, minlength=n_bins).astype(np.float64) - fg
    return fg, np.maximum(bg, 0.0)


def _density(counts: np.ndarray) -> np.ndarray:
    return counts / max(float(counts.sum()), 1.0)


def init_colour_model(frame: np.ndarray, box, compiled: bool = False) -> ColourModel:
    """The colour state at the initial box ``x, y, w, h`` (0-based pixels); ``compiled``: counted by a kernel."""
    grey = _is_grey(frame)
    fg, bg = _box_and_ring_histograms(frame, box, grey, compiled)
    return ColourModel(_readonly(_density(fg)), _readonly(_density(bg)), _readonly(np.asarray(box, float)), grey)


def update_colour_model(state: ColourModel, frame: np.ndarray, box, rate: float,
                        compiled: bool = False) -> ColourModel:
    """``state`` blended towards the histograms observed at ``box`` with learning ``rate`` (Staple: 0.04);
    ``compiled``: counted by a kernel (the same state, bit for bit)."""
    fg, bg = _box_and_ring_histograms(frame, box, state.grey, compiled)
    return ColourModel(
        _readonly((1 - rate) * state.fg + rate * _density(fg)),
        _readonly((1 - rate) * state.bg + rate * _density(bg)),
        _readonly(np.asarray(box, float)),
        state.grey,
    )


def foreground_lut(state: ColourModel) -> np.ndarray:
    """``P − ½`` of every colour bin, ``(bins,)``: the foreground probability of the module docstring, centred."""
    return (state.fg + PRIOR) / (state.fg + state.bg + 2 * PRIOR) - 0.5


@dataclass(frozen=True, slots=True, eq=False)
class ColourMap:
    """A frame's foreground probability around the previous estimate, ready for box sums.

    Attributes
    ----------
    origin : (int, int)
        ``x0, y0`` of the window in the frame, pixels.
    integral : ndarray, shape (h + 1, w + 1)
        Integral image of ``P − ½`` over the window (float64).
    best : float
        ``F*``: the sum of ``max(P − ½, 0)`` over the window.
    area : float
        ``A``: the area of the previous estimate, pixels².
    gain : float
        Factor of the term: 1, or with a reliability exponent ``r``,
        ``(contrast / CONTRAST_REF)**r`` (the histograms' power to tell target
        from background, as CSRT weighs its channels by their reliability).
    """

    origin: tuple[int, int]
    integral: np.ndarray
    best: float
    area: float
    gain: float = 1.0


def window_probabilities(frame: np.ndarray, window, lut: np.ndarray, grey: bool, compiled: bool = False) -> np.ndarray:
    """``lut`` at every pixel's colour bin in ``window`` = ``(X0, Y0, X1, Y1)`` of ``frame``, ``(Y1 - Y0, X1 - X0)``;
    ``compiled``: in one pass of a kernel (the same values)."""
    X0, Y0, X1, Y1 = (int(v) for v in window)
    k = _kernels_for(frame, compiled)
    if k is not None:
        return k.colour_window_fast(frame, X0, Y0, X1, Y1, grey, _COLOUR_SHIFT, _GREY_SHIFT, lut, False)[0]
    return lut[colour_bins(np.asarray(frame)[Y0:Y1, X0:X1], grey)]


def colour_map(frame: np.ndarray, state: ColourModel, reliability: float = 0.0, compiled: bool = False) -> ColourMap:
    """The foreground probability of ``frame`` in the window around ``state.box`` (:data:`WINDOW_FACTOR`).

    ``reliability`` > 0 scales the term by ``(state.contrast / CONTRAST_REF)**reliability``.
    ``compiled``: the bins, the probabilities and their integral image in one pass of a compiled kernel
    (:func:`covviz.model.kernels.colour_window_fast`), the same map bit for bit, without the numpy
    path's five window-sized temporaries.
    """
    H, W = np.shape(frame)[:2]
    x, y, w, h = (float(v) for v in state.box)
    cx, cy = x + w / 2, y + h / 2
    half = WINDOW_FACTOR * np.sqrt(w * h) / 2 + max(w, h) / 2
    X0, Y0 = int(np.clip(np.floor(cx - half), 0, W - 1)), int(np.clip(np.floor(cy - half), 0, H - 1))
    X1, Y1 = int(np.clip(np.ceil(cx + half), X0 + 1, W)), int(np.clip(np.ceil(cy + half), Y0 + 1, H))
    lut = foreground_lut(state)
    k = _kernels_for(frame, compiled)
    if k is not None:
        P, integral = k.colour_window_fast(frame, X0, Y0, X1, Y1, state.grey, _COLOUR_SHIFT, _GREY_SHIFT, lut)
    else:
        P = window_probabilities(frame, (X0, Y0, X1, Y1), lut, state.grey)
        integral = cv2.integral(P, sdepth=cv2.CV_64F)
    gain = (state.contrast / CONTRAST_REF) ** reliability if reliability > 0 else 1.0
    return ColourMap((X0, Y0), integral, float(np.maximum(P, 0.0).sum()), max(w * h, 1.0), float(gain))


def box_sums(integral: np.ndarray, origin, boxes: np.ndarray) -> np.ndarray:
    """Sums of the window's values over axis-aligned ``boxes`` ``(n, 4)`` (frame pixels), ``(n,)``.

    Boxes are rounded to whole pixels and clipped to the window; what falls
    outside it counts 0 (neutral).
    """
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    h, w = integral.shape[0] - 1, integral.shape[1] - 1
    x0 = np.clip(np.rint(b[:, 0] - origin[0]), 0, w).astype(np.intp)
    y0 = np.clip(np.rint(b[:, 1] - origin[1]), 0, h).astype(np.intp)
    x1 = np.clip(np.rint(b[:, 0] + b[:, 2] - origin[0]), 0, w).astype(np.intp)
    y1 = np.clip(np.rint(b[:, 1] + b[:, 3] - origin[1]), 0, h).astype(np.intp)
    x1, y1 = np.maximum(x1, x0), np.maximum(y1, y0)
    return integral[y1, x1] - integral[y0, x1] - integral[y1, x0] + integral[y0, x0]


def colour_term(cmap: ColourMap, boxes: np.ndarray) -> np.ndarray:
    """``t = (F* − F(B)) / A ≥ 0`` of each box ``(n, 4)``, ``(n,)`` (see the module docstring)."""
    t = np.maximum(cmap.best - box_sums(cmap.integral, cmap.origin, boxes), 0.0) / cmap.area
    return t if cmap.gain == 1.0 else cmap.gain * t
