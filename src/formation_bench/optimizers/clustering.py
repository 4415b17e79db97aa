"""k-means by Lloyd's algorithm: a numba-compiled version and the scikit-learn reference.

BSO clusters a population of a few dozen points every iteration. At that size
scikit-learn's per-call overhead (input validation, thread pools) dwarfs the
arithmetic, so the optimisers use :func:`lloyd_kmeans`; :func:`sklearn_kmeans`
is kept as the reference it is tested against and as a selectable backend.

Both start from the given initial centres and alternate assignment and mean
updates until the labels stop changing (or ``max_iter`` updates). From the
same initial centres they give the same partition, except in two cases:

* an **empty cluster**: :func:`lloyd_kmeans` keeps that cluster's previous
  centre (so it may capture points later, and labels stay in ``0..m-1``
  with no relocation), whereas scikit-learn moves it to a far-away point;
* exact distance **ties**, which both break towards the lower cluster index
  but which rounding may resolve differently (scikit-learn expands
  ``|x - c|^2``; the compiled version sums squared differences).
"""

from __future__ import annotations

from enum import Enum

import numpy as np

from formation_bench.kernel_cache import njit

DEFAULT_MAX_ITER = 100
"""Default cap on mean updates; populations of ~30 points converge in far fewer."""


class ClusteringBackend(Enum):
    """Which k-means implementation an optimiser calls."""

    COMPILED = "compiled"
    """:func:`lloyd_kmeans` (numba)."""
    SKLEARN = "sklearn"
    """:func:`sklearn_kmeans` (scikit-learn, slower per call on small populations)."""


# 'reassoc' lets LLVM vectorise the distance sums (about 3x faster at d = 40); it
# only reorders additions, so it can change a label only at an exact-tie.
@njit(cache=True, fastmath={"reassoc"})
def _assign(points: np.ndarray, centres: np.ndarray, labels: np.ndarray) -> bool:
    """Label each point with its nearest centre; True when any label changed."""
    n, d = points.shape
    m = centres.shape[0]
    changed = False
    for i in range(n):
        best = np.inf
        best_j = 0
        for j in range(m):
            s = 0.0
            for k in range(d):
                diff = points[i, k] - centres[j, k]
                s += diff * diff
            # strict '<': ties go to the lower index, as in numpy/scikit-learn argmin
            if s < best:
                best = s
                best_j = j
        if labels[i] != best_j:
            labels[i] = best_j
            changed = True
    return changed


@njit(cache=True)
def _update(
    points: np.ndarray,
    labels: np.ndarray,
    centres: np.ndarray,
    sums: np.ndarray,
    counts: np.ndarray,
) -> None:
    """Move each non-empty cluster's centre to its members' mean, in place.

    ``sums`` (m, d) and ``counts`` (m,) are scratch space, reused across
    iterations because allocations are a noticeable share of a ~3 us k-means.
    """
    n, d = points.shape
    m = centres.shape[0]
    sums[:] = 0.0
    counts[:] = 0
    for i in range(n):
        j = labels[i]
        counts[j] += 1
        for k in range(d):
            sums[j, k] += points[i, k]
    for j in range(m):
        if counts[j] > 0:  # an empty cluster keeps its previous centre
            for k in range(d):
                centres[j, k] = sums[j, k] / counts[j]


@njit(cache=True)
def lloyd_kmeans_kernel(
    points: np.ndarray, initial_centres: np.ndarray, max_iter: int
) -> tuple[np.ndarray, np.ndarray]:
    """Compiled body of :func:`lloyd_kmeans`; callable from other numba kernels."""
    centres = initial_centres.copy()
    labels = np.full(points.shape[0], -1, dtype=np.int64)
    sums = np.empty_like(centres)
    counts = np.empty(centres.shape[0], dtype=np.int64)
    _assign(points, centres, labels)
    for _ in range(max_iter):
        _update(points, labels, centres, sums, counts)
        if not _assign(points, centres, labels):
            break
    return labels, centres


def lloyd_kmeans(
    points: np.ndarray, initial_centres: np.ndarray, max_iter: int = DEFAULT_MAX_ITER
) -> tuple[np.ndarray, np.ndarray]:
    """k-means (Lloyd) from ``initial_centres``: ``(labels (n,) int64, centres (m, d))``.

    Iterates until no label changes or ``max_iter`` mean updates. The returned
    labels assign every point to its nearest returned centre. An empty
    cluster keeps its previous centre (its label simply does not occur).
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    initial_centres = np.ascontiguousarray(initial_centres, dtype=np.float64)
    _check(points, initial_centres, max_iter)
    return lloyd_kmeans_kernel(points, initial_centres, int(max_iter))


def sklearn_kmeans(
    points: np.ndarray, initial_centres: np.ndarray, max_iter: int = DEFAULT_MAX_ITER
) -> tuple[np.ndarray, np.ndarray]:
    """Reference: scikit-learn's Lloyd k-means from the same centres, no tolerance."""
    from sklearn.cluster import KMeans  # imported lazily: slow import, rarely used

    points = np.ascontiguousarray(points, dtype=np.float64)
    initial_centres = np.ascontiguousarray(initial_centres, dtype=np.float64)
    _check(points, initial_centres, max_iter)
    km = KMeans(
        n_clusters=initial_centres.shape[0],
        init=initial_centres,
        n_init=1,
        algorithm="lloyd",
        tol=0.0,
        max_iter=int(max_iter),
    ).fit(points)
    return km.labels_.astype(np.int64), np.asarray(km.cluster_centers_, dtype=np.float64)


def kmeans(
    backend: ClusteringBackend,
    points: np.ndarray,
    initial_centres: np.ndarray,
    max_iter: int = DEFAULT_MAX_ITER,
) -> tuple[np.ndarray, np.ndarray]:
    """Dispatch to the k-means of ``backend``."""
    if backend is ClusteringBackend.COMPILED:
        return lloyd_kmeans(points, initial_centres, max_iter)
    if backend is ClusteringBackend.SKLEARN:
        return sklearn_kmeans(points, initial_centres, max_iter)
    raise ValueError(f"unknown clustering backend {backend!r}")


def _check(points: np.ndarray, centres: np.ndarray, max_iter: int) -> None:
    if points.ndim != 2 or centres.ndim != 2 or points.shape[1] != centres.shape[1]:
        raise ValueError(
            f"points (n, d) and initial_centres (m, d) must share d, "
            f"got {points.shape} and {centres.shape}"
        )
    if not 1 <= centres.shape[0] <= points.shape[0]:
        raise ValueError(
            f"number of clusters must be in 1..{points.shape[0]}, got {centres.shape[0]}"
        )
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
