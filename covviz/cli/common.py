"""Shared pieces of the command line: argument types, output checks, config files, tracker construction."""

from __future__ import annotations

import argparse
import logging
import math
import shlex
from pathlib import Path

import numpy as np

from covviz.errors import InputError

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

class TrackerList(list):
    """The names of ``--trackers`` (``manifold``, ``manifold@b``), with each one's spec in ``specs``."""

    specs: dict


def tracker_list(text: str) -> TrackerList:
    """argparse type for ``--trackers a,b,a@FILE.json``: the checked names (variants named after their file).

    Unknown names get a did-you-mean; a name given twice is refused
    (:func:`covviz.trackers.variants.parse_specs`).
    """
    from covviz.trackers.variants import parse_specs

    try:
        specs = parse_specs(text.split(","))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    out = TrackerList(s.name for s in specs)
    out.specs = {s.name: s for s in specs}
    return out


def tracker_specs(names) -> list:
    """The :class:`~covviz.trackers.variants.TrackerSpec` of each name of :func:`tracker_list` (or plain names)."""
    from covviz.trackers.variants import parse_specs

    specs = getattr(names, "specs", None)
    return [specs[n] for n in names] if specs else parse_specs(names)


# --------------------------------------------------------------------------- #
# track
# --------------------------------------------------------------------------- #

def add_config_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--config",
        metavar="FILE.json|JSON",
        help="ManifoldConfig of the manifold trackers: a JSON object of its fields, the others default, in a "
        "file (e.g. the best.json of 'covviz tune') or inline ('{\"camera_share\": 0.5}'); --particles "
        "overrides its n_particles",
    )


def add_frames_by_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--frames-by",
        choices=("number", "order"),
        default="number",
        help="how an OTB/VOT folder's frames get their ground-truth rows: 'number' (default): img/0015.jpg is "
        "frame 15 and gets row 15, and a gap, a duplicate or unnumbered file, a blank line or more rows than "
        "frames is refused; 'order': the k-th image file in name order gets row k, whatever its number, and "
        "extra rows are dropped",
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
        from covviz.viz.defaults import MDS_EVERY

        g.add_argument(
            "--mds-every",
            type=nonneg_int,
            default=MDS_EVERY,
            metavar="K",
            help=f"MDS picture of the template cloud every K frames (default {MDS_EVERY}; 0: never)",
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
    import os
    import shutil

    if path.suffix != ".rrd":
        raise UsageError(f"--save {_cut(path)}: a recording file must end in .rrd")
    _check_name_length(path, "--save")
    if path.is_dir():
        raise UsageError(f"--save {path}: is a folder; give a file name ending in .rrd")
    parent = path.parent if str(path.parent) else Path(".")
    try:
        _mkdirs(parent, created)
        probe = parent / f".covviz-write-test-{os.getpid()}"
        with open(probe, "wb") as fh:
            fh.write(b"\0" * 65536)
            fh.flush()
        probe.unlink()
        if path.exists():
            with open(path, "ab"):
                pass
    except OSError as exc:
        raise UsageError(
            f"cannot write the recording {_cut(path)}: {exc.strerror or exc}; choose another --save or --no-save"
        ) from None
    need = n_frames * max(1, n_trackers) * RECORDING_BYTES_PER_FRAME + RECORDING_MARGIN_BYTES
    free = shutil.disk_usage(parent).free
    if free < need:
        raise UsageError(
            f"not enough free space for the recording in {parent}: about {need / 1e6:.0f} MB needed, "
            f"{free / 1e6:.0f} MB free; free some space, choose another --save, or --no-save"
        )

def _check_viewer(args) -> None:
    """``--spawn``: fail before the work starts if no viewer can be found (:func:`covviz.viz.snapshot.find_viewer`);
    ``--connect``: if no viewer listens at the URL."""
    if getattr(args, "spawn", False):
        from covviz.viz.viewer import find_viewer

        if find_viewer() is None:
            raise UsageError("--spawn: no Rerun viewer found (not installed with rerun-sdk, beside covviz, nor in "
                             "PATH); pip install rerun-sdk, or use --save and open the file later")
    if not getattr(args, "connect", None):
        return
    from covviz.viz.sinks import DEFAULT_VIEWER_URL, viewer_reachable

    url = DEFAULT_VIEWER_URL if args.connect is True else str(args.connect)
    if not viewer_reachable(url):
        raise UsageError(f"--connect: no viewer listens at {url}; start one with 'rerun', or use --spawn")

def default_recording_path(sequence_name: str, trackers: list[str], seed: int) -> Path:
    """``recordings/<sequence>-<tracker+tracker>-s<seed>.rrd``.

    A sequence name too long for a file name is cut, with 8 hex digits of its
    hash so that two long names stay two files.
    """
    import hashlib

    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in sequence_name) or "sequence"
    tail = f"-{'+'.join(trackers)}-s{seed}.rrd"
    room = NAME_MAX - len(tail.encode()) - RESERVED_NAME_BYTES
    if len(safe.encode()) > room:
        digest = hashlib.sha1(sequence_name.encode()).hexdigest()[:8]
        safe = safe.encode()[: max(1, room - 9)].decode(errors="ignore") + "_" + digest
    return Path("recordings") / f"{safe}{tail}"

#: Longest file name (bytes) on the file systems we write to (ext4, xfs, tmpfs, APFS, NTFS: 255).
NAME_MAX = 255
#: Bytes a file name must leave for the suffixes written beside it (``.part``).
RESERVED_NAME_BYTES = 5

def _check_name_length(path: Path, option: str) -> None:
    """A one-line :class:`UsageError` if the file name of ``path`` is too long to create (ENAMETOOLONG)."""
    import os

    name = os.fsencode(Path(path).name)
    for part in Path(path).parts[:-1]:
        if len(os.fsencode(part)) > NAME_MAX:
            raise UsageError(f"{option} {_cut(path)}: a folder name in it is {len(os.fsencode(part))} bytes, longer "
                             f"than the {NAME_MAX} a file system allows; give a shorter path")
    if len(name) > NAME_MAX - RESERVED_NAME_BYTES:
        raise UsageError(f"{option} {_cut(path)}: the file name is {len(name)} bytes, longer than the "
                         f"{NAME_MAX - RESERVED_NAME_BYTES} covviz can write (the file system allows {NAME_MAX}); "
                         "give a shorter name")

def _cut(path, keep: int = 80) -> str:
    """A path for a one-line message: a very long one is cut in the middle."""
    s = str(path)
    return s if len(s) <= keep else f"{s[: keep // 2]}…{s[-keep // 2:]}"

def _check_out_dir(out: Path, created: list[Path] | None = None) -> None:
    try:
        _mkdirs(out, created)
        probe = out / ".covviz-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise UsageError(f"cannot write to {out}: {exc.strerror or exc}; choose another --out") from None

def config_doc(value: str | Path):
    """What ``--config`` gives: a JSON object written inline (the text starts with ``{``) or the JSON in a file.

    Raises :class:`UsageError` (one line) on a missing file or text that is not JSON.
    """
    import json

    text = str(value)
    inline = text.lstrip().startswith("{")
    where = "--config" if inline else f"--config {text}"
    try:
        return json.loads(text if inline else Path(text).read_text())
    except OSError as exc:
        raise UsageError(f"{where}: {exc.strerror or exc} (give a JSON file, or a JSON object in quotes)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UsageError(f"{where}: not JSON ({exc}); give a JSON object of ManifoldConfig fields") from None


def read_config(path: str | Path | None, trackers: list[str]):
    """``--config FILE`` (or an inline JSON object): the ManifoldConfig of its fields (None without the option).

    Fields left out keep their defaults; ``--particles`` overrides ``n_particles``.
    Raises :class:`UsageError` (one line) on a missing or bad file or text, or when no tracker
    of ``trackers`` takes a config.
    """
    from covviz.trackers import CONFIGURABLE
    from covviz.trackers.variants import VARIANT_SEP

    if path is None:
        return None
    if any(VARIANT_SEP in t for t in trackers) and not {t for t in trackers if VARIANT_SEP not in t} & CONFIGURABLE:
        raise UsageError(
            f"--config would be ignored: every configurable tracker of {','.join(trackers)} has its own @FILE.json; "
            "drop --config, or add the tracker it is for"
        )
    if not set(trackers) & CONFIGURABLE:
        raise UsageError(
            f"--config sets a ManifoldConfig: it needs one of the trackers {', '.join(sorted(CONFIGURABLE))}"
        )
    from covviz.trackers.manifold import ManifoldConfig

    doc = config_doc(path)
    try:
        return ManifoldConfig.from_dict(doc)
    except (ValueError, TypeError) as exc:
        raise UsageError(f"--config {path}: {exc}") from None

def _make_trackers(names: list[str], seed: int, particles: int | None, config_path: Path | None = None) -> list:
    """The trackers of a run, each with the stream of ``seed`` (:func:`covviz.trackers.tracker_rng`).

    A variant (``manifold@b.json``) runs with its own config file; the others with ``--config``.
    """
    from covviz.trackers.variants import make_from_spec

    config = read_config(config_path, names)
    try:
        specs = tracker_specs(names)
        return [make_from_spec(s, seed=seed, n_particles=particles, config=config) for s in specs]
    except ValueError as exc:  # a config value the tracker refuses (e.g. --particles), a bad variant file
        raise UsageError(str(exc)) from None

def _q(path) -> str:
    """A path as a shell would need it (quoted if it has spaces)."""
    return shlex.quote(str(path))

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
