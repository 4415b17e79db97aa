"""The UAV model of eq. (1) and its discretisation.

State ``z = [x, y, theta, v]``, control ``u = [a, omega]``::

    x' = v cos(theta),  y' = v sin(theta),  theta' = omega,  v' = a.

Controls are held constant over each control period (zero-order hold) and
the state is advanced with classical RK4 over ``substeps`` equal sub-steps of
the period. Under a held control ``theta`` and ``v`` are affine in time, so
RK4's two middle stages coincide and the step is Simpson's rule on the exact
heading and speed. Heading and speed are therefore integrated exactly and the
position to O(h^5) per step.

Simpson's rule needs the heading's cosine and sine at the start, middle and
end of every sub-step. :func:`rk4_substep` takes them from ``math.cos`` and
``math.sin`` (three pairs per sub-step); :func:`rotated_substep` gets the
middle and end ones by rotating the start pair through the sub-step's constant
turn (:func:`turn_rotation`). The plant (:func:`rollout`, :func:`step_plant`)
and the compiled cost both advance a period by :func:`advance_period`: the
pair is taken afresh from the tracked heading by :func:`cos_sin` at every
period start (and every :data:`HEADING_RESET_SUBSTEPS` sub-steps within a
period) and rotated in between, so a plan's prediction and the plant agree to
the last bit.
"""

from __future__ import annotations

import math

import numpy as np

from formation_bench.kernel_cache import njit

STATE_DIM = 4
CONTROL_DIM = 2


@njit(cache=True, inline="always")
def rk4_substep(
    x: float, y: float, theta: float, v: float, a: float, omega: float, h: float
) -> tuple[float, float, float, float]:
    """One RK4 step of length ``h`` under a held control ``(a, omega)``, by three sin/cos pairs.

    The plain form, kept as the yardstick of :func:`rotated_substep`.
    """
    theta_mid = theta + 0.5 * h * omega
    v_mid = v + 0.5 * h * a
    theta_end = theta + h * omega
    v_end = v + h * a
    dx = v * math.cos(theta) + 4.0 * v_mid * math.cos(theta_mid) + v_end * math.cos(theta_end)
    dy = v * math.sin(theta) + 4.0 * v_mid * math.sin(theta_mid) + v_end * math.sin(theta_end)
    return x + h * dx / 6.0, y + h * dy / 6.0, theta_end, v_end


HEADING_RESET_SUBSTEPS = 16
"""Sub-steps between fresh ``cos_sin(theta)`` within a period: bounds the rotated pair's drift.

Unbounded, over a period of 1000 sub-steps the drift reached 3e-13 of the
cost; every 16 sub-steps it stays near the rounding of the sums themselves.
"""

# fdlibm's split of pi/2 into parts of 33 significant bits: their products
# with a quadrant count below 2**20 are exact, so the reduced angle is good to
# about one rounding of itself.
_PIO2_1 = 1.57079632673412561417e00
_PIO2_2 = 6.07710050630396597660e-11
_PIO2_3 = 2.02226624871116645580e-21
_TWO_OVER_PI = 6.36619772367581382433e-01
REDUCTION_LIMIT = 2.0**19 * _PIO2_1
"""Angles at least this large in magnitude (about 8.2e5 rad) go to ``math.cos``/``math.sin``."""
# fdlibm's minimax polynomials of sin and cos on [-pi/4, pi/4]
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


@njit(cache=True, inline="always")
def reduced_cos_sin(angle: float) -> tuple[float, float]:
    """``(cos, sin)`` of ``angle`` for ``|angle| < REDUCTION_LIMIT``, without a branch or a call.

    Reduction by the nearest multiple of pi/2, two polynomials, and selects
    for the quadrant: a loop over many angles compiles to vector
    instructions, where the calls of ``math.cos`` and ``math.sin`` run one
    angle at a time and cost several times more.
    """
    quadrant = math.floor(angle * _TWO_OVER_PI + 0.5)
    r = ((angle - quadrant * _PIO2_1) - quadrant * _PIO2_2) - quadrant * _PIO2_3
    z = r * r
    sin_r = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    cos_r = 1.0 - (
        0.5 * z - z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    )
    return in_quadrant(quadrant, cos_r, sin_r)


@njit(cache=True, inline="always")
def in_quadrant(quadrant: int, cos_r: float, sin_r: float) -> tuple[float, float]:
    """``(cos, sin)`` of ``r + quadrant * pi / 2`` from those of ``r``, by selects alone."""
    n = np.int64(quadrant) & 3
    sin_a = cos_r if n & 1 else sin_r
    cos_a = sin_r if n & 1 else cos_r
    sin_a = -sin_a if n & 2 else sin_a
    cos_a = -cos_a if (n + 1) & 2 else cos_a
    return cos_a, sin_a


@njit(cache=True, inline="always")
def cos_sin(angle: float) -> tuple[float, float]:
    """``(cos, sin)`` of ``angle``: :func:`reduced_cos_sin`, or ``math`` past its range.

    Within about one rounding of ``math.cos`` and ``math.sin``; NaN and
    infinities give NaN as they do.
    """
    if abs(angle) < REDUCTION_LIMIT:
        return reduced_cos_sin(angle)
    return math.cos(angle), math.sin(angle)


@njit(cache=True, inline="always")
def turn_rotation(omega: float, h: float) -> tuple[float, float, float, float]:
    """Cosine and sine of the turn over half a sub-step and over a whole one.

    Returns ``(cos(h omega / 2), sin(h omega / 2), cos(h omega), sin(h omega))``;
    the whole turn comes from the half by the double-angle formulas, so one
    sin/cos pair serves a control. ``1 - 2 sin^2`` rather than ``cos^2 - sin^2``
    keeps the cosine of a small turn accurate to the last bit.
    """
    cos_half, sin_half = cos_sin(0.5 * h * omega)
    return cos_half, sin_half, 1.0 - 2.0 * sin_half * sin_half, 2.0 * sin_half * cos_half


@njit(cache=True, inline="always")
def rotated_substep(
    x: float,
    y: float,
    cos_t: float,
    sin_t: float,
    v: float,
    a: float,
    h: float,
    cos_half: float,
    sin_half: float,
    cos_full: float,
    sin_full: float,
) -> tuple[float, float, float, float, float]:
    """:func:`rk4_substep` from the heading's ``(cos, sin)`` and the turn of :func:`turn_rotation`.

    Returns ``(x, y, cos, sin, v)`` at the end of the sub-step; the caller
    advances the heading itself.
    """
    v_mid = v + 0.5 * h * a
    v_end = v + h * a
    cos_mid = cos_t * cos_half - sin_t * sin_half
    sin_mid = sin_t * cos_half + cos_t * sin_half
    cos_end = cos_t * cos_full - sin_t * sin_full
    sin_end = sin_t * cos_full + cos_t * sin_full
    dx = v * cos_t + 4.0 * v_mid * cos_mid + v_end * cos_end
    dy = v * sin_t + 4.0 * v_mid * sin_mid + v_end * sin_end
    return x + h * dx / 6.0, y + h * dy / 6.0, cos_end, sin_end, v_end


@njit(cache=True, inline="always")
def advance_period(
    x: float,
    y: float,
    theta: float,
    v: float,
    a: float,
    omega: float,
    h: float,
    substeps: int,
    turn: tuple[float, float, float, float],
) -> tuple[float, float, float, float]:
    """The state one control period on: ``substeps`` :func:`rotated_substep` from ``theta``.

    ``turn`` is :func:`turn_rotation` ``(omega, h)``. The heading is advanced
    by the same sums as in :func:`rk4_substep`, so it is bit for bit the plain
    form's. The rotated pair drifts from the heading by about one rounding per
    sub-step, so it is taken afresh from it every :data:`HEADING_RESET_SUBSTEPS`
    sub-steps, counted from the period start.
    """
    cos_half, sin_half, cos_full, sin_full = turn
    cos_t, sin_t = 0.0, 0.0
    for m in range(substeps):
        if m % HEADING_RESET_SUBSTEPS == 0:
            cos_t, sin_t = cos_sin(theta)
        x, y, cos_t, sin_t, v = rotated_substep(
            x, y, cos_t, sin_t, v, a, h, cos_half, sin_half, cos_full, sin_full
        )
        theta = theta + h * omega
    return x, y, theta, v


@njit(cache=True)
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
        x, y, theta, v = advance_period(
            x, y, theta, v, a, omega, h, substeps, turn_rotation(omega, h)
        )
        out[k + 1, 0], out[k + 1, 1], out[k + 1, 2], out[k + 1, 3] = x, y, theta, v
    return out


@njit(cache=True)
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


@njit(cache=True)
def step_plant(
    states: np.ndarray, controls: np.ndarray, period: float, substeps: int
) -> np.ndarray:
    """Advance every UAV by one period: ``(N, 4), (N, 2) -> (N, 4)``."""
    out = np.empty_like(states)
    for i in range(states.shape[0]):
        reached = rollout(states[i], controls[i : i + 1], period, substeps)[1]
        # element by element: a row assignment makes numba compile its shape-mismatch error,
        # and with it string formatting (about 2 s of a first run's compile)
        for k in range(reached.shape[0]):
            out[i, k] = reached[k]
    return out


def coast(state: np.ndarray, durations: np.ndarray) -> np.ndarray:
    """Positions reached from ``state`` under zero control after each duration.

    Zero control keeps speed and heading, so the motion is a straight line;
    returns ``(len(durations), 2)``. The plain form of an estimate's COAST extension, which
    :func:`~formation_bench.mpc.problem.track_positions` computes compiled (a test checks the
    two agree to the bit).
    """
    x, y, theta, v = state
    durations = np.asarray(durations, dtype=np.float64)
    return np.column_stack(
        (x + v * math.cos(theta) * durations, y + v * math.sin(theta) * durations)
    )
