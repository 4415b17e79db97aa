"""The shipped instance library: its contents, its best-known optima and how it was drawn."""

import dataclasses

import numpy as np
import pytest

from formation_bench.benchmarks.instances.build import DrawPlan, draw
from formation_bench.benchmarks.instances.library import LibraryError, load, shipped
from formation_bench.optimizers import OPTIMIZERS, get_optimizer
from formation_bench.optimizers.adapters import ADAPTERS

GAP_TOLERANCE = 1e-6
"""How far below J* (relative) an optimiser may end before J* counts as beaten."""
ADAPTER_STRIDE = 50
"""The adapters solve every 50th instance: their libraries' Python overhead makes a solve 30-650
times slower than the compiled optimisers' (docs/optimizers.md, "Adapters")."""


@pytest.fixture(scope="module")
def library():
    return shipped()


def test_the_library_ships_at_least_500_instances_from_every_scenario_and_trigger(library):
    assert len(library) >= 500
    manifest = library.manifest
    assert manifest["instances"] == len(library)
    assert {s["name"] for s in manifest["scenarios"]} == {
        "paper",
        "paper-s-curve",
        "paper-straight",
    }
    instances = list(library)
    assert {i.trigger for i in instances} == {False, True}
    assert {i.drawn_by for i in instances} == set(manifest["draw_plan"]["optimizers"])
    assert {i.step for i in instances} >= {0}  # the start-up is in
    assert max(i.step for i in instances) >= 200  # and the steady state
    assert sum(manifest["found_by"].values()) == len(library)


def test_the_plain_eq14_at_x_star_gives_j_star(library):
    for instance in library:
        problem = instance.problem
        assert problem.bounds.contains(instance.x_star)
        plain = problem.reference_cost(instance.x_star)
        assert plain == pytest.approx(instance.j_star, rel=1e-9)
        assert problem(instance.warm_start[None])[0] >= instance.j_star


@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=pytest.mark.slow) if n in ADAPTERS else n for n in sorted(OPTIMIZERS)],
)
def test_no_registered_optimizer_at_its_default_budget_beats_j_star(library, name):
    optimizer = get_optimizer(name)
    worst = -np.inf
    instances = list(library)[:: ADAPTER_STRIDE if name in ADAPTERS else 1]
    for instance in instances:
        rng = np.random.default_rng(instance.index)
        result = optimizer.minimize(
            instance.problem, instance.problem.bounds, rng, None, instance.warm_start
        )
        worst = max(worst, float(-instance.gap(result.fun)))
    # a negative gap below the tolerance would mean J* is not the best known: rebuild it
    assert worst <= GAP_TOLERANCE


def test_drawing_takes_evenly_spaced_solves_from_the_start_on():
    plan = DrawPlan(scenarios=("paper",), triggers=(True,), optimizers=("pso",), seeds=(0,))
    instances, scenarios = draw(dataclasses.replace(plan, per_loop=5))
    steps = [i["step"] for i in instances]
    assert len(instances) == 5 and steps[0] == 0 and steps == sorted(steps)
    assert scenarios == [{"name": "paper", "overrides": {}}]


def test_a_missing_library_is_named(tmp_path):
    with pytest.raises(LibraryError, match="no such library file"):
        load(tmp_path, "v9")
