"""cma-es reaches the quality of pycma, the reference implementation by the algorithm's author.

On the 10-D sphere, ellipsoid and Rosenbrock functions (optimum off-centre in
[-5, 5]^10), 20 seeds each: ``cma-es`` at its defaults and pycma (``cma``,
the dev extra) with the same initial step size (2 = 0.2 x range), a uniform
random start in the box, the box as bounds (pycma's BoundTransform) and the
same evaluation budget, chosen so that neither has converged to machine
precision. A two-sided Mann-Whitney test on log10 of the final costs must not
reject equality (p > 0.01), and the medians must lie within a factor of 10.
The seeds are fixed, so the p-values are too: this is a regression check of
agreement, not a random trial.

With the optimum on the faces (the same functions centred outside the box in
half of the coordinates, so that the constrained optimum lies on five faces),
``cma-es`` (pycma's BoundTransform and constants, its defaults) must not be
significantly worse than the ``pycma`` adapter: 25 seeds, the same start,
sigma0 and default budget (1230 evaluations), a paired one-sided Wilcoxon
signed-rank test on the final costs (ours greater) must not reject at 0.05.
The same test rejects the reflect repair on the sphere, so it has power. The
library check does the same on the instance library's test split (slow: pycma
takes some 0.2 s per solve).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from helpers import BOX, CENTRE, D, shifted_sphere
from scipy.optimize import minimize
from scipy.stats import mannwhitneyu, wilcoxon

from formation_bench.optimizers import OPTIMIZERS, Budget, get_optimizer

SEEDS = range(20)
sphere = shifted_sphere(CENTRE)


def ellipsoid(x: np.ndarray) -> np.ndarray:
    return ((x - CENTRE) ** 2 * 10.0 ** (6.0 * np.arange(D) / (D - 1))).sum(axis=1)


def rosenbrock(x: np.ndarray) -> np.ndarray:
    return (100.0 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1.0 - x[:, :-1]) ** 2).sum(axis=1)


FUNCTIONS = {
    "sphere": (sphere, 800),
    "ellipsoid": (ellipsoid, 3000),
    "rosenbrock": (rosenbrock, 3000),
}


def pycma_best(f, evaluations: int, seed: int) -> float:
    """Best cost pycma finds within ``evaluations`` (whole generations only)."""
    import cma

    x0 = np.random.default_rng(1000 + seed).uniform(-5.0, 5.0, D)
    es = cma.CMAEvolutionStrategy(
        x0, 2.0, {"seed": seed + 1, "bounds": [-5.0, 5.0], "verbose": -9, "maxfevals": evaluations}
    )
    best = np.inf
    while not es.stop() and es.countevals + es.popsize <= evaluations:
        points = es.ask()
        costs = f(np.asarray(points))
        es.tell(points, costs.tolist())
        best = min(best, float(costs.min()))
    return best


def ours_best(f, evaluations: int, seed: int) -> float:
    budget = Budget(max_evaluations=evaluations)
    return get_optimizer("cma-es").minimize(f, BOX, np.random.default_rng(seed), budget).fun


def agreement(name: str) -> tuple[np.ndarray, np.ndarray, float]:
    f, evaluations = FUNCTIONS[name]
    ours = np.array([ours_best(f, evaluations, s) for s in SEEDS])
    reference = np.array([pycma_best(f, evaluations, s) for s in SEEDS])
    p = mannwhitneyu(np.log10(ours), np.log10(reference), alternative="two-sided").pvalue
    return ours, reference, float(p)


@pytest.mark.parametrize("name", list(FUNCTIONS))
@pytest.mark.slow
def test_cma_es_and_pycma_reach_the_same_quality(name: str) -> None:
    ours, reference, p = agreement(name)
    assert np.all(np.isfinite(ours)) and np.all(np.isfinite(reference))
    assert p > 0.01, (name, np.median(ours), np.median(reference), p)
    ratio = np.median(ours) / np.median(reference)
    assert 0.1 < ratio < 10.0, (name, ratio)


def test_the_check_tells_a_weaker_search_apart() -> None:
    """The test has power: cma-es with a quarter of pycma's budget on the sphere is rejected."""
    f, evaluations = FUNCTIONS["sphere"]
    ours = np.array([ours_best(f, evaluations // 4, s) for s in SEEDS])
    reference = np.array([pycma_best(f, evaluations, s) for s in SEEDS])
    p = mannwhitneyu(np.log10(ours), np.log10(reference), alternative="two-sided").pvalue
    assert p < 0.01


# --- the optimum on the faces --------------------------------------------------------------------

OUTSIDE = np.array([7.0, -6.0, 2.0, 8.0, -1.0, -9.0, 3.0, 6.5, -2.5, 1.5])
"""Centre of the bounded problems: outside [-5, 5] in coordinates 0, 1, 3, 5 and 7."""
BOUNDED_SEEDS = range(25)
BUDGET = Budget(max_evaluations=1230)
AXIS_WEIGHTS = 10.0 ** (6.0 * np.arange(D) / (D - 1))
needs_pycma = pytest.mark.skipif(
    "pycma" not in OPTIMIZERS, reason="the pycma adapter needs the cma package"
)


def bounded_sphere(x: np.ndarray) -> np.ndarray:
    z = np.atleast_2d(x) - OUTSIDE
    return np.einsum("ij,ij->i", z, z)


def bounded_ellipsoid(x: np.ndarray) -> np.ndarray:
    return ((np.atleast_2d(x) - OUTSIDE) ** 2 * AXIS_WEIGHTS).sum(axis=1)


def bounded_rosenbrock(x: np.ndarray) -> np.ndarray:
    z = np.atleast_2d(x) - OUTSIDE + 1.0  # its unconstrained optimum at OUTSIDE
    return (100.0 * (z[:, 1:] - z[:, :-1] ** 2) ** 2 + (1.0 - z[:, :-1]) ** 2).sum(axis=1)


BOUNDED = {
    "sphere": bounded_sphere,
    "ellipsoid": bounded_ellipsoid,
    "rosenbrock": bounded_rosenbrock,
}


@functools.cache
def constrained_optimum(name: str) -> float:
    """The least cost in the box: at the clipped centre for the separable ones, else the best
    of L-BFGS-B from the clipped centre and 40 uniform starts."""
    f = BOUNDED[name]
    clipped = np.clip(OUTSIDE, BOX.lower, BOX.upper)
    if name != "rosenbrock":
        return float(f(clipped)[0])
    rng = np.random.default_rng(0)
    starts = [clipped, *BOX.sample(rng, 40)]
    box = list(zip(BOX.lower, BOX.upper, strict=True))
    return min(
        float(minimize(lambda x: f(x)[0], s, method="L-BFGS-B", bounds=box, tol=1e-14).fun)
        for s in starts
    )


def final_costs(name: str, optimizer_name: str, **settings: object) -> np.ndarray:
    f = BOUNDED[name]
    optimizer = get_optimizer(optimizer_name, **settings)
    costs = []
    for seed in BOUNDED_SEEDS:
        x0 = np.random.default_rng(1000 + seed).uniform(-5.0, 5.0, D)
        result = optimizer.minimize(f, BOX, np.random.default_rng(seed), BUDGET, x0)
        assert result.nfev == 1230 and BOX.contains(result.x)
        costs.append(result.fun)
    return np.array(costs)


@functools.cache
def pycma_costs(name: str) -> np.ndarray:
    return final_costs(name, "pycma")


def not_worse(ours: np.ndarray, reference: np.ndarray) -> float:
    """p of the paired one-sided Wilcoxon test that ours are greater (worse)."""
    return float(wilcoxon(ours, reference, alternative="greater").pvalue)


@pytest.mark.slow
@needs_pycma
@pytest.mark.parametrize("name", ["sphere", "ellipsoid", "rosenbrock"])
def test_cma_es_is_not_worse_than_pycma_with_the_optimum_on_faces(name: str) -> None:
    best = constrained_optimum(name)
    ours = final_costs(name, "cma-es")
    reference = pycma_costs(name)
    assert np.all(ours >= best - 1e-9 * abs(best)) and np.all(reference >= best - 1e-9 * abs(best))
    p = not_worse(ours, reference)
    gaps = (np.median(ours) - best, np.median(reference) - best)
    assert p > 0.05, (name, best, gaps, p)


@pytest.mark.slow
@needs_pycma
def test_the_check_tells_the_reflect_repair_apart() -> None:
    ours = final_costs("sphere", "cma-es", bound_handling="reflect")
    assert not_worse(ours, pycma_costs("sphere")) < 0.01


@pytest.mark.slow
@needs_pycma
def test_cma_es_is_not_worse_than_pycma_on_the_library() -> None:
    from formation_bench.instances.library import shipped

    instances = shipped().instances("test")
    results = {}
    for name, optimizer in [("cma-es", get_optimizer("cma-es")), ("pycma", get_optimizer("pycma"))]:
        costs = []
        for instance in instances:
            problem = instance.problem
            rng = np.random.default_rng(instance.index)
            result = optimizer.minimize(problem, problem.bounds, rng, None, instance.warm_start)
            assert result.nfev <= 1230
            costs.append(result.fun)
        results[name] = np.array(costs)
    p = not_worse(results["cma-es"], results["pycma"])
    medians = {name: float(np.median(costs)) for name, costs in results.items()}
    assert p > 0.05, (medians, p)
