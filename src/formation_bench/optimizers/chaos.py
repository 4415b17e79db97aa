"""Chaotic maps of the unit interval, compiled for use inside numba kernels.

Every map takes and returns a float in the open interval (0, 1). Maps whose
textbook range is another interval (e.g. Chebyshev on [-1, 1]) must rescale
inside their own function, so that callers can swap maps freely.

Floating-point arithmetic breaks some chaotic maps: the logistic map has the
exact fixed points 0 and 0.75 and sends 0.5 to exactly 1 and then to 0 for
ever; the slope-2 tent map shifts one mantissa bit out per iteration and
reaches 0 after about 53 iterations. Two defences are used:

* the tent map uses slope :data:`TENT_SLOPE` (just under 2), whose products
  round instead of shifting bits out, so the orbit never empties;
* :func:`apply_map` (one value) and :func:`step_inplace` (an array) pass
  every iterate through a guard that *re-injects*
  a value derived deterministically from the previous iterate whenever the
  new one is within :data:`EDGE` of 0 or 1, is not finite, or equals its
  predecessor (an exact fixed point). No hidden randomness is involved, so
  sequences are reproducible from their seeds alone.

Adding a map: write its ``@njit`` function (input and output in (0, 1)), add
a member to :class:`ChaoticMap`, and add its branch to :func:`raw_map` and to
:func:`_raw_pass_by_id` (the array version, see there why there are two); the
guard, the vectorised helpers and every kernel that takes a map id then
support it.
"""

from __future__ import annotations

import math
from enum import IntEnum

import numpy as np

from formation_bench.kernel_cache import njit
from formation_bench.optimizers.chaos_formulas import (
    chebyshev_map,
    circle_map,
    gauss_map,
    iterative_map,
    piecewise_map,
    sine_map,
    singer_map,
    sinusoidal_map,
)

EDGE = 1e-10
"""Iterates closer than this to 0 or 1 are re-injected (they would stall near an edge)."""

TENT_SLOPE = 1.99999
"""Slope of the tent map; 2 exactly collapses to 0 in binary floating point."""

_GOLDEN = 0.6180339887498949  # irrational shift: re-injected values do not line up in cycles


class ChaoticMap(IntEnum):
    """Identifier of a chaotic map; its integer value is what numba kernels receive."""

    LOGISTIC = 0
    """``4 x (1 - x)``."""
    TENT = 1
    """``mu x`` for ``x < 0.5`` else ``mu (1 - x)``, with ``mu =`` :data:`TENT_SLOPE`."""
    SINE = 2
    """``sin(pi x)``: the sine map ``(a / 4) sin(pi x)`` with a = 4."""
    CHEBYSHEV = 3
    """Order-4 Chebyshev map ``cos(4 arccos z)`` on ``z = 2x - 1``, rescaled: ``(2 z^2 - 1)^2``."""
    CIRCLE = 4
    """``x + b - (K / 2 pi) sin(2 pi x) mod 1`` with K = 2 pi, b = 0.2 (see ``circle_map``)."""
    GAUSS = 5
    """Gauss/mouse map ``1 / x mod 1``."""
    ITERATIVE = 6
    """Iterative map ``sin(a pi / z)``, a = 0.7, on ``z = 2x - 1`` in (-1, 1), rescaled."""
    PIECEWISE = 7
    """Piecewise linear chaotic map with P = 0.4 (uniform invariant density)."""
    SINGER = 8
    """``mu (7.86 x - 23.31 x^2 + 28.75 x^3 - 13.302875 x^4)`` with mu = 1.07."""
    SINUSOIDAL = 9
    """``a z^2 sin(pi z)``, a = 2.3, on its chaotic interval, rescaled (see ``sinusoidal_map``)."""


@njit(cache=True)
def logistic_map(x: float) -> float:
    """Logistic map with r = 4 (unguarded)."""
    return 4.0 * x * (1.0 - x)


@njit(cache=True)
def tent_map(x: float) -> float:
    """Tent map with slope :data:`TENT_SLOPE` (unguarded)."""
    if x < 0.5:
        return TENT_SLOPE * x
    return TENT_SLOPE * (1.0 - x)


# inline: a thin layer (see the note at move_ideas in bso_ops)
@njit(cache=True, inline="always")
def reinject(x: float) -> float:
    """A value in [0.01, 0.99] derived from ``x``; replaces a degenerate iterate.

    Depends on ``x`` (rather than being one constant) so that two sequences
    that degenerate at different places do not merge into the same orbit.
    """
    if not math.isfinite(x):
        x = 0.0
    r = abs(x) + _GOLDEN
    r = r - math.floor(r)
    return 0.01 + 0.98 * r


# inline: a thin layer (see the note at move_ideas in bso_ops)
@njit(cache=True, inline="always")
def guard(x: float, y: float) -> float:
    """``y`` (the iterate after ``x``) unless it is degenerate, else :func:`reinject` (x)."""
    if not (EDGE < y < 1.0 - EDGE) or y == x:
        return reinject(x)
    return y


@njit(cache=True)
def raw_map(map_id: int, x: float) -> float:
    """One unguarded iteration of the map ``map_id``; NaN for an unknown id.

    The single dispatch point over maps: a new map needs one branch here.
    """
    if map_id == ChaoticMap.LOGISTIC:
        return logistic_map(x)
    if map_id == ChaoticMap.TENT:
        return tent_map(x)
    if map_id == ChaoticMap.SINE:
        return sine_map(x)
    if map_id == ChaoticMap.CHEBYSHEV:
        return chebyshev_map(x)
    if map_id == ChaoticMap.CIRCLE:
        return circle_map(x)
    if map_id == ChaoticMap.GAUSS:
        return gauss_map(x)
    if map_id == ChaoticMap.ITERATIVE:
        return iterative_map(x)
    if map_id == ChaoticMap.PIECEWISE:
        return piecewise_map(x)
    if map_id == ChaoticMap.SINGER:
        return singer_map(x)
    if map_id == ChaoticMap.SINUSOIDAL:
        return sinusoidal_map(x)
    return math.nan


@njit(cache=True)
def _check_map_id(map_id: int) -> None:
    if math.isnan(raw_map(map_id, 0.3)):
        raise ValueError("unknown chaotic map id")


@njit(cache=True)
def apply_map(map_id: int, x: float) -> float:
    """One guarded iteration of the map ``map_id`` (a :class:`ChaoticMap` value)."""
    _check_map_id(map_id)
    return guard(x, raw_map(map_id, x))


@njit(cache=True)
def iterate_scalar(map_id: int, x: float, n: int) -> float:
    """The ``n``-th guarded iterate of ``x`` (``x`` itself when ``n == 0``)."""
    for _ in range(n):
        x = apply_map(map_id, x)
    return x


@njit(cache=True)
def _raw_pass_by_id(map_id: int, x: np.ndarray, scratch: np.ndarray) -> bool:
    """``scratch = raw_map(map_id, x)`` entry-wise; True when any new value is degenerate.

    The array counterpart of :func:`raw_map`, choosing the map once per
    array: a loop over one map's formula vectorises, a loop over a ten-way
    branch does not (several times slower for the logistic map). Passing the
    map function as an argument would avoid the second list but disables
    numba's on-disk cache.
    """
    n = x.shape[0]
    if map_id == ChaoticMap.LOGISTIC:
        for j in range(n):
            scratch[j] = logistic_map(x[j])
    elif map_id == ChaoticMap.TENT:
        for j in range(n):
            scratch[j] = tent_map(x[j])
    elif map_id == ChaoticMap.SINE:
        for j in range(n):
            scratch[j] = sine_map(x[j])
    elif map_id == ChaoticMap.CHEBYSHEV:
        for j in range(n):
            scratch[j] = chebyshev_map(x[j])
    elif map_id == ChaoticMap.CIRCLE:
        for j in range(n):
            scratch[j] = circle_map(x[j])
    elif map_id == ChaoticMap.GAUSS:
        for j in range(n):
            scratch[j] = gauss_map(x[j])
    elif map_id == ChaoticMap.ITERATIVE:
        for j in range(n):
            scratch[j] = iterative_map(x[j])
    elif map_id == ChaoticMap.PIECEWISE:
        for j in range(n):
            scratch[j] = piecewise_map(x[j])
    elif map_id == ChaoticMap.SINGER:
        for j in range(n):
            scratch[j] = singer_map(x[j])
    elif map_id == ChaoticMap.SINUSOIDAL:
        for j in range(n):
            scratch[j] = sinusoidal_map(x[j])
    else:
        raise ValueError("unknown chaotic map id")
    degenerate = False
    for j in range(n):
        y = scratch[j]
        degenerate |= (y <= EDGE) | (y >= 1.0 - EDGE) | (y == x[j]) | (y != y)
    return degenerate


# inline: a thin layer (see the note at move_ideas in bso_ops)
@njit(cache=True, inline="always")
def step_inplace(map_id: int, x: np.ndarray, scratch: np.ndarray) -> None:
    """One guarded iteration of every entry of the 1-D array ``x``, in place.

    Same result as :func:`apply_map` entry by entry, but about 10x faster on
    arrays: the first pass is branch-free so it vectorises, and the guard
    runs only when that pass saw a degenerate value (rare). ``scratch`` is
    work space of ``x``'s size.
    """
    if _raw_pass_by_id(map_id, x, scratch):
        for j in range(x.shape[0]):
            scratch[j] = guard(x[j], scratch[j])
    for j in range(x.shape[0]):
        x[j] = scratch[j]


@njit(cache=True)
def _iterate_flat(map_id: int, x0: np.ndarray, n: int) -> np.ndarray:
    out = x0.copy()
    scratch = np.empty_like(out)
    for _ in range(n):
        step_inplace(map_id, out, scratch)
    return out


@njit(cache=True)
def _sequence_flat(map_id: int, x0: np.ndarray, n: int) -> np.ndarray:
    out = np.empty((n, x0.size))
    x = x0.copy()
    scratch = np.empty_like(x)
    for k in range(n):
        step_inplace(map_id, x, scratch)
        out[k] = x
    return out


def _check(map_: ChaoticMap | int, n: int) -> int:
    map_id = int(ChaoticMap(map_))
    if n < 0:
        raise ValueError(f"number of iterations must be >= 0, got {n}")
    return map_id


def iterate_map(map_: ChaoticMap, x0: np.ndarray, n: int) -> np.ndarray:
    """The ``n``-th iterate of every entry of ``x0`` (same shape as ``x0``).

    Seeds are used as given, including degenerate ones (0, 0.5, 0.75, 1): the
    guard replaces a degenerate iterate, so every result with ``n >= 1``
    lies in (0, 1). ``n == 0`` returns a copy of ``x0``.
    """
    map_id = _check(map_, n)
    x = np.ascontiguousarray(x0, dtype=np.float64)
    return _iterate_flat(map_id, x.reshape(-1), int(n)).reshape(x.shape)


def chaotic_sequence(map_: ChaoticMap, x0: np.ndarray, n: int) -> np.ndarray:
    """Iterates 1..n of every entry of ``x0``: shape ``(n, *x0.shape)``."""
    map_id = _check(map_, n)
    x = np.ascontiguousarray(x0, dtype=np.float64)
    return _sequence_flat(map_id, x.reshape(-1), int(n)).reshape((int(n), *x.shape))
