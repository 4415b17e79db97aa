"""``ilqr``: iterative LQR with control limits on the per-UAV problem of eq. (14).

The method of Li and Todorov, "Iterative linear quadratic regulator design for nonlinear
biological movement systems", ICINCO 2004, on the shooting formulation (the controls are the
variables, the states follow by simulation), with box-constrained controls as in Tassa,
Mansard and Todorov, "Control-limited differential dynamic programming", ICRA 2014, and the
loop of their ``iLQG.m``. The decision is blocked: a stage is one control block, its dynamics
the block's RK4 periods composed, its cost the block's terms (:mod:`~formation_bench.mpc.
solvers.ilqr_derivatives`); ``n_blocks = H`` is the full control sequence. Each iteration

1. linearises the stages about the current trajectory, if it changed (one evaluation of a
   CasADi function built once per problem shape, through its buffer interface);
2. runs the backward pass (:func:`~formation_bench.mpc.solvers.ilqr_passes.backward_pass`):
   a box QP per stage (:mod:`~formation_bench.mpc.solvers.ilqr_boxqp`) for the feed-forward
   step, the feedback gain on its free controls (clamped rows zero); when a QP's ``Q_uu`` is
   not positive definite ``mu`` is raised and the pass repeated;
3. runs the line search: closed-loop forward passes with the step lengths
   ``10^linspace(0, -3, line_search_steps)`` (``iLQG.m``'s ``Alpha``) in turn until one lowers
   the cost by more than ``z_min`` times the expected reduction; then ``mu`` falls, else it
   rises (:func:`~formation_bench.mpc.solvers.ilqr_passes.iterate`).

``mu`` follows ``iLQG.m``'s schedule (Tassa, Erez and Todorov, "Synthesis and stabilization
of complex behaviors through online trajectory optimization", IROS 2012): on a rise
``delta <- max(delta * factor, factor)``, ``mu <- max(mu * delta, mu_min)``; on a fall
``delta <- min(delta / factor, 1 / factor)``, ``mu <- mu * delta``, and 0 once below
``mu_min``.

The warm start is the shifted previous plan the loop passes as ``x0``: the first nominal
trajectory is its rollout. The cost of every forward pass is the harness's compiled cost of
the controls it applied, so ``fun`` is ``problem(x)`` to the bit and the result is never
worse than the warm start.

Choices the sources leave open, made here (the defaults measured on the instance library's
test split, 588 problems; docs/explanation/gradient-baselines.md):

- the cost Hessian is the Gauss-Newton one (:class:`~formation_bench.mpc.solvers.
  ilqr_derivatives.CostHessian`): positive semidefinite, so ``mu`` stays 0 on most solves;
  the exact stage Hessian needs as many iterations (median 4) and is no more accurate here;
- ``mu`` starts at 0, not at ``iLQG.m``'s 1 (meant for a cold start): from the shifted
  plan the undamped step is accepted at once on most problems (median 4 iterations, 8 from 1);
- stopping: ``iLQG.m`` stops on an absolute cost reduction below ``tolFun``; the costs here
  span orders of magnitude, so the test is relative (``tol_fun`` of the cost), and it is
  also applied to the expected reduction before the line search (with ``mu < 1e-5``), which
  spares the line searches that fail on rounding at the optimum. ``iLQG.m``'s gradient test,
  ``mean_b max_i |k_bi| / (|u_bi| + 1) < tol_grad`` with ``mu < 1e-5``, is kept, and a zero
  step stops whatever ``mu`` (every control clamped: a KKT point);
- the budget: ``max_iterations`` counts iterations (a backward pass or passes with their line
  search), ``max_evaluations`` (if set) the cost evaluations, the warm start's and every
  forward pass's; ``deadline_s`` is checked before each iteration after the first, and the
  best point so far returned. The iteration limit is no failure (the point returned is
  better than the warm start);
- failure (the warm start returned with ``success=False``): a warm start or stage derivatives
  that are not finite, or ``mu`` beyond ``mu_max`` before any step was accepted;
- ``nfev`` counts cost evaluations (rollouts); linearisations, backward passes and box-QP
  iterations are in ``info``.

The Generator is not used.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.fields import (
    kernel_settings_class,
    pack_settings,
    setting,
    validate_fields,
)
from formation_bench.mpc.solvers.gradient_common import (
    SolverCacheMixin,
    fallback_result,
    require_local_problem,
    warm_start_of,
)
from formation_bench.mpc.solvers.ilqr_derivatives import (
    CostHessian,
    StageDerivatives,
    build_derivatives,
)
from formation_bench.mpc.solvers.ilqr_passes import (
    ACCEPTED,
    CONVERGED_EXPECTED,
    CONVERGED_REDUCTION,
    CONVERGED_STEP,
    MU_LIMIT,
    Policy,
    forward_pass,
    iterate,
)
from formation_bench.mpc.solvers.problem_shape import (
    CONTROL_DIM,
    STATE_DIM,
    ProblemShape,
    pack_parameters,
)
from formation_bench.optimizers.base import (
    BatchObjective,
    Bounds,
    Budget,
    Optimizer,
    OptimizeResult,
    budget_setting,
)

STOPPED = {
    CONVERGED_STEP: "converged: mean relative step {:.1e} below tol_grad",
    CONVERGED_EXPECTED: "converged: expected reduction {:.1e} below tol_fun (relative)",
    CONVERGED_REDUCTION: "converged: reduction {:.1e} below tol_fun (relative)",
    MU_LIMIT: "regularisation mu above mu_max",
}
"""The message of every status of :func:`~formation_bench.mpc.solvers.ilqr_passes.iterate`
that ends a solve."""


@dataclass(frozen=True)
class IlqrOptimizer(SolverCacheMixin, Optimizer):
    """Iterative LQR with a box QP per stage (Li and Todorov 2004; Tassa et al. 2014)."""

    compile_cpu_s = 16.0

    max_iter: int = budget_setting(
        100, doc="Iterations when the caller gives no budget; the default budget"
    )
    """A budget's ``max_iterations`` replaces it."""
    cost_hessian: CostHessian = setting(
        CostHessian.GAUSS_NEWTON, doc="Stage cost Hessian: gauss-newton or exact"
    )
    state_regularisation: bool = setting(
        False, kernel=True, doc="Add mu to V_xx (Tassa 2012) instead of Q_uu (iLQG.m's default)"
    )
    jit: bool = setting(False, doc="Compile the derivative function to C (needs a C compiler)")
    """About 1 µs per linearisation instead of 7-11 µs, for about a second of ``gcc`` per
    problem shape and process."""
    mu_initial: float = setting(0.0, low=0.0, doc="Initial regularisation mu (iLQG.m: 1)")
    mu_factor: float = setting(
        1.6, low=1.0, low_open=True, kernel=True, doc="Factor of mu's schedule (iLQG.m: 1.6)"
    )
    mu_min: float = setting(
        1e-6, low=0.0, low_open=True, kernel=True, doc="mu below this becomes 0 (iLQG.m: 1e-6)"
    )
    mu_max: float = setting(
        1e10, low="mu_min", kernel=True, doc="Stop once mu exceeds this (iLQG.m: 1e10)"
    )
    line_search_steps: int = setting(
        11, low=1, doc="Step lengths 10^linspace(0, -3, n) of the line search (iLQG.m: 11)"
    )
    z_min: float = setting(
        0.0, low=0.0, high=1.0, high_open=True, kernel=True,
        doc="Accept a step above this share of its expected reduction (iLQG.m: 0)",
    )  # fmt: skip
    tol_fun: float = setting(
        1e-12,
        low=0.0,
        kernel=True,
        doc="Stop when a step's expected or actual reduction is below this share of the cost",
    )
    tol_grad: float = setting(
        1e-7,
        low=0.0,
        kernel=True,
        doc="Stop when the mean relative step is below this and mu < 1e-5",
    )

    def __post_init__(self) -> None:
        validate_fields(self)

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iter)

    @property
    def alphas(self) -> np.ndarray:
        """The line search's step lengths, longest first (computed once)."""
        alphas = self._solver_cache.get("alphas")
        if alphas is None:
            alphas = 10.0 ** np.linspace(0.0, -3.0, self.line_search_steps)
            self._solver_cache["alphas"] = alphas
        return alphas

    def derivatives(self, shape: ProblemShape) -> StageDerivatives:
        """The stage derivative function of ``shape`` (built once, shared by all UAVs)."""
        key = ("derivatives", shape)
        derivatives = self._solver_cache.get(key)
        if derivatives is None:
            derivatives = build_derivatives(shape, self.cost_hessian, self.jit)
            self._solver_cache[key] = derivatives
        return derivatives

    def compiled_kernels(self) -> tuple[Any, ...]:
        """The first forward pass and the iteration (its passes and box QP compile with it)."""
        return (forward_pass, iterate)

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
        max_evaluations = budget.max_evaluations
        x0 = warm_start_of(problem, bounds, x0)
        start = time.perf_counter()
        shape = ProblemShape.of(problem)
        functions = self.derivatives(shape)
        functions.parameters[:] = pack_parameters(problem, shape)
        packed, starts, alphas = problem.packed, functions.starts, self.alphas
        n_stages = shape.n_blocks
        policy = Policy(
            controls=x0.reshape(n_stages, CONTROL_DIM).copy(),
            states=np.zeros((n_stages, STATE_DIM)),
            feedforward=np.zeros((n_stages, CONTROL_DIM)),
            gains=np.zeros((n_stages, CONTROL_DIM, STATE_DIM)),
            lower=bounds.lower.reshape(n_stages, CONTROL_DIM).copy(),
            upper=bounds.upper.reshape(n_stages, CONTROL_DIM).copy(),
        )
        _, states, cost = forward_pass(packed, starts, policy, 0.0)
        policy.states[:] = states
        warm_cost, nfev = cost, 1
        history_nfev, history_fun = [nfev], [cost]
        regularisation = (self.mu_initial, 1.0)
        accepted = linearisations = backward_passes = qp_iterations = nit = 0
        message = f"iteration limit {max_iter}"
        failure = None if math.isfinite(cost) else "the warm start's cost is not finite"
        relinearise = True
        while failure is None and nit < max_iter:
            if nit > 0 and budget.deadline_s is not None:
                if time.perf_counter() - start >= budget.deadline_s:
                    message = f"deadline reached after {nit} iterations"
                    break
            if max_evaluations is not None and nfev >= max_evaluations:
                message = f"evaluation limit {max_evaluations}"
                break
            if relinearise:
                functions.states[:] = policy.states
                functions.controls[:] = policy.controls
                derivatives = functions.evaluate()
                linearisations += 1
                if not math.isfinite(derivatives.sum()):
                    failure = "stage derivatives not finite"
                    break
            left = (
                alphas.size if max_evaluations is None else min(max_evaluations - nfev, alphas.size)
            )
            step = iterate(
                derivatives, packed, starts, policy, alphas, self.kernel_settings(left),
                regularisation, cost,
            )  # fmt: skip
            nit += 1
            nfev += step.rollouts
            backward_passes += step.backward_passes
            qp_iterations += step.qp_iterations
            regularisation = (step.mu, step.delta)
            relinearise = step.status in (ACCEPTED, CONVERGED_REDUCTION)
            if relinearise:
                accepted += 1
                cost = step.cost
                history_nfev.append(nfev)
                history_fun.append(cost)
            if step.status in STOPPED:
                message = STOPPED[step.status].format(step.measure)
                break
        if failure is None and accepted == 0 and message == STOPPED[MU_LIMIT]:
            failure = message
        info: dict[str, Any] = {
            "cost_hessian": self.cost_hessian.value,
            "mu": regularisation[0],
            "accepted_steps": accepted,
            "linearisations": linearisations,
            "backward_passes": backward_passes,
            "qp_iterations": qp_iterations,
            "build_time_s": functions.build_time_s,
            "solve_time_s": time.perf_counter() - start,
        }
        if failure is not None:
            return fallback_result(x0, warm_cost, nfev, nit, f"iLQR: {failure}", info)
        return OptimizeResult(
            x=policy.controls.reshape(-1).copy(),
            fun=float(cost),
            nfev=nfev,
            nit=nit,
            success=True,
            message=f"iLQR: {message}",
            history_nfev=np.asarray(history_nfev, dtype=np.int64),
            history_fun=np.asarray(history_fun),
            info=info,
        )

    def kernel_settings(self, max_rollouts: int) -> tuple:
        """The :data:`IlqrSettings` of an iteration allowed ``max_rollouts`` forward passes
        (kept: one per ``max_rollouts``)."""
        key = ("settings", max_rollouts)
        settings = self._solver_cache.get(key)
        if settings is None:
            settings = IlqrSettings(*pack_settings(IlqrSettings, self, max_rollouts=max_rollouts))
            self._solver_cache[key] = settings
        return settings


IlqrSettings = kernel_settings_class(
    "IlqrSettings",
    __name__,
    IlqrOptimizer,
    ("max_rollouts",),
    """What :func:`~formation_bench.mpc.solvers.ilqr_passes.iterate` reads: the kernel fields of
    :class:`IlqrOptimizer`, then the forward passes the iteration may run.""",
)
