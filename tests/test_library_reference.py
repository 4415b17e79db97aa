"""de and de-current-to-best reach scipy's quality on the instance library.

The test split of the shipped library (its problems counted once, the degenerate stratum left
out), from each problem's warm start, at the optimiser's default budget (1230 evaluations), one
seed per problem: ``de`` and ``de-current-to-best`` against
``scipy.optimize.differential_evolution`` with the same settings (N = 30, F = 0.5, CR = 0.9, the
warm start as member 0, deferred updating, no polishing, the same 41 generations). The two-sided
Wilcoxon signed-rank test on the paired relative gaps to J* must not reject equality
(p > 0.01), and the medians must lie within a factor of 10. The seeds are fixed, so the p-values
are too: a regression check of agreement. ``cma-es`` against pycma and ``de-immediate`` against
scipy's immediate updating are checked on the same split in test_cma_reference.py and
test_de_reference.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import differential_evolution
from scipy.stats import wilcoxon

from formation_bench.instances.library import Instance, shipped
from formation_bench.optimizers import get_optimizer

SCIPY_STRATEGY = {"de": "rand1bin", "de-current-to-best": "currenttobest1bin"}


def problems() -> list[Instance]:
    return shipped().instances("test")


def our_gaps(name: str) -> np.ndarray:
    optimizer = get_optimizer(name)
    gaps = []
    for instance in problems():
        problem = instance.problem
        rng = np.random.default_rng(instance.index)
        result = optimizer.minimize(problem, problem.bounds, rng, None, instance.warm_start)
        assert result.nfev <= 1230
        gaps.append(float(instance.gap(result.fun)))
    return np.array(gaps)


def scipy_gaps(strategy: str) -> np.ndarray:
    gaps = []
    for instance in problems():
        problem, bounds = instance.problem, instance.problem.bounds
        evaluations = [0]

        def batch(x: np.ndarray, problem=problem, evaluations=evaluations) -> np.ndarray:
            evaluations[0] += x.shape[1]
            return problem(np.ascontiguousarray(x.T))

        result = differential_evolution(
            batch, list(zip(bounds.lower, bounds.upper, strict=True)), strategy=strategy,
            maxiter=40, popsize=3, mutation=0.5, recombination=0.9, init="random",
            updating="deferred", vectorized=True, polish=False, tol=0.0, atol=0.0,
            rng=1000 + instance.index, x0=instance.warm_start,
        )  # fmt: skip
        assert evaluations[0] == 30 * 41  # the same evaluations as de's 40 iterations
        gaps.append(float(instance.gap(result.fun)))
    return np.array(gaps)


def agree(ours: np.ndarray, reference: np.ndarray) -> None:
    assert np.all(np.isfinite(ours)) and np.all(np.isfinite(reference))
    p = wilcoxon(ours, reference).pvalue
    ratio = np.median(ours) / np.median(reference)
    assert p > 0.01, (np.median(ours), np.median(reference), p)
    assert 0.1 < ratio < 10.0, ratio


@pytest.mark.parametrize("name", list(SCIPY_STRATEGY))
@pytest.mark.slow
def test_de_and_scipy_reach_the_same_gaps_on_the_library(name: str) -> None:
    ours = our_gaps(name)
    assert get_optimizer(name).default_budget.max_iterations == 40
    agree(ours, scipy_gaps(SCIPY_STRATEGY[name]))


@pytest.mark.slow
def test_the_check_tells_a_weaker_search_apart() -> None:
    """The test has power: de at its default against scipy's DE with ten times the
    generations is rejected (on every 4th problem: the stronger search is ten times as long)."""
    ours = our_gaps("de")[::4]
    stronger = []
    for instance in problems()[::4]:
        problem, bounds = instance.problem, instance.problem.bounds
        result = differential_evolution(
            lambda x, problem=problem: problem(np.ascontiguousarray(x.T)),
            list(zip(bounds.lower, bounds.upper, strict=True)), strategy="currenttobest1bin",
            maxiter=400, popsize=3, mutation=0.5, recombination=0.9, init="random",
            updating="deferred", vectorized=True, polish=False, tol=0.0, atol=0.0,
            rng=1000 + instance.index, x0=instance.warm_start,
        )  # fmt: skip
        stronger.append(float(instance.gap(result.fun)))
    assert wilcoxon(ours, np.array(stronger)).pvalue < 0.01
