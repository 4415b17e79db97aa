"""Uniform random search: the floor every optimiser must beat.

Each iteration draws ``population_size`` points uniformly in the box and
evaluates them in one batch; the initial batch holds the warm start ``x0``
(when given) in its first row, so the result is never worse than the warm
start. Nothing is learned from the costs: the evaluation counter keeps the
best point seen, which is the result. With the defaults (30 points, 40
iterations after the first batch) it spends the ~1230 evaluations of the other
population optimisers' default budget, so its result is the budget's worth
of blind sampling any method has to improve on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from formation_bench.fields import Validated, setting
from formation_bench.optimizers.base import Bounds, Budget, EvaluationCounter, PopulationOptimizer
from formation_bench.optimizers.population import initial_population
from formation_bench.optimizers.registry import register


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


register(
    "random-search",
    RandomSearch(),
    "Uniform random search, 30 points per batch (the floor every optimiser must beat)",
)
