"""CMA-ES with pycma's BoundTransform: the transform itself, a generation, a solve, both loops.

The transform is checked against pycma's own ``cma.boundary_handler.BoundTransform`` (the dev
extra has pycma); the solves against the Python loop, which must give the compiled loop's
result to the bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import BOX, D
from test_cma_es import first_state, generation, view
from test_compiled_loop import CompiledSphere, PlainCallable, same_result

from formation_bench.optimizers import CMAES, Bounds, Budget, get_optimizer
from formation_bench.optimizers.cma_es import CMABoundHandling, CMAConstants, Restarts
from formation_bench.optimizers.cma_restarts import first_run
from formation_bench.optimizers.cma_transform import (
    linquad_inverse,
    linquad_margins,
    linquad_transform,
)

TRANSFORM = CMABoundHandling.TRANSFORM

# boxes whose margins take each branch of pycma's rule: (u - l) / 2 (narrow), 1/20, |bound|/20
BOXES = [
    (0.0, 1.0),
    (-5.0, 5.0),
    (-0.25, 0.25),
    (3.0, 3.01),
    (-1000.0, 2.0),
    (10.0, 1e4),
]


def far_and_near_points(rng: np.random.Generator, lower: float, upper: float) -> np.ndarray:
    """Points around the box, from well inside to some 3000 widths outside, in 4 dimensions."""
    width = upper - lower
    spread = np.exp(rng.uniform(-6.0, 8.0, (400, 1)))
    return 0.5 * (lower + upper) + width * spread * rng.standard_normal((400, 4))


@pytest.mark.parametrize(("lower", "upper"), BOXES)
def test_the_transform_is_pycmas_bound_transform(lower: float, upper: float) -> None:
    from cma.boundary_handler import BoundTransform

    rng = np.random.default_rng(int(upper - lower))
    lo, hi = np.full(4, lower), np.full(4, upper)
    reference = BoundTransform([lo, hi])
    x = far_and_near_points(rng, lower, upper)
    ours = linquad_transform(x, lo, hi)
    expected = np.array([reference.repair(row.copy()) for row in x])
    np.testing.assert_allclose(ours, expected, rtol=0.0, atol=1e-12 * (upper - lower))
    assert np.all((ours >= lo) & (ours <= hi))
    y = rng.uniform(lower, upper, (100, 4))
    y[:4] = [lo, hi, lo + 1e-3 * (hi - lo), hi - 1e-3 * (hi - lo)]
    inverse = np.array([linquad_inverse(row, lo, hi) for row in y])
    expected = np.array([reference.inverse(row.copy()) for row in y])
    np.testing.assert_allclose(inverse, expected, rtol=0.0, atol=1e-12 * (upper - lower))
    np.testing.assert_allclose(
        linquad_transform(inverse, lo, hi), y, rtol=0.0, atol=1e-12 * (upper - lower)
    )


def test_the_unit_box_margins_are_five_percent_and_the_transform_the_identity_between() -> None:
    assert linquad_margins(0.0, 1.0) == (0.05, 0.05)
    u = np.linspace(0.05, 0.95, 91)[None]
    np.testing.assert_array_equal(linquad_transform(u, np.zeros(91), np.ones(91)), u)
    # symmetric about the faces' outer margin, periodic with 2 (1 + 0.05 + 0.05)
    v = np.array([[-0.05 - 0.3, -0.05 + 0.3, 1.05 + 0.2, 1.05 - 0.2, 0.3 + 2.2, 0.3 - 4.4]])
    t = linquad_transform(v, np.zeros(6), np.ones(6))[0]
    assert t[0] == pytest.approx(t[1]) and t[2] == pytest.approx(t[3])
    assert t[4] == pytest.approx(0.3) and t[5] == pytest.approx(0.3)


def transform_run(rng: np.random.Generator, generations: int) -> tuple:
    """A transform run after some generations on the sphere, centred near the lower face (the
    tutorial's constants), its params and the last samples' costs."""
    lam = 10
    state, params = first_state(CMAES(constants=CMAConstants.TUTORIAL), 0.1)
    costs = np.empty(0)
    for _ in range(generations):
        state = generation(state, params, costs, rng.standard_normal((lam, D)))
        points = state.run.samples.points
        costs = ((points + 6.0) ** 2).sum(axis=1)  # the optimum is outside the box
    return state, params, costs


@pytest.mark.slow
def test_a_transform_generation_evaluates_the_mapped_samples_and_learns_the_samples() -> None:
    lam = 10
    state, params, costs = transform_run(np.random.default_rng(0), 4)
    normals = 3.0 * np.random.default_rng(1).standard_normal((lam, D))
    run = view(generation(state, params, costs, normals))
    sampled = (run.rows.T @ (run.axes[:, None] * normals.T)).T
    np.testing.assert_allclose(run.steps, sampled, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(run.lengths, (normals**2).sum(axis=1), rtol=1e-12)
    u = run.mean + run.sigma * sampled
    assert np.sum((u < 0.0) | (u > 1.0)) > 10  # some samples left the box
    mapped = linquad_transform(u, np.zeros(D), np.ones(D))
    np.testing.assert_allclose(run.points, BOX.lower + BOX.width * mapped, rtol=0, atol=1e-12)
    assert BOX.contains(run.points)


@pytest.mark.parametrize("where", [0.0, 0.01, 0.5, 0.97, 1.0])
def test_the_first_mean_is_the_inverse_image_of_the_start(where: float) -> None:
    x0 = BOX.lower + where * BOX.width
    state = first_run(CMAES(bound_handling=TRANSFORM), BOX.lower, BOX.width, x0)
    mean = state.run.distribution.mean
    np.testing.assert_allclose(linquad_transform(mean[None], np.zeros(D), np.ones(D))[0], where)
    if where == 0.0:  # the bottom of the parabola, a margin beyond the face
        np.testing.assert_allclose(mean, -0.05)
    if 0.05 <= where <= 0.95:
        np.testing.assert_array_equal(mean, where)


@pytest.mark.parametrize("lamarckian", [False, True])
@pytest.mark.slow
def test_the_transform_keeps_every_point_inside_and_reaches_a_corner(lamarckian: bool) -> None:
    box = Bounds(np.full(D, -1.0), np.full(D, 1.0))
    points = []

    def record(x):  # the optimum (3, ..., 3) is outside: the box's corner is best, cost 40
        points.append(x.copy())
        return ((x - 3.0) ** 2).sum(axis=1)

    opt = CMAES(bound_handling=TRANSFORM, lamarckian=lamarckian)
    res = opt.minimize(record, box, np.random.default_rng(0), Budget(max_evaluations=1230))
    assert box.contains(np.vstack(points)) and box.contains(res.x)
    if not lamarckian:  # reflect ends at 40.006 (cma_es's docstring): the corner is smooth here
        assert res.fun == pytest.approx(40.0, abs=1e-4)


@pytest.mark.parametrize("restarts", list(Restarts), ids=lambda r: r.name.lower())
@pytest.mark.parametrize("constants", list(CMAConstants), ids=lambda c: c.name.lower())
def test_transform_solves_in_the_compiled_loop_give_the_python_loop_result(
    restarts: Restarts, constants: CMAConstants
) -> None:
    # a loose TolFun makes runs stop and restart (a restart's mean is an inverse image too);
    # the optimum beyond the faces keeps the samples in the margins
    optimizer = CMAES(
        restarts=restarts, tol_fun=1e-2, bound_handling=TRANSFORM, constants=constants
    )
    bounds = Bounds(-5 * np.ones(6), 5 * np.ones(6))
    objective = CompiledSphere(np.linspace(-6.0, 6.0, 6))
    budgets = [Budget(max_evaluations=4000), Budget(max_evaluations=3000, max_iterations=170)]
    stops = []
    for seed, budget in enumerate(budgets):
        x0 = np.zeros(6) if seed % 2 == 0 else None
        python_rng, compiled_rng = np.random.default_rng(seed), np.random.default_rng(seed)
        python = optimizer.minimize(PlainCallable(objective), bounds, python_rng, budget, x0)
        compiled = optimizer.minimize(objective, bounds, compiled_rng, budget, x0)
        assert same_result(python, compiled), budget
        assert python_rng.random() == compiled_rng.random()
        assert bounds.contains(compiled.x)
        stops += compiled.info["stops"]
    assert len(stops) >= 2


def test_pycma_constants_change_the_solve_and_transform_is_a_setting() -> None:
    tutorial = get_optimizer("cma-es", constants="tutorial")
    pycma = get_optimizer("cma-es")
    assert tutorial.bound_handling is TRANSFORM and pycma.constants is CMAConstants.PYCMA
    assert tutorial.constants is CMAConstants.TUTORIAL
    objective = CompiledSphere(np.linspace(-6.0, 6.0, 6))
    bounds = Bounds(-5 * np.ones(6), 5 * np.ones(6))
    results = [
        opt.minimize(objective, bounds, np.random.default_rng(0), Budget(max_evaluations=300))
        for opt in (tutorial, pycma)
    ]
    assert results[0].fun != results[1].fun
    assert not math.isclose(results[0].info["sigma"], results[1].info["sigma"])


def test_cma_es_warm_is_cma_es_with_a_small_step() -> None:
    warm = get_optimizer("cma-es-warm")
    assert warm == CMAES(sigma0=0.02)
    # the defaults chosen on the validation split: pycma's bound handling and constants
    assert get_optimizer("cma-es").bound_handling is CMABoundHandling.TRANSFORM
    assert get_optimizer("cma-es").constants is CMAConstants.PYCMA
