"""Compiled objectives: a batch cost that a compiled solve loop calls without Python.

A solve of 30-member populations on the paper problem costs about a
microsecond of cost evaluation per member but, driven from Python, as much
again per iteration in calls, wrappers and bookkeeping. An objective may
therefore also offer a :class:`CompiledObjective`: the address of a C function

.. code-block:: c

    void cost(const double *x, int64_t n, int64_t d, const double *data, double *out);

which writes the costs of the ``n`` rows of the C-contiguous ``(n, d)`` array
``x`` to ``out``, reading its problem from the flat array ``data``. A numba
``@cfunc`` with :data:`COST_SIGNATURE` is one. An optimiser with a compiled
solve loop then runs whole blocks of iterations in one compiled call, counting
and budgeting evaluations there exactly as :class:`~formation_bench.optimizers.base.
EvaluationCounter` does (:func:`evaluate`, :func:`evaluate_prefix`), so that both
paths give the same result to the bit. The optimiser still knows nothing of
where the cost comes from: only this calling convention.

An objective offers the handle through a ``compiled`` attribute (see
:func:`compiled_of`); an objective without one is solved through Python. The handle must
compute exactly what the objective's call computes, for the dimension of the bounds it is
solved over: nothing can check a C function, and one that reads past its data reads
memory that is not its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from formation_bench.kernel_cache import njit

COST_SIGNATURE = types.void(
    types.CPointer(types.float64),
    types.int64,
    types.int64,
    types.CPointer(types.float64),
    types.CPointer(types.float64),
)
"""The numba signature of a compiled cost: ``(x, n, d, data, out)``, see the module docstring."""

NO_LIMIT = -1
"""``counts[LIMIT]`` of a solve without an evaluation limit."""

UNLIMITED = 9223372036854775807
"""The largest int64: what is left of a limit that is not set (evaluations, iterations)."""

NFEV, LIMIT, HAS_BEST = 0, 1, 2
"""Slots of a tally's ``counts``: evaluations so far, the evaluation limit (or :data:`NO_LIMIT`),
and 1 once a best point is held."""


@dataclass(frozen=True)
class CompiledObjective:
    """A compiled batch cost: the C function at ``address`` applied to the problem in ``data``."""

    address: int
    """Address of a C function with :data:`COST_SIGNATURE`; valid while ``owner`` lives."""
    data: np.ndarray
    """The problem, as the function reads it: float64, one-dimensional, C-contiguous."""
    owner: Any = None
    """What keeps the function alive (its numba ``CFunc``, for instance)."""

    def __post_init__(self) -> None:
        if not isinstance(self.address, int) or self.address == 0:
            raise ValueError(
                f"CompiledObjective.address must be a non-zero int, got {self.address!r}"
            )
        data = self.data
        if not (
            isinstance(data, np.ndarray)
            and data.dtype == np.float64
            and data.ndim == 1
            and data.flags.c_contiguous
        ):
            raise ValueError(
                "CompiledObjective.data must be a one-dimensional C-contiguous float64 array"
            )

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """The costs of the rows of ``x`` ``(n, d)``, by one call of the function."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.ndim != 2:
            raise ValueError(f"x must have shape (n, d), got {x.shape}")
        return call_cost(self.address, self.data, x, x.shape[0])


def compiled_of(objective: object) -> CompiledObjective | None:
    """The objective's :class:`CompiledObjective`, or None when it has none."""
    handle = getattr(objective, "compiled", None)
    return handle if isinstance(handle, CompiledObjective) else None


@intrinsic
def _call_c_cost(typingctx, address, x, rows, data, out):  # type: ignore[no-untyped-def]
    """Call the C cost at ``address`` on the first ``rows`` rows of ``x``, writing ``out``.

    The arrays are arguments (not raw pointers) so that they stay alive for the call; ``x``
    and ``data`` must be typed C-contiguous (any other layout does not compile), since the C
    function reads them as flat memory.
    """
    if not (
        isinstance(x, types.Array)
        and x.ndim == 2
        and x.layout == "C"
        and isinstance(data, types.Array)
        and data.layout == "C"
    ):
        return None
    sig = types.void(address, x, rows, data, out)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        address_v, x_v, rows_v, data_v, out_v = args
        x_arr = context.make_array(signature.args[1])(context, builder, x_v)
        data_arr = context.make_array(signature.args[3])(context, builder, data_v)
        out_arr = context.make_array(signature.args[4])(context, builder, out_v)
        shape = x_arr.shape
        width = builder.extract_value(shape, 1)
        double_ptr = ir.DoubleType().as_pointer()
        i64 = ir.IntType(64)
        fn_type = ir.FunctionType(ir.VoidType(), [double_ptr, i64, i64, double_ptr, double_ptr])
        fn = builder.inttoptr(address_v, fn_type.as_pointer())
        builder.call(
            fn,
            [
                x_arr.data,
                builder.sext(rows_v, i64) if rows_v.type.width < 64 else rows_v,
                width,
                data_arr.data,
                out_arr.data,
            ],
        )
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True)
def call_cost(address: int, data: np.ndarray, x: np.ndarray, rows: int) -> np.ndarray:
    """Costs of the first ``rows`` rows of the C-contiguous ``x``, by the C cost at ``address``."""
    out = np.empty(rows)
    if rows > 0:
        _call_c_cost(address, x, rows, data, out)
    return out


def new_tally(dim: int, max_evaluations: int | None) -> tuple[np.ndarray, np.ndarray]:
    """A solve's evaluation tally ``(counts, best)``: counts and budget, best cost and point.

    ``counts`` holds :data:`NFEV`, :data:`LIMIT` and :data:`HAS_BEST`; ``best`` is the best cost
    followed by its point.
    """
    limit = NO_LIMIT if max_evaluations is None else max_evaluations
    counts = np.array([0, limit, 0], dtype=np.int64)
    best = np.empty(dim + 1)
    best[0] = math.inf
    return counts, best


@njit(cache=True, inline="always")
def remaining(counts: np.ndarray) -> int:
    """Evaluations left (a large number without a limit), as ``EvaluationCounter.remaining``."""
    if counts[LIMIT] == NO_LIMIT:
        return UNLIMITED
    return counts[LIMIT] - counts[NFEV]


@njit(cache=True)
def evaluate(
    address: int, data: np.ndarray, points: np.ndarray, rows: int, counts: np.ndarray,
    best: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """Costs of the first ``rows`` rows of ``points``, counted and tracked as the counter does.

    Non-finite costs become ``+inf``; the first row of the smallest cost becomes the best point
    when it is strictly better (or when none is held yet). The caller keeps ``rows`` within
    :func:`remaining`.
    """
    costs = call_cost(address, data, points, rows)
    if rows == 0:
        return costs
    i = 0
    for r in range(rows):
        if not math.isfinite(costs[r]):
            costs[r] = math.inf
        if costs[r] < costs[i]:
            i = r
    counts[NFEV] += rows
    if costs[i] < best[0] or counts[HAS_BEST] == 0:
        best[0] = costs[i]
        for c in range(points.shape[1]):
            best[1 + c] = points[i, c]
        counts[HAS_BEST] = 1
    return costs


@njit(cache=True)
def evaluate_prefix(
    address: int, data: np.ndarray, points: np.ndarray, counts: np.ndarray, best: np.ndarray
) -> np.ndarray:
    """As :func:`formation_bench.optimizers.population.evaluate_prefix`: the rows the budget
    allows evaluated, the rest ``+inf``."""
    return evaluate_leading(address, data, points, points.shape[0], counts, best)


@njit(cache=True)
def evaluate_leading(
    address: int, data: np.ndarray, points: np.ndarray, n: int, counts: np.ndarray,
    best: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """:func:`evaluate_prefix` of the first ``n`` rows of ``points`` (without slicing them)."""
    allowed = min(n, remaining(counts))
    if allowed >= n:
        return evaluate(address, data, points, n, counts, best)
    costs = np.full(n, math.inf)
    if allowed > 0:
        head = evaluate(address, data, points, allowed, counts, best)
        for r in range(allowed):
            costs[r] = head[r]
    return costs
