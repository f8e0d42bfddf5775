"""``covviz mds``: the paper's manifold figures (MDS), as a recording and PNGs."""

from __future__ import annotations

import argparse
from pathlib import Path

from covviz.cli.common import (
    UsageError,
    _check_out_dir,
    _check_recording_path,
    _check_viewer,
    _q,
    _remove_empty,
    add_frames_by_arg,
    add_recording_args,
    log,
    nonneg_int,
    parse_box,
    positive_int,
)
from covviz.data.sequences import open_sequence
from covviz.errors import InputError

MDS_EPILOG = """\
examples:
  covviz mds                                       # the synthetic default (frames 1, 101, 201)
  covviz mds path/to/Car4                          # frames 1, 101, 201, 501 of Car4
  covviz mds path/to/Car4 --tracker manifold-paper # the same with the paper's likelihood and walk
  covviz mds path/to/Car4 --frames 1,51,101 --png-dir docs/img --format png,svg,pdf
  covviz mds path/to/Car4 --save car4-mds.rrd --no-png

Prints the paper's claims measured, each with its verdict (FAILS where it does not hold):
the silhouette of target vs background on the Riemannian distances (>= 0.25 holds), per
frame the template cloud's coverage of the target (nearest template over the median distance
of the templates to their mean; <= 1 holds), each embedding's stress-1, and for the "why
manifold" figure the Euclidean and Riemannian distance ratios from the first target patch and
two linear SVMs (vectorised patches, tangent vectors) cross-validated over blocks of frames.

Writes recordings/SEQUENCE-mds.rrd (--save another file, --no-save none; open it with
'rerun FILE') and three figures in --png-dir (default recordings/), in each --format:
SEQUENCE-mds-separation, SEQUENCE-mds-random-walk and SEQUENCE-why-manifold. Frames are
1-based (frame 1 is img/0001.jpg), as everywhere in covviz.
"""

def frame_list(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(v) for v in text.replace(" ", ",").split(",") if v)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--frames must be 1-based frame numbers like 1,101,201; got {text!r}") from None
    if not vals or min(vals) < 1:
        raise argparse.ArgumentTypeError(f"--frames must be 1-based frame numbers like 1,101,201; got {text!r}")
    return vals

def format_list(text: str) -> tuple[str, ...]:
    from covviz.viz.mds_figures import parse_formats

    try:
        return parse_formats(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


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
    p.add_argument("--tracker", choices=("manifold", "manifold-paper"), default="manifold",
                   help="the tracker whose observation model and template walk the figures show, with its shipped "
                   "config (default manifold; manifold-paper: the paper's likelihood)")
    p.add_argument("--format", type=format_list, default=None, metavar="FMT[,FMT…]",
                   help="figure formats, some of png,svg,pdf (default png)")
    p.add_argument("--no-why", action="store_true", help="skip the 'why manifold' figure (its SVMs take a few seconds)")
    p.add_argument("--seed", type=nonneg_int, default=0, help="random seed (default 0)")
    p.add_argument("--png-dir", type=Path, default=Path("recordings"),
                   help="folder for the figures (default recordings/)")
    p.add_argument("--no-png", action="store_true", help="write no figures (the numbers are still printed)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_frames_by_arg(p)
    add_recording_args(p, mds_options=False)
    p.set_defaults(func=cmd_mds)
    return p

def cmd_mds(args) -> int:
    from covviz.threads import limit_threads

    with limit_threads(1):
        return _mds(args)

def _mds(args) -> int:
    from covviz.viz.mds_figures import DEFAULT_FRAMES, MDSFiguresConfig

    seq = open_sequence(args.sequence, box=args.box, frames_by=args.frames_by)
    if len(seq) < 2:
        raise UsageError(f"{seq.name}: a sequence needs at least 2 frames, found {len(seq)}")
    seq.check_frames(len(seq))
    cfg = MDSFiguresConfig(
        frames=tuple(DEFAULT_FRAMES if args.frames is None else args.frames),
        max_target=max(2, args.max_target),
        n_background=args.n_background,
        method=args.method,
        seed=args.seed,
        n_particles=args.particles,
        tracker=args.tracker,
    )
    if args.no_save and args.save is not None:
        raise UsageError("--save and --no-save contradict each other; give one")
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in seq.name) or "sequence"
    save = None if args.no_save else (args.save or Path("recordings") / f"{safe}-mds.rrd")
    created: list[Path] = []  # folders the checks made: removed again if the command ends before writing
    try:
        return _mds_figures(args, seq, cfg, safe, save, created)
    finally:
        _remove_empty(created)

def _mds_figures(args, seq, cfg, safe: str, save: Path | None, created: list[Path]) -> int:
    from covviz.viz.mds_figures import random_walk_data, separation_data

    if save is not None:
        _check_recording_path(save, 10, 1, created)
    _check_viewer(args)
    if not args.no_png:
        _check_out_dir(args.png_dir, created)
    progress = not args.no_progress
    # One observation model for both figures: the one the tracker of figure (b) builds at init.
    walk = random_walk_data(seq, cfg, progress=progress)
    sep = separation_data(seq, cfg, progress=progress, model=walk.model)
    why = None
    if not args.no_why:
        from covviz.viz.why_manifold import why_manifold_data

        try:
            why = why_manifold_data(seq, walk.model, max_frames=cfg.max_target, n_background=cfg.n_background,
                                    seed=cfg.seed, progress=progress)
        except InputError as exc:  # a short sequence still gets the two MDS figures
            log.warning("the 'why manifold' figure is skipped: %s", exc)
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
        from covviz.viz.mds_figures import save_figures

        formats = args.format or ("png",)
        for path in save_figures(sep, walk, args.png_dir, safe, formats, seq.name):
            print(f"figure: {path}")
        if why is not None:
            from covviz.viz.why_manifold import why_manifold_figure

            for path in why_manifold_figure(why, args.png_dir, safe, formats, seq.name):
                print(f"figure: {path}")
    from covviz.viz.mds_figures import claims_text

    for line in claims_text(sep, walk, seq.name):
        print(line)
    if why is not None:
        from covviz.viz.why_manifold import why_manifold_text

        for line in why_manifold_text(why, seq.name):
            print(line)
    n_t = int((sep.kinds == "target").sum())
    frames = sorted({int(f) for f in walk.frames})
    print(f"{seq.name}: {n_t} target and {len(sep.kinds) - n_t} background descriptors; "
          f"templates at frames {', '.join(map(str, frames))}")
    return 0


# --------------------------------------------------------------------------- #
# snapshot
# --------------------------------------------------------------------------- #
