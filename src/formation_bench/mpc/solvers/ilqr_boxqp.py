"""The box-constrained QP of ``ilqr``'s backward pass: projected Newton (Tassa et al. 2014).

``minimize 0.5 x' H x + g' x  subject to  lower <= x <= upper`` by the projected-Newton method
of Tassa, Mansard and Todorov, "Control-limited differential dynamic programming", ICRA 2014,
as their ``boxQP.m`` writes it: at each iterate the *clamped* set is the coordinates on a
bound whose gradient pushes outwards; a Newton step on the free coordinates (the clamped ones
held), projected on the box, is shortened by an Armijo backtracking search.
It stops when the free gradient is small, the improvement is small, every coordinate is
clamped, the step search fails or the iteration limit is reached; a Hessian that is not
positive definite on the free coordinates is a failure (the caller then raises its
regularisation). The settings are ``boxQP.m``'s defaults (:data:`MAX_ITERATIONS` ...).

It returns the free set and the Cholesky factor of ``H`` on it, from which the backward pass
takes the feedback gain's free rows (the paper sets its clamped rows to zero).
"""

from __future__ import annotations

import math

import numpy as np

from formation_bench.kernel_cache import njit

MAX_ITERATIONS = 100
"""``boxQP.m``'s maxIter."""
MIN_GRADIENT = 1e-8
"""``minGrad``: stop when the free gradient's norm is below it."""
MIN_RELATIVE_IMPROVEMENT = 1e-8
"""``minRelImprove``: stop when an iteration improves the value by less, relative."""
STEP_DECREASE = 0.6
"""``stepDec``: the Armijo search's step factor."""
MIN_STEP = 1e-22
"""``minStep``: the Armijo search gives up below this step."""
ARMIJO = 0.1
"""``Armijo``: the share of the linear improvement a step must make."""

HESSIAN_NOT_POSITIVE_DEFINITE = -1
"""``boxQP.m``'s result codes (``result``): -1 the free Hessian is not positive definite,
0 no descent direction, 1 iteration limit, 2 step search failed, 4 small improvement,
5 small gradient, 6 every coordinate clamped. Below 1 the backward pass fails."""
NO_DESCENT, ITERATION_LIMIT, STEP_FAILED = 0, 1, 2
SMALL_IMPROVEMENT, SMALL_GRADIENT, ALL_CLAMPED = 4, 5, 6


@njit(cache=True, inline="always")
def cholesky_of(matrix: np.ndarray, index: np.ndarray, size: int, factor: np.ndarray) -> bool:
    """Lower Cholesky factor of ``matrix[index[:size]][:, index[:size]]`` into
    ``factor[:size, :size]``; False if that block is not positive definite."""
    for i in range(size):
        for j in range(i + 1):
            total = matrix[index[i], index[j]]
            for m in range(j):
                total -= factor[i, m] * factor[j, m]
            if i == j:
                if not total > 0.0:
                    return False
                factor[i, i] = math.sqrt(total)
            else:
                factor[i, j] = total / factor[j, j]
    return True


@njit(cache=True, inline="always")
def cholesky_solve(factor: np.ndarray, size: int, rhs: np.ndarray) -> None:
    """``rhs[:size] <- (L L')^-1 rhs[:size]`` in place, ``L = factor[:size, :size]``."""
    for i in range(size):
        total = rhs[i]
        for m in range(i):
            total -= factor[i, m] * rhs[m]
        rhs[i] = total / factor[i, i]
    for i in range(size - 1, -1, -1):
        total = rhs[i]
        for m in range(i + 1, size):
            total -= factor[m, i] * rhs[m]
        rhs[i] = total / factor[i, i]


@njit(cache=True, inline="always")
def _value(hessian: np.ndarray, gradient: np.ndarray, x: np.ndarray) -> float:
    n = x.shape[0]
    total = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += hessian[i, j] * x[j]
        total += x[i] * (gradient[i] + 0.5 * row)
    return total


@njit(cache=True)
def box_qp(
    hessian: np.ndarray,
    gradient: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    start: np.ndarray,
    free_index: np.ndarray,
    factor: np.ndarray,
) -> tuple[np.ndarray, int, int, int]:
    """Solve the box QP from ``start`` (clamped to the box).

    Returns ``(x, result, n_free, iterations)``; on return ``free_index[:n_free]`` are the
    free coordinates and ``factor[:n_free, :n_free]`` the Cholesky factor of ``hessian`` on
    them (both work arrays of the caller, of length / size n).
    """
    n = gradient.shape[0]
    x = np.minimum(np.maximum(start, lower), upper)
    grad = np.empty(n)
    search = np.empty(n)
    candidate = np.empty(n)
    rhs = np.empty(n)
    clamped = np.zeros(n, dtype=np.bool_)
    was_clamped = np.zeros(n, dtype=np.bool_)
    value = _value(hessian, gradient, x)
    old_value = 0.0
    result = ITERATION_LIMIT
    n_free = 0
    iteration = 0
    for iteration in range(1, MAX_ITERATIONS + 1):
        if iteration > 1 and old_value - value < MIN_RELATIVE_IMPROVEMENT * abs(old_value):
            result = SMALL_IMPROVEMENT
            break
        old_value = value
        for i in range(n):
            total = gradient[i]
            for j in range(n):
                total += hessian[i, j] * x[j]
            grad[i] = total
        changed = iteration == 1
        n_free = 0
        for i in range(n):
            was_clamped[i] = clamped[i]
            clamped[i] = (x[i] == lower[i] and grad[i] > 0.0) or (
                x[i] == upper[i] and grad[i] < 0.0
            )
            changed = changed or clamped[i] != was_clamped[i]
            if not clamped[i]:
                free_index[n_free] = i
                n_free += 1
        if n_free == 0:
            result = ALL_CLAMPED
            break
        if changed and not cholesky_of(hessian, free_index, n_free, factor):
            result = HESSIAN_NOT_POSITIVE_DEFINITE
            break
        norm = 0.0
        for m in range(n_free):
            norm += grad[free_index[m]] ** 2
        if math.sqrt(norm) < MIN_GRADIENT:
            result = SMALL_GRADIENT
            break
        # Newton step on the free coordinates, the clamped ones held at their bounds
        for m in range(n_free):
            i = free_index[m]
            total = gradient[i]
            for j in range(n):
                if clamped[j]:
                    total += hessian[i, j] * x[j]
            rhs[m] = total
        cholesky_solve(factor, n_free, rhs)
        search[:] = 0.0
        slope = 0.0
        for m in range(n_free):
            i = free_index[m]
            search[i] = -rhs[m] - x[i]
            slope += search[i] * grad[i]
        if slope >= 0.0:
            result = NO_DESCENT
            break
        step = 1.0
        while True:
            for i in range(n):
                candidate[i] = min(max(x[i] + step * search[i], lower[i]), upper[i])
            trial = _value(hessian, gradient, candidate)
            if (trial - old_value) / (step * slope) >= ARMIJO:
                break
            step *= STEP_DECREASE
            if step < MIN_STEP:
                result = STEP_FAILED
                break
        # as boxQP.m, the last candidate is taken even when the step search gave up
        x[:] = candidate
        value = trial
        if result == STEP_FAILED:
            break
    return x, result, n_free, iteration
