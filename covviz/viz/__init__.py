"""The Rerun app: the only package of covviz (with :mod:`covviz.cli`) that imports ``rerun``.

* :mod:`covviz.viz.paths` — every entity path, in one place;
* :mod:`covviz.viz.logger` — :class:`RerunLogger`, the observer that logs a run;
* :mod:`covviz.viz.sinks` — new recording streams, and the files and viewers they go to;
* :mod:`covviz.viz.palette` — colours and colour ramps;
* :mod:`covviz.viz.checks` — validation of arrays before they are logged;
* :mod:`covviz.viz.blueprint` — the layout the recording opens on;
* :mod:`covviz.viz.description` — the markdown "How to read this" logged into it;
* :mod:`covviz.viz.diagnostics` — costly diagnostics computed only when asked for (no rerun);
* :mod:`covviz.viz.mds_figures` — ``covviz mds``: the paper's manifold figures;
* :mod:`covviz.viz.snapshot` — ``covviz snapshot``: PNGs from the headless viewer.

Importing this package does not import rerun; the submodules that log do.
Before they do, it quietens Rerun's own log lines about its file sink (unless
``RUST_LOG`` is set): a full disk printed three lines of Rust log, which
:func:`covviz.viz.sinks.close_stream` replaces with one line that says what
happened and what the file still holds.
"""

import os

#: Rerun's log filter while covviz runs: warnings, except the file sink's and the stream's sink
#: errors, which covviz checks and reports itself (sinks.close_stream).
RUST_LOG = "warn,re_log_encoding::rrd=off,re_sdk::recording_stream=off"
os.environ.setdefault("RUST_LOG", RUST_LOG)

__all__ = ["LoggerConfig", "RerunLogger", "attach_sinks", "new_recording"]

_HOME = {"LoggerConfig": "logger", "RerunLogger": "logger", "attach_sinks": "sinks", "new_recording": "sinks"}


def __getattr__(name):
    if name in _HOME:
        import importlib

        return getattr(importlib.import_module(f"covviz.viz.{_HOME[name]}"), name)
    raise AttributeError(f"module 'covviz.viz' has no attribute {name!r}")
