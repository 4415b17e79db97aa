"""Predictive sampling: the kernels against the paper's rule in numpy, budgets, starts, settings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import Recorder
from test_compiled_loop import PlainCallable, same_result
from test_cost_and_problem import random_problem
from test_mppi import BOX6, LOWER, UPPER, X0, drive, quadratic, rosenbrock

from formation_bench.mpc.scenario import PAPER
from formation_bench.optimizers import Bounds, Budget, PredictiveSampling, get_optimizer
from formation_bench.optimizers.predictive_sampling import (
    predictive_sampling_ask,
    predictive_sampling_tell,
)


def reference_predictive_sampling(opt: PredictiveSampling, f, normals):  # type: ignore[no-untyped-def]
    """Howell et al. (2022): the best of the nominal and its noisy copies is the next nominal."""
    stages = X0.size // opt.plan_channels
    sigma = np.tile(opt.noise_std * (UPPER - LOWER).reshape(stages, -1).mean(axis=0), stages)
    u, cost, batches = X0.copy(), f(X0[None])[0], []
    for z in normals:
        candidates = np.clip(u + sigma * z, LOWER, UPPER)
        batches.append(candidates)
        costs = f(candidates)
        if costs.min() < cost:
            u, cost = candidates[np.argmin(costs)], costs.min()
    return batches, u, cost


@pytest.mark.parametrize("f", [quadratic, rosenbrock], ids=["quadratic", "rosenbrock"])
@pytest.mark.parametrize(
    "opt", [PredictiveSampling(noise_std=0.2), PredictiveSampling()], ids=["wide", "default"]
)
def test_kernels_follow_the_paper(opt: PredictiveSampling, f) -> None:  # type: ignore[no-untyped-def]
    normals = np.random.default_rng(3).standard_normal((6, opt.population_size, 6))
    ask, tell = predictive_sampling_ask, predictive_sampling_tell
    batches, state = drive(opt, ask, tell, f, normals)
    expected, nominal, cost = reference_predictive_sampling(opt, f, normals)
    for got, want in zip(batches, expected, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(state.nominal, nominal)
    assert state.cost == cost < f(X0[None])[0] and state.updates >= 1


def test_only_a_strictly_better_finite_sample_replaces_the_nominal() -> None:
    opt = PredictiveSampling(population_size=3)
    params = opt.params(BOX6, 1)
    state = opt.start(X0[None], np.array([2.0]), np.random.default_rng(0), params)
    candidates = np.stack([X0 * 0.5, X0 * 0.25, X0 * 0.125])
    for costs, winner in [([2.0, math.inf, 3.0], None), ([2.0, 1.0, 1.0], 1), ([1.5], 0)]:
        told = predictive_sampling_tell(state, params, candidates, np.array(costs), 1)
        if winner is None:
            np.testing.assert_array_equal(told.nominal, X0)
            assert (told.cost, told.updates) == (2.0, 0)
        else:
            np.testing.assert_array_equal(told.nominal, candidates[winner])
            assert told.cost == min(costs) and told.updates == 1


@pytest.mark.parametrize("evaluations", [1, 2, 9, 10, 11, 100, 1225])
def test_spends_the_evaluation_budget_exactly(evaluations: int) -> None:
    rec = Recorder(quadratic)
    res = PredictiveSampling().minimize(
        rec, BOX6, np.random.default_rng(1), Budget(evaluations), X0
    )
    assert res.nfev == rec.points.shape[0] == evaluations
    np.testing.assert_array_equal(rec.points[0], X0)


def test_default_budget() -> None:
    rec = Recorder(quadratic)
    res = get_optimizer("predictive-sampling").minimize(rec, BOX6, np.random.default_rng(1))
    assert res.nfev == 1 + 9 * 136 and rec.calls == [1] + [9] * 136
    np.testing.assert_array_equal(rec.points[0], (LOWER + UPPER) / 2)  # no warm start: the centre


def test_no_worse_than_the_warm_start_and_deadline_keeps_the_best() -> None:
    for seed in range(5):
        x0 = BOX6.sample(np.random.default_rng(seed), 1)[0]
        res = PredictiveSampling().minimize(
            rosenbrock, BOX6, np.random.default_rng(seed), Budget(200), x0
        )
        assert res.fun <= rosenbrock(x0[None])[0]
    rec = Recorder(rosenbrock)
    budget = Budget(max_iterations=10**7, deadline_s=0.05)
    res = PredictiveSampling().minimize(rec, BOX6, np.random.default_rng(0), budget, X0)
    assert res.message == "deadline reached" and 1 <= res.nit < 10**7
    assert res.fun == rosenbrock(rec.points).min() == rosenbrock(res.x[None])[0]
    assert res.history_fun[-1] == res.fun and res.nfev == rec.points.shape[0]


def test_same_generator_same_answer() -> None:
    a, b, c = (
        PredictiveSampling().minimize(
            rosenbrock, BOX6, np.random.default_rng(seed), Budget(300), X0
        )
        for seed in (5, 5, 6)
    )
    assert same_result(a, b) and a.fun != c.fun


def test_the_python_objective_gives_the_compiled_result() -> None:
    problem = random_problem(np.random.default_rng(2), PAPER)
    x0 = problem.bounds.sample(np.random.default_rng(3), 1)[0]
    for budget, start in [(None, x0), (Budget(max_evaluations=95), None)]:
        runs = [
            PredictiveSampling().minimize(
                objective, problem.bounds, np.random.default_rng(4), budget, start
            )
            for objective in (problem, PlainCallable(problem))
        ]
        assert math.isnan(runs[0].info["objective_time_s"])
        assert same_result(*runs) and runs[0].info["nominal_updates"] > 0


def test_a_plan_whose_length_is_not_a_multiple_of_the_channels_is_refused() -> None:
    box = Bounds(-np.ones(9), np.ones(9))
    with pytest.raises(ValueError, match=r"PredictiveSampling\.plan_channels = 2 .* dimension 9"):
        PredictiveSampling().minimize(quadratic, box, np.random.default_rng(0))
    opt = PredictiveSampling(plan_channels=3)
    assert (
        opt.minimize(
            lambda x: np.sum(x * x, axis=1), box, np.random.default_rng(0), Budget(40)
        ).nfev
        == 40
    )


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("plan_channels", 0),
        ("population_size", 0),
        ("max_iterations", -1),
        ("noise_std", 0.0),
        ("noise_std", 2.0),
    ],
)
def test_invalid_settings_name_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"PredictiveSampling\.{field} must"):
        PredictiveSampling(**{field: value})
