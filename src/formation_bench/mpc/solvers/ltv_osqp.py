"""``ltv-osqp``: linear time-varying MPC, the problem of eq. (14) as a QP solved by OSQP.

At each instant the model is linearised about the shifted previous plan ``u0``
(the warm start ``x0`` the loop passes) and its predicted trajectory. The cost
of eq. (14) is quadratic in the positions, so with linear dynamics it is a QP
in the deviation ``du = u - u0``:

``sparse``
    variables ``[du (2B), dx_1 .. dx_H (4H)]``; equality rows
    ``dx_{k+1} = A_k dx_k + B_k du_{b(k)}`` (``dx_0 = 0``: the current state is
    given) and box rows ``lower - u0 <= du <= upper - u0``; ``P`` is constant
    (the cost's Hessian in the positions), ``q`` is the cost's gradient at the
    nominal positions, and ``A``'s values (``A_k``, ``B_k``) change every
    instant on a fixed sparsity pattern.
``condensed`` (default)
    variables ``du`` only: the positions' sensitivities ``G = dp/du`` give the
    dense ``P = G' H G`` (all of its upper triangle kept as entries) and
    ``q = G' g``; ``A`` is the identity. Same solution, 10 variables instead of
    90: on the paper scenario OSQP needs a third of the iterations and the
    95th percentile of the solve time is 5-16 times lower (docs/explanation/gradient-baselines.md).

The collision and obstacle penalties ``w * max(0, r - d)^2`` are not convex in the positions,
and a QP cannot hold them. They enter by their Gauss-Newton model: with the residual
``e = sqrt(delta_T * w) * max(0, r - d)``, the QP's Hessian gains ``2 J' J`` and its gradient
``2 J' e`` (J = de/dp at the nominal positions), which is the penalty on the linearised
distance of every term active along the nominal trajectory. The gradient is exact, the
Hessian stays positive semidefinite, and terms inactive at the nominal (``d >= r``) do not
enter that round's QP; the line search on the true cost below keeps a step into them from
being accepted unless it still lowers the cost. With a penalty the sparse form's ``P``
changes every instant too.

Both are built from the CasADi expression of :mod:`formation_bench.mpc.solvers.casadi_model`
(one call returns every matrix value and vector of an instant; the function is
built once per problem shape, with common subexpressions merged, and evaluated
through CasADi's buffer interface on preallocated arrays: about 7 µs on the paper
problem). Each UAV's QP is set up in OSQP once and then
updated in place at every following instant (vectors, and
matrix values on the sparsity pattern fixed at setup: structural zeros are
kept as explicit entries, so a value that happens to be zero at one instant
never changes the pattern). The OSQP workspace, with its warm start and step
size, is kept while each call continues the plan the previous call returned,
as in the closed loop; a call that does not (the first of a run, one after a
failed solve, a problem out of sequence) sets up a fresh one, so a run never
depends on what the optimiser solved before it. OSQP is called through its
compiled extension (:mod:`formation_bench.mpc.solvers.osqp_workspace`): a set-up
costs about 8 µs there against 0.2 ms through ``osqp.OSQP``, so a fresh set-up is
cheap, and nothing is imported or looked up per call. The workspaces live in the
optimiser's bounded cache (:class:`~formation_bench.mpc.solvers.gradient_common.LruCache`),
keyed by shape, form and UAV; pickling drops them.

After the QP, the true cost is evaluated at ``u0 + alpha du`` for
``alpha in (1, 1/2, 1/4)`` (one batch call of the compiled cost) and the best
point is accepted if it improves on the current one; ``sqp_iterations > 1``
re-linearises about the accepted point and repeats (a fixed-count SQP with a
backtracking line search). The result is never worse than the warm start.

If the first QP is not solved (OSQP status other than ``solved``, e.g. its
iteration limit), the warm start is returned with ``success=False``: the loop
applies it and counts the failure. ``nfev`` counts one per linearisation (the
cost, its gradient and the Jacobians in one CasADi evaluation) plus every row
of the compiled cost (the warm start and the line-search points); OSQP's own
iterations are in ``info``. The Generator is not used.
"""

from __future__ import annotations

import enum
import functools
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from formation_bench.fields import setting, validate_fields
from formation_bench.mpc.model import rollout as numeric_rollout
from formation_bench.mpc.solvers.gradient_common import (
    BufferedFunction,
    SolverCacheMixin,
    fallback_result,
    require_local_problem,
    shift_of,
    warm_start_of,
)
from formation_bench.mpc.solvers.osqp_workspace import OsqpContext, QPWorkspace
from formation_bench.mpc.solvers.problem_shape import STATE_DIM, ProblemShape, pack_parameters
from formation_bench.optimizers.base import (
    BatchObjective,
    Bounds,
    Budget,
    Optimizer,
    OptimizeResult,
    budget_setting,
)

if TYPE_CHECKING:  # casadi, osqp and scipy.sparse are imported when a solver is first built
    import casadi as ca
    import scipy.sparse as sp

    from formation_bench.mpc.problem import LocalProblem
    from formation_bench.mpc.solvers.casadi_model import SymbolicParameters

LINE_SEARCH_STEPS = np.array([1.0, 0.5, 0.25])
"""Step lengths tried along each QP direction (one batch evaluation of the true cost)."""


LINEARISE_OPTIONS = {"cse": True}
"""CasADi options of the linearisation function: common subexpressions computed once (7 µs per
evaluation instead of 10 on the paper problem, the same values)."""


class QPForm(enum.StrEnum):
    """How the linearised problem is written as a QP."""

    SPARSE = "sparse"
    """Controls and states as variables, the linear dynamics as equality rows."""
    CONDENSED = "condensed"
    """Controls only; the states eliminated through the sensitivities dp/du."""


@dataclass
class LtvFunctions:
    """The CasADi function and constant QP data of one problem shape and form."""

    form: QPForm
    linearise: ca.Function
    """``(u0, p) -> (*matrix values, q)``: the nonzeros of the matrices named in
    :attr:`changing`, in that order, then ``q`` (every output dense)."""
    changing: tuple[str, ...]
    """The matrices whose values change every instant, as ``OSQP.update`` names them: ``Px``
    (condensed), ``Ax`` (sparse), ``Ax`` and ``Px`` (sparse with a penalty)."""
    P: sp.csc_matrix
    """P with its fixed pattern (upper triangle); constant for the sparse form without
    penalties."""
    A: sp.csc_matrix
    """A with its fixed pattern; constant (the identity) for the condensed form."""
    n_dynamics_rows: int
    """Rows of A before the box rows on ``du`` (the equality rows of the sparse form)."""
    dim: int
    """Length of ``du``: the first variables of the QP."""
    build_time_s: float
    _linearise: BufferedFunction = field(init=False, repr=False)
    """:attr:`linearise` on preallocated arrays: about 7 µs a call against about 50 µs."""
    _setup_matrices: tuple[sp.csc_matrix, sp.csc_matrix] = field(init=False, repr=False)
    """Copies of P and A whose values :meth:`setup_matrices` overwrites (OSQP copies them)."""

    def __post_init__(self) -> None:
        self._linearise = BufferedFunction(self.linearise)
        self._setup_matrices = (self.P.copy(), self.A.copy())

    def evaluate(
        self, u0: np.ndarray, params: np.ndarray
    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """The changing matrix values by ``OSQP.update`` name, and ``q``, of the QP about ``u0``."""
        call = self._linearise
        call.inputs["u0"][:] = u0
        call.inputs["p"][:] = params
        call()
        named = {name: call.outputs[name].copy() for name in self.changing}
        return named, call.outputs["q"].copy()

    def matrices(self, values: dict[str, np.ndarray]) -> tuple[sp.csc_matrix, sp.csc_matrix]:
        """``P`` and ``A`` with their changing values set to ``values`` (new matrices)."""
        P, A = self.setup_matrices(values)
        return P.copy(), A.copy()

    def setup_matrices(self, values: dict[str, np.ndarray]) -> tuple[sp.csc_matrix, sp.csc_matrix]:
        """:meth:`matrices` without the copies (SciPy's constructor takes 20 µs): the same
        two matrices every call, valid until the next call; for a set-up, which copies them."""
        P, A = self._setup_matrices
        if "Px" in values:
            P.data[:] = values["Px"]
        if "Ax" in values:
            A.data[:] = values["Ax"]
        return P, A

    def bounds_vectors(self, bounds: Bounds, u0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``l`` and ``u`` of an instant: zero on the dynamics rows, the shifted box on ``du``."""
        if not self.n_dynamics_rows:
            return bounds.lower - u0, bounds.upper - u0
        zeros = np.zeros(self.n_dynamics_rows)
        return (
            np.concatenate((zeros, bounds.lower - u0)),
            np.concatenate((zeros, bounds.upper - u0)),
        )


def _csc(matrix: ca.SX, values: np.ndarray) -> sp.csc_matrix:
    """A SciPy CSC matrix with ``matrix``'s CasADi pattern (CSC too) and ``values``."""
    import scipy.sparse as sp

    sparsity = matrix.sparsity()
    return sp.csc_matrix(
        (
            np.asarray(values, dtype=np.float64).reshape(-1),
            np.asarray(sparsity.row(), dtype=np.int64),
            np.asarray(sparsity.colind(), dtype=np.int64),
        ),
        shape=(matrix.size1(), matrix.size2()),
    )


def _upper_dense(matrix: ca.SX) -> tuple[ca.SX, np.ndarray, np.ndarray]:
    """Every upper-triangle entry of a square ``matrix`` in CSC order, zeros included."""
    import casadi as ca

    n = matrix.size1()
    entries, rows, colind = [], [], [0]
    for j in range(n):
        for i in range(j + 1):
            entries.append(matrix[i, j])
            rows.append(i)
        colind.append(len(rows))
    return ca.vertcat(*entries), np.asarray(rows), np.asarray(colind)


def _gauss_newton(
    shape: ProblemShape, positions: list[ca.SX], params: SymbolicParameters, variables: ca.SX
) -> tuple[ca.SX, ca.SX]:
    """Hessian and gradient in ``variables`` of the cost with the penalties' Gauss-Newton model.

    Eq. (14)'s terms are quadratic in the positions: their Hessian is exact. Each penalty
    ``e^2``, ``e = sqrt(delta_T * w) * max(0, r - d)``, enters with ``2 J' J`` (J the Jacobian
    of e): its curvature term ``2 e d2e``, negative across the distance, is dropped so that P
    stays positive semidefinite. The gradient ``2 J' e`` is exact, so the QP's model agrees
    with the cost in value and slope at the linearisation point; terms inactive there
    (``d >= r``) have ``J = 0`` and do not enter the QP.
    """
    import casadi as ca

    from formation_bench.mpc.solvers.casadi_model import horizon_cost, penalty_residuals

    quadratic = horizon_cost(shape, positions, params, penalties=False)
    hessian, gradient = ca.hessian(quadratic, variables)
    residuals = penalty_residuals(shape, positions, params)
    jacobian = ca.jacobian(residuals, variables)
    return hessian + 2 * (jacobian.T @ jacobian), gradient + 2 * (jacobian.T @ residuals)


def build_functions(shape: ProblemShape, form: QPForm) -> LtvFunctions:
    """Linearisation function and QP patterns of ``shape`` in ``form``."""
    import casadi as ca
    import scipy.sparse as sp

    from formation_bench.mpc.solvers.casadi_model import (
        block_controls,
        horizon_cost,
        period_step,
        rollout,
        symbolic_parameters,
    )

    start = time.perf_counter()
    params = symbolic_parameters(shape)
    u = ca.SX.sym("u", shape.dim)
    horizon = shape.horizon_steps
    nominal = rollout(shape, params.state, u)  # states 1..H along u
    dim = shape.dim
    if form == QPForm.SPARSE:
        x = ca.SX.sym("x", STATE_DIM, horizon)
        gaps = []
        previous = params.state
        for k in range(horizon):
            control = block_controls(u, shape.block_of_step[k])
            gaps.append(
                x[:, k] - period_step(previous, control, shape.period_s, shape.rk4_substeps)
            )
            previous = x[:, k]
        variables = ca.vertcat(u, ca.vec(x))
        rows = ca.vertcat(*gaps, u)  # dynamics gaps, then the box rows on u
        jacobian = ca.jacobian(rows, variables)
        positions = [x[:2, k] for k in range(horizon)]
        if shape.penalised:
            hessian, gradient = _gauss_newton(shape, positions, params, variables)
            upper = ca.triu(hessian)
            P = _csc(upper, np.ones(upper.nnz()))
            changing: tuple[str, ...] = ("Ax", "Px")
            outputs = [ca.vertcat(*jacobian.nonzeros()), ca.vertcat(*upper.nonzeros())]
        else:
            cost = horizon_cost(shape, positions, params)
            hessian, gradient = ca.hessian(cost, variables)
            if ca.depends_on(hessian, ca.vertcat(variables, params.vector)):
                raise AssertionError("the cost of eq. (14) must be quadratic in the positions")
            upper = ca.triu(hessian)
            P = _csc(upper, np.asarray(ca.Function("P", [], [upper])()["o0"].nonzeros()))
            changing = ("Ax",)
            outputs = [ca.vertcat(*jacobian.nonzeros())]
        # evaluate the Jacobian, the gradient (and P) along the nominal trajectory of u
        at_nominal = ca.Function("at", [u, x, params.vector], [*outputs, ca.densify(gradient)])
        values = at_nominal(u, ca.horzcat(*nominal), params.vector)
        linearise = ca.Function(
            "ltv_sparse",
            [u, params.vector],
            [ca.densify(value) for value in values],  # the buffer interface writes nonzeros
            ["u0", "p"],
            [*changing, "q"],
            LINEARISE_OPTIONS,
        )
        A = _csc(jacobian, np.ones(jacobian.nnz()))
        n_dynamics_rows = STATE_DIM * horizon
    else:
        positions = ca.vertcat(*[z[:2] for z in nominal])
        p_sym = ca.SX.sym("pos", 2, horizon)
        p_columns = [p_sym[:, k] for k in range(horizon)]
        if shape.penalised:
            hessian_p, gradient_p = _gauss_newton(shape, p_columns, params, ca.vec(p_sym))
        else:
            cost = horizon_cost(shape, p_columns, params)
            hessian_p, gradient_p = ca.hessian(cost, ca.vec(p_sym))
        sensitivity = ca.jacobian(positions, u)
        at = ca.Function("at", [ca.vec(p_sym), params.vector], [hessian_p, gradient_p])
        h_val, g_val = at(positions, params.vector)
        p_matrix = sensitivity.T @ h_val @ sensitivity
        p_values, p_rows, p_colind = _upper_dense(p_matrix)
        q = sensitivity.T @ g_val
        changing = ("Px",)
        linearise = ca.Function(
            "ltv_condensed",
            [u, params.vector],
            [ca.densify(p_values), ca.densify(q)],
            ["u0", "p"],
            ["Px", "q"],
            LINEARISE_OPTIONS,
        )
        P = sp.csc_matrix((np.ones(len(p_rows)), p_rows, p_colind), shape=(dim, dim))
        A = sp.csc_matrix(sp.identity(dim, format="csc"))
        n_dynamics_rows = 0
    return LtvFunctions(
        form, linearise, changing, P, A, n_dynamics_rows, dim, time.perf_counter() - start
    )


@dataclass
class _UavSolver:
    """One UAV's OSQP workspace and the plan its last call returned."""

    workspace: QPWorkspace
    decision: np.ndarray | None = None
    """The decision the last call returned (None until a call has finished)."""
    states: np.ndarray | None = None
    """Its predicted states ``(H + 1, 4)``."""


@dataclass(frozen=True)
class LtvOsqpOptimizer(SolverCacheMixin, Optimizer):
    """Linear time-varying MPC: linearise about the shifted plan, solve the QP with OSQP."""

    CARRIED: ClassVar[frozenset[str]] = frozenset({"osqp"})  # each UAV's warm workspace

    form: QPForm = setting(
        QPForm.CONDENSED,
        doc="QP transcription: condensed (controls only) or sparse (states as variables too)",
    )
    """The default was chosen by measurement (docs/explanation/gradient-baselines.md)."""
    sqp_iterations: int = budget_setting(
        1,
        doc="Linearise-solve-line-search rounds per instant when the caller gives no budget",
    )  # fmt: skip
    """A budget's ``max_iterations`` replaces it (its ``max_evaluations`` is ignored)."""
    eps_abs: float = setting(
        1e-4, low=0.0, low_open=True, doc="OSQP's absolute tolerance (OSQP's default is 1e-3)"
    )
    eps_rel: float = setting(
        1e-4, low=0.0, low_open=True, doc="OSQP's relative tolerance (OSQP's default is 1e-3)"
    )
    max_iter: int = setting(20_000, low=1, doc="OSQP's iteration limit per QP")
    """OSQP's default 4000 is too few for some start-up instants of the paper scenario (see
    docs/explanation/gradient-baselines.md)."""
    polishing: bool | None = setting(
        None, kind=bool, optional=True,
        doc="OSQP's solution polishing; None = on for the sparse form, off for the condensed one",
    )  # fmt: skip
    """Polishing is an active-set refinement after ADMM; off for the condensed form, where OSQP
    prints a line whenever no bound is active, even with ``verbose`` off."""

    def __post_init__(self) -> None:
        validate_fields(self)

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.sqp_iterations)

    def functions(self, shape: ProblemShape) -> LtvFunctions:
        """The linearisation function of ``shape`` (built once, shared by all UAVs)."""
        key = ("functions", shape, self.form)
        functions = self._solver_cache.get(key)
        if functions is None:
            functions = build_functions(shape, self.form)
            self._solver_cache[key] = functions
        return functions

    def settings(self) -> dict[str, Any]:
        """The OSQP settings of this configuration."""
        polishing = self.form == QPForm.SPARSE if self.polishing is None else self.polishing
        return {
            "verbose": False,
            "eps_abs": self.eps_abs,
            "eps_rel": self.eps_rel,
            "max_iter": self.max_iter,
            "polishing": polishing,
            "warm_starting": True,
        }

    def osqp_context(self) -> OsqpContext:
        """OSQP's extension and this configuration's settings (one per settings, per process)."""
        return _osqp_context(tuple(self.settings().items()))

    def setup(
        self,
        functions: LtvFunctions,
        matrix_values: dict[str, np.ndarray],
        q: np.ndarray,
        lower: np.ndarray,
        upper: np.ndarray,
    ) -> QPWorkspace:
        """A new OSQP workspace of the QP with these values on ``functions``' patterns."""
        P, A = functions.setup_matrices(matrix_values)
        return self.osqp_context().setup(P, q, A, lower, upper)

    def minimize(
        self,
        objective: BatchObjective,
        bounds: Bounds,
        rng: np.random.Generator,
        budget: Budget | None = None,
        x0: np.ndarray | None = None,
    ) -> OptimizeResult:
        problem = require_local_problem(type(self).__name__, objective)
        budget = self.solve_budget(budget)
        rounds = (
            self.sqp_iterations if budget.max_iterations is None else int(budget.max_iterations)
        )
        x0 = warm_start_of(problem, bounds, x0)
        start = time.perf_counter()
        shape = ProblemShape.of(problem)
        functions = self.functions(shape)
        params = pack_parameters(problem, shape)
        # This UAV's OSQP workspace carries its warm start and step size from call to call. It
        # is kept only when this call continues the plan the previous call returned (same run,
        # same UAV); otherwise a fresh one is set up (8 µs), so a run never depends on earlier
        # runs: updating a workspace set up on another QP would rescale the data from the old
        # scaling, and its rounding would carry that QP into this solve.
        key = ("osqp", shape, self.form, problem.uav)
        entry: _UavSolver | None = self._solver_cache.pop(key, None)
        if entry is not None and (
            entry.decision is None
            or entry.states is None
            or shift_of(problem, entry.decision, entry.states, x0) is None
        ):
            entry = None
        current = x0
        current_cost = float(problem(x0[None])[0])
        nfev = 1
        history_nfev, history_fun = [nfev], [current_cost]
        statuses: list[str] = []
        qp_iterations: list[int] = []
        qp_steps: list[np.ndarray] = []
        qp_time = 0.0
        fresh_setup = entry is None
        setup_time_s = 0.0
        message = "SQP rounds done"
        nit = 0
        failed = False
        for round_ in range(rounds):
            left_s = (
                None
                if budget.deadline_s is None
                else budget.deadline_s - (time.perf_counter() - start)
            )
            if left_s is not None and left_s <= 0 and round_ > 0:
                message = f"deadline reached after {round_} rounds"
                break
            matrix_values, q = functions.evaluate(current, params)
            nfev += 1
            lower, upper = functions.bounds_vectors(bounds, current)
            if entry is None:
                entry = _UavSolver(self.setup(functions, matrix_values, q, lower, upper))
                setup_time_s = entry.workspace.setup_time_s
            else:
                entry.workspace.update(q, lower, upper, **matrix_values)
            # OSQP stops at its time limit with the status saying so
            entry.workspace.limit_time(None if left_s is None else max(left_s, 1e-6))
            outcome = entry.workspace.solve()
            statuses.append(outcome.status)
            qp_iterations.append(outcome.iterations)
            qp_time += outcome.run_time_s
            if not outcome.solved:
                if round_ == 0:
                    failed = True
                else:
                    message = f"stopped: OSQP {statuses[-1]} in round {round_ + 1}"
                break
            step = outcome.x[: functions.dim]
            qp_steps.append(step)
            candidates = bounds.clip(current + LINE_SEARCH_STEPS[:, None] * step)
            costs = problem(candidates)
            nfev += len(LINE_SEARCH_STEPS)
            nit += 1
            best = int(np.argmin(costs))
            if not costs[best] < current_cost:
                history_nfev.append(nfev)
                history_fun.append(current_cost)
                message = f"no descent along the QP direction in round {round_ + 1}"
                break
            current, current_cost = candidates[best], float(costs[best])
            history_nfev.append(nfev)
            history_fun.append(current_cost)
        info: dict[str, Any] = {
            "form": self.form.value,
            "osqp_status": statuses,
            "osqp_iterations": qp_iterations,
            "osqp_run_time_s": qp_time,
            "qp_steps": qp_steps,
            "osqp_setup": fresh_setup,
            "osqp_setup_time_s": setup_time_s,
            "build_time_s": functions.build_time_s,
        }
        if entry is not None and not failed:
            scenario = problem.scenario
            entry.decision = current.copy()
            entry.states = numeric_rollout(
                problem.state,
                problem.controls(current),
                scenario.timing.period_s,
                scenario.timing.rk4_substeps,
            )
            self._solver_cache[key] = entry
        info["solve_time_s"] = time.perf_counter() - start
        if failed:
            return fallback_result(x0, current_cost, nfev, 0, f"OSQP: {statuses[-1]}", info)
        return OptimizeResult(
            x=current.copy(),
            fun=current_cost,
            nfev=nfev,
            nit=nit,
            success=True,
            message=message,
            history_nfev=np.asarray(history_nfev, dtype=np.int64),
            history_fun=np.asarray(history_fun),
            info=info,
        )


def qp_data(
    optimizer: LtvOsqpOptimizer, problem: LocalProblem, u0: np.ndarray
) -> tuple[sp.csc_matrix, np.ndarray, sp.csc_matrix, np.ndarray, np.ndarray]:
    """``(P, q, A, l, u)`` of the QP the optimiser poses at ``u0`` (for tests and docs)."""
    shape = ProblemShape.of(problem)
    functions = optimizer.functions(shape)
    matrix_values, q = functions.evaluate(u0, pack_parameters(problem, shape))
    P, A = functions.matrices(matrix_values)
    lower, upper = functions.bounds_vectors(problem.bounds, u0)
    return P, q, A, lower, upper


@functools.lru_cache(maxsize=16)
def _osqp_context(settings: tuple[tuple[str, Any], ...]) -> OsqpContext:
    """The :class:`OsqpContext` of ``settings`` (OSQP's names and values), built once per
    process; the configurations that share settings share it (it holds no solver state)."""
    return OsqpContext.build(dict(settings))
