"""Evaluation of the label-free drift detector (issue 21): the tables of docs/results.md's drift section.

Reads a ``covviz bench`` folder whose runs carry ``diagnosis.signals`` and ``frame_iou`` (no tracker is
re-run for the leave-one-sequence-out part), then:

1. leave-one-sequence-out, per tracker: the family's model fitted and its alarm rule chosen on the other
   sequences, each single-signal baseline's threshold chosen there by the same rule
   (:mod:`covviz.diagnosis.calibrate`), scored on the held-out sequence;
2. the shipped models (``covviz calibrate``; the seeds each was fitted on are in its file) on the folder's
   runs of the other seeds;
3. the shipped default model's alarms on the synthetic default, seeds 0-9 (runs the tracker).

Usage::

    python scripts/drift_eval.py /tmp/b21/dev --write docs/results.md
    python scripts/drift_eval.py runs/bench-drift --loso-seeds 0-5 --jobs 2 --write docs/results.md   # seeds 6-8 check the shipped models
    python scripts/drift_eval.py /tmp/b21/dev --target episodes --no-compare --no-synthetic   # one target, every fold

The section between ``<!-- drift-eval:begin -->`` and ``<!-- drift-eval:end -->`` is replaced (appended
the first time). Prints it too.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

TRACKERS = ("manifold", "manifold-paper", "ipca", "csrt", "kcf", "mil")
BEGIN, END = "<!-- drift-eval:begin -->", "<!-- drift-eval:end -->"


def _pct(v: float) -> str:
    return "—" if not np.isfinite(v) else f"{100 * v:.0f}%"


def _ci(c) -> str:
    return "" if not all(np.isfinite(c)) else f" [{100 * c[0]:.0f}–{100 * c[1]:.0f}]"


def _num(v: float, d: int = 2) -> str:
    return "—" if not np.isfinite(v) else f"{v:.{d}f}"


_RUNS: list = []  # a worker's runs (set once per process by _init_worker)


def _init_worker(runs) -> None:
    global _RUNS
    _RUNS = runs


def _loso_job(job):
    """One tracker's leave-one-sequence-out (:func:`covviz.diagnosis.calibrate.loso`), on one thread."""
    from covviz.diagnosis.calibrate import loso
    from covviz.threads import limit_threads

    tr, target = job
    t0 = time.perf_counter()
    with limit_threads(1):
        res = loso(_RUNS, tr, target=target)
    return res, time.perf_counter() - t0


def loso_all(runs, jobs: int = 1, targets=(None,)) -> dict:
    """:func:`covviz.diagnosis.calibrate.loso` of every tracker of :data:`TRACKERS` in ``runs``, once per fit
    target of ``targets`` (None: chosen in each fold), keyed ``(tracker, target)``; ``jobs`` processes at a time.

    The folds are deterministic and use no random numbers (the bootstrap comes after, in
    :func:`loso_tables`, in a fixed order), so the tables are the same for any ``jobs``.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from contextlib import nullcontext

    todo = [(tr, t) for t in dict.fromkeys(targets) for tr in TRACKERS if any(r.tracker == tr for r in runs)]
    if jobs <= 1:
        _init_worker(runs)
    out = {}
    with (nullcontext() if jobs <= 1 else
          ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_init_worker,
                              initargs=(runs,))) as pool:
        if pool is None:
            done = map(_loso_job, todo)
        else:  # all submitted at once (TRACKERS lists the slowest first), reported in order as they finish
            futs = [pool.submit(_loso_job, j) for j in todo]
            done = (f.result() for f in futs)
        for job, (res, dt) in zip(todo, done):
            out[job] = res
            print(f"  {job[0]}{'' if job[1] is None else ' (' + job[1] + ')'}: {dt:.1f} s", file=sys.stderr)
    return out


def loso_tables(runs, rng, target: str | None = None, results: dict | None = None) -> list[str]:
    """The main and the single-signal tables; ``results``: :func:`loso_all`'s, else computed here."""
    from covviz.diagnosis.calibrate import BASELINES, summarise

    main = [
        ("| tracker | runs | losses | PR-AUC (off-track share) | alarms | precision [95% CI] | recall [95% CI] "
        "| median lead (frames) | false alarms / 1000 on-track | "
        + ("design, fit target (folds) |" if target is None else "design (folds) |")),
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    base = [
        "| tracker | method | PR-AUC | alarms | precision | recall | median lead | false / 1000 |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    found: dict = {}
    results = results or loso_all(runs, 1, (target,))
    for tr in TRACKERS:
        if not any(r.tracker == tr for r in runs):
            continue
        res = results[tr, target]
        s = summarise(res["model"], rng)
        if not s:
            continue
        found[tr] = {"model": s}
        fp = {q: sum(c["fp"] for _, c, _ in v) for q, v in res["model"].items()}
        found[tr]["_fp_by_sequence"] = dict(sorted(fp.items(), key=lambda kv: -kv[1]))
        ds = [f"{d}, {res['targets'][q].replace('_', '-')}" if target is None else d
              for q, d in res.get("designs", {}).items()]
        # most chosen first, ties in the order of the folds (a set's order changes from process to process)
        design = "; ".join(f"{d} {ds.count(d)}" for d in sorted(dict.fromkeys(ds), key=lambda d: -ds.count(d)))
        if res.get("skipped"):  # folds where no candidate could be fitted: said, not silently dropped
            design += "; not scored (no model fits its training runs): " + ", ".join(sorted(res["skipped"]))
        main.append(
            f"| `{tr}` | {s['runs']} | {s['losses']} | {_num(s['pr_auc'])} ({_pct(s['base_rate'])}) | {s['alarms']} "
            f"| {_pct(s['precision'])}{_ci(s['precision_ci'])} | {_pct(s['recall'])}{_ci(s['recall_ci'])} "
            f"| {_num(s['lead'], 0)} | {_num(s['false_per_1000'], 1)} | {design} |"
        )
        for name in ["model", *BASELINES]:
            b = summarise(res[name], rng) if res.get(name) else {}
            found[tr][name] = b
            label = "**drift probability**" if name == "model" else name
            if not b:
                base.append(f"| `{tr}` | {label} | — | — | — | — | — | — |")
                continue
            base.append(
                f"| `{tr}` | {label} | {_num(b['pr_auc'])} | {b['alarms']} | {_pct(b['precision'])} "
                f"| {_pct(b['recall'])} | {_num(b['lead'], 0)} | {_num(b['false_per_1000'], 1)} |"
            )
    return main, base, found


def goals(found: dict) -> list[str]:
    """The issue's goals against the leave-one-sequence-out numbers, in words (computed, not typed in)."""
    from covviz.diagnosis.calibrate import BASELINES

    out = []
    m = found.get("manifold", {})
    if m:
        s = m["model"]
        ok = s["recall"] >= 0.7 and s["precision"] >= 0.5
        ahead = [n for n, b in m.items() if n in BASELINES and b
                 and (b["precision"] >= s["precision"] or b["recall"] >= s["recall"])]
        out.append(
            f"- Default tracker (`manifold`): recall {_pct(s['recall'])} at precision {_pct(s['precision'])} — the "
            f"goal (recall ≥ 70% at precision ≥ 50%) is **{'met' if ok else 'not met'}**"
            + (f"; a single signal matches or beats it on precision or recall: {', '.join(ahead)}" if ahead
               else "; ahead of every single signal on both") + ".")
        fp = m["_fp_by_sequence"]
        top = [f"{q} {n}" for q, n in list(fp.items())[:4] if n]
        out.append(f"  Its {sum(fp.values())} false alarms by held-out sequence: {', '.join(top)}, the other "
                   f"{len(fp) - len(top)} sequences {sum(list(fp.values())[len(top):])}.")
    c = found.get("csrt", {}).get("model")
    if c:
        out.append(f"- CSRT: alarms find {c['found']} of its {c['losses']} losses ({_pct(c['recall'])}; goal: at "
                   f"least half) — **{'met' if c['recall'] >= 0.5 else 'not met'}**.")
    return out


def _span(seeds) -> str:
    """``[0, 1, 2, 5]`` as ``0–2, 5``."""
    from covviz.diagnosis.calibrate import seed_list

    return seed_list(seeds, dash="–")


def model_scores(m, runs) -> tuple[list, dict, float, float, float]:
    """A drift model on labelled runs: its probabilities per run, the pooled alarm counts, precision, recall and
    false alarms per 1000 on-track frames."""
    from covviz.diagnosis.calibrate import _pool, _pr, alarm_frames, score_alarms

    ps = [m.predict_run(r.rows) for r in runs]
    c = _pool([score_alarms(alarm_frames(p, m.alarm), r) for p, r in zip(ps, runs)])
    pr, rc = _pr(c)
    fa = 1000 * c["fp"] / c["on_track"] if c["on_track"] else float("nan")
    return ps, c, pr, rc, fa


def shipped_table(runs) -> tuple[list[str], list, list]:
    """The shipped models on the runs of seeds each was not fitted on (its file says which it was): the
    table, the seeds they were fitted on, and the seeds they are scored on."""
    from covviz.diagnosis.detector import shipped_model

    L = [
        ("| tracker | model | fitted on seeds | runs | losses | PR-AUC | alarms | precision | recall | median lead "
        "| false / 1000 |"),
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    from sklearn.metrics import average_precision_score

    fitted, scored = set(), set()
    for tr in TRACKERS:
        m = shipped_model(tr)
        if m is None:
            continue
        own = set((m.fit or {}).get("seeds") or [])
        test = [r for r in runs if r.tracker == tr and r.seed is not None and r.seed not in own]
        if not test:
            continue
        fitted |= own
        scored |= {r.seed for r in test}
        ps, c, pr, rc, fa = model_scores(m, test)
        y = np.concatenate([r.off[r.labelled] for r in test])
        s = np.concatenate([p[r.labelled] for p, r in zip(ps, test)])
        auc = average_precision_score(y, s) if y.any() and not y.all() else float("nan")
        lead = float(np.median(c["leads"])) if c["leads"] else float("nan")
        L.append(f"| `{tr}` | {m.family} | {_span(own)} | {len(test)} (seeds {_span({r.seed for r in test})}) "
                 f"| {c['losses']} | {_num(auc)} | {c['alarms']} | {_pct(pr)} "
                 f"| {_pct(rc)} | {_num(lead, 0)} | {_num(fa, 1)} |")
    return L, sorted(fitted), sorted(scored)


def synthetic_alarms(seeds=range(10), frames: int = 300, detector=None, tracker: str = "manifold"
                     ) -> tuple[list[str], int]:
    """The alarms of ``detector`` (default: the shipped model) on ``tracker``'s runs of the synthetic default,
    which has no failure: a line per seed and their total."""
    from covviz.data.sequences import open_sequence
    from covviz.diagnosis.detector import DriftWatch
    from covviz.metrics import iou
    from covviz.runner import run
    from covviz.trackers import make_tracker

    seq = open_sequence(None)
    total, lines = 0, []
    for s in seeds:
        w = DriftWatch(detector=detector)
        res = run(make_tracker(tracker, seed=s), seq, [w], max_frames=frames, seed=s)
        rep = w.report(0)
        off = int(np.sum(iou(res.boxes, res.groundtruth)[1:] < 0.5))
        total += len(rep["alarms"])
        lines.append(f"seed {s}: {len(rep['alarms'])} alarm(s) {[a['frame'] for a in rep['alarms']]}, "
                     f"{off} frames off track, max p {max(rep['drift_probability']):.2f}")
    return lines, total


def _seeds(text: str) -> set:
    from covviz.diagnosis.calibrate import parse_seeds

    try:
        return parse_seeds(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seeds like 0,1,2 or 0-2, got {text!r}") from None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bench_dir", type=Path)
    ap.add_argument("--write", type=Path, help="the markdown file whose drift section to replace")
    ap.add_argument("--no-synthetic", action="store_true")
    ap.add_argument("--seed", type=int, default=0, help="bootstrap seed (default 0)")
    ap.add_argument("--target", choices=("episodes", "off_track"),
                    help="fit every fold's model to find this, instead of choosing it inside each fold")
    ap.add_argument("--no-compare", action="store_true",
                    help="skip the comparison with models fitted on every off-track frame (halves the time)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="trackers' leave-one-sequence-out runs at a time, each in a process of its own (default 1); "
                         "the tables are the same for any value")
    ap.add_argument("--loso-seeds", default="0-5", type=_seeds,
                    help="the particle filters' seeds of the leave-one-sequence-out tables (default 0-5); the "
                         "shipped models are scored on every seed of the folder they were not fitted on")
    args = ap.parse_args(argv)
    if args.write and args.write.exists():
        doc = args.write.read_text()
        if (BEGIN in doc) != (END in doc):
            # A lone marker (a section cut by hand) would leave a stray one or append a second section.
            ap.error(f"{args.write} has one of {BEGIN} / {END} without the other: fix it before a 10-minute run")

    from covviz.diagnosis.calibrate import load_runs

    every = load_runs(args.bench_dir)
    runs = [r for r in every if r.seed is None or r.seed in args.loso_seeds]
    ship_t, ship_fit, ship_test = shipped_table(every)
    rng = np.random.default_rng(args.seed)
    seeds = sorted({r.seed for r in runs if r.seed is not None})
    results = loso_all(runs, args.jobs, (args.target,) if args.no_compare else (args.target, "off_track"))
    main_t, base_t, found = loso_tables(runs, rng, target=args.target, results=results)
    compare = []
    if not args.no_compare:
        old_t, _, _ = loso_tables(runs, np.random.default_rng(args.seed), target="off_track", results=results)
        compare = [
            ("**What the model is fitted to find.** Each fold above chose, with the design, between the drift "
             "episodes — each loss's frames from 10 before its drift began to 5 after it (where an alarm is "
             "right) against the frames on track, the frames long lost left out — and every off-track frame "
             "(IoU < 0.5, the first design: four fifths of those frames are a box long lost on the "
             "background); the last column says which. With every fold fitted on every off-track frame, the "
             "same leave-one-sequence-out evaluation gives:"),
            "",
            *old_t,
            "",
        ]
    out = [
        BEGIN,
        "## Drift without ground truth: the label-free detector (issue 21)",
        "",
        ("Written by `python scripts/drift_eval.py BENCH_DIR --write docs/results.md` (the bench command is in "
        "`docs/tuning.md`). Every tracker carries per-frame label-free signals (`covviz/diagnosis/signals.py`); a "
        "logistic model per tracker family turns them into a drift probability, and an alarm is raised when it "
        "crosses a threshold (once per episode, hysteresis). The model reads the signals in one of three feature "
        "designs (`covviz/diagnosis/detector.py`): *levels* (each signal, its mean over the last 5 frames, its "
        "max over the last 10, some over their early-run median), *changes* (each signal's robust z-score "
        "against its own frames t−35…t−6) or *signal* (one signal of the baselines below alone, through a "
        "monotone logistic map, so its alarms are that signal's own; `signal:NAME` in the last column). Strictly **leave-one-sequence-out**: for each of the 14 dev sequences "
        "the design is chosen (leave-one-sequence-out over the 13 training sequences, by the alarm rule's "
        "own order) with what the model is fitted to find (the drift episodes or every off-track frame, below), the "
        "model fitted, and its threshold and hysteresis chosen together with its colour gate (no alarm while "
        "the box's `colour` signal says it still stands out from its surroundings as the target did; or none: "
        "the pair whose training alarms rank first by the rule below), on the other 13 only; a model of many "
        "signals has its rule chosen on the 13 sequences' held-out probabilities (each from the fold of the "
        "design choice that left it out), not on the ones it was fitted on; the last column says what "
        "the 14 folds chose. Each single signal used as a baseline gets its own threshold on the same training "
        "sequences by the same rule (of the thresholds at a training precision ≥ 50%, the one whose losses "
        "found less its false alarms are the most, else the best F1). "
        f"Runs: seeds {', '.join(map(str, seeds))} of the particle filters, one run of each OpenCV tracker "
        "(deterministic); the OpenCV family's model is fitted on csrt, kcf and mil together."),
        "",
        ("A loss is an IoU below 0.1 after a frame at 0.5 or more; an alarm is right from 10 frames before the "
        "drift began to 5 after the loss; alarms while the tracker is still off track (IoU < 0.5) outside those "
        "windows count neither way; every other alarm is false. PR-AUC: average precision of the per-frame "
        "probability for off-track frames (IoU < 0.5), with the off-track share (a random score's PR-AUC) beside "
        "it. Intervals: 95% bootstrap over sequences (1000 draws). Lead: frames from the first alarm in a "
        "loss's window to the loss (negative: after it)."),
        "",
        *main_t,
        "",
        *goals(found),
        "",
        *compare,
        ("**Each single signal alone** (the same runs, the same folds and rule; `—`: the tracker has no such "
        "signal):"),
        "",
        *base_t,
        "",
        (f"**The shipped models** (`covviz/diagnosis/models/*.json`, fitted on seeds {_span(ship_fit)} of all 14 "
        f"sequences by `covviz calibrate`, design and threshold chosen there) on the runs of seeds "
        f"{_span(ship_test)}, never used to fit or choose them — new runs of the same sequences, so this checks "
        "seed variation, not new scenes (the leave-one-sequence-out table is the honest one):"),
        "",
        *ship_t,
        "",
    ]
    if not args.no_synthetic:
        lines, total = synthetic_alarms()
        out += [
            (f"**False alarms on the synthetic default** (no failure; `manifold`, shipped model, seeds 0–9, "
            f"300 frames each): **{total}** alarm(s) in 3000 frames (goal: at most 3)."),
            "",
            *[f"- {x}" for x in lines],
            "",
        ]
    out.append(END)
    text = "\n".join(out) + "\n"
    print(text)
    if args.write:
        doc = args.write.read_text() if args.write.exists() else ""
        if BEGIN in doc:
            doc = doc[: doc.index(BEGIN)] + text + doc[doc.index(END) + len(END) + 1:]
        else:
            doc = doc.rstrip("\n") + "\n\n" + text
        args.write.write_text(doc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
