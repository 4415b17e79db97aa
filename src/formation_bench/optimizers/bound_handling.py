"""Bringing points that left the box ``[lower, upper]`` back inside.

Shared by every population optimiser: a compiled kernel (callable from other
numba kernels) over a whole population, with the random values of the
RESAMPLE mode passed in by the caller so that the result is reproducible.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from formation_bench.kernel_cache import njit


class BoundHandling(IntEnum):
    """How a coordinate outside ``[lower, upper]`` is brought back."""

    CLIP = 0
    """Project onto the nearest bound."""
    REFLECT = 1
    """Mirror at the bounds (repeatedly, for points more than a width outside)."""
    RESAMPLE = 2
    """Replace each violating coordinate by a uniform value in its range."""


@njit(cache=True)
def apply_bounds(
    x: np.ndarray, lower: np.ndarray, upper: np.ndarray, mode: int, uniforms: np.ndarray
) -> np.ndarray:
    """A copy of ``x`` with every coordinate brought into ``[lower, upper]`` by ``mode``.

    ``mode`` is a :class:`BoundHandling` value. Coordinates already inside
    are unchanged. ``uniforms`` (same shape as ``x``) is read only by
    RESAMPLE; other modes accept any array.
    """
    out = x.copy()
    apply_bounds_inplace(out, lower, upper, mode, uniforms)
    return out


@njit(cache=True)
def apply_bounds_inplace(
    x: np.ndarray, lower: np.ndarray, upper: np.ndarray, mode: int, uniforms: np.ndarray
) -> None:
    """:func:`apply_bounds` writing into ``x``; for kernels that own their intermediates."""
    n, d = x.shape
    for i in range(n):
        for c in range(d):
            v = x[i, c]
            lo = lower[c]
            hi = upper[c]
            if lo <= v <= hi:
                continue
            if mode == BoundHandling.CLIP:
                v = lo if v < lo else hi
            elif mode == BoundHandling.REFLECT:
                # fold onto a period of 2w so that far-away points land inside too
                w = hi - lo
                y = v - lo
                y = y - 2.0 * w * math.floor(y / (2.0 * w))
                if y > w:
                    y = 2.0 * w - y
                v = min(max(lo + y, lo), hi)  # rounding of lo + y may overshoot hi
            elif mode == BoundHandling.RESAMPLE:
                v = min(lo + uniforms[i, c] * (hi - lo), hi)
            else:
                raise ValueError("unknown bound handling mode")
            x[i, c] = v
