"""The evaluation budget the paper's precision takes.

A *seed* of an optimiser at a budget is its pair of runs on the paper scenario, with and
without the trigger: the paper's 11 figures (:data:`~.paper.PAPER_FIGURES`) span both. The
budget the paper needs is the smallest per-solve evaluation budget at which all 11 hold on at
least :data:`REQUIRED_SHARE` of the seeds (9 of 10), in each :class:`~.paper.Reading` (errors
counted from the 10 s settle time, or from each run's own settling time). The shipped suite
``paper-budget`` runs the grid; ``formation-bench report`` writes the tables; the per-run
values of one such sweep ship with the package (:data:`SHIPPED_RUNS`) so ``reproduce`` can
name the budget without running anything.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from formation_bench.benchmarks.analysis.paper import PAPER_FIGURES, PaperFigure, Reading

REQUIRED_SHARE = 0.9
"""Share of seeds on which every figure must hold (9 of 10)."""

SHIPPED_RUNS = Path(__file__).parent / "data" / "paper_budget_runs.csv"
"""The per-run figure values of the shipped ``paper-budget`` sweep (see docs/benchmarks.md)."""

KEYS = ("optimizer", "budget", "budget_max_evaluations", "seed", "trigger")
"""The columns that say which run a row is."""


def figure_columns() -> list[str]:
    """Every column the figures read, in both readings, and the settling time."""
    columns = {f.column_for(r): None for f in PAPER_FIGURES for r in Reading}
    return [*columns, "settling_time_s"]


def runs_table(results: pd.DataFrame) -> pd.DataFrame:
    """The rows the analysis needs from a results store: paper-scenario runs, with the run
    keys and the figure columns only (the form of :data:`SHIPPED_RUNS`)."""
    missing = [c for c in (*KEYS, "scenario_name", *figure_columns()) if c not in results]
    if missing:
        raise ValueError(f"the results lack the columns {', '.join(missing)}")
    paper = results[results["scenario_name"] == "paper"]
    if "scenario_overrides" in paper:
        paper = paper[paper["scenario_overrides"] == "{}"]
    table = paper[[*KEYS, *figure_columns()]].copy()
    return table.sort_values(list(KEYS), na_position="first").reset_index(drop=True)


def seed_outcomes(runs: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser, budget, seed and reading: how many of the 11 figures hold and whether
    all do. A seed needs both of its runs (with and without the trigger)."""
    rows = []
    for (optimizer, budget, seed), pair in runs.groupby(
        ["optimizer", "budget", "seed"], sort=False, dropna=False
    ):
        by_trigger = {bool(r["trigger"]): r for _, r in pair.iterrows()}
        if set(by_trigger) != {True, False}:
            continue
        max_evaluations = pair["budget_max_evaluations"].iloc[0]
        for reading in Reading:
            held = sum(f.holds(by_trigger[f.trigger], reading) for f in PAPER_FIGURES)
            rows.append(
                {
                    "optimizer": optimizer,
                    "budget": budget,
                    "max_evaluations": max_evaluations,
                    "seed": seed,
                    "reading": str(reading),
                    "figures_held": held,
                    "all_held": held == len(PAPER_FIGURES),
                }
            )
    return pd.DataFrame(rows)


def figure_short_name(figure: PaperFigure) -> str:
    """E.g. ``trigger d12`` or ``no trigger tracking``: a column header."""
    what = figure.label.split(" (")[0].replace(" error max", "")
    return f"{'trigger' if figure.trigger else 'no trigger'} {what}"


def figure_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser, reading and budget: on how many seeds each figure holds (which figures
    keep a budget from reaching the paper)."""
    rows = []
    for (optimizer, budget), group in runs.groupby(["optimizer", "budget"], sort=False):
        by_trigger = {t: g for t, g in group.groupby("trigger")}
        if set(by_trigger) != {True, False}:
            continue
        for reading in Reading:
            row = {
                "optimizer": optimizer,
                "reading": str(reading),
                "budget": budget_text(budget, group["budget_max_evaluations"].iloc[0]),
                "max_evaluations": group["budget_max_evaluations"].iloc[0],
                "seeds": group["seed"].nunique(),
            }
            for figure in PAPER_FIGURES:
                runs_of = by_trigger[figure.trigger]
                row[figure_short_name(figure)] = sum(
                    figure.holds(r, reading) for _, r in runs_of.iterrows()
                )
            rows.append(row)
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    return table.sort_values(
        ["optimizer", "reading", "max_evaluations"], na_position="first"
    ).reset_index(drop=True)


def budget_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser, budget and reading: seeds, seeds on which all 11 figures hold, the
    median count of figures held, and whether that meets :data:`REQUIRED_SHARE`."""
    outcomes = seed_outcomes(runs)
    if outcomes.empty:
        return pd.DataFrame()
    table = (
        outcomes.groupby(["optimizer", "reading", "budget"], sort=False, dropna=False)
        .agg(
            max_evaluations=("max_evaluations", "first"),
            seeds=("seed", "nunique"),
            seeds_all_held=("all_held", "sum"),
            figures_held_median=("figures_held", "median"),
        )
        .reset_index()
    )
    table["reaches_paper"] = table["seeds_all_held"] >= table["seeds"].map(required_seeds)
    return table.sort_values(
        ["optimizer", "reading", "max_evaluations"], na_position="first"
    ).reset_index(drop=True)


def required_seeds(seeds: int) -> int:
    """Seeds on which every figure must hold, of ``seeds`` (9 of 10)."""
    return math.ceil(REQUIRED_SHARE * seeds - 1e-9)


def budget_text(budget: str, max_evaluations: float) -> str:
    """``4800 evaluations`` for an evaluation budget, else the budget's label."""
    return budget if pd.isna(max_evaluations) else f"{int(max_evaluations)} evaluations"


def smallest_budgets(table: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser and reading: the smallest budget that reaches the paper (None if none
    of the budgets run does) and the largest budget run."""
    rows = []
    for (optimizer, reading), group in table.groupby(["optimizer", "reading"], sort=False):
        reached = group[group["reaches_paper"]]
        first = reached.iloc[0] if len(reached) else None
        rows.append(
            {
                "optimizer": optimizer,
                "reading": reading,
                "smallest_budget": None
                if first is None
                else budget_text(first["budget"], first["max_evaluations"]),
                "seeds_all_held": None if first is None else int(first["seeds_all_held"]),
                "seeds": int(group["seeds"].iloc[-1]),
                "largest_budget_run": budget_text(
                    group["budget"].iloc[-1], group["max_evaluations"].iloc[-1]
                ),
                "seeds_all_held_at_largest": int(group["seeds_all_held"].iloc[-1]),
            }
        )
    return pd.DataFrame(rows)


def to_markdown(
    table: pd.DataFrame, smallest: pd.DataFrame, figures: pd.DataFrame | None = None
) -> str:
    """The report section: the smallest budget per optimiser, every budget's count, and (if
    given) on how many seeds each figure holds."""
    lines = [
        "## The budget the paper needs",
        "",
        f"All 11 of the paper's figures on at least {REQUIRED_SHARE:.0%} of the seeds (a seed: "
        "its runs with and without the trigger). Errors counted from the 10 s settle time "
        "(`settle-time`) or from each run's own settling time (`settling`; a run that does not "
        "settle misses its error figures).",
        "",
        "| optimiser | reading | smallest budget | seeds with all 11 | largest budget run |",
        "|---|---|---|---|---|",
    ]
    for _, row in smallest.iterrows():
        found = f"{row['smallest_budget']}" if pd.notna(row["smallest_budget"]) else "not reached"
        held = (
            f"{row['seeds_all_held']}/{row['seeds']}"
            if pd.notna(row["smallest_budget"])
            else f"{row['seeds_all_held_at_largest']}/{row['seeds']} at the largest"
        )
        lines.append(
            f"| {row['optimizer']} | {row['reading']} | {found} | {held} | "
            f"{row['largest_budget_run']} |"
        )
    lines += [
        "",
        "Seeds with all 11 figures (median figures held) at each budget:",
        "",
        "| optimiser | reading | budget | seeds with all 11 | median figures held |",
        "|---|---|---|---|---|",
    ]
    for _, row in table.iterrows():
        lines.append(
            f"| {row['optimizer']} | {row['reading']} | "
            f"{budget_text(row['budget'], row['max_evaluations'])} | "
            f"{row['seeds_all_held']}/{row['seeds']} | {row['figures_held_median']:g} |"
        )
    if figures is not None and not figures.empty:
        names = [figure_short_name(f) for f in PAPER_FIGURES]
        lines += [
            "",
            "Seeds on which each figure holds (which figures keep a budget from the paper):",
            "",
            "| optimiser | reading | budget | " + " | ".join(names) + " |",
            "|---|---|---|" + "---|" * len(names),
        ]
        for _, row in figures.iterrows():
            cells = [f"{row[n]}/{row['seeds']}" for n in names]
            lines.append(
                f"| {row['optimizer']} | {row['reading']} | {row['budget']} | "
                + " | ".join(cells)
                + " |"
            )
    return "\n".join(lines) + "\n"


def applies(results: pd.DataFrame) -> bool:
    """Whether the results hold paper-scenario pairs of runs at more than one budget."""
    needed = {*KEYS, "scenario_name", *figure_columns()}
    if not needed <= set(results.columns):
        return False
    paper = results[results["scenario_name"] == "paper"]
    return paper["trigger"].nunique() == 2 and paper["budget"].nunique() > 1


def shipped_line(optimizer: str = "modified-bso", path: Path = SHIPPED_RUNS) -> str:
    """One line naming the budget the paper needs for ``optimizer``, read from the shipped
    per-run values (nothing is run)."""
    runs = pd.read_csv(path)
    smallest = smallest_budgets(budget_table(runs))
    mine = smallest[smallest["optimizer"] == optimizer].set_index("reading")
    if mine.empty:
        raise ValueError(f"{path.name} has no runs of {optimizer!r}")
    parts = []
    for reading in Reading:
        row = mine.loc[str(reading)]
        where = (
            "from the 10 s settle time"
            if reading is Reading.SETTLE_TIME
            else ("from each run's settling time")
        )
        if pd.isna(row["smallest_budget"]):
            parts.append(f"not reached up to {row['largest_budget_run']} ({where})")
        else:
            parts.append(f"{row['smallest_budget']} ({where})")
    seeds = int(mine["seeds"].iloc[0])
    return (
        f"The paper's 11 figures on {required_seeds(seeds)} of {seeds} seeds take {optimizer} "
        f"{'; '.join(parts)} per solve (shipped paper-budget sweep; "
        "formation-bench sweep paper-budget recomputes it)."
    )
