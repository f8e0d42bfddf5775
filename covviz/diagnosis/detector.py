"""The drift probability: a small logistic model on the label-free signals, and alarms with hysteresis.

A :class:`DriftModel` is a versioned JSON file (no pickle): the signals it
reads, the *design* of the features built from them (:func:`history_features`),
their standardisation, the logistic regression's coefficients and the alarm
rule (threshold, release, cooldown). Two designs:

* ``levels`` (the first): each signal's value, its mean over the last
  :data:`HISTORY_MEAN` frames and its max over the last :data:`HISTORY_MAX`, and some
  signals over their median on the run's first :data:`BASELINE_FRAMES` frames;
* ``changes``: each signal's robust z-score against its own recent past,
  ``z_t = (x_t − m) / (1.4826·MAD + 10⁻³|m| + 10⁻⁶)`` with ``m`` and ``MAD`` the
  median and median absolute deviation of ``x`` over frames ``t − lag − window …
  t − lag − 1`` (:data:`CHANGE_WINDOW`, :data:`CHANGE_LAG`; nan until
  :data:`CHANGE_MIN` of them are finite), squashed by ``asinh``. It says how unusual a
  frame is *for this run*, so it carries over between scenes whose signals sit at
  different levels: a small low-contrast car keeps a high ESS while on track, which
  the ``levels`` model of the default tracker read as a loss (160 false alarms on
  Car1 held out). ``covviz calibrate`` chooses the design per family by
  cross-validation over sequences on the runs it fits, with what the model is
  fitted to find — the drift episodes (each loss's frames from 10 before its drift
  began to 5 after it, against the frames on track) or every off-track frame
  (:func:`covviz.diagnosis.calibrate.choose_fit`);
* ``signal``: one signal alone, ``asinh`` of its value (a missing value: probability 0, no evidence).
  The logistic map is monotone, so its alarms are the signal's own threshold alarms, and the
  probability reads as the chance of being off track at that level of the signal. On unseen
  sequences a single steady signal can carry over better than any model of many (the flow gap
  beat the default tracker's twelve-signal model held out, ``docs/tuning.md``), so
  :func:`~covviz.diagnosis.calibrate.choose_fit` weighs each signal of
  :data:`covviz.diagnosis.calibrate.BASELINES` beside the two models, by the same held-out rule.

Any design may carry a **colour gate** (:attr:`DriftModel.gate`): on a frame whose ``colour`` signal (the
box's lost colour contrast against its surroundings, :mod:`covviz.diagnosis.signals`) is below the gate,
the box still stands out from its surroundings as the target did, and the probability is 0 there. The
motion signals fire on a box that shakes or snaps back onto its target as on one that slides off it; the
colour tells them apart. :func:`~covviz.diagnosis.calibrate.fit_model` chooses the gate (or none) on the
training runs together with the alarm rule, by the same rule (:func:`~covviz.diagnosis.calibrate.choose_rule`):
a gate only silences frames (an alarm it silences may still be raised later in the episode, once the colour
agrees), so with it a lower threshold may keep the rule's precision and find more losses.

Shipped models, one per tracker family with a generic fallback, are package data under
``covviz/diagnosis/models/`` (:func:`shipped_model`); ``covviz calibrate``
(:mod:`covviz.diagnosis.calibrate`) writes new ones.

:class:`DriftWatch` is the observer: it runs :class:`~covviz.diagnosis.signals.SignalObserver`
and, frame by frame, the model and the :class:`Hysteresis` rule of each
tracker. It never reads ground truth (``frame.gt``): the same frames give the
same probabilities with and without it, and the tracker's boxes do not depend
on it (it only reads records).

Why logistic regression and not gradient boosting: the dev set is 14
sequences, so a few dozen loss episodes per tracker; a linear model on
standardised, squashed signals has few degrees of freedom, gives probabilities
that need no further calibration, is a handful of numbers in a text file that a
reviewer can read (which signal pushes towards "off track"), and costs a dot
product per frame. Boosted trees would fit the training sequences' quirks and
need their trees serialised and re-implemented to predict without pickle.
"""

from __future__ import annotations

import json
import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path

import numpy as np

from covviz.diagnosis.signals import SIGNALS, SignalConfig, SignalObserver
from covviz.errors import InputError
from covviz.runner import Observer

__all__ = [
    "FAMILIES",
    "FORMAT",
    "VERSION",
    "DriftModel",
    "DriftWatch",
    "Hysteresis",
    "drift_watch",
    "family_of",
    "history_features",
    "shipped_model",
]

FORMAT = "covviz-drift-model"
#: Version 2 adds ``design``; a version-1 file is read as the ``levels`` design. Version 3 adds the
#: ``signal`` design (a version-2 reader would call such a file broken).
VERSION = 4
READS = (1, 2, 3, 4)
#: The feature designs (module docstring).
DESIGNS = ("levels", "changes", "signal")
#: Tracker families with a model of their own; any other tracker gets the ``generic`` one.
FAMILIES = {
    "manifold": ("manifold",),
    "manifold-paper": ("manifold-paper",),
    "ipca": ("ipca",),
    "opencv": ("csrt", "kcf", "mil", "mosse", "medianflow", "tld"),
}
#: History features: the mean of the last HISTORY_MEAN frames and the max of the last HISTORY_MAX.
HISTORY_MEAN = 5
HISTORY_MAX = 10
#: Signals also given relative to their own median over the run's first BASELINE_FRAMES frames.
RELATIVE = ("fb_error", "flow_gap", "d_first", "d_recent", "cloud_gap", "psr")
BASELINE_FRAMES = 20
#: The ``changes`` design: a signal's robust z-score against its own frames t − LAG − WINDOW … t − LAG − 1,
#: once at least CHANGE_MIN of them are finite.
CHANGE_WINDOW = 30
CHANGE_LAG = 5
CHANGE_MIN = 10
#: Frames the probability must stay below the release level before an episode ends.
COOLDOWN = 5
#: The signal a model's gate reads (:attr:`DriftModel.gate`).
GATE_SIGNAL = "colour"
#: Signal names as a person reads them in a summary line, with their unit.
LABELS = {
    "fb_error": ("FB error", " box"), "fb_fail": ("FB lost points", ""), "flow_gap": ("flow gap", " box"),
    "motion": ("motion", " box"), "scale_rate": ("scale rate", ""), "d_first": ("d to first look", ""),
    "d_recent": ("d to recent looks", ""), "psr": ("PSR", ""), "ess": ("ESS", ""),
    "dmin_z": ("distance z", ""), "mode_mass": ("second mode", ""), "cloud_gap": ("cloud gap", ""),
    "slip": ("slip", " box"), "colour": ("colour lost", ""),
}


def family_of(tracker: str) -> str:
    """The model family of a tracker name (``generic`` if it has none of its own)."""
    for fam, names in FAMILIES.items():
        if tracker in names:
            return fam
    return "generic"


def _squash(x: np.ndarray) -> np.ndarray:
    """``asinh``: linear near 0, logarithmic in the tails (the signals are heavy-tailed, some signed)."""
    return np.arcsinh(x)


class _History:
    """The last HISTORY_MAX squashed rows of one tracker's signals, and the features of the newest.

    Per signal: its value now, the mean of the last HISTORY_MEAN frames and the max of the last
    HISTORY_MAX (``asinh``-squashed); and, for the signals of :data:`RELATIVE`, ``asinh`` of its value
    over its own median on the run's first BASELINE_FRAMES frames where it is defined (the run's own
    scale, label-free: a target's texture sets how large its distances are).
    """

    def __init__(self, signals):
        self.rows: deque = deque(maxlen=HISTORY_MAX)
        self.rel = [i for i, s in enumerate(signals) if s in RELATIVE]
        self.first: list[list[float]] = [[] for _ in self.rel]
        self.base = np.full(len(self.rel), np.nan)

    def push(self, row: np.ndarray) -> np.ndarray:
        import warnings

        row = np.asarray(row, dtype=np.float64)
        self.rows.append(_squash(row))
        a = np.stack(self.rows)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(a[-HISTORY_MEAN:], axis=0)
            mx = np.nanmax(a, axis=0)
        rel = np.full(len(self.rel), np.nan)
        for j, i in enumerate(self.rel):
            v, first = row[i], self.first[j]
            if np.isfinite(v) and len(first) < BASELINE_FRAMES:
                first.append(float(v))
                self.base[j] = float(np.median(first))  # frozen once BASELINE_FRAMES are in
            if np.isfinite(v) and self.base[j] > 0:
                rel[j] = math.asinh(v / self.base[j])
        return np.concatenate([a[-1], mean, mx, rel])


def _median0(a: np.ndarray) -> np.ndarray:
    """``np.median(a, axis=0)`` by partition (4× faster on the 30 × 12 windows; nan where a column has one)."""
    n = len(a)
    k = n // 2
    bad = np.isnan(a).any(axis=0)
    if n % 2:
        m = np.partition(a, k, axis=0)[k]
    else:
        p = np.partition(a, [k - 1, k], axis=0)
        m = 0.5 * (p[k - 1] + p[k])
    m[bad] = np.nan
    return m


class _Changes:
    """The ``changes`` design online: each signal's ``asinh`` robust z-score against its own recent past."""

    def __init__(self, signals):
        self.k = len(signals)
        self.past = np.full((CHANGE_WINDOW + CHANGE_LAG, self.k), np.nan)  # oldest first
        self.n = 0
        self.usual = np.full(self.k, np.nan)  # the window's median behind the last row's z-scores

    def push(self, row: np.ndarray) -> np.ndarray:
        import warnings

        row = np.asarray(row, dtype=np.float64)
        out = np.full(self.k, np.nan)
        n = min(self.n, len(self.past))
        if n > CHANGE_LAG:
            win = self.past[len(self.past) - n: len(self.past) - CHANGE_LAG]
            ok = np.isfinite(win)
            cnt = ok.sum(axis=0)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                m = _median0(win)  # nan in a column with a gap: those are redone below
                mad = 1.4826 * _median0(np.abs(win - m))
            for j in np.flatnonzero((cnt < len(win)) & (cnt >= CHANGE_MIN)):
                w = win[ok[:, j], j]
                m[j] = np.median(w)
                mad[j] = 1.4826 * np.median(np.abs(w - m[j]))
            use = (cnt >= CHANGE_MIN) & np.isfinite(row)
            out[use] = np.arcsinh((row[use] - m[use]) / (mad[use] + 1e-3 * np.abs(m[use]) + 1e-6))
            self.usual = np.where(cnt >= CHANGE_MIN, m, np.nan)
        self.past[:-1] = self.past[1:]
        self.past[-1] = row
        self.n += 1
        return out


class _Raw:
    """The ``signal`` design online: ``asinh`` of the one signal's value."""

    def __init__(self, signals):
        pass

    def push(self, row: np.ndarray) -> np.ndarray:
        return _squash(np.asarray(row, dtype=np.float64))


def _features(signals, design: str):
    if design == "signal":
        return _Raw(signals)
    if design == "levels":
        return _History(signals)
    if design == "changes":
        return _Changes(signals)
    raise ValueError(f"unknown feature design {design!r}; known: {', '.join(DESIGNS)}")


def history_features(rows: np.ndarray, signals, design: str = "levels") -> np.ndarray:
    """Features of every frame of a run from its signal rows ``(n, k)`` (columns: ``signals``).

    Exactly what :class:`DriftWatch` computes online, frame by frame (it is the same code).
    """
    rows = np.asarray(rows, dtype=np.float64)
    h = _features(signals, design)
    n_feat = len(feature_names(signals, design))
    return np.stack([h.push(r) for r in rows]) if len(rows) else np.zeros((0, n_feat))


def feature_names(signals, design: str = "levels") -> list[str]:
    if design == "changes":
        return [f"{s}_z" for s in signals]
    if design == "signal":
        return list(signals)
    return ([f"{s}{suf}" for suf in ("", f"_mean{HISTORY_MEAN}", f"_max{HISTORY_MAX}") for s in signals]
            + [f"{s}_rel" for s in signals if s in RELATIVE])


@dataclass(frozen=True)
class Hysteresis:
    """Alarm rule: raise when the score reaches ``threshold`` (once per episode); the episode ends after
    ``cooldown`` frames in a row below ``release`` (``release <= threshold``)."""

    threshold: float
    release: float
    cooldown: int = COOLDOWN

    def __post_init__(self):
        if not self.release <= self.threshold:
            raise ValueError(f"release {self.release} must be <= threshold {self.threshold}")
        if self.cooldown < 1:
            raise ValueError("cooldown must be >= 1")

    def episodes(self, scores) -> list[tuple[int, int]]:
        """``(first, last)`` 0-based frames of each alarm episode of a score series (nan: below every level).

        ``last`` is the last frame at or above ``release`` before the episode ended.
        """
        out: list[list[int]] = []
        st = _AlarmState()
        for v in np.asarray(scores, dtype=np.float64):
            if self.step(st, v):
                out.append([st.last, st.last])
            elif st.active and out:
                out[-1][1] = st.last
        return [(a, b) for a, b in out]

    def step(self, st: _AlarmState, v: float) -> bool:
        """Advance one frame; True when an alarm is raised on it."""
        v = float(v) if np.isfinite(v) else -math.inf
        if not st.active:
            if v >= self.threshold:
                st.active, st.below, st.last = True, 0, st.i
                st.i += 1
                return True
            st.i += 1
            return False
        if v < self.release:
            st.below += 1
            if st.below >= self.cooldown:
                st.active = False
        else:
            st.below, st.last = 0, st.i
        st.i += 1
        return False


@dataclass
class _AlarmState:
    active: bool = False
    below: int = 0
    last: int = -1
    i: int = 0


def gate_probability(p: np.ndarray, colour: np.ndarray, gate: float) -> np.ndarray:
    """``p`` with the colour gate at ``gate``: 0 where ``colour`` is below it (nan, no colour: not gated)."""
    return np.where(colour < gate, 0.0, p)


@dataclass(frozen=True)
class DriftModel:
    """A fitted drift-probability model (see the module docstring); load with :meth:`load`."""

    family: str
    signals: tuple
    center: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    alarm: Hysteresis
    fit: dict = field(default_factory=dict)
    design: str = "levels"
    gate: float | None = None  # probability 0 where the colour signal is below this (None: no gate)

    def __post_init__(self):
        if self.design not in DESIGNS:
            raise ValueError(f"unknown feature design {self.design!r}; known: {', '.join(DESIGNS)}")
        if self.design == "signal" and len(self.signals) != 1:
            raise ValueError(f"the signal design reads one signal, got {len(self.signals)}")
        n = len(feature_names(self.signals, self.design))
        for name in ("center", "scale", "coef"):
            if np.shape(getattr(self, name)) != (n,):
                raise ValueError(f"{name} must have {n} values (one per feature), got {np.shape(getattr(self, name))}")
        unknown = [s for s in self.signals if s not in SIGNALS]
        if unknown:
            raise ValueError(f"unknown signal(s) {', '.join(unknown)}; known: {', '.join(SIGNALS)}")

    @property
    def columns(self) -> np.ndarray:
        return np.array([SIGNALS.index(s) for s in self.signals])

    def probability(self, feats: np.ndarray) -> np.ndarray:
        """Drift probability of feature rows (:func:`feature_names`; missing values count as the training mean)."""
        z = (np.asarray(feats, dtype=np.float64) - self.center) / self.scale
        if self.design == "signal":  # no value, no evidence: below every alarm level, as for the signal's own
            logit = np.where(np.isfinite(z[..., 0]), z[..., 0] * self.coef[0] + self.intercept, -np.inf)
            with np.errstate(over="ignore"):
                return 1.0 / (1.0 + np.exp(-logit))
        z = np.where(np.isfinite(z), z, 0.0)
        return 1.0 / (1.0 + np.exp(-(z @ self.coef + self.intercept)))

    def gated(self, p: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``p`` (one value per row of :data:`SIGNALS` ``rows``) with the gate applied: 0 where the colour signal
        is below :attr:`gate` (a missing colour gates nothing)."""
        if self.gate is None:
            return p
        return gate_probability(p, np.asarray(rows, dtype=np.float64)[..., SIGNALS.index(GATE_SIGNAL)], self.gate)

    def contributions(self, feats: np.ndarray) -> dict[str, float]:
        """Each signal's share of the logit on one frame (its features summed), by name."""
        z = (np.asarray(feats, dtype=np.float64) - self.center) / self.scale
        c = np.where(np.isfinite(z), z, 0.0) * self.coef
        out: dict[str, float] = dict.fromkeys(self.signals, 0.0)
        for name, v in zip(feature_names(self.signals, self.design), c):
            out[next(s for s in self.signals if name == s or name.startswith(s + "_"))] += float(v)
        return out

    def predict_run(self, rows: np.ndarray) -> np.ndarray:
        """Probabilities of every frame of a run from its :data:`SIGNALS` rows ``(n, len(SIGNALS))``."""
        rows = np.asarray(rows)
        return self.gated(self.probability(history_features(rows[:, self.columns], self.signals, self.design)), rows)

    # ------------------------------------------------------------------ #
    def as_dict(self) -> dict:
        return {
            "format": FORMAT,
            "version": VERSION,
            "family": self.family,
            "design": self.design,
            "model": _DESCRIBE[self.design],
            "signals": list(self.signals),
            "features": feature_names(self.signals, self.design),
            "center": [float(f"{v:.6g}") for v in self.center],
            "scale": [float(f"{v:.6g}") for v in self.scale],
            "coef": [float(f"{v:.6g}") for v in self.coef],
            "intercept": float(f"{self.intercept:.6g}"),
            "alarm": {"threshold": self.alarm.threshold, "release": self.alarm.release,
                      "cooldown": self.alarm.cooldown},
            "gate": None if self.gate is None else {"signal": GATE_SIGNAL, "below": self.gate},
            "fit": self.fit,
        }

    def save(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.as_dict(), indent=1) + "\n")
        return path

    @classmethod
    def from_dict(cls, d: dict, where: str = "model") -> DriftModel:
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise InputError(f"{where}: not a covviz drift model (format {d.get('format') if isinstance(d, dict) else None!r})")
        if d.get("version") not in READS:
            raise InputError(f"{where}: drift model version {d.get('version')!r}; this covviz reads versions "
                             f"{', '.join(map(str, READS))}")
        try:
            a = d["alarm"]
            g = d.get("gate")
            if g is not None and g.get("signal") != GATE_SIGNAL:
                raise ValueError(f"a gate reads {GATE_SIGNAL!r}, not {g.get('signal')!r}")
            return cls(
                family=str(d["family"]),
                signals=tuple(d["signals"]),
                center=np.asarray(d["center"], dtype=np.float64),
                scale=np.asarray(d["scale"], dtype=np.float64),
                coef=np.asarray(d["coef"], dtype=np.float64),
                intercept=float(d["intercept"]),
                alarm=Hysteresis(float(a["threshold"]), float(a["release"]), int(a.get("cooldown", COOLDOWN))),
                fit=dict(d.get("fit", {})),
                design=str(d.get("design", "levels")),
                gate=None if g is None else float(g["below"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: broken drift model ({exc}); re-create it with 'covviz calibrate'") from None

    @classmethod
    def load(cls, path) -> DriftModel:
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except FileNotFoundError:
            raise InputError(f"{path}: no such detector file") from None
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{path}: cannot read the detector ({exc.__class__.__name__})") from None
        return cls.from_dict(d, str(path))


_DESCRIBE = {
    "levels": "logistic regression on standardised asinh(signal) features: now, "
    f"mean of the last {HISTORY_MEAN} frames, max of the last {HISTORY_MAX}; and some signals over their "
    f"median on the run's first {BASELINE_FRAMES} frames",
    "changes": "logistic regression on standardised asinh of each signal's robust z-score against its own "
    f"frames t-{CHANGE_LAG + CHANGE_WINDOW}..t-{CHANGE_LAG + 1} (median, 1.4826 MAD)",
    "signal": "logistic regression on the standardised asinh of one signal's value (monotone: its alarms are "
    "the signal's own threshold alarms); a missing value gives probability 0",
}


def shipped_model(tracker: str) -> DriftModel | None:
    """The model shipped for ``tracker``'s family (else the generic one; None if neither is installed)."""
    root = resources.files("covviz.diagnosis") / "models"
    for fam in (family_of(tracker), "generic"):
        f = root / f"{fam}.json"
        if f.is_file():
            return DriftModel.from_dict(json.loads(f.read_text()), f"shipped model {fam}.json")
    return None


# --------------------------------------------------------------------------- #
# the observer
# --------------------------------------------------------------------------- #
class _Watch:
    def __init__(self, model: DriftModel | None):
        self.model = model
        self.history = _features(model.signals, model.design) if model else None
        self.alarm = _AlarmState()
        self.p: list[float] = []
        self.alarms: list[dict] = []


class DriftView:
    """Read-only access to a running :class:`DriftWatch`, for the observers after it (the results writer)."""

    def __init__(self, watch: DriftWatch) -> None:
        self._w = watch

    def report(self, index: int = 0, result=None) -> dict:
        return self._w.report(index, result)

    def config_dict(self) -> dict:
        return self._w.config_dict()

    def threshold(self, index: int = 0) -> float | None:
        """Tracker ``index``'s alarm threshold (None without a model)."""
        w = self._w.watches[index] if index < len(self._w.watches) else None
        return None if w is None or w.model is None else float(w.model.alarm.threshold)


class DriftWatch(Observer):
    """Observer: the label-free signals of every tracker, its drift probability and alarms, frame by frame.

    Its ``on_start`` hands the observers after it a :class:`DriftView` (``Findings.drift``); each
    ``on_frame`` the frame's ``(probability, new alarms)`` per tracker (``Findings.drift_news``).

    Parameters
    ----------
    detector : DriftModel, optional
        Used for every tracker; None: each tracker's shipped model (:func:`shipped_model`).
    use_shipped : bool
        Without ``detector``, whether to use the shipped models (False: signals only).
    signal_config : SignalConfig, optional

    Attributes
    ----------
    new : list of list of dict
        Per tracker, the alarms the last frame raised (for the recorder).
    """

    def __init__(self, detector: DriftModel | None = None, use_shipped: bool = True,
                 signal_config: SignalConfig | None = None):
        self.detector = detector
        self.use_shipped = use_shipped
        self.signals = SignalObserver(signal_config)
        self.watches: list[_Watch] = []
        self.new: list[list[dict]] = []
        self.frames = 0
        self.signals_cpu = self.model_cpu = 0.0  # seconds of thread CPU, all trackers together

    def on_start(self, start, found):
        self.signals.on_start(len(start.trackers))
        models = [self.detector or (shipped_model(info.name) if self.use_shipped else None)
                  for info in start.trackers]
        self.watches = [_Watch(m) for m in models]
        self.new = [[] for _ in start.trackers]
        return replace(found, drift=DriftView(self))

    def on_frame(self, frame, records, found=None):
        t0 = time.thread_time()  # (a system call on some machines: three a frame, not per step)
        self.signals.on_frame(frame, records)
        t1 = time.thread_time()
        self.frames += 1
        self.signals_cpu += t1 - t0
        for j, w in enumerate(self.watches):
            self.new[j] = []
            if w.model is None:
                continue
            row = self.signals.states[j].rows[-1]
            feats = w.history.push(row[w.model.columns])
            p = float(w.model.gated(w.model.probability(feats[None]), row[None])[0])
            w.p.append(p)
            if w.alarm.active and w.alarms:
                w.alarms[-1]["until"] = int(frame.index) + 1 if p >= w.model.alarm.release else w.alarms[-1]["until"]
                w.alarms[-1]["peak"] = round(max(w.alarms[-1]["peak"], p), 4)
            if w.model.alarm.step(w.alarm, p):
                contrib = w.model.contributions(feats)
                drivers = sorted((k for k in contrib if contrib[k] > 0), key=lambda k: -contrib[k])[:3]
                vals = self.signals.latest[j]
                a = {
                    "frame": int(frame.index) + 1,
                    "probability": round(p, 4),
                    "signals": {k: (None if not np.isfinite(v) else float(f"{v:.4g}")) for k, v in vals.items()},
                    "drivers": drivers,
                    **({} if w.model.gate is None else {"gate": w.model.gate}),
                    "until": int(frame.index) + 1,
                    "peak": round(p, 4),
                }
                if w.model.design == "changes":  # what each driver usually was in this run, and its z-score
                    z = dict(zip(w.model.signals, np.sinh(feats)))
                    usual = dict(zip(w.model.signals, w.history.usual))
                    a["z"] = {k: float(f"{z[k]:.4g}") for k in drivers if np.isfinite(z[k])}
                    a["usual"] = {k: float(f"{usual[k]:.4g}") for k in drivers if np.isfinite(usual[k])}
                w.alarms.append(a)
                self.new[j].append(a)
        self.model_cpu += time.thread_time() - t1
        if found is not None:
            return replace(found, drift_news=tuple((w.p[-1] if w.p else None, tuple(new))
                                                    for w, new in zip(self.watches, self.new)))
        return None

    def cpu_ms(self) -> dict[str, float]:
        """Thread CPU per tracker and frame so far, ms: the signals, and the model with the alarm rule.

        Not in the results (they stay the same from run to run); ``benchmarks/drift_cost.py`` prints it.
        """
        k = max(len(self.watches), 1) * max(self.frames, 1)
        return {"signals": 1e3 * self.signals_cpu / k, "model": 1e3 * self.model_cpu / k}

    def config_dict(self) -> dict:
        return {"signals": self.signals.config.as_dict()}

    def report(self, index: int = 0, result=None) -> dict:
        """Tracker ``index``'s signals, drift probability and alarms for its results JSON.

        With ``result`` (the run's :class:`~covviz.records.RunResult`), also ``frame_iou``: the IoU of
        every frame with the ground truth, the labels ``covviz calibrate`` fits on (computed after the
        run from the result; the detector never sees it).
        """
        out = self.signals.report(index) if index < len(self.signals.states) else {}
        w = self.watches[index] if index < len(self.watches) else _Watch(None)
        out["drift_probability"] = [round(p, 4) for p in w.p] if w.model else []
        out["alarms"] = list(w.alarms)
        out["detector"] = ({"family": w.model.family, "design": w.model.design, "fit": w.model.fit.get("id", "")}
                           if w.model else None)
        if result is not None and len(result.boxes):
            from covviz.metrics import iou, valid_rows

            gt = np.asarray(result.groundtruth, dtype=np.float64)
            v = iou(np.asarray(result.boxes, dtype=np.float64), gt)
            v[~valid_rows(gt)] = np.nan  # no truth to score there (as evaluate()): unlabelled, not IoU 0
            out["frame_iou"] = [None if not np.isfinite(x) else round(float(x), 4) for x in v]
        return out


def describe_alarm(a: dict, span: bool = True) -> str:
    """One line for a terminal: ``frames 63–80: likely off track, p 0.91 — FB error 0.4 box, ESS 0.01``
    (``span`` False: without its frames, for a row that shows them already).

    The probability and the signals are those of the alarm's first frame, as in the recording's event
    for it; where the episode's probability rose higher later, its peak follows: ``p 0.80 (peak 0.91)``.
    An alarm of the ``changes`` design also says what each value usually was in the run (the median
    of its window): ``ESS 0.01 (usually 0.31)``. A gated model's alarm ends with the colour that let it
    through: ``slip 0.52 box; colour lost 0.61 (gate 0.3)``.
    """
    frames = f"frame {a['frame']}" if a.get("until", a["frame"]) == a["frame"] else f"frames {a['frame']}–{a['until']}"
    parts = []
    for k in a.get("drivers", [])[:2]:
        v = a["signals"].get(k)
        if v is None:
            continue
        name, unit = LABELS.get(k, (k, ""))
        u = a.get("usual", {}).get(k)
        parts.append(f"{name} {v:.2g}{unit}" + ("" if u is None else f" (usually {u:.2g})"))
    p, peak = f"{a['probability']:.2f}", f"{a.get('peak', a['probability']):.2f}"
    gate = ""
    c = a["signals"].get("colour")
    if a.get("gate") is not None and c is not None and "colour" not in a.get("drivers", [])[:2]:
        gate = f"{'; ' if parts else ' — '}{LABELS['colour'][0]} {c:.2g} (gate {a['gate']:g})"
    return f"{frames + ': ' if span else ''}likely off track, p {p}" + ("" if peak == p else f" (peak {peak})") + (
        " — " + ", ".join(parts) if parts else "") + gate


def drift_watch(detector=None) -> DriftWatch:
    """The observer for a run: ``detector`` a path to a model file, a :class:`DriftModel`, or None (shipped)."""
    if detector is None or isinstance(detector, DriftModel):
        return DriftWatch(detector)
    return DriftWatch(DriftModel.load(detector))

