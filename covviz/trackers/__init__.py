"""Trackers behind one protocol: ``init(frame, box)`` / ``update(frame) -> box``."""

from covviz.trackers.base import IdentityTracker, Tracker

__all__ = ["IdentityTracker", "Tracker"]
