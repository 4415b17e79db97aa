"""Global-best particle swarm optimisation, with its inertia and chaotic variants as configurations.

One class covers the registered PSOs:

* **linearly decreasing inertia** (the default): ``w`` falls from 0.9 to 0.4
  over the planned iterations, ``c1 = c2 = 2`` (Shi & Eberhart, "A modified
  particle swarm optimizer", IEEE ICEC 1998; "Empirical study of particle
  swarm optimization", CEC 1999);
* **constriction** (``inertia_start = inertia_end = 0.7298``,
  ``c1 = c2 = 1.49618``): Clerc & Kennedy's constriction factor chi = 0.7298
  for phi = 4.1 in its equivalent inertia form (Clerc & Kennedy, "The particle
  swarm - explosion, stability, and convergence in a multidimensional complex
  space", IEEE TEC 6(1), 2002; the values of Eberhart & Shi, CEC 2000);
* **chaotic PSO** (``chaotic_coefficients`` and/or ``chaotic_inertia``), after
  Alatas, Akin & Ozer, "Chaos embedded particle swarm optimization
  algorithms", Chaos, Solitons & Fractals 40(4), 2009, 1715-1734: the uniform
  random coefficients ``r1``, ``r2`` are replaced by chaotic sequences (one
  sequence per particle and coordinate, iterated once per iteration from
  uniform seeds), and/or the inertia weight is made chaotic in the form of
  Feng et al., "Chaotic inertia weight in particle swarm optimization",
  ICICIC 2007: ``w = (w_start - w_end)(1 - s) + w_end z``, with ``s`` the
  progress in [0, 1] and ``z`` a chaotic sequence.

Every configuration starts uniformly in the box with particle 0 at the warm start; the
``-warm`` variant (``pso-warm``) starts a share of the swarm in a cloud around it instead
(:class:`~formation_bench.optimizers.population.WarmStartInit`, not in the sources above).

Velocities start at zero and are clamped per coordinate to
``velocity_clamp * (upper - lower)``. Positions leaving the box are brought back
by ``bound_handling`` (clip, reflect, or random re-initialisation of the
offending coordinate); the velocity of a repaired coordinate becomes the step
actually taken. Personal bests are updated only on strict improvement, so
NaN/inf costs (mapped to +inf by the evaluation counter) never become a best.

A compiled objective is solved block by block in
:func:`~formation_bench.optimizers.pso_ops.pso_block`, with the result and the draws of the
Python loop (:meth:`PSO.minimize_compiled`).
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
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.chaos import apply_map
from formation_bench.optimizers.compiled import CompiledObjective
from formation_bench.optimizers.population import (
    WarmStartInit,
    compiled_initial_population,
    evaluate_and_select,
    initial_population,
    run_compiled_draws,
)
from formation_bench.optimizers.pso_ops import (
    PSOConfig,
    chaotic_inertia,
    linear_inertia,
    move_swarm,
    next_iterates,
    pso_block,
)
from formation_bench.optimizers.registry import register


class PSOState(NamedTuple):
    """Swarm between iterations (arrays are never modified in place).

    A NamedTuple rather than a frozen dataclass: it is built once per
    iteration, and its constructor costs a third as much.
    """

    x: np.ndarray
    """Positions, shape (N, D)."""
    v: np.ndarray
    """Velocities, shape (N, D)."""
    best_x: np.ndarray
    """Personal best positions, shape (N, D)."""
    best_f: np.ndarray
    """Personal best costs (+inf for particles not evaluated for lack of budget)."""
    t_max: int
    """Planned iterations (the inertia schedule's length)."""
    lower: np.ndarray
    """Lower bounds (a private writable copy for the kernels)."""
    upper: np.ndarray
    """Upper bounds."""
    v_max: np.ndarray
    """Velocity clamp per coordinate, shape (D,)."""
    coefficients: np.ndarray
    """Current chaotic ``r1`` and ``r2``, shape (2, N, D); empty unless chaotic coefficients."""
    inertia_z: float
    """Current value of the chaotic inertia sequence (unused unless chaotic inertia)."""


# WarmStartInit leads the bases because dataclass fields follow the reversed MRO: its settings
# then come after PSOConfig's, whose positions and listing order stay as they were
@dataclass(frozen=True)
class PSO(WarmStartInit, PSOConfig, PopulationOptimizer[PSOState]):
    """Global-best PSO; see the module docstring for the variants and their sources,
    :class:`~formation_bench.optimizers.pso_ops.PSOConfig` for the settings and
    :class:`~formation_bench.optimizers.population.WarmStartInit` for the initial swarm."""

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iterations)

    def evaluations_per_step(self) -> int:
        return self.population_size

    def result_info(self, state: PSOState) -> dict[str, Any]:
        return {"final_inertia_z": state.inertia_z}

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> PSOState:
        """N particles at rest (particle 0 at ``x0`` if given, a share around it if configured,
        the rest uniform), evaluated in one batch."""
        n, d = self.population_size, bounds.dim
        x, f = initial_population(counter, bounds, rng, n, x0, self)
        coefficients, inertia_z = self.chaotic_seeds(rng, n, d)
        return PSOState(
            x=x,
            v=np.zeros((n, d)),
            best_x=x,
            best_f=f,
            t_max=int(max_iterations),
            lower=np.array(bounds.lower),
            upper=np.array(bounds.upper),
            v_max=self.velocity_clamp * bounds.width,
            coefficients=coefficients,
            inertia_z=inertia_z,
        )

    def chaotic_seeds(self, rng: np.random.Generator, n: int, d: int) -> tuple[np.ndarray, float]:
        """``(coefficients, inertia_z)`` at the start: the chaotic r1, r2 (shape (2, N, D), empty
        unless chaotic coefficients) and the inertia sequence's first value (0.5 unless chaotic)."""
        coefficients = np.zeros((0, n, d))
        inertia_z = 0.5
        if self.chaotic_coefficients or self.chaotic_inertia:
            # drawn only when used, so that plain PSO runs do not depend on them
            seeds = rng.random(2 * n * d + 1)
            inertia_z = float(seeds[-1])
            if self.chaotic_coefficients:
                coefficients = seeds[:-1].reshape(2, n, d)
        return coefficients, inertia_z

    def step(
        self,
        state: PSOState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> PSOState:
        n, d = state.x.shape
        resample = self.bound_handling is BoundHandling.RESAMPLE
        coefficients, inertia_z = state.coefficients, state.inertia_z
        # one draw: r1 and r2 (unless chaotic) | resample values (if used)
        n_uniform = 0 if self.chaotic_coefficients else 2 * n * d
        u = rng.random(self.uniforms_per_step(n, d))
        if self.chaotic_coefficients:
            coefficients = next_iterates(int(self.coefficient_map), coefficients)
            r = coefficients
        else:
            r = u[:n_uniform].reshape(2, n, d)
        if self.chaotic_inertia:
            inertia_z = apply_map(int(self.inertia_map), inertia_z)
            w = chaotic_inertia(
                self.inertia_start, self.inertia_end, iteration, state.t_max, inertia_z
            )
        else:
            w = linear_inertia(self.inertia_start, self.inertia_end, iteration, state.t_max)
        moved = move_swarm(
            state.x,
            state.v,
            state.best_x,
            state.best_x[int(np.argmin(state.best_f))],
            w,
            self.c1,
            self.c2,
            r[0],
            r[1],
            state.v_max,
            state.lower,
            state.upper,
            int(self.bound_handling),
            u[n_uniform:].reshape(n, d) if resample else state.v,
        )
        x = moved[:n]
        best_x, best_f = evaluate_and_select(counter, state.best_x, state.best_f, x)
        return PSOState(
            x=x,
            v=moved[n:],
            best_x=best_x,
            best_f=best_f,
            t_max=state.t_max,
            lower=state.lower,
            upper=state.upper,
            v_max=state.v_max,
            coefficients=coefficients,
            inertia_z=inertia_z,
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
        n, d = self.population_size, bounds.dim
        x, f, start = compiled_initial_population(
            objective, bounds, rng, n, x0, budget.max_evaluations, self
        )
        coefficients, inertia_z = self.chaotic_seeds(rng, n, d)
        packed = self.pso_settings(bounds, t_max)
        per_step = self.uniforms_per_step(n, d)
        # x, v, personal bests and their costs, chaotic coefficients, inertia_z
        carry: list[Any] = [x, np.zeros((n, d)), x, f, coefficients, inertia_z]

        def run_block(
            nit: int, rows: int, uniforms: np.ndarray, history_nfev: np.ndarray,
            history_fun: np.ndarray,
        ) -> int:  # fmt: skip
            x, v, best_x, best_f, coefficients, inertia_z, done = pso_block(
                objective.address, objective.data, start.counts, start.best, *carry,
                uniforms.reshape(rows, per_step), nit, packed, history_nfev, history_fun,
            )  # fmt: skip
            carry[:] = [x, v, best_x, best_f, coefficients, inertia_z]
            return done

        return run_compiled_draws(
            run_block, start, rng, budget, t_max, n, lambda evaluated: per_step,
            lambda: {"final_inertia_z": carry[5]},
        )  # fmt: skip


WARM_START_SHARE = 0.9
"""``warm_start_share`` of ``pso-warm``: chosen with the spread on the instance
library's validation split (docs/optimizers.md, "Initial population around the warm start")."""
WARM_START_SPREAD = 0.005
"""``warm_start_spread`` of ``pso-warm``, chosen with the share."""

register(
    "pso",
    PSO(),
    "Global-best PSO, inertia 0.9 -> 0.4, c1 = c2 = 2, velocity clamp 0.2 x range, clip",
)
register(
    "pso-warm",
    PSO(warm_start_share=WARM_START_SHARE, warm_start_spread=WARM_START_SPREAD),
    f"pso with {WARM_START_SHARE:.0%} of the initial swarm drawn around the warm start "
    f"(std {WARM_START_SPREAD:g} x range), the rest uniform",
)
register(
    "pso-constriction",
    PSO(inertia_start=0.7298, inertia_end=0.7298, c1=1.49618, c2=1.49618),
    "Global-best PSO with Clerc-Kennedy constriction (chi = 0.7298, c1 = c2 = 1.49618)",
)
register(
    "chaotic-pso",
    PSO(chaotic_coefficients=True, chaotic_inertia=True),
    "Chaotic PSO (after Alatas et al. 2009): logistic r1, r2 and chaotic inertia weight",
)
register(
    "chaotic-pso-coefficients",
    PSO(chaotic_coefficients=True),
    "Chaotic PSO: logistic sequences for r1, r2 only (linear inertia 0.9 -> 0.4)",
)
register(
    "chaotic-pso-inertia",
    PSO(chaotic_inertia=True),
    "Chaotic PSO: Feng et al.'s chaotic inertia weight only (uniform r1, r2)",
)
