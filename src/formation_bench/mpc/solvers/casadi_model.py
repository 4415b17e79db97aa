"""The per-UAV problem of eq. (14) in CasADi symbols: one expression for every derivative path.

The gradient baselines (:mod:`formation_bench.mpc.solvers.ipopt_solver`,
:mod:`formation_bench.mpc.solvers.ltv_osqp`)
need the problem that :class:`~formation_bench.mpc.problem.LocalProblem` evaluates numerically,
written symbolically so that CasADi can differentiate it. This module writes it
once:

- :func:`simpson_substep` is the RK4 step of :mod:`formation_bench.mpc.model` (zero-order hold,
  in its Simpson form: three sine/cosine pairs per sub-step);
- :func:`stage_cost` is the integrand of eq. (14) **as printed** (the centre is
  ``(p_i + sum_j p_hat_j) / N``; off the complete graph ``(p_i + S) / M`` with the problem's
  ``centre_group`` M and ``centre_neighbour_sum`` S), so it is a third, independent writing
  of the cost beside the compiled :func:`formation_bench.mpc.cost.batch_cost` and the plain
  :func:`formation_bench.mpc.cost.reference_cost`; a test checks all three agree;
- :func:`penalty_terms` are the collision and obstacle penalties, ``w * max(0, r - d)^2``
  with the exact distance ``d`` (the penalty is C1; its second derivative jumps where it
  starts, and is undefined only at ``d = 0``);
- :func:`horizon_cost` sums them with the same right-endpoint rectangle rule.

The problem's numbers enter as one parameter vector (:func:`pack_parameters`):
``[state (4), neighbour_positions (J, H, 2), desired_relative (J, H, 2),
reference (H, 2)]`` flattened in C order, then S ``(H, 2)`` when the centre is estimated
from the group and the obstacle rows ``(O, 3)`` when the obstacle penalty is on, so that a
function built once per :class:`ProblemShape` serves every UAV at every instant.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from formation_bench.mpc.solvers.problem_shape import (
    CONTROL_DIM,
    STATE_DIM,
    ProblemShape,
    pack_parameters,
)

if TYPE_CHECKING:  # mpc.problem imports optimizers.base: no run-time import here
    from formation_bench.mpc.problem import LocalProblem


@dataclass(frozen=True)
class SymbolicParameters:
    """The parameter vector's pieces as symbols."""

    vector: ca.SX
    """The whole vector, shape ``(n_parameters, 1)``."""
    state: ca.SX
    """Current state ``(4, 1)``."""
    neighbour_positions: list[list[ca.SX]]
    """``[j][k]``: estimated position ``(2, 1)`` of neighbour j at step k + 1."""
    desired_relative: list[list[ca.SX]]
    """``[j][k]``: desired ``p_i - p_j`` ``(2, 1)`` at step k + 1."""
    reference: list[ca.SX]
    """``[k]``: desired formation centre ``(2, 1)`` at step k + 1."""
    centre_neighbour_sum: list[ca.SX] | None
    """``[k]``: S ``(2, 1)`` with the centre ``(p_i + S) / M`` at step k + 1; None when the
    model sums the neighbours' estimates itself (eq. (14)'s centre)."""
    obstacles: list[ca.SX]
    """``[o]``: ``(c_x, c_y, r)`` ``(3, 1)`` of obstacle o, r where its penalty starts."""


def symbolic_parameters(shape: ProblemShape) -> SymbolicParameters:
    """A parameter vector symbol, sliced as :func:`pack_parameters` packs it."""
    p = ca.SX.sym("p", shape.n_parameters)
    horizon, n_nb = shape.horizon_steps, shape.n_neighbours
    offset = STATE_DIM

    def block(start: int) -> list[list[ca.SX]]:
        return [
            [
                p[start + 2 * (j * horizon + k) : start + 2 * (j * horizon + k) + 2]
                for k in range(horizon)
            ]
            for j in range(n_nb)
        ]

    neighbours = block(offset)
    offset += 2 * n_nb * horizon
    desired = block(offset)
    offset += 2 * n_nb * horizon
    reference = [p[offset + 2 * k : offset + 2 * k + 2] for k in range(horizon)]
    offset += 2 * horizon
    centre_sum = None
    if shape.group_centre:
        centre_sum = [p[offset + 2 * k : offset + 2 * k + 2] for k in range(horizon)]
        offset += 2 * horizon
    obstacles = [p[offset + 3 * o : offset + 3 * o + 3] for o in range(shape.n_obstacles)]
    return SymbolicParameters(
        p, p[:STATE_DIM], neighbours, desired, reference, centre_sum, obstacles
    )


def simpson_substep(z: ca.SX, u: ca.SX, h: float) -> ca.SX:
    """One RK4 sub-step of length ``h`` under the held control ``u = [a, omega]``.

    The same arithmetic as :func:`formation_bench.mpc.model.rk4_substep`: under a held control
    heading and speed are affine in time, RK4's middle stages coincide and the
    step is Simpson's rule on them.
    """
    x, y, theta, v = z[0], z[1], z[2], z[3]
    a, omega = u[0], u[1]
    theta_mid = theta + 0.5 * h * omega
    v_mid = v + 0.5 * h * a
    theta_end = theta + h * omega
    v_end = v + h * a
    dx = v * ca.cos(theta) + 4.0 * v_mid * ca.cos(theta_mid) + v_end * ca.cos(theta_end)
    dy = v * ca.sin(theta) + 4.0 * v_mid * ca.sin(theta_mid) + v_end * ca.sin(theta_end)
    return ca.vertcat(x + h * dx / 6.0, y + h * dy / 6.0, theta_end, v_end)


def period_step(z: ca.SX, u: ca.SX, period: float, substeps: int) -> ca.SX:
    """The state one control period later (``substeps`` RK4 sub-steps)."""
    h = period / substeps
    for _ in range(substeps):
        z = simpson_substep(z, u, h)
    return z


def block_controls(decision: ca.SX, block: int) -> ca.SX:
    """``[a, omega]`` of control block ``block`` of a decision vector."""
    return decision[CONTROL_DIM * block : CONTROL_DIM * block + CONTROL_DIM]


def rollout(shape: ProblemShape, state: ca.SX, decision: ca.SX) -> list[ca.SX]:
    """Predicted states at steps 1..H of a decision vector (single shooting)."""
    states = []
    z = state
    for k in range(shape.horizon_steps):
        z = period_step(
            z, block_controls(decision, shape.block_of_step[k]), shape.period_s, shape.rk4_substeps
        )
        states.append(z)
    return states


def stage_cost(shape: ProblemShape, position: ca.SX, params: SymbolicParameters, k: int) -> ca.SX:
    """The integrand of eq. (14) at step k + 1, as printed, without the penalties.

    ``w_dst * sum_j ||p_i - p_hat_j - p_ij^d||^2 + w_trj * ||(p_i + sum_j p_hat_j) / N - p_c^d||^2``
    on the complete graph (N = M = ``centre_group``); with the centre estimated from the
    group, the centre is ``(p_i + S) / M``.
    """
    formation = 0
    centre = position
    for j in range(shape.n_neighbours):
        error = position - params.neighbour_positions[j][k] - params.desired_relative[j][k]
        formation = formation + ca.dot(error, error)
        if params.centre_neighbour_sum is None:
            centre = centre + params.neighbour_positions[j][k]
    if params.centre_neighbour_sum is not None:
        centre = centre + params.centre_neighbour_sum[k]
    tracking = centre / shape.centre_group - params.reference[k]
    return shape.w_dst * formation + shape.w_trj * ca.dot(tracking, tracking)


def penalty_terms(
    shape: ProblemShape, position: ca.SX, params: SymbolicParameters, k: int
) -> list[tuple[float, ca.SX]]:
    """``(weight, max(0, r - d))`` of every penalty term at step k + 1.

    One per neighbour estimate when the collision penalty is on (r the safety radius), one
    per obstacle when the obstacle penalty is on (r its radius plus margin); d is the exact
    distance, written as :func:`formation_bench.mpc.cost.batch_cost` writes it.
    """
    terms = []
    centres = []
    if shape.w_collision > 0:
        centres += [
            (shape.w_collision, shape.safety_radius, params.neighbour_positions[j][k])
            for j in range(shape.n_neighbours)
        ]
    centres += [(shape.w_obstacle, row[2], row[:2]) for row in params.obstacles]
    for weight, radius, centre in centres:
        dx = position[0] - centre[0]
        dy = position[1] - centre[1]
        terms.append((weight, ca.fmax(0.0, radius - ca.sqrt(dx * dx + dy * dy))))
    return terms


def penalty_residuals(
    shape: ProblemShape, positions: list[ca.SX], params: SymbolicParameters
) -> ca.SX:
    """The residuals ``sqrt(delta_T * w) * max(0, r - d)`` of every penalty term over the
    horizon: the penalties of :func:`horizon_cost` are their sum of squares."""
    residuals = [
        math.sqrt(shape.period_s * weight) * gap
        for k, position in enumerate(positions)
        for weight, gap in penalty_terms(shape, position, params, k)
    ]
    return ca.vertcat(*residuals) if residuals else ca.SX(0, 1)


def horizon_cost(
    shape: ProblemShape,
    positions: list[ca.SX],
    params: SymbolicParameters,
    penalties: bool = True,
) -> ca.SX:
    """Eq. (14) plus the shape's penalties: the right-endpoint rectangle rule over steps 1..H.

    ``penalties=False`` leaves the penalties out (eq. (14)'s terms alone, quadratic in the
    positions).
    """
    total = 0
    for k, position in enumerate(positions):
        stage = stage_cost(shape, position, params, k)
        if penalties and shape.penalised:
            for weight, gap in penalty_terms(shape, position, params, k):
                stage = stage + weight * gap * gap
        total = total + shape.period_s * stage
    return total


def cost_function(shape: ProblemShape) -> ca.Function:
    """``cost(decision, p) -> J``: the whole problem as one CasADi function."""
    params = symbolic_parameters(shape)
    decision = ca.SX.sym("u", shape.dim)
    states = rollout(shape, params.state, decision)
    cost = horizon_cost(shape, [z[:2] for z in states], params)
    return ca.Function("cost", [decision, params.vector], [cost], ["u", "p"], ["J"])


def casadi_cost(problem: LocalProblem, decisions: np.ndarray) -> np.ndarray:
    """Cost of every row of ``decisions`` through the CasADi expression (for tests)."""
    shape = ProblemShape.of(problem)
    decisions = np.atleast_2d(np.asarray(decisions, dtype=np.float64))
    function = cost_function(shape).map(decisions.shape[0])
    params = pack_parameters(problem, shape)
    values = function(decisions.T, np.tile(params[:, None], (1, decisions.shape[0])))
    return np.asarray(values, dtype=np.float64).reshape(-1)


def gradient_function(shape: ProblemShape) -> ca.Function:
    """``gradient(decision, p) -> (J, dJ/du)``: the cost and its gradient in the decision."""
    decision = ca.SX.sym("u", shape.dim)
    params = symbolic_parameters(shape)
    cost = cost_function(shape)(decision, params.vector)
    return ca.Function(
        "cost_gradient",
        [decision, params.vector],
        [cost, ca.gradient(cost, decision)],
        ["u", "p"],
        ["J", "g"],
    )


def projected_gradient(problem: LocalProblem, decision: np.ndarray, tol: float) -> np.ndarray:
    """The cost's gradient projected on the box: zero at a local optimum (first-order KKT).

    A coordinate within ``tol * width`` of a bound counts as on it: there only a
    gradient pushing inwards (away from the bound) counts, as the bound's
    multiplier absorbs the rest.
    """
    shape = ProblemShape.of(problem)
    _, gradient = gradient_function(shape)(decision, pack_parameters(problem, shape))
    gradient = np.asarray(gradient, dtype=np.float64).reshape(-1)
    lower, upper, width = problem.bounds.lower, problem.bounds.upper, problem.bounds.width
    at_lower = decision - lower <= tol * width
    at_upper = upper - decision <= tol * width
    projected = gradient.copy()
    projected[at_lower] = np.minimum(gradient[at_lower], 0.0)
    projected[at_upper] = np.maximum(gradient[at_upper], 0.0)
    return projected
