"""The UAV model of eq. (1) and its discretisation.

State ``z = [x, y, theta, v]``, control ``u = [a, omega]``::

    x' = v cos(theta),  y' = v sin(theta),  theta' = omega,  v' = a.

Controls are held constant over each control period (zero-order hold) and
the state is advanced with classical RK4 over ``substeps`` equal sub-steps of
the period. Under a held control ``theta`` and ``v`` are affine in time, so
RK4's two middle stages coincide and the step is Simpson's rule on the exact
heading and speed: three sine/cosine pairs per sub-step. Heading and speed are
therefore integrated exactly and the position to O(h^5) per step.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

STATE_DIM = 4
CONTROL_DIM = 2


@nb.njit(cache=True, inline="always")
def rk4_substep(
    x: float, y: float, theta: float, v: float, a: float, omega: float, h: float
) -> tuple[float, float, float, float]:
    """One RK4 step of length ``h`` under a held control ``(a, omega)``."""
    theta_mid = theta + 0.5 * h * omega
    v_mid = v + 0.5 * h * a
    theta_end = theta + h * omega
    v_end = v + h * a
    dx = v * math.cos(theta) + 4.0 * v_mid * math.cos(theta_mid) + v_end * math.cos(theta_end)
    dy = v * math.sin(theta) + 4.0 * v_mid * math.sin(theta_mid) + v_end * math.sin(theta_end)
    return x + h * dx / 6.0, y + h * dy / 6.0, theta_end, v_end


@nb.njit(cache=True)
def rollout(state: np.ndarray, controls: np.ndarray, period: float, substeps: int) -> np.ndarray:
    """States at every period boundary under held controls.

    ``state`` has shape ``(4,)``, ``controls`` ``(H, 2)``; returns ``(H + 1, 4)``
    with row 0 equal to ``state``.
    """
    horizon = controls.shape[0]
    out = np.empty((horizon + 1, STATE_DIM))
    x, y, theta, v = state[0], state[1], state[2], state[3]
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = x, y, theta, v
    h = period / substeps
    for k in range(horizon):
        a = controls[k, 0]
        omega = controls[k, 1]
        for _ in range(substeps):
            x, y, theta, v = rk4_substep(x, y, theta, v, a, omega, h)
        out[k + 1, 0], out[k + 1, 1], out[k + 1, 2], out[k + 1, 3] = x, y, theta, v
    return out


@nb.njit(cache=True)
def rollout_batch(
    state: np.ndarray, controls: np.ndarray, period: float, substeps: int
) -> np.ndarray:
    """:func:`rollout` for many control sequences: ``(n, H, 2) -> (n, H + 1, 4)``."""
    n = controls.shape[0]
    horizon = controls.shape[1]
    out = np.empty((n, horizon + 1, STATE_DIM))
    for i in range(n):
        out[i] = rollout(state, controls[i], period, substeps)
    return out


def step_plant(
    states: np.ndarray, controls: np.ndarray, period: float, substeps: int
) -> np.ndarray:
    """Advance every UAV by one period: ``(N, 4), (N, 2) -> (N, 4)``."""
    out = np.empty_like(states)
    for i in range(states.shape[0]):
        out[i] = rollout(states[i], controls[i : i + 1], period, substeps)[1]
    return out


def coast(state: np.ndarray, durations: np.ndarray) -> np.ndarray:
    """Positions reached from ``state`` under zero control after each duration.

    Zero control keeps speed and heading, so the motion is a straight line;
    returns ``(len(durations), 2)``.
    """
    x, y, theta, v = state
    durations = np.asarray(durations, dtype=np.float64)
    return np.column_stack(
        (x + v * math.cos(theta) * durations, y + v * math.sin(theta) * durations)
    )
