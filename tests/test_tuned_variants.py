"""The shipped tuned variants (``src/formation_bench/optimizers/tuned/``): each is its file's
configuration, and solves a recorded MPC problem as a registered optimiser must.

The tests over the registry check each class and hand-written configuration
(:func:`helpers.configured_names`); a tuned variant is other values of a class its base covers,
so here each one is checked once on the problem it was tuned for, a problem of the instance
library's test split: within the bounds, at its tuning budget, repeatable, no worse than the
warm start and not below the best-known cost."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import formation_bench.optimizers.tuned as tuned_package
from formation_bench.experiments.score import split_instances
from formation_bench.instances.library import j_star_tolerance, shipped
from formation_bench.optimizers import get_optimizer, optimizer_names
from formation_bench.optimizers.tuned import is_tuned, tuned_data, tuned_optimizer

FILES = sorted(Path(tuned_package.__file__).parent.glob("*.json"))
NAMES = [name for name in optimizer_names() if is_tuned(name)]


def test_every_shipped_file_is_registered_under_its_name():
    assert FILES, "the package ships tuned variants"
    assert sorted(path.stem for path in FILES) == sorted(NAMES)


@pytest.mark.parametrize("path", FILES, ids=lambda path: path.stem)
def test_a_tuned_variant_is_its_base_with_the_file_s_values(path):
    data = json.loads(path.read_text())
    registered = get_optimizer(data["name"])
    assert registered == tuned_optimizer(data)
    base = get_optimizer(data["base"])
    assert type(registered) is type(base)
    assert tuned_data(data["name"])["values"] == data["values"]
    assert len(data["history"]) == data["tuner"]["trials"]
    assert data["history"][0] == data["default_value"]
    assert data["best_value"] == min(data["history"])


@pytest.fixture(scope="module")
def instance():
    return split_instances(shipped(), "test")[3]


@pytest.mark.parametrize("name", NAMES)
def test_a_tuned_variant_solves_a_recorded_problem_within_bounds_at_its_tuning_budget(
    name, instance
):
    optimizer = get_optimizer(name)
    problem = instance.problem
    budget = tuned_data(name)["objective"]["budget"]

    def solve():
        rng = np.random.default_rng(11)
        return optimizer.minimize(problem, problem.bounds, rng, None, instance.warm_start)

    first, again = solve(), solve()
    np.testing.assert_array_equal(first.x, again.x)
    assert first.fun == again.fun
    assert np.all(first.x >= problem.bounds.lower) and np.all(first.x <= problem.bounds.upper)
    # the default budget is the tuning budget, to within one iteration's evaluations, and the
    # modified BSO's chaotic replacements on top (evaluated beside its N ideas an iteration;
    # its plan counts round(p_replace * n_replace) of them, none when that rounds to 0)
    replacements = first.info.get("chaotic_replacements", 0)
    assert budget * 0.95 <= first.nfev <= budget * 1.05 + replacements
    assert first.fun <= instance.warm_cost
    assert first.fun >= instance.j_star - j_star_tolerance(instance.j_star)
