"""The Python API: ``covviz.track``, ``covviz.read_events``, ``covviz.show``.

What ``covviz track`` does, for a notebook or a script::

    import covviz

    runs = covviz.track("path/to/Car4", trackers=["manifold", "ipca"], seed=1, max_frames=200, save="car4.rrd")
    for r in runs:
        print(r.tracker, r.metrics["success_auc"], [d["cause"] for d in r.diagnosis["diagnoses"]])
    events = covviz.read_events("car4.rrd")
    covviz.show("car4.rrd")            # the viewer inline (needs pip install rerun-notebook)

A tracker is a name (``"manifold"``, a variant ``"manifold@b.json"``) or any
object following the tracker protocol (:class:`covviz.trackers.base.Tracker`:
``name``, ``last_record``, ``init(frame, box)``, ``update(frame) -> box``,
``config_dict()``); give it ``snapshot()``/``restore()`` too and the diagnosis'
replays work for it as for ours.

Importing ``covviz`` imports none of this: ``covviz.track`` and the others are
loaded on first use (``covviz/__init__.py``).
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import dataclass, field
from pathlib import Path

from covviz.records import RunResult

__all__ = ["TrackResult", "read_events", "run_trackers", "show", "track", "warm_kernels"]

log = logging.getLogger("covviz")


@dataclass(frozen=True, slots=True, eq=False)
class TrackResult(RunResult):
    """A :class:`~covviz.records.RunResult` with what ``covviz track`` prints and saves beside the boxes.

    Attributes
    ----------
    metrics : dict
        :class:`covviz.metrics.SequenceMetrics` as a dict (success AUC, P@20,
        r_on_track, …); empty when there is no ground truth to score.
    diagnosis : dict
        The drift diagnosis: ``events``, ``diagnoses`` (each loss's cause and
        evidence), ``suspects``, ``labels`` (frames off track by failure kind).
    recording : Path or None
        The ``.rrd`` file written, if ``save`` was given.
    """

    metrics: dict = field(default_factory=dict)
    diagnosis: dict = field(default_factory=dict)
    recording: Path | None = None


#: Cores up to which a recorded run observes with one thread (:func:`observe_threads_for_recording`).
RECORDING_ONE_THREAD_CORES = 2


def observe_threads_for_recording(trackers, keep=None) -> None:
    """A recorded run on two cores: the manifold trackers observe with one thread, not two.

    The recorder's thread (the detector, the diagnosis, the views) is then the busier one, and a
    second observation thread only takes the core it needs: on Car4's first 200 frames the whole
    recorded ``covviz track`` took 0.95x the time with one (seven alternating pairs, 0.88-0.98), the
    run without a recording 1.09x (so it keeps two). Boxes never depend on it, and the results' config
    says what ran. ``keep``: per tracker, True where its threads were given (``--config``, a variant's
    file, a config of your own): those are left as they are, as are trackers without ``set_threads``.
    """
    import os

    if (os.cpu_count() or 1) > RECORDING_ONE_THREAD_CORES:
        return
    for tr, kept in zip(trackers, keep if keep is not None else [False] * len(trackers)):
        if not kept and hasattr(tr, "set_threads"):
            tr.set_threads(1)


def warm_kernels(trackers) -> None:
    """Compile the manifold tracker's kernels before a run (once per install; then loaded from numba's cache)."""
    from covviz.model import kernels

    if kernels.JIT_ENABLED and any(_observes_with_kernels(t) for t in trackers):
        if kernels.kernels_cached():
            return  # each kernel loads from numba's cache at its first call (only those the run uses)
        took = kernels.warmup(lambda: log.info("compiling kernels (once; about 20-40 s, then cached)..."))
        log.debug("kernels ready in %.1f s", took)


def run_trackers(trackers, sequence, seed, observers=(), max_frames: int | None = None,
                 progress: bool = False, checkpoints: tuple[int, int] | None = None) -> list[RunResult]:
    """The run of ``covviz track`` and :func:`track`: kernels warmed, trackers side by side, closed after.

    Every tracker is written with ``seed`` into its result; observers as for
    :func:`covviz.runner.run_many`.
    """
    from covviz.runner import run_many

    warm_kernels(trackers)
    with contextlib.ExitStack() as stack:  # the trackers' threads end with the run
        for tr in trackers:
            if hasattr(tr, "close"):
                stack.callback(tr.close)
        return run_many(trackers, sequence, observers, max_frames=max_frames, progress=progress,
                        seeds=[seed] * len(trackers), checkpoints=checkpoints)


def _trackers(trackers, seed: int, particles: int | None, config) -> list:
    """Names (and variants) built by the registry, objects checked against the protocol."""
    from covviz.trackers.base import Tracker
    from covviz.trackers.variants import make_from_spec, parse_specs

    items = _items(trackers)
    names = [t for t in items if isinstance(t, str)]
    specs = iter(parse_specs(names)) if names else iter(())
    out = []
    for t in items:
        if isinstance(t, str):
            if t.strip():
                out.append(make_from_spec(next(specs), seed=seed, n_particles=particles, config=config))
        elif isinstance(t, Tracker):
            out.append(t)
        else:
            missing = [m for m in ("name", "last_record", "init", "update", "config_dict") if not hasattr(t, m)]
            raise TypeError(f"{t!r} is not a tracker: it lacks {', '.join(missing)} (see covviz.trackers.base.Tracker)")
    taken = [t.name for t in out]
    if len(set(taken)) != len(taken):
        raise ValueError(f"two trackers share a name ({', '.join(taken)}); give each its own name")
    if not out:
        raise ValueError("no trackers given")
    return out


def _observes_with_kernels(tracker) -> bool:
    """A manifold tracker (or a variant of one) whose config asks for the compiled kernels."""
    from covviz.trackers.manifold import ManifoldConfig

    config = getattr(tracker, "config", None)  # any object may be a tracker here (bring your own)
    return isinstance(config, ManifoldConfig) and config.observation.jit


def track(
    sequence=None,
    trackers=("manifold",),
    seed: int = 0,
    max_frames: int | None = None,
    save: str | Path | None = None,
    *,
    box=None,
    particles: int | None = None,
    config=None,
    progress: bool = False,
    mds_every: int = 10,
    counterfactual: bool = True,
    detector=None,
) -> list[TrackResult]:
    """Run trackers on a sequence, as ``covviz track`` does; one :class:`TrackResult` per tracker.

    Parameters
    ----------
    sequence : str, Path, Sequence or None
        What ``covviz track`` takes (an OTB or VOT folder, a video, a quoted
        glob, ``"synthetic:occlusion"``; None: the synthetic default), or a
        sequence object (``frame(i)``, ``groundtruth``, ``init_box``, ``name``).
    trackers : str, or sequence of str or tracker objects
        ``"manifold,ipca"``, ``["manifold", "manifold@b.json"]``, or objects
        following :class:`covviz.trackers.base.Tracker`.
    seed : int
        The seed of every stochastic tracker built here (the rule of
        :func:`covviz.trackers.tracker_rng`: the same boxes as ``covviz track --seed``).
    max_frames : int, optional
    save : str or Path, optional
        Write a Rerun recording there (``.rrd``); open it with :func:`show` or ``rerun FILE``.
    box : array-like, shape (4,), optional
        Initial box ``x, y, w, h`` (0-based pixels), for videos and globs.
    particles : int, optional
        Particles of the trackers built here.
    config : ManifoldConfig, optional
        Config of the manifold trackers built here (variants keep their own file's).
    progress : bool
        A progress bar on stderr.
    mds_every : int
        Template-cloud pictures every k frames in the recording.
    detector : str, Path or DriftModel, optional
        The label-free drift model (``covviz calibrate``); None: the shipped one of each tracker's family.
    counterfactual : bool
        Replay every loss with the search, the model or the estimate fixed (needs ground truth;
        each diagnosis then carries ``counterfactual`` and ``verdict``). Trackers of your own
        are replayed when they have ``snapshot``/``restore`` and an ``intervention`` attribute
        (:class:`covviz.trackers.base.Intervention`).

    Raises
    ------
    covviz.errors.InputError
        A sequence that cannot be read, a bad box.
    ValueError
        An unknown tracker name (with the closest), a name given twice.
    TypeError
        An object that does not follow the tracker protocol.
    """
    import numpy as np

    from covviz.data.sequences import open_sequence
    from covviz.diagnosis.drift import Diagnoser
    from covviz.metrics import evaluate, nothing_to_score
    from covviz.runner import BackgroundObserver, Pipeline

    seq = sequence if hasattr(sequence, "groundtruth") and hasattr(sequence, "frame") else open_sequence(sequence, box)
    built = _trackers(trackers, seed, particles, config)
    if save is not None:  # as covviz track records: only the trackers built here from a name and no config
        from covviz.trackers.variants import VARIANT_SEP

        observe_threads_for_recording(built, [not (isinstance(t, str) and config is None and VARIANT_SEP not in t)
                                              for t in _items(trackers) if not isinstance(t, str) or t.strip()])
    diagnoser = Diagnoser()
    stages: list = [diagnoser]
    replays = None
    if counterfactual and np.isfinite(np.asarray(seq.groundtruth)[1:]).all(axis=1).any():
        from covviz.diagnosis.counterfactual import Counterfactuals

        replays = Counterfactuals(built, [(lambda t=t: _trackers([t], seed, particles, config)[0])
                                          if isinstance(t, str) else None for t in _items(trackers)])
        stages.append(replays)
    from covviz.diagnosis.detector import drift_watch

    watch = drift_watch(detector)  # the label-free drift probability and alarms
    save = None if save is None else Path(save)
    # The detector, the diagnosis (and the recorder) on one background thread, as covviz track runs them.
    if save is None:
        observers = [BackgroundObserver(Pipeline([watch, *stages]))]
    else:
        if save.suffix != ".rrd":
            raise ValueError(f"save={str(save)!r}: a recording file ends in .rrd")
        save.parent.mkdir(parents=True, exist_ok=True)
        from covviz.viz.logger import LoggerConfig, RerunLogger
        from covviz.viz.sinks import attach_sinks, new_recording

        stream = new_recording()
        attach_sinks(stream, save=save)
        names = [t.name for t in built]
        info = {"name": f"{seq.name} · {'+'.join(names)} · seed {seed}", "command": "covviz.track(...)",
                "seed": seed, "trackers": names, "max_frames": max_frames, "particles": particles}
        cfg = LoggerConfig(mds_every=mds_every, seed=seed, diagnosis=diagnoser.config)
        from covviz.viz.drift import DriftRecorder

        observers = [BackgroundObserver(Pipeline([watch, DriftRecorder(stream), *stages,
                                                  RerunLogger(stream, cfg, run_info=info)]))]
    results = run_trackers(built, seq, seed, observers, max_frames=max_frames, progress=progress,
                           checkpoints=None if replays is None else replays.config.checkpoints)
    out = []
    for j, r in enumerate(results):
        scored = len(r.boxes) and not nothing_to_score(r.groundtruth)
        out.append(TrackResult(
            sequence=r.sequence, tracker=r.tracker, seed=r.seed, boxes=r.boxes, times=r.times,
            groundtruth=r.groundtruth, config=r.config, interrupted=r.interrupted,
            metrics=evaluate(r.boxes, r.groundtruth).as_dict() if scored else {},
            diagnosis={**_diagnosis(diagnoser, replays, j), **watch.report(j)}, recording=save,
        ))
    return out


def _diagnosis(diagnoser, replays, j: int) -> dict:
    """Tracker ``j``'s diagnosis report, with each loss's replays and verdict when they ran."""
    if j >= len(diagnoser.states):
        return {}
    report = diagnoser.report(j)
    if replays is not None and j < len(replays.replays):
        from covviz.diagnosis.counterfactual import with_replays

        with_replays(report, replays.replays[j], diagnoser.config.tie_ratio)
    return report


def _items(trackers) -> list:
    return trackers.split(",") if isinstance(trackers, str) else list(trackers)


def read_events(path: str | Path) -> list[dict]:
    """The events and drift diagnoses of a recording (:func:`covviz.viz.readback.read_events`): a list of dicts,
    each with ``tracker``, ``frame`` (1-based), ``kind``, ``cause``, ``text``, ``details`` and ``index``."""
    from covviz.viz.readback import read_events as _read

    return _read(path)


def show(path: str | Path, width: int | None = None, height: int | None = None):
    """The recording in the Rerun viewer inline in a notebook (``rerun.notebook``; pip install rerun-notebook)."""
    from covviz.viz.notebook import show_recording

    return show_recording(path, width=width, height=height)
