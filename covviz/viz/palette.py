"""Colours and colour ramps of the recording (the paper's palette for the template cloud).

Green generated templates, red target, blue background, as in the paper's
figures; one colour per tracker; the particles' weight ramp and the
likelihood map's colours.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

__all__ = [
    "BACKGROUND_COLOR",
    "GT_COLOR",
    "INITIAL_COLOR",
    "LIKELIHOOD_RANGE_NATS",
    "LUT",
    "N_WEIGHT_LEVELS",
    "SERIES_COLORS",
    "TEMPLATE_COLOR",
    "TOP_COLOR",
    "TRACKER_COLORS",
    "WEIGHT_FLOOR",
    "likelihood_rgba",
    "tracker_color",
    "weight_levels",
    "weight_lut",
]

# Colours (RGB[A]). The cloud uses the paper's: green generated templates, red target, blue background.
GT_COLOR = (235, 64, 52)
TOP_COLOR = (40, 235, 90)
TEMPLATE_COLOR = (150, 215, 150, 170)
BACKGROUND_COLOR = (50, 120, 255)
INITIAL_COLOR = (255, 255, 255)
TRACKER_COLORS = {
    "manifold": (255, 196, 0),
    "manifold-paper": (190, 255, 60),
    "ipca": (0, 210, 255),
    "identity": (190, 190, 190),
    "csrt": (255, 105, 180),
    "kcf": (170, 120, 255),
    "mil": (255, 140, 0),
    "mosse": (0, 160, 160),
    "medianflow": (240, 240, 240),
    "tld": (150, 150, 255),
}
FALLBACK_COLORS = [(255, 196, 0), (0, 210, 255), (255, 105, 180), (170, 120, 255), (255, 140, 0)]
SERIES_COLORS = {
    "ess": (255, 196, 0),
    "max": (255, 90, 90),
    "survivors": (120, 200, 255),
    "resampled": (255, 255, 255),
    "min": (40, 235, 90),
    "mean": (255, 196, 0),
    "spread": (200, 120, 255),
    "evidence": (255, 130, 0),
    "redetected": (0, 220, 220),
    "pull_light": (255, 240, 120),
    "pull_look": (200, 160, 255),
    "drift": (255, 60, 60),
    "lost": (255, 0, 0),
    "recovered": (40, 235, 90),
}
#: Levels of the weight colour ramp of the particles ...
N_WEIGHT_LEVELS = 16
#: ... on a log scale of w / w_max from this value (level 0 and below) to 1 (the top level).
WEIGHT_FLOOR = 1e-3


def weight_levels(w: np.ndarray) -> np.ndarray:
    """Colour level 0..N_WEIGHT_LEVELS-1 of each weight, by ``log10(w / w_max)`` from WEIGHT_FLOOR to 0."""
    wn = np.asarray(w, dtype=np.float64) / np.max(w)
    with np.errstate(divide="ignore"):
        t = 1.0 - np.log10(np.maximum(wn, 1e-300)) / np.log10(WEIGHT_FLOOR)
    return np.clip(np.floor(t * (N_WEIGHT_LEVELS - 1) + 0.5), 0, N_WEIGHT_LEVELS - 1).astype(np.int64)


def weight_lut(n: int = N_WEIGHT_LEVELS, hi=(120, 255, 150)) -> np.ndarray:
    """RGBA ramp from dark and transparent (negligible weight) to ``hi``, opaque (max weight).

    Green for the first tracker with particles (the paper's colour for generated templates);
    a second one ramps to its own colour, so the two clouds can be told apart.
    """
    t = np.linspace(0.0, 1.0, n)[:, None]
    hi = np.asarray(hi, dtype=float)
    lo = 0.3 * hi
    rgb = lo + (hi - lo) * t
    a = 20 + 150 * t  # even the heaviest outlines let the frame show through
    return np.concatenate([rgb, a], axis=1).round().astype(np.uint8)


#: The weight ramp of the first tracker with particles.
LUT = weight_lut()


def tracker_color(name: str, index: int) -> tuple:
    """The colour of a tracker: its own (:data:`TRACKER_COLORS`), else one of a fallback cycle by position."""
    return TRACKER_COLORS.get(name, FALLBACK_COLORS[index % len(FALLBACK_COLORS)])


#: The likelihood map shows log-likelihoods from this many nats below the best position (transparent)
#: to the best (bright): the likelihood itself (σ = 0.3) is a single bright pixel.
LIKELIHOOD_RANGE_NATS = 20.0


def likelihood_rgba(log_lik: np.ndarray, range_nats: float = LIKELIHOOD_RANGE_NATS,
                    floor_alpha: int = 0) -> np.ndarray:
    """Relative log-likelihood (<= 0) -> RGBA: inferno colours, from ``floor_alpha`` far below the best."""
    v = np.nan_to_num(np.clip(1.0 + np.asarray(log_lik) / range_nats, 0.0, 1.0))
    rgb = colormap_rgb((v * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)
    a = (floor_alpha + (200 - min(floor_alpha, 200)) * np.sqrt(v)).astype(np.uint8)
    return np.concatenate([rgb, a[..., None]], axis=2)


def colormap_rgb(u8: np.ndarray, cmap: int) -> np.ndarray:
    """OpenCV's colour map ``cmap`` (``cv2.COLORMAP_*``) of 8-bit values, RGB: ``cv2.applyColorMap`` as a table.

    The same colours as ``cv2.applyColorMap(u8, cmap)[..., ::-1]``; OpenCV builds its 256-entry table
    on every call (~0.3 ms, whatever the image: the recorder's 9x9 heatmaps paid it twice a frame).
    """
    return _colormap_table(int(cmap))[np.asarray(u8, dtype=np.uint8)]


@functools.lru_cache(maxsize=8)
def _colormap_table(cmap: int) -> np.ndarray:
    table = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], cmap)[:, 0, ::-1].copy()
    table.setflags(write=False)
    return table
