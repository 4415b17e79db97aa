"""The paper's modified Brain Storm Optimization (section 2.3), with its ablations.

Per iteration: k-means of the population into ``m`` clusters (initial centres
are ``m`` distinct members drawn at random); the best member of each cluster
is its centre; with probability ``p_r`` a random centre is replaced by the
best of ``n_r`` chaotic points (eqs. 6-7); every one of the ``N`` slots gets
a new idea from a chaotic weighting of all centres (eqs. 8-9, eq. 8 corrected as
described in docs/paper.md) moved by the logsig step of eq. (10), which
replaces the slot's member only when strictly better.

Switching off ``all_centre_weighting`` uses Shi's (2011) idea selection
instead; switching off ``chaos_replacement`` drops the replacement. With both
off the algorithm is Shi's BSO without its random-point centre replacement.

The paper starts from N uniform points with the warm start as one of them, and so does
``modified-bso``. ``modified-bso-warm``, not part of the paper, draws a share of them around
the warm start (:class:`~formation_bench.optimizers.population.WarmStartInit`).

Each iteration is one compiled call
(:func:`~formation_bench.optimizers.modified_bso_kernels.modified_bso_iteration`) besides the
objective calls, with the slot-wise selection deferred into the next call
(see :class:`ModifiedBSOState`) and the random numbers drawn ahead
(:func:`~formation_bench.optimizers.population.iteration_randoms`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from formation_bench.fields import pack_settings
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    OptimizeResult,
    PopulationOptimizer,
)
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    chaotic_candidates,
    cluster_centres,
    distinct_indices,
)
from formation_bench.optimizers.chaos import ChaoticMap
from formation_bench.optimizers.clustering import ClusteringBackend, sklearn_kmeans
from formation_bench.optimizers.compiled import CompiledObjective
from formation_bench.optimizers.modified_bso_kernels import (
    KernelSettings,
    ModifiedBSOConfig,
    ideas_from_clusters,
    modified_bso_block,
    modified_bso_iteration,
)
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
    step_scale,
)
from formation_bench.optimizers.registry import register


class ModifiedBSOState(NamedTuple):
    """Population, the last batch of ideas, and bookkeeping (arrays are never modified in place).

    The slot-wise selection of an iteration's ideas is applied at the start of
    the next iteration, inside the same compiled call as its clustering and
    idea generation: an iteration then costs one kernel call besides the
    objective. :meth:`population` applies the pending selection.

    A NamedTuple rather than a frozen dataclass: it is built once per
    iteration, and its constructor costs a third as much.
    """

    x: np.ndarray
    """Population before the selection of ``ideas``, shape (N, D)."""
    f: np.ndarray
    """Its costs (+inf for members not evaluated for lack of budget)."""
    ideas: np.ndarray
    """The last iteration's ideas, each competing for its slot, shape (N, D); 0 rows at first."""
    idea_costs: np.ndarray
    """Their costs (+inf for ideas not evaluated for lack of budget)."""
    settings: KernelSettings
    """The kernel settings fixed for the solve (T_max, bounds, step scale, configuration)."""
    packed: tuple
    """``settings`` as the plain tuple the kernels take."""
    randoms: RandomAhead
    """Random numbers drawn ahead for the next iterations."""
    replacements: int = 0
    """Chaotic replacements performed so far."""

    def population(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, f)`` after the pending slot-wise selection of ``ideas``."""
        x, f, _ = greedy_select(self.x, self.f, self.ideas, self.idea_costs)
        return x, f


# WarmStartInit leads the bases because dataclass fields follow the reversed MRO: its settings
# then come after the method's own, whose positions and listing order stay as they were
@dataclass(frozen=True)
class ModifiedBSO(WarmStartInit, ModifiedBSOConfig, PopulationOptimizer[ModifiedBSOState]):
    """The paper's modified BSO; the settings are those of
    :class:`~formation_bench.optimizers.modified_bso_kernels.ModifiedBSOConfig` and, for the
    initial population, :class:`~formation_bench.optimizers.population.WarmStartInit`."""

    # --- interface -------------------------------------------------------------------------------

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iterations)

    def evaluations_per_step(self) -> int:
        """N, plus the expected replacement evaluations ``round(p_r * n_r)`` when enabled.

        Counting the replacements' expected cost makes the planned T_max (and
        so the logsig schedule) match the iterations an evaluation budget
        actually allows.
        """
        extra = round(self.p_replace * self.n_replace) if self.chaos_replacement else 0
        return self.population_size + int(extra)

    def initial_evaluations(self) -> int:
        return self.population_size

    def result_info(self, state: ModifiedBSOState) -> dict[str, Any]:
        return {"chaotic_replacements": state.replacements}

    def kernel_settings(self, bounds: Bounds, t_max: int) -> tuple:
        """The packed :class:`KernelSettings` of a solve over ``bounds`` planning ``t_max``."""
        return pack_settings(
            KernelSettings,
            self,
            t_max=int(t_max),
            scale=step_scale(bounds, self.step_scale, self.step_relative_to_range),
            lower=np.array(bounds.lower),
            upper=np.array(bounds.upper),
        )

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> ModifiedBSOState:
        """N points (row 0 = ``x0`` if given, a share around it if configured, the rest
        uniform), evaluated in one call within the budget."""
        x, f = initial_population(counter, bounds, rng, self.population_size, x0, self)
        n, d = x.shape
        randoms = no_randoms(self.uniforms_per_step(n, d), (n, d))
        packed = self.kernel_settings(bounds, max_iterations)
        settings = KernelSettings(*packed)
        return ModifiedBSOState(x, f, np.empty((0, d)), np.empty(0), settings, packed, randoms)

    def uniforms_per_step(self, n: int, d: int) -> int:
        """Length of one iteration's uniforms (the layout is in :meth:`step`)."""
        width = self.n_clusters if self.all_centre_weighting else SHI_UNIFORMS_PER_IDEA
        resample = self.bound_handling is BoundHandling.RESAMPLE
        return self.n_clusters + 2 + d + n * (width + 1) + (n * d if resample else 0)

    def step(
        self,
        state: ModifiedBSOState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> ModifiedBSOState:
        n, d = state.x.shape
        m = self.n_clusters
        settings = state.settings
        # One row of uniforms per iteration, laid out as: k-means seeds (m) | p_r0 |
        # replaced cluster | cr(0) (D) | idea seeds (N x (m or 7)) | rand (N) | resample
        # values (N x D, if used), and N x D normals. The layout does not depend on which
        # branches are taken, so runs stay comparable.
        randoms, u, normals = iteration_randoms(state.randoms, rng, iteration, settings.t_max)
        # Replacement needs all n_r candidates; when fewer evaluations remain it is
        # skipped and the rest of the budget goes to the ideas. The candidates do not
        # depend on the clustering, so they are made and evaluated before it.
        replace = bool(
            self.chaos_replacement and u[m] < self.p_replace and counter.remaining >= self.n_replace
        )
        if replace:
            candidates = chaotic_candidates(
                int(self.replacement_map), u[m + 2 : m + 2 + d], self.n_replace, settings.lower,
                settings.upper,
            )  # fmt: skip
            candidate_costs = counter(candidates)
        else:  # placeholders of the right types, not read
            candidates, candidate_costs = state.x, state.f
        if self.clustering is ClusteringBackend.COMPILED:
            x, f, ideas = modified_bso_iteration(
                state.x, state.f, state.ideas, state.idea_costs, u, normals, replace, candidates,
                candidate_costs, iteration, state.packed,
            )  # fmt: skip
        else:
            x, f = state.population()
            labels, _ = sklearn_kmeans(x, x[distinct_indices(u[:m], n)], self.kmeans_max_iter)
            centre_index, sizes = cluster_centres(labels, f, m)
            x, f, ideas = ideas_from_clusters(
                x, f, labels, centre_index, sizes, u, normals, replace, candidates,
                candidate_costs, iteration, state.packed,
            )  # fmt: skip
        # the replacement may have used the last evaluations: then no idea is evaluated
        costs = evaluate_prefix(counter, ideas)
        return ModifiedBSOState(
            x, f, ideas, costs, settings, state.packed, randoms, state.replacements + replace
        )

    def has_compiled_loop(self) -> bool:
        return self.clustering is ClusteringBackend.COMPILED

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
        packed = self.kernel_settings(bounds, t_max)
        replacement = (
            self.chaos_replacement, float(self.p_replace), int(self.n_replace),
            int(self.replacement_map),
        )  # fmt: skip
        carry = [x, f, np.empty((0, d)), np.empty(0), 0]

        def run_block(
            nit: int, limit: int, randoms: RandomAhead, history_nfev: np.ndarray,
            history_fun: np.ndarray,
        ) -> int:  # fmt: skip
            x, f, ideas, idea_costs, replacements = carry
            x, f, ideas, idea_costs, done, replaced = modified_bso_block(
                objective.address, objective.data, start.counts, start.best, x, f, ideas,
                idea_costs, randoms.uniforms, randoms.normals, nit, randoms.first_iteration,
                limit, replacement, packed, history_nfev, history_fun,
            )  # fmt: skip
            carry[:] = [x, f, ideas, idea_costs, replacements + replaced]
            return done

        return run_compiled_blocks(
            run_block, start, rng, budget, t_max, self.uniforms_per_step(n, d), (n, d),
            lambda: {"chaotic_replacements": carry[4]},
        )  # fmt: skip


WARM_START_SHARE = 0.9
"""``warm_start_share`` of ``modified-bso-warm``: chosen with the spread on the instance
library's validation split (docs/optimizers.md, "Initial population around the warm start")."""
WARM_START_SPREAD = 0.005
"""``warm_start_spread`` of ``modified-bso-warm``, chosen with the share."""

register(
    "modified-bso",
    ModifiedBSO(),
    "Modified BSO of the paper: chaotic centre replacement + chaotic all-centre weighting",
)
register(
    "modified-bso-warm",
    ModifiedBSO(warm_start_share=WARM_START_SHARE, warm_start_spread=WARM_START_SPREAD),
    f"modified-bso with {WARM_START_SHARE:.0%} of the initial population drawn around the "
    f"warm start (std {WARM_START_SPREAD:g} x range), the rest uniform; not the paper's start",
)
register(
    "modified-bso-no-chaos-replacement",
    ModifiedBSO(chaos_replacement=False),
    "Modified BSO ablation: without the chaotic centre replacement (eqs. 6-7)",
)
register(
    "modified-bso-no-all-centre",
    ModifiedBSO(all_centre_weighting=False),
    "Modified BSO ablation: Shi's idea selection instead of all-centre weighting (eqs. 8-9)",
)
register(
    "modified-bso-no-modifications",
    ModifiedBSO(chaos_replacement=False, all_centre_weighting=False),
    "Modified BSO with both modifications off (Shi's BSO without random centre replacement)",
)
register(
    "modified-bso-raw-weights",
    ModifiedBSO(normalise_weights=False),
    "Modified BSO with the raw, unnormalised chaotic weights printed in eq. (9)",
)
for _map in ChaoticMap:
    if _map is not ChaoticMap.LOGISTIC:
        register(
            f"modified-bso-{_map.name.lower()}",
            ModifiedBSO(replacement_map=_map, weight_map=_map),
            f"Modified BSO with the {_map.name.lower()} map as f_rmap and f_hmap",
        )
del _map
