"""Compiled objectives and the two solve loops: the same result, to the bit.

Every population optimiser drives its one pair of ask/tell kernels from two loops: the compiled
one, when the objective has a compiled handle, and the Python one otherwise. Each is solved
twice from the same seed, once with the objective's compiled handle and once through a plain
Python callable (which has none): the best point, its cost, the counts, the history, the
message and the generator's state after the solve must all be equal. The evaluation rules
(budget, non-finite costs, ties) are checked on a hand-made compiled cost.
"""

from __future__ import annotations

import math
import pickle
import time
from typing import NamedTuple

import numba as nb
import numpy as np
import pytest
from helpers import configured_names
from test_cost_and_problem import random_problem

from formation_bench.mpc.scenario import PAPER
from formation_bench.optimizers import (
    CMAES,
    PSO,
    Bounds,
    Budget,
    PopulationOptimizer,
    RandomSearch,
    get_optimizer,
)
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.chaos import ChaoticMap
from formation_bench.optimizers.cma_es import Restarts
from formation_bench.optimizers.compiled import (
    COST_SIGNATURE,
    HAS_BEST,
    NFEV,
    CompiledObjective,
    compiled_of,
    evaluate,
    evaluate_prefix,
    new_tally,
)
from formation_bench.optimizers.population import ROWS_AHEAD
from formation_bench.optimizers.tallies import dressed, plain


def _shifted_sphere(x_ptr, n, d, data_ptr, out_ptr):  # type: ignore[no-untyped-def]
    """sum((x - data[:d])^2), except NaN where data[d] marks the row, -inf at data[d + 1]."""
    x = nb.carray(x_ptr, (n, d))
    data = nb.carray(data_ptr, (d + 2,))
    out = nb.carray(out_ptr, (n,))
    for i in range(n):
        s = 0.0
        for c in range(d):
            s += (x[i, c] - data[c]) ** 2
        out[i] = s
        if i == int(data[d]):
            out[i] = math.nan
        if i == int(data[d + 1]):
            out[i] = -math.inf


SPHERE = nb.cfunc(COST_SIGNATURE, cache=True)(_shifted_sphere)


def sphere(centre: np.ndarray, nan_row: int = -1, minus_inf_row: int = -1) -> CompiledObjective:
    data = np.concatenate([centre, [nan_row, minus_inf_row]]).astype(np.float64)
    return CompiledObjective(SPHERE.address, data, SPHERE)


class CompiledSphere:
    """A batch objective with a compiled handle (the Python call gives the same costs)."""

    def __init__(self, centre: np.ndarray) -> None:
        self.compiled = sphere(centre)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.compiled(x)


class PlainCallable:
    """The same objective without its handle: solved by the Python loop."""

    def __init__(self, objective) -> None:
        self.objective = objective

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.objective(x)


def compiled_loop_optimizers() -> list[str]:
    return [
        name
        for name in configured_names()
        if isinstance(get_optimizer(name), PopulationOptimizer)
        and get_optimizer(name).has_compiled_loop()
    ]


def test_local_problem_handle_gives_the_problem_costs_to_the_bit():
    rng = np.random.default_rng(3)
    for n_blocks, substeps in [(4, 1), (20, 1), (3, 3)]:
        scenario = PAPER.with_overrides(n_blocks=n_blocks, rk4_substeps=substeps)
        problem = random_problem(rng, scenario)
        assert compiled_of(problem) is problem.compiled
        decisions = problem.bounds.sample(rng, 23)
        assert np.array_equal(problem.compiled(decisions), problem(decisions))


def test_a_problem_with_its_handle_built_still_pickles():
    problem = random_problem(np.random.default_rng(8), PAPER)
    decisions = problem.bounds.sample(np.random.default_rng(9), 5)
    before = problem.compiled(decisions)
    copy = pickle.loads(pickle.dumps(problem))
    assert np.array_equal(copy.compiled(decisions), before)
    assert np.array_equal(copy(decisions), before)


def test_handle_refuses_a_null_address_and_bad_data():
    with pytest.raises(ValueError, match="address"):
        CompiledObjective(0, np.zeros(3))
    with pytest.raises(ValueError, match="data"):
        CompiledObjective(SPHERE.address, np.zeros((2, 2)))
    with pytest.raises(ValueError, match="data"):
        CompiledObjective(SPHERE.address, np.zeros(3, dtype=np.float32))
    assert compiled_of(lambda x: x.sum(axis=1)) is None


def test_evaluate_maps_non_finite_costs_and_keeps_the_first_best():
    objective = sphere(np.zeros(2), nan_row=1, minus_inf_row=2)
    points = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.5, 0.0], [0.5, 0.0]])
    counts, best = new_tally(2, max_evaluations=None)
    costs = evaluate(objective.address, objective.data, points, 5, counts, best)
    assert costs.tolist() == [1.0, math.inf, math.inf, 0.25, 0.25]
    assert counts[NFEV] == 5 and counts[HAS_BEST] == 1
    assert best[0] == 0.25 and best[1:].tolist() == [0.5, 0.0]  # the first of the tie, row 3


def test_evaluate_prefix_stops_at_the_budget():
    objective = sphere(np.zeros(2))
    points = np.arange(10.0).reshape(5, 2)
    counts, best = new_tally(2, max_evaluations=3)
    costs = evaluate_prefix(objective.address, objective.data, points, counts, best)
    assert counts[NFEV] == 3
    assert costs[:3].tolist() == [1.0, 13.0, 41.0] and np.all(np.isinf(costs[3:]))
    again = evaluate_prefix(objective.address, objective.data, points, counts, best)
    assert counts[NFEV] == 3 and np.all(np.isinf(again))


def test_an_all_infinite_first_batch_still_holds_a_best_point():
    objective = sphere(np.zeros(2), nan_row=0)
    counts, best = new_tally(2, max_evaluations=None)
    evaluate(objective.address, objective.data, np.ones((1, 2)), 1, counts, best)
    assert counts[HAS_BEST] == 1 and best[0] == math.inf and best[1:].tolist() == [1.0, 1.0]


def test_the_paper_optimiser_has_a_compiled_loop():
    assert "modified-bso" in compiled_loop_optimizers()


def test_pso_and_random_search_have_a_compiled_loop():
    names = set(compiled_loop_optimizers())
    pso_names = {n for n in configured_names() if isinstance(get_optimizer(n), PSO)}
    assert {"pso", "pso-constriction", "chaotic-pso"} <= pso_names <= names
    assert "random-search" in names


BUDGETS = [
    None,
    Budget(max_evaluations=1200),
    Budget(max_evaluations=777),
    Budget(max_iterations=3),
    Budget(max_evaluations=3000, max_iterations=70),
    Budget(max_evaluations=31),
    Budget(max_evaluations=5),
]


def same_result(a, b) -> bool:
    return (
        np.array_equal(a.x, b.x)
        and a.fun == b.fun
        and a.nfev == b.nfev
        and a.nit == b.nit
        and a.message == b.message
        and a.success == b.success
        and np.array_equal(a.history_nfev, b.history_nfev)
        and np.array_equal(a.history_fun, b.history_fun)
        and {k: v for k, v in a.info.items() if k != "objective_time_s"}
        == {k: v for k, v in b.info.items() if k != "objective_time_s"}
    )


@pytest.mark.parametrize("name", compiled_loop_optimizers())
def test_compiled_loop_gives_the_python_loop_result_on_the_paper_problem(name):
    optimizer = get_optimizer(name)
    rng = np.random.default_rng(11)
    problem = random_problem(rng, PAPER)
    warm_start = problem.bounds.sample(rng, 1)[0]
    for k, budget in enumerate(BUDGETS):
        x0 = warm_start if k % 2 == 0 else None
        python_rng, compiled_rng = np.random.default_rng(k), np.random.default_rng(k)
        python = optimizer.minimize(PlainCallable(problem), problem.bounds, python_rng, budget, x0)
        compiled = optimizer.minimize(problem, problem.bounds, compiled_rng, budget, x0)
        assert math.isnan(compiled.info["objective_time_s"])
        assert not math.isnan(python.info["objective_time_s"])
        assert same_result(python, compiled), (name, budget)
        # the generator is left where the Python loop leaves it: the next solve draws the same
        assert python_rng.random() == compiled_rng.random()


@pytest.mark.parametrize("name", compiled_loop_optimizers())
def test_compiled_loop_gives_the_python_loop_result_on_a_sphere(name):
    optimizer = get_optimizer(name)
    bounds = Bounds(-np.ones(6), 2 * np.ones(6))
    objective = CompiledSphere(np.full(6, 0.3))
    for seed, budget in enumerate([None, Budget(max_evaluations=500)]):
        python = optimizer.minimize(
            PlainCallable(objective), bounds, np.random.default_rng(seed), budget
        )
        compiled = optimizer.minimize(objective, bounds, np.random.default_rng(seed), budget)
        assert same_result(python, compiled), (name, budget)


@pytest.mark.parametrize("restarts", list(Restarts), ids=lambda r: r.name.lower())
@pytest.mark.parametrize(
    ("bound_handling", "lamarckian"),
    [(BoundHandling.REFLECT, False), (BoundHandling.RESAMPLE, True)],
    ids=["reflect", "resample-lamarckian"],
)
def test_cma_es_restarts_in_the_compiled_loop_give_the_python_loop_result(
    restarts, bound_handling, lamarckian
):
    # a loose TolFun stops runs on the sphere after some dozens of generations, so a solve
    # restarts several times, at varying rows of the drawn blocks; the optimum near the faces
    # makes the bound handling (and RESAMPLE's uniforms) matter
    optimizer = CMAES(
        restarts=restarts, tol_fun=1e-2, bound_handling=bound_handling, lamarckian=lamarckian
    )
    bounds = Bounds(-5 * np.ones(6), 5 * np.ones(6))
    objective = CompiledSphere(np.linspace(-4.9, 4.9, 6))
    budgets = [
        Budget(max_evaluations=4000),
        Budget(max_evaluations=3000, max_iterations=170),
        Budget(max_iterations=250),
    ]
    stops = []
    for seed, budget in enumerate(budgets):
        x0 = np.zeros(6) if seed % 2 == 0 else None
        python_rng, compiled_rng = np.random.default_rng(seed), np.random.default_rng(seed)
        python = optimizer.minimize(PlainCallable(objective), bounds, python_rng, budget, x0)
        compiled = optimizer.minimize(objective, bounds, compiled_rng, budget, x0)
        assert math.isnan(compiled.info["objective_time_s"])
        assert same_result(python, compiled), budget
        assert python_rng.random() == compiled_rng.random()
        stops += compiled.info["stops"]
    assert len(stops) >= 3  # the restarts this test is about did happen
    if restarts is Restarts.BIPOP and bound_handling is BoundHandling.REFLECT:
        assert "runbudget" in stops  # a small run stopped by its allowance


@pytest.mark.parametrize("name", compiled_loop_optimizers())
def test_a_generous_deadline_changes_nothing_in_the_compiled_loop(name):
    # under a deadline the clock is read inside the compiled block, before every iteration:
    # the result and the draws must still be the Python loop's
    optimizer = get_optimizer(name)
    problem = random_problem(np.random.default_rng(5), PAPER)
    for budget in [Budget(max_evaluations=1500), Budget(max_iterations=70)]:
        generous = Budget(budget.max_evaluations, budget.max_iterations, deadline_s=60.0)
        rngs = [np.random.default_rng(2) for _ in range(3)]
        plain = optimizer.minimize(problem, problem.bounds, rngs[0], budget)
        timed = optimizer.minimize(problem, problem.bounds, rngs[1], generous)
        python = optimizer.minimize(PlainCallable(problem), problem.bounds, rngs[2], generous)
        assert math.isnan(timed.info["objective_time_s"])
        assert same_result(plain, timed) and same_result(python, timed), (name, budget)
        assert rngs[0].random() == rngs[1].random() == rngs[2].random()


@pytest.mark.parametrize("name", ["modified-bso", "pso", "de", "cma-es", "random-search"])
def test_a_compiled_solve_stops_at_its_deadline_with_its_best_point(name):
    optimizer = get_optimizer(name)
    problem = random_problem(np.random.default_rng(6), PAPER)
    optimizer.minimize(problem, problem.bounds, np.random.default_rng(0), Budget(3))  # loaded
    budget = Budget(max_iterations=10_000_000, deadline_s=0.005)
    start = time.perf_counter()
    result = optimizer.minimize(problem, problem.bounds, np.random.default_rng(0), budget)
    elapsed = time.perf_counter() - start
    assert result.message == "deadline reached"
    assert 1 <= result.nit < 10_000_000 and result.nfev == result.history_nfev[-1]
    assert elapsed < 0.005 + 0.05  # checked before every iteration: at most one overruns
    assert result.fun == result.history_fun[-1] == problem(result.x[None])[0]


def same_state(a, b) -> bool:
    """Equal bit-generator states (nested dicts of numbers and arrays)."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same_state(a[k], b[k]) for k in a)
    return bool(np.array_equal(a, b))


BIT_GENERATORS = [np.random.PCG64, np.random.PCG64DXSM, np.random.Philox, np.random.SFC64,
                  np.random.MT19937]  # fmt: skip


@pytest.mark.parametrize("bit_generator", BIT_GENERATORS, ids=lambda g: g.__name__)
def test_one_uniform_draw_is_the_separate_draws_one_after_the_other(bit_generator):
    """What :func:`~formation_bench.optimizers.ask_tell.per_batch_draws` relies on:
    ``random(a)``, ``random(b)``, ... give the numbers of one ``random(a + b + ...)`` in order
    and leave the Generator in the same state; an empty draw (of any shape, uniform or normal)
    leaves it unchanged."""
    sizes = [7, 0, 60, 1, 33, 120]
    separate, joined = (np.random.Generator(bit_generator(42)) for _ in range(2))
    parts = [separate.random(k) for k in sizes]
    parts.append(separate.random((3, 5)).reshape(-1))
    whole = joined.random(sum(sizes) + 15)
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    assert same_state(separate.bit_generator.state, joined.bit_generator.state)
    state = joined.bit_generator.state
    assert joined.random((4, 0)).shape == (4, 0)
    assert joined.standard_normal((4, 0)).shape == (4, 0)
    assert same_state(joined.bit_generator.state, state)
    assert separate.random() == joined.random()


# configurations the registered variants miss: every bound handling (RESAMPLE draws per
# iteration too), chaotic coefficients with and without those draws (an iteration may draw
# nothing), other maps, a population that does not divide the budget
EXTRA_CONFIGURATIONS = [
    PSO(bound_handling=BoundHandling.RESAMPLE),
    PSO(bound_handling=BoundHandling.REFLECT, velocity_clamp=1.5, c1=3.0),
    PSO(chaotic_coefficients=True, bound_handling=BoundHandling.RESAMPLE, velocity_clamp=1.0),
    PSO(
        chaotic_coefficients=True,
        coefficient_map=ChaoticMap.TENT,
        chaotic_inertia=True,
        inertia_map=ChaoticMap.SINE,
        population_size=7,
    ),
    RandomSearch(population_size=7),
    RandomSearch(population_size=1),
]
LONG_BUDGETS = [
    Budget(max_evaluations=2 * 30 * ROWS_AHEAD + 101),  # blocks of 64, then the rest
    Budget(max_iterations=ROWS_AHEAD + 5),
    Budget(max_evaluations=1000, max_iterations=ROWS_AHEAD + 2),
    Budget(max_iterations=1),  # the fewest a budget allows
    Budget(max_evaluations=30),
]


@pytest.mark.parametrize("optimizer", EXTRA_CONFIGURATIONS, ids=repr)
def test_other_configurations_give_the_python_loop_result(optimizer):
    rng = np.random.default_rng(23)
    problem = random_problem(rng, PAPER)
    warm_start = problem.bounds.sample(rng, 1)[0]
    for k, budget in enumerate(BUDGETS + LONG_BUDGETS):
        x0 = warm_start if k % 2 == 1 else None
        python_rng, compiled_rng = np.random.default_rng(k), np.random.default_rng(k)
        python = optimizer.minimize(PlainCallable(problem), problem.bounds, python_rng, budget, x0)
        compiled = optimizer.minimize(problem, problem.bounds, compiled_rng, budget, x0)
        assert math.isnan(compiled.info["objective_time_s"])
        assert same_result(python, compiled), (optimizer, budget)
        assert python_rng.random() == compiled_rng.random()


@pytest.mark.parametrize("name", ["pso", "chaotic-pso", "random-search"])
def test_long_solves_give_the_python_loop_result(name):
    optimizer = get_optimizer(name)
    problem = random_problem(np.random.default_rng(31), PAPER)
    for k, budget in enumerate(LONG_BUDGETS):
        python_rng, compiled_rng = np.random.default_rng(k), np.random.default_rng(k)
        python = optimizer.minimize(PlainCallable(problem), problem.bounds, python_rng, budget)
        compiled = optimizer.minimize(problem, problem.bounds, compiled_rng, budget)
        assert same_result(python, compiled), (name, budget)
        assert python_rng.random() == compiled_rng.random()


def test_one_generator_through_consecutive_solves_stays_in_step():
    """A UAV's Generator serves all its solves: each one must leave it where Python does."""
    problem = random_problem(np.random.default_rng(2), PAPER)
    budgets = [
        Budget(max_evaluations=95),
        None,
        Budget(max_evaluations=31),
        Budget(max_iterations=2),
    ]
    python_rng, compiled_rng = np.random.default_rng(8), np.random.default_rng(8)
    for name in ["chaotic-pso", "random-search", "pso", "modified-bso"] * 2:
        for budget in budgets:
            optimizer = get_optimizer(name)
            python = optimizer.minimize(PlainCallable(problem), problem.bounds, python_rng, budget)
            compiled = optimizer.minimize(problem, problem.bounds, compiled_rng, budget)
            assert same_result(python, compiled), (name, budget)
    assert same_state(python_rng.bit_generator.state, compiled_rng.bit_generator.state)


class Inner(NamedTuple):
    values: np.ndarray
    count: int


class Outer(NamedTuple):
    inner: Inner
    scale: float
    pair: tuple


@nb.njit
def _returned_plain(value):  # type: ignore[no-untyped-def]
    return plain(value)


def test_a_compiled_state_crosses_back_to_python_as_plain_tuples_and_is_dressed_again():
    """numba boxes a named tuple through an unchecked Python call, where a Ctrl-C crashed the
    process: a block returns plain tuples, and Python gives them their classes back."""
    value = Outer(Inner(np.arange(3.0), 2), 1.5, (1, 2.0))
    returned = _returned_plain(value)
    assert type(returned) is tuple and type(returned[0]) is tuple
    twin = plain(value)  # the Python twin gives the same shape
    assert type(twin) is tuple and type(twin[0]) is tuple and twin[1:] == returned[1:]
    again = dressed(returned, value)
    assert type(again) is Outer and type(again.inner) is Inner and type(again.pair) is tuple
    np.testing.assert_array_equal(again.inner.values, value.inner.values)
    assert (again.inner.count, again.scale, again.pair) == (2, 1.5, (1, 2.0))
    # a real block: CMA-ES's nested state comes back with every class
    optimizer = get_optimizer("cma-es")
    result = optimizer.minimize(
        lambda x: (x**2).sum(axis=1), Bounds(-np.ones(4), np.ones(4)), np.random.default_rng(0),
        Budget(max_evaluations=200),
    )  # fmt: skip
    assert result.info["population_size"] == 8 and math.isfinite(result.info["sigma"])
