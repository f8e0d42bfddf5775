"""covviz: a particle-filter tracker on the Riemannian manifold of covariance
matrices, and the Rerun app to see why it holds on or drifts.

The Python API (:mod:`covviz.api`), loaded on first use so that ``import covviz`` stays light:
``covviz.track(sequence, trackers=..., seed=..., max_frames=..., save=...)`` returns one
:class:`~covviz.api.TrackResult` per tracker (boxes, metrics, diagnosis);
``covviz.read_events(path)`` the events of a recording; ``covviz.show(path)`` the viewer inline in a notebook.
"""

__version__ = "0.1.0"

__all__ = ["TrackResult", "read_events", "show", "track"]


def __getattr__(name: str):
    if name in __all__:
        from covviz import api

        return getattr(api, name)
    raise AttributeError(f"module 'covviz' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *__all__])
