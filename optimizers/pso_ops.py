"""Particle swarm update rules as pure, compiled functions.

Like :mod:`formation_bench.optimizers.bso_ops`, every random number comes in as an array (the
coefficients ``r1``, ``r2`` are uniforms or chaotic values in (0, 1)), inputs
are never modified, and one kernel call moves the whole swarm.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from formation_bench.optimizers.bound_handling import apply_bounds_inplace
from formation_bench.optimizers.chaos import step_inplace
from formation_bench.optimizers.population import progress


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
    bound_mode: int,
    resample_uniforms: np.ndarray,
) -> np.ndarray:
    """One PSO move of every particle; returns ``[x_new; v_new]`` stacked as ``(2N, D)``.

    ``v' = w v + c1 r1 (p - x) + c2 r2 (g - x)``, each component clamped to
    ``[-v_max, v_max]``; ``x' = x + v'`` brought back into the box by
    ``bound_mode`` (a :class:`~formation_bench.optimizers.bound_handling.BoundHandling`
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
    apply_bounds_inplace(positions, lower, upper, bound_mode, resample_uniforms)
    for i in range(n):
        for c in range(d):
            if out[i, c] != x[i, c] + out[n + i, c]:  # moved by the bound handling
                out[n + i, c] = out[i, c] - x[i, c]
    return out


def linear_inertia(start: float, end: float, iteration: int, t_max: int) -> float:
    """Inertia falling linearly from ``start`` at iteration 1 to ``end`` at ``t_max``."""
    return start + (end - start) * progress(iteration, t_max)


def chaotic_inertia(start: float, end: float, iteration: int, t_max: int, z: float) -> float:
    """Feng et al.'s (2007) chaotic inertia: ``(start - end) (1 - s) + end z``, s in [0, 1].

    ``z`` is the current value of a chaotic sequence in (0, 1); at the start
    the weight is ``start - end + end z``, at the end ``end z``.
    """
    return (start - end) * (1.0 - progress(iteration, t_max)) + end * z


@njit(cache=True)
def next_iterates(map_id: int, values: np.ndarray) -> np.ndarray:
    """A copy of ``values`` (any shape, C order) with every entry advanced one guarded map step."""
    out = values.copy()
    flat = out.reshape(-1)
    step_inplace(map_id, flat, np.empty_like(flat))
    return out
