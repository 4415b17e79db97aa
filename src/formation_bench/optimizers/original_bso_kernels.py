"""Shi's BSO: its settings, its steps 2-6 (:func:`shi_step`, shared with the chaotic local
search BSO of :mod:`formation_bench.optimizers.cls_bso`) and the ask/tell kernels of
:class:`~formation_bench.optimizers.original_bso.OriginalBSO`. Like
:mod:`formation_bench.optimizers.bso_ops`, the kernels are pure: random numbers come in as
arrays and inputs are never modified.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from formation_bench.fields import (
    Search,
    Validated,
    kernel_settings_class,
    pack_settings,
    setting,
)
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.ask_tell import iterate, register_kernels
from formation_bench.optimizers.base import Bounds, budget_setting
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    BSODraws,
    Clusters,
    bso_draws,
    cluster_population,
    logsig_factor,
    move_ideas,
    nonempty,
    pick_index,
    shi_select,
    uniforms_per_iteration,
)
from formation_bench.optimizers.clustering import DEFAULT_MAX_ITER
from formation_bench.optimizers.population import POPULATION_SEARCH, greedy_select, step_scale

PER_SOLVE = ("t_max", "scale", "lower", "upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""

MOST_CLUSTERS_SEARCHED = 12
"""Most k-means clusters a tuner tries: beyond a dozen a cluster of a small population holds
two or three ideas, and the clustering no longer groups anything."""


def clusters_search_high(obj: object) -> int:
    """min(population_size, 12)"""
    return min(obj.population_size, MOST_CLUSTERS_SEARCHED)  # type: ignore[attr-defined]


CLUSTERS_SEARCH = Search(2, clusters_search_high)
"""What a tuner searches of BSO's m (one cluster would leave nothing to choose between)."""
REPLACE_SEARCH = Search(0.05, 0.8)
"""What a tuner searches of BSO's centre replacement probability: above 0, where the
replacement is off and the method the ablation without it."""
SHI_PROBABILITY_SEARCH = Search(0.0, 1.0)
"""What a tuner searches of Shi's idea-selection probabilities p_6b, p_6biii and p_6c."""


@dataclass(frozen=True)
class ShiConfig(Validated):
    """The settings of Shi's BSO, declared once for every optimiser built on :func:`shi_step`
    (:class:`~formation_bench.optimizers.original_bso.OriginalBSO`,
    :class:`~formation_bench.optimizers.cls_bso.ChaoticLocalSearchBSO`).

    Declared next to the kernels that read them: the fields marked
    ``kernel=True`` make :class:`ShiSettings`, which the kernels rebuild and
    read by name (numba's cache is invalidated when this file changes).
    """

    population_size: int = setting(
        30, low=2, search=POPULATION_SEARCH, doc="N, ideas per iteration"
    )
    n_clusters: int = setting(
        5, low=1, high="population_size", kernel=True, search=CLUSTERS_SEARCH,
        doc="m, k-means clusters",
    )  # fmt: skip
    max_iterations: int = budget_setting(
        40, doc="T_max when the caller gives no budget; the default budget is N (T_max + 1)"
    )
    slope: float = setting(
        20.0, low=0.0, low_open=True, kernel=True, search=Search(1.0, 100.0, log=True),
        doc="k, slope of the logsig step-size schedule",
    )  # fmt: skip
    p_replace: float = setting(
        0.2, low=0.0, high=1.0, kernel=True, search=REPLACE_SEARCH,
        doc="p_5a, probability per iteration of replacing a random centre by a random point",
    )  # fmt: skip
    p_one_cluster: float = setting(
        0.8, low=0.0, high=1.0, kernel=True, search=SHI_PROBABILITY_SEARCH,
        doc="p_6b, probability that an idea comes from one cluster rather than two",
    )  # fmt: skip
    p_one_centre: float = setting(
        0.4, low=0.0, high=1.0, kernel=True, search=SHI_PROBABILITY_SEARCH,
        doc="p_6biii, probability that a one-cluster idea starts from the centre",
    )  # fmt: skip
    p_two_centres: float = setting(
        0.5, low=0.0, high=1.0, kernel=True, search=SHI_PROBABILITY_SEARCH,
        doc="p_6c, probability that a two-cluster idea mixes the two centres",
    )  # fmt: skip
    step_scale: float = setting(
        1.0, low=0.0, low_open=True, search=Search(0.001, 10.0, log=True),
        doc="Multiplier of the N(0, 1) step; 1 as published",
    )  # fmt: skip
    step_relative_to_range: bool = setting(
        False, doc="Multiply step_scale by each coordinate's range (False as published)"
    )
    bound_handling: BoundHandling = setting(
        BoundHandling.CLIP, kernel=True, search=Search(),
        doc="How ideas outside the bounds are brought back (not specified by the paper)",
    )  # fmt: skip
    kmeans_max_iter: int = setting(
        DEFAULT_MAX_ITER, low=1, kernel=True, doc="Cap on Lloyd iterations per clustering"
    )

    def shi_settings(self, bounds: Bounds, t_max: int) -> tuple:
        """The packed :class:`ShiSettings` of a solve over ``bounds`` planning ``t_max``."""
        return pack_settings(
            ShiSettings,
            self,
            t_max=int(t_max),
            scale=step_scale(bounds, self.step_scale, self.step_relative_to_range),
            lower=np.array(bounds.lower),
            upper=np.array(bounds.upper),
        )

    def uniforms_per_step(self, n: int, d: int) -> int:
        """Length of one iteration's uniforms (:class:`~formation_bench.optimizers.bso_ops.
        BSODraws`, the sources of width :data:`~formation_bench.optimizers.bso_ops.
        SHI_UNIFORMS_PER_IDEA`)."""
        resample = self.bound_handling is BoundHandling.RESAMPLE
        return uniforms_per_iteration(n, d, self.n_clusters, SHI_UNIFORMS_PER_IDEA, resample)


ShiSettings = kernel_settings_class(
    "ShiSettings",
    __name__,
    ShiConfig,
    PER_SOLVE,
    """What :func:`shi_step` reads, fixed during a solve: the kernel fields of :class:`ShiConfig`
    (enums as integers), then T_max, the per-coordinate step multiplier and the bounds (private
    writable copies: numba compiles read-only arrays separately).""",
)


@njit(cache=True)
def replace_centre(
    population: np.ndarray, centre_index: np.ndarray, u: float, point: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Shi's step 4: the centre of a non-empty cluster chosen uniformly by ``u`` becomes ``point``.

    Returns ``(sources, centres)``: the population with ``point`` appended as
    row N, and a copy of ``centre_index`` in which the chosen cluster's centre
    is that row. Members (the rows a random-member idea is drawn from) are
    unchanged, since cluster membership is read from the labels of rows 0..N-1.
    """
    n, d = population.shape
    sources = np.empty((n + 1, d))
    # element by element: a slice assignment makes numba compile its shape-mismatch error,
    # and with it string formatting (about 1.5 s of a first run's compile)
    for i in range(n):
        for j in range(d):
            sources[i, j] = population[i, j]
    for j in range(d):
        sources[n, j] = point[j]
    centres = centre_index.copy()
    used = nonempty(centre_index)
    centres[used[pick_index(u, used.shape[0])]] = n
    return sources, centres


@njit(cache=True)
def shi_step(
    x: np.ndarray, f: np.ndarray, draws: BSODraws, iteration: int, s: ShiSettings
) -> np.ndarray:
    """Steps 2-6 of Shi's BSO on the ideas ``(x, f)``: the N new ideas.

    k-means from ``draws.kmeans``; with ``draws.replace_draw < p_replace`` the random point
    ``draws.point`` (scaled to the box) replaces a centre (:func:`replace_centre`); the ideas
    are Shi's selection from ``draws.sources`` moved by the step of ``iteration`` out of
    ``s.t_max``.
    """
    clusters = cluster_population(x, f, draws.kmeans, kmeans_max_iter=s.kmeans_max_iter)
    sources, centres = x, clusters.centre_index
    if draws.replace_draw < s.p_replace:
        point = s.lower + draws.point * (s.upper - s.lower)
        sources, centres = replace_centre(x, centres, draws.centre_draw, point)
    auxiliary = shi_select(
        sources, Clusters(clusters.labels, centres, clusters.sizes), draws.sources,
        p_one_cluster=s.p_one_cluster, p_one_centre=s.p_one_centre,
        p_two_centres=s.p_two_centres,
    )  # fmt: skip
    return move_ideas(auxiliary, logsig_factor(iteration, t_max=s.t_max, slope=s.slope), draws, s)


class BSOState(NamedTuple):
    """Shi's ideas between iterations (kernels return a new state, never modify one)."""

    x: np.ndarray
    """Ideas, shape (N, D)."""
    f: np.ndarray
    """Their costs (+inf for ideas not evaluated for lack of budget)."""
    replacements: int
    """Random-point centre replacements so far."""


@njit(cache=True, inline="always")
def shi_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """Steps 2-6 (:func:`shi_step`): the N new ideas."""
    s = ShiSettings(*params)
    draws = bso_draws(uniforms, normals, n_clusters=s.n_clusters, width=SHI_UNIFORMS_PER_IDEA)
    ideas = shi_step(state.x, state.f, draws, iteration, s)
    replaced = state.replacements + (draws.replace_draw < s.p_replace)
    return BSOState(state.x, state.f, replaced), ideas, True


@njit(cache=True, inline="always")
def shi_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """Step 7: each evaluated idea replaces the idea of its slot when strictly better."""
    x, f, _ = greedy_select(state.x, state.f, candidates[: costs.shape[0]], costs)
    return BSOState(x, f, state.replacements)


register_kernels(BSOState, shi_ask, shi_tell)


@njit(cache=True)
def shi_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with Shi's kernels."""
    return iterate(state, params, block, nit, rows)
