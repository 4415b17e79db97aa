"""Particle swarm settings and update rules as pure, compiled functions.

Like :mod:`formation_bench.optimizers.bso_ops`, every random number comes in as an array (the
coefficients ``r1``, ``r2`` are uniforms or chaotic values in (0, 1)), inputs
are never modified, and one kernel call moves the whole swarm. :func:`pso_block` runs whole
blocks of iterations of a solve whose objective is compiled (see
:mod:`~formation_bench.optimizers.compiled`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from formation_bench.fields import Validated, kernel_settings_class, pack_settings, setting
from formation_bench.optimizers.base import Bounds
from formation_bench.optimizers.bound_handling import BoundHandling, apply_bounds_inplace
from formation_bench.optimizers.chaos import ChaoticMap, apply_map, step_inplace
from formation_bench.optimizers.compiled import NFEV, evaluate, remaining
from formation_bench.optimizers.population import greedy_select, progress

PER_SOLVE = ("t_max", "v_max", "lower", "upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


@dataclass(frozen=True)
class PSOConfig(Validated):
    """The settings of :class:`~formation_bench.optimizers.pso.PSO`, declared once.

    Declared next to the kernels that read them: the fields marked
    ``kernel=True`` make :class:`PSOSettings`, which :func:`pso_block` rebuilds
    and reads by name.
    """

    population_size: int = setting(30, low=2, doc="N, particles")
    max_iterations: int = setting(
        40, low=0,
        doc="Iterations when the caller gives no budget; the default budget is N (T + 1)",
    )  # fmt: skip
    inertia_start: float = setting(
        0.9, low=0.0, high=2.0, kernel=True, doc="Inertia weight at the first iteration"
    )
    inertia_end: float = setting(
        0.4, low=0.0, high=2.0, kernel=True,
        doc="Inertia weight at the last planned iteration; equal to start: constant",
    )  # fmt: skip
    c1: float = setting(
        2.0, low=0.0, high=5.0, kernel=True,
        doc="Cognitive acceleration (towards the personal best)",
    )  # fmt: skip
    c2: float = setting(
        2.0, low=0.0, high=5.0, kernel=True, doc="Social acceleration (towards the global best)"
    )
    velocity_clamp: float = setting(
        0.2, low=0.0, high=2.0, low_open=True, doc="v_max as a fraction of each coordinate's range"
    )
    bound_handling: BoundHandling = setting(
        BoundHandling.CLIP, kernel=True,
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
    """What :func:`pso_block` reads, fixed during a solve: the kernel fields of
    :class:`PSOConfig` (enums as integers), then T_max, the velocity clamp per coordinate and the
    bounds (private writable copies: numba compiles read-only arrays separately).""",
)


@njit(cache=True)
def move_swarm(
    x: np.ndarray,
    v: np.ndarray,
    personal_best: np.ndarray,
    global_best: np.ndarray,
    inertia: float,
    c1: float,
    c2: float,
    r1: np.ndarray,
    r2: np.ndarray,
    v_max: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_handling: int,
    resample_uniforms: np.ndarray,
) -> np.ndarray:
    """One PSO move of every particle; returns ``[x_new; v_new]`` stacked as ``(2N, D)``.

    ``v' = w v + c1 r1 (p - x) + c2 r2 (g - x)``, each component clamped to
    ``[-v_max, v_max]``; ``x' = x + v'`` brought back into the box by
    ``bound_handling`` (a :class:`~formation_bench.optimizers.bound_handling.BoundHandling`
    value). For a coordinate the bound handling moved, the velocity becomes
    the step actually taken, ``x'_repaired - x``, so a particle does not keep
    pushing through the wall it hit. ``r1``, ``r2`` are ``(N, D)``;
    ``resample_uniforms`` is read only by RESAMPLE. One stacked array is
    returned because a tuple costs an extra conversion at the Python boundary.
    """
    n, d = x.shape
    out = np.empty((2 * n, d))
    for i in range(n):
        for c in range(d):
            vel = (
                inertia * v[i, c]
                + c1 * r1[i, c] * (personal_best[i, c] - x[i, c])
                + c2 * r2[i, c] * (global_best[c] - x[i, c])
            )
            vel = min(max(vel, -v_max[c]), v_max[c])
            out[i, c] = x[i, c] + vel
            out[n + i, c] = vel
    positions = out[:n]
    apply_bounds_inplace(positions, lower, upper, bound_handling, resample_uniforms)
    for i in range(n):
        for c in range(d):
            if out[i, c] != x[i, c] + out[n + i, c]:  # moved by the bound handling
                out[n + i, c] = out[i, c] - x[i, c]
    return out


# compiled, so that pso_block and the Python step compute the weight with the same code
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


@njit(cache=True)
def pso_block(
    address: int,
    data: np.ndarray,
    counts: np.ndarray,
    best: np.ndarray,
    x: np.ndarray,
    v: np.ndarray,
    best_x: np.ndarray,
    best_f: np.ndarray,
    coefficients: np.ndarray,
    inertia_z: float,
    uniforms: np.ndarray,
    nit: int,
    packed: tuple,
    history_nfev: np.ndarray,
    history_fun: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, int]:
    """Iterations ``nit + 1``, ... of a compiled solve, one per row of ``uniforms``.

    Each is :meth:`PSO.step <formation_bench.optimizers.pso.PSO.step>` with the objective called
    through ``address``/``data`` (see :mod:`~formation_bench.optimizers.compiled`), row ``j`` of
    ``uniforms`` being the numbers that step draws; the block stops early when no evaluation is
    left. ``packed`` is a plain tuple in :class:`PSOSettings` order. Returns ``(x, v, best_x,
    best_f, coefficients, inertia_z, iterations done)``; the history arrays get one entry per
    iteration done.
    """
    s = PSOSettings(*packed)
    n, d = x.shape
    n_uniform = 0 if s.chaotic_coefficients else 2 * n * d
    resample = s.bound_handling == BoundHandling.RESAMPLE
    done = 0
    for row in range(uniforms.shape[0]):
        if remaining(counts) <= 0:
            break
        nit += 1
        u = uniforms[row]
        if s.chaotic_coefficients:
            coefficients = next_iterates(s.coefficient_map, coefficients)
            r1, r2 = coefficients[0], coefficients[1]
        else:
            r1 = u[: n * d].reshape(n, d)
            r2 = u[n * d : n_uniform].reshape(n, d)
        if s.chaotic_inertia:
            inertia_z = apply_map(s.inertia_map, inertia_z)
            w = chaotic_inertia(
                inertia_start=s.inertia_start, inertia_end=s.inertia_end, iteration=nit,
                t_max=s.t_max, z=inertia_z,
            )  # fmt: skip
        else:
            w = linear_inertia(
                inertia_start=s.inertia_start, inertia_end=s.inertia_end, iteration=nit,
                t_max=s.t_max,
            )  # fmt: skip
        moved = move_swarm(
            x, v, best_x, best_x[np.argmin(best_f)], w, c1=s.c1, c2=s.c2, r1=r1, r2=r2,
            v_max=s.v_max, lower=s.lower, upper=s.upper, bound_handling=s.bound_handling,
            resample_uniforms=u[n_uniform:].reshape(n, d) if resample else v,
        )  # fmt: skip
        x = moved[:n].copy()
        v = moved[n:].copy()
        # as population.evaluate_and_select: only the evaluations left are made and compete
        allowed = min(n, remaining(counts))
        costs = evaluate(address, data, x, allowed, counts, best)
        best_x, best_f, _ = greedy_select(best_x, best_f, x[:allowed], costs)
        history_nfev[done] = counts[NFEV]
        history_fun[done] = best[0]
        done += 1
    return x, v, best_x, best_f, coefficients, inertia_z, done
