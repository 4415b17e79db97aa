"""Brain Storm Optimization update rules as pure, compiled functions.

Every function here is deterministic: the caller draws all random numbers
with its :class:`numpy.random.Generator` and passes them in as arrays (always
uniforms in [0, 1) or standard normals), so a test can drive each rule with
hand-picked numbers. Inputs are never modified; new arrays are returned.

The functions are numba kernels so that one BSO iteration costs a handful of
Python-level calls: a population of 30 is evaluated in tens of microseconds,
and a chain of small numpy operations per idea would cost more than that.
:func:`generate_ideas` fuses the per-idea rules for that reason; the single
rules stay public for tests and for other BSO variants (Shi's original BSO,
chaotic local search) to compose differently.

Shapes: ``N`` ideas/population members, ``D`` dimensions, ``m`` clusters,
``K`` non-empty clusters.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# BoundHandling is re-exported: bound handling is one of the BSO operators
from formation_bench.optimizers.bound_handling import (  # noqa: F401
    BoundHandling,
    apply_bounds,
    apply_bounds_inplace,
)

# The clustering-step operators live in their own module; bso_ops is the single
# import point for every BSO operator.
from formation_bench.optimizers.bso_clusters import (  # noqa: F401
    cluster_centres,
    cluster_population,
    distinct_indices,
    nonempty,
    pick_index,
    random_centre,
)
from formation_bench.optimizers.chaos import step_inplace

# The slot-wise selection is generic population code; re-exported as a BSO operator.
from formation_bench.optimizers.population import greedy_select  # noqa: F401

SHI_UNIFORMS_PER_IDEA = 7
"""Columns of the uniforms driving :func:`shi_select`, in this order:
0 one cluster (``< p_one_cluster``) or two; 1 first cluster; 2 centre(s)
(``< p_one_centre`` or ``< p_two_centres``) or random member(s); 3 member of
the first cluster; 4 second cluster; 5 member of the second cluster; 6 the
mixing weight ``r`` of ``r A + (1 - r) B``."""


@njit(cache=True)
def chaotic_weights(
    map_id: int, seeds: np.ndarray, n_iterations: int, normalise: bool
) -> np.ndarray:
    """Eq. (8): each seed ``ch(0)`` iterated ``n_iterations`` times; rows optionally sum to 1.

    ``seeds`` is ``(N, K)``. Without normalisation the weights are the raw
    chaotic values in (0, 1) printed in eq. (9), which may sum to more than 1.
    """
    n, k = seeds.shape
    w = seeds.copy()
    flat = w.reshape(-1)
    scratch = np.empty_like(flat)
    # whole-array steps: the n*k chains are independent, so they vectorise
    for _ in range(n_iterations):
        step_inplace(map_id, flat, scratch)
    if normalise:
        for i in range(n):
            total = 0.0
            for j in range(k):
                total += w[i, j]
            if total > 0.0:
                for j in range(k):
                    w[i, j] /= total
            else:  # only reachable with n_iterations == 0 and all-zero seeds
                for j in range(k):
                    w[i, j] = 1.0 / k
    return w


@njit(cache=True)
def weighted_centres(weights: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Eq. (9): ``X_h = sum_j w_j X_Cj`` for each row of ``weights`` (N, K); centres (K, D)."""
    n, k = weights.shape
    d = centres.shape[1]
    out = np.zeros((n, d))
    for i in range(n):
        for j in range(k):
            w = weights[i, j]
            for c in range(d):
                out[i, c] += w * centres[j, c]
    return out


# inline: a thin layer (see the note at ideas_from_clusters in modified_bso_kernels)
@njit(cache=True, inline="always")
def all_centre_auxiliary(
    population: np.ndarray,
    centre_index: np.ndarray,
    seeds: np.ndarray,
    map_id: int,
    n_iterations: int,
    normalise: bool,
) -> np.ndarray:
    """Eqs. (8)-(9) over the non-empty clusters.

    ``seeds`` is ``(N, m)``; the columns of empty clusters are ignored.
    """
    used = nonempty(centre_index)
    # gathers as loops: fancy indexing compiles numba's generic advanced-indexing code
    n, k, d = seeds.shape[0], used.shape[0], population.shape[1]
    picked = np.empty((n, k))
    centres = np.empty((k, d))
    for j in range(k):
        for i in range(n):
            picked[i, j] = seeds[i, used[j]]
        for c in range(d):
            centres[j, c] = population[centre_index[used[j]], c]
    w = chaotic_weights(map_id, picked, n_iterations, normalise)
    return weighted_centres(w, centres)


# inline: a thin layer (see the note at ideas_from_clusters in modified_bso_kernels)
@njit(cache=True, inline="always")
def _member(labels: np.ndarray, cluster: int, k: int) -> int:
    """Population index of the k-th member (in index order) of ``cluster``."""
    seen = 0
    for i in range(labels.shape[0]):
        if labels[i] == cluster:
            if seen == k:
                return i
            seen += 1
    raise ValueError("cluster has fewer members than requested")


@njit(cache=True)
def shi_select(
    population: np.ndarray,
    labels: np.ndarray,
    centre_index: np.ndarray,
    sizes: np.ndarray,
    uniforms: np.ndarray,
    p_one_cluster: float,
    p_one_centre: float,
    p_two_centres: float,
) -> np.ndarray:
    """Shi's (2011) idea sources, one per row of ``uniforms`` (N, 7).

    One cluster (probability ``p_one_cluster``, chosen with probability
    proportional to its size): its centre with probability ``p_one_centre``,
    else a uniformly random member. Two clusters (chosen uniformly, distinct):
    both centres with probability ``p_two_centres``, else a random member of
    each, mixed as ``r A + (1 - r) B``. With one non-empty cluster the
    one-cluster branch is always taken. Column meanings: see
    :data:`SHI_UNIFORMS_PER_IDEA`.
    """
    n_ideas = uniforms.shape[0]
    d = population.shape[1]
    used = nonempty(centre_index)
    k = used.shape[0]
    total = 0
    for j in range(sizes.shape[0]):
        total += sizes[j]
    out = np.empty((n_ideas, d))
    for i in range(n_ideas):
        u = uniforms[i]
        if u[0] < p_one_cluster or k == 1:
            # roulette over sizes: cluster c owns [cum_before, cum_before + size)
            target = pick_index(u[1], total)
            c = 0
            cum = sizes[0]
            while cum <= target:
                c += 1
                cum += sizes[c]
            if u[2] < p_one_centre:
                src = centre_index[c]
            else:
                src = _member(labels, c, pick_index(u[3], sizes[c]))
            for c in range(d):
                out[i, c] = population[src, c]
        else:
            a = pick_index(u[1], k)
            b = pick_index(u[4], k - 1)
            if b >= a:
                b += 1
            ca = used[a]
            cb = used[b]
            if u[2] < p_two_centres:
                ia = centre_index[ca]
                ib = centre_index[cb]
            else:
                ia = _member(labels, ca, pick_index(u[3], sizes[ca]))
                ib = _member(labels, cb, pick_index(u[5], sizes[cb]))
            r = u[6]
            for c in range(d):
                out[i, c] = r * population[ia, c] + (1.0 - r) * population[ib, c]
    return out


# inline: a thin layer (see the note at ideas_from_clusters in modified_bso_kernels)
@njit(cache=True, inline="always")
def logsig_factor(t_now: float, t_max: float, slope: float) -> float:
    """Eq. (10) step-size factor ``logsig((0.5 T_max - T_now) / k)`` in (0, 1)."""
    return 1.0 / (1.0 + math.exp(-(0.5 * t_max - t_now) / slope))


@njit(cache=True)
def perturb(
    auxiliary: np.ndarray, factor: float, rand: np.ndarray, normals: np.ndarray, scale: np.ndarray
) -> np.ndarray:
    """Eq. (10): ``X_h + factor * rand_i * N(0, 1, D) * scale``.

    ``rand`` is ``(N,)`` (one scalar per idea), ``normals`` ``(N, D)``.
    """
    out = auxiliary.copy()
    _perturb_inplace(out, factor, rand, normals, scale)
    return out


@njit(cache=True)
def _perturb_inplace(
    x: np.ndarray, factor: float, rand: np.ndarray, normals: np.ndarray, scale: np.ndarray
) -> None:
    n, d = x.shape
    for i in range(n):
        a = factor * rand[i]
        for c in range(d):
            x[i, c] += a * normals[i, c] * scale[c]


@njit(cache=True)
def chaotic_candidates(
    map_id: int, seed: np.ndarray, n_candidates: int, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """Eqs. (6)-(7): ``cx(i) = cr(i) (X_max - X_min) + X_min``, i = 1..n_r; shape (n_r, D).

    ``cr(i)`` is the i-th iterate of the map from ``cr(0) = seed`` (D,).
    """
    d = seed.shape[0]
    out = np.empty((n_candidates, d))
    cr = seed.copy()
    scratch = np.empty_like(cr)
    for i in range(n_candidates):
        step_inplace(map_id, cr, scratch)
        for c in range(d):
            out[i, c] = min(lower[c] + cr[c] * (upper[c] - lower[c]), upper[c])
    return out


@njit(cache=True)
def install_best(
    x: np.ndarray, f: np.ndarray, slot: int, candidates: np.ndarray, candidate_costs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Copies of ``x``, ``f`` with member ``slot`` replaced by the best candidate.

    The replacement is unconditional (even when the candidate is worse), as
    in BSO's centre replacement; the first of equal-cost candidates wins.
    """
    best = 0
    for i in range(1, candidate_costs.shape[0]):
        if candidate_costs[i] < candidate_costs[best]:
            best = i
    x_new = x.copy()
    f_new = f.copy()
    # element loop, not a row assignment: see greedy_select
    for c in range(x.shape[1]):
        x_new[slot, c] = candidates[best, c]
    f_new[slot] = candidate_costs[best]
    return x_new, f_new


# inline: a thin layer (see the note at ideas_from_clusters in modified_bso_kernels)
@njit(cache=True, inline="always")
def generate_ideas(
    population: np.ndarray,
    labels: np.ndarray,
    centre_index: np.ndarray,
    sizes: np.ndarray,
    idea_uniforms: np.ndarray,
    all_centre_weighting: bool,
    weight_map: int,
    n_weight_iterations: int,
    normalise_weights: bool,
    p_one_cluster: float,
    p_one_centre: float,
    p_two_centres: float,
    factor: float,
    rand: np.ndarray,
    normals: np.ndarray,
    scale: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_handling: int,
    resample_uniforms: np.ndarray,
) -> np.ndarray:
    """All N new ideas of one iteration: auxiliary solutions, eq. (10) step, bound handling.

    ``idea_uniforms`` is ``(N, m)`` chaotic seeds when ``all_centre_weighting``
    (eqs. 8-9) and ``(N, 7)`` :func:`shi_select` uniforms otherwise (the three
    probabilities are read only then). The settings parameters are named as the
    config fields they come from, so the kernels pass them as ``name=s.name``.
    """
    if all_centre_weighting:
        aux = all_centre_auxiliary(
            population,
            centre_index,
            idea_uniforms,
            weight_map,
            n_weight_iterations,
            normalise_weights,
        )
    else:
        aux = shi_select(
            population,
            labels,
            centre_index,
            sizes,
            idea_uniforms,
            p_one_cluster,
            p_one_centre,
            p_two_centres,
        )
    # aux is this kernel's own array: step and repair it in place (no extra allocations)
    _perturb_inplace(aux, factor, rand, normals, scale)
    apply_bounds_inplace(aux, lower, upper, bound_handling, resample_uniforms)
    return aux
