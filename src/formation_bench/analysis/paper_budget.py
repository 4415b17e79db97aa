"""The evaluation budget the paper's precision takes.

A *seed* of an optimiser at a budget is its pair of runs on the paper scenario as the paper
sets it (no scenario overrides), with and without the trigger: the paper's 11 figures
(:data:`~.paper.PAPER_FIGURES`) span both. The budget the paper needs is the smallest
per-solve evaluation budget at which the figures hold together on at least
:data:`REQUIRED_SHARE` of the seeds (9 of 10), in each
:class:`~.paper.Reading` (errors counted from the 10 s settle time, or from each run's own
settling time). Two targets are looked for: all 11 figures, and the figures that the exact
solvers (:data:`REFERENCES`) reach themselves; a figure the optimal control of the problem
misses is one no budget can be asked to reach. The shipped suite ``paper-budget`` runs the
grid; ``formation-bench report`` writes the tables; the per-run values of one such sweep ship
with the package (:data:`SHIPPED_RUNS`) so ``reproduce`` names the budget without running
anything.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from formation_bench.analysis.paper import PAPER_FIGURES, PaperFigure, Reading

REQUIRED_SHARE = 0.9
"""Share of seeds on which the figures must hold together (9 of 10)."""

REFERENCES = ("ipopt", "ltv-osqp")
"""Registered names of the exact solvers whose reached figures set the second target."""

SHIPPED_RUNS = Path(__file__).parent / "data" / "paper_budget_runs.csv"
"""The per-run figure values of the shipped ``paper-budget`` sweep (see
docs/explanation/benchmarks.md)."""

KEYS = ("optimizer", "optimizer_name", "budget", "budget_max_evaluations", "seed", "trigger")
"""The columns that say which run a row is."""

ALL = "all 11"
REACHED = "reached by the exact solvers"
TARGETS = (ALL, REACHED)
"""The two sets of figures a budget is asked to reach."""


def figure_short_name(figure: PaperFigure) -> str:
    """E.g. ``trigger d12`` or ``no trigger tracking``: a column header."""
    what = figure.label.split(" (")[0].replace(" error max", "")
    return f"{'trigger' if figure.trigger else 'no trigger'} {what}"


FIGURE_NAMES = tuple(figure_short_name(f) for f in PAPER_FIGURES)


def figure_columns() -> list[str]:
    """Every column the figures read, in both readings, and the settling time."""
    columns = {f.column_for(r): None for f in PAPER_FIGURES for r in Reading}
    return [*columns, "settling_time_s"]


def required_seeds(seeds: int) -> int:
    """Seeds on which the figures must hold, of ``seeds`` (9 of 10)."""
    return math.ceil(REQUIRED_SHARE * seeds - 1e-9)


def budget_text(budget: str, max_evaluations: float) -> str:
    """``4800 evaluations`` for an evaluation budget, else the budget's label."""
    return budget if pd.isna(max_evaluations) else f"{int(max_evaluations)} evaluations"


def missing_columns(results: pd.DataFrame) -> list[str]:
    """The columns the analysis reads that ``results`` lacks."""
    return [c for c in (*KEYS, "scenario_name", *figure_columns()) if c not in results]


def runs_table(results: pd.DataFrame) -> pd.DataFrame:
    """The rows the analysis needs from a results store: runs of the unmodified paper
    scenario, with the run keys and the figure columns only (the form of
    :data:`SHIPPED_RUNS`)."""
    missing = missing_columns(results)
    if missing:
        raise ValueError(f"the results lack the columns {', '.join(missing)}")
    paper = results[results["scenario_name"] == "paper"]
    # the figures bound the paper's own problem: a run with scenario overrides (fewer steps,
    # another settle time, losses) is of another problem, whatever its scenario is named
    if "scenario_overrides" in paper:
        paper = paper[paper["scenario_overrides"] == "{}"]
    table = paper[[*KEYS, *figure_columns()]].copy()
    return table.sort_values(list(KEYS), na_position="first").reset_index(drop=True)


def paired_budgets(runs: pd.DataFrame) -> int:
    """The budgets at which some seed of ``runs`` (a :func:`runs_table`) has its pair of
    runs, with and without the trigger (:func:`seed_outcomes` counts no other seed)."""
    settings = runs.groupby(["optimizer", "budget", "seed"], dropna=False)["trigger"].nunique()
    return settings[settings == 2].index.get_level_values("budget").nunique()


def seed_outcomes(runs: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser, budget, seed and reading: whether each figure holds (a column per
    figure, :data:`FIGURE_NAMES`). A seed needs both of its runs."""
    rows = []
    for (optimizer, budget, seed), pair in runs.groupby(
        ["optimizer", "budget", "seed"], sort=False, dropna=False
    ):
        by_trigger = {bool(r["trigger"]): r for _, r in pair.iterrows()}
        if set(by_trigger) != {True, False}:
            continue
        for reading in Reading:
            row = {
                "optimizer": optimizer,
                "optimizer_name": pair["optimizer_name"].iloc[0],
                "budget": budget,
                "max_evaluations": pair["budget_max_evaluations"].iloc[0],
                "seed": seed,
                "reading": str(reading),
            }
            for figure, name in zip(PAPER_FIGURES, FIGURE_NAMES, strict=True):
                row[name] = figure.holds(by_trigger[figure.trigger], reading)
            rows.append(row)
    return pd.DataFrame(rows)


def _by_budget(outcomes: pd.DataFrame, **columns: tuple[str, str]) -> pd.DataFrame:
    """Seed outcomes grouped per optimiser, reading and budget, ordered by budget."""
    table = (
        outcomes.groupby(["optimizer", "reading", "budget"], sort=False, dropna=False)
        .agg(
            optimizer_name=("optimizer_name", "first"),
            max_evaluations=("max_evaluations", "first"),
            seeds=("seed", "nunique"),
            **columns,
        )
        .reset_index()
    )
    return table.sort_values(
        ["optimizer", "reading", "max_evaluations"], na_position="first"
    ).reset_index(drop=True)


def figure_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser, reading and budget: on how many seeds each figure holds (which figures
    keep a budget from the paper)."""
    outcomes = seed_outcomes(runs)
    if outcomes.empty:
        return outcomes
    return _by_budget(outcomes, **{name: (name, "sum") for name in FIGURE_NAMES})


def reference_figures(figures: pd.DataFrame) -> dict[str, list[str]]:
    """Per reading, the figures that some exact solver (:data:`REFERENCES`) meets on at least
    :data:`REQUIRED_SHARE` of its seeds (no entry without reference runs); ``figures`` is a
    :func:`figure_table`."""
    references = figures[figures["optimizer_name"].isin(REFERENCES)]
    met = references[list(FIGURE_NAMES)].ge(references["seeds"].map(required_seeds), axis=0)
    return {
        reading: [n for n in FIGURE_NAMES if group[n].any()]
        for reading, group in met.groupby(references["reading"], sort=False)
    }


def budget_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser, reading and budget: seeds; seeds on which all 11 figures hold, and on
    which every figure the exact solvers reach holds; the median count of figures held; and
    whether each target is met on :data:`REQUIRED_SHARE` of the seeds."""
    outcomes = seed_outcomes(runs)
    if outcomes.empty:
        return pd.DataFrame()
    reached = reference_figures(
        _by_budget(outcomes, **{name: (name, "sum") for name in FIGURE_NAMES})
    )
    figures = outcomes[list(FIGURE_NAMES)]
    outcomes["figures_held"] = figures.sum(axis=1)
    outcomes["all_held"] = figures.all(axis=1)
    outcomes["reached_held"] = False
    for reading, names in reached.items():
        rows = outcomes["reading"] == reading
        outcomes.loc[rows, "reached_held"] = figures.loc[rows, names].all(axis=1)
    table = _by_budget(
        outcomes,
        seeds_all_held=("all_held", "sum"),
        seeds_reached_held=("reached_held", "sum"),
        figures_held_median=("figures_held", "median"),
    )
    needed = table["seeds"].map(required_seeds)
    table["reaches_all"] = table["seeds_all_held"] >= needed
    table["reaches_reached"] = table["seeds_reached_held"] >= needed
    table["figures_reached_by_references"] = [
        len(reached.get(reading, ())) for reading in table["reading"]
    ]
    return table


SMALLEST_COLUMNS = (
    "optimizer", "reading", "target", "figures", "smallest_budget", "seeds_held", "seeds",
    "largest_budget_run",
)  # fmt: skip
"""The columns of :func:`smallest_budgets`."""


def smallest_budgets(table: pd.DataFrame) -> pd.DataFrame:
    """Per optimiser, reading and target (:data:`TARGETS`): the smallest budget that meets it
    (None if none of the budgets run does), the seeds there, and the largest budget run with
    its seeds."""
    if table.empty:  # no seed with both runs: budget_table has no columns to group by
        return pd.DataFrame(columns=SMALLEST_COLUMNS)
    rows = []
    for (optimizer, reading), group in table.groupby(["optimizer", "reading"], sort=False):
        for target, met, held in (
            (ALL, "reaches_all", "seeds_all_held"),
            (REACHED, "reaches_reached", "seeds_reached_held"),
        ):
            hits = group[group[met]]
            first = hits.iloc[0] if len(hits) else None
            last = group.iloc[-1]
            rows.append(
                {
                    "optimizer": optimizer,
                    "reading": reading,
                    "target": target,
                    "figures": 11 if target == ALL else int(last["figures_reached_by_references"]),
                    "smallest_budget": None
                    if first is None
                    else budget_text(first["budget"], first["max_evaluations"]),
                    "seeds_held": int(last[held] if first is None else first[held]),
                    "seeds": int(last["seeds"]),
                    "largest_budget_run": budget_text(last["budget"], last["max_evaluations"]),
                }
            )
    return pd.DataFrame(rows, columns=SMALLEST_COLUMNS)


def _found(row: pd.Series) -> str:
    if pd.notna(row["smallest_budget"]):
        return f"{row['smallest_budget']} ({row['seeds_held']}/{row['seeds']} seeds)"
    return f"not reached ({row['seeds_held']}/{row['seeds']} at {row['largest_budget_run']})"


def to_markdown(
    table: pd.DataFrame, smallest: pd.DataFrame, figures: pd.DataFrame | None = None
) -> str:
    """The report section: the smallest budget per optimiser and target, every budget's
    counts, and (if given) on how many seeds each figure holds."""
    lines = [
        "## The budget the paper needs",
        "",
        f"The paper's figures together on at least {REQUIRED_SHARE:.0%} of the seeds (a seed: "
        "its runs with and without the trigger): all 11, or those the exact solvers "
        f"({', '.join(REFERENCES)}) reach themselves. Errors counted from the 10 s settle time "
        "(`settle-time`) or from each run's own settling time (`settling`; a run that does not "
        "settle misses its error figures).",
        "",
        "| optimiser | reading | all 11 | the figures the exact solvers reach |",
        "|---|---|---|---|",
    ]
    for (optimizer, reading), pair in smallest.groupby(["optimizer", "reading"], sort=False):
        by_target = pair.set_index("target")
        reached = by_target.loc[REACHED]
        lines.append(
            f"| {optimizer} | {reading} | {_found(by_target.loc[ALL])} | "
            f"{reached['figures']}: {_found(reached)} |"
        )
    lines += [
        "",
        "At each budget: seeds with all 11 figures, seeds with the figures the exact solvers "
        "reach, and the median count of figures held:",
        "",
        "| optimiser | reading | budget | all 11 | reached by the exact solvers | median held |",
        "|---|---|---|---|---|---|",
    ]
    for _, row in table.iterrows():
        lines.append(
            f"| {row['optimizer']} | {row['reading']} | "
            f"{budget_text(row['budget'], row['max_evaluations'])} | "
            f"{row['seeds_all_held']}/{row['seeds']} | "
            f"{row['seeds_reached_held']}/{row['seeds']} | {row['figures_held_median']:g} |"
        )
    if figures is not None and not figures.empty:
        lines += [
            "",
            "Seeds on which each figure holds (which figures keep a budget from the paper):",
            "",
            "| optimiser | reading | budget | " + " | ".join(FIGURE_NAMES) + " |",
            "|---|---|---|" + "---|" * len(FIGURE_NAMES),
        ]
        for _, row in figures.iterrows():
            cells = [f"{row[n]}/{row['seeds']}" for n in FIGURE_NAMES]
            budget = budget_text(row["budget"], row["max_evaluations"])
            lines.append(
                f"| {row['optimizer']} | {row['reading']} | {budget} | " + " | ".join(cells) + " |"
            )
    return "\n".join(lines) + "\n"


def applies(results: pd.DataFrame) -> bool:
    """Whether the results hold pairs of runs of the unmodified paper scenario at more than
    one budget: read through :func:`runs_table`, so that the section is written exactly when
    its tables have rows."""
    return not missing_columns(results) and paired_budgets(runs_table(results)) > 1


def shipped_line(optimizer: str = "modified-bso", path: Path = SHIPPED_RUNS) -> str:
    """One line naming the budget the paper needs for ``optimizer``, read from the shipped
    per-run values (nothing is run)."""
    runs = pd.read_csv(path)
    smallest = smallest_budgets(budget_table(runs))
    mine = smallest[smallest["optimizer"] == optimizer].set_index(["reading", "target"])
    if mine.empty:
        raise ValueError(f"{path.name} has no runs of {optimizer!r}")
    parts = []
    for target in TARGETS:
        found = []
        for reading in Reading:
            row = mine.loc[(str(reading), target)]
            where = "errors from 10 s" if reading is Reading.SETTLE_TIME else "from settling"
            budget = (
                f"not reached up to {row['largest_budget_run']}"
                if pd.isna(row["smallest_budget"])
                else row["smallest_budget"]
            )
            found.append(f"{budget} ({where})")
        what = "all 11" if target == ALL else f"the {row['figures']} the exact solvers reach"
        parts.append(f"{what}: {', '.join(found)}")
    seeds = int(row["seeds"])
    return (
        f"Budget the paper needs ({optimizer}, figures together on {required_seeds(seeds)} of "
        f"{seeds} seeds; the shipped paper-budget sweep, not run again): {'; '.join(parts)}."
    )
