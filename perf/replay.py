"""The time a solve spends inside its objective, when the solve runs in compiled code.

A compiled solve loop (:mod:`formation_bench.optimizers.compiled`) calls the cost with no clock
around it. Its objective time is therefore measured by replay: the same solve is run once
through Python with an objective that records every batch (both loops evaluate the same
batches, as the tests show), and those batches are then evaluated again through the
objective's compiled handle, in one compiled loop, under the clock. The replay's caches are
warmer than the solve's, so it can only underestimate the objective's time: a share outside
the objective computed from it errs on the high side.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numba import njit

from formation_bench.optimizers.base import Bounds, Budget, Optimizer
from formation_bench.optimizers.compiled import CompiledObjective, call_cost


class RecordingObjective:
    """A batch objective that keeps a copy of every batch it evaluates."""

    def __init__(self, objective: Callable[[np.ndarray], np.ndarray]) -> None:
        self.objective = objective
        self.batches: list[np.ndarray] = []

    def __call__(self, x: np.ndarray) -> np.ndarray:
        self.batches.append(np.array(x, dtype=np.float64))
        return self.objective(x)


@njit(cache=True)
def _evaluate_batches(
    address: int, data: np.ndarray, points: np.ndarray, offsets: np.ndarray
) -> float:
    total = 0.0
    for b in range(offsets.shape[0] - 1):
        rows = offsets[b + 1] - offsets[b]
        costs = call_cost(address, data, points[offsets[b] : offsets[b + 1]], rows)
        total += costs[0]  # read, so that no call can be left out
    return total


def solve_batches(
    optimizer: Optimizer,
    objective: Callable[[np.ndarray], np.ndarray],
    bounds: Bounds,
    rng: np.random.Generator,
    budget: Budget | None,
    x0: np.ndarray | None,
) -> list[np.ndarray]:
    """The batches a solve evaluates, in order (run through Python, the handle hidden)."""
    recording = RecordingObjective(objective)
    optimizer.minimize(recording, bounds, rng, budget, x0)
    return recording.batches


def replayed_objective_seconds(
    handle: CompiledObjective,
    batches: list[np.ndarray],
    repeats: int = 3,
    clock: Callable[[], float] = time.thread_time,
) -> float:
    """Fastest of ``repeats`` evaluations of ``batches`` through ``handle``, by ``clock``."""
    points = np.ascontiguousarray(np.concatenate(batches), dtype=np.float64)
    offsets = np.concatenate([[0], np.cumsum([b.shape[0] for b in batches])]).astype(np.int64)
    _evaluate_batches(handle.address, handle.data, points, offsets)  # compile or load first
    fastest = np.inf
    for _ in range(repeats):
        start = clock()
        _evaluate_batches(handle.address, handle.data, points, offsets)
        fastest = min(fastest, clock() - start)
    return float(fastest)
