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

from typing import NamedTuple

import numpy as np
from numba import njit

from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    cluster_population,
    generate_ideas,
    greedy_select,
    logsig_factor,
    nonempty,
    pick_index,
)


class ShiSettings(NamedTuple):
    """The arguments of :func:`shi_ideas` that stay fixed during a solve, in their order.

    Built once per solve and passed as ``*settings``: a tuple argument would go
    through numba's slow type inference at every call, separate scalars
    through its fast path.
    """

    t_max: int
    """Planned iterations: T_max of the logsig schedule."""
    slope: float
    """k, slope of the logsig schedule."""
    n_clusters: int
    """m, k-means clusters."""
    kmeans_max_iter: int
    """Cap on Lloyd iterations."""
    p_replace: float
    """p_5a."""
    p_one_cluster: float
    """p_6b."""
    p_one_centre: float
    """p_6biii."""
    p_two_centres: float
    """p_6c."""
    scale: np.ndarray
    """Per-coordinate multiplier of the N(0, 1) step, shape (D,)."""
    lower: np.ndarray
    """Lower bounds (a private writable copy: numba compiles read-only arrays separately)."""
    upper: np.ndarray
    """Upper bounds (same reason)."""
    bound_mode: int
    """A :class:`~formation_bench.optimizers.bound_handling.BoundHandling` value."""


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
    x: np.ndarray,
    f: np.ndarray,
    u: np.ndarray,
    normals: np.ndarray,
    iteration: int,
    t_max: int,
    slope: float,
    n_clusters: int,
    kmeans_max_iter: int,
    p_replace: float,
    p_one_cluster: float,
    p_one_centre: float,
    p_two_centres: float,
    scale: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_mode: int,
) -> np.ndarray:
    """Steps 2-6 of Shi's BSO on the ideas ``(x, f)``: the N new ideas.

    The step factor is that of ``iteration`` out of ``t_max``. ``u`` holds, in
    this order: the k-means seeds (m), the p_5a draw, the replaced cluster,
    the random point (D), the idea-selection uniforms (N x 7, see
    :data:`~formation_bench.optimizers.bso_ops.SHI_UNIFORMS_PER_IDEA`), ``rand`` (N) and, for
    RESAMPLE bound handling only, N x D resample values. ``normals`` is N x D.
    The arguments from ``t_max`` on are the fields of :class:`ShiSettings`.
    """
    n, d = x.shape
    m = n_clusters
    point_at = m + 2
    ideas_at = point_at + d
    rand_at = ideas_at + n * SHI_UNIFORMS_PER_IDEA
    end = rand_at + n
    labels, centres, sizes = cluster_population(x, f, u[:m], kmeans_max_iter)
    sources = x
    if u[m] < p_replace:
        point = lower + u[point_at:ideas_at] * (upper - lower)
        sources, centres = replace_centre(x, centres, u[m + 1], point)
    resample_uniforms = u[end:].reshape(n, d) if u.shape[0] > end else normals
    return generate_ideas(
        sources,
        labels,
        centres,
        sizes,
        u[ideas_at:rand_at].reshape(n, SHI_UNIFORMS_PER_IDEA),
        False,
        0,
        0,
        False,
        p_one_cluster,
        p_one_centre,
        p_two_centres,
        logsig_factor(iteration, t_max, slope),
        u[rand_at:end],
        normals,
        scale,
        lower,
        upper,
        bound_mode,
        resample_uniforms,
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
    t_max: int,
    slope: float,
    n_clusters: int,
    kmeans_max_iter: int,
    p_replace: float,
    p_one_cluster: float,
    p_one_centre: float,
    p_two_centres: float,
    scale: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_mode: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 7 of the last iteration, then :func:`shi_step`, in one call: ``(x, f, ideas)``.

    ``(x, f)`` are the ideas after the slot-wise selection of ``new_ideas``
    (costs ``new_costs``), ``ideas`` the N new ones made from them; the other
    arguments are those of :func:`shi_step`. Fused so that an iteration costs
    one kernel call.
    """
    x, f, _ = greedy_select(x, f, new_ideas, new_costs)
    ideas = shi_step(
        x, f, u, normals, iteration, t_max, slope, n_clusters, kmeans_max_iter, p_replace,
        p_one_cluster, p_one_centre, p_two_centres, scale, lower, upper, bound_mode,
    )  # fmt: skip
    return x, f, ideas
