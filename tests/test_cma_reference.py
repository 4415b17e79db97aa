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
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import mannwhitneyu

from formation_bench.optimizers import Bounds, Budget, get_optimizer

D = 10
BOX = Bounds(np.full(D, -5.0), np.full(D, 5.0))
CENTRE = np.linspace(-3.0, 2.0, D)
SEEDS = range(20)


def sphere(x: np.ndarray) -> np.ndarray:
    z = x - CENTRE
    return np.einsum("ij,ij->i", z, z)


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
