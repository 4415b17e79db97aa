"""Iterations a per-solve deadline leaves a population method, against what its arithmetic allows.

Run ``python -m perf.deadline_overhead`` (``--deadline-ms``, ``--rounds``, ``--optimizers``).
On the paper scenario's recorded per-UAV problems (:func:`perf.population_speed.paper_instants`),
with the loop's warm start, for each optimiser:

- its **arithmetic**: the wall time ``T(k)`` of solves without a deadline that stop after
  ``k`` iterations, for ``k = K_SHORT`` and a ``k = K`` a quarter beyond what the deadline
  allows (estimated first, on one problem); the time of an iteration is
  ``b = (T(K) - T(K_SHORT)) / (K - K_SHORT)``, and the time before the first one (the initial
  population and the solve's set-up) ``a = T(K_SHORT) - K_SHORT b``. An iteration's time so
  includes its share of what the harness does once per block of iterations (drawing the
  block's random numbers, the call into compiled code), as in any solve. Per problem the
  fastest solve of the rounds counts: the least disturbed by the machine's other work;
- what that **allows** under a deadline ``D``: ``(D - a) / b`` iterations;
- what a solve under the deadline **completes**: its ``nit``, the median over the rounds. Its
  iteration limit is ``K`` too, so that it plans the same schedule, draws the same numbers and
  runs the same first iterations as the solve of ``K`` iterations (the cost of an iteration
  may change along a solve: the modified BSO's clustering, say), and the deadline ends it.

The ratio completed / allowed is 1 when a deadline costs the method nothing but its own
arithmetic; a harness that spends time between iterations (calls, clock reads, random numbers
drawn for iterations that never run) lowers it. Rounds alternate the three kinds of solve
problem by problem, so a burst of load on a shared machine hits them alike; the spread over
the rounds is printed beside the median. ``--json FILE`` keeps the figures.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.instances.instants import RecordedInstant
from formation_bench.optimizers import Budget, get_optimizer
from formation_bench.optimizers.population import ROWS_AHEAD
from formation_bench.pipeline.runner import warm_up_kernels
from perf.population_speed import paper_instants

OPTIMIZERS = ("cma-es", "predictive-sampling", "mppi", "modified-bso")
"""The methods measured by default: many short iterations (CMA-ES's generations of 10,
predictive sampling) and a few longer ones (MPPI, the modified BSO)."""

K_SHORT = 4
"""Iterations of the short solve without a deadline."""

MARGIN = 1.25
"""The long solve's iterations, and the deadline solves' limit, as a multiple of the iterations
the deadline allows by the first estimate."""


def _solve_seconds(
    optimizer: Any, inst: RecordedInstant, seed: int, budget: Budget
) -> tuple[float, int]:
    """Wall seconds and iterations of one solve."""
    problem = inst.problem
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    result = optimizer.minimize(problem, problem.bounds, rng, budget, inst.warm_start)
    return time.perf_counter() - start, result.nit


def measure_optimizer(
    name: str, instants: list[RecordedInstant], deadline_s: float, rounds: int
) -> dict[str, Any]:
    """The figures of one optimiser (see the module docstring)."""
    optimizer = get_optimizer(name)
    short = Budget(max_iterations=K_SHORT)
    long = Budget(max_iterations=_long_iterations(optimizer, instants[0], deadline_s))
    timed = Budget(max_iterations=long.max_iterations, deadline_s=deadline_s)
    n = len(instants)
    t_short, t_long = np.full(n, np.inf), np.full(n, np.inf)
    done = np.zeros((rounds, n))
    for r in range(rounds):
        for k, inst in enumerate(instants):
            seconds, nit = _solve_seconds(optimizer, inst, k, short)
            assert nit == K_SHORT, (name, nit)
            t_short[k] = min(t_short[k], seconds)
            seconds, nit = _solve_seconds(optimizer, inst, k, long)
            assert nit == long.max_iterations, (name, nit)
            t_long[k] = min(t_long[k], seconds)
            done[r, k] = _solve_seconds(optimizer, inst, k, timed)[1]
    per_iteration = (t_long - t_short) / (long.max_iterations - K_SHORT)
    setup = t_short - K_SHORT * per_iteration
    allowed = (deadline_s - setup) / per_iteration
    ratio_by_round = np.median(done / allowed, axis=1)
    return {
        "optimizer": name,
        "long_iterations": long.max_iterations,
        "setup_s": float(np.median(setup)),
        "per_iteration_s": float(np.median(per_iteration)),
        "allowed": float(np.median(allowed)),
        "completed": float(np.median(done)),
        "ratio": float(np.median(done / allowed)),
        "ratio_by_round": [float(v) for v in ratio_by_round],
        "deadline_binds": bool(np.all(done < long.max_iterations)),
    }


def _long_iterations(optimizer: Any, inst: RecordedInstant, deadline_s: float) -> int:
    """:data:`MARGIN` times the iterations ``deadline_s`` allows, by a first estimate from
    solves of :data:`K_SHORT` and :data:`ROWS_AHEAD` iterations (the fastest of eight; the
    first solves also compile the kernels, or load them from numba's cache)."""
    times = {}
    for k in (K_SHORT, ROWS_AHEAD):
        budget = Budget(max_iterations=k)
        times[k] = min(_solve_seconds(optimizer, inst, 0, budget)[0] for _ in range(8))
    per_iteration = (times[ROWS_AHEAD] - times[K_SHORT]) / (ROWS_AHEAD - K_SHORT)
    allowed = (deadline_s - times[K_SHORT]) / per_iteration + K_SHORT
    return max(2 * K_SHORT, round(MARGIN * allowed))


def measure(names: Sequence[str], deadline_s: float, rounds: int) -> dict[str, Any]:
    """Every figure of the table."""
    warm_up_kernels()
    instants = paper_instants()
    return {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "deadline_s": deadline_s,
        "problems": len(instants),
        "rounds": rounds,
        "rows": [measure_optimizer(n, instants, deadline_s, rounds) for n in names],
    }


def format_results(results: dict[str, Any]) -> str:
    """Markdown table of :func:`measure`'s figures."""
    deadline_ms = 1e3 * results["deadline_s"]
    lines = [
        f"| optimiser | K | set-up (µs) | per iteration (µs) "
        f"| iterations {deadline_ms:g} ms allows | iterations completed | completed / allowed "
        "| range over the rounds |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in results["rows"]:
        spread = row["ratio_by_round"]
        lines.append(
            f"| {row['optimizer']} | {row['long_iterations']} | {1e6 * row['setup_s']:.0f} "
            f"| {1e6 * row['per_iteration_s']:.1f} | {row['allowed']:.1f} "
            f"| {row['completed']:.0f} | {100 * row['ratio']:.0f} % "
            f"| {100 * min(spread):.0f}-{100 * max(spread):.0f} % |"
            + ("" if row["deadline_binds"] else " (a solve did not reach the deadline)")
        )
    lines.append(
        f"\n{results['problems']} problems x {results['rounds']} rounds; medians over the "
        f"problems; {results['machine']}, Python {results['python']}."
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.deadline_overhead", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--deadline-ms", type=float, default=1.0, help="per-solve deadline (1)")
    parser.add_argument("--rounds", type=int, default=5, help="passes over the problems (5)")
    parser.add_argument("--optimizers", default=",".join(OPTIMIZERS), help="comma-separated names")
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error("--rounds must be >= 1")
    if not args.deadline_ms > 0:
        parser.error("--deadline-ms must be > 0")
    results = measure(args.optimizers.split(","), args.deadline_ms / 1000.0, args.rounds)
    print(format_results(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
