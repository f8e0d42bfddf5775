"""Where a recording goes: new streams, file and viewer sinks, closing them, and whether a viewer listens.

``rr.script_setup`` attaches one sink; a tracking run may want a file *and* a
live viewer at once, so :func:`attach_sinks` attaches several, and
:func:`close_stream` finishes them and checks that the file is complete.

What survives what (rerun 0.41, checked): the file sink writes each batch
(:data:`BATCH_SECONDS`) as it comes, so a run killed with SIGKILL leaves a file
that holds every batch written before the kill but no footer. ``rerun FILE``
opens it, ``rerun rrd verify --check-footers false FILE`` accepts it (also when
the kill cut a message in half), and ``rerun rrd migrate FILE`` rewrites it with
a footer, after which ``rerun rrd verify FILE`` passes. A file sink that meets a
full disk stops writing; a ``flush`` with a timeout on it times out and leaves
the stream unable to close (``disconnect`` and the interpreter's exit hang), so
:func:`close_stream` only ever disconnects, which returns, and then reads the
file's last bytes for the footer.
"""

from __future__ import annotations

import logging
import shlex
import threading
import uuid
import weakref
from dataclasses import dataclass
from pathlib import Path

import rerun as rr

from covviz.errors import InputError, WriteError, free_space
from covviz.viz.viewer import find_viewer

__all__ = [
    "APPLICATION_ID",
    "BATCH_BYTES",
    "BATCH_SECONDS",
    "BATCH_SECONDS_LIVE",
    "DEFAULT_VIEWER_URL",
    "FLUSH_TIMEOUT",
    "attach_sinks",
    "close_stream",
    "find_viewer",
    "new_recording",
    "recording_complete",
    "viewer_reachable",
]

log = logging.getLogger("covviz")

#: Rerun application id of every covviz recording.
APPLICATION_ID = "covviz"
#: Seconds of logging gathered into one chunk per entity. A tracker logs ~10-50 frames a second;
#: Rerun's default (a few ms) would write one tiny chunk per entity and frame, whose per-chunk
#: overhead triples the file size and defeats compression. One second costs ~3% of file size
#: against four (Car4, 200 frames: 7.27 MB against 7.06 MB) and keeps a killed run's recording
#: at most about a second behind; a live viewer shows data one batch late.
BATCH_SECONDS = 1.0
BATCH_SECONDS_LIVE = 1.0
#: Seconds to wait, at the end of a run, for the last batches to reach their sinks.
FLUSH_TIMEOUT = 15.0
#: The last bytes of a finished rerun 0.41 file: the footer's magic and version (a file starts with b"RRF2").
RRD_FOOTER_MAGIC = b"RRF2FOOT"
#: The viewer URL of ``--connect`` without a value (Rerun's default).
DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"


def viewer_reachable(url: str | None = None, timeout: float = 1.0) -> bool:
    """Whether something listens at a viewer URL's host and port (``rerun+http://host:port/proxy``)."""
    import socket
    from urllib.parse import urlsplit

    parts = urlsplit(url or DEFAULT_VIEWER_URL)
    host = parts.hostname or "127.0.0.1"
    port = parts.port or (443 if parts.scheme.endswith("https") else 9876)
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


#: ... or this many bytes, whichever comes first.
BATCH_BYTES = 8_000_000


def new_recording(
    recording_id: str | None = None,
    application_id: str = APPLICATION_ID,
    batch_seconds: float = BATCH_SECONDS,
) -> rr.RecordingStream:
    """A fresh :class:`rerun.RecordingStream` with a unique recording id (a UUID4 unless given).

    Log calls are batched into chunks of ``batch_seconds`` (see :data:`BATCH_SECONDS`);
    :meth:`RerunLogger.close` flushes the rest.
    """
    batcher = rr.ChunkBatcherConfig(flush_tick=float(batch_seconds), flush_num_bytes=BATCH_BYTES)
    stream = rr.RecordingStream(
        application_id, recording_id=recording_id or str(uuid.uuid4()), batcher_config=batcher
    )
    stream.set_log_time_enabled(
        False
    )  # our timelines are `frame` and `time`; wall-clock log time only costs bytes
    return stream


def attach_sinks(
    stream: rr.RecordingStream,
    save: str | Path | None = None,
    spawn: bool = False,
    connect: str | bool | None = None,
    serve_web: bool = False,
    port: int = 9876,
) -> None:
    """Send ``stream`` to a file and/or a viewer, as ``rr.script_setup`` does, but several at once.

    Parameters
    ----------
    save : path, optional
        Write an ``.rrd`` file.
    spawn : bool
        Start a viewer on ``port`` and stream to it.
    connect : str or True, optional
        Stream to a running viewer (``True``: the default URL
        ``rerun+http://127.0.0.1:9876/proxy``).
    serve_web : bool
        Host a gRPC server and a web viewer connected to it.
    """
    sinks = []
    viewer = None
    if save is not None:
        sinks.append(rr.FileSink(str(save)))
    if spawn:
        exe = find_viewer()
        if exe is None:
            raise InputError("--spawn: no Rerun viewer found (not installed with rerun-sdk, beside covviz, nor in "
                             "PATH); pip install rerun-sdk, or use --save and open the file later")
        rr.spawn(port=port, connect=False, executable_path=exe, recording=stream)
        viewer = f"rerun+http://127.0.0.1:{port}/proxy"
        sinks.append(rr.GrpcSink(viewer))
    if connect:
        viewer = DEFAULT_VIEWER_URL if connect is True else str(connect)
        sinks.append(rr.GrpcSink(None if connect is True else str(connect)))
    _ATTACHED[stream] = _Sinks(save=None if save is None else Path(save), viewer=viewer)
    server = None
    if serve_web:
        server = rr.GrpcServerSink()
        sinks.append(server)
    if not sinks:
        raise ValueError("nothing to send the recording to: give save, spawn, connect or serve_web")
    stream.set_sinks(*sinks)
    if server is not None:
        rr.serve_web_viewer(open_browser=True, connect_to=server.uri)


@dataclass(frozen=True)
class _Sinks:
    save: Path | None
    viewer: str | None


#: What :func:`attach_sinks` attached to each stream, for :func:`close_stream`.
_ATTACHED: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def recording_complete(path: str | Path) -> bool | None:
    """Whether an ``.rrd`` file ends with its footer (True), lacks it (False), or is not a rerun 0.41 file (None).

    A file without a footer was cut short: a killed run, a full disk. Rerun can
    still open it (see the module docstring).
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
            size = fh.seek(0, 2)
            fh.seek(max(0, size - 64))
            tail = fh.read()
    except OSError:
        return False
    if head != b"RRF2":
        return None
    return RRD_FOOTER_MAGIC in tail[-16:]


def close_stream(stream: rr.RecordingStream, timeout: float = FLUSH_TIMEOUT) -> None:
    """Send what is left to the sinks, disconnect, and check that the recording file is complete.

    ``disconnect`` flushes each sink; it runs on a helper thread so that a sink
    that never returns cannot hold the run for more than ``timeout`` seconds.
    A live viewer that went away is a warning (the file, if any, has everything).

    Raises
    ------
    WriteError
        If the file sink could not write the whole recording (a full disk):
        the message names the file and says what it still holds.
    """
    sinks = _ATTACHED.pop(stream, None)
    done = threading.Event()

    def disconnect() -> None:
        try:
            stream.disconnect()
        finally:
            done.set()

    threading.Thread(target=disconnect, name="covviz-rerun-close", daemon=True).start()
    finished = done.wait(timeout)
    if sinks is None:
        return
    if sinks.save is not None and recording_complete(sinks.save) is False:
        path = sinks.save
        rest = f"rerun opens what it holds; 'rerun rrd migrate {shlex.quote(str(path))}' completes it"
        if _nearly_full(path):
            raise WriteError(
                f"no space left on the device for the recording {path} ({free_space(path)}): it was cut "
                f"short; {rest} once there is space"
            )
        raise WriteError(
            f"the recording {path} was cut short{'' if finished else f' (still writing after {timeout:.0f} s)'}; "
            f"{rest}"
        )
    if sinks.viewer is not None and not viewer_reachable(sinks.viewer, timeout=0.5):
        log.warning("the viewer at %s went away before the end of the run%s", sinks.viewer,
                    "; the recording file has every frame" if sinks.save is not None else "")


#: Free bytes under which a recording cut short is blamed on a full disk.
NEARLY_FULL_BYTES = 1_000_000


def _nearly_full(path: Path) -> bool:
    import shutil

    try:
        return shutil.disk_usage(Path(path).parent).free < NEARLY_FULL_BYTES
    except OSError:
        return False
