"""Global-best PSO: the move by hand, the schedules, bound handling and the chaotic variants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import BOX, sphere

from formation_bench.optimizers import PSO, Bounds, Budget, get_optimizer
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.chaos import ChaoticMap, chaotic_sequence
from formation_bench.optimizers.population import progress
from formation_bench.optimizers.pso import (
    PSOSettings,
    PSOState,
    chaotic_inertia,
    linear_inertia,
    move_swarm,
)


def move(x, v, p, g, w, r1, r2, v_max, lower, upper, mode=BoundHandling.CLIP, u=None):
    box = Bounds(np.array(lower, dtype=float), np.array(upper, dtype=float))
    settings = PSOSettings(*PSO(c1=2.0, c2=1.5, bound_handling=mode).params(box, 10))
    settings = settings._replace(v_max=np.asarray(v_max, dtype=float))
    state = PSOState(x, v, p, np.zeros(x.shape[0]), np.zeros((0, *x.shape)), 0.5)
    out = move_swarm(state, g, w, r1, r2, x if u is None else u, settings)
    n = x.shape[0]
    return out[:n], out[n:]


def test_move_is_the_velocity_update_by_hand() -> None:
    x = np.array([[0.0, 1.0]])
    v = np.array([[0.5, -0.5]])
    p = np.array([[1.0, 1.0]])
    g = np.array([2.0, -1.0])
    r1, r2 = np.array([[0.5, 0.25]]), np.array([[0.2, 1.0]])
    big = np.full(2, 100.0)
    x1, v1 = move(x, v, p, g, 0.8, r1, r2, big, -big, big)
    expected_v = 0.8 * v + 2.0 * r1 * (p - x) + 1.5 * r2 * (g - x)
    np.testing.assert_allclose(v1, expected_v)
    np.testing.assert_allclose(x1, x + expected_v)
    # clamping each component to +-v_max
    x2, v2 = move(x, v, p, g, 0.8, r1, r2, np.array([0.1, 0.1]), -big, big)
    np.testing.assert_allclose(v2, np.clip(expected_v, -0.1, 0.1))
    np.testing.assert_allclose(x2, x + v2)


@pytest.mark.parametrize("mode", list(BoundHandling))
def test_repaired_coordinates_get_the_step_actually_taken(mode: BoundHandling) -> None:
    x = np.array([[0.9, 0.0]])
    v = np.array([[0.5, 0.1]])
    lower, upper = np.array([0.0, -1.0]), np.array([1.0, 1.0])
    zeros = np.zeros((1, 2))
    x1, v1 = move(x, v, x, x[0], 1.0, zeros, zeros, np.full(2, 5.0), lower, upper, mode, zeros)
    assert lower[0] <= x1[0, 0] <= upper[0]
    expected_first = {
        BoundHandling.CLIP: 1.0,
        BoundHandling.REFLECT: 0.6,
        BoundHandling.RESAMPLE: 0.0,
    }
    assert x1[0, 0] == pytest.approx(expected_first[mode])
    assert v1[0, 0] == pytest.approx(x1[0, 0] - 0.9)
    assert (x1[0, 1], v1[0, 1]) == (0.1, 0.1)  # the coordinate inside is untouched


def test_inertia_schedules() -> None:
    assert linear_inertia(0.9, 0.4, 1, 40) == pytest.approx(0.9)
    assert linear_inertia(0.9, 0.4, 40, 40) == pytest.approx(0.4)
    assert linear_inertia(0.9, 0.4, 20, 39) == pytest.approx(0.65)
    assert linear_inertia(0.7298, 0.7298, 17, 40) == 0.7298
    assert chaotic_inertia(0.9, 0.4, 1, 40, 0.5) == pytest.approx(0.5 + 0.2)
    assert chaotic_inertia(0.9, 0.4, 40, 40, 0.5) == pytest.approx(0.2)
    assert progress(1, 1) == 0.0 and progress(50, 40) == 1.0


def test_registered_variants() -> None:
    assert get_optimizer("pso") == PSO()
    constriction = get_optimizer("pso-constriction")
    assert (constriction.inertia_start, constriction.inertia_end) == (0.7298, 0.7298)
    assert (constriction.c1, constriction.c2) == (1.49618, 1.49618)
    assert get_optimizer("chaotic-pso") == PSO(chaotic_coefficients=True, chaotic_inertia=True)
    assert get_optimizer("chaotic-pso-coefficients").chaotic_coefficients
    assert get_optimizer("chaotic-pso-inertia").chaotic_inertia


@pytest.mark.parametrize(
    "name", ["pso", "pso-constriction", "chaotic-pso", "chaotic-pso-coefficients"]
)
def test_each_variant_converges_on_the_sphere(name: str) -> None:
    results = [
        get_optimizer(name).minimize(sphere, BOX, np.random.default_rng(s)) for s in range(3)
    ]
    assert all(r.nfev == 1230 for r in results)
    assert np.median([r.fun for r in results]) < 1.0


def test_chaotic_variants_differ_from_plain_pso_and_from_each_other() -> None:
    runs = {
        name: get_optimizer(name).minimize(sphere, BOX, np.random.default_rng(4)).fun
        for name in ("pso", "chaotic-pso", "chaotic-pso-coefficients", "chaotic-pso-inertia")
    }
    assert len(set(runs.values())) == 4


def test_chaotic_coefficients_follow_the_map() -> None:
    """With r1 = r2 = the chaotic sequence, a one-particle swarm moves as computed by hand."""
    opt = PSO(population_size=2, chaotic_coefficients=True, coefficient_map=ChaoticMap.TENT)
    box = Bounds(np.full(1, -100.0), np.full(1, 100.0))
    points = []

    def record(x: np.ndarray) -> np.ndarray:
        points.append(x.copy())
        return (x[:, 0] - 3.0) ** 2

    rng = np.random.default_rng(0)
    opt.minimize(record, box, rng, Budget(max_iterations=1))
    again = np.random.default_rng(0)
    x0 = box.sample(again, 2)
    seeds = again.random(2 * 2 * 1 + 1)[:-1].reshape(2, 2, 1)
    r = chaotic_sequence(ChaoticMap.TENT, seeds, 1)[0]
    f0 = (x0[:, 0] - 3.0) ** 2
    g = x0[np.argmin(f0)]
    v = np.clip(2.0 * r[0] * (x0 - x0) + 2.0 * r[1] * (g - x0), -40.0, 40.0)
    np.testing.assert_allclose(points[1], x0 + v)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("population_size", 1),
        ("max_iterations", -2),
        ("inertia_start", -0.1),
        ("inertia_end", math.inf),
        ("c1", 6.0),
        ("c2", "2"),
        ("velocity_clamp", 0.0),
        ("bound_handling", "bounce"),
        ("chaotic_coefficients", "yes"),
        ("coefficient_map", "henon"),
        ("chaotic_inertia", None),
        ("inertia_map", 99),
    ],
)
def test_invalid_config_names_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"PSO\.{field} must"):
        PSO(**{field: value})


def test_enum_fields_accept_names() -> None:
    opt = PSO(bound_handling="reflect", coefficient_map="sine", inertia_map="GAUSS")
    assert opt.bound_handling is BoundHandling.REFLECT
    assert opt.coefficient_map is ChaoticMap.SINE and opt.inertia_map is ChaoticMap.GAUSS
