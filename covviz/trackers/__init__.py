"""Trackers behind one protocol: ``init(frame, box)`` / ``update(frame) -> box``.

:func:`make_tracker` builds any tracker by name; modules are imported lazily so
that, for example, the manifold tracker does not pay for OpenCV's trackers.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass

import numpy as np

from covviz.trackers.base import IdentityTracker, Tracker

__all__ = [
    "CONFIGURABLE",
    "REGISTRY",
    "STOCHASTIC",
    "TRACKERS",
    "IdentityTracker",
    "Tracker",
    "TrackerEntry",
    "make_tracker",
    "native_threads_wanted",
    "tracker_names",
    "tracker_rng",
]

@dataclass(frozen=True)
class TrackerEntry:
    """One tracker of the registry and its properties.

    Attributes
    ----------
    factory : str
        ``"module:function"``; the function takes ``(n_particles=None, rng=None)``,
        and ``config=None`` when ``configurable``.
    stochastic : bool
        Its output depends on the seed (a bench runs several seeds).
    configurable : bool
        Its factory takes a ``ManifoldConfig`` (``--config``).
    snapshots : bool
        ``snapshot()``/``restore()`` work: its losses can be replayed (else a restart at the truth).
    native_threads : bool
        Its work runs in a native library's own thread pool (OpenCV's trackers): ``covviz track``
        leaves OpenCV its threads when every tracker of the run has this (the boxes do not depend
        on them), and limits OpenCV to one thread otherwise (:func:`native_threads_wanted`).
    """

    factory: str
    stochastic: bool = False
    configurable: bool = False
    snapshots: bool = False
    native_threads: bool = False


#: Every tracker covviz knows, by name.
REGISTRY: dict[str, TrackerEntry] = {
    "manifold": TrackerEntry("covviz.trackers.manifold:make", stochastic=True, configurable=True, snapshots=True),
    "manifold-paper": TrackerEntry("covviz.trackers.manifold:make_paper", stochastic=True, configurable=True,
                                   snapshots=True),
    "ipca": TrackerEntry("covviz.trackers.ipca:make", stochastic=True, snapshots=True),
    "identity": TrackerEntry("covviz.trackers.base:make_identity", snapshots=True),
    "csrt": TrackerEntry("covviz.trackers.opencv:make_csrt", native_threads=True),
    "kcf": TrackerEntry("covviz.trackers.opencv:make_kcf", native_threads=True),
    "mil": TrackerEntry("covviz.trackers.opencv:make_mil", native_threads=True),
    "mosse": TrackerEntry("covviz.trackers.opencv:make_mosse", native_threads=True),
    "medianflow": TrackerEntry("covviz.trackers.opencv:make_medianflow", native_threads=True),
    "tld": TrackerEntry("covviz.trackers.opencv:make_tld", native_threads=True),
}
#: Views of :data:`REGISTRY`: the names, and those with each property.
TRACKERS = {name: e.factory for name, e in REGISTRY.items()}
STOCHASTIC = frozenset(name for name, e in REGISTRY.items() if e.stochastic)
CONFIGURABLE = frozenset(name for name, e in REGISTRY.items() if e.configurable)


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


def native_threads_wanted(names) -> bool:
    """Whether a run of these trackers (registry or variant names) should leave OpenCV its threads.

    True when every one runs in OpenCV's own thread pool (:attr:`TrackerEntry.native_threads`):
    limited to one thread, CSRT's ``update()`` on Car4 takes 1.3x as long (26.3 against 20.2 ms on a
    2-core Xeon), with the same boxes.
    With a covviz tracker in the run, OpenCV only contends with its observation threads.
    """
    from covviz.trackers.variants import base_name

    entries = [REGISTRY.get(base_name(n)) for n in names]
    return bool(entries) and all(e is not None and e.native_threads for e in entries)


def tracker_rng(seed: int | None) -> np.random.Generator | None:
    """The random stream of a tracker run with ``seed``: the one seed rule of covviz.

    ``default_rng(SeedSequence(seed).spawn(1)[0])``, for every tracker and every
    command: ``covviz track --seed s`` (whatever the other ``--trackers`` and
    their order), ``covviz bench`` (seed ``s`` of ``--seeds``) and the library
    give a tracker the same stream for the same seed, so any run can be
    replayed by another command. ``None`` (deterministic trackers in a bench):
    no generator.
    """
    if seed is None:
        return None
    return np.random.default_rng(np.random.SeedSequence(int(seed)).spawn(1)[0])


def make_tracker(name: str, rng=None, n_particles: int | None = None, seed: int | None = None, config=None):
    """Build the tracker called ``name`` (see :data:`TRACKERS`).

    Give ``seed`` (the rule of :func:`tracker_rng`) or an explicit ``rng``, not both.
    ``config``: the tracker's config object (trackers in :data:`CONFIGURABLE` only;
    ``n_particles``, if given, overrides its particle count).

    Raises
    ------
    ValueError
        If ``name`` is unknown (the message lists the known names), or ``config``
        is given to a tracker that takes none.
    """
    if name not in TRACKERS:
        raise ValueError(f"unknown tracker {name!r}; choose from {', '.join(TRACKERS)}")
    if seed is not None:
        if rng is not None:
            raise ValueError("give seed or rng, not both")
        rng = tracker_rng(seed)
    module, factory = TRACKERS[name].split(":")
    kw = {}
    if config is not None:
        if name not in CONFIGURABLE:
            raise ValueError(f"tracker {name!r} takes no config; only {', '.join(sorted(CONFIGURABLE))} do")
        kw["config"] = config
    return getattr(importlib.import_module(module), factory)(n_particles=n_particles, rng=rng, **kw)
