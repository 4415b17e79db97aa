"""Shi's BSO iteration as compiled kernels (driven by :mod:`.original_bso`).

One iteration of :class:`~formation_bench.optimizers.original_bso.OriginalBSO` is one call of
:func:`shi_ideas` besides the objective call: at a population of 30 a
Python-level call into a kernel costs about as much as its arithmetic, so the
selection of the previous ideas, the k-means step, the random-point centre
replacement and the new ideas are fused. The chaotic-local-search BSO
(:mod:`formation_bench.optimizers.cls_bso`) calls :func:`shi_step` from its own kernel. Like
:mod:`formation_bench.optimizers.bso_ops`, the kernels are pure: random numbers come in as
arrays and inputs are never modified.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from formation_bench.fields import Validated, kernel_settings_class, pack_settings, setting
from formation_bench.optimizers.base import Bounds
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    cluster_population,
    generate_ideas,
    logsig_factor,
    nonempty,
    pick_index,
)
from formation_bench.optimizers.clustering import DEFAULT_MAX_ITER
from formation_bench.optimizers.compiled import NFEV, evaluate_prefix, remaining
from formation_bench.optimizers.population import greedy_select, step_scale

PER_SOLVE = ("t_max", "scale", "lower", "upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


@dataclass(frozen=True)
class ShiConfig(Validated):
    """The settings of Shi's BSO, declared once for every optimiser built on :func:`shi_step`.

    Declared next to the kernels that read them: the fields marked
    ``kernel=True`` make :class:`ShiSettings`, which the kernels rebuild and
    read by name (numba's cache is invalidated when this file changes).
    """

    population_size: int = setting(30, low=2, doc="N, ideas per iteration")
    n_clusters: int = setting(
        5, low=1, high="population_size", kernel=True, doc="m, k-means clusters"
    )
    max_iterations: int = setting(
        40, low=0, doc="T_max when the caller gives no budget; the default budget is N (T_max + 1)"
    )
    slope: float = setting(
        20.0, low=0.0, low_open=True, kernel=True, doc="k, slope of the logsig step-size schedule"
    )
    p_replace: float = setting(
        0.2, low=0.0, high=1.0, kernel=True,
        doc="p_5a, probability per iteration of replacing a random centre by a random point",
    )  # fmt: skip
    p_one_cluster: float = setting(
        0.8, low=0.0, high=1.0, kernel=True,
        doc="p_6b, probability that an idea comes from one cluster rather than two",
    )  # fmt: skip
    p_one_centre: float = setting(
        0.4, low=0.0, high=1.0, kernel=True,
        doc="p_6biii, probability that a one-cluster idea starts from the centre",
    )  # fmt: skip
    p_two_centres: float = setting(
        0.5, low=0.0, high=1.0, kernel=True,
        doc="p_6c, probability that a two-cluster idea mixes the two centres",
    )  # fmt: skip
    step_scale: float = setting(
        1.0, low=0.0, low_open=True, doc="Multiplier of the N(0, 1) step; 1 as published"
    )
    step_relative_to_range: bool = setting(
        False, doc="Multiply step_scale by each coordinate's range (False as published)"
    )
    bound_handling: BoundHandling = setting(
        BoundHandling.CLIP, kernel=True,
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
        """Length of one iteration's uniforms (layout: :func:`shi_step`)."""
        resample = self.bound_handling is BoundHandling.RESAMPLE
        return uniforms_per_iteration(n, d, self.n_clusters) + (n * d if resample else 0)


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
    sources[:n] = population
    sources[n] = point
    centres = centre_index.copy()
    used = nonempty(centre_index)
    centres[used[pick_index(u, used.shape[0])]] = n
    return sources, centres


def uniforms_per_iteration(n: int, d: int, n_clusters: int) -> int:
    """Length of the uniforms :func:`shi_step` reads, without the resample values."""
    return n_clusters + 2 + d + n * SHI_UNIFORMS_PER_IDEA + n


@njit(cache=True)
def shi_step(
    x: np.ndarray, f: np.ndarray, u: np.ndarray, normals: np.ndarray, iteration: int, s: ShiSettings
) -> np.ndarray:
    """Steps 2-6 of Shi's BSO on the ideas ``(x, f)``: the N new ideas.

    The step factor is that of ``iteration`` out of ``s.t_max``. ``u`` holds,
    in this order: the k-means seeds (m), the p_5a draw, the replaced
    cluster, the random point (D), the idea-selection uniforms (N x 7, see
    :data:`~formation_bench.optimizers.bso_ops.SHI_UNIFORMS_PER_IDEA`), ``rand`` (N) and, for
    RESAMPLE bound handling only, N x D resample values. ``normals`` is N x D.
    """
    n, d = x.shape
    m = s.n_clusters
    point_at = m + 2
    ideas_at = point_at + d
    rand_at = ideas_at + n * SHI_UNIFORMS_PER_IDEA
    end = rand_at + n
    labels, centres, sizes = cluster_population(x, f, u[:m], kmeans_max_iter=s.kmeans_max_iter)
    sources = x
    if u[m] < s.p_replace:
        point = s.lower + u[point_at:ideas_at] * (s.upper - s.lower)
        sources, centres = replace_centre(x, centres, u[m + 1], point)
    resample_uniforms = u[end:].reshape(n, d) if u.shape[0] > end else normals
    return generate_ideas(
        sources,
        labels,
        centres,
        sizes,
        u[ideas_at:rand_at].reshape(n, SHI_UNIFORMS_PER_IDEA),
        # Shi's selection: the all-centre weighting and its settings are not used
        all_centre_weighting=False,
        weight_map=0,
        n_weight_iterations=0,
        normalise_weights=False,
        p_one_cluster=s.p_one_cluster,
        p_one_centre=s.p_one_centre,
        p_two_centres=s.p_two_centres,
        factor=logsig_factor(iteration, t_max=s.t_max, slope=s.slope),
        rand=u[rand_at:end],
        normals=normals,
        scale=s.scale,
        lower=s.lower,
        upper=s.upper,
        bound_handling=s.bound_handling,
        resample_uniforms=resample_uniforms,
    )


@njit(cache=True)
def shi_ideas(
    x: np.ndarray,
    f: np.ndarray,
    new_ideas: np.ndarray,
    new_costs: np.ndarray,
    u: np.ndarray,
    normals: np.ndarray,
    iteration: int,
    packed: tuple,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 7 of the last iteration, then :func:`shi_step`, in one call: ``(x, f, ideas)``.

    ``(x, f)`` are the ideas after the slot-wise selection of ``new_ideas``
    (costs ``new_costs``), ``ideas`` the N new ones made from them;
    ``packed`` is :meth:`ShiConfig.shi_settings`. Fused so that an iteration
    costs one kernel call.
    """
    x, f, _ = greedy_select(x, f, new_ideas, new_costs)
    return x, f, shi_step(x, f, u, normals, iteration, ShiSettings(*packed))


@njit(cache=True)
def shi_block(
    address: int,
    data: np.ndarray,
    counts: np.ndarray,
    best: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    ideas: np.ndarray,
    idea_costs: np.ndarray,
    uniforms: np.ndarray,
    normals: np.ndarray,
    nit: int,
    first_iteration: int,
    iteration_limit: int,
    packed: tuple,
    history_nfev: np.ndarray,
    history_fun: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Iterations ``nit + 1``, ... of a compiled solve, one per row of the random block.

    Each is :meth:`OriginalBSO.step` with the objective called through ``address``/``data``
    (see :mod:`~formation_bench.optimizers.compiled`); the block stops early at the iteration
    limit or when no evaluation is left. Returns ``(x, f, ideas, idea_costs, iterations done,
    random replacements)``; the history arrays get one entry per iteration done.
    """
    s = ShiSettings(*packed)
    done = 0
    replacements = 0
    row = nit + 1 - first_iteration
    while nit < iteration_limit and row < uniforms.shape[0] and remaining(counts) > 0:
        nit += 1
        u = uniforms[row]
        x, f, ideas = shi_ideas(x, f, ideas, idea_costs, u, normals[row], nit, packed)
        idea_costs = evaluate_prefix(address, data, ideas, counts, best)
        if u[s.n_clusters] < s.p_replace:
            replacements += 1
        history_nfev[done] = counts[NFEV]
        history_fun[done] = best[0]
        done += 1
        row += 1
    return x, f, ideas, idea_costs, done, replacements
