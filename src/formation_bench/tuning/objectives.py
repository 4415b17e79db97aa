"""What one trial's configuration scores: the tuning's objective, lower is better.

- ``solve``: the median normalised gap ``(f - J*) / (f_warm - J*)`` over the non-degenerate
  problems of the library's validation split, each solved once at the tuning's budget as a
  score run solves it (:func:`~formation_bench.experiments.score.solve_instance`). Every
  trial solves with the same random numbers (common random numbers, derived from the
  tuning's seed), so two trials differ by their configurations only.
- ``loop``: the median of a record column over closed loops at the validation seeds, each
  run by the project's one run path (:func:`~formation_bench.pipeline.runner.execute`) with
  the suite's scenario and trigger setting at the tuning's budget.

A trial is carried out by :func:`evaluate_trial` in a worker process of the sweep's executor
(or in this process); what a process loads (the library's problems, the suite) is kept for
its next trials, and numba compiles the optimiser's kernels once per process: a trial's
settings reach the kernels as values, not as compile-time constants.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from formation_bench.experiments.executors import RunResult, computed
from formation_bench.experiments.score import normalised_gap_of, solve_instance
from formation_bench.experiments.suite import Suite, load_suite
from formation_bench.instances.library import Instance, load_shipped
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import Budget, Optimizer, get_optimizer
from formation_bench.pipeline.runner import execute
from formation_bench.pipeline.spec import RunSpec, from_json_value
from formation_bench.plugins import load_plugins
from formation_bench.tuning.settings import TUNING_SPLIT, Objective, TuningSettings

SOLVE_STREAM = 1
"""The child of the tuning's SeedSequence the solves' random numbers come from (the
sampler's are :data:`~formation_bench.tuning.study.SAMPLER_STREAM`)."""


@dataclass(frozen=True)
class TrialJob:
    """One trial to evaluate, as an executor carries it out (named by its key)."""

    key: str
    number: int
    values: dict[str, Any] = field(hash=False)
    """The trial's values of the searched settings, as ``--set`` writes them."""
    settings: TuningSettings
    plugins: tuple[str, ...] = ()
    """Plugins the worker loads before building the optimiser."""


def evaluate_trial(job: TrialJob) -> RunResult:
    """The objective of one trial, in a worker (an executor's ``work``): its value in the
    result's row (``{"value": v}``), or its error."""

    def evaluated() -> RunResult:
        load_plugins(job.plugins)
        return RunResult(job.key, {"value": objective_value(job.settings, job.values)})

    return computed(job.key, evaluated)


def objective_value(settings: TuningSettings, values: dict[str, Any]) -> float:
    """The objective of the configuration ``values`` of the tuned optimiser."""
    from threadpoolctl import threadpool_limits

    optimizer = get_optimizer(settings.optimizer, **values)
    budget = Budget(max_evaluations=settings.max_evaluations)
    with threadpool_limits(limits=1):
        if settings.objective is Objective.SOLVE:
            instances = validation_instances(settings.library, settings.problems)
            return solve_objective(optimizer, instances, solve_entropy(settings.seed), budget)
        return loop_objective(settings, optimizer, budget)


def solve_entropy(seed: int) -> int:
    """The entropy of every trial's solves: one number derived from the tuning's seed (each
    problem's stream is ``SeedSequence([entropy, problem index])``, as in a score run)."""
    state = np.random.SeedSequence(seed).spawn(SOLVE_STREAM + 1)[SOLVE_STREAM].generate_state(4)
    return int.from_bytes(state.astype("<u4").tobytes(), "little")


@functools.cache
def validation_instances(library: str, problems: int | None) -> tuple[Instance, ...]:
    """The non-degenerate problems of ``library``'s validation split (the first ``problems``
    of them if given), loaded once per process."""
    instances = load_shipped(library).instances(TUNING_SPLIT)
    return tuple(instances if problems is None else instances[:problems])


def solve_objective(
    optimizer: Optimizer, instances: tuple[Instance, ...], entropy: int, budget: Budget
) -> float:
    """The median normalised gap of ``optimizer`` over ``instances``."""
    gaps = [
        normalised_gap_of(instance, solve_instance(optimizer, instance, entropy, budget).fun)
        for instance in instances
    ]
    return float(np.median(gaps))


@functools.cache
def _suite(name: str) -> Suite:
    return load_suite(name)


def loop_runs(settings: TuningSettings, optimizer: Optimizer, budget: Budget) -> list[RunSpec]:
    """The closed loops of one trial: the suite's scenario and trigger setting, at each
    validation seed (the run's seed as ``formation-bench run --seed`` takes it)."""
    suite = _suite(settings.suite)
    entry, trigger = suite.scenarios[0], suite.triggers[0]
    scenario = get_scenario(entry.name, **from_json_value(json.loads(entry.overrides)))
    return [
        RunSpec.of(
            settings.optimizer,
            optimizer,
            entry.name,
            scenario,
            trigger=trigger,
            seed=seed,
            budget=budget,
        )
        for seed in settings.seeds
    ]


def loop_objective(settings: TuningSettings, optimizer: Optimizer, budget: Budget) -> float:
    """The median of ``settings.metric`` over the closed loops of :func:`loop_runs`."""
    values = [
        float(execute(spec).record.to_json()[settings.metric])
        for spec in loop_runs(settings, optimizer, budget)
    ]
    return float(np.median(values))
