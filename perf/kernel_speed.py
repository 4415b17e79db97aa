"""The cost kernel's speed against this machine's limit.

Run ``python -m perf.kernel_speed`` (``--json FILE`` keeps the figures). On recorded
problems of the paper scenario it times, per evaluation and in this thread's CPU time,
the three implementations of the cost as a compiled solve loop calls them (from compiled
code, through the compiled-objective handle where there is one, so no Python call is
timed), at populations of 30 (PSO, BSO) and 10 (CMA-ES on 10 variables):

- ``batch_cost_reference``, three sine-cosine pairs per RK4 sub-step (the yardstick);
- the numba kernel (``packed_batch_cost`` behind ``compiled_cost``), the fallback;
- the C kernel (``_cost_kernel.c``), when it was built at install.

The implementations take turns on every problem and every ratio is formed within one
repeat, so a slow spell of the machine that outlasts a repeat cancels.

Then the limit. :func:`operations_per_evaluation` counts the kernel's floating-point
operations on the problem (a fused multiply-add counts two), and :func:`flop_rates`
measures what one core of this machine sustains: independent fused multiply-adds, and
separate multiplies and adds, in vector registers (compiled with the C kernel's flags).
Their quotient is the floor of an evaluation here, and the kernel's time over it is its
distance to the limit. The floor is optimistic: it takes every operation at the fused
rate, where the kernel's sums and products are not all fused, and leaves out loads,
stores, conversions and selects.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numba as nb
import numpy as np

from formation_bench.instances.instants import RecordedInstant, record_instants
from formation_bench.mpc.cost import batch_cost_reference, compiled_cost
from formation_bench.mpc.model import HEADING_RESET_SUBSTEPS
from formation_bench.mpc.native_cost import native_cost_address
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import get_optimizer
from formation_bench.optimizers.compiled import _call_c_cost
from formation_bench.pipeline.runner import warm_up_kernels

POPULATIONS = (30, 10)
"""Batch sizes timed: PSO's and BSO's population, and CMA-ES's on the paper's 10 variables."""

# floating-point operations of one candidate in the fused kernel (batch_cost and
# _cost_kernel.c), counted from the source; a fused multiply-add counts two
COS_SIN_OPS = 37
"""``fused_cos_sin``: 1 + 3 fused reductions, r^2, two polynomials of 6 and 5 fused steps."""
TURN_OPS = 1 + COS_SIN_OPS + 3 + 2
"""Per control block: the half turn, its cosine and sine, and the double-angle pair."""
SUBSTEP_OPS = 33
"""Per sub-step: speeds, two rotations, Simpson's sums, position and heading updates."""
NEIGHBOUR_OPS = 6
"""Per period and neighbour: the offset from the target and its fused square."""
CENTRE_OPS = 9
"""Per period: the centre term and the weighted sum into the total."""


def operations_per_evaluation(horizon: int, n_blocks: int, substeps: int, neighbours: int) -> int:
    """Floating-point operations of one evaluation of eq. (14) without penalties."""
    resets = -(-horizon * substeps // HEADING_RESET_SUBSTEPS)
    per_period = substeps * SUBSTEP_OPS + neighbours * NEIGHBOUR_OPS + CENTRE_OPS
    return n_blocks * TURN_OPS + resets * COS_SIN_OPS + horizon * per_period + 1


def flop_rates(repeats: int = 7, rounds: int = 2_000_000) -> dict[str, float] | None:
    """This core's sustained rate in floating-point operations per second (best of
    ``repeats``): fused multiply-adds (two each), and separate multiplies and adds. Measured
    by the C kernel's module, compiled with the kernel's flags; None without it (numba
    leaves such chains unvectorised, and a scalar rate is no limit of this machine)."""
    try:
        from formation_bench.mpc._cost_kernel import multiply_add_chains
    except ImportError:
        return None
    rates = {}
    for name, fused in (("fma", True), ("mul_add", False)):
        multiply_add_chains(1000, fused)
        best = np.inf
        for _ in range(repeats):
            start = time.thread_time()
            multiply_add_chains(rounds, fused)
            best = min(best, time.thread_time() - start)
        rates[name] = 2.0 * 64 * rounds / best
    return rates


@nb.njit(cache=True)
def _time_handle(
    address: int, x: np.ndarray, data: np.ndarray, out: np.ndarray, calls: int
) -> float:
    total = 0.0
    for _ in range(calls):
        _call_c_cost(address, x, x.shape[0], data, out)
        total += out[0]
    return total


@nb.njit(cache=True)
def _time_reference(x, state, block_of_step, period, substeps, targets, centre, w_dst, w_centre,
                    calls):  # type: ignore[no-untyped-def]  # fmt: skip
    total = 0.0
    for _ in range(calls):
        total += batch_cost_reference(
            x, state, block_of_step, period, substeps, targets, centre, w_dst, w_centre
        )[0]
    return total


def kernel_times(
    instants: list[RecordedInstant], population: int, repeats: int, calls: int
) -> dict[str, Any]:
    """Median CPU seconds per evaluation of each implementation, and per-repeat ratios."""
    handles = {"numba": compiled_cost().address}
    if native_cost_address() is not None:
        handles["c"] = native_cost_address()
    rng = np.random.default_rng(population)
    problems = [(i.problem, i.problem.bounds.sample(rng, population)) for i in instants]
    per_eval: dict[str, list[float]] = {name: [] for name in ("reference", *handles)}
    for _ in range(repeats):
        totals = dict.fromkeys(per_eval, 0.0)
        for problem, x in problems:
            timing, out = problem.scenario.timing, np.empty(population)
            start = time.thread_time()
            _time_reference(
                x, problem.state, problem.block_of_step, timing.period_s, timing.rk4_substeps,
                problem._distance_targets, problem._centre_target,
                problem.scenario.weights.w_dst, problem._w_centre, calls,
            )  # fmt: skip
            totals["reference"] += time.thread_time() - start
            for name, address in handles.items():
                start = time.thread_time()
                _time_handle(address, x, problem.packed, out, calls)
                totals[name] += time.thread_time() - start
        for name, total in totals.items():
            per_eval[name].append(total / (calls * population * len(problems)))
    result: dict[str, Any] = {
        f"{name}_per_eval_s": float(np.median(times)) for name, times in per_eval.items()
    }
    if "c" in handles:
        result["c_over_numba"] = float(np.median(np.divide(per_eval["c"], per_eval["numba"])))
    result["numba_over_reference"] = float(
        np.median(np.divide(per_eval["numba"], per_eval["reference"]))
    )
    return result


def measure(repeats: int = 11, calls: int = 300) -> dict[str, Any]:
    """Every figure of the module docstring, on problems of three instants of a paper run."""
    warm_up_kernels()
    scenario = get_scenario("paper")
    instants = record_instants(scenario, get_optimizer("modified-bso"), [5, 60, 150], seed=1)
    timing = scenario.timing
    neighbours = instants[0].problem.neighbour_positions.shape[0]
    results: dict[str, Any] = {
        "machine": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "load_average_before": list(os.getloadavg()),
        "operations_per_evaluation": operations_per_evaluation(
            timing.horizon_steps, timing.n_blocks, timing.rk4_substeps, neighbours
        ),
        "c_kernel_built": native_cost_address() is not None,
    }
    rates = flop_rates()
    if rates is not None:
        results.update({f"{k}_flops": v for k, v in rates.items()})
    for population in POPULATIONS:
        times = kernel_times(instants, population, repeats, calls)
        results.update({f"{key}_{population}": value for key, value in times.items()})
    results["load_average_after"] = list(os.getloadavg())
    return results


def format_results(results: dict[str, Any]) -> str:
    """The figures as two Markdown tables: the kernels, and the limit."""
    ns = 1e9
    names = [
        ("reference", "reference, three sin/cos pairs per sub-step"),
        ("numba", "numba kernel (fused, the fallback)"),
        ("c", "C kernel (fused)"),
    ]
    header = " | ".join(f"batch {p}" for p in POPULATIONS)
    lines = [f"| kernel, ns per evaluation | {header} |", "|---|" + "---:|" * len(POPULATIONS)]
    for key, label in names:
        if f"{key}_per_eval_s_{POPULATIONS[0]}" in results:
            cells = [f"{ns * results[f'{key}_per_eval_s_{p}']:.1f}" for p in POPULATIONS]
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    if results["c_kernel_built"]:
        cells = [f"{results[f'c_over_numba_{p}']:.3f}" for p in POPULATIONS]
        lines.append("| C / numba, median per repeat | " + " | ".join(cells) + " |")
    operations = results["operations_per_evaluation"]
    lines += [
        "",
        "| the limit | value |",
        "|---|---|",
        f"| operations per evaluation (a fused multiply-add counts 2) | {operations} |",
    ]
    if "fma_flops" not in results:
        lines.append("| this core's rate | not measured: it needs the C kernel |")
    else:
        fma_rate, separate_rate = results["fma_flops"], results["mul_add_flops"]
        floor_ns = ns * operations / fma_rate
        lines += [
            f"| this core, fused multiply-adds | {fma_rate / 1e9:.1f} GFLOP/s |",
            f"| this core, separate multiplies and adds | {separate_rate / 1e9:.1f} GFLOP/s |",
            f"| floor of an evaluation (operations / FMA rate) | {floor_ns:.1f} ns |",
        ]
        fastest = "c" if results["c_kernel_built"] else "numba"
        for p in POPULATIONS:
            kernel_ns = ns * results[f"{fastest}_per_eval_s_{p}"]
            lines.append(
                f"| {fastest} kernel at batch {p}: time / floor, rate | "
                f"{kernel_ns / floor_ns:.2f}, {operations / kernel_ns:.1f} GFLOP/s |"
            )
    before, after = results["load_average_before"], results["load_average_after"]
    lines.append(f"| load average (1 min) before -> after | {before[0]:.2f} -> {after[0]:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.kernel_speed", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--repeats", type=int, default=11, help="repeats (11)")
    parser.add_argument("--calls", type=int, default=300, help="calls per problem per repeat")
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    results = measure(args.repeats, args.calls)
    print(format_results(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
