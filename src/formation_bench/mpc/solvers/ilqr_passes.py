"""The passes of ``ilqr``, compiled: one iteration of ``iLQG.m``'s loop.

They follow ``iLQG.m`` of Tassa, Mansard and Todorov, "Control-limited differential dynamic
programming", ICRA 2014 (the iLQR of Li and Todorov, ICINCO 2004, with control limits):

- :func:`backward_pass`: the Riccati-like recursion from the last stage, with no terminal
  cost (every term of eq. (14) belongs to a stage); the feed-forward step ``k`` from the box
  QP of :mod:`~formation_bench.mpc.solvers.ilqr_boxqp`, warm-started from the next stage's
  step (the last stage from its previous one) as ``iLQG.m`` does; the feedback gain ``K`` on
  the QP's free controls, its clamped rows zero. ``mu`` is added to ``Q_uu`` (``iLQG.m``'s
  default ``regType = 1``) or, with ``state_regularisation``, to the next stage's ``V_xx``
  (Tassa, Erez and Todorov, IROS 2012); the value function is updated with the
  unregularised ``Q``, as in ``iLQG.m``;
- :func:`forward_pass`: ``u_b = clamp(u_bar_b + alpha k_b + K_b (x_b - x_bar_b))`` along the
  new trajectory, integrated as the plant does (:func:`formation_bench.mpc.model.
  advance_period`, so the feedback reads the states the controls really reach), its cost the
  harness's own compiled cost of the controls applied (:func:`formation_bench.mpc.cost.
  packed_batch_cost`: the objective to the bit);
- :func:`iterate`: backward passes until one succeeds, the stopping tests, the serial
  backtracking line search over the step lengths, and ``mu``'s schedule.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from formation_bench.kernel_cache import njit
from formation_bench.mpc.cost import PACKED_HEADER, packed_batch_cost
from formation_bench.mpc.model import advance_period, turn_rotation
from formation_bench.mpc.solvers.ilqr_boxqp import box_qp, cholesky_solve
from formation_bench.mpc.solvers.problem_shape import CONTROL_DIM, STATE_DIM

N, M = STATE_DIM, CONTROL_DIM


class Policy(NamedTuple):
    """A nominal trajectory and the affine control law about it, with the control box."""

    controls: np.ndarray
    """``(B, 2)`` nominal controls ``u_bar``."""
    states: np.ndarray
    """``(B, 4)`` nominal block-start states ``x_bar`` (row 0 the current state)."""
    feedforward: np.ndarray
    """``(B, 2)`` steps ``k`` of the last backward pass."""
    gains: np.ndarray
    """``(B, 2, 4)`` feedback gains ``K``."""
    lower: np.ndarray
    """``(B, 2)`` lower control bounds."""
    upper: np.ndarray
    """``(B, 2)`` upper control bounds."""


class BackwardOutcome(NamedTuple):
    """What a backward pass returns besides the policy it writes."""

    failed_stage: int
    """-1 on success, else the stage whose box QP failed (``Q_uu`` not positive definite)."""
    linear: float
    """``sum_b k_b' Q_u``: the expected reduction is ``-(alpha linear + alpha^2 quadratic)``."""
    quadratic: float
    """``sum_b k_b' Q_uu k_b / 2``."""
    qp_iterations: int
    """Box-QP iterations summed over the stages."""


F_X, F_U, L_X, L_U, L_XX, L_UU, L_UX = 0, 16, 24, 28, 30, 46, 50
"""Offsets of the derivatives in a stage's row (:data:`~formation_bench.mpc.solvers.
ilqr_derivatives.STAGE_LAYOUT`, row-major); a test checks them against the layout."""


@njit(cache=True, inline="always")
def _q_terms(row: np.ndarray, v_x: np.ndarray, v_xx: np.ndarray, q: tuple, work: tuple) -> None:
    """``Q_x, Q_u, Q_xx, Q_uu, Q_ux`` (into ``q``) of a stage's ``row`` and the next stage's
    value ``v_x``, ``v_xx``; ``work`` holds ``V_xx f_x`` and ``V_xx f_u``."""
    q_x, q_u, q_xx, q_uu, q_ux = q
    vf_x, vf_u = work
    for i in range(N):
        for j in range(N):
            vf_x[i, j] = 0.0
            for m in range(N):
                vf_x[i, j] += v_xx[i, m] * row[F_X + N * m + j]
        for j in range(M):
            vf_u[i, j] = 0.0
            for m in range(N):
                vf_u[i, j] += v_xx[i, m] * row[F_U + M * m + j]
    for j in range(N):
        q_x[j] = row[L_X + j]
        for i in range(N):
            q_x[j] += row[F_X + N * i + j] * v_x[i]
        for a in range(N):
            q_xx[a, j] = row[L_XX + N * a + j]
            for i in range(N):
                q_xx[a, j] += row[F_X + N * i + a] * vf_x[i, j]
        for a in range(M):
            q_ux[a, j] = row[L_UX + N * a + j]
            for i in range(N):
                q_ux[a, j] += row[F_U + M * i + a] * vf_x[i, j]
    for j in range(M):
        q_u[j] = row[L_U + j]
        for i in range(N):
            q_u[j] += row[F_U + M * i + j] * v_x[i]
        for a in range(M):
            q_uu[a, j] = row[L_UU + M * a + j]
            for i in range(N):
                q_uu[a, j] += row[F_U + M * i + a] * vf_u[i, j]


@njit(cache=True)
def backward_pass(
    derivatives: np.ndarray, policy: Policy, mu: float, state_regularisation: bool
) -> BackwardOutcome:
    """Write ``policy.feedforward`` and ``policy.gains`` from the stages' ``derivatives``
    (``(B, 58)`` rows in :data:`~formation_bench.mpc.solvers.ilqr_derivatives.STAGE_LAYOUT`
    order) about ``policy.controls``."""
    n_stages = derivatives.shape[0]
    v_x, v_xx = np.zeros(N), np.zeros((N, N))
    q_x, q_u, q_xx = np.empty(N), np.empty(M), np.empty((N, N))
    q_uu, q_ux = np.empty((M, M)), np.empty((M, N))
    q_uu_reg, q_ux_reg = np.empty((M, M)), np.empty((M, N))
    work = (np.empty((N, N)), np.empty((N, M)))
    lower, upper, column, q_uu_k = np.empty(M), np.empty(M), np.empty(M), np.empty(M)
    free_index, factor = np.empty(M, dtype=np.int64), np.empty((M, M))
    linear, quadratic, iterations = 0.0, 0.0, 0
    for b in range(n_stages - 1, -1, -1):
        row = derivatives[b]
        _q_terms(row, v_x, v_xx, (q_x, q_u, q_xx, q_uu, q_ux), work)
        for a in range(M):
            for j in range(M):
                q_uu_reg[a, j] = q_uu[a, j]
                if state_regularisation:  # f_u' (V_xx + mu I) f_u
                    for i in range(N):
                        q_uu_reg[a, j] += mu * row[F_U + M * i + a] * row[F_U + M * i + j]
            for j in range(N):
                q_ux_reg[a, j] = q_ux[a, j]
                if state_regularisation:  # f_u' (V_xx + mu I) f_x
                    for i in range(N):
                        q_ux_reg[a, j] += mu * row[F_U + M * i + a] * row[F_X + N * i + j]
            if not state_regularisation:
                q_uu_reg[a, a] += mu
            lower[a] = policy.lower[b, a] - policy.controls[b, a]
            upper[a] = policy.upper[b, a] - policy.controls[b, a]
        start = policy.feedforward[min(b + 1, n_stages - 1)]
        k, result, n_free, used = box_qp(q_uu_reg, q_u, lower, upper, start, free_index, factor)
        iterations += used
        if result < 1:
            return BackwardOutcome(b, linear, quadratic, iterations)
        gain = policy.gains[b]
        gain[:] = 0.0
        for j in range(N):
            for m in range(n_free):
                column[m] = q_ux_reg[free_index[m], j]
            # K_free = -Q_uu,free^-1 Q_ux,free, the clamped rows stay zero
            cholesky_solve(factor, n_free, column)
            for m in range(n_free):
                gain[free_index[m], j] = -column[m]
        policy.feedforward[b] = k
        for a in range(M):
            q_uu_k[a] = 0.0
            for j in range(M):
                q_uu_k[a] += q_uu[a, j] * k[j]
            linear += k[a] * q_u[a]
            quadratic += 0.5 * k[a] * q_uu_k[a]
        # the value function from the unregularised Q, as iLQG.m
        for j in range(N):
            v_x[j] = q_x[j]
            for a in range(M):
                v_x[j] += gain[a, j] * (q_uu_k[a] + q_u[a]) + q_ux[a, j] * k[a]
            for i in range(N):
                total = q_xx[i, j]
                for a in range(M):
                    total += gain[a, i] * q_ux[a, j] + q_ux[a, i] * gain[a, j]
                    for c in range(M):
                        total += gain[a, i] * q_uu[a, c] * gain[c, j]
                v_xx[i, j] = total
        for i in range(N):
            for j in range(i):
                v_xx[i, j] = v_xx[j, i] = 0.5 * (v_xx[i, j] + v_xx[j, i])
    return BackwardOutcome(-1, linear, quadratic, iterations)


@njit(cache=True)
def forward_pass(
    packed: np.ndarray, starts: np.ndarray, policy: Policy, alpha: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Controls ``(B, 2)``, block-start states ``(B, 4)`` and cost of the step ``alpha``."""
    substeps, period = int(packed[2]), packed[3]
    h = period / substeps
    n_stages = starts.shape[0] - 1
    controls = np.empty((n_stages, M))
    states = np.empty((n_stages, N))
    at = PACKED_HEADER
    x, y, theta, v = packed[at], packed[at + 1], packed[at + 2], packed[at + 3]
    for b in range(n_stages):
        states[b, 0], states[b, 1], states[b, 2], states[b, 3] = x, y, theta, v
        for i in range(M):
            u = policy.controls[b, i] + alpha * policy.feedforward[b, i]
            for j in range(N):
                u += policy.gains[b, i, j] * (states[b, j] - policy.states[b, j])
            controls[b, i] = min(max(u, policy.lower[b, i]), policy.upper[b, i])
        a, omega = controls[b, 0], controls[b, 1]
        turn = turn_rotation(omega, h)
        for _ in range(starts[b], starts[b + 1]):
            x, y, theta, v = advance_period(x, y, theta, v, a, omega, h, substeps, turn)
    cost = packed_batch_cost(controls.reshape((1, n_stages * M)), packed)[0]
    return controls, states, cost


class Iteration(NamedTuple):
    """What one iteration did (:func:`iterate`)."""

    status: int
    """One of :data:`ACCEPTED` ... :data:`MU_LIMIT`."""
    cost: float
    """The nominal cost after the iteration."""
    mu: float
    """The regularisation after the iteration."""
    delta: float
    """The regularisation's factor of change (``iLQG.m``'s ``dlambda``)."""
    rollouts: int
    """Forward passes run (cost evaluations)."""
    backward_passes: int
    qp_iterations: int
    """Box-QP iterations summed over the stages and backward passes."""
    measure: float
    """What the stopping test saw: the mean relative step (:data:`CONVERGED_STEP`), the
    expected (:data:`CONVERGED_EXPECTED`) or actual (:data:`CONVERGED_REDUCTION`) reduction
    relative to the cost."""


ACCEPTED, REJECTED, CONVERGED_STEP, CONVERGED_EXPECTED, CONVERGED_REDUCTION, MU_LIMIT = range(6)
"""Statuses of :func:`iterate`: a step was accepted; none was (``mu`` raised, the next
iteration reuses the derivatives); converged by the step size, by the expected reduction, by
the actual reduction of the accepted step; ``mu`` exceeded ``mu_max``."""
CONVERGED_MU = 1e-5
"""``iLQG.m``'s gradient test counts only with ``mu`` below this (a nearly Newton step)."""


@njit(cache=True, inline="always")
def _raise_mu(mu: float, delta: float, factor: float, mu_min: float) -> tuple[float, float]:
    delta = max(delta * factor, factor)
    return max(mu * delta, mu_min), delta


@njit(cache=True, inline="always")
def _lower_mu(mu: float, delta: float, factor: float, mu_min: float) -> tuple[float, float]:
    delta = min(delta / factor, 1.0 / factor)
    return (mu * delta if mu > mu_min else 0.0), delta


@njit(cache=True)
def iterate(
    derivatives: np.ndarray,
    packed: np.ndarray,
    starts: np.ndarray,
    policy: Policy,
    alphas: np.ndarray,
    settings: tuple,
    regularisation: tuple[float, float],
    cost: float,
) -> Iteration:
    """One iteration of ``iLQG.m``'s loop from the stages' ``derivatives`` about ``policy``
    (of cost ``cost``): backward passes until one succeeds (``mu`` raised after each failure),
    the stopping tests, the line search, and ``mu`` lowered or raised. An accepted step
    replaces ``policy.controls`` and ``policy.states``; ``settings`` holds ``mu_factor``,
    ``mu_min``, ``mu_max``, ``z_min``, ``tol_fun``, ``tol_grad``, ``state_regularisation`` and
    ``max_rollouts``; ``regularisation`` is ``(mu, delta)``."""
    mu, delta = regularisation
    factor, mu_min = settings.mu_factor, settings.mu_min
    passes, qp_iterations = 0, 0
    while True:
        outcome = backward_pass(derivatives, policy, mu, settings.state_regularisation)
        passes += 1
        qp_iterations += outcome.qp_iterations
        if outcome.failed_stage < 0:
            break
        mu, delta = _raise_mu(mu, delta, factor, mu_min)
        if mu > settings.mu_max:
            return Iteration(MU_LIMIT, cost, mu, delta, 0, passes, qp_iterations, np.nan)
    step_size = 0.0
    for b in range(policy.controls.shape[0]):
        largest = 0.0
        for i in range(M):
            largest = max(largest, abs(policy.feedforward[b, i]) / (abs(policy.controls[b, i]) + 1))
        step_size += largest / policy.controls.shape[0]
    # a zero step in every stage is a KKT point whatever mu: the box QP's solution is 0 exactly
    # when the gradient Q_u (exact when every k is 0) vanishes on the free controls and
    # pushes the others outwards
    if step_size < settings.tol_grad and (mu < CONVERGED_MU or step_size == 0.0):
        mu, delta = _lower_mu(mu, delta, factor, mu_min)
        return Iteration(CONVERGED_STEP, cost, mu, delta, 0, passes, qp_iterations, step_size)
    expected = -(outcome.linear + outcome.quadratic) / abs(cost)
    if expected < settings.tol_fun and mu < CONVERGED_MU:
        return Iteration(CONVERGED_EXPECTED, cost, mu, delta, 0, passes, qp_iterations, expected)
    tried = 0
    for index in range(min(alphas.shape[0], settings.max_rollouts)):
        alpha = alphas[index]
        controls, states, trial = forward_pass(packed, starts, policy, alpha)
        tried += 1
        reduction = cost - trial
        expected = -alpha * (outcome.linear + alpha * outcome.quadratic)
        ratio = reduction / expected if expected > 0.0 else np.sign(reduction)
        if ratio > settings.z_min:
            mu, delta = _lower_mu(mu, delta, factor, mu_min)
            policy.controls[:] = controls
            policy.states[:] = states
            relative = reduction / abs(trial)
            status = CONVERGED_REDUCTION if relative < settings.tol_fun else ACCEPTED
            return Iteration(status, trial, mu, delta, tried, passes, qp_iterations, relative)
    mu, delta = _raise_mu(mu, delta, factor, mu_min)
    status = MU_LIMIT if mu > settings.mu_max else REJECTED
    return Iteration(status, cost, mu, delta, tried, passes, qp_iterations, np.nan)
