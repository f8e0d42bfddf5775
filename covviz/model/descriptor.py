"""Features -> regularised covariance descriptors (the paper's eq. 1).

``C = 1/(N-1) Σ (f_i − f̄)(f_i − f̄)ᵀ`` over the ``N = S·S`` pixels of each
patch, then ``C + ε·(tr C / d)·I`` so that every descriptor is SPD (a constant
patch, whose intensity and derivative features have zero variance, gives a
well-defined matrix instead of a singular one).

References
----------
.. [1] O. Tuzel, F. Porikli, P. Meer, "Region covariance: a fast descriptor for
   detection and classification", ECCV 2006.
"""

from __future__ import annotations

import numpy as np

from covviz.model.features import patch_features, warp_patches
from covviz.model.spd import regularize, sym

__all__ = ["DEFAULT_EPS", "QUADRANTS", "covariance", "descriptors", "quadrant_covariances"]

#: Default shrinkage of :func:`covariance` (fraction of the mean variance added to the diagonal).
DEFAULT_EPS = 1e-3


def covariance(features: np.ndarray, eps: float = DEFAULT_EPS) -> np.ndarray:
    """Unbiased, regularised covariance of each feature set.

    Parameters
    ----------
    features : ndarray, shape (n, d, N)
        ``d`` features of ``N`` pixels per patch (as :func:`patch_features` returns).
    eps : float
        Shrinkage towards ``(tr C / d)·I``; 0 gives the plain unbiased covariance.

    Returns
    -------
    ndarray, shape (n, d, d), float64
        Symmetric positive-definite when ``eps > 0``.
    """
    F = np.asarray(features)
    if F.ndim != 3 or F.shape[2] < 2:
        raise ValueError(f"features must have shape (n, d, N) with N >= 2; got {F.shape}")
    M, s = _moments(F)
    return _finish(M, s, F.shape[2], eps)


def _moments(F: np.ndarray):
    """Raw second moments ``F Fᵀ`` and sums ``F 1`` over the last axis, float64."""
    # Raw second moments in one batched product (float32), mean correction in
    # float64 (_finish). Cheaper than centring the array first; accurate when
    # the features are roughly centred, as patch_features makes them.
    M = np.matmul(F, np.swapaxes(F, -1, -2)).astype(np.float64)
    # einsum's own summation loop, not a BLAS product (BLAS splits long float32
    # sums differently by thread count, and the last bits would follow), and
    # not np.sum (pairwise: 3-6x slower here).
    s = np.einsum("...dk->...d", F).astype(np.float64)
    return M, s


def _finish(M: np.ndarray, s: np.ndarray, N: int, eps: float) -> np.ndarray:
    """Unbiased covariance of ``N`` samples from raw moments, then regularised (and surely SPD)."""
    mu = s / N
    C = sym((M - N * mu[..., :, None] * mu[..., None, :]) / (N - 1))
    return _surely_spd(regularize(C, eps)) if eps > 0 else C


def _surely_spd(C: np.ndarray) -> np.ndarray:
    """``C`` unchanged when every matrix has a Cholesky factor; else those that have none lifted.

    The raw moments are float32 sums: on a nearly flat patch (a dark or
    clipped region, gain-normalised), their cancellation can leave an error
    larger than a small shrinkage ``eps``, and the matrix a hair short of
    positive-definite. Those (and only those: every other result stays
    bit-identical) get ``(-λ_min + 1e-9·tr/d)·I`` added.
    """
    try:
        np.linalg.cholesky(C)
        return C
    except np.linalg.LinAlgError:
        pass
    C = C.copy()
    flat = C.reshape(-1, *C.shape[-2:])
    d = C.shape[-1]
    for k in range(len(flat)):
        try:
            np.linalg.cholesky(flat[k])
        except np.linalg.LinAlgError:
            lam = np.linalg.eigvalsh(flat[k])
            tiny = 1e-9 * max(float(np.trace(flat[k])) / d, np.finfo(float).tiny)
            flat[k] += (max(0.0, -lam[0]) + tiny) * np.eye(d)
    return C


#: The four sub-regions of :func:`quadrant_covariances`, in order.
QUADRANTS = ("top-left", "top-right", "bottom-left", "bottom-right")


def quadrant_covariances(features: np.ndarray, eps: float = DEFAULT_EPS):
    """Covariance of the whole patch and of each of its four quadrants.

    The sub-region covariances of Porikli, Tuzel and Meer [2]_: one whole-region
    descriptor says *what* the region holds, but little about *where*; the
    quadrants' descriptors pin the layout down. The whole region's moments are
    the sums of the quadrants', so the five descriptors cost one pass of raw
    moments.

    Parameters
    ----------
    features : ndarray, shape (n, 4, d, (S/2)²) or (n, d, S·S)
        Features by quadrant, as ``patch_features(..., quadrants=True)``
        returns them (no copy), or of the whole patch in row-major pixel order
        (``S`` even; regrouped by quadrant with one copy).
    eps : float
        Shrinkage, as in :func:`covariance`.

    Returns
    -------
    whole : ndarray, shape (n, d, d)
        Equal to :func:`covariance` up to float32 summation order.
    quadrants : ndarray, shape (n, 4, d, d)
        In :data:`QUADRANTS` order.

    References
    ----------
    .. [2] F. Porikli, O. Tuzel, P. Meer, "Covariance tracking using model
       update based on Lie algebra", CVPR 2006.
    """
    F = np.asarray(features)
    if F.ndim == 4 and F.shape[1] == 4:
        Q = F
    elif F.ndim == 3:
        n, d, N = F.shape
        S = round(np.sqrt(N))
        if S * S != N or S % 2 or S < 4:
            raise ValueError(f"quadrant_covariances needs an S x S patch with S even and >= 4; got {N} pixels")
        h = S // 2
        # (n, d, row-half, row, col-half, col) -> (n, quadrant, d, pixel), one copy.
        Q = np.ascontiguousarray(F.reshape(n, d, 2, h, 2, h).transpose(0, 2, 4, 1, 3, 5)).reshape(n, 4, d, h * h)
    else:
        raise ValueError(f"features must have shape (n, 4, d, P) or (n, d, S*S); got {F.shape}")
    if Q.shape[-1] < 2:
        raise ValueError(f"quadrants need at least 2 pixels each; got {Q.shape[-1]}")
    M, s = _moments(Q)
    N = 4 * Q.shape[-1]
    return _finish(M.sum(axis=1), s.sum(axis=1), N, eps), _finish(M, s, Q.shape[-1], eps)


def descriptors(
    gray: np.ndarray, poses, base_wh, size: int = 32, eps: float = DEFAULT_EPS, step=1.0, gain_normalize: bool = False
):
    """Covariance descriptors of the regions of a batch of poses, ``(n, 9, 9)``.

    Warps each region to ``size x size`` (:func:`~covviz.model.features.warp_patches`),
    computes the 9 features and their regularised covariance.
    """
    P = warp_patches(gray, poses, base_wh, size, 1, step)
    return covariance(patch_features(P, gain_normalize=gain_normalize), eps)
