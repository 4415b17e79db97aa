"""Plans, neighbour estimates, and the per-UAV optimisation problem.

A :class:`Plan` is what a UAV publishes after a solve: its control sequence
over the horizon and the states it predicts. Neighbours turn it into an
*estimate* (Section 2.2): the plan's predicted positions from the current
instant on, extended past the plan's end by the scenario's
:class:`~formation_bench.mpc.scenario.EstimateExtension` rule. :class:`LocalProblem` is the
problem of eq. (14) built from those estimates, exposed to optimisers as a
batch objective over the (blocked) control sequence with box bounds.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from formation_bench.kernel_cache import njit
from formation_bench.mpc.cost import (
    Penalties,
    block_map,
    pack_problem,
    reference_cost,
)
from formation_bench.mpc.model import rollout
from formation_bench.mpc.native_cost import cost_function, python_cost
from formation_bench.mpc.scenario import EstimateExtension, Scenario
from formation_bench.optimizers.base import Bounds
from formation_bench.optimizers.compiled import CompiledObjective


@dataclass(frozen=True)
class Plan:
    """A UAV's published plan."""

    start_step: int
    """Update instant c at which the plan was computed (its first control applies then)."""
    controls: np.ndarray
    """Planned controls ``(H, 2)``, one per period."""
    states: np.ndarray
    """Predicted states ``(H + 1, 4)``; row 0 is the state at ``start_step``."""

    @property
    def horizon_steps(self) -> int:
        return int(self.controls.shape[0])


def coasting_plan(state: np.ndarray, start_step: int, scenario: Scenario) -> Plan:
    """The zero-control plan from ``state``: what a UAV is assumed to do before any plan.

    At t0 no plan has been exchanged; each UAV then assumes its neighbours
    keep their current speed and heading.
    """
    timing = scenario.timing
    controls = np.zeros((timing.horizon_steps, 2))
    states = rollout(state, controls, timing.period_s, timing.rk4_substeps)
    return Plan(start_step, controls, states)


def estimate_positions(
    plan: Plan, step: int, n_points: int, period: float, extension: EstimateExtension
) -> np.ndarray:
    """Estimated positions at instants ``step, step + 1, ..., step + n_points - 1``.

    Inside the plan they are its predicted positions; past its end they follow
    ``extension``: COAST flies the terminal state on at constant speed and
    heading (:func:`~formation_bench.mpc.model.coast`), HOLD keeps the terminal position.
    """
    first = step - plan.start_step
    if first < 0:
        raise ValueError(f"plan starts at instant {plan.start_step}, after {step}")
    return track_positions(
        plan.states, first, n_points, period, extension == EstimateExtension.COAST
    )


@njit(cache=True)
def track_positions(
    states: np.ndarray, first: int, n_points: int, period: float, coasting: bool
) -> np.ndarray:
    """``(n_points, 2)``: the positions of predicted ``states`` ``(H + 1, 4)`` from row
    ``first`` on, past the last row coasting (``coasting``) or held there. Compiled: every new
    plan is estimated, where numpy's calls on a few rows cost more than the arithmetic; it
    computes :func:`~formation_bench.mpc.model.coast`'s formula in its order."""
    horizon = states.shape[0] - 1
    x, y, theta, v = states[horizon, 0], states[horizon, 1], states[horizon, 2], states[horizon, 3]
    velocity_x, velocity_y = v * math.cos(theta), v * math.sin(theta)
    positions = np.empty((n_points, 2))
    for k in range(n_points):
        index = first + k
        if index > horizon and coasting:
            duration = (index - horizon) * period
            positions[k, 0] = x + velocity_x * duration
            positions[k, 1] = y + velocity_y * duration
        else:
            row = min(index, horizon)
            positions[k, 0] = states[row, 0]
            positions[k, 1] = states[row, 1]
    return positions


def shifted_controls(plan: Plan, step: int) -> np.ndarray:
    """The plan's controls from instant ``step`` on, padded with its last control."""
    horizon = plan.horizon_steps
    index = np.minimum(step - plan.start_step + np.arange(horizon), horizon - 1)
    return plan.controls[index]


@functools.lru_cache(maxsize=256)
def decision_space(scenario: Scenario, uav: int = 0) -> tuple[np.ndarray, Bounds]:
    """Block index of every period and the box of UAV ``uav``'s decision vector; shared, do
    not modify.

    They depend on the scenario only, and a problem is built at every solve:
    building them each time cost 33 µs, a tenth of an ``ltv-osqp`` solve. The
    block map stays writable because numba compiles read-only arrays separately.
    """
    timing = scenario.timing
    block_of_step = block_map(timing.horizon_steps, timing.n_blocks)
    lower, upper = scenario.control_bounds_of(uav)
    bounds = Bounds(np.tile(lower, timing.n_blocks), np.tile(upper, timing.n_blocks))
    return block_of_step, bounds


@functools.lru_cache(maxsize=256)
def scenario_penalties(scenario: Scenario) -> Penalties:
    """The scenario's penalties as the cost kernel reads them (obstacle radii grown by the
    margin); shared, do not modify. Built once per scenario, not at every solve."""
    safety = scenario.safety
    obstacles = np.asarray(safety.obstacles, dtype=np.float64).reshape(-1, 3).copy()
    obstacles[:, 2] += safety.obstacle_margin_m
    return Penalties(safety.w_collision, safety.safety_radius_m, obstacles, safety.w_obstacle)


def centre_group_size(n_uav: int, n_neighbours: int, group_centre: bool) -> int:
    """M, the number of UAVs a UAV estimates the formation centre from: every UAV (eq. 14),
    or with ``group_centre`` the UAV and its ``n_neighbours`` neighbours alone."""
    return n_neighbours + 1 if group_centre else n_uav


@njit(cache=True)
def block_means(controls: np.ndarray, block_of_step: np.ndarray, n_blocks: int) -> np.ndarray:
    """``(2 * n_blocks,)``: the mean of the per-period ``controls`` ``(H, 2)`` over each block,
    as a decision vector. Summed period by period in order, as ``np.add.at`` sums."""
    sums = np.zeros((n_blocks, 2))
    counts = np.zeros(n_blocks, dtype=np.int64)
    for k in range(block_of_step.shape[0]):
        block = block_of_step[k]
        sums[block, 0] += controls[k, 0]
        sums[block, 1] += controls[k, 1]
        counts[block] += 1
    means = np.empty(2 * n_blocks)
    for block in range(n_blocks):
        means[2 * block] = sums[block, 0] / counts[block]
        means[2 * block + 1] = sums[block, 1] / counts[block]
    return means


class LocalProblem:
    """UAV ``uav``'s problem of eq. (14) at one update instant, as a batch objective.

    Calling it with ``(n, 2 * n_blocks)`` decision vectors (rows of
    ``[a_1, omega_1, a_2, omega_2, ...]``, one pair per block) returns ``(n,)``
    costs. ``bounds`` are the control bounds repeated per block.
    """

    def __init__(
        self,
        scenario: Scenario,
        uav: int,
        state: np.ndarray,
        neighbour_positions: np.ndarray,
        desired_relative: np.ndarray,
        reference: np.ndarray,
        centre_offset_sum: np.ndarray | None = None,
    ) -> None:
        self.scenario = scenario
        self.uav = uav
        self.state = np.ascontiguousarray(state, dtype=np.float64)
        self.neighbour_positions = neighbour_positions
        """Estimated neighbour positions over the horizon, ``(J, H, 2)``."""
        self.desired_relative = desired_relative
        """Desired ``p_i - p_j`` over the horizon, ``(J, H, 2)``."""
        self.reference = reference
        """Desired formation-centre positions over the horizon, ``(H, 2)``."""
        self.centre_offset_sum = centre_offset_sum
        """The UAV's and its neighbours' desired offsets summed, ``(H, 2)``, when the centre is
        estimated from them alone; None: eq. (14)'s centre over all ``n_uav`` UAVs."""
        self.block_of_step, self.bounds = decision_space(scenario, uav)
        group = self.centre_group
        self._distance_targets = np.ascontiguousarray(neighbour_positions + desired_relative)
        self._centre_target = np.ascontiguousarray(group * reference - self.centre_neighbour_sum)
        self._w_centre = scenario.weights.w_trj / group**2

    @property
    def centre_group(self) -> int:
        """M, the number of UAVs the formation centre is estimated from."""
        return centre_group_size(
            self.scenario.n_uav,
            self.neighbour_positions.shape[0],
            group_centre=self.centre_offset_sum is not None,
        )

    @property
    def centre_neighbour_sum(self) -> np.ndarray:
        """``(H, 2)`` S with the estimated centre ``(p_i + S) / M``: the neighbours' estimates
        summed, less the group's offsets when the centre is estimated from the group."""
        total = self.neighbour_positions.sum(axis=0)
        return total if self.centre_offset_sum is None else total - self.centre_offset_sum

    @property
    def penalties(self) -> Penalties:
        """The collision and obstacle penalties of the scenario (none in the paper's)."""
        return scenario_penalties(self.scenario)

    @property
    def dim(self) -> int:
        return self.bounds.dim

    def __call__(self, decisions: np.ndarray) -> np.ndarray:
        decisions = np.ascontiguousarray(decisions, dtype=np.float64)
        if decisions.ndim != 2 or decisions.shape[1] != self.dim:
            raise ValueError(f"decisions must have shape (n, {self.dim}), got {decisions.shape}")
        return self._python_cost(decisions, self.packed)

    @functools.cached_property
    def _python_cost(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """The kernel of calls from Python (:func:`~formation_bench.mpc.native_cost.
        python_cost`), chosen at the problem's first call."""
        return python_cost()

    @functools.cached_property
    def packed(self) -> np.ndarray:
        """The problem as :func:`~formation_bench.mpc.cost.pack_problem` lays it out: what the
        cost kernel reads, called from Python or through :attr:`compiled`."""
        timing, weights = self.scenario.timing, self.scenario.weights
        return pack_problem(
            self.state, self.block_of_step, timing.period_s, timing.rk4_substeps,
            self._distance_targets, self._centre_target, weights.w_dst, self._w_centre,
            np.ascontiguousarray(self.neighbour_positions, dtype=np.float64), self.penalties,
        )  # fmt: skip

    def __getstate__(self) -> dict:
        # the compiled handle holds a C function and the Python cost may be a closure, which do
        # not pickle; both are rebuilt on use
        state = dict(self.__dict__)
        state.pop("compiled", None)
        state.pop("_python_cost", None)
        return state

    @functools.cached_property
    def compiled(self) -> CompiledObjective:
        """The same cost as a compiled objective, for optimisers with a compiled solve loop."""
        cost = cost_function()
        return CompiledObjective(cost.address, self.packed, cost.owner)

    def reference_cost(self, decision: np.ndarray) -> float:
        """Eq. (14) for one decision vector by the plain reference implementation."""
        scenario, timing, weights = self.scenario, self.scenario.timing, self.scenario.weights
        return reference_cost(
            decision, self.state, self.block_of_step, timing.period_s, timing.rk4_substeps,
            self.neighbour_positions, self.desired_relative, self.reference,
            weights.w_dst, weights.w_trj, scenario.n_uav, self.centre_offset_sum,
            self.penalties.w_collision, self.penalties.safety_radius, self.penalties.obstacles,
            self.penalties.w_obstacle,
        )  # fmt: skip

    def controls(self, decision: np.ndarray) -> np.ndarray:
        """Per-period controls ``(H, 2)`` of one decision vector."""
        return np.asarray(decision, dtype=np.float64).reshape(-1, 2)[self.block_of_step]

    def decision_from_controls(self, controls: np.ndarray) -> np.ndarray:
        """Block averages of per-period controls ``(H, 2)``: the warm-start decision."""
        return self.bounds.clip(
            block_means(controls, self.block_of_step, self.scenario.timing.n_blocks)
        )

    def plan(self, decision: np.ndarray, start_step: int) -> Plan:
        """The plan a decision vector stands for, starting at ``start_step``."""
        controls = self.controls(decision)
        timing = self.scenario.timing
        states = rollout(self.state, controls, timing.period_s, timing.rk4_substeps)
        return Plan(start_step, controls, states)
