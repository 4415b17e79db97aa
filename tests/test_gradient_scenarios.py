"""The derivative-based baselines on the problem families beyond the paper: partial
communication graphs (the centre estimated from the group), collision and obstacle penalties,
per-UAV bounds, and the problem-shape caches."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formation_bench.instances.instants import record_instants
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.metrics import compute_metrics
from formation_bench.mpc.model import rollout
from formation_bench.mpc.problem import LocalProblem
from formation_bench.mpc.scenario import PAPER, get_scenario
from formation_bench.mpc.solvers.casadi_model import (
    ProblemShape,
    casadi_cost,
    gradient_function,
    pack_parameters,
    projected_gradient,
)
from formation_bench.mpc.solvers.ipopt_solver import IpoptOptimizer
from formation_bench.mpc.solvers.ltv_cvxpy import CvxpyLtvQP
from formation_bench.mpc.solvers.ltv_osqp import LtvOsqpOptimizer, qp_data
from formation_bench.optimizers import get_optimizer

GRAPHS = {
    "ring": {"graph": "ring"},
    "k-nearest": {"graph": "k-nearest", "graph_neighbours": 3},
    "range": {"graph": "range", "graph_range_m": 15.0},
}
PENALISED = get_scenario(
    "swarm-5",
    graph="ring",
    w_collision=50.0,
    safety_radius_m=8.0,
    obstacles=((0.0, 0.0, 12.0), (25.0, 10.0, 6.0)),
    obstacle_margin_m=2.0,
    w_obstacle=20.0,
)
"""Penalties large enough to matter next to eq. (14)'s terms of the random problems below."""
NEW = {"ipopt": IpoptOptimizer, "ltv-osqp": LtvOsqpOptimizer}
"""A fresh instance of each solver, with empty caches (``get_optimizer`` gives the registered
one)."""


def group_problem(
    rng: np.random.Generator, scenario, n_neighbours: int, uav: int = 0, near: bool = False
) -> LocalProblem:
    """A random problem with the centre estimated from the UAV and its ``n_neighbours``.

    ``near``: the UAV starts by the obstacles of :data:`PENALISED` and the neighbours'
    estimates follow its coasting trajectory a few metres off, so the penalties are active.
    """
    horizon = scenario.timing.horizon_steps
    state = np.array(
        [rng.normal(0, 20), rng.normal(0, 20), rng.uniform(-math.pi, math.pi), rng.uniform(5, 20)]
    )
    if near:
        state[:2] = rng.normal(0, 6, size=2)
        coasting = rollout(state, np.zeros((horizon, 2)), scenario.timing.period_s, 1)[1:, :2]
        neighbours = coasting + rng.normal(0, 4, size=(n_neighbours, horizon, 2))
    else:
        neighbours = rng.normal(0, 30, size=(n_neighbours, horizon, 2))
    return LocalProblem(
        scenario,
        uav,
        state,
        neighbours,
        rng.normal(0, 10, size=(n_neighbours, horizon, 2)),
        rng.normal(0, 30, size=(horizon, 2)),
        rng.normal(0, 10, size=(horizon, 2)),
    )


def without_penalties(problem: LocalProblem) -> LocalProblem:
    """The same problem with both penalty weights 0."""
    scenario = problem.scenario.with_overrides(w_collision=0.0, w_obstacle=0.0)
    return LocalProblem(
        scenario, problem.uav, problem.state, problem.neighbour_positions,
        problem.desired_relative, problem.reference, problem.centre_offset_sum,
    )  # fmt: skip


@pytest.fixture(scope="module")
def graph_instants():
    """Problems a short closed loop posed on each partial graph of a 10-UAV swarm."""
    return {
        name: record_instants(
            get_scenario("swarm-10", **fields), get_optimizer("ltv-osqp"), [0, 5], seed=0
        )
        for name, fields in GRAPHS.items()
    }


# --- the modelled cost is the problem's cost ------------------------------------------------------


def test_centre_group_and_sum_equal_the_old_formula_on_the_complete_graph():
    rng = np.random.default_rng(7)
    horizon = PAPER.timing.horizon_steps
    problem = LocalProblem(
        PAPER, 1, np.array([1.0, 2.0, 0.3, 15.0]), rng.normal(0, 30, size=(2, horizon, 2)),
        rng.normal(0, 10, size=(2, horizon, 2)), rng.normal(0, 30, size=(horizon, 2)),
    )  # fmt: skip
    shape = ProblemShape.of(problem)
    assert shape.centre_group == PAPER.n_uav == 3
    assert not shape.group_centre and not shape.penalised
    np.testing.assert_array_equal(
        problem.centre_neighbour_sum, problem.neighbour_positions.sum(axis=0)
    )
    # the parameter vector is the paper's: no S, no obstacles
    assert pack_parameters(problem).size == shape.n_parameters == 4 + 4 * 2 * horizon + 2 * horizon


@pytest.mark.parametrize("graph", sorted(GRAPHS))
def test_casadi_cost_equals_the_problem_on_partial_graphs(graph, graph_instants):
    rng = np.random.default_rng(1)
    counts = set()
    for inst in graph_instants[graph]:
        problem = inst.problem
        shape = ProblemShape.of(problem)
        counts.add(shape.n_neighbours)
        assert shape.group_centre
        assert shape.centre_group == problem.neighbour_positions.shape[0] + 1
        decisions = problem.bounds.sample(rng, 8)
        np.testing.assert_allclose(casadi_cost(problem, decisions), problem(decisions), rtol=1e-9)
    if graph == "range":  # the neighbour count changes from UAV to UAV and instant to instant
        assert len(counts) >= 3 and 0 in counts


@pytest.mark.parametrize("n_neighbours", [0, 1, 2, 4])
def test_casadi_cost_equals_the_problem_with_penalties(n_neighbours):
    rng = np.random.default_rng(n_neighbours)
    mattered = 0
    for _ in range(3):
        problem = group_problem(rng, PENALISED, n_neighbours, near=True)
        decisions = problem.bounds.sample(rng, 12)
        compiled = problem(decisions)
        symbolic = casadi_cost(problem, decisions)
        plain = np.array([problem.reference_cost(d) for d in decisions])
        np.testing.assert_allclose(symbolic, compiled, rtol=1e-9)
        np.testing.assert_allclose(symbolic, plain, rtol=1e-9)
        # the penalties are far above the tolerance in most of these costs: leaving one out
        # would show
        mattered += np.sum(compiled > (1 + 1e-6) * without_penalties(problem)(decisions))
    assert mattered >= 18


@pytest.mark.parametrize("form", ["sparse", "condensed"])
def test_ltv_qp_matches_the_cvxpy_reference_off_the_complete_graph(form, graph_instants):
    tight = LtvOsqpOptimizer(
        form=form, eps_abs=1e-9, eps_rel=1e-9, max_iter=400_000, polishing=form == "sparse"
    )
    atol = {"sparse": 1e-6, "condensed": 2e-5}  # in box widths, as for the paper's problems
    references: dict[ProblemShape, CvxpyLtvQP] = {}
    for inst in graph_instants["range"][::3]:
        problem = inst.problem
        shape = ProblemShape.of(problem)
        reference = references.setdefault(shape, CvxpyLtvQP.build(shape))
        result = tight.minimize(
            problem, problem.bounds, np.random.default_rng(0), None, inst.warm_start
        )
        assert result.success, result.message
        expected = reference.solve(
            problem, inst.warm_start, tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12
        )
        width = problem.bounds.width
        np.testing.assert_allclose(
            result.info["qp_steps"][0] / width, expected / width, atol=atol[form]
        )
    assert len(references) >= 2  # several neighbour counts, each with its own QP


# --- ipopt with the penalties -----------------------------------------------------------------


@pytest.mark.parametrize("shooting", ["single", "multiple"])
def test_ipopt_reaches_a_kkt_point_of_the_penalised_problem(shooting):
    rng = np.random.default_rng(11)
    optimizer = IpoptOptimizer(shooting=shooting)
    for n_neighbours in (2, 4):
        problem = group_problem(rng, PENALISED, n_neighbours, near=True)
        x0 = np.zeros(problem.dim)
        result = optimizer.minimize(problem, problem.bounds, np.random.default_rng(0), None, x0)
        assert result.success, result.message
        assert problem.bounds.contains(result.x)
        assert result.fun == pytest.approx(problem(result.x[None])[0], rel=1e-12)
        assert result.fun < problem(x0[None])[0]
        start = np.abs(projected_gradient(problem, x0, 1e-6)).max()
        final = np.abs(projected_gradient(problem, result.x, 1e-6)).max()
        assert final <= 1e-4 * max(1.0, start), (n_neighbours, final, start)


# --- ltv-osqp with the penalties: the Gauss-Newton model ---------------------------------------


@pytest.mark.parametrize("form", ["sparse", "condensed"])
def test_ltv_penalty_model_is_convex_and_exact_to_first_order(form):
    optimizer = LtvOsqpOptimizer(form=form)
    rng = np.random.default_rng(5)
    for n_neighbours in (1, 4):
        problem = group_problem(rng, PENALISED, n_neighbours, near=True)
        u0 = problem.bounds.sample(rng, 1)[0] * 0.2
        P, q, *_ = qp_data(optimizer, problem, u0)
        upper_triangle = P.toarray()
        full = upper_triangle + upper_triangle.T - np.diag(np.diag(upper_triangle))
        eigenvalues = np.linalg.eigvalsh(full)
        assert eigenvalues.min() >= -1e-9 * eigenvalues.max()
        if form == "condensed":  # q is then the gradient of the true cost in u
            shape = ProblemShape.of(problem)
            _, gradient = gradient_function(shape)(u0, pack_parameters(problem))
            np.testing.assert_allclose(q, np.asarray(gradient).reshape(-1), rtol=1e-9, atol=1e-9)
            # ... and it differs from the gradient without the penalties
            bare = without_penalties(problem)
            _, bare_gradient = gradient_function(ProblemShape.of(bare))(u0, pack_parameters(bare))
            assert np.abs(q - np.asarray(bare_gradient).reshape(-1)).max() > 1e-3 * np.abs(q).max()


@pytest.mark.parametrize("form", ["sparse", "condensed"])
def test_ltv_penalised_qp_matches_the_cvxpy_reference(form):
    tight = LtvOsqpOptimizer(
        form=form, eps_abs=1e-9, eps_rel=1e-9, max_iter=400_000, polishing=form == "sparse"
    )
    rng = np.random.default_rng(9)
    for n_neighbours in (2, 3):
        problem = group_problem(rng, PENALISED, n_neighbours, near=True)
        u0 = np.zeros(problem.dim)
        result = tight.minimize(problem, problem.bounds, np.random.default_rng(0), None, u0)
        assert result.success, result.message
        expected = CvxpyLtvQP.build(ProblemShape.of(problem)).solve(
            problem, u0, tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12
        )
        bare = CvxpyLtvQP.build(ProblemShape.of(without_penalties(problem))).solve(
            without_penalties(problem), u0
        )
        width = problem.bounds.width
        np.testing.assert_allclose(result.info["qp_steps"][0] / width, expected / width, atol=2e-5)
        assert np.abs((expected - bare) / width).max() > 1e-2  # the penalties moved the step
        assert result.fun <= problem(u0[None])[0]


# --- per-UAV bounds ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["ipopt", "ltv-osqp"])
def test_a_solve_keeps_to_the_uavs_own_bounds(name):
    """UAV 2 flies at 15 m/s behind a formation at 10 m/s and may brake at most 0.5 m/s^2."""
    tight = ((-7.0, 7.0), (-0.5, 7.0), (-7.0, 7.0))
    scenario = PAPER.with_overrides(uav_accel_bounds=tight)
    horizon = scenario.timing.horizon_steps
    times = scenario.timing.period_s * np.arange(1, horizon + 1)
    reference = np.column_stack((10.0 * times, np.zeros(horizon)))
    side = np.array([0.0, 10.0])
    neighbours = np.stack([reference + side, reference - side])
    desired = np.stack([np.tile(-side, (horizon, 1)), np.tile(side, (horizon, 1))])
    state = np.array([0.0, 0.0, 0.0, 15.0])
    problems = {
        key: LocalProblem(sc, 1, state, neighbours, desired, reference)
        for key, sc in (("own", scenario), ("shared", PAPER))
    }
    assert problems["own"].bounds.lower[0] == -0.5 and problems["shared"].bounds.lower[0] == -7.0
    results = {}
    for key, problem in problems.items():
        results[key] = NEW[name]().minimize(
            problem, problem.bounds, np.random.default_rng(0), None, np.zeros(problem.dim)
        )
        assert results[key].success, results[key].message
    assert problems["own"].bounds.contains(results["own"].x)
    assert results["own"].x[0::2].min() <= -0.5 + 1e-6  # the UAV's own bound is active ...
    assert results["shared"].x[0::2].min() < -1.0  # ... where the shared bound is not


def test_closed_loop_controls_stay_within_each_uavs_bounds():
    bounds = ((-7.0, 7.0), (-1.0, 1.0), (-3.0, 3.0))
    scenario = get_scenario("paper", n_steps=40, settle_time_s=0.0, uav_accel_bounds=bounds)
    for name in ("ipopt", "ltv-osqp"):
        trace = simulate(scenario, get_optimizer(name), trigger=False, seed=0)
        assert not trace.solve_failed.any()
        for uav, (low, high) in enumerate(bounds):
            accel = trace.controls[:, uav, 0]
            assert accel.min() >= low - 1e-9 and accel.max() <= high + 1e-9
        # UAV 2 needs more than its 1 m/s^2 at start-up: its bound is reached
        assert np.abs(trace.controls[:, 1, 0]).max() >= 1.0 - 1e-6


# --- caches -----------------------------------------------------------------------------------


def test_shape_keys_on_what_changes_the_model():
    rng = np.random.default_rng(3)
    base = group_problem(rng, PENALISED, 2)
    complete_graph_arguments = (
        PENALISED,
        0,
        base.state,
        base.neighbour_positions,
        base.desired_relative,
        base.reference,
    )
    shapes = {
        "base": ProblemShape.of(base),
        "more neighbours": ProblemShape.of(group_problem(rng, PENALISED, 3)),
        "no penalties": ProblemShape.of(without_penalties(base)),
        "no obstacle penalty": ProblemShape.of(
            group_problem(rng, PENALISED.with_overrides(w_obstacle=0.0), 2)
        ),
        "complete graph": ProblemShape.of(LocalProblem(*complete_graph_arguments)),
    }
    assert len(set(shapes.values())) == len(shapes)
    assert shapes["complete graph"].centre_group == 5 != shapes["base"].centre_group == 3
    # obstacles elsewhere, or other numbers, change parameters, not the shape
    moved = PENALISED.with_overrides(obstacles=((50.0, 50.0, 3.0), (-9.0, 4.0, 20.0)))
    assert ProblemShape.of(group_problem(rng, moved, 2)) == shapes["base"]


@pytest.mark.parametrize("name", ["ipopt", "ltv-osqp"])
def test_a_used_instance_solves_like_a_fresh_one_across_shapes(name):
    """Shapes in turn (neighbour count, penalties, obstacles moved): cached solvers never mix."""
    rng = np.random.default_rng(4)
    moved = PENALISED.with_overrides(obstacles=((5.0, -3.0, 9.0), (-8.0, 8.0, 6.0)))
    problems = [
        group_problem(rng, PENALISED, 2, near=True),
        group_problem(rng, PENALISED, 4, near=True),
        group_problem(rng, moved, 2, near=True),
        without_penalties(group_problem(rng, PENALISED, 2, near=True)),
        group_problem(rng, PENALISED, 2, near=True),
    ]
    used = NEW[name]()
    for problem in problems:
        x0 = np.zeros(problem.dim)
        again = used.minimize(problem, problem.bounds, np.random.default_rng(0), None, x0)
        fresh = NEW[name]().minimize(problem, problem.bounds, np.random.default_rng(0), None, x0)
        assert again.success and fresh.success
        np.testing.assert_array_equal(again.x, fresh.x)
    assert len({key[1] for key in used._solver_cache}) == 3  # moved obstacles: same shape


# --- closed loop ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["ipopt", "ltv-osqp"])
@pytest.mark.parametrize("graph", ["range", "k-nearest"])
@pytest.mark.slow
def test_closed_loop_on_partial_graphs(name, graph):
    scenario = get_scenario("swarm-10", n_steps=25, settle_time_s=0.0, **GRAPHS[graph])
    first = simulate(scenario, NEW[name](), trigger=True, seed=0)
    again = simulate(scenario, NEW[name](), trigger=True, seed=0)
    assert not first.solve_failed.any()
    np.testing.assert_array_equal(first.states, again.states)
    counts = first.neighbours.sum(axis=2)[first.solved]
    if graph == "range":
        assert len(set(counts.tolist())) >= 3
    else:
        assert set(counts.tolist()) == {3}


@pytest.mark.parametrize("name", ["ipopt", "ltv-osqp"])
def test_the_penalties_keep_the_paper_formation_clear_of_the_obstacles(name):
    """paper-obstacles: without the penalties the formation flies through the first zone."""
    scenario = get_scenario("paper-obstacles", n_steps=120)
    metrics = {}
    for key, sc in (
        ("penalised", scenario),
        ("bare", scenario.with_overrides(w_obstacle=0.0, w_collision=0.0)),
    ):
        trace = simulate(sc, get_optimizer(name), trigger=True, seed=0)
        assert not trace.solve_failed.any()
        metrics[key] = compute_metrics(trace)
    assert metrics["bare"].obstacle_intrusions >= 1
    assert metrics["penalised"].obstacle_intrusions == 0
