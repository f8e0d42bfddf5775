"""``covviz mds SEQUENCE``: the paper's manifold figures, with their claims measured.

(a) **Target vs background** (the paper's "target on manifold separated from
    background"). Covariance descriptors of the target (at the ground-truth
    box) and of background regions of the same size (random positions that
    barely overlap the target) over the whole sequence, placed in the plane by
    MDS of their Riemannian distance matrix: red target, blue background. The
    claim ("clear separation of target and background") is measured on the
    distances themselves, not on the picture: the silhouette of the two labels
    on the Riemannian distance matrix (:func:`covviz.embedding.silhouette`),
    which holds above :data:`SEPARATED_SILHOUETTE`.
(b) **Random walk of the templates** (the paper's "random walk on the
    manifold"). The tracker (its shipped config, or ``manifold-paper``: the
    paper's likelihood and walk) runs up to the last chosen frame (1-based,
    default 1, 101, 201, 501, 801 as far as the sequence reaches). At each
    chosen frame, as the paper's caption says: the 10 generated templates most
    similar to the truth (green), the truth (red) and background around it
    (blue); beside it the whole cloud (a sample of every particle's template,
    the estimate's template, the initial one). All of it is one MDS. The claim
    (the target is "well modelled by the generated covariances") is measured
    per frame by the cloud's **coverage** of the target: the distance from the
    target descriptor to the nearest template over the median distance of the
    templates to the cloud's (Karcher) mean (:func:`covviz.embedding.coverage`),
    over every particle's template; it holds at or below :data:`COVERED`.

Each figure prints its embedding's stress-1 (how much of the distances the 2-D
picture misrepresents). A claim that fails is printed as failing, on stdout
and in the figure.

One observation model serves both figures: the tracker's, built at its
initialisation on frame 1 (:class:`covviz.model.observation.ObservationModel`,
taken from the tracker's init record), so a descriptor here is exactly what
the tracker would observe at that box. Each figure names the model it used.

The data functions return arrays and numbers (no rerun); the logging and
plotting functions draw them. The paper's first manifold figure ("why
manifold") is :mod:`covviz.viz.why_manifold`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from covviz.embedding import coverage, distance_matrix, embed, silhouette, silhouette_by_group, stress1
from covviz.errors import InputError
from covviz.metrics import iou, valid_rows
from covviz.model.observation import ObservationModel, box_to_pose
from covviz.model.spd import distance_riemann, expm, mean_riemann
from covviz.runner import Observer
from covviz.viz.palette import BACKGROUND_COLOR as BLUE
from covviz.viz.palette import GT_COLOR as RED
from covviz.viz.palette import INITIAL_COLOR as WHITE

__all__ = [
    "COVERED",
    "DEFAULT_FRAMES",
    "FIGURE_FORMATS",
    "SEPARATED_SILHOUETTE",
    "Claim",
    "FrameCoverage",
    "MDSFiguresConfig",
    "RandomWalk",
    "Separation",
    "claims",
    "claims_text",
    "log_figures",
    "random_walk_data",
    "save_figures",
    "save_pngs",
    "separation_data",
]

log = logging.getLogger("covviz.viz")

#: The paper's frames (1-based) for the random-walk figure.
DEFAULT_FRAMES = (1, 101, 201, 501, 801)
#: Trackers whose template walk figure (b) can show.
WALK_TRACKERS = ("manifold", "manifold-paper")
#: The separation claim holds when the silhouette of target vs background on the Riemannian
#: distances is at least this (below 0.25: "no substantial structure", Kaufman & Rousseeuw 1990).
SEPARATED_SILHOUETTE = 0.25
#: The random-walk claim holds at a frame when the cloud's coverage of the target
#: (nearest template / the cloud's median radius) is at most this.
COVERED = 1.0
#: Formats the figures can be written in.
FIGURE_FORMATS = ("png", "svg", "pdf")


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
        Generated templates per chosen frame drawn in the whole cloud (a sample;
        the coverage uses every particle's template).
    n_near : int
        The templates most similar to the truth per frame (the paper's caption: 10).
    method : {"classical", "smacof"}
    seed : int
        Seeds the background positions, the template samples and the tracker.
    n_particles : int, optional
        Particles of the tracker (default: its own).
    n_walk_background : int
        Background regions around the target at each frame of figure (b).
    tracker : {"manifold", "manifold-paper"}
        The tracker of figure (b), with its shipped config; ``manifold-paper`` is the
        paper's likelihood. Its observation model serves both figures.
    """

    frames: tuple = DEFAULT_FRAMES
    max_target: int = 150
    n_background: int = 3
    max_background_overlap: float = 0.1
    n_generated: int = 30
    n_near: int = 10
    method: str = "classical"
    seed: int = 0
    n_particles: int | None = None
    n_walk_background: int = 4
    tracker: str = "manifold"

    def __post_init__(self):
        if not self.frames or any(int(f) < 1 for f in self.frames):
            raise ValueError(f"frames must be 1-based frame numbers (>= 1), got {self.frames}")
        if self.max_target < 2 or self.n_background < 1:
            raise ValueError("max_target must be >= 2 and n_background >= 1")
        if self.method not in ("classical", "smacof"):
            raise ValueError(f"method must be 'classical' or 'smacof', got {self.method!r}")
        if self.tracker not in WALK_TRACKERS:
            raise ValueError(f"tracker must be one of {', '.join(WALK_TRACKERS)}, got {self.tracker!r}")
        if self.n_near < 1:
            raise ValueError("n_near must be at least 1")


@dataclass(frozen=True)
class Separation:
    """Figure (a): coordinates, kinds (``target``/``background``), 1-based frames, the model's name, and its numbers.

    ``silhouette``: of target vs background on the Riemannian distances ``distances``
    between the descriptors ``matrices``; ``stress``: the embedding's stress-1 against them.
    """

    coords: np.ndarray
    kinds: np.ndarray
    frames: np.ndarray
    model: str = ""
    distances: np.ndarray | None = None
    silhouette: float = float("nan")
    stress: float = float("nan")
    matrices: np.ndarray | None = None
    by_group: dict = field(default_factory=dict)


@dataclass(frozen=True)
class FrameCoverage:
    """The template cloud against the target at one frame (1-based).

    ``nearest``: the target's distance to its nearest template; ``radius``: the
    median distance of the templates to the cloud's Karcher mean; ``ratio``:
    ``nearest / radius`` (:func:`covviz.embedding.coverage`); ``n``: templates;
    ``iou``: the tracker's estimate against the truth there (a cloud that lost the
    target cannot be expected to cover it); ``nearest_estimate``: the distance of the
    descriptor at the estimate's own box to its nearest template (does the cloud cover
    even what the tracker observes where it is?).
    """

    frame: int
    nearest: float
    radius: float
    ratio: float
    n: int
    iou: float = float("nan")
    nearest_estimate: float = float("nan")

    @property
    def holds(self) -> bool:
        return bool(self.ratio <= COVERED)


@dataclass(frozen=True)
class RandomWalk:
    """Figure (b): coordinates, kinds, 1-based frames, the observation model the tracker used, and its numbers.

    Kinds: ``initial``, ``template`` (a sample of the cloud), ``near`` (the
    templates most similar to the truth), ``estimate``, ``target``,
    ``background``. ``coverage``: one :class:`FrameCoverage` per chosen frame
    with ground truth and a spread cloud; ``clouds``: every particle's template
    (SPD) at those frames, and ``targets`` the target descriptor there;
    ``matrices`` every embedded point's SPD matrix and ``distances`` their
    Riemannian distances (for checking the numbers).
    """

    coords: np.ndarray
    kinds: np.ndarray
    frames: np.ndarray
    model: ObservationModel | None = None
    coverage: tuple = ()
    stress: float = float("nan")
    tracker: str = "manifold"
    clouds: dict = field(default_factory=dict)
    targets: dict = field(default_factory=dict)
    matrices: np.ndarray | None = None
    distances: np.ndarray | None = None


@dataclass(frozen=True)
class Claim:
    """One claim of the paper, measured: what it says, its number, the rule, and whether it holds."""

    figure: str
    says: str
    value: float
    rule: str
    holds: bool

    @property
    def verdict(self) -> str:
        return "holds" if self.holds else "FAILS"

    def line(self) -> str:
        return f"{self.says}: {self.value:.3f} ({self.rule}) - {self.verdict}"


def _region_descriptors(model: ObservationModel, image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Descriptors the model observes at axis-aligned boxes (centre and area; its aspect ratio)."""
    poses = np.stack([box_to_pose(b, model.base_wh) for b in np.asarray(boxes).reshape(-1, 4)])
    return model.descriptors(model.prepare(image), poses)


def default_model(sequence, tracker: str = "manifold") -> ObservationModel:
    """The observation model of the tracker (its shipped config) started on the sequence's first frame."""
    from covviz.trackers.manifold import PAPER_LIKELIHOOD, ManifoldConfig

    cfg = ManifoldConfig() if tracker == "manifold" else ManifoldConfig().replace(**PAPER_LIKELIHOOD)
    return ObservationModel.build(sequence.frame(0).image, sequence.init_box, cfg.observation)


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


def sample_frames(sequence, max_frames: int) -> np.ndarray:
    """0-based frames with ground truth, at most ``max_frames`` of them with an even stride."""
    valid = np.flatnonzero(valid_rows(sequence.groundtruth))
    stride = max(1, int(np.ceil(len(valid) / max_frames)))
    return valid[::stride]


def separation_data(
    sequence,
    cfg: MDSFiguresConfig = MDSFiguresConfig(),
    progress: bool = False,
    model: ObservationModel | None = None,
) -> Separation:
    """Figure (a): target and background descriptors over the sequence, embedded by MDS, and their silhouette.

    ``model``: the tracker's observation model (figure (b)'s, ``RandomWalk.model``);
    default :func:`default_model`.

    Raises
    ------
    InputError
        If the sequence has fewer than two frames with ground truth.
    """
    rng = np.random.default_rng([cfg.seed, 1])
    picked = sample_frames(sequence, cfg.max_target)
    if len(picked) < 2:
        raise InputError(f"{sequence.name}: figure (a) needs ground truth on at least 2 frames")
    model = model or default_model(sequence, cfg.tracker)
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
    kinds = np.array(kinds)
    D = distance_matrix(M)
    X = embed(D, cfg.method)
    two = 2 <= len(set(kinds)) and len(D) > 2
    sil = silhouette(D, kinds) if two else float("nan")
    return Separation(X, kinds, np.array(frames), model.describe(), D, sil, stress1(X, D), M,
                      silhouette_by_group(D, kinds) if two else {})


class _WalkCollector(Observer):
    """Observer collecting templates and target descriptors at chosen 0-based frames."""

    def __init__(self, indices: set[int], cfg: MDSFiguresConfig):
        self.indices, self.cfg = indices, cfg
        self.model: ObservationModel | None = None
        self.rng = np.random.default_rng([cfg.seed, 2])
        self.mats: list[np.ndarray] = []
        self.kinds: list[str] = []
        self.frames: list[int] = []
        self.coverage: list[FrameCoverage] = []
        self.clouds: dict[int, np.ndarray] = {}
        self.targets: dict[int, np.ndarray] = {}

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
        target = estimate = None
        if frame.gt is not None and self.model is not None:
            bg = _background_boxes(frame.gt, frame.image.shape, self.cfg.n_walk_background,
                                   self.cfg.max_background_overlap, self.rng)
            C = _region_descriptors(self.model, frame.image, np.concatenate([frame.gt[None], bg,
                                                                            np.asarray(r.box)[None]]))
            target, estimate, C = C[0], C[-1], C[:-1]
            self._add(C[:1], "target", i + 1)
            if len(bg):
                self._add(C[1:], "background", i + 1)
        if r.templates is not None and i > 0:
            T = expm(r.templates)  # every particle's template, SPD
            near = np.zeros(0, dtype=int)
            if target is not None:
                to_target = distance_riemann(T, target[None])
                near = np.argsort(to_target, kind="stable")[: self.cfg.n_near]
                centre = mean_riemann(T, maxiter=50)
                to_mean = distance_riemann(T, centre[None])
                ratio = coverage(to_target, to_mean)
                on = float(iou(np.asarray(r.box, dtype=np.float64)[None], frame.gt[None])[0])
                own = float(distance_riemann(T, estimate[None]).min())
                self.coverage.append(FrameCoverage(i + 1, float(to_target.min()), float(np.median(to_mean)),
                                                   ratio, len(T), on, own))
                self.clouds[i + 1], self.targets[i + 1] = T, target
            rest = np.setdiff1d(np.arange(len(T)), near)
            m = min(len(rest), self.cfg.n_generated)
            other = self.rng.choice(rest, size=m, replace=False) if m else np.zeros(0, dtype=int)
            self._add(T[other], "template", i + 1)
            if len(near):
                self._add(T[near], "near", i + 1)
        if r.estimate_template is not None and i > 0:
            self._add(expm(r.estimate_template), "estimate", i + 1)


def random_walk_data(
    sequence, cfg: MDSFiguresConfig = MDSFiguresConfig(), progress: bool = False
) -> RandomWalk:
    """Figure (b): run the tracker, embed its templates at the chosen frames together, measure the coverage."""
    from covviz.runner import run
    from covviz.trackers.manifold import make, make_paper

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
    factory = make if cfg.tracker == "manifold" else make_paper
    with factory(n_particles=cfg.n_particles, rng=np.random.default_rng([cfg.seed, 3])) as tracker:
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
    return RandomWalk(X, np.array(col.kinds), np.array(col.frames), col.model, tuple(col.coverage), stress1(X, D),
                      cfg.tracker, col.clouds, col.targets, M, D)


def claims(sep: Separation | None, walk: RandomWalk | None) -> list[Claim]:
    """The paper's claims of the two figures, measured (:class:`Claim`), in the order the figures show them."""
    out = []
    if sep is not None and np.isfinite(sep.silhouette):
        out.append(Claim("separation", "target vs background: silhouette on the Riemannian distances",
                         sep.silhouette, f">= {SEPARATED_SILHOUETTE:g} claimed: clear separation",
                         bool(sep.silhouette >= SEPARATED_SILHOUETTE)))
    if walk is not None:
        for c in walk.coverage:
            track = "" if not np.isfinite(c.iou) else f" (estimate's IoU {c.iou:.2f}{'' if c.iou >= 0.5 else ', off track'})"
            out.append(Claim("random walk", f"frame {c.frame}{track}: templates' coverage of the target", c.ratio,
                             f"nearest template {c.nearest:.3f} / cloud radius {c.radius:.3f}; <= {COVERED:g} "
                             "claimed: well modelled by the generated covariances; the estimate's own observation: "
                             f"nearest {c.nearest_estimate:.3f}", c.holds))
    return out


def _stress_note(stress: float) -> str:
    """Kruskal's reading of a stress-1."""
    quality = "good" if stress <= 0.05 else "fair" if stress <= 0.1 else "poor" if stress <= 0.2 else "bad"
    return f"embedding stress-1 {stress:.3f} ({quality}: " + (
        "the picture keeps the distances)" if stress <= 0.1 else "read distances from the numbers, not the picture)")


def claims_text(sep: Separation | None, walk: RandomWalk | None, sequence_name: str = "") -> list[str]:
    """The lines ``covviz mds`` prints: each claim with its number and verdict, and each embedding's stress."""
    lines = []
    tracker = walk.tracker if walk is not None else "manifold"
    head = f"{sequence_name}: " if sequence_name else ""
    if sep is not None:
        lines.append(f"{head}target vs background ({int((sep.kinds == 'target').sum())} target, "
                     f"{int((sep.kinds == 'background').sum())} background descriptors; {tracker}'s model)")
        lines += [f"  {c.line()}" for c in claims(sep, None)]
        if sep.by_group:
            lines.append("  mean silhouette of the target's points " + f"{sep.by_group.get('target', np.nan):.3f}, "
                         f"of the background's {sep.by_group.get('background', np.nan):.3f}")
        if np.isfinite(sep.stress):
            lines.append(f"  {_stress_note(sep.stress)}")
    if walk is not None:
        lines.append(f"{head}random walk of {tracker}'s templates (coverage = nearest template / median distance "
                     "of the templates to their mean)")
        lines += [f"  {c.line()}" for c in claims(None, walk)]
        if not walk.coverage:
            lines.append("  no frame with both ground truth and generated templates: no coverage to measure")
        if np.isfinite(walk.stress):
            lines.append(f"  {_stress_note(walk.stress)}")
    return lines


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


def _walk_frames(walk: RandomWalk) -> list[int]:
    return sorted({int(f) for f in walk.frames[walk.kinds != "initial"]}) or [1]


def log_figures(stream, sep: Separation | None, walk: RandomWalk | None, sequence_name: str = "") -> None:
    """Log both figures as static 2-D points, and the description with the claims' numbers, into ``stream``.

    Under ``figures/random_walk/frame_NNNN``: ``near`` (the templates most similar to the truth),
    ``target`` and ``background`` are the paper's caption; ``template`` and ``estimate`` the whole cloud.
    Only the targets carry a label (their frame), so labels do not pile up.
    """
    import rerun as rr

    from covviz.viz import paths as P
    from covviz.viz.description import MDS_DESCRIPTION, viewer_safe

    note = _model_note(sep, walk)
    numbers = "\n".join(f"    {line}" for line in claims_text(sep, walk, sequence_name))
    far = 0 if walk is None else int((~_viewer_keep(walk)).sum())
    text = (MDS_DESCRIPTION + (f"\n\n**Observation model** (both figures): {note}.\n" if note else "")
            + (f"\n{far} background descriptors of the random walk lie far outside it and are left out of the "
               "view (the PNG's inset shows them).\n" if far else "")
            + (f"\n**The claims, measured** (FAILS where a claim does not hold here):\n\n{numbers}\n" if numbers else ""))
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
        frames = _walk_frames(walk)
        greens = _frame_greens(frames)
        keep = _viewer_keep(walk)
        m = walk.kinds == "initial"
        if m.any():
            stream.log(
                f"{P.FIGURE_RANDOM_WALK}/initial",
                rr.Points2D(walk.coords[m], colors=[WHITE], radii=[-7.0], labels=["initial"]),
                static=True,
            )
        for f in frames:
            base = f"{P.FIGURE_RANDOM_WALK}/frame_{f:04d}"
            for kind, radius, colour in (("template", -2.0, greens[f]), ("near", -4.5, greens[f]),
                                         ("estimate", -5.0, greens[f]), ("background", -3.0, BLUE)):
                mk = (walk.kinds == kind) & (walk.frames == f) & keep
                if mk.any():
                    stream.log(f"{base}/{kind}", rr.Points2D(walk.coords[mk], colors=[colour], radii=[radius],
                                                             show_labels=False), static=True)
            mk = (walk.kinds == "target") & (walk.frames == f)
            if mk.any():
                stream.log(
                    f"{base}/target",
                    rr.Points2D(walk.coords[mk], colors=[RED], radii=[-6.0], labels=[f"{f}"], show_labels=True),
                    static=True,
                )


def _viewer_keep(walk: RandomWalk) -> np.ndarray:
    """Which points of the walk the viewer shows.

    The view frames everything it holds: background far from the templates would shrink the walk
    to one clump of labels, so only the background within twice the walk's extent is logged.
    """
    keep = np.ones(len(walk.kinds), dtype=bool)
    mb = walk.kinds == "background"
    if mb.any() and (~mb).any():
        lo, hi = _focus_box(walk.coords, ~mb, 1.6)
        lo, hi = lo - (hi - lo) / 2, hi + (hi - lo) / 2
        keep = ~mb | ((walk.coords >= lo) & (walk.coords <= hi)).all(axis=1)
    return keep


def _model_note(sep: Separation | None, walk: RandomWalk | None) -> str:
    """The observation model's one-line description, as the figures print it."""
    if walk is not None and walk.model is not None:
        return f"the {walk.tracker} tracker's (shipped config), built on frame 1: {walk.model.describe()}"
    return sep.model if sep is not None and sep.model else ""


def parse_formats(text: str) -> tuple[str, ...]:
    """``"png,svg"`` -> ``("png", "svg")``; raises ValueError on a format not in :data:`FIGURE_FORMATS`."""
    out = tuple(dict.fromkeys(v.strip().lower().lstrip(".") for v in str(text).split(",") if v.strip()))
    bad = [v for v in out if v not in FIGURE_FORMATS]
    if not out or bad:
        raise ValueError(f"formats must be some of {','.join(FIGURE_FORMATS)}; got {text!r}")
    return out


def save_pngs(sep: Separation | None, walk: RandomWalk | None, out_dir: Path, stem: str) -> list[Path]:
    """The figures as PNGs (:func:`save_figures`)."""
    return save_figures(sep, walk, out_dir, stem, ("png",))


def _rgb(c) -> tuple:
    return tuple(v / 255 for v in c)


def _claim_block(fig, lines: list[str], y: float, size: float = 7.0) -> None:
    """The measured claims under a figure; failing ones in orange."""
    import textwrap

    step = 1.35 * size / 72 / fig.get_figheight()
    for line in lines:
        for part in textwrap.wrap(line, 150, subsequent_indent="    "):
            fig.text(0.02, y, part, ha="left", va="top", fontsize=size, family="monospace",
                     color="#ffa040" if "FAILS" in line else "0.85")
            y -= step


def save_figures(
    sep: Separation | None, walk: RandomWalk | None, out_dir: Path, stem: str, formats=("png",),
    sequence_name: str = "",
) -> list[Path]:
    """Write the figures (matplotlib, Agg) in each of ``formats``; returns the paths written.

    The separation figure has the silhouette and the stress under it; the random-walk figure two
    panels (the paper's caption: the templates most similar to the truth; and the whole cloud) with
    the coverage of every frame under them. Legends sit outside the data.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    name = sequence_name or stem
    note = _model_note(sep, walk)

    def save(fig, suffix: str) -> None:
        for fmt in formats:
            path = out_dir / f"{stem}-mds-{suffix}.{fmt}"
            fig.savefig(path)
            written.append(path)
        plt.close(fig)

    with plt.style.context("dark_background"):
        if sep is not None:
            fig = plt.figure(figsize=(8.4, 6.0), dpi=120)
            ax = fig.add_axes((0.09, 0.27, 0.66, 0.64))
            for kind, col in (("background", BLUE), ("target", RED)):
                m = sep.kinds == kind
                ax.scatter(*sep.coords[m].T, s=14, color=_rgb(col), alpha=0.8, label=f"{kind} ({m.sum()})",
                           edgecolors="none")
            ax.set_title(f"{name}: target vs background on the manifold (MDS)", fontsize=10)
            _axes_labels(ax)
            ax.set_aspect("equal", adjustable="datalim")
            ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8, frameon=False)
            lines = claims_text(sep, None)[1:]
            _claim_block(fig, [*lines, *(_wrap_note(note))], 0.15)
            save(fig, "separation")
        if walk is not None:
            fig = plt.figure(figsize=(13, 7.4), dpi=120)
            axl = fig.add_axes((0.07, 0.38, 0.40, 0.54))
            axr = fig.add_axes((0.56, 0.38, 0.40, 0.54))
            _draw_walk_caption(axl, walk)
            _draw_walk_cloud(axr, walk)
            n_near = max(_near_counts(walk), default=0)
            axl.set_title(f"{name}: as the paper's caption - the {n_near} generated templates most similar to "
                          "the truth", fontsize=10)
            axr.set_title(f"{name}: the whole template cloud of {walk.tracker}", fontsize=10)
            lines = claims_text(None, walk)[1:]
            _claim_block(fig, [*lines, *(_wrap_note(note))], 0.16)
            save(fig, "random-walk")
    return written


def _near_counts(walk: RandomWalk) -> set[int]:
    return {int(((walk.kinds == "near") & (walk.frames == f)).sum()) for f in _walk_frames(walk)} - {0}


def _wrap_note(note: str) -> list[str]:
    return [f"descriptors by {note}"] if note else []


def _axes_labels(ax) -> None:
    ax.set_xlabel("MDS 1 (Riemannian distance units)")
    ax.set_ylabel("MDS 2")


def _draw_walk_caption(ax, walk: RandomWalk) -> None:
    """The paper's caption: per frame the templates most similar to the truth (green x), the truth (red), background (blue x)."""
    frames = _walk_frames(walk)
    greens = _frame_greens(frames)
    cov = {c.frame: c for c in walk.coverage}
    mb = walk.kinds == "background"
    if mb.any():
        ax.scatter(*walk.coords[mb].T, s=16, color=_rgb(BLUE), marker="x", linewidths=0.8,
                   label="background around the truth")
    for f in frames:
        mk = (walk.kinds == "near") & (walk.frames == f)
        if mk.any():
            ax.scatter(*walk.coords[mk].T, s=26, color=_rgb(greens[f]), marker="x", linewidths=1.0,
                       label=f"@{f}: {int(mk.sum())} most similar to the truth")
        mt = (walk.kinds == "target") & (walk.frames == f)
        if mt.any():
            ax.scatter(*walk.coords[mt].T, s=70, color=_rgb(RED), marker="*", edgecolors="none")
            c = cov.get(f)
            ax.annotate(f"{f}" + (f" ({c.ratio:.2f}{'' if c.holds else ' FAILS'})" if c else ""),
                        walk.coords[mt][0], color=_rgb(RED), fontsize=7, xytext=(5, 4), textcoords="offset points")
    ax.scatter([], [], s=70, color=_rgb(RED), marker="*", label="truth (frame, coverage)")
    _axes_labels(ax)
    _zoom_to_walk(ax, walk, _rgb(BLUE), np.isin(walk.kinds, ("near", "target", "initial")))
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=2, fontsize=7, frameon=False)


def _draw_walk_cloud(ax, walk: RandomWalk) -> None:
    """The whole cloud: a sample of every frame's templates, the estimate's, the initial one, the truth."""
    frames = _walk_frames(walk)
    greens = _frame_greens(frames)
    mb = walk.kinds == "background"
    if mb.any():
        ax.scatter(*walk.coords[mb].T, s=10, color=_rgb(BLUE), alpha=0.6, edgecolors="none", label="background")
    for f in frames:
        mk = ((walk.kinds == "template") | (walk.kinds == "near")) & (walk.frames == f)
        if mk.any():
            ax.scatter(*walk.coords[mk].T, s=9, color=_rgb(greens[f]), edgecolors="none", label=f"templates @{f}")
        me = (walk.kinds == "estimate") & (walk.frames == f)
        if me.any():
            ax.scatter(*walk.coords[me].T, s=40, color=_rgb(greens[f]), marker="D", edgecolors="black",
                       linewidths=0.5)
        mt = (walk.kinds == "target") & (walk.frames == f)
        if mt.any():
            ax.scatter(*walk.coords[mt].T, s=70, color=_rgb(RED), marker="*", edgecolors="none")
            ax.annotate(str(f), walk.coords[mt][0], color=_rgb(RED), fontsize=7, xytext=(5, 4),
                        textcoords="offset points")
    m = walk.kinds == "initial"
    if m.any():
        ax.scatter(*walk.coords[m].T, s=70, color="white", marker="o", edgecolors="black", label="initial template")
    ax.scatter([], [], s=40, color="0.7", marker="D", edgecolors="black", label="estimate's template")
    ax.scatter([], [], s=70, color=_rgb(RED), marker="*", label="truth (frame)")
    _axes_labels(ax)
    _zoom_to_walk(ax, walk, _rgb(BLUE), walk.kinds != "background")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3, fontsize=7, frameon=False)


#: Width over height of the zoomed random-walk axes (about the free area of each panel).
WALK_BOX_ASPECT = 1.0


def _focus_box(coords: np.ndarray, mask: np.ndarray, aspect: float = WALK_BOX_ASPECT) -> tuple:
    """``(lo, hi)`` corners of a box of width/height ``aspect`` around ``coords[mask]``, 15% padded."""
    focus = coords[mask]
    lo, hi = focus.min(axis=0), focus.max(axis=0)
    pad = 0.15 * max(float((hi - lo).max()), 1e-6)
    lo, hi = lo - pad, hi + pad
    # equal axis units: grow the narrower side about its centre
    width = max(float(hi[0] - lo[0]), aspect * float(hi[1] - lo[1]))
    size = np.array([width, width / aspect])
    centre = (lo + hi) / 2
    return centre - size / 2, centre + size / 2


def _zoom_to_walk(ax, walk: RandomWalk, background_colour, focus_mask: np.ndarray) -> None:
    """Frame the points of ``focus_mask``; background descriptors far outside go to an inset.

    Background regions sit several distance units from the target while a template cloud spans a
    fraction of one, so framing everything shrinks each cloud to a dot. The axes frame what the
    panel is about; when some background lies beyond that view, an inset (top right, outside the
    zoomed data's corner) shows the full extent with the zoomed region outlined.
    """
    import matplotlib.patches as mpatches

    mb = walk.kinds == "background"
    if not focus_mask.any():
        return
    focus = walk.coords[focus_mask]
    lo, hi = _focus_box(walk.coords, focus_mask)
    # a strip on the right for the inset, so it covers no data
    hi = hi + np.array([0.45 * (hi - lo)[0], 0.0])
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal", adjustable="box")
    outside = ~((walk.coords[mb] >= lo) & (walk.coords[mb] <= hi)).all(axis=1)
    if not outside.any():
        return
    inset = ax.inset_axes((0.71, 0.60, 0.28, 0.33))
    inset.scatter(*walk.coords[mb].T, s=3, color=background_colour, edgecolors="none")
    inset.scatter(*focus.T, s=3, color="0.85", edgecolors="none")
    inset.add_patch(mpatches.Rectangle(lo, *(hi - lo), fill=False, edgecolor="white", linewidth=0.8))
    inset.set_xticks([])
    inset.set_yticks([])
    inset.set_aspect("equal", adjustable="datalim")
    inset.set_title(f"full extent: {int(outside.sum())} background outside", fontsize=6, pad=2)
