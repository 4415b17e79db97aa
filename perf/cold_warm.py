"""Cold and warm: each command and each optimiser's first run, on an empty numba cache and again.

Run ``python -m perf.cold_warm`` from a checkout (``--json FILE`` keeps the figures). Every
figure comes from a fresh process, as a user starts it:

- **commands**: ``run`` (the modified BSO), ``reproduce``, ``score`` (the modified BSO on the
  test split), a small ``sweep`` on two workers (``--suite`` names another, e.g.
  ``comparison``) and a short ``tune``; each first with ``NUMBA_CACHE_DIR`` pointing at a new
  empty folder (cold), then again on the cache that run filled (warm);
- **optimisers**: ``run --optimizer NAME --no-figures`` of the paper scenario for each
  registered optimiser (by default one per group of optimisers that compile the same kernels,
  and each that compiles none; ``--optimizers`` names others), cold then warm, each on its
  own new cache, so that every cold run also compiles the harness, as a new user's first run
  does;
- **compile time**: the CPU time of numba's compile events in the cold process (each event's
  time without that of the events nested in it, summed), beside its wall time.

The targets checked beside the figures are the project's: a cold ``reproduce`` within 2x its
warm time, an optimiser's cold first run within 3 s of its warm run, a cold sweep within 1.3x
the warm one. A cold run's wall time includes the compile, the import of numba and the
command's own work; a warm run loads every kernel from the cache. The machine may be busy:
the load average is printed with the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

COMMANDS = ("run", "reproduce", "score", "sweep", "tune")
"""The commands measured (:func:`command_lines`)."""
RUN_TARGET_S = 3.0
"""An optimiser's cold first run may take at most this many seconds more than its warm run."""
COMMAND_TARGETS = {"reproduce": 2.0, "sweep comparison": 1.3}
"""Commands with a target: the cold wall time over the warm one at most this (a sweep's is for
the ``comparison`` suite, ``--suite comparison``; the small default sweep is mostly compile)."""

# A command in a child process that reports, on its last stderr line, the CPU seconds of
# numba's compile events (each event's time without the events nested in it, summed).
COMPILE_PROBE = """
import json, sys, time
from numba.core import event
from formation_bench.cli.main import main

class Exclusive(event.Listener):
    def __init__(self):
        self.stack, self.seconds, self.count = [], 0.0, 0
    def on_start(self, ev):
        self.stack.append([time.process_time(), 0.0])
    def on_end(self, ev):
        start, nested = self.stack.pop()
        spent = time.process_time() - start
        if self.stack:
            self.stack[-1][1] += spent
        self.seconds += spent - nested
        self.count += 1

listener = Exclusive()
event.register("numba:compile", listener)
try:
    code = main(sys.argv[1:])
finally:
    print(json.dumps({"compile_cpu_s": listener.seconds, "compiles": listener.count}),
          file=sys.stderr)
raise SystemExit(code)
"""

SMALL_SWEEP = """\
name = "cold-warm"
seeds = 4
triggers = [true]

[[optimizers]]
name = "modified-bso"

[[optimizers]]
name = "pso"

[[scenarios]]
name = "paper"
"""
"""The default sweep: two optimisers, four seeds each, on two workers."""


@dataclass(frozen=True)
class ColdWarm:
    """One command measured cold and then warm."""

    what: str
    """The command, or the optimiser whose first run it is."""
    cold_s: float
    """Wall time on an empty numba cache."""
    warm_s: float
    """Wall time on the cache the cold run filled."""
    compile_cpu_s: float
    """CPU time of numba's compile events in the cold process (the command's own process:
    a sweep's workers are not counted)."""
    compiles: int
    """Numba's compile events in that process."""

    @property
    def excess_s(self) -> float:
        return self.cold_s - self.warm_s

    @property
    def ratio(self) -> float:
        return self.cold_s / self.warm_s


def _cli() -> list[str]:
    return [sys.executable, "-c", COMPILE_PROBE]


def timed(args: list[str], cache: Path) -> tuple[float, dict[str, float]]:
    """Wall seconds of one child process on numba cache ``cache``, and what the probe said."""
    start = time.perf_counter()
    done = subprocess.run(
        args,
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, "NUMBA_CACHE_DIR": str(cache)},
    )
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed:\n{done.stderr[-3000:]}")
    return wall, json.loads(done.stderr.strip().splitlines()[-1])


def cold_then_warm(what: str, command: list[str], work: Path) -> ColdWarm:
    """``formation-bench COMMAND`` on a new empty cache, then again on it. A results folder
    that a second run would resume rather than recompute (a sweep's, a score's, a tuning's:
    a command without ``--overwrite``) is removed before each run."""
    cache = Path(tempfile.mkdtemp(prefix="numba-cache-", dir=work))
    walls, probes = [], []
    for _ in range(2):
        if "--out" in command and "--overwrite" not in command:
            out = Path(command[command.index("--out") + 1])
            if out.exists():
                _remove(out, work)
        wall, probe = timed([*_cli(), *command], cache)
        walls.append(wall)
        probes.append(probe)
    cold = probes[0]
    return ColdWarm(what, walls[0], walls[1], cold["compile_cpu_s"], int(cold["compiles"]))


def command_lines(work: Path, suite: str | None) -> dict[str, list[str]]:
    """The commands measured, each writing into ``work`` (``--overwrite`` where a second run
    would otherwise be refused)."""
    sweep_suite = suite
    if sweep_suite is None:
        sweep_suite = str(work / "cold-warm.toml")
        Path(sweep_suite).write_text(SMALL_SWEEP)
    return {
        "run": ["run", "--optimizer", "modified-bso", "--no-figures", "--no-progress",
                "--out", str(work / "run"), "--overwrite"],
        "reproduce": ["reproduce", "--out", str(work / "reproduce"), "--overwrite",
                      "--no-progress"],
        "score": ["score", "--optimizer", "modified-bso", "--budgets", "default", "--seeds", "0",
                  "--library", "v2", "--split", "test", "--out", str(work / "score"),
                  "--jobs", "1"],
        "sweep": ["sweep", sweep_suite, "--out", str(work / "sweep"), "--jobs", "2",
                  "--no-progress"],
        "tune": ["tune", "--optimizer", "pso", "--objective", "solve", "--trials", "8",
                 "--out", str(work / "tune"), "--jobs", "1", "--no-progress"],
    }  # fmt: skip


def _remove(path: Path, work: Path) -> None:
    """Delete a results folder this benchmark made under ``work`` (nothing else)."""
    if work.resolve() not in path.resolve().parents:
        raise RuntimeError(f"refusing to delete {path}: not under {work}")
    shutil.rmtree(path)


def measure_commands(names: Sequence[str], work: Path, suite: str | None) -> list[ColdWarm]:
    lines = command_lines(work, suite)
    results = []
    for name in names:
        what = f"sweep {suite}" if name == "sweep" and suite is not None else name
        results.append(cold_then_warm(what, lines[name], work))
        print(_row(results[-1], command=True), flush=True)
    return results


def measure_optimizers(names: Sequence[str], work: Path) -> list[ColdWarm]:
    results = []
    for name in names:
        command = ["run", "--optimizer", name, "--no-figures", "--no-progress",
                   "--out", str(work / "runs" / name), "--overwrite"]  # fmt: skip
        results.append(cold_then_warm(name, command, work))
        print(_row(results[-1]), flush=True)
    return results


def default_optimizers() -> list[str]:
    """One registered optimiser per group of optimisers that compile the same kernels (the
    shortest name of each, by :meth:`~formation_bench.optimizers.Optimizer.compiled_kernels`),
    and every one that compiles none (its first run builds other things), but
    :data:`SLOW_ADAPTERS`."""
    from formation_bench.optimizers import get_optimizer, optimizer_names

    groups: dict[tuple[object, ...], list[str]] = {}
    names = []
    for name in optimizer_names():
        if name.startswith(SLOW_ADAPTERS):
            continue
        kernels = get_optimizer(name).compiled_kernels()
        if kernels:
            groups.setdefault(kernels, []).append(name)
        else:
            names.append(name)
    # the group's plainest name: its shortest
    names += [min(group, key=lambda n: (len(n), n)) for group in groups.values()]
    return sorted(names)


SLOW_ADAPTERS = ("ng-",)
"""Left out by default: nevergrad's optimisers take 0.3-0.9 s a solve, so their warm run alone
takes 5-15 minutes (they compile nothing of their own; ``--optimizers`` still takes them)."""


HEADER = (
    "| what | cold wall | warm wall | cold - warm | cold / warm | compile CPU (events) | target |\n"
    "|---|---|---|---|---|---|---|"
)


def _target(row: ColdWarm, command: bool) -> str:
    if command:
        limit = COMMAND_TARGETS.get(row.what)
        if limit is None:
            return ""
        return f"{'met' if row.ratio <= limit else 'missed'} (<= {limit:g}x)"
    return f"{'met' if row.excess_s <= RUN_TARGET_S else 'missed'} (<= {RUN_TARGET_S:g} s)"


def _row(row: ColdWarm, command: bool = False) -> str:
    return (
        f"| {'`' + row.what + '`' if command else row.what} | {row.cold_s:.1f} s | "
        f"{row.warm_s:.1f} s | {row.excess_s:.1f} s | {row.ratio:.1f}x | "
        f"{row.compile_cpu_s:.1f} s ({row.compiles}) | {_target(row, command)} |"
    )


def format_results(commands: list[ColdWarm], optimizers: list[ColdWarm]) -> str:
    lines = []
    if commands:
        lines += ["Commands:", "", HEADER, *[_row(r, command=True) for r in commands], ""]
    if optimizers:
        met = sum(r.excess_s <= RUN_TARGET_S for r in optimizers)
        lines += [
            "First run of each optimiser (`run --optimizer NAME --no-figures`):",
            "",
            HEADER,
            *[_row(r) for r in optimizers],
            "",
            f"within {RUN_TARGET_S:g} s of the warm run: {met} of {len(optimizers)}; "
            f"compile CPU summed: {sum(r.compile_cpu_s for r in optimizers):.0f} s",
        ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.cold_warm",
        description="Cold (empty numba cache) and warm wall time of each command and each "
        "optimiser's first run, and numba's compile time in them.",
    )
    parser.add_argument(
        "--commands", nargs="*", default=None, metavar="COMMAND",
        help="commands to measure: run, reproduce, score, sweep, tune (default: all; none "
        "with the option alone)",
    )  # fmt: skip
    parser.add_argument(
        "--optimizers", nargs="*", default=None, metavar="NAME",
        help="optimisers whose first run to measure (default: one per group compiling the "
        "same kernels, and each compiling none; none with the option alone)",
    )  # fmt: skip
    parser.add_argument("--suite", help="the sweep's suite (default: a small one, two workers)")
    parser.add_argument("--json", type=Path, help="also write the figures as JSON")
    args = parser.parse_args(argv)
    commands = list(COMMANDS) if args.commands is None else args.commands
    unknown = sorted(set(commands) - set(COMMANDS))
    if unknown:
        parser.error(f"--commands: unknown {', '.join(unknown)}; allowed: {', '.join(COMMANDS)}")
    names = default_optimizers() if args.optimizers is None else args.optimizers
    from formation_bench.optimizers import optimizer_names

    missing = sorted(set(names) - set(optimizer_names()))
    if missing:
        parser.error(f"--optimizers: not registered: {', '.join(missing)}")
    print(
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
        f"load average {os.getloadavg()[0]:.2f}",
        flush=True,
    )
    with tempfile.TemporaryDirectory(prefix="cold-warm-") as folder:
        work = Path(folder)
        measured_commands = measure_commands(commands, work, args.suite)
        measured_optimizers = measure_optimizers(names, work)
    print()
    print(format_results(measured_commands, measured_optimizers))
    if args.json is not None:
        args.json.write_text(
            json.dumps(
                {
                    "load_average": os.getloadavg(),
                    "commands": [asdict(r) for r in measured_commands],
                    "optimizers": [asdict(r) for r in measured_optimizers],
                },
                indent=2,
            )
            + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
