"""Smoke tests of the BBOB validation and the population speed benchmark (tiny settings).

``ioh`` and ``mealpy`` are in the ``dev`` extra, so these run in CI rather than
being skipped.
"""

from __future__ import annotations

import numpy as np
import pytest

from formation_bench.optimizers import get_optimizer
from perf import bbob, population_speed, replay


@pytest.mark.slow
def test_bbob_runs_and_tabulates() -> None:
    records = bbob.measure(["original-bso", "pso"], [1, 15], 2, 10, 200)
    assert len(records) == 3 * 2 * 2  # two optimisers and mealpy, two functions, two instances
    assert all(r["error"] >= 0.0 and r["nfev"] <= 200 for r in records)
    mealpy = [r for r in records if r["optimizer"] == bbob.MEALPY_NAME]
    assert all(r["nfev"] >= 150 for r in mealpy)
    table = bbob.median_table(records)
    assert table.count("\n") == 4 and "f15 rot. Rastrigin" in table and "mealpy" in table


def test_bbob_error_is_measured_from_the_optimum() -> None:
    error, nfev, _ = bbob.run_registered("pso", 1, 1, 10, 1300, seed=0)
    assert nfev == 1300 and 0.0 <= error < 1.0  # sphere: PSO gets close
    assert "pso" in bbob.population_optimizers()
    assert "original-bso" in bbob.population_optimizers()


def test_population_speed_measures_and_formats() -> None:
    instants = population_speed.paper_instants((5,))
    row = population_speed.time_optimizer("pso", instants, 1)
    assert row["nfev"] == 1230 and 0.0 < row["python_outside_share"] < 1.0
    assert row["wall_solve_s"] > 0.0
    assert 0.0 < row["per_evaluation_s"] < row["solve_s"]
    mealpy = population_speed.time_mealpy(instants[:1], 200)
    assert mealpy["per_evaluation_s"] > 0.0
    row["mealpy_ratio"] = mealpy["per_evaluation_s"] / row["per_evaluation_s"]
    table = population_speed.format_results({"rows": [row], "mealpy": mealpy})
    assert "| pso | 1230 |" in table and "mealpy-OriginalBSO" in table


@pytest.mark.slow
def test_population_speed_times_de_and_random_search_beside_the_modified_bso() -> None:
    # the table enumerates the registry: the newer optimisers get rows without an edit
    assert {"modified-bso", "de", "de-current-to-best", "random-search"} <= set(
        bbob.population_optimizers()
    )
    instants = population_speed.paper_instants((5,))
    for name in ("de", "random-search"):
        row = population_speed.time_optimizer(name, instants, 1)
        assert row["nfev"] == 1230 and 0.0 < row["python_outside_share"] < 1.0
        assert f"| {name} | 1230 |" in population_speed.format_results({"rows": [row]})


def test_population_speed_times_the_compiled_loop_beside_the_python_one() -> None:
    instants = population_speed.paper_instants((5,))
    row = population_speed.time_optimizer("de", instants, 2)
    assert 0.0 < row["compiled_outside_share"] < 1.0
    assert row["compiled_speedup"] > 0.0 and row["solve_s"] == row["compiled_solve_s"]
    table = population_speed.format_results({"rows": [row]})
    assert f"{row['compiled_speedup']:.2f}x" in table


def test_replay_evaluates_the_batches_of_the_solve() -> None:
    inst = population_speed.paper_instants((5,))[0]
    optimizer = get_optimizer("modified-bso")
    problem, bounds = inst.problem, inst.problem.bounds
    batches = replay.solve_batches(
        optimizer, problem, bounds, np.random.default_rng(4), None, inst.warm_start
    )
    result = optimizer.minimize(problem, bounds, np.random.default_rng(4), None, inst.warm_start)
    assert sum(b.shape[0] for b in batches) == result.nfev
    assert min(problem(b).min() for b in batches) == result.fun
    assert replay.replayed_objective_seconds(problem.compiled, batches, repeats=2) > 0.0
