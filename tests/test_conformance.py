"""Conformance of every registered optimiser to the interface of ``optimizers.base``.

Each test is parametrised over ``optimizer_names()``, so a newly registered
configuration is checked without editing this file. The black-box properties
(sphere, NaN costs, random-search baseline) apply to population optimisers,
which accept any batch objective; optimisers that only solve the MPC problem
(gradient baselines built on its symbolic model) are checked on a recorded
paper problem instead, and skip the black-box tests with a stated reason.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import BOX, CENTRE, D, Recorder, configured_names, shifted_sphere

from formation_bench.instances.instants import record_instants
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import (
    OPTIMIZERS,
    Bounds,
    Budget,
    PopulationOptimizer,
    get_optimizer,
)

sphere = shifted_sphere(CENTRE)
NAMES = [
    # nevergrad's adapters take seconds per test (Python per candidate): CI runs them
    pytest.param(name, marks=pytest.mark.slow) if name.startswith("ng-") else name
    for name in configured_names()
]
MISSING = OPTIMIZERS.missing()
"""Optional optimisers (the adapters) whose library is not installed here, and why."""


def black_box(name: str) -> PopulationOptimizer:
    optimizer = get_optimizer(name)
    if not isinstance(optimizer, PopulationOptimizer):
        pytest.skip(f"{name} solves only the MPC problem; checked on a recorded paper problem")
    return optimizer


@pytest.fixture(scope="module")
def paper_problem():
    """One UAV's problem of the paper scenario as the closed loop posed it at instant 5."""
    instants = record_instants(get_scenario("paper"), get_optimizer("modified-bso"), [5], seed=1)
    return instants[0]


@pytest.mark.parametrize("name", sorted(MISSING) or ["-"])
def test_optional_optimizers_not_installed_here_are_named_with_the_extra(name: str) -> None:
    if not MISSING:
        pytest.skip("every optional optimiser is installed, so all are checked below")
    assert "pip install" in MISSING[name]
    pytest.skip(f"{name} is not checked here: {MISSING[name]}")


# --- every registered optimiser, on a real MPC problem ------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_paper_problem_within_bounds_deterministic_and_no_worse_than_warm_start(
    name: str, paper_problem
) -> None:
    problem, x0 = paper_problem.problem, paper_problem.warm_start
    optimizer = get_optimizer(name)
    runs = [optimizer.minimize(problem, problem.bounds, np.random.default_rng(4), None, x0)]
    runs.append(optimizer.minimize(problem, problem.bounds, np.random.default_rng(4), None, x0))
    for res in runs:
        assert problem.bounds.contains(res.x)
        assert res.fun <= problem(x0[None])[0] + 1e-9 * abs(res.fun)
        assert res.fun == pytest.approx(problem(res.x[None])[0], rel=1e-9)
    np.testing.assert_array_equal(runs[0].x, runs[1].x)
    assert runs[0].fun == runs[1].fun and runs[0].nfev == runs[1].nfev


# --- population optimisers: black-box properties ------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_respects_the_bounds(name: str) -> None:
    optimizer = black_box(name)
    # the optimum lies far outside a narrow box: new points keep pushing through its faces
    box = Bounds(np.linspace(-1.0, 0.5, D), np.linspace(1.0, 2.0, D))
    rec = Recorder(lambda x: np.einsum("ij,ij->i", x - 10.0, x - 10.0))
    res = optimizer.minimize(rec, box, np.random.default_rng(1), Budget(max_evaluations=400))
    assert box.contains(rec.points)
    assert box.contains(res.x)


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_result(name: str) -> None:
    optimizer = black_box(name)
    a, b = (optimizer.minimize(sphere, BOX, np.random.default_rng(7)) for _ in range(2))
    np.testing.assert_array_equal(a.x, b.x)
    assert a.fun == b.fun and a.nfev == b.nfev and a.nit == b.nit
    np.testing.assert_array_equal(a.history_fun, b.history_fun)
    c = optimizer.minimize(sphere, BOX, np.random.default_rng(8))
    assert c.fun != a.fun  # the seed matters


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("evaluations", [1, 7, 31, 100, 1001])
def test_never_exceeds_the_evaluation_budget(name: str, evaluations: int) -> None:
    optimizer = black_box(name)
    rec = Recorder(sphere)
    res = optimizer.minimize(
        rec, BOX, np.random.default_rng(2), Budget(max_evaluations=evaluations)
    )
    assert res.nfev == rec.points.shape[0] <= evaluations
    assert np.all(res.history_nfev <= evaluations)
    assert res.nfev >= min(evaluations, optimizer.initial_evaluations())


@pytest.mark.parametrize("name", NAMES)
def test_default_budget_is_about_1300_evaluations(name: str) -> None:
    optimizer = black_box(name)
    res = optimizer.minimize(sphere, BOX, np.random.default_rng(3))
    assert 1200 <= res.nfev <= 1400


@pytest.mark.parametrize("name", NAMES)
def test_uses_the_warm_start(name: str) -> None:
    optimizer = black_box(name)
    rec = Recorder(sphere)
    # the warm start is the optimum: only an optimiser that evaluates it reaches cost 0
    res = optimizer.minimize(rec, BOX, np.random.default_rng(5), Budget(max_evaluations=60), CENTRE)
    assert res.fun == 0.0
    np.testing.assert_array_equal(res.x, CENTRE)
    assert np.any(np.all(rec.points == CENTRE, axis=1))


@pytest.mark.parametrize("name", NAMES)
def test_nan_and_inf_costs_rank_below_finite_ones(name: str) -> None:
    optimizer = black_box(name)

    def nasty(x: np.ndarray) -> np.ndarray:
        f = sphere(x)
        f[x[:, 0] > 0.0] = np.nan
        f[x[:, 1] > 0.0] = np.inf
        f[x[:, 2] > 0.0] = -np.inf  # a "too good" value is not trusted either
        return f

    res = optimizer.minimize(nasty, BOX, np.random.default_rng(6))
    assert math.isfinite(res.fun)
    assert np.all(res.x[:3] <= 0.0)
    assert res.fun == pytest.approx(sphere(res.x[None])[0])
    # no NaN is ever the best so far; +inf only until the first finite cost (a small first
    # step from a start among the bad points, cma-es-warm's, may need a few generations)
    history = res.history_fun
    assert not np.any(np.isnan(history)) and np.all(history[1:] <= history[:-1])
    first_finite = int(np.argmax(np.isfinite(history)))
    assert np.all(np.isfinite(history[first_finite:])) and first_finite <= len(history) // 2
    everything_nan = optimizer.minimize(
        lambda x: np.full(x.shape[0], np.nan),
        BOX,
        np.random.default_rng(6),
        Budget(max_iterations=3),
    )
    assert everything_nan.fun == math.inf


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.slow
def test_beats_random_search_of_the_same_budget_on_a_10d_sphere(name: str) -> None:
    if name == "random-search":
        pytest.skip("random-search is the floor itself (tests/test_random_search.py)")
    optimizer = black_box(name)
    ours, random_search = [], []
    for seed in range(5):
        res = optimizer.minimize(sphere, BOX, np.random.default_rng(seed))
        ours.append(res.fun)
        random_search.append(sphere(BOX.sample(np.random.default_rng(100 + seed), res.nfev)).min())
    # every run beats every random search (of ~1300 points, ending near 20 here)
    assert max(ours) < min(random_search)
    assert np.median(ours) < np.median(random_search) / 4
