"""The evaluation counter: what it returns for every shape of objective answer, and its budget."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formation_bench.optimizers.base import BudgetExhausted, EvaluationCounter

D = 3


def test_returns_a_copy_so_an_objective_may_reuse_its_buffer() -> None:
    buffer = np.zeros(4)

    def reusing(x: np.ndarray) -> np.ndarray:
        buffer[: x.shape[0]] = x.sum(axis=1)
        return buffer[: x.shape[0]]

    counter = EvaluationCounter(reusing, D, None)
    first = counter(np.ones((4, D)))
    counter(np.full((4, D), 2.0))
    assert np.array_equal(first, np.full(4, 3.0))  # not overwritten by the second call
    assert counter.nfev == 8 and counter.best_f == 3.0


@pytest.mark.parametrize(
    "answer",
    [
        lambda x: x.sum(axis=1).astype(np.float32),
        lambda x: x.sum(axis=1)[:, None],
        lambda x: list(x.sum(axis=1)),
        lambda x: x.sum(axis=1).astype(">f8"),
        lambda x: x.sum(axis=1).astype(np.int64),
    ],
    ids=["float32", "column", "list", "big-endian", "int64"],
)
def test_any_array_like_answer_becomes_float64_costs(answer) -> None:
    x = np.array([[3.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    counter = EvaluationCounter(answer, D, None)
    f = counter(x)
    assert f.dtype == np.float64 and f.shape == (3,) and f.flags.c_contiguous
    assert np.array_equal(f, [3.0, 1.0, 2.0])
    assert counter.best_f == 1.0 and type(counter.best_f) is float
    assert np.array_equal(counter.best_x, x[1])


def test_keeps_the_best_over_calls_and_maps_non_finite_costs_to_inf() -> None:
    costs = iter([np.array([5.0, np.nan]), np.array([-np.inf, 7.0]), np.array([2.0, 9.0])])
    counter = EvaluationCounter(lambda x: next(costs), D, None)
    assert np.array_equal(counter(np.zeros((2, D))), [5.0, math.inf])
    assert np.array_equal(counter(np.ones((2, D))), [math.inf, 7.0])
    assert counter.best_f == 5.0 and np.array_equal(counter.best_x, np.zeros(D))
    counter(np.full((2, D), 4.0))
    assert counter.best_f == 2.0 and np.array_equal(counter.best_x, np.full(D, 4.0))


def test_refuses_more_rows_than_the_budget_and_wrong_shapes() -> None:
    counter = EvaluationCounter(lambda x: x.sum(axis=1), D, 5)
    counter(np.zeros((3, D)))
    with pytest.raises(BudgetExhausted, match="3 evaluations requested, 2 left"):
        counter(np.zeros((3, D)))
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        counter(np.zeros((2, D + 1)))
    wrong_count = EvaluationCounter(lambda x: np.zeros(x.shape[0] + 1), D, None)
    with pytest.raises(ValueError, match="returned 3 costs for 2 points"):
        wrong_count(np.zeros((2, D)))
