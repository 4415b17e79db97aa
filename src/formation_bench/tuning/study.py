"""The tuning study: Optuna's seeded TPE sampler, a journal file that makes it resumable, and
batches of trials evaluated by worker processes.

Determinism. Trials are asked in batches of ``batch`` (a setting, not the worker count):
every trial of a batch is asked before any is evaluated, from the trials completed before
the batch, by a TPE sampler seeded from the tuning's seed and the trial's number
(:func:`trial_seed`). So a trial's parameters depend on the seed, its number and the trials
before its batch alone, and the same seed gives the same trials with any ``--jobs``, and
after any interruption. Trial 0 is the base configuration (enqueued).

Storage and resume. A trial enters the study's journal file (Optuna's ``JournalStorage``
with its file backend, ``<out>/<NAME>.journal``) once evaluated, complete with its value, in
trial-number order after its batch; the asking is done on an in-memory copy of the completed
trials. A killed tuning therefore leaves only complete trials behind: run again, it asks the
rest of the interrupted batch anew, which gives the parameters it had (same seed, number and
earlier trials), evaluates them and goes on. The study records its settings; a folder holding
a tuning of other settings is refused. Trials beyond ``trials`` stored by an earlier, longer
tuning of the same settings are left out: they never change the earlier ones.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from formation_bench.experiments.executors import run_locally
from formation_bench.optimizers import Optimizer, get_optimizer
from formation_bench.pipeline.spec import canonical_json
from formation_bench.tuning.objectives import TrialJob, evaluate_trial
from formation_bench.tuning.settings import TuningError, TuningSettings
from formation_bench.tuning.space import base_params, from_text, search_space, suggest
from formation_bench.tuning.variants import machine, read_variant, variant_file, write_variant

if TYPE_CHECKING:
    import optuna

SAMPLER_STREAM = 0
"""The child of the tuning's SeedSequence the sampler's seeds come from (one per trial)."""
SETTINGS_ATTR = "formation_bench_settings"
"""The study's user attribute holding the settings it was made with (less ``trials``)."""
JOURNAL_LOCK_GRACE_S = 3
"""Seconds after which a journal lock left by a killed tuning is taken as stale."""
Report = Callable[[int, int, float, float], None]
"""``report(done, total, best so far, seconds of the batch)`` after each batch."""


class TrialFailed(RuntimeError):
    """A trial whose evaluation raised or gave no finite value."""


@dataclass(frozen=True)
class TuningOutcome:
    """A finished tuning: its file, what it holds, and whether this call computed it."""

    path: Path
    data: dict[str, Any]
    computed: bool


def trial_seed(seed: int, number: int) -> int:
    """The sampler's seed for trial ``number``: a child of ``SeedSequence(seed)``."""
    sequence = np.random.SeedSequence(seed, spawn_key=(SAMPLER_STREAM, number))
    return int(sequence.generate_state(1)[0])


def journal_path(out: Path, settings: TuningSettings) -> Path:
    return out / f"{settings.variant_name}.journal"


def settings_key(settings: TuningSettings) -> str:
    """What makes two tunings the same study: every setting but the trial count (a longer
    tuning's first trials are those of a shorter one)."""
    fields = {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)}
    del fields["trials"]
    return canonical_json(fields)


def open_study(out: Path, settings: TuningSettings) -> optuna.Study:
    """The study of ``settings`` in ``out``, created or resumed; refuses a study of other
    settings."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend, JournalFileSymlinkLock

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    out.mkdir(parents=True, exist_ok=True)
    path = str(journal_path(out, settings))
    # the folder's lock already keeps other tunings out, so the journal's own lock can only be
    # left stale by a killed process: broken after 3 s (the least Optuna takes without a
    # warning) instead of its 30
    lock = JournalFileSymlinkLock(path, grace_period=JOURNAL_LOCK_GRACE_S)
    storage = JournalStorage(JournalFileBackend(path, lock_obj=lock))
    study = optuna.create_study(
        study_name=settings.variant_name, storage=storage, direction="minimize",
        load_if_exists=True,
    )  # fmt: skip
    key = settings_key(settings)
    stored = study.user_attrs.get(SETTINGS_ATTR)
    if stored is None:
        study.set_user_attr(SETTINGS_ATTR, key)
    elif stored != key:
        raise TuningError(
            f"--out: {out} holds a tuning of {settings.variant_name} with other settings "
            f"({stored}); choose another folder, or give the same settings to resume it"
        )
    return study


def completed(study: optuna.Study) -> list[optuna.trial.FrozenTrial]:
    import optuna

    trials = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    return sorted(trials, key=lambda t: t.number)


def ask(
    settings: TuningSettings, base: Optimizer, before: list[optuna.trial.FrozenTrial], number: int
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """Trial ``number``'s parameters, distributions and configuration values, asked of a TPE
    sampler seeded for it over the trials ``before`` its batch (trial 0: the base)."""
    import optuna

    sampler = optuna.samplers.TPESampler(seed=trial_seed(settings.seed, number))
    study = optuna.create_study(direction="minimize", sampler=sampler)
    study.add_trials(before)
    if number == 0:
        study.enqueue_trial(base_params(base))
    trial = study.ask()
    with warnings.catch_warnings():
        # the base's value of a setting may lie outside its searched range: trial 0 keeps it
        warnings.filterwarnings("ignore", "Fixed parameter", UserWarning)
        values = suggest(trial, settings.optimizer, base)
    distributions = dict(trial.distributions)
    if number == 0:
        distributions = {
            name: _widened(d, trial.params[name]) for name, d in distributions.items()
        }
    return dict(trial.params), distributions, values


def _widened(distribution: Any, value: Any) -> Any:
    """A numeric distribution widened to hold ``value`` (the base's, out of the searched
    range), as the stored trial must hold its own value."""
    import optuna

    numeric = (optuna.distributions.FloatDistribution, optuna.distributions.IntDistribution)
    if isinstance(distribution, numeric) and not distribution.low <= value <= distribution.high:
        low, high = min(distribution.low, value), max(distribution.high, value)
        return type(distribution)(low=low, high=high, log=distribution.log)
    return distribution


def evaluate(
    settings: TuningSettings, asked: dict[int, dict[str, Any]], jobs: int, plugins: tuple[str, ...]
) -> dict[int, float]:
    """Every asked trial's objective, on ``jobs`` worker processes; by trial number."""
    todo = [
        TrialJob(f"trial-{number}", number, values, settings, plugins)
        for number, values in asked.items()
    ]
    by_key = {job.key: job.number for job in todo}
    values: dict[int, float] = {}
    results = run_locally(todo, jobs, evaluate_trial)
    try:
        for result in results:
            number = by_key[result.key]
            if result.failed:
                last = (result.error or "no error text").strip().splitlines()[-1]
                raise TrialFailed(f"trial {number} ({asked[number]}) failed: {last}")
            value = float(result.row["value"])  # type: ignore[index]
            if not math.isfinite(value):
                raise TrialFailed(f"trial {number} ({asked[number]}) gave {value}")
            values[number] = value
    finally:
        results.close()
    return values


def run_tuning(
    settings: TuningSettings,
    out: Path,
    *,
    jobs: int = 1,
    plugins: tuple[str, ...] = (),
    command: str = "",
    report: Report | None = None,
) -> TuningOutcome:
    """Tune ``settings.optimizer`` into ``out`` (resuming what is stored there), then write
    ``<out>/<NAME>.json``; a finished tuning's file is returned as it is. Holds the folder's
    lock (as a sweep does), so a second tuning into it is refused instead of racing."""
    from formation_bench.experiments.store import ResultStore

    with ResultStore(out).lock():
        return _tune(settings, out, jobs, plugins, command, report)


def _tune(
    settings: TuningSettings,
    out: Path,
    jobs: int,
    plugins: tuple[str, ...],
    command: str,
    report: Report | None,
) -> TuningOutcome:
    import optuna

    path = out / f"{settings.variant_name}.json"
    study = open_study(out, settings)
    done = completed(study)
    if len(done) >= settings.trials and path.exists():
        stored = read_variant(path)
        if stored.get("tuner", {}).get("trials") == settings.trials:
            return TuningOutcome(path, stored, computed=False)
    base = get_optimizer(settings.optimizer)
    while len(done) < settings.trials:
        first = len(done)
        batch_start = first - first % settings.batch
        batch_end = min(batch_start + settings.batch, settings.trials)
        before = done[:batch_start]
        asked = {number: ask(settings, base, before, number) for number in range(first, batch_end)}
        started = time.perf_counter()
        values = evaluate(settings, {n: a[2] for n, a in asked.items()}, jobs, plugins)
        seconds = time.perf_counter() - started
        for number in sorted(asked):  # told in trial order, so the journal's numbers are theirs
            params, distributions, _ = asked[number]
            study.add_trial(
                optuna.trial.create_trial(
                    params=params, distributions=distributions, value=values[number],
                    user_attrs={"seconds": seconds / len(asked)},
                )
            )  # fmt: skip
        done = completed(study)
        if report is not None:
            report(len(done), settings.trials, min(t.value for t in done), seconds)  # type: ignore[type-var]
    data = result_file(settings, done[: settings.trials], command)
    write_variant(path, data)
    return TuningOutcome(path, data, computed=True)


def result_file(
    settings: TuningSettings, trials: list[optuna.trial.FrozenTrial], command: str
) -> dict[str, Any]:
    """The tuned-variant file of the finished ``trials``."""
    from formation_bench.pipeline.provenance import git_info, now

    history = [float(t.value) for t in trials]  # type: ignore[arg-type]
    best = int(np.argmin(history))  # the first of equal values: the earliest trial
    specs = {field.name: field.spec for field in search_space(get_optimizer(settings.optimizer))}
    best_values = {name: from_text(specs[name], v) for name, v in trials[best].params.items()}
    info = git_info()
    provenance = {
        "date": now(),
        "commit": info["commit"],
        "version": info["version"],
        "command": command,
        "wall_time_s": round(sum(t.user_attrs.get("seconds", 0.0) for t in trials), 3),
        "machine": machine(),
    }
    return variant_file(settings, best_values, history, history[best], provenance)


@contextmanager
def progress_report(total: int, show: bool | None) -> Iterator[Report]:
    """A tqdm bar on stderr (by default on a terminal), or one line per batch."""
    if show or (show is None and sys.stderr.isatty()):
        from tqdm import tqdm

        with tqdm(total=total, desc="trials", unit="trial", file=sys.stderr, leave=False) as bar:

            def advance(done: int, total: int, best: float, seconds: float) -> None:
                bar.update(done - bar.n)
                bar.set_postfix(best=f"{best:.4g}")

            yield advance
        return

    def line(done: int, total: int, best: float, seconds: float) -> None:
        print(f"trials {done}/{total}: best {best:.6g} (batch {seconds:.1f} s)", file=sys.stderr)

    yield line
