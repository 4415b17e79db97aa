"""The event trigger of eqs. (15)-(19), one pure function per condition.

UAV i re-solves at t_c when ANY condition holds (eq. 19); otherwise it keeps
applying its last plan. With the corrections described in docs/explanation/paper.md: eq. (16)
divides by N_uav, and eq. (17) uses u_max = [a_max, omega_max] (checked on
both sides of each control's range, since the bounds are symmetric in the
paper but need not be here).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from formation_bench.kernel_cache import njit

TRIGGER_CONDITIONS = ("distance", "tracking", "control", "expiry")
"""Names of the conditions, in the order of eqs. (15)-(18)."""


@njit(cache=True)
def distance_condition(
    own_positions: np.ndarray,
    neighbour_positions: np.ndarray,
    desired_relative: np.ndarray,
    eps_p: float,
) -> bool:
    """Eq. (15): some neighbour's relative-position error reaches ``eps_p``.

    ``own_positions`` is ``(L, 2)``, the other two ``(J, L, 2)``, over the
    checked instants (t_c and any look-ahead). Compiled: the closed loop asks every UAV
    at every instant, where numpy's calls cost ten times the arithmetic;
    :func:`numpy_distance_condition` is the plain form, and a test checks the two agree.
    """
    for j in range(neighbour_positions.shape[0]):
        for k in range(own_positions.shape[0]):
            dx = own_positions[k, 0] - neighbour_positions[j, k, 0] - desired_relative[j, k, 0]
            dy = own_positions[k, 1] - neighbour_positions[j, k, 1] - desired_relative[j, k, 1]
            if math.sqrt(dx * dx + dy * dy) >= eps_p:
                return True
    return False


@njit(cache=True)
def tracking_condition(
    own_positions: np.ndarray,
    neighbour_positions: np.ndarray,
    reference: np.ndarray,
    group_size: int,
    eps_o: float,
    offset_sum: np.ndarray | None = None,
) -> bool:
    """Eq. (16): the estimated formation centre is ``eps_o`` or more from the reference.

    The centre is ``(p_i + sum_j p_hat_j) / group_size`` (eq. 16 with N_uav UAVs); with
    ``offset_sum`` ``(L, 2)``, the group's summed desired offsets, it is estimated from the
    UAV and its neighbours alone, ``(p_i + sum_j p_hat_j - offset_sum) / group_size``.
    Compiled, with the sums in numpy's order (:func:`numpy_tracking_condition`).
    """
    n_neighbours = neighbour_positions.shape[0]
    for k in range(own_positions.shape[0]):
        centre = [0.0, 0.0]
        for axis in range(2):
            total = neighbour_positions[0, k, axis] if n_neighbours else 0.0
            for j in range(1, n_neighbours):
                total += neighbour_positions[j, k, axis]
            total = own_positions[k, axis] + total
            if offset_sum is not None:
                total = total - offset_sum[k, axis]
            centre[axis] = total / group_size - reference[k, axis]
        if math.sqrt(centre[0] * centre[0] + centre[1] * centre[1]) >= eps_o:
            return True
    return False


@njit(cache=True)
def control_condition(
    control: np.ndarray, lower: np.ndarray, upper: np.ndarray, eta: float
) -> bool:
    """Eq. (17): the planned control reaches ``eta`` times a bound in some component."""
    for m in range(control.shape[0]):
        if control[m] >= eta * upper[m]:
            return True
    for m in range(control.shape[0]):
        if control[m] <= eta * lower[m]:
            return True
    return False


def numpy_distance_condition(
    own_positions: np.ndarray,
    neighbour_positions: np.ndarray,
    desired_relative: np.ndarray,
    eps_p: float,
) -> bool:
    """:func:`distance_condition` in numpy, as eq. (15) reads."""
    error = np.linalg.norm(own_positions[None] - neighbour_positions - desired_relative, axis=-1)
    return bool(np.any(error >= eps_p))


def numpy_tracking_condition(
    own_positions: np.ndarray,
    neighbour_positions: np.ndarray,
    reference: np.ndarray,
    group_size: int,
    eps_o: float,
    offset_sum: np.ndarray | None = None,
) -> bool:
    """:func:`tracking_condition` in numpy, as eq. (16) reads."""
    total = own_positions + neighbour_positions.sum(axis=0)
    if offset_sum is not None:
        total = total - offset_sum
    centre = total / group_size
    return bool(np.any(np.linalg.norm(centre - reference, axis=-1) >= eps_o))


def numpy_control_condition(
    control: np.ndarray, lower: np.ndarray, upper: np.ndarray, eta: float
) -> bool:
    """:func:`control_condition` in numpy, as eq. (17) reads."""
    return bool(np.any(control >= eta * upper) or np.any(control <= eta * lower))


def expiry_condition(steps_since_solve: int, horizon_steps: int) -> bool:
    """Eq. (18): the last plan has run out, t_c - t_trg >= Tp."""
    return steps_since_solve >= horizon_steps


class TriggerDecision(NamedTuple):
    """Which conditions held for one UAV at one instant (a tuple: one is made per UAV and
    instant)."""

    distance: bool
    tracking: bool
    control: bool
    expiry: bool

    @property
    def fire(self) -> bool:
        """Eq. (19): re-solve when any condition holds."""
        return self.distance or self.tracking or self.control or self.expiry

    def as_tuple(self) -> tuple[bool, bool, bool, bool]:
        return tuple(self)
