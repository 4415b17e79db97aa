"""Uniform random search: uniform batches in the box, the warm start first, nothing learned."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import Recorder
from scipy.stats import kstest, mannwhitneyu

from formation_bench.optimizers import Bounds, Budget, RandomSearch, get_optimizer

D = 4
BOX = Bounds(np.array([-1.0, 0.0, 2.0, -0.25]), np.array([1.0, 5.0, 3.0, 0.25]))


def test_batches_are_uniform_in_the_box_with_the_warm_start_first() -> None:
    rec = Recorder()
    x0 = np.array([0.5, 1.0, 2.5, 0.0])
    res = RandomSearch().minimize(rec, BOX, np.random.default_rng(0), None, x0)
    assert [b.shape[0] for b in rec.batches] == [30] * 41
    assert (res.nfev, res.nit) == (1230, 40)
    np.testing.assert_array_equal(rec.batches[0][0], x0)
    points = np.vstack(rec.batches)[1:]
    assert BOX.contains(points)
    unit = (points - BOX.lower) / BOX.width
    for c in range(D):  # each coordinate uniform over its own range
        assert kstest(unit[:, c], "uniform").pvalue > 0.01
    # the result is the best point evaluated, and the history is its running minimum
    costs = np.einsum("ij,ij->i", np.vstack(rec.batches), np.vstack(rec.batches))
    assert res.fun == costs.min()
    ends = np.cumsum([b.shape[0] for b in rec.batches])
    np.testing.assert_array_equal(res.history_fun, np.minimum.accumulate(costs)[ends - 1])


def test_an_evaluation_budget_cuts_the_last_batch() -> None:
    rec = Recorder()
    res = RandomSearch(population_size=8).minimize(
        rec, BOX, np.random.default_rng(1), Budget(max_evaluations=21)
    )
    assert [b.shape[0] for b in rec.batches] == [8, 8, 5]
    assert res.nfev == 21 and res.message == "evaluation budget reached"


def test_it_is_the_floor_of_the_conformance_tests() -> None:
    """Its finals on the conformance tests' shifted 10-D sphere are those of plain uniform
    sampling of the same size (the floor test_conformance compares every optimiser with)."""
    box = Bounds(np.full(10, -5.0), np.full(10, 5.0))
    centre = np.linspace(-3.0, 2.0, 10)

    def sphere(x: np.ndarray) -> np.ndarray:
        return np.einsum("ij,ij->i", x - centre, x - centre)

    ours = [get_optimizer("random-search").minimize(sphere, box, np.random.default_rng(s)).fun
            for s in range(20)]  # fmt: skip
    floor = [sphere(box.sample(np.random.default_rng(100 + s), 1230)).min() for s in range(20)]
    assert mannwhitneyu(ours, floor).pvalue > 0.01
    de = [get_optimizer("de").minimize(sphere, box, np.random.default_rng(s)).fun for s in range(5)]
    assert max(de) < min(ours)


def test_configuration() -> None:
    assert get_optimizer("random-search") == RandomSearch()
    assert RandomSearch().default_budget == Budget(max_iterations=40)
    with pytest.raises(ValueError, match="population_size"):
        RandomSearch(population_size=0)
