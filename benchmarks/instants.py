"""Recorded per-UAV problems from a closed-loop run, for timing and comparisons.

Benchmarks of one solve need realistic problems: the paper scenario's
problems as the closed loop actually poses them (estimates, reference, warm
start). :func:`record_instants` runs the loop with a recording wrapper around
an optimiser and keeps the problems it was given.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mpc.loop import simulate
from mpc.problem import LocalProblem
from mpc.scenario import Scenario
from optimizers.base import BatchObjective, Bounds, Budget, Optimizer, OptimizeResult


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
class _Recorder(Optimizer):
    inner: Optimizer
    calls: list[tuple[LocalProblem, np.ndarray]] = field(default_factory=list)

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
        assert isinstance(objective, LocalProblem) and x0 is not None
        self.calls.append((objective, x0.copy()))
        return self.inner.minimize(objective, bounds, rng, budget, x0)


def record_instants(
    scenario: Scenario,
    optimizer: Optimizer,
    steps: list[int],
    *,
    seed: int = 0,
) -> list[RecordedInstant]:
    """Problems of every UAV at the given instants of a run without trigger."""
    last = max(steps)
    if last >= scenario.n_steps:
        raise ValueError(f"steps must be < n_steps={scenario.n_steps}, got {last}")
    recorder = _Recorder(optimizer)
    short = scenario.with_overrides(n_steps=last + 1, settle_time_s=0.0)
    simulate(short, recorder, trigger=False, seed=seed)
    n_uav = scenario.n_uav
    wanted = set(steps)
    return [
        RecordedInstant(index // n_uav, index % n_uav, problem, warm_start)
        for index, (problem, warm_start) in enumerate(recorder.calls)
        if index // n_uav in wanted
    ]
