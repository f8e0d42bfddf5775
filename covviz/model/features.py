"""Image -> warped patches for a batch of poses -> the paper's 9 per-pixel features.

A pose ``(cx, cy, scale, theta)`` with the target's base size ``(w, h)`` names a
(possibly rotated) region of the frame. :func:`warp_patches` samples every
region onto a ``size x size`` grid (32 x 32 in the paper) by bilinear
interpolation, with a one-pixel border so that derivatives at the patch edge
use real image context. :func:`patch_features` turns those patches into the
feature vectors of the paper's eq. (2)::

    f = [x, y, I, |Ix|, |Iy|, sqrt(Ix² + Iy²), atan(|Ix| / |Iy|), |Ixx|, |Iyy|]

with ``x, y`` the patch coordinates, ``I`` the intensity, and the derivatives
taken on the warped patch (central differences ``[-1, 0, 1]/2`` and
``[1, -2, 1]``).

Feature scales. The affine-invariant distance between descriptors does not
depend on a per-feature scaling (a diagonal congruence), but the
regulariser and the template random walk do; each feature is therefore scaled
by a fixed constant (:data:`FEATURE_SCALE`) so that their variances on natural
images are of the same order (about 0.01 to 0.1).

All arrays are float32 for speed; coordinates are 0-based continuous pixels
(see :mod:`covviz.records`).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

__all__ = [
    "FEATURE_NAMES",
    "FEATURE_SCALE",
    "N_FEATURES",
    "normalize_gradients",
    "patch_features",
    "pose_corners",
    "pose_to_box",
    "remap_stacked",
    "sample_grid",
    "warp_patches",
]

#: OpenCV's remap needs every side of its output below SHRT_MAX (32767): stacked grids go in chunks.
REMAP_MAX_ROWS = 32766

FEATURE_NAMES = ("x", "y", "I", "|Ix|", "|Iy|", "|grad I|", "atan(|Ix|/|Iy|)", "|Ixx|", "|Iyy|")
N_FEATURES = len(FEATURE_NAMES)
#: Fixed per-feature scale (intensity in [0, 1], coordinates in [-1/2, 1/2], angle in [0, 1]).
#: ``|Ix|``, ``|Iy|`` and the magnitude must share one scale.
FEATURE_SCALE = np.array([1.0, 1.0, 1.0, 4.0, 4.0, 4.0, 2.0 / np.pi, 2.0, 2.0], dtype=np.float32)
# _fill_features folds the derivative scales into one doubling of the patch
# (0.5·k[3] == 0.5·k[4] == k[7] == k[8] == 2 and k[3] == k[5]; tested).


def _poses(poses) -> np.ndarray:
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim == 1:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 4:
        raise ValueError(f"poses must have shape (n, 4) as cx, cy, scale, theta; got {np.shape(poses)}")
    return p


def pose_corners(poses, base_wh) -> np.ndarray:
    """Corners of each pose's region, ``(n, 4, 2)``: TL, TR, BR, BL in pixels."""
    p = _poses(poses)
    w, h = float(base_wh[0]), float(base_wh[1])
    q = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    c, s = np.cos(p[:, 3]), np.sin(p[:, 3])
    ox = q[None, :, 0] * w * p[:, 2, None]
    oy = q[None, :, 1] * h * p[:, 2, None]
    x = p[:, 0, None] + c[:, None] * ox - s[:, None] * oy
    y = p[:, 1, None] + s[:, None] * ox + c[:, None] * oy
    return np.stack([x, y], axis=-1)


def pose_to_box(poses, base_wh) -> np.ndarray:
    """Axis-aligned ``x, y, w, h`` of each pose, ignoring rotation, ``(n, 4)``.

    This is how a tracker reports its estimate (OTB boxes are axis-aligned and
    annotated unrotated); the rotated region is in :func:`pose_corners`.
    """
    p = _poses(poses)
    w = base_wh[0] * p[:, 2]
    h = base_wh[1] * p[:, 2]
    return np.stack([p[:, 0] - w / 2, p[:, 1] - h / 2, w, h], axis=1)


@functools.lru_cache(maxsize=8)
def _unit_grid(size: int, border: int) -> np.ndarray:
    """Rows ``1, qx, qy`` of the unit sampling grid, ``(3, g·g)`` (read-only, cached)."""
    g = size + 2 * border
    q = (np.arange(-border, size + border, dtype=np.float64) + 0.5) / size - 0.5
    qy, qx = np.meshgrid(q, q, indexing="ij")
    basis = np.stack([np.ones(g * g), qx.ravel(), qy.ravel()])
    basis.flags.writeable = False
    return basis


def sample_grid(poses, base_wh, size: int = 32, border: int = 1, step: float = 1.0):
    """Sampling coordinates of every pose's grid, for :func:`cv2.remap`.

    Grid point ``(u, v)``, ``u, v = -border … size-1+border``, of a pose sits at
    ``c + R(theta) · scale · (w·qu, h·qv)`` with ``q = (u + ½)/size − ½``, so the
    ``size x size`` interior tiles the region exactly.

    Parameters
    ----------
    poses : ndarray, shape (n, 4)
    base_wh : (float, float)
        Width and height of the region at scale 1, pixels.
    size, border : int
    step : float or (float, float)
        The image was downsampled by this factor (coordinates are divided by
        it); a pair gives the x and y factors separately.

    Returns
    -------
    map_x, map_y : ndarray, shape (n, size + 2·border, size + 2·border), float32
        Pixel-centre coordinates (continuous coordinate − ½), as cv2.remap wants.
    """
    p = _poses(poses)
    g = size + 2 * border
    sx, sy = (step, step) if np.isscalar(step) else step
    # Every grid is an affine image of the unit grid (1, qx, qy): one small
    # product gives all of them, in the frame's (possibly downsampled) pixels.
    c, s = np.cos(p[:, 3]), np.sin(p[:, 3])
    sw, sh = base_wh[0] * p[:, 2], base_wh[1] * p[:, 2]
    ax = np.stack([p[:, 0] / sx - 0.5, c * sw / sx, -s * sh / sx], axis=1)
    ay = np.stack([p[:, 1] / sy - 0.5, s * sw / sy, c * sh / sy], axis=1)
    basis = _unit_grid(size, border)
    mx = (ax @ basis).astype(np.float32).reshape(-1, g, g)
    my = (ay @ basis).astype(np.float32).reshape(-1, g, g)
    return mx, my


def remap_stacked(
    gray: np.ndarray,
    map_x: np.ndarray,
    map_y: np.ndarray,
    border: int = cv2.BORDER_REPLICATE,
    border_value: float = 0.0,
) -> np.ndarray:
    """Bilinear samples of ``gray`` at a stack of grids, by ``cv2.remap`` in as few calls as it allows.

    Parameters
    ----------
    gray : ndarray, shape (H, W)
        The image (converted to float32).
    map_x, map_y : ndarray, shape (n, g, g2), float32
        Pixel-centre coordinates of every grid point (continuous coordinate − ½).
    border : int
        OpenCV border mode for samples outside the image.
    border_value : float
        The value outside with ``cv2.BORDER_CONSTANT``.

    Returns
    -------
    ndarray, shape (n, g, g2), float32

    Notes
    -----
    The grids are stacked vertically into one image-sized map; OpenCV caps
    each side of its output at ``SHRT_MAX``, so more than
    ``REMAP_MAX_ROWS // g`` grids go in several calls (each grid whole, so
    every sample is computed the same way whatever the batch).
    """
    n, g, g2 = map_x.shape
    src = np.ascontiguousarray(gray, dtype=np.float32)
    out = np.empty((n * g, g2), np.float32)
    if n == 0:
        return out.reshape(0, g, g2)
    mx = np.ascontiguousarray(map_x, dtype=np.float32).reshape(n * g, g2)
    my = np.ascontiguousarray(map_y, dtype=np.float32).reshape(n * g, g2)
    rows = (REMAP_MAX_ROWS // g) * g
    if rows < g:
        raise ValueError(f"a grid of {g} rows exceeds OpenCV's remap limit of {REMAP_MAX_ROWS}")
    for r in range(0, n * g, rows):
        cv2.remap(
            src,
            mx[r : r + rows],
            my[r : r + rows],
            cv2.INTER_LINEAR,
            dst=out[r : r + rows],
            borderMode=border,
            borderValue=border_value,
        )
    return out.reshape(n, g, g2)


def warp_patches(gray: np.ndarray, poses, base_wh, size: int = 32, border: int = 1, step: float = 1.0):
    """Bilinear warp of every pose's region to a ``(size+2b) x (size+2b)`` patch.

    The grids of all poses are sampled together (:func:`remap_stacked`, in
    chunks under OpenCV's size limit). Samples outside the frame replicate the
    border pixel.

    Parameters
    ----------
    gray : ndarray, shape (H, W), float32
        Frame intensities (in [0, 1]), possibly downsampled by ``step``.
    poses : ndarray, shape (n, 4)
    base_wh : (float, float)

    Returns
    -------
    ndarray, shape (n, size + 2·border, size + 2·border), float32
    """
    mx, my = sample_grid(poses, base_wh, size, border, step)
    return remap_stacked(gray, mx, my, cv2.BORDER_REPLICATE)


def patch_features(
    patches: np.ndarray, border: int = 1, gain_normalize: bool = False, quadrants: bool = False
) -> np.ndarray:
    """The 9 per-pixel features of the interior of each patch.

    Parameters
    ----------
    patches : ndarray, shape (n, S + 2, S + 2), float32
        Warped patches with a one-pixel border (``border`` must be 1).
    gain_normalize : bool
        Divide the intensity and derivative features of each patch by its mean
        intensity, which makes the descriptor invariant to a multiplicative
        illumination change ``I -> g·I`` (the paper's features are not: a gain
        rescales six of the nine, all but ``x, y`` and the angle).
    quadrants : bool
        Return the pixels grouped by quadrant (``S`` must be even), the layout
        :func:`covviz.model.descriptor.quadrant_covariances` reads without a copy.
        The values are those of the default layout, pixel for pixel.

    Returns
    -------
    ndarray, float32
        ``(n, 9, S·S)``: features along axis 1 (in :data:`FEATURE_NAMES`
        order, scaled by :data:`FEATURE_SCALE`), pixels along axis 2
        (row-major). With ``quadrants``, ``(n, 4, 9, (S/2)²)``: quadrants
        top-left, top-right, bottom-left, bottom-right, each row-major. The
        array is a view of a feature-major buffer (the fastest layout to fill).

    Notes
    -----
    Two features are shifted, which leaves their covariance unchanged but keeps
    the float32 second moments accurate: the coordinates are centred
    (``x, y`` in ``[-½, ½]``) and the intensity has its patch mean removed.
    """
    if border != 1:
        raise ValueError("patch_features needs patches with a one-pixel border")
    P = np.asarray(patches, dtype=np.float32)
    if P.ndim != 3 or P.shape[1] != P.shape[2] or P.shape[1] < 3:
        raise ValueError(f"patches must have shape (n, S+2, S+2); got {P.shape}")
    n, g, _ = P.shape
    S = g - 2
    if quadrants and S % 2:
        raise ValueError(f"quadrants need an even patch side, got {S}")
    if gain_normalize:
        # Mean of the interior; the floor keeps black patches finite.
        gain = P[:, 1:-1, 1:-1].mean(axis=(1, 2), keepdims=True)
        P = P * (1.0 / np.maximum(gain, 1e-3))
    mean = P[:, 1:-1, 1:-1].mean(axis=(1, 2), keepdims=True)
    u = (np.arange(S, dtype=np.float32) + 0.5) / S - 0.5
    if not quadrants:
        F = np.empty((N_FEATURES, n, S, S), dtype=np.float32)
        F[0] = u[None, None, :] * FEATURE_SCALE[0]
        F[1] = u[None, :, None] * FEATURE_SCALE[1]
        _fill_features(F, P, mean)
        return F.reshape(N_FEATURES, n, S * S).transpose(1, 0, 2)
    # Quadrant sub-patches with their one-pixel borders (a copy of the small
    # intensity patches, not of the nine feature planes), the whole patch's
    # coordinates and intensity mean, so that the quadrants' pixels are
    # exactly those of the default layout.
    h = S // 2
    Pq = np.empty((n, 4, h + 2, h + 2), dtype=np.float32)
    for q, (r, c) in enumerate(((0, 0), (0, h), (h, 0), (h, h))):
        Pq[:, q] = P[:, r : r + h + 2, c : c + h + 2]
    F = np.empty((N_FEATURES, n, 4, h, h), dtype=np.float32)
    halves = u.reshape(2, h)  # coordinates of the first and the second half of a side
    F[0] = (halves[[0, 1, 0, 1], None, :] * FEATURE_SCALE[0])[None]
    F[1] = (halves[[0, 0, 1, 1], :, None] * FEATURE_SCALE[1])[None]
    _fill_features(F.reshape(N_FEATURES, 4 * n, h, h), Pq.reshape(4 * n, h + 2, h + 2), np.repeat(mean, 4, axis=0))
    return F.reshape(N_FEATURES, n, 4, h * h).transpose(1, 2, 0, 3)


def normalize_gradients(F: np.ndarray, power: float = 1.0, floor: float = 0.0) -> np.ndarray:
    """Features with their derivatives divided by the patch's mean: ``|Ix|, |Iy|, |grad I|`` by the mean
    ``|grad I|``, ``|Ixx|, |Iyy|`` by their mean, each to ``power`` (a new array).

    ``F`` is :func:`patch_features`' output, ``(n, 9, P)`` or, by quadrant,
    ``(n, 4, 9, P)`` (the means are then over the whole patch). The
    magnitude of a derivative depends on how finely the region is sampled:
    a target that shrinks to half its size is warped from half the pixels,
    so its edges span twice as many patch samples and its derivatives per
    sample halve, while a box grown around it keeps sharper ones. Dividing by
    the patch's own mean makes the descriptor invariant to that (and to the
    contrast), keeping the derivatives' spatial layout and correlations.
    A ``power`` below 1 keeps part of the absolute magnitude (how textured
    the patch is). ``floor`` bounds the first derivatives' divisor from
    below: the mean ``|grad I|`` is taken as at least ``floor``, so a
    textureless patch keeps its small absolute derivatives instead of having
    its noise amplified (the second derivatives' mean is floored at 1e-6 only:
    a floor there, half of ``floor``, cost Surfer more than it gave VOT15_bag).
    """
    F = np.array(F, dtype=np.float32, copy=True)
    G = F if F.ndim == 4 else F[:, None]  # (n, regions, 9, P), a view
    g1 = np.maximum(G[:, :, 5].astype(np.float64).mean(axis=(1, 2)), max(float(floor), 1e-6)) ** power
    g2 = np.maximum(G[:, :, 7:9].astype(np.float64).mean(axis=(1, 2, 3)), 1e-6) ** power
    G[:, :, 3:6] /= g1[:, None, None, None].astype(np.float32)
    G[:, :, 7:9] /= g2[:, None, None, None].astype(np.float32)
    return F


def _fill_features(F: np.ndarray, P: np.ndarray, mean: np.ndarray) -> None:
    """Features 2–8 of bordered patches ``P`` ``(m, s+2, s+2)`` into ``F[2:]`` ``(9, m, s, s)``.

    ``mean`` ``(m, 1, 1)``: the intensity each patch's ``I`` feature is centred on.
    """
    k = FEATURE_SCALE
    C = P[:, 1:-1, 1:-1]
    np.subtract(C, mean, out=F[2])
    if k[2] != 1.0:
        F[2] *= k[2]
    # The four derivative planes are all scaled by 2 (0.5·k[3] for |Ix| and
    # |Iy|, k[7] for |Ixx| and |Iyy|). Doubling the small patch once is exact
    # in binary floating point, so the differences of the doubled patch are
    # the scaled derivatives bit for bit, without a scaling pass per plane.
    P2 = P * np.float32(2.0)
    C4 = P2[:, 1:-1, 1:-1] * np.float32(2.0)
    # |Ix|, |Iy|: central differences [-1, 0, 1] / 2, scaled.
    np.subtract(P2[:, 1:-1, 2:], P2[:, 1:-1, :-2], out=F[3])
    np.subtract(P2[:, 2:, 1:-1], P2[:, :-2, 1:-1], out=F[4])
    np.abs(F[3], out=F[3])
    np.abs(F[4], out=F[4])
    # sqrt(Ix² + Iy²) (k[3] == k[4] == k[5], so the scaled magnitude is exact).
    # Not cv2.magnitude: called from concurrent threads its results vary in the last bit.
    np.multiply(F[3], F[3], out=F[5])
    F[5] += F[4] * F[4]
    np.sqrt(F[5], out=F[5])
    # atan(|Ix| / |Iy|) in [0, pi/2], defined where Iy == 0.
    np.arctan2(F[3], F[4], out=F[6])
    F[6] *= k[6]
    # |Ixx|, |Iyy|: [1, -2, 1], scaled.
    np.add(P2[:, 1:-1, 2:], P2[:, 1:-1, :-2], out=F[7])
    np.add(P2[:, 2:, 1:-1], P2[:, :-2, 1:-1], out=F[8])
    F[7] -= C4
    F[8] -= C4
    np.abs(F[7], out=F[7])
    np.abs(F[8], out=F[8])
