"""The modified BSO's settings, state and ask/tell kernels (the optimiser:
:mod:`.modified_bso`).

An iteration is one or two ask/tell rounds. When the chaotic centre replacement is drawn
(and at least ``n_r`` evaluations are left), the first round asks for its ``n_r`` chaotic
candidates (eqs. 6-7), which do not depend on the clustering; the last round clusters the
population, installs the best candidate in place of a random centre, and asks for the ``N``
ideas of eqs. (8)-(10), which its tell selects slot by slot.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from formation_bench.fields import Search, Validated, kernel_settings_class, setting
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.ask_tell import iterate, register_kernels
from formation_bench.optimizers.base import budget_setting
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    all_centre_auxiliary,
    bso_draws,
    chaotic_candidates,
    clusters_of,
    install_best,
    logsig_factor,
    move_ideas,
    random_centre,
    shi_select,
)
from formation_bench.optimizers.chaos import ChaoticMap
from formation_bench.optimizers.clustering import DEFAULT_MAX_ITER, ClusteringBackend
from formation_bench.optimizers.original_bso_kernels import (
    CLUSTERS_SEARCH,
    PER_SOLVE,
    REPLACE_SEARCH,
    SHI_PROBABILITY_SEARCH,
)
from formation_bench.optimizers.population import POPULATION_SEARCH, greedy_select


@dataclass(frozen=True)
class ModifiedBSOConfig(Validated):
    """The settings of :class:`~formation_bench.optimizers.modified_bso.ModifiedBSO`, declared once.

    Declared next to the kernels that read them: the fields marked
    ``kernel=True`` make :class:`KernelSettings`, which the kernels rebuild and
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
        40, doc="T_max when the caller gives no budget; the default budget"
    )
    slope: float = setting(
        20.0, low=0.0, low_open=True, kernel=True, search=Search(1.0, 100.0, log=True),
        doc="k, slope of the logsig step-size schedule of eq. (10)",
    )  # fmt: skip
    p_replace: float = setting(
        0.2, low=0.0, high=1.0, kernel=True, search=REPLACE_SEARCH,
        doc="p_r, probability per iteration of a chaotic centre replacement",
    )  # fmt: skip
    n_replace: int = setting(
        10, low=1, kernel=True, search=Search(1, 30, log=True),
        doc="n_r, chaotic candidates per replacement",
    )  # fmt: skip
    n_weight_iterations: int = setting(
        10, low=0, kernel=True,
        doc="n_h, iterations of the weight map from the random seed ch(0)",
    )  # fmt: skip
    replacement_map: ChaoticMap = setting(
        ChaoticMap.LOGISTIC, kernel=True,
        doc="f_rmap, chaotic map of the replacement candidates (eq. 6)",
    )  # fmt: skip
    weight_map: ChaoticMap = setting(
        ChaoticMap.LOGISTIC, kernel=True, doc="f_hmap, chaotic map of the centre weights (eq. 8)"
    )
    normalise_weights: bool = setting(
        True, kernel=True,
        doc="Scale each idea's weights to sum to one (False: the raw weights printed in eq. 9)",
    )  # fmt: skip
    step_scale: float = setting(
        0.1, low=0.0, low_open=True, search=Search(0.001, 1.0, log=True),
        doc="Multiplier of the N(0, 1) step of eq. (10)",
    )  # fmt: skip
    step_relative_to_range: bool = setting(
        True, doc="Multiply step_scale by each coordinate's range upper - lower"
    )
    bound_handling: BoundHandling = setting(
        BoundHandling.CLIP, kernel=True, search=Search(),
        doc="How ideas outside the bounds are brought back",
    )  # fmt: skip
    clustering: ClusteringBackend = setting(
        ClusteringBackend.COMPILED, doc="k-means implementation"
    )
    kmeans_max_iter: int = setting(
        DEFAULT_MAX_ITER, low=1, kernel=True, doc="Cap on Lloyd iterations per clustering"
    )
    p_one_cluster: float = setting(
        0.8, low=0.0, high=1.0, kernel=True, search=SHI_PROBABILITY_SEARCH,
        doc="Shi's p_6b: idea from one cluster rather than two (all-centre weighting off)",
    )  # fmt: skip
    p_one_centre: float = setting(
        0.4, low=0.0, high=1.0, kernel=True, search=SHI_PROBABILITY_SEARCH,
        doc="Shi's p_6biii: one-cluster idea is the centre, else a random member",
    )  # fmt: skip
    p_two_centres: float = setting(
        0.5, low=0.0, high=1.0, kernel=True, search=SHI_PROBABILITY_SEARCH,
        doc="Shi's p_6c: two-cluster idea mixes the centres, else random members",
    )  # fmt: skip
    chaos_replacement: bool = setting(
        True, kernel=True, doc="Ablation switch: chaotic centre replacement (eqs. 6-7)"
    )
    all_centre_weighting: bool = setting(
        True, kernel=True,
        doc="Ablation switch: all-centre auxiliary solutions (eqs. 8-9), else Shi's selection",
    )  # fmt: skip


KernelSettings = kernel_settings_class(
    "KernelSettings",
    __name__,
    ModifiedBSOConfig,
    PER_SOLVE,
    """What the kernels read, fixed during a solve: the kernel fields of
    :class:`ModifiedBSOConfig` (enums as integers), then T_max, the per-coordinate multiplier of
    the eq. (10) step and the bounds (private writable copies: numba compiles read-only arrays
    separately).""",
)

STARTING, REPLACEMENT_ASKED, REPLACEMENT_TOLD = 0, 1, 2
"""Stages of an iteration (:attr:`ModifiedBSOState.stage`): the next ask starts one; the
replacement candidates are out for evaluation; their costs are in, the ideas come next."""


class ModifiedBSOState(NamedTuple):
    """The population between ask/tell rounds (kernels return a new state, never modify one)."""

    x: np.ndarray
    """Population, shape (N, D)."""
    f: np.ndarray
    """Its costs (+inf for members not evaluated for lack of budget)."""
    stage: int
    """Where the iteration stands: ``STARTING``, ``REPLACEMENT_ASKED`` or ``REPLACEMENT_TOLD``."""
    candidates: np.ndarray
    """The last chaotic replacement candidates, (n_r, D); 0 rows before the first."""
    candidate_costs: np.ndarray
    """Their costs."""
    labels: np.ndarray
    """Cluster labels of ``x`` computed outside the kernels (scikit-learn's k-means); empty:
    the ask clusters with the compiled k-means."""
    replacements: int
    """Chaotic replacements performed so far."""


@njit(cache=True, inline="always")
def modified_bso_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """The replacement candidates when the replacement is drawn at the start of an iteration
    (not last), else the N ideas (last). ``uniforms`` and ``normals``: :class:`~formation_bench.
    optimizers.bso_ops.BSODraws` with the sources of width m (all-centre weighting) or 7."""
    s = KernelSettings(*params)
    width = s.n_clusters if s.all_centre_weighting else SHI_UNIFORMS_PER_IDEA
    draws = bso_draws(uniforms, normals, n_clusters=s.n_clusters, width=width)
    x, f = state.x, state.f
    # all n_r candidates or none: when fewer evaluations are left the ideas get them
    replacing = (
        state.stage == STARTING and s.chaos_replacement and draws.replace_draw < s.p_replace
        and remaining >= s.n_replace
    )  # fmt: skip
    # one return: each exit would count references to the state's arrays again
    if replacing:
        asked_points = chaotic_candidates(
            replacement_map=s.replacement_map, seed=draws.point, n_replace=s.n_replace,
            lower=s.lower, upper=s.upper,
        )  # fmt: skip
        asked = ModifiedBSOState(x, f, REPLACEMENT_ASKED, asked_points, state.candidate_costs,
                                 state.labels, state.replacements)  # fmt: skip
    else:
        clusters = clusters_of(x, f, state.labels, draws.kmeans, kmeans_max_iter=s.kmeans_max_iter)
        if state.stage == REPLACEMENT_TOLD:
            slot = random_centre(clusters.centre_index, draws.centre_draw)
            x, f = install_best(x, f, slot, state.candidates, state.candidate_costs)
        if s.all_centre_weighting:
            auxiliary = all_centre_auxiliary(
                x, clusters.centre_index, draws.sources, weight_map=s.weight_map,
                n_weight_iterations=s.n_weight_iterations, normalise_weights=s.normalise_weights,
            )  # fmt: skip
        else:
            auxiliary = shi_select(
                x, clusters, draws.sources, p_one_cluster=s.p_one_cluster,
                p_one_centre=s.p_one_centre, p_two_centres=s.p_two_centres,
            )  # fmt: skip
        factor = logsig_factor(iteration, t_max=s.t_max, slope=s.slope)
        asked_points = move_ideas(auxiliary, factor, draws, s)
        asked = ModifiedBSOState(x, f, STARTING, state.candidates, state.candidate_costs,
                                 state.labels, state.replacements)  # fmt: skip
    return asked, asked_points, not replacing


@njit(cache=True, inline="always")
def modified_bso_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """Keep the replacement candidates' costs for the ideas' round, or select the ideas: each
    evaluated idea replaces the member of its slot when strictly better."""
    if state.stage == REPLACEMENT_ASKED:
        told = ModifiedBSOState(state.x, state.f, REPLACEMENT_TOLD, candidates, costs,
                                state.labels, state.replacements + 1)  # fmt: skip
    else:
        x, f, _ = greedy_select(state.x, state.f, candidates[: costs.shape[0]], costs)
        told = ModifiedBSOState(x, f, STARTING, state.candidates, state.candidate_costs,
                                state.labels, state.replacements)  # fmt: skip
    return told


register_kernels(ModifiedBSOState, modified_bso_ask, modified_bso_tell)


@njit(cache=True)
def modified_bso_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the modified BSO's kernels."""
    return iterate(state, params, block, nit, rows)
