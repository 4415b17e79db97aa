"""The report's tables of one block: the configurations as rows, the metrics as columns.

A *block* is one comparison the report makes (:mod:`~formation_bench.analysis.comparison`):
the levels of the compared factor (the optimisers, say) at one setting of the others. Its
tables share their rows and columns, each column a metric headed by its name and unit
(:func:`~formation_bench.analysis.cells.metric_column`); where the metrics do not fit the width
of one table (:data:`~formation_bench.analysis.cells.TABLE_WIDTH`), they are split into groups
in their order, and each group gets all three tables:

- the values: median [bootstrap 95 % CI of the median] over the seeds, with the number of
  runs of each configuration;
- with 3 or more levels, the Friedman average ranks (1 = the lowest value) and the Friedman
  p-value of each metric;
- per baseline, every level against it paired by seed: Holm-adjusted Wilcoxon p (``*`` below
  the significance level) and A12 = P(level > baseline).

A metric that has one value in every run of the block (or none) gets no column: one line
under the values names it and its value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

from formation_bench.analysis.cells import Grid, MetricColumn, fit_columns, metric_column, p_cell
from formation_bench.analysis.comparison import Report
from formation_bench.analysis.stats import SIGNIFICANCE
from formation_bench.mpc.metrics import Better, Per, metric_of

VALUES_LEGEND = (
    "Median [bootstrap 95 % CI of the median] over the seeds; runs: runs of the configuration "
    "(n: runs with a value, where fewer)."
)


class BlockTables:
    """The report's statistics split by block and metric once: filtering them for every
    block and metric took 6.4 s per Markdown pass on the swarm suite's 14 blocks and 76
    metrics, the split 2.5-3 s (same text)."""

    NAMES = ("summary", "wilcoxon", "ranks", "friedman")

    def __init__(self, report: Report) -> None:
        self.report = report
        self.tables = {name: getattr(report, name) for name in self.NAMES}
        keys = [*report.block_factors, "metric"]
        self.groups = {
            name: {} if table.empty else dict(list(table.groupby(keys, sort=False)))
            for name, table in self.tables.items()
        }

    def select(self, name: str, block_key: dict[str, str], metric: str) -> pd.DataFrame:
        """The rows of table ``name`` of this block and metric."""
        table = self.tables[name]
        if table.empty:
            return table
        key = (*(block_key[f] for f in self.report.block_factors), metric)
        return self.groups[name].get(key, table.iloc[0:0])


def absent(block: pd.DataFrame, column: str) -> bool:
    """Whether ``column`` is a value per UAV, pair or condition that no run of ``block`` has
    (a UAV the block's swarms do not have): such a column does not apply, it is left out."""
    info = metric_of(column)
    return info is not None and info.per is not Per.RUN and block[column].isna().all()


def constant_metrics(block: pd.DataFrame, metrics: list[str]) -> dict[str, float]:
    """The metrics of ``metrics`` with one value in every run of ``block`` (NaN: no run has
    one, as a settling time where no run settled), with that value; :func:`absent` columns
    are not among them."""
    constant = {}
    for metric in metrics:
        values = pd.to_numeric(block[metric], errors="coerce")
        if absent(block, metric):
            continue
        if values.isna().all():
            constant[metric] = math.nan
        elif values.notna().all() and values.nunique() == 1:
            constant[metric] = float(values.iloc[0])
    return constant


def constant_line(constant: dict[str, float]) -> str:
    """``Constant in every run: collisions per run = 0, ...``; empty when there is none."""
    if not constant:
        return ""
    parts = []
    for metric, value in constant.items():
        column = metric_column(metric, [value])
        shown = "no value" if math.isnan(value) else column.with_unit(value)
        parts.append(f"{column.name} = {shown}")
    return "Constant in every run of this block (no column): " + ", ".join(parts) + "."


def _summary_cell(column: MetricColumn, summary: pd.DataFrame, level: str, runs: int) -> str:
    """``median [CI]`` of ``level``, with ``(n k)`` when fewer of its ``runs`` have a value."""
    if level not in summary.index or not summary.loc[level, "n"]:
        return "–"
    row = summary.loc[level]
    text = (
        f"{column.value(row['median'])} "
        f"[{column.value(row['ci_low'])}, {column.value(row['ci_high'])}]"
    )
    if row["n"] < runs:  # some runs have no value (never settled)
        text += f" (n {int(row['n'])})"
    return text


@dataclass(frozen=True)
class Verdicts:
    """A table of verdicts on the metrics (ranks, tests), what is said above it, and which of
    its columns have a verdict: a part of a split table with none is left out."""

    grid: Grid
    legend: list[str]
    """The lines above the first part."""
    short: list[str]
    """The lines above a further part."""
    filled: list[bool]

    def lines(self, group: list[int], first: bool) -> list[str]:
        """The part of the table with the metric columns at ``group``, none if it has no
        verdict."""
        if not any(self.filled[k] for k in group):
            return []
        return [*(self.legend if first else self.short), *self.grid.select(group).lines(), ""]


def _values_grid(
    tables: BlockTables,
    block_key: dict[str, str],
    block: pd.DataFrame,
    levels: list[str],
    columns: list[MetricColumn],
) -> Grid:
    factor = tables.report.factor
    runs = block.groupby(factor, sort=False).size()
    summaries = {
        c.column: tables.select("summary", block_key, c.column).set_index(factor) for c in columns
    }
    rows = [
        [
            level,
            str(int(runs.get(level, 0))),
            *(
                _summary_cell(c, summaries[c.column], level, int(runs.get(level, 0)))
                for c in columns
            ),
        ]
        for level in levels
    ]
    return Grid([factor, "runs", *(c.header for c in columns)], rows, lead=2)


def _ranks(
    tables: BlockTables, block_key: dict[str, str], levels: list[str], columns: list[MetricColumn]
) -> Verdicts:
    factor = tables.report.factor
    ranks = {}
    for c in columns:
        selected = tables.select("ranks", block_key, c.column)
        ranks[c.column] = (
            pd.Series(dtype=float) if selected.empty else selected.set_index(factor)["average_rank"]
        )
    higher = [c.name for c in columns if (i := metric_of(c.column)) and i.better is Better.HIGHER]
    note = f" ({', '.join(higher)}: higher is better, so rank 1 is the worst)" if higher else ""
    legend = (
        f"Friedman average rank over the seeds every {factor} ran, 1 = the lowest value{note}; "
        "last row: Friedman's p-value (seeds)."
    )

    def rank_cell(level: str, column: MetricColumn) -> str:
        rank = ranks[column.column].get(level, math.nan)
        return "–" if pd.isna(rank) else f"{rank:.2f}"

    def friedman_cell(column: MetricColumn) -> str:
        friedman = tables.select("friedman", block_key, column.column)
        if friedman.empty:
            return "–"
        first = friedman.iloc[0]
        return f"{p_cell(first['p'])} ({int(first['n_seeds'])})"

    rows = [[level, *(rank_cell(level, c) for c in columns)] for level in levels]
    rows.append(["Friedman p", *(friedman_cell(c) for c in columns)])
    grid = Grid([factor, *(c.header for c in columns)], rows)
    return Verdicts(grid, [legend, ""], [], [not ranks[c.column].empty for c in columns])


def _tests(
    tables: BlockTables,
    block_key: dict[str, str],
    levels: list[str],
    columns: list[MetricColumn],
    base: str,
) -> Verdicts:
    factor = tables.report.factor
    tests = {}
    for column in columns:
        rows = tables.select("wilcoxon", block_key, column.column)
        if not rows.empty:
            rows = rows[rows["baseline"] == base]
        tests[column.column] = rows.set_index(factor) if not rows.empty else rows
    legend = (
        f"Against {base}, paired by seed: Wilcoxon signed-rank p (two-sided, Holm-adjusted "
        f"over the levels compared with {base} on that metric; * p < {SIGNIFICANCE:g}) and "
        f"A12 = P({factor} > {base}) (< 0.5: lower values than {base})."
    )

    def test_cell(level: str, column: MetricColumn) -> str:
        table = tests[column.column]
        if level == base:
            return "baseline"
        if table.empty or level not in table.index:
            return "–"
        test = table.loc[level]
        mark = " *" if test["significant"] else ""
        return f"{p_cell(test['p_holm'])}{mark}, A12 {test['a12']:.2f}"

    rows = [[level, *(test_cell(level, c) for c in columns)] for level in levels]
    grid = Grid([factor, *(c.header for c in columns)], rows)
    short = [f"Against {base}: p (Holm), A12.", ""]
    return Verdicts(grid, [legend, ""], short, [not tests[c.column].empty for c in columns])


def block_lines(
    tables: BlockTables,
    block_key: dict[str, str],
    block: pd.DataFrame,
    metrics: list[str],
    *,
    constant_note: bool = True,
) -> list[str]:
    """The Markdown of one block: per group of the metrics that vary in the block, as many
    as fit one table (:func:`~formation_bench.analysis.cells.fit_columns`), the values, the
    ranks and the tests against each baseline; the metrics that do not vary on one line
    under the first values table."""
    report = tables.report
    levels = list(dict.fromkeys(block[report.factor]))
    metrics = [m for m in metrics if not absent(block, m)]
    constant = constant_metrics(block, metrics)
    columns = [metric_column(m, block[m]) for m in metrics if m not in constant]
    note = [constant_line(constant), ""] if constant and constant_note else []
    if not columns:
        return note
    values = _values_grid(tables, block_key, block, levels, columns)
    verdicts = [
        _ranks(tables, block_key, levels, columns),
        *(_tests(tables, block_key, levels, columns, base) for base in report.baselines),
    ]
    lines: list[str] = []
    groups = fit_columns([values, *(v.grid for v in verdicts)])
    for k, group in enumerate(groups):
        first = k == 0
        lines += [*([VALUES_LEGEND, ""] if first else []), *values.select(group).lines(), ""]
        lines += note if first else []
        for verdict in verdicts:
            lines += verdict.lines(group, first)
    return lines
