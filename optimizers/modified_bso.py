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
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    PopulationOptimizer,
    check_bool,
    check_int,
    check_real,
    coerce_enum,
)
from optimizers.bound_handling import BoundHandling
from optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    chaotic_candidates,
    cluster_centres,
    cluster_population_packed,
    distinct_indices,
    generate_ideas,
    greedy_select,
    install_best,
    logsig_factor,
    random_centre,
)
from optimizers.chaos import ChaoticMap
from optimizers.clustering import DEFAULT_MAX_ITER, ClusteringBackend, sklearn_kmeans


@dataclass(frozen=True)
class ModifiedBSOState:
    """Population and bookkeeping between iterations (arrays are never modified in place)."""

    x: np.ndarray
    """Population, shape (N, D)."""
    f: np.ndarray
    """Costs of the population (+inf for members not evaluated for lack of budget)."""
    t_max: int
    """Planned iterations: T_max of the logsig schedule."""
    lower: np.ndarray
    """Lower bounds (a private writable copy: numba compiles read-only arrays separately)."""
    upper: np.ndarray
    """Upper bounds (same reason)."""
    scale: np.ndarray
    """Per-coordinate multiplier of the eq. (10) step, shape (D,)."""
    clustering_time_s: float = 0.0
    """Wall time spent clustering so far (k-means and picking each cluster's best member)."""
    replacements: int = 0
    """Chaotic replacements performed so far."""


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
        return {
            "clustering_time_s": state.clustering_time_s,
            "chaotic_replacements": state.replacements,
        }

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> ModifiedBSOState:
        """N uniform points (row 0 = ``x0`` if given), evaluated in one call within the budget."""
        n = self.population_size
        x = bounds.sample(rng, n)
        if x0 is not None:
            x[0] = x0
        f = np.full(n, math.inf)
        n_eval = min(n, counter.remaining)
        f[:n_eval] = counter(x[:n_eval])
        scale = self.step_scale * (
            bounds.width if self.step_relative_to_range else np.ones(bounds.dim)
        )
        return ModifiedBSOState(
            x=x,
            f=f,
            t_max=int(max_iterations),
            lower=np.array(bounds.lower),
            upper=np.array(bounds.upper),
            scale=np.ascontiguousarray(scale, dtype=np.float64),
        )

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
        width = m if self.all_centre_weighting else SHI_UNIFORMS_PER_IDEA
        resample = self.bound_handling is BoundHandling.RESAMPLE
        # One draw of uniforms, laid out as: k-means seeds (m) | p_r0 | replaced cluster |
        # cr(0) (D) | idea seeds (N x width) | rand (N) | resample values (N x D, if used).
        # The layout does not depend on which branches are taken, so runs stay comparable.
        o_cr = m + 2
        o_idea = o_cr + d
        o_rand = o_idea + n * width
        o_res = o_rand + n
        u = rng.random(o_res + (n * d if resample else 0))
        normals = rng.standard_normal((n, d))

        start = time.perf_counter()
        if self.clustering is ClusteringBackend.COMPILED:
            packed = cluster_population_packed(state.x, state.f, u[:m], self.kmeans_max_iter)
            labels, centre_index, sizes = packed[:n], packed[n : n + m], packed[n + m :]
        else:
            first = state.x[distinct_indices(u[:m], n)]
            labels, _ = sklearn_kmeans(state.x, first, self.kmeans_max_iter)
            centre_index, sizes = cluster_centres(labels, state.f, m)
        clustering_time = time.perf_counter() - start

        x, f = state.x, state.f
        replacements = state.replacements
        # Replacement needs all n_r candidates; when fewer evaluations remain it is
        # skipped and the rest of the budget goes to the ideas.
        if self.chaos_replacement and u[m] < self.p_replace and counter.remaining >= self.n_replace:
            slot = random_centre(centre_index, u[m + 1])
            candidates = chaotic_candidates(
                int(self.replacement_map), u[o_cr:o_idea], self.n_replace, state.lower, state.upper
            )
            x, f = install_best(x, f, slot, candidates, counter(candidates))
            replacements += 1

        # the replacement may have used the last evaluations: then no ideas are made
        n_eval = min(n, counter.remaining)
        if n_eval > 0:
            ideas = generate_ideas(
                x,
                labels,
                centre_index,
                sizes,
                u[o_idea:o_rand].reshape(n, width),
                self.all_centre_weighting,
                int(self.weight_map),
                self.n_weight_iterations,
                self.normalise_weights,
                self.p_one_cluster,
                self.p_one_centre,
                self.p_two_centres,
                logsig_factor(float(iteration), float(state.t_max), self.slope),
                u[o_rand:o_res],
                normals,
                state.scale,
                state.lower,
                state.upper,
                int(self.bound_handling),
                u[o_res:].reshape(n, d) if resample else normals,  # not read unless resampling
            )
            evaluated = ideas[:n_eval]
            x, f, _ = greedy_select(x, f, evaluated, counter(evaluated))
        # direct construction: dataclasses.replace costs several microseconds per call
        return ModifiedBSOState(
            x=x,
            f=f,
            t_max=state.t_max,
            lower=state.lower,
            upper=state.upper,
            scale=state.scale,
            clustering_time_s=state.clustering_time_s + clustering_time,
            replacements=replacements,
        )
