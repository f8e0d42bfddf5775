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
import contextlib
import logging
import math
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from covviz.errors import InputError
from covviz.data.sequences import IMAGE_EXTENSIONS, open_sequence

log = logging.getLogger("covviz")

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


class UsageError(InputError):
    """Bad input on the command line: printed as one line, exit code 2."""


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
    parts = [v for v in text.replace(" ", ",").split(",") if v]
    for name, v, raw in zip("xywh", vals, parts):
        if math.isnan(v):
            raise argparse.ArgumentTypeError(f"{name} is not a number ({raw!r}); give 4 numbers x,y,w,h in pixels")
        if math.isinf(v):
            raise argparse.ArgumentTypeError(f"{name}={raw} is not a finite number; give x,y,w,h in pixels")
    return np.array(vals)


def _int_at_least(lo: int, what: str):
    """argparse type: an integer ``>= lo``; ``what`` names it in the error."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if v < lo:
            raise argparse.ArgumentTypeError(f"expected {what}, got {v}")
        return v

    return parse


positive_int = _int_at_least(1, "a positive integer")
nonneg_int = _int_at_least(0, "an integer >= 0")


def tracker_list(text: str) -> list[str]:
    """argparse type for ``--trackers a,b``: the checked names."""
    from covviz.trackers import tracker_names

    try:
        return tracker_names(text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


# --------------------------------------------------------------------------- #
# track
# --------------------------------------------------------------------------- #
TRACK_EPILOG = """\
examples:
  covviz track                                   # the embedded synthetic sequence
  covviz track synthetic:occlusion               # a failure on purpose at a known frame; also distractor,
                                                 #   illumination, fast-motion, scale, appearance
  covviz track path/to/Car4 --seed 1             # an OTB folder (img/0001.jpg... + groundtruth_rect.txt)
  covviz track clip.mp4 --box 120,80,40,60       # a video (or 'frames/*.png', quoted): give the first box
  covviz track path/to/Car4 --trackers manifold,ipca   # several trackers side by side on the same frames
  covviz track path/to/Couple --spawn            # watch it live in a Rerun viewer (and save it)
  covviz track --mds-every 5 --save my.rrd       # denser template-cloud pictures, another file

Every run writes a Rerun recording (default recordings/SEQUENCE-TRACKERS-sSEED.rrd;
--no-save to skip); open it with 'rerun FILE.rrd'.

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
        help="tracker(s) to run: manifold (default), manifold-paper (the paper's likelihood: without the quadrant "
        "term, the derivative normalisation and the colour term), ipca, identity, csrt, kcf, mil, mosse, medianflow, tld",
    )
    p.add_argument("--particles", type=positive_int, help="number of particles (default: the tracker's own)")
    add_config_arg(p)
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0): same seed, same boxes")
    p.add_argument("--max-frames", type=positive_int, help="stop after this many frames")
    p.add_argument("--out", type=Path, default=Path("runs"), help="results folder (default: runs/)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_recording_args(p)
    p.set_defaults(func=cmd_track)
    return p


def add_config_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--config",
        type=Path,
        metavar="FILE.json",
        help="ManifoldConfig of the manifold trackers: a JSON object of its fields, the others default "
        "(e.g. the best.json of 'covviz tune'); --particles overrides its n_particles",
    )


# Rerun options in the style of rr.script_add_args, as our own flags: several sinks at once
# (a file and a viewer), and no --headless/--stdout, which do not fit a tracking run.
def add_recording_args(p: argparse.ArgumentParser, mds_options: bool = True) -> None:
    g = p.add_argument_group("recording (Rerun)")
    g.add_argument(
        "--save",
        type=Path,
        metavar="PATH",
        help="write the recording to this .rrd file (default: recordings/SEQUENCE-TRACKERS-sSEED.rrd)",
    )
    g.add_argument("--no-save", action="store_true", help="write no recording file")
    v = g.add_mutually_exclusive_group()
    v.add_argument("--spawn", action="store_true", help="also stream to a new Rerun viewer window")
    v.add_argument(
        "--connect",
        nargs="?",
        const=True,
        default=None,
        metavar="URL",
        help="also stream to a running viewer (default URL rerun+http://127.0.0.1:9876/proxy)",
    )
    v.add_argument("--serve-web", action="store_true", help="also host a web viewer and stream to it")
    if mds_options:
        g.add_argument(
            "--mds-every",
            type=nonneg_int,
            default=10,
            metavar="K",
            help="MDS picture of the template cloud every K frames (default 10; 0: never)",
        )
        g.add_argument(
            "--likelihood-every",
            type=nonneg_int,
            default=None,
            metavar="K",
            help="likelihood map around the estimate every K frames (default: as --mds-every; 0: never)",
        )


#: Upper estimate of recording bytes per frame and tracker (600 particles, 320x240: ~28 KB measured).
RECORDING_BYTES_PER_FRAME = 40_000
#: Free space kept on top of the estimate.
RECORDING_MARGIN_BYTES = 20_000_000


def _mkdirs(path: Path, created: list[Path] | None) -> None:
    """``mkdir -p path``, noting in ``created`` (top first) the folders it made, for :func:`_remove_empty`."""
    missing = []
    p = Path(path)
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    Path(path).mkdir(parents=True, exist_ok=True)
    if created is not None:
        created.extend(reversed(missing))


def _remove_empty(created: list[Path]) -> None:
    """Remove the folders a command made that are still empty (an error before the run wrote anything)."""
    for d in reversed(created):
        try:
            d.rmdir()
        except OSError:
            pass


def _check_recording_path(path: Path, n_frames: int, n_trackers: int, created: list[Path] | None = None) -> None:
    """Fail before tracking if the recording cannot be written (one-line UsageError)."""
    import shutil

    if path.suffix != ".rrd":
        raise UsageError(f"--save {path}: a recording file must end in .rrd")
    if path.is_dir():
        raise UsageError(f"--save {path}: is a folder; give a file name ending in .rrd")
    parent = path.parent if str(path.parent) else Path(".")
    try:
        _mkdirs(parent, created)
        probe = parent / f".covviz-write-test-{path.stem}"
        with open(probe, "wb") as fh:
            fh.write(b"\0" * 65536)
            fh.flush()
        probe.unlink()
        if path.exists():
            with open(path, "ab"):
                pass
    except OSError as exc:
        raise UsageError(
            f"cannot write the recording {path}: {exc.strerror or exc}; choose another --save or --no-save"
        ) from None
    need = n_frames * max(1, n_trackers) * RECORDING_BYTES_PER_FRAME + RECORDING_MARGIN_BYTES
    free = shutil.disk_usage(parent).free
    if free < need:
        raise UsageError(
            f"not enough free space for the recording in {parent}: about {need / 1e6:.0f} MB needed, "
            f"{free / 1e6:.0f} MB free; free some space, choose another --save, or --no-save"
        )


def _check_viewer(args) -> None:
    """``--connect``: fail before the work starts if no viewer listens at the URL."""
    if not getattr(args, "connect", None):
        return
    from covviz.viz.sinks import DEFAULT_VIEWER_URL, viewer_reachable

    url = DEFAULT_VIEWER_URL if args.connect is True else str(args.connect)
    if not viewer_reachable(url):
        raise UsageError(f"--connect: no viewer listens at {url}; start one with 'rerun', or use --spawn")


def default_recording_path(sequence_name: str, trackers: list[str], seed: int) -> Path:
    """``recordings/<sequence>-<tracker+tracker>-s<seed>.rrd``."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in sequence_name) or "sequence"
    return Path("recordings") / f"{safe}-{'+'.join(trackers)}-s{seed}.rrd"


def _print_diagnosis(found: dict | None) -> None:
    """The terminal summary of the drift diagnosis: every loss with its cause, the suspects' count."""
    if not found:
        return
    for d in found.get("diagnoses", []):
        print(f"  {d['text']}")
    sus = found.get("suspects", [])
    if sus:
        kinds = sorted({sp["kind"] for sp in sus})
        print(f"  {len(sus)} suspect frame(s) without ground truth ({', '.join(kinds)}); 'covviz events' lists them")
    labels = found.get("labels", {})
    off = {k: v for k, v in labels.items() if k != "ok" and v}
    if off:
        print("  frames off track: " + ", ".join(f"{v} {k} failure{'s' * (v != 1)}" for k, v in off.items()))


def _recording_observers(
    args, seq, n_frames: int, diagnoser, created: list[Path] | None = None
) -> tuple[list, Path | None]:
    """The Rerun logger for ``track`` (checked and connected before tracking starts), and its file.

    Without a recording, the drift diagnosis runs on its own background thread.
    """
    save = None if args.no_save else (args.save or default_recording_path(seq.name, args.trackers, args.seed))
    if args.no_save and args.save is not None:
        raise UsageError("--save and --no-save contradict each other; give one")
    live = bool(args.spawn or args.connect or args.serve_web)
    from covviz.runner import BackgroundObserver

    if save is None and not live:
        return [BackgroundObserver(diagnoser)], None
    if save is not None:
        _check_recording_path(save, n_frames, len(args.trackers), created)
    _check_viewer(args)
    from covviz.viz.logger import LoggerConfig, RerunLogger
    from covviz.viz.sinks import BATCH_SECONDS, BATCH_SECONDS_LIVE, attach_sinks, new_recording

    config = LoggerConfig(
        mds_every=args.mds_every, likelihood_every=args.likelihood_every, seed=args.seed, diagnosis=diagnoser.config
    )
    stream = new_recording(batch_seconds=BATCH_SECONDS_LIVE if live else BATCH_SECONDS)
    attach_sinks(stream, save=save, spawn=args.spawn, connect=args.connect, serve_web=args.serve_web)
    info = {
        "name": f"{seq.name} · {'+'.join(args.trackers)} · seed {args.seed}",
        "command": "covviz " + " ".join(getattr(args, "argv", sys.argv[1:])),
        "seed": args.seed,
        "trackers": args.trackers,
        "max_frames": args.max_frames,
        "particles": args.particles,
    }
    # The recorder logs on its own thread, overlapping the tracker (runner.BackgroundObserver).
    return [BackgroundObserver(RerunLogger(stream, config, run_info=info, diagnoser=diagnoser))], save


def _check_out_dir(out: Path, created: list[Path] | None = None) -> None:
    try:
        _mkdirs(out, created)
        probe = out / ".covviz-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"cannot write to {out}: {exc.strerror or exc}; choose another --out") from None


def read_config(path: Path | None, trackers: list[str]):
    """``--config FILE``: the ManifoldConfig in a JSON file of its fields (None without the option).

    Fields left out keep their defaults; ``--particles`` overrides ``n_particles``.
    Raises :class:`UsageError` (one line) on a missing or bad file, or when no tracker
    of ``trackers`` takes a config.
    """
    import json

    from covviz.trackers import CONFIGURABLE

    if path is None:
        return None
    if not set(trackers) & CONFIGURABLE:
        raise UsageError(
            f"--config sets a ManifoldConfig: it needs one of the trackers {', '.join(sorted(CONFIGURABLE))}"
        )
    from covviz.trackers.manifold import ManifoldConfig

    try:
        doc = json.loads(Path(path).read_text())
    except OSError as exc:
        raise UsageError(f"--config {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UsageError(f"--config {path}: not JSON ({exc}); give a JSON object of ManifoldConfig fields") from None
    try:
        return ManifoldConfig.from_dict(doc)
    except (ValueError, TypeError) as exc:
        raise UsageError(f"--config {path}: {exc}") from None


def _make_trackers(names: list[str], seed: int, particles: int | None, config_path: Path | None = None) -> list:
    """The trackers of a run, each with the stream of ``seed`` (:func:`covviz.trackers.tracker_rng`)."""
    from covviz.trackers import CONFIGURABLE, make_tracker

    config = read_config(config_path, names)
    try:
        return [
            make_tracker(name, seed=seed, n_particles=particles, config=config if name in CONFIGURABLE else None)
            for name in names
        ]
    except ValueError as exc:  # a config value the tracker refuses (e.g. --particles)
        raise UsageError(str(exc)) from None


def cmd_track(args) -> int:
    # One native thread for BLAS and OpenCV while tracking: more only contend with the
    # tracker's own threads on 9x9 matrices (one BLAS thread halves the CPU time at the same speed).
    from covviz.threads import limit_threads

    with limit_threads(1):
        return _track(args)


def _warm_kernels(trackers) -> None:
    """Compile the manifold tracker's kernels before the run (once per install; then loaded from the cache)."""
    from covviz.model import kernels

    if kernels.JIT_ENABLED and any(getattr(getattr(t, "config", None), "jit", False) for t in trackers):
        if kernels.kernels_cached():
            return  # each kernel loads from numba's cache at its first call (only those the run uses)
        took = kernels.warmup(lambda: log.info("compiling kernels (once; about 20-40 s, then cached)..."))
        log.debug("kernels ready in %.1f s", took)


def _check_frames(seq, n_frames: int) -> None:
    """Fail before tracking if a numbered frame is missing among the frames to track.

    Frames are matched to ground truth by their number (img/0015.jpg is row 15);
    tracking across a gap would score every later frame against the wrong row,
    and the OTB results format has no way to skip a frame.
    """
    missing = [i for i in getattr(seq, "missing", ()) if i < n_frames]
    if missing:
        first = seq.files[missing[0]]
        more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
        raise UsageError(
            f"{first}: frame missing{more} (frames are matched to the ground truth by number); restore it, "
            f"or track the {missing[0]} frames before it with --max-frames {missing[0]}"
        )


def _recorded(args) -> bool:
    return not args.no_save or bool(args.spawn or args.connect or args.serve_web)


def _check_memory(args, frame_shape) -> None:
    """Fail before tracking if ``--particles`` needs more memory than the machine has free."""
    if args.particles is None:
        return
    from covviz.resources import available_memory, run_memory
    from covviz.trackers import STOCHASTIC

    n = sum(name in STOCHASTIC for name in args.trackers)
    avail = available_memory()
    if not n or avail is None:
        return
    rec = _recorded(args)
    need = run_memory(args.particles, frame_shape, n, rec)
    if need > avail:
        fixed = run_memory(0, frame_shape, n, rec)
        most = max(0, int((avail - fixed) / ((need - fixed) / args.particles)))
        raise UsageError(
            f"--particles {args.particles} needs about {need / 1e9:.1f} GB of memory and {avail / 1e9:.1f} GB is "
            f"available; use at most about {most} particles" + (" or fewer trackers" if n > 1 else "")
        )


def _recording_complete(path: Path) -> bool:
    from covviz.viz.sinks import recording_complete

    return bool(recording_complete(path))


def _q(path) -> str:
    """A path as a shell would need it (quoted if it has spaces)."""
    return shlex.quote(str(path))


def _track(args) -> int:
    from covviz.diagnosis.drift import Diagnoser
    from covviz.trackers.base import check_init_box

    seq = open_sequence(args.sequence, box=args.box)
    if len(seq) < 2:
        raise UsageError(f"{seq.name}: a sequence needs at least 2 frames, found {len(seq)}")
    n_frames = len(seq) if args.max_frames is None else min(len(seq), args.max_frames)
    _check_frames(seq, n_frames)
    first = seq.frame(0)  # fail early on an unreadable first frame or a bad box
    check_init_box(seq.init_box, first.image.shape)
    _check_memory(args, first.image.shape)
    created: list[Path] = []  # folders made by the checks: removed again if nothing is written
    try:
        _check_out_dir(args.out, created)
        trackers = _make_trackers(args.trackers, args.seed, args.particles, getattr(args, "config", None))
        diagnoser = Diagnoser()
        # Last of the checks (an unwritable file, a viewer that is not there), then the file is opened.
        recorders, rrd = _recording_observers(args, seq, n_frames, diagnoser, created)
    except BaseException:
        _remove_empty(created)
        raise
    _warm_kernels(trackers)
    with contextlib.ExitStack() as stack:  # the trackers' threads end with the run
        for tr in trackers:
            if hasattr(tr, "close"):
                stack.callback(tr.close)
        return _run_tracking(args, seq, trackers, diagnoser, recorders, rrd, created)


def _run_tracking(args, seq, trackers, diagnoser, recorders, rrd, created) -> int:
    from covviz.metrics import nothing_to_score
    from covviz.experiments.results import ResultWriter
    from covviz.runner import FreeSpaceGuard, ResultCollector, run_many
    from covviz.signals import exit_code

    def extra(j: int) -> dict:
        """What the drift diagnosis found for tracker ``j`` so far, for its results JSON."""
        if j >= len(diagnoser.states):
            return {}
        return {"diagnosis": diagnoser.report(j), "diagnosis_config": diagnoser.config.as_dict()}

    # The results are on disk while the run goes (every second, and at the end): what a kill, a
    # signal or a full disk leaves is the frames done. The writer ends after the recorder (whose
    # thread also runs the drift diagnosis), so the final files hold the whole diagnosis.
    writer = ResultWriter(args.out, extra=extra)
    guard = FreeSpaceGuard([args.out, *([rrd] if rrd is not None else [])])
    collector = ResultCollector()
    observers = [*getattr(args, "observers", []), guard, *recorders, writer, collector]
    where = args.out / seq.name
    t0 = time.perf_counter()
    code = 0
    try:
        results = run_many(
            trackers,
            seq,
            observers,
            max_frames=args.max_frames,
            progress=not args.no_progress,
            seeds=[args.seed] * len(trackers),
        )
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM (covviz.signals): keep what was done
        code = exit_code(exc)
        for note in getattr(exc, "__notes__", []):  # an observer that could not finish (covviz.runner)
            log.warning("%s", note)
        results = collector.results
        log.warning("interrupted: the results hold the %d frames done so far", writer.saved_frames)
        if rrd is not None:
            print(f"recording (up to the interruption) in {rrd}   open it with: rerun {_q(rrd)}")
        if not writer.docs:
            _remove_empty(created)
            return code
    except InputError as exc:
        # A broken frame or a full disk: one line from main (exit 2) that also says what was kept
        # (the observers' notes - the recording cut short by the same full disk - are in it).
        kept = [f"the results of the {writer.saved_frames} frames before it in {where}/"] if writer.saved_frames else []
        if rrd is not None:
            kept.append(f"the recording {_q(rrd)}" if _recording_complete(rrd) else
                        f"the recording {_q(rrd)} cut short ('rerun rrd migrate {_q(rrd)}' completes it)")
        if kept:
            exc.args = (f"{exc} (kept: {'; '.join(kept)})",)
        exc.__notes__ = []
        _remove_empty(created)
        raise
    except BaseException:
        # A bug in a tracker (traceback, exit 1): the results of the frames before it are on disk.
        if writer.saved_frames:
            log.warning("results of the %d frames before the error are in %s/", writer.saved_frames, where)
        _remove_empty(created)
        raise
    wall = time.perf_counter() - t0
    for res, doc in zip(results, writer.docs):
        m = doc["metrics"]
        head = f"{res.sequence} · {res.tracker} (seed {res.seed}): {len(res.boxes)} frames, {res.fps:.1f} fps"
        if nothing_to_score(res.groundtruth):
            print(f"{head}\n  nothing to score: no ground truth after the first frame, whose box is the one given")
            continue
        print(
            f"{head}\n"
            f"  success AUC {m['success_auc']:.3f}   P@20 {m['precision_20']:.3f}   "
            f"r_on_track {m['r_on_track']:.3f}   rms_on_track {m['rms_on_track']:.3f}   "
            f"mean IoU {m['mean_iou']:.3f}   ({m['n_skipped']} frames without ground truth skipped)"
        )
        _print_diagnosis(doc.get("diagnosis"))
    print(f"results in {where}/  ({wall:.1f} s wall)")
    if rrd is not None and not code:
        print(f"recording in {rrd}   open it with: rerun {_q(rrd)}")
    return code


# --------------------------------------------------------------------------- #
# bench and report
# --------------------------------------------------------------------------- #
BENCH_EPILOG = """\
examples:
  covviz bench ../shared/sequences --trackers csrt,kcf,mil --out runs/peers
  covviz bench ../shared/sequences --trackers manifold,ipca,csrt,kcf,mil --seeds 3 --jobs 2 --out runs/bench
  covviz bench ../shared/sequences/Car4 --trackers manifold --seeds 5 --max-frames 200 --out runs/car4
  covviz bench ../shared/sequences --trackers manifold --config runs/tune/best.json --out runs/tuned
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

REPORT_EPILOG = """\
examples:
  covviz report runs/bench                           # runs/bench/report.md + runs/bench/img/*.png
  covviz report runs/bench --out docs/results.md     # docs/results.md + docs/img/*.png

The report is rebuilt from the result files only; nothing is re-run. Figures go to
img/ next to the markdown file and are linked with relative paths.
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
        help=f"trackers to run (default: manifold,ipca,csrt,kcf,mil); from {', '.join(TRACKERS)}",
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
    p.add_argument(
        "--force", action="store_true", help="re-run every job, even into a folder from another run"
    )
    p.add_argument("--no-report", action="store_true", help="do not write the report at the end")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_bench)
    return p


def add_report_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "report",
        help="rebuild the markdown report and figures of a bench from its result files",
        description="Read the results of 'covviz bench' in DIR and write a markdown report: tables per "
        "sequence and overall (success AUC, P@20, r_on_track, rms_on_track, fps; mean ± std over seeds), "
        "the OTB success and precision plots, and the paper's bar charts (manifold against ipca).",
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
    p.set_defaults(func=cmd_report)
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
    p.add_argument("--config", type=Path, metavar="FILE.json",
                   help="base ManifoldConfig (JSON of its fields): the first trial, and the values of the fields "
                   "not searched")
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


def cmd_report(args) -> int:
    from covviz.experiments.report import write_report

    path = write_report(args.dir, args.out, append=args.append)
    print(f"report: {path}")
    return 0


# --------------------------------------------------------------------------- #
# mds
# --------------------------------------------------------------------------- #
MDS_EPILOG = """\
examples:
  covviz mds                                       # the synthetic default (frames 1, 101, 201)
  covviz mds path/to/Car4                          # frames 1, 101, 201, 501 of Car4
  covviz mds path/to/Car4 --frames 1,51,101 --png-dir docs/img
  covviz mds path/to/Car4 --save car4-mds.rrd --no-png

Writes recordings/SEQUENCE-mds.rrd (--save another file, --no-save none; open it with
'rerun FILE') and two PNGs in --png-dir (default recordings/): SEQUENCE-mds-separation.png
(target vs background) and SEQUENCE-mds-random-walk.png. Frames are 1-based (frame 1 is
img/0001.jpg), as everywhere in covviz.
"""


def frame_list(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(v) for v in text.replace(" ", ",").split(",") if v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--frames must be 1-based frame numbers like 1,101,201; got {text!r}") from None
    if not vals or min(vals) < 1:
        raise argparse.ArgumentTypeError(f"--frames must be 1-based frame numbers like 1,101,201; got {text!r}")
    return vals


def add_mds_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "mds",
        help="the paper's manifold figures (MDS of Riemannian distances)",
        description="Reproduce the paper's figures: (a) target vs background descriptors over the sequence "
        "on the covariance manifold, (b) the random walk of the templates at chosen frames; "
        "both by MDS of Riemannian distance matrices. Writes a recording and PNGs.",
        epilog=MDS_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("sequence", nargs="?", default=None, help="as for 'covviz track' (default: synthetic)")
    p.add_argument("--box", type=parse_box, help="initial box x,y,w,h (0-based px) for videos and globs")
    p.add_argument(
        "--frames",
        type=frame_list,
        default=None,  # mds_figures.DEFAULT_FRAMES, resolved in cmd_mds: building the parser imports no scipy
        metavar="F[,F…]",
        help="1-based frames of the random-walk figure (default 1,101,201,501,801 as far as the sequence goes)",
    )
    p.add_argument("--max-target", type=positive_int, default=150, metavar="N",
                   help="at most N target descriptors in figure (a) (default 150)")
    p.add_argument("--n-background", type=positive_int, default=3, metavar="N",
                   help="background regions per sampled frame (default 3)")
    p.add_argument("--method", choices=("classical", "smacof"), default="classical",
                   help="MDS: classical (default) or SMACOF (started from the classical solution)")
    p.add_argument("--particles", type=positive_int, help="particles of the tracker for figure (b)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--png-dir", type=Path, default=Path("recordings"), help="folder for the PNGs (default recordings/)")
    p.add_argument("--no-png", action="store_true", help="write no PNGs")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_recording_args(p, mds_options=False)
    p.set_defaults(func=cmd_mds)
    return p


def cmd_mds(args) -> int:
    from covviz.threads import limit_threads

    with limit_threads(1):
        return _mds(args)


def _mds(args) -> int:
    from covviz.viz.mds_figures import DEFAULT_FRAMES, MDSFiguresConfig, random_walk_data, separation_data

    seq = open_sequence(args.sequence, box=args.box)
    if len(seq) < 2:
        raise UsageError(f"{seq.name}: a sequence needs at least 2 frames, found {len(seq)}")
    cfg = MDSFiguresConfig(
        frames=tuple(DEFAULT_FRAMES if args.frames is None else args.frames),
        max_target=max(2, args.max_target),
        n_background=args.n_background,
        method=args.method,
        seed=args.seed,
        n_particles=args.particles,
    )
    if args.no_save and args.save is not None:
        raise UsageError("--save and --no-save contradict each other; give one")
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in seq.name) or "sequence"
    save = None if args.no_save else (args.save or Path("recordings") / f"{safe}-mds.rrd")
    if save is not None:
        _check_recording_path(save, 10, 1)
    _check_viewer(args)
    if not args.no_png:
        _check_out_dir(args.png_dir)
    progress = not args.no_progress
    # One observation model for both figures: the one the tracker of figure (b) builds at init.
    walk = random_walk_data(seq, cfg, progress=progress)
    sep = separation_data(seq, cfg, progress=progress, model=walk.model)
    if save is not None or args.spawn or args.connect or args.serve_web:
        from covviz.viz.blueprint import mds_blueprint
        from covviz.viz.mds_figures import log_figures
        from covviz.viz.sinks import attach_sinks, close_stream, new_recording

        stream = new_recording()
        attach_sinks(stream, save=save, spawn=args.spawn, connect=args.connect, serve_web=args.serve_web)
        stream.send_blueprint(mds_blueprint())
        stream.send_recording_name(f"{safe} · MDS figures")
        log_figures(stream, sep, walk, seq.name)
        close_stream(stream, timeout=30.0)  # flushes, disconnects, checks the file (a full disk is one line)
        if save is not None:
            print(f"recording in {save}   open it with: rerun {_q(save)}")
    if not args.no_png:
        from covviz.viz.mds_figures import save_pngs

        for path in save_pngs(sep, walk, args.png_dir, safe):
            print(f"figure: {path}")
    n_t = int((sep.kinds == "target").sum())
    frames = sorted({int(f) for f in walk.frames})
    print(f"{seq.name}: {n_t} target and {len(sep.kinds) - n_t} background descriptors; "
          f"templates at frames {', '.join(map(str, frames))}")
    return 0


# --------------------------------------------------------------------------- #
# snapshot
# --------------------------------------------------------------------------- #
SNAPSHOT_EPILOG = """\
examples:
  covviz snapshot recordings/synthetic-manifold-s0.rrd --frame 120 --out shot.png
  covviz snapshot run.rrd --size 1920x1080            # the last frame
  covviz events run.rrd                               # which events are there (their numbers K)
  covviz snapshot run.rrd --event 3 --offsets -5,0,5 --out sheet.png   # before / at / after event 3
  covviz snapshot recordings/Car4-mds.rrd --out mds.png                # an 'mds' recording (static)

Frames are 1-based, as on the recording's timeline and in the events (frame 1 is the first image).
Needs a Vulkan driver for the headless viewer: apt-get install -y mesa-vulkan-drivers libvulkan1
"""


def offset_list(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(v) for v in text.replace(" ", ",").split(",") if v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--offsets must be frame offsets like -5,0,5; got {text!r}") from None
    if not vals:
        raise argparse.ArgumentTypeError(f"--offsets must be frame offsets like -5,0,5; got {text!r}")
    return vals


def add_snapshot_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "snapshot",
        help="a PNG of a recording in the headless Rerun viewer (a frame, or a sheet around an event)",
        description="Open a recording in the real Rerun viewer, headless (software rendering), go to a frame "
        "and save a screenshot of the whole window with the recording's own layout. With --event, take one "
        "screenshot per offset around that event (one viewer launch) and stack them into one sheet.",
        epilog=SNAPSHOT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("recording", type=Path, help="an .rrd file")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--frame", type=positive_int, help="frame number to show, 1-based (default: the last)")
    where.add_argument("--event", type=nonneg_int, metavar="K",
                       help="event K of 'covviz events REC.rrd' (its frame, plus --offsets)")
    p.add_argument("--offsets", type=offset_list, default=(-5, 0, 5), metavar="A,B,…",
                   help="with --event: frames relative to the event's (default -5,0,5)")
    p.add_argument("--out", type=Path, default=Path("shot.png"), help="PNG to write (default shot.png)")
    p.add_argument("--size", default="1600x900", help="window size WxH in points (default 1600x900)")
    p.add_argument("--timeline", default="frame", help="timeline of --frame (default 'frame')")
    p.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for the viewer (default 60)")
    p.set_defaults(func=cmd_snapshot)
    return p


def cmd_snapshot(args) -> int:
    import tempfile

    from covviz.viz.readback import last_frame, read_events
    from covviz.viz.snapshot import SnapshotError, contact_sheet, parse_size, snapshot, snapshot_frames

    if not args.recording.is_file():
        raise UsageError(f"{args.recording}: no such recording")
    size = parse_size(args.size)
    created: list[Path] = []
    _check_png_path(args.out, created)
    try:
        if args.event is None:
            out = snapshot(args.recording, args.out, frame=args.frame, size=size, timeline=args.timeline,
                           timeout=args.timeout)
            print(f"screenshot: {out}")
            return 0
        events = read_events(args.recording)
        if not events:
            raise UsageError(f"{args.recording}: the recording has no events (see 'covviz events')")
        if args.event >= len(events):
            raise UsageError(f"--event {args.event}: the recording has events 0..{len(events) - 1} "
                             "(list them with 'covviz events')")
        ev = events[args.event]
        last = last_frame(args.recording) or ev["frame"]
        frames = sorted({min(max(1, ev["frame"] + k), last) for k in args.offsets})
        with tempfile.TemporaryDirectory() as tmp:
            shots = [(Path(tmp) / f"f{f}.png", f) for f in frames]
            snapshot_frames(args.recording, shots, size, args.timeline, args.timeout)
            labels = [f"frame {f} ({f - ev['frame']:+d} from event {args.event}: {ev['kind']} "
                      f"{ev['cause'].replace('_', ' ')}) - {ev['tracker']}" for f in frames]
            out = contact_sheet([p for p, _ in shots], labels, args.out)
    except SnapshotError as exc:
        _remove_empty(created)
        raise UsageError(str(exc)) from None
    except BaseException:
        _remove_empty(created)
        raise
    print(f"sheet: {out} (frames {', '.join(map(str, frames))} around event {args.event}: {ev['text'][:100]})")
    return 0


# --------------------------------------------------------------------------- #
# events
# --------------------------------------------------------------------------- #
EVENTS_EPILOG = """\
examples:
  covviz events recordings/synthetic-manifold-s0.rrd
  covviz events run.rrd --kind diagnosis            # only the diagnosed losses
  covviz events run.rrd --json > events.json        # for scripts (evidence included)
  covviz snapshot run.rrd --event 4 --offsets -5,0,5 --out sheet.png

Kinds: drift, lost, recovered, storm, storm_end (from the ground truth and the weights),
diagnosis (the cause of a loss, with its evidence), suspect (warnings without ground truth).
Frames are 1-based, as on the recording's timeline.
"""


def add_events_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "events",
        help="list the events and drift diagnoses of a recording",
        description="Read the events of a tracking recording (loss, drift onset, recovery, resampling storms, "
        "the diagnosed cause of every loss, label-free suspects) from the file, and print them with their "
        "numbers K for 'covviz snapshot --event K'.",
        epilog=EVENTS_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("recording", type=Path, help="an .rrd file written by 'covviz track'")
    p.add_argument("--kind", action="append", metavar="KIND", help="only events of this kind (repeatable)")
    p.add_argument("--tracker", help="only this tracker's events")
    p.add_argument("--json", action="store_true", help="print JSON (one list, evidence included)")
    p.set_defaults(func=cmd_events)
    return p


def cmd_events(args) -> int:
    import json

    from covviz.viz.readback import read_events

    events = read_events(args.recording)
    if args.kind:
        events = [e for e in events if e["kind"] in args.kind]
    if args.tracker:
        events = [e for e in events if e["tracker"] == args.tracker]
    if args.json:
        print(json.dumps(events, indent=1))
        return 0
    if not events:
        print(f"{args.recording}: no events")
        return 0
    for e in events:
        cause = f" [{e['cause'].replace('_', ' ')}]" if e["cause"] else ""
        print(f"{e['index']:>3}  frame {e['frame']:>5}  {e['tracker']:<14} {e['kind']:<9}{cause} {e['text']}")
    return 0


def _check_png_path(out: Path, created: list[Path]) -> None:
    """``snapshot --out``: a PNG file that can be written (not a folder, not under a file)."""
    if out.is_dir():
        raise UsageError(f"--out {out}: is a folder; give a file name ending in .png")
    if out.suffix.lower() != ".png":
        raise UsageError(f"--out {out}: a screenshot is a PNG; give a file name ending in .png")
    parent = out.parent if str(out.parent) else Path(".")
    try:
        _mkdirs(parent, created)
        probe = parent / f".covviz-write-test-{out.stem}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        _remove_empty(created)
        raise UsageError(f"cannot write {out}: {exc.strerror or exc}; choose another --out") from None


# --------------------------------------------------------------------------- #
# entry point
# --------------------------------------------------------------------------- #
def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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
    return parser


def _glue_negative_values(argv: list[str]) -> list[str]:
    """``--offsets -5,0,5`` as ``--offsets=-5,0,5``: argparse takes a value starting with '-' for an option."""
    out: list[str] = []
    it = iter(argv)
    for a in it:
        if a == "--offsets":
            nxt = next(it, None)
            out.append(a if nxt is None else f"{a}={nxt}")
        else:
            out.append(a)
    return out


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
    parser.error(f"unrecognized arguments: {' '.join(extra)}")


def main(argv: list[str] | None = None) -> int:
    from covviz.signals import exit_code, stop_signals

    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args, extra = parser.parse_known_args(_glue_negative_values(argv))
    if extra:
        _unquoted_glob(parser, args, extra)
    args.argv = argv  # written into recordings
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s: %(message)s"
    )
    try:
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


if __name__ == "__main__":
    sys.exit(main())
