"""BSO's clustering step: k-means of the population and each cluster's best member.

Pure compiled functions like the rest of :mod:`formation_bench.optimizers.bso_ops` (which
re-exports them): random numbers come in as arrays of uniforms.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from formation_bench.kernel_cache import njit
from formation_bench.optimizers.clustering import lloyd_kmeans_kernel


class Clusters(NamedTuple):
    """BSO's clustering of a population (its steps 2 and 3)."""

    labels: np.ndarray
    """Cluster of each member, shape (N,), int64 in 0..m-1."""
    centre_index: np.ndarray
    """Population index of each cluster's best member (its centre), -1 when it is empty, (m,)."""
    sizes: np.ndarray
    """Members of each cluster, (m,)."""


# inline: a thin layer (see the note at move_ideas in bso_ops)
@njit(cache=True, inline="always")
def pick_index(u: float, n: int) -> int:
    """Index in 0..n-1 from a uniform; the min guards against rounding up to n."""
    return min(int(u * n), n - 1)


@njit(cache=True)
def distinct_indices(uniforms: np.ndarray, n: int) -> np.ndarray:
    """``len(uniforms)`` distinct indices of 0..n-1 (partial Fisher-Yates shuffle)."""
    perm = np.arange(n)
    k = uniforms.shape[0]
    for i in range(k):
        j = i + pick_index(uniforms[i], n - i)
        perm[i], perm[j] = perm[j], perm[i]
    return perm[:k].copy()


@njit(cache=True)
def cluster_centres(
    labels: np.ndarray, costs: np.ndarray, n_clusters: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(centre_index (m,), sizes (m,))``: the best member of each cluster and its size.

    ``centre_index[j]`` is the population index of the lowest-cost member of
    cluster ``j`` (the lowest index among equal costs), or -1 when the
    cluster is empty.
    """
    centre = np.full(n_clusters, -1, dtype=np.int64)
    sizes = np.zeros(n_clusters, dtype=np.int64)
    for i in range(labels.shape[0]):
        j = labels[i]
        sizes[j] += 1
        if centre[j] < 0 or costs[i] < costs[centre[j]]:
            centre[j] = i
    return centre, sizes


# inline: a thin layer (see the note at move_ideas in bso_ops)
@njit(cache=True, inline="always")
def cluster_population(
    population: np.ndarray, costs: np.ndarray, uniforms: np.ndarray, kmeans_max_iter: int
) -> Clusters:
    """BSO's clustering step.

    k-means (Lloyd, at most ``kmeans_max_iter`` updates) from ``m = len(uniforms)``
    distinct members chosen by :func:`distinct_indices`, then
    :func:`cluster_centres`. Fused into one kernel to save Python-level calls.
    """
    idx = distinct_indices(uniforms, population.shape[0])
    # the initial centres gathered by a loop (fancy indexing compiles generic code)
    d = population.shape[1]
    initial = np.empty((idx.shape[0], d))
    for j in range(idx.shape[0]):
        for c in range(d):
            initial[j, c] = population[idx[j], c]
    labels, _ = lloyd_kmeans_kernel(population, initial, kmeans_max_iter)
    centre, sizes = cluster_centres(labels, costs, uniforms.shape[0])
    return Clusters(labels, centre, sizes)


# inline: a thin layer (see the note at move_ideas in bso_ops)
@njit(cache=True, inline="always")
def clusters_of(
    population: np.ndarray,
    costs: np.ndarray,
    given_labels: np.ndarray,
    uniforms: np.ndarray,
    kmeans_max_iter: int,
) -> Clusters:
    """The population's clusters: from ``given_labels`` when it holds one label per member
    (a k-means computed outside compiled code, e.g. scikit-learn's), else by
    :func:`cluster_population`."""
    # one return: each exit of an inlined function counts references to its result's arrays
    if given_labels.shape[0] == population.shape[0]:
        centre, sizes = cluster_centres(given_labels, costs, uniforms.shape[0])
        clusters = Clusters(given_labels, centre, sizes)
    else:
        clusters = cluster_population(population, costs, uniforms, kmeans_max_iter=kmeans_max_iter)
    return clusters


# inline: a thin layer (see the note at move_ideas in bso_ops)
@njit(cache=True, inline="always")
def nonempty(centre_index: np.ndarray) -> np.ndarray:
    """Indices of the non-empty clusters (those with ``centre_index >= 0``), ascending."""
    # a counting loop: np.flatnonzero compiles its own generic implementation (a quarter
    # second of a cold start) for what is a handful of integers
    count = 0
    for j in range(centre_index.shape[0]):
        if centre_index[j] >= 0:
            count += 1
    used = np.empty(count, dtype=np.int64)
    k = 0
    for j in range(centre_index.shape[0]):
        if centre_index[j] >= 0:
            used[k] = j
            k += 1
    return used


# inline: a thin layer (see the note at move_ideas in bso_ops)
@njit(cache=True, inline="always")
def random_centre(centre_index: np.ndarray, u: float) -> int:
    """Population index of the centre of a non-empty cluster chosen uniformly by ``u``."""
    used = nonempty(centre_index)
    return centre_index[used[pick_index(u, used.shape[0])]]
