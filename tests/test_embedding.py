"""Tests for :mod:`covviz.embedding`: MDS of distance matrices and Procrustes alignment."""

from __future__ import annotations

import numpy as np
import pytest

from covviz.embedding import (
    AlignedMDS,
    classical_mds,
    distance_matrix,
    embed,
    procrustes_align,
    smacof_mds,
    stress,
)
from covviz.model.spd import distance_riemann, expm


def _pairwise(X: np.ndarray) -> np.ndarray:
    return np.linalg.norm(X[:, None] - X[None], axis=-1)


def _rotation(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


@pytest.fixture
def config(rng) -> np.ndarray:
    """A known 2-D configuration (not degenerate)."""
    return rng.normal(size=(30, 2)) * np.array([3.0, 1.0])


def test_classical_mds_recovers_a_planar_configuration_up_to_rigid_motion(config):
    X = classical_mds(_pairwise(config))
    assert X.shape == config.shape
    # Same distances ...
    np.testing.assert_allclose(_pairwise(X), _pairwise(config), atol=1e-9)
    # ... and a rigid motion maps one onto the other exactly.
    Y, R, _ = procrustes_align(X, config)
    np.testing.assert_allclose(Y, config, atol=1e-9)
    np.testing.assert_allclose(R @ R.T, np.eye(2), atol=1e-12)


def test_classical_mds_is_centred_and_deterministic(config):
    D = _pairwise(config)
    X1, X2 = classical_mds(D), classical_mds(D.copy())
    np.testing.assert_array_equal(X1, X2)
    np.testing.assert_allclose(X1.mean(axis=0), 0.0, atol=1e-9)


def test_classical_mds_small_inputs():
    assert classical_mds(np.zeros((1, 1))).shape == (1, 2)
    X = classical_mds(np.array([[0.0, 2.0], [2.0, 0.0]]))
    assert np.linalg.norm(X[0] - X[1]) == pytest.approx(2.0)


def test_smacof_keeps_a_high_dimensional_cloud_open(rng):
    """Classical MDS flattens an isotropic 20-D cloud next to a far point; SMACOF fits the distances."""
    cloud = rng.normal(scale=0.1, size=(40, 20))
    far = np.zeros((1, 20))
    far[0, 0] = 3.0
    P = np.concatenate([cloud, far])
    D = _pairwise(P)
    Xc, Xs = classical_mds(D), smacof_mds(D, max_iter=100)
    assert stress(Xs, D) < 0.5 * stress(Xc, D)
    inner = _pairwise(Xs[:40]).mean() / D[:40, :40].mean()
    assert inner > 0.6  # the cloud stays open (classical shrinks it)


def test_smacof_matches_euclidean_distances(config):
    D = _pairwise(config)
    X = smacof_mds(D)
    np.testing.assert_allclose(_pairwise(X), D, atol=1e-3)
    np.testing.assert_array_equal(X, smacof_mds(D))
    assert embed(D, "smacof").shape == (len(D), 2)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.ones((3, 2)), "square"),
        (np.array([[0.0, np.nan], [np.nan, 0.0]]), "NaN"),
        (np.array([[0.0, -1.0], [-1.0, 0.0]]), "negative"),
        (np.array([[0.0, 1.0], [2.0, 0.0]]), "symmetric"),
    ],
)
def test_bad_distance_matrices_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        classical_mds(bad)


def test_unknown_method_is_refused():
    with pytest.raises(ValueError, match="classical"):
        embed(np.zeros((2, 2)), "tsne")
    with pytest.raises(ValueError, match="classical"):
        AlignedMDS("tsne")


@pytest.mark.parametrize("flip", [False, True])
def test_procrustes_removes_a_rotation_a_flip_and_a_translation(config, flip):
    M = _rotation(1.1)
    if flip:
        M = M @ np.diag([1.0, -1.0])
    moved = config @ M + np.array([5.0, -3.0])
    back, R, _ = procrustes_align(moved, config)
    np.testing.assert_allclose(back, config, atol=1e-9)
    assert abs(abs(np.linalg.det(R)) - 1.0) < 1e-12


def test_procrustes_fits_on_matched_points_and_moves_all(config):
    moved = config @ _rotation(-0.7) + 2.0
    idx = np.array([0, 3, 5, 8])
    back, _, _ = procrustes_align(moved, config[idx], mask=idx)
    np.testing.assert_allclose(back, config, atol=1e-9)  # the unmatched points follow


def test_procrustes_does_not_scale(config):
    back, _, _ = procrustes_align(config * 2.0, config)
    # Distances keep their meaning: the picture is not shrunk onto the reference.
    np.testing.assert_allclose(_pairwise(back), 2.0 * _pairwise(config), atol=1e-9)


def test_procrustes_checks_shapes(config):
    with pytest.raises(ValueError, match="shape"):
        procrustes_align(config, config[:5])


def test_aligned_mds_keeps_anchors_in_place(config, rng):
    """A second, slightly perturbed configuration lands where the first was (no flip, no spin)."""
    keys = [f"a{i}" for i in range(len(config))]
    emb = AlignedMDS()
    X1 = emb.fit(_pairwise(config), keys)
    perturbed = config + rng.normal(scale=0.01, size=config.shape)
    # Reorder and add two new, unkeyed points: alignment goes by key, not by position.
    order = rng.permutation(len(config))
    extra = rng.normal(size=(2, 2))
    pts = np.concatenate([perturbed[order], extra])
    X2 = emb.fit(_pairwise(pts), [keys[i] for i in order] + [None, None])
    np.testing.assert_allclose(X2[: len(config)], X1[order], atol=0.05)


def test_aligned_mds_checks_keys(config):
    with pytest.raises(ValueError, match="keys"):
        AlignedMDS().fit(_pairwise(config), ["a"])


def test_distance_matrix_of_spd_matrices(rng):
    A = rng.normal(size=(6, 4, 4))
    C = expm(0.3 * (A + A.transpose(0, 2, 1)))
    D = distance_matrix(C)
    assert D.shape == (6, 6)
    np.testing.assert_allclose(D, D.T)
    np.testing.assert_allclose(np.diag(D), 0.0)
    assert D[1, 4] == pytest.approx(float(distance_riemann(C[1], C[4])), rel=1e-9)


@pytest.mark.parametrize("power", [1.0, 0.7])  # Euclidean distances, and distances no plane can hold
def test_smacof_is_scikit_learns_smacof(rng, power):
    """Our Guttman transform against scikit-learn's (metric, unit weights), from the same start."""
    from sklearn.manifold import smacof

    for _ in range(6):
        n, k = int(rng.integers(5, 40)), int(rng.integers(3, 10))
        P = rng.standard_normal((n, k)) * rng.random(k)
        D = np.sqrt(((P[:, None] - P[None]) ** 2).sum(-1)) ** power
        X0 = classical_mds(D)
        for eps, max_iter in ((0.0, 60), (1e-6, 300)):  # a fixed number of steps; the stopping rule
            ours = smacof_mds(D, init=X0, max_iter=max_iter, eps=eps)
            theirs, _ = smacof(D, metric=True, n_components=2, init=X0.copy(), n_init=1, max_iter=max_iter,
                               eps=eps, normalized_stress=False)
            np.testing.assert_allclose(ours, theirs - theirs.mean(axis=0), rtol=0, atol=1e-9 * np.abs(theirs).max())


def test_distance_matrix_of_descriptors_is_pyriemanns(rng):
    """9x9 matrices go through the compiled Jacobi (covviz.model.kernels.pair_distances_fast): every entry
    against pyriemann's affine-invariant distance (a test-only oracle) and the numpy reference."""
    pr_distance = pytest.importorskip("pyriemann.geometry.distance").distance_riemann
    from covviz.model.spd import pairwise_distance

    n = 23
    A = rng.normal(size=(n, 9, 40)) * rng.uniform(0.01, 10.0, size=(n, 9, 1))  # spread-out scales
    C = A @ A.transpose(0, 2, 1) / 40 + 1e-3 * np.eye(9)
    C[3] = C[2] * 1.0000001  # a near-duplicate pair: distance ~1e-7
    D = distance_matrix(C)
    np.testing.assert_array_equal(D, D.T)
    assert np.all(np.diag(D) == 0.0)
    np.testing.assert_allclose(D, pairwise_distance(C), rtol=1e-12, atol=1e-13)
    for i, j in [(0, 1), (2, 3), (5, 22), (17, 4)]:
        assert D[i, j] == pytest.approx(pr_distance(C[i], C[j]), rel=1e-11, abs=1e-13)
    assert D[2, 3] == pytest.approx(np.sqrt(9) * np.log(1.0000001), rel=1e-6)


def test_procrustes_is_scipys_orthogonal_procrustes(rng):
    # Noisy points (no exact fit): the rotation is Schönemann's, as scipy.linalg computes it.
    import scipy.linalg

    X, ref = rng.normal(size=(20, 2)), rng.normal(size=(20, 2))
    _, R, _ = procrustes_align(X, ref)
    R_ref, _ = scipy.linalg.orthogonal_procrustes(X - X.mean(axis=0), ref - ref.mean(axis=0))
    np.testing.assert_allclose(R, R_ref, atol=1e-12)


@pytest.mark.parametrize("n", [2, 3, 40])
def test_classical_mds_takes_scipys_top_eigenpairs(rng, n):
    # Riemannian (non-Euclidean) distances: the top two eigenpairs of the double-centred matrix,
    # as scipy.linalg.eigh's partial solve gives them (signs fixed as classical_mds fixes them).
    import scipy.linalg

    A = rng.normal(scale=0.3, size=(n, 4, 4))
    D = distance_matrix(expm(A + A.transpose(0, 2, 1)))
    X = classical_mds(D)
    D2 = D * D
    r = D2.mean(axis=1)
    B = -0.5 * (D2 - r[:, None] - r[None, :] + r.mean())
    k = min(2, n)
    w, V = scipy.linalg.eigh(B, subset_by_index=[n - k, n - 1])
    ref = V[:, ::-1] * np.sqrt(np.clip(w[::-1], 0.0, None))
    ref *= np.where(ref[np.abs(ref).argmax(axis=0), np.arange(k)] < 0, -1.0, 1.0)
    np.testing.assert_allclose(X[:, :k], ref, atol=1e-10)
