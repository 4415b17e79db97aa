"""Start-up benchmark of the ``formation-bench`` commands.

Run ``python -m perf.startup`` (add ``--json FILE`` to keep the
figures, ``--quick`` for one repeat of each). Every figure comes from fresh processes, as a
user starts them:

- **imports**: wall and CPU time of ``formation-bench --help`` and ``list`` (which do little
  besides importing), and the heavy libraries each command leaves in ``sys.modules`` (``run
  --no-figures`` included);
- **warm run overhead**: ``run --no-figures --no-trigger`` of the paper scenario with the
  modified BSO (720 solves) on a filled numba cache: the command's wall time over the sum of
  its ``solve_times_s`` (each solve's problem build and optimiser), repeated;
- **cold start**: the same run with ``NUMBA_CACHE_DIR`` pointing at a new empty folder, its
  wall time, and the compile time of each kernel, read in a separate process from numba's
  compile events (exclusive of the kernels compiled inside it; CPU time, which other
  processes on the machine disturb less than wall time);
- **reproduce**: ``formation-bench reproduce`` on a warm and on a cold cache.

The machine may be shared: each figure is reported as the median and the range over the
repeats, with the CPU time (user + system of the child) beside the wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HEAVY_MODULES = (
    "matplotlib",
    "seaborn",
    "scipy.stats",
    "sklearn",
    "casadi",
    "osqp",
    "joblib",
    "pandas",
    "pyarrow",
    "tqdm",
    "numba",
)
"""Libraries whose import costs a noticeable share of a command's start."""

RUN = ["run", "--optimizer", "modified-bso", "--no-trigger", "--no-figures", "--seed", "0"]
"""The run whose overhead is measured: the paper scenario, 720 solves, no figures."""

# A command run in a child process, followed by the heavy modules it imported (on stderr, so
# that the command's own output on stdout stays untouched).
MODULES_PROBE = """
import json, sys
from formation_bench.cli.main import main
try:
    code = main(sys.argv[2:])
except SystemExit as stop:  # --help
    code = stop.code
heavy = json.loads(sys.argv[1])
print(json.dumps(sorted(m for m in heavy if m in sys.modules)), file=sys.stderr)
raise SystemExit(code)
"""

# The compile time of every kernel a command compiles, from numba's compile events: each
# event's CPU time minus that of the events nested in it (kernels compiled while typing it).
COMPILE_PROBE = """
import json, sys, time
from numba.core import event
from formation_bench.cli.main import main

class Exclusive(event.Listener):
    def __init__(self):
        self.stack, self.seconds = [], {}
    def on_start(self, ev):
        self.stack.append([time.process_time(), 0.0])
    def on_end(self, ev):
        start, nested = self.stack.pop()
        spent = time.process_time() - start
        if self.stack:
            self.stack[-1][1] += spent
        func = getattr(ev.data["dispatcher"], "py_func", None)
        name = f"{func.__module__}.{func.__qualname__}" if func else "?"
        self.seconds[name] = self.seconds.get(name, 0.0) + spent - nested

listener = Exclusive()
event.register("numba:compile", listener)
main(sys.argv[1:])
print(json.dumps(listener.seconds), file=sys.stderr)
"""


def _command() -> list[str]:
    return [sys.executable, "-m", "formation_bench.cli.main"]


def timed(args: list[str], env: dict[str, str] | None = None) -> dict[str, Any]:
    """Wall and CPU seconds (user + system) of one child process; its stderr too."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(
        args, capture_output=True, text=True, env={**os.environ, **(env or {})}, check=False
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed:\n{done.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "stderr": done.stderr}


def spread(values: list[float]) -> dict[str, float]:
    """Median, smallest and largest of repeated measurements."""
    return {"median": statistics.median(values), "min": min(values), "max": max(values)}


def modules_loaded(command: list[str]) -> list[str]:
    """The :data:`HEAVY_MODULES` that ``formation-bench COMMAND`` leaves imported."""
    probe = [sys.executable, "-c", MODULES_PROBE, json.dumps(HEAVY_MODULES), *command]
    return json.loads(timed(probe)["stderr"].strip().splitlines()[-1])


def import_times(repeats: int) -> dict[str, Any]:
    """``--help`` and ``list``: wall and CPU seconds over ``repeats`` fresh processes."""
    results: dict[str, Any] = {}
    for command in (["--help"], ["list"]):
        runs = [timed([*_command(), *command]) for _ in range(repeats)]
        results[" ".join(command)] = {
            "wall_s": spread([r["wall_s"] for r in runs]),
            "cpu_s": spread([r["cpu_s"] for r in runs]),
        }
    return results


def run_once(out: Path, env: dict[str, str] | None = None) -> dict[str, float]:
    """One :data:`RUN` in a fresh process: its wall and CPU time and the sum of its solves."""
    measured = timed([*_command(), *RUN, "--out", str(out), "--overwrite"], env)
    (record,) = json.loads((out / "metrics.json").read_text())
    solves = sum(record["solve_times_s"])
    return {
        "wall_s": measured["wall_s"],
        "cpu_s": measured["cpu_s"],
        "solve_sum_s": solves,
        "ratio": measured["wall_s"] / solves,
    }


def warm_overhead(repeats: int, work: Path) -> dict[str, Any]:
    """The command's wall time over the sum of its solve times, on a filled numba cache."""
    run_once(work / "fill")  # fills the cache if it is cold
    runs = [run_once(work / "warm") for _ in range(repeats)]
    return {key: spread([r[key] for r in runs]) for key in runs[0]}


def cold_start(repeats: int, work: Path) -> dict[str, Any]:
    """:data:`RUN` on an empty numba cache, and the compile time of each kernel it compiles."""
    runs = []
    for k in range(repeats):
        with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache:
            runs.append(run_once(work / f"cold{k}", {"NUMBA_CACHE_DIR": cache}))
    with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache:
        probe = [sys.executable, "-c", COMPILE_PROBE, *RUN, "--out", str(work / "probe")]
        measured = timed([*probe, "--overwrite"], {"NUMBA_CACHE_DIR": cache})
    kernels = json.loads(measured["stderr"].strip().splitlines()[-1])
    return {
        "wall_s": spread([r["wall_s"] for r in runs]),
        "cpu_s": spread([r["cpu_s"] for r in runs]),
        "compile_cpu_s": sum(kernels.values()),
        "kernels_cpu_s": dict(sorted(kernels.items(), key=lambda kv: -kv[1])),
    }


def reproduce_times(repeats: int, work: Path) -> dict[str, Any]:
    """``formation-bench reproduce`` (two closed loops and the figures), warm and cold."""
    command = [*_command(), "reproduce", "--out", str(work / "reproduce"), "--overwrite"]
    warm = [timed(command) for _ in range(repeats)]
    cold = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory(prefix="numba-cache-") as cache:
            cold.append(timed(command, {"NUMBA_CACHE_DIR": cache}))
    return {
        name: {
            "wall_s": spread([r["wall_s"] for r in runs]),
            "cpu_s": spread([r["cpu_s"] for r in runs]),
        }
        for name, runs in (("warm", warm), ("cold", cold))
    }


def measure(repeats: int = 5, cold_repeats: int = 3) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="startup-") as folder:
        work = Path(folder)
        return {
            "machine": {
                "python": platform.python_version(),
                "processor": platform.processor() or platform.machine(),
                "cpus": os.cpu_count(),
                "load_average": os.getloadavg(),
            },
            "modules": {
                "--help": modules_loaded(["--help"]),
                "list": modules_loaded(["list"]),
                "run --no-figures": modules_loaded(
                    [*RUN, "--out", str(work / "modules"), "--overwrite"]
                ),
            },
            "imports": import_times(repeats),
            "warm_run": warm_overhead(repeats, work),
            "cold_run": cold_start(cold_repeats, work),
            "reproduce": reproduce_times(cold_repeats, work),
        }


def _range(figure: dict[str, float], unit: str = "s") -> str:
    return f"{figure['median']:.2f} {unit} ({figure['min']:.2f}-{figure['max']:.2f})"


def format_results(results: dict[str, Any]) -> str:
    lines = ["| measurement | wall: median (range) | CPU: median (range) |", "|---|---|---|"]
    for command, figure in results["imports"].items():
        lines.append(
            f"| `formation-bench {command}` | {_range(figure['wall_s'])} | "
            f"{_range(figure['cpu_s'])} |"
        )
    warm, cold = results["warm_run"], results["cold_run"]
    lines.append(
        f"| warm `run --no-figures` (720 solves) | {_range(warm['wall_s'])} | "
        f"{_range(warm['cpu_s'])} |"
    )
    lines.append(f"| its solves (sum of solve_times_s) | {_range(warm['solve_sum_s'])} | |")
    lines.append(
        f"| cold `run --no-figures` | {_range(cold['wall_s'])} | {_range(cold['cpu_s'])} |"
    )
    for name, figure in results["reproduce"].items():
        lines.append(
            f"| {name} `reproduce` | {_range(figure['wall_s'])} | {_range(figure['cpu_s'])} |"
        )
    lines.append("")
    lines.append(f"warm run overhead: wall / solve sum = {_range(warm['ratio'], 'x')}")
    lines.append(
        f"cold compile (numba compile events, CPU): {cold['compile_cpu_s']:.2f} s; largest:"
    )
    for name, seconds in list(cold["kernels_cpu_s"].items())[:8]:
        lines.append(f"  {seconds:6.2f} s  {name}")
    lines.append("")
    for command, modules in results["modules"].items():
        lines.append(f"`{command}` imports: {', '.join(modules) or 'none of them'}")
    lines.append(f"load average at the start: {results['machine']['load_average']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.startup",
        description="Start-up time of the formation-bench commands: imports, the warm run's "
        "overhead over its solves, the cold compile, reproduce.",
    )
    parser.add_argument("--repeats", type=int, default=5, help="warm repeats (default 5)")
    parser.add_argument(
        "--cold-repeats", type=int, default=3, help="cold-cache repeats (default 3)"
    )
    parser.add_argument("--quick", action="store_true", help="one repeat of each")
    parser.add_argument("--json", type=Path, help="also write the figures as JSON")
    args = parser.parse_args(argv)
    repeats, cold_repeats = (1, 1) if args.quick else (args.repeats, args.cold_repeats)
    if repeats < 1 or cold_repeats < 1:
        parser.error("--repeats and --cold-repeats must be >= 1")
    results = measure(repeats, cold_repeats)
    print(format_results(results))
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
