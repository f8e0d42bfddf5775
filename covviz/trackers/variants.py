"""Tracker names as the user writes them: ``manifold``, or a variant ``manifold@b.json``.

A *variant* is a registered tracker run with the config of a JSON file; it is
named after the file (``manifold@configs/b.json`` -> ``manifold@b``), and that
name is what its results, its recording entities and the report show, so two
configs of one tracker stay apart. ``--trackers manifold,manifold`` is refused
(it would be one tracker twice): the message says to give each a config file.

Pure parsing and construction on top of the registry (:mod:`covviz.trackers`);
no command-line or rerun code.
"""

from __future__ import annotations

import difflib
import json
from dataclasses import dataclass
from pathlib import Path

__all__ = ["VARIANT_SEP", "TrackerSpec", "base_name", "did_you_mean", "make_from_spec", "parse_specs"]

#: Separates a tracker's registry name from its config file: ``manifold@b.json``.
VARIANT_SEP = "@"


def did_you_mean(word: str, choices, n: int = 1) -> str:
    """``"; did you mean 'x'?"`` for the closest of ``choices`` (difflib), or ``""``."""
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=n, cutoff=0.6)
    return f"; did you mean {' or '.join(map(repr, close))}?" if close else ""


def base_name(name: str) -> str:
    """The registry name of a tracker or variant name: ``manifold@b`` -> ``manifold``."""
    return str(name).partition(VARIANT_SEP)[0]


@dataclass(frozen=True)
class TrackerSpec:
    """One tracker of a run.

    Attributes
    ----------
    name : str
        What results and recordings call it: ``manifold``, or ``manifold@b`` for
        ``manifold@b.json``.
    base : str
        Its registry name (:data:`covviz.trackers.TRACKERS`).
    config_path : Path, optional
        The variant's config file (a JSON object of the tracker's config fields).
    """

    name: str
    base: str
    config_path: Path | None = None

    @property
    def stochastic(self) -> bool:
        from covviz.trackers import STOCHASTIC

        return self.base in STOCHASTIC

    @property
    def configurable(self) -> bool:
        from covviz.trackers import CONFIGURABLE

        return self.base in CONFIGURABLE

    def config_dict(self) -> dict | None:
        """The variant's config file as a dict (checked by the tracker's config class), or None.

        Raises
        ------
        ValueError
            A missing or unreadable file, not JSON, or a field the config refuses.
        """
        if self.config_path is None:
            return None
        from covviz.trackers.manifold import ManifoldConfig

        where = f"{self.base}{VARIANT_SEP}{self.config_path}"
        try:
            doc = json.loads(Path(self.config_path).read_text())
        except OSError as exc:
            raise ValueError(f"{where}: {exc.strerror or exc}") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ValueError(f"{where}: not JSON ({exc}); give a JSON object of ManifoldConfig fields") from None
        try:
            return ManifoldConfig.from_dict(doc).as_dict()
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{where}: {exc}") from None


def parse_specs(items) -> list[TrackerSpec]:
    """Check and name the trackers of ``--trackers a,b@FILE.json`` (strings; blanks dropped).

    Raises
    ------
    ValueError
        No tracker; an unknown name (with the closest known one); a config file
        on a tracker that takes none; two trackers of the same name (the message
        says to give each its own ``@config.json``).
    """
    from covviz.trackers import CONFIGURABLE, TRACKERS

    specs: list[TrackerSpec] = []
    for raw in items:
        text = str(raw).strip()
        if not text:
            continue
        base, sep, file = text.partition(VARIANT_SEP)
        base = base.strip().lower()
        if base not in TRACKERS:
            raise ValueError(f"unknown tracker {base!r}{did_you_mean(base, TRACKERS)} (known: {', '.join(TRACKERS)})")
        if not sep:
            specs.append(TrackerSpec(base, base))
            continue
        if base not in CONFIGURABLE:
            raise ValueError(f"{text}: tracker {base!r} takes no config file; only {', '.join(sorted(CONFIGURABLE))} do")
        path = Path(file.strip())
        if not file.strip() or path.suffix.lower() != ".json":
            raise ValueError(f"{text}: a variant is NAME@FILE.json, a JSON object of the tracker's config fields")
        specs.append(TrackerSpec(f"{base}{VARIANT_SEP}{path.stem}", base, path))
    if not specs:
        raise ValueError("no trackers given; pass --trackers NAME[,NAME…]")
    seen: set[str] = set()
    for s in specs:
        if s.name in seen:
            hint = (f"to compare two configs of {s.base!r}, give each a config file: "
                    f"--trackers {s.base},{s.base}{VARIANT_SEP}other.json"
                    if s.configurable else "give each tracker once")
            raise ValueError(f"tracker {s.name!r} is given twice; {hint}")
        seen.add(s.name)
    return specs


def make_from_spec(spec: TrackerSpec, seed=None, n_particles: int | None = None, config=None):
    """Build the tracker of ``spec``: its variant's config file if it has one, else ``config``.

    The tracker is renamed after the variant (``manifold@b``); the seed rule is the
    registry's (:func:`covviz.trackers.tracker_rng`), so a variant and its base
    tracker get the same random stream for the same seed.
    """
    from covviz.trackers import make_tracker

    if spec.config_path is not None:
        from covviz.trackers.manifold import ManifoldConfig

        config = ManifoldConfig.from_dict(spec.config_dict())
    tr = make_tracker(spec.base, seed=seed, n_particles=n_particles, config=config if spec.configurable else None)
    if spec.name != spec.base:
        tr.name = spec.name
    return tr
