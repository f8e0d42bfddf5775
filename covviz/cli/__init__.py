"""The ``covviz`` command line.

Subcommands::

    covviz track [SEQUENCE]   run tracker(s) on a sequence, print metrics, save boxes + JSON
    covviz bench ROOT         every tracker on every sequence under ROOT, resumable, then a report
    covviz report DIR         rebuild a bench's markdown report and figures from its result files
    covviz tune ROOT          an Optuna study over the manifold tracker's config, checked on held-out seeds
    covviz mds [SEQUENCE]     the paper's manifold figures (MDS), as a recording and PNGs
    covviz snapshot RRD       a PNG of a recording in the headless Rerun viewer (a frame, or a sheet around an event)
    covviz events RRD         the events and drift diagnoses of a recording

Exit codes: 0 success, 1 unexpected error, 2 bad input or an output that
cannot be written (the one-line message says what to fix), 130 interrupted by
Ctrl-C, 143 stopped by SIGTERM (both keep the results of the frames done).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from covviz.cli.bench import add_bench_parser
from covviz.cli.calibrate import add_calibrate_parser
from covviz.cli.common import EXIT_BAD_INPUT, _q
from covviz.cli.events import add_events_parser
from covviz.cli.habits import CovvizParser, check_ignored, given_options, glue_negative_values, unrecognized
from covviz.cli.mds import add_mds_parser
from covviz.cli.report import add_report_parser
from covviz.cli.snapshot import add_snapshot_parser
from covviz.cli.track import add_track_parser
from covviz.cli.tune import add_tune_parser
from covviz.data.sequences import IMAGE_EXTENSIONS
from covviz.errors import InputError


def build_parser() -> argparse.ArgumentParser:
    parser = CovvizParser(
        prog="covviz",
        description="A tracker on the Riemannian manifold of covariance matrices, "
        "and a Rerun app to see why it holds on or drifts.",
        epilog="""\
examples:
  covviz track                                  # the synthetic default: metrics, runs/, recordings/
  covviz track path/to/Car4 --trackers manifold,ipca --seed 1
  rerun 'recordings/Car4-manifold+ipca-s1.rrd'  # scrub it frame by frame in the viewer
  covviz events 'recordings/Car4-manifold+ipca-s1.rrd'   # the losses and their diagnosed causes
  covviz snapshot recordings/synthetic-manifold-s0.rrd --frame 120 --out shot.png
  covviz mds path/to/Car4                       # the paper's manifold MDS figures
  covviz bench path/to/sequences --trackers manifold,ipca,csrt --seeds 3 --jobs 2
  covviz report runs/bench --out docs/results.md

Run 'covviz COMMAND --help' for the options and examples of each command.""",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    add_track_parser(sub)
    add_bench_parser(sub)
    add_report_parser(sub)
    add_tune_parser(sub)
    add_mds_parser(sub)
    add_snapshot_parser(sub)
    add_events_parser(sub)
    add_calibrate_parser(sub)
    return parser

def _glue_negative_values(argv: list[str]) -> list[str]:
    """``--box -5,10,40,60`` as ``--box=-5,10,40,60``: argparse takes a value starting with '-' for an option."""
    return glue_negative_values(argv)

def _unquoted_glob(parser: argparse.ArgumentParser, args, extra: list[str]) -> None:
    """Unrecognised arguments: argparse's error, with a hint when the shell expanded an unquoted glob."""
    images = [a for a in [getattr(args, "sequence", None), *extra]
              if a and Path(a).suffix.lower() in IMAGE_EXTENSIONS and Path(a).is_file()]
    if getattr(args, "command", None) in ("track", "mds") and len(images) > 1:
        pattern = str(Path(images[0]).parent / ("*" + Path(images[0]).suffix))
        print(
            f"covviz {args.command}: error: got {len(images)} image files ({images[0]} {images[1]} …): the shell "
            f"expanded an unquoted glob; quote it: covviz {args.command} {_q(pattern)} --box x,y,w,h",
            file=sys.stderr,
        )
        raise SystemExit(EXIT_BAD_INPUT)
    unrecognized(parser, getattr(args, "command", None), extra)

def main(argv: list[str] | None = None) -> int:
    from covviz.signals import exit_code, stop_signals

    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    glued = _glue_negative_values(argv)
    args, extra = parser.parse_known_args(glued)
    if extra:
        _unquoted_glob(parser, args, extra)
    args.argv = argv  # written into recordings
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s: %(message)s"
    )
    try:
        # An option that would do nothing: an error. The parser is done with, so it is reused (and spent).
        check_ignored(args, given_options(lambda: parser, glued))
        # SIGTERM stops a run as Ctrl-C does (results of the frames done, a valid recording),
        # with exit code 143; a second signal never cuts short the saving of the first.
        with stop_signals():
            return int(args.func(args) or 0)
    except InputError as exc:
        # Validation of what the user gave (covviz.errors); any other exception, a ValueError
        # raised by a tracker in the middle of a run included, is a bug: traceback, exit 1.
        print(f"covviz {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt as exc:
        print(f"covviz {args.command}: interrupted", file=sys.stderr)
        return exit_code(exc)
