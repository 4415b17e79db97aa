"""What an ask/tell optimiser keeps between solves (its kernel settings per box, its draw plan)
changes nothing: parametrised over every registered ask/tell configuration."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from helpers import BOX, CENTRE, configured_names, shifted_sphere

from formation_bench.optimizers import Bounds, Budget, get_optimizer
from formation_bench.optimizers.ask_tell import AskTellOptimizer

sphere = shifted_sphere(CENTRE)
ASK_TELL = [
    name
    for name in configured_names()
    if not name.startswith("ng-") and isinstance(get_optimizer(name), AskTellOptimizer)
]
OTHER_BOX = Bounds(BOX.lower * 0.5, BOX.upper * 2.0)


def _arrays_in(value: object) -> list[np.ndarray]:
    if isinstance(value, np.ndarray):
        return [value]
    if isinstance(value, tuple):
        return [array for item in value for array in _arrays_in(item)]
    if hasattr(value, "__dict__"):
        return _arrays_in(tuple(vars(value).values()))
    return []


def _kept_arrays(optimizer: AskTellOptimizer) -> list[tuple[object, np.ndarray]]:
    kept = optimizer.__dict__.get("_solve_constants", {})
    return [(key, array.copy()) for key, value in kept.items() for array in _arrays_in(value)]


def test_every_ask_tell_configuration_is_checked() -> None:
    assert {"pso", "modified-bso", "cma-es", "de", "mppi", "cem"} <= set(ASK_TELL)


@pytest.mark.parametrize("name", ASK_TELL)
def test_solves_with_kept_constants_equal_a_fresh_optimiser_s(name: str) -> None:
    budget = Budget(max_evaluations=300)
    reused = get_optimizer(name)
    for box in (BOX, OTHER_BOX, BOX):  # builds, keeps, and takes back what it keeps
        reused.minimize(sphere, box, np.random.default_rng(3), budget)
    assert reused.__dict__.get("_solve_constants"), "nothing kept: the solves rebuild them"
    before = _kept_arrays(reused)
    for box in (BOX, OTHER_BOX):
        fresh = get_optimizer(name).minimize(sphere, box, np.random.default_rng(5), budget)
        again = reused.minimize(sphere, box, np.random.default_rng(5), budget)
        np.testing.assert_array_equal(again.x, fresh.x)
        assert (again.fun, again.nfev, again.nit) == (fresh.fun, fresh.nfev, fresh.nit)
        np.testing.assert_array_equal(again.history_fun, fresh.history_fun)
    # no solve wrote into what the next solves read
    after = _kept_arrays(reused)
    assert [repr(key) for key, _ in after[: len(before)]] == [repr(key) for key, _ in before]
    for (_, kept), (_, array) in zip(after, before, strict=False):
        np.testing.assert_array_equal(kept, array)


@pytest.mark.parametrize("name", ["pso", "modified-bso", "cma-es"])
def test_kept_constants_are_not_pickled_nor_part_of_the_configuration(name: str) -> None:
    optimizer = get_optimizer(name)
    fresh = get_optimizer(name)
    optimizer.minimize(sphere, BOX, np.random.default_rng(1), Budget(max_evaluations=100))
    assert "_solve_constants" in optimizer.__dict__
    copy = pickle.loads(pickle.dumps(optimizer))
    assert "_solve_constants" not in copy.__dict__
    assert optimizer == fresh and hash(optimizer) == hash(fresh) and repr(optimizer) == repr(fresh)
