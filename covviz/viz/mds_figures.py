"""``covviz mds SEQUENCE``: the paper's two manifold figures, as a recording and PNGs.

(a) **Target vs background.** Covariance descriptors of the target (at the
    ground-truth box) and of background regions of the same size (random
    positions that barely overlap the target) over the whole sequence, placed
    in the plane by MDS of their Riemannian distance matrix: red target, blue
    background. Separated clouds are what makes covariance tracking work.
(b) **Random walk of the templates.** The manifold tracker is run up to the
    last chosen frame; at each chosen frame (1-based, default 1, 101, 201, 501,
    801 as far as the sequence reaches) its generated templates (top 10 by
    weight and a sample of the others), the estimate's template, the target
    descriptor and background descriptors around it are collected, and all
    of them are embedded together (one MDS), with the initial template: the
    templates follow the target across the manifold, away from the
    background (the paper's caption).

One observation model serves both figures: the manifold tracker's, built at
its initialisation on frame 1 (:class:`covviz.model.observation.ObservationModel`,
taken from the tracker's init record), so a descriptor here is exactly what
the tracker would observe at that box. Each figure names the model it used.

Distances are computed in batches (:func:`covviz.embedding.distance_matrix`);
the embedding is classical MDS or SMACOF started from it (both deterministic). The data functions return arrays (no rerun); the logging
and plotting functions draw them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from covviz.embedding import distance_matrix, embed
from covviz.errors import InputError
from covviz.metrics import iou, valid_rows
from covviz.model.observation import ObservationModel, box_to_pose
from covviz.model.spd import expm
from covviz.runner import Observer
from covviz.viz.diagnostics import top_k
from covviz.viz.palette import BACKGROUND_COLOR as BLUE
from covviz.viz.palette import GT_COLOR as RED
from covviz.viz.palette import INITIAL_COLOR as WHITE

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
    n_walk_background : int
        Background regions around the target at each frame of figure (b).
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
    n_walk_background: int = 4

    def __post_init__(self):
        if not self.frames or any(int(f) < 1 for f in self.frames):
            raise ValueError(f"frames must be 1-based frame numbers (>= 1), got {self.frames}")
        if self.max_target < 2 or self.n_background < 1:
            raise ValueError("max_target must be >= 2 and n_background >= 1")
        if self.method not in ("classical", "smacof"):
            raise ValueError(f"method must be 'classical' or 'smacof', got {self.method!r}")


@dataclass(frozen=True)
class Separation:
    """Figure (a): coordinates, kinds (``target``/``background``), 1-based frames, and the model's name."""

    coords: np.ndarray
    kinds: np.ndarray
    frames: np.ndarray
    model: str = ""


@dataclass(frozen=True)
class RandomWalk:
    """Figure (b): coordinates, kinds, 1-based frames, and the observation model the tracker used.

    Kinds: ``initial``, ``template``, ``top``, ``estimate``, ``target``, ``background``.
    """

    coords: np.ndarray
    kinds: np.ndarray
    frames: np.ndarray
    model: ObservationModel | None = None


def _region_descriptors(model: ObservationModel, image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Descriptors the model observes at axis-aligned boxes (centre and area; its aspect ratio)."""
    poses = np.stack([box_to_pose(b, model.base_wh) for b in np.asarray(boxes).reshape(-1, 4)])
    return model.descriptors(model.prepare(image), poses)


def default_model(sequence) -> ObservationModel:
    """The observation model of the default manifold tracker started on the sequence's first frame."""
    return ObservationModel.build(sequence.frame(0).image, sequence.init_box)


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
    sequence,
    cfg: MDSFiguresConfig = MDSFiguresConfig(),
    progress: bool = False,
    model: ObservationModel | None = None,
) -> Separation:
    """Figure (a): target and background descriptors over the sequence, embedded by MDS.

    ``model``: the tracker's observation model (figure (b)'s, ``RandomWalk.model``);
    default :func:`default_model`.

    Raises
    ------
    ValueError
        If the sequence has fewer than two frames with ground truth.
    """
    rng = np.random.default_rng([cfg.seed, 1])
    valid = np.flatnonzero(valid_rows(sequence.groundtruth))
    if len(valid) < 2:
        raise InputError(f"{sequence.name}: figure (a) needs ground truth on at least 2 frames")
    model = model or default_model(sequence)
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
        C = _region_descriptors(model, fr.image, np.concatenate([gt[None], bg]))
        mats.append(C)
        kinds += ["target"] + ["background"] * len(bg)
        frames += [int(t) + 1] * len(C)
    M = np.concatenate(mats)
    X = embed(distance_matrix(M), cfg.method)
    return Separation(X, np.array(kinds), np.array(frames), model.describe())


class _WalkCollector(Observer):
    """Observer collecting templates and target descriptors at chosen 0-based frames."""

    def __init__(self, indices: set[int], cfg: MDSFiguresConfig):
        self.indices, self.cfg = indices, cfg
        self.model: ObservationModel | None = None
        self.rng = np.random.default_rng([cfg.seed, 2])
        self.mats: list[np.ndarray] = []
        self.kinds: list[str] = []
        self.frames: list[int] = []

    def _add(self, M: np.ndarray, kind: str, frame1: int) -> None:
        self.mats.append(M.reshape(-1, *M.shape[-2:]))
        self.kinds += [kind] * len(self.mats[-1])
        self.frames += [frame1] * len(self.mats[-1])

    def on_start(self, start, found) -> None:
        self.model = start.trackers[0].model  # the tracker's frozen observation model

    def on_frame(self, frame, records, found) -> None:
        i = int(frame.index)
        r = records[0]
        if i not in self.indices:
            return
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
        if frame.gt is not None and self.model is not None:
            bg = _background_boxes(frame.gt, frame.image.shape, self.cfg.n_walk_background,
                                   self.cfg.max_background_overlap, self.rng)
            C = _region_descriptors(self.model, frame.image, np.concatenate([frame.gt[None], bg]))
            self._add(C[:1], "target", i + 1)
            if len(bg):
                self._add(C[1:], "background", i + 1)


def random_walk_data(
    sequence, cfg: MDSFiguresConfig = MDSFiguresConfig(), progress: bool = False
) -> RandomWalk:
    """Figure (b): run the manifold tracker and embed its templates at the chosen frames together."""
    from covviz.runner import run
    from covviz.trackers.manifold import make

    frames = sorted({int(f) for f in cfg.frames if int(f) <= len(sequence)})
    if not frames:
        raise InputError(
            f"{sequence.name}: none of the frames {list(cfg.frames)} is in the sequence "
            f"({len(sequence)} frames)"
        )
    dropped = sorted({int(f) for f in cfg.frames} - set(frames))
    if dropped:
        # the paper's frames outlast a short sequence: only worth a warning when the user chose them
        level = logging.INFO if tuple(cfg.frames) == DEFAULT_FRAMES else logging.WARNING
        log.log(level, "%s: frames %s are past the end (%d frames); the random walk shows %s", sequence.name,
                    ", ".join(map(str, dropped)), len(sequence), ", ".join(map(str, frames)))
    col = _WalkCollector({f - 1 for f in frames} | {0}, cfg)
    with make(n_particles=cfg.n_particles, rng=np.random.default_rng([cfg.seed, 3])) as tracker:
        run(tracker, sequence, [col], max_frames=max(frames), progress=progress, seed=cfg.seed)
    no_target = [f for f in frames if not any(k == "target" and fr == f for k, fr in zip(col.kinds, col.frames))]
    if no_target:
        log.warning("%s: no ground truth at frames %s: the figure has no target (red) there", sequence.name,
                    ", ".join(map(str, no_target)))
    M = np.concatenate(col.mats)
    D = distance_matrix(M)
    if not np.any(D > 0):
        raise InputError(f"{sequence.name}: every template and descriptor of the random walk is the same matrix; "
                         "there is nothing to draw (a constant image?)")
    X = embed(D, cfg.method)
    return RandomWalk(X, np.array(col.kinds), np.array(col.frames), col.model)


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
    from covviz.viz.description import MDS_DESCRIPTION, viewer_safe

    note = _model_note(sep, walk)
    text = MDS_DESCRIPTION + (f"\n\n**Observation model** (both figures): {note}.\n" if note else "")
    stream.log(P.DESCRIPTION, rr.TextDocument(viewer_safe(text), media_type=rr.MediaType.MARKDOWN), static=True)
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
            mk = (walk.kinds == "background") & (walk.frames == f)
            if mk.any():
                stream.log(
                    f"{base}/background",
                    rr.Points2D(walk.coords[mk], colors=[BLUE], radii=[-3.0]),
                    static=True,
                )


def _model_note(sep: Separation | None, walk: RandomWalk | None) -> str:
    """The observation model's one-line description, as the figures print it."""
    if walk is not None and walk.model is not None:
        return f"the manifold tracker's, built on frame 1: {walk.model.describe()}"
    return sep.model if sep is not None and sep.model else ""


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
                                   out_dir / f"{stem}-mds-separation.png", _model_note(sep, walk)))
        if walk is not None:
            fig, ax = plt.subplots(figsize=(6, 5.2), dpi=110)
            frames = sorted({int(f) for f in walk.frames[walk.kinds != "initial"]}) or [1]
            greens = _frame_greens(frames)
            mb = walk.kinds == "background"
            if mb.any():
                ax.scatter(*walk.coords[mb].T, s=12, color=rgb(BLUE), alpha=0.7, edgecolors="none",
                           label="background (around the target)")
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
            _zoom_to_walk(ax, walk, rgb(BLUE))
            written.append(_finish(plt, fig, ax, f"{stem}: random walk of the templates (MDS)", 7,
                                   out_dir / f"{stem}-mds-random-walk.png", _model_note(sep, walk)))
    return written


#: Width over height of the zoomed random-walk axes (about the free area of a 6 x 5.2 in figure).
WALK_BOX_ASPECT = 1.3


def _zoom_to_walk(ax, walk: RandomWalk, background_colour) -> None:
    """Frame the templates and targets; background descriptors far outside go to an inset.

    Background regions sit several distance units from the target while a template cloud spans a
    fraction of one, so framing everything shrinks each cloud to a dot. The main axes frame what the
    figure is about (templates, targets, the initial template); when some background lies beyond that
    view, an inset shows the full extent with the zoomed region outlined.
    """
    import matplotlib.patches as mpatches

    mb = walk.kinds == "background"
    if not mb.any() or mb.all():
        return
    focus = walk.coords[~mb]
    lo, hi = focus.min(axis=0), focus.max(axis=0)
    pad = 0.15 * max(float((hi - lo).max()), 1e-6)
    lo, hi = lo - pad, hi + pad
    # equal axis units in a box about as wide as the figure's: grow the narrower side about its centre
    width = max(float(hi[0] - lo[0]), WALK_BOX_ASPECT * float(hi[1] - lo[1]))
    size = np.array([width, width / WALK_BOX_ASPECT])
    centre = (lo + hi) / 2
    lo, hi = centre - size / 2, centre + size / 2
    outside = ~((walk.coords[mb] >= lo) & (walk.coords[mb] <= hi)).all(axis=1)
    if not outside.any():
        return
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    inset = ax.inset_axes((0.02, 0.02, 0.3, 0.3))
    inset.scatter(*walk.coords[mb].T, s=3, color=background_colour, edgecolors="none")
    inset.scatter(*focus.T, s=3, color="0.85", edgecolors="none")
    inset.add_patch(mpatches.Rectangle(lo, *(hi - lo), fill=False, edgecolor="white", linewidth=0.8))
    inset.set_xticks([])
    inset.set_yticks([])
    inset.set_aspect("equal", adjustable="datalim")
    inset.set_title(f"full extent: {int(outside.sum())} background outside", fontsize=6, pad=2)


def _finish(plt, fig, ax, title: str, legend_size: int, path: Path, note: str = "") -> Path:
    """Title, axes, legend and the observation model's note of an MDS figure; save it to ``path``, close it."""
    import textwrap

    ax.set_title(title, fontsize=10)
    if note:
        fig.text(0.5, 0.005, "\n".join(textwrap.wrap("Descriptors by " + note, 95)), ha="center", va="bottom",
                 fontsize=6, color="0.75")
    ax.set_xlabel("MDS 1 (Riemannian distance units)")
    ax.set_ylabel("MDS 2")
    # zoomed axes (fixed limits) keep them and give up the box shape; the others grow their limits
    ax.set_aspect("equal", adjustable="datalim" if ax.get_autoscalex_on() else "box")
    ax.legend(loc="best", fontsize=legend_size)
    fig.tight_layout(rect=(0, 0.06 if note else 0, 1, 1))
    fig.savefig(path)
    plt.close(fig)
    return path
