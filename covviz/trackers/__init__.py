"""Trackers behind one protocol: ``init(frame, box)`` / ``update(frame) -> box``.

:func:`make_tracker` builds any tracker by name; modules are imported lazily so
that, for example, the manifold tracker does not pay for OpenCV's trackers.
"""

from __future__ import annotations

import importlib

from covviz.trackers.base import IdentityTracker, Tracker

__all__ = ["IdentityTracker", "STOCHASTIC", "TRACKERS", "Tracker", "make_tracker"]

#: name -> "module:factory"; each factory takes (n_particles=None, rng=None).
TRACKERS = {
    "manifold": "covviz.trackers.manifold:make",
    "ipca": "covviz.trackers.ipca:make",
    "identity": "covviz.trackers.base:make_identity",
    "csrt": "covviz.trackers.opencv:make_csrt",
    "kcf": "covviz.trackers.opencv:make_kcf",
    "mil": "covviz.trackers.opencv:make_mil",
    "mosse": "covviz.trackers.opencv:make_mosse",
    "medianflow": "covviz.trackers.opencv:make_medianflow",
    "tld": "covviz.trackers.opencv:make_tld",
}
#: Trackers whose output depends on the seed (run several seeds of these).
STOCHASTIC = frozenset({"manifold", "ipca"})


def make_tracker(name: str, rng=None, n_particles: int | None = None):
    """Build the tracker called ``name`` (see :data:`TRACKERS`).

    Raises
    ------
    ValueError
        If ``name`` is unknown (the message lists the known names).
    """
    if name not in TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose from {', '.join(TRACKERS)}")
    module, factory = TRACKERS[name].split(":")
    return getattr(importlib.import_module(module), factory)(n_particles=n_particles, rng=rng)
