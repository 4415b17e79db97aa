"""Per-solve time of every registered optimiser on fixed recorded paper-problem instants.

The instants are the paper scenario's real per-UAV problems (all three UAVs at
instants 5, 60 and 150 of a run without trigger, modified BSO, seed 1), recorded
once per session by :func:`formation_bench.instances.instants.record_instants`, so every
optimiser solves exactly the same problems with the same warm starts. Each
benchmark round is one solve, cycling through the 9 problems with a fresh,
fixed generator per round.

Two budgets: the optimiser's own default (as the ``run``/``paper`` runs use it)
and the equal evaluation budget of the ``comparison`` suite. ``extra_info``
records the evaluations used.

    taskset -c 0,1 pytest perf/timing --benchmark-json=timing.json
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from formation_bench.instances.instants import record_instants
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import OPTIMIZERS, Budget, get_optimizer
from formation_bench.pipeline.runner import warm_up_kernels

INSTANT_STEPS = [5, 60, 150]
EQUAL_BUDGET = Budget(max_evaluations=1200)
ROUNDS = 27  # three passes over the 9 problems


@pytest.fixture(scope="session")
def instants():
    warm_up_kernels()
    return record_instants(
        get_scenario("paper"), get_optimizer("modified-bso"), INSTANT_STEPS, seed=1
    )


@pytest.mark.parametrize("budget_name", ["default", "equal-1200"])
@pytest.mark.parametrize("name", sorted(OPTIMIZERS))
def test_solve_time(benchmark, instants, name, budget_name):
    optimizer = get_optimizer(name)
    budget = None if budget_name == "default" else EQUAL_BUDGET
    cycle = itertools.cycle(enumerate(instants))
    rounds = itertools.count()
    nfev: list[int] = []

    def setup():
        k, inst = next(cycle)
        rng = np.random.default_rng([k, next(rounds)])
        return (inst.problem, inst.problem.bounds, rng, budget, inst.warm_start), {}

    def solve(problem, bounds, rng, budget, x0):
        result = optimizer.minimize(problem, bounds, rng, budget, x0)
        nfev.append(result.nfev)
        return result

    benchmark.group = f"budget {budget_name}"
    benchmark.extra_info.update(
        {
            "optimizer": name,
            "budget": budget_name,
            "instants": [f"step {i.step} uav {i.uav + 1}" for i in instants],
            "decision_dim": instants[0].problem.dim,
        }
    )
    benchmark.pedantic(solve, setup=setup, rounds=ROUNDS, warmup_rounds=len(instants))
    benchmark.extra_info["nfev_median"] = int(np.median(nfev))
