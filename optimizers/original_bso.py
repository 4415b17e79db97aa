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
    PopulationOptimizer,
    check_bool,
    check_int,
    check_real,
    coerce_enum,
)
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.bso_ops import greedy_select
from formation_bench.optimizers.clustering import DEFAULT_MAX_ITER
from formation_bench.optimizers.original_bso_kernels import (
    ShiSettings,
    shi_ideas,
    uniforms_per_iteration,
)
from formation_bench.optimizers.population import (
    RandomAhead,
    evaluate_prefix,
    initial_population,
    iteration_randoms,
    no_randoms,
    step_scale,
)


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
    settings: ShiSettings
    """The kernel arguments fixed for the solve (T_max, bounds, step scale, configuration)."""
    randoms: RandomAhead
    """Random numbers drawn ahead for the next iterations."""
    replacements: int = 0
    """Random-point centre replacements so far."""

    def population(self) -> tuple[np.ndarray, np.ndarray]:
        """``(x, f)`` after the pending slot-wise selection of ``new_ideas``."""
        x, f, _ = greedy_select(self.x, self.f, self.new_ideas, self.new_costs)
        return x, f


@dataclass(frozen=True)
class OriginalBSO(PopulationOptimizer[BSOState]):
    """Shi's (2011) BSO: probabilities and slope as published; N and T_max for ~1300 evaluations."""

    population_size: int = 30
    """N, ideas per iteration (>= 2)."""
    n_clusters: int = 5
    """m, k-means clusters (1..N)."""
    max_iterations: int = 40
    """T_max when the caller gives no budget (>= 0); the default budget is N (T_max + 1)."""
    slope: float = 20.0
    """k, slope of the logsig step-size schedule (> 0)."""
    p_replace: float = 0.2
    """p_5a, probability per iteration of replacing a random centre by a random point ([0, 1])."""
    p_one_cluster: float = 0.8
    """p_6b, probability that an idea comes from one cluster rather than two ([0, 1])."""
    p_one_centre: float = 0.4
    """p_6biii, probability that a one-cluster idea starts from the centre ([0, 1])."""
    p_two_centres: float = 0.5
    """p_6c, probability that a two-cluster idea mixes the two centres ([0, 1])."""
    step_scale: float = 1.0
    """Multiplier of the N(0, 1) step (> 0); 1 as published."""
    step_relative_to_range: bool = False
    """Multiply ``step_scale`` by each coordinate's range (False as published)."""
    bound_handling: BoundHandling = BoundHandling.CLIP
    """How ideas outside the bounds are brought back (not specified by the paper)."""
    kmeans_max_iter: int = DEFAULT_MAX_ITER
    """Cap on Lloyd iterations per clustering (>= 1)."""

    def __post_init__(self) -> None:
        owner = type(self).__name__
        put = object.__setattr__
        put(self, "population_size", check_int(owner, "population_size", self.population_size, 2))
        n = self.population_size
        put(self, "n_clusters", check_int(owner, "n_clusters", self.n_clusters, 1, n))
        put(self, "max_iterations", check_int(owner, "max_iterations", self.max_iterations, 0))
        put(self, "kmeans_max_iter", check_int(owner, "kmeans_max_iter", self.kmeans_max_iter, 1))
        for name in ("slope", "step_scale"):
            put(self, name, check_real(owner, name, getattr(self, name), 0.0, low_open=True))
        for name in ("p_replace", "p_one_cluster", "p_one_centre", "p_two_centres"):
            put(self, name, check_real(owner, name, getattr(self, name), 0.0, 1.0))
        relative = check_bool(owner, "step_relative_to_range", self.step_relative_to_range)
        put(self, "step_relative_to_range", relative)
        mode = coerce_enum(owner, "bound_handling", BoundHandling, self.bound_handling)
        put(self, "bound_handling", mode)

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
        """N uniform ideas (row 0 = ``x0`` if given), evaluated in one batch within the budget."""
        x, f = initial_population(counter, bounds, rng, self.population_size, x0)
        n, d = x.shape
        return BSOState(
            x=x,
            f=f,
            new_ideas=np.empty((0, d)),
            new_costs=np.empty(0),
            settings=self.shi_settings(bounds, max_iterations),
            randoms=no_randoms(self.uniforms_per_step(n, d), (n, d)),
        )

    def shi_settings(self, bounds: Bounds, t_max: int) -> ShiSettings:
        """The kernel arguments fixed for a solve over ``bounds`` planning ``t_max`` iterations."""
        return ShiSettings(
            t_max=int(t_max),
            slope=self.slope,
            n_clusters=self.n_clusters,
            kmeans_max_iter=self.kmeans_max_iter,
            p_replace=self.p_replace,
            p_one_cluster=self.p_one_cluster,
            p_one_centre=self.p_one_centre,
            p_two_centres=self.p_two_centres,
            scale=step_scale(bounds, self.step_scale, self.step_relative_to_range),
            lower=np.array(bounds.lower),
            upper=np.array(bounds.upper),
            bound_mode=int(self.bound_handling),
        )

    def uniforms_per_step(self, n: int, d: int) -> int:
        """Length of one iteration's uniforms (layout: :func:`.original_bso_kernels.shi_step`)."""
        resample = self.bound_handling is BoundHandling.RESAMPLE
        return uniforms_per_iteration(n, d, self.n_clusters) + (n * d if resample else 0)

    def step(
        self,
        state: BSOState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> BSOState:
        settings = state.settings
        randoms, u, normals = iteration_randoms(state.randoms, rng, iteration, settings.t_max)
        x, f, ideas = shi_ideas(
            state.x, state.f, state.new_ideas, state.new_costs, u, normals, iteration, *settings
        )
        costs = evaluate_prefix(counter, ideas)
        replaced = bool(u[self.n_clusters] < self.p_replace)
        return BSOState(x, f, ideas, costs, settings, randoms, state.replacements + replaced)
