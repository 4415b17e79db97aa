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

The iteration is written once, as the compiled kernels :func:`pso_ask` (move the swarm) and
:func:`pso_tell` (keep the personal bests), which both solve loops of
:mod:`~formation_bench.optimizers.ask_tell` drive.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from formation_bench.fields import (
    Search,
    Validated,
    kernel_settings_class,
    pack_settings,
    setting,
)
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.ask_tell import (
    AskTellOptimizer,
    DrawPlan,
    Kernels,
    iterate,
    register_kernels,
)
from formation_bench.optimizers.base import Bounds, budget_setting
from formation_bench.optimizers.bound_handling import BoundHandling, apply_bounds_inplace
from formation_bench.optimizers.chaos import ChaoticMap, apply_map, step_inplace
from formation_bench.optimizers.population import (
    POPULATION_SEARCH,
    WarmStartInit,
    greedy_select,
    progress,
)
from formation_bench.optimizers.registry import register

PER_SOLVE = ("t_max", "v_max", "lower", "upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


@dataclass(frozen=True)
class PSOConfig(Validated):
    """The settings of :class:`PSO`, declared once: the fields marked ``kernel=True`` make
    :class:`PSOSettings`, which the kernels rebuild and read by name."""

    population_size: int = setting(30, low=2, search=POPULATION_SEARCH, doc="N, particles")
    max_iterations: int = budget_setting(
        40,
        doc="Iterations when the caller gives no budget; the default budget is N (T + 1)",
    )  # fmt: skip
    inertia_start: float = setting(
        0.9, low=0.0, high=2.0, kernel=True, search=Search(0.2, 1.2),
        doc="Inertia weight at the first iteration",
    )  # fmt: skip
    inertia_end: float = setting(
        0.4, low=0.0, high=2.0, kernel=True, search=Search(0.0, 1.0),
        doc="Inertia weight at the last planned iteration; equal to start: constant",
    )  # fmt: skip
    c1: float = setting(
        2.0, low=0.0, high=5.0, kernel=True, search=Search(0.0, 4.0),
        doc="Cognitive acceleration (towards the personal best)",
    )  # fmt: skip
    c2: float = setting(
        2.0, low=0.0, high=5.0, kernel=True, search=Search(0.0, 4.0),
        doc="Social acceleration (towards the global best)",
    )  # fmt: skip
    velocity_clamp: float = setting(
        0.2, low=0.0, high=2.0, low_open=True, search=Search(0.02, 1.0, log=True),
        doc="v_max as a fraction of each coordinate's range",
    )  # fmt: skip
    bound_handling: BoundHandling = setting(
        BoundHandling.CLIP, kernel=True, search=Search(),
        doc="How positions outside the box are brought back: clip, reflect or resample",
    )  # fmt: skip
    chaotic_coefficients: bool = setting(
        False, kernel=True,
        doc="Use chaotic sequences of coefficient_map for r1 and r2 instead of uniforms",
    )  # fmt: skip
    coefficient_map: ChaoticMap = setting(
        ChaoticMap.LOGISTIC, kernel=True, doc="Chaotic map of r1 and r2"
    )
    chaotic_inertia: bool = setting(
        False, kernel=True,
        doc="Use Feng et al.'s chaotic inertia weight instead of the linear schedule",
    )  # fmt: skip
    inertia_map: ChaoticMap = setting(
        ChaoticMap.LOGISTIC, kernel=True, doc="Chaotic map of the inertia sequence"
    )

    def pso_settings(self, bounds: Bounds, t_max: int) -> tuple:
        """The packed :class:`PSOSettings` of a solve over ``bounds`` planning ``t_max``."""
        return pack_settings(
            PSOSettings,
            self,
            t_max=int(t_max),
            v_max=self.velocity_clamp * bounds.width,
            lower=np.array(bounds.lower),
            upper=np.array(bounds.upper),
        )

    def uniforms_per_step(self, n: int, d: int) -> int:
        """Uniforms one iteration draws: r1 and r2 (unless chaotic), then resample values (if
        used)."""
        n_uniform = 0 if self.chaotic_coefficients else 2 * n * d
        return n_uniform + (n * d if self.bound_handling is BoundHandling.RESAMPLE else 0)


PSOSettings = kernel_settings_class(
    "PSOSettings",
    __name__,
    PSOConfig,
    PER_SOLVE,
    """What the kernels read, fixed during a solve: the kernel fields of
    :class:`PSOConfig` (enums as integers), then T_max, the velocity clamp per coordinate and the
    bounds (private writable copies: numba compiles read-only arrays separately).""",
)


class PSOState(NamedTuple):
    """The swarm between iterations (kernels return a new state, never modify one)."""

    x: np.ndarray
    """Positions, shape (N, D)."""
    v: np.ndarray
    """Velocities, shape (N, D)."""
    best_x: np.ndarray
    """Personal best positions, shape (N, D)."""
    best_f: np.ndarray
    """Personal best costs (+inf for particles not evaluated for lack of budget)."""
    coefficients: np.ndarray
    """Current chaotic ``r1`` and ``r2``, shape (2, N, D); empty unless chaotic coefficients."""
    inertia_z: float
    """Current value of the chaotic inertia sequence (unused unless chaotic inertia)."""


@njit(cache=True)
def move_swarm(state, global_best, inertia, r1, r2, resample_uniforms, s):  # type: ignore[no-untyped-def]
    """One PSO move of every particle of ``state``; returns ``[x_new; v_new]`` as ``(2N, D)``.

    ``v' = w v + c1 r1 (p - x) + c2 r2 (g - x)``, each component clamped to
    ``[-v_max, v_max]``; ``x' = x + v'`` brought back into the box by
    ``s.bound_handling`` (a :class:`~formation_bench.optimizers.bound_handling.BoundHandling`
    value). For a coordinate the bound handling moved, the velocity becomes
    the step actually taken, ``x'_repaired - x``, so a particle does not keep
    pushing through the wall it hit. ``r1``, ``r2`` are ``(N, D)``;
    ``resample_uniforms`` is read only by RESAMPLE. ``s`` is the solve's :class:`PSOSettings`.
    """
    x, v, personal_best = state.x, state.v, state.best_x
    v_max = s.v_max
    n, d = x.shape
    out = np.empty((2 * n, d))
    for i in range(n):
        for c in range(d):
            vel = (
                inertia * v[i, c]
                + s.c1 * r1[i, c] * (personal_best[i, c] - x[i, c])
                + s.c2 * r2[i, c] * (global_best[c] - x[i, c])
            )
            vel = min(max(vel, -v_max[c]), v_max[c])
            out[i, c] = x[i, c] + vel
            out[n + i, c] = vel
    positions = out[:n]
    apply_bounds_inplace(positions, s.lower, s.upper, s.bound_handling, resample_uniforms)
    for i in range(n):
        for c in range(d):
            if out[i, c] != x[i, c] + out[n + i, c]:  # moved by the bound handling
                out[n + i, c] = out[i, c] - x[i, c]
    return out


# compiled: pso_ask calls it
@njit(cache=True)
def linear_inertia(inertia_start: float, inertia_end: float, iteration: int, t_max: int) -> float:
    """Inertia falling linearly from ``inertia_start`` at iteration 1 to ``inertia_end`` at
    ``t_max``."""
    return inertia_start + (inertia_end - inertia_start) * progress(iteration, t_max)


@njit(cache=True)
def chaotic_inertia(
    inertia_start: float, inertia_end: float, iteration: int, t_max: int, z: float
) -> float:
    """Feng et al.'s (2007) chaotic inertia: ``(start - end) (1 - s) + end z``, s in [0, 1].

    ``z`` is the current value of a chaotic sequence in (0, 1); at the start
    the weight is ``start - end + end z``, at the end ``end z``.
    """
    return (inertia_start - inertia_end) * (1.0 - progress(iteration, t_max)) + inertia_end * z


@njit(cache=True)
def next_iterates(map_id: int, values: np.ndarray) -> np.ndarray:
    """A copy of ``values`` (any shape, C order) with every entry advanced one guarded map step."""
    out = values.copy()
    flat = out.reshape(-1)
    step_inplace(map_id, flat, np.empty_like(flat))
    return out


@njit(cache=True, inline="always")
def pso_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """Move the swarm: ``uniforms`` holds r1 and r2 (unless chaotic), then the resample values
    (if used). The moved positions are the candidates."""
    s = PSOSettings(*params)
    n, d = state.x.shape
    n_uniform = 0 if s.chaotic_coefficients else 2 * n * d
    coefficients, inertia_z = state.coefficients, state.inertia_z
    if s.chaotic_coefficients:
        coefficients = next_iterates(s.coefficient_map, coefficients)
        r1, r2 = coefficients[0], coefficients[1]
    else:
        r1 = uniforms[: n * d].reshape(n, d)
        r2 = uniforms[n * d : n_uniform].reshape(n, d)
    if s.chaotic_inertia:
        inertia_z = apply_map(s.inertia_map, inertia_z)
        w = chaotic_inertia(s.inertia_start, s.inertia_end, iteration, s.t_max, inertia_z)
    else:
        w = linear_inertia(s.inertia_start, s.inertia_end, iteration, s.t_max)
    if s.bound_handling == BoundHandling.RESAMPLE:
        resample = uniforms[n_uniform : n_uniform + n * d].reshape(n, d)
    else:
        resample = state.v
    moved = move_swarm(state, state.best_x[np.argmin(state.best_f)], w, r1, r2, resample, s)
    x = moved[:n].copy()
    moved_state = PSOState(x, moved[n:].copy(), state.best_x, state.best_f, coefficients,
                           inertia_z)  # fmt: skip
    return moved_state, x, True


@njit(cache=True, inline="always")
def pso_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """Keep each particle's personal best (the evaluated moves that improve it)."""
    best_x, best_f, _ = greedy_select(
        state.best_x, state.best_f, candidates[: costs.shape[0]], costs
    )
    return PSOState(state.x, state.v, best_x, best_f, state.coefficients, state.inertia_z)


register_kernels(PSOState, pso_ask, pso_tell)


@njit(cache=True)
def pso_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the PSO kernels."""
    return iterate(state, params, block, nit, rows)


# WarmStartInit leads the bases because dataclass fields follow the reversed MRO: its settings
# then come after PSOConfig's, whose positions and listing order stay as they were
@dataclass(frozen=True)
class PSO(WarmStartInit, PSOConfig, AskTellOptimizer):
    """Global-best PSO; see the module docstring for the variants and their sources,
    :class:`PSOConfig` for the settings and
    :class:`~formation_bench.optimizers.population.WarmStartInit` for the initial swarm."""

    compile_cpu_s = 10.0
    kernels = Kernels(pso_ask, pso_tell, pso_iterate)

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return pack_settings(
            PSOSettings, self, t_max=int(t_max), v_max=self.velocity_clamp * bounds.width,
            lower=np.array(bounds.lower), upper=np.array(bounds.upper),
        )  # fmt: skip

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> PSOState:
        """Particles at rest at ``points``; the chaotic sequences' seeds are drawn only when
        used, so that plain PSO runs do not depend on them."""
        n, d = points.shape
        coefficients = np.zeros((0, n, d))
        inertia_z = 0.5
        if self.chaotic_coefficients or self.chaotic_inertia:
            seeds = rng.random(2 * n * d + 1)
            inertia_z = float(seeds[-1])
            if self.chaotic_coefficients:
                coefficients = seeds[:-1].reshape(2, n, d)
        return PSOState(points, np.zeros((n, d)), points, costs, coefficients, inertia_z)

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        per_step = self.uniforms_per_step(n, d)
        return DrawPlan(per_step, per_batch=lambda evaluated: per_step, batch=n)

    def result_info(self, state: PSOState) -> dict[str, Any]:
        return {"final_inertia_z": float(state.inertia_z)}


WARM_START_SHARE = 0.9
"""``warm_start_share`` of ``pso-warm``: chosen with the spread on the instance
library's validation split (docs/explanation/optimizers.md, "Initial population around the
warm start")."""
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
