"""The stages of ``ilqr`` and their derivatives, from the CasADi model of eq. (14).

The decision is blocked: the horizon's H periods share ``n_blocks`` = B controls, block b
holding the contiguous periods ``starts[b] .. starts[b + 1] - 1``
(:func:`formation_bench.mpc.cost.block_map`). iLQR runs on B *stages*, one per block: stage b
starts at the state ``x_b`` at the block's first period (``x_0`` the current state), its
dynamics ``F_b(x_b, u_b)`` is the composition of the block's RK4 periods under the held
control ``u_b``, and its cost ``l_b(x_b, u_b)`` sums eq. (14)'s terms (and the penalties) of the
block's periods, each at the position that period ends at (the right-endpoint rule of
:func:`formation_bench.mpc.solvers.casadi_model.horizon_cost`). The stage costs add up to the
problem's cost exactly; with ``n_blocks = H`` a stage is one period and the decision the full
control sequence.

:func:`build_derivatives` writes every stage once in CasADi symbols (the dynamics by
:func:`~formation_bench.mpc.solvers.casadi_model.period_step`, the cost by
:func:`~formation_bench.mpc.solvers.casadi_model.stage_cost` and
:func:`~formation_bench.mpc.solvers.casadi_model.penalty_terms`) and returns one function per
:class:`~formation_bench.mpc.solvers.problem_shape.ProblemShape` that, given the block-start
states and the controls of a trajectory, gives every stage's ``f_x``, ``f_u``, ``l_x``,
``l_u``, ``l_xx``, ``l_uu``, ``l_ux`` in one evaluation (:data:`STAGE_LAYOUT`). It is called
through CasADi's buffer interface on preallocated arrays: about 0.1 µs of call overhead
against about 17 µs for an ordinary call that converts its arguments and results.

CasADi rather than derivatives written out, by measurement: on the paper's problem an
evaluation takes 7 µs (Gauss-Newton; 11 µs exact, about 25-30 µs with the obstacle penalties)
in CasADi's virtual machine, of about 30 µs per iteration and 120 µs per solve (best of 7,
median of 30 library problems); compiled to C (``jit``) it takes about 1 µs and the solve
80 µs. Derivatives written out in numba could gain no more than the compiled function does,
and would be a fourth writing of the model beside the compiled cost, the plain reference and
:mod:`~formation_bench.mpc.solvers.casadi_model`, which this one reuses.

The cost's second derivative is one of two (:class:`CostHessian`; the second derivatives of
the dynamics between stages are dropped in either, as iLQR does, Li and Todorov 2004):

- ``exact``: the Hessian of ``l_b`` in ``(x_b, u_b)``. ``l_b`` reads the positions of the
  block's periods, which are nonlinear in ``(x_b, u_b)``, so it holds the curvature of the
  dynamics *within* the block contracted with the cost's slope; the penalties enter with
  their exact Hessian (it jumps where a penalty starts);
- ``gauss-newton``: ``sum_k G_k' H_k G_k`` over the block's periods, ``G_k`` the Jacobian of
  period k's position in ``(x_b, u_b)`` and ``H_k`` the Hessian of eq. (14)'s terms in that
  position (constant: they are quadratic in it); each penalty ``e^2``,
  ``e = sqrt(delta_T w) max(0, r - d)``, adds ``2 J_e' J_e`` as in ``ltv-osqp``. Positive
  semidefinite by construction.
"""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from formation_bench.mpc.solvers.problem_shape import CONTROL_DIM, STATE_DIM, ProblemShape

if TYPE_CHECKING:  # casadi is imported when the first function is built
    import casadi as ca

    from formation_bench.mpc.solvers.casadi_model import SymbolicParameters

N, M = STATE_DIM, CONTROL_DIM
STAGE_LAYOUT = (("f_x", (N, N)), ("f_u", (N, M)), ("l_x", (N,)), ("l_u", (M,)),
                ("l_xx", (N, N)), ("l_uu", (M, M)), ("l_ux", (M, N)))  # fmt: skip
"""The derivatives of a stage in the order of its row of :attr:`StageDerivatives.values`,
each flattened in row-major (C) order."""
STAGE_WIDTH = sum(math.prod(shape) for _, shape in STAGE_LAYOUT)
"""Entries per stage (58)."""


class CostHessian(enum.StrEnum):
    """Which second derivative of the stage cost the backward pass uses."""

    EXACT = "exact"
    """The stage cost's Hessian in ``(x_b, u_b)``, the dynamics' curvature within a block
    and the penalties' exact Hessian included."""
    GAUSS_NEWTON = "gauss-newton"
    """``G' H G`` of eq. (14)'s terms and ``2 J' J`` of the penalties' residuals."""


def stage_starts(shape: ProblemShape) -> np.ndarray:
    """``(B + 1,)`` first period of every block, then H; ValueError unless every block is
    one run of consecutive periods in block order (as ``block_map`` makes them)."""
    blocks = np.asarray(shape.block_of_step, dtype=np.int64)
    expected = np.arange(shape.n_blocks)
    starts = np.searchsorted(blocks, expected)
    if not (
        np.all(np.diff(blocks) >= 0)
        and np.array_equal(np.unique(blocks), expected)
        and blocks.size == shape.horizon_steps
    ):
        raise ValueError(
            f"ilqr needs each control block to be consecutive periods in block order, got "
            f"block_of_step={shape.block_of_step}"
        )
    return np.append(starts, shape.horizon_steps).astype(np.int64)


def _stage(
    shape: ProblemShape,
    params: SymbolicParameters,
    periods: range,
    hessian: CostHessian,
) -> tuple[ca.SX, ca.SX]:
    """Block-start state and control symbols ``z = (x, u)`` and the stage's row of
    derivatives in :data:`STAGE_LAYOUT` order."""
    import casadi as ca

    from formation_bench.mpc.solvers.casadi_model import (
        penalty_terms,
        period_step,
        stage_cost,
    )

    x, u = ca.SX.sym("x", N), ca.SX.sym("u", M)
    z = ca.vertcat(x, u)
    state, cost, curvature = x, 0, ca.SX.zeros(N + M, N + M)
    position = ca.SX.sym("position", 2)
    for k in periods:
        state = period_step(state, u, shape.period_s, shape.rk4_substeps)
        reached = state[:2]
        cost = cost + shape.period_s * stage_cost(shape, reached, params, k)
        if hessian == CostHessian.GAUSS_NEWTON:
            # eq. (14)'s terms are quadratic in the position: their Hessian there is constant
            in_position = ca.hessian(shape.period_s * stage_cost(shape, position, params, k),
                                     position)[0]  # fmt: skip
            jacobian = ca.jacobian(reached, z)
            curvature = curvature + jacobian.T @ in_position @ jacobian
        for weight, gap in penalty_terms(shape, reached, params, k):
            cost = cost + shape.period_s * weight * gap * gap
            if hessian == CostHessian.GAUSS_NEWTON:
                residual_jacobian = ca.jacobian(math.sqrt(shape.period_s * weight) * gap, z)
                curvature = curvature + 2 * residual_jacobian.T @ residual_jacobian
    if hessian == CostHessian.EXACT:
        curvature = ca.hessian(cost, z)[0]
    dynamics = ca.jacobian(state, z)
    gradient = ca.gradient(cost, z)
    pieces = {
        "f_x": dynamics[:, :N], "f_u": dynamics[:, N:], "l_x": gradient[:N], "l_u": gradient[N:],
        "l_xx": curvature[:N, :N], "l_uu": curvature[N:, N:], "l_ux": curvature[N:, :N],
    }  # fmt: skip
    row = [pieces[name][i, j] for name, dims in STAGE_LAYOUT for i, j in _entries(dims)]
    return z, ca.vertcat(*row)


def _entries(dims: tuple[int, ...]) -> list[tuple[int, int]]:
    """Row-major ``(i, j)`` of a matrix, ``(i, 0)`` of a vector."""
    rows, cols = dims[0], dims[1] if len(dims) == 2 else 1
    return [(i, j) for i in range(rows) for j in range(cols)]


@dataclass
class StageDerivatives:
    """One problem shape's derivative function, bound to its own input and output arrays."""

    shape: ProblemShape
    hessian: CostHessian
    starts: np.ndarray
    """:func:`stage_starts` of the shape."""
    states: np.ndarray
    """``(B, 4)`` block-start states: write them before :meth:`evaluate`."""
    controls: np.ndarray
    """``(B, 2)`` controls: write them before :meth:`evaluate`."""
    parameters: np.ndarray
    """The problem's parameter vector (:func:`pack_parameters`): write it before a solve."""
    values: np.ndarray
    """``(B, STAGE_WIDTH)``: every stage's derivatives after :meth:`evaluate`."""
    function: ca.Function
    build_time_s: float
    _trigger: object = None
    _buffer: object = None

    def __post_init__(self) -> None:
        self._buffer, self._trigger = self.function.buffer()
        for index, array in enumerate((self.states, self.controls, self.parameters)):
            self._buffer.set_arg(index, memoryview(array))  # type: ignore[attr-defined]
        self._buffer.set_res(0, memoryview(self.values))  # type: ignore[attr-defined]

    def evaluate(self) -> np.ndarray:
        """The derivatives at :attr:`states` and :attr:`controls` (into :attr:`values`)."""
        self._trigger()  # type: ignore[operator]
        return self.values

    def unpacked(self) -> dict[str, np.ndarray]:
        """:attr:`values` as named arrays ``(B, *dims)`` (for tests)."""
        out, at = {}, 0
        for name, dims in STAGE_LAYOUT:
            size = math.prod(dims)
            out[name] = self.values[:, at : at + size].reshape(-1, *dims).copy()
            at += size
        return out


def build_derivatives(
    shape: ProblemShape, hessian: CostHessian, jit: bool = False
) -> StageDerivatives:
    """The stage derivative function of ``shape`` (inputs: block-start states ``(B, 4)``,
    controls ``(B, 2)`` and the parameter vector, all row-major; output ``(B, 58)``).

    ``jit`` compiles it to C with the system's compiler (as ``ipopt``'s ``jit``): about
    1 µs per evaluation instead of 7-11 µs in CasADi's virtual machine, for about a second
    of ``gcc`` per shape."""
    import casadi as ca

    from formation_bench.mpc.solvers.casadi_model import symbolic_parameters

    start = time.perf_counter()
    starts = stage_starts(shape)
    params = symbolic_parameters(shape)
    states = ca.SX.sym("X", shape.n_blocks * N)
    controls = ca.SX.sym("U", shape.n_blocks * M)
    rows = []
    for b in range(shape.n_blocks):
        z, row = _stage(shape, params, range(starts[b], starts[b + 1]), hessian)
        at = ca.vertcat(states[N * b : N * b + N], controls[M * b : M * b + M])
        rows.append(ca.substitute(row, z, at))
    options: dict[str, object] = {"cse": True}
    if jit:
        options.update(
            {"jit": True, "compiler": "shell", "jit_options": {"flags": ["-O2"], "verbose": False}}
        )
    output = ca.densify(ca.vertcat(*rows))  # the buffer interface writes nonzeros only
    function = ca.Function(
        "ilqr_stages", [states, controls, params.vector], [output], ["X", "U", "p"], ["D"],
        options,
    )  # fmt: skip
    return StageDerivatives(
        shape=shape,
        hessian=hessian,
        starts=starts,
        states=np.zeros((shape.n_blocks, N)),
        controls=np.zeros((shape.n_blocks, M)),
        parameters=np.zeros(shape.n_parameters),
        values=np.zeros((shape.n_blocks, STAGE_WIDTH)),
        function=function,
        build_time_s=time.perf_counter() - start,
    )
