"""Time per solve of the derivative-based baselines beside the modified BSO, on the paper problem.

Run ``python -m perf.gradient_speed`` (``--json FILE`` keeps the figures,
``--quick`` runs a short scenario for a smoke test). In one process it measures,
for ``ipopt``, ``ltv-osqp``, ``ilqr`` and ``modified-bso`` (or ``--optimizers``):

A. **closed loop**: the paper scenario without trigger, so every UAV solves at
   every instant (240 x 3 = 720 solves per run), each optimiser on the problems
   its own run poses, warm-started from its own shifted plan (the way the
   baselines are used: IPOPT gets its previous multipliers, OSQP keeps its
   factorisation and iterates). "per solve" is what the loop times: building
   the instant's problem (the cost's parameters) plus ``minimize`` (the problem
   update, every cost and derivative evaluation, the solver);
B. **same recorded problems**: the 720 problems of one modified-BSO run with
   its warm starts, given to every optimiser. The baselines see a plan
   that is not their own, so IPOPT starts without multipliers and OSQP is set
   up afresh at every call: a common-problem comparison, slower for them.
   Two orders, both in every repeat: **back to back** (each optimiser solves
   all 720 problems, then the next optimiser: each finds the CPU's caches
   holding its own data, as in a score run) and **alternating** (every
   optimiser solves one problem before the next problem: each solve finds the
   caches filled by another solver). The ratio of two optimisers' times
   depends on the order; the medians of each repeat show the spread. B also
   reports the solving thread's CPU time, which other processes on a shared
   machine inflate less than the wall clock.

Runs are interleaved (A for every optimiser, then again) ``--repeats`` times and
pooled; CasADi and numba are built before anything is timed. Wall-clock times
on a shared machine: the load average is printed with the table.

C. **set-up apart** (``ipopt`` and ``ltv-osqp``, from A and B): the median of each
   part of a call as the solvers report it in ``OptimizeResult.info``. ``ltv-osqp``:
   the OSQP set-up (calls that set a workspace up) and OSQP's own solve time; ``ipopt``:
   the preparation before ``nlpsol`` (the problem's parameters and the warm start) and
   the ``nlpsol`` call split into CasADi's evaluations and IPOPT's own time. IPOPT
   rebuilds its algorithm on every call; that set-up is measured apart by solves with
   ``max_iter = 0`` of the recorded problems (IPOPT's own time of a call that stops
   before its first iteration).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.instances.instants import ObservedOptimizer, record_instants
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.metrics import compute_metrics
from formation_bench.mpc.scenario import Scenario, get_scenario
from formation_bench.optimizers import get_optimizer
from formation_bench.pipeline.runner import warm_up_kernels

DEFAULT_OPTIMIZERS = ("ipopt", "ltv-osqp", "ilqr", "modified-bso")
BACK_TO_BACK, ALTERNATING = "back to back", "alternating"
ORDERS = (BACK_TO_BACK, ALTERNATING)
"""The orders of section B's solves (the module docstring says what each measures)."""
TARGETS_MS = {"ipopt": 3.0, "ltv-osqp": 1.0}
"""Median per solve the issue asks for (per UAV per instant, 2-core machine)."""


def _summary(seconds: list[float] | np.ndarray) -> dict[str, float]:
    values = np.asarray(seconds, dtype=np.float64)
    return {
        "n": int(values.size),
        "median_ms": float(1e3 * np.median(values)),
        "p95_ms": float(1e3 * np.percentile(values, 95)),
        "max_ms": float(1e3 * values.max()),
    }


def schedule(names: tuple[str, ...], n_problems: int, order: str) -> list[tuple[str, int]]:
    """``(optimizer, problem index)`` of section B's solves, in the order they run."""
    if order == BACK_TO_BACK:
        return [(name, i) for name in names for i in range(n_problems)]
    return [(name, i) for i in range(n_problems) for name in names]


def measure(
    names: tuple[str, ...] = DEFAULT_OPTIMIZERS, repeats: int = 2, quick: bool = False
) -> dict[str, Any]:
    """Every measurement of the module docstring, as a dict."""
    scenario: Scenario = get_scenario("paper")
    if quick:
        scenario = scenario.with_overrides(n_steps=12, settle_time_s=0.0)
        repeats = 1
    warm_up_kernels()
    optimizers = {name: get_optimizer(name) for name in names}
    short = scenario.with_overrides(n_steps=2, settle_time_s=0.0)
    for optimizer in optimizers.values():  # build CasADi functions and OSQP before timing
        simulate(short, optimizer, trigger=False, seed=0)
    results: dict[str, Any] = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "scenario": scenario.name,
        "n_steps": scenario.timing.n_steps,
        "load_average_before": list(os.getloadavg()),
        "closed_loop": {},
        "recorded": {},
    }
    loop: dict[str, dict[str, list]] = {
        name: {"loop": [], "optimizer": [], "iterations": [], "nfev": [], "metrics": [], "info": []}
        for name in names
    }
    for repeat in range(repeats):
        for name, optimizer in optimizers.items():
            timed = ObservedOptimizer(optimizer)
            trace = simulate(scenario, timed, trigger=False, seed=repeat, optimizer_name=name)
            record = loop[name]
            record["loop"].extend(trace.solve_time_s[trace.solved].tolist())
            record["optimizer"].extend(solve.seconds for solve in timed.solves)
            record["iterations"].extend(int(solve.result.nit) for solve in timed.solves)
            record["nfev"].extend(int(solve.result.nfev) for solve in timed.solves)
            record["info"].extend((solve.seconds, solve.result.info) for solve in timed.solves)
            metrics = compute_metrics(trace).columns() if not quick else {}
            record["metrics"].append(
                {
                    "seed": repeat,
                    "solve_failures": int(trace.solve_failed.sum()),
                    **{
                        k: metrics[k]
                        for k in metrics
                        if k == "tracking_error_max_m" or k.startswith("distance_error_max_m_d")
                    },
                }
            )
    for name, record in loop.items():
        results["closed_loop"][name] = {
            "per_solve": _summary(record["loop"]),
            "optimizer_only": _summary(record["optimizer"]),
            "iterations_median": float(np.median(record["iterations"])),
            "nfev_median": float(np.median(record["nfev"])),
            "runs": record["metrics"],
        }
        parts = _parts(name, record["info"])
        if parts:
            results.setdefault("parts", {})[f"A {name}"] = parts

    instants = record_instants(
        scenario, get_optimizer("modified-bso"), list(range(scenario.timing.n_steps)), seed=0
    )
    recorded = {order: {name: [] for name in names} for order in ORDERS}
    by_repeat = {order: {name: [] for name in names} for order in ORDERS}
    cpu = {order: {name: [] for name in names} for order in ORDERS}
    recorded_info: dict[str, list[tuple[float, dict[str, Any]]]] = {name: [] for name in names}
    for repeat in range(repeats):
        for order in ORDERS:
            # each optimiser draws from its own Generator, the same in either order
            rngs = {name: np.random.default_rng(repeat) for name in names}
            times: dict[str, list[float]] = {name: [] for name in names}
            for name, index in schedule(names, len(instants), order):
                inst = instants[index]
                start, start_cpu = time.perf_counter(), time.thread_time()
                result = optimizers[name].minimize(
                    inst.problem, inst.problem.bounds, rngs[name], None, inst.warm_start
                )
                seconds = time.perf_counter() - start
                cpu[order][name].append(time.thread_time() - start_cpu)
                times[name].append(seconds)
                if order == BACK_TO_BACK:
                    recorded_info[name].append((seconds, result.info))
            for name in names:
                recorded[order][name].extend(times[name])
                by_repeat[order][name].append(_median_ms(times[name]))
    results["recorded_alternating"] = {}
    for name in names:
        results["recorded"][name] = {
            **_summary(recorded[BACK_TO_BACK][name]),
            "median_ms_by_repeat": by_repeat[BACK_TO_BACK][name],
            "cpu_median_ms": _median_ms(cpu[BACK_TO_BACK][name]),
        }
        results["recorded_alternating"][name] = {
            **_summary(recorded[ALTERNATING][name]),
            "median_ms_by_repeat": by_repeat[ALTERNATING][name],
            "cpu_median_ms": _median_ms(cpu[ALTERNATING][name]),
        }
        parts = _parts(name, recorded_info[name])
        if parts:
            results.setdefault("parts", {})[f"B {name}"] = parts
    if "ipopt" in optimizers:
        results["ipopt_setup"] = ipopt_setup(optimizers["ipopt"], instants)
    results["load_average_after"] = list(os.getloadavg())
    return results


def _median_ms(values: list[float]) -> float:
    return float(1e3 * np.median(values)) if values else float("nan")


def _parts(name: str, calls: list[tuple[float, dict[str, Any]]]) -> dict[str, float] | None:
    """Median parts of the calls of ``ipopt`` or ``ltv-osqp`` (ms), from their ``info``."""
    if not calls:
        return None
    if name == "ltv-osqp":
        setups = [info["osqp_setup_time_s"] for _, info in calls if info["osqp_setup"]]
        return {
            "minimize_ms": _median_ms([seconds for seconds, _ in calls]),
            "setup_share": len(setups) / len(calls),
            "osqp_setup_ms": _median_ms(setups),
            "osqp_solve_ms": _median_ms([info["osqp_run_time_s"] for _, info in calls]),
            "rest_ms": _median_ms(
                [
                    seconds
                    - info["osqp_run_time_s"]
                    - (info["osqp_setup_time_s"] if info["osqp_setup"] else 0.0)
                    for seconds, info in calls
                ]
            ),
        }
    if name == "ipopt":
        return {
            "minimize_ms": _median_ms([seconds for seconds, _ in calls]),
            "preparation_ms": _median_ms([info["setup_time_s"] for _, info in calls]),
            "ipopt_wall_ms": _median_ms([info["ipopt_wall_s"] for _, info in calls]),
            "evaluations_ms": _median_ms([info["evaluation_wall_s"] for _, info in calls]),
            "ipopt_own_ms": _median_ms([info["ipopt_own_s"] for _, info in calls]),
            "iterations_median": float(np.median([info["iterations"] for _, info in calls])),
        }
    return None


def ipopt_setup(optimizer: Any, instants: list[Any]) -> dict[str, float]:
    """IPOPT's set-up per call: solves with ``max_iter = 0`` of the recorded problems (ms).

    Such a call builds IPOPT's algorithm and evaluates the start, then stops before its first
    iteration; its ``t_wall_total`` less the evaluations is IPOPT's own set-up.
    """
    from formation_bench.mpc.solvers.ipopt_solver import call_times
    from formation_bench.mpc.solvers.problem_shape import ProblemShape, pack_parameters

    own, total = [], []
    for inst in instants:
        problem = inst.problem
        shape = ProblemShape.of(problem)
        nlpsol = optimizer.build(shape, 0).nlpsol
        start = time.perf_counter()
        nlpsol(
            x0=inst.warm_start,
            p=pack_parameters(problem, shape),
            lbx=problem.bounds.lower,
            ubx=problem.bounds.upper,
        )
        times = call_times(nlpsol.stats(), time.perf_counter() - start)
        own.append(times["ipopt_own_s"])
        total.append(times["ipopt_wall_s"])
    return {"ipopt_own_ms": _median_ms(own), "ipopt_wall_ms": _median_ms(total)}


def format_results(results: dict[str, Any]) -> str:
    """Markdown tables of :func:`measure`'s figures."""
    lines = [
        f"Paper scenario, no trigger, {results['n_steps']} instants x 3 UAVs per run; "
        f"{results['machine']}, {results['cpus']} CPUs, load average "
        f"{results['load_average_before'][0]:.2f} before / "
        f"{results['load_average_after'][0]:.2f} after.",
        "",
        "A. Closed loop, each optimiser on its own run (per solve = problem build + minimize):",
        "",
        "| optimizer | solves | median per solve | p95 per solve | median minimize only "
        "| p95 minimize only | median iterations | median nfev | failures | target (median) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, row in results["closed_loop"].items():
        per, own = row["per_solve"], row["optimizer_only"]
        failures = sum(run["solve_failures"] for run in row["runs"])
        target = TARGETS_MS.get(name)
        verdict = (
            ""
            if target is None
            else f"< {target:g} ms: " + ("met" if per["median_ms"] < target else "NOT met")
        )
        lines.append(
            f"| {name} | {per['n']} | {per['median_ms']:.2f} ms | {per['p95_ms']:.2f} ms "
            f"| {own['median_ms']:.2f} ms | {own['p95_ms']:.2f} ms "
            f"| {row['iterations_median']:g} | {row['nfev_median']:g} | {failures} | {verdict} |"
        )
    lines += [
        "",
        "B. The same recorded problems (one modified-BSO run's 720 problems and warm starts;",
        "   the baselines start without their own previous solve: no multipliers, fresh OSQP),",
        "   back to back (each optimiser over every problem in turn) and alternating (every",
        "   optimiser on a problem before the next problem); medians of each repeat in brackets:",
        "",
        "| optimizer | order | solves | median per solve | p95 per solve | median by repeat "
        "| median thread CPU |",
        "|---|---|---|---|---|---|---|",
    ]
    for order, key in ((BACK_TO_BACK, "recorded"), (ALTERNATING, "recorded_alternating")):
        for name, row in results[key].items():
            repeats_ms = ", ".join(f"{ms:.3f}" for ms in row["median_ms_by_repeat"])
            lines.append(
                f"| {name} | {order} | {row['n']} | {row['median_ms']:.3f} ms "
                f"| {row['p95_ms']:.3f} ms | {repeats_ms} | {row['cpu_median_ms']:.3f} ms |"
            )
    parts = results.get("parts", {})
    osqp_rows = {k: v for k, v in parts.items() if k.endswith("ltv-osqp")}
    ipopt_rows = {k: v for k, v in parts.items() if k.endswith("ipopt")}
    if osqp_rows:
        lines += [
            "",
            "C. ltv-osqp, set-up apart (medians; A closed loop, B recorded problems):",
            "",
            "| run | median minimize | calls that set OSQP up | OSQP set-up (those calls) "
            "| OSQP solve | rest (linearisation, cost, Python) |",
            "|---|---|---|---|---|---|",
        ]
        for key, row in osqp_rows.items():
            lines.append(
                f"| {key} | {row['minimize_ms']:.3f} ms | {100 * row['setup_share']:.0f} % "
                f"| {row['osqp_setup_ms']:.3f} ms | {row['osqp_solve_ms']:.3f} ms "
                f"| {row['rest_ms']:.3f} ms |"
            )
    if ipopt_rows:
        lines += [
            "",
            "C. ipopt, set-up apart (medians; A closed loop, B recorded problems):",
            "",
            "| run | median minimize | preparation | nlpsol call | of it evaluations "
            "| of it IPOPT's own | iterations |",
            "|---|---|---|---|---|---|---|",
        ]
        for key, row in ipopt_rows.items():
            lines.append(
                f"| {key} | {row['minimize_ms']:.3f} ms | {row['preparation_ms']:.3f} ms "
                f"| {row['ipopt_wall_ms']:.3f} ms | {row['evaluations_ms']:.3f} ms "
                f"| {row['ipopt_own_ms']:.3f} ms | {row['iterations_median']:g} |"
            )
    if "ipopt_setup" in results:
        setup = results["ipopt_setup"]
        lines += [
            "",
            f"IPOPT's set-up per call (max_iter = 0 on the recorded problems, medians): "
            f"{setup['ipopt_own_ms']:.3f} ms of IPOPT's own time, "
            f"{setup['ipopt_wall_ms']:.3f} ms for the whole call (CasADi's t_wall_total).",
        ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.gradient_speed",
        description=__doc__.splitlines()[0],
    )
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    parser.add_argument("--repeats", type=int, default=2, help="interleaved repeats (default 2)")
    parser.add_argument(
        "--optimizers",
        nargs="+",
        default=list(DEFAULT_OPTIMIZERS),
        help=f"registered names (default: {' '.join(DEFAULT_OPTIMIZERS)})",
    )
    parser.add_argument("--quick", action="store_true", help="12 instants, one repeat (smoke test)")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be >= 1")
    results = measure(tuple(args.optimizers), repeats=args.repeats, quick=args.quick)
    print(format_results(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
