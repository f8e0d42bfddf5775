"""``covviz calibrate``: fit the drift-probability model on labelled bench runs (and ``--detector FILE``)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from covviz.cli.common import UsageError

CALIBRATE_EPILOG = """\
examples:
  covviz bench ../shared/sequences --trackers manifold --seeds 3 --out runs/bench
  covviz calibrate runs/bench --out my-detector.json            # one model on every run there
  covviz calibrate runs/bench --trackers csrt,kcf --out cv.json   # only these trackers' runs
  covviz calibrate runs/bench --seeds 0-5 --all-families covviz/diagnosis/models   # the shipped models
  covviz calibrate runs/bench --trackers manifold --design signal:slip --out slip.json   # one fixed design
  covviz track clip.mp4 --box 120,80,40,60 --detector my-detector.json

The runs need ground truth and the per-frame signals that covviz bench saves
(diagnosis.signals); no tracker is re-run. The model learns the drift episodes: each
loss's frames (a loss: IoU below 0.1 after a frame at 0.5 or more) from 10 before its
drift began to 5 after it, against the frames on track (IoU >= 0.5), frames long lost
left out; or every frame below 0.5 (the first design). --target auto picks the one
whose alarms hold up best on sequences held out in turn, with the design.
It is a logistic regression on the signals, in one of three feature designs:
their levels and short history; their changes (each signal's robust z-score against
its own last 30 frames, which carries over between scenes); or one signal alone
(the flow gap, the slip, the FB error, PSR, ESS, the distance z-score or the colour: its
own threshold alarm, with a calibrated probability). --design auto picks the candidate
whose alarms hold up best on sequences held out in turn; the alarm threshold and
hysteresis are chosen on the same runs together with the colour gate (no alarm while the
box stands out from its surroundings as the target did): for no gate and each gate level,
of the thresholds whose alarms reach 50% precision, the one whose losses found less its false
alarms are the most (one more loss is worth at most one more false alarm); a gate is kept if
its alarms rank higher by the same order (see covviz/diagnosis/calibrate.py).
"""


_TROUBLE = ("flow_gap", "slip", "fb_error", "psr", "ess", "dmin_z", "colour")  # calibrate.TROUBLE, without importing scikit-learn's caller


def add_detector_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--detector", type=Path, metavar="FILE",
                   help="drift model from 'covviz calibrate' (default: the model shipped for each tracker's family)")


def detector_text(path: Path | None) -> str | None:
    """``--detector FILE``: the model's JSON text, checked (None without the option)."""
    if path is None:
        return None
    from covviz.diagnosis.detector import DriftModel

    return json.dumps(DriftModel.load(path).as_dict())


def _seeds(text: str) -> set[int]:
    from covviz.diagnosis.calibrate import parse_seeds

    try:
        return parse_seeds(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seeds like 0,1,2 or 0-2, got {text!r}") from None


def add_calibrate_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "calibrate",
        help="fit the drift-probability model on labelled bench runs",
        description="Fit the label-free drift detector (a logistic model on the per-frame signals) on the "
        "labelled runs of a 'covviz bench' folder and write it as a JSON file for --detector.",
        epilog=CALIBRATE_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("bench_dir", type=Path, metavar="BENCH_DIR", help="a 'covviz bench --out' folder")
    p.add_argument("--out", type=Path, metavar="FILE", help="the model file to write")
    p.add_argument("--all-families", type=Path, metavar="DIR",
                   help="instead: one model per tracker family found (DIR/FAMILY.json) plus DIR/generic.json")
    p.add_argument("--trackers", metavar="NAME[,NAME…]", help="only these trackers' runs (default: all)")
    p.add_argument("--seeds", type=_seeds, metavar="LIST", help="only these seeds of stochastic trackers, e.g. 0-2")
    p.add_argument("--design", choices=("auto", "levels", "changes", "signal", *(f"signal:{s}" for s in _TROUBLE)),
                   default="auto", metavar="DESIGN",
                   help="feature design: levels, changes, signal (the best single signal) or signal:NAME "
                        f"({', '.join(_TROUBLE)}); default auto: chosen by cross-validation over the runs' "
                        "sequences, among the two models and each single signal")
    p.add_argument("--target", choices=("auto", "episodes", "off-track"), default="auto",
                   help="what the model learns to find: the drift episodes, each loss's frames from 10 before its "
                        "drift began to 5 after it, against the frames on track (what an alarm is scored on), or "
                        "every frame off track (IoU < 0.5; long-lost frames included); default auto: chosen with "
                        "the design, by cross-validation over the runs' sequences")
    p.set_defaults(func=cmd_calibrate)
    return p


def cmd_calibrate(args) -> int:
    from covviz.diagnosis.calibrate import fit_design, fit_families, load_runs
    from covviz.diagnosis.detector import family_of

    if (args.out is None) == (args.all_families is None):
        raise UsageError("give --out FILE (one model) or --all-families DIR (one per family), not both or neither")
    trackers = None if args.trackers is None else set(args.trackers.split(","))
    runs = load_runs(args.bench_dir, trackers, args.seeds)
    _warn_without_colour(runs, args.bench_dir)
    info = {"id": f"{args.bench_dir.name}"}
    design = None if args.design == "auto" else args.design
    target = None if args.target == "auto" else args.target.replace("-", "_")
    if args.all_families is not None:
        for fam, m in fit_families(runs, info, design, target).items():
            path = m.save(args.all_families / f"{fam}.json")
            print(f"{fam}: {_describe(m)} -> {path}")
            print(f"  {_held_out(m)}")
        return 0
    fams = {family_of(r.tracker) for r in runs}
    fam = fams.pop() if len(fams) == 1 else "generic"
    m = fit_design(runs, fam, fit_info=info, target=target, design=design)
    print(f"{m.family}: {_describe(m)} -> {m.save(args.out)}")
    print(f"  {_held_out(m)}")
    return 0


def _warn_without_colour(runs, bench_dir) -> None:
    """Runs made before the ``colour`` signal existed can fit no colour gate: say so, and how to add it."""
    import logging

    import numpy as np

    from covviz.diagnosis.signals import SIGNALS

    k = SIGNALS.index("colour")
    n = sum(not np.isfinite(r.rows[:, k]).any() for r in runs)
    if n:
        logging.getLogger("covviz").warning(
            "%d of %d runs have no colour signal (made before it existed): no colour gate is fitted on them; "
            "'python scripts/backfill_colour.py %s' adds it from their saved boxes", n, len(runs), bench_dir)


def _describe(m) -> str:
    f = m.fit
    found = "in drift episodes" if f.get("target", "off_track") == "episodes" else "off track"
    design = f"{m.design} design ({m.signals[0]})" if m.design == "signal" else f"{m.design} design"
    return (f"{design}, {f['runs']} runs, {f['frames']} frames ({f['positive_frames']} {found}), "
            f"{f['losses']} losses; "
            f"alarm at p >= {_level(m.alarm.threshold)}, released below {_level(m.alarm.release)}"
            + ("" if m.gate is None else f", silenced while colour < {m.gate:g}"))


def _held_out(m) -> str:
    """How the fitted model's candidate did on sequences it had not seen, from its file's design choice
    (:func:`covviz.diagnosis.calibrate.choose_fit`: each of the runs' sequences held out in turn), for the user
    to know how far to trust it before using it."""
    from covviz.diagnosis.calibrate import held_out_score

    got, candidates = held_out_score(m)
    if not got or got.get("precision") is None or got.get("recall") is None:
        return ("no held-out estimate (one candidate, or a single sequence): score it on other labelled runs "
                "before trusting its alarms")
    n = len(m.fit.get("sequences") or ())
    return (f"held out (each of the {n} sequences left out in turn): its alarms found {100 * got['recall']:.0f}% "
            f"of the losses at {100 * got['precision']:.0f}% precision; the best of {candidates} candidates "
            "there, so read it as an upper estimate for a new video")


def _level(p: float) -> str:
    """A probability level to 3 decimals, or as many more as it takes not to read as 0 or 1 when it is neither
    (a saturated model's threshold of 0.99971 is not "p >= 1.000")."""
    s = f"{p:.3f}"
    for d in range(4, 10):
        if not 0.0 < p < 1.0 or 0.0 < float(s) < 1.0:
            break
        s = f"{p:.{d}f}"
    return s
