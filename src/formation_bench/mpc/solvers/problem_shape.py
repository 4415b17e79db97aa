"""The shape of a per-UAV problem and its parameter vector, without any solver library.

A :class:`ProblemShape` keys the derivative-based solvers' caches (two problems
of equal shape share their CasADi functions and solvers), and
:func:`pack_parameters` flattens a problem's numbers into the vector those
functions take. Neither needs casadi, so the solvers can be configured and
registered without importing it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from formation_bench.mpc.problem import LocalProblem

__all__ = ["CONTROL_DIM", "STATE_DIM", "ProblemShape", "pack_parameters"]

STATE_DIM = 4
CONTROL_DIM = 2


@dataclass(frozen=True)
class ProblemShape:
    """Everything a symbolic problem depends on besides the parameter values.

    Two :class:`~formation_bench.mpc.problem.LocalProblem` with equal shapes share their
    CasADi functions and solvers; it is the key of the optimisers' caches, so it holds
    everything that changes the model: the neighbour count (it varies on the range and
    k-nearest graphs), how the formation centre is estimated, and which penalties are on.
    """

    horizon_steps: int
    n_blocks: int
    block_of_step: tuple[int, ...]
    n_neighbours: int
    centre_group: int
    """M, the UAVs the formation centre is estimated from (``LocalProblem.centre_group``)."""
    group_centre: bool
    """Whether the centre is ``(p_i + S) / M`` with S (``LocalProblem.centre_neighbour_sum``)
    a parameter; False: eq. (14)'s ``(p_i + sum_j p_hat_j) / M`` summed in the model."""
    period_s: float
    rk4_substeps: int
    w_dst: float
    w_trj: float
    w_collision: float = 0.0
    """Weight of the collision penalty against the neighbours' estimates; 0 = off."""
    safety_radius: float = 0.0
    """Distance at which the collision penalty starts (0 when it is off)."""
    n_obstacles: int = 0
    """Obstacles in the parameter vector (0 when the obstacle penalty is off)."""
    w_obstacle: float = 0.0
    """Weight of the obstacle penalty; 0 = off."""

    @classmethod
    def of(cls, problem: LocalProblem) -> ProblemShape:
        """The shape of ``problem``."""
        scenario = problem.scenario
        penalties = problem.penalties
        collision = penalties.w_collision > 0
        n_obstacles = penalties.obstacles.shape[0] if penalties.w_obstacle > 0 else 0
        return cls(
            horizon_steps=int(scenario.timing.horizon_steps),
            n_blocks=int(scenario.timing.n_blocks),
            block_of_step=tuple(int(b) for b in problem.block_of_step),
            n_neighbours=int(problem.neighbour_positions.shape[0]),
            centre_group=int(problem.centre_group),
            group_centre=problem.centre_offset_sum is not None,
            period_s=float(scenario.timing.period_s),
            rk4_substeps=int(scenario.timing.rk4_substeps),
            w_dst=float(scenario.weights.w_dst),
            w_trj=float(scenario.weights.w_trj),
            w_collision=float(penalties.w_collision) if collision else 0.0,
            safety_radius=float(penalties.safety_radius) if collision else 0.0,
            n_obstacles=int(n_obstacles),
            w_obstacle=float(penalties.w_obstacle) if n_obstacles else 0.0,
        )

    @property
    def dim(self) -> int:
        """Length of the decision vector ``[a_1, omega_1, ..., a_B, omega_B]``."""
        return CONTROL_DIM * self.n_blocks

    @property
    def penalised(self) -> bool:
        """Whether a collision or obstacle penalty adds to eq. (14)'s terms."""
        return self.w_collision > 0 or self.n_obstacles > 0

    @property
    def n_parameters(self) -> int:
        """Length of the parameter vector of :func:`pack_parameters`."""
        return (
            STATE_DIM
            + 2 * 2 * self.n_neighbours * self.horizon_steps
            + 2 * self.horizon_steps * (2 if self.group_centre else 1)
            + 3 * self.n_obstacles
        )


def pack_parameters(problem: LocalProblem, shape: ProblemShape | None = None) -> np.ndarray:
    """The parameter vector of ``problem`` (of shape ``shape``, computed when not given):
    state, estimates, desired offsets, reference, then the centre's neighbour sum S (when the
    centre is estimated from the group) and the obstacle rows ``(c_x, c_y, r + margin)`` (when
    the obstacle penalty is on)."""
    shape = ProblemShape.of(problem) if shape is None else shape
    pieces = [
        np.asarray(problem.state, dtype=np.float64).reshape(-1),
        np.asarray(problem.neighbour_positions, dtype=np.float64).reshape(-1),
        np.asarray(problem.desired_relative, dtype=np.float64).reshape(-1),
        np.asarray(problem.reference, dtype=np.float64).reshape(-1),
    ]
    if shape.group_centre:
        pieces.append(np.asarray(problem.centre_neighbour_sum, dtype=np.float64).reshape(-1))
    if shape.n_obstacles:
        pieces.append(np.asarray(problem.penalties.obstacles, dtype=np.float64).reshape(-1))
    return np.concatenate(pieces)
