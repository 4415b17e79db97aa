"""Differential evolution: a generation by hand with fixed random numbers; agreement with scipy.

Immediate updating against scipy, and by hand, is in ``test_de_reference.py``.
"""

from __future__ import annotations

import ast
import inspect
import itertools
import math
import textwrap

import numpy as np
import pytest
from scipy.optimize import differential_evolution
from scipy.stats import mannwhitneyu

from formation_bench.fields import describe_fields, kernel_field_names
from formation_bench.instances.library import shipped
from formation_bench.optimizers import Bounds, Budget, DifferentialEvolution, get_optimizer
from formation_bench.optimizers.base import EvaluationCounter
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.de_ops import (
    PARTNER_UNIFORMS,
    PER_SOLVE,
    DEConfig,
    DESettings,
    DEStrategy,
    DEUpdating,
    de_block,
    de_generation,
    distinct_partners,
    immediate_trial,
    make_trial,
    make_trials,
    select_trials,
    uniforms_per_generation,
)
from formation_bench.optimizers.population import WarmStartInit

RAND, TO_BEST = int(DEStrategy.RAND_1_BIN), int(DEStrategy.CURRENT_TO_BEST_1_BIN)
WIDE = 100.0


def partners_by_hand(i: int, n: int, u: list[float]) -> list[int]:
    """The k-th partner: the floor(u_k * free)-th of the indices not yet taken, in order."""
    taken = [i]
    for value in u:
        free = [k for k in range(n) if k not in taken]
        taken.append(free[math.floor(value * len(free))])
    return taken[1:]


def trials_by_hand(x, best, strategy, F, CR, u):
    n, d = x.shape
    block = PARTNER_UNIFORMS + 1 + d
    out = x.copy()
    for i in range(n):
        ui = u[i * block : (i + 1) * block]
        j_rand = math.floor(ui[3] * d)
        if strategy == RAND:
            a, b, c = partners_by_hand(i, n, list(ui[:3]))
            mutant = x[a] + F * (x[b] - x[c])
        else:
            a, b = partners_by_hand(i, n, list(ui[:2]))
            mutant = x[i] + F * (x[best] - x[i]) + F * (x[a] - x[b])
        for j in range(d):
            if j == j_rand or ui[4 + j] < CR:
                out[i, j] = mutant[j]
    return out


def trials(x, u, strategy=RAND, F=0.5, CR=0.9, best=0, mode=BoundHandling.CLIP, box=WIDE):
    d = x.shape[1]
    return make_trials(x, best, strategy, F, CR, int(mode), np.full(d, -box), np.full(d, box), u)


def test_partners_cover_every_ordered_choice_once_and_never_the_member() -> None:
    n, i = 6, 2
    seen = []
    for a, b, c in itertools.product(range(5), range(4), range(3)):
        u = np.array([(a + 0.5) / 5, (b + 0.5) / 4, (c + 0.5) / 3])
        out = np.empty(3, dtype=np.int64)
        distinct_partners(i, n, u, out)
        assert list(out) == partners_by_hand(i, n, list(u))
        seen.append(tuple(out))
    others = [k for k in range(n) if k != i]
    assert sorted(seen) == sorted(itertools.permutations(others, 3))
    edge = np.empty(3, dtype=np.int64)
    distinct_partners(5, n, np.array([1.0 - 1e-17, 1.0, 1.0]), edge)  # u = 1 stays in range
    assert sorted(edge) == [2, 3, 4]


@pytest.mark.parametrize("strategy", [RAND, TO_BEST])
@pytest.mark.parametrize("CR", [0.0, 0.5, 1.0])
def test_trials_are_mutation_and_binomial_crossover_by_hand(strategy: int, CR: float) -> None:
    rng = np.random.default_rng(11)
    n, d = 7, 5
    x = rng.normal(size=(n, d))
    u = rng.random(uniforms_per_generation(n, d, resample=False))
    got = trials(x, u, strategy, 0.7, CR, best=4)
    np.testing.assert_allclose(got, trials_by_hand(x, 4, strategy, 0.7, CR, u), rtol=1e-13)
    changed = (got != x).sum(axis=1)
    if CR == 0.0:  # only j_rand comes from the mutant
        assert np.all(changed == 1)
    if CR == 1.0:
        assert np.all(changed == d)
    np.testing.assert_array_equal(x, x.copy())  # the input is not modified


def test_current_to_best_moves_towards_the_best_member_passed() -> None:
    # every member but the best is at 0: a trial whose partners are not the best is exactly
    # F x_best, whichever member is passed as the best
    n, d = 8, 3
    x = np.zeros((n, d))
    x[3] = [1.0, 2.0, -4.0]
    u = np.random.default_rng(0).random(uniforms_per_generation(n, d, resample=False))
    got = trials(x, u, TO_BEST, 0.5, 1.0, best=3)
    block = PARTNER_UNIFORMS + 1 + d
    checked = 0
    for i in (0, 1, 2, 4, 5, 6, 7):
        if 3 not in partners_by_hand(i, n, list(u[i * block : i * block + 2])):
            np.testing.assert_allclose(got[i], 0.5 * x[3])
            checked += 1
    assert checked >= 3
    np.testing.assert_array_equal(trials(x, u, TO_BEST, 0.5, 1.0, best=0)[0], 0.0)


@pytest.mark.parametrize("mode", list(BoundHandling))
def test_only_coordinates_outside_the_box_are_repaired(mode: BoundHandling) -> None:
    n, d = 4, 2
    # member 0's mutant from partners 1, 2, 3 is x1 + 0.5 (x2 - x3) = (3, 0.5): first outside
    x = np.array([[0.0, 0.0], [1.0, 0.5], [5.0, 0.0], [1.0, 0.0]])
    u = np.zeros(uniforms_per_generation(n, d, resample=True))
    u[n * (4 + d) :] = 0.25  # the re-draws
    got = trials(x, u, RAND, 0.5, 1.0, mode=mode, box=2.0)
    expected_first = {
        BoundHandling.CLIP: 2.0,
        BoundHandling.REFLECT: 1.0,
        BoundHandling.RESAMPLE: -2.0 + 0.25 * 4.0,
    }[mode]
    assert got[0, 0] == pytest.approx(expected_first)
    assert got[0, 1] == 0.5
    assert np.all(np.abs(got) <= 2.0)


def test_selection_prefers_the_trial_on_ties_and_never_a_nan() -> None:
    x = np.arange(8.0).reshape(4, 2)
    f = np.array([1.0, 2.0, 3.0, np.inf])
    t = -x
    tf = np.array([1.0, 2.5, np.inf, 7.0])
    new_x, new_f = select_trials(x, f, t, tf)
    np.testing.assert_array_equal(new_f, [1.0, 2.0, 3.0, 7.0])
    np.testing.assert_array_equal(new_x, [t[0], x[1], x[2], t[3]])
    # a generation the budget cut short: only the evaluated trials compete
    cut_x, cut_f = select_trials(x, f, t[:1], np.array([0.0]))
    np.testing.assert_array_equal(cut_f, [0.0, 2.0, 3.0, np.inf])
    np.testing.assert_array_equal(cut_x[1:], x[1:])


def test_a_generation_selects_first_then_mutates_around_the_new_best() -> None:
    n, d = 5, 2
    config = DifferentialEvolution(strategy=DEStrategy.CURRENT_TO_BEST_1_BIN)
    box = Bounds(np.full(d, -WIDE), np.full(d, WIDE))
    x = np.random.default_rng(3).normal(size=(n, d))
    f = np.arange(n, dtype=float)
    winner = np.array([[9.0, 9.0]])
    u = np.random.default_rng(4).random(config.uniforms_per_step(n, d))
    x1, f1, t1 = de_generation(x, f, winner, np.array([-1.0]), u, config.de_settings(box))
    np.testing.assert_array_equal(x1[0], winner[0])
    assert f1[0] == -1.0
    np.testing.assert_allclose(t1, trials_by_hand(x1, 0, TO_BEST, 0.5, 0.9, u), rtol=1e-13)


def test_configuration_and_registered_variants() -> None:
    assert get_optimizer("de") == DifferentialEvolution()
    assert get_optimizer("de").bound_handling is BoundHandling.RESAMPLE
    assert get_optimizer("de").updating is DEUpdating.DEFERRED
    assert get_optimizer("de").warm_start_share == 0.0
    assert get_optimizer("de-immediate") == DifferentialEvolution(updating="immediate")
    warm = get_optimizer("de-immediate-warm")
    assert isinstance(warm, WarmStartInit) and warm.warm_start_share > 0.0
    assert warm == DifferentialEvolution(
        updating=warm.updating,
        warm_start_share=warm.warm_start_share,
        warm_start_spread=warm.warm_start_spread,
    )
    names = [f.name for f in describe_fields(DifferentialEvolution)]
    assert names[-3:] == ["updating", "warm_start_share", "warm_start_spread"]
    with pytest.raises(ValueError, match="updating"):
        DifferentialEvolution(updating="sometimes")
    with pytest.raises(ValueError, match="warm_start_share"):
        get_optimizer("de", warm_start_share=1.5)
    assert get_optimizer("de-current-to-best").strategy is DEStrategy.CURRENT_TO_BEST_1_BIN
    assert DifferentialEvolution(strategy="current-to-best-1-bin") == get_optimizer(
        "de-current-to-best"
    )
    with pytest.raises(ValueError, match="population_size"):
        DifferentialEvolution(population_size=3)
    with pytest.raises(ValueError, match="differential_weight"):
        DifferentialEvolution(differential_weight=0.0)
    with pytest.raises(ValueError, match="crossover_rate"):
        DifferentialEvolution(crossover_rate=1.5)


def test_the_kernels_read_exactly_their_declared_settings_by_name() -> None:
    declared = set(kernel_field_names(DEConfig)) | set(PER_SOLVE)
    assert declared == set(DESettings._fields)
    read = set()
    for kernel in (de_generation, immediate_trial, de_block):
        tree = ast.parse(textwrap.dedent(inspect.getsource(kernel.py_func)))
        read |= {
            node.attr
            for node in ast.walk(tree)
            if isinstance(node, ast.Attribute) and getattr(node.value, "id", None) == "s"
        }
        handed_on = [
            (kw.arg, kw.value.attr)
            for call in ast.walk(tree)
            if isinstance(call, ast.Call)
            for kw in call.keywords
            if isinstance(kw.value, ast.Attribute)
        ]
        assert all(arg == attr for arg, attr in handed_on), kernel
    assert read == declared


def test_random_numbers_per_generation_follow_the_layout() -> None:
    class Spy:
        def __init__(self) -> None:
            self.rows = 0

        def __call__(self, x: np.ndarray) -> np.ndarray:
            self.rows += x.shape[0]
            return np.einsum("ij,ij->i", x, x)

    box = Bounds(np.full(3, -1.0), np.full(3, 1.0))
    for mode, per_member in ((BoundHandling.CLIP, 4 + 3), (BoundHandling.RESAMPLE, 4 + 3 + 3)):
        config = DifferentialEvolution(population_size=6, bound_handling=mode)
        assert config.uniforms_per_step(6, 3) == 6 * per_member
        spy = Spy()
        res = config.minimize(spy, box, np.random.default_rng(0), Budget(max_evaluations=40))
        # 6 initial members, then 5 generations of 6 and one cut to 4 trials
        assert (res.nfev, res.nit, spy.rows) == (40, 6, 40)


@pytest.mark.parametrize("strategy", [RAND, TO_BEST])
@pytest.mark.parametrize("mode", list(BoundHandling))
def test_a_single_trial_is_the_row_of_a_generation_of_trials(strategy, mode) -> None:
    """Immediate updating makes the trials one at a time from the same numbers as a deferred
    generation: on the same population each is that generation's row, to the bit."""
    rng = np.random.default_rng(5)
    n, d = 6, 4
    x = rng.uniform(-1.0, 1.0, size=(n, d))
    u = rng.random(uniforms_per_generation(n, d, resample=True))
    lower, upper = np.full(d, -1.0), np.full(d, 1.0)
    args = (strategy, 0.9, 0.8, int(mode), lower, upper, u)
    every = make_trials(x, 2, *args)
    unbounded = make_trials(x, 2, strategy, 0.9, 0.8, int(mode), 10 * lower, 10 * upper, u)
    assert np.any(np.abs(unbounded) > 1.0)  # the bound handling has work to do
    for i in range(n):
        np.testing.assert_array_equal(make_trial(x, i, 2, *args), every[i : i + 1])


def test_immediate_updating_evaluates_one_trial_at_a_time_within_the_budget() -> None:
    class Spy:
        def __init__(self) -> None:
            self.calls: list[int] = []

        def __call__(self, x: np.ndarray) -> np.ndarray:
            self.calls.append(x.shape[0])
            return np.einsum("ij,ij->i", x, x)

    box = Bounds(np.full(3, -1.0), np.full(3, 1.0))
    rngs = []
    for updating in DEUpdating:
        config = DifferentialEvolution(population_size=6, updating=updating)
        spy = Spy()
        rng = np.random.default_rng(0)
        res = config.minimize(spy, box, rng, Budget(max_evaluations=40))
        # 6 initial members, then 5 generations of 6 trials and one cut to 4
        assert (res.nfev, res.nit, sum(spy.calls)) == (40, 6, 40)
        assert res.history_nfev.tolist() == [6, 12, 18, 24, 30, 36, 40]
        if updating is DEUpdating.IMMEDIATE:
            assert spy.calls == [6] + [1] * 34
        else:
            assert spy.calls == [6] * 6 + [4]
        rngs.append(rng)
    # the same numbers drawn in either mode
    assert rngs[0].bit_generator.state == rngs[1].bit_generator.state


class PlainCallable:
    """A problem without its compiled handle: solved by the Python loop."""

    def __init__(self, objective) -> None:
        self.objective = objective

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.objective(x)


IMMEDIATE_AND_WARM = [
    DifferentialEvolution(updating=DEUpdating.IMMEDIATE, strategy=DEStrategy.CURRENT_TO_BEST_1_BIN),
    DifferentialEvolution(updating=DEUpdating.IMMEDIATE, bound_handling=BoundHandling.CLIP),
    DifferentialEvolution(
        updating=DEUpdating.IMMEDIATE, bound_handling=BoundHandling.REFLECT, population_size=7
    ),
    DifferentialEvolution(warm_start_share=0.25, warm_start_spread=0.1),
    DifferentialEvolution(
        updating=DEUpdating.IMMEDIATE, warm_start_share=1.0, strategy="current-to-best-1-bin"
    ),
]


@pytest.mark.parametrize("optimizer", IMMEDIATE_AND_WARM, ids=repr)
def test_compiled_and_python_solves_agree_for_immediate_and_warm_configurations(optimizer):
    instance = shipped()[3]
    problem, bounds = instance.problem, instance.problem.bounds
    budgets = [None, Budget(max_evaluations=1001), Budget(max_evaluations=31), Budget(3)]
    for k, budget in enumerate(budgets):
        x0 = instance.warm_start if k != 2 else None
        python_rng, compiled_rng = np.random.default_rng(k), np.random.default_rng(k)
        python = optimizer.minimize(PlainCallable(problem), bounds, python_rng, budget, x0)
        compiled = optimizer.minimize(problem, bounds, compiled_rng, budget, x0)
        assert math.isnan(compiled.info["objective_time_s"])
        assert np.array_equal(python.x, compiled.x) and python.fun == compiled.fun, budget
        assert (python.nfev, python.nit, python.message) == (
            compiled.nfev, compiled.nit, compiled.message,
        )  # fmt: skip
        assert np.array_equal(python.history_fun, compiled.history_fun)
        assert np.array_equal(python.history_nfev, compiled.history_nfev)
        assert python_rng.random() == compiled_rng.random()


def test_the_warm_start_settings_shape_the_initial_population() -> None:
    box = Bounds(np.full(4, -10.0), np.full(4, 10.0))
    x0 = np.full(4, 3.0)

    def population(config: DifferentialEvolution, x0: np.ndarray | None) -> np.ndarray:
        counter = EvaluationCounter(lambda x: (x * x).sum(axis=1), 4, None)
        return config.init(counter, box, np.random.default_rng(1), x0, 10).x

    uniform = population(DifferentialEvolution(), x0)
    warm = population(DifferentialEvolution(warm_start_share=0.5, warm_start_spread=0.01), x0)
    assert np.array_equal(uniform[0], x0) and np.array_equal(warm[0], x0)
    # rows 1-15 around the warm start (0.01 of the range 20 is 0.2), the rest uniform as before
    assert np.all(np.abs(warm[1:16] - x0) < 1.5)
    np.testing.assert_array_equal(warm[16:], uniform[16:])
    # without a warm start there is nothing to start around
    np.testing.assert_array_equal(
        population(DifferentialEvolution(warm_start_share=0.5), None),
        population(DifferentialEvolution(), None),
    )


# --- agreement with scipy.optimize.differential_evolution ----------------------------------------

D = 10
BOX = Bounds(np.full(D, -5.0), np.full(D, 5.0))
SHIFT = np.linspace(-3.0, 2.0, D)
AXIS_SCALES = 10.0 ** (6.0 * np.arange(D) / (D - 1))
EVALUATIONS = 3000  # N = 30: the initial population and 99 generations
SEEDS = 15


def sphere(x: np.ndarray) -> np.ndarray:
    z = x - SHIFT
    return (z * z).sum(axis=-1)


def ellipsoid(x: np.ndarray) -> np.ndarray:
    z = x - SHIFT
    return (AXIS_SCALES * z * z).sum(axis=-1)


def rosenbrock(x: np.ndarray) -> np.ndarray:
    return (100.0 * (x[..., 1:] - x[..., :-1] ** 2) ** 2 + (1.0 - x[..., :-1]) ** 2).sum(axis=-1)


SCIPY_STRATEGY = {DEStrategy.RAND_1_BIN: "rand1bin", DEStrategy.CURRENT_TO_BEST_1_BIN:
                  "currenttobest1bin"}  # fmt: skip


def scipy_finals(function, strategy: DEStrategy) -> list[float]:
    """scipy's DE with our settings: N = 30, F = 0.5, CR = 0.9, uniform start, resampling bounds,
    all trials of a generation from one population (``updating='deferred'``), no polishing and no
    early stop (tol = atol = 0), the same number of evaluations."""
    finals = []
    for seed in range(SEEDS):
        rows = [0]

        def counted(x: np.ndarray, rows=rows) -> np.ndarray:
            rows[0] += x.shape[1]
            return function(x.T)

        res = differential_evolution(
            counted, list(zip(BOX.lower, BOX.upper, strict=True)),
            strategy=SCIPY_STRATEGY[strategy], maxiter=EVALUATIONS // 30 - 1, popsize=3,
            mutation=0.5, recombination=0.9, init="random", updating="deferred",
            vectorized=True, polish=False, tol=0.0, atol=0.0, rng=1000 + seed,
        )  # fmt: skip
        assert rows[0] == EVALUATIONS
        finals.append(float(res.fun))
    return finals


def our_finals(function, **overrides) -> list[float]:
    optimizer = DifferentialEvolution(**overrides)
    budget = Budget(max_evaluations=EVALUATIONS)
    runs = [
        optimizer.minimize(function, BOX, np.random.default_rng(s), budget) for s in range(SEEDS)
    ]
    assert all(r.nfev == EVALUATIONS for r in runs)
    return [r.fun for r in runs]


@pytest.mark.parametrize("strategy", list(DEStrategy), ids=lambda s: s.name.lower())
def test_same_quality_as_scipy_with_the_same_settings_and_budget(strategy: DEStrategy) -> None:
    """Two-sided Mann-Whitney U on the final costs of 15 seeds each, per function."""
    for function in (sphere, ellipsoid, rosenbrock):
        ours = our_finals(function, strategy=strategy)
        theirs = scipy_finals(function, strategy)
        p = mannwhitneyu(ours, theirs).pvalue
        assert p > 0.01, (function.__name__, np.median(ours), np.median(theirs), p)


def test_the_comparison_tells_another_differential_weight_apart() -> None:
    """The same comparison with F = 0.6 on our side rejects equality: the test has power."""
    ours = our_finals(sphere, differential_weight=0.6)
    theirs = scipy_finals(sphere, DEStrategy.RAND_1_BIN)
    assert mannwhitneyu(ours, theirs).pvalue < 0.001
