"""The ``covviz`` command line.

Subcommands::

    covviz track [SEQUENCE]   run tracker(s) on a sequence, print metrics, save boxes + JSON

Exit codes: 0 success, 1 unexpected error, 2 bad input (the one-line message
says what to fix), 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

from covviz.metrics import evaluate
from covviz.sequences import SequenceError, open_sequence

log = logging.getLogger("covviz")

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


class UsageError(ValueError):
    """Bad input from the user: printed as one line, exit code 2."""


# --------------------------------------------------------------------------- #
# argument types
# --------------------------------------------------------------------------- #
def parse_box(text: str) -> np.ndarray:
    """``"x,y,w,h"`` -> array; argparse type for ``--box``."""
    try:
        vals = [float(v) for v in text.replace(" ", ",").split(",") if v]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--box must be 4 numbers x,y,w,h; got {text!r}") from None
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"--box must be 4 numbers x,y,w,h; got {text!r}")
    return np.array(vals)


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {v}")
    return v


def tracker_list(text: str) -> list[str]:
    from covviz.trackers import TRACKERS

    names = [t.strip().lower() for t in text.split(",") if t.strip()]
    bad = [n for n in names if n not in TRACKERS]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown tracker {', '.join(bad) or text!r}; choose from {', '.join(TRACKERS)}"
        )
    return names


# --------------------------------------------------------------------------- #
# track
# --------------------------------------------------------------------------- #
TRACK_EPILOG = """\
examples:
  covviz track                                   # the embedded synthetic sequence
  covviz track ../shared/sequences/Car4 --seed 1 # an OTB folder
  covviz track clip.mp4 --box 120,80,40,60       # a video (or 'frames/*.png'): give the first box
  covviz track Car4 --trackers manifold,ipca     # several trackers side by side on the same frames

Boxes are x,y,w,h in pixels. --box is 0-based (as an image viewer shows them);
OTB ground-truth and result files are 1-based, as the OTB toolkit expects.
"""


def add_track_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "track",
        help="run a tracker on a sequence, print metrics, write results",
        description="Run one or more trackers on a sequence, print OTB and on-track metrics and fps, "
        "and write per-frame boxes (OTB results format) plus a JSON of metrics and config to --out.",
        epilog=TRACK_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "sequence",
        nargs="?",
        default=None,
        help="OTB folder (img/ + groundtruth_rect.txt), VOT folder, video file or image glob; "
        "omitted: the embedded synthetic sequence",
    )
    p.add_argument("--box", type=parse_box, help="initial box x,y,w,h (0-based px); required for videos and globs")
    p.add_argument(
        "--tracker",
        "--trackers",
        dest="trackers",
        type=tracker_list,
        default=["manifold"],
        metavar="NAME[,NAME…]",
        help="tracker(s) to run: manifold (default), ipca, identity, csrt, kcf, mil, mosse, medianflow, tld",
    )
    p.add_argument("--particles", type=positive_int, help="number of particles (default: the tracker's own)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0): same seed, same boxes")
    p.add_argument("--max-frames", type=positive_int, help="stop after this many frames")
    p.add_argument("--out", type=Path, default=Path("runs"), help="results folder (default: runs/)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_track)
    return p


def _check_out_dir(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".covviz-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"cannot write to {out}: {exc.strerror or exc}; choose another --out") from None


def cmd_track(args) -> int:
    from covviz.results import save_result
    from covviz.runner import ResultCollector, run_many
    from covviz.trackers import make_tracker

    seq = open_sequence(args.sequence, box=args.box)
    if len(seq) < 2:
        raise UsageError(f"{seq.name}: a sequence needs at least 2 frames, found {len(seq)}")
    first = seq.frame(0)  # fail early on an unreadable first frame or a bad box
    from covviz.trackers.base import check_init_box

    check_init_box(seq.init_box, first.image.shape)
    _check_out_dir(args.out)
    seeds = np.random.SeedSequence(args.seed).spawn(len(args.trackers))
    trackers = [
        make_tracker(name, rng=np.random.default_rng(s), n_particles=args.particles)
        for name, s in zip(args.trackers, seeds)
    ]
    collector = ResultCollector()
    observers = [*getattr(args, "observers", []), collector]
    t0 = time.perf_counter()
    interrupted = False
    try:
        results = run_many(
            trackers,
            seq,
            observers,
            max_frames=args.max_frames,
            progress=not args.no_progress,
            seeds=[args.seed] * len(trackers),
        )
    except KeyboardInterrupt:
        interrupted = True
        results = collector.results
        log.warning("interrupted: the results hold the %d frames done so far", len(results[0].boxes) if results else 0)
        if not results or not len(results[0].boxes):
            return EXIT_INTERRUPTED
    wall = time.perf_counter() - t0
    for res in results:
        doc = save_result(res, args.out)
        m = doc["metrics"]
        print(
            f"{res.sequence} · {res.tracker} (seed {res.seed}): {len(res.boxes)} frames, "
            f"{res.fps:.1f} fps\n"
            f"  success AUC {m['success_auc']:.3f}   P@20 {m['precision_20']:.3f}   "
            f"r_on_track {m['r_on_track']:.3f}   rms_on_track {m['rms_on_track']:.3f}   "
            f"mean IoU {m['mean_iou']:.3f}   ({m['n_skipped']} frames without ground truth skipped)"
        )
    print(f"results in {args.out}/{seq.name}/  ({wall:.1f} s wall)")
    return EXIT_INTERRUPTED if interrupted else 0


# --------------------------------------------------------------------------- #
# entry point
# --------------------------------------------------------------------------- #
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="covviz",
        description="A tracker on the Riemannian manifold of covariance matrices, "
        "and a Rerun app to see why it holds on or drifts.",
        epilog="Run 'covviz COMMAND --help' for the options and examples of each command.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    add_track_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s: %(message)s"
    )
    try:
        return int(args.func(args) or 0)
    except (UsageError, SequenceError) as exc:
        print(f"covviz {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except ValueError as exc:
        # Validation errors of configs, boxes and inputs are user errors too.
        print(f"covviz {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"covviz {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
