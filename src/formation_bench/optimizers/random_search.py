"""Uniform random search: the floor every optimiser must beat.

Each iteration draws ``population_size`` points uniformly in the box and
evaluates them in one batch; the initial batch holds the warm start ``x0``
(when given) in its first row, so the result is never worse than the warm
start. Nothing is learned from the costs: the evaluation counter keeps the
best point seen, which is the result. A solve whose objective is compiled runs its batches in
:func:`random_search_block`, which draws, evaluates and tracks them as the Python loop does.
With the defaults (30 points, 40
iterations after the first batch) it spends the ~1230 evaluations of the other
population optimisers' default budget, so its result is the budget's worth
of blind sampling any method has to improve on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from formation_bench.fields import Validated, setting
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    OptimizeResult,
    PopulationOptimizer,
)
from formation_bench.optimizers.compiled import NFEV, CompiledObjective, evaluate, remaining
from formation_bench.optimizers.population import (
    compiled_initial_population,
    initial_population,
    run_compiled_draws,
)
from formation_bench.optimizers.registry import register


@njit(cache=True)
def random_search_block(
    address: int,
    data: np.ndarray,
    counts: np.ndarray,
    best: np.ndarray,
    lower: np.ndarray,
    width: np.ndarray,
    population_size: int,
    rows: int,
    uniforms: np.ndarray,
    history_nfev: np.ndarray,
    history_fun: np.ndarray,
) -> int:
    """``rows`` iterations of a compiled solve: :meth:`RandomSearch.step` with the objective
    called through ``address``/``data`` (see :mod:`~formation_bench.optimizers.compiled`).

    Each batch of ``m = min(population_size, evaluations left)`` points is
    ``lower + u * width`` on the next ``m * D`` entries of ``uniforms`` (row by row, as
    :meth:`Bounds.sample <formation_bench.optimizers.base.Bounds.sample>` uses its draw). Stops
    early when no evaluation is left; returns the iterations done, each with its history entry.
    """
    d = lower.shape[0]
    used = 0
    done = 0
    for _ in range(rows):
        m = min(population_size, remaining(counts))
        if m <= 0:
            break
        points = np.empty((m, d))
        for i in range(m):
            for c in range(d):
                points[i, c] = lower[c] + uniforms[used + i * d + c] * width[c]
        used += m * d
        evaluate(address, data, points, m, counts, best)
        history_nfev[done] = counts[NFEV]
        history_fun[done] = best[0]
        done += 1
    return done


@dataclass(frozen=True)
class RandomSearch(Validated, PopulationOptimizer[None]):
    """Uniform samples in the box, batch-evaluated; see the module docstring."""

    population_size: int = setting(30, low=1, doc="Points drawn and evaluated per batch")
    max_iterations: int = setting(
        40, low=0,
        doc="Batches after the first when the caller gives no budget; default budget N (T + 1)",
    )  # fmt: skip

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iterations)

    def evaluations_per_step(self) -> int:
        return self.population_size

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> None:
        """The first batch: N uniform points (row 0 = ``x0`` if given), within the budget."""
        initial_population(counter, bounds, rng, self.population_size, x0)

    def step(
        self,
        state: None,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> None:
        counter(bounds.sample(rng, min(self.population_size, counter.remaining)))

    def has_compiled_loop(self) -> bool:
        return True

    def minimize_compiled(
        self,
        objective: CompiledObjective,
        bounds: Bounds,
        rng: np.random.Generator,
        budget: Budget,
        x0: np.ndarray | None,
    ) -> OptimizeResult:
        n, d = self.population_size, bounds.dim
        _, _, start = compiled_initial_population(
            objective, bounds, rng, n, x0, budget.max_evaluations
        )
        lower, width = np.array(bounds.lower), bounds.width

        def run_block(
            nit: int, rows: int, uniforms: np.ndarray, history_nfev: np.ndarray,
            history_fun: np.ndarray,
        ) -> int:  # fmt: skip
            return random_search_block(
                objective.address, objective.data, start.counts, start.best, lower, width, n,
                rows, uniforms, history_nfev, history_fun,
            )  # fmt: skip

        return run_compiled_draws(
            run_block, start, rng, budget, self.planned_iterations(budget), n,
            lambda evaluated: evaluated * d, dict,
        )  # fmt: skip


register(
    "random-search",
    RandomSearch(),
    "Uniform random search, 30 points per batch (the floor every optimiser must beat)",
)
