"""``covviz mds SEQUENCE``: the paper's two manifold figures, as a recording and PNGs.

(a) **Target vs background.** Covariance descriptors of the target (at the
    ground-truth box) and of background regions of the same size (random
    positions that barely overlap the target) over the whole sequence, placed
    in the plane by MDS of their Riemannian distance matrix: red target, blue
    background. Separated clouds are what makes covariance tracking work.
(b) **Random walk of the templates.** The manifold tracker is run up to the
    last chosen frame; at each chosen frame (1-based, default 1, 101, 201, 501,
    801 as far as the sequence reaches) its generated templates (top 10 by
    weight and a sample of the others), the estimate's template and the
    target descriptor are collected, and all of them are embedded together
    (one MDS), with the initial template: the templates follow the target
    across the manifold.

Distances are computed in batches (:func:`covviz.embedding.distance_matrix`);
the embedding is classical MDS or SMACOF started from it (both deterministic). The data functions return arrays (no rerun); the logging
and plotting functions draw them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from covviz.descriptor import DEFAULT_EPS, descriptors
from covviz.embedding import distance_matrix, embed
from covviz.metrics import iou, valid_rows
from covviz.spd import expm
from covviz.trackers.base import to_gray
from covviz.viz.diagnostics import ObservationModel, box_to_pose, top_k

__all__ = [
    "DEFAULT_FRAMES",
    "MDSFiguresConfig",
    "RandomWalk",
    "Separation",
    "log_figures",
    "random_walk_data",
    "save_pngs",
    "separation_data",
]

log = logging.getLogger("covviz.viz")

#: The paper's frames (1-based) for the random-walk figure.
DEFAULT_FRAMES = (1, 101, 201, 501, 801)

RED = (235, 64, 52)
BLUE = (50, 120, 255)
WHITE = (255, 255, 255)


@dataclass(frozen=True)
class MDSFiguresConfig:
    """Settings of ``covviz mds``.

    Attributes
    ----------
    frames : tuple of int
        1-based frames of the random-walk figure (those past the end are dropped).
    max_target : int
        At most this many target descriptors in figure (a): frames are taken
        with an even stride.
    n_background : int
        Background regions per sampled frame.
    max_background_overlap : float
        Background regions overlap the target by at most this IoU.
    n_generated : int
        Generated templates per chosen frame in figure (b), besides the top-k.
    top_k : int
    method : {"classical", "smacof"}
    seed : int
        Seeds the background positions, the template samples and the tracker.
    n_particles : int, optional
        Particles of the tracker (default: its own).
    patch_size : int
    eps : float
        Descriptor regulariser.
    """

    frames: tuple = DEFAULT_FRAMES
    max_target: int = 150
    n_background: int = 3
    max_background_overlap: float = 0.1
    n_generated: int = 30
    top_k: int = 10
    method: str = "classical"
    seed: int = 0
    n_particles: int | None = None
    patch_size: int = 32
    eps: float = DEFAULT_EPS

    def __post_init__(self):
        if not self.frames or any(int(f) < 1 for f in self.frames):
            raise ValueError(f"frames must be 1-based frame numbers (>= 1), got {self.frames}")
        if self.max_target < 2 or self.n_background < 1:
            raise ValueError("max_target must be >= 2 and n_background >= 1")
        if self.method not in ("classical", "smacof"):
            raise ValueError(f"method must be 'classical' or 'smacof', got {self.method!r}")


@dataclass(frozen=True)
class Separation:
    """Figure (a): coordinates, kinds (``target``/``background``) and 0-based frames of the points."""

    coords: np.ndarray
    kinds: np.ndarray
    frames: np.ndarray


@dataclass(frozen=True)
class RandomWalk:
    """Figure (b): coordinates, kinds (``initial``/``template``/``top``/``estimate``/``target``), 1-based frames."""

    coords: np.ndarray
    kinds: np.ndarray
    frames: np.ndarray


def _region_descriptors(image: np.ndarray, boxes: np.ndarray, cfg: MDSFiguresConfig) -> np.ndarray:
    """Descriptors of axis-aligned boxes of one size (the first box's), with the tracker's anti-aliasing."""
    w, h = float(boxes[0, 2]), float(boxes[0, 3])
    gray = to_gray(image)
    per_sample = min(w, h) / cfg.patch_size
    step = int(per_sample // 2) if per_sample >= 4 else 1
    step_exact = 1.0
    if step > 1:
        H, W = gray.shape
        gray = cv2.resize(
            gray, (max(1, round(W / step)), max(1, round(H / step))), interpolation=cv2.INTER_AREA
        )
        step_exact = W / gray.shape[1]
    poses = np.stack(
        [boxes[:, 0] + w / 2, boxes[:, 1] + h / 2, np.ones(len(boxes)), np.zeros(len(boxes))], axis=1
    )
    return descriptors(gray, poses, (w, h), cfg.patch_size, cfg.eps, step_exact)


def _background_boxes(gt: np.ndarray, shape, n: int, max_overlap: float, rng) -> np.ndarray:
    H, W = shape[:2]
    w, h = gt[2], gt[3]
    out = []
    for _ in range(50 * n):
        if len(out) == n or w >= W or h >= H:
            break
        b = np.array([rng.uniform(0, W - w), rng.uniform(0, H - h), w, h])
        if iou(b[None], gt[None])[0] <= max_overlap:
            out.append(b)
    return np.array(out).reshape(-1, 4)


def separation_data(
    sequence, cfg: MDSFiguresConfig = MDSFiguresConfig(), progress: bool = False
) -> Separation:
    """Figure (a): target and background descriptors over the sequence, embedded by MDS.

    Raises
    ------
    ValueError
        If the sequence has fewer than two frames with ground truth.
    """
    rng = np.random.default_rng([cfg.seed, 1])
    valid = np.flatnonzero(valid_rows(sequence.groundtruth))
    if len(valid) < 2:
        raise ValueError(f"{sequence.name}: figure (a) needs ground truth on at least 2 frames")
    stride = max(1, int(np.ceil(len(valid) / cfg.max_target)))
    picked = valid[::stride]
    mats, kinds, frames = [], [], []
    it = picked
    if progress:
        from tqdm import tqdm

        it = tqdm(picked, desc=f"{sequence.name} descriptors", unit="frame", leave=False)
    for t in it:
        fr = sequence.frame(int(t))
        gt = sequence.groundtruth[t]
        bg = _background_boxes(gt, fr.image.shape, cfg.n_background, cfg.max_background_overlap, rng)
        C = _region_descriptors(fr.image, np.concatenate([gt[None], bg]), cfg)
        mats.append(C)
        kinds += ["target"] + ["background"] * len(bg)
        frames += [int(t)] * len(C)
    M = np.concatenate(mats)
    X = embed(distance_matrix(M), cfg.method)
    return Separation(X, np.array(kinds), np.array(frames))


class _WalkCollector:
    """Observer collecting templates and target descriptors at chosen 0-based frames."""

    def __init__(self, tracker, indices: set[int], cfg: MDSFiguresConfig):
        self.tracker, self.indices, self.cfg = tracker, indices, cfg
        self.rng = np.random.default_rng([cfg.seed, 2])
        self.mats: list[np.ndarray] = []
        self.kinds: list[str] = []
        self.frames: list[int] = []

    def _add(self, M: np.ndarray, kind: str, frame1: int) -> None:
        self.mats.append(M.reshape(-1, *M.shape[-2:]))
        self.kinds += [kind] * len(self.mats[-1])
        self.frames += [frame1] * len(self.mats[-1])

    def on_frame(self, frame, records) -> None:
        i = int(frame.index)
        if i not in self.indices:
            return
        r = records[0]
        if i == 0 and r.estimate_template is not None:
            self._add(expm(r.estimate_template), "initial", 1)
        if r.templates is not None and r.log_weights is not None:
            w = np.exp(r.log_weights)
            top = top_k(w, self.cfg.top_k)
            rest = np.setdiff1d(np.arange(len(w)), top)
            m = min(len(rest), self.cfg.n_generated)
            other = self.rng.choice(rest, size=m, replace=False) if m else np.zeros(0, dtype=int)
            self._add(expm(r.templates[other]), "template", i + 1)
            self._add(expm(r.templates[top]), "top", i + 1)
        if r.estimate_template is not None and i > 0:
            self._add(expm(r.estimate_template), "estimate", i + 1)
        if frame.gt is not None:
            model = ObservationModel.from_tracker(self.tracker)
            if model is not None:
                pose = box_to_pose(frame.gt, model.base_wh)
                self._add(model.descriptors(model.prepare(frame.image), pose[None]), "target", i + 1)


def random_walk_data(
    sequence, cfg: MDSFiguresConfig = MDSFiguresConfig(), progress: bool = False
) -> RandomWalk:
    """Figure (b): run the manifold tracker and embed its templates at the chosen frames together."""
    from covviz.runner import run
    from covviz.trackers.manifold import make

    frames = sorted({int(f) for f in cfg.frames if int(f) <= len(sequence)})
    if not frames:
        raise ValueError(
            f"{sequence.name}: none of the frames {list(cfg.frames)} is in the sequence "
            f"({len(sequence)} frames)"
        )
    tracker = make(n_particles=cfg.n_particles, rng=np.random.default_rng([cfg.seed, 3]))
    col = _WalkCollector(tracker, {f - 1 for f in frames} | {0}, cfg)
    run(tracker, sequence, [col], max_frames=max(frames), progress=progress, seed=cfg.seed)
    M = np.concatenate(col.mats)
    X = embed(distance_matrix(M), cfg.method)
    return RandomWalk(X, np.array(col.kinds), np.array(col.frames))


# --------------------------------------------------------------------------- #
# drawing
# --------------------------------------------------------------------------- #
def _frame_greens(frames: list[int]) -> dict[int, tuple]:
    """Distinct shades from dark teal green (earliest frame) to bright yellow-green (latest)."""
    lo, hi = np.array([20, 120, 110]), np.array([210, 250, 60])
    out = {}
    for k, f in enumerate(frames):
        t = k / max(1, len(frames) - 1)
        out[f] = tuple(int(v) for v in np.round(lo + (hi - lo) * t))
    return out


def log_figures(stream, sep: Separation | None, walk: RandomWalk | None, sequence_name: str = "") -> None:
    """Log both figures as static 2-D points (and the description) into ``stream``."""
    import rerun as rr

    from covviz.viz import paths as P
    from covviz.viz.description import MDS_DESCRIPTION

    stream.log(P.DESCRIPTION, rr.TextDocument(MDS_DESCRIPTION, media_type=rr.MediaType.MARKDOWN), static=True)
    if sep is not None:
        for kind, col in (("background", BLUE), ("target", RED)):
            m = sep.kinds == kind
            stream.log(
                f"{P.FIGURE_SEPARATION}/{kind}",
                rr.Points2D(sep.coords[m], colors=[col], radii=[-3.5]),
                rr.AnyValues(frame=sep.frames[m].astype(np.int64)),
                static=True,
            )
    if walk is not None:
        frames = sorted({int(f) for f in walk.frames[walk.kinds != "initial"]}) or [1]
        greens = _frame_greens(frames)
        m = walk.kinds == "initial"
        if m.any():
            stream.log(
                f"{P.FIGURE_RANDOM_WALK}/initial",
                rr.Points2D(walk.coords[m], colors=[WHITE], radii=[-7.0], labels=["initial template"]),
                static=True,
            )
        for f in frames:
            base = f"{P.FIGURE_RANDOM_WALK}/frame_{f:04d}"
            for kind, radius in (("template", -2.5), ("top", -4.5), ("estimate", -6.0)):
                mk = (walk.kinds == kind) & (walk.frames == f)
                if mk.any():
                    labels = [f"estimate @{f}"] if kind == "estimate" else None
                    stream.log(
                        f"{base}/{kind}",
                        rr.Points2D(walk.coords[mk], colors=[greens[f]], radii=[radius], labels=labels),
                        static=True,
                    )
            mk = (walk.kinds == "target") & (walk.frames == f)
            if mk.any():
                stream.log(
                    f"{base}/target",
                    rr.Points2D(walk.coords[mk], colors=[RED], radii=[-6.0], labels=[f"target @{f}"]),
                    static=True,
                )


def save_pngs(sep: Separation | None, walk: RandomWalk | None, out_dir: Path, stem: str) -> list[Path]:
    """Write the figures as PNGs (matplotlib, Agg backend); returns the paths written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []

    def rgb(c):
        return tuple(v / 255 for v in c)

    with plt.style.context("dark_background"):
        if sep is not None:
            fig, ax = plt.subplots(figsize=(6, 5.2), dpi=110)
            for kind, col, label in (("background", BLUE, "background"), ("target", RED, "target")):
                m = sep.kinds == kind
                ax.scatter(
                    *sep.coords[m].T,
                    s=14,
                    color=rgb(col),
                    alpha=0.8,
                    label=f"{label} ({m.sum()})",
                    edgecolors="none",
                )
            written.append(_finish(plt, fig, ax, f"{stem}: target vs background on the manifold (MDS)", 8,
                                   out_dir / f"{stem}-mds-separation.png"))
        if walk is not None:
            fig, ax = plt.subplots(figsize=(6, 5.2), dpi=110)
            frames = sorted({int(f) for f in walk.frames[walk.kinds != "initial"]}) or [1]
            greens = _frame_greens(frames)
            for f in frames:
                for kind, size in (("template", 10), ("top", 34)):
                    mk = (walk.kinds == kind) & (walk.frames == f)
                    if mk.any():
                        ax.scatter(
                            *walk.coords[mk].T,
                            s=size,
                            color=rgb(greens[f]),
                            edgecolors="none",
                            label=f"templates @{f}" if kind == "template" else None,
                        )
                mt = ((walk.kinds == "template") | (walk.kinds == "top")) & (walk.frames == f)
                if mt.any():  # name each cloud by its frame
                    ax.annotate(
                        f"@{f}",
                        walk.coords[mt].mean(axis=0),
                        color=rgb(greens[f]),
                        fontsize=9,
                        fontweight="bold",
                        xytext=(0, -16),
                        textcoords="offset points",
                        ha="center",
                    )
                mk = (walk.kinds == "target") & (walk.frames == f)
                if mk.any():
                    ax.scatter(*walk.coords[mk].T, s=60, color=rgb(RED), marker="*", edgecolors="none")
                    ax.annotate(
                        str(f),
                        walk.coords[mk][0],
                        color=rgb(RED),
                        fontsize=8,
                        xytext=(4, 4),
                        textcoords="offset points",
                    )
            m = walk.kinds == "initial"
            if m.any():
                ax.scatter(
                    *walk.coords[m].T,
                    s=70,
                    color="white",
                    marker="o",
                    edgecolors="black",
                    label="initial template",
                )
            ax.scatter([], [], s=60, color=rgb(RED), marker="*", label="target (frame)")
            written.append(_finish(plt, fig, ax, f"{stem}: random walk of the templates (MDS)", 7,
                                   out_dir / f"{stem}-mds-random-walk.png"))
    return written


def _finish(plt, fig, ax, title: str, legend_size: int, path: Path) -> Path:
    """Title, axes and legend of an MDS figure; save it to ``path`` and close it."""
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("MDS 1 (Riemannian distance units)")
    ax.set_ylabel("MDS 2")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best", fontsize=legend_size)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
