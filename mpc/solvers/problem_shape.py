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
    CasADi functions and solvers; it is the key of the optimisers' caches.
    """

    horizon_steps: int
    n_blocks: int
    block_of_step: tuple[int, ...]
    n_neighbours: int
    n_uav: int
    period_s: float
    rk4_substeps: int
    w_dst: float
    w_trj: float

    @classmethod
    def of(cls, problem: LocalProblem) -> ProblemShape:
        """The shape of ``problem``."""
        scenario = problem.scenario
        return cls(
            horizon_steps=int(scenario.horizon_steps),
            n_blocks=int(scenario.n_blocks),
            block_of_step=tuple(int(b) for b in problem.block_of_step),
            n_neighbours=int(problem.neighbour_positions.shape[0]),
            n_uav=int(scenario.n_uav),
            period_s=float(scenario.period_s),
            rk4_substeps=int(scenario.rk4_substeps),
            w_dst=float(scenario.w_dst),
            w_trj=float(scenario.w_trj),
        )

    @property
    def dim(self) -> int:
        """Length of the decision vector ``[a_1, omega_1, ..., a_B, omega_B]``."""
        return CONTROL_DIM * self.n_blocks

    @property
    def n_parameters(self) -> int:
        """Length of the parameter vector of :func:`pack_parameters`."""
        return STATE_DIM + 2 * 2 * self.n_neighbours * self.horizon_steps + 2 * self.horizon_steps


def pack_parameters(problem: LocalProblem) -> np.ndarray:
    """The parameter vector of ``problem``: state, estimates, desired offsets, reference."""
    return np.concatenate(
        (
            np.asarray(problem.state, dtype=np.float64).reshape(-1),
            np.asarray(problem.neighbour_positions, dtype=np.float64).reshape(-1),
            np.asarray(problem.desired_relative, dtype=np.float64).reshape(-1),
            np.asarray(problem.reference, dtype=np.float64).reshape(-1),
        )
    )
