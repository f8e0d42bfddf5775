"""Where a recording goes: new streams, file and viewer sinks, and whether a viewer listens.

``rr.script_setup`` attaches one sink; a tracking run may want a file *and* a
live viewer at once, so :func:`attach_sinks` attaches several.
"""

from __future__ import annotations

import uuid
from pathlib import Path

import rerun as rr

__all__ = [
    "APPLICATION_ID",
    "BATCH_BYTES",
    "BATCH_SECONDS",
    "BATCH_SECONDS_LIVE",
    "DEFAULT_VIEWER_URL",
    "FLUSH_TIMEOUT",
    "attach_sinks",
    "new_recording",
    "viewer_reachable",
]

#: Rerun application id of every covviz recording.
APPLICATION_ID = "covviz"
#: Seconds of logging gathered into one chunk per entity. A tracker logs ~10-30 frames a second;
#: Rerun's default (a few ms) would write one tiny chunk per entity and frame, whose per-chunk
#: overhead triples the file size and defeats compression. Longer batches for a file alone,
#: shorter when a live viewer is attached (it shows data one batch late).
BATCH_SECONDS = 4.0
BATCH_SECONDS_LIVE = 1.0
#: Seconds to wait, at the end of a run, for the last batches to reach their sinks.
FLUSH_TIMEOUT = 15.0
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
    if save is not None:
        sinks.append(rr.FileSink(str(save)))
    if spawn:
        stream.spawn(port=port, connect=False)
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{port}/proxy"))
    if connect:
        sinks.append(rr.GrpcSink(None if connect is True else str(connect)))
    server = None
    if serve_web:
        server = rr.GrpcServerSink()
        sinks.append(server)
    if not sinks:
        raise ValueError("nothing to send the recording to: give save, spawn, connect or serve_web")
    stream.set_sinks(*sinks)
    if server is not None:
        rr.serve_web_viewer(open_browser=True, connect_to=server.uri)
