"""The LTV-MPC QP of ``ltv-osqp`` written readably in cvxpy: the reference it is tested against.

:mod:`formation_bench.mpc.solvers.ltv_osqp` builds its QP as raw OSQP data (CSC nonzeros of one
big CasADi Jacobian, updated in place). This module writes the same QP the
way one would on paper, with cvxpy Parameters so that it is compiled once and
re-solved per instant (DPP)::

    minimise   delta_T * sum_k [ w_dst * sum_j || p_k - p_hat_jk - p_ij,k^d ||^2
                               + w_trj * || (p_k + S_k) / M - p_c,k^d ||^2 ]
               + sum_t sum_k delta_T * w_t * [active_tk * (r_t - d_tk - n_tk' dp_k)]^2
    over       du, dx_1..dx_H,   with p_k = p_bar_k + dp_k,  dp_k = (dx_k)_{x,y}
    subject to dx_1 = B_0 du_{b(0)},  dx_{k+1} = A_k dx_k + B_k du_{b(k)},
               lower - u0 <= du <= upper - u0

where ``p_bar`` is the trajectory predicted along the nominal controls ``u0``
and ``A_k``, ``B_k`` are the per-period Jacobians of the RK4 step, taken one
period at a time from :func:`formation_bench.mpc.solvers.casadi_model.period_step`. M and S
are the problem's ``centre_group`` and ``centre_neighbour_sum`` (on the complete graph N and
``sum_j p_hat_jk``). The last line is the penalties' Gauss-Newton model: for every
penalty term t (a neighbour's estimate when the collision penalty is on, an obstacle when
the obstacle penalty is on) with centre ``c_tk``, ``d_tk = |p_bar_k - c_tk|`` is the
nominal distance, ``n_tk`` its unit direction, and ``active_tk`` whether ``d_tk < r_t``:
the penalty ``w_t * max(0, r_t - d)^2`` on the linearised distance of the terms active
along the nominal trajectory. It is not used in the closed loop (cvxpy's per-solve
overhead is milliseconds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import cvxpy as cp
import numpy as np

from formation_bench.mpc.model import rollout as numeric_rollout
from formation_bench.mpc.solvers.casadi_model import (
    CONTROL_DIM,
    STATE_DIM,
    ProblemShape,
    period_step,
)

if TYPE_CHECKING:
    from formation_bench.mpc.problem import LocalProblem


def step_jacobians(
    shape: ProblemShape, problem: LocalProblem, u0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nominal states ``(H + 1, 4)`` along ``u0``; Jacobians ``A (H, 4, 4)``, ``B (H, 4, 2)``."""
    z = ca.SX.sym("z", STATE_DIM)
    u = ca.SX.sym("u", CONTROL_DIM)
    nxt = period_step(z, u, shape.period_s, shape.rk4_substeps)
    jac = ca.Function("step_jacobians", [z, u], [ca.jacobian(nxt, z), ca.jacobian(nxt, u)])
    controls = problem.controls(u0)
    states = numeric_rollout(problem.state, controls, shape.period_s, shape.rk4_substeps)
    a = np.empty((shape.horizon_steps, STATE_DIM, STATE_DIM))
    b = np.empty((shape.horizon_steps, STATE_DIM, CONTROL_DIM))
    for k in range(shape.horizon_steps):
        ak, bk = jac(states[k], controls[k])
        a[k], b[k] = np.asarray(ak), np.asarray(bk)
    return states, a, b


@dataclass
class CvxpyLtvQP:
    """The parametrised QP of one problem shape (compile once, solve per instant)."""

    shape: ProblemShape
    problem: cp.Problem
    du: cp.Variable
    dx: cp.Variable
    a: list[cp.Parameter]
    b: list[cp.Parameter]
    nominal: cp.Parameter
    distance_targets: list[cp.Parameter]
    neighbour_sum: cp.Parameter
    reference: cp.Parameter
    lower: cp.Parameter
    upper: cp.Parameter
    penalty_offsets: list[cp.Parameter]
    """Per penalty term: ``sqrt(delta_T * w) * active * (r - d)`` ``(H,)``."""
    penalty_normals: list[cp.Parameter]
    """Per penalty term: ``sqrt(delta_T * w) * active * n`` ``(H, 2)``."""

    @classmethod
    def build(cls, shape: ProblemShape) -> CvxpyLtvQP:
        horizon, n_nb = shape.horizon_steps, shape.n_neighbours
        du = cp.Variable(shape.dim, name="du")
        dx = cp.Variable((horizon, STATE_DIM), name="dx")
        a = [cp.Parameter((STATE_DIM, STATE_DIM), name=f"A{k}") for k in range(horizon)]
        b = [cp.Parameter((STATE_DIM, CONTROL_DIM), name=f"B{k}") for k in range(horizon)]
        nominal = cp.Parameter((horizon, 2), name="p_bar")
        targets = [cp.Parameter((horizon, 2), name=f"p_hat{j}+p_d{j}") for j in range(n_nb)]
        neighbour_sum = cp.Parameter((horizon, 2), name="S")
        reference = cp.Parameter((horizon, 2), name="p_c")
        lower = cp.Parameter(shape.dim, name="lower-u0")
        upper = cp.Parameter(shape.dim, name="upper-u0")
        n_terms = len(_penalty_weights(shape))
        offsets = [cp.Parameter(horizon, name=f"penalty_offset{t}") for t in range(n_terms)]
        normals = [cp.Parameter((horizon, 2), name=f"penalty_normal{t}") for t in range(n_terms)]

        positions = nominal + dx[:, :2]
        formation = sum(cp.sum_squares(positions - targets[j]) for j in range(n_nb))
        tracking = cp.sum_squares((positions + neighbour_sum) / shape.centre_group - reference)
        cost = shape.period_s * (shape.w_dst * formation + shape.w_trj * tracking)
        for offset, normal in zip(offsets, normals, strict=True):
            cost = cost + cp.sum_squares(offset - cp.sum(cp.multiply(normal, dx[:, :2]), axis=1))

        def control(k: int) -> cp.Expression:
            block = shape.block_of_step[k]
            return du[CONTROL_DIM * block : CONTROL_DIM * block + CONTROL_DIM]

        constraints = [dx[0] == b[0] @ control(0)]
        constraints += [dx[k] == a[k] @ dx[k - 1] + b[k] @ control(k) for k in range(1, horizon)]
        constraints += [du >= lower, du <= upper]
        problem = cp.Problem(cp.Minimize(cost), constraints)
        assert problem.is_dpp()
        return cls(
            shape, problem, du, dx, a, b, nominal, targets, neighbour_sum, reference, lower,
            upper, offsets, normals,
        )  # fmt: skip

    def solve(self, problem: LocalProblem, u0: np.ndarray, **solver_options: object) -> np.ndarray:
        """The optimal ``du`` of the QP about ``u0`` for ``problem``."""
        states, a, b = step_jacobians(self.shape, problem, u0)
        for k in range(self.shape.horizon_steps):
            self.a[k].value = a[k]
            self.b[k].value = b[k]
        self.nominal.value = states[1:, :2]
        for j, target in enumerate(self.distance_targets):
            target.value = problem.neighbour_positions[j] + problem.desired_relative[j]
        self.neighbour_sum.value = problem.centre_neighbour_sum
        self.reference.value = np.asarray(problem.reference)
        nominal = states[1:, :2]
        for (weight, radius, centre), offset, normal in zip(
            _penalty_terms(self.shape, problem), self.penalty_offsets, self.penalty_normals,
            strict=True,
        ):  # fmt: skip
            away = nominal - centre
            distance = np.hypot(away[:, 0], away[:, 1])
            scale = np.sqrt(self.shape.period_s * weight) * (distance < radius)
            offset.value = scale * (radius - distance)
            normal.value = scale[:, None] * away / distance[:, None]
        self.lower.value = problem.bounds.lower - u0
        self.upper.value = problem.bounds.upper - u0
        options = {"solver": cp.CLARABEL, **solver_options}
        self.problem.solve(**options)
        if self.problem.status != cp.OPTIMAL:
            raise RuntimeError(f"cvxpy reference QP: {self.problem.status}")
        return np.asarray(self.du.value, dtype=np.float64)


def _penalty_weights(shape: ProblemShape) -> list[float]:
    """The weight of every penalty term: the neighbours' (collision), then the obstacles'."""
    collision = [shape.w_collision] * shape.n_neighbours if shape.w_collision > 0 else []
    return collision + [shape.w_obstacle] * shape.n_obstacles


def _penalty_terms(
    shape: ProblemShape, problem: LocalProblem
) -> list[tuple[float, float, np.ndarray]]:
    """``(weight, radius, centres (H, 2))`` of every penalty term, as :func:`_penalty_weights`
    orders them."""
    horizon = shape.horizon_steps
    terms = []
    if shape.w_collision > 0:
        terms += [
            (shape.w_collision, shape.safety_radius, problem.neighbour_positions[j])
            for j in range(shape.n_neighbours)
        ]
    for cx, cy, radius in problem.penalties.obstacles if shape.n_obstacles else ():
        terms.append((shape.w_obstacle, float(radius), np.tile([cx, cy], (horizon, 1))))
    return terms
