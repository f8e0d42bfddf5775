"""Fitting the drift model on labelled runs, and its strict leave-one-sequence-out evaluation.

Everything here reads results on disk (``covviz bench`` folders): each run's
``diagnosis.signals`` (label-free, saved frame by frame) and ``diagnosis.frame_iou``
(the labels: a frame is *off track* when its IoU with the ground truth is below
:data:`OFF_TRACK_IOU`). No tracker is re-run.

The alarm rule (threshold, release, cooldown) of the model and of every single
signal used as a baseline is chosen by :func:`choose_alarm` — the same rule for
all — on the training runs only; the model's colour gate is chosen with its rule
(:func:`choose_rule`). A model of many signals has them chosen on its training
runs' held-out probabilities (each run's from the model of the design choice's fold
that left its sequence out, :func:`fit_model`'s ``rule_probs``): on its own fitted
probabilities the threshold that reaches the rule's precision is one a new
sequence does not reach.

The rule's order (:func:`_rule_key`, :data:`RULE_ORDER`): among the candidates whose
training precision reaches :data:`MIN_PRECISION`, the most losses found less the
false alarms, each weighed ``MIN_PRECISION / (1 - MIN_PRECISION)`` (1 at the floor
of 0.5): finding one more loss is worth at most one more false alarm. The first
order took the most event recall, so one more loss outranked any number of false
alarms: on the default tracker's Xeon dev runs its refit traded 26 more false alarms
for one loss. Leave one sequence out on the default's runs, the model's alarms went
from 50% precision at 93% recall to 76% at 77% (seeds 0-5) and from 53% at 88% to
81% at 95% (seeds 6-8), ahead of every single signal on both (``docs/tuning.md``).

What the model is fitted to find (:data:`TARGETS`): the frames of the *drift
episodes* — each loss's window, from :data:`MATCH_BEFORE` frames before its drift
began to :data:`MATCH_AFTER` after it, the frames an alarm is scored right on —
against the frames on track outside them, the frames off track outside every
window (the box long lost, sitting on the background) left out of the fit; or every
off-track frame (``"off_track"``: IoU below :data:`OFF_TRACK_IOU`, the first
design), where the model learns mostly what a lost box looks like (four fifths of
the default tracker's off-track frames on the dev runs) and its alarms come at or
after the loss. Which of the two a family's model is fitted to find is chosen with
its feature design, by held-out alarms on the training sequences
(:func:`choose_fit`). Beside the two models of many signals, each single signal of
:data:`BASELINES` alone is a candidate of that choice (the ``signal`` design,
``"signal:NAME"`` in :func:`candidates`). Leave-one-sequence-out on the default tracker's dev runs: every
fold on the off-track frames, recall 61% at precision 51%; on the episodes, 75% at
52%; chosen inside each fold, 65% at 49% (``docs/tuning.md``, ``docs/results.md``).

Events (as ``covviz.diagnosis.events`` defines them): a *loss* is an IoU below
0.1 after a frame at 0.5 or more; its drift began where
:func:`covviz.diagnosis.events.drift_onset` says. An alarm is *right* when it
falls between :data:`MATCH_BEFORE` frames before the drift began and
:data:`MATCH_AFTER` frames after the loss; an alarm on a frame still off track
(IoU < 0.5) and outside every window is neither right nor false; every other
alarm is false.
"""

from __future__ import annotations

import functools
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from covviz.diagnosis.detector import (
    COOLDOWN,
    DESIGNS,
    FAMILIES,
    GATE_SIGNAL,
    DriftModel,
    Hysteresis,
    family_of,
    gate_probability,
    history_features,
)
from covviz.diagnosis.signals import GENERIC_SIGNALS, SIGNALS
from covviz.errors import InputError

log = logging.getLogger("covviz")

__all__ = [
    "BASELINES",
    "FIT_TARGET",
    "OFF_TRACK_IOU",
    "TARGETS",
    "Run",
    "alarm_frames",
    "choose_alarm",
    "choose_design",
    "choose_fit",
    "choose_rule",
    "episode_frames",
    "fit_model",
    "fit_target",
    "load_runs",
    "losses_of",
    "parse_seeds",
    "score_alarms",
    "seed_list",
]

#: A frame is off track (the label the model is fitted on) below this IoU with the ground truth.
OFF_TRACK_IOU = 0.5
#: An alarm matches a loss from this many frames before its drift began ...
MATCH_BEFORE = 10
#: ... to this many after the loss.
MATCH_AFTER = 5
#: What the model is fitted to find (module docstring): the drift episodes, or every off-track frame.
TARGETS = ("episodes", "off_track")
FIT_TARGET = "episodes"
#: Regularisation of the logistic regression (inverse strength), fixed a priori.
C_REG = 1.0
#: Quantile levels of the training scores tried as thresholds, and release offsets below them.
THRESHOLD_LEVELS = (0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.93, 0.95, 0.97, 0.98, 0.99, 0.995, 0.998)
RELEASE_OFFSETS = (0.0, 0.1, 0.3)
#: The rule's floor: the candidates at a training precision of at least this are ranked by
#: :data:`RULE_ORDER`; if none reaches it, the best F1.
MIN_PRECISION = 0.5
#: How the rule ranks the candidates at the floor (:func:`_rule_key`): ``"losses"`` (the losses found less
#: the false alarms, each weighed ``MIN_PRECISION / (1 - MIN_PRECISION)``: 1 at the floor of 0.5; then
#: recall, then fewer false alarms), ``"alarms"`` (the same with the right alarms in place of the losses
#: found, so a second alarm in one loss's window counts as a find) or ``"recall"`` (the most event recall,
#: then fewer false: the first order). The last two are kept for the comparison (``docs/tuning.md``).
RULE_ORDER = "losses"
#: The orders :data:`RULE_ORDER` may name.
RULE_ORDERS = ("losses", "alarms", "recall")
#: Single signals scored as baselines: name -> (signal, sign); the score is sign * signal (high = trouble).
#: The issue's four, the flow gap (the strongest single signal on the dev runs) and the slip (the flow gap
#: summed as a vector over recent frames).
BASELINES = {"FB error": ("fb_error", 1.0), "PSR": ("psr", -1.0), "ESS": ("ess", -1.0), "distance z": ("dmin_z", 1.0),
             "flow gap": ("flow_gap", 1.0), "slip": ("slip", 1.0), "colour": ("colour", 1.0)}
#: The direction of trouble of each signal a ``signal`` design may read (from :data:`BASELINES`).
TROUBLE = {sig: sign for sig, sign in BASELINES.values()}
#: What a ``signal`` design is fitted on: its alarms do not depend on it (the map is monotone), and with
#: the off-track frames its probability reads as the chance of being off track at that level.
SIGNAL_TARGET = "off_track"
#: Whether a many-signal model's alarm rule is chosen on its training runs' held-out probabilities
#: (:func:`fit_model`'s ``rule_probs``) rather than on its own fitted ones.
RULE_ON_HELD_OUT = True
#: The gates :func:`choose_rule` weighs (levels of the ``colour`` signal: the share of its first contrast lost).
GATE_LEVELS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)


@dataclass(frozen=True, eq=False)
class Run:
    """One result's signals and labels."""

    sequence: str
    tracker: str
    seed: int | None
    rows: np.ndarray  # (n, len(SIGNALS)), nan where a signal does not apply
    iou: np.ndarray  # (n,), nan without ground truth
    losses: tuple = field(default=())  # ((drift began, lost at), ...) 1-based

    @property
    def off(self) -> np.ndarray:
        return self.iou < OFF_TRACK_IOU

    @property
    def labelled(self) -> np.ndarray:
        m = np.isfinite(self.iou)
        m[:1] = False  # the first frame is the given box
        return m


def _floats(v) -> np.ndarray:
    return np.array([np.nan if x is None else float(x) for x in v], dtype=np.float64)


def losses_of(iou: np.ndarray) -> tuple:
    """``(drift began, lost at)`` of every loss of an IoU series (1-based), as the event detector finds them."""
    from covviz.diagnosis.events import EventDetector

    det = EventDetector()
    for i, v in enumerate(iou):
        det.update(i + 1, float(v) if np.isfinite(v) else None)
    return tuple(zip(det.drifts, det.losses))


def load_runs(bench_dir, trackers=None, seeds=None) -> list[Run]:
    """Every result under ``bench_dir`` with signals and labels (optionally only these trackers / seeds).

    Raises
    ------
    InputError
        If the folder does not exist or holds no such result, if a tracker of ``trackers`` has no result
        there, or if none of ``seeds`` is among its stochastic trackers' seeds (a seed filter that matched
        nothing would leave only the deterministic trackers' runs, silently). Seeds of ``seeds`` that are
        missing while others are present are logged as a warning.
    """
    root = Path(bench_dir)
    if not root.is_dir():
        raise InputError(f"{root}: no such folder (give a 'covviz bench --out' folder)")
    runs: list[Run] = []
    skipped = 0
    seen_trackers: set = set()
    seen_seeds: set = set()
    for js in sorted(root.glob("*/*.json")):
        try:
            doc = json.loads(js.read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError):
            skipped += 1
            continue
        if not isinstance(doc, dict) or "tracker" not in doc:
            continue
        seen_trackers.add(doc["tracker"])
        if trackers is not None and doc["tracker"] not in trackers:
            continue
        if doc.get("seed") is not None:
            seen_seeds.add(doc["seed"])
        if seeds is not None and doc.get("seed") is not None and doc["seed"] not in seeds:
            continue
        dg = doc.get("diagnosis") or {}
        sig, fi = dg.get("signals"), dg.get("frame_iou")
        if not sig or fi is None or doc.get("interrupted"):
            skipped += 1
            continue
        n = len(fi)
        rows = np.stack([_floats(sig[k]) if k in sig else np.full(n, np.nan) for k in SIGNALS], axis=1)
        iou = _floats(fi)
        runs.append(Run(doc.get("sequence", js.parent.name), doc["tracker"], doc.get("seed"), rows, iou,
                        losses_of(iou)))
    if skipped:
        log.info("%d results without signals or labels skipped (re-run them with this covviz)", skipped)
    missing = sorted(set(trackers or ()) - seen_trackers)
    if missing and seen_trackers:
        raise InputError(f"{root}: no results of {', '.join(missing)} (it has {', '.join(sorted(seen_trackers))})")
    if seeds is not None and seen_seeds:
        if not set(seeds) & seen_seeds:
            raise InputError(f"{root}: no results of seed(s) {seed_list(seeds)} (its stochastic trackers have "
                             f"seeds {seed_list(seen_seeds)})")
        if set(seeds) - seen_seeds:
            log.warning("%s: no results of seed(s) %s; using %s", root, seed_list(set(seeds) - seen_seeds),
                        seed_list(set(seeds) & seen_seeds))
    if not runs:
        raise InputError(f"{root}: no results with drift signals and ground truth "
                         "(run 'covviz bench' on labelled sequences with this covviz first)")
    return runs


def parse_seeds(text: str) -> set[int]:
    """``"0-2,5"`` as ``{0, 1, 2, 5}`` (the inverse of :func:`seed_list`); ValueError on anything else."""
    out: set[int] = set()
    for part in text.split(","):
        a, _, b = part.partition("-")
        out.update(range(int(a), int(b or a) + 1))
    return out


def seed_list(seeds, dash: str = "-") -> str:
    """``{0, 1, 2, 5}`` as ``0-2, 5`` (runs of consecutive seeds joined by ``dash``)."""
    out, run = [], []
    for s in sorted(seeds):
        if run and s == run[-1] + 1:
            run.append(s)
            continue
        if run:
            out.append(str(run[0]) if len(run) == 1 else f"{run[0]}{dash}{run[-1]}")
        run = [s]
    if run:
        out.append(str(run[0]) if len(run) == 1 else f"{run[0]}{dash}{run[-1]}")
    return ", ".join(out)


# --------------------------------------------------------------------------- #
# alarms and their scores
# --------------------------------------------------------------------------- #
def alarm_frames(scores, rule: Hysteresis) -> np.ndarray:
    """0-based frames where ``rule`` raises an alarm on ``scores`` (vectorised :meth:`Hysteresis.step`)."""
    v = np.asarray(scores, dtype=np.float64)
    v = np.where(np.isfinite(v), v, -np.inf)
    above = np.flatnonzero(v >= rule.threshold)
    if not len(above):
        return np.zeros(0, dtype=int)
    below = v < rule.release
    # consecutive frames below the release level ending at each frame
    idx = np.arange(len(v))
    last_not = np.maximum.accumulate(np.where(~below, idx, -1))
    run = idx - last_not
    ends = np.flatnonzero(run >= rule.cooldown)
    out = []
    i = int(above[0])
    while True:
        out.append(i)
        k = np.searchsorted(ends, i + rule.cooldown)  # the episode cannot end before cooldown frames
        k = k if k < len(ends) and ends[k] > i else len(ends)
        if k >= len(ends):
            break
        end = int(ends[k])
        j = np.searchsorted(above, end + 1)
        if j >= len(above):
            break
        i = int(above[j])
    return np.asarray(out, dtype=int)


def loss_windows(run: Run) -> list[tuple[int, int, int]]:
    """``(first, last, lost at)`` of each loss: the 1-based frames (inclusive) where an alarm is right."""
    return [(d - MATCH_BEFORE, lost + MATCH_AFTER, lost) for d, lost in run.losses]


def score_alarms(alarms, run: Run) -> dict:
    """Event-level counts of one run's alarms (0-based frames) against its losses (module docstring)."""
    frames = np.asarray(alarms, dtype=int) + 1
    windows = loss_windows(run)
    tp = fp = 0
    for f in frames:
        if any(a <= f <= b for a, b, _ in windows):
            tp += 1
        else:
            v = run.iou[f - 1]
            if np.isfinite(v) and v >= OFF_TRACK_IOU:
                fp += 1
    found, leads = 0, []
    for a, b, lost in windows:
        hit = frames[(frames >= a) & (frames <= b)]
        if len(hit):
            found += 1
            leads.append(int(lost - hit.min()))
    on = int(np.sum(run.labelled & (run.iou >= OFF_TRACK_IOU)))
    return {"alarms": len(frames), "tp": tp, "fp": fp, "losses": len(windows), "found": found, "leads": leads,
            "on_track": on}


def episode_frames(run: Run) -> np.ndarray:
    """Boolean per frame: inside some loss's matching window (where an alarm is right; 0-based frames)."""
    w = np.zeros(len(run.iou), dtype=bool)
    for first, last, _ in loss_windows(run):
        w[max(first, 1) - 1: last] = True
    return w


def fit_target(run: Run, target: str = FIT_TARGET) -> tuple[np.ndarray, np.ndarray]:
    """The frames a model is fitted on and their labels (1: what it should find), for ``target``."""
    if target not in TARGETS:
        raise ValueError(f"unknown fit target {target!r}; use one of {', '.join(TARGETS)}")
    if target == "off_track":
        return run.labelled, run.off
    w = episode_frames(run)
    keep = run.labelled & (w | (run.iou >= OFF_TRACK_IOU))
    return keep, w


def _pool(counts: list[dict]) -> dict:
    out = {k: sum(c[k] for c in counts) for k in ("alarms", "tp", "fp", "losses", "found", "on_track")}
    out["leads"] = [x for c in counts for x in c["leads"]]
    return out


def _pr(c: dict) -> tuple[float, float]:
    p = c["tp"] / (c["tp"] + c["fp"]) if c["tp"] + c["fp"] else float("nan")
    r = c["found"] / c["losses"] if c["losses"] else float("nan")
    return p, r


def _rule_key(c: dict) -> tuple:
    """The rule's order of pooled counts: at a precision of at least MIN_PRECISION, by :data:`RULE_ORDER`
    (``losses``: ``found - w * fp``, ``alarms``: ``tp - w * fp``, with ``w = MIN_PRECISION / (1 -
    MIN_PRECISION)``, then recall; ``recall``: recall), fewer false alarms last; below the floor, the F1, then
    fewer false alarms. Any candidate at the floor ranks above every one below it."""
    p, rc = _pr(c)
    p, rc = (0.0 if not np.isfinite(p) else p), (0.0 if not np.isfinite(rc) else rc)
    f1 = 2 * p * rc / (p + rc) if p + rc else 0.0
    if not (p >= MIN_PRECISION and rc > 0):
        return (0, f1, -c["fp"])
    if RULE_ORDER == "recall":
        return (1, rc, -c["fp"])
    if RULE_ORDER not in RULE_ORDERS:
        raise ValueError(f"calibrate.RULE_ORDER: one of {', '.join(RULE_ORDERS)}, not {RULE_ORDER!r}")
    finds = c["found"] if RULE_ORDER == "losses" else c["tp"]
    return (1, finds - MIN_PRECISION / (1 - MIN_PRECISION) * c["fp"], rc, -c["fp"])


def _rule_counts_py(v, th, rel, cooldown, first, last, iou, off_iou, out) -> None:
    """For each rule ``(th[k], rel[k])`` the alarms' ``tp``, ``fp`` and the losses ``found`` on one run, into
    ``out[k]``: :func:`alarm_frames` and :func:`score_alarms` in one pass (``v``: scores, nan as -inf;
    ``first``/``last``: the 1-based loss windows, :func:`loss_windows`). Compiled by :func:`_rule_counts`."""
    n, nw = len(v), len(first)
    for k in range(len(th)):
        active, below, tp, fp = False, 0, 0, 0
        hit = np.zeros(nw, dtype=np.bool_)
        for i in range(n):
            x = v[i]
            if not active:
                if x >= th[k]:
                    active, below = True, 0
                    f, inside = i + 1, False
                    for j in range(nw):
                        if first[j] <= f <= last[j]:
                            inside = True
                            hit[j] = True
                    if inside:
                        tp += 1
                    elif iou[i] >= off_iou:  # nan (no label): False, neither right nor false
                        fp += 1
            elif x < rel[k]:
                below += 1
                if below >= cooldown:
                    active = False
            else:
                below = 0
        out[k, 0], out[k, 1], out[k, 2] = tp, fp, hit.sum()


@functools.cache
def _rule_counts():
    """:func:`_rule_counts_py`, compiled by numba when the kernels are (else as it is: the same counts)."""
    from covviz.model import kernels

    if not kernels.JIT_ENABLED:
        return _rule_counts_py
    import numba

    return numba.njit(cache=True, nogil=True)(_rule_counts_py)


def _counts(scores: list[np.ndarray], runs: list[Run], rules: list[Hysteresis]) -> np.ndarray:
    """``(tp, fp, found)`` of each rule's alarms on ``scores``, summed over ``runs`` (one compiled pass per run)."""
    counts = np.zeros((len(rules), 3), dtype=np.int64)
    kernel = _rule_counts()
    ths = np.array([r.threshold for r in rules], dtype=np.float64)
    rels = np.array([r.release for r in rules], dtype=np.float64)
    cooldowns = {r.cooldown for r in rules}
    if len(cooldowns) > 1:
        raise ValueError("the rules must share one cooldown")
    cooldown = cooldowns.pop() if cooldowns else COOLDOWN
    for s, r in zip(scores, runs):
        v = np.asarray(s, dtype=np.float64)
        v = np.where(np.isfinite(v), v, -np.inf)
        w = np.array(loss_windows(r), dtype=np.int64).reshape(-1, 3)
        out = np.zeros((len(rules), 3), dtype=np.int64)
        kernel(v, ths, rels, cooldown, w[:, 0].copy(), w[:, 1].copy(), np.asarray(r.iou, dtype=np.float64),
               OFF_TRACK_IOU, out)
        counts += out
    return counts


def _key_of(counts, runs: list[Run]) -> tuple:
    tp, fp, found = (int(v) for v in counts)
    return _rule_key({"tp": tp, "fp": fp, "found": found, "losses": sum(len(r.losses) for r in runs)})


def choose_rule(probs: list[np.ndarray], runs: list[Run]) -> tuple[Hysteresis, float | None]:
    """The alarm rule and the colour gate (:attr:`~covviz.diagnosis.detector.DriftModel.gate`) of a model, chosen
    together on ``runs``: for no gate and each of :data:`GATE_LEVELS`, the rule :func:`choose_alarm` picks on the
    gated probabilities; the pair whose alarms rank first by the alarm rule's own order (:func:`_rule_key`) wins.

    Ties keep no gate (then the lower level). Where the runs have no colour signal there is no gate. Choosing the
    two together is the rule applied to both: choosing the threshold first, without the gate, sets it where the
    ungated alarms reach the rule's precision, and the precision the gate then adds goes unused (on the default
    tracker's dev runs, the threshold-then-gate choice found 78% of the losses leave-one-sequence-out, the joint
    one 94%; ``docs/tuning.md``).
    """
    rule = choose_alarm(probs, runs)
    col = SIGNALS.index(GATE_SIGNAL)
    if not any(np.isfinite(r.rows[:, col]).any() for r in runs):
        return rule, None
    best, best_key = (rule, None), _key_of(_counts(probs, runs, [rule])[0], runs)
    for g in GATE_LEVELS:
        gated = [gate_probability(p, r.rows[:, col], g) for p, r in zip(probs, runs)]
        rule_g = choose_alarm(gated, runs)
        key = _key_of(_counts(gated, runs, [rule_g])[0], runs)
        if key > best_key:
            best, best_key = (rule_g, g), key
    return best


def choose_alarm(scores: list[np.ndarray], runs: list[Run]) -> Hysteresis:
    """The alarm rule for a score on training runs: thresholds at quantiles of their scores, releases below.

    The rule is the same for the model and for every baseline signal: of the candidates at a training
    precision of at least :data:`MIN_PRECISION`, the one ranked first by :data:`RULE_ORDER` (the most losses
    found less the weighed false alarms, then recall); if no candidate reaches it, the best F1; ties go to
    fewer false alarms. The candidates are scored in one compiled pass per run (:func:`_rule_counts_py`: the
    counts of :func:`score_alarms` on :func:`alarm_frames`, which ``tests/test_drift_detector.py`` checks).
    """
    allv = np.concatenate([s[r.labelled] for s, r in zip(scores, runs)])
    allv = allv[np.isfinite(allv)]
    if not len(allv):
        return Hysteresis(np.inf, np.inf, COOLDOWN)
    rules = []
    for q in THRESHOLD_LEVELS:
        th = float(np.quantile(allv, q))
        for off in RELEASE_OFFSETS:
            rel = float(np.quantile(allv, max(q - off, 0.0)))
            rules.append(Hysteresis(th, min(rel, th), COOLDOWN))
    counts = _counts(scores, runs, rules)
    losses = sum(len(r.losses) for r in runs)
    best, best_key = None, None
    for rule, (tp, fp, found) in zip(rules, counts.tolist()):
        key = _rule_key({"tp": tp, "fp": fp, "found": found, "losses": losses})
        if best_key is None or key > best_key:
            best, best_key = rule, key
    return best


# --------------------------------------------------------------------------- #
# fitting
# --------------------------------------------------------------------------- #
def signals_for(trackers) -> tuple:
    """The signals a model of these trackers reads: all of them for particle filters, else the generic ones."""
    from covviz.trackers import STOCHASTIC

    return SIGNALS if trackers and all(t in STOCHASTIC for t in trackers) else GENERIC_SIGNALS


def candidates(signals, designs=DESIGNS) -> tuple:
    """The candidates :func:`choose_fit` weighs: each model design of ``designs`` on ``signals``, and for the
    ``signal`` design one ``"signal:NAME"`` per signal of :data:`TROUBLE` among ``signals``."""
    out = [d for d in designs if d != "signal"]
    if "signal" in designs:
        out += [_signal_key(s) for s in TROUBLE if s in signals]
    return tuple(out)


def targets_of(key: str, targets) -> tuple:
    """The fit targets :func:`choose_fit` tries for candidate ``key`` among ``targets``: all of them for a
    model; one for a single signal (:data:`SIGNAL_TARGET` if among them), whose alarms are the same for either."""
    if key.startswith("signal"):
        return (SIGNAL_TARGET if SIGNAL_TARGET in targets else targets[0],)
    return tuple(targets)


def split_design(key: str, signals) -> tuple[str, tuple]:
    """A candidate key (:func:`candidates`) as ``(design, signals it reads)``."""
    design, _, name = key.partition(":")
    if design == "signal":
        if name not in TROUBLE:
            raise ValueError(f"the signal design reads one of {', '.join(TROUBLE)}, got {name!r}")
        return design, (name,)
    if design not in DESIGNS or name:
        raise ValueError(f"unknown feature design {key!r}; known: {', '.join(DESIGNS)}")
    return design, tuple(signals)


def _design(runs: list[Run], signals, design: str = "levels") -> list[np.ndarray]:
    design, signals = split_design(design, signals)
    cols = np.array([SIGNALS.index(s) for s in signals])
    return [history_features(r.rows[:, cols], signals, design) for r in runs]


def choose_design(runs: list[Run], family: str, signals, feats: dict[str, list[np.ndarray]] | None = None,
                  target: str = FIT_TARGET) -> tuple[str, dict]:
    """The feature design of the many-signal models (``levels`` or ``changes``) that carries over best to
    unseen sequences, for models fitted to find ``target``: :func:`choose_fit` with those only."""
    design, _, scores = choose_fit(runs, family, signals, feats, (target,), ("levels", "changes"))
    return design, {d: v for (d, _), v in scores.items()}


def choose_fit(runs: list[Run], family: str, signals, feats: dict[str, list[np.ndarray]] | None = None,
               targets=TARGETS, designs=None, held_out: dict | None = None) -> tuple[str, str, dict]:
    """The feature design and the fit target (:data:`TARGETS`) whose models carry over best to unseen sequences.

    ``designs``: the candidate keys (default :func:`candidates` of ``signals``: the two models and each
    single signal; a ``"signal:NAME"`` candidate is fitted on one target only, :func:`targets_of`).

    Leave-one-sequence-out on ``runs`` only: for each of their sequences a model of each design and
    target is fitted, and its alarm rule chosen, on the other sequences' runs, and the sequence's runs
    are scored. The pair whose pooled held-out alarms rank first by the alarm rule's own order
    (:func:`choose_alarm`) wins; ties go to ``changes``, then to :data:`FIT_TARGET`. (Four groups of
    sequences instead of one each chose less steadily: on the paper's likelihood the design flipped
    from fold to fold of the outer evaluation, and its alarms were worse than either design's alone.)
    With a single sequence nothing can be held out, and ``changes`` (the design made to carry over
    between scenes) is used with the first of ``targets``. Returns the design, the target and each
    pair's held-out precision and recall, keyed ``(design, target)``.

    ``held_out``, if given, is filled with each pair's held-out probabilities, keyed ``(design, target)``:
    one array per run of ``runs`` (in their order), from the model fitted without the run's sequence, or
    None where that fold could not be fitted. :func:`fit_model` chooses the chosen pair's alarm rule on them
    (its ``rule_probs``).
    """
    targets = tuple(targets)
    designs = candidates(signals) if designs is None else tuple(designs)
    if len(designs) == 1 and len(targets_of(designs[0], targets)) == 1:  # nothing to choose
        return designs[0], targets_of(designs[0], targets)[0], {}
    fallback = ("changes" if "changes" in designs else designs[0]), targets[0], {}
    seqs = sorted({r.sequence for r in runs})
    if len(seqs) < 2:
        return fallback
    feats = dict(feats or {})
    feats.update({d: _design(runs, signals, d) for d in designs if d not in feats})
    keys, scores = {}, {}
    for d in designs:
        for t in targets_of(d, targets):
            counts, probs = [], [None] * len(runs)
            for q in seqs:
                tr = [i for i, r in enumerate(runs) if r.sequence != q]
                te = [i for i, r in enumerate(runs) if r.sequence == q]
                try:
                    m = fit_model([runs[i] for i in tr], family, signals, [feats[d][i] for i in tr], design=d,
                                  target=t)
                except InputError:
                    continue
                for i in te:
                    probs[i] = m.probability(feats[d][i])
                counts += [score_alarms(alarm_frames(m.gated(probs[i], runs[i].rows), m.alarm), runs[i]) for i in te]
            if held_out is not None:
                held_out[d, t] = probs
            if not counts:
                continue
            c = _pool(counts)
            keys[d, t] = (*_rule_key(c), d == "changes", t == FIT_TARGET)
            p, rc = _pr(c)
            scores[d, t] = {"precision": round(p, 4) if np.isfinite(p) else None,
                            "recall": round(rc, 4) if np.isfinite(rc) else None}
    # The best-ranked pair that can be fitted on all of ``runs`` (a single signal that held up on every
    # 13-sequence subset may still point the wrong way on all of them together: fit_model refuses it).
    for d, t in sorted(keys, key=keys.get, reverse=True):
        try:
            fit_model(runs, family, signals, feats[d], design=d, target=t)
        except InputError:
            continue
        return d, t, scores
    return fallback[:2] + (scores,)


def fit_model(runs: list[Run], family: str, signals=None, feats: list[np.ndarray] | None = None,
              fit_info: dict | None = None, design: str = "levels", target: str = FIT_TARGET,
              rule_probs: list | None = None) -> DriftModel:
    """A logistic drift model fitted on ``runs`` to find ``target`` (:func:`fit_target`), with its alarm
    rule chosen on them too.

    ``design``: a candidate key (:func:`candidates`); ``"signal:NAME"`` fits the ``signal`` design on that
    one signal. ``feats``, if given, are the runs' features of ``design`` (:func:`_design`).

    ``rule_probs``: the runs' held-out probabilities (:func:`choose_fit`'s ``held_out``: each run's from a
    model fitted without its sequence). Given for every run, a model of many signals has its alarm rule
    and gate chosen on them rather than on its own fitted probabilities, which it has seen: on those the
    threshold that reaches the rule's precision sits lower than the one that reaches it on a new
    sequence (cross-fitted thresholds, as scikit-learn's ``TunedThresholdClassifierCV`` does; on the
    default tracker's dev runs, leave one sequence out, ``docs/tuning.md``). A single signal's model keeps
    the rule of its own probabilities: a monotone map of the signal, it has the baseline's rule.

    Raises
    ------
    InputError
        If the runs have nothing to learn from: no loss (``episodes``) or no off-track frame
        (``off_track``), or no frame on track; or, for a single signal, if it is missing on every
        training frame or higher trouble on it does not mean more frames off track there.
    """
    from sklearn import __version__ as skv
    from sklearn.linear_model import LogisticRegression

    signals = tuple(signals or signals_for(sorted({r.tracker for r in runs})))
    feats = feats if feats is not None else _design(runs, signals, design)
    design, signals = split_design(design, signals)
    parts = [fit_target(r, target) for r in runs]
    X = np.concatenate([f[m] for f, (m, _) in zip(feats, parts)])
    y = np.concatenate([lab[m] for m, lab in parts])
    if y.all() or not y.any():
        missing = "no frame on track" if y.all() else (
            "no frame off track (IoU < 0.5)" if target == "off_track"
            else "no loss (no fall below IoU 0.1 after a frame at 0.5 or more)")
        raise InputError(f"the runs have {missing}: nothing to calibrate on; add runs with and without losses")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        center = np.nanmean(X, axis=0)
        scale = np.nanstd(X, axis=0)
    center = np.where(np.isfinite(center), center, 0.0)
    scale = np.where(np.isfinite(scale) & (scale > 1e-9), scale, 1.0)
    Z = (X - center) / scale
    if design == "signal":  # fitted on the frames where the signal is, read as "no evidence" elsewhere
        ok = np.isfinite(Z[:, 0])
        Z, y = Z[ok], y[ok]
        if y.all() or not y.any():
            raise InputError(f"{signals[0]} is missing on every training frame of one class: nothing to fit")
    Z = np.where(np.isfinite(Z), Z, 0.0)
    lr = LogisticRegression(C=C_REG, max_iter=2000)
    lr.fit(Z, y)
    if design == "signal" and not lr.coef_[0][0] * TROUBLE[signals[0]] > 0:
        raise InputError(f"{signals[0]}: more trouble on it does not mean more frames off track on these runs")
    model = DriftModel(family, signals, center, scale, lr.coef_[0].copy(), float(lr.intercept_[0]),
                       Hysteresis(np.inf, np.inf, COOLDOWN), design=design)
    held = design != "signal" and rule_probs is not None and all(p is not None for p in rule_probs)
    probs = list(rule_probs) if held else [model.probability(f) for f in feats]
    rule, gate = choose_rule(probs, runs)
    info = {
        "off_track_iou": OFF_TRACK_IOU,
        "target": target,
        "rule_on": "held-out" if held else "fit",
        "C": C_REG,
        "runs": len(runs),
        "sequences": sorted({r.sequence for r in runs}),
        "trackers": sorted({r.tracker for r in runs}),
        "seeds": sorted({r.seed for r in runs if r.seed is not None}),
        "frames": len(y),
        "positive_frames": int(y.sum()),
        "losses": int(sum(len(r.losses) for r in runs)),
        "sklearn": skv,
        **(fit_info or {}),
    }
    return DriftModel(family, signals, center, scale, model.coef, model.intercept, rule, info, design, gate)


def family_runs(runs: list[Run], family: str) -> list[Run]:
    """The runs a family's model is fitted on (``generic``: every run)."""
    if family == "generic":
        return list(runs)
    return [r for r in runs if family_of(r.tracker) == family]


def fit_design(runs: list[Run], family: str, signals=None, fit_info: dict | None = None,
               target: str | None = None, design: str | None = None) -> DriftModel:
    """A model of the design and fit target :func:`choose_fit` picks on ``runs`` (those given are kept),
    fitted on all of them.

    ``design``: None (every candidate of :func:`candidates`), a design (``"signal"``: the best single
    signal) or one candidate key (``"signal:flow_gap"``).
    """
    signals = tuple(signals or signals_for(sorted({r.tracker for r in runs})))
    designs = candidates(signals, DESIGNS if design is None else (design,))
    if not designs:
        raise InputError(f"no single signal of {', '.join(TROUBLE)} among this family's signals")
    targets = TARGETS if target is None else (target,)
    feats = {d: _design(runs, signals, d) for d in designs}
    probs: dict = {}
    design, target, held_out = choose_fit(runs, family, signals, feats, targets, designs, probs)
    info = {**(fit_info or {}), "design_choice": {"held_out": {_choice_key(d, t): v for (d, t), v in held_out.items()}}}
    return fit_model(runs, family, signals, feats[design], info, design, target,
                     probs.get((design, target)) if RULE_ON_HELD_OUT else None)


def _signal_key(name: str) -> str:
    """The candidate key of the ``signal`` design on one signal (:func:`candidates`, ``--design``)."""
    return f"signal:{name}"


def _choice_key(key: str, target: str) -> str:
    """How a model file's ``fit.design_choice.held_out`` names a candidate (:func:`candidates`) and its target."""
    return f"{key} {target}"


def held_out_score(model: DriftModel) -> tuple[dict | None, int]:
    """The held-out precision and recall of the candidate ``model`` is (its file's design choice, written by
    :func:`fit_design`), or None where the file has none for it; and how many candidates that choice weighed."""
    choice = ((model.fit or {}).get("design_choice") or {}).get("held_out") or {}
    key = _signal_key(model.signals[0]) if model.design == "signal" else model.design
    return choice.get(_choice_key(key, (model.fit or {}).get("target", SIGNAL_TARGET))), len(choice)


def fit_families(runs: list[Run], fit_info: dict | None = None, design: str | None = None,
                 target: str | None = None) -> dict[str, DriftModel]:
    """One model per family present in ``runs``, plus the generic fallback (generic signals, every run).

    Each family's feature design and fit target are ``design`` and ``target``, or (None) chosen on its
    own runs (:func:`choose_fit`).
    """
    out = {}
    for fam in [*FAMILIES, "generic"]:
        rs = family_runs(runs, fam)
        if rs:
            sig = GENERIC_SIGNALS if fam == "generic" else None
            out[fam] = fit_design(rs, fam, sig, fit_info, target, design)
    return out


# --------------------------------------------------------------------------- #
# leave-one-sequence-out evaluation
# --------------------------------------------------------------------------- #
def loso(runs: list[Run], tracker: str, family: str | None = None, target: str | None = None) -> dict:
    """Leave-one-sequence-out scores of ``tracker``: the model of its family and each baseline.

    For each sequence, the model's feature design and (``target`` None) its fit target are chosen
    (:func:`choose_fit`, nested inside the fold), the model fitted and its alarm rule and gate chosen, on the
    family's runs of the other sequences only, and so is each baseline's threshold; the held-out
    sequence's runs of ``tracker`` are then scored. Returns, per method (``model`` and each of
    :data:`BASELINES`), the held-out scores and alarm counts of every run, keyed by sequence, and under
    ``"designs"`` and ``"targets"`` what each fold chose.
    """
    family = family or family_of(tracker)
    pool = family_runs(runs, family)
    signals = signals_for(sorted({r.tracker for r in pool}))
    feats = {d: dict(zip(map(id, pool), _design(pool, signals, d))) for d in candidates(signals)}
    seqs = sorted({r.sequence for r in pool if r.tracker == tracker})
    out: dict = {"model": {}, **{b: {} for b in BASELINES}, "designs": {}, "targets": {}}
    for q in seqs:
        train = [r for r in pool if r.sequence != q]
        test = [r for r in pool if r.sequence == q and r.tracker == tracker]
        if not train or not test:
            continue
        probs: dict = {}
        design, tgt, _ = choose_fit(train, family, signals, {d: [feats[d][id(r)] for r in train] for d in feats},
                                    TARGETS if target is None else (target,), held_out=probs)
        try:
            m = fit_model(train, family, signals, [feats[design][id(r)] for r in train], design=design, target=tgt,
                          rule_probs=probs.get((design, tgt)) if RULE_ON_HELD_OUT else None)
        except InputError as exc:  # no candidate fits the training runs: the fold is reported, not scored
            out.setdefault("skipped", {})[q] = str(exc)
            continue
        out["designs"][q] = design
        out["targets"][q] = tgt
        out["model"][q] = held_out_model(m, [feats[design][id(r)] for r in test], test)
        for name in BASELINES:
            scored = held_out_signal(name, train, test)
            if scored is not None:
                out[name][q] = scored
    return out


def held_out_model(model: DriftModel, feats: list[np.ndarray], test: list[Run]) -> list:
    """``(probability, alarm counts, run)`` of each held-out run, from its features ``feats`` of the model's design."""
    return [(p, score_alarms(alarm_frames(p, model.alarm), r), r) for f, r in zip(feats, test)
            for p in [model.gated(model.probability(f), r.rows)]]


def held_out_signal(name: str, train: list[Run], test: list[Run]) -> list | None:
    """``(score, alarm counts, run)`` of each held-out run for the baseline signal ``name`` (:data:`BASELINES`),
    its alarm rule chosen on ``train``; None if no training run has the signal."""
    sig, sign = BASELINES[name]
    k = SIGNALS.index(sig)
    if not np.isfinite(np.concatenate([r.rows[:, k] for r in train])).any():
        return None
    rule = choose_alarm([sign * r.rows[:, k] for r in train], train)
    return [(sign * r.rows[:, k], score_alarms(alarm_frames(sign * r.rows[:, k], rule), r), r) for r in test]


def summarise(per_seq: dict, rng: np.random.Generator, n_boot: int = 1000) -> dict:
    """Pooled scores of held-out runs (``{sequence: [(scores, counts, run), ...]}``) with bootstrap intervals.

    Bootstrap: sequences drawn with replacement (all runs of a drawn sequence together), 95% percentile
    intervals of event precision and recall.
    """
    from sklearn.metrics import average_precision_score

    rng = np.random.default_rng(rng)
    if not per_seq:
        return {}
    items = [x for v in per_seq.values() for x in v]
    s = np.concatenate([sc[r.labelled] for sc, _, r in items])
    y = np.concatenate([r.off[r.labelled] for _, _, r in items])
    s = np.where(np.isfinite(s), s, -1e300)
    auc = float(average_precision_score(y, s)) if y.any() and not y.all() else float("nan")
    c = _pool([cnt for _, cnt, _ in items])
    p, r = _pr(c)
    seqs = list(per_seq)
    per = {q: _pool([cnt for _, cnt, _ in per_seq[q]]) for q in seqs}
    bp, br = [], []
    for _ in range(n_boot):
        draw = rng.integers(0, len(seqs), len(seqs))
        cb = _pool([per[seqs[i]] for i in draw])
        pb, rb = _pr(cb)
        if np.isfinite(pb):
            bp.append(pb)
        if np.isfinite(rb):
            br.append(rb)

    def ci(v):
        return (float(np.quantile(v, 0.025)), float(np.quantile(v, 0.975))) if v else (float("nan"),) * 2

    return {
        "pr_auc": auc,
        "base_rate": float(y.mean()) if len(y) else float("nan"),
        "precision": p,
        "precision_ci": ci(bp),
        "recall": r,
        "recall_ci": ci(br),
        "lead": float(np.median(c["leads"])) if c["leads"] else float("nan"),
        "false_per_1000": 1000 * c["fp"] / c["on_track"] if c["on_track"] else float("nan"),
        **c,
        "runs": len(items),
        "sequences": len(seqs),
    }
