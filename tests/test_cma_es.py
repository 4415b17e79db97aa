"""CMA-ES: parameters, update and sampling by hand, the eigendecomposition, repair, restarts."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import BOX, CENTRE, D, Recorder, shifted_sphere

from formation_bench.optimizers import CMAES, Bounds, Budget, get_optimizer
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.cma_eigen import symmetric_eigen
from formation_bench.optimizers.cma_es import (
    CMABoundHandling,
    CMAConstants,
    Restarts,
    cma_ask,
    cma_tell,
)
from formation_bench.optimizers.cma_ops import (
    MAX_CONDITION,
    cma_parameters,
    default_population_size,
    injection_cap,
    owned,
    refresh,
)
from formation_bench.optimizers.cma_restarts import MAX_DOUBLINGS, CMAState, first_run, restart

sphere = shifted_sphere(CENTRE)


# --- driving the kernels by hand ----------------------------------------------------------------


def first_state(opt: CMAES, mean: float, bounds: Bounds = BOX) -> tuple[CMAState, tuple]:
    """``opt``'s first run centred on ``mean`` in every normalised coordinate, and its params."""
    state = first_run(opt, bounds.lower, bounds.width, bounds.lower + mean * bounds.width)
    return state, opt.params(bounds, 2**62)


def generation(state: CMAState, params: tuple, costs: np.ndarray, normals: np.ndarray) -> CMAState:
    """Tell the last samples' ``costs`` (none: nothing to learn), then ask with ``normals``
    (lambda x n): the update from the costs and the next samples, on a copy of ``state`` (the
    kernels advance a run in place)."""
    state = CMAState(owned(state.run), state.plan, state.campaign)
    if costs.shape[0] > 0:
        state = cma_tell(state, params, state.run.samples.points, costs, 1)
    state, _, _ = cma_ask(state, params, normals, normals, 1, 10**9)
    return state


def view(state: CMAState) -> SimpleNamespace:
    """The run's named parts in one namespace; ``rows`` are C's eigenvectors (B^T)."""
    run = state.run
    d, samples, progress = run.distribution, run.samples, run.progress
    return SimpleNamespace(**d._asdict(), **samples._asdict(), **progress._asdict(),
                           rows=d.eigenvectors)  # fmt: skip


def with_path_sigma(state: CMAState, path_sigma: np.ndarray) -> CMAState:
    """``state`` with its run's p_sigma replaced."""
    run = state.run
    distribution = run.distribution._replace(path_sigma=np.array(path_sigma, dtype=float))
    return state._replace(run=run._replace(distribution=distribution))


# --- parameters ---------------------------------------------------------------------------------


def test_default_population_size_is_4_plus_floor_3_ln_n() -> None:
    assert [default_population_size(n) for n in (1, 2, 3, 10, 20, 100)] == [4, 6, 7, 10, 12, 17]


@pytest.mark.parametrize(("n", "lam"), [(10, 10), (2, 6), (30, 14), (10, 41)])
def test_parameters_agree_with_pycma(n: int, lam: int) -> None:
    import cma  # the dev extra has it: a missing reference fails, not skips

    es = cma.CMAEvolutionStrategy(n * [0.0], 1.0, {"popsize": lam, "verbose": -9})
    ours = cma_parameters(n, lam)
    np.testing.assert_allclose(ours.weights, np.asarray(es.sp.weights), rtol=1e-12)
    assert ours.mu == es.sp.weights.mu
    assert ours.mueff == pytest.approx(es.sp.weights.mueff, rel=1e-12)
    assert ours.c_1 == pytest.approx(es.sp.c1, rel=1e-12)
    assert ours.c_mu == pytest.approx(es.sp.cmu, rel=1e-12)
    assert ours.c_c == pytest.approx(es.sp.cc, rel=1e-12)
    # pycma's CSA learning rate differs from the tutorial's Table 1 (n + mueff + 3, capped),
    # so the step-size parameters are checked against the table itself
    mueff = ours.mueff
    assert ours.c_sigma == pytest.approx((mueff + 2) / (n + mueff + 5), rel=1e-12)
    assert ours.d_sigma == pytest.approx(
        1 + 2 * max(0.0, math.sqrt((mueff - 1) / (n + 1)) - 1) + ours.c_sigma, rel=1e-12
    )


@pytest.mark.parametrize(("n", "lam"), [(10, None), (2, None), (30, 14), (10, 41), (5, 4), (40, 7)])
def test_pycma_constants_are_pycmas(n: int, lam: int | None) -> None:
    import cma

    # pycma samples mirrored pairs below lambda = 6 by default, which changes its d_sigma;
    # there are no mirrors here
    options = {"verbose": -9, "CMA_mirrors": 0}
    if lam is not None:
        options["popsize"] = lam
    es = cma.CMAEvolutionStrategy(n * [0.5], 0.2, options)
    ours = cma_parameters(n, es.sp.popsize, True, CMAConstants.PYCMA)
    assert es.sp.popsize == (lam or default_population_size(n))
    assert ours.c_sigma == pytest.approx(es.adapt_sigma.cs, rel=1e-12)
    assert ours.d_sigma == pytest.approx(es.adapt_sigma.damps, rel=1e-12)
    assert ours.c_c == pytest.approx(es.sp.cc, rel=1e-12)
    assert ours.c_1 == pytest.approx(es.sp.c1, rel=1e-12)
    assert ours.c_mu == pytest.approx(es.sp.cmu, rel=1e-12)
    sampler = es.sm.parameters(mueff=es.sp.weights.mueff, lam=es.sp.weights.lambda_)
    assert ours.c_1 == pytest.approx(sampler["c1"], rel=1e-12)  # the one its update uses
    np.testing.assert_allclose(ours.weights, np.asarray(es.sp.weights), rtol=1e-12)


def test_the_constants_differ_as_documented_at_n_10() -> None:
    tutorial = cma_parameters(10, 10, True, CMAConstants.TUTORIAL)
    pycma = cma_parameters(10, 10, True, CMAConstants.PYCMA)
    assert round(tutorial.c_sigma, 4) == 0.2844 and round(tutorial.d_sigma, 4) == 1.2844
    assert round(pycma.c_sigma, 4) == 0.3196 and round(pycma.d_sigma, 4) == 1.3196
    assert (tutorial.c_c, tutorial.c_1, tutorial.c_mu) == (pycma.c_c, pycma.c_1, pycma.c_mu)


def test_passive_weights_are_zero_after_mu_and_the_positive_ones_sum_to_one() -> None:
    active, passive = cma_parameters(10, 10, True), cma_parameters(10, 10, False)
    assert active.weights[:5].sum() == pytest.approx(1.0)
    assert np.all(active.weights[5:] < 0.0)
    np.testing.assert_array_equal(passive.weights[:5], active.weights[:5])
    assert np.all(passive.weights[5:] == 0.0)
    # the negative weights sum to -min(1 + c1/cmu, ...), here the first term
    assert active.weights[5:].sum() == pytest.approx(-(1.0 + active.c_1 / active.c_mu))
    assert active.history == 10 + 30 and injection_cap(10) == pytest.approx(math.sqrt(10) + 20 / 12)


# --- the eigensolver ----------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 3, 5, 10, 17, 30])
def test_symmetric_eigen_decomposes_random_symmetric_matrices(n: int) -> None:
    rng = np.random.default_rng(n)
    for _ in range(5):
        a = rng.standard_normal((n, n))
        a = (a + a.T) / 2.0
        values, rows = symmetric_eigen(a)
        np.testing.assert_allclose(rows @ rows.T, np.eye(n), atol=1e-13)
        np.testing.assert_allclose(rows.T @ np.diag(values) @ rows, a, atol=1e-12)
        np.testing.assert_allclose(np.sort(values), np.linalg.eigvalsh(a), atol=1e-12)


@pytest.mark.parametrize(
    "a",
    [
        np.eye(4),
        np.zeros((3, 3)),
        np.diag([1e-20, 1.0, 1e-3]),
        np.ones((4, 4)),
        np.array([[2.0, 1.0], [1.0, 2.0]]),
        np.diag([1.0, 1.0, 2.0, 2.0]) + 1e-9 * np.ones((4, 4)),
    ],
    ids=["identity", "zero", "wide-range", "rank-one", "2x2", "near-repeated"],
)
def test_symmetric_eigen_on_degenerate_matrices(a: np.ndarray) -> None:
    values, rows = symmetric_eigen(a)
    n = a.shape[0]
    np.testing.assert_allclose(rows @ rows.T, np.eye(n), atol=1e-13)
    np.testing.assert_allclose(rows.T @ np.diag(values) @ rows, a, atol=1e-13)
    np.testing.assert_allclose(np.sort(values), np.linalg.eigvalsh(a), atol=1e-13)


def test_a_covariance_not_finite_or_zero_keeps_the_eigensystem_and_stops_the_run() -> None:
    state, _ = first_state(CMAES(), 0.5)
    distribution = state.run.distribution
    kept = [a.copy() for a in (distribution.eigenvectors, distribution.axes, distribution.inv_sqrt)]
    for bad in (math.nan, math.inf, 0.0):
        cov = np.eye(D) * (bad if bad == 0.0 else 1.0)
        cov[0, 1] = cov[1, 0] = bad
        condition = refresh(distribution._replace(cov=cov), state.run.work)
        assert condition == math.inf and not condition <= MAX_CONDITION
        for before, now in zip(kept, (distribution.eigenvectors, distribution.axes,
                                      distribution.inv_sqrt), strict=True):  # fmt: skip
            np.testing.assert_array_equal(now, before)


def test_a_refreshed_eigensystem_is_that_of_c() -> None:
    state, _ = first_state(CMAES(), 0.5)
    a = np.random.default_rng(0).standard_normal((D, D + 3))
    cov = a @ a.T / D
    out = state.run.distribution._replace(cov=cov)
    condition = refresh(out, state.run.work)
    rows, axes = out.eigenvectors, out.axes
    np.testing.assert_allclose(rows.T @ np.diag(axes**2) @ rows, cov, atol=1e-12)
    np.testing.assert_allclose(out.inv_sqrt @ out.inv_sqrt @ cov, np.eye(D), atol=1e-9)
    values = np.linalg.eigvalsh(cov)
    assert condition == pytest.approx(values[-1] / values[0], rel=1e-9)


# --- one generation by hand ---------------------------------------------------------------------


def reference_update(
    view, costs: np.ndarray, weights: np.ndarray, params, n: int, pycma_h_sigma: bool = False
):
    """The tutorial's Fig. 6 written out with numpy, from a run's named arrays.

    With ``pycma_h_sigma`` h_sigma is pycma's test (``CMAAdaptSigmaBase.hsig``).
    """
    order = np.argsort(costs, kind="stable")
    y = view.steps[order]
    mu = params.mu
    y_w = weights[:mu] @ y[:mu]
    mean = view.mean + view.sigma * y_w
    ps = (1 - params.c_sigma) * view.path_sigma + math.sqrt(
        params.c_sigma * (2 - params.c_sigma) * params.mueff
    ) * (view.inv_sqrt @ y_w)
    g = view.generation
    h = (
        np.linalg.norm(ps) / math.sqrt(1 - (1 - params.c_sigma) ** (2 * (g + 1)))
        < (1.4 + 2 / (n + 1)) * params.chi_n
    )
    if pycma_h_sigma:  # pycma's countiter is g + 1 when it computes hsig
        squared_sum = np.sum(ps**2) / (1 - (1 - params.c_sigma) ** (2 * (g + 1)))
        h = squared_sum / n - 1 < 1 + 4.0 / (n + 1)
    pc = (1 - params.c_c) * view.path_c + h * math.sqrt(
        params.c_c * (2 - params.c_c) * params.mueff
    ) * y_w
    w_circ = weights.copy()
    for k in range(len(weights)):
        if weights[k] < 0:
            w_circ[k] *= n / np.linalg.norm(view.inv_sqrt @ y[k]) ** 2
    delta = (1 - h) * params.c_c * (2 - params.c_c)
    cov = (
        (1 + params.c_1 * delta - params.c_1 - params.c_mu * weights.sum()) * view.cov
        + params.c_1 * np.outer(pc, pc)
        + params.c_mu * (y.T * w_circ) @ y
    )
    sigma = view.sigma * math.exp(
        params.c_sigma / params.d_sigma * (np.linalg.norm(ps) / params.chi_n - 1)
    )
    return mean, ps, pc, cov, sigma


def evolved_run(
    rng: np.random.Generator,
    generations: int,
    active: bool = True,
    lamarckian: bool = False,
    constants: CMAConstants = CMAConstants.TUTORIAL,
):
    """A run after some generations on the sphere, so that C, paths and sigma are not trivial,
    its params and the last samples' costs."""
    lam = 10
    opt = CMAES(active=active, bound_handling=CMABoundHandling.CLIP, lamarckian=lamarckian,
                constants=constants)  # fmt: skip
    state, params = first_state(opt, 0.5)
    costs = np.empty(0)
    for _ in range(generations):
        state = generation(state, params, costs, rng.standard_normal((lam, D)))
        costs = sphere(state.run.samples.points)
    return state, params, costs


@pytest.mark.parametrize(("active", "stalled"), [(True, False), (False, False), (True, True)])
def test_one_update_is_the_tutorial_written_out(active: bool, stalled: bool) -> None:
    lam = 10
    params = cma_parameters(D, lam, active)
    state, settings, costs = evolved_run(np.random.default_rng(0), 7, active)
    if stalled:  # a long p_sigma: h_sigma = 0 stalls the rank-one path
        state = with_path_sigma(state, np.full(D, 3.0 * params.chi_n))
    before = view(state)
    assert before.generation == 6 and not np.allclose(before.cov, np.eye(D))
    normals = np.random.default_rng(1).standard_normal((lam, D))
    after = view(generation(state, settings, costs, normals))
    mean, ps, pc, cov, sigma = reference_update(before, costs, params.weights, params, D)
    np.testing.assert_allclose(after.mean, mean, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(after.path_sigma, ps, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(after.path_c, pc, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(after.cov, cov, rtol=1e-10, atol=1e-15)
    assert after.sigma == pytest.approx(sigma, rel=1e-12)
    assert after.generation == before.generation + 1
    assert after.history[0] == costs.min() and after.history[1] == before.history[0]


@pytest.mark.parametrize("stalled", [False, True])
def test_one_update_with_pycmas_constants_is_written_out_with_its_h_sigma(stalled: bool) -> None:
    lam = 10
    params = cma_parameters(D, lam, True, CMAConstants.PYCMA)
    state, settings, costs = evolved_run(np.random.default_rng(0), 7, constants=CMAConstants.PYCMA)
    if stalled:
        state = with_path_sigma(state, np.full(D, 3.0 * params.chi_n))
    before = view(state)
    normals = np.random.default_rng(1).standard_normal((lam, D))
    after = view(generation(state, settings, costs, normals))
    mean, ps, pc, cov, sigma = reference_update(before, costs, params.weights, params, D, True)
    np.testing.assert_allclose(after.mean, mean, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(after.path_sigma, ps, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(after.path_c, pc, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(after.cov, cov, rtol=1e-10, atol=1e-15)
    assert after.sigma == pytest.approx(sigma, rel=1e-12)
    stalled_path = (1 - params.c_c) * before.path_c
    assert np.allclose(after.path_c, stalled_path, rtol=1e-12) == stalled


def test_the_two_h_sigma_tests_disagree_between_their_thresholds() -> None:
    """A p_sigma of squared length 23.7 n / 10 passes the tutorial's test, not pycma's."""
    lam = 10
    outcomes = []
    for constants in CMAConstants:
        params = cma_parameters(D, lam, True, constants)
        state, settings, costs = evolved_run(np.random.default_rng(0), 40, constants=constants)
        normals = np.random.default_rng(1).standard_normal((lam, D))
        # choose the old path so that the new one has the length wanted: the new path is
        # (1 - c_sigma) old + the (known) contribution of this generation's mean shift
        probe = with_path_sigma(state, np.zeros(D))
        shift = view(generation(probe, settings, costs, normals)).path_sigma
        direction = np.ones(D) / math.sqrt(D)
        target = math.sqrt(23.7) * direction
        state = with_path_sigma(state, (target - shift) / (1 - params.c_sigma))
        after = view(generation(state, settings, costs, normals))
        assert np.sum(after.path_sigma**2) == pytest.approx(23.7, rel=1e-9)
        outcomes.append(np.allclose(after.path_c, (1 - params.c_c) * view(state).path_c))
    assert outcomes == [False, True]  # tutorial: < 23.80, no stall; pycma: >= 23.64, stall


def test_samples_are_the_mean_plus_sigma_b_d_z_mapped_to_the_box() -> None:
    lam = 10
    state, settings, costs = evolved_run(np.random.default_rng(2), 5)
    normals = np.random.default_rng(3).standard_normal((lam, D)) * 0.01  # stay inside
    out = view(generation(state, settings, costs, normals))
    steps = (out.rows.T @ (out.axes[:, None] * normals.T)).T
    np.testing.assert_allclose(out.steps, steps, rtol=1e-12, atol=1e-15)
    u = out.mean + out.sigma * steps
    np.testing.assert_allclose(out.points, BOX.lower + BOX.width * u, rtol=1e-12)


def test_the_eigensystem_is_refreshed_lazily_and_then_matches_c() -> None:
    lam = 10
    params = cma_parameters(D, lam)
    assert 10 < params.eigen_gap < 20  # purecma's gap: every second generation at n = 10
    # sampled once, nothing learned yet
    state, settings, costs = evolved_run(np.random.default_rng(4), 1)
    refreshed = []
    for g in range(6):
        normals = np.random.default_rng(g).standard_normal((lam, D))
        state = generation(state, settings, costs, normals)
        costs = sphere(state.run.samples.points)
        run = view(state)
        reconstructed = run.rows.T @ np.diag(run.axes**2) @ run.rows
        refreshed.append(np.allclose(reconstructed, run.cov, rtol=1e-10, atol=1e-14))
        inverse = run.inv_sqrt @ run.inv_sqrt
        np.testing.assert_allclose(inverse @ reconstructed, np.eye(D), atol=1e-8)
    assert refreshed == [False, True, False, True, False, True]


@pytest.mark.parametrize("lamarckian", [False, True])
def test_a_sample_outside_is_evaluated_repaired_and_learned_from_by_the_policy(
    lamarckian: bool,
) -> None:
    lam = 10
    state, settings, costs = evolved_run(np.random.default_rng(5), 3, lamarckian=lamarckian)
    normals = np.zeros((lam, D))
    normals[0, :] = 60.0  # far outside along most coordinates
    run = view(generation(state, settings, costs, normals))
    assert BOX.contains(run.points)
    sampled = run.rows.T @ (run.axes * normals[0])
    u = run.mean + run.sigma * sampled
    outside = (u < 0) | (u > 1)
    assert outside.sum() >= 5
    repaired = np.clip(u, 0.0, 1.0)  # the evolved run clips
    np.testing.assert_allclose(run.points[0], BOX.lower + BOX.width * repaired, rtol=1e-12)
    if lamarckian:  # the repaired point's step, shortened to the cap
        assert np.linalg.norm(run.inv_sqrt @ run.steps[0]) == pytest.approx(injection_cap(D))
        direction = repaired - run.mean
        np.testing.assert_allclose(
            run.steps[0] / np.linalg.norm(run.steps[0]),
            direction / np.linalg.norm(direction),
            rtol=1e-10,
        )
    else:  # the sampled step: the search minimises f(repair(x))
        np.testing.assert_allclose(run.steps[0], sampled, rtol=1e-12)
    # a sample inside keeps its sampled step either way
    np.testing.assert_allclose(run.points[1], BOX.lower + BOX.width * run.mean)
    np.testing.assert_array_equal(run.steps[1], np.zeros(D))


# --- behaviour ----------------------------------------------------------------------------------


@pytest.mark.parametrize("lamarckian", [False, True])
def test_the_kept_step_lengths_are_their_mahalanobis_lengths(lamarckian: bool) -> None:
    """The update's negative weights read ||C^(-1/2) y||^2 as sample() kept it (||z||^2 for a
    sampled step, the capped length for a repaired one): it must equal the product with the
    C^(-1/2) that the update uses, refreshed or not in between."""
    lam = 10
    state, settings, costs = evolved_run(np.random.default_rng(5), 3, lamarckian=lamarckian)
    for g in range(4):
        # large normals, so that some samples leave the box and are repaired
        normals = 4.0 * np.random.default_rng(10 + g).standard_normal((lam, D))
        state = generation(state, settings, costs, normals)
        costs = sphere(state.run.samples.points)
        run = view(state)
        expected = np.sum((run.steps @ run.inv_sqrt.T) ** 2, axis=1)
        np.testing.assert_allclose(run.lengths, expected, rtol=1e-10)
        repaired = ~np.isclose(run.lengths, np.sum(normals**2, axis=1), rtol=1e-12)
        assert repaired.any() == lamarckian
        if lamarckian:
            assert np.all(run.lengths[repaired] <= injection_cap(D) ** 2 * (1 + 1e-12))


def test_the_mean_starts_at_the_warm_start() -> None:
    rec = Recorder(sphere)
    x0 = np.full(D, 4.0)
    opt = CMAES(sigma0=1e-6)
    res = opt.minimize(rec, BOX, np.random.default_rng(0), Budget(max_evaluations=21), x0)
    assert rec.calls == [1, 10, 10]
    assert res.nfev == 21 and np.max(np.abs(res.x - x0)) < 1e-4


def test_a_generation_cut_short_by_the_budget_evaluates_its_first_samples() -> None:
    rec = Recorder(sphere)
    res = CMAES().minimize(rec, BOX, np.random.default_rng(0), Budget(max_evaluations=36))
    assert rec.calls == [1, 10, 10, 10, 5] and res.nfev == 36 and res.nit == 4


@pytest.mark.parametrize("name", ["cma-es", "cma-es-ipop", "cma-es-bipop"])
def test_converges_on_sphere_ellipsoid_and_rosenbrock_with_enough_budget(name: str) -> None:
    def ellipsoid(x):
        return ((x - CENTRE) ** 2 * 10.0 ** (6 * np.arange(D) / (D - 1))).sum(axis=1)

    def rosenbrock(x):
        return (100 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1 - x[:, :-1]) ** 2).sum(axis=1)

    opt = get_optimizer(name)
    for f, budget in ((sphere, 2000), (ellipsoid, 6000), (rosenbrock, 8000)):
        results = [
            opt.minimize(f, BOX, np.random.default_rng(s), Budget(max_evaluations=budget)).fun
            for s in range(3)
        ]
        assert np.median(results) < 1e-8, (f.__name__, results)


def test_a_flat_objective_stops_runs_on_tolfun_and_restarts() -> None:
    rec = Recorder(lambda x: np.ones(x.shape[0]))
    res = CMAES().minimize(rec, BOX, np.random.default_rng(0), Budget(max_evaluations=2000))
    history = cma_parameters(D, 10).history
    assert res.info["stops"] and set(res.info["stops"]) == {"tolfun"}
    # a run learns from `history` generations before TolFun can apply
    assert res.info["restarts"] <= 2000 // (10 * history)
    assert set(rec.calls[1:-1]) == {10} and rec.calls[-1] == 9  # the budget cuts the last


def solve_with_restarts(restarts: Restarts, budget: int, seed: int = 0) -> tuple[list, list]:
    """``(batch sizes after the first point, runs)`` of a solve on the sphere."""
    rec = Recorder(sphere)
    # a loose TolFun makes runs on the sphere stop after some dozens of generations
    opt = CMAES(restarts=restarts, tol_fun=1e-2)
    res = opt.minimize(rec, BOX, np.random.default_rng(seed), Budget(max_evaluations=budget))
    assert res.nfev == sum(rec.calls) <= budget
    runs = res.info["runs"]
    assert len(runs) == res.info["restarts"] + 1
    assert [r["stop"] for r in runs[:-1]] == res.info["stops"] and runs[-1]["stop"] is None
    # every run learns from all of its generations but the solve's last one
    learned = sum(r["evaluations"] for r in runs)
    assert learned == res.nfev - 1 - rec.calls[-1]
    return rec.calls[1:], runs


def test_same_restarts_keep_lambda() -> None:
    sizes, runs = solve_with_restarts(Restarts.SAME, 3000)
    assert len(runs) >= 3 and {r["population_size"] for r in runs} == {10}
    assert set(sizes[:-1]) == {10}


def test_ipop_doubles_lambda_at_every_restart() -> None:
    sizes, runs = solve_with_restarts(Restarts.IPOP, 6000)
    assert len(runs) >= 3
    assert [r["population_size"] for r in runs] == [10 * 2**k for k in range(len(runs))]
    assert sizes[: runs[0]["evaluations"] // 10] == [10] * (runs[0]["evaluations"] // 10)


def test_ipop_stops_doubling_at_the_cap() -> None:
    opt = CMAES(restarts=Restarts.IPOP)
    state = first_run(opt, BOX.lower, BOX.width, np.zeros(D))
    for _ in range(MAX_DOUBLINGS + 3):
        state = restart(opt, state, BOX, np.random.default_rng(1))
    assert state.plan.population_size == 10 * 2**MAX_DOUBLINGS


def test_bipop_interleaves_large_and_small_runs_within_their_budgets() -> None:
    _, runs = solve_with_restarts(Restarts.BIPOP, 12000, seed=3)
    assert len(runs) >= 5
    # the first run has the default lambda and counts as small; a large run follows
    assert runs[0]["population_size"] == 10
    small_total, large_total, doublings = runs[0]["evaluations"], 0, 0
    kinds = []
    for run in runs[1:]:
        lam, evaluations = run["population_size"], run["evaluations"]
        if small_total >= max(1, large_total):
            doublings += 1
            assert lam == 10 * 2**doublings
            large_total += evaluations
            kinds.append("large")
        else:  # lambda between the default and the latest large one, half the large budget
            assert 10 <= lam <= 10 * 2**doublings
            assert evaluations < 0.5 * large_total + lam
            if run["stop"] == "runbudget":
                assert evaluations >= 0.5 * large_total
            small_total += evaluations
            kinds.append("small")
    assert kinds[0] == "large" and kinds.count("small") >= 2


def test_sigma0_is_a_fraction_of_each_coordinates_range() -> None:
    box = Bounds(np.array([-7.0, -0.25]), np.array([7.0, 0.25]))
    rec_points: list[np.ndarray] = []

    def record(x):
        rec_points.append(x.copy())
        return np.zeros(x.shape[0])

    CMAES(sigma0=0.01, population_size=400).minimize(
        record, box, np.random.default_rng(0), Budget(max_evaluations=401), np.zeros(2)
    )
    spread = rec_points[1].std(axis=0)
    np.testing.assert_allclose(spread, 0.01 * box.width, rtol=0.1)


@pytest.mark.parametrize("lamarckian", [False, True])
@pytest.mark.parametrize("mode", list(BoundHandling))
def test_every_bound_policy_keeps_points_inside(mode: BoundHandling, lamarckian: bool) -> None:
    box = Bounds(np.full(D, -1.0), np.full(D, 1.0))
    points = []

    def record(x):  # the optimum (3, ..., 3) is outside: the box's corner is best, cost 40
        points.append(x.copy())
        return ((x - 3.0) ** 2).sum(axis=1)

    opt = CMAES(bound_handling=mode, lamarckian=lamarckian)
    res = opt.minimize(record, box, np.random.default_rng(0), Budget(max_evaluations=1230))
    assert box.contains(np.vstack(points)) and box.contains(res.x)
    if mode is BoundHandling.REFLECT and not lamarckian:  # the default reaches the corner
        assert res.fun == pytest.approx(40.0, abs=0.05)
    if mode is BoundHandling.CLIP and not lamarckian:  # exactly: the corner is a clipped point
        assert res.fun == 40.0


def test_registered_variants() -> None:
    assert get_optimizer("cma-es") == CMAES()
    assert get_optimizer("cma-es-ipop").restarts is Restarts.IPOP
    assert get_optimizer("cma-es-bipop").restarts is Restarts.BIPOP
    warm = get_optimizer("cma-es-warm")
    assert warm.bound_handling is CMABoundHandling.TRANSFORM and warm.sigma0 == 0.02
    assert get_optimizer("cma-es", bound_handling="transform", constants="pycma") == CMAES(
        bound_handling=CMABoundHandling.TRANSFORM, constants=CMAConstants.PYCMA
    )
    assert CMAES().default_budget == Budget(max_evaluations=1230)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("population_size", 1),
        ("sigma0", 0.0),
        ("sigma0", 1.5),
        ("max_evaluations", 0),
        ("active", "yes"),
        ("restarts", "lpop"),
        ("bound_handling", "bounce"),
        ("constants", "matlab"),
        ("tol_fun", -1.0),
        ("tol_x", math.nan),
    ],
)
def test_invalid_config_names_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"CMAES\.{field} must"):
        CMAES(**{field: value})
