"""mealpy's metaheuristics (its original BSO, SHADE) behind the formation-bench interface.

Van Thieu, N. & Mirjalili, S. (2023), *MEALPY: An open-source library for latest
meta-heuristic algorithms in Python*, Journal of Systems Architecture 139,
https://github.com/thieu1995/mealpy. Needs the ``adapters`` extra
(:data:`~.common.INSTALL_HINT`); mealpy is imported when a solve starts. Written
against mealpy 3.0's ``Optimizer`` (``check_problem``, ``evolve``, ...).

**Batches.** mealpy evaluates one point per call in its default mode. In its
``swarm`` mode an algorithm hands whole groups of new points to
``update_target_for_population``; the adapter runs the algorithm in that mode
with that method (and ``get_target``, for the single points some algorithms
still evaluate on their own) replaced by a call of the batch objective. How
large the batches are is the algorithm's: SHADE evaluates its whole
population in one call per iteration; the original BSO one cluster per call
(``m_clusters`` calls of ``pop_size / m_clusters`` points) and a single point
when it replaces a cluster centre; GWO and WOA their whole population in
one call.

**Loop and budget.** The adapter drives mealpy's iteration (``evolve``) itself
instead of calling ``solve``: one ``evolve`` is one iteration, and mealpy's
``epoch`` (which schedules such as BSO's step size read) is the number of
iterations the budget allows. An evaluation that would exceed the budget is
not made: the point gets the cost +inf, and the solve ends after that
iteration, so the evaluation count is exact.

**Start and warm start.** The initial population is drawn uniformly in the box
from the passed Generator, ``x0`` as its first member when given, and
evaluated in one call.

**Bounds.** mealpy corrects every new point into the box (its
``correct_solution``; the BSO replaces a coordinate outside it by a uniform
one), and the adapter projects onto the box again against rounding.

**Seeding.** mealpy draws from a ``numpy.random.default_rng(seed)`` of its own
(the algorithm's ``generator``, the variables' generators); the seed is drawn
from the passed Generator, so same Generator, same solve. Only algorithms that
draw from those generators alone are offered (:data:`ALGORITHMS`): mealpy
3.0.2's SHADE, L-SHADE and DE also draw from numpy's global state (through
``scipy.stats``), so a seed would not fix their solves.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from formation_bench.fields import Validated, setting
from formation_bench.optimizers.adapters.common import import_library, library_seed
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    PopulationOptimizer,
    budget_setting,
)
from formation_bench.optimizers.population import evaluate_prefix

ALGORITHMS = {
    "OriginalBSO": "mealpy.human_based.BSO",
    "ImprovedBSO": "mealpy.human_based.BSO",
    "OriginalGWO": "mealpy.swarm_based.GWO",
    "OriginalWOA": "mealpy.swarm_based.WOA",
}
"""mealpy classes the adapter offers, and the modules they live in: ones checked to draw every
random number from mealpy's seeded generators and to run on the population as the adapter
builds it (mealpy's PSO, for one, keeps per-agent memories the adapter does not set up)."""


class MealpyState(NamedTuple):
    """The mealpy optimiser of the solve, which ``evolve`` changes in place."""

    model: Any
    """The mealpy ``Optimizer`` instance (a subclass evaluating through the batch objective)."""


@functools.cache
def batched_class(algorithm: str) -> type:
    """The mealpy class ``algorithm`` with its evaluations routed to one batch objective.

    The instance's ``batch_evaluate`` (set by the adapter) takes an ``(n, d)``
    array and returns ``n`` costs.
    """
    import_library("mealpy", f"the mealpy adapter ({algorithm})")
    from mealpy.utils.target import Target

    module = import_library(ALGORITHMS[algorithm], f"the mealpy adapter ({algorithm})")
    base = getattr(module, algorithm)

    def update_target_for_population(self: Any, pop: list[Any] | None = None) -> list[Any]:
        costs = self.batch_evaluate(np.array([agent.solution for agent in pop]))
        for agent, cost in zip(pop, costs.tolist(), strict=True):
            agent.target = Target(objectives=[cost], weights=self.problem.obj_weights)
        self.nfe_counter += len(pop)
        return pop

    def get_target(self: Any, solution: np.ndarray, counted: bool = True) -> Any:
        if counted:
            self.nfe_counter += 1
        cost = float(self.batch_evaluate(np.asarray(solution)[None])[0])
        return Target(objectives=[cost], weights=self.problem.obj_weights)

    return type(
        f"Batched{algorithm}",
        (base,),
        {"update_target_for_population": update_target_for_population, "get_target": get_target},
    )


def _not_called(x: np.ndarray) -> float:
    raise RuntimeError("mealpy evaluates through the adapter's batch objective")


@dataclass(frozen=True)
class MealpyOptimizer(Validated, PopulationOptimizer[MealpyState]):
    """A mealpy algorithm, iteration by iteration, evaluating in batches; see the module doc."""

    algorithm: str = setting(
        "OriginalBSO", choices=tuple(ALGORITHMS), doc="mealpy class, by its name in mealpy"
    )
    population_size: int = setting(
        30, low=10, doc="mealpy's pop_size (at least 10, mealpy's own lower limit)"
    )
    max_evaluations: int = budget_setting(
        1230, doc="Evaluations when the caller gives no budget (the default budget)"
    )

    @property
    def default_budget(self) -> Budget:
        return Budget(max_evaluations=self.max_evaluations)

    def evaluations_per_step(self) -> int:
        return self.population_size

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> MealpyState:
        """Sets mealpy up as its ``solve`` would, with a population from ``rng`` (``x0`` first)."""
        cls = batched_class(self.algorithm)
        mealpy = import_library("mealpy", f"the mealpy adapter ({self.algorithm})")
        problem = mealpy.Problem(
            bounds=mealpy.FloatVar(lb=bounds.lower, ub=bounds.upper),
            minmax="min",
            obj_func=_not_called,
            obj_weights=np.ones(1),
            log_to=None,
        )
        model = cls(epoch=max(1, min(max_iterations, 100_000)), pop_size=self.population_size)
        model.batch_evaluate = lambda x: evaluate_prefix(counter, bounds.clip(x))
        model.check_problem(problem, library_seed(rng))
        model.check_mode_and_workers("swarm", None)
        model.check_termination("start", None, None)
        model.initialize_variables()
        start = bounds.sample(rng, self.population_size)
        if x0 is not None:
            start[0] = x0
        model.pop = model.update_target_for_population(
            [model.generate_empty_agent(x) for x in start]
        )
        model.initialization()
        model.after_initialization()
        model.before_main_loop()
        return MealpyState(model)

    def step(
        self,
        state: MealpyState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> MealpyState:
        model = state.model
        # mealpy's schedules run to its epoch; iterations past it (an iteration budget larger
        # than planned cannot happen, a deadline-free evaluation budget can) stay at its end
        model.evolve(min(iteration, model.epoch))
        population, model.g_best = model.update_global_best_agent(model.pop)
        if model.sort_flag:
            model.pop = population
        return state

    def planned_iterations(self, budget: Budget) -> int:
        """Iterations needed to spend the budget at ``population_size`` points each."""
        planned = []
        if budget.max_iterations is not None:
            planned.append(budget.max_iterations)
        if budget.max_evaluations is not None:
            left = max(0, budget.max_evaluations - self.population_size)
            planned.append(math.ceil(left / self.population_size))
        return int(min(planned))

    def result_info(self, state: MealpyState) -> dict[str, Any]:
        """mealpy's own count of the evaluations it asked for (budget-cut ones included)."""
        return {"mealpy_evaluations": int(state.model.nfe_counter)}
