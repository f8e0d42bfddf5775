"""``covviz events``: the events and drift diagnoses of a recording."""

from __future__ import annotations

import argparse
from pathlib import Path

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

#: The kinds of event a recording holds (the epilog says what each is).
EVENT_KINDS = ("drift", "lost", "recovered", "storm", "storm_end", "diagnosis", "verdict", "alarm", "suspect")


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
    p.add_argument("--kind", action="append", metavar="KIND", choices=EVENT_KINDS,
                   help=f"only events of this kind (repeatable): {', '.join(EVENT_KINDS)}")
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
        names = sorted({e["tracker"] for e in events})
        if args.tracker not in names and names:
            from covviz.cli.common import UsageError
            from covviz.trackers.variants import did_you_mean

            raise UsageError(f"--tracker {args.tracker}: no events of that tracker in {args.recording}"
                             f"{did_you_mean(args.tracker, names)} (events of: {', '.join(names)})")
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
