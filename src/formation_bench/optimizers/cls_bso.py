"""Shi's BSO with a chaotic local search (CLS) around the best idea, after the CBSO family.

Yu, Y., Gao, S., Cheng, S., Wang, Y., Song, S., Yuan, F. (2018). CBSO: a
memetic brain storm optimization with chaotic local search. Memetic
Computing 10(4), 353-367. (The CLS form goes back to the chaotic local
searches of Gao's group, e.g. Gao et al., "Gravitational search algorithm
combined with chaos for unconstrained numerical optimization", Applied
Mathematics and Computation 231, 2014.)

Every iteration is one step of Shi's BSO
(:func:`~formation_bench.optimizers.original_bso_kernels.shi_step`) plus a chaotic local
search of ``n_local`` points

    x_k = x_best + r_t (upper - lower) (2 z_k - 1),   k = 1..n_local,

where ``x_best`` is the best idea at the start of the iteration, ``z_1, z_2,
...`` are successive iterates (one chaotic sequence per coordinate, carried
over from iteration to iteration) of ``local_map``, and the radius shrinks
geometrically from ``local_radius_start`` at the first iteration to
``local_radius_end`` at the last planned one. The points are brought into the
box by the BSO's ``bound_handling`` and evaluated in the same batch as the
BSO's new ideas (one objective call per iteration; under a truncated budget
the ideas come first). After the BSO's slot-wise selection, the best local
point replaces the idea in ``x_best``'s slot if it is strictly better.

Differences from CBSO as published: CBSO draws one of twelve maps at random
for each search, here the map is a configuration field (any
:class:`~formation_bench.optimizers.chaos.ChaoticMap`); CBSO shrinks the radius by a fixed
factor per iteration, here the schedule is tied to the planned iterations so
that it spans the short budgets of an MPC solve.

The default population is 25 with 5 local points per iteration: 30 evaluations
per iteration, the same budget as the other population optimisers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from formation_bench.fields import Validated, kernel_settings_class, pack_settings, setting
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    OptimizeResult,
    PopulationOptimizer,
)
from formation_bench.optimizers.bso_ops import BoundHandling, apply_bounds_inplace
from formation_bench.optimizers.chaos import ChaoticMap, step_inplace
from formation_bench.optimizers.compiled import (
    NFEV,
    CompiledObjective,
    evaluate_leading,
    remaining,
)
from formation_bench.optimizers.original_bso_kernels import ShiConfig, ShiSettings, shi_step
from formation_bench.optimizers.population import (
    RandomAhead,
    WarmStartInit,
    compiled_initial_population,
    evaluate_prefix,
    greedy_select,
    initial_population,
    iteration_randoms,
    no_randoms,
    progress,
    run_compiled_blocks,
)
from formation_bench.optimizers.registry import register


@dataclass(frozen=True)
class LocalSearchConfig(Validated):
    """The chaotic local search's settings, declared once (composed with Shi's in the optimiser).

    Declared next to the kernels that read them: the fields marked
    ``kernel=True`` make :class:`LocalSettings`, which :func:`cls_iteration`
    rebuilds and reads by name.
    """

    n_local: int = setting(5, low=1, kernel=True, doc="Chaotic local search points per iteration")
    local_radius_start: float = setting(
        0.1, low=0.0, high=1.0, low_open=True, kernel=True,
        doc="Search radius at the first iteration, as a fraction of the range",
    )  # fmt: skip
    local_radius_end: float = setting(
        0.001, low=0.0, high="local_radius_start", low_open=True, kernel=True,
        doc="Search radius at the last planned iteration",
    )  # fmt: skip
    local_map: ChaoticMap = setting(
        ChaoticMap.LOGISTIC, kernel=True, doc="Chaotic map of the local search sequence"
    )


LocalSettings = kernel_settings_class(
    "LocalSettings",
    __name__,
    LocalSearchConfig,
    (),
    """What :func:`cls_iteration` reads of the local search: the kernel fields of
    :class:`LocalSearchConfig` (the map as an integer).""",
)


class LocalSearchState(NamedTuple):
    """The BSO population, the last candidates and bookkeeping (arrays never modified in place).

    As in :class:`~formation_bench.optimizers.original_bso.BSOState`, an iteration's candidates
    (N new ideas, then the local points) are selected at the start of the next
    iteration, by :func:`select_with_local` in the same kernel call;
    :meth:`population` applies the pending selection.
    """

    x: np.ndarray
    """Ideas before the selection of ``candidates``, shape (N, D)."""
    f: np.ndarray
    """Their costs (+inf for ideas not evaluated for lack of budget)."""
    candidates: np.ndarray
    """The last N new ideas, the n_local local points and, as the last row, the current
    value of the chaotic sequence of every coordinate (only that row at first)."""
    costs: np.ndarray
    """Costs of the ideas and local points (+inf if not evaluated); empty at first."""
    settings: tuple
    """The packed :class:`~formation_bench.optimizers.original_bso_kernels.ShiSettings`."""
    local: tuple
    """The packed :class:`LocalSettings`."""
    t_max: int
    """Planned iterations (also in ``settings``; read here by the Python side)."""
    randoms: RandomAhead
    """Random numbers drawn ahead for the next iterations."""
    replacements: int = 0
    """Random-point centre replacements so far."""
    improvements: int = 0
    """Local searches whose point was selected into the best idea's slot so far."""

    def population(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, f)`` after the pending selection of the candidates."""
        x, f, _ = select_with_local(self.x, self.f, self.candidates, self.costs, self.x.shape[0])
        return x, f


@njit(cache=True)
def local_radius(
    local_radius_start: float, local_radius_end: float, iteration: int, t_max: int
) -> float:
    """Geometric schedule: ``local_radius_start`` at iteration 1, ``local_radius_end`` at
    iteration ``t_max``."""
    ratio = local_radius_end / local_radius_start
    return local_radius_start * ratio ** progress(iteration, t_max)


@njit(cache=True)
def local_candidates(
    ideas: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    local_map: int,
    z: np.ndarray,
    n_local: int,
    radius: float,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_handling: int,
    resample_uniforms: np.ndarray,
) -> np.ndarray:
    """The ideas, the local search points and the sequence's next state, stacked.

    Rows ``0..N-1`` are ``ideas``; row ``N + k`` (k < n_local) is
    ``x_best + radius (upper - lower) (2 z_{k+1} - 1)`` brought into the box by
    ``bound_mode``, with ``x_best`` the lowest-cost row of ``x`` and ``z_{k+1}``
    the (k+1)-th iterate of ``z`` under the map ``local_map``; the last row is the
    last iterate (the next ``z``). ``resample_uniforms`` (n_local x D) is read
    only by RESAMPLE.
    """
    n, d = ideas.shape
    out = np.empty((n + n_local + 1, d))
    out[:n] = ideas
    best = x[np.argmin(f)]
    sequence = z.copy()
    scratch = np.empty(d)
    for k in range(n_local):
        step_inplace(local_map, sequence, scratch)
        for c in range(d):
            out[n + k, c] = best[c] + radius * (upper[c] - lower[c]) * (2.0 * sequence[c] - 1.0)
    out[n + n_local] = sequence
    apply_bounds_inplace(out[n : n + n_local], lower, upper, bound_handling, resample_uniforms)
    return out


@njit(cache=True)
def select_with_local(
    x: np.ndarray, f: np.ndarray, candidates: np.ndarray, costs: np.ndarray, n_ideas: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """Slot-wise greedy selection of the ideas, then the best local point into the best's slot.

    ``candidates`` holds ``n_ideas`` ideas and then the local points (further
    rows are ignored), ``costs`` one cost for each of these (none: nothing to
    select). The best local point replaces the member in the slot that held
    the best idea before this selection only if it is strictly better than
    that slot's member after the greedy selection. Returns ``(x, f, 1 if it
    did)``, new arrays.
    """
    n_costs = costs.shape[0]
    if n_costs == 0:
        return x.copy(), f.copy(), 0
    slot = np.argmin(f)
    new_x, new_f, _ = greedy_select(x, f, candidates[:n_ideas], costs[:n_ideas])
    if n_costs == n_ideas:
        return new_x, new_f, 0
    k = n_ideas + np.argmin(costs[n_ideas:])
    if costs[k] < new_f[slot]:
        new_x[slot] = candidates[k]
        new_f[slot] = costs[k]
        return new_x, new_f, 1
    return new_x, new_f, 0


@njit(cache=True)
def cls_iteration(
    x: np.ndarray,
    f: np.ndarray,
    candidates: np.ndarray,
    costs: np.ndarray,
    u: np.ndarray,
    normals: np.ndarray,
    resample_local: np.ndarray,
    iteration: int,
    shi_packed: tuple,
    local_packed: tuple,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One iteration besides the evaluations: ``(x, f, candidates, 1 if the local point won)``.

    :func:`select_with_local` of the last ``candidates``, then
    :func:`~formation_bench.optimizers.original_bso_kernels.shi_step` and :func:`local_candidates`
    around the selected population's best, from the sequence value in the
    last row of ``candidates``. ``shi_packed`` and ``local_packed`` are the
    packed :class:`~formation_bench.optimizers.original_bso_kernels.ShiSettings` and
    :class:`LocalSettings`.
    """
    s = ShiSettings(*shi_packed)
    local = LocalSettings(*local_packed)
    n = x.shape[0]
    x, f, improved = select_with_local(x, f, candidates, costs, n)
    z = candidates[candidates.shape[0] - 1]
    ideas = shi_step(x, f, u, normals, iteration, s)
    radius = local_radius(
        local_radius_start=local.local_radius_start,
        local_radius_end=local.local_radius_end,
        iteration=iteration,
        t_max=s.t_max,
    )
    out = local_candidates(
        ideas, x, f, local_map=local.local_map, z=z, n_local=local.n_local, radius=radius,
        lower=s.lower, upper=s.upper, bound_handling=s.bound_handling,
        resample_uniforms=resample_local,
    )  # fmt: skip
    return x, f, out, improved


@njit(cache=True)
def cls_block(
    address: int,
    data: np.ndarray,
    counts: np.ndarray,
    best: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    candidates: np.ndarray,
    costs: np.ndarray,
    uniforms: np.ndarray,
    normals: np.ndarray,
    nit: int,
    first_iteration: int,
    iteration_limit: int,
    shi_packed: tuple,
    local_packed: tuple,
    history_nfev: np.ndarray,
    history_fun: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int, int]:
    """Iterations ``nit + 1``, ... of a compiled solve, one per row of the random block.

    Each is :meth:`ChaoticLocalSearchBSO.step` (bound handling other than RESAMPLE, which draws
    per iteration) with the objective called through ``address``/``data``; the block stops
    early at the iteration limit or when no evaluation is left. Returns ``(x, f, candidates,
    costs, iterations done, random replacements, local improvements)``; the history arrays get
    one entry per iteration done.
    """
    s = ShiSettings(*shi_packed)
    done = 0
    replacements = 0
    improvements = 0
    row = nit + 1 - first_iteration
    while nit < iteration_limit and row < uniforms.shape[0] and remaining(counts) > 0:
        nit += 1
        u = uniforms[row]
        # the local points' resample uniforms are not read without RESAMPLE
        x, f, candidates, improved = cls_iteration(
            x, f, candidates, costs, u, normals[row], x, nit, shi_packed, local_packed
        )
        # one objective call for the ideas and the local points (ideas first under a short budget)
        costs = evaluate_leading(address, data, candidates, candidates.shape[0] - 1, counts, best)
        if u[s.n_clusters] < s.p_replace:
            replacements += 1
        improvements += improved
        history_nfev[done] = counts[NFEV]
        history_fun[done] = best[0]
        done += 1
        row += 1
    return x, f, candidates, costs, done, replacements, improvements


# WarmStartInit leads the bases because dataclass fields follow the reversed MRO: its settings
# then come after the method's own, whose positions and listing order stay as they were
@dataclass(frozen=True)
class ChaoticLocalSearchBSO(
    WarmStartInit, LocalSearchConfig, ShiConfig, PopulationOptimizer[LocalSearchState]
):
    """Shi's BSO step plus a chaotic local search around the best idea each iteration.

    Composed of Shi's settings and step
    (:class:`~formation_bench.optimizers.original_bso_kernels.ShiConfig`,
    :func:`~formation_bench.optimizers.original_bso_kernels.shi_step`) and the local search's
    (:class:`LocalSearchConfig`, :func:`local_candidates`); the fields are Shi's, then the
    local search's, then the initial population's
    (:class:`~formation_bench.optimizers.population.WarmStartInit`).
    """

    population_size: int = setting(
        25, low=2, doc="N, ideas per iteration; 25 + n_local = 30 evaluations per iteration"
    )

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iterations)

    def evaluations_per_step(self) -> int:
        return self.population_size + self.n_local

    def initial_evaluations(self) -> int:
        return self.population_size

    def result_info(self, state: LocalSearchState) -> dict[str, Any]:
        return {
            "random_replacements": state.replacements,
            "local_search_improvements": state.improvements,
        }

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> LocalSearchState:
        x, f = initial_population(counter, bounds, rng, self.population_size, x0, self)
        n, d = x.shape
        return LocalSearchState(
            x=x,
            f=f,
            candidates=rng.random((1, d)),
            costs=np.empty(0),
            settings=self.shi_settings(bounds, max_iterations),
            local=pack_settings(LocalSettings, self),
            t_max=int(max_iterations),
            randoms=no_randoms(self.uniforms_per_step(n, d), (n, d)),
        )

    def step(
        self,
        state: LocalSearchState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> LocalSearchState:
        randoms, u, normals = iteration_randoms(state.randoms, rng, iteration, state.t_max)
        resample_local = (
            rng.random((self.n_local, bounds.dim))
            if self.bound_handling is BoundHandling.RESAMPLE
            else state.x  # not read
        )
        x, f, candidates, improved = cls_iteration(
            state.x, state.f, state.candidates, state.costs, u, normals, resample_local,
            iteration, state.settings, state.local,
        )  # fmt: skip
        # one objective call for the ideas and the local points (ideas first under a short budget)
        costs = evaluate_prefix(counter, candidates[:-1])
        replaced = bool(u[self.n_clusters] < self.p_replace)
        return LocalSearchState(
            x, f, candidates, costs, state.settings, state.local, state.t_max, randoms,
            state.replacements + replaced, state.improvements + improved,
        )  # fmt: skip

    def has_compiled_loop(self) -> bool:
        # RESAMPLE draws the local points' uniforms at every iteration, between the blocks
        return self.bound_handling is not BoundHandling.RESAMPLE

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
        shi_packed = self.shi_settings(bounds, t_max)
        local_packed = pack_settings(LocalSettings, self)
        carry = [x, f, rng.random((1, d)), np.empty(0), 0, 0]

        def run_block(
            nit: int, limit: int, randoms: RandomAhead, history_nfev: np.ndarray,
            history_fun: np.ndarray,
        ) -> int:  # fmt: skip
            x, f, candidates, costs, replacements, improvements = carry
            x, f, candidates, costs, done, replaced, improved = cls_block(
                objective.address, objective.data, start.counts, start.best, x, f, candidates,
                costs, randoms.uniforms, randoms.normals, nit, randoms.first_iteration,
                limit, shi_packed, local_packed, history_nfev, history_fun,
            )  # fmt: skip
            carry[:] = [
                x, f, candidates, costs, replacements + replaced, improvements + improved
            ]  # fmt: skip
            return done

        return run_compiled_blocks(
            run_block, start, rng, budget, t_max, self.uniforms_per_step(n, d), (n, d),
            lambda: {"random_replacements": carry[4], "local_search_improvements": carry[5]},
        )  # fmt: skip


register(
    "cls-bso",
    ChaoticLocalSearchBSO(),
    "Shi's BSO + chaotic local search around the best idea (after CBSO, Yu et al. 2018)",
)
