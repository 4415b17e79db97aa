"""Recorded per-UAV problems from a closed-loop run, for timing and comparisons.

Benchmarks of one solve need realistic problems: the paper scenario's
problems as the closed loop actually poses them (estimates, reference, warm
start). :func:`record_instants` runs the loop with a recording wrapper around
an optimiser and keeps the problems it was given.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from formation_bench.mpc.loop import simulate
from formation_bench.mpc.problem import LocalProblem
from formation_bench.mpc.scenario import Scenario
from formation_bench.optimizers.base import (
    BatchObjective,
    Bounds,
    Budget,
    Optimizer,
    OptimizeResult,
)


@dataclass(frozen=True)
class RecordedInstant:
    """One problem as the closed loop posed it."""

    step: int
    """Update instant c."""
    uav: int
    """UAV index (0-based)."""
    problem: LocalProblem
    """The batch objective with its bounds."""
    warm_start: np.ndarray
    """The shifted previous plan the loop passed as ``x0``."""


@dataclass(frozen=True)
class Solve:
    """One call of an observed optimiser."""

    objective: BatchObjective
    """What it minimised (a :class:`LocalProblem` in the closed loop)."""
    warm_start: np.ndarray | None
    """The ``x0`` it was given."""
    result: OptimizeResult
    """What it returned."""
    seconds: float
    """Wall time of the ``minimize`` call alone."""


@dataclass(frozen=True)
class ObservedOptimizer(Optimizer):
    """Runs ``inner`` unchanged and keeps every call (for recording and timing)."""

    inner: Optimizer
    solves: list[Solve] = field(default_factory=list)

    @property
    def default_budget(self) -> Budget:
        return self.inner.default_budget

    def minimize(
        self,
        objective: BatchObjective,
        bounds: Bounds,
        rng: np.random.Generator,
        budget: Budget | None = None,
        x0: np.ndarray | None = None,
    ) -> OptimizeResult:
        start = time.perf_counter()
        result = self.inner.minimize(objective, bounds, rng, budget, x0)
        seconds = time.perf_counter() - start
        self.solves.append(Solve(objective, None if x0 is None else x0.copy(), result, seconds))
        return result


def record_instants(
    scenario: Scenario,
    optimizer: Optimizer,
    steps: list[int],
    *,
    seed: int = 0,
) -> list[RecordedInstant]:
    """Problems of every UAV at the given instants of a run without trigger."""
    last = max(steps)
    if last >= scenario.timing.n_steps:
        raise ValueError(f"steps must be < n_steps={scenario.timing.n_steps}, got {last}")
    recorder = ObservedOptimizer(optimizer)
    short = scenario.with_overrides(n_steps=last + 1, settle_time_s=0.0)
    simulate(short, recorder, trigger=False, seed=seed)
    n_uav = scenario.n_uav
    wanted = set(steps)
    return [
        RecordedInstant(index // n_uav, index % n_uav, solve.objective, solve.warm_start)
        for index, solve in enumerate(recorder.solves)
        if index // n_uav in wanted
    ]
