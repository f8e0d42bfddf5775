"""Batched geometry of symmetric positive-definite (SPD) matrices.

Every function takes arrays of shape ``(..., d, d)`` and broadcasts over the
leading axes. Matrix functions go through one helper, :func:`_eig_apply`
("eigh -> map eigenvalues -> rebuild"), so that ``logm``, ``expm``, ``sqrtm``
and ``invsqrtm`` are one line each.

The metric is the affine-invariant one used by the paper (Tuzel, Porikli &
Meer 2006; Pennec, Fillard & Ayache 2006)::

    d(A, B) = sqrt(sum_k ln^2 lambda_k(A, B))

where ``lambda_k`` are the generalized eigenvalues of ``(B, A)``, computed by a
Cholesky whitening ``L^-1 B L^-T`` with ``A = L L^T``.

References
----------
.. [1] X. Pennec, P. Fillard, N. Ayache, "A Riemannian framework for tensor
   computing", IJCV 66(1), 2006.
.. [2] V. Arsigny, P. Fillard, X. Pennec, N. Ayache, "Geometric means in a novel
   vector space structure on symmetric positive-definite matrices", SIAM J.
   Matrix Anal. Appl. 29(1), 2007.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np

__all__ = [
    "check_spd",
    "distance_jbld",
    "distance_logeuclid",
    "distance_riemann",
    "distance_riemann_log",
    "exp_map",
    "expm",
    "expm_taylor",
    "generalized_eigvals",
    "invsqrtm",
    "jbld",
    "log_map",
    "logdet",
    "logm",
    "mean_logeuclid",
    "mean_riemann",
    "pairwise_distance",
    "powm",
    "regularize",
    "spread_riemann",
    "sqrtm",
    "sym",
]


# --------------------------------------------------------------------------- #
# helpers
# --------------------------------------------------------------------------- #
def sym(A: np.ndarray) -> np.ndarray:
    """Symmetric part ``(A + A^T) / 2`` of a batch of square matrices."""
    return 0.5 * (A + np.swapaxes(A, -1, -2))


def _check_square(A: np.ndarray, name: str = "A") -> np.ndarray:
    A = np.asarray(A, dtype=np.float64)
    if A.ndim < 2 or A.shape[-1] != A.shape[-2]:
        raise ValueError(f"{name} must have shape (..., d, d), got {A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError(f"{name} contains NaN or inf; check the inputs that produced it")
    return A


def check_spd(A: np.ndarray, name: str = "A") -> np.ndarray:
    """Validate a batch of SPD matrices and return it as float64.

    Raises
    ------
    ValueError
        If the shape is not ``(..., d, d)``, entries are non-finite, the matrices
        are not symmetric, or not positive-definite. The message says which.
    """
    A = _check_square(A, name)
    scale = np.maximum(np.abs(A).max(axis=(-1, -2), keepdims=True), np.finfo(float).tiny)
    if np.any(np.abs(A - np.swapaxes(A, -1, -2)) > 1e-8 * scale):
        raise ValueError(f"{name} is not symmetric; symmetrise it with covviz.model.spd.sym")
    w = np.linalg.eigvalsh(A)
    if np.any(w <= 0):
        raise ValueError(
            f"{name} is not positive-definite (smallest eigenvalue {w.min():.3g}); "
            "regularise it with covviz.model.spd.regularize"
        )
    return A


def _eig_apply(A: np.ndarray, fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Apply ``fn`` to the eigenvalues of symmetric ``A`` and rebuild ``V f(w) V^T``.

    The result is symmetrised, so it is exactly symmetric (not only to rounding).
    """
    w, V = np.linalg.eigh(A)
    return sym((V * fn(w)[..., None, :]) @ np.swapaxes(V, -1, -2))


def _positive(w: np.ndarray) -> np.ndarray:
    if np.any(w <= 0):
        raise ValueError(
            f"matrix is not positive-definite (smallest eigenvalue {w.min():.3g}); "
            "regularise it with covviz.model.spd.regularize"
        )
    return w


def _sqrt_invsqrt(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``C^½`` and ``C^-½`` of SPD matrices from one ``eigh`` (the whitening of the maps and means)."""
    w, V = np.linalg.eigh(C)
    w = _positive(w)
    Vt = np.swapaxes(V, -1, -2)
    r = np.sqrt(w)
    return (V * r[..., None, :]) @ Vt, (V * (1.0 / r)[..., None, :]) @ Vt


# --------------------------------------------------------------------------- #
# matrix functions
# --------------------------------------------------------------------------- #
def logm(A: np.ndarray) -> np.ndarray:
    """Principal matrix logarithm of SPD matrices, shape ``(..., d, d)``."""
    return _eig_apply(_check_square(A), lambda w: np.log(_positive(w)))


def expm(S: np.ndarray) -> np.ndarray:
    """Matrix exponential of symmetric matrices (result is SPD), shape ``(..., d, d)``."""
    return _eig_apply(_check_square(S, "S"), np.exp)


def expm_taylor(S: np.ndarray, order: int = 11) -> np.ndarray:
    """Matrix exponential by scaling and squaring of a Taylor polynomial.

    The same result as :func:`expm` (to ~1e-14 relative for symmetric input)
    using only batched matrix products, which for stacks of small matrices is
    several times faster than one ``eigh`` per matrix.
    :func:`distance_riemann_log` uses it for ``expm(-L/2)`` of every
    particle's template.

    The polynomial is evaluated by the Paterson–Stockmeyer scheme: with ``X²``
    and ``X³`` computed once, Horner's rule runs in powers of ``X³`` over
    blocks ``c₀I + c₁X + c₂X²`` (element-wise sums), so degree 11 costs 5
    matrix products instead of 10.

    Parameters
    ----------
    S : ndarray, shape (..., d, d)
        Symmetric matrices.
    order : int
        Degree of the Taylor polynomial, applied after scaling to norm <= 1/4
        (truncation error ``4⁻¹²/12! ≈ 1e-16`` at the default).
    """
    S = _check_square(S, "S")
    if order < 1:
        raise ValueError(f"order must be at least 1, got {order}")
    d = S.shape[-1]
    eye = np.eye(d)
    # expm(S) = e^c expm(S - cI) with c = tr(S)/d: the shift is exact (cI commutes
    # with S) and shrinks the norm, so fewer squarings are needed.
    c = np.trace(S, axis1=-2, axis2=-1)[..., None, None] / d
    S = S - c * eye
    norm = np.abs(S).sum(axis=-1).max() if S.size else 0.0  # largest inf-norm in the batch
    k = max(0, int(np.ceil(np.log2(norm / 0.25)))) if norm > 0.25 else 0
    X = S / 2.0**k
    coef = 1.0 / np.cumprod(np.r_[1.0, np.arange(1.0, order + 1)])  # 1/j!, j = 0..order
    coef = np.r_[coef, np.zeros(-len(coef) % 3)].reshape(-1, 3)  # blocks of 3
    X2 = X @ X
    X3 = X2 @ X

    def block(b):
        return coef[b, 0] * eye + coef[b, 1] * X + coef[b, 2] * X2

    E = block(len(coef) - 1)
    for b in range(len(coef) - 2, -1, -1):  # Horner in X³
        E = block(b) + X3 @ E
    for _ in range(k):
        E = E @ E
    return sym(np.exp(c) * E)


def sqrtm(A: np.ndarray) -> np.ndarray:
    """Principal square root ``A^(1/2)`` of SPD matrices."""
    return _eig_apply(_check_square(A), lambda w: np.sqrt(_positive(w)))


def invsqrtm(A: np.ndarray) -> np.ndarray:
    """Inverse principal square root ``A^(-1/2)`` of SPD matrices."""
    return _eig_apply(_check_square(A), lambda w: 1.0 / np.sqrt(_positive(w)))


def powm(A: np.ndarray, p: float) -> np.ndarray:
    """Matrix power ``A^p`` of SPD matrices."""
    return _eig_apply(_check_square(A), lambda w: _positive(w) ** p)


def regularize(C: np.ndarray, eps: float = 1e-4) -> np.ndarray:
    """Shrink towards a scaled identity so the result is always SPD.

    ``C + eps * (tr(C)/d + tiny) * I``. The ``tiny`` floor (1e-12) keeps an
    all-zero matrix positive-definite.
    """
    C = np.asarray(C, dtype=np.float64)
    d = C.shape[-1]
    tr = np.trace(C, axis1=-2, axis2=-1)[..., None, None] / d
    return C + eps * (tr + 1e-12) * np.eye(d)


# --------------------------------------------------------------------------- #
# distances
# --------------------------------------------------------------------------- #
def _whiten(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``L^-1 B L^-T`` with ``A = L L^T`` (Cholesky), re-symmetrised."""
    try:
        L = np.linalg.cholesky(A)
    except np.linalg.LinAlgError as exc:
        raise ValueError(
            "first argument is not positive-definite; regularise it with covviz.model.spd.regularize"
        ) from exc
    Li = np.linalg.inv(L)  # triangular inverse: cheaper than two batched solves for small d
    return sym(Li @ B @ np.swapaxes(Li, -1, -2))


def generalized_eigvals(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Generalized eigenvalues ``lambda`` of ``B v = lambda A v``, ascending, ``(..., d)``."""
    A = _check_square(A, "A")
    B = _check_square(B, "B")
    return np.linalg.eigvalsh(_whiten(A, B))


def distance_riemann(A: np.ndarray, B: np.ndarray, squared: bool = False) -> np.ndarray:
    """Affine-invariant Riemannian distance, broadcast over leading axes.

    Parameters
    ----------
    A, B : ndarray, shape (..., d, d)
        SPD matrices (broadcastable).
    squared : bool
        Return ``d^2`` instead of ``d``.

    Returns
    -------
    ndarray, shape (...)
        ``sqrt(sum_k ln^2 lambda_k)`` over the generalized eigenvalues of
        ``(B, A)`` (the paper's eq. for ``d(C_i, C_j)``).
    """
    lam = generalized_eigvals(A, B)
    d2 = np.sum(np.log(_positive(lam)) ** 2, axis=-1)
    return d2 if squared else np.sqrt(d2)


def distance_riemann_log(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``d(expm(L), B)`` for symmetric log-space ``L`` and SPD ``B``, shape ``(...)``.

    ``expm(L)^(-1/2) = expm(-L/2) =: E`` exactly, so the generalized
    eigenvalues of the pair are those of ``E B E``: one matrix exponential
    (:func:`expm_taylor`, batched products only), two products and
    ``eigvalsh``. Equal to ``distance_riemann(expm(L), B)`` to ~1e-12 relative
    and cheaper than an ``eigh`` of every ``L`` (the manifold tracker's
    template distances, 600 a frame).

    The Taylor scaling is chosen per batch (the largest norm in it), so a
    distance can differ in the last bits with the batch it is computed in:
    callers that need bit-identical results keep their batches fixed.

    Parameters
    ----------
    L : ndarray, shape (..., d, d)
        Symmetric (a template in log space).
    B : ndarray, shape (..., d, d)
        SPD (an observed descriptor).

    Raises
    ------
    ValueError
        If ``B`` is not positive-definite (a non-positive eigenvalue of ``E B E``).
    """
    E = expm_taylor(-0.5 * np.asarray(L, dtype=np.float64))
    mu = np.linalg.eigvalsh(E @ _check_square(B, "B") @ E)
    return np.sqrt(np.sum(np.log(_positive(mu)) ** 2, axis=-1))


def logdet(A: np.ndarray) -> np.ndarray:
    """``log det A`` of SPD matrices through a Cholesky factor, shape ``(...)``.

    Raises :class:`numpy.linalg.LinAlgError` if a matrix is not positive-definite.
    """
    Lc = np.linalg.cholesky(_check_square(A))
    return 2.0 * np.sum(np.log(np.diagonal(Lc, axis1=-2, axis2=-1)), axis=-1)


def jbld(A: np.ndarray, B: np.ndarray, logdet_a=None, logdet_b=None) -> np.ndarray:
    """Jensen–Bregman LogDet divergence ``log det((A+B)/2) − ½ log det(A B)``.

    A fast stand-in for the squared affine-invariant distance [1]_: in terms of
    the generalized eigenvalues ``λ_k`` of the pair it is
    ``Σ log cosh(½ ln λ_k)``, so it shares the metric's invariances (congruence
    ``W·Wᵀ``, inversion, symmetry) and ``8·J = d²(A, B) + O(d⁴)`` for nearby
    matrices; it costs Cholesky factorisations instead of an eigensolver.

    Parameters
    ----------
    A, B : ndarray, shape (..., d, d)
        SPD matrices (broadcastable).
    logdet_a, logdet_b : ndarray, optional
        Precomputed :func:`logdet` of ``A`` or ``B`` (for a fixed reference).

    Returns
    -------
    ndarray, shape (...), >= 0 up to rounding

    References
    ----------
    .. [1] A. Cherian, S. Sra, A. Banerjee, N. Papanikolopoulos, "Jensen-Bregman
       LogDet divergence with application to efficient similarity search for
       covariance matrices", IEEE TPAMI 35(9), 2013.
    """
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    la = logdet(A) if logdet_a is None else np.asarray(logdet_a)
    lb = logdet(B) if logdet_b is None else np.asarray(logdet_b)
    return logdet(0.5 * (A + B)) - 0.5 * (la + lb)


def distance_jbld(A: np.ndarray, B: np.ndarray, logdet_a=None, logdet_b=None) -> np.ndarray:
    """``sqrt(8·J(A, B))``: the Jensen–Bregman LogDet divergence as a distance, shape ``(...)``.

    Equal to the affine-invariant distance to second order (``8·J = d² + O(d⁴)``,
    see :func:`jbld`), with its invariances, at the cost of Cholesky
    factorisations. The manifold tracker's quadrant distances.

    Raises
    ------
    ValueError
        If ``J`` is negative beyond rounding (``< -1e-9``), which only
        non-SPD input gives.
    """
    J = jbld(A, B, logdet_a=logdet_a, logdet_b=logdet_b)
    if np.any(J < -1e-9):
        raise ValueError(
            f"negative LogDet divergence ({np.min(J):.3g}): an input is not positive-definite; "
            "regularise it with covviz.model.spd.regularize"
        )
    return np.sqrt(8.0 * np.maximum(J, 0.0))


def distance_logeuclid(A: np.ndarray, B: np.ndarray, squared: bool = False) -> np.ndarray:
    """Log-Euclidean distance ``||logm(A) - logm(B)||_F``, shape ``(...)``."""
    D = logm(A) - logm(B)
    d2 = np.sum(D * D, axis=(-1, -2))
    return d2 if squared else np.sqrt(d2)


def pairwise_distance(
    X: np.ndarray,
    Y: np.ndarray | None = None,
    metric: str = "riemann",
    batch_size: int = 4096,
) -> np.ndarray:
    """Matrix of distances between two sets of SPD matrices.

    Parameters
    ----------
    X : ndarray, shape (n, d, d)
    Y : ndarray, shape (m, d, d), optional
        Defaults to ``X``; the result is then exactly symmetric with a zero diagonal.
    metric : {"riemann", "logeuclid"}
    batch_size : int
        Number of pairs evaluated per vectorised call (bounds memory).

    Returns
    -------
    ndarray, shape (n, m)
    """
    X = _check_square(X, "X")
    if X.ndim != 3:
        raise ValueError(f"X must have shape (n, d, d), got {X.shape}")
    if metric not in ("riemann", "logeuclid"):
        raise ValueError(f"unknown metric {metric!r}; use 'riemann' or 'logeuclid'")
    symmetric = Y is None
    if not symmetric:
        Y = _check_square(Y, "Y")
        if Y.ndim != 3 or Y.shape[-1] != X.shape[-1]:
            raise ValueError(f"Y must have shape (m, {X.shape[-1]}, {X.shape[-1]}), got {Y.shape}")
    n = len(X)
    m = n if symmetric else len(Y)
    if symmetric:
        I, J = np.triu_indices(n, k=1)
    else:
        I, J = (a.ravel() for a in np.meshgrid(np.arange(n), np.arange(m), indexing="ij"))
    D = np.zeros((n, m))
    if metric == "logeuclid":
        # Differences of logs, not |a|^2 + |b|^2 - 2ab, which cancels for close pairs.
        LX = logm(X)
        LY = LX if symmetric else logm(Y)
        for s in range(0, len(I), batch_size):
            i, j = I[s : s + batch_size], J[s : s + batch_size]
            E = LX[i] - LY[j]
            D[i, j] = np.sqrt(np.sum(E * E, axis=(-1, -2)))
        return D + D.T if symmetric else D
    # Riemannian: whiten every Y by X_i^{-1/2}, then the eigenvalues.
    Y = X if symmetric else Y
    Xi = invsqrtm(X)
    for s in range(0, len(I), batch_size):
        i, j = I[s : s + batch_size], J[s : s + batch_size]
        M = sym(Xi[i] @ Y[j] @ Xi[i])
        lam = np.linalg.eigvalsh(M)
        D[i, j] = np.sqrt(np.sum(np.log(_positive(lam)) ** 2, axis=-1))
    if symmetric:
        D = D + D.T
    return D


# --------------------------------------------------------------------------- #
# exponential and logarithm maps
# --------------------------------------------------------------------------- #
def exp_map(C: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Riemannian exponential at ``C``: ``C^½ expm(C^-½ Y C^-½) C^½``.

    Parameters
    ----------
    C : ndarray, shape (..., d, d)
        Base point (SPD).
    Y : ndarray, shape (..., d, d)
        Tangent vector (symmetric) at ``C``.
    """
    Cs, Cis = _sqrt_invsqrt(_check_square(C, "C"))
    return sym(Cs @ expm(sym(Cis @ Y @ Cis)) @ Cs)


def log_map(C: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Riemannian logarithm at ``C``: ``C^½ logm(C^-½ P C^-½) C^½``.

    The inverse of :func:`exp_map`; ``||log_map(C, P)||_C = d(C, P)``.
    """
    Cs, Cis = _sqrt_invsqrt(_check_square(C, "C"))
    return sym(Cs @ logm(sym(Cis @ P @ Cis)) @ Cs)


# --------------------------------------------------------------------------- #
# means
# --------------------------------------------------------------------------- #
def mean_logeuclid(C: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Log-Euclidean mean ``expm(sum_i w_i logm(C_i))`` of ``(n, d, d)`` matrices."""
    C = _check_square(C, "C")
    w = _weights(len(C), weights)
    return expm(np.einsum("i,ijk->jk", w, logm(C)))


def mean_riemann(
    C: np.ndarray,
    weights: np.ndarray | None = None,
    tol: float = 1e-9,
    maxiter: int = 100,
    init: np.ndarray | None = None,
    return_iterations: bool = False,
):
    """Karcher (Fréchet) mean under the affine-invariant metric.

    Riemannian gradient descent ``M <- M^½ expm(ν Σ_i w_i logm(M^-½ C_i M^-½)) M^½``
    started at the log-Euclidean mean, with ``ν = 1`` (the classical fixed
    point) halved until the step lowers the cost ``Σ w_i d²(M, C_i)`` enough
    (Armijo backtracking).
    Warns (``RuntimeWarning``) if it has not
    converged after ``maxiter`` iterations.

    Parameters
    ----------
    C : ndarray, shape (n, d, d)
    weights : ndarray, shape (n,), optional
        Non-negative; normalised to sum to one.
    tol : float
        Stop when the Frobenius norm of the mean tangent step is below ``tol``.
    maxiter : int
    init : ndarray, shape (d, d), optional
    return_iterations : bool
        Also return the number of iterations used.
    """
    C = _check_square(C, "C")
    if C.ndim != 3:
        raise ValueError(f"C must have shape (n, d, d), got {C.shape}")
    w = _weights(len(C), weights)
    if maxiter < 1:
        raise ValueError(f"maxiter must be at least 1, got {maxiter}")
    M = mean_logeuclid(C, w) if init is None else check_spd(init, "init")

    def grad(M):
        # Whitened logs L_i = logm(M^-1/2 C_i M^-1/2): their weighted mean is the
        # (whitened) descent direction, and sum w_i |L_i|^2 the cost.
        Ms, Mis = _sqrt_invsqrt(M)
        L = logm(sym(Mis @ C @ Mis))
        cost = float(np.einsum("i,ijk,ijk->", w, L, L))
        return Ms, np.einsum("i,ijk->jk", w, L), cost

    # Riemannian gradient descent with a backtracking step nu: the plain fixed
    # point (nu = 1) oscillates for spread-out data.
    Ms, T, cost = grad(M)
    nu = 1.0
    for it in range(1, maxiter + 1):
        if np.linalg.norm(T) < tol:
            break
        M_new = sym(Ms @ expm(nu * T) @ Ms)
        Ms_new, T_new, cost_new = grad(M_new)
        # Armijo: the cost must fall by a fair share of its first-order decrease
        # 2ν|T|² (the plain fixed point zig-zags and crawls otherwise). Near the
        # optimum that decrease is below rounding; a smaller gradient then decides.
        g2 = float(np.sum(T * T))
        armijo = cost_new <= cost - 0.5 * nu * g2
        rounding = abs(cost_new - cost) <= 1e-8 * cost and float(np.sum(T_new * T_new)) < g2
        if armijo or rounding:
            M, Ms, T, cost = M_new, Ms_new, T_new, cost_new
            nu = min(1.0, 2.0 * nu)
        else:
            nu *= 0.5
            if nu < 1e-10:
                warnings.warn(
                    f"mean_riemann stopped early after {it} iterations: no step lowers the cost "
                    f"(gradient {np.linalg.norm(T):.2e} > tol {tol:.1e}); the mean is as accurate as "
                    "rounding allows here",
                    RuntimeWarning,
                    stacklevel=2,
                )
                break
    else:
        warnings.warn(
            f"mean_riemann did not converge in {maxiter} iterations "
            f"(last step {np.linalg.norm(T):.2e} > tol {tol:.1e})",
            RuntimeWarning,
            stacklevel=2,
        )
    return (M, it) if return_iterations else M


def spread_riemann(C: np.ndarray, init: np.ndarray | None = None, tol: float = 1e-9, maxiter: int = 100):
    """Spread of a set of SPD matrices: their mean affine-invariant distance to the Karcher mean.

    Parameters
    ----------
    C : ndarray, shape (n, d, d)
    init : ndarray, shape (d, d), optional
        Start of :func:`mean_riemann` (e.g. the previous call's mean, for a
        slowly moving set).
    tol, maxiter
        As in :func:`mean_riemann`.

    Returns
    -------
    spread : float
    mean : ndarray, shape (d, d)
        The Karcher mean.
    """
    M = mean_riemann(C, init=init, tol=tol, maxiter=maxiter)
    return float(distance_riemann(M, C).mean()), M


def _weights(n: int, weights: np.ndarray | None) -> np.ndarray:
    if weights is None:
        return np.full(n, 1.0 / n)
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (n,) or np.any(w < 0) or not np.isfinite(w).all() or w.sum() <= 0:
        raise ValueError(f"weights must be {n} non-negative finite numbers with a positive sum")
    return w / w.sum()
