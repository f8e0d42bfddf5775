"""The viewer inline in a Jupyter notebook (``rerun.notebook``; ``pip install rerun-notebook``)."""

from __future__ import annotations

import uuid
from pathlib import Path

__all__ = ["show_recording"]


def show_recording(path: str | Path, width: int | None = None, height: int | None = None):
    """Open the recording ``path`` in a notebook viewer widget and display it; returns the widget.

    The file goes through Rerun's own ``.rrd`` loader into a fresh stream the widget
    listens to, with the recording's own blueprint (layout).

    Raises
    ------
    ImportError
        Without the ``rerun-notebook`` package (the message says what to install).
    FileNotFoundError
        No such file.
    """
    import rerun as rr
    from rerun.notebook import HAS_NOTEBOOK, Viewer

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such recording")
    if not HAS_NOTEBOOK:
        raise ImportError("the inline viewer needs the rerun-notebook package: pip install rerun-notebook "
                          f"(or open the file with: rerun {path})")
    stream = rr.RecordingStream("covviz", recording_id=str(uuid.uuid4()))
    viewer = Viewer(width=width, height=height, recording=stream)
    stream.log_file_from_path(path)
    viewer.display()
    return viewer
