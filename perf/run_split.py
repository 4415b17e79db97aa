"""Where a closed-loop run's time goes: the solves, the loop around them, and the rest.

Run ``python -m perf.run_split`` (``--optimizers pso,cma-es``, ``--seeds 5``). For each
optimiser it carries out runs of the ``comparison`` suite (the paper scenario with the trigger,
1200 evaluations per solve) in this process, through :func:`~formation_bench.pipeline.runner.
execute`, the one path every run takes, after one run that loads the kernels; then it splits
each run's wall time with what the run records:

- **solves**: the sum of the logged solve times (the problem's set-up, the optimiser's
  ``minimize`` and the plan it returns);
- **loop bookkeeping**: the closed loop's time (the trace's wall time) less the solves: the
  links, the estimates, the trigger, the plant, the log;
- **outside the loop**: the run's time (the record's ``run_time_s``) less the loop's: building
  the run, the metrics, the record.

Medians over the seeds, in milliseconds per run; the last row sums the suite's configurations
times its seeds (the CPU time a sweep spends inside its runs). Keep the machine quiet for
comparable numbers; ``--json FILE`` keeps them.
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import numpy as np

from formation_bench.experiments.suite import load_suite
from formation_bench.pipeline.runner import execute
from formation_bench.pipeline.spec import RunSpec

PARTS = ("run", "solves", "loop bookkeeping", "outside the loop")
"""The columns, in milliseconds per run."""


def split(label_runs: list[RunSpec], seeds: int) -> dict[str, float]:
    """Median milliseconds per run of each of :data:`PARTS` over the first ``seeds`` runs."""
    execute(label_runs[0])  # loads the optimiser's kernels from numba's cache
    rows = []
    for spec in label_runs[:seeds]:
        outcome = execute(spec)
        run_s = outcome.record.provenance.run_time_s
        loop_s = outcome.trace.wall_time_s
        solves_s = float(np.nansum(outcome.trace.solve_time_s))
        rows.append((run_s, solves_s, loop_s - solves_s, run_s - loop_s))
    return dict(zip(PARTS, (1000 * np.median(rows, axis=0)).tolist(), strict=True))


def measure(optimizers: list[str] | None, seeds: int) -> dict[str, dict[str, float]]:
    """:func:`split` of every configuration of the ``comparison`` suite (or those named)."""
    suite = load_suite("comparison")
    by_label: dict[str, list[RunSpec]] = {}
    for spec in suite.runs():
        by_label.setdefault(spec.optimizer_label, []).append(spec)
    unknown = sorted(set(optimizers or ()) - set(by_label))
    if unknown:
        raise SystemExit(f"--optimizers: not in the comparison suite: {', '.join(unknown)}")
    return {label: split(by_label[label], seeds) for label in optimizers or by_label}


def table(figures: dict[str, dict[str, float]], suite_seeds: int) -> str:
    """The figures as a Markdown table, with the suite's total in seconds."""
    lines = [
        "| optimiser | " + " | ".join(f"{part}, ms" for part in PARTS) + " |",
        "|---|" + "---:|" * len(PARTS),
    ]
    for label, row in figures.items():
        lines.append(f"| {label} | " + " | ".join(f"{row[p]:.1f}" for p in PARTS) + " |")
    totals = [suite_seeds * sum(row[p] for row in figures.values()) / 1000 for p in PARTS]
    lines.append(
        f"| all x {suite_seeds} seeds, s | " + " | ".join(f"{t:.1f}" for t in totals) + " |"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.run_split",
        description="Split closed-loop runs of the comparison suite into solves, loop and rest.",
    )
    parser.add_argument("--optimizers", help="comma-separated configurations (default: all)")
    parser.add_argument("--seeds", type=int, default=3, help="runs per configuration (3)")
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error(f"--seeds must be at least 1, got {args.seeds}")
    names = args.optimizers.split(",") if args.optimizers else None
    figures = measure(names, args.seeds)
    print(table(figures, len(load_suite("comparison").seeds)))
    if args.json:
        args.json.write_text(
            json.dumps({"machine": platform.processor() or platform.machine(), "runs": figures})
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
