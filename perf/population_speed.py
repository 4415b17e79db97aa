"""Speed of every population optimiser on the paper problem, and against mealpy's one-point BSO.

Run ``python -m perf.population_speed`` (needs ``mealpy`` from the
``peers`` extra for the last column). It records real per-UAV problems of the
paper scenario (:func:`formation_bench.instances.instants.record_instants`), then, for every
registered population optimiser at its default budget with the loop's warm
start:

- the solve time, split into the cost evaluations and everything else (the
  optimiser's own work, the evaluation counter, Python): this thread's CPU
  time, which other processes on the machine do not inflate; for each problem
  the fastest of ``--repeats`` identical solves (same seed), then the median
  over the problems. Once through the Python loop (the objective without its
  compiled handle) and, for the optimisers that have one, through the compiled
  loop, whose objective time is replayed
  (:mod:`perf.replay`);
- the time per evaluation, ``solve time / nfev``;
- the same for mealpy's ``OriginalBSO`` (Shi's parameters, one point per
  objective call) on the same problems in the same run, and the ratio.

CPU times are steadier than wall-clock times on a shared machine (the wall
time is reported too), but caches and memory bandwidth are still shared: keep
the machine quiet for comparable numbers (``--json FILE`` keeps the figures).
"""

from __future__ import annotations

import argparse
import functools
import json
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.instances.instants import RecordedInstant, record_instants
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import PopulationOptimizer, get_optimizer
from formation_bench.pipeline.runner import warm_up_kernels
from perf.bbob import mealpy_original_bso, population_optimizers
from perf.replay import replayed_objective_seconds, solve_batches


def paper_instants(steps: Sequence[int] = (5, 60, 150)) -> list[RecordedInstant]:
    """Every UAV's problem at the given instants of the paper scenario (no trigger)."""
    return record_instants(
        get_scenario("paper"), get_optimizer("modified-bso"), list(steps), seed=1
    )


class CpuTimedObjective:
    """A batch objective that adds up the CPU time of this thread spent inside ``problem``."""

    def __init__(self, problem: Callable[[np.ndarray], np.ndarray]) -> None:
        self.problem = problem
        self.cpu_s = 0.0

    def __call__(self, x: np.ndarray) -> np.ndarray:
        start = time.thread_time()
        costs = self.problem(x)
        self.cpu_s += time.thread_time() - start
        return costs


def _solve(optimizer: Any, objective: Any, inst: RecordedInstant, seed: int) -> Any:
    return optimizer.minimize(
        objective, inst.problem.bounds, np.random.default_rng(seed), None, inst.warm_start
    )


def _fastest_cpu(solve: Callable[[], Any], repeats: int) -> tuple[float, float, Any]:
    """``(CPU s, wall s, result)`` of the fastest of ``repeats`` identical solves."""
    runs = []
    for _ in range(repeats):
        cpu_start, wall_start = time.thread_time(), time.perf_counter()
        result = solve()
        runs.append((time.thread_time() - cpu_start, time.perf_counter() - wall_start, result))
    return min(runs, key=lambda r: r[0])


def time_optimizer(name: str, instants: list[RecordedInstant], repeats: int) -> dict[str, Any]:
    """CPU time of ``name`` per solve through Python and compiled, and the objective's part.

    Times are this thread's CPU time (``time.thread_time``), which does not
    advance while other processes hold the cores, so the split is stable on a
    shared machine. Every repeat of a problem uses the same seed and does the
    same work; per problem the fastest repeat counts, then the median over the
    problems.

    - The Python loop: the objective is wrapped so that it has no compiled
      handle, and its part is the CPU time inside the problem's call.
    - The compiled loop (optimisers that have one): the problem itself, and the
      objective's part replayed (:mod:`perf.replay`).
    """
    optimizer = get_optimizer(name)
    compiled = isinstance(optimizer, PopulationOptimizer) and optimizer.has_compiled_loop()
    first = instants[0]
    for objective in (first.problem, CpuTimedObjective(first.problem)):
        optimizer.minimize(
            objective, first.problem.bounds, np.random.default_rng(0), None, first.warm_start
        )
    rows: dict[str, list[float]] = {
        k: [] for k in ("python", "python_objective", "compiled", "compiled_objective", "wall")
    }
    nfev = []
    for k, inst in enumerate(instants):
        bounds, x0 = inst.problem.bounds, inst.warm_start
        timed = CpuTimedObjective(inst.problem)
        python_solve = functools.partial(_solve, optimizer, timed, inst, k)
        cpu, wall, result = _fastest_cpu(python_solve, repeats)
        timed.cpu_s = 0.0
        python_solve()  # the objective's CPU time of one solve, read from the wrapper
        rows["python"].append(cpu)
        rows["python_objective"].append(timed.cpu_s)
        nfev.append(result.nfev)
        if compiled:
            cpu, wall, _ = _fastest_cpu(
                functools.partial(_solve, optimizer, inst.problem, inst, k), repeats
            )
            batches = solve_batches(
                optimizer, inst.problem, bounds, np.random.default_rng(k), None, x0
            )
            rows["compiled"].append(cpu)
            rows["compiled_objective"].append(
                replayed_objective_seconds(inst.problem.compiled, batches, repeats)
            )
        rows["wall"].append(wall)
    figures = {k: np.array(v) for k, v in rows.items()}
    row: dict[str, Any] = {
        "optimizer": name,
        "nfev": int(np.median(nfev)),
        "python_solve_s": float(np.median(figures["python"])),
        "python_outside_share": float(
            np.median(1.0 - figures["python_objective"] / figures["python"])
        ),
        "wall_solve_s": float(np.median(figures["wall"])),
    }
    fastest = figures["python"]
    if compiled:
        fastest = figures["compiled"]
        row["compiled_solve_s"] = float(np.median(fastest))
        row["compiled_outside_share"] = float(
            np.median(1.0 - figures["compiled_objective"] / fastest)
        )
        row["compiled_speedup"] = float(np.median(figures["python"] / fastest))
    row["solve_s"] = float(np.median(fastest))
    row["per_evaluation_s"] = float(np.median(fastest / np.array(nfev)))
    return row


def time_mealpy(
    instants: list[RecordedInstant], evaluations: int, repeats: int = 2
) -> dict[str, Any]:
    """mealpy's OriginalBSO on the same problems: CPU time per evaluation (fastest repeat)."""
    per_evaluation, solve = [], []
    for k, inst in enumerate(instants):
        problem = inst.problem
        times = []
        for _ in range(repeats):
            start = time.thread_time()
            _, nfev = mealpy_original_bso(
                lambda s, p=problem: float(p(np.asarray(s)[None])[0]),
                problem.bounds.lower,
                problem.bounds.upper,
                evaluations,
                seed=k,
            )
            times.append(time.thread_time() - start)
        solve.append(min(times))
        per_evaluation.append(min(times) / nfev)
    return {
        "optimizer": "mealpy-OriginalBSO",
        "nfev": evaluations,
        "solve_s": float(np.median(solve)),
        "per_evaluation_s": float(np.median(per_evaluation)),
    }


def measure(
    names: Sequence[str] | None = None, repeats: int = 5, with_mealpy: bool = True
) -> dict[str, Any]:
    """Every figure of the tables; ``names`` defaults to every population optimiser."""
    warm_up_kernels()
    instants = paper_instants()
    rows = [time_optimizer(n, instants, repeats) for n in (names or population_optimizers())]
    results: dict[str, Any] = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "decision_dim": instants[0].problem.dim,
        "problems": len(instants),
        "repeats": repeats,
        "rows": rows,
    }
    if with_mealpy:
        mealpy = time_mealpy(instants, evaluations=1300)
        results["mealpy"] = mealpy
        for row in rows:
            row["mealpy_ratio"] = mealpy["per_evaluation_s"] / row["per_evaluation_s"]
    return results


def format_results(results: dict[str, Any]) -> str:
    """Markdown table of :func:`measure`'s figures (CPU times; wall time for reference)."""
    lines = [
        "| optimiser | nfev | solve through Python, CPU (ms) | outside evaluations "
        "| compiled solve, CPU (ms) | outside evaluations | compiled speed-up "
        "| µs per evaluation | mealpy / this, per evaluation | solve, wall (ms) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in results["rows"]:
        ratio = f"{row['mealpy_ratio']:.0f}x" if "mealpy_ratio" in row else "-"
        if "compiled_solve_s" in row:
            share = 100 * row["compiled_outside_share"]
            compiled = (
                f"{1e3 * row['compiled_solve_s']:.2f} | {share:.0f} % "
                f"| {row['compiled_speedup']:.2f}x"
            )
        else:
            compiled = "- | - | -"
        lines.append(
            f"| {row['optimizer']} | {row['nfev']} | {1e3 * row['python_solve_s']:.2f} "
            f"| {100 * row['python_outside_share']:.0f} % | {compiled} "
            f"| {1e6 * row['per_evaluation_s']:.2f} | {ratio} | {1e3 * row['wall_solve_s']:.2f} |"
        )
    if "mealpy" in results:
        m = results["mealpy"]
        lines.append(
            f"| {m['optimizer']} (one point per call) | {m['nfev']} | {1e3 * m['solve_s']:.1f} "
            f"| - | - | - | - | {1e6 * m['per_evaluation_s']:.1f} | 1x | - |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.population_speed",
        description=__doc__.splitlines()[0],
    )
    parser.add_argument("--repeats", type=int, default=5, help="solves per problem (5)")
    parser.add_argument("--optimizers", help="comma-separated names (default: all population)")
    parser.add_argument("--no-mealpy", action="store_true", help="skip the mealpy comparison")
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    names = args.optimizers.split(",") if args.optimizers else None
    results = measure(names, args.repeats, not args.no_mealpy)
    print(format_results(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
