"""2-D pictures of sets of SPD matrices: MDS of Riemannian distance matrices, aligned frame to frame.

The paper's figures place covariance descriptors and templates in the plane by
multidimensional scaling (MDS) of their affine-invariant distance matrix. This
module holds the pure maths (no plotting, no rerun):

* :func:`distance_matrix` — pairwise Riemannian distances, in batches
  (:func:`covviz.model.spd.pairwise_distance`);
* :func:`classical_mds` — Torgerson's classical MDS (double centring and the
  top eigenvectors): deterministic, one partial ``eigh``. Our own, not
  scikit-learn's ``ClassicalMDS`` (1.8+): that one takes every eigenpair and
  the square root of the top eigenvalues unclipped, so Riemannian (not
  Euclidean) distances with fewer than two positive eigenvalues give NaN
  coordinates, where ours clips them to 0;
* :func:`smacof_mds` — metric MDS by SMACOF (the Guttman transform of
  :func:`sklearn.manifold.smacof`, written out here and checked against it),
  started from the classical solution, so it is deterministic; it keeps tight
  clouds open where classical MDS flattens them;
* :func:`procrustes_align` — the rotation/reflection and translation (no
  scaling: distances keep their meaning) that best maps one embedding onto a
  reference, fitted on the points the two share;
* :class:`AlignedMDS` — embeds a new distance matrix every call and aligns it
  to the previous call's embedding through "anchor" points that have the same
  identity (key) in both, so that points do not flip or spin from frame to
  frame.

References
----------
.. [1] W. S. Torgerson, "Multidimensional scaling: I. Theory and method",
   Psychometrika 17, 1952 (classical MDS).
.. [2] J. de Leeuw, "Applications of convex analysis to multidimensional
   scaling", 1977 (SMACOF).
.. [3] P. H. Schönemann, "A generalized solution of the orthogonal Procrustes
   problem", Psychometrika 31, 1966.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np

from covviz.model.spd import invsqrtm, pairwise_distance

__all__ = [
    "AlignedMDS",
    "classical_mds",
    "coverage",
    "distance_matrix",
    "embed",
    "procrustes_align",
    "silhouette",
    "silhouette_by_group",
    "smacof_mds",
    "stress",
    "stress1",
]


def _check_distances(D: np.ndarray) -> np.ndarray:
    D = np.asarray(D, dtype=np.float64)
    if D.ndim != 2 or D.shape[0] != D.shape[1]:
        raise ValueError(f"a distance matrix must be square (n, n), got shape {D.shape}")
    if not np.all(np.isfinite(D)):
        raise ValueError("the distance matrix contains NaN or inf; check the matrices it was computed from")
    if np.any(D < 0):
        raise ValueError("the distance matrix has negative entries")
    if not np.allclose(D, D.T, atol=1e-9 * max(1.0, float(D.max(initial=0.0)))):
        raise ValueError("the distance matrix is not symmetric")
    return 0.5 * (D + D.T)


def distance_matrix(C: np.ndarray, metric: str = "riemann", batch_size: int = 4096) -> np.ndarray:
    """Pairwise distances of SPD matrices, shape ``(n, n)``, zero diagonal.

    Parameters
    ----------
    C : ndarray, shape (n, d, d)
        SPD matrices (descriptors, or templates after ``expm``).
    metric : {"riemann", "logeuclid"}
    batch_size : int
        Pairs per vectorised call (bounds memory).
    """
    C = np.asarray(C, dtype=np.float64)
    if metric == "riemann" and C.ndim == 3 and C.shape[1:] == (9, 9) and len(C) > 1:
        from covviz.model import kernels

        if kernels.JIT_ENABLED:
            # The compiled Jacobi on the whitened pairs (covviz.model.kernels.pair_distances_fast): the
            # same distances to ~1e-13, 2.8x faster than numpy's eigvalsh on 1 275 9x9 pairs (2.4 against 6.6 ms).
            I, J = np.triu_indices(len(C), k=1)
            D = np.zeros((len(C), len(C)))
            D[I, J] = kernels.pair_distances_fast(invsqrtm(C), C, I, J)
            return D + D.T
    return pairwise_distance(C, metric=metric, batch_size=batch_size)


def classical_mds(D: np.ndarray, n_components: int = 2) -> np.ndarray:
    """Classical (Torgerson) MDS of a distance matrix.

    ``B = -½ J D² J`` with the centring matrix ``J``; the coordinates are the
    top ``n_components`` eigenvectors of ``B`` scaled by the square roots of
    their (clipped non-negative) eigenvalues. For Euclidean distances this
    recovers the configuration exactly, up to a rigid motion.

    Parameters
    ----------
    D : ndarray, shape (n, n)
        Symmetric non-negative distances.
    n_components : int

    Returns
    -------
    ndarray, shape (n, n_components)
        Centred coordinates, in the units of ``D``. The sign of each axis is
        fixed so that its largest-magnitude coordinate is positive
        (deterministic output).
    """
    D = _check_distances(D)
    n = len(D)
    if n_components < 1:
        raise ValueError(f"n_components must be at least 1, got {n_components}")
    X = np.zeros((n, n_components))
    if n < 2:
        return X
    D2 = D * D
    # Double centring without forming J: B = -1/2 (D2 - row means - col means + grand mean).
    r = D2.mean(axis=1)
    B = -0.5 * (D2 - r[:, None] - r[None, :] + r.mean())
    k = min(n_components, n)
    # numpy's eigh, not scipy.linalg's partial one: importing scipy.linalg cost a recorded run
    # ~0.15 s of start-up, and at the recorder's sizes (n ~ 100) the full solve is ~1 ms.
    w, V = np.linalg.eigh(B)
    w, V = np.clip(w[::-1][:k], 0.0, None), V[:, ::-1][:, :k]  # the top k, largest first
    X[:, :k] = V * np.sqrt(w)
    # Deterministic signs.
    idx = np.argmax(np.abs(X), axis=0)
    signs = np.sign(X[idx, np.arange(n_components)])
    signs[signs == 0] = 1.0
    return X * signs


def stress(X: np.ndarray, D: np.ndarray) -> float:
    """Raw stress ``Σ_{i<j} (||x_i - x_j|| - D_ij)²`` of an embedding."""
    d = np.sqrt(((X[:, None, :] - X[None, :, :]) ** 2).sum(axis=-1))
    return 0.5 * float(((d - D) ** 2).sum())


def stress1(X: np.ndarray, D: np.ndarray) -> float:
    """Kruskal's stress-1 ``sqrt(Σ (||x_i - x_j|| - D_ij)² / Σ D_ij²)``: 0 perfect, 0.1 fair, 0.2 poor.

    How much of the distances a 2-D picture misrepresents: a picture with a
    high stress is not to be read as a map.
    """
    D = np.asarray(D, dtype=np.float64)
    den = float((D * D).sum())
    return float(np.sqrt(2.0 * stress(X, D) / den)) if den > 0 else 0.0


def silhouette(D: np.ndarray, labels) -> float:
    """Mean silhouette of ``labels`` on the distance matrix ``D`` itself (not on an embedding).

    ``(b - a) / max(a, b)`` per point, ``a`` its mean distance to its own group,
    ``b`` to the nearest other group (:func:`sklearn.metrics.silhouette_score`
    with ``metric="precomputed"``): 1 far apart, 0 touching, < 0 mixed. Below
    0.25 a grouping has "no substantial structure" (Kaufman & Rousseeuw,
    *Finding Groups in Data*, 1990).

    Parameters
    ----------
    D : ndarray, shape (n, n)
    labels : array-like, shape (n,)
        At least two groups, at most ``n - 1``.
    """
    from sklearn.metrics import silhouette_score

    D = _check_distances(D)
    labels = np.asarray(labels)
    if not 2 <= len(np.unique(labels)) <= len(D) - 1:
        raise ValueError("a silhouette needs at least 2 groups and fewer groups than points")
    return float(silhouette_score(D, labels, metric="precomputed"))


def silhouette_by_group(D: np.ndarray, labels) -> dict:
    """Mean silhouette of each group's points on ``D`` (:func:`sklearn.metrics.silhouette_samples`).

    Tells which group makes a low :func:`silhouette`: a tight target cloud beside a
    spread-out background has a high target and a low background value.
    """
    from sklearn.metrics import silhouette_samples

    D = _check_distances(D)
    labels = np.asarray(labels)
    s = silhouette_samples(D, labels, metric="precomputed")
    return {str(g): float(s[labels == g].mean()) for g in np.unique(labels)}


def coverage(to_target: np.ndarray, to_mean: np.ndarray) -> float:
    """How well a cloud of templates covers a target: nearest template over the cloud's typical radius.

    ``min(to_target) / median(to_mean)``: the target's distance to its nearest
    template over the median distance of the templates to the cloud's mean. At
    most 1: the target lies as close to some template as a typical template lies
    to the cloud's centre (covered); well above 1: the cloud missed it.

    Parameters
    ----------
    to_target : ndarray, shape (n,)
        Distances of the n templates to the target.
    to_mean : ndarray, shape (n,)
        Distances of the same templates to the cloud's mean.

    Returns
    -------
    float
        ``inf`` when the cloud has no spread and misses the target; 0 when it hits it exactly.
    """
    to_target, to_mean = np.asarray(to_target, dtype=np.float64), np.asarray(to_mean, dtype=np.float64)
    if not len(to_target) or to_target.shape != to_mean.shape:
        raise ValueError("coverage needs one distance to the target and one to the mean per template")
    nearest, radius = float(to_target.min()), float(np.median(to_mean))
    if radius > 0:
        return nearest / radius
    return 0.0 if nearest == 0 else float("inf")


def _euclidean(X: np.ndarray) -> np.ndarray:
    """Pairwise Euclidean distances of the rows of ``X`` (differences first: exact zeros on the diagonal)."""
    diff = X[:, None, :] - X[None, :, :]
    return np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))


def smacof_mds(
    D: np.ndarray,
    n_components: int = 2,
    init: np.ndarray | None = None,
    max_iter: int = 300,
    eps: float = 1e-6,
) -> np.ndarray:
    """Metric MDS by SMACOF, deterministic.

    Minimises the raw stress ``Σ_{i<j} (||x_i - x_j|| - D_ij)²`` by the
    Guttman transform ``X ← B(X) X / n``, started from ``init`` if given, else
    from :func:`classical_mds` (one run, no random restarts), so the same input
    gives the same output. It is scikit-learn's :func:`sklearn.manifold.smacof`
    (``metric=True``, unit weights; coincident points at distance 1e-5 as there)
    written out: the tests check it against scikit-learn to 1e-9. Written out
    because importing ``sklearn.manifold`` costs ~0.8 s of CPU, which the
    recorder paid on its first MDS frame of every run (a sixth of a 200-frame
    traced run's overhead), for ~20 lines of linear algebra; and because
    scikit-learn's stopping rule changed between releases (1.9 divides the
    stress decrease by the squared distances, earlier releases by the sum of the
    points' norms), so the same recording would have depended on its version.

    Parameters
    ----------
    D : ndarray, shape (n, n)
    n_components : int
    init : ndarray, shape (n, n_components), optional
    max_iter : int
    eps : float
        Stop when an iteration lowers the stress by less than this fraction
        of half the embedding's squared distances (scikit-learn 1.9's criterion).

    Returns
    -------
    ndarray, shape (n, n_components)
        Centred coordinates.
    """
    D = _check_distances(D)
    n = len(D)
    if n < 3:
        return classical_mds(D, n_components)
    X = classical_mds(D, n_components) if init is None else np.array(init, dtype=np.float64)
    if X.shape != (n, n_components):
        raise ValueError(f"init must have shape {(n, n_components)}, got {X.shape}")
    dist = _euclidean(X)
    diag = np.arange(n)
    old = None
    for _ in range(max_iter):
        dist[dist == 0] = 1e-5  # coincident points (and the diagonal, where D is 0: ratio 0)
        ratio = D / dist
        B = -ratio
        B[diag, diag] += ratio.sum(axis=1)
        X = 1.0 / n * (B @ X)
        dist = _euclidean(X)
        stress = ((dist - D) ** 2).sum() / 2
        if old is not None and (old - stress) / ((dist**2).sum() / 2) < eps:
            break
        old = stress
    return X - X.mean(axis=0)


def embed(D: np.ndarray, method: str = "classical", n_components: int = 2, max_iter: int = 300) -> np.ndarray:
    """MDS by name: ``"classical"`` (:func:`classical_mds`) or ``"smacof"`` (:func:`smacof_mds`).

    Classical MDS projects on the top principal directions, so a tight cloud
    that spreads in many dimensions (a random walk of templates in the 45 of a
    9×9 symmetric matrix) collapses to a dot next to far-away points; SMACOF
    fits all pairwise distances and keeps it open.
    """
    if method == "classical":
        return classical_mds(D, n_components)
    if method == "smacof":
        return smacof_mds(D, n_components, max_iter=max_iter)
    raise ValueError(f"unknown MDS method {method!r}; use 'classical' or 'smacof'")


def procrustes_align(
    X: np.ndarray,
    ref: np.ndarray,
    mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rigidly move an embedding onto a reference (rotation or reflection, then translation).

    Solves ``min_R,t Σ_i ||(X_i - c) R + t - ref_i||²`` over orthogonal ``R``
    (reflections allowed: MDS is defined up to them) on the matched points
    and applies the transform to *every* row of ``X``. There is no scaling,
    so distances in the aligned picture are still Riemannian distances.

    Parameters
    ----------
    X : ndarray, shape (n, k)
        The new embedding.
    ref : ndarray, shape (m, k)
        Reference coordinates of the matched points.
    mask : ndarray of bool or int indices, optional
        Which rows of ``X`` correspond, in order, to the rows of ``ref``.
        Default: all rows (then ``m == n``).

    Returns
    -------
    X_aligned : ndarray, shape (n, k)
    R : ndarray, shape (k, k)
        Orthogonal matrix applied to the coordinates centred on the matched points' centroid ``c``.
    t : ndarray, shape (k,)
        Translation (the reference centroid): ``X_aligned = (X - c) @ R + t``.
    """
    X = np.asarray(X, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    A = X if mask is None else X[mask]
    if A.shape != ref.shape:
        raise ValueError(f"matched points differ in shape: {A.shape} vs reference {ref.shape}")
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(ref))):
        raise ValueError("cannot align embeddings with NaN or inf coordinates")
    k = X.shape[1]
    ca, cr = A.mean(axis=0), ref.mean(axis=0)
    if len(A) < 2:
        R = np.eye(k)
    else:
        # Schönemann's solution (scipy.linalg.orthogonal_procrustes): R = U Vᵀ of the SVD of Aᵀ·ref.
        u, _, vt = np.linalg.svd((A - ca).T @ (ref - cr))
        R = u @ vt
    return (X - ca) @ R + cr, R, cr


class AlignedMDS:
    """MDS of a sequence of distance matrices, each aligned to the previous embedding.

    Points carry optional keys; points with the same key in two consecutive
    calls are "anchors" and the new embedding is moved (rotated/reflected and
    translated, never scaled) so that the anchors land as close as possible
    to where they were. Points without a key (``None``), such as particles that
    are resampled from frame to frame, follow the transform.

    Parameters
    ----------
    method : {"classical", "smacof"}
    n_components : int
    max_iter : int
        For SMACOF (started from the classical solution, 30 are usually enough).

    Examples
    --------
    >>> emb = AlignedMDS()
    >>> X = emb.fit(D, keys=["initial", "target", None, None])  # doctest: +SKIP
    """

    def __init__(self, method: str = "classical", n_components: int = 2, max_iter: int = 300):
        if method not in ("classical", "smacof"):
            raise ValueError(f"unknown MDS method {method!r}; use 'classical' or 'smacof'")
        self.method = method
        self.n_components = n_components
        self.max_iter = max_iter
        self._anchors: dict[Hashable, np.ndarray] = {}

    def reset(self) -> None:
        """Forget the previous embedding."""
        self._anchors = {}

    def fit(self, D: np.ndarray, keys: Sequence[Hashable | None] | None = None) -> np.ndarray:
        """Embed ``D`` and align it to the previous call's anchors.

        Parameters
        ----------
        D : ndarray, shape (n, n)
        keys : sequence of hashable or None, length n, optional
            Identity of each point across calls (``None``: not an anchor).

        Returns
        -------
        ndarray, shape (n, n_components)
        """
        X = embed(D, self.method, self.n_components, self.max_iter)
        n = len(X)
        keys = list(keys) if keys is not None else [None] * n
        if len(keys) != n:
            raise ValueError(f"keys has {len(keys)} entries for {n} points")
        common = [i for i, key in enumerate(keys) if key is not None and key in self._anchors]
        if len(common) >= 2:
            ref = np.stack([self._anchors[keys[i]] for i in common])
            X, _, _ = procrustes_align(X, ref, mask=np.asarray(common))
        self._anchors = {key: X[i].copy() for i, key in enumerate(keys) if key is not None}
        return X
