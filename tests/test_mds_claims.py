"""The numbers of the paper's manifold figures (issue 22, item 4), checked against distances computed directly.

Oracles: pyriemann's affine-invariant distance and Karcher mean, the silhouette and the stress written out
from their definitions, one pair at a time.
"""

from __future__ import annotations

import numpy as np
import pytest
from pyriemann.geometry.distance import distance_riemann as pr_distance
from pyriemann.geometry.mean import mean_riemann as pr_mean

from covviz.data.synthetic import SyntheticConfig, SyntheticSequence
from covviz.embedding import coverage, silhouette
from covviz.model.observation import box_to_pose
from covviz.viz import mds_figures as mf
from covviz.viz import why_manifold as wm


def silhouette_by_definition(D: np.ndarray, labels: np.ndarray) -> float:
    s = []
    for i in range(len(D)):
        own = (labels == labels[i]) & (np.arange(len(D)) != i)
        a = D[i, own].mean() if own.any() else 0.0
        b = min(D[i, labels == g].mean() for g in set(labels) - {labels[i]})
        s.append(0.0 if not own.any() else (b - a) / max(a, b))
    return float(np.mean(s))


def pairwise_by_pairs(M: np.ndarray) -> np.ndarray:
    n = len(M)
    D = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            D[i, j] = D[j, i] = pr_distance(M[i], M[j])
    return D


def stress1_by_definition(X: np.ndarray, D: np.ndarray) -> float:
    num = den = 0.0
    for i in range(len(D)):
        for j in range(i + 1, len(D)):
            num += (np.linalg.norm(X[i] - X[j]) - D[i, j]) ** 2
            den += D[i, j] ** 2
    return float(np.sqrt(num / den))


@pytest.fixture(scope="module")
def seq():
    return SyntheticSequence(SyntheticConfig(n_frames=24, seed=5))


CFG = mf.MDSFiguresConfig(frames=(1, 12, 24), max_target=12, n_background=2, n_particles=40, n_generated=8)


@pytest.fixture(scope="module")
def walk(seq):
    return mf.random_walk_data(seq, CFG)


@pytest.fixture(scope="module")
def sep(seq, walk):
    return mf.separation_data(seq, CFG, model=walk.model)


def test_silhouette_is_the_definitions(rng):
    X = rng.normal(size=(30, 3)) + np.repeat([[0, 0, 0], [2, 0, 0]], 15, axis=0)
    D = np.linalg.norm(X[:, None] - X[None], axis=-1)
    labels = np.repeat(["target", "background"], 15)
    assert silhouette(D, labels) == pytest.approx(silhouette_by_definition(D, labels), abs=1e-12)
    with pytest.raises(ValueError, match="2 groups"):
        silhouette(D, np.zeros(30))


def test_coverage_exact_values():
    assert coverage([3.0, 1.0, 2.0], [0.5, 1.0, 2.0]) == pytest.approx(1.0)  # nearest 1 over median radius 1
    assert coverage([0.2, 4.0], [0.4, 0.4]) == pytest.approx(0.5)
    assert coverage([0.0, 1.0], [0.0, 0.0]) == 0.0 and coverage([1.0], [0.0]) == float("inf")
    with pytest.raises(ValueError):
        coverage([], [])


def test_separation_numbers_are_those_of_the_riemannian_distances(sep):
    D = pairwise_by_pairs(sep.matrices)
    np.testing.assert_allclose(sep.distances, D, rtol=1e-6, atol=1e-8)
    assert sep.silhouette == pytest.approx(silhouette_by_definition(D, sep.kinds), abs=1e-6)
    n_t = (sep.kinds == "target").sum()
    overall = (n_t * sep.by_group["target"] + (len(D) - n_t) * sep.by_group["background"]) / len(D)
    assert overall == pytest.approx(sep.silhouette, abs=1e-9)  # the groups' means make the whole
    assert sep.stress == pytest.approx(stress1_by_definition(sep.coords, D), rel=1e-6)
    assert set(sep.kinds) == {"target", "background"}


def test_separation_descriptors_are_what_the_model_observes_at_the_truth(seq, sep, walk):
    model = walk.model
    f = int(sep.frames[sep.kinds == "target"][1])
    fr = seq.frame(f - 1)
    direct = model.descriptors(model.prepare(fr.image), box_to_pose(seq.groundtruth[f - 1], model.base_wh)[None])[0]
    np.testing.assert_allclose(sep.matrices[(sep.kinds == "target") & (sep.frames == f)][0], direct, rtol=1e-6)


def test_coverage_of_each_frame_against_distances_computed_directly(walk):
    assert [c.frame for c in walk.coverage] == [12, 24]  # frame 1 has no generated templates yet
    for c in walk.coverage:
        T, target = walk.clouds[c.frame], walk.targets[c.frame]
        assert len(T) == c.n == 40
        to_target = np.array([pr_distance(t, target) for t in T])
        centre = pr_mean(T, tol=1e-10, maxiter=100)
        radius = np.median([pr_distance(t, centre) for t in T])
        assert c.nearest == pytest.approx(to_target.min(), rel=1e-6)
        assert c.radius == pytest.approx(radius, rel=1e-4)
        assert c.ratio == pytest.approx(to_target.min() / radius, rel=1e-4)
        near = (walk.kinds == "near") & (walk.frames == c.frame)
        assert near.sum() == CFG.n_near  # the paper's caption: the 10 most similar to the truth


def test_walk_numbers_against_direct_distances(walk):
    D = pairwise_by_pairs(walk.matrices)
    np.testing.assert_allclose(walk.distances, D, rtol=1e-6, atol=1e-8)
    assert walk.stress == pytest.approx(stress1_by_definition(walk.coords, D), rel=1e-6)
    for c in walk.coverage:  # the green crosses are the templates nearest to the truth, none of the others nearer
        target = walk.targets[c.frame]
        d = {k: [pr_distance(m, target) for m in walk.matrices[(walk.kinds == k) & (walk.frames == c.frame)]]
             for k in ("near", "template")}
        assert min(d["near"]) == pytest.approx(c.nearest, rel=1e-6)
        assert max(d["near"]) <= min(d["template"]) + 1e-9


def test_a_claim_that_fails_is_printed_as_failing(sep, walk):
    bad = mf.Separation(sep.coords, sep.kinds, sep.frames, silhouette=0.1, stress=0.3)
    lines = mf.claims_text(bad, None, "Seq")
    assert "FAILS" in lines[1] and "0.100" in lines[1] and "stress-1 0.300" in lines[2]
    good = mf.Separation(sep.coords, sep.kinds, sep.frames, silhouette=0.6, stress=0.05)
    assert mf.claims_text(good, None)[1].endswith("holds")
    for c in mf.claims(None, walk):
        assert c.line().endswith("holds" if c.value <= mf.COVERED else "FAILS")


def test_figures_in_every_format_with_the_numbers(tmp_path, sep, walk):
    paths = mf.save_figures(sep, walk, tmp_path, "Syn", ("png", "svg", "pdf"), "synthetic")
    assert sorted(p.name for p in paths) == sorted(f"Syn-mds-{k}.{f}" for k in ("separation", "random-walk")
                                                   for f in ("png", "svg", "pdf"))
    assert (tmp_path / "Syn-mds-separation.pdf").read_bytes().startswith(b"%PDF")
    svg = (tmp_path / "Syn-mds-separation.svg").read_text()
    assert "silhouette" in svg and f"{sep.silhouette:.3f}" in svg  # the number is in the figure


def test_tangent_vectors_carry_the_log_euclidean_distance(rng):
    A = rng.normal(size=(5, 4, 4))
    C = A @ A.transpose(0, 2, 1) + 0.5 * np.eye(4)
    V = wm.tangent_vectors(C)
    from pyriemann.geometry.distance import distance_logeuclid

    assert V.shape == (5, 10)
    assert np.linalg.norm(V[0] - V[3]) == pytest.approx(distance_logeuclid(C[0], C[3]), rel=1e-9)


def test_why_manifold_numbers_against_direct_distances(seq, walk):
    w = wm.why_manifold_data(seq, walk.model, max_frames=24, n_background=2)
    assert w.is_target[0] and w.frames[0] == 1  # the first target patch is the reference
    others, bg = w.is_target.copy(), ~w.is_target
    others[0] = False
    e = np.array([np.sqrt(((p - w.patches[0]) ** 2).sum()) for p in w.patches])
    r = np.array([pr_distance(c, w.descriptors[0]) for c in w.descriptors])
    assert w.euclid_ratio == pytest.approx(np.median(e[others]) / np.median(e[bg]), rel=1e-9)
    assert w.riemann_ratio == pytest.approx(np.median(r[others]) / np.median(r[bg]), rel=1e-6)
    assert w.patches.shape[1] == w.patch_size ** 2 and 0 <= w.patches.min() and w.patches.max() <= 1
    assert 0 <= w.svm_patch <= 1 and 0 <= w.svm_manifold <= 1
    assert len(w.svm_c_patch) == wm.N_BLOCKS and set(w.svm_c_patch) <= set(wm.SVM_C_GRID)
    text = "\n".join(wm.why_manifold_text(w, "synthetic"))
    assert f"{w.euclid_ratio:.3f}" in text and f"{w.svm_manifold:.3f}" in text


def test_grouped_svm_scores_separable_and_mixed_samples(rng):
    groups = np.repeat(np.arange(5), 20)
    y = np.tile([True, False], 50)
    separable = np.c_[y * 4.0 + rng.normal(0, 0.3, 100), rng.normal(size=100)]
    acc, chosen = wm.grouped_svm_accuracy(separable, y, groups)
    assert acc == 1.0 and len(chosen) == wm.N_BLOCKS and set(chosen) <= set(wm.SVM_C_GRID)
    mixed, _ = wm.grouped_svm_accuracy(rng.normal(size=(100, 2)), y, groups)
    assert mixed < 0.75  # labels independent of the features: about chance
