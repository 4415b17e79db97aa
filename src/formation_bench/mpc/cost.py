"""The per-UAV cost of eq. (14), compiled, and a plain reference of it.

For UAV i over the horizon (s = t_c + k * delta_T, k = 1..H)::

    J_i = delta_T * sum_k [ w_dst * sum_j || p_i(k) - p_hat_j(k) - p_ij^d(k) ||^2
                          + w_trj * || (p_i(k) + sum_j p_hat_j(k)) / N - p_c^d(k) ||^2 ]

The integral of eq. (5) is the right-endpoint rectangle rule on the control
grid: the state at t_c does not depend on the decision, so leaving it out
changes no minimiser.

The compiled kernels precompute everything that does not depend on the
decision: the distance targets ``p_hat_j + p_ij^d`` and the centre target
``N * p_c^d - sum_j p_hat_j`` (then the centre term is
``w_trj / N^2 * ||p_i - target||^2``). :func:`batch_cost` integrates the
model in fused multiply-adds (:mod:`formation_bench.mpc.fused`: the heading's
cosine and sine from a vectorisable polynomial, rotations in between) and
advances all candidates together; the C kernel of
:mod:`formation_bench.mpc.native_cost` computes the same numbers to the bit, faster.
:func:`batch_cost_reference` is the straightforward kernel, three sin/cos pairs
per RK4 sub-step; :func:`reference_cost` evaluates the formula
as printed, one point at a time, with a textbook RK4. Tests check that they
agree.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numba as nb
import numpy as np

from formation_bench.kernel_cache import njit
from formation_bench.mpc.fused import fma, fused_cos_sin, fused_substep, fused_turn
from formation_bench.mpc.model import HEADING_RESET_SUBSTEPS, REDUCTION_LIMIT, rk4_substep


@njit(cache=True, inline="always")
def _add_intrusion(
    penalty: np.ndarray, x: np.ndarray, y: np.ndarray, cx: float, cy: float, radius: float
) -> None:
    """``penalty[i] += max(0, radius - |(x_i, y_i) - (cx, cy)|)^2`` for every candidate i."""
    for i in range(x.shape[0]):
        dx, dy = x[i] - cx, y[i] - cy
        gap = radius - math.sqrt(dx * dx + dy * dy)
        if gap > 0.0:
            penalty[i] += gap * gap


# inline: the closed loop calls it only through packed_batch_cost, which then holds the one
# compiled copy a run builds
@njit(cache=True, inline="always")
def batch_cost(
    decisions: np.ndarray,
    state: np.ndarray,
    block_of_step: np.ndarray,
    period: float,
    substeps: int,
    distance_targets: np.ndarray,
    centre_target: np.ndarray,
    w_dst: float,
    w_centre: float,
    neighbour_positions: np.ndarray,
    w_collision: float,
    safety_radius: float,
    obstacles: np.ndarray,
    w_obstacle: float,
) -> np.ndarray:
    """Cost of every row of ``decisions`` ``(n, 2 * n_blocks)``: returns ``(n,)``.

    ``distance_targets`` is ``(J, H, 2)``, ``centre_target`` ``(H, 2)``,
    ``block_of_step`` ``(H,)`` maps each period to its control block, and
    ``w_centre`` is ``w_trj / M**2`` (M UAVs in the centre's estimate).

    The penalties are added after eq. (14)'s terms at each period, and only when their
    weight is positive (so they leave the paper's cost untouched to the bit):
    ``w_collision * sum_j max(0, safety_radius - |p_i - p_hat_j|)^2`` over the neighbours'
    estimates ``neighbour_positions`` ``(J, H, 2)``, and
    ``w_obstacle * sum_o max(0, r_o - |p_i - c_o|)^2`` over ``obstacles`` rows
    ``(c_x, c_y, r_o)`` (r_o the radius at which the penalty starts).

    Each period is :func:`~formation_bench.mpc.model.advance_period` for every
    candidate in the fused arithmetic of :mod:`formation_bench.mpc.fused`, written out
    with the candidates innermost so that the sub-steps, free of calls, run several
    candidates per instruction. The turn's cosine and sine are taken once per block, the
    heading's every ``HEADING_RESET_SUBSTEPS`` sub-steps counted from the horizon's
    start; in between they are rotated. The predicted positions agree with the plant's to
    rounding. ``_cost_kernel.c`` (:mod:`formation_bench.mpc.native_cost`) is this function
    in C, to the bit.
    """
    n = decisions.shape[0]
    horizon = block_of_step.shape[0]
    n_neighbours = distance_targets.shape[0]
    h = period / substeps
    sixth_h = h / 6.0
    # one row per quantity, one column per candidate: the loops over the
    # candidates then run over contiguous memory, and one allocation serves all
    work = np.empty((15, n))
    x, y, theta, v, cos_t, sin_t = work[0], work[1], work[2], work[3], work[4], work[5]
    accel, omega, cos_half, sin_half = work[6], work[7], work[8], work[9]
    cos_full, sin_full, total, penalty, formation = work[10], work[11], work[12], work[13], work[14]
    for i in range(n):
        x[i], y[i], theta[i], v[i] = state[0], state[1], state[2], state[3]
        total[i] = 0.0
    current_block = -1
    substep = 0
    for k in range(horizon):
        block = block_of_step[k]
        if block != current_block:
            current_block = block
            for i in range(n):
                accel[i] = decisions[i, 2 * block]
                omega[i] = decisions[i, 2 * block + 1]
                cos_half[i], sin_half[i], cos_full[i], sin_full[i] = fused_turn(0.5 * h * omega[i])
        for _ in range(substeps):
            if substep % HEADING_RESET_SUBSTEPS == 0:
                # cos_sin(theta) of every candidate, split so that the common case vectorises
                for i in range(n):
                    cos_t[i], sin_t[i] = fused_cos_sin(theta[i])
                for i in range(n):
                    if not abs(theta[i]) < REDUCTION_LIMIT:
                        cos_t[i], sin_t[i] = math.cos(theta[i]), math.sin(theta[i])
            substep += 1
            for i in range(n):
                turn = (cos_half[i], sin_half[i], cos_full[i], sin_full[i])
                dx, dy, cos_t[i], sin_t[i], v[i] = fused_substep(
                    cos_t[i], sin_t[i], v[i], accel[i], h, turn
                )
                x[i] = fma(sixth_h, dx, x[i])
                y[i] = fma(sixth_h, dy, y[i])
                theta[i] = fma(h, omega[i], theta[i])
        # neighbour outermost, so that the candidates stay innermost here too
        formation[:] = 0.0
        for j in range(n_neighbours):
            target_x, target_y = distance_targets[j, k, 0], distance_targets[j, k, 1]
            for i in range(n):
                dx, dy = x[i] - target_x, y[i] - target_y
                formation[i] = fma(dx, dx, fma(dy, dy, formation[i]))
        centre_x, centre_y = centre_target[k, 0], centre_target[k, 1]
        for i in range(n):
            cx, cy = x[i] - centre_x, y[i] - centre_y
            total[i] = fma(w_dst, formation[i], fma(w_centre, fma(cx, cx, cy * cy), total[i]))
        # each penalty sums over its points in order, point outermost: the candidates stay
        # innermost, as in the integration above
        if w_collision > 0.0:
            penalty[:] = 0.0
            for j in range(neighbour_positions.shape[0]):
                _add_intrusion(
                    penalty, x, y, neighbour_positions[j, k, 0], neighbour_positions[j, k, 1],
                    safety_radius,
                )  # fmt: skip
            for i in range(n):
                total[i] += w_collision * penalty[i]
        if w_obstacle > 0.0:
            penalty[:] = 0.0
            for o in range(obstacles.shape[0]):
                _add_intrusion(penalty, x, y, obstacles[o, 0], obstacles[o, 1], obstacles[o, 2])
            for i in range(n):
                total[i] += w_obstacle * penalty[i]
    out = np.empty(n)
    for i in range(n):
        out[i] = total[i] * period
    return out


NO_PENALTIES = (np.zeros((0, 0, 2)), 0.0, 1.0, np.zeros((0, 3)), 0.0)
""":func:`batch_cost`'s trailing arguments for eq. (14) alone: no collision or obstacle
penalty."""


@njit(cache=True)
def batch_cost_reference(
    decisions: np.ndarray,
    state: np.ndarray,
    block_of_step: np.ndarray,
    period: float,
    substeps: int,
    distance_targets: np.ndarray,
    centre_target: np.ndarray,
    w_dst: float,
    w_centre: float,
) -> np.ndarray:
    """:func:`batch_cost` by :func:`~formation_bench.mpc.model.rk4_substep`, one row at a time.

    The kernel before the rotation form, kept as its yardstick and as the
    "before" of the speed benchmark; it agrees with :func:`batch_cost` to
    rounding, not to the bit.
    """
    n = decisions.shape[0]
    horizon = block_of_step.shape[0]
    n_neighbours = distance_targets.shape[0]
    h = period / substeps
    out = np.empty(n)
    for i in range(n):
        x, y, theta, v = state[0], state[1], state[2], state[3]
        total = 0.0
        for k in range(horizon):
            block = block_of_step[k]
            a = decisions[i, 2 * block]
            omega = decisions[i, 2 * block + 1]
            for _ in range(substeps):
                x, y, theta, v = rk4_substep(x, y, theta, v, a, omega, h)
            formation = 0.0
            for j in range(n_neighbours):
                dx = x - distance_targets[j, k, 0]
                dy = y - distance_targets[j, k, 1]
                formation += dx * dx + dy * dy
            cx = x - centre_target[k, 0]
            cy = y - centre_target[k, 1]
            total += w_dst * formation + w_centre * (cx * cx + cy * cy)
        out[i] = total * period
    return out


def reference_cost(
    decision: np.ndarray,
    state: np.ndarray,
    block_of_step: np.ndarray,
    period: float,
    substeps: int,
    neighbour_positions: np.ndarray,
    desired_relative: np.ndarray,
    reference: np.ndarray,
    w_dst: float,
    w_trj: float,
    n_uav: int,
    centre_offset_sum: np.ndarray | None = None,
    w_collision: float = 0.0,
    safety_radius: float = 1.0,
    obstacles: np.ndarray | None = None,
    w_obstacle: float = 0.0,
) -> float:
    """Eq. (14) as printed, for one decision vector, with a four-stage RK4.

    ``neighbour_positions`` and ``desired_relative`` are ``(J, H, 2)`` (the
    estimates p_hat_j and the desired p_ij^d), ``reference`` is ``(H, 2)``.
    With ``centre_offset_sum`` ``(H, 2)`` (the UAV's and its neighbours' summed desired
    offsets) the centre is estimated from the UAV and its J neighbours alone, as
    ``(p_i + sum_j p_hat_j - centre_offset_sum) / (J + 1)``; without it, eq. (14)'s
    ``(p_i + sum_j p_hat_j) / n_uav``. The penalties are as in :func:`batch_cost`.
    Deliberately plain: it is the yardstick for :func:`batch_cost`.
    """

    def derivative(z: np.ndarray, u: np.ndarray) -> np.ndarray:
        return np.array([z[3] * np.cos(z[2]), z[3] * np.sin(z[2]), u[1], u[0]])

    controls = np.asarray(decision, dtype=np.float64).reshape(-1, 2)
    z = np.array(state, dtype=np.float64)
    h = period / substeps
    total = 0.0
    for k in range(len(block_of_step)):
        u = controls[block_of_step[k]]
        for _ in range(substeps):
            k1 = derivative(z, u)
            k2 = derivative(z + 0.5 * h * k1, u)
            k3 = derivative(z + 0.5 * h * k2, u)
            k4 = derivative(z + h * k3, u)
            z = z + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        p_i = z[:2]
        formation = sum(
            float(np.sum((p_i - neighbour_positions[j, k] - desired_relative[j, k]) ** 2))
            for j in range(neighbour_positions.shape[0])
        )
        if centre_offset_sum is None:
            centre = (p_i + neighbour_positions[:, k].sum(axis=0)) / n_uav
        else:
            group = neighbour_positions.shape[0] + 1
            centre = (p_i + neighbour_positions[:, k].sum(axis=0) - centre_offset_sum[k]) / group
        tracking = float(np.sum((centre - reference[k]) ** 2))
        penalty = 0.0
        for j in range(neighbour_positions.shape[0] if w_collision > 0 else 0):
            gap = safety_radius - float(np.linalg.norm(p_i - neighbour_positions[j, k]))
            penalty += w_collision * max(gap, 0.0) ** 2
        for cx, cy, radius in obstacles if obstacles is not None and w_obstacle > 0 else ():
            gap = radius - float(np.hypot(p_i[0] - cx, p_i[1] - cy))
            penalty += w_obstacle * max(gap, 0.0) ** 2
        total += period * (w_dst * formation + w_trj * tracking + penalty)
    return total


PACKED_HEADER = 10
"""Leading scalars of :func:`pack_problem`'s array: neighbours, horizon, sub-steps, period,
``w_dst``, ``w_centre``, ``w_collision``, the safety radius, obstacles and ``w_obstacle``."""


@dataclasses.dataclass(frozen=True)
class Penalties:
    """The penalty terms of :func:`batch_cost` beyond eq. (14); the default is none."""

    w_collision: float = 0.0
    safety_radius: float = 1.0
    obstacles: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3)))
    """Rows ``(c_x, c_y, r)``, r the radius at which the penalty starts."""
    w_obstacle: float = 0.0


def pack_problem(
    state: np.ndarray,
    block_of_step: np.ndarray,
    period: float,
    substeps: int,
    distance_targets: np.ndarray,
    centre_target: np.ndarray,
    w_dst: float,
    w_centre: float,
    neighbour_positions: np.ndarray,
    penalties: Penalties,
) -> np.ndarray:
    """:func:`batch_cost`'s problem as one flat float64 array, as :func:`compiled_cost` reads it.

    Header (:data:`PACKED_HEADER` values), then the state (4), the block index of every
    period (H, exact as floats), the distance targets (J * H * 2), the centre target (H * 2),
    the neighbours' estimates (J * H * 2) and the obstacles (3 per obstacle).
    """
    horizon = block_of_step.shape[0]
    n_neighbours = distance_targets.shape[0]
    obstacles = np.asarray(penalties.obstacles, dtype=np.float64).reshape(-1, 3)
    header = [
        n_neighbours, horizon, substeps, period, w_dst, w_centre,
        penalties.w_collision, penalties.safety_radius, obstacles.shape[0], penalties.w_obstacle,
    ]  # fmt: skip
    return np.concatenate(
        (
            np.array(header, dtype=np.float64),
            state,
            block_of_step,
            distance_targets.reshape(-1),
            centre_target.reshape(-1),
            neighbour_positions.reshape(-1),
            obstacles.reshape(-1),
        ),
        dtype=np.float64,
    )


@njit(cache=True, inline="always")
def packed_size(header: np.ndarray) -> int:
    """Length of a packed problem from its header."""
    n_neighbours, horizon, n_obstacles = int(header[0]), int(header[1]), int(header[8])
    return PACKED_HEADER + 4 + horizon + 4 * n_neighbours * horizon + 2 * horizon + 3 * n_obstacles


@njit(cache=True)
def packed_batch_cost(decisions: np.ndarray, data: np.ndarray) -> np.ndarray:
    """:func:`batch_cost` of the problem packed by :func:`pack_problem` (same arithmetic)."""
    n_neighbours, horizon, substeps = int(data[0]), int(data[1]), int(data[2])
    period, w_dst, w_centre = data[3], data[4], data[5]
    w_collision, safety_radius, n_obstacles, w_obstacle = data[6], data[7], int(data[8]), data[9]
    at = PACKED_HEADER
    state = data[at : at + 4]
    at += 4
    block_of_step = np.empty(horizon, dtype=np.int64)
    for k in range(horizon):
        block_of_step[k] = int(data[at + k])
    at += horizon
    size = n_neighbours * horizon * 2
    distance_targets = data[at : at + size].reshape((n_neighbours, horizon, 2))
    at += size
    centre_target = data[at : at + 2 * horizon].reshape((horizon, 2))
    at += 2 * horizon
    neighbour_positions = data[at : at + size].reshape((n_neighbours, horizon, 2))
    at += size
    obstacles = data[at : at + 3 * n_obstacles].reshape((n_obstacles, 3))
    return batch_cost(
        decisions, state, block_of_step, period, substeps, distance_targets, centre_target,
        w_dst, w_centre, neighbour_positions, w_collision, safety_radius, obstacles, w_obstacle,
    )  # fmt: skip


def _compiled_cost(x_ptr, n, d, data_ptr, out_ptr):  # type: ignore[no-untyped-def]
    size = packed_size(nb.carray(data_ptr, (PACKED_HEADER,)))
    costs = packed_batch_cost(nb.carray(x_ptr, (n, d)), nb.carray(data_ptr, (size,)))
    out = nb.carray(out_ptr, (n,))
    for i in range(n):
        out[i] = costs[i]


@functools.cache
def compiled_cost() -> nb.core.ccallback.CFunc:
    """:func:`packed_batch_cost` as a C function with
    :data:`~formation_bench.optimizers.compiled.COST_SIGNATURE` (built on first use)."""
    from formation_bench.optimizers.compiled import COST_SIGNATURE

    return nb.cfunc(COST_SIGNATURE, cache=True)(_compiled_cost)


def block_map(horizon_steps: int, n_blocks: int) -> np.ndarray:
    """Block index of every period: ``n_blocks`` contiguous, nearly equal blocks."""
    return (np.arange(horizon_steps) * n_blocks // horizon_steps).astype(np.int64)
