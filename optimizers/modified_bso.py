"""The paper's modified Brain Storm Optimization (section 2.3), with its ablations.

Per iteration: k-means of the population into ``m`` clusters (initial centres
are ``m`` distinct members drawn at random); the best member of each cluster
is its centre; with probability ``p_r`` a random centre is replaced by the
best of ``n_r`` chaotic points (eqs. 6-7); every one of the ``N`` slots gets
a new idea from a chaotic weighting of all centres (eqs. 8-9, with eq. 8 as
corrected in the reading notes) moved by the logsig step of eq. (10), which
replaces the slot's member only when strictly better.

Switching off ``all_centre_weighting`` uses Shi's (2011) idea selection
instead; switching off ``chaos_replacement`` drops the replacement. With both
off the algorithm is Shi's BSO without its random-point centre replacement.

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

from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    PopulationOptimizer,
    check_bool,
    check_int,
    check_real,
    coerce_enum,
)
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    chaotic_candidates,
    cluster_centres,
    distinct_indices,
    greedy_select,
)
from formation_bench.optimizers.chaos import ChaoticMap
from formation_bench.optimizers.clustering import (
    DEFAULT_MAX_ITER,
    ClusteringBackend,
    sklearn_kmeans,
)
from formation_bench.optimizers.modified_bso_kernels import (
    KernelSettings,
    ideas_from_clusters,
    modified_bso_iteration,
)
from formation_bench.optimizers.population import (
    RandomAhead,
    evaluate_prefix,
    initial_population,
    iteration_randoms,
    no_randoms,
    step_scale,
)


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
    """The kernel arguments fixed for the solve (T_max, bounds, step scale, configuration)."""
    randoms: RandomAhead
    """Random numbers drawn ahead for the next iterations."""
    replacements: int = 0
    """Chaotic replacements performed so far."""

    def population(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, f)`` after the pending slot-wise selection of ``ideas``."""
        x, f, _ = greedy_select(self.x, self.f, self.ideas, self.idea_costs)
        return x, f


@dataclass(frozen=True)
class ModifiedBSO(PopulationOptimizer[ModifiedBSOState]):
    """Modified BSO: chaotic centre replacement and chaotic all-centre auxiliary solutions.

    The chaotic replacement overwrites the chosen centre with the best
    chaotic candidate **even when that candidate is worse** than the centre,
    as published (the best member found so far is still kept by the
    evaluation counter). Its ``n_r`` candidates are evaluated in one batch
    and count toward the budget.

    Under an evaluation budget the last batch is truncated: only the first
    ``remaining`` ideas are evaluated and the other slots keep their members,
    and a replacement is skipped when fewer than ``n_r`` evaluations remain,
    so ``nfev`` equals ``max_evaluations`` exactly when that limit binds.
    The logsig schedule's T_max is the number of iterations the budget
    allows (see :meth:`evaluations_per_step`).
    """

    population_size: int = 30
    """N, ideas per iteration (>= 2)."""
    n_clusters: int = 5
    """m, k-means clusters (1..N)."""
    max_iterations: int = 40
    """T_max when the caller gives no budget (>= 0); the default budget."""
    slope: float = 20.0
    """k, slope of the logsig step-size schedule of eq. (10) (> 0)."""
    p_replace: float = 0.2
    """p_r, probability per iteration of a chaotic centre replacement ([0, 1])."""
    n_replace: int = 10
    """n_r, chaotic candidates per replacement (>= 1)."""
    n_weight_iterations: int = 10
    """n_h, iterations of the weight map from the random seed ch(0) (>= 0)."""
    replacement_map: ChaoticMap = ChaoticMap.LOGISTIC
    """f_rmap, chaotic map of the replacement candidates (eq. 6)."""
    weight_map: ChaoticMap = ChaoticMap.LOGISTIC
    """f_hmap, chaotic map of the centre weights (eq. 8)."""
    normalise_weights: bool = True
    """Scale each idea's weights to sum to one (False: the raw weights printed in eq. 9)."""
    step_scale: float = 0.1
    """Multiplier of the N(0, 1) step of eq. (10) (> 0)."""
    step_relative_to_range: bool = True
    """Multiply ``step_scale`` by each coordinate's range ``upper - lower``."""
    bound_handling: BoundHandling = BoundHandling.CLIP
    """How ideas outside the bounds are brought back."""
    clustering: ClusteringBackend = ClusteringBackend.COMPILED
    """k-means implementation."""
    kmeans_max_iter: int = DEFAULT_MAX_ITER
    """Cap on Lloyd iterations per clustering (>= 1)."""
    p_one_cluster: float = 0.8
    """Shi's p_6b: idea from one cluster rather than two ([0, 1]; all-centre weighting off)."""
    p_one_centre: float = 0.4
    """Shi's p_6biii: one-cluster idea is the centre, else a random member ([0, 1])."""
    p_two_centres: float = 0.5
    """Shi's p_6c: two-cluster idea mixes the centres, else random members ([0, 1])."""
    chaos_replacement: bool = True
    """Ablation switch: chaotic centre replacement (eqs. 6-7)."""
    all_centre_weighting: bool = True
    """Ablation switch: all-centre auxiliary solutions (eqs. 8-9), else Shi's selection."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        put = object.__setattr__  # frozen: normalised values are written back this way
        put(self, "population_size", check_int(owner, "population_size", self.population_size, 2))
        n = self.population_size
        put(self, "n_clusters", check_int(owner, "n_clusters", self.n_clusters, 1, n))
        for name, low in (
            ("max_iterations", 0),
            ("n_replace", 1),
            ("n_weight_iterations", 0),
            ("kmeans_max_iter", 1),
        ):
            put(self, name, check_int(owner, name, getattr(self, name), low))
        put(self, "slope", check_real(owner, "slope", self.slope, 0.0, low_open=True))
        put(
            self, "step_scale", check_real(owner, "step_scale", self.step_scale, 0.0, low_open=True)
        )
        for name in ("p_replace", "p_one_cluster", "p_one_centre", "p_two_centres"):
            put(self, name, check_real(owner, name, getattr(self, name), 0.0, 1.0))
        for name in (
            "normalise_weights",
            "step_relative_to_range",
            "chaos_replacement",
            "all_centre_weighting",
        ):
            put(self, name, check_bool(owner, name, getattr(self, name)))
        for name, enum_type in (
            ("replacement_map", ChaoticMap),
            ("weight_map", ChaoticMap),
            ("bound_handling", BoundHandling),
            ("clustering", ClusteringBackend),
        ):
            put(self, name, coerce_enum(owner, name, enum_type, getattr(self, name)))

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

    def kernel_settings(self, bounds: Bounds, t_max: int) -> KernelSettings:
        """The kernel arguments fixed for a solve over ``bounds`` planning ``t_max`` iterations."""
        return KernelSettings(
            t_max=int(t_max),
            slope=self.slope,
            n_clusters=self.n_clusters,
            kmeans_max_iter=self.kmeans_max_iter,
            all_centre=self.all_centre_weighting,
            weight_map=int(self.weight_map),
            n_weight_iterations=self.n_weight_iterations,
            normalise=self.normalise_weights,
            p_one_cluster=self.p_one_cluster,
            p_one_centre=self.p_one_centre,
            p_two_centres=self.p_two_centres,
            scale=step_scale(bounds, self.step_scale, self.step_relative_to_range),
            lower=np.array(bounds.lower),
            upper=np.array(bounds.upper),
            bound_mode=int(self.bound_handling),
        )

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> ModifiedBSOState:
        """N uniform points (row 0 = ``x0`` if given), evaluated in one call within the budget."""
        x, f = initial_population(counter, bounds, rng, self.population_size, x0)
        n, d = x.shape
        randoms = no_randoms(self.uniforms_per_step(n, d), (n, d))
        settings = self.kernel_settings(bounds, max_iterations)
        return ModifiedBSOState(x, f, np.empty((0, d)), np.empty(0), settings, randoms)

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
                candidate_costs, iteration, *settings,
            )  # fmt: skip
        else:
            x, f = state.population()
            labels, _ = sklearn_kmeans(x, x[distinct_indices(u[:m], n)], self.kmeans_max_iter)
            centre_index, sizes = cluster_centres(labels, f, m)
            x, f, ideas = ideas_from_clusters(
                x, f, labels, centre_index, sizes, u, normals, replace, candidates,
                candidate_costs, iteration, *settings,
            )  # fmt: skip
        # the replacement may have used the last evaluations: then no idea is evaluated
        costs = evaluate_prefix(counter, ideas)
        return ModifiedBSOState(x, f, ideas, costs, settings, randoms, state.replacements + replace)
