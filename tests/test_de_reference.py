"""de-immediate against scipy's ``differential_evolution`` with ``updating='immediate'``.

scipy's default updating makes trial ``i`` from the population as trials ``0 .. i-1`` left it,
evaluates it alone and selects it at once, and moves its best member as soon as a trial beats
it. ``de-immediate`` is meant to be that DE: DE/rand/1/bin, N = 30 (scipy's ``popsize=3`` in
10-D), F = 0.5, CR = 0.9, out-of-box coordinates re-drawn uniformly, no polishing, no early stop
(``tol = atol = 0``), the same evaluations. Both sides start from the same population (ours,
passed to scipy as its ``init`` array) and draw their own numbers after it, so each problem
gives a pair of final costs; the two-sided Wilcoxon signed-rank test on the pairs must not
reject equality (p > 0.05). The seeds are fixed, so the p-values are too.

A unit test drives the immediate rule with fixed random numbers on a four-member population and
checks it against values worked out by hand.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
import pytest
from helpers import BOX, D, shifted_sphere
from scipy.optimize import differential_evolution
from scipy.stats import wilcoxon

from formation_bench.instances.library import Instance, shipped
from formation_bench.optimizers import Bounds, Budget, DifferentialEvolution, get_optimizer
from formation_bench.optimizers.base import EvaluationCounter
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.compiled import COST_SIGNATURE, new_tally
from formation_bench.optimizers.differential_evolution import DEState, DEStrategy, DEUpdating
from formation_bench.optimizers.population import starting_points
from formation_bench.optimizers.tallies import Block, Draws, dressed, iterate_python

# --- the immediate rule by hand --------------------------------------------------------------

N4, D2 = 4, 2
BLOCK = 3 + 1 + D2  # partner uniforms, j_rand, crossover draws
START = np.array([[2.0, 0.0], [0.0, 2.0], [1.0, 1.0], [3.0, 3.0]])


def hand_uniforms() -> np.ndarray:
    """Partner draws 0 (the first free indices in order) except member 0's second, 0.5, which
    picks the second free index: member 0's partners are (1, 3), the others' the two lowest
    other indices. CR = 1 takes every coordinate from the mutant. The re-draws are 0.9 except
    member 1's first coordinate, 0.25."""
    u = np.zeros(HAND.uniforms_per_step(N4, D2))
    u[1] = 0.5
    for i in range(N4):
        u[i * BLOCK + 4 : (i + 1) * BLOCK] = 0.5
    u[N4 * BLOCK :] = 0.9
    u[N4 * BLOCK + 1 * D2 + 0] = 0.25
    return u


def squares(x: np.ndarray) -> np.ndarray:
    return (x * x).sum(axis=1)


# the box [-0.25, 4.75] x [-10, 10] holds the population; member 1's mutant leaves it
HAND_BOX = Bounds(np.array([-0.25, -10.0]), np.array([4.75, 10.0]))
HAND = DifferentialEvolution(
    population_size=N4, strategy=DEStrategy.CURRENT_TO_BEST_1_BIN, crossover_rate=1.0,
    updating=DEUpdating.IMMEDIATE,
)  # fmt: skip
# Worked by hand, F = 0.5, v = x_i + F (x_best - x_i + x_a - x_b); costs |x|^2 = 4, 4, 2, 18,
# so the best is member 2 at first.
#   i = 0, partners (1, 3): v = (2,0) + 0.5 ((-1,1) + (-3,-1)) = (0, 0), cost 0 <= 4: taken,
#          and below the best's 2: member 0 is the best from here on.
#   i = 1, partners (0, 2), best 0: v = (0,2) + 0.5 ((0,-2) + (-1,-1)) = (-0.5, 0.5); -0.5 is
#          below -0.25, re-drawn as -0.25 + 0.25 * 5 = 1: (1, 0.5), cost 1.25 <= 4: taken.
#          (Deferred, from the old population and best 2, it would have been (1, 1).)
#   i = 2, partners (0, 1): v = (1,1) + 0.5 ((-1,-1) + (-1,-0.5)) = (0, 0.25), cost 0.0625.
#   i = 3, partners (0, 1): v = (3,3) + 0.5 ((-3,-3) + (-1,-0.5)) = (1, 1.25), cost 2.5625.
HAND_TRIALS = [[0.0, 0.0], [1.0, 0.5], [0.0, 0.25], [1.0, 1.25]]
HAND_COSTS = [0.0, 1.25, 0.0625, 2.5625]


def hand_state() -> DEState:
    return DEState(START.copy(), squares(START), 0, 0, 0)


def python_generation(
    config: DifferentialEvolution, state: DEState, box: Bounds, u: np.ndarray, counter
) -> DEState:
    """One generation on the uniforms ``u``, in the Python loop of the kernels."""
    draws = Draws(u[None, :], np.empty((1, 0)), np.empty(1, dtype=np.int64), np.empty(1))
    after, done = iterate_python(config.kernels, state, config.params(box, 1), counter, draws, 0)
    assert done == 1
    return after


@nb.cfunc(COST_SIGNATURE, cache=True)
def _compiled_squares(x_ptr, n, d, data_ptr, out_ptr):  # type: ignore[no-untyped-def]
    x = nb.carray(x_ptr, (n, d))
    out = nb.carray(out_ptr, (n,))
    for i in range(n):
        s = 0.0
        for c in range(d):
            s += x[i, c] * x[i, c]
        out[i] = s


def test_the_immediate_rule_by_hand_in_both_paths() -> None:
    calls = []

    def spy(x: np.ndarray) -> np.ndarray:
        calls.append(x.copy())
        return squares(x)

    state = hand_state()
    counter = EvaluationCounter(spy, D2, None)
    after = python_generation(HAND, state, HAND_BOX, hand_uniforms(), counter)
    # one call per trial, each made from the population the earlier trials left
    assert [c.tolist() for c in calls] == [[t] for t in HAND_TRIALS]
    np.testing.assert_array_equal(after.x, HAND_TRIALS)
    np.testing.assert_array_equal(after.f, HAND_COSTS)
    np.testing.assert_array_equal(state.x, START)  # the state passed in is untouched
    assert (counter.nfev, counter.best_f) == (4, 0.0)

    counts, best = new_tally(D2, None)
    counts[2] = 1  # a best is held (the initial population's): the point of cost 2
    best[:] = [2.0, 1.0, 1.0]
    u = hand_uniforms()
    block = Block(_compiled_squares.address, np.zeros(1), counts, best, u[None, :],
                  np.empty((1, 0)), np.empty(1, dtype=np.int64), np.empty(1))  # fmt: skip
    returned, done = HAND.kernels.iterate(state, HAND.params(HAND_BOX, 1), block, 0, 1)
    compiled = dressed(returned, state)
    assert done == 1
    np.testing.assert_array_equal(compiled.x, HAND_TRIALS)
    np.testing.assert_array_equal(compiled.f, HAND_COSTS)
    assert counts[0] == 4 and best.tolist() == [0.0, 0.0, 0.0]


def test_the_budget_ends_an_immediate_generation_after_its_first_trials() -> None:
    calls = []

    def spy(x: np.ndarray) -> np.ndarray:
        calls.append(x.shape[0])
        return squares(x)

    counter = EvaluationCounter(spy, D2, 2)
    after = python_generation(HAND, hand_state(), HAND_BOX, hand_uniforms(), counter)
    assert calls == [1, 1]
    np.testing.assert_array_equal(after.x, [[0.0, 0.0], [1.0, 0.5], START[2], START[3]])
    np.testing.assert_array_equal(after.f, [0.0, 1.25, 2.0, 18.0])


def test_ties_go_to_the_trial_but_leave_the_best_where_it_was() -> None:
    # costs 4, 4, 2, 16: the best is member 2. Member 0's trial costs 2, as much as the best:
    # it replaces member 0 (Storn & Price's <=) but the best stays member 2, as scipy keeps its
    # best on a tie; member 1's current-to-best trial is then made around member 2
    x = np.array([[2.0, 0.0], [0.0, 2.0], [1.0, 1.0], [0.0, 4.0]])
    config = DifferentialEvolution(
        population_size=N4, strategy=DEStrategy.CURRENT_TO_BEST_1_BIN, crossover_rate=1.0,
        updating=DEUpdating.IMMEDIATE, differential_weight=1.0, bound_handling=BoundHandling.CLIP,
    )  # fmt: skip
    box = Bounds(np.full(2, -10.0), np.full(2, 10.0))
    u = np.zeros(config.uniforms_per_step(N4, D2))
    u[1] = 0.5  # member 0's partners (1, 3): v = x2 + (x1 - x3) = (1, -1), cost 2
    state = DEState(x, squares(x), 0, 0, 0)
    after = python_generation(config, state, box, u, EvaluationCounter(squares, 2, 2))
    assert after.best == 2
    # member 1, partners (0, 2), best 2: v = x2 + (x0 - x2) = x0 = (1, -1), cost 2 <= 4; with
    # member 0 as the best it would be (1, -3), cost 10, and rejected
    np.testing.assert_array_equal(after.x[:2], [[1.0, -1.0], [1.0, -1.0]])
    np.testing.assert_array_equal(after.f, [2.0, 2.0, 2.0, 16.0])


# --- against scipy ----------------------------------------------------------------------------

N = 30
# the unconstrained optimum lies outside the box in every other coordinate: the best point is
# on a face there
CENTRE = np.where(np.arange(D) % 2 == 0, np.linspace(5.5, 8.0, D), np.linspace(-3.0, 2.0, D))
AXIS_SCALES = 10.0 ** (6.0 * np.arange(D) / (D - 1))
GENERATIONS = 99  # 3000 evaluations
SEEDS = 30


sphere = shifted_sphere(CENTRE)


def ellipsoid(x: np.ndarray) -> np.ndarray:
    z = x - CENTRE
    return (AXIS_SCALES * z * z).sum(axis=-1)


def rosenbrock(x: np.ndarray) -> np.ndarray:
    z = x - CENTRE + 1.0  # the optimum, z = 1, at the centre
    return (100.0 * (z[..., 1:] - z[..., :-1] ** 2) ** 2 + (1.0 - z[..., :-1]) ** 2).sum(axis=-1)


def scipy_immediate(
    function, bounds: Bounds, population: np.ndarray, generations: int, seed: int
) -> float:
    """scipy's DE/rand/1/bin, immediate updating, from ``population``; its final cost."""
    evaluations = [0]

    def single(x: np.ndarray) -> float:
        evaluations[0] += 1
        return float(function(x[None, :])[0])

    result = differential_evolution(
        single, list(zip(bounds.lower, bounds.upper, strict=True)), strategy="rand1bin",
        maxiter=generations, popsize=3, mutation=0.5, recombination=0.9, init=population,
        updating="immediate", polish=False, tol=0.0, atol=0.0, rng=np.random.default_rng(seed),
    )  # fmt: skip
    assert evaluations[0] == N * (generations + 1)
    return float(result.fun)


def ours(
    name: str, function, bounds: Bounds, generations: int, seed: int, x0: np.ndarray | None
) -> tuple[float, np.ndarray]:
    """Our final cost, and the initial population the solve evaluated first."""
    first = []

    def recording(x: np.ndarray) -> np.ndarray:
        if not first:
            first.append(x.copy())
        return function(x)

    optimizer = get_optimizer(name)
    budget = Budget(max_iterations=generations)
    result = optimizer.minimize(recording, bounds, np.random.default_rng(seed), budget, x0)
    assert result.nfev == N * (generations + 1)
    return result.fun, first[0]


def paired(name: str, function) -> tuple[np.ndarray, np.ndarray]:
    mine, theirs = [], []
    for seed in range(SEEDS):
        cost, population = ours(name, function, BOX, GENERATIONS, seed, None)
        # our first batch is the population starting_points draws from the seed: scipy's init
        assert population.shape == (N, D)
        drawn = starting_points(BOX, np.random.default_rng(seed), N, None)
        np.testing.assert_array_equal(population, drawn)
        mine.append(cost)
        theirs.append(scipy_immediate(function, BOX, population, GENERATIONS, 1000 + seed))
    return np.array(mine), np.array(theirs)


@pytest.mark.slow
@pytest.mark.parametrize("function", [sphere, ellipsoid, rosenbrock], ids=lambda f: f.__name__)
def test_de_immediate_reaches_scipys_immediate_costs(function) -> None:
    mine, theirs = paired("de-immediate", function)
    p = wilcoxon(mine, theirs).pvalue
    assert p > 0.05, (np.median(mine), np.median(theirs), p)


@pytest.mark.slow
def test_the_comparison_tells_deferred_updating_apart() -> None:
    """The test has power: ``de`` (deferred) against scipy's immediate DE is rejected."""
    mine, theirs = paired("de", sphere)
    assert wilcoxon(mine, theirs).pvalue < 0.01, (np.median(mine), np.median(theirs))


def library_problems() -> list[Instance]:
    return shipped().instances("test")


@pytest.mark.slow
def test_de_immediate_reaches_scipys_immediate_gaps_on_the_library() -> None:
    optimizer = get_optimizer("de-immediate")
    generations = optimizer.default_budget.max_iterations
    mine, theirs = [], []
    for instance in library_problems():
        problem, bounds = instance.problem, instance.problem.bounds
        rng = np.random.default_rng(instance.index)
        population = starting_points(bounds, np.random.default_rng(instance.index), N,
                                     instance.warm_start, optimizer)  # fmt: skip
        result = optimizer.minimize(problem, bounds, rng, None, instance.warm_start)
        assert result.nfev == N * (generations + 1)
        mine.append(float(instance.gap(result.fun)))
        cost = scipy_immediate(problem, bounds, population, generations, 1000 + instance.index)
        theirs.append(float(instance.gap(cost)))
    mine_a, theirs_a = np.array(mine), np.array(theirs)
    assert np.all(np.isfinite(mine_a)) and np.all(np.isfinite(theirs_a))
    p = wilcoxon(mine_a, theirs_a).pvalue
    assert p > 0.05, (np.median(mine_a), np.median(theirs_a), p)
    assert math.isclose(np.median(mine_a), np.median(theirs_a), rel_tol=0.5)
