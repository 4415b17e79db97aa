"""nevergrad's optimisers (NGOpt, TwoPointsDE, ...) behind the formation-bench interface.

Rapin, J. & Teytaud, O. (2018), *Nevergrad - A gradient-free optimization
platform*, https://github.com/facebookresearch/nevergrad. Needs the ``adapters``
extra (:data:`~.common.INSTALL_HINT`); nevergrad is imported when a solve starts,
not when this module is.

**Batches.** The optimiser is built with ``num_workers = batch_size``, so it
plans for that many candidates in flight (NGOpt picks its algorithm knowing
it); every iteration asks ``batch_size`` candidates, evaluates them in one call
of the batch objective, then tells all their costs. nevergrad's ``tell`` takes
one candidate at a time, the objective is still called once per batch.

**Budget.** nevergrad is given the solve's evaluation budget (or, under an
iteration budget only, ``batch_size`` times the iterations plus one); a last
batch that would exceed it asks only the evaluations left.

**Bounds.** The decision vector is a ``nevergrad.p.Array`` with the box as its
bounds (nevergrad's default "bouncing" keeps every candidate inside); the
values are projected onto the box again, a no-op that guarantees it.

**Warm start.** ``x0`` is the array's initial value (the centre of the
search; the box centre without one) and is ``suggest``-ed, so it is the first
candidate evaluated.

**Seeding.** The parametrisation's ``random_state`` is a ``RandomState`` seeded
from the passed Generator, which is where nevergrad's optimisers draw their
numbers (the sub-optimisers NGOpt builds, and pycma inside nevergrad's CMA,
are seeded from it): same Generator, same solve. Building a bounded array
draws one number from numpy's global state (for a random state nevergrad
replaces at once); the adapter puts the global state back. NGOpt's meta-model
(which it picks for small problems) builds optimisers that seed themselves
from numpy's global state at every ask: the optimiser is built, asked and told
with the global state swapped for one seeded from the same Generator
(:class:`~.common.SolveGlobalRandomState`), so those draws are repeatable too
and a solve leaves the caller's global state as it was.

**numpy 2.4.** nevergrad 1.0.12 (the newest release as of November 2026)
fails inside its meta-model with numpy >= 2.4, which refuses ``float()`` of
a one-element array; NGOpt picks a meta-model for small problems (measured
with numpy 2.4.6: every budget from 31 to 3000 evaluations at n = 4, 400
evaluations at n = 10; CMA, which works, at n = 10 and 20 from 1230
evaluations on). The project's lock holds a numpy below 2.4
(``requirements/known-breaks.txt``); with a newer numpy the adapter raises a
:class:`~.common.LibraryIncompatibility` naming the versions instead of
nevergrad's TypeError. Another algorithm (``ng-de``) does not meet it.

**Costs.** Non-finite costs are told as a finite penalty above every finite
cost seen (:func:`~.common.finite_costs`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from formation_bench.fields import Validated, setting
from formation_bench.optimizers.adapters.common import (
    LibraryIncompatibility,
    SolveGlobalRandomState,
    finite_costs,
    global_random_state_kept,
    import_library,
    library_seed,
)
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    PopulationOptimizer,
    budget_setting,
)

ALGORITHMS = (
    "NGOpt",
    "TwoPointsDE",
    "DE",
    "CMA",
    "DiagonalCMA",
    "PSO",
    "OnePlusOne",
    "TBPSA",
    "Shiwa",
)
"""nevergrad registry names the adapter offers: algorithms that take a batch of candidates."""


class NevergradState(NamedTuple):
    """The nevergrad optimiser of the solve, which its ``ask``/``tell`` change in place."""

    optimizer: Any
    """The ``nevergrad.optimizers`` instance."""
    worst: float
    """Worst finite cost seen so far (-inf before any), for the penalty of non-finite ones."""
    global_state: SolveGlobalRandomState
    """numpy's global random state the optimiser is asked and told under."""


@dataclass(frozen=True)
class NevergradOptimizer(Validated, PopulationOptimizer[NevergradState]):
    """A nevergrad optimiser asked and told whole batches; see the module docstring."""

    algorithm: str = setting(
        "NGOpt", choices=ALGORITHMS, doc="nevergrad optimiser, by its name in nevergrad's registry"
    )
    batch_size: int = setting(
        30, low=1, doc="Candidates asked per iteration (nevergrad's num_workers), one call for all"
    )
    max_evaluations: int = budget_setting(
        1230, doc="Evaluations when the caller gives no budget (the default budget)"
    )

    @property
    def default_budget(self) -> Budget:
        return Budget(max_evaluations=self.max_evaluations)

    def evaluations_per_step(self) -> int:
        return self.batch_size

    def planned_iterations(self, budget: Budget) -> int:
        """Iterations needed to spend the budget (the last one possibly a partial batch)."""
        planned = []
        if budget.max_iterations is not None:
            planned.append(budget.max_iterations)
        if budget.max_evaluations is not None:
            left = max(0, budget.max_evaluations - self.batch_size)
            planned.append(math.ceil(left / self.batch_size))
        return int(min(planned))

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> NevergradState:
        """Builds the nevergrad optimiser and evaluates its first batch (``x0`` first if given)."""
        ng = import_library("nevergrad", f"the nevergrad adapter ({self.algorithm})")
        start = 0.5 * (bounds.lower + bounds.upper) if x0 is None else x0
        # a bounded Array seeds a first random state from numpy's global one while it is built
        # (replaced just below)
        with global_random_state_kept():
            parametrization = ng.p.Array(init=start, lower=bounds.lower, upper=bounds.upper)
        seed = library_seed(rng)
        parametrization.random_state = np.random.RandomState(seed)
        global_state = SolveGlobalRandomState(seed)
        total = min(counter.remaining, self.batch_size * (max_iterations + 1))
        with global_state.active():
            optimizer = ng.optimizers.registry[self.algorithm](
                parametrization=parametrization, budget=total, num_workers=self.batch_size
            )
            if x0 is not None:
                optimizer.suggest(x0)
        state = NevergradState(optimizer, -np.inf, global_state)
        return self.step(state, counter, bounds, rng, 0)

    def step(
        self,
        state: NevergradState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> NevergradState:
        optimizer = state.optimizer
        try:
            with state.global_state.active():
                asked = min(self.batch_size, counter.remaining)
                candidates = [optimizer.ask() for _ in range(asked)]
        except TypeError as err:
            if "only 0-dimensional arrays" not in str(err):
                raise
            raise LibraryIncompatibility(_metamodel_failure(optimizer)) from err
        if not candidates:
            return state
        points = bounds.clip(np.array([c.value for c in candidates], dtype=np.float64))
        costs, worst = finite_costs(counter(points), state.worst)
        with state.global_state.active():
            for candidate, cost in zip(candidates, costs.tolist(), strict=True):
                optimizer.tell(candidate, cost)
        return NevergradState(optimizer, worst, state.global_state)

    def result_info(self, state: NevergradState) -> dict[str, Any]:
        """The algorithm NGOpt (or another wrapper) chose, when nevergrad says."""
        chosen = getattr(state.optimizer, "optim", None)
        return {"nevergrad_algorithm": type(chosen or state.optimizer).__name__}


def _metamodel_failure(optimizer: Any) -> str:
    from importlib.metadata import version

    chosen = type(getattr(optimizer, "optim", None) or optimizer).__name__
    return (
        f"nevergrad {version('nevergrad')}'s {chosen} failed with numpy {np.__version__}: its "
        "meta-model converts one-element arrays with float(), which numpy >= 2.4 refuses. "
        "NGOpt picks a meta-model for small dimensions or budgets; install the locked numpy "
        "(pip install -c requirements/lock.txt numpy, in the clone), or use a larger budget or "
        "another algorithm (ng-de)"
    )
