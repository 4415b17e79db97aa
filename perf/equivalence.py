"""Are two sweeps of one suite, by two versions of the code, statistically the same?

Run ``python -m perf.equivalence BEFORE AFTER`` on two results folders of the same suite
(``formation-bench sweep paper --out BEFORE`` with one version installed, then with the
other). A change that rounds differently (the fused cost kernel, for instance) moves
single runs; this checks that it moves no metric as a whole. Runs are paired by
scenario, optimiser, budget, trigger and seed; for every metric and every group of the
other factors it prints:

- the medians before and after, how many pairs are lower, higher and tied after;
- the two-sided Wilcoxon signed-rank p of the paired differences, Holm-adjusted over all
  rows (a difference);
- the 90 % bootstrap interval of the mean paired difference, and whether it lies inside
  +-``--margin-sd`` seed-to-seed standard deviations of the metric before (an equivalence
  test in the two one-sided tests' sense at 5 %; 0.2 by default, a small effect).

The machine-speed metrics (solve and wall times) are left out: they measure the machine.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from formation_bench.analysis.comparison import metric_columns, prepare
from formation_bench.analysis.stats import holm_family, paired_comparison
from formation_bench.experiments.store import load_results

PAIRING = ["scenario", "optimizer", "budget", "trigger", "seed"]
GROUPS = ["scenario", "optimizer", "budget", "trigger"]
MARGIN_SD = 0.2
"""Default equivalence margin, in seed-to-seed standard deviations of the metric before.

A pair whose runs diverged (a rounding flipped one decision, and the rest of the run went
its own way) differs like two independent runs: the 90 % interval of the mean of 30 such
differences is then about +-0.43 standard deviations wide, so with 30 seeds a margin below
that cannot be shown even when nothing changed (``--margin-sd 0.5`` is the usual medium
effect)."""
BOOTSTRAP = 10_000
SPEED_METRICS = ("wall_time_s",)
"""Metrics of the machine's speed, left out besides the solve times."""


def mean_difference_interval(
    difference: np.ndarray, rng: np.random.Generator, level: float = 0.90
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``difference``."""
    means = rng.choice(difference, (BOOTSTRAP, difference.size)).mean(axis=1)
    tail = (1.0 - level) / 2.0
    return float(np.quantile(means, tail)), float(np.quantile(means, 1.0 - tail))


def compare(
    before: pd.DataFrame, after: pd.DataFrame, seed: int = 0, margin_sd: float = MARGIN_SD
) -> pd.DataFrame:
    """One row per metric and group: the paired statistics described in the module."""
    before, after = prepare(before), prepare(after)
    metrics = [
        m
        for m in metric_columns(before)
        if m not in SPEED_METRICS and not m.startswith("solve_time")
    ]
    paired = before.merge(after, on=PAIRING, suffixes=("_before", "_after"))
    if paired.empty:
        raise SystemExit("no runs pair up: are both folders sweeps of the same suite?")
    rng = np.random.default_rng(seed)
    rows = []
    for group, runs in paired.groupby(GROUPS, sort=True):
        for metric in metrics:
            x = runs[f"{metric}_after"].to_numpy(np.float64)
            y = runs[f"{metric}_before"].to_numpy(np.float64)
            keep = np.isfinite(x) & np.isfinite(y)
            x, y = x[keep], y[keep]
            if x.size == 0:
                continue
            row = dict(zip(GROUPS, group, strict=True))
            row["metric"] = metric
            row.update(paired_comparison(x, y))
            spread = float(np.std(y, ddof=1)) if y.size > 1 else 0.0
            low, high = mean_difference_interval(x - y, rng) if np.any(x != y) else (0.0, 0.0)
            margin = margin_sd * spread
            row.update(
                interval_low=low,
                interval_high=high,
                margin=margin,
                equivalent=bool(-margin <= low and high <= margin) or bool(np.all(x == y)),
            )
            rows.append(row)
    holm_family(rows)
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("before", type=Path, help="results folder of the sweep before")
    parser.add_argument("after", type=Path, help="results folder of the same sweep after")
    parser.add_argument("--csv", type=Path, help="also write the table to this CSV file")
    parser.add_argument(
        "--margin-sd", type=float, default=MARGIN_SD,
        help=f"equivalence margin in standard deviations of the metric before ({MARGIN_SD})",
    )  # fmt: skip
    args = parser.parse_args(argv)
    if not args.margin_sd > 0:
        parser.error(f"--margin-sd must be a positive number, got {args.margin_sd}")
    table = compare(load_results(args.before), load_results(args.after), margin_sd=args.margin_sd)
    if args.csv:
        table.to_csv(args.csv, index=False)
    shown = table.rename(columns={"x_median": "after", "y_median": "before",
                                  "x_lower": "lower", "x_higher": "higher"})  # fmt: skip
    columns = ["trigger", "optimizer", "metric", "before", "after", "lower", "higher", "ties",
               "p_holm", "interval_low", "interval_high", "margin", "equivalent"]  # fmt: skip
    with pd.option_context("display.width", 200, "display.max_rows", 500):
        print(shown[columns].to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    significant = int(table["significant"].sum())
    equivalent = int(table["equivalent"].sum())
    print(
        f"\n{len(table)} metric rows: {significant} differ significantly (Holm, 5 %), "
        f"{equivalent} equivalent within +-{args.margin_sd} SD (90 % bootstrap interval); "
        f"{int(((table['x_lower'] + table['x_higher']) > 0).sum())} with any run moved"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
