"""The counterfactual replays of a bench, as ``covviz report`` reads them (issue 20, item 5).

``covviz bench --counterfactual`` replays every loss inside its job
(:mod:`covviz.diagnosis.counterfactual`) and stores on each entry of a result's
``diagnosis.diagnoses`` the outcome of each intervention (``counterfactual``), the
``verdict`` and the replayed boxes (``replay``). This module turns them into, per tracker:

* **losses by verdict**, and how many unchanged (``none``) replays reproduced their run bit
  for bit: a ``none`` replay that did not means the replays of that loss cannot be trusted;
* **what fixing each kind of failure would gain**: for a fix ``F``, every loss of a run whose
  replay has ``F`` has the run's boxes on its window (frames ``from..to``) replaced by the
  replay's boxes under ``F`` (:func:`patched_boxes`; losses in frame order, a later window
  overriding an earlier where they overlap); ΔAUC is the OTB success AUC of the whole patched
  run minus the run's own (:func:`fix_aucs`), averaged over the tracker's runs;
* **how stable the verdicts are across seeds**: the losses of different seeds of one
  (sequence, tracker) lost within :data:`MATCH_FRAMES` frames of each other are matched
  (:func:`match_losses`), and the share of matched pairs with the same verdict is reported;
* **cause × verdict**: what happened in the scene against which part of the tracker failed.

Both AUCs of a ΔAUC are computed here, from the saved boxes at the precision of the results
file (2 decimals, :data:`BOX_DECIMALS`) and the sequence's ground truth, so the unchanged
replay of a loss it reproduced gives ΔAUC exactly 0. Nothing is re-run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from covviz.diagnosis.counterfactual import FIXES
from covviz.experiments.results import ResultError
from covviz.metrics import success_curve

__all__ = [
    "BOX_DECIMALS",
    "GAIN_FIXES",
    "MATCH_FRAMES",
    "NO_REPLAYS",
    "VERDICTS",
    "LossReplay",
    "TrackerReplays",
    "fix_aucs",
    "fmt_delta",
    "losses_of",
    "match_losses",
    "patched_boxes",
    "render_section",
    "success_auc",
    "summarize_replays",
]

#: Every verdict, in the order the tables show them (the fixes smallest first).
VERDICTS = (*FIXES, "restart", "none helps")
#: The interventions whose replayed boxes the ΔAUC table patches in (``none``: the check, 0 when identical).
GAIN_FIXES = ("none", *FIXES, "restart")
#: Losses of two seeds of one (sequence, tracker) lost at most this many frames apart are the same loss.
MATCH_FRAMES = 10
#: Boxes are compared at the precision the results file keeps them (``x,y,w,h`` with 2 decimals).
BOX_DECIMALS = 2
#: What the report says where results hold no replays.
NO_REPLAYS = "no replays (run bench with --counterfactual)"


@dataclass(frozen=True, eq=False)
class LossReplay:
    """One loss of a run, with its replays if it has any.

    Attributes
    ----------
    lost_at : int
        1-based frame of the loss.
    cause : str
        The diagnosed cause (:data:`covviz.diagnosis.drift.CAUSES` or ``"unknown"``).
    verdict : str or None
        The smallest fix that kept the track (:data:`VERDICTS`); None if the loss was not replayed.
    outcomes : dict
        ``counterfactual`` of the result: per intervention ``kept``, ``mean_iou``, ``frames_kept``
        (and ``identical`` on ``none``).
    start, end : int or None
        The window the interventions acted on, 1-based frames, inclusive.
    boxes : dict of str to ndarray, shape (end - start + 1, 4)
        The replayed boxes per intervention, 0-based pixels, rounded to :data:`BOX_DECIMALS`.
    """

    lost_at: int
    cause: str
    verdict: str | None = None
    outcomes: dict = field(default_factory=dict)
    start: int | None = None
    end: int | None = None
    boxes: dict = field(default_factory=dict)

    @property
    def replayed(self) -> bool:
        return self.verdict is not None

    @property
    def identical(self) -> bool | None:
        """Whether the unchanged replay reproduced the run bit for bit (None: no ``none`` replay)."""
        o = self.outcomes.get("none")
        return None if not o or "identical" not in o else bool(o["identical"])


def losses_of(diagnosis: dict | None, n_frames: int, where: str | Path = "result") -> tuple[LossReplay, ...]:
    """The losses of a result's ``diagnosis`` with their replays, in frame order.

    Raises
    ------
    ResultError
        If a replay's boxes do not fit its window or the run (``where`` names the file).
    """
    out = []
    for d in (diagnosis or {}).get("diagnoses", []):
        lost_at, cause = int(d["lost_at"]), str(d.get("cause", "unknown"))
        if "verdict" not in d or "replay" not in d:
            out.append(LossReplay(lost_at, cause))
            continue
        rp = d["replay"]
        start, end = int(rp["from"]), int(rp["to"])
        if not 1 <= start <= end <= n_frames:
            raise ResultError(f"{where}: the replay of the loss at {lost_at} covers frames {start}-{end} "
                              f"of a run of {n_frames}; re-run it")
        boxes = {}
        for name, b in (rp.get("boxes") or {}).items():
            arr = np.round(np.asarray(b, dtype=np.float64).reshape(-1, 4), BOX_DECIMALS)
            if len(arr) != end - start + 1:
                raise ResultError(f"{where}: the {name!r} replay of the loss at {lost_at} has {len(arr)} boxes "
                                  f"for frames {start}-{end}; re-run it")
            boxes[name] = arr
        out.append(LossReplay(lost_at, cause, str(d["verdict"]), dict(d.get("counterfactual") or {}),
                              start, end, boxes))
    return tuple(sorted(out, key=lambda lr: lr.lost_at))


def saved_boxes(boxes: np.ndarray) -> np.ndarray:
    """``boxes`` at the precision of the results file (what both AUCs of a ΔAUC are computed on)."""
    return np.round(np.asarray(boxes, dtype=np.float64).reshape(-1, 4), BOX_DECIMALS)


def patched_boxes(boxes: np.ndarray, losses, fix: str) -> np.ndarray:
    """The run's boxes with the window of every loss whose replay has ``fix`` replaced by that replay.

    Losses are applied in frame order, so a later window overrides an earlier one where they
    overlap; losses without a ``fix`` replay leave their frames as they were. ``boxes`` is not changed.

    Parameters
    ----------
    boxes : ndarray, shape (n, 4)
        The run's boxes, 0-based pixels.
    losses : sequence of LossReplay
    fix : str
        An intervention name (:data:`GAIN_FIXES`).

    Returns
    -------
    ndarray, shape (n, 4)
    """
    out = np.array(boxes, dtype=np.float64, copy=True).reshape(-1, 4)
    for lr in sorted(losses, key=lambda lr: lr.lost_at):
        b = lr.boxes.get(fix)
        if b is not None:
            out[lr.start - 1: lr.end] = b
    return out


def success_auc(boxes: np.ndarray, gt: np.ndarray) -> float:
    """OTB success AUC of a whole run (as :func:`covviz.metrics.evaluate` computes it)."""
    return float(np.mean(success_curve(boxes, gt)))


def fix_aucs(boxes: np.ndarray, gt: np.ndarray, losses) -> dict[str, float]:
    """The success AUC of the run patched under each fix its losses were replayed with.

    Returns
    -------
    dict of str to float
        ``{fix: AUC of patched_boxes(boxes, losses, fix)}`` for each fix of :data:`GAIN_FIXES`
        that at least one loss has; empty when no loss was replayed.
    """
    present = {k for lr in losses for k in lr.boxes}
    return {f: success_auc(patched_boxes(boxes, losses, f), gt) for f in GAIN_FIXES if f in present}


def match_losses(by_seed: dict, window: int = MATCH_FRAMES) -> tuple[list, list]:
    """Match the losses of different seeds of one (sequence, tracker) that were lost close together.

    For every two seeds, the pairs of their losses lost at most ``window`` frames apart are taken
    nearest first, each loss at most once per pair of seeds (a greedy one-to-one matching).

    Parameters
    ----------
    by_seed : dict
        ``seed -> [(lost_at, verdict), ...]``.
    window : int
        Frames.

    Returns
    -------
    pairs : list of ((seed, lost_at, verdict), (seed, lost_at, verdict))
    unmatched : list of (seed, lost_at, verdict)
        The losses matched with no loss of any other seed.
    """
    seeds = sorted(by_seed, key=lambda s: (s is None, s))
    pairs, matched = [], set()
    for i, a in enumerate(seeds):
        for b in seeds[i + 1:]:
            cands = sorted(
                (abs(la - lb), la, lb, va, vb)
                for la, va in by_seed[a] for lb, vb in by_seed[b] if abs(la - lb) <= window
            )
            used_a, used_b = set(), set()
            for _, la, lb, va, vb in cands:
                if la in used_a or lb in used_b:
                    continue
                used_a.add(la)
                used_b.add(lb)
                pairs.append(((a, la, va), (b, lb, vb)))
                matched |= {(a, la), (b, lb)}
    unmatched = [(s, la, v) for s in seeds for la, v in by_seed[s] if (s, la) not in matched]
    return pairs, unmatched


@dataclass(frozen=True)
class TrackerReplays:
    """The replays of one tracker's losses over a bench (see the module docstring).

    Attributes
    ----------
    runs : int
    losses, replayed : int
        Every loss, and those with replays.
    verdicts : dict
        ``verdict -> losses``.
    none_replays, none_identical : int
        Replayed losses with an unchanged (``none``) replay, and how many of those reproduced their run.
    not_identical : tuple
        ``(sequence, seed, lost_at)`` of the ``none`` replays that did not.
    scored_runs : int
        Runs whose ground truth was found (the AUC and ΔAUC means are over these).
    auc : float
        Mean over the scored runs of the run's success AUC.
    gains : dict
        ``fix -> mean ΔAUC`` over the scored runs (0 for a run without a replay under the fix).
    cause_verdict : dict
        ``(cause, verdict) -> losses``.
    pairs, same : int or None
        Loss pairs matched across seeds and how many have the same verdict (None: one run per sequence).
    unmatched, stability_losses : int
        Replayed losses with no counterpart in another seed, out of the replayed losses of
        (sequence, tracker) that ran with more than one seed.
    disagreements : tuple
        ``(sequence, (seed, lost_at, verdict), (seed, lost_at, verdict))`` of the matched pairs whose verdicts differ.
    unreplayed : tuple
        ``(sequence, seed, lost_at)`` of the losses without replays.
    """

    tracker: str
    runs: int
    losses: int
    replayed: int
    verdicts: dict
    none_replays: int
    none_identical: int
    not_identical: tuple
    scored_runs: int
    auc: float
    gains: dict
    cause_verdict: dict
    pairs: int | None
    same: int | None
    unmatched: int
    stability_losses: int
    disagreements: tuple = ()
    unreplayed: tuple = ()


def summarize_replays(runs, trackers) -> dict[str, TrackerReplays]:
    """Aggregate the replays of the runs (:class:`covviz.experiments.report.Run`) per tracker.

    Each run must carry ``loss_replays`` (tuple of :class:`LossReplay`), ``auc`` (float, nan
    without ground truth) and ``fixed_auc`` (:func:`fix_aucs` of its boxes).
    """
    out = {}
    for t in trackers:
        rs = [r for r in runs if r.tracker == t]
        losses = [(r, lr) for r in rs for lr in r.loss_replays]
        rep = [(r, lr) for r, lr in losses if lr.replayed]
        verdicts: dict = {}
        cause_verdict: dict = {}
        for _, lr in rep:
            verdicts[lr.verdict] = verdicts.get(lr.verdict, 0) + 1
            cause_verdict[(lr.cause, lr.verdict)] = cause_verdict.get((lr.cause, lr.verdict), 0) + 1
        checked = [(r, lr) for r, lr in rep if lr.identical is not None]
        not_identical = tuple((r.sequence, r.seed, lr.lost_at) for r, lr in checked if not lr.identical)
        scored = [r for r in rs if np.isfinite(r.auc)]
        fixes = [f for f in GAIN_FIXES if any(f in r.fixed_auc for r in scored)]
        gains = {f: float(np.mean([r.fixed_auc.get(f, r.auc) - r.auc for r in scored])) for f in fixes}
        # verdict stability: the losses of different seeds of one sequence
        pairs = same = None
        unmatched = stability_losses = 0
        disagreements = []
        for seq in sorted({r.sequence for r in rs}):
            by_seed = {r.seed: [(lr.lost_at, lr.verdict) for lr in r.loss_replays if lr.replayed]
                       for r in rs if r.sequence == seq}
            if len(by_seed) < 2:
                continue
            p, u = match_losses(by_seed)
            pairs, same = (pairs or 0) + len(p), (same or 0) + sum(a[2] == b[2] for a, b in p)
            unmatched += len(u)
            disagreements += [(seq, a, b) for a, b in p if a[2] != b[2]]
            stability_losses += sum(len(v) for v in by_seed.values())
        out[t] = TrackerReplays(
            tracker=t, runs=len(rs), losses=len(losses), replayed=len(rep), verdicts=verdicts,
            none_replays=len(checked), none_identical=len(checked) - len(not_identical),
            not_identical=not_identical, scored_runs=len(scored),
            auc=float(np.mean([r.auc for r in scored])) if scored else float("nan"),
            gains=gains, cause_verdict=cause_verdict, pairs=pairs, same=same, unmatched=unmatched,
            stability_losses=stability_losses, disagreements=tuple(disagreements),
            unreplayed=tuple((r.sequence, r.seed, lr.lost_at) for r, lr in losses if not lr.replayed),
        )
    return out


def fmt_delta(v: float) -> str:
    """A ΔAUC: exactly 0 as ``0``, anything else with its sign (``+0.000``: above 0 but below 0.0005)."""
    return "—" if not np.isfinite(v) else ("0" if v == 0 else f"{v:+.3f}")


def _seed(s) -> str:
    return "" if s is None else f" s{s}"


def render_section(replays: dict[str, TrackerReplays], trackers) -> list[str]:
    """The report's section on the replays (markdown lines)."""
    L = ["## What fixing each kind of failure would gain (counterfactual replays)", ""]
    with_replays = [t for t in trackers if t in replays and replays[t].replayed]
    if not with_replays:
        return [*L, f"No replays in these results: {NO_REPLAYS}.", ""]
    L += [
        (
            "`covviz bench --counterfactual` replayed every loss from the tracker's state a few frames before "
            "its drift began (3 by default) to some frames after the loss (20 by default, fewer where the run "
            "ended sooner), under each oracle fix of "
            "`covviz.diagnosis.counterfactual` (from the ground truth): `none` (unchanged: it must reproduce the "
            "run bit for bit), `estimate` (the estimate replaced by the particle nearest the truth), `search` "
            "(some particles moved to the truth), `model` (the templates set from the truth's look), "
            "`search+model` (both); trackers that cannot be forked (OpenCV's) were `restart`ed at the truth at "
            "the drift onset. A replay *kept* the track when its IoU with the truth was ≥ 0.5 at the loss frame "
            "and ≥ 0.5 on average over the frames after it. The **verdict** of a loss is the smallest fix that "
            "kept the track (estimate < search < model < search+model; `restart` for OpenCV's), or *none helps*. The cause (the section above) names what happened "
            "in the scene; the verdict, which part of the tracker failed."
        ),
        "",
    ]
    n_none = sum(replays[t].none_replays for t in with_replays)
    n_same = sum(replays[t].none_identical for t in with_replays)
    bad = [(t, *x) for t in with_replays for x in replays[t].not_identical]
    line = (f"**The unchanged (`none`) replay reproduced its run bit for bit on {n_same} of {n_none} replayed "
            f"losses.**")
    if bad:
        shown = ", ".join(f"`{t}` {s}{_seed(sd)} at {la}" for t, s, sd, la in bad[:12])
        more = f" and {len(bad) - 12} more" if len(bad) > 12 else ""
        line += (f" Not on {shown}{more}: the replays of these losses did not start from the run's own state, "
                 "so their verdicts and gains cannot be trusted.")
    L += [line, ""]
    without = [t for t in trackers if t in replays and not replays[t].replayed]
    no_losses = [t for t in without if not replays[t].losses]
    not_replayed = [t for t in without if replays[t].losses]

    # ---- losses by verdict ------------------------------------------------------------------------------
    cols = [v for v in VERDICTS if any(v in replays[t].verdicts for t in with_replays)]
    L += ["### Losses by verdict", "",
          "| tracker | losses | replayed | `none` identical | " + " | ".join(cols) + " |",
          "|---|---:|---:|---:|" + "---:|" * len(cols)]
    for t in with_replays:
        r = replays[t]
        ident = f"{r.none_identical}/{r.none_replays}" if r.none_replays else "—"
        L.append(f"| `{t}` | {r.losses} | {r.replayed} | {ident} | "
                 + " | ".join(str(r.verdicts.get(v, 0) or "·") for v in cols) + " |")
    L += [
        "",
        (
            "*replayed*: the losses with replays. A loss is replayed from a checkpoint of its run's state at or "
            "before the frame the replay starts on; the runner keeps a bounded memory of them "
            "(`covviz.runner.CheckpointRing`: dense for the recent past, sparse further back), so a loss "
            "older than the sparse ring's reach has none left and is not replayed. *`none` identical*: of the "
            "replayed losses with an unchanged replay, those that reproduced the run (— : restarts only)."
        ),
        "",
    ]
    for t in with_replays:
        un = replays[t].unreplayed
        if un:
            more = f" and {len(un) - 12} more" if len(un) > 12 else ""
            L += [f"Not replayed, `{t}`: " + ", ".join(f"{sq}{_seed(sd)} at {la}" for sq, sd, la in un[:12])
                  + more + ".", ""]
    if not_replayed:
        L += [(f"{', '.join(f'`{t}`' for t in not_replayed)}: losses but none replayed — {NO_REPLAYS}, "
              "or no checkpoint reached them."), ""]
    if no_losses:
        L += [f"{', '.join(f'`{t}`' for t in no_losses)}: no losses.", ""]

    # ---- what fixing would gain -------------------------------------------------------------------------
    fixes = [f for f in GAIN_FIXES if any(f in replays[t].gains for t in with_replays)]
    L += [
        "### What fixing each kind of failure would gain",
        "",
        (
            "For a fix F and a run: every loss whose replay has F gets the run's boxes on its replayed window "
            "(frames *from*..*to*) replaced by the replay's boxes under F, losses in frame order (a later window "
            "overrides an earlier where they overlap); then the OTB success AUC of the whole run. "
            "**ΔAUC F** = that AUC − the run's own, averaged over the tracker's runs (sequences × seeds; a run "
            "without a loss replayed under F counts 0). *AUC*: the mean of the runs' own success AUC. Both are "
            f"computed from the saved boxes ({BOX_DECIMALS} decimals; the AUC may differ from the overall "
            "table's in the fourth decimal) and the sequences' ground truth, so "
            "**ΔAUC none** is exactly 0 where the unchanged replays reproduced their runs; a fix's ΔAUC is what "
            "a tracker with that part fixed during its losses' windows (and only there) would gain."
        ),
        "",
        "| tracker | runs | AUC | " + " | ".join(f"ΔAUC {f}" for f in fixes) + " |",
        "|---|---:|---:|" + "---:|" * len(fixes),
    ]
    for t in with_replays:
        r = replays[t]
        runs = f"{r.scored_runs}" + (f" of {r.runs}" if r.scored_runs != r.runs else "")
        auc = "—" if not np.isfinite(r.auc) else f"{r.auc:.3f}"
        L.append(f"| `{t}` | {runs} | {auc} | " + " | ".join(fmt_delta(r.gains.get(f, float('nan'))) for f in fixes)
                 + " |")
    L.append("")
    if any(replays[t].scored_runs < replays[t].runs for t in with_replays):
        L += [("*runs*: the runs whose sequence's ground truth was found (at the result's `bench.path` or the "
              "manifest's root); the others cannot be scored and are left out."), ""]

    # ---- verdict stability ------------------------------------------------------------------------------
    seeded = [t for t in with_replays if replays[t].pairs is not None]
    L += ["### Are the verdicts stable across seeds?", ""]
    if seeded:
        L += [
            (
                f"For each sequence and tracker, the replayed losses of two different seeds lost at most "
                f"`MATCH_FRAMES` = {MATCH_FRAMES} frames apart are one loss seen twice (matched nearest first, "
                "each loss at most once per pair of seeds). *same verdict*: the share of matched pairs whose two "
                "verdicts agree; *no counterpart*: losses matched with no loss of any other seed."
            ),
            "",
            "| tracker | replayed losses | matched pairs | same verdict | no counterpart |",
            "|---|---:|---:|---:|---:|",
        ]
        for t in seeded:
            r = replays[t]
            share = f"{r.same}/{r.pairs} ({100 * r.same / r.pairs:.0f}%)" if r.pairs else "—"
            L.append(f"| `{t}` | {r.stability_losses} | {r.pairs} | {share} | {r.unmatched} |")
        L.append("")
        for t in seeded:
            dis = replays[t].disagreements
            if dis:
                shown = "; ".join(f"{sq} s{a[0]} at {a[1]} {a[2]} / s{b[0]} at {b[1]} {b[2]}" for sq, a, b in dis[:10])
                more = f"; and {len(dis) - 10} more" if len(dis) > 10 else ""
                L += [f"Verdicts that differ, `{t}`: {shown}{more}.", ""]
    once = [t for t in with_replays if replays[t].pairs is None]
    if once:
        L += [f"{', '.join(f'`{t}`' for t in once)}: one run per sequence, nothing to compare.", ""]

    # ---- cause x verdict --------------------------------------------------------------------------------
    L += ["### Cause × verdict", "",
          "Replayed losses per tracker: the diagnosed cause (rows) against the verdict (columns).", ""]
    for t in with_replays:
        cv = replays[t].cause_verdict
        vcols = [v for v in VERDICTS if any(k[1] == v for k in cv)]
        causes = sorted({k[0] for k in cv}, key=lambda c: (-sum(n for k, n in cv.items() if k[0] == c), c))
        L += [f"`{t}`:", "", "| cause | " + " | ".join(vcols) + " |", "|---|" + "---:|" * len(vcols)]
        for c in causes:
            L.append(f"| {c.replace('_', ' ')} | " + " | ".join(str(cv.get((c, v), 0) or "·") for v in vcols) + " |")
        L.append("")
    return L
