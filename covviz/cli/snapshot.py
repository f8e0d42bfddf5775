"""``covviz snapshot``: a PNG of a recording in the headless Rerun viewer."""

from __future__ import annotations

import argparse
from pathlib import Path

from covviz.cli.common import UsageError, _check_png_path, _remove_empty, nonneg_int, positive_int

SNAPSHOT_EPILOG = """\
examples:
  covviz snapshot recordings/synthetic-manifold-s0.rrd --frame 120 --out shot.png
  covviz snapshot run.rrd --size 1920x1080            # the last frame
  covviz events run.rrd                               # which events are there (their numbers K)
  covviz snapshot run.rrd --event 3 --offsets -5,0,5 --out sheet.png   # before / at / after event 3
  covviz snapshot two.rrd --frame 80 --tracker ipca   # ipca's panels (a recording of manifold,ipca)
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
    p.add_argument("--tracker", metavar="NAME",
                   help="whose panels to show (zoom, slices, cloud, heatmaps, terms) in a recording of several "
                   "trackers; with --event: default the event's tracker")
    p.add_argument("--out", type=Path, default=Path("shot.png"), help="PNG to write (default shot.png)")
    p.add_argument("--size", default="1600x900", help="window size WxH in points (default 1600x900)")
    p.add_argument("--timeline", default="frame", help="timeline of --frame (default 'frame')")
    p.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for the viewer (default 60)")
    p.set_defaults(func=cmd_snapshot)
    return p

def cmd_snapshot(args) -> int:
    import tempfile

    from covviz.viz.readback import last_frame, read_events
    from covviz.viz.snapshot import (
        SnapshotError,
        contact_sheet,
        focus_blueprint,
        parse_size,
        snapshot,
        snapshot_frames,
    )

    if not args.recording.is_file():
        raise UsageError(f"{args.recording}: no such recording")
    size = parse_size(args.size)
    created: list[Path] = []
    _check_png_path(args.out, created)
    try:
        if args.tracker is not None:
            focus_blueprint(args.recording, args.tracker)  # a wrong name: one line, before the viewer starts
        if args.event is None:
            out = snapshot(args.recording, args.out, frame=args.frame, size=size, timeline=args.timeline,
                           timeout=args.timeout, focus=args.tracker)
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
            # The event's tracker's panels, unless --tracker says whose.
            focus = args.tracker or ev["tracker"]
            try:
                focus_blueprint(args.recording, focus)
            except SnapshotError:
                focus = None  # a recording without a layout: its own blueprint
            snapshot_frames(args.recording, shots, size, args.timeline, args.timeout, focus=focus)
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
