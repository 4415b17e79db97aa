"""Speed benchmark of the hot paths on the paper problem.

Run ``python -m perf.speed`` (add ``--json FILE`` to keep the figures).
It records real per-UAV problems of the paper scenario, then measures:

- the batch objective for a population of 30: compiled kernel versus the plain
  eq. (14) reference evaluated row by row (the "before");
- the cost kernel per evaluation and this machine's floor: :mod:`perf.kernel_speed`
  (``python -m perf.kernel_speed`` runs just this);
- one modified-BSO solve at its default budget (median over instants and
  repeats; the compiled loop), split into cost evaluation (replayed, see
  :mod:`perf.replay`), clustering (replayed, see
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

from formation_bench.instances.instants import RecordedInstant, record_instants
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import ModifiedBSO, get_optimizer
from formation_bench.optimizers.ask_tell import Kernels, run_blocks
from formation_bench.optimizers.bso_ops import cluster_population
from formation_bench.optimizers.clustering import lloyd_kmeans, sklearn_kmeans
from formation_bench.optimizers.tallies import open_tally
from formation_bench.pipeline.runner import execute, warm_up_kernels
from formation_bench.pipeline.spec import RunSpec
from perf import kernel_speed
from perf.replay import replayed_objective_seconds, solve_batches


def _median_seconds(func, number: int, repeat: int) -> float:
    return float(np.median(timeit.repeat(func, number=number, repeat=repeat)) / number)


def replayed_clustering_seconds(
    optimizer: ModifiedBSO, instant: RecordedInstant, rng: np.random.Generator
) -> float:
    """Time of the k-means steps of one default-budget solve, replayed outside the solve.

    The solve runs its k-means inside the one compiled call per iteration,
    where it cannot be timed. So the solve is repeated with the same ``rng``, its rounds
    driven from Python (the same kernels, the same draws), and before each iteration's first
    round the compiled k-means step (``cluster_population``: k-means from m random distinct
    members, then each cluster's best) is timed on the population the iteration clusters,
    from m members drawn by a separate generator. Each timed call also pays the entry into
    a kernel (about 0.5 µs) that the compiled loop does not: a slight overestimate.
    """
    problem = instant.problem
    budget = optimizer.default_budget
    t_max = optimizer.planned_iterations(budget)
    params = optimizer.params(problem.bounds, t_max)
    tally = open_tally(problem, problem.dim, budget, time.perf_counter(), compiled_loop=False)
    points = optimizer.initial_points(problem.bounds, rng, instant.warm_start)
    state = optimizer.start(points, tally.evaluate_prefix(points), rng, params)
    seeds = np.random.default_rng(1).random((t_max, optimizer.n_clusters))
    timed: dict[int, float] = {}

    def timed_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
        if iteration not in timed:
            start = time.perf_counter()
            cluster_population(state.x, state.f, seeds[(iteration - 1) % t_max],
                               optimizer.kmeans_max_iter)  # fmt: skip
            timed[iteration] = time.perf_counter() - start
        return optimizer.kernels.ask(state, params, uniforms, normals, iteration, remaining)

    kernels = Kernels(timed_ask, optimizer.kernels.tell, None)
    source = optimizer.block_source(problem.bounds, points.shape, t_max)
    run_blocks(kernels, state, params, tally, rng, budget, source)
    return sum(timed.values())


def default_population_size() -> int:
    """The population of the paper's optimiser and of PSO at their defaults (both 30)."""
    sizes = {get_optimizer(name).population_size for name in ("modified-bso", "pso")}
    if len(sizes) != 1:
        raise ValueError(f"modified-bso and pso default to different populations: {sizes}")
    return sizes.pop()


def measure(quick: bool = False) -> dict[str, Any]:
    """Run every measurement; ``quick`` shrinks repeats (for a smoke test)."""
    warm_up_kernels()
    scenario = get_scenario("paper")
    optimizer = get_optimizer("modified-bso")
    assert isinstance(optimizer, ModifiedBSO)
    instants = record_instants(scenario, optimizer, [5, 60, 150], seed=1)
    results_kernel = kernel_speed.measure(repeats=3 if quick else 11, calls=20 if quick else 300)
    rng = np.random.default_rng(0)
    results: dict[str, Any] = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "decision_dim": instants[0].problem.dim,
        **results_kernel,
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
            batches = solve_batches(
                optimizer, inst.problem, inst.problem.bounds, np.random.default_rng([k, r]), None,
                inst.warm_start,
            )  # fmt: skip
            objective_times.append(
                replayed_objective_seconds(inst.problem.compiled, batches, clock=time.perf_counter)
            )
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
    return "\n".join(lines) + "\n\n" + kernel_speed.format_results(results)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.speed", description=__doc__.splitlines()[0]
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
