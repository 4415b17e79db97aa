"""The event trigger of eqs. (15)-(19), one pure function per condition.

UAV i re-solves at t_c when ANY condition holds (eq. 19); otherwise it keeps
applying its last plan. With the corrections described in docs/paper.md: eq. (16)
divides by N_uav, and eq. (17) uses u_max = [a_max, omega_max] (checked on
both sides of each control's range, since the bounds are symmetric in the
paper but need not be here).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

TRIGGER_CONDITIONS = ("distance", "tracking", "control", "expiry")
"""Names of the conditions, in the order of eqs. (15)-(18)."""


def distance_condition(
    own_positions: np.ndarray,
    neighbour_positions: np.ndarray,
    desired_relative: np.ndarray,
    eps_p: float,
) -> bool:
    """Eq. (15): some neighbour's relative-position error reaches ``eps_p``.

    ``own_positions`` is ``(L, 2)``, the other two ``(J, L, 2)``, over the
    checked instants (t_c and any look-ahead).
    """
    error = np.linalg.norm(own_positions[None] - neighbour_positions - desired_relative, axis=-1)
    return bool(np.any(error >= eps_p))


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
    """
    total = own_positions + neighbour_positions.sum(axis=0)
    if offset_sum is not None:
        total = total - offset_sum
    centre = total / group_size
    return bool(np.any(np.linalg.norm(centre - reference, axis=-1) >= eps_o))


def control_condition(
    control: np.ndarray, lower: np.ndarray, upper: np.ndarray, eta: float
) -> bool:
    """Eq. (17): the planned control reaches ``eta`` times a bound in some component."""
    return bool(np.any(control >= eta * upper) or np.any(control <= eta * lower))


def expiry_condition(steps_since_solve: int, horizon_steps: int) -> bool:
    """Eq. (18): the last plan has run out, t_c - t_trg >= Tp."""
    return steps_since_solve >= horizon_steps


@dataclass(frozen=True)
class TriggerDecision:
    """Which conditions held for one UAV at one instant."""

    distance: bool
    tracking: bool
    control: bool
    expiry: bool

    @property
    def fire(self) -> bool:
        """Eq. (19): re-solve when any condition holds."""
        return self.distance or self.tracking or self.control or self.expiry

    def as_tuple(self) -> tuple[bool, bool, bool, bool]:
        return (self.distance, self.tracking, self.control, self.expiry)
