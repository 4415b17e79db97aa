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
from helpers import BOX, D, shifted_sphere
from scipy.optimize import differential_evolution
from scipy.stats import mannwhitneyu

from formation_bench.fields import describe_fields, kernel_field_names
from formation_bench.instances.library import shipped
from formation_bench.optimizers import Bounds, Budget, DifferentialEvolution, get_optimizer
from formation_bench.optimizers.base import EvaluationCounter
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.differential_evolution import (
    PARTNER_UNIFORMS,
    PER_SOLVE,
    DEConfig,
    DESettings,
    DEState,
    DEStrategy,
    DEUpdating,
    de_ask,
    de_tell,
    mutant_into,
    partners_of,
    redraws_of,
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


def uniforms_per_generation(n: int, d: int, resample: bool) -> int:
    mode = BoundHandling.RESAMPLE if resample else BoundHandling.CLIP
    return DifferentialEvolution(bound_handling=mode).uniforms_per_step(n, d)


def costs_with_best(n: int, best: int) -> np.ndarray:
    f = np.zeros(n)
    f[best] = -1.0
    return f


def config_and_params(strategy, F, CR, mode, box, updating=DEUpdating.DEFERRED):
    config = DifferentialEvolution(
        strategy=DEStrategy(strategy), differential_weight=F, crossover_rate=CR,
        bound_handling=mode, updating=updating,
    )  # fmt: skip
    return config, config.params(box, 1)


def trials(x, u, strategy=RAND, F=0.5, CR=0.9, best=0, mode=BoundHandling.CLIP, box=WIDE):
    """A deferred generation's trials (``de_ask``) on the population ``x`` whose best is
    ``best``."""
    n, d = x.shape
    bounds = Bounds(np.full(d, -box), np.full(d, box))
    _, params = config_and_params(strategy, F, CR, mode, bounds)
    state = DEState(x, costs_with_best(n, best), 0, 0, 0)
    _, got, last = de_ask(state, params, u, np.empty(0), 1, 10**9)
    assert last  # one round per deferred generation
    return got


def test_partners_cover_every_ordered_choice_once_and_never_the_member() -> None:
    n, i = 6, 2
    seen = []
    for a, b, c in itertools.product(range(5), range(4), range(3)):
        u = np.array([(a + 0.5) / 5, (b + 0.5) / 4, (c + 0.5) / 3])
        out = partners_of(i, n, u, 3)
        assert list(out) == partners_by_hand(i, n, list(u))
        assert partners_of(i, n, u, 2) == (*out[:2], -1)  # current-to-best/1 draws two
        seen.append(tuple(out))
    others = [k for k in range(n) if k != i]
    assert sorted(seen) == sorted(itertools.permutations(others, 3))
    edge = partners_of(5, n, np.array([1.0 - 1e-17, 1.0, 1.0]), 3)
    # u = 1 stays in range
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
    _, params = config_and_params(RAND, 0.5, 0.9, BoundHandling.CLIP, Bounds(-x[-1], x[-1]))
    state = DEState(x, f, 0, 0, 0)
    after = de_tell(state, params, t, tf, 1)
    np.testing.assert_array_equal(after.f, [1.0, 2.0, 3.0, 7.0])
    np.testing.assert_array_equal(after.x, [t[0], x[1], x[2], t[3]])
    np.testing.assert_array_equal(state.x, np.arange(8.0).reshape(4, 2))  # not modified
    # a generation the budget cut short: only the evaluated trials compete
    cut = de_tell(state, params, t, np.array([0.0]), 1)
    np.testing.assert_array_equal(cut.f, [0.0, 2.0, 3.0, np.inf])
    np.testing.assert_array_equal(cut.x[1:], x[1:])


def test_a_generation_selects_first_then_mutates_around_the_new_best() -> None:
    n, d = 5, 2
    config = DifferentialEvolution(strategy=DEStrategy.CURRENT_TO_BEST_1_BIN)
    box = Bounds(np.full(d, -WIDE), np.full(d, WIDE))
    x = np.random.default_rng(3).normal(size=(n, d))
    f = np.arange(n, dtype=float)
    winner = np.array([[9.0, 9.0]])
    u = np.random.default_rng(4).random(config.uniforms_per_step(n, d))
    params = config.params(box, 1)
    selected = de_tell(DEState(x, f, 0, 0, 0), params, winner, np.array([-1.0]), 1)
    np.testing.assert_array_equal(selected.x[0], winner[0])
    assert selected.f[0] == -1.0
    _, t1, _ = de_ask(selected, params, u, np.empty(0), 2, 10**9)
    np.testing.assert_allclose(t1, trials_by_hand(selected.x, 0, TO_BEST, 0.5, 0.9, u),
                               rtol=1e-13)  # fmt: skip


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
    for kernel in (de_ask, de_tell, mutant_into, redraws_of):
        tree = ast.parse(textwrap.dedent(inspect.getsource(kernel.py_func)))
        read |= {
            node.attr
            for node in ast.walk(tree)
            if isinstance(node, ast.Attribute) and getattr(node.value, "id", None) == "s"
        }
    assert read == declared


def test_no_kernel_takes_more_than_eight_positional_arguments() -> None:
    for kernel in (de_ask, de_tell, mutant_into, partners_of, redraws_of):
        assert len(inspect.signature(kernel.py_func).parameters) <= 8, kernel


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
    generation: on the same population and best member each is that generation's row, to the
    bit."""
    rng = np.random.default_rng(5)
    n, d = 6, 4
    x = rng.uniform(-1.0, 1.0, size=(n, d))
    f = costs_with_best(n, 2)
    u = rng.random(uniforms_per_generation(n, d, resample=True))
    box = Bounds(np.full(d, -1.0), np.full(d, 1.0))
    _, deferred = config_and_params(strategy, 0.9, 0.8, mode, box)
    _, immediate = config_and_params(strategy, 0.9, 0.8, mode, box, DEUpdating.IMMEDIATE)
    _, every, _ = de_ask(DEState(x, f, 0, 0, 0), deferred, u, np.empty(0), 1, 10**9)
    _, unbounded = config_and_params(strategy, 0.9, 0.8, mode, Bounds(-10 * box.upper,
                                                                       10 * box.upper))  # fmt: skip
    _, wide, _ = de_ask(DEState(x, f, 0, 0, 0), unbounded, u, np.empty(0), 1, 10**9)
    assert np.any(np.abs(wide) > 1.0)  # the bound handling has work to do
    state = DEState(x, f, 0, 0, 0)
    for i in range(n):
        state, trial, last = de_ask(state, immediate, u, np.empty(0), 1, 10**9)
        assert (state.member, state.best, last) == (i, 2, i == n - 1)
        np.testing.assert_array_equal(trial, every[i : i + 1])
    # the last evaluation left ends the generation
    assert de_ask(DEState(x, f, 0, 0, 0), immediate, u, np.empty(0), 1, 1)[2]


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

SHIFT = np.linspace(-3.0, 2.0, D)
AXIS_SCALES = 10.0 ** (6.0 * np.arange(D) / (D - 1))
EVALUATIONS = 3000  # N = 30: the initial population and 99 generations
SEEDS = 15


sphere = shifted_sphere(SHIFT)


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
