"""The prediction's arithmetic in fused multiply-adds, as the cost kernels compute it.

A fused multiply-add ``fma(a, b, c)`` rounds ``a * b + c`` once: it is one instruction
where the separate product and sum are two, and IEEE 754 defines its result to the bit,
so every machine (with or without the instruction: without it, the C library computes
it exactly in software) and both cost kernels (numba and C,
:mod:`formation_bench.mpc.native_cost`) get the same numbers from the same sequence of
operations. The sequences below are the ones ``_cost_kernel.c`` writes out; a test
checks the two kernels to the bit.

The model is :mod:`formation_bench.mpc.model`'s: Simpson's rule on the exact heading
and speed, the heading's cosine and sine rotated through each sub-step's turn. The
plant takes them afresh at every period start; the prediction takes them afresh every
:data:`~formation_bench.mpc.model.HEADING_RESET_SUBSTEPS` sub-steps counted from the
horizon's start, which saves a polynomial pair per period and agrees with the plant to
rounding (about 1e-15 of a position over the paper's horizon), not to the bit.
"""

from __future__ import annotations

import math

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from formation_bench.kernel_cache import njit
from formation_bench.mpc.model import (
    _C1,
    _C2,
    _C3,
    _C4,
    _C5,
    _C6,
    _PIO2_1,
    _PIO2_2,
    _PIO2_3,
    _S1,
    _S2,
    _S3,
    _S4,
    _S5,
    _S6,
    _TWO_OVER_PI,
    in_quadrant,
)


@intrinsic
def fma(typingctx, a, b, c):  # type: ignore[no-untyped-def]
    """``a * b + c`` rounded once (LLVM's ``llvm.fma``; float64 arguments only)."""
    if not all(arg == types.float64 for arg in (a, b, c)):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        double = ir.DoubleType()
        signature_ir = ir.FunctionType(double, [double, double, double])
        function = builder.module.declare_intrinsic("llvm.fma", [double], signature_ir)
        return builder.call(function, args)

    return types.float64(types.float64, types.float64, types.float64), codegen


@njit(cache=True, inline="always")
def fused_cos_sin(angle: float) -> tuple[float, float]:
    """:func:`~formation_bench.mpc.model.reduced_cos_sin` with its products and sums fused.

    The same reduction and polynomials, for ``|angle| <``
    :data:`~formation_bench.mpc.model.REDUCTION_LIMIT`.
    """
    quadrant = math.floor(fma(angle, _TWO_OVER_PI, 0.5))
    q = float(quadrant)
    r = fma(-q, _PIO2_3, fma(-q, _PIO2_2, fma(-q, _PIO2_1, angle)))
    z = r * r
    sin_r = fma(r * z, fma(z, fma(z, fma(z, fma(z, fma(z, _S6, _S5), _S4), _S3), _S2), _S1), r)
    cos_poly = fma(z, fma(z, fma(z, fma(z, fma(z, _C6, _C5), _C4), _C3), _C2), _C1)
    cos_r = 1.0 - fma(-z * z, cos_poly, 0.5 * z)
    return in_quadrant(quadrant, cos_r, sin_r)


@njit(cache=True, inline="always")
def fused_turn(half_turn: float) -> tuple[float, float, float, float]:
    """``(cos, sin)`` of ``half_turn`` and of twice it (double-angle formulas), fused.

    As :func:`~formation_bench.mpc.model.turn_rotation` with ``half_turn = h * omega / 2``.
    """
    if abs(half_turn) < 2.0**19 * _PIO2_1:
        cos_half, sin_half = fused_cos_sin(half_turn)
    else:
        cos_half, sin_half = math.cos(half_turn), math.sin(half_turn)
    return cos_half, sin_half, fma(-2.0 * sin_half, sin_half, 1.0), 2.0 * sin_half * cos_half


@njit(cache=True, inline="always")
def fused_substep(
    cos_t: float,
    sin_t: float,
    v: float,
    a: float,
    h: float,
    turn: tuple[float, float, float, float],
) -> tuple[float, float, float, float, float]:
    """One Simpson sub-step of :func:`~formation_bench.mpc.model.rotated_substep`, fused.

    Returns ``(dx, dy, cos, sin, v)``: the position advances by ``h / 6`` times
    ``(dx, dy)`` (the caller's ``fma``), the heading's pair and the speed are at the
    sub-step's end.
    """
    cos_half, sin_half, cos_full, sin_full = turn
    v_mid = fma(0.5 * h, a, v)
    v_end = fma(h, a, v)
    cos_mid = fma(cos_t, cos_half, -(sin_t * sin_half))
    sin_mid = fma(sin_t, cos_half, cos_t * sin_half)
    cos_end = fma(cos_t, cos_full, -(sin_t * sin_full))
    sin_end = fma(sin_t, cos_full, cos_t * sin_full)
    weight = 4.0 * v_mid
    dx = fma(v, cos_t, fma(weight, cos_mid, v_end * cos_end))
    dy = fma(v, sin_t, fma(weight, sin_mid, v_end * sin_end))
    return dx, dy, cos_end, sin_end, v_end
