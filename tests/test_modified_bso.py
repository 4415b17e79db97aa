"""ModifiedBSO end to end, and the pure BSO operators driven with fixed random numbers."""

from __future__ import annotations

import itertools
import math
from collections import namedtuple

import numba as nb
import numpy as np
import pytest
from helpers import BOX, D, Recorder, sphere

from formation_bench.optimizers import (
    OPTIMIZERS,
    Bounds,
    Budget,
    EvaluationCounter,
    ModifiedBSO,
    OptimizeResult,
    get_optimizer,
    register,
)
from formation_bench.optimizers import bso_ops as ops
from formation_bench.optimizers.bso_ops import BoundHandling
from formation_bench.optimizers.chaos import ChaoticMap, chaotic_sequence
from formation_bench.optimizers.clustering import ClusteringBackend
from formation_bench.optimizers.compiled import COST_SIGNATURE, CompiledObjective
from formation_bench.optimizers.population import initial_population

RASTRIGIN_BOX = Bounds(np.full(D, -5.12), np.full(D, 5.12))
SHIFT = np.linspace(-2.0, 2.0, D)
VARIANTS = [
    "modified-bso",
    "modified-bso-no-chaos-replacement",
    "modified-bso-no-all-centre",
    "modified-bso-no-modifications",
    "modified-bso-raw-weights",
]


def shifted_rastrigin(x: np.ndarray) -> np.ndarray:
    z = x - SHIFT
    return 10.0 * z.shape[1] + (z * z - 10.0 * np.cos(2.0 * np.pi * z)).sum(axis=1)


@nb.cfunc(COST_SIGNATURE, cache=True)
def compiled_shifted_sphere(x_ptr, n, d, data_ptr, out_ptr):  # type: ignore[no-untyped-def]
    x = nb.carray(x_ptr, (n, d))
    shift = nb.carray(data_ptr, (d,))
    out = nb.carray(out_ptr, (n,))
    for i in range(n):
        out[i] = 0.0
        for c in range(d):
            out[i] += (x[i, c] - shift[c]) ** 2


class CompiledSphere:
    """The shifted sphere with a compiled handle (its Python call gives the same costs)."""

    def __init__(self, shift: np.ndarray) -> None:
        data = np.ascontiguousarray(shift, dtype=np.float64)
        self.compiled = CompiledObjective(
            compiled_shifted_sphere.address, data, compiled_shifted_sphere
        )

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.compiled(x)


def random_search(f, bounds: Bounds, evaluations: int, seed: int) -> float:
    return float(f(bounds.sample(np.random.default_rng(seed), evaluations)).min())


def solve(opt: ModifiedBSO, f=sphere, seed: int = 0, **kw) -> OptimizeResult:
    return opt.minimize(f, kw.pop("bounds", BOX), np.random.default_rng(seed), **kw)


def same_result(a: OptimizeResult, b: OptimizeResult) -> bool:
    return (
        np.array_equal(a.x, b.x)
        and a.fun == b.fun
        and np.array_equal(a.history_nfev, b.history_nfev)
        and np.array_equal(a.history_fun, b.history_fun)
    )


# --- end to end --------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(3))
def test_converges_on_sphere_where_random_search_does_not(seed: int) -> None:
    res = solve(ModifiedBSO(), seed=seed)
    assert res.nit == 40 and res.success
    assert res.fun < 0.5
    assert random_search(sphere, BOX, res.nfev, seed) > 0.5
    assert np.all(np.diff(res.history_fun) <= 0)
    assert res.history_fun[-1] == res.fun


@pytest.mark.parametrize("seed", range(3))
def test_converges_on_shifted_rastrigin_better_than_random_search(seed: int) -> None:
    budget = Budget(max_evaluations=3000)
    res = solve(ModifiedBSO(), shifted_rastrigin, seed, bounds=RASTRIGIN_BOX, budget=budget)
    rs = random_search(shifted_rastrigin, RASTRIGIN_BOX, 3000, seed)
    assert res.fun < 50.0 < rs
    assert shifted_rastrigin(res.x[None])[0] == pytest.approx(res.fun)


@pytest.mark.parametrize("name", VARIANTS)
@pytest.mark.parametrize(
    "handling", [BoundHandling.CLIP, BoundHandling.REFLECT, BoundHandling.RESAMPLE]
)
def test_never_leaves_the_bounds(name: str, handling: BoundHandling) -> None:
    # optimum far outside a narrow box: ideas keep pushing through its faces
    box = Bounds(np.linspace(-1.0, 0.5, D), np.linspace(1.0, 2.0, D))
    rec = Recorder(lambda x: sphere(x - 10.0))
    opt = get_optimizer(name, bound_handling=handling, max_iterations=15)
    res = opt.minimize(rec, box, np.random.default_rng(1))
    assert box.contains(rec.points)
    assert box.contains(res.x)


def test_same_seed_same_result_different_seed_different_result() -> None:
    a, b, c = (solve(ModifiedBSO(), seed=s) for s in (7, 7, 8))
    assert same_result(a, b)
    assert a.nfev == b.nfev and a.nit == b.nit
    assert not np.array_equal(a.x, c.x) and a.fun != c.fun


@pytest.mark.parametrize("evaluations", [1, 7, 29, 30, 31, 45, 61, 100, 333, 1001, 1234])
def test_evaluation_budget_is_met_exactly(evaluations: int) -> None:
    rec = Recorder()
    res = solve(ModifiedBSO(), rec, budget=Budget(max_evaluations=evaluations))
    assert res.nfev == evaluations == rec.points.shape[0]
    assert res.history_nfev[-1] == evaluations
    assert np.all(res.history_nfev <= evaluations)


@pytest.mark.parametrize(("evaluations", "iterations"), [(100, 50), (1000, 5), (95, 2), (2000, 1)])
def test_both_limits_never_exceeded(evaluations: int, iterations: int) -> None:
    rec = Recorder()
    budget = Budget(max_evaluations=evaluations, max_iterations=iterations)
    res = solve(ModifiedBSO(p_replace=0.5), rec, budget=budget)
    assert res.nfev == rec.points.shape[0] <= evaluations
    assert res.nit <= iterations
    if res.nit < iterations:
        assert res.nfev == evaluations


def test_replacement_evaluations_are_counted() -> None:
    opt = ModifiedBSO(p_replace=1.0, n_replace=7)
    res = solve(opt, budget=Budget(max_iterations=5))
    assert res.nfev == 30 + 5 * (7 + 30)
    assert res.info["chaotic_replacements"] == 5
    assert solve(opt, budget=Budget(max_evaluations=100)).nfev == 100
    assert opt.evaluations_per_step() == 37
    assert ModifiedBSO(chaos_replacement=False).evaluations_per_step() == 30


def test_info_reports_objective_time_and_replacements() -> None:
    res = solve(ModifiedBSO())
    assert res.info["objective_time_s"] > 0.0
    assert type(res.info["chaotic_replacements"]) is int


def iterations_by_hand(optimizer, objective, iterations: int, seed: int, max_evaluations=None):
    """Drive ``optimizer``'s ask/tell kernels from the test, one iteration at a time: yields
    ``(state, counter, rounds)`` after each, ``rounds`` the ``(candidates, last)`` asked."""
    counter = EvaluationCounter(objective, D, max_evaluations)
    rng = np.random.default_rng(seed)
    points, costs = initial_population(
        counter, BOX, rng, optimizer.population(), None, optimizer.initialisation()
    )
    params = optimizer.params(BOX, iterations)
    state = optimizer.start(points, costs, rng, params)
    plan = optimizer.draw_plan(*points.shape)
    ask, tell = optimizer.kernels.ask, optimizer.kernels.tell
    for iteration in range(1, iterations + 1):
        uniforms, normals = rng.random(plan.uniforms), rng.standard_normal(plan.normal_shape)
        rounds, last = [], False
        while not last:
            state, candidates, last = ask(
                state, params, uniforms, normals, iteration, counter.remaining
            )
            rounds.append((candidates, last))
            allowed = min(candidates.shape[0], counter.remaining)
            state = tell(state, params, candidates, counter(candidates[:allowed]), iteration)
        yield state, counter, rounds


@pytest.mark.parametrize("name", VARIANTS)
def test_after_each_iteration_costs_are_the_members_own_and_slots_improve(name: str) -> None:
    """Every member's cost is its own, and a slot only gets worse by a chaotic replacement."""
    optimizer = get_optimizer(name)
    runs = list(iterations_by_hand(optimizer, sphere, 10, seed=4))
    previous = None
    for state, _, _ in runs:
        np.testing.assert_array_equal(sphere(state.x), state.f)
        if previous is not None:
            assert np.sum(state.f > previous[0]) <= state.replacements - previous[1]
        previous = state.f.copy(), state.replacements
    state, counter, _ = runs[-1]
    if not optimizer.chaos_replacement:  # then the population keeps the best point found
        assert state.f.min() == counter.best_f
        np.testing.assert_array_equal(state.x[np.argmin(state.f)], counter.best_x)


def test_a_replacement_is_a_first_round_of_n_r_candidates() -> None:
    """With p_r = 1 every iteration asks for the n_r chaotic candidates (not last), then for
    the N ideas; with fewer than n_r evaluations left it asks for the ideas at once."""
    optimizer = ModifiedBSO(p_replace=1.0, n_replace=7, population_size=12, n_clusters=3)
    shapes = [
        [(c.shape, last) for c, last in rounds]
        for _, _, rounds in iterations_by_hand(optimizer, sphere, 3, seed=1)
    ]
    assert shapes == [[((7, D), False), ((12, D), True)]] * 3
    # 12 initial, then 7 + 12 = 31, then 5 left: fewer than n_r, the ideas come first
    runs = list(iterations_by_hand(optimizer, sphere, 2, seed=1, max_evaluations=36))
    assert [len(rounds) for _, _, rounds in runs] == [2, 1]
    assert runs[-1][0].replacements == 1 and runs[-1][1].nfev == 36


def test_nan_and_inf_costs_rank_below_finite_ones() -> None:
    def nasty(x: np.ndarray) -> np.ndarray:
        f = sphere(x - 1.0)
        f[x[:, 0] > 2.0] = np.nan
        f[x[:, 1] > 2.0] = np.inf
        f[x[:, 2] > 2.0] = -np.inf  # a "too good" value is not trusted either
        return f

    res = solve(ModifiedBSO(), nasty)
    assert math.isfinite(res.fun) and res.fun < 1.0
    assert np.all(res.x[:3] <= 2.0)
    assert np.all(np.isfinite(res.history_fun[1:]))


def test_all_nan_objective_does_not_crash() -> None:
    res = solve(ModifiedBSO(max_iterations=3), lambda x: np.full(x.shape[0], np.nan))
    assert res.fun == math.inf and res.nfev == 30 + 3 * 30 + res.info["chaotic_replacements"] * 10


def test_warm_start_is_evaluated_and_never_beaten_by_worse() -> None:
    x0 = np.full(D, 1e-3)
    rec = Recorder()
    res = solve(ModifiedBSO(), rec, x0=x0)
    np.testing.assert_array_equal(rec.batches[0][0], x0)
    assert res.fun <= sphere(x0[None])[0]
    only = solve(ModifiedBSO(), budget=Budget(max_evaluations=1), x0=x0)
    np.testing.assert_array_equal(only.x, x0)


@pytest.mark.parametrize("name", VARIANTS[1:])
def test_each_ablation_changes_the_result(name: str) -> None:
    base = solve(ModifiedBSO(), seed=3)
    other = get_optimizer(name).minimize(sphere, BOX, np.random.default_rng(3))
    assert not same_result(base, other)


@pytest.mark.parametrize(
    "change",
    [
        {"replacement_map": ChaoticMap.TENT},
        {"weight_map": ChaoticMap.TENT},
        {"n_weight_iterations": 0},
        {"step_relative_to_range": False},
        {"bound_handling": BoundHandling.REFLECT},
    ],
)
def test_other_settings_run_and_change_the_result(change: dict) -> None:
    def near_corner(x: np.ndarray) -> np.ndarray:  # ideas cross the bounds: handling matters
        return sphere(x - 4.8)

    # over a few seeds: one setting may by chance leave a short run unchanged
    changed = 0
    for seed in range(3):
        base = solve(ModifiedBSO(max_iterations=15), near_corner, seed=seed)
        other = solve(ModifiedBSO(max_iterations=15, **change), near_corner, seed=seed)
        changed += not same_result(base, other)
        assert other.fun < other.history_fun[0]
    assert changed > 0


def test_sklearn_backend_gives_the_same_run() -> None:
    compiled = solve(ModifiedBSO(max_iterations=6), seed=2)
    reference = solve(ModifiedBSO(max_iterations=6, clustering=ClusteringBackend.SKLEARN), seed=2)
    assert same_result(compiled, reference)


def test_sklearn_backend_solves_a_compiled_objective_through_python() -> None:
    """Its k-means runs in Python, so it takes the objective's Python call; same run."""
    objective = CompiledSphere(SHIFT)
    sklearn = ModifiedBSO(max_iterations=6, clustering=ClusteringBackend.SKLEARN)
    assert not sklearn.has_compiled_loop() and ModifiedBSO().has_compiled_loop()
    reference = solve(sklearn, objective, seed=3)
    compiled = solve(ModifiedBSO(max_iterations=6), objective, seed=3)
    assert same_result(compiled, reference)
    assert math.isnan(compiled.info["objective_time_s"])
    assert reference.info["objective_time_s"] > 0.0


# --- configuration and registry ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("population_size", 1),
        ("population_size", 2.5),
        ("population_size", True),
        ("n_clusters", 0),
        ("n_clusters", 31),
        ("max_iterations", -1),
        ("slope", 0.0),
        ("slope", math.inf),
        ("p_replace", 1.5),
        ("p_replace", -0.1),
        ("n_replace", 0),
        ("n_weight_iterations", -1),
        ("replacement_map", "henon"),
        ("weight_map", 42),
        ("normalise_weights", "yes"),
        ("step_scale", -1.0),
        ("step_relative_to_range", 1),
        ("bound_handling", "wrap"),
        ("clustering", "gpu"),
        ("kmeans_max_iter", 0),
        ("p_one_cluster", 2.0),
        ("p_one_centre", math.nan),
        ("p_two_centres", -1),
        ("chaos_replacement", None),
        ("all_centre_weighting", 0),
    ],
)
def test_invalid_config_names_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"ModifiedBSO\.{field} must"):
        ModifiedBSO(**{field: value})


def test_enum_fields_accept_their_names() -> None:
    opt = ModifiedBSO(
        replacement_map="tent",
        weight_map="LOGISTIC",
        bound_handling="reflect",
        clustering="sklearn",
    )
    assert opt.replacement_map is ChaoticMap.TENT
    assert opt.weight_map is ChaoticMap.LOGISTIC
    assert opt.bound_handling is BoundHandling.REFLECT
    assert opt.clustering is ClusteringBackend.SKLEARN
    via_registry = get_optimizer("modified-bso", replacement_map="tent", n_clusters=3)
    assert via_registry == ModifiedBSO(replacement_map=ChaoticMap.TENT, n_clusters=3)
    assert ModifiedBSO().default_budget == Budget(max_iterations=40)


def test_registry_entries_and_duplicate_names() -> None:
    for name in VARIANTS:
        assert isinstance(OPTIMIZERS[name].optimizer, ModifiedBSO)
        assert OPTIMIZERS[name].description
    assert not OPTIMIZERS["modified-bso-no-modifications"].optimizer.chaos_replacement
    assert not OPTIMIZERS["modified-bso-raw-weights"].optimizer.normalise_weights
    with pytest.raises(ValueError, match="already registered"):
        register("modified-bso", ModifiedBSO(), "duplicate")


# --- pure operators with fixed random numbers --------------------------------------------------


def test_distinct_indices_is_a_partial_shuffle() -> None:
    np.testing.assert_array_equal(ops.distinct_indices(np.zeros(3), 10), [0, 1, 2])
    # i = 0 swaps 0 and 9; i = 1 then draws slot 9, which now holds 0; and so on
    np.testing.assert_array_equal(ops.distinct_indices(np.full(3, 0.999), 10), [9, 0, 1])
    idx = ops.distinct_indices(np.random.default_rng(0).random(10), 10)
    assert sorted(idx) == list(range(10))


def test_cluster_centres_best_member_and_sizes() -> None:
    labels = np.array([0, 2, 0, 2, 2, 0], dtype=np.int64)
    costs = np.array([5.0, 1.0, 3.0, np.inf, 1.0, 3.0])
    centre, sizes = ops.cluster_centres(labels, costs, 4)
    np.testing.assert_array_equal(centre, [2, -1, 1, -1])  # ties -> lowest index
    np.testing.assert_array_equal(sizes, [3, 0, 3, 0])
    np.testing.assert_array_equal(ops.nonempty(centre), [0, 2])


def test_cluster_population_matches_its_parts() -> None:
    rng = np.random.default_rng(4)
    x, f, u = rng.random((30, 4)), rng.random(30), rng.random(5)
    labels, centre, sizes = ops.cluster_population(x, f, u, 100)
    from formation_bench.optimizers.clustering import lloyd_kmeans

    ref, _ = lloyd_kmeans(x, x[ops.distinct_indices(u, 30)])
    np.testing.assert_array_equal(labels, ref)
    np.testing.assert_array_equal(sizes, np.bincount(ref, minlength=5))
    for j in range(5):
        members = np.flatnonzero(ref == j)
        assert centre[j] == members[np.argmin(f[members])]


def test_normalised_weights_sum_to_one_and_stay_in_the_hull() -> None:
    seeds = np.random.default_rng(5).random((50, 3))
    w = ops.chaotic_weights(int(ChaoticMap.LOGISTIC), seeds, 10, True)
    raw = ops.chaotic_weights(int(ChaoticMap.LOGISTIC), seeds, 10, False)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(raw, chaotic_sequence(ChaoticMap.LOGISTIC, seeds, 10)[-1])
    assert np.all(raw > 0) and np.all(raw < 1) and np.any(np.abs(raw.sum(axis=1) - 1) > 0.1)
    np.testing.assert_allclose(w, raw / raw.sum(axis=1, keepdims=True))
    # centres at the corners of a triangle: normalised ideas inside it, raw ones not all
    centres = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    xh = ops.weighted_centres(w, centres)
    assert np.all(xh >= 0) and np.all(xh.sum(axis=1) <= 1 + 1e-12)
    np.testing.assert_allclose(xh, w @ centres)
    xr = ops.weighted_centres(raw, centres)
    assert np.any((xr < 0).any(axis=1) | (xr.sum(axis=1) > 1))
    assert np.all(ops.chaotic_weights(0, seeds, 0, False) == seeds)  # n_h = 0: the seeds


def test_all_centre_auxiliary_skips_empty_clusters() -> None:
    population = np.array([[0.0], [10.0], [20.0], [30.0]])
    centre_index = np.array([3, -1, 0], dtype=np.int64)
    seeds = np.array([[0.2, 0.9, 0.3]])  # column 1 belongs to the empty cluster
    aux = ops.all_centre_auxiliary(population, centre_index, seeds, 0, 0, True)
    np.testing.assert_allclose(aux, [[(0.2 * 30.0 + 0.3 * 0.0) / 0.5]])


def shi_case() -> tuple[np.ndarray, ...]:
    population = np.arange(6, dtype=np.float64)[:, None] * 10.0  # member i sits at 10 i
    labels = np.array([0, 0, 0, 1, 1, 2], dtype=np.int64)
    costs = np.array([3.0, 1.0, 2.0, 5.0, 4.0, 0.0])  # centres: 1, 4, 5
    centre, sizes = ops.cluster_centres(labels, costs, 3)
    return population, labels, centre, sizes


@pytest.mark.parametrize(
    ("u", "expected"),
    [
        # one cluster by size (sizes 3, 2, 1 of 6), its centre
        ([0.0, 0.0, 0.0, 0, 0, 0, 0], 10.0),
        ([0.5, 0.55, 0.3, 0, 0, 0, 0], 40.0),
        ([0.7, 0.99, 0.39, 0, 0, 0, 0], 50.0),
        # one cluster, a random member (k-th member in index order)
        ([0.1, 0.2, 0.5, 0.99, 0, 0, 0], 20.0),
        ([0.1, 0.6, 0.4, 0.0, 0, 0, 0], 30.0),
        # two clusters chosen uniformly among 3: a = floor(3 u1), b from the other two
        ([0.9, 0.0, 0.2, 0, 0.0, 0, 0.25], 0.25 * 10.0 + 0.75 * 40.0),
        ([0.9, 0.9, 0.2, 0, 0.0, 0, 1.0], 50.0),
        ([0.9, 0.5, 0.2, 0, 0.9, 0, 0.5], 0.5 * 40.0 + 0.5 * 50.0),
        # two clusters, random members
        ([0.8, 0.0, 0.5, 0.5, 0.6, 0.99, 0.5], 0.5 * 10.0 + 0.5 * 50.0),
    ],
)
def test_shi_selection_branches(u: list[float], expected: float) -> None:
    population, labels, centre, sizes = shi_case()
    clusters = ops.Clusters(labels, centre, sizes)
    out = ops.shi_select(population, clusters, np.array([u]), 0.8, 0.4, 0.5)
    assert out[0, 0] == pytest.approx(expected)


def test_shi_selection_with_one_nonempty_cluster_uses_one_cluster() -> None:
    population = np.arange(4, dtype=np.float64)[:, None]
    labels = np.zeros(4, dtype=np.int64)
    centre, sizes = ops.cluster_centres(labels, np.array([2.0, 1.0, 3.0, 4.0]), 2)
    u = np.array([[0.99, 0.5, 0.1, 0.0, 0.5, 0.5, 0.5], [0.99, 0.5, 0.9, 0.8, 0.5, 0.5, 0.5]])
    out = ops.shi_select(population, ops.Clusters(labels, centre, sizes), u, 0.0, 0.4, 0.5)
    np.testing.assert_array_equal(out[:, 0], [1.0, 3.0])


def test_logsig_schedule() -> None:
    assert ops.logsig_factor(20.0, 40.0, 20.0) == pytest.approx(0.5)
    assert ops.logsig_factor(0.0, 40.0, 20.0) == pytest.approx(1 / (1 + math.exp(-1.0)))
    assert ops.logsig_factor(40.0, 40.0, 20.0) == pytest.approx(1 / (1 + math.exp(1.0)))
    values = [ops.logsig_factor(t, 40.0, 20.0) for t in range(41)]
    assert all(a > b for a, b in itertools.pairwise(values))
    assert ops.logsig_factor(1.0, 40.0, 1.0) > 0.999  # steep slope: a step function


def test_perturb_is_equation_10() -> None:
    aux = np.array([[1.0, 2.0], [3.0, 4.0]])
    normals = np.array([[1.0, -1.0], [0.5, 2.0]])
    out = ops.perturb(aux, 0.5, np.array([0.2, 1.0]), normals, np.array([10.0, 1.0]))
    np.testing.assert_allclose(out, [[2.0, 1.9], [5.5, 5.0]])


def test_bound_handling_by_hand() -> None:
    lower, upper = np.zeros(6), np.ones(6)
    x = np.array([[0.3, 1.2, -0.3, 2.5, 3.7, -4.2]])
    u = np.full((1, 6), 0.25)
    clip = ops.apply_bounds(x, lower, upper, int(BoundHandling.CLIP), u)
    reflect = ops.apply_bounds(x, lower, upper, int(BoundHandling.REFLECT), u)
    resample = ops.apply_bounds(x, lower, upper, int(BoundHandling.RESAMPLE), u)
    np.testing.assert_allclose(clip, [[0.3, 1.0, 0.0, 1.0, 1.0, 0.0]])
    np.testing.assert_allclose(reflect, [[0.3, 0.8, 0.3, 0.5, 0.3, 0.2]])
    np.testing.assert_allclose(resample, [[0.3, 0.25, 0.25, 0.25, 0.25, 0.25]])
    np.testing.assert_array_equal(x, [[0.3, 1.2, -0.3, 2.5, 3.7, -4.2]])  # input untouched


@pytest.mark.parametrize("mode", list(BoundHandling))
def test_bound_handling_keeps_random_points_inside(mode: BoundHandling) -> None:
    rng = np.random.default_rng(6)
    lower, upper = np.array([-1.0, 1e6, -1e-3]), np.array([2.0, 1e6 + 1.0, 0.0])
    x = lower + (upper - lower) * rng.normal(0.5, 20.0, (1000, 3))
    y = ops.apply_bounds(x, lower, upper, int(mode), rng.random((1000, 3)))
    assert np.all(y >= lower) and np.all(y <= upper)
    inside = np.all((x >= lower) & (x <= upper), axis=1)
    np.testing.assert_array_equal(y[inside], x[inside])


def test_chaotic_candidates_are_equation_7() -> None:
    seed = np.array([0.1, 0.5, 0.9])
    lower, upper = np.array([-1.0, 0.0, 10.0]), np.array([1.0, 5.0, 20.0])
    cx = ops.chaotic_candidates(int(ChaoticMap.TENT), seed, 4, lower, upper)
    cr = chaotic_sequence(ChaoticMap.TENT, seed, 4)
    assert cx.shape == (4, 3)
    np.testing.assert_allclose(cx, lower + cr * (upper - lower))
    assert np.all(cx > lower) and np.all(cx < upper)


def test_replacement_installs_the_best_candidate_even_if_worse() -> None:
    x, f = np.zeros((3, 2)), np.array([0.0, 1.0, 2.0])
    cand = np.array([[5.0, 5.0], [7.0, 7.0], [6.0, 6.0]])
    x2, f2 = ops.install_best(x, f, 0, cand, np.array([9.0, 8.0, 8.0]))
    np.testing.assert_array_equal(x2[0], [7.0, 7.0])
    assert f2[0] == 8.0 and f[0] == 0.0 and np.all(x == 0.0)
    centre = np.array([4, -1, 2], dtype=np.int64)
    assert ops.random_centre(centre, 0.0) == 4 and ops.random_centre(centre, 0.99) == 2


def test_greedy_keeps_the_strictly_better() -> None:
    old_x, old_f = np.arange(8.0).reshape(4, 2), np.array([1.0, 1.0, np.inf, 1.0])
    new_x = -np.arange(6.0).reshape(3, 2)  # a truncated batch: slot 3 keeps its member
    x, f, improved = ops.greedy_select(old_x, old_f, new_x, np.array([0.5, 1.0, 7.0]))
    np.testing.assert_array_equal(f, [0.5, 1.0, 7.0, 1.0])  # a tie keeps the old member
    np.testing.assert_array_equal(x, [[-0.0, -1.0], [2.0, 3.0], [-4.0, -5.0], [6.0, 7.0]])
    assert improved == 2
    _, f_nan, n_nan = ops.greedy_select(old_x, old_f, new_x, np.array([np.nan, np.inf, np.nan]))
    assert n_nan == 0 and np.array_equal(f_nan, old_f)


def test_bso_draws_lay_out_one_row_of_uniforms() -> None:
    n, d, m, width = 4, 3, 2, 5
    for resample in (False, True):
        size = ops.uniforms_per_iteration(n, d, m, width, resample)
        u, normals = np.arange(size, dtype=np.float64), np.full((n, d), -1.0)
        draws = ops.bso_draws(u, normals, m, width)
        parts = [draws.kmeans, [draws.replace_draw], [draws.centre_draw], draws.point,
                 draws.sources.ravel(), draws.rand]  # fmt: skip
        if resample:
            parts.append(draws.resample.ravel())
        else:
            assert draws.resample is draws.normals or np.all(draws.resample == -1.0)
        np.testing.assert_array_equal(np.concatenate(parts), u)
        assert draws.sources.shape == (n, width) and draws.resample.shape == (n, d)


def test_move_ideas_is_equation_10_then_the_bounds() -> None:
    rng = np.random.default_rng(9)
    n, d = 12, 3
    # any namedtuple with these fields will do
    settings = namedtuple("Settings", "scale lower upper bound_handling")(
        np.full(d, 0.1), np.zeros(d), np.ones(d), int(BoundHandling.REFLECT)
    )
    u = rng.random(ops.uniforms_per_iteration(n, d, 3, 3, False))
    normals = rng.standard_normal((n, d)) * 20.0
    draws = ops.bso_draws(u, normals, 3, 3)
    aux = rng.random((n, d))
    ideas = ops.move_ideas(aux.copy(), 0.6, draws, settings)
    expected = ops.apply_bounds(
        ops.perturb(aux, 0.6, draws.rand, normals, settings.scale), settings.lower,
        settings.upper, int(BoundHandling.REFLECT), normals,
    )  # fmt: skip
    np.testing.assert_array_equal(ideas, expected)
    assert np.any(ops.perturb(aux, 0.6, draws.rand, normals, settings.scale) > 1.0)
