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
per iteration, the same budget as the other population optimisers. The iteration is written
once, as the ask/tell kernels :func:`cls_ask` and :func:`cls_tell`, which both solve loops of
:mod:`~formation_bench.optimizers.ask_tell` drive; with RESAMPLE bound handling the local
points' resample values follow Shi's numbers in the iteration's row of uniforms.
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
from formation_bench.optimizers.base import Bounds
from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    BoundHandling,
    apply_bounds_inplace,
    bso_draws,
)
from formation_bench.optimizers.chaos import ChaoticMap, step_inplace
from formation_bench.optimizers.original_bso_kernels import ShiConfig, ShiSettings, shi_step
from formation_bench.optimizers.population import (
    POPULATION_SEARCH,
    WarmStartInit,
    greedy_select,
    progress,
)
from formation_bench.optimizers.registry import register


def radius_end_search_high(obj: object) -> float:
    """min(local_radius_start, 0.1)"""
    return min(obj.local_radius_start, 0.1)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class LocalSearchConfig(Validated):
    """The chaotic local search's settings, declared once (composed with Shi's in the optimiser).

    Declared next to the kernels that read them: the fields marked
    ``kernel=True`` make :class:`LocalSettings`, which :func:`cls_ask` rebuilds and reads by
    name.
    """

    n_local: int = setting(
        5, low=1, kernel=True, search=Search(1, 20, log=True),
        doc="Chaotic local search points per iteration",
    )  # fmt: skip
    local_radius_start: float = setting(
        0.1, low=0.0, high=1.0, low_open=True, kernel=True,
        search=Search(0.01, 0.5, log=True),
        doc="Search radius at the first iteration, as a fraction of the range",
    )  # fmt: skip
    local_radius_end: float = setting(
        0.001, low=0.0, high="local_radius_start", low_open=True, kernel=True,
        search=Search(0.0001, radius_end_search_high, log=True),
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
    """What :func:`cls_ask` reads of the local search: the kernel fields of
    :class:`LocalSearchConfig` (the map as an integer).""",
)


class LocalSearchState(NamedTuple):
    """The BSO population between iterations (kernels return a new state, never modify one)."""

    x: np.ndarray
    """Ideas, shape (N, D)."""
    f: np.ndarray
    """Their costs (+inf for ideas not evaluated for lack of budget)."""
    z: np.ndarray
    """Current value of the chaotic sequence of every coordinate, (D,)."""
    replacements: int
    """Random-point centre replacements so far."""
    improvements: int
    """Local searches whose point was selected into the best idea's slot so far."""


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
    best: np.ndarray,
    z: np.ndarray,
    radius: float,
    resample_uniforms: np.ndarray,
    local: LocalSettings,
    s: ShiSettings,
) -> tuple[np.ndarray, np.ndarray]:
    """``(candidates, next z)``: the ideas, then the local search points.

    Rows ``0..N-1`` of the candidates are ``ideas``; row ``N + k`` (k < n_local) is
    ``best + radius (upper - lower) (2 z_{k+1} - 1)`` brought into the box by the BSO's
    bound handling, with ``z_{k+1}`` the (k+1)-th iterate of ``z`` under ``local_map``; the
    next ``z`` is the last iterate. ``resample_uniforms`` (n_local x D) is read only by
    RESAMPLE.
    """
    n, d = ideas.shape
    n_local, local_map = local.n_local, local.local_map
    lower, upper, bound_handling = s.lower, s.upper, s.bound_handling
    out = np.empty((n + n_local, d))
    out[:n] = ideas
    sequence = z.copy()
    scratch = np.empty(d)
    for k in range(n_local):
        step_inplace(local_map, sequence, scratch)
        for c in range(d):
            out[n + k, c] = best[c] + radius * (upper[c] - lower[c]) * (2.0 * sequence[c] - 1.0)
    apply_bounds_inplace(out[n:], lower, upper, bound_handling, resample_uniforms)
    return out, sequence


@njit(cache=True)
def select_with_local(
    x: np.ndarray, f: np.ndarray, candidates: np.ndarray, costs: np.ndarray, n_ideas: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """Slot-wise greedy selection of the ideas, then the best local point into the best's slot.

    ``candidates`` holds ``n_ideas`` ideas and then the local points, ``costs`` the costs of
    the leading candidates evaluated (the ideas first). The best local point replaces the
    member in the slot that held the best idea before this selection only if it is strictly
    better than that slot's member after the greedy selection. Returns ``(x, f, 1 if it
    did)``, new arrays.
    """
    n_costs = costs.shape[0]
    slot = np.argmin(f)
    told = min(n_costs, n_ideas)
    new_x, new_f, _ = greedy_select(x, f, candidates[:told], costs[:told])
    if n_costs <= n_ideas:
        return new_x, new_f, 0
    k = n_ideas + np.argmin(costs[n_ideas:])
    if costs[k] < new_f[slot]:
        new_x[slot] = candidates[k]
        new_f[slot] = costs[k]
        return new_x, new_f, 1
    return new_x, new_f, 0


@njit(cache=True, inline="always")
def cls_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """Shi's N new ideas (:func:`~formation_bench.optimizers.original_bso_kernels.shi_step`),
    then the local points around the best idea (:func:`local_candidates`); ``params`` is
    ``(ShiSettings, LocalSettings)`` packed."""
    s = ShiSettings(*params[0])
    local = LocalSettings(*params[1])
    d = state.x.shape[1]
    draws = bso_draws(uniforms, normals, n_clusters=s.n_clusters, width=SHI_UNIFORMS_PER_IDEA)
    ideas = shi_step(state.x, state.f, draws, iteration, s)
    radius = local_radius(
        local_radius_start=local.local_radius_start, local_radius_end=local.local_radius_end,
        iteration=iteration, t_max=s.t_max,
    )  # fmt: skip
    if s.bound_handling == BoundHandling.RESAMPLE:  # the last n_local x D uniforms
        n_local = local.n_local
        resample = uniforms[uniforms.shape[0] - n_local * d :].reshape(n_local, d)
    else:
        resample = normals
    best = state.x[np.argmin(state.f)]
    candidates, z = local_candidates(ideas, best, state.z, radius, resample, local, s)
    replaced = state.replacements + (draws.replace_draw < s.p_replace)
    asked = LocalSearchState(state.x, state.f, z, replaced, state.improvements)
    return asked, candidates, True


@njit(cache=True, inline="always")
def cls_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """The ideas' slot-wise selection and the local point's (:func:`select_with_local`)."""
    x, f, improved = select_with_local(state.x, state.f, candidates, costs, state.x.shape[0])
    return LocalSearchState(x, f, state.z, state.replacements, state.improvements + improved)


register_kernels(LocalSearchState, cls_ask, cls_tell)


@njit(cache=True)
def cls_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the CLS BSO's kernels."""
    return iterate(state, params, block, nit, rows)


# WarmStartInit leads the bases because dataclass fields follow the reversed MRO: its settings
# then come after the method's own, whose positions and listing order stay as they were
@dataclass(frozen=True)
class ChaoticLocalSearchBSO(WarmStartInit, LocalSearchConfig, ShiConfig, AskTellOptimizer):
    """Shi's BSO step plus a chaotic local search around the best idea each iteration.

    Composed of Shi's settings and step
    (:class:`~formation_bench.optimizers.original_bso_kernels.ShiConfig`,
    :func:`~formation_bench.optimizers.original_bso_kernels.shi_step`) and the local search's
    (:class:`LocalSearchConfig`, :func:`local_candidates`); the fields are Shi's, then the
    local search's, then the initial population's
    (:class:`~formation_bench.optimizers.population.WarmStartInit`).
    """

    population_size: int = setting(
        25, low=2, search=POPULATION_SEARCH,
        doc="N, ideas per iteration; 25 + n_local = 30 evaluations per iteration",
    )  # fmt: skip

    compile_cpu_s = 19.0
    kernels = Kernels(cls_ask, cls_tell, cls_iterate)

    def evaluations_per_step(self) -> int:
        return self.population_size + self.n_local

    def initial_evaluations(self) -> int:
        return self.population_size

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return self.shi_settings(bounds, t_max), pack_settings(LocalSettings, self)

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> LocalSearchState:
        """The ideas, and the chaotic sequence's seed drawn after them."""
        return LocalSearchState(points, costs, rng.random(points.shape[1]), 0, 0)

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        resample = self.bound_handling is BoundHandling.RESAMPLE
        return DrawPlan(self.uniforms_per_step(n, d) + (self.n_local * d if resample else 0),
                        (n, d))  # fmt: skip

    def result_info(self, state: LocalSearchState) -> dict[str, Any]:
        return {
            "random_replacements": state.replacements,
            "local_search_improvements": state.improvements,
        }


register(
    "cls-bso",
    ChaoticLocalSearchBSO(),
    "Shi's BSO + chaotic local search around the best idea (after CBSO, Yu et al. 2018)",
)
