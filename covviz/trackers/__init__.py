"""Trackers behind one protocol: ``init(frame, box)`` / ``update(frame) -> box``.

:func:`make_tracker` builds any tracker by name; modules are imported lazily so
that, for example, the manifold tracker does not pay for OpenCV's trackers.
"""

from __future__ import annotations

import importlib

from covviz.trackers.base import IdentityTracker, Tracker

__all__ = ["STOCHASTIC", "TRACKERS", "IdentityTracker", "Tracker", "make_tracker", "tracker_names"]

#: name -> "module:factory"; each factory takes (n_particles=None, rng=None).
TRACKERS = {
    "manifold": "covviz.trackers.manifold:make",
    "manifold-paper": "covviz.trackers.manifold:make_paper",
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
STOCHASTIC = frozenset({"manifold", "manifold-paper", "ipca"})


def tracker_names(names) -> list[str]:
    """Normalise tracker names (strip, lower-case, drop blanks and repeats) and check them.

    Raises
    ------
    ValueError
        If no name is left, or a name is not in :data:`TRACKERS` (the message
        lists the known names).
    """
    out = list(dict.fromkeys(n.strip().lower() for n in names if n.strip()))
    if not out:
        raise ValueError("no trackers given; pass --trackers NAME[,NAME…]")
    unknown = [n for n in out if n not in TRACKERS]
    if unknown:
        raise ValueError(f"unknown tracker {', '.join(map(repr, unknown))}; choose from {', '.join(TRACKERS)}")
    return out


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
