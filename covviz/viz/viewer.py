"""Where the Rerun viewer is (no rerun import here: ``covviz snapshot`` looks it up before loading the SDK)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

__all__ = ["find_viewer"]


def find_viewer() -> str | None:
    """Path of the ``rerun`` viewer, or None: ``$RERUN_CLI_PATH``, the native binary of the installed
    ``rerun_cli`` package, a ``rerun`` beside this Python or beside the running ``covviz`` script (a
    virtual environment's ``bin/``, used without activating it), then ``PATH``."""
    import sys

    env = os.environ.get("RERUN_CLI_PATH")
    if env and Path(env).is_file():
        return env
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).with_name("rerun")
        if exe.is_file():
            return str(exe)
    except ImportError:
        pass
    for folder in (Path(sys.executable).parent, Path(sys.argv[0]).parent if sys.argv and sys.argv[0] else None):
        if folder is not None and (folder / "rerun").is_file() and os.access(folder / "rerun", os.X_OK):
            return str(folder / "rerun")
    return shutil.which("rerun")
