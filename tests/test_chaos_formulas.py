"""The eight maps beyond logistic and tent: formulas, parameters, and why some deviate from tables.

Range, non-collapse over 10,000 iterations from random and degenerate seeds,
and determinism are tested for every :class:`ChaoticMap` member in
``test_chaos.py``; this file checks each map against its textbook formula.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from formation_bench.optimizers.chaos import ChaoticMap, chaotic_sequence, iterate_map
from formation_bench.optimizers.chaos_formulas import (
    CIRCLE_B,
    SINUSOIDAL_HIGH,
    SINUSOIDAL_LOW,
    sin_pi,
)

X = np.array([0.07, 0.13, 0.3, 0.41, 0.62, 0.77, 0.9, 0.97])

TEXTBOOK = {
    ChaoticMap.SINE: lambda x: np.sin(np.pi * x),
    ChaoticMap.CHEBYSHEV: lambda x: (np.cos(4.0 * np.arccos(2.0 * x - 1.0)) + 1.0) / 2.0,
    ChaoticMap.CIRCLE: lambda x: np.mod(x + 0.2 - np.sin(2.0 * np.pi * x), 1.0),
    ChaoticMap.GAUSS: lambda x: np.mod(1.0 / x, 1.0),
    ChaoticMap.ITERATIVE: lambda x: (np.sin(0.7 * np.pi / (2.0 * x - 1.0)) + 1.0) / 2.0,
    ChaoticMap.PIECEWISE: lambda x: np.select(
        [x < 0.4, x < 0.5, x < 0.6],
        [x / 0.4, (x - 0.4) / 0.1, (0.6 - x) / 0.1],
        (1.0 - x) / 0.4,
    ),
    ChaoticMap.SINGER: lambda x: 1.07 * (7.86 * x - 23.31 * x**2 + 28.75 * x**3 - 13.302875 * x**4),
}


def sinusoidal(z: np.ndarray) -> np.ndarray:
    return 2.3 * z * z * np.sin(np.pi * z)


def test_at_least_the_ten_maps_of_the_issue() -> None:
    names = {m.name for m in ChaoticMap}
    assert names >= {
        "LOGISTIC",
        "TENT",
        "SINE",
        "CHEBYSHEV",
        "CIRCLE",
        "GAUSS",
        "ITERATIVE",
        "PIECEWISE",
        "SINGER",
        "SINUSOIDAL",
    }


@pytest.mark.parametrize("map_", list(TEXTBOOK))
def test_each_map_is_its_textbook_formula(map_: ChaoticMap) -> None:
    np.testing.assert_allclose(iterate_map(map_, X, 1), TEXTBOOK[map_](X), rtol=1e-12, atol=1e-12)


def test_sinusoidal_map_is_the_textbook_map_on_its_invariant_interval() -> None:
    width = SINUSOIDAL_HIGH - SINUSOIDAL_LOW
    z = SINUSOIDAL_LOW + width * X
    np.testing.assert_allclose(
        iterate_map(ChaoticMap.SINUSOIDAL, X, 1), (sinusoidal(z) - SINUSOIDAL_LOW) / width
    )
    # [f(f(c)), f(c)] with c the critical point: f maps the interval onto itself
    grid = np.linspace(SINUSOIDAL_LOW, SINUSOIDAL_HIGH, 100_001)
    image = sinusoidal(grid)
    assert image.max() == pytest.approx(SINUSOIDAL_HIGH, abs=1e-9)
    assert image.min() == pytest.approx(SINUSOIDAL_LOW, abs=1e-9)
    assert (SINUSOIDAL_LOW, SINUSOIDAL_HIGH) == pytest.approx((0.4870, 0.9194), abs=1e-4)


def test_the_raw_sinusoidal_map_collapses_from_random_seeds() -> None:
    """Why the sinusoidal map is rescaled: unrescaled, most seeds fall into 0."""
    z = np.random.default_rng(0).random(1000)
    for _ in range(200):
        z = sinusoidal(z)
    assert np.mean(z < 1e-12) > 0.3


def lyapunov(f, seeds: np.ndarray, n: int = 5000, eps: float = 1e-9) -> float:
    x, total = seeds.copy(), np.zeros_like(seeds)
    for _ in range(n):
        fx, fy = f(x), f(x + eps)
        d = np.abs(fy - fx)
        total += np.log(np.maximum(np.minimum(d, 1.0 - d), 1e-300) / eps)  # distance on the circle
        x = fx
    return float(np.median(total / n))


def test_circle_map_parameters() -> None:
    """The tables' K = 0.5 is quasi-periodic (exponent 0); K = 2 pi, used here, is chaotic."""
    seeds = np.random.default_rng(1).random(16)

    def tables(x: np.ndarray) -> np.ndarray:
        return np.mod(x + CIRCLE_B - 0.5 / (2.0 * np.pi) * np.sin(2.0 * np.pi * x), 1.0)

    assert abs(lyapunov(tables, seeds)) < 0.01
    assert lyapunov(TEXTBOOK[ChaoticMap.CIRCLE], seeds) > 1.0


@pytest.mark.parametrize("map_", [m for m in ChaoticMap if m is not ChaoticMap.CIRCLE])
def test_positive_lyapunov_exponent(map_: ChaoticMap) -> None:
    seeds = np.random.default_rng(2).random(8)
    exponent = lyapunov(lambda x: iterate_map(map_, x, 1), seeds, n=2000)
    assert exponent > 0.3


def test_sin_pi_matches_math_sin() -> None:
    t = np.random.default_rng(3).uniform(-50.0, 50.0, 5000)
    got = np.array([sin_pi(v) for v in t])
    np.testing.assert_allclose(got, np.sin(np.pi * t), atol=2e-14)
    assert sin_pi(0.0) == 0.0 and sin_pi(1.0) == 0.0 and sin_pi(2.0) == 0.0
    assert sin_pi(0.5) == pytest.approx(1.0, abs=1e-15)
    assert sin_pi(-1.5) == pytest.approx(1.0, abs=1e-15)
    assert not math.isfinite(sin_pi(math.inf)) and math.isnan(sin_pi(math.nan))


def test_sequences_of_different_maps_differ() -> None:
    x0 = np.array([0.123, 0.456])
    tails = {m: chaotic_sequence(m, x0, 50)[-1].tobytes() for m in ChaoticMap}
    assert len(set(tails.values())) == len(ChaoticMap)
