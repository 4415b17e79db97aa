"""Compiled Lloyd k-means against scikit-learn's, from the same initial centres."""

from __future__ import annotations

import numpy as np
import pytest

from formation_bench.optimizers.clustering import (
    ClusteringBackend,
    kmeans,
    lloyd_kmeans,
    sklearn_kmeans,
)


def blobs(rng: np.random.Generator, n: int, d: int, m: int, spread: float) -> np.ndarray:
    """``n`` points around ``m`` random centres; ``spread`` small = well separated."""
    centres = rng.normal(size=(m, d)) * 10.0
    return centres[rng.integers(0, m, n)] + spread * rng.normal(size=(n, d))


def data_sets() -> list[tuple[np.ndarray, np.ndarray]]:
    """(points, initial centres) pairs, well separated to heavily overlapping, no empty cluster."""
    rng = np.random.default_rng(12345)
    out = []
    for spread in (0.5, 3.0, 10.0, 30.0):
        for n, d, m in ((30, 10, 5), (30, 40, 5), (60, 3, 4), (100, 20, 8)):
            while True:
                points = blobs(rng, n, d, m, spread)
                init = points[rng.choice(n, m, replace=False)]
                labels, _ = lloyd_kmeans(points, init)
                if np.unique(labels).size == m:  # sklearn relocates empty clusters; skip those
                    break
            out.append((points, init))
    return out


@pytest.mark.parametrize(("points", "init"), data_sets())
def test_same_partition_as_sklearn(points: np.ndarray, init: np.ndarray) -> None:
    labels, centres = lloyd_kmeans(points, init)
    ref_labels, ref_centres = sklearn_kmeans(points, init)
    np.testing.assert_array_equal(labels, ref_labels)
    np.testing.assert_allclose(centres, ref_centres, rtol=1e-10, atol=1e-10)
    assert labels.dtype == np.int64 and labels.shape == (points.shape[0],)


def test_converged_partition_is_a_fixed_point() -> None:
    points, init = data_sets()[5]
    labels, centres = lloyd_kmeans(points, init)
    for j in range(init.shape[0]):
        np.testing.assert_allclose(centres[j], points[labels == j].mean(axis=0))
    nearest = np.argmin(((points[:, None, :] - centres[None]) ** 2).sum(-1), axis=1)
    np.testing.assert_array_equal(labels, nearest)


def test_max_iter_caps_updates_like_sklearn() -> None:
    rng = np.random.default_rng(7)
    points = rng.uniform(-1.0, 1.0, (200, 2))  # no structure: Lloyd needs many updates
    init = points[:6].copy()
    for max_iter in (1, 2, 3):
        labels, _ = lloyd_kmeans(points, init, max_iter=max_iter)
        ref, _ = sklearn_kmeans(points, init, max_iter=max_iter)
        np.testing.assert_array_equal(labels, ref)


def test_empty_cluster_keeps_its_centre() -> None:
    points = np.array([[0.0, 0.0], [0.1, 0.0], [0.0, 0.1], [10.0, 10.0], [10.1, 10.0]])
    far = [100.0, -100.0]  # no point is ever nearest to it
    init = np.array([[0.0, 0.0], [10.0, 10.0], far])
    labels, centres = lloyd_kmeans(points, init)
    np.testing.assert_array_equal(labels, [0, 0, 0, 1, 1])
    np.testing.assert_array_equal(centres[2], far)
    assert np.all(np.isfinite(centres))


def test_duplicate_initial_centres_leave_a_cluster_empty() -> None:
    points = np.random.default_rng(3).normal(size=(30, 10))
    points[0] = 100.0  # isolated: cluster 0 stays {points[0]}, so centre 0 never moves
    init = np.vstack([points[0], points[0], points[1:4]])  # cluster 1 loses every tie
    labels, centres = lloyd_kmeans(points, init)
    assert 1 not in labels
    np.testing.assert_array_equal(centres[1], points[0])


def test_inputs_are_not_modified_and_backends_dispatch() -> None:
    points, init = data_sets()[0]
    p0, i0 = points.copy(), init.copy()
    a = kmeans(ClusteringBackend.COMPILED, points, init)
    b = kmeans(ClusteringBackend.SKLEARN, points, init)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(points, p0)
    np.testing.assert_array_equal(init, i0)


def test_invalid_shapes_raise() -> None:
    points = np.zeros((5, 2))
    with pytest.raises(ValueError, match="share d"):
        lloyd_kmeans(points, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="number of clusters"):
        lloyd_kmeans(points, np.zeros((6, 2)))
    with pytest.raises(ValueError, match="max_iter"):
        lloyd_kmeans(points, np.zeros((2, 2)), max_iter=0)
