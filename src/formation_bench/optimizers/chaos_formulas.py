"""The formulas of the chaotic maps beyond the logistic and tent maps.

Plain unguarded maps of (0, 1), one ``@njit`` function each; :mod:`formation_bench.optimizers.chaos`
dispatches to them by :class:`~formation_bench.optimizers.chaos.ChaoticMap` id and guards
their iterates. Maps whose textbook domain is another interval are conjugated
onto (0, 1) inside their function. The trigonometric maps use :func:`sin_pi`,
which vectorises in array loops where ``math.sin`` (a library call) does not.
"""

from __future__ import annotations

import math

import numpy as np

from formation_bench.kernel_cache import njit

# Parameters of the maps below: the values of the chaotic-map tables of the
# chaos-enhanced metaheuristics literature (e.g. Gandomi et al. 2013, Mirjalili &
# Gandomi 2017), except where a docstring says why not.
CIRCLE_K = 1.0
"""Circle map: ``K / 2 pi`` (K = 2 pi; the tables' K = 0.5 is not chaotic, see circle_map)."""
CIRCLE_B = 0.2
"""Circle map: the shift b."""
ITERATIVE_A = 0.7
"""Iterative map: a."""
PIECEWISE_P = 0.4
"""Piecewise linear map: P in (0, 0.5)."""
SINGER_MU = 1.07
"""Singer map: mu."""
SINUSOIDAL_A = 2.3
"""Sinusoidal map: a."""


def _sinusoidal_interval(a: float) -> tuple[float, float]:
    """``(f(f(c)), f(c))`` for ``f(z) = a z^2 sin(pi z)`` and its critical point c."""
    lo, hi = 0.6, 0.8  # f'(z) / (a z) = 2 sin(pi z) + pi z cos(pi z) changes sign once here
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if 2.0 * math.sin(math.pi * mid) + math.pi * mid * math.cos(math.pi * mid) > 0.0:
            lo = mid
        else:
            hi = mid
    top = a * lo * lo * math.sin(math.pi * lo)
    return a * top * top * math.sin(math.pi * top), top


SINUSOIDAL_LOW, SINUSOIDAL_HIGH = _sinusoidal_interval(SINUSOIDAL_A)
"""The sinusoidal map's invariant interval ``[f^2(c), f(c)]``, about [0.4870, 0.9194]."""


# Taylor coefficients of sin(pi r) in r, odd powers 1..19: on |r| <= 1/2 the first
# omitted term is below 3e-16, so sin_pi agrees with math.sin to a few ulps.
_SIN_PI_COEFFICIENTS = tuple(
    (-1.0) ** k * math.pi ** (2 * k + 1) / math.factorial(2 * k + 1) for k in range(10)
)


@njit(cache=True, error_model="numpy")
def sin_pi(t: float) -> float:
    """``sin(pi t)`` by range reduction to ``|r| <= 1/2`` and a polynomial.

    Unlike ``math.sin`` (a library call) it vectorises inside array loops,
    which makes the trigonometric maps about as cheap as the polynomial ones.
    """
    k = np.floor(t + 0.5)
    r = t - k
    r2 = r * r
    c = _SIN_PI_COEFFICIENTS
    p = c[9]
    p = p * r2 + c[8]
    p = p * r2 + c[7]
    p = p * r2 + c[6]
    p = p * r2 + c[5]
    p = p * r2 + c[4]
    p = p * r2 + c[3]
    p = p * r2 + c[2]
    p = p * r2 + c[1]
    p = p * r2 + c[0]
    half = 0.5 * k
    sign = 1.0 - 4.0 * (half - np.floor(half))  # +1 for even k, -1 for odd k
    return sign * r * p


@njit(cache=True)
def sine_map(x: float) -> float:
    """``sin(pi x)`` (unguarded; 0.5 maps to the edge 1)."""
    return sin_pi(x)


@njit(cache=True)
def chebyshev_map(x: float) -> float:
    """Order-4 Chebyshev map on ``z = 2x - 1``: ``(T_4(z) + 1) / 2 = T_2(z)^2`` (unguarded).

    The polynomial form is exact (``T_4 = 2 T_2^2 - 1``) and costs no
    trigonometry.
    """
    z = 2.0 * x - 1.0
    t2 = 2.0 * z * z - 1.0
    return t2 * t2


@njit(cache=True)
def circle_map(x: float) -> float:
    """``x + b - (K / 2 pi) sin(2 pi x) mod 1`` with K / 2 pi = :data:`CIRCLE_K` (unguarded).

    The tables' parameters (K = 0.5, b = 0.2) make an invertible circle map
    with Lyapunov exponent 0: its orbits are quasi-periodic, not chaotic, and
    two seeds 1e-12 apart never separate. K = 2 pi (exponent about 1.3) is
    chaotic.
    """
    y = x + CIRCLE_B - CIRCLE_K * sin_pi(2.0 * x)
    return y - np.floor(y)


@njit(cache=True, error_model="numpy")  # 1/0 gives inf for the guard, not an exception
def gauss_map(x: float) -> float:
    """Gauss/mouse map ``1 / x mod 1`` (unguarded; 0 and ``1/n`` map to 0)."""
    y = 1.0 / x
    return y - np.floor(y)


@njit(cache=True, error_model="numpy")  # 1/0 gives inf for the guard, not an exception
def iterative_map(x: float) -> float:
    """``(sin(a pi / z) + 1) / 2`` on ``z = 2x - 1`` (unguarded; 0.5 gives NaN).

    The textbook map iterates z in (-1, 1); this is the same map seen on (0, 1).
    """
    return 0.5 * (sin_pi(ITERATIVE_A / (2.0 * x - 1.0)) + 1.0)


@njit(cache=True)
def piecewise_map(x: float) -> float:
    """Piecewise linear chaotic map with ``P =`` :data:`PIECEWISE_P` (unguarded)."""
    y = 1.0 - x if x >= 0.5 else x  # the map is symmetric about 0.5
    if y < PIECEWISE_P:
        return y / PIECEWISE_P
    return (y - PIECEWISE_P) / (0.5 - PIECEWISE_P)


@njit(cache=True)
def singer_map(x: float) -> float:
    """Singer map with ``mu =`` :data:`SINGER_MU` (unguarded)."""
    return SINGER_MU * (x * (7.86 + x * (-23.31 + x * (28.75 - 13.302875 * x))))


@njit(cache=True)
def sinusoidal_map(x: float) -> float:
    """``a z^2 sin(pi z)`` on its invariant interval ``z in [lo, hi]``, rescaled (unguarded).

    On (0, 1) the textbook map has a super-attracting fixed point at 0 whose
    basin holds every seed below about 0.43, and its chaotic orbits fill
    only [:data:`SINUSOIDAL_LOW`, :data:`SINUSOIDAL_HIGH`]. The map is
    therefore applied to ``z = lo + (hi - lo) x``, and ``(z' - lo) / (hi - lo)``
    returned: the same dynamics, no absorbing 0, values spread over (0, 1).
    """
    width = SINUSOIDAL_HIGH - SINUSOIDAL_LOW
    z = SINUSOIDAL_LOW + width * x
    return (SINUSOIDAL_A * z * z * sin_pi(z) - SINUSOIDAL_LOW) / width
