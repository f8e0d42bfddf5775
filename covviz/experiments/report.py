"""``covviz report``: the markdown report and figures of a bench, from its result files only.

Reads ``DIR/bench_manifest.json`` (if present) and every ``DIR/<sequence>/*.json``
written by :func:`covviz.experiments.results.save_result`; never runs a tracker. Writes

* ``report.md``: an overall table and one table per sequence (success AUC,
  P@20, r_on_track, rms_on_track, fps, failed frames; mean ± std over seeds),
  a success-AUC matrix, and the thresholds used; the losses by diagnosed cause and, for
  a bench run with ``--counterfactual``, what fixing each kind of failure would gain
  (:mod:`covviz.experiments.report_counterfactual`: the only part that reads the
  sequences, for their ground truth);
* ``img/bench_success.png``, ``img/bench_precision.png``: the OTB success and
  precision plots (curves averaged over sequences);
* ``img/bench_on_track.png``: the paper's figure, bar charts of the track
  duration rate (``r_on_track``) and the track accuracy (``rms_on_track``) per
  sequence, ours (:data:`OURS`) against IPCA (:data:`BASELINE`), its legend
  beside the bars;
* every figure also as SVG and PDF beside the PNG (:data:`FIGURE_FORMATS`), for a paper;
* with ``latex=True`` (``covviz report --latex``), ``report.tex`` beside the
  markdown: the same tables in LaTeX (booktabs).

Figures go to ``img/`` next to the markdown file and are linked relatively, so
``covviz report runs/bench --out docs/results.md`` writes ``docs/img/…``.

Aggregation
    Per sequence: mean ± sample std (``ddof = STD_DDOF``) of each metric over
    the seeds. Overall: for each seed, the mean of the metric over sequences
    (fps: the median over sequences), then mean ± std of those over seeds.
    Deterministic trackers have one run: no ± part.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from covviz.experiments.report_counterfactual import (
    TrackerReplays,
    fix_aucs,
    losses_of,
    render_section,
    saved_boxes,
    success_auc,
    summarize_replays,
)
from covviz.experiments.results import READABLE_FORMATS, ResultError, load_result, read_manifest
from covviz.metrics import IOU_THRESHOLDS, ON_TRACK_GAMMA, PRECISION_AT, PRECISION_THRESHOLDS

__all__ = ["BASELINE", "OURS", "REPORT_NAME", "Run", "Summary", "load_runs", "render", "summarize", "write_report"]

log = logging.getLogger("covviz.experiments.report")

#: Default name of the report inside a results folder.
REPORT_NAME = "report.md"
#: Folder of the figures, next to the markdown file.
IMG_DIR = "img"
#: Prefix of the figure files (docs/img/ may hold other pictures).
FIGURE_PREFIX = "bench_"
#: The paper's tracker and the baseline of its figure.
OURS = "manifold"
BASELINE = "ipca"
#: Degrees of freedom of the standard deviation over seeds (1: sample std).
STD_DDOF = 1
#: Resolution of the PNG figures.
DPI = 110
#: Every figure is written in each of these formats (the markdown links the first).
FIGURE_FORMATS = ("png", "svg", "pdf")

#: (metric key in the result JSON, column title, higher is better)
COLUMNS = (
    ("success_auc", "success AUC ↑", True),
    ("precision_20", "P@20 ↑", True),
    ("r_on_track", "r_on_track ↑", True),
    ("rms_on_track", "rms_on_track ↓", False),
)


@dataclass(frozen=True)
class Run:
    """One result file, as the report needs it."""

    sequence: str
    tracker: str
    seed: int | None
    n_frames: int
    metrics: dict
    fps: float
    n_failed: int
    jobs: int | None  # worker processes of the bench that made it, and threads per worker
    threads: int | None
    success: np.ndarray | None  # OTB success curve over the IoU thresholds
    precision: np.ndarray | None  # OTB precision curve over the pixel thresholds
    causes: tuple = ()  # the diagnosed cause of each loss (covviz.diagnosis.drift)
    losses: tuple = ()  # (drift began, lost at) of each loss, 1-based frames
    suspects: tuple = ()  # frames of the label-free suspects
    loss_replays: tuple = ()  # each loss with its counterfactual replays (report_counterfactual.LossReplay)
    auc: float = float("nan")  # success AUC from the saved boxes (nan: not computed, or no ground truth)
    fixed_auc: dict = field(default_factory=dict)  # fix -> AUC with the losses' windows replayed under it


def _diagnosis_fields(found: dict | None) -> dict:
    """The causes, losses and suspects of a result's drift diagnosis (none for results without one)."""
    if not found:
        return {}
    events = found.get("events", [])
    drifts = [e["frame"] for e in events if e.get("kind") == "drift"]
    lost = [e["frame"] for e in events if e.get("kind") == "lost"]
    return {
        "causes": tuple(d.get("cause", "unknown") for d in found.get("diagnoses", [])),
        "losses": tuple(zip(drifts, lost)),
        "suspects": tuple(int(sp["frame"]) for sp in found.get("suspects", [])),
    }


def _relative_root(root, md_path: Path) -> str:
    """The manifest's root as the report names it: relative to the report's folder, never absolute."""
    if not root:
        return "?"
    try:
        return Path(os.path.relpath(Path(root).resolve(), md_path.parent.resolve())).as_posix()
    except ValueError:  # another drive (Windows): the folder's name is all that can be said
        return Path(root).name


def _f(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def is_own_result(js: Path) -> bool:
    """Whether ``js`` is a covviz result, whole or half-written: its text starts with our format tag.

    :func:`covviz.experiments.results.save_result` writes ``"format"`` first, so
    a result cut short still shows it; any other JSON in the folder is not ours
    to judge (nor to ask the user to delete).
    """
    try:
        with open(js, "rb") as fh:
            head = fh.read(256)
    except OSError:
        return False
    return any(f'"format": "{tag}"'.encode() in head for tag in READABLE_FORMATS)


def load_runs(results_dir: str | Path) -> tuple[dict | None, list[Run], dict]:
    """Read the manifest and every result of a bench folder.

    Returns
    -------
    manifest : dict or None
    runs : list of Run
    thresholds : dict
        ``iou``, ``precision`` (arrays), ``precision_at``, ``on_track_gamma``,
        as stored in the results (the metric module's constants for results
        written without them).

    Raises
    ------
    ResultError
        If the folder does not exist or holds no result.
    covviz.experiments.results.ResultError
        If a result file is corrupt (the message names it).
    """
    d = Path(results_dir)
    if not d.is_dir():
        raise ResultError(f"{d}: no such results folder")
    manifest = read_manifest(d)
    if manifest is not None:
        seq_names = list(manifest.get("sequences", {}))
        trackers = set(manifest.get("trackers", []))
        files = [js for s in seq_names for js in sorted((d / s).glob("*.json"))]
    else:
        trackers = None
        files = sorted(d.glob("*/*.json"))
    thr = {
        "iou": np.asarray(IOU_THRESHOLDS, dtype=float),
        "precision": np.asarray(PRECISION_THRESHOLDS, dtype=float),
        "precision_at": float(PRECISION_AT),
        "on_track_gamma": float(ON_TRACK_GAMMA),
    }
    seen_thr = False
    runs: list[Run] = []
    foreign = [js for js in files if not is_own_result(js)]
    if foreign:
        log.warning("%s: skipped %d JSON file(s) that are not covviz results (%s%s)", d, len(foreign),
                    foreign[0], " …" if len(foreign) > 1 else "")
    boxes_of: list[tuple] = []  # per run: its boxes (0-based) and the sequence's path
    for js in files:
        if js in foreign:
            continue
        doc, boxes = load_result(js)
        if trackers is not None and doc.get("tracker") not in trackers:
            continue
        if doc.get("interrupted"):
            log.warning("%s: an interrupted run; left out of the report", js)
            continue
        curves = doc.get("curves") or {}
        succ = np.asarray(curves["success"], dtype=float) if "success" in curves else None
        prec = np.asarray(curves["precision"], dtype=float) if "precision" in curves else None
        if curves.get("iou_thresholds") is not None:
            t_iou = np.asarray(curves["iou_thresholds"], dtype=float)
            t_prec = np.asarray(curves["precision_thresholds"], dtype=float)
            if not seen_thr:
                thr["iou"], thr["precision"], seen_thr = t_iou, t_prec, True
            elif (
                t_iou.shape != thr["iou"].shape
                or t_prec.shape != thr["precision"].shape
                or not (np.allclose(t_iou, thr["iou"]) and np.allclose(t_prec, thr["precision"]))
            ):
                raise ResultError(f"{js}: computed with other thresholds than the other results; re-run it")
        t = doc.get("thresholds") or {}
        thr["precision_at"] = float(t.get("precision_at", thr["precision_at"]))
        thr["on_track_gamma"] = float(t.get("on_track_gamma", thr["on_track_gamma"]))
        runs.append(
            Run(
                sequence=str(doc.get("sequence", js.parent.name)),
                tracker=str(doc.get("tracker")),
                seed=doc.get("seed"),
                n_frames=int(doc.get("n_frames", 0)),
                metrics=doc.get("metrics") or {},
                fps=_f(doc.get("fps")),
                n_failed=len(doc.get("failed_frames") or []),
                jobs=(doc.get("bench") or {}).get("jobs"),
                threads=(doc.get("bench") or {}).get("threads"),
                success=succ,
                precision=prec,
                **_diagnosis_fields(doc.get("diagnosis")),
                loss_replays=losses_of(doc.get("diagnosis"), len(boxes), js),
            )
        )
        boxes_of.append((boxes, (doc.get("bench") or {}).get("path")))
    if not runs:
        raise ResultError(
            f"{d}: no results to report (expected <sequence>/<tracker>.json files from covviz bench)"
        )
    return manifest, _with_fix_aucs(runs, boxes_of, manifest), thr


def _with_fix_aucs(runs: list[Run], boxes_of: list, manifest: dict | None) -> list[Run]:
    """The runs of every tracker with replays, with their own AUC and the AUC under each fix
    (:mod:`covviz.experiments.report_counterfactual`); needs the sequences' ground truth."""
    replayed = {r.tracker for r in runs if any(lr.replayed for lr in r.loss_replays)}
    if not replayed:
        return runs
    from covviz.data.sequences import SequenceError, open_sequence

    cache: dict = {}
    warned: set = set()

    def truth(sequence: str, path: str | None, n: int) -> np.ndarray | None:
        cands = [p for p in (path, str(Path(manifest["root"]) / sequence) if (manifest or {}).get("root") else None)
                 if p]
        for p in cands:
            if p not in cache:
                try:
                    cache[p] = np.asarray(open_sequence(p).groundtruth, dtype=np.float64)
                except (SequenceError, OSError):
                    cache[p] = None
            if cache[p] is not None:
                gt = np.full((n, 4), np.nan)
                m = min(n, len(cache[p]))
                gt[:m] = cache[p][:m]
                return gt
        if sequence not in warned:
            warned.add(sequence)
            log.warning("%s: ground truth not found (%s); its runs are left out of the replays' AUC table",
                        sequence, ", ".join(cands) or "no path in the results")
        return None

    out = []
    for r, (boxes, path) in zip(runs, boxes_of):
        gt = truth(r.sequence, path, len(boxes)) if r.tracker in replayed else None
        if gt is not None:
            b = saved_boxes(boxes)
            r = replace(r, auc=success_auc(b, gt), fixed_auc=fix_aucs(b, gt, r.loss_replays))
        out.append(r)
    return out


# --------------------------------------------------------------------------- #
# statistics and formatting
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class Stat:
    """Mean and std over runs of one number; ``partial`` if some runs had no value."""

    mean: float
    std: float
    n: int
    partial: bool

    @classmethod
    def of(cls, values) -> Stat:
        v = np.asarray([_f(x) for x in values], dtype=float)
        ok = v[np.isfinite(v)]
        if not len(ok):
            return cls(float("nan"), float("nan"), 0, len(v) > 0)
        std = float(np.std(ok, ddof=STD_DDOF)) if len(ok) > STD_DDOF else float("nan")
        return cls(float(ok.mean()), std, len(ok), len(ok) < len(v))

    def fmt(self, digits: int = 3) -> str:
        if not np.isfinite(self.mean):
            return "—"
        s = f"{self.mean:.{digits}f}"
        if self.n > 1 and np.isfinite(self.std):
            s += f" ± {self.std:.{digits}f}"
        return s + ("†" if self.partial else "")


def _jobs_note(runs: list[Run]) -> str:
    """How the runs shared the machine (fps depend on it)."""
    settings = sorted({(r.jobs, r.threads) for r in runs if r.jobs is not None}, key=str)
    if not settings:
        return "settings unknown"
    if len(settings) > 1:
        return "with different --jobs settings (compare fps with care)"
    jobs, threads = settings[0]
    return f"{jobs} at a time" + (
        f" with {threads} OpenCV/BLAS thread{'s' * (threads != 1)} each" if threads else ""
    )


def _fps_digits(v: float) -> int:
    return 0 if (np.isfinite(v) and v >= 100) else 1


def _order(names, preferred) -> list[str]:
    names = set(names)
    return [t for t in preferred if t in names] + sorted(names - set(preferred))


def _table_head(rows) -> tuple[list[str], dict[str, float]]:
    """The overall table's column titles, and the best mean of each metric column (to set in bold)."""
    head = ["tracker", "runs"] + [title for _, title, _ in COLUMNS] + ["fps", "failed frames"]
    best = {}
    for key, _, higher in COLUMNS:
        means = [r[2][key].mean for r in rows if np.isfinite(r[2][key].mean)]
        if len(rows) > 1 and means:
            best[key] = max(means) if higher else min(means)
    return head, best


def _table(rows: list[tuple[str, str, dict[str, Stat], Stat, Stat]]) -> list[str]:
    """Markdown table; the best mean of each metric column is bold."""
    head, best = _table_head(rows)
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] * 2 + ["---:"] * (len(head) - 2)) + "|"]
    for name, runs, stats, fps, failed in rows:
        cells = [f"`{name}`", runs]
        for key, _, _ in COLUMNS:
            c = stats[key].fmt()
            if (
                key in best
                and np.isfinite(stats[key].mean)
                and round(stats[key].mean, 3) == round(best[key], 3)
            ):
                c = f"**{c}**"
            cells.append(c)
        cells.append(fps.fmt(_fps_digits(fps.mean)))
        cells.append(failed.fmt(0) if np.isfinite(failed.mean) else "—")
        lines.append("| " + " | ".join(cells) + " |")
    return lines


# --------------------------------------------------------------------------- #
# the report: aggregation (pure), rendering, writing
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class Summary:
    """What a report says, aggregated from a results folder (no formatting, no files written).

    Attributes
    ----------
    results_dir : Path
    manifest : dict or None
    runs : list of Run
    thresholds : dict
        As :func:`load_runs` returns them.
    trackers : list of str
        In the manifest's order, then the others by name.
    sequences : list of str
    seq_frames : dict
        Frames per sequence.
    stochastic : set of str
        Trackers run with seeds.
    n_seeds : int
        Seeds in the manifest (0 without one).
    by : dict
        ``(sequence, tracker) -> [Run]``, sorted by seed.
    per_sequence : dict
        ``sequence -> rows`` of :func:`_table`.
    overall : list
        Rows of :func:`_table` over all sequences.
    incomplete : list of str
        Trackers that miss some runs.
    causes : dict
        ``tracker -> {cause: losses}`` over every sequence and seed.
    causes_by_sequence : dict
        ``(sequence, tracker) -> {cause: losses}`` over seeds.
    suspects : dict
        ``tracker -> covviz.diagnosis.drift.score_suspects`` totals over every run.
    replays : dict
        ``tracker -> report_counterfactual.TrackerReplays``: the counterfactual replays of its losses.
    """

    results_dir: Path
    manifest: dict | None
    runs: list
    thresholds: dict
    trackers: list
    sequences: list
    seq_frames: dict
    stochastic: set
    n_seeds: int
    by: dict
    per_sequence: dict
    overall: list
    incomplete: list
    causes: dict = field(default_factory=dict)
    causes_by_sequence: dict = field(default_factory=dict)
    suspects: dict = field(default_factory=dict)
    replays: dict[str, TrackerReplays] = field(default_factory=dict)


def frames_tracked(summary: Summary, sequence: str) -> str:
    """``"80 of 140 frames tracked"`` (a bench with ``--max-frames``), or ``"140 frames tracked"``.

    The sequence's length comes from the manifest; the frames tracked from the runs themselves (the most
    any run of that sequence tracked), so a header never claims frames that no tracker saw.
    """
    total = summary.seq_frames.get(sequence)
    done = [r.n_frames for r in summary.runs if r.sequence == sequence and r.n_frames]
    if not done:
        return f"{total if total is not None else '?'} frames, none tracked yet"
    n = max(done)
    return f"{n} of {total} frames tracked" if total is not None and n < total else f"{n} frames tracked"


def summarize(results_dir: str | Path) -> Summary:
    """Aggregate the results of a bench folder: per sequence (over seeds) and overall (per seed, then over seeds)."""
    d = Path(results_dir)
    manifest, runs, thr = load_runs(d)
    preferred = list((manifest or {}).get("trackers", []))
    trackers = _order({r.tracker for r in runs}, preferred)
    if manifest is not None:
        seq_frames = {k: int(v) for k, v in manifest.get("sequences", {}).items()}
    else:
        seq_frames = {}
        for r in runs:
            seq_frames.setdefault(r.sequence, r.n_frames)
    sequences = sorted({r.sequence for r in runs} | set(seq_frames), key=str.lower)
    by = {}
    for r in runs:
        by.setdefault((r.sequence, r.tracker), []).append(r)
    for v in by.values():
        v.sort(key=lambda r: -1 if r.seed is None else r.seed)
    stochastic = {t for t in trackers if any(r.seed is not None for r in runs if r.tracker == t)}
    n_seeds_manifest = int((manifest or {}).get("seeds", 0))

    def expected(t: str) -> int:
        if t not in stochastic:
            return 1
        seeds = {r.seed for r in runs if r.tracker == t}
        return max(n_seeds_manifest, len(seeds))

    # ---- per sequence ------------------------------------------------------
    per_seq: dict[str, list] = {}
    for s in sequences:
        rows = []
        for t in trackers:
            rs = by.get((s, t), [])
            if not rs:
                continue
            stats = {k: Stat.of(r.metrics.get(k) for r in rs) for k, _, _ in COLUMNS}
            rows.append(
                (
                    t,
                    f"{len(rs)}/{expected(t)}",
                    stats,
                    Stat.of(r.fps for r in rs),
                    Stat.of(r.n_failed for r in rs),
                )
            )
        per_seq[s] = rows

    # ---- overall: per seed, mean over sequences; then over seeds -----------
    overall_rows, incomplete = [], []
    for t in trackers:
        rs = [r for r in runs if r.tracker == t]
        seeds = sorted({r.seed for r in rs}, key=lambda x: -1 if x is None else x)
        per_seed = {k: [] for k, _, _ in COLUMNS}
        partial = set()  # metrics undefined on some sequence: the mean is over the others
        fps, failed = [], []
        for sd in seeds:
            rr = [r for r in rs if r.seed == sd]
            for k, _, _ in COLUMNS:
                vals = np.array([_f(r.metrics.get(k)) for r in rr])
                if not np.isfinite(vals).all():
                    partial.add(k)
                per_seed[k].append(float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan"))
            f = np.array([r.fps for r in rr])
            fps.append(float(np.nanmedian(f)) if np.isfinite(f).any() else float("nan"))
            failed.append(sum(r.n_failed for r in rr))
        n_exp = len(sequences) * expected(t)
        if len(rs) < n_exp:
            incomplete.append(t)
        overall_rows.append(
            (
                t,
                f"{len(rs)}/{n_exp}",
                {
                    k: replace(Stat.of(v), partial=True) if k in partial else Stat.of(v)
                    for k, v in per_seed.items()
                },
                Stat.of(fps),
                Stat.of(failed),
            )
        )

    # ---- failures: causes of the losses, and the label-free suspects against them ----------
    from covviz.diagnosis.drift import score_suspects

    causes: dict = {}
    by_seq: dict = {}
    suspects: dict = {}
    for r in runs:
        for c in r.causes:
            causes.setdefault(r.tracker, {}).setdefault(c, 0)
            causes[r.tracker][c] += 1
            by_seq.setdefault((r.sequence, r.tracker), {}).setdefault(c, 0)
            by_seq[(r.sequence, r.tracker)][c] += 1
        sc = score_suspects([{"frame": f} for f in r.suspects], list(r.losses))
        tot = suspects.setdefault(r.tracker, dict.fromkeys(sc, 0))
        for k, v in sc.items():
            tot[k] += v
    return Summary(
        results_dir=d,
        manifest=manifest,
        runs=runs,
        thresholds=thr,
        trackers=trackers,
        sequences=sequences,
        seq_frames=seq_frames,
        stochastic=stochastic,
        n_seeds=n_seeds_manifest,
        by=by,
        per_sequence=per_seq,
        overall=overall_rows,
        incomplete=incomplete,
        causes=causes,
        causes_by_sequence=by_seq,
        suspects=suspects,
        replays=summarize_replays(runs, trackers),
    )


def _failure_section(summary: Summary) -> list[str]:
    """Losses by diagnosed cause (overall and per sequence) and how far the label-free suspects can be trusted."""
    from covviz.diagnosis.drift import CAUSES, DiagnosisConfig

    match_before, match_after = DiagnosisConfig().match_before, DiagnosisConfig().match_after

    if not summary.suspects:
        return []
    trackers = [t for t in summary.trackers if t in summary.suspects]
    cols = [c for c in (*CAUSES, "unknown") if any(c in summary.causes.get(t, {}) for t in trackers)]
    L = [
        "## Failures and their causes",
        "",
        (
            "Every loss of track (IoU below 0.1) was diagnosed from the frames between the start of its drift and "
            "the loss (`covviz.diagnosis.drift`; the rules and their thresholds are in the results' `diagnosis_config`). "
            "Counts over all sequences and seeds; *unknown*: no rule of the vocabulary held."
        ),
        "",
    ]
    if cols:
        L += ["| tracker | losses | " + " | ".join(c.replace("_", " ") for c in cols) + " |",
              "|---|---:|" + "---:|" * len(cols)]
        for t in trackers:
            c = summary.causes.get(t, {})
            L.append(f"| `{t}` | {sum(c.values())} | " + " | ".join(str(c.get(k, 0) or "·") for k in cols) + " |")
        L += ["", "Per sequence (losses by cause, all seeds):", "",
              "| sequence | " + " | ".join(f"`{t}`" for t in trackers) + " |", "|---|" + "---|" * len(trackers)]
        for seq in summary.sequences:
            cells = []
            for t in trackers:
                c = summary.causes_by_sequence.get((seq, t), {})
                cells.append(", ".join(f"{k.replace('_', ' ')} {v}" for k, v in sorted(c.items())) or "—")
            L.append(f"| {seq} | " + " | ".join(cells) + " |")
    else:
        L.append("No tracker lost its target.")
    L += [
        "",
        "### Suspects without ground truth: how far to trust them",
        "",
        (
            "A user's own video has no ground truth; the diagnosis then raises *suspects* from the filter's own "
            "numbers (weights collapsing, the best distance leaving its running range, a second mode of the weights, "
            f"the scale running away). Scored here against the losses: a suspect is right when it falls between "
            f"{match_before} frames before a drift began and {match_after} frames after the loss (precision), and a "
            "loss is found when at least one suspect falls in that window (recall)."
        ),
        "",
        "| tracker | suspects | precision | losses | recall |",
        "|---|---:|---:|---:|---:|",
    ]
    for t in trackers:
        sc = summary.suspects[t]
        prec = sc["true_positives"] / sc["suspects"] if sc["suspects"] else float("nan")
        rec = sc["losses_found"] / sc["losses"] if sc["losses"] else float("nan")
        L.append(f"| `{t}` | {sc['suspects']} | {_fmt_pct(prec)} | {sc['losses']} | {_fmt_pct(rec)} |")
    return [*L, ""]


#: A place where losses recur: at least this share of a tracker's seeds (and two) lose the target there.
RECUR_SHARE = 1 / 3
#: ... within this many frames (:func:`covviz.experiments.losses.recurring`).
RECUR_WINDOW = 10


def recurring_losses(summary: Summary) -> dict[str, list[tuple]]:
    """Per stochastic tracker run with three seeds or more: ``[(sequence, first, last, seeds, n_seeds, verdicts,
    causes), ...]``, the places where its seeds' losses recur (:func:`covviz.experiments.losses.recurring`),
    with the counts of the verdicts (replayed losses) and of the diagnosed causes of the losses there."""
    from collections import Counter

    from covviz.experiments.losses import recurring

    out: dict[str, list[tuple]] = {}
    for t in summary.trackers:
        rs = [r for r in summary.runs if r.tracker == t and r.seed is not None]
        n_seeds = len({r.seed for r in rs})
        if t not in summary.stochastic or n_seeds < 3:
            continue
        rows = []
        for seq in summary.sequences:
            runs = [r for r in rs if r.sequence == seq]
            per_seed = {r.seed: [lost for _, lost in r.losses] for r in runs}
            for first, last, k in recurring(per_seed, RECUR_WINDOW, RECUR_SHARE):
                verdicts, causes = Counter(), Counter()
                for r in runs:
                    verdicts.update(x.verdict for x in r.loss_replays if x.verdict and first <= x.lost_at <= last)
                    causes.update(c for (_, lost), c in zip(r.losses, r.causes) if first <= lost <= last)
                rows.append((seq, first, last, k, len(runs), dict(verdicts), dict(causes)))
        out[t] = rows
    return out


def _recurring_section(summary: Summary) -> list[str]:
    """Where the losses of the stochastic trackers recur over the seeds (the scene's losses, not chance's)."""
    places = recurring_losses(summary)
    if not places:
        return []
    L = [
        "### Where the losses recur over the seeds",
        "",
        (
            "A stochastic tracker's losses at the same frames on most seeds are the scene's, not the random "
            f"stream's, and the first to look at: the places (at most {RECUR_WINDOW} frames) where at least "
            f"{RECUR_SHARE:.0%} of the seeds, and two, "
            "lose the target, each seed counted once (`covviz.experiments.losses.recurring`), with the verdicts "
            "of the replayed losses there and their diagnosed causes. *share*: of all the tracker's losses, "
            "those in a place."
        ),
        "",
        "| tracker | sequence | lost at | seeds | verdicts | causes |",
        "|---|---|---|---:|---|---|",
    ]
    fmt = lambda c: ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in sorted(c.items(), key=lambda kv: -kv[1])) or "—"
    shares = []
    for t, rows in places.items():
        for seq, first, last, k, n, verdicts, causes in rows:
            span = f"{first}" if first == last else f"{first}–{last}"
            L.append(f"| `{t}` | {seq} | {span} | {k}/{n} | {fmt(verdicts)} | {fmt(causes)} |")
        if not rows:
            L.append(f"| `{t}` | — | | | | |")
        spans = {}
        for seq, first, last, *_ in rows:
            spans.setdefault(seq, []).append((first, last))
        lost = [(r.sequence, f) for r in summary.runs if r.tracker == t for _, f in r.losses]
        inside = sum(any(a <= f <= b for a, b in spans.get(seq, ())) for seq, f in lost)
        shares.append(f"`{t}` {inside} of {len(lost)}")
    return [*L, "", "*share*: " + "; ".join(shares) + ".", ""]


def _fmt_pct(v: float) -> str:
    return "—" if not np.isfinite(v) else f"{100 * v:.0f}%"


def render(summary: Summary, md_path: str | Path, figs: dict[str, Path]) -> str:
    """The markdown of a report written to ``md_path``: every path in it relative to that file.

    No absolute path of the machine that made it appears: the results folder and the
    sequences' root are given relative to the report (as the figures are).
    """
    md_path = Path(md_path)
    d, manifest, runs, thr = summary.results_dir, summary.manifest, summary.runs, summary.thresholds
    trackers, sequences, seq_frames = summary.trackers, summary.sequences, summary.seq_frames
    stochastic, n_seeds_manifest, by = summary.stochastic, summary.n_seeds, summary.by
    per_seq, overall_rows, incomplete = summary.per_sequence, summary.overall, summary.incomplete
    rel = lambda p: Path(os.path.relpath(p, md_path.parent)).as_posix()
    L: list[str] = ["# covviz benchmark", ""]
    n_files = len(runs)
    # Where the results are, relative to the markdown (the report may move with its folder).
    where = rel(d)
    where = "this folder" if where == "." else f"`{where}` (relative to this file)"
    if manifest is not None:
        L += [
            f"Results in {where}: {n_files} runs of {len(trackers)} trackers "
            f"on {len(sequences)} sequences from "
            f"`{_relative_root(manifest.get('root'), md_path)}`"
            + (f", first {manifest['max_frames']} frames of each" if manifest.get("max_frames") else "")
            + ".",
            (
                f"Stochastic trackers ({', '.join(f'`{t}`' for t in sorted(stochastic))}) ran with "
                f"{n_seeds_manifest} seeds (seed *s* replays with "
                "`covviz track SEQ --tracker NAME --seed s`); "
                "the others once"
                if stochastic
                else "All trackers are deterministic and ran once"
            )
            + (f"; {manifest['particles']} particles" if manifest.get("particles") else "")
            + f". Each run in a fresh process, {_jobs_note(runs)}. covviz {manifest.get('covviz')}.",
        ]
    else:
        L += [
            (
                f"Results in {where}: {n_files} runs of {len(trackers)} trackers "
                f"on {len(sequences)} sequences "
                "(no bench manifest)."
            )
        ]
    L += [
        "",
        (
            "Rebuilt from the result files by `covviz report`; nothing is re-run. ± is the standard "
            f"deviation over seeds (ddof={STD_DDOF}); † marks a mean over the runs (overall: the sequences) "
            "where the metric is defined (rms_on_track is undefined when no frame is on track). "
            "**Bold**: best of the table. *runs*: results found / expected. *failed frames*: frames on which "
            "an OpenCV tracker reported a failure (it then keeps its last box); overall, their total."
        ),
        "",
        "## Overall",
        "",
        (
            f"Each metric is averaged over the {len(sequences)} sequences "
            "(each sequence weighs the same), per seed; "
            "fps is the median over sequences of `update` calls per second (frame reading excluded)."
        ),
        "",
        *_table(overall_rows),
        "",
    ]
    if incomplete:
        L += [
            (
                f"Incomplete: {', '.join(f'`{t}`' for t in incomplete)} miss some runs; "
                "their overall row averages "
                "over the sequences they have. Run the bench again to complete them."
            ),
            "",
        ]
    if figs.get("success"):
        L += [
            f"![OTB success plot]({rel(figs['success'])}) ![OTB precision plot]({rel(figs['precision'])})",
            "",
        ]
    L += ["## The paper's figure: track duration rate and accuracy, ours against IPCA", ""]
    if figs.get("on_track"):
        missing = [t for t in (OURS, BASELINE) if t not in trackers]
        L += [
            f"`{OURS}` (ours) against `{BASELINE}` (IVT) per sequence: the track duration rate "
            "r_on_track (higher is better) and the track accuracy rms_on_track (lower is better), "
            "mean over seeds with ±1 std bars."
            + (f" No `{'`, `'.join(missing)}` results yet." if missing else ""),
            "",
            f"![track duration rate and accuracy]({rel(figs['on_track'])})",
            "",
            "Every figure is also beside its PNG as SVG and PDF (same name), for a paper.",
            "",
        ]
    else:
        L += [f"Needs `{OURS}` or `{BASELINE}` results; this bench has neither.", ""]

    L += _failure_section(summary)
    L += _recurring_section(summary)
    L += render_section(summary.replays, summary.trackers)
    L += ["## Success AUC per sequence", ""]
    L += [
        "| sequence | frames | " + " | ".join(f"`{t}`" for t in trackers) + " |",
        "|---|---:|" + "---:|" * len(trackers),
    ]
    for s in sequences:
        cells = []
        for t in trackers:
            rs = by.get((s, t), [])
            cells.append(Stat.of(r.metrics.get("success_auc") for r in rs).fmt() if rs else "—")
        L.append(f"| {s} | {seq_frames.get(s, '?')} | " + " | ".join(cells) + " |")
    L += ["", "## Per sequence", ""]
    for s in sequences:
        L += [f"### {s} ({frames_tracked(summary, s)})", ""]
        L += _table(per_seq[s]) if per_seq[s] else ["No results yet."]
        L.append("")

    iou_t, prec_t = thr["iou"], thr["precision"]
    L += [
        "## Definitions and thresholds",
        "",
        "Named constants (of `covviz.metrics` and `covviz.experiments.report`), as used for these results:",
        "",
        (
            f"- `IOU_THRESHOLDS` = {len(iou_t)} values {iou_t[0]:g}, {iou_t[1]:g}, …, {iou_t[-1]:g}. "
            "**Success AUC**: the mean over these thresholds of the fraction of frames with IoU > threshold "
            "(OTB's success plot, Wu et al. 2013)."
        ),
        (
            f"- `PRECISION_THRESHOLDS` = {prec_t[0]:g} … {prec_t[-1]:g} px; "
            f"`PRECISION_AT` = {thr['precision_at']:g} px. **P@{thr['precision_at']:g}**: the fraction of "
            f"frames whose centre error is ≤ {thr['precision_at']:g} px."
        ),
        (
            f"- `ON_TRACK_GAMMA` = {thr['on_track_gamma']:g}. A frame is on track when "
            "γ = ½(|e_x|/W_gt + |e_y|/H_gt) ≤ `ON_TRACK_GAMMA`. **r_on_track**: on-track frames / "
            "frames with ground truth (the track duration rate); **rms_on_track**: √(mean over on-track "
            "frames of "
            "½((e_x/W_gt)² + (e_y/H_gt)²)) (the track accuracy)."
        ),
        (
            f"- `OURS` = `{OURS}`, `BASELINE` = `{BASELINE}` (the bars of the paper's figure); "
            f"`STD_DDOF` = {STD_DDOF}."
        ),
        (
            "- Frames without ground truth are skipped; frame 0 (the given box) counts, as in OTB's "
            "one-pass evaluation."
        ),
        "",
    ]
    return "\n".join(L).rstrip("\n") + "\n"


def write_report(results_dir: str | Path, out: str | Path | None = None, append=(), latex: bool = False) -> Path:
    """Write the report of the bench in ``results_dir``; return the markdown path.

    Parameters
    ----------
    results_dir : path
        A folder written by ``covviz bench``.
    out : path, optional
        The markdown file (default ``results_dir/report.md``); figures go to
        ``img/`` beside it.
    append : sequence of paths
        Markdown files appended to the report as they are (read before
        anything is written: a missing one is an error and the report is kept).
    latex : bool
        Also write the tables as LaTeX (``report.tex`` beside the markdown; :func:`render_latex`).
    """
    d = Path(results_dir)
    md_path = Path(out) if out is not None else d / REPORT_NAME
    if md_path.suffix.lower() != ".md":
        raise ResultError(f"--out must be a markdown file (.md), got {md_path}")
    extra = []
    for a in append:
        try:
            extra.append(Path(a).read_text().strip())
        except OSError as exc:
            raise ResultError(f"cannot read {a} (--append): {exc.strerror or exc}") from None
    summary = summarize(d)
    img_dir = md_path.parent / IMG_DIR
    try:
        img_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ResultError(f"cannot write to {img_dir}: {exc.strerror or exc}") from None
    figs = _figures(img_dir, summary.sequences, summary.trackers, summary.by, summary.thresholds)
    text = render(summary, md_path, figs)
    if extra:
        text = text.rstrip("\n") + "\n\n" + "\n\n".join(extra) + "\n"
    tmp = md_path.with_name(md_path.name + ".part")
    tmp.write_text(text)
    os.replace(tmp, md_path)
    if latex:
        tex = md_path.with_suffix(".tex")
        tmp = tex.with_name(tex.name + ".part")
        tmp.write_text(render_latex(summary))
        os.replace(tmp, tex)
    return md_path


# --------------------------------------------------------------------------- #
# figures (matplotlib, Agg, imported here only)
# --------------------------------------------------------------------------- #
def _mean_curve(by, sequences, t, attr) -> np.ndarray | None:
    """Mean over sequences of (mean over seeds of) a run curve; None without curves."""
    per_seq = []
    for s in sequences:
        cs = [getattr(r, attr) for r in by.get((s, t), []) if getattr(r, attr) is not None]
        if cs:
            per_seq.append(np.nanmean(np.stack(cs), axis=0))
    if not per_seq:
        return None
    with np.errstate(all="ignore"):
        return np.nanmean(np.stack(per_seq), axis=0)


def _figures(img_dir: Path, sequences, trackers, by, thr) -> dict[str, Path]:
    # The object API with the Agg canvas: no pyplot, no global backend switch, no display.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    def new_figure(**kw) -> Figure:
        fig = Figure(layout="constrained", **kw)
        FigureCanvasAgg(fig)
        return fig

    out: dict[str, Path] = {}
    from covviz.trackers import TRACKERS

    # Colours follow the registry order, so a tracker has the same colour in every report.
    known = list(TRACKERS)
    colours = {
        t: f"C{(known.index(t) if t in known else len(known) + i) % 10}" for i, t in enumerate(trackers)
    }

    # OTB success and precision plots
    curves = {
        t: (_mean_curve(by, sequences, t, "success"), _mean_curve(by, sequences, t, "precision"))
        for t in trackers
    }
    curves = {t: c for t, c in curves.items() if c[0] is not None and c[1] is not None}
    if curves:
        k_at = int(np.argmin(np.abs(thr["precision"] - thr["precision_at"])))
        for kind in ("success", "precision"):
            fig = new_figure(figsize=(5.6, 4.2))
            ax = fig.add_subplot()
            if kind == "success":
                score = {t: float(np.nanmean(c[0])) for t, c in curves.items()}
                x, idx, xlabel = thr["iou"], 0, "overlap threshold (IoU)"
                title, label = "Success plots of OPE", "AUC"
            else:
                score = {t: float(c[1][k_at]) for t, c in curves.items()}
                x, idx, xlabel = thr["precision"], 1, "location error threshold (px)"
                title, label = "Precision plots of OPE", f"P@{thr['precision_at']:g}"
            for t in sorted(curves, key=lambda t: -np.nan_to_num(score[t], nan=-1)):
                ax.plot(x, curves[t][idx], color=colours[t], lw=2, label=f"{t} [{score[t]:.3f}]")
            if kind == "precision":
                ax.axvline(thr["precision_at"], color="0.6", lw=0.8, ls="--")
            ax.set(
                xlabel=xlabel,
                ylabel="success rate" if kind == "success" else "precision",
                title=f"{title} ({len(sequences)} sequences)",
                ylim=(0, 1.0),
                xlim=(x[0], x[-1]),
            )
            ax.grid(alpha=0.3)
            ax.legend(loc="lower left" if kind == "success" else "lower right", fontsize=8, title=label)
            out[kind] = _save_figure(fig, img_dir / f"{FIGURE_PREFIX}{kind}")

    # The paper's figure: r_on_track and rms_on_track per sequence, ours against the baseline
    pair = [t for t in (OURS, BASELINE) if t in trackers]
    if pair:
        fig = new_figure(figsize=(max(6.0, 0.55 * len(sequences) * len(pair) + 2), 6.4))
        axes = fig.subplots(2, 1, sharex=True)
        x = np.arange(len(sequences))
        width = 0.8 / len(pair)
        for ax, (key, title) in zip(
            axes,
            (
                ("r_on_track", "track duration rate r_on_track (higher is better)"),
                ("rms_on_track", "track accuracy rms_on_track (lower is better)"),
            ),
        ):
            for i, t in enumerate(pair):
                st = [Stat.of(r.metrics.get(key) for r in by.get((s, t), [])) for s in sequences]
                m = np.array([s_.mean for s_ in st])
                e = np.array([s_.std if np.isfinite(s_.std) else 0.0 for s_ in st])
                xs = x + (i - (len(pair) - 1) / 2) * width
                ok = np.isfinite(m)
                ax.bar(
                    xs[ok],
                    m[ok],
                    width,
                    yerr=e[ok],
                    capsize=2,
                    color=colours[t],
                    label=f"{t}" + (" (ours)" if t == OURS else ""),
                )
                # No bar is not a zero: say why (no result, or no frame on track for rms).
                for xi in xs[~ok]:
                    ax.text(xi, 0, "n/a", ha="center", va="bottom", fontsize=6, rotation=90, color=colours[t])
            ax.set_title(title, fontsize=10)
            ax.grid(axis="y", alpha=0.3)
        axes[0].set_ylim(0, 1.05)
        axes[1].set_xticks(x, sequences, rotation=45, ha="right", fontsize=8)
        # one legend for both panels, beside them: never over a bar
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=8)
        out["on_track"] = _save_figure(fig, img_dir / f"{FIGURE_PREFIX}on_track")
    return out


def _save_figure(fig, stem: Path) -> Path:
    """``fig`` as ``stem.png`` (at :data:`DPI`), ``stem.svg`` and ``stem.pdf``; returns the PNG's path."""
    paths = [stem.with_name(f"{stem.name}.{fmt}") for fmt in FIGURE_FORMATS]
    for path in paths:
        fig.savefig(path, dpi=DPI)
    return paths[0]


# --------------------------------------------------------------------------- #
# LaTeX tables (covviz report --latex)
# --------------------------------------------------------------------------- #
def _tex(text: str) -> str:
    """Plain text as LaTeX (the characters the report's names and numbers use)."""
    out = str(text)
    for a, b in (("\\", r"\textbackslash{}"), ("_", r"\_"), ("&", r"\&"), ("%", r"\%"), ("#", r"\#"),
                 ("±", r"$\pm$"), ("†", r"$^\dagger$"), ("↑", r"$\uparrow$"), ("↓", r"$\downarrow$"),
                 ("—", "--")):
        out = out.replace(a, b)
    return out


def _latex_table(rows, caption: str, label: str) -> list[str]:
    """One table of :func:`_table`'s rows in LaTeX (booktabs), the best mean of each metric in bold."""
    head, best = _table_head(rows)
    L = [r"\begin{table}[t]", r"\centering", r"\small", r"\begin{tabular}{ll" + "r" * (len(head) - 2) + "}",
         r"\toprule", " & ".join(_tex(h) for h in head) + r" \\", r"\midrule"]
    for name, runs, stats, fps, failed in rows:
        cells = [r"\texttt{" + _tex(name) + "}", _tex(runs)]
        for key, _, _ in COLUMNS:
            c = _tex(stats[key].fmt())
            if key in best and np.isfinite(stats[key].mean) and round(stats[key].mean, 3) == round(best[key], 3):
                c = r"\textbf{" + c + "}"
            cells.append(c)
        cells.append(_tex(fps.fmt(_fps_digits(fps.mean))))
        cells.append(_tex(failed.fmt(0)) if np.isfinite(failed.mean) else "--")
        L.append(" & ".join(cells) + r" \\")
    L += [r"\bottomrule", r"\end{tabular}", r"\caption{" + caption + "}", r"\label{" + label + "}",
          r"\end{table}", ""]
    return L


def render_latex(summary: Summary) -> str:
    """The report's tables in LaTeX (needs ``\\usepackage{booktabs}``): overall, success AUC per sequence,
    and one per sequence; mean $\\pm$ std over seeds as in the markdown."""
    L = ["% covviz report --latex: the tables of report.md (needs \\usepackage{booktabs})", ""]
    L += _latex_table(summary.overall, f"Overall, averaged over the {len(summary.sequences)} sequences "
                      r"(mean $\pm$ std over seeds; best in bold).", "tab:covviz-overall")
    trackers = summary.trackers
    L += [r"\begin{table}[t]", r"\centering", r"\small", r"\begin{tabular}{lr" + "r" * len(trackers) + "}",
          r"\toprule", "sequence & frames & " + " & ".join(r"\texttt{" + _tex(t) + "}" for t in trackers) + r" \\",
          r"\midrule"]
    for s in summary.sequences:
        cells = []
        for t in trackers:
            rs = summary.by.get((s, t), [])
            cells.append(_tex(Stat.of(r.metrics.get("success_auc") for r in rs).fmt()) if rs else "--")
        L.append(f"{_tex(s)} & {summary.seq_frames.get(s, '?')} & " + " & ".join(cells) + r" \\")
    L += [r"\bottomrule", r"\end{tabular}", r"\caption{Success AUC per sequence.}",
          r"\label{tab:covviz-auc}", r"\end{table}", ""]
    L += _latex_replays(summary)
    for s in summary.sequences:
        if summary.per_sequence.get(s):
            L += _latex_table(summary.per_sequence[s], f"{_tex(s)} ({frames_tracked(summary, s)}).",
                              f"tab:covviz-{''.join(c if c.isalnum() else '-' for c in s)}")
    return "\n".join(L)


def _latex_replays(summary: Summary) -> list[str]:
    """The counterfactual replays' two main tables in LaTeX: losses by verdict, and ΔAUC per fix (none without replays)."""
    from covviz.experiments.report_counterfactual import GAIN_FIXES, VERDICTS, fmt_delta

    reps = summary.replays
    ts = [t for t in summary.trackers if t in reps and reps[t].replayed]
    if not ts:
        return []
    cols = [v for v in VERDICTS if any(v in reps[t].verdicts for t in ts)]
    fixes = [f for f in GAIN_FIXES if any(f in reps[t].gains for t in ts)]
    tt = lambda t: r"\texttt{" + _tex(t) + "}"
    L = [r"\begin{table}[t]", r"\centering", r"\small", r"\begin{tabular}{lrrr" + "r" * len(cols) + "}",
         r"\toprule", " & ".join(["tracker", "losses", "replayed", r"\texttt{none} identical", *cols]) + r" \\",
         r"\midrule"]
    for t in ts:
        r = reps[t]
        ident = f"{r.none_identical}/{r.none_replays}" if r.none_replays else "--"
        L.append(" & ".join([tt(t), str(r.losses), str(r.replayed), ident,
                             *(str(r.verdicts.get(v, 0)) for v in cols)]) + r" \\")
    L += [r"\bottomrule", r"\end{tabular}",
          r"\caption{Losses by verdict: the smallest oracle fix whose replay kept the track.}",
          r"\label{tab:covviz-verdicts}", r"\end{table}", ""]
    L += [r"\begin{table}[t]", r"\centering", r"\small", r"\begin{tabular}{lrr" + "r" * len(fixes) + "}",
          r"\toprule", " & ".join(["tracker", "runs", "AUC", *(r"$\Delta$" + _tex(f) for f in fixes)]) + r" \\",
          r"\midrule"]
    for t in ts:
        r = reps[t]
        cells = [_tex(fmt_delta(r.gains[f])) if f in r.gains else "--" for f in fixes]
        L.append(" & ".join([tt(t), str(r.scored_runs), f"{r.auc:.3f}" if np.isfinite(r.auc) else "--", *cells])
                 + r" \\")
    L += [r"\bottomrule", r"\end{tabular}",
          (r"\caption{What fixing each kind of failure would gain: success AUC with every loss's replayed window "
          r"replaced by its replay under the fix, minus the run's own (mean over runs).}"),
          r"\label{tab:covviz-gains}", r"\end{table}", ""]
    return L
