"""Scoring an optimiser on the instance library: every instance solved, stored per run.

A *score run* (:class:`ScoreRun`) is one optimiser configuration at one
:class:`~formation_bench.optimizers.Budget` with one seed, solving every instance of one split
of the library (``test``, ``validation`` or ``all``; a library without splits, ``v1``, has
``all`` only) from its warm start, degenerate instances included. Its rows (one per instance:
where it comes from, its content hash, family, phase, split, whether it is degenerate, ``J*``
and the warm start's cost; the final cost, the relative gap ``(f - J*) / J*`` and the
normalised gap ``(f - J*) / (f_warm - J*)``, evaluations, iterations, wall time, the
evaluations to each target of the normalised gap, the improvements of the best cost so far
and the point returned; and every setting of the optimiser that ran, with the hash of its
configuration) are stored as ``DIR/score/<key>.parquet``.

A score run goes through the machinery of a sweep: its key and random numbers derive from
its identity (:class:`~formation_bench.pipeline.spec.Identified`), it is carried out by the
sweep's executor (:func:`~formation_bench.experiments.executors.run_locally`, local worker
processes, one thread each) and stored, sealed, by the sweep's store
(:class:`~formation_bench.experiments.store.ResultStore`, which holds the folder's lock while
``score`` writes). So an interrupted ``score`` resumes with the runs still missing, damaged,
stored before checksums were kept, stored with columns that mean other things
(:data:`SAME_MEANING_SCORE_FORMATS`) or of another configuration;
:func:`load_scores` (what ``report`` and ``export-ioh`` read) leaves a damaged file out and
names it on stderr. Instance ``k`` of a run draws its random numbers from
``SeedSequence([run entropy, k])``, so results do not depend on the worker count.
"""

from __future__ import annotations

import functools
import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from formation_bench.experiments.errors import StoreError
from formation_bench.experiments.executors import RunResult, computed, run_locally
from formation_bench.experiments.gaps import (
    TARGETS,
    evaluations_to_target,
    normalised_gap,
    target_column,
)
from formation_bench.experiments.store import ResultStore, to_stderr
from formation_bench.experiments.store import load_scores as load_stored_scores
from formation_bench.instances.library import (
    Instance,
    Library,
    LibraryError,
    load_shipped,
    shipped,
)
from formation_bench.optimizers import Budget, Optimizer, OptimizeResult, get_optimizer
from formation_bench.pipeline.interrupts import interrupts_deferred, interrupts_where_safe
from formation_bench.pipeline.record import Provenance
from formation_bench.pipeline.runner import warm_up_solve
from formation_bench.pipeline.spec import (
    Identified,
    budget_deadline_ms,
    budget_label,
    budget_limits,
    canonical_json,
    config_of,
    from_json_value,
    labelled,
    resolved_config_hash,
    solve_budget,
)
from formation_bench.plugins import load_plugins

SCORE_FORMAT = 3
"""What the score rows' columns mean, as a number (column ``score_format``): bumped only when
a column changes meaning, so a run stored under another meaning is redone on resume; a column
added alone changes nothing (a row stored before it reads it as empty). 2 added the
improvement history and the point returned; 3 the run's split (``run_split``), the instance's
content hash, family, phase, split, degeneracy and warm-start cost, the normalised gap, and
the evaluations to targets of the normalised gap (``evals_to_norm_*``, where 2 had targets of
the relative gap)."""
SAME_MEANING_SCORE_FORMATS = frozenset({SCORE_FORMAT})
"""Score formats whose columns mean what those of :data:`SCORE_FORMAT` mean."""
DESCRIPTION_COLUMNS = (
    "run_key",
    "optimizer",
    "optimizer_name",
    "optimizer_overrides",
    "budget",
    "budget_max_evaluations",
    "deadline_ms",
    "seed",
    "library",
    "run_split",
    "config_hash",
    "optimizer_config",
)
"""The columns that say which score run a row belongs to (:meth:`ScoreRun.description`);
``config_hash`` and ``optimizer_config`` are empty in rows stored before they were kept."""
SPLITS = ("test", "validation", "all")
"""Splits a score run can solve: a split of the library, or ``all``, every instance."""
DEFAULT_SPLIT = "test"
"""The split scored when none is named, on a library with splits (``all`` on one without)."""


class ScoreError(ValueError):
    """A score run that cannot be made as asked (one line, naming the option)."""


class ScoreRunsFailed(StoreError):
    """Score runs that raised; the others are stored."""

    def __init__(self, failed: list[tuple[ScoreRun, str]]) -> None:
        self.failed = failed
        super().__init__(f"{len(failed)} score run(s) failed")


def resolved_split(library: Library, split: str | None) -> str:
    """``split`` checked against ``library`` (None: :data:`DEFAULT_SPLIT`, or ``all`` on a
    library without splits); raises :class:`ScoreError` naming ``--split``."""
    allowed = SPLITS if library.has_splits else ("all",)
    if split is None:
        return DEFAULT_SPLIT if library.has_splits else "all"
    if split not in allowed:
        without = "" if library.has_splits else " (it has no splits)"
        raise ScoreError(
            f"--split: {split!r} is not a split of library {library.version}{without}; "
            f"allowed: {', '.join(allowed)}"
        )
    return split


def split_instances(library: Library, split: str) -> list[Instance]:
    """The instances a score run over ``split`` solves, degenerate ones included."""
    resolved_split(library, split)
    return library.instances(None if split == "all" else split, degenerate=None)


@dataclass(frozen=True)
class ScoreRun(Identified):
    """One optimiser configuration at one budget with one seed, over one split of a library."""

    ENTROPY_DOMAIN: ClassVar[bytes] = b"formation-bench score\0"

    optimizer_label: str
    optimizer_name: str
    optimizer_overrides: str
    """Canonical JSON of the fields changed from the registered configuration."""
    budget: Budget | None
    """Per-solve budget; None: the optimiser's own."""
    seed: int
    library_version: str
    split: str = "all"
    """The split solved (:data:`SPLITS`); ``all``: every instance."""
    plugins: tuple[str, ...] = ()

    @property
    def budget_label(self) -> str:
        return budget_label(self.budget)

    def identity(self) -> dict[str, Any]:
        """What the run's key and random numbers derive from. The split is part of it, but
        for ``all``, which leaves it out, so a run over a whole library keeps the key (and
        random numbers) it had before runs had splits, and is redone in place on resume."""
        max_evaluations, max_iterations = budget_limits(self.budget)
        identity = {
            "optimizer": self.optimizer_name,
            "optimizer_overrides": json.loads(self.optimizer_overrides),
            "max_evaluations": max_evaluations,
            "max_iterations": max_iterations,
            "deadline_ms": budget_deadline_ms(self.budget),
            "seed": self.seed,
            "library": self.library_version,
        }
        if self.split != "all":
            identity["split"] = self.split
        return identity

    @property
    def entropy(self) -> int:
        """Entropy of the run's random numbers (instance ``k``: ``[entropy, k]``)."""
        return self.identity_entropy()

    def optimizer(self) -> Optimizer:
        return get_optimizer(
            self.optimizer_name, **from_json_value(json.loads(self.optimizer_overrides))
        )

    def budget_for(self, optimizer: Optimizer) -> Budget | None:
        """The per-solve budget of this run's ``optimizer``; None: the optimiser's own."""
        return solve_budget(self.budget, optimizer)

    @property
    def config_hash(self) -> str:
        """SHA-256 of the fully resolved optimiser and budget: a stored run whose hash differs
        was made with other settings (changed code defaults) and is redone."""
        return self.config_hash_of(self.optimizer())

    def config_hash_of(self, optimizer: Optimizer) -> str:
        """:attr:`config_hash`, of this run's ``optimizer`` (already built)."""
        return resolved_config_hash(None, optimizer, self.budget_for(optimizer))

    def describe(self) -> str:
        return f"{self.optimizer_label} / {self.budget_label} / seed {self.seed}"

    def description(self, optimizer: Optimizer) -> dict[str, Any]:
        """The values of :data:`DESCRIPTION_COLUMNS` for a row of this run."""
        max_evaluations, _ = budget_limits(self.budget)
        deadline_ms = budget_deadline_ms(self.budget)
        return {
            "run_key": self.key,
            "optimizer": self.optimizer_label,
            "optimizer_name": self.optimizer_name,
            "optimizer_overrides": self.optimizer_overrides,
            "budget": self.budget_label,
            "budget_max_evaluations": max_evaluations,
            "deadline_ms": math.nan if deadline_ms is None else deadline_ms,
            "seed": self.seed,
            "library": self.library_version,
            "run_split": self.split,
            "config_hash": self.config_hash_of(optimizer),
            "optimizer_config": canonical_json(config_of(optimizer)),
        }


def score_runs(
    optimizer_name: str,
    overrides: dict[str, Any],
    budgets: Sequence[Budget | None],
    seeds: Sequence[int],
    *,
    library: Library | None = None,
    split: str | None = None,
    plugins: tuple[str, ...] = (),
) -> list[ScoreRun]:
    """The score runs of one optimiser configuration at every budget (None: the optimiser's
    own) and seed, over ``split`` of ``library`` (by default the shipped library and
    :func:`resolved_split`'s default)."""
    library = shipped() if library is None else library
    split = resolved_split(library, split)
    configured = get_optimizer(optimizer_name, **overrides)
    label, changed = labelled(optimizer_name, get_optimizer(optimizer_name), configured)
    return [
        ScoreRun(
            optimizer_label=label,
            optimizer_name=optimizer_name,
            optimizer_overrides=canonical_json(changed),
            budget=budget,
            seed=seed,
            library_version=library.version,
            split=split,
            plugins=plugins,
        )
        for budget in budgets
        for seed in seeds
    ]


def run_library(run: ScoreRun, library: Library | None = None) -> Library:
    """The library ``run`` solves: ``library`` if given (it must be the run's version), else
    the shipped one of the run's version."""
    if library is None:
        try:
            return load_shipped(run.library_version)
        except LibraryError as err:
            raise ScoreError(f"--library: {err}") from None
    if library.version != run.library_version:
        raise ScoreError(
            f"a score run on library {run.library_version} given library {library.version}"
        )
    return library


def execute_score(run: ScoreRun, library: Library | None = None) -> pd.DataFrame:
    """Solve every instance of the run's split once; one row per instance."""
    from threadpoolctl import threadpool_limits

    load_plugins(run.plugins)
    library = run_library(run, library)
    optimizer = run.optimizer()
    budget = run.budget_for(optimizer)
    rows = []
    instances = split_instances(library, run.split)
    with threadpool_limits(limits=1), interrupts_where_safe():
        if instances:  # compiled before the clock starts: no solve's time holds it
            first = instances[0].problem
            warm_up_solve(optimizer, first, first.bounds, budget, instances[0].warm_start)
        started = time.perf_counter()
        for instance in instances:
            start = time.perf_counter()
            result = solve_instance(optimizer, instance, run.entropy, budget)
            seconds = time.perf_counter() - start
            history_nfev = result.history_nfev if result.history_nfev.size else [result.nfev]
            history_fun = result.history_fun if result.history_fun.size else [result.fun]
            improved_nfev, improved_fun = improvements(history_nfev, history_fun)
            rows.append(
                {
                    "instance": instance.index,
                    "content_hash": instance.content_hash,
                    "family": instance.family,
                    "phase": instance.phase,
                    "split": instance.split,
                    "degenerate": bool(instance.degenerate),
                    "scenario": instance.scenario_name,
                    "trigger": instance.trigger,
                    "step": instance.step,
                    "j_star": instance.j_star,
                    "warm_cost": float(instance.warm_cost),
                    "fun": float(result.fun),
                    "gap": float(instance.gap(result.fun)),
                    "normalised_gap": normalised_gap_of(instance, result.fun),
                    "nfev": int(result.nfev),
                    "nit": int(result.nit),
                    "seconds": seconds,
                    "success": bool(result.success),
                    **{
                        target_column(t): (
                            math.nan
                            if instance.degenerate
                            else evaluations_to_target(
                                np.asarray(history_nfev),
                                np.asarray(history_fun),
                                instance.j_star,
                                instance.warm_cost,
                                t,
                            )
                        )
                        for t in TARGETS
                    },
                    "improvement_nfev": improved_nfev,
                    "improvement_fun": improved_fun,
                    "x": np.asarray(result.x, dtype=np.float64).tolist(),
                    "score_format": SCORE_FORMAT,
                }
            )
    frame = pd.DataFrame(rows)
    if frame.empty:
        raise ScoreError(f"--split: library {run.library_version} has no {run.split} instances")
    description = run.description(optimizer)
    for k, name in enumerate(DESCRIPTION_COLUMNS):
        frame.insert(k, name, [description[name]] * len(frame))
    frame["budget_max_evaluations"] = frame["budget_max_evaluations"].astype("Int64")
    # the same provenance as a closed-loop run's record: the code, the machine and the date
    # that every timing of the run needs beside it
    provenance = Provenance.here(run_time_s=time.perf_counter() - started)
    for name, value in asdict(provenance).items():
        frame[name] = value
    return frame


def solve_instance(
    optimizer: Optimizer, instance: Instance, entropy: int, budget: Budget | None
) -> OptimizeResult:
    """One solve of ``instance`` from its warm start, as a score run makes it: its random
    numbers from ``SeedSequence([entropy, instance.index])``, so they depend on the run and
    the instance only (not on the order or the worker that solves it)."""
    problem = instance.problem
    rng = np.random.default_rng(np.random.SeedSequence([entropy, instance.index]))
    return optimizer.minimize(problem, problem.bounds, rng, budget, instance.warm_start)


def execute_score_run(run: ScoreRun, library: Library | None = None) -> RunResult:
    """Carry out one score run in a worker (an executor's ``work``): its rows, or its error."""
    return computed(run.key, lambda: RunResult(run.key, None, rows=execute_score(run, library)))


def normalised_gap_of(instance: Instance, cost: float) -> float:
    """The normalised gap of ``cost`` on ``instance``: NaN on a degenerate one."""
    if instance.degenerate:
        return math.nan
    return float(normalised_gap(cost, instance.j_star, instance.warm_cost))


def improvements(history_nfev: np.ndarray, history_fun: np.ndarray) -> tuple[list, list]:
    """The points of a best-so-far history where the best cost first fell to a new low."""
    fun = np.asarray(history_fun, dtype=np.float64)
    # a solve that starts at the warm start has no cost before its first record: it counts
    previous = np.concatenate(([np.inf], np.minimum.accumulate(fun)[:-1]))
    keep = fun < previous
    return np.asarray(history_nfev)[keep].tolist(), fun[keep].tolist()


def is_stored(store: ResultStore, run: ScoreRun) -> bool:
    """Whether ``run`` is stored whole, sealed, with columns of today's meaning and its
    configuration (else resume redoes it)."""
    status = store.score_status(
        run.key, run.config_hash, SAME_MEANING_SCORE_FORMATS, "score_format"
    )
    return status.state == "done"


def stored_keys(out: Path | str, runs: Sequence[ScoreRun] | None = None) -> set[str]:
    """Keys of the score runs stored whole in ``out``: those of ``runs`` (each also of its
    configuration), or of every score file (whole, sealed, with columns of today's meaning)."""
    store = ResultStore(out)
    if runs is not None:
        return {run.key for run in runs if is_stored(store, run)}
    return {
        key
        for key in store.score_keys()
        if store.score_status(key, None, SAME_MEANING_SCORE_FORMATS, "score_format").state == "done"
    }


def write_score(out: Path | str, run: ScoreRun, frame: pd.DataFrame) -> Path:
    """Store the rows of a finished score run (sealed, atomically)."""
    return ResultStore(out).write_score(run.key, frame)


def run_scores(
    runs: Sequence[ScoreRun], out: Path | str, *, jobs: int = 2, library: Library | None = None
) -> Iterator[ScoreRun]:
    """Carry out the runs not stored whole in ``out`` (on ``library``, by default the shipped
    one), holding the folder's lock; yields each as it is stored, and at the end raises
    :class:`ScoreRunsFailed` naming the runs that raised (the others are stored)."""
    store = ResultStore(out)
    with store.lock():
        store.remove_temporaries()
        todo = [run for run in runs if not is_stored(store, run)]
        by_key = {run.key: run for run in todo}
        work = functools.partial(execute_score_run, library=library)
        failed = []
        results = run_locally(todo, jobs, work)
        try:
            for result in results:
                run = by_key[result.key]
                if result.failed:
                    failed.append((run, result.error or ""))
                    continue
                with interrupts_deferred():  # a Ctrl-C waits until the file is whole
                    store.write_score(run.key, result.rows)
                yield run
        finally:
            # stop the workers now, and let no Ctrl-C cut that short (as a sweep does)
            with interrupts_deferred():
                results.close()
    if failed:
        raise ScoreRunsFailed(failed)


def check_score_format(scores: pd.DataFrame, doing: str) -> None:
    """Raise :class:`StoreError` naming the runs of ``scores`` stored with columns that mean
    other things than today's (which ``doing`` cannot use), with the fix."""
    stored = scores["score_format"] if "score_format" in scores else pd.Series(np.nan, scores.index)
    old = scores[~stored.fillna(0).astype(int).isin(SAME_MEANING_SCORE_FORMATS)]
    if old.empty:
        return
    runs = old.drop_duplicates("run_key")
    named = ", ".join(f"{r.optimizer} / {r.budget} / seed {r.seed}" for r in runs.itertuples())
    raise StoreError(
        f"{len(runs)} score run(s) were stored in an older score format (before "
        f"{SCORE_FORMAT}: no normalised gap), which {doing} cannot use: {named}; run the same "
        "'formation-bench score' commands on the folder again to redo them"
    )


def load_scores(out: Path | str, *, notice: Callable[[str], None] = to_stderr) -> pd.DataFrame:
    """Every intact stored score row of ``out``, one row per (run, instance); a description
    column a row lacks (stored before it was kept) is empty.

    A file that fails its checks is left out and named on stderr, one line each. How many
    files were used unverified (stored before checksums were kept) goes to ``notice``.
    """
    return load_stored_scores(out, list(DESCRIPTION_COLUMNS), notice=notice)
