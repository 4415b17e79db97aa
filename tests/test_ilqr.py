"""``ilqr``: the box QP, the stage derivatives, the passes, and the optimum it reaches."""

from __future__ import annotations

import itertools
import math
import pickle
import shutil

import numpy as np
import pytest
from scipy.optimize import minimize as scipy_minimize

from formation_bench.instances.instants import record_instants
from formation_bench.instances.library import shipped
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.model import rollout
from formation_bench.mpc.problem import LocalProblem
from formation_bench.mpc.scenario import PAPER, get_scenario
from formation_bench.mpc.solvers.ilqr import IlqrOptimizer
from formation_bench.mpc.solvers.ilqr_boxqp import (
    ALL_CLAMPED,
    HESSIAN_NOT_POSITIVE_DEFINITE,
    box_qp,
)
from formation_bench.mpc.solvers.ilqr_derivatives import (
    STAGE_LAYOUT,
    CostHessian,
    build_derivatives,
    stage_starts,
)
from formation_bench.mpc.solvers.ilqr_passes import (
    F_U,
    F_X,
    L_U,
    L_UU,
    L_UX,
    L_X,
    L_XX,
    Policy,
    backward_pass,
    forward_pass,
)
from formation_bench.mpc.solvers.problem_shape import ProblemShape, pack_parameters
from formation_bench.optimizers import Budget, get_optimizer

PENALISED = get_scenario(
    "swarm-5",
    graph="ring",
    w_collision=50.0,
    safety_radius_m=8.0,
    obstacles=((0.0, 0.0, 12.0), (25.0, 10.0, 6.0)),
    obstacle_margin_m=2.0,
    w_obstacle=20.0,
)
"""The centre estimated from the group, with both penalties, large enough to matter."""
SCENARIOS = {
    "paper": PAPER,
    "full-sequence": PAPER.with_overrides(n_blocks=20),
    "uneven-blocks": PAPER.with_overrides(n_blocks=3, rk4_substeps=3),
    "penalised": PENALISED,
}
"""Stages of four, one and six or seven periods (with three RK4 sub-steps); penalties."""


def random_problem(rng: np.random.Generator, scenario, near: bool = False) -> LocalProblem:
    """A random problem of ``scenario``; ``near``: the neighbours' estimates follow the UAV's
    coasting path a few metres off and the UAV starts by the obstacles (penalties active)."""
    horizon, n_nb = scenario.timing.horizon_steps, 2
    state = np.array(
        [rng.normal(0, 20), rng.normal(0, 20), rng.uniform(-math.pi, math.pi), rng.uniform(5, 20)]
    )
    if near:
        state[:2] = rng.normal(0, 6, size=2)
        coasting = rollout(state, np.zeros((horizon, 2)), scenario.timing.period_s, 1)[1:, :2]
        neighbours = coasting + rng.normal(0, 4, size=(n_nb, horizon, 2))
    else:
        neighbours = rng.normal(0, 30, size=(n_nb, horizon, 2))
    group = scenario.communication.graph != "complete"
    return LocalProblem(
        scenario, 0, state, neighbours, rng.normal(0, 10, size=(n_nb, horizon, 2)),
        rng.normal(0, 30, size=(horizon, 2)),
        rng.normal(0, 10, size=(horizon, 2)) if group else None,
    )  # fmt: skip


# --- the box QP -----------------------------------------------------------------------------------


def qp_value(hessian, gradient, x):
    return float(0.5 * x @ hessian @ x + gradient @ x)


def exact_box_qp(hessian, gradient, lower, upper):
    """The minimiser of a strictly convex box QP by trying every active set (3^n)."""
    n = gradient.size
    best, best_value = None, math.inf
    for sides in itertools.product((0, -1, 1), repeat=n):
        sides = np.array(sides)
        x = np.where(sides == -1, lower, np.where(sides == 1, upper, 0.0))
        free = sides == 0
        if free.any():
            rhs = gradient[free] + hessian[np.ix_(free, ~free)] @ x[~free]
            x[free] = np.linalg.solve(hessian[np.ix_(free, free)], -rhs)
        if np.any(x < lower - 1e-12) or np.any(x > upper + 1e-12):
            continue
        value = qp_value(hessian, gradient, x)
        if value < best_value:
            best, best_value = x, value
    return best


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_box_qp_finds_the_minimiser_of_random_qps(n):
    rng = np.random.default_rng(n)
    free_index, factor = np.empty(n, dtype=np.int64), np.empty((n, n))
    clamped_somewhere = 0
    for _ in range(60):
        root = rng.normal(size=(n, n))
        hessian = root @ root.T + 0.05 * np.eye(n)
        gradient = rng.normal(0, 3, size=n)
        centre, half = rng.normal(0, 1, size=n), rng.uniform(0.1, 2.0, size=n)
        lower, upper = centre - half, centre + half
        start = rng.normal(0, 2, size=n)
        x, result, n_free, _ = box_qp(hessian, gradient, lower, upper, start, free_index, factor)
        assert result >= 1
        expected = exact_box_qp(hessian, gradient, lower, upper)
        np.testing.assert_allclose(x, expected, atol=1e-8 * (1 + np.abs(expected).max()))
        reference = scipy_minimize(
            lambda z, h=hessian, g=gradient: qp_value(h, g, z),
            np.clip(start, lower, upper),
            jac=lambda z, h=hessian, g=gradient: h @ z + g,
            bounds=list(zip(lower, upper, strict=True)),
            method="L-BFGS-B",
            options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 1000},
        )
        assert qp_value(hessian, gradient, x) <= reference.fun + 1e-10 * (1 + abs(reference.fun))
        # the free set and the Cholesky factor of the Hessian on it, for the feedback gain
        free = free_index[:n_free]
        gradient_at = hessian @ x + gradient
        on_bound = (x == lower) & (gradient_at > 0) | (x == upper) & (gradient_at < 0)
        assert set(free) == set(np.flatnonzero(~on_bound))
        chol = np.tril(factor[:n_free, :n_free])
        np.testing.assert_allclose(chol @ chol.T, hessian[np.ix_(free, free)], rtol=1e-12)
        clamped_somewhere += n_free < n
    assert clamped_somewhere > 10  # the bounds were active in many of them


def test_box_qp_reports_an_indefinite_hessian_and_a_fully_clamped_solution():
    free_index, factor = np.empty(2, dtype=np.int64), np.empty((2, 2))
    box = (np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    indefinite = np.array([[1.0, 0.0], [0.0, -1.0]])
    _, result, _, _ = box_qp(
        indefinite, np.array([0.1, 0.1]), *box, np.zeros(2), free_index, factor
    )
    assert result == HESSIAN_NOT_POSITIVE_DEFINITE
    # pushed through both upper bounds: x = upper, nothing free
    x, result, n_free, _ = box_qp(
        np.eye(2), np.array([-5.0, -7.0]), *box, np.zeros(2), free_index, factor
    )
    assert result == ALL_CLAMPED and n_free == 0
    np.testing.assert_array_equal(x, box[1])


# --- the stage derivatives ----------------------------------------------------------------------


def plain_stage(problem: LocalProblem, starts: np.ndarray, b: int, z: np.ndarray):
    """Stage b from ``z = (x_b, u_b)`` by eq. (14) as printed: the state after the block and
    the block's cost, penalties included."""
    timing, weights = problem.scenario.timing, problem.scenario.weights
    state, cost = z[:4], 0.0
    for k in range(starts[b], starts[b + 1]):
        state = rollout(state, z[None, 4:], timing.period_s, timing.rk4_substeps)[1]
        p = state[:2]
        formation = sum(
            np.sum((p - problem.neighbour_positions[j, k] - problem.desired_relative[j, k]) ** 2)
            for j in range(problem.neighbour_positions.shape[0])
        )
        centre = (p + problem.centre_neighbour_sum[k]) / problem.centre_group
        term = weights.w_dst * formation + weights.w_trj * np.sum(
            (centre - problem.reference[k]) ** 2
        )
        term += sum(weight * max(0.0, radius - math.hypot(*(p - c))) ** 2 for weight, radius, c in
                    penalty_centres(problem, k))  # fmt: skip
        cost += timing.period_s * term
    return state, cost


def penalty_centres(problem: LocalProblem, k: int):
    penalties = problem.penalties
    centres = []
    if penalties.w_collision > 0:
        centres += [(penalties.w_collision, penalties.safety_radius, c)
                    for c in problem.neighbour_positions[:, k]]  # fmt: skip
    if penalties.w_obstacle > 0:
        centres += [(penalties.w_obstacle, row[2], row[:2]) for row in penalties.obstacles]
    return centres


def central_difference(f, z: np.ndarray, step: float = 1e-5) -> np.ndarray:
    """Jacobian of ``f`` at ``z`` (rows: outputs) by central differences."""
    columns = []
    for i in range(z.size):
        h = step * (1.0 + abs(z[i]))
        up, down = z.copy(), z.copy()
        up[i] += h
        down[i] -= h
        columns.append((np.atleast_1d(f(up)) - np.atleast_1d(f(down))) / (2 * h))
    return np.stack(columns, axis=-1)


def position_after(problem: LocalProblem, z: np.ndarray, periods: int) -> np.ndarray:
    """The position ``periods`` periods after ``x`` under the held ``u``, ``z = (x, u)``."""
    timing = problem.scenario.timing
    controls = np.repeat(z[None, 4:], periods, axis=0)
    return rollout(z[:4], controls, timing.period_s, timing.rk4_substeps)[-1, :2]


def gauss_newton_hessian(problem, starts, b, z) -> tuple[np.ndarray, int]:
    """Stage b's Gauss-Newton Hessian in ``z`` from finite-difference Jacobians: eq. (14)'s
    terms are ``c |p|^2 + ...`` in each position p, ``c = delta_T (2 w_dst J + 2 w_trj / M^2)``;
    each active penalty adds ``2 J' J`` of its residual ``sqrt(delta_T w) max(0, r - d)``.
    Also returns how many penalty terms were active."""
    timing, weights = problem.scenario.timing, problem.scenario.weights
    curvature = (
        timing.period_s
        * 2
        * (
            weights.w_dst * problem.neighbour_positions.shape[0]
            + weights.w_trj / problem.centre_group**2
        )
    )
    hessian, active = np.zeros((6, 6)), 0
    for periods, k in enumerate(range(starts[b], starts[b + 1]), start=1):
        jacobian = central_difference(lambda w, n=periods: position_after(problem, w, n), z)
        hessian += curvature * jacobian.T @ jacobian
        for weight, radius, centre in penalty_centres(problem, k):

            def residual(w, n=periods, r=radius, c=centre, w_=weight):
                gap = r - float(np.linalg.norm(position_after(problem, w, n) - c))
                return math.sqrt(timing.period_s * w_) * max(0.0, gap)

            if residual(z) > 0:
                active += 1
                jacobian = central_difference(residual, z)
                hessian += 2 * jacobian.T @ jacobian
    return hessian, active


def trajectory(problem, starts, decision):
    timing = problem.scenario.timing
    states = rollout(
        problem.state, problem.controls(decision), timing.period_s, timing.rk4_substeps
    )
    return states[starts[:-1]]


def derivatives_at(functions, problem, states, controls) -> dict[str, np.ndarray]:
    functions.parameters[:] = pack_parameters(problem, functions.shape)
    functions.states[:] = states
    functions.controls[:] = controls
    functions.evaluate()
    return functions.unpacked()


def test_the_kernels_read_the_layout_the_function_writes():
    offsets, at = {}, 0
    for name, dims in STAGE_LAYOUT:
        offsets[name] = at
        at += math.prod(dims)
    assert (F_X, F_U, L_X, L_U, L_XX, L_UU, L_UX) == tuple(offsets.values())


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_stage_derivatives_agree_with_finite_differences(name):
    scenario = SCENARIOS[name]
    rng = np.random.default_rng(len(name))
    problem = random_problem(rng, scenario, near=name == "penalised")
    shape = ProblemShape.of(problem)
    starts = stage_starts(shape)
    decision = problem.bounds.sample(rng, 1)[0]
    states, controls = trajectory(problem, starts, decision), decision.reshape(-1, 2)
    exact = build_derivatives(shape, CostHessian.EXACT)
    gauss_newton = build_derivatives(shape, CostHessian.GAUSS_NEWTON)
    d = derivatives_at(exact, problem, states, controls)
    gn = derivatives_at(gauss_newton, problem, states, controls)
    active = 0
    for b in range(shape.n_blocks):
        z = np.concatenate((states[b], controls[b]))
        jacobian = central_difference(lambda w, b=b: plain_stage(problem, starts, b, w)[0], z)
        gradient = central_difference(lambda w, b=b: plain_stage(problem, starts, b, w)[1], z)[0]
        scale = np.abs(jacobian).max()
        np.testing.assert_allclose(d["f_x"][b], jacobian[:, :4], rtol=1e-6, atol=1e-7 * scale)
        np.testing.assert_allclose(d["f_u"][b], jacobian[:, 4:], rtol=1e-6, atol=1e-7 * scale)
        g = np.concatenate((d["l_x"][b], d["l_u"][b]))
        np.testing.assert_allclose(g, gradient, rtol=1e-6, atol=1e-7 * np.abs(g).max())
        for name_ in ("f_x", "f_u", "l_x", "l_u"):  # the Hessian choice changes only l_zz
            np.testing.assert_array_equal(gn[name_][b], d[name_][b])

        # exact: the derivative of the function's own gradient
        def stage_gradient(w, b=b):
            moved_states, moved_controls = states.copy(), controls.copy()
            moved_states[b], moved_controls[b] = w[:4], w[4:]
            values = derivatives_at(exact, problem, moved_states, moved_controls)
            return np.concatenate((values["l_x"][b], values["l_u"][b]))

        hessian = np.block([[d["l_xx"][b], d["l_ux"][b].T], [d["l_ux"][b], d["l_uu"][b]]])
        numeric = central_difference(stage_gradient, z)
        np.testing.assert_allclose(hessian, numeric, rtol=1e-5, atol=1e-6 * np.abs(hessian).max())
        # Gauss-Newton: G' H G of eq. (14)'s terms, 2 J' J of the penalties' residuals
        expected, terms = gauss_newton_hessian(problem, starts, b, z)
        active += terms
        gn_hessian = np.block([[gn["l_xx"][b], gn["l_ux"][b].T], [gn["l_ux"][b], gn["l_uu"][b]]])
        np.testing.assert_allclose(
            gn_hessian, expected, rtol=1e-5, atol=1e-6 * np.abs(expected).max()
        )
        assert np.linalg.eigvalsh(gn_hessian).min() >= -1e-9 * np.abs(gn_hessian).max()
    assert (active > 0) == (name == "penalised")


# --- the passes ---------------------------------------------------------------------------------


def stage_problem(rng, scenario, hessian=CostHessian.GAUSS_NEWTON):
    """A random problem, its stage derivatives at a random decision, and a policy about it."""
    problem = random_problem(rng, scenario)
    shape = ProblemShape.of(problem)
    functions = build_derivatives(shape, hessian)
    decision = problem.bounds.sample(rng, 1)[0]
    states = trajectory(problem, functions.starts, decision)
    derivatives_at(functions, problem, states, decision.reshape(-1, 2))
    policy = Policy(
        decision.reshape(-1, 2).copy(), states.copy(), np.zeros((shape.n_blocks, 2)),
        np.zeros((shape.n_blocks, 2, 4)), problem.bounds.lower.reshape(-1, 2).copy(),
        problem.bounds.upper.reshape(-1, 2).copy(),
    )  # fmt: skip
    return problem, functions, policy


@pytest.mark.parametrize("name", ["paper", "full-sequence", "uneven-blocks"])
def test_without_active_bounds_the_backward_pass_solves_the_lq_problem(name):
    """The controls ``k_b + K_b dx_b`` along the linearised dynamics minimise the quadratic
    model of the cost, here written out as one dense QP in all the control steps."""
    _, functions, policy = stage_problem(np.random.default_rng(7), SCENARIOS[name])
    policy.lower[:], policy.upper[:] = -1e9, 1e9
    outcome = backward_pass(functions.values, policy, 0.0, False)
    assert outcome.failed_stage == -1
    d = functions.unpacked()
    n_stages = d["f_x"].shape[0]
    # dx_b = sum_c S[b, c] du_c along the linear dynamics, dx_0 = 0
    sensitivity = np.zeros((n_stages, 4, 2 * n_stages))
    for b in range(n_stages - 1):
        sensitivity[b + 1] = d["f_x"][b] @ sensitivity[b]
        sensitivity[b + 1][:, 2 * b : 2 * b + 2] += d["f_u"][b]
    hessian, gradient = np.zeros((2 * n_stages,) * 2), np.zeros(2 * n_stages)
    for b in range(n_stages):
        select = np.zeros((2, 2 * n_stages))
        select[:, 2 * b : 2 * b + 2] = np.eye(2)
        s = sensitivity[b]
        gradient += s.T @ d["l_x"][b] + select.T @ d["l_u"][b]
        cross = select.T @ d["l_ux"][b] @ s
        hessian += s.T @ d["l_xx"][b] @ s + select.T @ d["l_uu"][b] @ select + cross + cross.T
    expected = np.linalg.solve(hessian, -gradient)
    steps, dx = np.zeros((n_stages, 2)), np.zeros(4)
    for b in range(n_stages):
        steps[b] = policy.feedforward[b] + policy.gains[b] @ dx
        dx = d["f_x"][b] @ dx + d["f_u"][b] @ steps[b]
    np.testing.assert_allclose(
        steps.reshape(-1), expected, rtol=1e-7, atol=1e-9 * np.abs(expected).max()
    )
    model = gradient @ expected + 0.5 * expected @ hessian @ expected
    assert outcome.linear + outcome.quadratic == pytest.approx(model, rel=1e-8)


def test_clamped_controls_get_no_feedback():
    rng = np.random.default_rng(11)
    _, functions, policy = stage_problem(rng, PAPER)
    # the accelerations in a tiny box about u (their steps reach its faces), the turn rates free
    half_width = np.array([1e-6, 1e3])
    policy.lower[:] = policy.controls - half_width
    policy.upper[:] = policy.controls + half_width
    assert backward_pass(functions.values, policy, 0.0, False).failed_stage == -1
    clamped = np.isclose(np.abs(policy.feedforward), half_width, rtol=1e-9, atol=0)
    np.testing.assert_array_equal(clamped, [[True, False]] * len(clamped))
    assert not policy.gains[:, 0].any()  # clamped: the rows of K are zero
    assert np.abs(policy.gains[:, 1]).min() > 0


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_forward_pass_costs_are_the_problems_to_the_bit(name):
    rng = np.random.default_rng(3)
    problem, functions, policy = stage_problem(rng, SCENARIOS[name])
    starts = functions.starts
    for alpha in (1.0, 0.3, 0.0):
        policy.feedforward[:] = rng.normal(0, 1, size=policy.feedforward.shape)
        policy.gains[:] = rng.normal(0, 0.1, size=policy.gains.shape)
        controls, states, cost = forward_pass(problem.packed, starts, policy, alpha)
        decision = controls.reshape(-1)
        assert problem.bounds.contains(decision)
        assert cost == problem(decision[None])[0]
        assert cost == pytest.approx(problem.reference_cost(decision), rel=1e-12)
        np.testing.assert_array_equal(states, trajectory(problem, starts, decision))
        if alpha == 0.0:
            policy.gains[:] = 0.0
            controls = forward_pass(problem.packed, starts, policy, 0.0)[0]
            np.testing.assert_array_equal(controls, policy.controls)


# --- the solver -----------------------------------------------------------------------------------


def stratified(instances, per_family: int):
    by_family: dict[str, list] = {}
    for instance in instances:
        by_family.setdefault(instance.family, []).append(instance)
    return [i for group in by_family.values() for i in group[:per_family]]


def library_gaps(optimizer, instances):
    gaps = []
    for instance in instances:
        problem = instance.problem
        result = optimizer.minimize(
            problem, problem.bounds, np.random.default_rng(0), None, instance.warm_start
        )
        assert result.success, result.message
        assert result.fun == problem(result.x[None])[0]
        assert result.fun <= instance.warm_cost
        assert problem.bounds.contains(result.x)
        gaps.append(float(instance.normalised_gap(result.fun)))
    return np.array(gaps)


def test_reaches_the_best_known_optimum_on_a_sample_of_the_test_split():
    instances = stratified(shipped().instances("test"), 2)
    gaps = library_gaps(IlqrOptimizer(), instances)
    assert len(instances) >= 20
    assert np.median(gaps) <= 1e-6, np.percentile(gaps, [50, 90, 100])


@pytest.mark.slow
def test_reaches_the_best_known_optimum_on_the_test_split():
    instances = shipped().instances("test")
    gaps = library_gaps(IlqrOptimizer(), instances)
    summary = f"{len(gaps)} instances, median/p90/max {np.percentile(gaps, [50, 90, 100])}"
    assert np.median(gaps) <= 1e-6, summary
    assert np.percentile(gaps, 90) <= 1e-6, summary


@pytest.mark.parametrize("name", ["full-sequence", "uneven-blocks", "penalised"])
@pytest.mark.parametrize(
    ("hessian", "state_regularisation"),
    [("gauss-newton", False), ("exact", False), ("exact", True)],
)
def test_reaches_ipopts_optimum_on_other_blockings_and_penalties(
    name, hessian, state_regularisation
):
    instants = record_instants(SCENARIOS[name], get_optimizer("ltv-osqp"), [0, 6], seed=2)
    ilqr = IlqrOptimizer(cost_hessian=hessian, state_regularisation=state_regularisation)
    ipopt = get_optimizer("ipopt")
    for instant in instants:
        problem, x0 = instant.problem, instant.warm_start
        ours = ilqr.minimize(problem, problem.bounds, np.random.default_rng(0), None, x0)
        best = ipopt.minimize(problem, problem.bounds, np.random.default_rng(0), None, x0)
        warm = problem(x0[None])[0]
        assert ours.success and best.success
        assert ours.fun == problem(ours.x[None])[0]
        assert ours.fun - best.fun <= 1e-6 * (warm - best.fun) + 1e-12 * best.fun, (
            instant.step, instant.uav, ours.fun, best.fun, warm,
        )  # fmt: skip


def test_budget_iterations_evaluations_and_deadline():
    instance = stratified(shipped().instances("test"), 1)[0]
    problem, x0 = instance.problem, instance.warm_start
    optimizer = IlqrOptimizer()
    full = optimizer.minimize(problem, problem.bounds, np.random.default_rng(0), None, x0)
    assert full.nit >= 3 and "converged" in full.message
    assert np.all(np.diff(full.history_fun) < 0) and full.history_nfev[0] == 1
    assert full.nfev >= full.history_nfev[-1] and full.info["linearisations"] <= full.nit
    for budget in (Budget(max_iterations=2), Budget(max_evaluations=3), Budget(deadline_s=1e-9)):
        result = optimizer.minimize(problem, problem.bounds, np.random.default_rng(0), budget, x0)
        assert result.success
        assert result.fun == problem(result.x[None])[0]
        assert full.fun <= result.fun < instance.warm_cost
        if budget.max_iterations is not None:
            assert result.nit == 2
        if budget.max_evaluations is not None:
            assert result.nfev <= 3
        if budget.deadline_s is not None:  # one iteration, then the deadline
            assert result.nit == 1 and "deadline" in result.message
    one = optimizer.minimize(
        problem, problem.bounds, np.random.default_rng(0), Budget(max_iterations=1), x0
    )
    assert one.nit == 1 and full.fun <= one.fun < instance.warm_cost


def test_a_cost_that_cannot_be_evaluated_falls_back_to_the_warm_start():
    problem = random_problem(np.random.default_rng(0), PAPER)
    problem.reference[3] = np.nan
    x0 = problem.bounds.sample(np.random.default_rng(1), 1)[0]
    result = IlqrOptimizer().minimize(problem, problem.bounds, np.random.default_rng(0), None, x0)
    assert not result.success and result.info["fallback"]
    np.testing.assert_array_equal(result.x, x0)


def test_regularisation_beyond_its_limit_before_any_step_is_a_failure():
    """The exact stage Hessian of this obstacle problem is indefinite at its warm start:
    the backward pass fails until mu is raised, here beyond a tiny mu_max."""
    instance = shipped()[852]
    problem, x0 = instance.problem, instance.warm_start
    for mu_max, succeeds in [(1e-6, False), (1e10, True)]:
        optimizer = IlqrOptimizer(cost_hessian="exact", mu_max=mu_max)
        result = optimizer.minimize(problem, problem.bounds, np.random.default_rng(0), None, x0)
        assert result.info["backward_passes"] > result.nit  # some passes failed and were redone
        assert result.success is succeeds
        if not succeeds:
            assert "mu_max" in result.message and result.info["fallback"]
            np.testing.assert_array_equal(result.x, x0)
        else:
            assert instance.normalised_gap(result.fun) <= 1e-6


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("gcc") is None, reason="jit needs a C compiler")
def test_the_compiled_derivatives_are_the_virtual_machines():
    rng = np.random.default_rng(5)
    problem, functions, _ = stage_problem(rng, PENALISED)
    compiled = build_derivatives(functions.shape, CostHessian.GAUSS_NEWTON, jit=True)
    expected = functions.values.copy()
    derivatives_at(compiled, problem, functions.states, functions.controls)
    np.testing.assert_allclose(
        compiled.values, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max()
    )


def test_needs_a_local_problem_and_refuses_bad_fields():
    with pytest.raises(TypeError, match="LocalProblem"):
        IlqrOptimizer().minimize(
            lambda x: np.sum(x**2, axis=1),
            random_problem(np.random.default_rng(0), PAPER).bounds,
            np.random.default_rng(0),
        )
    for field, value in [("cost_hessian", "newton"), ("mu_factor", 1.0),
                         ("line_search_steps", 0), ("mu_max", 1e-9), ("z_min", 1.0)]:  # fmt: skip
        with pytest.raises(ValueError, match=field):
            IlqrOptimizer(**{field: value})


def test_closed_loop_is_deterministic_picklable_and_run_independent():
    scenario = get_scenario("paper", n_steps=30, settle_time_s=0.0)
    optimizer = get_optimizer("ilqr")
    first = simulate(scenario, optimizer, trigger=True, seed=0)
    again = simulate(scenario, optimizer, trigger=True, seed=0)
    copy = pickle.loads(pickle.dumps(optimizer))
    assert copy == optimizer and copy._solver_cache == {}
    fresh = simulate(scenario, copy, trigger=True, seed=0)
    for other in (again, fresh):
        np.testing.assert_array_equal(other.states, first.states)
        np.testing.assert_array_equal(other.solved, first.solved)
    assert not first.solve_failed.any()
