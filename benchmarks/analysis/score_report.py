"""The report of score runs: gaps to the best-known optima and the runtime statistics.

Per optimiser and budget, over every (instance, seed) trial: the relative gap to ``J*``
(median, IQR, bootstrap 95 % CI of the median), success rates at 1e-2, 1e-3 and 1e-4,
COCO's expected running time to each target, the shifted geometric mean of solve time with
failures (final gap above 1e-3) charged at the slowest solve at the same budget, and the
Dolan-More performance profile of solve time over the instances (a failure never counts).
Files: ``score.md``, ``score_summary.csv``, ``score_ert.csv``, ``score_profile.csv`` and,
with figures, ``figures/score_ecdf.png`` (targets reached against evaluations) and
``figures/score_profile.png``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from formation_bench.benchmarks.analysis import stats
from formation_bench.benchmarks.analysis.scoring import (
    SUCCESS_TARGETS,
    TARGETS,
    expected_running_time,
    performance_profile,
    runtime_ecdf,
    shifted_geometric_mean,
    success_rate,
)
from formation_bench.benchmarks.experiments.score import target_column

FAILURE_GAP = 1e-3
"""A trial whose final gap is above this failed (for the time statistics)."""
TIME_SHIFT_S = 1e-3
"""Shift of the geometric mean of solve times, s (about a tenth of a typical solve)."""
PROFILE_TAUS = np.array([1, 1.5, 2, 3, 5, 10, 20, 50, 100], dtype=float)
"""Factors of the performance profile."""

GROUP = ["optimizer", "budget"]


def summary_table(scores: pd.DataFrame) -> pd.DataFrame:
    """One row per optimiser and budget: gap statistics, success rates, solve time."""
    # a failure is charged at the slowest solve of any optimiser at the same budget
    slowest = scores.groupby("budget")["seconds"].max()
    rows = []
    for (optimizer, budget), trials in scores.groupby(GROUP, sort=False):
        gaps = trials["gap"].to_numpy()
        gap = stats.describe(gaps)
        failed = gaps > FAILURE_GAP
        rows.append(
            {
                "optimizer": optimizer,
                "budget": budget,
                "trials": len(trials),
                "gap_median": gap.median,
                "gap_q1": gap.q1,
                "gap_q3": gap.q3,
                "gap_ci_low": gap.ci_low,
                "gap_ci_high": gap.ci_high,
                **{f"success_{t:.0e}": success_rate(gaps, t) for t in SUCCESS_TARGETS},
                "nfev_median": float(trials["nfev"].median()),
                "solve_time_median_s": float(trials["seconds"].median()),
                "solve_time_sgm_s": shifted_geometric_mean(
                    trials["seconds"].to_numpy(), TIME_SHIFT_S, failed, charge=slowest[budget]
                ),
            }
        )
    return pd.DataFrame(rows).sort_values(["budget", "gap_median"], ignore_index=True)


def ert_table(scores: pd.DataFrame) -> pd.DataFrame:
    """COCO's expected running time (evaluations) per optimiser, budget and target."""
    rows = []
    for (optimizer, budget), trials in scores.groupby(GROUP, sort=False):
        used = trials["nfev"].to_numpy(dtype=float)
        for target in TARGETS:
            hits = trials[target_column(target)].to_numpy(dtype=float)
            rows.append(
                {
                    "optimizer": optimizer,
                    "budget": budget,
                    "target": target,
                    "successes": int(np.isfinite(hits).sum()),
                    "ert_evaluations": expected_running_time(hits, used),
                }
            )
    return pd.DataFrame(rows)


def profile_table(scores: pd.DataFrame) -> pd.DataFrame:
    """Performance profile of solve time per budget (mean over seeds per instance)."""
    frames = []
    for budget, trials in scores.groupby("budget", sort=False):
        timed = trials.assign(
            time=np.where(trials["gap"] <= FAILURE_GAP, trials["seconds"], np.inf)
        )
        per_instance = timed.groupby(["instance", "optimizer"])["time"].mean().unstack()
        profile = performance_profile(per_instance, PROFILE_TAUS)
        frames.append(profile.reset_index().melt("tau", var_name="optimizer", value_name="share"))
        frames[-1].insert(0, "budget", budget)
    return pd.concat(frames, ignore_index=True)


def ecdf_curves(scores: pd.DataFrame, points: int = 40) -> pd.DataFrame:
    """Share of (trial, target) pairs reached against evaluations, per optimiser and budget."""
    top = max(float(scores["nfev"].max()), 10.0)
    budgets = np.unique(np.geomspace(1, top, points).round())
    columns = [target_column(t) for t in TARGETS]
    rows = []
    for (optimizer, budget), trials in scores.groupby(GROUP, sort=False):
        shares = runtime_ecdf(trials[columns].to_numpy(dtype=float), budgets)
        rows += [
            {"optimizer": optimizer, "budget": budget, "evaluations": b, "share": s}
            for b, s in zip(budgets, shares, strict=True)
        ]
    return pd.DataFrame(rows)


def to_markdown(summary: pd.DataFrame, library: str) -> str:
    """The summary as the leaderboard: per budget, optimisers by median gap."""
    lines = [
        f"# Score on the instance library {library}",
        "",
        f"Gap: (cost - J*) / J*, per (instance, seed) trial. Success: final gap <= target. "
        f"Solve time: median, and shifted geometric mean (shift {TIME_SHIFT_S * 1e3:g} ms) with "
        f"trials whose gap is above {FAILURE_GAP:g} charged at the slowest solve at the same "
        "budget.",
        "",
    ]
    for budget, rows in summary.groupby("budget", sort=False):
        lines += [
            f"## budget {budget}",
            "",
            "| optimizer | trials | median gap [95 % CI] | IQR | success 1e-2 | 1e-3 | 1e-4 "
            "| median evaluations | solve time median (ms) | sgm, failures charged (ms) |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for _, r in rows.iterrows():
            lines.append(
                f"| {r['optimizer']} | {r['trials']} | {r['gap_median']:.3g} "
                f"[{r['gap_ci_low']:.3g}, {r['gap_ci_high']:.3g}] | "
                f"{r['gap_q1']:.3g} - {r['gap_q3']:.3g} | {r['success_1e-02']:.0%} | "
                f"{r['success_1e-03']:.0%} | {r['success_1e-04']:.0%} | {r['nfev_median']:.0f} "
                f"| {1e3 * r['solve_time_median_s']:.2f} | {1e3 * r['solve_time_sgm_s']:.1f} |"
            )
        lines.append("")
    return "\n".join(lines)


def write_score_report(scores: pd.DataFrame, folder: Path, *, figures: bool = True) -> str:
    """Write every score file into ``folder``; returns the Markdown leaderboard."""
    folder.mkdir(parents=True, exist_ok=True)
    summary = summary_table(scores)
    summary.to_csv(folder / "score_summary.csv", index=False)
    ert_table(scores).to_csv(folder / "score_ert.csv", index=False)
    profile = profile_table(scores)
    profile.to_csv(folder / "score_profile.csv", index=False)
    markdown = to_markdown(summary, ", ".join(sorted(scores["library"].unique())))
    (folder / "score.md").write_text(markdown)
    if figures:
        _figures(scores, profile, folder / "figures")
    return markdown


def _figures(scores: pd.DataFrame, profile: pd.DataFrame, folder: Path) -> None:
    import matplotlib.pyplot as plt

    from formation_bench.benchmarks.analysis.figures import score_ecdf_figure, score_profile_figure

    folder.mkdir(parents=True, exist_ok=True)
    for name, figure in (
        ("score_ecdf.png", score_ecdf_figure(ecdf_curves(scores))),
        ("score_profile.png", score_profile_figure(profile)),
    ):
        figure.savefig(folder / name, dpi=120)
        plt.close(figure)
