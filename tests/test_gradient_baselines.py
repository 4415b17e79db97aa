"""The derivative-based baselines ``ipopt``, ``ltv-osqp`` and ``ilqr`` on the paper's problem."""

from __future__ import annotations

import json
import math
import pickle

import numpy as np
import pytest
import scipy.sparse as sp

from formation_bench.cli.main import main as cli_main
from formation_bench.instances.instants import record_instants
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.metrics import compute_metrics
from formation_bench.mpc.problem import LocalProblem
from formation_bench.mpc.scenario import PAPER, get_scenario
from formation_bench.mpc.solvers.casadi_model import (
    ProblemShape,
    casadi_cost,
    pack_parameters,
    projected_gradient,
)
from formation_bench.mpc.solvers.ipopt_solver import IpoptOptimizer
from formation_bench.mpc.solvers.ltv_cvxpy import CvxpyLtvQP
from formation_bench.mpc.solvers.ltv_osqp import LtvOsqpOptimizer, qp_data
from formation_bench.optimizers import OPTIMIZERS, Budget, PopulationOptimizer, get_optimizer

SHORT = get_scenario("paper", n_steps=8, settle_time_s=0.0)
PAPER_BOUNDS = LocalProblem(
    PAPER, 0, np.zeros(4), np.zeros((2, 20, 2)), np.zeros((2, 20, 2)), np.zeros((20, 2))
).bounds

GRADIENT_SOLVERS = ["ipopt", "ltv-osqp", "ilqr"]
"""The derivative-based baselines the shared checks run on."""


def random_problem(rng: np.random.Generator, scenario, uav: int = 0) -> LocalProblem:
    horizon, n_nb = scenario.timing.horizon_steps, scenario.n_uav - 1
    state = np.array(
        [rng.normal(0, 20), rng.normal(0, 20), rng.uniform(-math.pi, math.pi), rng.uniform(5, 20)]
    )
    return LocalProblem(
        scenario,
        uav,
        state,
        rng.normal(0, 30, size=(n_nb, horizon, 2)),
        rng.normal(0, 10, size=(n_nb, horizon, 2)),
        rng.normal(0, 30, size=(horizon, 2)),
    )


@pytest.fixture(scope="module")
def instants():
    """Problems of the paper scenario as a modified-BSO run posed them (all three UAVs)."""
    return record_instants(get_scenario("paper"), get_optimizer("modified-bso"), [5, 40], seed=1)


# --- one source of truth for the cost -----------------------------------------------------------


@pytest.mark.parametrize(
    ("n_blocks", "substeps", "w_dst", "w_trj", "n_uav"),
    [(5, 1, 1.0, 3.0, 3), (20, 1, 0.3, 2.5, 3), (3, 3, 1.7, 0.0, 3), (4, 2, 1.0, 1.0, 4)],
)
def test_casadi_compiled_and_plain_costs_agree(n_blocks, substeps, w_dst, w_trj, n_uav):
    scenario = PAPER.with_overrides(
        n_blocks=n_blocks, rk4_substeps=substeps, w_dst=w_dst, w_trj=w_trj
    )
    if n_uav != scenario.n_uav:
        offsets = ((10.0, -10.0), (-10.0, -10.0), (-10.0, 10.0), (10.0, 10.0))
        states = (*scenario.initial_states, (0.0, 20.0, 0.0, 15.0))
        scenario = scenario.with_overrides(initial_states=states, formation_offsets=offsets)
    rng = np.random.default_rng(n_blocks * 10 + substeps)
    for _ in range(4):
        problem = random_problem(rng, scenario, uav=int(rng.integers(scenario.n_uav)))
        decisions = problem.bounds.sample(rng, 12)
        compiled = problem(decisions)
        symbolic = casadi_cost(problem, decisions)
        plain = np.array([problem.reference_cost(d) for d in decisions])
        np.testing.assert_allclose(symbolic, compiled, rtol=1e-9)
        np.testing.assert_allclose(symbolic, plain, rtol=1e-9)
        np.testing.assert_allclose(compiled, plain, rtol=1e-9)


# --- ipopt ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("shooting", ["single", "multiple"])
def test_ipopt_solution_is_a_kkt_point_better_than_the_warm_start(instants, shooting):
    optimizer = IpoptOptimizer(shooting=shooting)
    for inst in instants:
        problem = inst.problem
        result = optimizer.minimize(
            problem, problem.bounds, np.random.default_rng(0), None, inst.warm_start
        )
        assert result.success, result.message
        assert problem.bounds.contains(result.x)
        assert result.fun == pytest.approx(problem(result.x[None])[0], rel=1e-12)
        assert result.fun < problem(inst.warm_start[None])[0]
        start = np.abs(projected_gradient(problem, inst.warm_start, 1e-6)).max()
        final = np.abs(projected_gradient(problem, result.x, 1e-6)).max()
        assert final <= 1e-4 * max(1.0, start), (inst.step, inst.uav, final, start)
        assert result.info["return_status"] == "Solve_Succeeded"
        assert result.info["iterations"] == result.nit >= 1
        info = result.info
        assert 0 < info["evaluation_wall_s"] < info["ipopt_wall_s"] <= info["solve_time_s"]
        assert info["ipopt_own_s"] == pytest.approx(
            info["ipopt_wall_s"] - info["evaluation_wall_s"]
        )
        assert result.nfev == sum(result.info["casadi_counts"].values()) + 2
        again = optimizer.minimize(
            problem, problem.bounds, np.random.default_rng(0), None, inst.warm_start
        )  # the counters are this call's, not summed over the solver's calls
        assert again.info["casadi_counts"] == result.info["casadi_counts"]


def test_both_shootings_find_the_same_optimum(instants):
    for inst in instants:
        problem = inst.problem
        a, b = (
            IpoptOptimizer(shooting=s).minimize(
                problem, problem.bounds, np.random.default_rng(0), None, inst.warm_start
            )
            for s in ("single", "multiple")
        )
        assert a.fun == pytest.approx(b.fun, rel=1e-7)


def test_no_population_optimizer_beats_ipopt_from_the_same_warm_start(instants):
    """On a fixed recorded instant; a population optimiser below IPOPT would be a finding."""
    inst = instants[0]  # UAV 1 at instant 5: the formation is still forming
    problem = inst.problem
    best = get_optimizer("ipopt").minimize(
        problem, problem.bounds, np.random.default_rng(0), None, inst.warm_start
    )
    population = [n for n, e in OPTIMIZERS.items() if isinstance(e.optimizer, PopulationOptimizer)]
    assert "modified-bso" in population
    for name in population:
        for seed in range(2):
            result = OPTIMIZERS[name].optimizer.minimize(
                problem, problem.bounds, np.random.default_rng(seed), None, inst.warm_start
            )
            assert result.fun >= best.fun * (1 - 1e-9), (name, seed, result.fun, best.fun)


def test_dual_warm_start_is_used_only_when_continuing_the_previous_plan():
    optimizer = get_optimizer("ipopt")
    trace_infos = []

    class Spy:
        default_budget = optimizer.default_budget

        def minimize(self, objective, bounds, rng, budget=None, x0=None):
            result = optimizer.minimize(objective, bounds, rng, budget, x0)
            trace_infos.append(result.info["dual_warm_start"])
            return result

    simulate(SHORT, Spy(), trigger=False, seed=0)
    assert trace_infos[:3] == [False, False, False]  # first solve of each UAV: nothing to continue
    assert all(trace_infos[3:])
    trace_infos.clear()
    simulate(SHORT, Spy(), trigger=False, seed=0)  # a new run does not continue the last one
    assert trace_infos[:3] == [False, False, False]


# --- ltv-osqp -------------------------------------------------------------------------------------


@pytest.mark.parametrize("form", ["sparse", "condensed"])
def test_osqp_path_matches_the_cvxpy_reference(form):
    """Every first QP step of a short run (set up, then updated in place) against cvxpy."""
    tight = LtvOsqpOptimizer(
        form=form, eps_abs=1e-9, eps_rel=1e-9, max_iter=400_000, polishing=form == "sparse"
    )
    solves = []

    class Spy:
        default_budget = tight.default_budget

        def minimize(self, objective, bounds, rng, budget=None, x0=None):
            result = tight.minimize(objective, bounds, rng, budget, x0)
            solves.append((objective, x0, result))
            return result

    simulate(get_scenario("paper", n_steps=4, settle_time_s=0.0), Spy(), trigger=False, seed=0)
    reference = CvxpyLtvQP.build(ProblemShape.of(solves[0][0]))
    # in box widths; the condensed Hessian's condition number (~1e4 in box units) turns OSQP's
    # 1e-9 residuals into ~1e-6 errors in its weakest directions
    atol = {"sparse": 1e-6, "condensed": 2e-5}
    for problem, x0, result in solves:
        assert result.success, result.message
        expected = reference.solve(
            problem, x0, tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12
        )
        width = problem.bounds.width
        np.testing.assert_allclose(
            result.info["qp_steps"][0] / width, expected / width, atol=atol[form]
        )
    # the first solve of each UAV sets its OSQP instance up, the others update it in place
    assert [r.info["osqp_setup"] for _, _, r in solves] == [True] * 3 + [False] * 9


@pytest.mark.parametrize("form", ["sparse", "condensed"])
def test_matrix_pattern_keeps_structural_zeros(form):
    """Values that are zero at setup (heading 0, speed 0) stay entries: updates keep the pattern."""
    optimizer = LtvOsqpOptimizer(form=form, eps_abs=1e-9, eps_rel=1e-9, max_iter=100_000)
    rng = np.random.default_rng(3)
    still = random_problem(rng, PAPER)
    still.state[2:] = 0.0  # heading and speed zero: d(x, y)/d(theta, v, omega) vanish
    moving = random_problem(rng, PAPER)
    functions = optimizer.functions(ProblemShape.of(still))
    u0 = np.zeros(still.dim)
    zero_values, q0 = functions.evaluate(u0, pack_parameters(still))
    values, q = functions.evaluate(u0, pack_parameters(moving))
    name = "Ax" if form == "sparse" else "Px"
    assert functions.changing == (name,)
    changing = functions.A if form == "sparse" else functions.P
    assert zero_values[name].size == values[name].size == changing.nnz
    assert np.sum(zero_values[name] == 0.0) > np.sum(values[name] == 0.0)
    lower0, upper0 = functions.bounds_vectors(still.bounds, u0)
    lower, upper = functions.bounds_vectors(moving.bounds, u0)
    workspace = optimizer.setup(functions, zero_values, q0, lower0, upper0)
    workspace.update(q, lower, upper, **values)
    updated = workspace.solve()
    fresh = optimizer.setup(functions, values, q, lower, upper).solve()
    assert updated.solved and fresh.solved
    np.testing.assert_allclose(updated.x, fresh.x, atol=1e-5)


def _full(upper: sp.csc_matrix) -> np.ndarray:
    dense = upper.toarray()
    return dense + dense.T - np.diag(np.diag(dense))


def _osqp_error_bound(optimizer: LtvOsqpOptimizer, problem: LocalProblem, u0, du) -> float:
    """How far two OSQP solutions of the QP at ``u0`` may lie apart in ``du`` (max norm).

    OSQP stops when the dual residual ``P x + q + A'y`` is at most ``eps_abs + eps_rel * s``
    (s the largest of its terms' max norms) and the primal residual at most ``eps_abs +
    eps_rel * |x|``. The QP in ``du`` (condensed: the same QP with the states eliminated) has
    the Hessian ``P_c``, so a dual residual r moves ``du`` by at most ``|r| / lambda_min(P_c)``;
    two solutions lie within twice the sum of the two effects.
    """
    condensed = LtvOsqpOptimizer(form="condensed")
    P, q, *_ = qp_data(condensed, problem, u0)
    hessian = _full(P)
    weakest = float(np.linalg.eigvalsh(hessian)[0])
    assert weakest > 0
    scale = max(np.abs(hessian @ du).max(), np.abs(q).max(), np.abs(hessian @ du + q).max())
    eps_abs, eps_rel = optimizer.eps_abs, optimizer.eps_rel
    dual = (eps_abs + eps_rel * scale) / weakest
    primal = eps_abs + eps_rel * np.abs(du).max()
    return 2.0 * (dual + primal)


@pytest.mark.parametrize("form", ["sparse", "condensed"])
def test_an_updated_osqp_workspace_solves_like_a_fresh_one(form):
    """The closed loop updates each UAV's OSQP workspace in place (its warm start and step size
    carried over); a workspace set up on one random problem is updated with another. Both
    solve each QP like a workspace set up on it afresh, within OSQP's tolerances."""
    optimizer = LtvOsqpOptimizer(form=form, eps_abs=1e-9, eps_rel=1e-9, max_iter=400_000)
    solves = []

    class Spy:
        default_budget = optimizer.default_budget

        def minimize(self, objective, bounds, rng, budget=None, x0=None):
            result = optimizer.minimize(objective, bounds, rng, budget, x0)
            solves.append((objective, x0, result.info))
            return result

    simulate(get_scenario("paper", n_steps=8, settle_time_s=0.0), Spy(), trigger=False, seed=0)
    updated = [(problem, x0, info["qp_steps"][0]) for problem, x0, info in solves[3:]]
    assert not any(info["osqp_setup"] for *_, info in solves[3:])  # updated, not set up
    rng = np.random.default_rng(11)
    previous = random_problem(rng, PAPER)
    workspace = optimizer.setup(*_qp_values(optimizer, previous, np.zeros(previous.dim)))
    for _ in range(6):
        problem, u0 = random_problem(rng, PAPER), rng.uniform(-1.0, 1.0, PAPER_BOUNDS.dim)
        u0 = problem.bounds.clip(u0)
        _, values, q, lower, upper = _qp_values(optimizer, problem, u0)
        workspace.update(q, lower, upper, **values)
        outcome = workspace.solve()
        assert outcome.solved
        updated.append((problem, u0, outcome.x[: problem.dim]))
    for problem, u0, step in updated:
        functions, values, q, lower, upper = _qp_values(optimizer, problem, u0)
        fresh = optimizer.setup(functions, values, q, lower, upper).solve()
        assert fresh.solved
        bound = _osqp_error_bound(optimizer, problem, u0, fresh.x[: problem.dim])
        assert np.abs(step - fresh.x[: problem.dim]).max() <= bound


def _qp_values(optimizer: LtvOsqpOptimizer, problem: LocalProblem, u0: np.ndarray):
    functions = optimizer.functions(ProblemShape.of(problem))
    values, q = functions.evaluate(u0, pack_parameters(problem))
    lower, upper = functions.bounds_vectors(problem.bounds, u0)
    return functions, values, q, lower, upper


def test_ltv_osqp_is_never_worse_than_its_warm_start_and_iterates(instants):
    for sqp in (1, 3):
        optimizer = LtvOsqpOptimizer(sqp_iterations=sqp)
        for inst in instants:
            problem = inst.problem
            result = optimizer.minimize(
                problem, problem.bounds, np.random.default_rng(0), None, inst.warm_start
            )
            assert result.success, result.message
            assert problem.bounds.contains(result.x)
            assert result.fun <= problem(inst.warm_start[None])[0]
            assert result.fun == pytest.approx(problem(result.x[None])[0], rel=1e-12)
            assert 1 <= len(result.info["osqp_status"]) <= sqp
            assert np.all(np.diff(result.history_fun) <= 0)
    capped = LtvOsqpOptimizer(sqp_iterations=5).minimize(
        problem, problem.bounds, np.random.default_rng(0), Budget(max_iterations=2), inst.warm_start
    )
    assert len(capped.info["osqp_status"]) <= 2


# --- both: interface, failures, closed loop -------------------------------------------------------


@pytest.mark.parametrize("name", GRADIENT_SOLVERS)
def test_needs_a_local_problem(name):
    with pytest.raises(TypeError, match="LocalProblem"):
        get_optimizer(name).minimize(
            lambda x: np.sum(x**2, axis=1),
            PAPER_BOUNDS,
            np.random.default_rng(0),
        )


@pytest.mark.parametrize(
    ("name", "override"),
    [
        ("ipopt", {"shooting": "triple"}),
        ("ipopt", {"ipopt_options": (("tol",),)}),
        ("ipopt", {"tol": 0.0}),
        ("ltv-osqp", {"form": "dense"}),
        ("ltv-osqp", {"sqp_iterations": 0}),
    ],
)
def test_bad_fields_are_refused(name, override):
    with pytest.raises(ValueError, match=next(iter(override))):
        get_optimizer(name, **override)


@pytest.mark.parametrize(("name", "override"), [("ipopt", "max_iter"), ("ltv-osqp", "max_iter")])
@pytest.mark.parametrize("trigger", [False, True])
def test_forced_failure_falls_back_to_the_shifted_plan_and_is_counted(name, override, trigger):
    optimizer = get_optimizer(name, **{override: 1})
    trace = simulate(SHORT, optimizer, trigger=trigger, seed=0)
    metrics = compute_metrics(trace)
    assert trace.solved[0].all()
    assert np.array_equal(trace.solve_failed, trace.solved)  # every solve failed ...
    assert metrics.solve_failures == int(trace.solved.sum()) > 0
    # ... and every UAV flew its shifted previous plan: the zero-control coasting plan of t0
    np.testing.assert_array_equal(trace.controls, 0.0)
    assert np.all(np.isfinite(trace.states))


@pytest.mark.parametrize("name", GRADIENT_SOLVERS)
def test_a_solver_error_is_a_counted_failure_not_an_exception(name):
    problem = random_problem(np.random.default_rng(0), PAPER)
    problem.reference[3] = np.nan  # the cost cannot be evaluated anywhere
    x0 = np.zeros(problem.dim)
    result = get_optimizer(name).minimize(
        problem, problem.bounds, np.random.default_rng(0), None, x0
    )
    assert not result.success
    np.testing.assert_array_equal(result.x, x0)


@pytest.mark.parametrize("name", GRADIENT_SOLVERS)
def test_deterministic_picklable_and_run_independent(name):
    scenario = get_scenario("paper", n_steps=30, settle_time_s=0.0)
    optimizer = get_optimizer(name)
    first = simulate(scenario, optimizer, trigger=True, seed=0)
    again = simulate(scenario, optimizer, trigger=True, seed=0)  # used instance, warm caches
    copy = pickle.loads(pickle.dumps(optimizer))
    assert copy == optimizer and copy._solver_cache == {}
    fresh = simulate(scenario, copy, trigger=True, seed=0)
    for other in (again, fresh):
        np.testing.assert_array_equal(other.states, first.states)
        np.testing.assert_array_equal(other.solved, first.solved)
    assert not first.solve_failed.any()


@pytest.mark.slow
def test_cli_runs_every_baseline_with_and_without_trigger(tmp_path, capfd):
    short = ["--set", "n_steps=15", "--set", "settle_time_s=1.0"]
    for name in GRADIENT_SOLVERS:
        for flag in ("--trigger", "--no-trigger"):
            out_dir = tmp_path / f"{name}{flag}"
            code = cli_main(["run", "--optimizer", name, flag, *short, "--out", str(out_dir)])
            assert code == 0
            out, err = capfd.readouterr()
            assert err == ""  # quiet: nothing from IPOPT or OSQP on either stream
            assert out.count("\n") == 2  # the summary line and the "wrote" line only
            (metrics,) = json.loads((out_dir / "metrics.json").read_text())
            assert metrics["optimizer"] == name
            assert metrics["trigger"] is (flag == "--trigger")
            assert metrics["solve_failures"] == 0
            assert metrics["nfev_total"] > 0
