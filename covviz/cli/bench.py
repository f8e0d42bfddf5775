"""``covviz bench``: every tracker on every sequence under a folder, resumable, then a report."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from covviz.cli.calibrate import add_detector_arg, detector_text
from covviz.cli.common import add_config_arg, nonneg_int, positive_int, read_config

BENCH_EPILOG = """\
examples:
  covviz bench ../shared/sequences --trackers csrt,kcf,mil --out runs/peers
  covviz bench ../shared/sequences --trackers manifold,ipca,csrt,kcf,mil --seeds 3 --jobs 2 --out runs/bench
  covviz bench ../shared/sequences/Car4 --trackers manifold --seeds 5 --max-frames 200 --out runs/car4
  covviz bench ../shared/sequences --trackers manifold --config runs/tune/best.json --out runs/tuned
  covviz bench ../shared/sequences --trackers manifold,manifold@runs/tune/best.json --out runs/ab   # manifold@best
  covviz bench /data/sequences --cluster tcp://scheduler:8786 --out runs/bench   # on a Dask cluster
  covviz bench ../shared/sequences --cluster local:2 --out runs/bench          # a local Dask cluster
  covviz report runs/bench --out docs/results.md     # rebuild the report elsewhere

Results go to OUT/<sequence>/<tracker>_s<seed>.txt (boxes, OTB results format, 1-based)
and .json (metrics, per-frame times, config, seed); deterministic trackers have no _s<seed>.
Run the same command again to resume: finished results are kept and skipped. Adding
trackers or seeds to a folder extends it. Seed s of a stochastic tracker reproduces
'covviz track SEQ --tracker NAME --seed s'.

Every job runs in a fresh process; a job whose process is killed runs again (--retries).
On a cluster (pip install 'covviz[cluster]'; start 'dask scheduler' and, on each machine,
'dask worker ADDRESS --nthreads 1'), workers read the sequences at the same path as given
here and send their results back: they need no access to --out.
"""

def add_bench_parser(sub) -> argparse.ArgumentParser:
    from covviz.trackers import TRACKERS

    p = sub.add_parser(
        "bench",
        help="run trackers on every sequence under a folder; write results and a report",
        description="Run each tracker on each sequence under ROOT (K seeds for the stochastic trackers, "
        "once for the others), J at a time here or on a Dask cluster, each in a fresh process; write "
        "per-frame boxes and a JSON per run to --out "
        "as each finishes (resumable), then the report (see 'covviz report').",
        epilog=BENCH_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("root", type=Path, help="a sequence folder (OTB or VOT layout) or a folder of them")
    p.add_argument(
        "--trackers",
        "--tracker",
        dest="trackers",
        default="manifold,ipca,csrt,kcf,mil",
        metavar="NAME[,NAME…]",
        help=f"trackers to run (default: manifold,ipca,csrt,kcf,mil); from {', '.join(TRACKERS)}; "
        "NAME@FILE.json: a variant with the config of FILE.json, named NAME@FILE",
    )
    p.add_argument(
        "--seeds", type=positive_int, default=3, metavar="K", help="seeds per stochastic tracker (default 3)"
    )
    p.add_argument("--jobs", type=positive_int, default=1, metavar="J", help="jobs at a time on this machine "
                   "(default 1), each in a fresh process")
    add_cluster_args(p)
    p.add_argument(
        "--out", type=Path, default=Path("runs/bench"), help="results folder (default: runs/bench)"
    )
    p.add_argument(
        "--max-frames", type=positive_int, metavar="N", help="run only the first N frames of each sequence"
    )
    p.add_argument(
        "--particles", type=positive_int, help="particles of the stochastic trackers (default: their own)"
    )
    add_config_arg(p)
    add_detector_arg(p)
    p.add_argument(
        "--force", action="store_true", help="re-run every job, even into a folder from another run"
    )
    p.add_argument("--no-report", action="store_true", help="do not write the report at the end")
    p.add_argument(
        "--counterfactual",
        action="store_true",
        help="replay every loss inside its job with the search, the model or the estimate fixed (see 'covviz "
        "track --help'); the report then adds losses by verdict and what fixing each would gain (ΔAUC)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_bench)
    return p

def add_cluster_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--cluster",
        metavar="ADDRESS",
        help="run the jobs on a Dask cluster: a scheduler address (tcp://host:8786), its scheduler "
        "file (.json), or local:N for N local worker processes; needs pip install 'covviz[cluster]'. "
        "Workers need covviz and the sequences at the same path as here, not the results folder",
    )
    p.add_argument(
        "--retries",
        type=nonneg_int,
        default=1,
        metavar="R",
        help="run a job whose process died (killed, its worker lost) again up to R times (default 1)",
    )

def cmd_bench(args) -> int:
    from covviz.experiments.bench import bench

    config = read_config(args.config, args.trackers.split(","))
    t0 = time.perf_counter()
    summary = bench(
        args.root,
        args.trackers.split(","),
        args.out,
        seeds=args.seeds,
        jobs=args.jobs,
        max_frames=args.max_frames,
        particles=args.particles,
        force=args.force,
        progress=not args.no_progress,
        report=not args.no_report,
        config=None if config is None else config.as_dict(),
        cluster=args.cluster,
        retries=args.retries,
        counterfactual=args.counterfactual,
        detector=detector_text(args.detector),
    )
    n_failed = len(summary["failed"])
    for event in summary.get("events", []):
        print(f"note: {event}", file=sys.stderr)
    print(
        f"bench: {summary['run']} runs done, {summary['skipped']} already done, {n_failed} failed "
        f"({time.perf_counter() - t0:.1f} s); results in {args.out}/"
    )
    if summary["report"] is not None:
        print(f"report: {summary['report']}")
    if n_failed:
        print(
            f"covviz bench: {n_failed} runs failed "
            f"(first: {summary['failed'][0][0]}: {summary['failed'][0][1]})",
            file=sys.stderr,
        )
        return 1
    return 0
