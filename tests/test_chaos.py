"""Chaotic maps: stay in (0, 1), never collapse, survive degenerate seeds, deterministic."""

from __future__ import annotations

import numpy as np
import pytest

from formation_bench.optimizers.chaos import (
    EDGE,
    TENT_SLOPE,
    ChaoticMap,
    apply_map,
    chaotic_sequence,
    iterate_map,
    logistic_map,
    step_inplace,
    tent_map,
)

ALL_MAPS = list(ChaoticMap)

# Seeds on which an unguarded map degenerates in binary floating point: exact fixed
# points (0, 0.75 for the logistic map, mu/(1+mu) for the tent map), the 0.5 -> 1 -> 0
# path, the edges, values that leave (0, 1), and non-finite input.
BAD_SEEDS = np.array(
    [
        0.0,
        0.5,
        0.75,
        0.25,
        1.0,
        1.0 - 1e-16,
        np.nextafter(1.0, 0.0),
        5e-324,
        1e-300,
        1e-12,
        TENT_SLOPE / (1.0 + TENT_SLOPE),
        2.0 / 3.0,
        -0.5,
        1.5,
        np.nan,
        np.inf,
    ]
)


def assert_chaotic(seq: np.ndarray) -> None:
    """``seq`` (iterations, seeds): inside (0, 1), and the tail of every orbit still moves."""
    assert np.all(seq > 0.0) and np.all(seq < 1.0)
    tail = seq[-1000:]
    assert tail.std(axis=0).min() > 0.2  # an invariant density on (0, 1) has std ~0.3
    for j in range(tail.shape[1]):
        assert np.unique(tail[:, j]).size > 990  # no fixed point, no short cycle
        assert np.all(tail[1:, j] != tail[:-1, j])  # never stuck for a single step


@pytest.mark.parametrize("map_", ALL_MAPS)
def test_random_seeds_stay_inside_and_do_not_collapse(map_: ChaoticMap) -> None:
    seeds = np.random.default_rng(0).random(100)
    assert_chaotic(chaotic_sequence(map_, seeds, 10_000))


@pytest.mark.parametrize("map_", ALL_MAPS)
def test_degenerate_seeds_are_rescued(map_: ChaoticMap) -> None:
    seq = chaotic_sequence(map_, BAD_SEEDS, 10_000)
    assert np.all(np.isfinite(seq))
    assert_chaotic(seq)


@pytest.mark.parametrize("map_", ALL_MAPS)
@pytest.mark.parametrize("seed", list(BAD_SEEDS))
def test_every_single_step_from_a_bad_seed_is_valid(map_: ChaoticMap, seed: float) -> None:
    y = apply_map(int(map_), seed)
    assert EDGE < y < 1.0 - EDGE
    assert y != seed


@pytest.mark.parametrize("map_", ALL_MAPS)
def test_array_step_equals_scalar_step(map_: ChaoticMap) -> None:
    x = np.concatenate([BAD_SEEDS, np.random.default_rng(3).random(50)])
    expected = np.array([apply_map(int(map_), v) for v in x])
    step_inplace(int(map_), x, np.empty_like(x))
    np.testing.assert_array_equal(x, expected)


def test_unknown_map_id_raises_in_kernels() -> None:
    with pytest.raises(ValueError, match="unknown chaotic map"):
        apply_map(99, 0.3)
    with pytest.raises(ValueError, match="unknown chaotic map"):
        step_inplace(99, np.array([0.3]), np.empty(1))


def test_the_guard_is_needed() -> None:
    """Without the guard the maps really do degenerate on these seeds."""
    assert logistic_map(0.75) == 0.75
    assert logistic_map(logistic_map(0.5)) == 0.0
    x = np.random.default_rng(1).random(10)
    for _ in range(60):  # the slope-2 tent map shifts one mantissa bit out per step
        x = np.where(x < 0.5, 2.0 * x, 2.0 * (1.0 - x))
    assert np.all(x == 0.0)
    # the slope used here does not collapse on the same seeds without any guard
    y = np.random.default_rng(1).random(10)
    for _ in range(10_000):
        y = np.array([tent_map(v) for v in y])
    assert np.all(y > 1e-6)


@pytest.mark.parametrize("map_", ALL_MAPS)
def test_iterate_map_is_the_last_row_of_the_sequence(map_: ChaoticMap) -> None:
    x0 = np.random.default_rng(2).random((3, 4))
    seq = chaotic_sequence(map_, x0, 25)
    assert seq.shape == (25, 3, 4)
    np.testing.assert_array_equal(iterate_map(map_, x0, 25), seq[-1])
    np.testing.assert_array_equal(iterate_map(map_, x0, 1), seq[0])
    np.testing.assert_array_equal(iterate_map(map_, x0, 0), x0)


def test_maps_match_their_formulas_on_ordinary_values() -> None:
    x = np.array([0.1, 0.3, 0.6, 0.9])
    np.testing.assert_allclose(iterate_map(ChaoticMap.LOGISTIC, x, 1), 4 * x * (1 - x))
    tent = np.where(x < 0.5, TENT_SLOPE * x, TENT_SLOPE * (1 - x))
    np.testing.assert_allclose(iterate_map(ChaoticMap.TENT, x, 1), tent)


@pytest.mark.parametrize("map_", ALL_MAPS)
def test_deterministic_and_seed_sensitive(map_: ChaoticMap) -> None:
    x0 = np.array([0.2, 0.2 + 1e-12, 0.0, 0.5])
    a = iterate_map(map_, x0, 200)
    np.testing.assert_array_equal(a, iterate_map(map_, x0, 200))
    assert a[0] != a[1]  # sensitive dependence: a 1e-12 change decorrelates by step 200
    assert a[2] != a[3]  # two degenerate seeds are re-injected into different orbits


def test_map_given_by_integer_and_bad_arguments() -> None:
    x0 = np.array([0.3])
    np.testing.assert_array_equal(iterate_map(0, x0, 3), iterate_map(ChaoticMap.LOGISTIC, x0, 3))
    with pytest.raises(ValueError):
        iterate_map(99, x0, 3)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        iterate_map(ChaoticMap.TENT, x0, -1)
