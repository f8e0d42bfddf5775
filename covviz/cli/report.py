"""``covviz report``: rebuild a bench's markdown report and figures from its result files."""

from __future__ import annotations

import argparse
from pathlib import Path

REPORT_EPILOG = """\
examples:
  covviz report runs/bench                           # runs/bench/report.md + runs/bench/img/*.png
  covviz report runs/bench --out docs/results.md     # docs/results.md + docs/img/*.png
  covviz report runs/bench --latex                   # also runs/bench/report.tex: the tables in LaTeX

The report is rebuilt from the result files only; nothing is re-run. Figures go to
img/ next to the markdown file, each as PNG (linked with a relative path), SVG and PDF.
For a bench run with --counterfactual it adds, per tracker, the losses by verdict, what
fixing each kind of failure would gain (ΔAUC per fix) and how stable the verdicts are
across seeds; those read the sequences' ground truth (at the paths the results name).
"""

def add_report_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "report",
        help="rebuild the markdown report and figures of a bench from its result files",
        description="Read the results of 'covviz bench' in DIR and write a markdown report: tables per "
        "sequence and overall (success AUC, P@20, r_on_track, rms_on_track, fps; mean ± std over seeds), "
        "the OTB success and precision plots, the paper's bar charts (manifold against ipca), the losses by "
        "cause and, after 'covviz bench --counterfactual', by verdict with what fixing each would gain.",
        epilog=REPORT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("dir", type=Path, help="results folder written by 'covviz bench'")
    p.add_argument(
        "--out", type=Path, help="markdown file to write (default: DIR/report.md); figures go to its img/"
    )
    p.add_argument(
        "--append",
        type=Path,
        action="append",
        default=[],
        metavar="FILE.md",
        help="markdown to append to the report as is, e.g. the ablation that benchmarks/ablation.py writes "
        "(repeatable)",
    )
    p.add_argument("--latex", action="store_true",
                   help="also write the tables as LaTeX (booktabs), REPORT.tex beside the markdown")
    p.set_defaults(func=cmd_report)
    return p

def cmd_report(args) -> int:
    from covviz.experiments.report import write_report

    path = write_report(args.dir, args.out, append=args.append, latex=args.latex)
    print(f"report: {path}")
    if args.latex:
        print(f"tables in LaTeX: {path.with_suffix('.tex')}")
    return 0


# --------------------------------------------------------------------------- #
# mds
# --------------------------------------------------------------------------- #
