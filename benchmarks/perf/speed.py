"""Speed benchmark of the hot paths on the paper problem.

Run ``python -m formation_bench.benchmarks.perf.speed`` (add ``--json FILE`` to keep the figures).
It records real per-UAV problems of the paper scenario, then measures:

- the batch objective for a population of 30: compiled kernel versus the plain
  eq. (14) reference evaluated row by row (the "before");
- one modified-BSO solve at its default budget (median over instants and
  repeats), split into cost evaluation, clustering (replayed, see
  :func:`replayed_clustering_seconds`) and the rest;
- k-means on a BSO population: the compiled Lloyd iteration versus
  scikit-learn's KMeans from the same initial centres;
- a whole ``reproduce`` (both closed-loop runs) in this process.

All figures are wall-clock medians on this machine; pin the process (e.g.
``taskset -c 0,1``) for comparable numbers.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
import timeit
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.benchmarks.instants import RecordedInstant, record_instants
from formation_bench.benchmarks.runner import execute, warm_up_kernels
from formation_bench.benchmarks.spec import RunSpec
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import EvaluationCounter, ModifiedBSO, get_optimizer
from formation_bench.optimizers.bso_ops import cluster_population
from formation_bench.optimizers.clustering import lloyd_kmeans, sklearn_kmeans


def _median_seconds(func, number: int, repeat: int) -> float:
    return float(np.median(timeit.repeat(func, number=number, repeat=repeat)) / number)


def replayed_clustering_seconds(
    optimizer: ModifiedBSO, instant: RecordedInstant, rng: np.random.Generator
) -> float:
    """Time of the k-means steps of one default-budget solve, replayed outside the solve.

    The solve runs its k-means inside the one compiled call per iteration,
    where it cannot be timed. So the solve is repeated step by step with the
    same ``rng``, and the compiled k-means step (``cluster_population``: k-means
    from m random distinct members, then each cluster's best) is timed on the
    population each iteration clusters, from m members drawn by a separate
    generator. Each timed call also pays the entry into a kernel (about
    0.5 µs) that the fused iteration does not: a slight overestimate.
    """
    problem = instant.problem
    counter = EvaluationCounter(problem, problem.dim, None)
    t_max = optimizer.planned_iterations(optimizer.default_budget)
    state = optimizer.init(counter, problem.bounds, rng, instant.warm_start, t_max)
    seeds = np.random.default_rng(1).random((t_max, optimizer.n_clusters))
    total = 0.0
    for iteration in range(1, t_max + 1):
        x, f = state.population()
        start = time.perf_counter()
        cluster_population(x, f, seeds[iteration - 1], optimizer.kmeans_max_iter)
        total += time.perf_counter() - start
        state = optimizer.step(state, counter, problem.bounds, rng, iteration)
    return total


def measure(quick: bool = False) -> dict[str, Any]:
    """Run every measurement; ``quick`` shrinks repeats (for a smoke test)."""
    warm_up_kernels()
    scenario = get_scenario("paper")
    optimizer = get_optimizer("modified-bso")
    assert isinstance(optimizer, ModifiedBSO)
    instants = record_instants(scenario, optimizer, [5, 60, 150], seed=1)
    rng = np.random.default_rng(0)
    results: dict[str, Any] = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "decision_dim": instants[0].problem.dim,
    }

    population = [inst.problem.bounds.sample(rng, 30) for inst in instants]
    repeat = 3 if quick else 15
    compiled = [
        _median_seconds(lambda p=inst.problem, x=pop: p(x), 200, repeat)
        for inst, pop in zip(instants, population, strict=True)
    ]
    results["objective_pop30_compiled_s"] = float(np.median(compiled))

    problem, pop = instants[0].problem, population[0]

    def plain() -> None:
        for row in pop:
            problem.reference_cost(row)

    results["objective_pop30_plain_python_s"] = _median_seconds(plain, 1, 3 if quick else 7)

    solve_times, objective_times, clustering_times, nfevs = [], [], [], []
    for k, inst in enumerate(instants):
        for r in range(2 if quick else 10):
            solve_rng = np.random.default_rng([k, r])
            start = time.perf_counter()
            result = optimizer.minimize(
                inst.problem, inst.problem.bounds, solve_rng, None, inst.warm_start
            )
            solve_times.append(time.perf_counter() - start)
            objective_times.append(result.info["objective_time_s"])
            clustering_times.append(
                replayed_clustering_seconds(optimizer, inst, np.random.default_rng([k, r]))
            )
            nfevs.append(result.nfev)
    solve = float(np.median(solve_times))
    objective = float(np.median(objective_times))
    clustering = float(np.median(clustering_times))
    results.update(
        {
            "bso_solve_median_s": solve,
            "bso_solve_nfev": int(np.median(nfevs)),
            "bso_objective_median_s": objective,
            "bso_clustering_median_s": clustering,
            "bso_rest_median_s": solve - objective - clustering,
            "bso_solve_over_objective": solve / objective,
        }
    )

    points = population[1]
    centres = points[rng.choice(30, size=5, replace=False)]
    results["kmeans_compiled_s"] = _median_seconds(
        lambda: lloyd_kmeans(points, centres), 200, repeat
    )
    results["kmeans_sklearn_s"] = _median_seconds(
        lambda: sklearn_kmeans(points, centres), 5, 3 if quick else 7
    )

    if not quick:
        start = time.perf_counter()
        for trigger in (False, True):
            execute(
                RunSpec.of("modified-bso", optimizer, "paper", scenario, trigger=trigger, seed=0)
            )
        results["reproduce_both_runs_s"] = time.perf_counter() - start
    return results


def format_results(results: dict[str, Any]) -> str:
    """A Markdown table of :func:`measure`'s figures."""
    us = 1e6
    rows = [
        (
            "batch objective, population 30, compiled",
            f"{us * results['objective_pop30_compiled_s']:.1f} µs",
        ),
        (
            "same, plain eq. (14) row by row (reference)",
            f"{us * results['objective_pop30_plain_python_s']:.0f} µs",
        ),
        (
            f"modified-BSO solve, default budget ({results['bso_solve_nfev']} evaluations)",
            f"{1e3 * results['bso_solve_median_s']:.2f} ms",
        ),
        ("  of which cost evaluation", f"{1e3 * results['bso_objective_median_s']:.2f} ms"),
        ("  of which clustering", f"{1e3 * results['bso_clustering_median_s']:.2f} ms"),
        ("  of which the rest", f"{1e3 * results['bso_rest_median_s']:.2f} ms"),
        ("solve time / cost-evaluation time", f"{results['bso_solve_over_objective']:.2f}"),
        ("k-means of 30 points, compiled Lloyd", f"{us * results['kmeans_compiled_s']:.1f} µs"),
        ("k-means of 30 points, scikit-learn KMeans", f"{us * results['kmeans_sklearn_s']:.0f} µs"),
    ]
    if "reproduce_both_runs_s" in results:
        rows.append(
            ("reproduce, both runs (kernels cached)", f"{results['reproduce_both_runs_s']:.1f} s")
        )
    width = max(len(r[0]) for r in rows)
    lines = [f"| {'measurement':<{width}} | median |", f"|{'-' * (width + 2)}|--------|"]
    lines += [f"| {name:<{width}} | {value} |" for name, value in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m formation_bench.benchmarks.perf.speed", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    parser.add_argument("--quick", action="store_true", help="few repeats, no closed-loop run")
    args = parser.parse_args(argv)
    results = measure(quick=args.quick)
    print(format_results(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
