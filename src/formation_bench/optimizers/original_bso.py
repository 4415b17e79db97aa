"""Shi's Brain Storm Optimization exactly as published (ICSI 2011), on the shared BSO operators.

Shi, Y. (2011). Brain Storm Optimization Algorithm. In: Advances in Swarm
Intelligence (ICSI 2011), LNCS 6728, pp. 303-309, Springer.

Per iteration, following the paper's steps:

2. **k-means** of the N ideas into m clusters (Lloyd's algorithm, started
   from m distinct members drawn at random), re-run every iteration;
3. the **best idea of each cluster is its centre**;
4. with probability **p_5a** (0.2) a randomly chosen centre is replaced by a
   **uniformly random point** of the box. The paper does not say whether
   that point is evaluated or enters the population; here it replaces the
   centre only as a *source of ideas* for this iteration: it is not
   evaluated and the population slot of the old centre keeps its idea;
5. every one of the N slots gets a new idea: with probability **p_6b** (0.8)
   from **one cluster chosen with probability proportional to its size**
   (p_6bi), its centre with probability **p_6biii** (0.4) or else a uniformly
   random member; otherwise from **two distinct clusters** chosen uniformly,
   both centres with probability **p_6c** (0.5) or else one random member of
   each, mixed as **r A + (1 - r) B** with r uniform in (0, 1) per idea;
6. the idea is moved by ``xi * N(0, 1)`` with an independent normal per
   dimension and ``xi = logsig((0.5 T_max - t) / k) * rand``, where ``rand`` is
   one uniform per idea and **k = 20**;
7. **slot-wise greedy selection**: the new idea replaces the idea in the same
   slot only when it is strictly better.

Where public implementations deviate (and this one does not): fixed groups of
consecutive indices instead of k-means, a cluster chosen at random instead of
by size, a greedy step that compares the new idea with itself and so always
accepts it, and 0.5 (A + B) instead of r A + (1 - r) B (all in mealpy's
``OriginalBSO``), one ``xi`` per iteration instead of one per idea and no
``xi`` at all for ideas from a random member (mealpy), or one normal value
added to every dimension (other implementations). ``docs/optimizers.md``
compares this implementation with mealpy's on BBOB functions.

The paper says nothing about ideas that leave the box; they are clipped
(``bound_handling``). The step ``N(0, 1)`` is in absolute units as published
(``step_scale = 1``, ``step_relative_to_range = False``); on a box as narrow as
the turn-rate bounds of the paper problem (+-0.25) that step is huge, which is
why the modified BSO scales it by the range.

Shi starts from N uniform ideas; here the warm start is one of them, as for every
population method. ``original-bso-warm``, not Shi's, draws a share of them around the warm
start (:class:`~formation_bench.optimizers.population.WarmStartInit`).

The random numbers of one iteration are laid out as in
:class:`~formation_bench.optimizers.modified_bso.ModifiedBSO` with all-centre weighting off,
the random point taking the place of the chaotic seed ``cr(0)``: with
``p_replace = 0`` and the same step settings the two produce identical runs,
which the tests use to show that the ablation without both modifications is
Shi's idea generation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    OptimizeResult,
    PopulationOptimizer,
)
from formation_bench.optimizers.compiled import CompiledObjective
from formation_bench.optimizers.original_bso_kernels import ShiConfig, shi_block, shi_ideas
from formation_bench.optimizers.population import (
    RandomAhead,
    WarmStartInit,
    compiled_initial_population,
    evaluate_prefix,
    greedy_select,
    initial_population,
    iteration_randoms,
    no_randoms,
    run_compiled_blocks,
)
from formation_bench.optimizers.registry import register


class BSOState(NamedTuple):
    """Ideas, the last batch of new ideas, and bookkeeping (arrays are never modified in place).

    Step 7 (the slot-wise selection) of an iteration is applied at the start
    of the next one, in the same compiled call as its steps 2-6, so that an
    iteration costs one kernel call besides the objective; :meth:`population`
    applies the pending selection. A NamedTuple rather than a frozen
    dataclass: it is built once per iteration, and its constructor costs a
    third as much.
    """

    x: np.ndarray
    """Ideas before the selection of ``new_ideas``, shape (N, D)."""
    f: np.ndarray
    """Their costs (+inf for ideas not evaluated for lack of budget)."""
    new_ideas: np.ndarray
    """The last iteration's new ideas, each competing for its slot, (N, D); 0 rows at first."""
    new_costs: np.ndarray
    """Their costs (+inf for ideas not evaluated for lack of budget)."""
    settings: tuple
    """The packed :class:`~formation_bench.optimizers.original_bso_kernels.ShiSettings` of the
    solve (T_max, bounds, step scale, configuration)."""
    t_max: int
    """Planned iterations (also in ``settings``; read here by the Python side)."""
    randoms: RandomAhead
    """Random numbers drawn ahead for the next iterations."""
    replacements: int = 0
    """Random-point centre replacements so far."""

    def population(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, f)`` after the pending slot-wise selection of ``new_ideas``."""
        x, f, _ = greedy_select(self.x, self.f, self.new_ideas, self.new_costs)
        return x, f


# WarmStartInit leads the bases because dataclass fields follow the reversed MRO: its settings
# then come after the method's own, whose positions and listing order stay as they were
@dataclass(frozen=True)
class OriginalBSO(WarmStartInit, ShiConfig, PopulationOptimizer[BSOState]):
    """Shi's (2011) BSO: probabilities and slope as published; N and T_max for ~1300 evaluations.

    The settings are those of :class:`~formation_bench.optimizers.original_bso_kernels.ShiConfig`
    and, for the initial ideas, :class:`~formation_bench.optimizers.population.WarmStartInit`.
    """

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iterations)

    def evaluations_per_step(self) -> int:
        return self.population_size

    def result_info(self, state: BSOState) -> dict[str, Any]:
        return {"random_replacements": state.replacements}

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> BSOState:
        """N ideas (row 0 = ``x0`` if given, a share around it if configured, the rest uniform),
        evaluated in one batch within the budget."""
        x, f = initial_population(counter, bounds, rng, self.population_size, x0, self)
        n, d = x.shape
        return BSOState(
            x=x,
            f=f,
            new_ideas=np.empty((0, d)),
            new_costs=np.empty(0),
            settings=self.shi_settings(bounds, max_iterations),
            t_max=int(max_iterations),
            randoms=no_randoms(self.uniforms_per_step(n, d), (n, d)),
        )

    def step(
        self,
        state: BSOState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> BSOState:
        settings = state.settings
        randoms, u, normals = iteration_randoms(state.randoms, rng, iteration, state.t_max)
        x, f, ideas = shi_ideas(
            state.x, state.f, state.new_ideas, state.new_costs, u, normals, iteration, settings
        )
        costs = evaluate_prefix(counter, ideas)
        replaced = bool(u[self.n_clusters] < self.p_replace)
        return BSOState(
            x, f, ideas, costs, settings, state.t_max, randoms, state.replacements + replaced
        )

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
            objective, bounds, rng, self.population_size, x0, budget.max_evaluations, self
        )
        n, d = x.shape
        settings = self.shi_settings(bounds, t_max)
        carry = [x, f, np.empty((0, d)), np.empty(0), 0]

        def run_block(
            nit: int, limit: int, randoms: RandomAhead, history_nfev: np.ndarray,
            history_fun: np.ndarray,
        ) -> int:  # fmt: skip
            x, f, ideas, idea_costs, replacements = carry
            x, f, ideas, idea_costs, done, replaced = shi_block(
                objective.address, objective.data, start.counts, start.best, x, f, ideas,
                idea_costs, randoms.uniforms, randoms.normals, nit, randoms.first_iteration,
                limit, settings, history_nfev, history_fun,
            )  # fmt: skip
            carry[:] = [x, f, ideas, idea_costs, replacements + replaced]
            return done

        return run_compiled_blocks(
            run_block, start, rng, budget, t_max, self.uniforms_per_step(n, d), (n, d),
            lambda: {"random_replacements": carry[4]},
        )  # fmt: skip


WARM_START_SHARE = 0.9
"""``warm_start_share`` of ``original-bso-warm``: chosen with the spread on the instance
library's validation split (docs/optimizers.md, "Initial population around the warm start")."""
WARM_START_SPREAD = 0.005
"""``warm_start_spread`` of ``original-bso-warm``, chosen with the share."""

register(
    "original-bso",
    OriginalBSO(),
    "Shi's (2011) BSO as published: k-means, random-point centre replacement, logsig N(0,1) step",
)
register(
    "original-bso-warm",
    OriginalBSO(warm_start_share=WARM_START_SHARE, warm_start_spread=WARM_START_SPREAD),
    f"original-bso with {WARM_START_SHARE:.0%} of the initial ideas drawn around the warm "
    f"start (std {WARM_START_SPREAD:g} x range), the rest uniform; not Shi's start",
)
register(
    "original-bso-range-step",
    OriginalBSO(step_scale=0.1, step_relative_to_range=True),
    "Shi's BSO with the modified BSO's step (0.1 x range instead of N(0, 1))",
)
