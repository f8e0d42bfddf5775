"""``covviz tune``: an Optuna study over the manifold tracker's config, checked on held-out seeds."""

from __future__ import annotations

import argparse
from pathlib import Path

from covviz.cli.bench import add_cluster_args
from covviz.cli.common import nonneg_int, positive_int, read_config

TUNE_EPILOG = """\
examples:
  covviz tune ../shared/sequences --trials 30 --seeds 2 --max-frames 200 --cluster local:2
  covviz tune ROOT --trials 60 --storage sqlite:///study.db --study sigma   # in two terminals: one study
  covviz tune ROOT --trials 60 --storage postgresql://user@db/optuna --cluster tcp://sched:8786
  covviz tune ROOT --trials 0 --out runs/tune       # only rebuild the report of the study

A trial runs one ManifoldConfig (the search space is SEARCH_SPACE in covviz/trackers/manifold.py)
on every sequence x tuning seed; its score is the mean success AUC. The first trial of a new study
is the base config (the defaults, or --config). At the end the best config and the base run again
on held-out seeds; OUT/tune_report.md sets both gains side by side, OUT/best.json is ready for
'covviz track SEQ --config OUT/best.json'. --trials counts the study's finished trials, whichever
process ran them. Needs pip install 'covviz[cluster]'.
"""

def add_tune_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "tune",
        help="an Optuna study over the manifold tracker's config (needs the 'cluster' extra)",
        description="Search ManifoldConfig's parameters for the best mean success AUC over the sequences "
        "under ROOT and the tuning seeds, pruning hopeless trials after the first sequences; then check the "
        "best on held-out seeds and write a report with the best config, parameter importances and plots.",
        epilog=TUNE_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("root", type=Path, help="a sequence folder (OTB or VOT layout) or a folder of them")
    p.add_argument("--trials", type=nonneg_int, required=True, metavar="N",
                   help="finished trials the study should hold (0: only the report)")
    p.add_argument("--storage", metavar="URL",
                   help="Optuna storage shared by cooperating processes: sqlite:///FILE.db on one machine, any "
                   "RDB URL across machines (default: sqlite:///OUT/study.db)")
    p.add_argument("--study", default="covviz-tune", metavar="NAME", help="study name (default covviz-tune)")
    p.add_argument("--tracker", choices=("manifold", "manifold-paper"), default="manifold",
                   help="tracker whose config is searched (default manifold)")
    p.add_argument("--seeds", type=positive_int, default=2, metavar="K", help="tuning seeds 0..K-1 (default 2)")
    p.add_argument("--holdout-seeds", type=nonneg_int, metavar="H",
                   help="held-out seeds K..K+H-1 for the final check (default: as many as --seeds; 0: none)")
    p.add_argument("--max-frames", type=positive_int, metavar="N", help="run only the first N frames of each sequence")
    p.add_argument("--particles", type=positive_int, help="particles (default: the config's)")
    p.add_argument("--config", metavar="FILE.json|JSON",
                   help="base ManifoldConfig (a JSON object of its fields, in a file or inline): the first trial, "
                   "and the values of the fields not searched")
    p.add_argument("--jobs", type=positive_int, default=1, metavar="J",
                   help="jobs at a time on this machine (default 1), each in a fresh process")
    add_cluster_args(p)
    p.add_argument("--out", type=Path, default=Path("runs/tune"),
                   help="folder of the report, best.json and figures (default runs/tune)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_tune)
    return p

def cmd_tune(args) -> int:
    from covviz.experiments.tune import print_summary, tune

    base = read_config(args.config, [args.tracker])
    summary = tune(
        args.root,
        args.trials,
        out=args.out,
        storage=args.storage,
        study_name=args.study,
        seeds=args.seeds,
        holdout_seeds=args.holdout_seeds,
        max_frames=args.max_frames,
        particles=args.particles,
        tracker=args.tracker,
        base=None if base is None else base.as_dict(),
        jobs=args.jobs,
        cluster=args.cluster,
        retries=args.retries,
        progress=not args.no_progress,
    )
    print_summary(summary)
    return 0
