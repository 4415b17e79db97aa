"""External validation: the population optimisers on BBOB functions, and mealpy's OriginalBSO.

Run ``python -m perf.bbob`` (needs the ``peers`` extra: ``ioh`` and
``mealpy``). Every registered population optimiser, and mealpy's
``OriginalBSO`` (a published implementation of Shi's BSO, evaluating one
point at a time), minimises a handful of BBOB functions from ``ioh`` in 10
dimensions, several instances each, with the same evaluation budget. The
table gives the median final error ``f(best) - f(optimum)`` per function and
optimiser. The functions were written by the BBOB authors (Hansen et al.),
not here, so they check the optimisers against code nobody here wrote.

``--markdown FILE`` / ``--json FILE`` keep the table and the raw errors.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.optimizers import (
    Bounds,
    Budget,
    PopulationOptimizer,
    get_optimizer,
    optimizer_names,
)

FUNCTIONS: dict[int, str] = {
    1: "f1 sphere",
    2: "f2 ellipsoid",
    8: "f8 Rosenbrock",
    10: "f10 rot. ellipsoid",
    15: "f15 rot. Rastrigin",
    21: "f21 Gallagher 101",
}
"""BBOB function ids used by default, with short names for the table."""

MEALPY_NAME = "mealpy-OriginalBSO"


def bbob_problem(function: int, instance: int, dimension: int) -> Any:
    """A fresh ``ioh`` BBOB problem (its evaluation counter starts at 0)."""
    import ioh  # benchmark-only dependency

    return ioh.get_problem(
        function, instance=instance, dimension=dimension, problem_class=ioh.ProblemClass.BBOB
    )


def batch_objective(problem: Any) -> Callable[[np.ndarray], np.ndarray]:
    """The ioh problem as a batch objective ``(n, d) -> (n,)``."""
    return lambda x: np.asarray(problem(np.asarray(x)), dtype=np.float64)


def run_registered(
    name: str, function: int, instance: int, dimension: int, evaluations: int, seed: int
) -> tuple[float, int, float]:
    """``(final error, evaluations used, seconds)`` of the registered optimiser ``name``."""
    problem = bbob_problem(function, instance, dimension)
    bounds = Bounds(np.asarray(problem.bounds.lb), np.asarray(problem.bounds.ub))
    optimizer = get_optimizer(name)
    start = time.perf_counter()
    result = optimizer.minimize(
        batch_objective(problem),
        bounds,
        np.random.default_rng(seed),
        Budget(max_evaluations=evaluations),
    )
    seconds = time.perf_counter() - start
    return float(result.fun - problem.optimum.y), result.nfev, seconds


def mealpy_original_bso(
    objective: Callable[[np.ndarray], float],
    lower: np.ndarray,
    upper: np.ndarray,
    evaluations: int,
    seed: int,
    population_size: int = 30,
) -> tuple[float, int]:
    """mealpy's ``OriginalBSO`` with Shi's parameters: ``(best cost, evaluations used)``.

    It evaluates one point per call; ``epoch`` (its logsig T_max) is set to the
    iterations the budget allows, and it stops at ``evaluations``.
    """
    from mealpy import FloatVar
    from mealpy.human_based.BSO import OriginalBSO

    problem = {
        "obj_func": objective,
        "bounds": FloatVar(lb=tuple(lower), ub=tuple(upper)),
        "minmax": "min",
        "log_to": None,
    }
    epochs = max(1, (evaluations - population_size) // population_size)
    model = OriginalBSO(
        epoch=epochs, pop_size=population_size, m_clusters=5, p1=0.2, p2=0.8, p3=0.4, p4=0.5
    )
    best = model.solve(problem, termination={"max_fe": evaluations}, seed=seed)
    return float(best.target.fitness), int(model.nfe_counter)


def run_mealpy(
    function: int, instance: int, dimension: int, evaluations: int, seed: int
) -> tuple[float, int, float]:
    """``(final error, evaluations used, seconds)`` of mealpy's OriginalBSO."""
    problem = bbob_problem(function, instance, dimension)
    start = time.perf_counter()
    best, nfev = mealpy_original_bso(
        lambda s: float(problem(np.asarray(s))),
        np.asarray(problem.bounds.lb),
        np.asarray(problem.bounds.ub),
        evaluations,
        seed,
    )
    return best - float(problem.optimum.y), nfev, time.perf_counter() - start


def population_optimizers() -> list[str]:
    """Registered names of the optimisers that accept any batch objective."""
    return [n for n in optimizer_names() if isinstance(get_optimizer(n), PopulationOptimizer)]


def measure(
    names: Sequence[str],
    functions: Sequence[int],
    instances: int,
    dimension: int,
    evaluations: int,
    with_mealpy: bool = True,
) -> list[dict[str, Any]]:
    """One record per (optimiser, function, instance); instance k runs with seed k."""
    records = []
    everyone = [*names, MEALPY_NAME] if with_mealpy else list(names)
    for function in functions:
        for instance in range(1, instances + 1):
            for name in everyone:
                run = run_mealpy if name == MEALPY_NAME else partial(run_registered, name)
                error, nfev, seconds = run(function, instance, dimension, evaluations, instance)
                records.append(
                    {
                        "optimizer": name,
                        "function": function,
                        "instance": instance,
                        "error": error,
                        "nfev": nfev,
                        "seconds": seconds,
                    }
                )
    return records


def median_table(records: list[dict[str, Any]]) -> str:
    """Markdown table: median final error per optimiser (rows) and function (columns)."""
    functions = sorted({r["function"] for r in records})
    names = list(dict.fromkeys(r["optimizer"] for r in records))
    header = "| optimiser | " + " | ".join(FUNCTIONS.get(f, f"f{f}") for f in functions) + " |"
    lines = [header, "|---|" + "---:|" * len(functions)]
    for name in names:
        cells = []
        for function in functions:
            errors = [
                r["error"] for r in records if r["optimizer"] == name and r["function"] == function
            ]
            cells.append(f"{np.median(errors):.3g}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.bbob", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--evaluations", type=int, default=1300, help="budget per run (1300)")
    parser.add_argument("--instances", type=int, default=5, help="BBOB instances 1..N (5)")
    parser.add_argument("--dimension", type=int, default=10, help="dimension (10)")
    parser.add_argument(
        "--functions",
        default=",".join(str(f) for f in FUNCTIONS),
        help="comma-separated BBOB function ids (default: %(default)s)",
    )
    parser.add_argument(
        "--optimizers", help="comma-separated registered names (default: every population one)"
    )
    parser.add_argument("--no-mealpy", action="store_true", help="skip mealpy's OriginalBSO")
    parser.add_argument("--markdown", type=Path, help="also write the table to this file")
    parser.add_argument("--json", type=Path, help="also write every run's error to this file")
    args = parser.parse_args(argv)
    names = args.optimizers.split(",") if args.optimizers else population_optimizers()
    functions = [int(f) for f in args.functions.split(",")]
    records = measure(
        names, functions, args.instances, args.dimension, args.evaluations, not args.no_mealpy
    )
    table = median_table(records)
    print(
        f"Median final error f - f_opt over instances 1..{args.instances}, "
        f"d = {args.dimension}, {args.evaluations} evaluations per run:\n"
    )
    print(table)
    if args.markdown:
        args.markdown.write_text(table + "\n")
    if args.json:
        args.json.write_text(json.dumps(records, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
