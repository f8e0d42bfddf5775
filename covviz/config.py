"""Declarative validation of the frozen configs: each field's type and range in one table.

A config dataclass (``ManifoldConfig``, ``ObservationConfig``, ``KinematicModel``,
``IPCAConfig``) declares a :class:`Spec` per field next to its defaults and calls
:func:`check` from ``__post_init__``; :func:`from_mapping` builds one from a JSON
object (``--config FILE.json``, a results file, ``covviz tune``'s trials) with the
same table. So a wrong type (``{"quadrants": "false"}``), an unknown key or an
out-of-range value is refused before anything runs, with one line that names the
field — never taken as true, never written into results as if it ran.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, is_dataclass
from typing import Any

import numpy as np

from covviz.errors import InputError

__all__ = ["ConfigError", "Spec", "check", "from_mapping"]


class ConfigError(InputError):
    """A config value of the wrong type, out of range, or an unknown field (one line, exit 2)."""


@dataclass(frozen=True)
class Spec:
    """What one field of a config may hold.

    Attributes
    ----------
    kind : {"float", "int", "bool", "str", "pair", "matrix", "config"}
        ``pair``: two floats (mode 0, mode 1); ``matrix``: a nested tuple of
        floats; ``config``: a nested config dataclass (``cls``).
    lo, hi : float, optional
        Bounds (inclusive unless ``lo_open`` / ``hi_open``).
    choices : tuple of str, optional
    optional : bool
        ``None`` allowed.
    cls : type, optional
        The dataclass of a ``config`` field.
    """

    kind: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] | None = None
    optional: bool = False
    cls: type | None = None

    def describe(self) -> str:
        """The allowed values in words (for error messages)."""
        if self.kind == "bool":
            return "true or false"
        if self.kind == "str":
            return " or ".join(repr(c) for c in self.choices or ())
        if self.kind == "config":
            return f"a JSON object of {self.cls.__name__} fields"
        what = {"float": "a number", "int": "an integer", "pair": "two numbers [mode 0, mode 1]",
                "matrix": "a 9x9 matrix"}[self.kind]
        rng = _range_text(self)
        return what + (f" {rng}" if rng else "")


def _range_text(spec: Spec) -> str:
    lo, hi = spec.lo, spec.hi
    if lo is None and hi is None:
        return ""
    if hi is None:
        return f"{'>' if spec.lo_open else '>='} {lo:g}"
    if lo is None:
        return f"{'<' if spec.hi_open else '<='} {hi:g}"
    return f"in {'(' if spec.lo_open else '['}{lo:g}, {hi:g}{')' if spec.hi_open else ']'}"


def _in_range(v: float, spec: Spec) -> bool:
    if spec.lo is not None and (v <= spec.lo if spec.lo_open else v < spec.lo):
        return False
    return not (spec.hi is not None and (v >= spec.hi if spec.hi_open else v > spec.hi))


def _is_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _ok(v: Any, spec: Spec) -> bool:
    if v is None:
        return spec.optional
    k = spec.kind
    if k == "bool":
        return isinstance(v, (bool, np.bool_))
    if k == "str":
        return isinstance(v, str) and (spec.choices is None or v in spec.choices)
    if k == "int":
        return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)) and _in_range(v, spec)
    if k == "float":
        return _is_number(v) and math.isfinite(v) and _in_range(v, spec)
    if k == "pair":
        return (isinstance(v, (tuple, list)) and len(v) == 2
                and all(_is_number(x) and math.isfinite(x) and _in_range(x, spec) for x in v))
    if k == "matrix":
        try:
            m = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            return False
        return m.ndim == 2 and bool(np.all(np.isfinite(m))) and _in_range(float(m.min()), spec)
    if k == "config":
        return isinstance(v, spec.cls)
    raise AssertionError(f"unknown spec kind {k!r}")


def check(obj, specs: dict[str, Spec]) -> None:
    """Raise :class:`ConfigError` naming the first field of ``obj`` that its spec refuses.

    Every dataclass field of ``obj`` must have a spec (a test checks the tables are complete).
    """
    name = type(obj).__name__
    for f in fields(obj):
        spec = specs[f.name]
        v = getattr(obj, f.name)
        if not _ok(v, spec):
            raise ConfigError(f"{name}.{f.name} must be {spec.describe()}, got {v!r}")


def from_mapping(cls, d, specs: dict[str, Spec], aliases: dict[str, str] | None = None):
    """``cls(**d)`` for a JSON object ``d``: unknown keys refused, nested configs built, lists made tuples.

    ``aliases`` maps a flat key to the nested config field that holds it
    (``{"quadrants": "observation"}``: ``{"quadrants": false}`` sets
    ``observation.quadrants``), so configs written flat before a field moved still read.
    """
    if not isinstance(d, dict):
        raise ConfigError(f"a {cls.__name__} must be a JSON object of fields, got {type(d).__name__}")
    names = [f.name for f in fields(cls)]
    aliases = aliases or {}
    unknown = sorted(set(d) - set(names) - set(aliases))
    if unknown:
        raise ConfigError(
            f"unknown {cls.__name__} field(s) {', '.join(unknown)}; known: {', '.join(sorted(set(names) | set(aliases)))}"
        )
    kw: dict = {}
    nested: dict[str, dict] = {}
    for key, v in d.items():
        if key in aliases:
            nested.setdefault(aliases[key], {})[key] = v
        else:
            kw[key] = v
    for key, sub in nested.items():
        inner = kw.get(key, {})
        if isinstance(inner, dict):
            both = sorted(set(sub) & set(inner))
            if both:
                raise ConfigError(f"{cls.__name__}: {', '.join(both)} given both flat and inside {key!r}; give it once")
            kw[key] = {**inner, **sub}
    for key, v in list(kw.items()):
        spec = specs[key]
        if spec.kind == "config":
            if isinstance(v, dict):
                kw[key] = spec.cls.from_dict(v)
            elif not isinstance(v, spec.cls):
                raise ConfigError(f"{cls.__name__}.{key} must be {spec.describe()}, got {v!r}")
        elif spec.kind == "pair" and isinstance(v, list):
            kw[key] = tuple(v)
        elif spec.kind == "matrix" and isinstance(v, list):
            kw[key] = tuple(tuple(r) if isinstance(r, list) else r for r in v)
    return cls(**kw)


def as_plain(obj) -> Any:
    """A config as JSON-ready data: dataclasses as dicts, tuples as lists."""
    if is_dataclass(obj):
        return {f.name: as_plain(getattr(obj, f.name)) for f in fields(obj)}
    if isinstance(obj, (tuple, list)):
        return [as_plain(x) for x in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
