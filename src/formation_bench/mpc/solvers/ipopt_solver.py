"""``ipopt``: the per-UAV problem of eq. (14) solved by IPOPT through CasADi's ``nlpsol``.

The decision vector and bounds are those the population optimisers search
(``[a_1, omega_1, ..., a_B, omega_B]`` in the UAV's control box, ``problem.bounds``). The
problem is written once in CasADi symbols (:mod:`formation_bench.mpc.solvers.casadi_model`)
with the instant's numbers (state, neighbour estimates, desired offsets, reference) as
parameters, handed to ``nlpsol`` once per problem shape, and re-used at every
instant and by every UAV. The collision and obstacle penalties are in the NLP exactly, with
the exact distance (``max(0, r - d)^2`` is C1; IPOPT gets its exact Hessian, which jumps where
a penalty starts). Two transcriptions:

- ``single`` shooting: the states are eliminated; IPOPT sees ``2 B`` box-bounded
  variables and no constraints;
- ``multiple`` shooting: the predicted states ``x_1..x_H`` are variables too,
  tied by ``H`` equality constraints ``x_{k+1} = F(x_k, u_k)``; the Hessian is
  block sparse but the KKT system is larger.

Warm start: the primal point is the shifted previous plan the loop passes as
``x0`` (and, for multiple shooting, the states it predicts). With
``warm_start_duals`` the multipliers of this UAV's previous solve, shifted by
the periods elapsed, start IPOPT's dual iterates (``warm_start_init_point``);
they are used only when ``x0`` is exactly that solve's plan shifted (see
:func:`formation_bench.mpc.solvers.gradient_common.shift_of`), so a run never depends on what the
optimiser solved before it.

A solve that does not end in ``Solve_Succeeded`` or ``Solved_To_Acceptable_Level``
(iteration limit, restoration failure, an exception) returns the warm start
with ``success=False``; the closed loop applies it and counts the failure.
``nfev`` is the sum of CasADi's evaluation counters (objective, gradient,
constraints, their Jacobian, the Lagrangian Hessian) plus the two compiled
evaluations that compare the solution with the warm start. The Generator is
not used.
"""

from __future__ import annotations

import enum
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
from formation_bench.mpc.solvers.problem_shape import STATE_DIM, ProblemShape, pack_parameters
from formation_bench.optimizers.base import (
    BatchObjective,
    Bounds,
    Budget,
    Optimizer,
    OptimizeResult,
    budget_setting,
)

if TYPE_CHECKING:
    import casadi as ca

SUCCESS_STATUSES = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
DEADLINE_STATUS = "Maximum_WallTime_Exceeded"
"""IPOPT's status at a solve's deadline: its iterate is the best point so far, within bounds."""
EVALUATION_COUNTERS = (
    "n_call_nlp_f",
    "n_call_nlp_grad_f",
    "n_call_nlp_g",
    "n_call_nlp_jac_g",
    "n_call_nlp_hess_l",
    "n_call_nlp_grad",
)
"""CasADi's counters of objective and derivative evaluations that make up ``nfev``."""


class Shooting(enum.StrEnum):
    """How the prediction model enters the NLP."""

    SINGLE = "single"
    """States eliminated by forward simulation: variables = the decision vector."""
    MULTIPLE = "multiple"
    """States are variables tied by equality constraints (one per period)."""


@dataclass
class _Solver:
    """A built ``nlpsol`` and what calling it needs."""

    nlpsol: ca.Function
    dim: int
    n_states: int
    build_time_s: float
    _defaults: dict[str, float] = field(init=False, repr=False)
    _call: BufferedFunction = field(init=False, repr=False)
    """:attr:`nlpsol` on preallocated arrays: an ordinary call converts its 8 arguments and
    6 results to and from DM, about 0.1 ms per call."""
    last_stats: dict[str, Any] = field(init=False, repr=False, default_factory=dict)
    """CasADi's statistics of the last :meth:`solve`."""

    def __post_init__(self) -> None:
        nlpsol = self.nlpsol
        self._defaults = {n: float(nlpsol.default_in(i)) for i, n in enumerate(nlpsol.name_in())}
        self._call = BufferedFunction(nlpsol)

    def solve(self, arguments: dict[str, np.ndarray | float]) -> dict[str, np.ndarray]:
        """``nlpsol`` on ``arguments`` (by nlpsol's input names; the others take nlpsol's
        defaults, as in an ordinary call); copies of its results by name. :attr:`last_stats`
        holds CasADi's statistics of this call, also when it raises."""
        call = self._call
        for name, array in call.inputs.items():
            array[:] = arguments.get(name, self._defaults[name])
        try:
            call()
        finally:
            self.last_stats = call.stats()
        return {name: array.copy() for name, array in call.outputs.items()}


@dataclass
class _Memory:
    """What a UAV's last successful solve leaves for the next one (dual warm start)."""

    decision: np.ndarray
    states: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray


@dataclass(frozen=True)
class IpoptOptimizer(SolverCacheMixin, Optimizer):
    """IPOPT (via CasADi ``nlpsol``) on the problem of eq. (14); derivative-based baseline."""

    CARRIED: ClassVar[frozenset[str]] = frozenset({"memory"})  # the previous plan's multipliers

    shooting: Shooting = setting(Shooting.SINGLE, doc="Transcription: single or multiple shooting")
    """Transcription: ``single`` or ``multiple`` shooting (default chosen by measurement,
    see docs/explanation/gradient-baselines.md)."""
    max_iter: int = budget_setting(
        100, doc="IPOPT's max_iter when the caller gives no budget; the default budget"
    )
    """A budget's ``max_iterations`` replaces it; its ``max_evaluations`` is ignored."""
    tol: float = setting(
        1e-6, low=0.0, low_open=True, doc="IPOPT's tol (IPOPT's own default is 1e-8)"
    )
    acceptable_tol: float = setting(
        1e-4, low=0.0, low_open=True,
        doc="IPOPT's acceptable_tol; a solve stopped there counts as a success",
    )  # fmt: skip
    mu_init: float = setting(
        1e-4, low=0.0, low_open=True, doc="IPOPT's initial barrier parameter mu_init"
    )
    """IPOPT's default 0.1 suits a cold start, a small one lets a warm start near the solution
    finish in a few iterations."""
    mu_strategy: str = setting(
        "adaptive", choices=("adaptive", "monotone"),
        doc="IPOPT's mu_strategy: adaptive or monotone (IPOPT's default)",
    )  # fmt: skip
    warm_start_duals: bool = setting(
        True, doc="Start the multipliers from this UAV's previous solve (warm_start_init_point)"
    )
    bound_push: float = setting(
        1e-6, low=0.0, low_open=True,
        doc="IPOPT's bound_push, bound_frac and their warm_start_ forms",
    )  # fmt: skip
    """How far a starting point on a bound is moved inside (IPOPT's default 1e-2 undoes a warm
    start whose controls sit on a bound)."""
    jit: bool = setting(False, doc="Compile the CasADi functions to C (needs a C compiler)")
    ipopt_options: tuple[tuple[str, str | int | float], ...] = setting(
        (), check=lambda owner, _name, value: _check_options(owner, value),
        allowed="(name, value) pairs, string names, string or number values",
        doc="Further IPOPT options as (name, value) pairs; they override the fields above",
    )  # fmt: skip
    """E.g. ``(("mu_strategy", "adaptive"),)``."""

    def __post_init__(self) -> None:
        validate_fields(self)

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iter)

    # --- building -----------------------------------------------------------------------------

    def _options(
        self, max_iter: int, dual_start: bool, deadline_s: float | None = None
    ) -> dict[str, Any]:
        options: dict[str, Any] = {
            "print_time": False,
            "record_time": True,
            "error_on_fail": False,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "ipopt.max_iter": max_iter,
            "ipopt.tol": self.tol,
            "ipopt.acceptable_tol": self.acceptable_tol,
            "ipopt.mu_init": self.mu_init,
            "ipopt.mu_strategy": self.mu_strategy,
            "ipopt.bound_push": self.bound_push,
            "ipopt.bound_frac": self.bound_push,
            "ipopt.warm_start_bound_push": self.bound_push,
            "ipopt.warm_start_bound_frac": self.bound_push,
            "ipopt.warm_start_mult_bound_push": self.bound_push,
            "ipopt.warm_start_init_point": "yes" if dual_start else "no",
        }
        if deadline_s is not None:
            options["ipopt.max_wall_time"] = deadline_s
        options.update({f"ipopt.{name}": value for name, value in self.ipopt_options})
        if self.jit:
            options.update(
                {
                    "jit": True,
                    "compiler": "shell",
                    "jit_options": {"flags": ["-O2"], "verbose": False},
                }
            )
        return options

    def build(
        self,
        shape: ProblemShape,
        max_iter: int,
        dual_start: bool = False,
        deadline_s: float | None = None,
    ) -> _Solver:
        """The ``nlpsol`` for ``shape`` (cached: built once per shape and iteration limit).

        ``dual_start`` selects IPOPT's ``warm_start_init_point``: the multipliers
        passed in are used (a separate solver, since it is a construction option).
        ``deadline_s`` is IPOPT's ``max_wall_time`` (also a construction option).
        """
        key = ("solver", shape, max_iter, dual_start, deadline_s)
        solver = self._solver_cache.get(key)
        if solver is None:
            import casadi as ca  # imported when a solver is first built: a slow import

            from formation_bench.mpc.solvers.casadi_model import (
                block_controls,
                horizon_cost,
                period_step,
                rollout,
                symbolic_parameters,
            )

            start = time.perf_counter()
            params = symbolic_parameters(shape)
            decision = ca.SX.sym("u", shape.dim)
            if self.shooting == Shooting.SINGLE:
                states = rollout(shape, params.state, decision)
                variables = decision
                constraints = ca.SX(0, 1)
                n_states = 0
            else:
                horizon = shape.horizon_steps
                state_vars = ca.SX.sym("x", STATE_DIM, horizon)
                gaps = []
                previous = params.state
                for k in range(horizon):
                    control = block_controls(decision, shape.block_of_step[k])
                    predicted = period_step(previous, control, shape.period_s, shape.rk4_substeps)
                    gaps.append(state_vars[:, k] - predicted)
                    previous = state_vars[:, k]
                states = [state_vars[:, k] for k in range(horizon)]
                variables = ca.vertcat(decision, ca.vec(state_vars))
                constraints = ca.vertcat(*gaps)
                n_states = STATE_DIM * horizon
            cost = horizon_cost(shape, [z[:2] for z in states], params)
            nlp = {"x": variables, "p": params.vector, "f": cost, "g": constraints}
            options = self._options(max_iter, dual_start, deadline_s)
            nlpsol = ca.nlpsol("dmpc_ipopt", "ipopt", nlp, options)
            solver = _Solver(nlpsol, shape.dim, n_states, time.perf_counter() - start)
            self._solver_cache[key] = solver
        return solver

    # --- solving ------------------------------------------------------------------------------

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
        max_iter = self.max_iter if budget.max_iterations is None else int(budget.max_iterations)
        x0 = warm_start_of(problem, bounds, x0)
        start = time.perf_counter()
        shape = ProblemShape.of(problem)
        params = pack_parameters(problem, shape)
        n_states = STATE_DIM * shape.horizon_steps if self.shooting == Shooting.MULTIPLE else 0
        scenario = problem.scenario
        warm_states = numeric_rollout(
            problem.state,
            problem.controls(x0),
            scenario.timing.period_s,
            scenario.timing.rk4_substeps,
        )
        lbx, ubx = bounds.lower, bounds.upper
        primal = x0
        if n_states:
            lbx = np.concatenate((lbx, np.full(n_states, -np.inf)))
            ubx = np.concatenate((ubx, np.full(n_states, np.inf)))
            # states as CasADi's vec() of the (4, H) matrix: column k = state at step k + 1
            primal = np.concatenate((x0, warm_states[1:].reshape(-1)))
        args: dict[str, Any] = {"x0": primal, "p": params, "lbx": lbx, "ubx": ubx}
        if n_states:
            args["lbg"] = 0.0
            args["ubg"] = 0.0
        memory_key = ("memory", shape, problem.uav)
        dual_start = False
        memory = self._solver_cache.pop(memory_key, None) if self.warm_start_duals else None
        if memory is not None:
            shift = shift_of(problem, memory.decision, memory.states, x0)
            if shift is not None:
                args["lam_x0"] = memory.lam_x
                if n_states:
                    lam_g = memory.lam_g.reshape(-1, STATE_DIM)
                    index = np.minimum(shift + np.arange(lam_g.shape[0]), lam_g.shape[0] - 1)
                    args["lam_g0"] = lam_g[index].reshape(-1)
                dual_start = True
        solver = self.build(shape, max_iter, dual_start, budget.deadline_s)
        setup_s = time.perf_counter() - start
        message = ""
        call_start = time.perf_counter()
        try:
            solution = solver.solve(args)
            call_s = time.perf_counter() - call_start
            stats = solver.last_stats
            status = str(stats.get("return_status", "unknown"))
            x = solution["x"]
            stopped = budget.deadline_s is not None and status == DEADLINE_STATUS
            ok = (status in SUCCESS_STATUSES or stopped) and bool(np.all(np.isfinite(x)))
        except RuntimeError as err:  # CasADi raises on evaluation errors it cannot recover
            call_s = time.perf_counter() - call_start
            stats = {}
            status = "exception"
            message = str(err).splitlines()[0] if str(err) else "exception"
            ok = False
            solution = None
            x = primal
        counts = {name: int(stats.get(name, 0)) for name in EVALUATION_COUNTERS}
        nfev = sum(counts.values())
        iterations = int(stats.get("iter_count", 0))
        info: dict[str, Any] = {
            "return_status": status,
            "iterations": iterations,
            "shooting": self.shooting.value,
            "dual_warm_start": dual_start,
            "setup_time_s": setup_s,
            "build_time_s": solver.build_time_s,
            "casadi_stats": {
                k: float(v) for k, v in stats.items() if k.startswith(("t_wall_", "t_proc_"))
            },
            "casadi_counts": counts,
            **call_times(stats, call_s),
        }
        decision = np.clip(x[: solver.dim], bounds.lower, bounds.upper)
        costs = problem(np.stack((decision, x0)))
        nfev += 2
        info["solve_time_s"] = time.perf_counter() - start
        if not ok:
            return fallback_result(
                x0, costs[1], nfev, iterations, f"IPOPT: {message or status}", info
            )
        assert solution is not None
        if not costs[0] <= costs[1]:  # IPOPT ended above its start (it moved x0 off a bound)
            decision, fun = x0, float(costs[1])
            info["kept_warm_start"] = True
        else:
            fun = float(costs[0])
        if self.warm_start_duals:
            planned = numeric_rollout(
                problem.state,
                problem.controls(decision),
                scenario.timing.period_s,
                scenario.timing.rk4_substeps,
            )
            self._solver_cache[memory_key] = _Memory(
                decision.copy(),
                planned,
                solution["lam_x"],
                solution["lam_g"],
            )
        return OptimizeResult(
            x=decision,
            fun=fun,
            nfev=nfev,
            nit=iterations,
            success=True,
            message=f"IPOPT: {status}",
            history_nfev=np.asarray([nfev], dtype=np.int64),
            history_fun=np.asarray([fun]),
            info=info,
        )


def call_times(stats: dict[str, Any], call_s: float) -> dict[str, float]:
    """Where the time of one ``nlpsol`` call went, from CasADi's timers (seconds).

    ``ipopt_wall_s`` is the call: IPOPT's ``OptimizeTNLP``, which on every call builds IPOPT's
    algorithm objects and MUMPS afresh before the first iteration (about 0.15 ms on the paper
    problem, see perf/gradient_speed.py) and then iterates. ``evaluation_wall_s`` is the part
    spent in CasADi's evaluations of the objective and its derivatives (the ``t_wall_nlp_*``
    timers), ``ipopt_own_s`` the rest: IPOPT's set-up, its linear algebra and line search.
    ``call_overhead_s`` is the call's wall time outside CasADi's ``t_wall_total`` (converting
    the arguments and results of an ordinary call). A call through the buffer interface, as
    :class:`IpoptOptimizer` makes it, converts nothing and leaves ``t_wall_total`` at 0: its
    wall time ``call_s`` is then the whole call.
    """
    total = float(stats.get("t_wall_total", 0.0)) or call_s
    evaluations = sum(
        float(value)
        for name, value in stats.items()
        if name.startswith("t_wall_nlp_") or name == "t_wall_callback_fun"
    )
    return {
        "ipopt_wall_s": total,
        "evaluation_wall_s": evaluations,
        "ipopt_own_s": total - evaluations,
        "call_overhead_s": max(call_s - total, 0.0),
    }


def _check_options(owner: str, options: object) -> tuple[tuple[str, str | int | float], ...]:
    """``options`` as a tuple of ``(name, value)`` pairs, else ValueError."""
    try:
        pairs = tuple((name, value) for name, value in options)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        pairs = None
    if pairs is None or not all(
        isinstance(name, str)
        and isinstance(value, str | int | float)
        and not isinstance(value, bool)
        for name, value in pairs
    ):
        raise ValueError(
            f"{owner}.ipopt_options must be (name, value) pairs with string names and "
            f"string or number values, got {options!r}"
        )
    return pairs
