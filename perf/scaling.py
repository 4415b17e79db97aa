"""Scaling of the sweep machinery: speed-up with 2 workers, and its per-run overhead.

Run ``python -m perf.scaling`` (``--json FILE`` keeps the figures). It
sweeps a fixed suite (the paper scenario with the modified BSO at its default
budget, trigger off so that every run does the same work; 8 seeds by default)
into fresh folders, once with 1 worker and once with 2, after warming the
workers (imports and numba's on-disk kernel cache; that start-up cost is
measured and reported separately, it is paid once per worker per sweep):

- speed-up = wall time with 1 worker / wall time with 2 workers (target >= 1.8);
- machinery overhead per run = (sweep wall time with 1 worker - the runs' own
  simulation time) / runs: planning, building, metrics, the results row,
  Parquet writes, manifest, progress; as a fraction of a run (target < 5 %);
- the same with 2 workers: (2 x wall - simulation time) / runs, which also counts
  the idle tail and the coordinating process sharing the 2 cores.

The figures are wall-clock times on a machine that may be shared: rerun on a
quiet machine (``taskset -c 0,1`` pins it to two cores) for reference numbers.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path
from typing import Any

from formation_bench.experiments.executors import run_locally
from formation_bench.experiments.store import load_results
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.pipeline.provenance import machine_info

SUITE = """\
name = "scaling"
description = "Fixed sweep for the scaling benchmark: equal work per run"
seeds = {runs}
triggers = [false]

[[optimizers]]
name = "modified-bso"

[[scenarios]]
name = "{scenario}"
overrides = {{ n_steps = {steps}, settle_time_s = {settle} }}
"""

WARM = """\
name = "warm-up"
seeds = {n}
triggers = [false]

[[optimizers]]
name = "modified-bso"
overrides = {{ max_iterations = 2 }}

[[scenarios]]
name = "paper"
overrides = {{ n_steps = 40, settle_time_s = 0.0 }}
"""


def warm_workers(jobs: int) -> dict[str, float]:
    """Start ``jobs`` workers and load every kernel in each; returns the start-up times."""
    start = time.perf_counter()
    specs = parse_suite(WARM.format(n=8 * jobs), Path("warm.toml")).runs()
    pids: dict[int, float] = {}
    for result in run_locally(specs, jobs):
        assert result.row is not None, result.error
        pids.setdefault(result.row["worker_pid"], result.row["run_time_s"])
    return {
        "workers_started": float(len(pids)),
        "warm_up_wall_s": time.perf_counter() - start,
        "first_run_in_worker_s": max(pids.values()),
    }


def timed_sweep(text: str, jobs: int) -> tuple[float, Any]:
    suite = parse_suite(text, Path("scaling.toml"))
    with tempfile.TemporaryDirectory(prefix="formation-bench-scaling-") as folder:
        start = time.perf_counter()
        summary = run_sweep(suite, folder, jobs=jobs, progress=False, log=lambda _: None)
        wall = time.perf_counter() - start
        assert summary.stored == len(suite.runs()) and not summary.failed
        results = load_results(folder)
    return wall, results


def measure(
    runs: int = 8, steps: int = 240, scenario: str = "paper", repeat: int = 1
) -> dict[str, Any]:
    """Sweep the fixed suite with 1 and 2 workers, alternating, ``repeat`` times each.

    The figures of each worker count are those of its fastest repetition (the least
    disturbed by other work on the machine).
    """
    import os

    settle = min(10.0, 0.1 * steps)  # the paper's 10 s, or half of a shorter run
    text = SUITE.format(runs=runs, steps=steps, scenario=scenario, settle=settle)
    figures: dict[str, Any] = {
        "runs": runs,
        "scenario": scenario,
        "steps": steps,
        "repeat": repeat,
        "python": platform.python_version(),
        "machine": machine_info(),
        "load_average_before": os.getloadavg(),
    }
    for _ in range(repeat):
        for jobs in (1, 2):
            warm = warm_workers(jobs)
            wall, results = timed_sweep(text, jobs)
            simulate = float(results["wall_time_s"].sum())
            entry = {
                **warm,
                "sweep_wall_s": wall,
                "simulate_total_s": simulate,
                "run_mean_s": simulate / runs,
                "task_total_s": float(results["run_time_s"].sum()),
                "overhead_per_run_s": (jobs * wall - simulate) / runs,
                "overhead_fraction": (jobs * wall - simulate) / simulate,
                "workers_used": int(results["worker_pid"].nunique()),
            }
            figures.setdefault(f"jobs{jobs}_all_walls_s", []).append(wall)
            best = figures.get(f"jobs{jobs}")
            if best is None or wall < best["sweep_wall_s"]:
                figures[f"jobs{jobs}"] = entry
    figures["load_average_after"] = os.getloadavg()
    figures["speedup"] = figures["jobs1"]["sweep_wall_s"] / figures["jobs2"]["sweep_wall_s"]
    return figures


def format_figures(f: dict[str, Any]) -> str:
    one, two = f["jobs1"], f["jobs2"]
    rows = [
        ("runs (paper scenario, trigger off, equal work)", f"{f['runs']} x {f['steps']} instants"),
        ("mean simulation time of a run (1 worker)", f"{one['run_mean_s']:.2f} s"),
        ("sweep wall time, 1 worker", f"{one['sweep_wall_s']:.2f} s"),
        ("sweep wall time, 2 workers", f"{two['sweep_wall_s']:.2f} s"),
        ("speed-up, 2 workers over 1", f"{f['speedup']:.2f}x"),
        (
            "machinery overhead per run, 1 worker",
            f"{1e3 * one['overhead_per_run_s']:.0f} ms "
            f"({100 * one['overhead_fraction']:.2f} % of a run)",
        ),
        (
            "same, 2 workers (incl. idle tail, shared cores)",
            f"{1e3 * two['overhead_per_run_s']:.0f} ms "
            f"({100 * two['overhead_fraction']:.2f} % of a run)",
        ),
        (
            "worker start-up (imports + kernel cache), once per worker",
            f"{two['first_run_in_worker_s']:.2f} s",
        ),
    ]
    rows.append(
        (
            "load average before / after (1 min; other work on the machine)",
            f"{f['load_average_before'][0]:.2f} / {f['load_average_after'][0]:.2f}",
        )
    )
    if f["repeat"] > 1:
        walls = ", ".join(
            f"{jobs} worker(s): " + " ".join(f"{w:.1f}" for w in f[f"jobs{jobs}_all_walls_s"])
            for jobs in (1, 2)
        )
        rows.append((f"all {f['repeat']} repetitions, wall s (best is used)", walls))
    width = max(len(r[0]) for r in rows)
    lines = [f"| {'measurement':<{width}} | value |", f"|{'-' * (width + 2)}|-------|"]
    lines += [f"| {name:<{width}} | {value} |" for name, value in rows]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.scaling",
        description=__doc__.splitlines()[0],
    )
    parser.add_argument("--runs", type=int, default=8, help="runs in the fixed sweep (default 8)")
    parser.add_argument(
        "--steps", type=int, default=240, help="instants per run (default 240, the paper's)"
    )
    parser.add_argument(
        "--repeat", type=int, default=1, help="alternate 1 and 2 workers N times, keep the best"
    )
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    figures = measure(runs=args.runs, steps=args.steps, repeat=args.repeat)
    print(format_figures(figures))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
