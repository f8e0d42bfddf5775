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
"""

__all__ = ["LoggerConfig", "RerunLogger", "attach_sinks", "new_recording"]

_HOME = {"LoggerConfig": "logger", "RerunLogger": "logger", "attach_sinks": "sinks", "new_recording": "sinks"}


def __getattr__(name):
    if name in _HOME:
        import importlib

        return getattr(importlib.import_module(f"covviz.viz.{_HOME[name]}"), name)
    raise AttributeError(f"module 'covviz.viz' has no attribute {name!r}")
