"""Brain Storm Optimization update rules as pure, compiled functions.

Every function here is deterministic: the caller draws all random numbers
with its :class:`numpy.random.Generator` and passes them in as arrays (always
uniforms in [0, 1) or standard normals), so a test can drive each rule with
hand-picked numbers. Inputs are never modified; new arrays are returned.

The functions are numba kernels, composed by the ask kernels of the BSO family (the modified
BSO, Shi's original BSO and the chaotic-local-search BSO): a population of 30 is evaluated in
tens of microseconds, and a chain of small numpy operations per idea would cost more than
that. The iteration's random numbers have one layout for the whole family
(:class:`BSODraws`).

Shapes: ``N`` ideas/population members, ``D`` dimensions, ``m`` clusters,
``K`` non-empty clusters.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from formation_bench.kernel_cache import njit

# BoundHandling is re-exported: bound handling is one of the BSO operators
from formation_bench.optimizers.bound_handling import (  # noqa: F401
    BoundHandling,
    apply_bounds,
    apply_bounds_inplace,
)

# The clustering-step operators live in their own module; bso_ops is the single
# import point for every BSO operator.
from formation_bench.optimizers.bso_clusters import (  # noqa: F401
    Clusters,
    cluster_centres,
    cluster_population,
    clusters_of,
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


# inline: a thin layer (see the note at move_ideas)
@njit(cache=True, inline="always")
def all_centre_auxiliary(
    population: np.ndarray,
    centre_index: np.ndarray,
    seeds: np.ndarray,
    weight_map: int,
    n_weight_iterations: int,
    normalise_weights: bool,
) -> np.ndarray:
    """Eqs. (8)-(9) over the non-empty clusters, with the chaotic map ``weight_map`` iterated
    ``n_weight_iterations`` times (:func:`chaotic_weights`).

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
    w = chaotic_weights(weight_map, picked, n_weight_iterations, normalise_weights)
    return weighted_centres(w, centres)


# inline: a thin layer (see the note at move_ideas)
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
    clusters: Clusters,
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
    labels, centre_index, sizes = clusters
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


# inline: a thin layer (see the note at move_ideas)
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
    replacement_map: int, seed: np.ndarray, n_replace: int, lower: np.ndarray, upper: np.ndarray
) -> np.ndarray:
    """Eqs. (6)-(7): ``cx(i) = cr(i) (X_max - X_min) + X_min``, i = 1..n_r; shape (n_r, D).

    ``cr(i)`` is the i-th iterate of the map ``replacement_map`` from ``cr(0) = seed`` (D,).
    """
    d = seed.shape[0]
    out = np.empty((n_replace, d))
    cr = seed.copy()
    scratch = np.empty_like(cr)
    for i in range(n_replace):
        step_inplace(replacement_map, cr, scratch)
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


class BSODraws(NamedTuple):
    """One BSO iteration's random numbers: its row of uniforms, laid out in this order, and its
    standard normals. Every BSO of the family reads this layout (:func:`bso_draws`), which
    does not depend on the branches taken, so that runs stay comparable."""

    kmeans: np.ndarray
    """(m,): the k-means initial centres (:func:`distinct_indices`)."""
    replace_draw: float
    """Whether a centre is replaced this iteration (``< p_replace``)."""
    centre_draw: float
    """Which non-empty cluster's centre is replaced."""
    point: np.ndarray
    """(D,): the replacement's seed, the chaotic ``cr(0)`` or the uniform random point."""
    sources: np.ndarray
    """(N, width): the idea sources, chaotic weight seeds (width m) or :func:`shi_select`'s
    uniforms (width :data:`SHI_UNIFORMS_PER_IDEA`)."""
    rand: np.ndarray
    """(N,): ``rand_i`` of the step of eq. (10)."""
    normals: np.ndarray
    """(N, D): the standard normals of the step."""
    resample: np.ndarray
    """(N, D): resample values of RESAMPLE bound handling (``normals``, unread, otherwise)."""


def uniforms_per_iteration(n: int, d: int, n_clusters: int, width: int, resample: bool) -> int:
    """Length of the row of uniforms of :class:`BSODraws` (with the resample values if
    ``resample``)."""
    return n_clusters + 2 + d + n * (width + 1) + (n * d if resample else 0)


# inline: a thin layer (see the note at move_ideas)
@njit(cache=True, inline="always")
def bso_draws(uniforms: np.ndarray, normals: np.ndarray, n_clusters: int, width: int) -> BSODraws:
    """The iteration's numbers as :class:`BSODraws`; ``uniforms`` may hold further values after
    them (read by the caller)."""
    n, d = normals.shape
    m = n_clusters
    sources_at = m + 2 + d
    rand_at = sources_at + n * width
    resample_at = rand_at + n
    if uniforms.shape[0] > resample_at:
        resample = uniforms[resample_at : resample_at + n * d].reshape(n, d)
    else:
        resample = normals
    return BSODraws(
        uniforms[:m], uniforms[m], uniforms[m + 1], uniforms[m + 2 : sources_at],
        uniforms[sources_at:rand_at].reshape(n, width), uniforms[rand_at:resample_at], normals,
        resample,
    )  # fmt: skip


# inline: a thin layer. Every compiled call boundary re-optimises the whole callee tree below
# it when the caller is built, so thin layers cost cold-start seconds; see
# docs/explanation/kernels.md
@njit(cache=True, inline="always")
def move_ideas(auxiliary: np.ndarray, factor: float, draws: BSODraws, s: tuple) -> np.ndarray:
    """The ideas: the ``auxiliary`` solutions (modified in place and returned) moved by the
    step of eq. (10), ``factor rand_i N(0, 1) scale``, and brought back into the box.

    ``s`` is the optimiser's settings (any namedtuple with ``scale``, ``lower``, ``upper``,
    ``bound_handling``).
    """
    lower, upper, bound_handling = s.lower, s.upper, s.bound_handling
    _perturb_inplace(auxiliary, factor, draws.rand, draws.normals, scale=s.scale)
    apply_bounds_inplace(auxiliary, lower, upper, bound_handling, draws.resample)
    return auxiliary
