"""``covviz track``: run tracker(s) on a sequence, print metrics, save boxes + JSON and a recording."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

from covviz.cli.calibrate import add_detector_arg
from covviz.cli.common import (
    UsageError,
    _check_out_dir,
    _check_recording_path,
    _check_viewer,
    _make_trackers,
    _q,
    _remove_empty,
    add_config_arg,
    add_frames_by_arg,
    add_recording_args,
    config_doc,
    default_recording_path,
    log,
    nonneg_int,
    parse_box,
    positive_int,
    tracker_list,
    tracker_specs,
)
from covviz.data.sequences import open_sequence
from covviz.errors import InputError

TRACK_EPILOG = """\
examples:
  covviz track                                   # the embedded synthetic sequence
  covviz track synthetic:occlusion               # a failure on purpose at a known frame; also distractor,
                                                 #   illumination, fast-motion, scale, appearance
  covviz track path/to/Car4 --seed 1             # an OTB folder (img/0001.jpg... + groundtruth_rect.txt)
  covviz track clip.mp4 --box 120,80,40,60       # a video (or 'frames/*.png', quoted): give the first box
  covviz track path/to/Car4 --trackers manifold,ipca   # several trackers side by side on the same frames
  covviz track path/to/Car4 --trackers manifold,manifold@b.json   # two configs of one tracker: manifold@b
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
        "term, the derivative normalisation and the colour term), ipca, identity, csrt, kcf, mil, mosse, medianflow, tld; "
        "NAME@FILE.json: a variant with the config of FILE.json, named NAME@FILE (manifold,manifold@b.json)",
    )
    p.add_argument("--particles", type=positive_int, help="number of particles (default: the tracker's own)")
    add_config_arg(p)
    add_detector_arg(p)
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0): same seed, same boxes")
    p.add_argument("--max-frames", type=positive_int, help="stop after this many frames")
    add_frames_by_arg(p)
    p.add_argument("--out", type=Path, default=Path("runs"), help="results folder (default: runs/)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--no-counterfactual",
        action="store_true",
        help="do not replay the losses (by default each loss is replayed from the tracker's state a few frames "
        "before its drift began, with the search, the model or the estimate fixed from the ground truth, and "
        "the smallest fix that keeps the track is its verdict; needs ground truth)",
    )
    add_recording_args(p)
    p.set_defaults(func=cmd_track)
    return p

def replay_line(d: dict) -> str:
    """A diagnosis's replays in one line: the verdict, each fix with its mean IoU, what was replayed."""
    cf, rp = d["counterfactual"], d["replay"]
    fixes = " · ".join(f"{k} {'KEPT' if o['kept'] else 'lost'} {_iou(o['mean_iou'])}"
                       for k, o in cf.items() if k != "none")
    none = cf.get("none")
    check = "" if none is None or none.get("identical") else " · THE UNCHANGED REPLAY DIFFERS FROM THE RUN"
    return (f"verdict: {d['verdict'].upper()} · fixes (mean IoU of the replay): {fixes} · replayed frames "
            f"{rp['from']}-{rp['to']} ({rp['frames_after_loss']} after the loss) in {rp['seconds']:.1f} s{check}")


def _print_diagnosis(found: dict | None) -> None:
    """The terminal summary of the drift diagnosis: every loss with its cause (the label-free alarms, which
    replace the suspects here, are :func:`_print_alarms`')."""
    if not found:
        return
    for d in found.get("diagnoses", []):
        print(f"  {d['text']}")
        if "verdict" in d:
            print(f"    {replay_line(d)}")
            if d.get("verdict_note"):
                print(f"    note: {d['verdict_note']}")
    labels = found.get("labels", {})
    off = {k: v for k, v in labels.items() if k != "ok" and v}
    if off:
        print("  frames off track over the whole run: "
              + ", ".join(f"{v} {k} failure{'s' * (v != 1)}" for k, v in off.items())
              + (" (a loss's card counts those from its drift to the loss)" if found.get("diagnoses") else ""))

def _print_alarms(found: dict | None, every: bool) -> None:
    """The label-free drift alarms, one line each without ground truth (else their count)."""
    from covviz.diagnosis.detector import describe_alarm

    alarms = (found or {}).get("alarms", [])
    if every:
        for a in alarms[:20]:
            print(f"  {describe_alarm(a)}")
        if len(alarms) > 20:
            print(f"  ... {len(alarms) - 20} more drift alarm(s) in the results JSON (diagnosis.alarms)")
    elif alarms:
        print(f"  {len(alarms)} label-free drift alarm(s) (first at frame {alarms[0]['frame']}); "
              "diagnosis.alarms in the results JSON")

def _recording_observers(
    args, seq, n_frames: int, stages: list, created: list[Path] | None = None, locks=None, watch=None
) -> tuple[list, Path | None]:
    """The Rerun logger for ``track`` (checked and connected before tracking starts), and its file.

    ``watch``: the label-free drift detector (with the logger of its probability when recorded), and
    ``stages``: the observers before the recorder (the drift diagnosis, the replays of its losses):
    run, in that order and before the recorder, on one background thread.
    ``locks`` (an ExitStack) holds the lock of every output of the run
    (:mod:`covviz.locks`), taken after the checks and before the recording file
    is opened, so a second run on the same outputs is refused before it writes.
    """
    diagnoser = stages[0]
    save = None if args.no_save else (args.save or default_recording_path(seq.name, args.trackers, args.seed))
    if args.no_save and args.save is not None:
        raise UsageError("--save and --no-save contradict each other; give one")
    live = _live(args)
    from covviz.runner import BackgroundObserver, Pipeline

    if save is not None:
        _check_recording_path(save, n_frames, len(args.trackers), created)
    _check_viewer(args)
    if locks is not None:
        locks.enter_context(_hold_outputs(args, seq, save, created))
    if save is None and not live:
        # The detector, then the diagnosis, on one thread of their own: a second Python thread would
        # only contend with the tracker's kernel threads for the two cores (and the GIL).
        return [BackgroundObserver(Pipeline([*([] if watch is None else [watch]), *stages]))], None
    from covviz.viz.logger import LoggerConfig, RerunLogger
    from covviz.viz.sinks import BATCH_SECONDS, BATCH_SECONDS_LIVE, attach_sinks, new_recording

    config = LoggerConfig(
        mds_every=args.mds_every, likelihood_every=args.likelihood_every, seed=args.seed, diagnosis=diagnoser.config,
        # a live viewer: its plots a batch behind its images, but every view on the image as it comes
        **({"series_seconds": BATCH_SECONDS_LIVE, "views_in_columns": False} if live else {}),
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
    # The detector and the logger of its probability, the diagnosis (and the replays of its losses,
    # after the last frame), then the recorder that shows what they found (it closes the stream, so it
    # ends last): on one thread of their own that overlaps the tracker (runner.BackgroundObserver);
    # the results writer comes after them. One thread, not one per observer: on two cores a second
    # Python thread only contends with the tracker's kernel threads (the whole run 0.93x the time).
    drift = []
    if watch is not None:
        from covviz.viz.drift import DriftRecorder

        drift = [watch, DriftRecorder(stream, series_seconds=config.series_seconds)]
    return [BackgroundObserver(Pipeline([*drift, *stages, RerunLogger(stream, config, run_info=info)]))], save

def _hold_outputs(args, seq, save: Path | None, created: list[Path] | None):
    """The locks of the run's outputs: each tracker's results, and the recording (:func:`covviz.locks.hold_outputs`)."""
    from covviz.cli.common import _mkdirs
    from covviz.experiments.results import result_paths
    from covviz.locks import hold_outputs

    outputs = []
    for name in args.trackers:
        _, js = result_paths(args.out, seq.name, name, args.seed)
        _mkdirs(js.parent, created)
        outputs.append((js, "choose another --out"))  # the .json stands for its .txt too
    if save is not None:
        outputs.append((save, "choose another --save"))
    return hold_outputs(outputs)

def cmd_track(args) -> int:
    # One native thread for BLAS and OpenCV while tracking: more only contend with the
    # tracker's own threads on 9x9 matrices (one BLAS thread halves the CPU time at the same speed).
    # A run of OpenCV's trackers alone keeps OpenCV's threads: they are its trackers' own.
    from covviz.threads import limit_threads
    from covviz.trackers import native_threads_wanted

    with limit_threads(1, opencv=not native_threads_wanted(args.trackers)):
        return _track(args)

def _report_unscored(seq, n_frames: int) -> None:
    """Say which frames are tracked without ground truth because the ground-truth file ends before them."""
    rows = getattr(seq, "n_gt_lines", None)
    if rows is not None and rows < n_frames:
        log.info("%s: the ground truth has %d rows for %d frames: frames %d-%d are tracked but not scored",
                 seq.name, rows, n_frames, rows + 1, n_frames)

def _recorded(args) -> bool:
    return not args.no_save or bool(args.spawn or args.connect or args.serve_web)

def _check_memory(args, frame_shape, n_frames: int = 0) -> None:
    """Fail before tracking if ``--particles`` needs more memory than the machine has free."""
    if args.particles is None:
        return
    from covviz.resources import available_memory, run_memory
    from covviz.trackers import STOCHASTIC
    from covviz.trackers.variants import base_name

    n = sum(base_name(name) in STOCHASTIC for name in args.trackers)
    avail = available_memory()
    if not n or avail is None:
        return
    rec = _recorded(args)
    need = run_memory(args.particles, frame_shape, n, rec, n_frames)
    if need > avail:
        fixed = run_memory(0, frame_shape, n, rec, n_frames)
        most = max(0, int((avail - fixed) / ((need - fixed) / args.particles)))
        raise UsageError(
            f"--particles {args.particles} needs about {need / 1e9:.1f} GB of memory and {avail / 1e9:.1f} GB is "
            f"available; use at most about {most} particles" + (" or fewer trackers" if n > 1 else "")
        )

def _recording_complete(path: Path) -> bool:
    from covviz.viz.sinks import recording_complete

    return bool(recording_complete(path))

def _track(args) -> int:
    from covviz.diagnosis.detector import drift_watch
    from covviz.diagnosis.drift import Diagnoser
    from covviz.model.image import check_init_box

    seq = open_sequence(args.sequence, box=args.box, frames_by=args.frames_by)
    if len(seq) < 2:
        raise UsageError(f"{seq.name}: a sequence needs at least 2 frames, found {len(seq)}")
    if args.max_frames == 1:
        raise UsageError("--max-frames 1 tracks nothing: frame 1 is where the box is given; give at least 2")
    n_frames = len(seq) if args.max_frames is None else min(len(seq), args.max_frames)
    seq.check_frames(n_frames)
    _report_unscored(seq, n_frames)
    first = seq.frame(0)  # fail early on an unreadable first frame or a bad box
    check_init_box(seq.init_box, first.image.shape)
    _check_memory(args, first.image.shape, n_frames)
    created: list[Path] = []  # folders made by the checks: removed again if nothing is written
    locks = contextlib.ExitStack()  # one writer per output: held until the last file is written
    try:
        _check_out_dir(args.out, created)
        trackers = _make_trackers(args.trackers, args.seed, args.particles, getattr(args, "config", None))
        _threads_for_recording(args, trackers)
        # The template cloud's scores on on-track frames: only a recorder shows them.
        stages = [Diagnoser(on_track_scores=_recorded(args))]
        replays = _counterfactuals(args, seq, n_frames, trackers)
        if replays is not None:
            stages.append(replays)
        watch = drift_watch(args.detector)  # the label-free drift probability and alarms
        # Last of the checks (an unwritable file, a viewer that is not there, an output another run
        # is writing), then the file is opened.
        recorders, rrd = _recording_observers(args, seq, n_frames, stages, created, locks, watch)
    except BaseException:
        locks.close()
        _remove_empty(created)
        raise
    try:
        with locks:
            return _run_tracking(args, seq, trackers, replays, recorders, rrd, created)
    finally:
        _remove_empty(created)  # those the lock files alone kept (a run stopped before its first write)

def _live(args) -> bool:
    """The run streams to a viewer (``--spawn``, ``--connect``, ``--serve-web``)."""
    return bool(args.spawn or args.connect or args.serve_web)


def _threads_for_recording(args, trackers) -> None:
    """A recorded run on two cores observes with one thread (:func:`covviz.api.observe_threads_for_recording`).

    A ``threads`` given in ``--config`` or in a variant's file is kept.
    """

    from covviz.api import observe_threads_for_recording

    live = _live(args)
    if args.no_save and not live:
        return
    config_path = getattr(args, "config", None)
    given = config_path is not None and "threads" in config_doc(config_path)  # read_config checked it
    specs = tracker_specs(args.trackers)
    keep = ["threads" in s.config_dict() if s.config_path is not None else given for s in specs]
    observe_threads_for_recording(trackers, keep)


def _counterfactuals(args, seq, n_frames: int, trackers):
    """The replays of every loss (on by default when the frames after the first have ground truth)."""
    import numpy as np

    from covviz.diagnosis.counterfactual import Counterfactuals

    if args.no_counterfactual or not np.isfinite(seq.groundtruth[1:n_frames]).all(axis=1).any():
        return None
    config_path = getattr(args, "config", None)
    # Fresh trackers for those that cannot be forked (a restart at the truth): made as this run's.
    factories = [(lambda name=name: _make_trackers([name], args.seed, args.particles, config_path)[0])
                 for name in args.trackers]
    return Counterfactuals(trackers, factories)

def _run_tracking(args, seq, trackers, replays, recorders, rrd, created) -> int:
    from covviz.api import run_trackers  # shared with covviz.track: warm the kernels, run, close the trackers
    from covviz.experiments.results import ResultWriter
    from covviz.metrics import nothing_to_score
    from covviz.runner import FreeSpaceGuard, ResultCollector
    from covviz.signals import exit_code

    # The results are on disk while the run goes (every second, and at the end): what a kill, a
    # signal or a full disk leaves is the frames done. The pipeline's order: the free-space guard,
    # the diagnosis (and the recorder after it, on their own thread), then the results writer, which
    # is handed the diagnosis by the observers before it, so the final files hold all of it.
    writer = ResultWriter(args.out)
    guard = FreeSpaceGuard([args.out, *([rrd] if rrd is not None else [])])
    collector = ResultCollector()
    observers = [*getattr(args, "observers", []), guard, *recorders, writer, collector]
    where = args.out / seq.name
    t0 = time.perf_counter()
    code = 0
    try:
        results = run_trackers(trackers, seq, args.seed, observers, max_frames=args.max_frames,
                               progress=not args.no_progress,
                               checkpoints=None if replays is None else replays.config.checkpoints)
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
            _print_alarms(doc.get("diagnosis"), every=True)
            continue
        print(
            f"{head}\n"
            f"  success AUC {m['success_auc']:.3f}   P@20 {m['precision_20']:.3f}   "
            f"r_on_track {m['r_on_track']:.3f}   rms_on_track {m['rms_on_track']:.3f}   "
            f"mean IoU {m['mean_iou']:.3f}   ({m['n_skipped']} frames without ground truth skipped)"
        )
        found = doc.get("diagnosis") or {}
        if found.get("diagnoses") and m["r_on_track"] > 0.5:
            print("  (r_on_track is the paper's centre-error rule: a frame is on track while the centre error is "
                  "within the truth's size; LOST is the IoU rule, IoU < 0.1: a box far too large or small "
                  "keeps its centre on the target and still loses it)")
        _print_diagnosis(doc.get("diagnosis"))
        _print_alarms(doc.get("diagnosis"), every=False)
    print(f"results in {where}/  ({wall:.1f} s wall)")
    if rrd is not None and not code:
        print(f"recording in {rrd}   open it with: rerun {_q(rrd)}")
    return code


# --------------------------------------------------------------------------- #
# bench and report
# --------------------------------------------------------------------------- #


def _iou(v) -> str:
    return "nan" if v is None else f"{v:.2f}"
