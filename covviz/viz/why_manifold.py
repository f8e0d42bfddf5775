"""The paper's first manifold figure ("why manifold"), with its numbers.

The paper (section 2.3, figure "why manifold") shows on one sequence that

(d) the Euclidean distance between vectorised target patches can be larger
    than from a target patch to the background, measured from the first
    target patch, and not so for the Riemannian distance between their
    covariance descriptors;
(e) a linear SVM cannot separate targets from backgrounds on vectorised
    patches, while they separate on the manifold.

This module measures both on the same samples: target patches at the ground
truth and background regions of the same size over the sequence, each as the
tracker's observation model sees it (its warped ``S×S`` grey patch, vectorised;
and its covariance descriptor).

* **Distance ratios** from the first target patch: the median distance of the
  other target patches over the median distance of the background patches,
  Euclidean on the vectorised patches and Riemannian on the descriptors. The
  paper claims the Euclidean ratio is at least 1 and the Riemannian one below 1.
* **Linear SVMs** (scikit-learn's ``LinearSVC`` behind a ``StandardScaler``),
  one on the vectorised patches, one on the descriptors' log-Euclidean tangent
  vectors (the upper triangle of ``logm(C)``, off-diagonal entries times √2, so
  that the Euclidean norm is the log-Euclidean distance). Both are scored by
  cross-validation with folds grouped by blocks of consecutive frames
  (``GroupKFold``: no fold trains on the frames next to the ones it is tested
  on), ``C`` chosen by an inner grouped cross-validation from :data:`SVM_C_GRID`;
  the score is the balanced accuracy. The paper claims the manifold separates
  (at least :data:`SEPARATES`) and the patches do not.

No rerun here: the data function returns arrays and numbers, the plot function
draws them with matplotlib.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from covviz.errors import InputError
from covviz.model.spd import distance_riemann, logm

__all__ = [
    "N_BLOCKS",
    "SEPARATES",
    "SVM_C_GRID",
    "WhyManifold",
    "grouped_svm_accuracy",
    "tangent_vectors",
    "why_manifold_claims",
    "why_manifold_data",
    "why_manifold_figure",
    "why_manifold_text",
]

#: C of the linear SVMs, chosen by inner cross-validation from this grid.
SVM_C_GRID = (0.001, 0.01, 0.1, 1.0, 10.0, 100.0)
#: Outer folds: blocks of consecutive frames.
N_BLOCKS = 5
#: Inner folds that choose C.
N_INNER = 3
#: A classifier "separates" targets from backgrounds at this balanced accuracy or more.
SEPARATES = 0.95


@dataclass(frozen=True)
class WhyManifold:
    """Samples and numbers of the "why manifold" figure.

    Attributes
    ----------
    patches : ndarray, shape (n, S*S)
        Vectorised grey patches (intensities in [0, 1]); row 0 is the first target patch.
    descriptors : ndarray, shape (n, d, d)
    is_target : ndarray of bool, shape (n,)
    frames : ndarray of int, shape (n,)
        1-based frame of each sample.
    euclid : ndarray, shape (n,)
        Euclidean distance of each vectorised patch to the first target patch.
    riemann : ndarray, shape (n,)
        Riemannian distance of each descriptor to the first target's.
    euclid_ratio, riemann_ratio : float
        Median distance of the other targets over that of the backgrounds (both from the first target).
    svm_patch, svm_manifold : float
        Cross-validated balanced accuracy of a linear SVM on the patches / on the tangent vectors.
    svm_c_patch, svm_c_manifold : list of float
        The C each outer fold chose.
    patch_size : int
    model : str
        The observation model's description.
    """

    patches: np.ndarray
    descriptors: np.ndarray
    is_target: np.ndarray
    frames: np.ndarray
    euclid: np.ndarray
    riemann: np.ndarray
    euclid_ratio: float
    riemann_ratio: float
    svm_patch: float
    svm_manifold: float
    svm_c_patch: list
    svm_c_manifold: list
    patch_size: int
    model: str = ""


def tangent_vectors(C: np.ndarray) -> np.ndarray:
    """Log-Euclidean tangent vectors ``(n, d(d+1)/2)`` of SPD matrices ``(n, d, d)``.

    The upper triangle of ``logm(C)`` with off-diagonal entries times √2, so that
    ``||v_i - v_j|| = ||logm C_i - logm C_j||_F`` (the log-Euclidean distance).
    """
    L = logm(np.asarray(C, dtype=np.float64))
    d = L.shape[-1]
    iu = np.triu_indices(d)
    w = np.where(iu[0] == iu[1], 1.0, np.sqrt(2.0))
    return L[:, iu[0], iu[1]] * w


def grouped_svm_accuracy(X: np.ndarray, y: np.ndarray, groups: np.ndarray, c_grid=SVM_C_GRID,
                         n_outer: int = N_BLOCKS, n_inner: int = N_INNER) -> tuple[float, list]:
    """Balanced accuracy of a linear SVM under grouped cross-validation, C by inner grouped CV.

    Returns the mean over the outer folds and the C each fold chose.
    """
    from sklearn.metrics import balanced_accuracy_score
    from sklearn.model_selection import GridSearchCV, GroupKFold
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import LinearSVC

    scores, chosen = [], []
    for train, test in GroupKFold(n_splits=n_outer).split(X, y, groups):
        pipe = make_pipeline(StandardScaler(), LinearSVC(class_weight="balanced", max_iter=20000))
        search = GridSearchCV(pipe, {"linearsvc__C": list(c_grid)}, cv=GroupKFold(n_splits=n_inner),
                              scoring="balanced_accuracy")
        search.fit(X[train], y[train], groups=groups[train])
        scores.append(balanced_accuracy_score(y[test], search.predict(X[test])))
        chosen.append(float(search.best_params_["linearsvc__C"]))
    return float(np.mean(scores)), chosen


def why_manifold_data(sequence, model=None, max_frames: int = 150, n_background: int = 3, seed: int = 0,
                      max_overlap: float = 0.1, progress: bool = False) -> WhyManifold:
    """Target and background samples of ``sequence`` as ``model`` sees them, and the figure's numbers.

    ``model``: an :class:`~covviz.model.observation.ObservationModel` (default: the
    manifold tracker's, :func:`covviz.viz.mds_figures.default_model`). Frames with
    ground truth are taken with an even stride (at most ``max_frames``), the first
    always; ``n_background`` regions of the target's size per frame, overlapping it
    by at most ``max_overlap`` IoU.

    Raises
    ------
    InputError
        Too few frames with ground truth for the grouped folds.
    """
    from covviz.model.observation import box_to_pose
    from covviz.viz.mds_figures import _background_boxes, default_model, sample_frames

    rng = np.random.default_rng([seed, 4])
    picked = sample_frames(sequence, max_frames)
    if len(picked) < 2 * N_BLOCKS:
        raise InputError(f"{sequence.name}: the 'why manifold' figure needs ground truth on at least "
                         f"{2 * N_BLOCKS} frames (its folds are {N_BLOCKS} blocks of frames)")
    model = model or default_model(sequence)
    patches, mats, is_target, frames = [], [], [], []
    it = picked
    if progress:
        from tqdm import tqdm

        it = tqdm(picked, desc=f"{sequence.name} patches", unit="frame", leave=False)
    for t in it:
        fr = sequence.frame(int(t))
        gt = sequence.groundtruth[t]
        bg = _background_boxes(gt, fr.image.shape, n_background, max_overlap, rng)
        boxes = np.concatenate([gt[None], bg])
        poses = np.stack([box_to_pose(b, model.base_wh) for b in boxes])
        gray = model.prepare(fr.image)
        patches.append(model.patches(gray, poses).reshape(len(boxes), -1))
        mats.append(model.descriptors(gray, poses))
        is_target += [True] + [False] * len(bg)
        frames += [int(t) + 1] * len(boxes)
    P = np.concatenate(patches).astype(np.float64)
    C = np.concatenate(mats)
    y = np.array(is_target)
    frames = np.array(frames)
    if y.all():
        raise InputError(f"{sequence.name}: no background region fits beside the target (it fills the frame)")
    euclid = np.linalg.norm(P - P[0], axis=1)
    riemann = distance_riemann(C, C[0][None])
    others = y.copy()
    others[0] = False

    def ratio(d: np.ndarray) -> float:
        return float(np.median(d[others]) / np.median(d[~y]))

    # blocks of consecutive frames: a fold never tests on the neighbours of frames it trained on
    order = np.searchsorted(np.unique(frames), frames)
    groups = (order * N_BLOCKS) // (order.max() + 1)
    acc_p, c_p = grouped_svm_accuracy(P, y, groups)
    acc_m, c_m = grouped_svm_accuracy(tangent_vectors(C), y, groups)
    return WhyManifold(P, C, y, frames, euclid, riemann, ratio(euclid), ratio(riemann), acc_p, acc_m, c_p, c_m,
                       int(model.patch_size), model.describe())


def why_manifold_claims(w: WhyManifold):
    """The figure's claims, measured (:class:`covviz.viz.mds_figures.Claim`)."""
    from covviz.viz.mds_figures import Claim

    return [
        Claim("why manifold", "Euclidean (vectorised patches): other targets / background, from the first target",
              w.euclid_ratio, ">= 1 claimed: targets as far as the background", bool(w.euclid_ratio >= 1.0)),
        Claim("why manifold", "Riemannian (covariances): other targets / background, from the first target",
              w.riemann_ratio, "< 1 claimed: targets nearer than the background", bool(w.riemann_ratio < 1.0)),
        Claim("why manifold", "linear SVM on the tangent vectors: balanced accuracy", w.svm_manifold,
              f">= {SEPARATES:g} claimed: separates", bool(w.svm_manifold >= SEPARATES)),
        Claim("why manifold", "linear SVM on the vectorised patches: balanced accuracy", w.svm_patch,
              f"< {SEPARATES:g} and below the manifold's claimed: does not separate",
              bool(w.svm_patch < SEPARATES and w.svm_patch < w.svm_manifold)),
    ]


def why_manifold_text(w: WhyManifold, sequence_name: str = "") -> list[str]:
    """The lines ``covviz mds`` prints for this figure."""
    n_t = int(w.is_target.sum())
    head = f"{sequence_name}: " if sequence_name else ""
    lines = [(f"{head}why manifold ({n_t} target and {len(w.is_target) - n_t} background patches of "
             f"{w.patch_size}x{w.patch_size}; SVM folds: {N_BLOCKS} blocks of frames, C by inner {N_INNER}-fold CV "
             f"from {', '.join(f'{c:g}' for c in SVM_C_GRID)})")]
    lines += [f"  {c.line()}" for c in why_manifold_claims(w)]
    lines.append(f"  C chosen: patches {', '.join(f'{c:g}' for c in w.svm_c_patch)}; "
                 f"manifold {', '.join(f'{c:g}' for c in w.svm_c_manifold)}")
    return lines


def why_manifold_figure(w: WhyManifold, out_dir: Path, stem: str, formats=("png",), sequence_name: str = "") -> list[Path]:
    """The figure as the paper lays it out: (a) targets, (b) backgrounds, (c) the SVMs, (d) Euclidean, (e) Riemannian."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from covviz.viz.mds_figures import BLUE, RED, _claim_block, _rgb

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    name = sequence_name or stem
    S = w.patch_size
    with plt.style.context("dark_background"):
        fig = plt.figure(figsize=(13, 7.6), dpi=120)
        fig.suptitle(f"{name}: why the manifold (the paper's first manifold figure, measured)", fontsize=11)
        for k, (mask, title) in enumerate(((w.is_target, "(a) targets"), (~w.is_target, "(b) backgrounds"))):
            idx = np.flatnonzero(mask)
            idx = idx[np.linspace(0, len(idx) - 1, min(8, len(idx))).astype(int)]
            for j, i in enumerate(idx):
                ax = fig.add_axes((0.04 + j * 0.055, 0.80 - k * 0.12, 0.05, 0.09))
                ax.imshow(w.patches[i].reshape(S, S), cmap="gray", vmin=0, vmax=1)
                ax.set_xticks([])
                ax.set_yticks([])
                ax.set_xlabel(f"{w.frames[i]}", fontsize=6, labelpad=1)
                if j == 0:
                    ax.set_title(title, fontsize=8, loc="left")
        ax = fig.add_axes((0.55, 0.62, 0.12, 0.26))
        bars = ax.bar([0, 1], [w.svm_patch, w.svm_manifold], color=["0.6", _rgb(RED)], width=0.6)
        ax.set_xticks([0, 1], ["patches", "manifold"], fontsize=7)
        ax.set_ylim(0, 1.12)
        ax.axhline(SEPARATES, color="white", linewidth=0.6, linestyle=":")
        for b in bars:
            ax.text(b.get_x() + b.get_width() / 2, b.get_height() + 0.02, f"{b.get_height():.3f}", ha="center",
                    fontsize=7)
        ax.set_title("(c) linear SVM, balanced acc.", fontsize=8)
        ax.tick_params(labelsize=7)
        for k, (d, ratio, title) in enumerate(((w.euclid, w.euclid_ratio, "(d) Euclidean distance, vectorised patches"),
                                                (w.riemann, w.riemann_ratio, "(e) Riemannian distance, covariances"))):
            ax = fig.add_axes((0.06 + k * 0.46, 0.25, 0.32, 0.26))
            others = w.is_target.copy()
            others[0] = False
            ax.scatter(w.frames[~w.is_target], d[~w.is_target], s=6, color=_rgb(BLUE), edgecolors="none",
                       label="background")
            ax.scatter(w.frames[others], d[others], s=8, color=_rgb(RED), edgecolors="none", label="targets")
            ax.axhline(np.median(d[~w.is_target]), color=_rgb(BLUE), linewidth=0.8, linestyle="--")
            ax.axhline(np.median(d[others]), color=_rgb(RED), linewidth=0.8, linestyle="--")
            ax.set_title(f"{title}\nfrom the first target; median ratio {ratio:.2f}", fontsize=8)
            ax.set_xlabel("frame", fontsize=7)
            ax.tick_params(labelsize=7)
            ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=6, frameon=False)
        _claim_block(fig, [*why_manifold_text(w)[1:], f"samples by {w.model}" if w.model else ""], 0.13)
        written = []
        for fmt in formats:
            path = out_dir / f"{stem}-why-manifold.{fmt}"
            fig.savefig(path)
            written.append(path)
        plt.close(fig)
    return written
