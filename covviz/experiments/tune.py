"""``covviz tune``: an Optuna study over :class:`~covviz.trackers.manifold.ManifoldConfig`.

The search space is declared once, next to the config
(:data:`covviz.trackers.manifold.SEARCH_SPACE`, :func:`~covviz.trackers.manifold.suggest_config`).
A trial is one configuration, scored by its **mean success AUC over the
sequences and tuning seeds** (seeds ``0 … K-1``, the bench's seed rule). Its jobs
run through the bench's executors (:mod:`covviz.experiments.jobs`: a local pool or
``--cluster``), in sequence order; after each sequence the trial reports the mean
so far, and Optuna's median pruner stops a trial that is below the median of the
earlier ones at the same point (not on the first sequence, nor in the first
:data:`PRUNE_STARTUP_TRIALS` trials).

A new study first runs the base configuration (the defaults, or ``--config``),
so every study holds its own baseline. Several ``covviz tune`` processes on one
``--storage`` (SQLite on one machine, any RDB URL across machines) share the
study; ``--trials`` is the study's total, finished or pruned.

Guard against tuning to noise
    The best trial was chosen on the tuning seeds, so its score there is biased
    upwards. At the end the best configuration and the base are both run again
    on held-out seeds ``K … K+H-1``, never used to choose; the report sets their
    gain on the held-out seeds next to the gain on the tuning seeds.

Outputs (``--out``, default ``runs/tune``)::

    best.json                     the best configuration (covviz track|bench --config best.json)
    tune_report.md                best trial, held-out check, parameter importances, figures
    img/tune_*.png                Optuna's plots (history, importances, slices, intermediate values)
    study.db                      the study (SQLite) when no --storage is given

Held-out scores are kept in the study (its user attributes), so a report is
cheap to rebuild: ``covviz tune ROOT --trials 0``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

from covviz.errors import InputError
from covviz.experiments.bench import BenchError, make_executor, read_sequences, run_with_progress
from covviz.experiments.cluster import require
from covviz.experiments.jobs import Job

__all__ = ["TuneError", "TuneSettings", "tune"]

log = logging.getLogger("covviz.experiments.tune")

#: Trials that are never pruned (the pruner's reference needs some finished trials).
PRUNE_STARTUP_TRIALS = 5
#: Sequences a trial runs before it can be pruned (steps are counted from 0).
PRUNE_WARMUP_STEPS = 1
#: Name of the study's report, of the best configuration, and of the figures' folder.
REPORT_NAME = "tune_report.md"
BEST_NAME = "best.json"
IMG_DIR = "img"
#: Study attributes that define the objective: a study made with other values is refused.
IDENTITY = ("tracker", "sequences", "seeds", "max_frames", "particles", "base")
#: Resolution of the figures.
DPI = 110


class TuneError(InputError):
    """Bad input to ``tune`` (or a study from another objective): one line, exit code 2."""


class _JobFailed(Exception):
    """A job of a trial failed: the trial fails, the study goes on."""


@dataclass(frozen=True)
class TuneSettings:
    """What defines a study's objective (stored in the study; see :data:`IDENTITY`)."""

    tracker: str
    sequences: dict  # name -> (path, frames)
    seeds: int
    max_frames: int | None
    particles: int | None
    base: dict  # the base ManifoldConfig, as_dict()

    def identity(self) -> dict:
        return {
            "tracker": self.tracker,
            "sequences": {k: v[1] for k, v in self.sequences.items()},
            "seeds": self.seeds,
            "max_frames": self.max_frames,
            "particles": self.particles,
            "base": self.base,
        }

    def jobs(self, config: dict, seeds) -> list[Job]:
        """One job per (sequence, seed), sequence by sequence in name order."""
        text = json.dumps(config, sort_keys=True, allow_nan=True)
        out = []
        for name, (path, n) in self.sequences.items():
            n_run = n if self.max_frames is None else min(n, self.max_frames)
            for s in seeds:
                out.append(Job(name, path, n_run, self.tracker, s, self.particles, self.max_frames, text))
        return out


# --------------------------------------------------------------------------- #
# running configurations
# --------------------------------------------------------------------------- #
def score_config(executor, settings: TuneSettings, config: dict, seeds, trial=None, progress=True,
                 desc="tune") -> dict:
    """Run ``config`` on every sequence × seed; return per-sequence mean AUCs and their mean.

    With an Optuna ``trial``: after each sequence (in order), report the mean over
    the sequences done so far and stop (``optuna.TrialPruned``) if the pruner says so;
    the remaining jobs are ended.

    Returns
    -------
    dict with ``mean`` (mean over sequences of the mean over seeds), ``per_sequence``
    ({name: mean AUC}), ``per_seed`` ({seed: mean over sequences}) and ``seeds``.

    Raises
    ------
    _JobFailed
        If a job fails (its message).
    """
    import optuna

    seeds = list(seeds)
    jobs = settings.jobs(config, seeds)
    auc: dict[tuple[str, int], float] = {}
    order = list(settings.sequences)
    reported = 0
    with contextlib.closing(run_with_progress(executor, jobs, progress, desc)) as outcomes:
        for outcome in outcomes:
            if outcome.output is None:
                raise _JobFailed(f"{outcome.job.label}: {outcome.error}")
            auc[(outcome.job.sequence, outcome.job.seed)] = outcome.output.success_auc
            # report every sequence whose seeds are all done, in order
            while reported < len(order) and all((order[reported], s) in auc for s in seeds):
                reported += 1
                if trial is not None:
                    done = order[:reported]
                    trial.report(_mean([_mean([auc[(q, s)] for s in seeds]) for q in done]), reported - 1)
                    if trial.should_prune():
                        raise optuna.TrialPruned(f"pruned after {reported} sequences")
    per_sequence = {q: _mean([auc[(q, s)] for s in seeds]) for q in order}
    per_seed = {s: _mean([auc[(q, s)] for q in order]) for s in seeds}
    return {"mean": _mean(list(per_sequence.values())), "per_sequence": per_sequence, "per_seed": per_seed,
            "seeds": seeds}


def _mean(values) -> float:
    return float(sum(values) / len(values)) if values else float("nan")


# --------------------------------------------------------------------------- #
# the study
# --------------------------------------------------------------------------- #
#: Attempts at opening a storage: processes that create one at the same moment race on its schema.
STORAGE_ATTEMPTS = 5


def _storage(optuna, url: str):
    """An RDB storage; SQLite waits for a lock instead of failing at once (several processes)."""
    kw = {"engine_kwargs": {"connect_args": {"timeout": 60}}} if url.startswith("sqlite") else {}
    for attempt in range(1, STORAGE_ATTEMPTS + 1):
        try:
            return optuna.storages.RDBStorage(url, **kw)
        except Exception as exc:  # noqa: BLE001 - bad URL, missing driver, unreachable database, a race
            # Two processes creating the tables at once: one fails on the schema version row
            # (IntegrityError) or a lock (OperationalError); the tables exist on the next try.
            if attempt < STORAGE_ATTEMPTS and exc.__class__.__name__ in ("IntegrityError", "OperationalError"):
                time.sleep(0.5 * attempt)
                continue
            why = " ".join(str(exc).split("(Background on this error")[0].split())  # one line
            raise TuneError(f"--storage {url}: cannot open it ({exc.__class__.__name__}: {why})") from None
    raise AssertionError("unreachable")


def _db_has_finished_trials(db: Path) -> bool:
    """Whether the SQLite study ``db`` holds a trial that finished (then it is kept, whatever happened)."""
    import sqlite3

    try:
        with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True)) as con:
            return bool(con.execute("SELECT COUNT(*) FROM trials WHERE state IN ('COMPLETE', 'PRUNED')").fetchone()[0])
    except sqlite3.Error:
        return False


def _remove_empty(created: list[Path]) -> None:
    """Remove the folders this command made, deepest first, if they are still empty."""
    for d in reversed(created):
        with contextlib.suppress(OSError):
            d.rmdir()


def _open_study(optuna, storage, name: str, settings: TuneSettings):
    from optuna.pruners import MedianPruner
    from optuna.samplers import TPESampler

    study = optuna.create_study(
        study_name=name,
        storage=storage,
        direction="maximize",
        load_if_exists=True,
        # constant_liar: processes sharing the study do not propose the same point at once
        sampler=TPESampler(multivariate=True, constant_liar=True),
        pruner=MedianPruner(n_startup_trials=PRUNE_STARTUP_TRIALS, n_warmup_steps=PRUNE_WARMUP_STEPS),
    )
    ident = json.loads(json.dumps(settings.identity()))
    attrs = study.user_attrs
    if "objective" not in attrs:
        study.set_user_attr("objective", ident)
    elif attrs["objective"] != ident:
        old = attrs["objective"]
        key = next((k for k in IDENTITY if old.get(k) != ident.get(k)), "settings")
        raise TuneError(
            f"study {name!r} was made with other {key} ({old.get(key)!r}, now {ident.get(key)!r}); "
            "give the same settings, or another --study"
        )
    return study


def _finished(study) -> int:
    from optuna.trial import TrialState

    return len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)))


def tune(
    root: str | Path,
    trials: int,
    out: str | Path = "runs/tune",
    storage: str | None = None,
    study_name: str = "covviz-tune",
    seeds: int = 2,
    holdout_seeds: int | None = None,
    max_frames: int | None = None,
    particles: int | None = None,
    tracker: str = "manifold",
    base: dict | None = None,
    jobs: int = 1,
    cluster: str | None = None,
    retries: int = 1,
    progress: bool = True,
) -> dict:
    """Run (or join) a study, then re-run its best configuration on held-out seeds and write the report.

    Parameters
    ----------
    root : path
        A sequence folder or a folder of them (as for ``covviz bench``).
    trials : int
        The study's total of finished (complete or pruned) trials; 0: only the report.
    out : path
        Folder of the report, ``best.json`` and the figures (and ``study.db`` by default).
    storage : str, optional
        An Optuna RDB URL (``sqlite:///study.db``, ``postgresql://…``); default
        ``sqlite:///OUT/study.db``.
    study_name : str
    seeds : int
        Tuning seeds ``0 … seeds-1``.
    holdout_seeds : int, optional
        Held-out seeds ``seeds … seeds+holdout_seeds-1`` (default: as many as ``seeds``; 0: no check).
    max_frames, particles : int, optional
        As for ``covviz bench``.
    tracker : {"manifold", "manifold-paper"}
    base : dict, optional
        Fields of the base ManifoldConfig (default: the defaults); the space's
        parameters vary around it, the other fields stay.
    jobs, cluster, retries
        The executor, as for ``covviz bench``.

    Returns
    -------
    dict with ``best`` (trial number, value, params), ``holdout`` (or None),
    ``report`` and ``best_config`` (paths), ``trials`` (counts by state).
    """
    optuna = require("optuna", "covviz tune")
    from covviz.trackers import CONFIGURABLE
    from covviz.trackers.manifold import ManifoldConfig

    if tracker not in CONFIGURABLE:
        raise TuneError(f"covviz tune searches a ManifoldConfig: --tracker must be one of {', '.join(sorted(CONFIGURABLE))}")
    if trials < 0 or seeds < 1 or jobs < 1:
        raise TuneError("--trials must be at least 0, --seeds and --jobs at least 1")
    holdout_seeds = seeds if holdout_seeds is None else holdout_seeds
    out = Path(out)
    created = [p for p in [out, *out.parents] if not p.exists()][::-1]  # made here: removed on an early error
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise TuneError(f"cannot write to {out}: {exc.strerror or exc}; choose another --out") from None
    db = out / "study.db"
    db_existed = storage is not None or db.exists()
    if trials == 0 and not db_existed:
        _remove_empty(created)
        raise TuneError(f"--trials 0 reports on an existing study, and {out} holds none; give --trials N to run N "
                        "trials (or --storage of a study)")
    try:
        try:
            base_cfg = ManifoldConfig.from_dict({**(base or {}), **({"n_particles": particles} if particles else {})})
        except (ValueError, TypeError) as exc:
            raise TuneError(f"--config: {exc}") from None
        try:
            sequences = read_sequences(Path(root).resolve(), exclude=[out])
        except BenchError as exc:
            raise TuneError(str(exc)) from None
        settings = TuneSettings(tracker, sequences, seeds, max_frames, particles, base_cfg.as_dict())
        url = storage or f"sqlite:///{(out / 'study.db').resolve()}"

        # Optuna's own lines (a trial's failure with its traceback, Ctrl-C included) give way to ours.
        optuna.logging.set_verbosity(optuna.logging.ERROR)
        study = _open_study(optuna, _storage(optuna, url), study_name, settings)

        from covviz.trackers.manifold import search_params, suggest_config

        if not study.trials:
            study.enqueue_trial(search_params(base_cfg), user_attrs={"base": True}, skip_if_exists=True)

        executor = make_executor(cluster, jobs, retries)
        try:
            n_before = _finished(study)
            if trials > n_before:
                log.info("study %r in %s: %d trials finished, running up to %d", study_name, url, n_before, trials)

                def objective(trial):
                    config = suggest_config(trial, base_cfg).as_dict()
                    trial.set_user_attr("config", config)
                    t0 = time.perf_counter()
                    try:
                        score = score_config(executor, settings, config, range(seeds), trial, progress,
                                             desc=f"trial {trial.number}")
                    except optuna.TrialPruned:
                        log.info("trial %d pruned (%.0f s)", trial.number, time.perf_counter() - t0)
                        raise
                    except _JobFailed as exc:
                        log.warning("trial %d failed (the study goes on): %s", trial.number, exc)
                        raise
                    trial.set_user_attr("per_sequence", score["per_sequence"])
                    trial.set_user_attr("per_seed", {str(k): v for k, v in score["per_seed"].items()})
                    best = _best_value(study)
                    log.info("trial %d: mean success AUC %.4f (best so far %s; %.0f s)", trial.number, score["mean"],
                             "this one" if best is None or score["mean"] > best else f"{best:.4f}",
                             time.perf_counter() - t0)
                    return score["mean"]

                from optuna.study import MaxTrialsCallback
                from optuna.trial import TrialState

                study.optimize(
                    objective,
                    n_trials=trials - n_before,
                    callbacks=[MaxTrialsCallback(trials, states=(TrialState.COMPLETE, TrialState.PRUNED))],
                    catch=(_JobFailed,),
                    gc_after_trial=False,
                )
            best = _best_trial(study)
            holdout = None
            if holdout_seeds > 0:
                held = range(seeds, seeds + holdout_seeds)
                h_base = _holdout(study, executor, settings, None, held, progress, base_cfg.as_dict())
                h_best = h_base if best.user_attrs.get("base") else _holdout(
                    study, executor, settings, best, held, progress, _trial_config(best, base_cfg)
                )
                holdout = {"seeds": list(held), "best": h_best, "base": h_base}
        finally:
            executor.close()
        best_config = out / BEST_NAME
        best_config.write_text(json.dumps(_trial_config(best, base_cfg), indent=1) + "\n")
        report = write_tune_report(study, settings, out, url, Path(root), holdout, best_config)
        return {
            "best": {"number": best.number, "value": best.value, "params": best.params},
            "holdout": holdout,
            "report": report,
            "best_config": best_config,
            "trials": _counts(study),
        }
    except BaseException:
        # An error before the study has a finished trial leaves nothing behind: no study.db of
        # this command's making, no folder it made (a finished trial is kept, whatever happens).
        if not db_existed and db.exists() and not _db_has_finished_trials(db):
            with contextlib.suppress(OSError):
                db.unlink()
        _remove_empty(created)
        raise


def _trial_config(trial, base_cfg) -> dict:
    """The full config a trial ran (stored with it; else rebuilt from its parameters)."""
    from covviz.trackers.manifold import config_from_params

    return trial.user_attrs.get("config") or config_from_params(trial.params, base_cfg).as_dict()


def _best_value(study) -> float | None:
    try:
        return study.best_value
    except ValueError:
        return None


def _best_trial(study):
    try:
        return study.best_trial
    except ValueError:
        raise TuneError(
            f"study {study.study_name!r} has no finished trial yet; run more --trials "
            "(failed trials: see the log)"
        ) from None


def _base_trial(study):
    """The study's base trial (the first one, enqueued with the base config), if it finished."""
    from optuna.trial import TrialState

    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        if t.user_attrs.get("base"):
            return t
    return None


def _holdout(study, executor, settings, trial, seeds, progress, config) -> dict:
    """``config``'s score on the held-out ``seeds``, kept in the study (computed once per trial and seeds)."""
    key = f"holdout:{'base' if trial is None else trial.number}:{','.join(map(str, seeds))}"
    cached = study.user_attrs.get(key)
    if cached is not None:
        return cached
    desc = "held-out " + ("base" if trial is None else f"trial {trial.number}")
    try:
        score = score_config(executor, settings, config, seeds, progress=progress, desc=desc)
    except _JobFailed as exc:
        # A finding, not a crash of the command: the configuration fails on seeds it was not chosen on.
        log.warning("the held-out run of the %s failed: %s", desc.removeprefix("held-out "), exc)
        score = {"mean": None, "per_sequence": {}, "per_seed": {}, "seeds": list(seeds), "error": str(exc)}
    score["per_seed"] = {str(k): v for k, v in score["per_seed"].items()}
    score["trial"] = None if trial is None else trial.number
    study.set_user_attr(key, score)
    return score


def _counts(study) -> dict[str, int]:
    out: dict[str, int] = {}
    for t in study.get_trials(deepcopy=False):
        out[t.state.name.lower()] = out.get(t.state.name.lower(), 0) + 1
    return out


# --------------------------------------------------------------------------- #
# the report
# --------------------------------------------------------------------------- #
def _fmt(v, digits: int = 3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    if isinstance(v, float):
        return f"{v:.{digits}f}" if abs(v) >= 10 ** -digits or v == 0 else f"{v:.2g}"
    return str(v)


def _seeds_text(seeds) -> str:
    seeds = list(seeds)
    return f"{seeds[0]}–{seeds[-1]}" if len(seeds) > 1 else str(seeds[0])


def write_tune_report(study, settings: TuneSettings, out: Path, url: str, root: Path, holdout, best_config) -> Path:
    """Write ``tune_report.md`` and the figures; return the report's path."""
    from covviz.trackers.manifold import SEARCH_SPACE, ManifoldConfig, search_params

    best = _best_trial(study)
    base = _base_trial(study)
    base_params = search_params(ManifoldConfig.from_dict(settings.base))
    counts = _counts(study)
    tuning = range(settings.seeds)
    lines = [
        f"# covviz tune: study `{study.study_name}`",
        "",
        f"Storage `{url}`; tracker `{settings.tracker}`"
        + (f", {settings.particles} particles" if settings.particles else "")
        + f"; {len(settings.sequences)} sequences under `{root}`"
        + (f" (first {settings.max_frames} frames)" if settings.max_frames else "")
        + f"; tuning seeds {_seeds_text(tuning)}"
        + (f", held-out seeds {_seeds_text(holdout['seeds'])}" if holdout else "")
        + ".",
        "",
        "Trials: " + ", ".join(f"{v} {k}" for k, v in sorted(counts.items())) + ". The objective is the mean "
        "success AUC over sequences (each the mean over the tuning seeds); trials below the median of the "
        "earlier ones after a sequence are pruned.",
        "",
        "## Best configuration",
        "",
        f"Trial {best.number}: mean success AUC **{best.value:.4f}** on the tuning seeds"
        + (f" (the base configuration, trial {base.number}: {base.value:.4f})." if base is not None else "."),
        "",
        "| parameter | range | best | base |",
        "|---|---|---:|---:|",
    ]
    for name, (lo, hi, scale) in SEARCH_SPACE.items():
        lines.append(f"| `{name}` | {_fmt(lo)}–{_fmt(hi)} ({scale}) | {_fmt(best.params.get(name))} | "
                     f"{_fmt(base_params.get(name))} |")
    lines += [
        "",
        "Run it:",
        "",
        "```bash",
        f"covviz track SEQUENCE --tracker {settings.tracker} --config {best_config}",
        f"covviz bench {root} --trackers {settings.tracker} --config {best_config}",
        "```",
        "",
    ]
    lines += _holdout_section(best, base, holdout, settings)
    lines += _importance_section(study)
    figures = _figures(study, out / IMG_DIR)
    if figures:
        lines += ["## Figures", ""]
        for title, path in figures:
            lines += [f"![{title}]({IMG_DIR}/{path.name})", ""]
    path = out / REPORT_NAME
    path.write_text("\n".join(lines).rstrip() + "\n")
    return path


def _holdout_section(best, base, holdout, settings) -> list[str]:
    if not holdout:
        return ["## Held-out seeds", "", "Not run (`--holdout-seeds 0`).", ""]
    hb, h0 = holdout["best"], holdout["base"]
    tuning = _seeds_text(range(settings.seeds))
    held = _seeds_text(holdout["seeds"])
    failed = [(who, h["error"]) for who, h in (("best", hb), ("base", h0)) if h.get("error")]
    if failed:
        return ["## Does it hold on held-out seeds?", "",
                *[f"The held-out run (seeds {held}) of the {who} configuration failed: {err}." for who, err in failed],
                ""]
    lines = [
        "## Does it hold on held-out seeds?",
        "",
        (f"The best trial was chosen on seeds {tuning}, so its score there is biased upwards. Both it and "
         f"the base were run again on seeds {held}, never used to choose:"),
        "",
        f"| configuration | tuning seeds {tuning} | held-out seeds {held} | per held-out seed |",
        "|---|---:|---:|---|",
        f"| best (trial {best.number}) | {best.value:.4f} | {hb['mean']:.4f} | "
        + ", ".join(f"{v:.3f}" for v in hb["per_seed"].values()) + " |",
        f"| base | {_fmt(None if base is None else base.value, 4)} | {h0['mean']:.4f} | "
        + ", ".join(f"{v:.3f}" for v in h0["per_seed"].values()) + " |",
        "",
    ]
    gain_held = hb["mean"] - h0["mean"]
    if base is not None:
        gain_tune = best.value - base.value
        kept = gain_held / gain_tune if gain_tune > 0 and gain_held > 0 else float("nan")
        lines += [
            f"Gain of the best over the base: {gain_tune:+.4f} on the tuning seeds, **{gain_held:+.4f}** on the "
            "held-out seeds"
            + (f" ({kept:.0%} of it held)." if math.isfinite(kept) else ".")
            + " For scale, the base's mean success AUC per seed, tuning and held-out: "
            + ", ".join(f"{v:.3f}" for v in _base_per_seed(base, h0)) + " (std "
            + _fmt(_spread(_base_per_seed(base, h0)), 3) + ").",
            "",
        ]
    lines += ["| sequence | best, held-out | base, held-out | difference |", "|---|---:|---:|---:|"]
    for q, v in hb["per_sequence"].items():
        b = h0["per_sequence"].get(q, float("nan"))
        lines.append(f"| {q} | {v:.3f} | {b:.3f} | {v - b:+.3f} |")
    return [*lines, ""]


def _base_per_seed(base, h0) -> list[float]:
    """The base configuration's score of every seed it ran, tuning seeds then held-out ones."""
    tuning = (base.user_attrs.get("per_seed") or {}) if base is not None else {}
    return [*map(float, tuning.values()), *map(float, h0["per_seed"].values())]


def _spread(values) -> float:
    v = list(values)
    if len(v) < 2:
        return float("nan")
    m = sum(v) / len(v)
    return math.sqrt(sum((x - m) ** 2 for x in v) / (len(v) - 1))


def _importance_section(study) -> list[str]:
    import optuna

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            imp = optuna.importance.get_param_importances(study)
    except (ValueError, RuntimeError, ZeroDivisionError) as exc:
        return ["## Parameter importance", "", f"Not available yet ({exc}).", ""]
    lines = [
        "## Parameter importance",
        "",
        ("Optuna's default importance evaluator over the completed trials (shares sum to 1; with few "
         "trials a rough guide only):"),
        "",
        "| parameter | importance |",
        "|---|---:|",
    ]
    lines += [f"| `{k}` | {v:.3f} |" for k, v in imp.items()]
    return [*lines, ""]


def _figures(study, img_dir: Path) -> list[tuple[str, Path]]:
    """Optuna's matplotlib plots as PNGs; a plot that cannot be drawn yet is left out."""
    import numpy as np
    import optuna.visualization.matplotlib as ovm

    img_dir.mkdir(parents=True, exist_ok=True)
    plots = [
        ("optimization history", "tune_history.png", ovm.plot_optimization_history),
        ("parameter importances", "tune_importances.png", ovm.plot_param_importances),
        ("intermediate values (mean AUC after each sequence)", "tune_intermediate.png",
         ovm.plot_intermediate_values),
    ]
    import matplotlib.pyplot as plt

    done = []
    for title, name, fn in plots:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # ExperimentalWarning of the matplotlib backend
                ax = fn(study)
        except Exception as exc:  # noqa: BLE001 - e.g. importances with a single completed trial
            log.debug("figure %s not drawn: %s", name, exc)
            plt.close("all")
            continue
        fig = (np.ravel(ax)[0] if isinstance(ax, np.ndarray) else ax).figure
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "tight layout not applied" on a long list of parameters
            fig.savefig(img_dir / name, dpi=DPI, bbox_inches="tight")
        plt.close(fig)
        done.append((title, img_dir / name))
    if _slices(study, img_dir / "tune_slices.png"):
        done.insert(2, ("score against each parameter (completed trials; best ★, base ◆)", img_dir / "tune_slices.png"))
    return done


def _slices(study, path: Path) -> bool:
    """Score against each parameter of the space, one panel each (Optuna's slice plot, on a grid)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from optuna.trial import TrialState

    from covviz.trackers.manifold import SEARCH_SPACE

    trials = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not trials:
        return False
    best = _best_trial(study)
    import matplotlib.style
    from matplotlib.ticker import NullFormatter

    names = list(SEARCH_SPACE)
    cols = 3
    rows = -(-len(names) // cols)
    with matplotlib.style.context("default"):  # Optuna's plots switch pyplot to its own style
        fig = Figure(figsize=(3.4 * cols, 2.6 * rows))
        FigureCanvasAgg(fig)
        _slice_panels(fig, study, trials, best, names, cols, rows, SEARCH_SPACE, NullFormatter)
        fig.tight_layout()
        fig.savefig(path, dpi=DPI)
    return True


def _slice_panels(fig, study, trials, best, names, cols, rows, space, null_formatter) -> None:
    y = [t.value for t in trials]
    for k, name in enumerate(names):
        ax = fig.add_subplot(rows, cols, k + 1)
        x = [t.params.get(name, float("nan")) for t in trials]
        ax.scatter(x, y, c=[t.number for t in trials], cmap="viridis", s=16)
        for t, marker in ((best, "*"), (_base_trial(study), "D")):
            if t is not None and name in t.params:
                ax.scatter([t.params[name]], [t.value], marker=marker, s=90 if marker == "*" else 40,
                           facecolor="none", edgecolor="crimson", linewidth=1.2)
        low, high, scale = space[name]
        if scale == "log":
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(null_formatter())
        ax.set_xlim(low, high)
        ax.set_xlabel(name, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
        if k % cols == 0:
            ax.set_ylabel("mean success AUC", fontsize=8)


def print_summary(summary: dict, file=None) -> None:
    """The lines ``covviz tune`` prints at the end (to ``file``, default stdout)."""
    file = file or sys.stdout
    b = summary["best"]
    print(f"best: trial {b['number']}, mean success AUC {b['value']:.4f} on the tuning seeds", file=file)
    h = summary["holdout"]
    failed = [f"the {who} failed ({h[who]['error']})" for who in ("best", "base") if h and h[who].get("error")]
    if failed:
        print(f"held-out seeds {_seeds_text(h['seeds'])}: " + "; ".join(failed), file=file)
    elif h:
        print(f"held-out seeds {_seeds_text(h['seeds'])}: best {h['best']['mean']:.4f}, "
              f"base {h['base']['mean']:.4f} ({h['best']['mean'] - h['base']['mean']:+.4f})", file=file)
    print(f"best configuration: {summary['best_config']}   "
          f"(covviz track SEQUENCE --config {summary['best_config']})", file=file)
    print(f"report: {summary['report']}", file=file)
