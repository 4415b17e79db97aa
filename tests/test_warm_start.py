"""Initial populations around the warm start (``WarmStartInit``) in PSO and the BSOs.

The draws of :func:`starting_points` are checked by hand and against a twin generator; the
optimiser classes that take the mixin are checked to start closer to the warm start when
configured to, to refuse bad settings by name, and to give the same result in their Python
and compiled loops on a recorded library instance.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_compiled_loop import PlainCallable, same_result

from formation_bench.instances.library import Instance, shipped
from formation_bench.optimizers import (
    PSO,
    Bounds,
    Budget,
    ChaoticLocalSearchBSO,
    ModifiedBSO,
    OriginalBSO,
    PopulationOptimizer,
    get_optimizer,
)
from formation_bench.optimizers.base import EvaluationCounter
from formation_bench.optimizers.population import UNIFORM_START, WarmStartInit, starting_points

WARM_VARIANTS = {
    "pso-warm": "pso",
    "modified-bso-warm": "modified-bso",
    "original-bso-warm": "original-bso",
}
"""Each registered warm-start variant and the configuration it starts differently from."""

MIXIN_CLASSES = (PSO, ModifiedBSO, OriginalBSO, ChaoticLocalSearchBSO)


def library_instance(k: int = 0) -> Instance:
    return shipped()[k]


class ScriptedRng:
    """Stands in for a Generator: hands out the given arrays in order, checking their shapes."""

    def __init__(self, *arrays: np.ndarray) -> None:
        self.arrays = list(arrays)
        self.calls: list[tuple[str, tuple[int, ...]]] = []

    def next_array(self, kind: str, shape: tuple[int, ...]) -> np.ndarray:
        self.calls.append((kind, shape))
        out = np.asarray(self.arrays.pop(0), dtype=float)
        assert out.shape == shape
        return out

    def random(self, shape: tuple[int, ...]) -> np.ndarray:
        return self.next_array("random", shape)

    def standard_normal(self, shape: tuple[int, ...]) -> np.ndarray:
        return self.next_array("standard_normal", shape)


def mirrored(v: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Reference mirror at the faces, written out independently of the kernel."""
    out = np.array(v, dtype=float)
    for index in np.ndindex(out.shape):
        c = index[-1]
        x = out[index]
        while not lower[c] <= x <= upper[c]:
            x = 2 * lower[c] - x if x < lower[c] else 2 * upper[c] - x
        out[index] = x
    return out


# --- starting_points ---------------------------------------------------------------------------


def test_cloud_members_by_hand_in_a_two_dimensional_box() -> None:
    # box [0, 8] x [-1, 1], spread 1/8: std 1 and 1/4; every number is exact in binary
    bounds = Bounds(np.array([0.0, -1.0]), np.array([8.0, 1.0]))
    x0 = np.array([7.0, 0.5])
    uniforms = [[0.5, 0.5], [0.25, 0.75], [0.125, 0.375], [0.625, 0.5], [0.75, 0.25]]
    normals = [[2.0, -1.0], [-0.5, 3.0], [-8.0, -7.0]]
    rng = ScriptedRng(np.array(uniforms), np.array(normals))
    init = WarmStartInit(warm_start_share=0.6, warm_start_spread=0.125)
    points = starting_points(bounds, rng, 5, x0, init)  # type: ignore[arg-type]
    # round(0.6 * 5) = 3 cloud rows, drawn after the uniforms
    assert rng.calls == [("random", (5, 2)), ("standard_normal", (3, 2))]
    expected = np.array(
        [
            [7.0, 0.5],  # the warm start
            [7.0, 0.25],  # (9, 0.25): 1 beyond the upper face of x, back 1 inside
            [6.5, 0.75],  # (6.5, 1.25): 0.25 beyond the upper face of y, back 0.25 inside
            [1.0, -0.75],  # (-1, -1.25): beyond both lower faces, mirrored at each
            [6.0, -0.5],  # uniform: (0, -1) + (0.75, 0.25) * (8, 2)
        ]
    )
    np.testing.assert_array_equal(points, expected)


def test_cloud_member_by_hand_in_a_one_dimensional_box() -> None:
    bounds = Bounds(np.array([-2.0]), np.array([2.0]))
    rng = ScriptedRng(np.array([[0.25], [0.5], [0.75], [1.0 / 8.0]]), np.array([[-3.0]]))
    init = WarmStartInit(warm_start_share=0.25, warm_start_spread=0.125)  # 1 row, std 0.5
    points = starting_points(bounds, rng, 4, np.array([-1.5]), init)  # type: ignore[arg-type]
    # -1.5 - 3 * 0.5 = -3: 1 below -2, mirrored to -1; rows 2, 3 are -2 + 4 u
    np.testing.assert_array_equal(points[:, 0], [-1.5, -1.0, 1.0, -1.5])


def test_share_zero_is_the_uniform_sample_with_the_warm_start_in_row_zero() -> None:
    bounds = Bounds(np.array([-1.0, 0.0, 10.0]), np.array([1.0, 0.5, 20.0]))
    x0 = np.array([0.9, 0.01, 19.0])
    for init in [UNIFORM_START, WarmStartInit(warm_start_share=0.0, warm_start_spread=0.3)]:
        rng, twin = np.random.default_rng(5), np.random.default_rng(5)
        points = starting_points(bounds, rng, 9, x0, init)
        expected = bounds.sample(twin, 9)
        expected[0] = x0
        np.testing.assert_array_equal(points, expected)
        # nothing more drawn: the optimiser's later draws are those it made before the mixin
        assert rng.random() == twin.random()


def test_without_a_warm_start_the_population_is_uniform_whatever_the_share() -> None:
    bounds = Bounds(np.zeros(4), np.ones(4))
    init = WarmStartInit(warm_start_share=0.7, warm_start_spread=0.1)
    rng, twin = np.random.default_rng(2), np.random.default_rng(2)
    np.testing.assert_array_equal(
        starting_points(bounds, rng, 10, None, init), bounds.sample(twin, 10)
    )
    assert rng.random() == twin.random()


@pytest.mark.parametrize(
    ("share", "size", "cloud"),
    [(0.25, 10, 2), (0.5, 30, 15), (0.75, 30, 22), (1.0, 30, 29), (0.99, 4, 3), (0.5, 1, 0)],
)
def test_cloud_rows_follow_the_uniforms_and_are_mirrored_into_the_box(
    share: float, size: int, cloud: int
) -> None:
    bounds = Bounds(np.array([-1.0, 0.0, 5.0]), np.array([1.0, 0.5, 6.0]))
    x0 = np.array([0.95, 0.0, 5.5])  # near or on faces: the cloud crosses them
    spread = 0.2
    init = WarmStartInit(warm_start_share=share, warm_start_spread=spread)
    assert init.warm_members(size) == cloud == min(size - 1, round(share * size))
    rng, twin = np.random.default_rng(17), np.random.default_rng(17)
    points = starting_points(bounds, rng, size, x0, init)
    expected = bounds.sample(twin, size)
    expected[0] = x0
    raw = x0 + spread * bounds.width * twin.standard_normal((cloud, 3))
    expected[1 : cloud + 1] = mirrored(raw, bounds.lower, bounds.upper)
    np.testing.assert_allclose(points, expected, rtol=0, atol=1e-15)
    assert bounds.contains(points)
    assert rng.random() == twin.random()


# --- the optimisers ----------------------------------------------------------------------------


def initial_points(optimizer: PopulationOptimizer, instance: Instance, seed: int) -> np.ndarray:
    problem = instance.problem
    counter = EvaluationCounter(problem, problem.bounds.dim, None)
    rng = np.random.default_rng(seed)
    state = optimizer.init(counter, problem.bounds, rng, instance.warm_start, 10)
    return np.asarray(state.x)


def median_distance(points: np.ndarray, x0: np.ndarray, bounds: Bounds) -> float:
    return float(np.median(np.linalg.norm((points - x0) / bounds.width, axis=1)))


def test_every_pso_and_bso_class_takes_the_warm_start_settings() -> None:
    for cls in MIXIN_CLASSES:
        assert issubclass(cls, WarmStartInit)
        names = [f.name for f in dataclasses.fields(cls)]
        # the mixin's fields come last: the methods' own keep their order
        assert names[-2:] == ["warm_start_share", "warm_start_spread"]
        assert cls().warm_start_share == 0.0  # published start by default


@pytest.mark.parametrize(
    ("warm", "uniform"),
    [
        *WARM_VARIANTS.items(),
        ("chaotic-pso", "chaotic-pso"),
        ("cls-bso", "cls-bso"),
    ],
)
def test_warm_configurations_start_closer_to_the_warm_start(warm: str, uniform: str) -> None:
    reference = get_optimizer(uniform)
    optimizer = get_optimizer(warm)
    if warm == uniform:  # no registered variant: the same settings as the registered ones
        optimizer = dataclasses.replace(
            optimizer,
            warm_start_share=get_optimizer("pso-warm").warm_start_share,
            warm_start_spread=get_optimizer("pso-warm").warm_start_spread,
        )
    assert isinstance(optimizer, PopulationOptimizer)
    assert isinstance(reference, PopulationOptimizer)
    assert optimizer.warm_start_share > 0.0  # type: ignore[attr-defined]
    instance = library_instance(3)
    bounds = instance.problem.bounds
    for seed in range(3):
        warm_points = initial_points(optimizer, instance, seed)
        uniform_points = initial_points(reference, instance, seed)
        np.testing.assert_array_equal(warm_points[0], instance.warm_start)
        assert bounds.contains(warm_points)
        assert median_distance(warm_points, instance.warm_start, bounds) < median_distance(
            uniform_points, instance.warm_start, bounds
        )


def test_warm_variants_are_their_registered_configuration_with_the_warm_settings() -> None:
    for warm, uniform in WARM_VARIANTS.items():
        variant = get_optimizer(warm)
        assert variant.warm_start_share > 0.0  # type: ignore[attr-defined]
        same_settings = dataclasses.replace(
            get_optimizer(uniform),
            warm_start_share=variant.warm_start_share,  # type: ignore[attr-defined]
            warm_start_spread=variant.warm_start_spread,  # type: ignore[attr-defined]
        )
        assert variant == same_settings
    assert get_optimizer("modified-bso").warm_start_share == 0.0  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    ("overrides", "field"),
    [
        ({"warm_start_share": 2.0}, "warm_start_share"),
        ({"warm_start_share": -0.1}, "warm_start_share"),
        ({"warm_start_share": math.nan}, "warm_start_share"),
        ({"warm_start_spread": 0.0}, "warm_start_spread"),
        ({"warm_start_spread": -0.05}, "warm_start_spread"),
    ],
)
@pytest.mark.parametrize("name", ["pso", "modified-bso", "original-bso", "cls-bso"])
def test_bad_warm_start_settings_are_refused_by_name(
    name: str, overrides: dict[str, float], field: str
) -> None:
    with pytest.raises(ValueError, match=rf"\.{field} must be"):
        get_optimizer(name, **overrides)


def test_bad_warm_start_settings_are_refused_by_the_constructor() -> None:
    with pytest.raises(ValueError, match=r"PSO\.warm_start_share must be a finite number in"):
        PSO(warm_start_share=2.0)
    with pytest.raises(ValueError, match=r"OriginalBSO\.warm_start_spread .*\(0\.0, 1\.0\]"):
        OriginalBSO(warm_start_spread=0.0)


# test_compiled_loop checks every registered name with a compiled loop, the warm variants
# included, on random paper problems; here on a recorded one, with its own warm start
@pytest.mark.parametrize(
    "optimizer",
    [
        *(get_optimizer(name) for name in WARM_VARIANTS),
        get_optimizer("chaotic-pso", warm_start_share=0.3, warm_start_spread=0.1),
        get_optimizer("cls-bso", warm_start_share=0.3, warm_start_spread=0.1),
    ],
    ids=[*WARM_VARIANTS, "chaotic-pso-warm", "cls-bso-warm"],
)
def test_python_and_compiled_loops_agree_on_a_library_instance(
    optimizer: PopulationOptimizer,
) -> None:
    assert optimizer.has_compiled_loop()
    instance = library_instance(7)
    problem = instance.problem
    for k, budget in enumerate([None, Budget(max_evaluations=777), Budget(max_iterations=2)]):
        python_rng, compiled_rng = np.random.default_rng(k), np.random.default_rng(k)
        python = optimizer.minimize(
            PlainCallable(problem), problem.bounds, python_rng, budget, instance.warm_start
        )
        compiled = optimizer.minimize(
            problem, problem.bounds, compiled_rng, budget, instance.warm_start
        )
        assert same_result(python, compiled), (optimizer, budget)
        assert python_rng.random() == compiled_rng.random()
