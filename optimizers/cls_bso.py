"""Shi's BSO with a chaotic local search (CLS) around the best idea, after the CBSO family.

Yu, Y., Gao, S., Cheng, S., Wang, Y., Song, S., Yuan, F. (2018). CBSO: a
memetic brain storm optimization with chaotic local search. Memetic
Computing 10(4), 353-367. (The CLS form goes back to the chaotic local
searches of Gao's group, e.g. Gao et al., "Gravitational search algorithm
combined with chaos for unconstrained numerical optimization", Applied
Mathematics and Computation 231, 2014.)

Every iteration is one iteration of :class:`~optimizers.original_bso.OriginalBSO`
plus a chaotic local search of ``n_local`` points

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
:class:`~optimizers.chaos.ChaoticMap`); CBSO shrinks the radius by a fixed
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

from optimizers.base import (
    Bounds,
    EvaluationCounter,
    check_int,
    check_real,
    coerce_enum,
)
from optimizers.bso_ops import BoundHandling, apply_bounds_inplace, greedy_select
from optimizers.chaos import ChaoticMap, step_inplace
from optimizers.original_bso import BSOState, OriginalBSO, advance, shi_ideas
from optimizers.population import evaluate_prefix, progress


class LocalSearchState(NamedTuple):
    """The BSO population plus the chaotic local search's own state."""

    bso: BSOState
    """Population and bookkeeping of the underlying BSO."""
    z: np.ndarray
    """Current value of the chaotic sequence of every coordinate, shape (D,)."""
    improvements: int = 0
    """Local searches that replaced the best idea so far."""


def local_radius(start: float, end: float, iteration: int, t_max: int) -> float:
    """Geometric schedule: ``start`` at iteration 1, ``end`` at iteration ``t_max``."""
    return start * (end / start) ** progress(iteration, t_max)


@njit(cache=True)
def local_candidates(
    ideas: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    map_id: int,
    z: np.ndarray,
    n_local: int,
    radius: float,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_mode: int,
    resample_uniforms: np.ndarray,
) -> np.ndarray:
    """The ideas, the local search points and the sequence's next state, stacked.

    Rows ``0..N-1`` are ``ideas``; row ``N + k`` (k < n_local) is
    ``x_best + radius (upper - lower) (2 z_{k+1} - 1)`` brought into the box by
    ``bound_mode``, with ``x_best`` the lowest-cost row of ``x`` and ``z_{k+1}``
    the (k+1)-th iterate of ``z`` under the map ``map_id``; the last row is the
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
        step_inplace(map_id, sequence, scratch)
        for c in range(d):
            out[n + k, c] = best[c] + radius * (upper[c] - lower[c]) * (2.0 * sequence[c] - 1.0)
    out[n + n_local] = sequence
    apply_bounds_inplace(out[n : n + n_local], lower, upper, bound_mode, resample_uniforms)
    return out


@njit(cache=True)
def cls_candidates(
    x: np.ndarray,
    f: np.ndarray,
    u: np.ndarray,
    normals: np.ndarray,
    n_clusters: int,
    kmeans_max_iter: int,
    p_replace: float,
    p_one_cluster: float,
    p_one_centre: float,
    p_two_centres: float,
    factor: float,
    scale: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_mode: int,
    map_id: int,
    z: np.ndarray,
    n_local: int,
    radius: float,
    resample_local: np.ndarray,
) -> tuple[np.ndarray, bool]:
    """:func:`~optimizers.original_bso.shi_ideas` then :func:`local_candidates`, in one call.

    The first 15 arguments are those of ``shi_ideas``; returns the stacked
    ideas, local points and next ``z``, and whether a centre was replaced.
    """
    ideas, replaced = shi_ideas(
        x, f, u, normals, n_clusters, kmeans_max_iter, p_replace, p_one_cluster, p_one_centre,
        p_two_centres, factor, scale, lower, upper, bound_mode,
    )  # fmt: skip
    candidates = local_candidates(
        ideas, x, f, map_id, z, n_local, radius, lower, upper, bound_mode, resample_local
    )
    return candidates, replaced


@njit(cache=True)
def select_with_local(
    x: np.ndarray, f: np.ndarray, candidates: np.ndarray, costs: np.ndarray, n_ideas: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """Slot-wise greedy selection of the ideas, then the best local point into the best's slot.

    ``candidates`` and ``costs`` hold the N ideas and then the local points.
    The best local point replaces the member in the slot that held the best
    idea before this iteration only if it is strictly better than that
    slot's member after the greedy selection. Returns ``(x, f, 1 if it did)``.
    """
    slot = np.argmin(f)
    new_x, new_f, _ = greedy_select(x, f, candidates[:n_ideas], costs[:n_ideas])
    k = n_ideas + np.argmin(costs[n_ideas:])
    if costs[k] < new_f[slot]:
        new_x[slot] = candidates[k]
        new_f[slot] = costs[k]
        return new_x, new_f, 1
    return new_x, new_f, 0


@dataclass(frozen=True)
class ChaoticLocalSearchBSO(OriginalBSO):
    """:class:`OriginalBSO` plus a chaotic local search around the best idea each iteration."""

    population_size: int = 25
    """N, ideas per iteration (>= 2); 25 + ``n_local`` = 30 evaluations per iteration."""
    n_local: int = 5
    """Chaotic local search points per iteration (>= 1)."""
    local_radius_start: float = 0.1
    """Search radius at the first iteration, as a fraction of the range ((0, 1])."""
    local_radius_end: float = 0.001
    """Search radius at the last planned iteration ((0, local_radius_start])."""
    local_map: ChaoticMap = ChaoticMap.LOGISTIC
    """Chaotic map of the local search sequence."""

    def __post_init__(self) -> None:
        super().__post_init__()
        owner = type(self).__name__
        put = object.__setattr__
        put(self, "n_local", check_int(owner, "n_local", self.n_local, 1))
        start = check_real(
            owner, "local_radius_start", self.local_radius_start, 0.0, 1.0, low_open=True
        )
        put(self, "local_radius_start", start)
        end = check_real(
            owner, "local_radius_end", self.local_radius_end, 0.0, start, low_open=True
        )
        put(self, "local_radius_end", end)
        put(self, "local_map", coerce_enum(owner, "local_map", ChaoticMap, self.local_map))

    def evaluations_per_step(self) -> int:
        return self.population_size + self.n_local

    def initial_evaluations(self) -> int:
        return self.population_size

    def result_info(self, state: LocalSearchState) -> dict[str, Any]:  # type: ignore[override]
        return {**super().result_info(state.bso), "local_search_improvements": state.improvements}

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> LocalSearchState:  # type: ignore[override]
        bso = super().init(counter, bounds, rng, x0, max_iterations)
        return LocalSearchState(bso=bso, z=rng.random(bounds.dim))

    def step(
        self,
        state: LocalSearchState,  # type: ignore[override]
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> LocalSearchState:
        bso = state.bso
        n, d = bso.x.shape
        resample = self.bound_handling is BoundHandling.RESAMPLE
        candidates, replaced = cls_candidates(
            *self.shi_arguments(bso, rng, iteration),
            int(self.local_map),
            state.z,
            self.n_local,
            local_radius(self.local_radius_start, self.local_radius_end, iteration, bso.t_max),
            rng.random((self.n_local, d)) if resample else bso.x,
        )
        # one objective call for the ideas and the local points (ideas first under a short budget)
        costs = evaluate_prefix(counter, candidates[:-1])
        x, f, improved = select_with_local(bso.x, bso.f, candidates[:-1], costs, n)
        return LocalSearchState(
            advance(bso, x, f, int(replaced)), candidates[-1], state.improvements + improved
        )
