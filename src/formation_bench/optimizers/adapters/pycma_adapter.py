"""pycma's CMA-ES (``cma.CMAEvolutionStrategy``) behind the formation-bench interface.

Hansen, N., Akimoto, Y. & Baudis, P., *CMA-ES/pycma*,
https://github.com/CMA-ES/pycma. Needs the ``adapters`` extra
(:data:`~.common.INSTALL_HINT`); pycma is imported when a solve starts.

**Coordinates and bounds.** pycma searches the box normalised to [0, 1]^n
with the box as its ``bounds`` option, so pycma's own bound handling
(``BoundTransform``, its default) maps every sample into the box; the
evaluated point is ``lower + u (upper - lower)``, projected onto the box
against rounding. ``sigma0`` is a fraction of each coordinate's range, as in
the project's ``cma-es``.

**Batches.** Each iteration is one ``ask()`` of ``popsize`` points, one call
of the batch objective, one ``tell()``. A generation the evaluation budget
cuts short evaluates its first points only and is not told.

**Start, warm start, restarts.** The first mean is ``x0`` (else a uniform
point of the box), evaluated first, so the result is never worse than it.
When pycma meets one of its stop criteria before the budget is spent, a new
run starts from a uniform point with the same ``popsize`` and ``sigma0``.

**Seeding.** pycma's ``randn`` option is the passed Generator's
``standard_normal`` and its ``seed`` option is NaN ("do nothing"), so pycma
draws from the passed Generator only and leaves numpy's global state alone.

**Costs.** Non-finite costs are told as a finite penalty above every finite
cost seen (:func:`~.common.finite_costs`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from formation_bench.fields import Validated, setting
from formation_bench.optimizers.adapters.common import finite_costs, import_library
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    PopulationOptimizer,
    budget_setting,
)


class PyCMAState(NamedTuple):
    """The current pycma run, which ``ask``/``tell`` change in place, and what came before."""

    strategy: Any
    """The ``cma.CMAEvolutionStrategy`` of the current run."""
    worst: float
    """Worst finite cost seen so far (-inf before any), for the penalty of non-finite ones."""
    stops: tuple[str, ...] = ()
    """Why each earlier run stopped (pycma's stop criteria)."""


@dataclass(frozen=True)
class PyCMA(Validated, PopulationOptimizer[PyCMAState]):
    """pycma's CMA-ES with ask/tell batches and restarts; see the module docstring."""

    population_size: int | None = setting(
        None, kind=int, optional=True, low=2,
        doc="pycma's popsize, points per generation; None: pycma's default 4 + floor(3 ln n)",
    )  # fmt: skip
    sigma0: float = setting(
        0.2, low=0.0, high=1.0, low_open=True,
        doc="Initial step size as a fraction of each coordinate's range",
    )  # fmt: skip
    max_evaluations: int = budget_setting(
        1230, doc="Evaluations when the caller gives no budget (the default budget)"
    )

    @property
    def default_budget(self) -> Budget:
        return Budget(max_evaluations=self.max_evaluations)

    def evaluations_per_step(self) -> int:
        """popsize if set; else pycma's default at n = 10 (an estimate: n is not known yet)."""
        return self.population_size or 4 + int(3 * math.log(10))

    def initial_evaluations(self) -> int:
        return 1

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> PyCMAState:
        """Evaluates the start (``x0`` or a uniform point) and starts a run there."""
        start = bounds.sample(rng, 1) if x0 is None else x0[None].copy()
        counter(start)
        mean = (start[0] - bounds.lower) / bounds.width
        return PyCMAState(self.new_run(mean, rng), -math.inf)

    def new_run(self, mean: np.ndarray, rng: np.random.Generator) -> Any:
        """A pycma run centred on ``mean`` (normalised) drawing from ``rng`` only."""
        cma = import_library("cma", "the pycma adapter")
        options = {
            "bounds": [0.0, 1.0],
            "seed": math.nan,
            "randn": lambda *shape: rng.standard_normal(shape),
            "verbose": -9,
            "verb_disp": 0,
            "verb_log": 0,
        }
        if self.population_size is not None:
            options["popsize"] = self.population_size
        # no stop by pycma's own evaluation or iteration limits: the budget is ours
        options["maxfevals"] = math.inf
        options["maxiter"] = math.inf
        return cma.CMAEvolutionStrategy(np.clip(mean, 0.0, 1.0), self.sigma0, options)

    def step(
        self,
        state: PyCMAState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> PyCMAState:
        strategy, stops = state.strategy, state.stops
        stop = strategy.stop()
        if stop:
            stops = (*stops, ", ".join(sorted(stop)))
            strategy = self.new_run(rng.random(bounds.dim), rng)
        solutions = strategy.ask()
        unit = np.array(solutions, dtype=np.float64)
        points = bounds.clip(bounds.lower + unit * bounds.width)
        allowed = min(points.shape[0], counter.remaining)
        costs = counter(points[:allowed])
        if allowed < points.shape[0]:
            return PyCMAState(strategy, state.worst, stops)
        told, worst = finite_costs(costs, state.worst)
        strategy.tell(solutions, told.tolist())
        return PyCMAState(strategy, worst, stops)

    def result_info(self, state: PyCMAState) -> dict[str, Any]:
        """Restarts, why each earlier run stopped, the last run's popsize and sigma."""
        return {
            "restarts": len(state.stops),
            "stops": list(state.stops),
            "population_size": int(state.strategy.popsize),
            "sigma": float(state.strategy.sigma),
        }
