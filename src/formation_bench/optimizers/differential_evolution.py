"""Differential evolution: DE/rand/1/bin and DE/current-to-best/1/bin, configurations of one class.

Storn, R. & Price, K. (1997). *Differential Evolution - A Simple and
Efficient Heuristic for Global Optimization over Continuous Spaces*. Journal
of Global Optimization 11, 341-359.

Per generation, for every member ``x_i`` of the N-member population:

* **mutation**: ``v = x_r1 + F (x_r2 - x_r3)`` (rand/1, ``de``) or
  ``v = x_i + F (x_best - x_i) + F (x_r1 - x_r2)`` (current-to-best/1,
  ``de-current-to-best``, with one F for both terms as in scipy and in Das &
  Suganthan's survey), the partners ``r1, r2, r3`` distinct and not ``i``,
  ``x_best`` the best member at the start of the generation;
* **binomial crossover**: coordinate ``j`` of the trial comes from ``v`` when a
  uniform draw is below CR or ``j = j_rand`` (one random coordinate per
  member, so every trial differs from its target), else from ``x_i``;
* **bounds**: a trial coordinate outside the box is re-drawn uniformly in its
  range (``bound_handling=resample``, the default: the rule of scipy's
  ``differential_evolution``, which keeps the population spread where
  clipping would pile members onto the faces). ``clip`` and ``reflect`` are
  the project's other options. Only mutant coordinates can leave the box;
* **selection**: trial ``i`` replaces ``x_i`` when its cost is *no higher*
  (Storn & Price's rule; ties let the population cross plateaus). With
  ``updating=deferred`` (the default, Storn & Price's scheme) the N trials are
  made from the population at the start of the generation, evaluated in one
  batch, then selected. With ``updating=immediate`` (scipy's default,
  ``de-immediate``) trial ``i`` is made from the population as trials
  ``0 .. i-1`` left it, evaluated alone and selected at once, and the best
  member (current-to-best/1's ``x_best``) is updated as soon as a trial beats
  it: later trials of a generation already use the improvements of earlier
  ones.

The defaults F = 0.5, CR = 0.9 are Storn & Price's suggested start; N = 30
and 40 generations give the ~1230 evaluations of the other population
optimisers' default budget (Storn & Price suggest N = 5-10 D, which at the
paper problem's D = 10 would leave 12-25 generations). The warm start ``x0``
is member 0 of the initial population; with ``warm_start_share`` > 0 (see
:class:`~formation_bench.optimizers.population.WarmStartInit`, ``de-immediate-warm``)
that share of the other members is drawn around it.

A deferred generation is one compiled call
(:func:`~formation_bench.optimizers.de_ops.de_generation`) besides the
objective call, with the selection of a generation's trials deferred into the
next call, and the random numbers drawn ahead
(:func:`~formation_bench.optimizers.population.iteration_randoms`). An
immediate generation of a compiled solve is one compiled call too, objective
calls included (:func:`~formation_bench.optimizers.de_ops.immediate_generation`).
Both updating modes read the same random numbers per generation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    OptimizeResult,
    PopulationOptimizer,
)
from formation_bench.optimizers.compiled import CompiledObjective
from formation_bench.optimizers.de_ops import (
    DEConfig,
    DEStrategy,
    DEUpdating,
    best_member,
    de_block,
    de_generation,
    immediate_trial,
    select_trial_inplace,
    select_trials,
)
from formation_bench.optimizers.population import (
    RandomAhead,
    WarmStartInit,
    compiled_initial_population,
    initial_population,
    iteration_randoms,
    no_randoms,
    run_compiled_blocks,
)
from formation_bench.optimizers.registry import register


class DEState(NamedTuple):
    """Population, the last generation's trials, and bookkeeping (arrays never modified in place).

    With deferred updating the selection of a generation's trials is applied
    at the start of the next generation, in the same compiled call that makes
    the next trials; :meth:`population` applies the pending selection. With
    immediate updating nothing is pending: ``trials`` has no rows.
    """

    x: np.ndarray
    """Members before the selection of ``trials``, shape (N, D)."""
    f: np.ndarray
    """Their costs (+inf for members not evaluated for lack of budget)."""
    trials: np.ndarray
    """The last generation's evaluated trials, one per slot from 0 (0 rows at first)."""
    trial_costs: np.ndarray
    """Their costs."""
    settings: tuple
    """The packed :class:`~formation_bench.optimizers.de_ops.DESettings` of the solve."""
    t_max: int
    """Planned generations (how far ahead random numbers are drawn)."""
    randoms: RandomAhead
    """Random numbers drawn ahead for the next generations."""

    def population(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, f)`` after the pending selection of ``trials``."""
        return select_trials(self.x, self.f, self.trials, self.trial_costs)


# WarmStartInit before DEConfig: a dataclass lists the fields of its bases from the last in
# the MRO, so the DE settings come first and the initialisation's after them
@dataclass(frozen=True)
class DifferentialEvolution(WarmStartInit, DEConfig, PopulationOptimizer[DEState]):
    """Storn & Price's DE; the settings are those of
    :class:`~formation_bench.optimizers.de_ops.DEConfig` and the initial population's of
    :class:`~formation_bench.optimizers.population.WarmStartInit`."""

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
    ) -> DEState:
        """N members (member 0 = ``x0`` if given, a share around it by the warm-start settings),
        evaluated in one batch within budget."""
        x, f = initial_population(counter, bounds, rng, self.population_size, x0, init=self)
        n, d = x.shape
        return DEState(
            x=x,
            f=f,
            trials=np.empty((0, d)),
            trial_costs=np.empty(0),
            settings=self.de_settings(bounds),
            t_max=int(max_iterations),
            randoms=no_randoms(self.uniforms_per_step(n, d), (0,)),
        )

    def step(
        self,
        state: DEState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> DEState:
        """One generation.

        With immediate updating each trial must be evaluated before the next one
        is made, so this Python path calls ``counter`` once per trial (N calls of
        one row instead of one call of N); the compiled path
        (:meth:`minimize_compiled`) makes those calls inside its kernel.
        """
        randoms, u, _ = iteration_randoms(state.randoms, rng, iteration, state.t_max)
        if self.updating is DEUpdating.IMMEDIATE:
            x, f = state.population()  # new arrays, which the loop below updates in place
            best = best_member(f)
            for i in range(min(x.shape[0], counter.remaining)):
                trial = immediate_trial(x, i, best, u, state.settings)
                best = select_trial_inplace(x, f, i, best, trial, counter(trial)[0])
            return state._replace(x=x, f=f, randoms=randoms)
        x, f, trials = de_generation(
            state.x, state.f, state.trials, state.trial_costs, u, state.settings
        )
        # a generation the budget cuts short evaluates its first trials; only those compete
        allowed = min(trials.shape[0], counter.remaining)
        if allowed < trials.shape[0]:
            trials = trials[:allowed]
        costs = counter(trials)
        return DEState(x, f, trials, costs, state.settings, state.t_max, randoms)

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
        t_max = self.planned_iterations(budget)
        x, f, start = compiled_initial_population(
            objective, bounds, rng, self.population_size, x0, budget.max_evaluations, init=self
        )
        n, d = x.shape
        settings = self.de_settings(bounds)
        carry = [x, f, np.empty((0, d)), np.empty(0)]

        def run_block(
            nit: int, limit: int, randoms: RandomAhead, history_nfev: np.ndarray,
            history_fun: np.ndarray,
        ) -> int:  # fmt: skip
            x, f, trials, trial_costs, done = de_block(
                objective.address, objective.data, start.counts, start.best, *carry,
                randoms.uniforms, nit, randoms.first_iteration, limit, settings,
                history_nfev, history_fun,
            )  # fmt: skip
            carry[:] = [x, f, trials, trial_costs]
            return done

        return run_compiled_blocks(
            run_block, start, rng, budget, t_max, self.uniforms_per_step(n, d), (0,), dict
        )


register(
    "de",
    DifferentialEvolution(),
    "Differential evolution DE/rand/1/bin (Storn & Price 1997), N = 30, F = 0.5, CR = 0.9",
)
register(
    "de-current-to-best",
    DifferentialEvolution(strategy=DEStrategy.CURRENT_TO_BEST_1_BIN),
    "Differential evolution DE/current-to-best/1/bin, N = 30, F = 0.5, CR = 0.9",
)
register(
    "de-immediate",
    DifferentialEvolution(updating=DEUpdating.IMMEDIATE),
    "Differential evolution DE/rand/1/bin, N = 30, F = 0.5, CR = 0.9, immediate updating "
    "(each trial selected before the next is made: scipy's default)",
)
WARM_START_SHARE = 0.9
"""``warm_start_share`` of ``de-immediate-warm``: chosen with the spread on the instance
library's validation split (docs/optimizers.md, "Initial population around the warm start")."""
WARM_START_SPREAD = 0.02
"""``warm_start_spread`` of ``de-immediate-warm``, chosen with the share."""

register(
    "de-immediate-warm",
    DifferentialEvolution(
        updating=DEUpdating.IMMEDIATE,
        warm_start_share=WARM_START_SHARE,
        warm_start_spread=WARM_START_SPREAD,
    ),
    f"de-immediate with {WARM_START_SHARE:.0%} of the initial population drawn around the warm "
    f"start (std {WARM_START_SPREAD:g} x range), the rest uniform",
)
