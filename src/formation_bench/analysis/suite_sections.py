"""Report sections of the suites beyond the paper's scenario: the number of UAVs and the
communication graph (``swarm``), disturbances and communication faults (``robustness``),
obstacle and collision penalties (``obstacles``).

What a run's scenario is (its UAVs, graph, disturbance family, penalties) is read from its
registered name and overrides (:func:`scenario_columns`), never from its label, so every
results folder that varies these gets the section, whatever the suite is called. The
disturbance and fault families are the harness's (:mod:`formation_bench.mpc.families`): a
registered family's levels get their own blocks, and a run disturbed in a setting no family
claims is refused rather than counted as nominal. A section
has one table per *block*, one comparison (an (N, graph) cell against the complete graph; a
disturbance level against the nominal runs; a scenario's penalties on against off): the
optimisers as rows, the metrics as columns (constant ones on a line), each cell the median
over the seeds against the reference's median; metrics that do not fit the width of one
table (:data:`~formation_bench.analysis.cells.TABLE_WIDTH`) continue in further tables of the
same rows. It carries the report's statistics
(:func:`~formation_bench.analysis.comparison.analyse`):

- every condition against its baseline condition (the complete graph at the same N; the
  nominal scenario; the penalties off), same optimiser, trigger and budget, paired by seed:
  Wilcoxon signed-rank, Holm-adjusted over the conditions compared with that baseline, and
  A12 = P(condition > baseline);
- the optimisers within every condition: Friedman's average rank over the seeds that all of
  them ran (1 = lowest value) and its p-value, and every optimiser against the baseline
  optimiser (Wilcoxon, Holm-adjusted, A12);
- in the swarm section, the optimisers' Friedman ranks across all cells (blocks: cell and
  seed, :func:`overall_ranking`).

:func:`write_sections` writes ``<section>.md`` and ``<section>.csv`` (one row per condition,
trigger, budget, optimiser and metric) and the figures, and returns the Markdown that
``report.md`` appends.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from formation_bench.analysis import stats
from formation_bench.analysis.block_table import absent, constant_line, constant_metrics
from formation_bench.analysis.cells import Grid, MetricColumn, fitted, metric_column, p_cell
from formation_bench.analysis.comparison import analyse, prepare
from formation_bench.analysis.stats import SIGNIFICANCE
from formation_bench.mpc.families import FAMILIES, JOINED, NOMINAL, scenario_families
from formation_bench.mpc.metrics import Better, metric_of
from formation_bench.mpc.scenario import CommunicationGraph, Scenario
from formation_bench.pipeline.record import stored_scenarios

SWARM_METRICS = (
    "tracking_error_max_m",
    "distance_error_rms_m",
    "solves_total",
    "collisions",
    "solve_time_median_s",
)
ROBUSTNESS_METRICS = (
    "tracking_error_max_m",
    "distance_error_rms_m",
    "distance_error_max_m_max",
    "solves_total",
    "min_separation_m",
)
OBSTACLE_METRICS = (
    "obstacle_intrusions",
    "obstacle_time_s",
    "collisions",
    "collision_time_s",
    "min_separation_m",
    "tracking_error_max_m",
    "distance_error_rms_m",
)
PENALTIES_OFF = "off"
COMPLETE = "complete"


# --- what each run's scenario is ----------------------------------------------------------------


def graph_label(scenario: Scenario) -> str:
    """``complete``, ``ring``, ``3-nearest`` or ``range 35 m``."""
    if scenario.communication.graph == CommunicationGraph.K_NEAREST:
        return f"{scenario.communication.graph_neighbours}-nearest"
    if scenario.communication.graph == CommunicationGraph.RANGE:
        return f"range {scenario.communication.graph_range_m:g} m"
    return str(scenario.communication.graph)


def penalties_label(scenario: Scenario) -> str:
    """Which penalties act in the local cost: ``obstacle``, ``collision``, both, or ``off``."""
    parts = []
    if scenario.safety.w_obstacle > 0 and scenario.safety.obstacles:
        parts.append("obstacle")
    if scenario.safety.w_collision > 0:
        parts.append("collision")
    return " + ".join(parts) or PENALTIES_OFF


def _describe(scenario: Scenario) -> dict[str, object]:
    active = scenario_families(scenario)
    if not active:
        family, family_index, severity = NOMINAL, -1, ()
    elif len(active) == 1:
        family_index = FAMILIES.index(active[0])
        family = active[0].name
        severity = active[0].severity(scenario)
    else:  # several at once: after the single families
        family, family_index = JOINED.join(f.name for f in active), len(FAMILIES)
        severity = tuple(v for f in active for v in f.severity(scenario))
    return {
        "n_uav": scenario.n_uav,
        "graph": graph_label(scenario),
        "family": family,
        "family_index": family_index,
        "severity": severity,
        "penalties": penalties_label(scenario),
        "obstacles": len(scenario.safety.obstacles),
        "safety_radius_m": scenario.safety.safety_radius_m,
    }


def scenario_columns(results: pd.DataFrame) -> pd.DataFrame:
    """``results`` with what each run's scenario is: ``n_uav``, ``graph``, ``family`` (of
    the registered :data:`~formation_bench.mpc.families.FAMILIES`, ``nominal`` or several
    joined by ``+``), ``penalties``, ``obstacles``, ``safety_radius_m``, and ``level_order``
    (levels sorted by family, then severity). A scenario disturbed in a setting no family
    claims raises :class:`~formation_bench.mpc.families.UnclaimedDisturbanceError`.

    Each run's scenario is the one its row records (:func:`~formation_bench.pipeline.record.
    stored_scenario`), not today's registry's; a row whose scenario cannot be rebuilt here
    (a plugin's class not loaded, say) leaves its columns empty, and it is in no section."""
    described: dict[int, dict[str, object]] = {}  # by identity: one per distinct scenario
    rows = []
    for scenario in stored_scenarios(results):
        if scenario is None:
            rows.append({})
            continue
        if id(scenario) not in described:
            described[id(scenario)] = _describe(scenario)
        rows.append(described[id(scenario)])
    info = pd.DataFrame(rows, index=results.index)
    frame = pd.concat([results, info], axis=1)
    if "family" in frame:
        levels = (
            frame.dropna(subset=["family"])
            .drop_duplicates("scenario")
            .sort_values(["family_index", "severity", "scenario"])
        )
        order = {label: k for k, label in enumerate(levels["scenario"])}
        frame["level_order"] = frame["scenario"].map(order)
    return frame


# --- statistics ------------------------------------------------------------------------------


def condition_tests(
    frame: pd.DataFrame, metrics: tuple[str, ...], group: list[str], is_baseline: pd.Series
) -> pd.DataFrame:
    """Every condition (scenario label) against the baseline condition of its ``group`` (the
    rows where ``is_baseline``), per optimiser, trigger and budget: the report's Wilcoxon
    table with ``scenario`` the condition and ``baseline`` its baseline."""
    tables = []
    for _, rows in frame.groupby(group, sort=False):
        baselines = rows.loc[is_baseline.loc[rows.index], "scenario"].unique()
        if len(baselines) != 1 or rows["scenario"].nunique() < 2:
            continue
        report = analyse(rows, compare="scenario", baseline=baselines[0], metrics=list(metrics))
        tables.append(report.wilcoxon)
    return pd.concat(tables, ignore_index=True) if tables else pd.DataFrame()


def section_table(
    frame: pd.DataFrame, metrics: tuple[str, ...], conditions: pd.DataFrame
) -> pd.DataFrame:
    """One row per scenario, trigger, budget, optimiser and metric: n, median, CI, the
    optimisers' Friedman rank and test within the scenario, the optimiser against the baseline
    optimiser, and (from ``conditions``, :func:`condition_tests`) the scenario against its
    baseline condition."""
    keys = ["scenario", "trigger", "budget", "optimizer", "metric"]
    report = analyse(frame, compare="optimizer", metrics=list(metrics))
    table = report.summary.drop(columns=["q1", "q3"])
    if not report.wilcoxon.empty:
        versus = report.wilcoxon[[*keys, "baseline", "a12", "p_holm", "significant"]]
        versus = versus.rename(
            columns={
                "baseline": "optimizer_baseline",
                "a12": "optimizer_a12",
                "p_holm": "optimizer_p_holm",
                "significant": "optimizer_significant",
            }
        )
        table = table.merge(versus, on=keys, how="left")
    if not report.ranks.empty:
        table = table.merge(report.ranks, on=keys, how="left")
    if not report.friedman.empty:
        friedman = report.friedman.rename(
            columns={"p": "friedman_p", "n_seeds": "friedman_seeds", "statistic": "friedman_chi2"}
        ).drop(columns=["k"])
        table = table.merge(friedman, on=[k for k in keys if k != "optimizer"], how="left")
    if not conditions.empty:
        versus = conditions[[*keys, "baseline", "n_pairs", "a12", "p_holm", "significant"]]
        versus = versus.rename(
            columns={
                "baseline": "condition_baseline",
                "n_pairs": "condition_pairs",
                "a12": "condition_a12",
                "p_holm": "condition_p_holm",
                "significant": "condition_significant",
            }
        )
        table = table.merge(versus, on=keys, how="left")
    described = frame.drop_duplicates("scenario").set_index("scenario")
    for column in ("n_uav", "graph", "family", "penalties", "scenario_name", "level_order"):
        table[column] = table["scenario"].map(described[column])
    return table


# --- Markdown ----------------------------------------------------------------------------------

KEYS = ["scenario", "trigger", "budget", "optimizer", "metric"]
"""A row of :func:`section_table`: one condition, setting, optimiser and metric."""
SETTING = ("trigger", "budget")
"""The factors every comparison of a section holds fixed (named in a block's heading when
they vary over the section)."""


def _is_true(value: object) -> bool:
    # a merged column of test outcomes holds booleans and NaN (no test)
    return isinstance(value, bool | np.bool_) and bool(value)


def _value_cell(row: dict | None, reference: dict | None, column: MetricColumn) -> str:
    """The median; against a reference, ``median vs reference median, A12 x.xx`` (``*``: the
    Holm-adjusted Wilcoxon p below the significance level)."""
    if row is None or not row["n"]:
        return "–"
    text = column.value(row["median"])
    if row["n"] < row["seeds"]:  # some runs have no value (e.g. never settled)
        text += f" (n {int(row['n'])})"
    if reference is not None:
        text += f" vs {column.value(reference['median'])}"
        if pd.notna(row.get("condition_a12")):
            mark = "*" if _is_true(row.get("condition_significant")) else ""
            text += f", A12 {row['condition_a12']:.2f}{mark}"
    return text


def _rank_cell(row: dict | None) -> str:
    if row is None:
        return "–"
    rank = row.get("average_rank")
    text = f"{rank:.2f}" if pd.notna(rank) else ""
    if pd.notna(row.get("optimizer_a12")):
        mark = "*" if _is_true(row.get("optimizer_significant")) else ""
        text += f" (A12 {row['optimizer_a12']:.2f}{mark})"
    return text.strip() or ("baseline" if row.get("is_optimizer_baseline") else "–")


def _split(head: list[str], rows: list[list[str]], lead: int) -> list[str]:
    """A table of ``lead`` columns naming the row and metric columns, as tables of the same
    rows that each fit the page (:func:`~formation_bench.analysis.cells.fitted`), one after
    the other."""
    lines: list[str] = []
    for part in fitted(Grid(head, rows, lead=lead, left=lead)):
        lines += [*([""] if lines else []), *part.lines()]
    return lines


def _higher_is_better(metrics: list[str] | tuple[str, ...]) -> list[str]:
    return [
        metric_column(m).name
        for m in metrics
        if (info := metric_of(m)) is not None and info.better is Better.HIGHER
    ]


def _worst_note(metrics: list[str] | tuple[str, ...]) -> str:
    higher = _higher_is_better(metrics)
    if not higher:
        return ""
    return f", but rank 1 is the worst on {', '.join(higher)} (higher is better)"


RANKED = (
    "the closed-loop metrics as their columns name them (the errors after the settle time, "
    "i.e. the steady state; counts and times over the whole run)"
)
"""What the ranks rank, for the sentence above a ranks table."""


def power_note(table: pd.DataFrame) -> str:
    """What the number of seeds allows the paired tests to show."""
    pairs = pd.concat([table.get("condition_pairs", pd.Series(dtype=float)), table["n"]]).dropna()
    if pairs.empty:
        return ""
    n = int(pairs.max())
    smallest = 2.0 / 2.0**n  # the exact two-sided signed-rank p when every difference agrees
    if smallest < SIGNIFICANCE:
        return ""
    return (
        f"With {n} seeds paired, the smallest two-sided Wilcoxon p is {smallest:.4g}: no paired "
        f"comparison can reach p < {SIGNIFICANCE:g} (no `*` is possible). Read the A12 effect "
        "sizes (0 or 1: the two sets of runs do not overlap) and Friedman's test, which can."
    )


@dataclass(frozen=True)
class Block:
    """One comparison of a section: the conditions (scenario labels) its values table shows,
    each against its reference condition where it has one, at one setting."""

    heading: str
    setting: tuple[str, str]
    """Trigger and budget."""
    shown: tuple[str, ...]
    ranked: tuple[str, ...] = ()
    """The conditions whose optimiser ranks the block shows (none: the section ranks)."""


class _Tables:
    """A section's table by row, and how its blocks print."""

    def __init__(
        self,
        runs: pd.DataFrame,
        table: pd.DataFrame,
        metrics: tuple[str, ...],
        condition: tuple[str, Callable[[str], str]] | None = None,
    ) -> None:
        self.runs = runs
        self.table = table
        self.metrics = [m for m in metrics if m in runs]
        self.rows = table.set_index(KEYS).to_dict("index")
        self.optimizers = list(dict.fromkeys(table["optimizer"]))
        self.baseline = _baseline_optimizer(table)
        self.condition = condition
        """Heading and label of the condition column, where a table shows several."""
        described = table.drop_duplicates("scenario").set_index("scenario")
        self.reference = (
            described["condition_baseline"].dropna().to_dict()
            if "condition_baseline" in described
            else {}
        )

    def row(self, scenario: str, setting: tuple[str, str], optimizer: str, metric: str):
        return self.rows.get((scenario, *setting, optimizer, metric))

    def block_runs(self, block: Block) -> pd.DataFrame:
        """The runs a block compares: its conditions, their references and the ranked ones."""
        scenarios = {*block.shown, *block.ranked}
        scenarios |= {self.reference[s] for s in block.shown if s in self.reference}
        trigger, budget = block.setting
        runs = self.runs
        mask = (runs["trigger"] == trigger) & (runs["budget"] == budget)
        return runs[mask & runs["scenario"].isin(scenarios)]

    def _lead(self, scenarios: tuple[str, ...]) -> tuple[list[str], Callable[[str], list[str]]]:
        if self.condition is None or len(scenarios) < 2:
            return [], lambda _: []
        heading, label = self.condition
        return [heading], lambda scenario: [label(scenario)]

    def values(self, block: Block, columns: list[MetricColumn]) -> list[str]:
        """The values table, split into tables that fit the page (:func:`_split`)."""
        lead, label = self._lead(block.shown)
        rows = []
        for scenario in block.shown:
            reference = self.reference.get(scenario)
            for optimizer in self.optimizers:
                cells = []
                for column in columns:
                    row = self.row(scenario, block.setting, optimizer, column.column)
                    versus = None
                    if reference is not None:
                        versus = self.row(reference, block.setting, optimizer, column.column)
                    cells.append(_value_cell(row, versus, column))
                if any(c != "–" for c in cells) or not columns:
                    rows.append([*label(scenario), optimizer, *cells])
        return _split([*lead, "optimizer", *(c.header for c in columns)], rows, len(lead) + 1)

    def tied(self, block: Block, metric: str) -> bool:
        """Whether every optimiser has the same average rank on ``metric`` in every ranked
        condition of ``block``."""
        ranks = [
            row.get("average_rank")
            for scenario in block.ranked
            for optimizer in self.optimizers
            if (row := self.row(scenario, block.setting, optimizer, metric)) is not None
        ]
        if not ranks or all(pd.isna(r) for r in ranks):
            return False
        by_condition = [
            {
                round(float(row["average_rank"]), 9)
                for optimizer in self.optimizers
                if (row := self.row(scenario, block.setting, optimizer, metric)) is not None
                and pd.notna(row.get("average_rank"))
            }
            for scenario in block.ranked
        ]
        return all(len(ranks) <= 1 for ranks in by_condition)

    def _friedman_cell(self, scenario: str, setting: tuple[str, str], metric: str) -> str:
        """Friedman's p (seeds) of the optimisers on ``metric`` in ``scenario``."""
        rows = [self.row(scenario, setting, o, metric) for o in self.optimizers]
        found = [r for r in rows if r is not None and pd.notna(r.get("friedman_p"))]
        if not found:
            return "–"
        return f"{p_cell(found[0]['friedman_p'])} ({int(found[0]['friedman_seeds'])})"

    def ranks(self, block: Block, columns: list[MetricColumn], what: str) -> list[str]:
        """The optimisers' ranks in the block's ranked conditions; a metric on which every
        rank is tied is named on one line instead."""
        if not block.ranked or not columns:
            return []
        tied = [c for c in columns if self.tied(block, c.column)]
        ranked = [c for c in columns if c not in tied]
        tied_line = (
            "Every optimiser has the same average rank (Friedman p 1.000) on: "
            + ", ".join(c.name for c in tied)
            + "."
        )
        if not ranked:
            return [f"Ranks within {what}: no ranks table. {tied_line}", ""]
        lead, label = self._lead(block.ranked)
        lines = [
            f"Optimiser ranks within {what}: each closed-loop metric's average Friedman rank "
            f"over the seeds, 1 = the lowest value{_worst_note([c.column for c in ranked])}; "
            f"in brackets A12 = P(optimiser > {self.baseline}), * Holm-adjusted p < "
            f"{SIGNIFICANCE:g}.",
            "",
        ]
        rows = self._rank_rows(block, [c.column for c in ranked], label)
        lines += _split([*lead, "optimizer", *(c.header for c in ranked)], rows, len(lead) + 1)
        return [*lines, "", *([tied_line, ""] if tied else [])]

    def _rank_rows(
        self, block: Block, metrics: list[str], label: Callable[[str], list[str]]
    ) -> list[list[str]]:
        """Per ranked condition, each optimiser's ranks on ``metrics``, then Friedman's p."""
        rows = [
            [
                *label(scenario),
                optimizer,
                *(_rank_cell(self.row(scenario, block.setting, optimizer, m)) for m in metrics),
            ]
            for scenario in block.ranked
            for optimizer in self.optimizers
        ]
        for scenario in block.ranked:
            cells = [self._friedman_cell(scenario, block.setting, m) for m in metrics]
            rows.append([*label(scenario), "Friedman p (seeds)", *cells])
        return rows

    def block(self, block: Block, what: str) -> tuple[str, list[str]]:
        """The Markdown of ``block`` and the metrics it has a column for: its values table,
        the line naming the metrics constant over its runs, its ranks."""
        runs = self.block_runs(block)
        metrics = [m for m in self.metrics if not absent(runs, m)]
        constant = constant_metrics(runs, metrics)
        columns = [metric_column(m, runs[m]) for m in metrics if m not in constant]
        lines = [block.heading, ""]
        if columns:
            lines += [*self.values(block, columns), ""]
        if constant:
            lines += [constant_line(constant), ""]
        lines += self.ranks(block, columns, what)
        return "\n".join(lines), [c.column for c in columns]


def _varying(table: pd.DataFrame) -> list[str]:
    return [c for c in SETTING if table[c].nunique() > 1]


def _setting_text(setting: tuple[str, str], varying: list[str]) -> str:
    named = zip(SETTING, setting, strict=True)
    return "".join(f", {name} {value}" for name, value in named if name in varying)


def _settings(table: pd.DataFrame) -> list[tuple[str, str]]:
    """The (trigger, budget) settings in table order (the trigger on first)."""
    return list(dict.fromkeys(zip(table["trigger"], table["budget"], strict=True)))


def overall_ranking(runs: pd.DataFrame, metrics: tuple[str, ...], order: list[str]) -> pd.DataFrame:
    """The optimisers' Friedman ranks across every condition of ``runs``, per trigger and
    budget setting and metric: the blocks are the (condition, seed) pairs that every optimiser
    ran, the treatments the optimisers (in ``order``). One row per setting, metric and
    optimiser: ``average_rank``, ``friedman_p``, ``friedman_chi2`` and ``friedman_blocks``."""
    rows = []
    for (trigger, budget), setting in runs.groupby(list(SETTING), sort=False):
        for metric in metrics:
            if metric not in setting:
                continue
            values = setting.pivot_table(
                index=["scenario", "seed"], columns="optimizer", values=metric, aggfunc="first"
            ).reindex(columns=[o for o in order if o in set(setting["optimizer"])])
            result = stats.friedman(values)
            for optimizer, rank in result.average_ranks.items():
                rows.append(
                    {
                        "trigger": trigger,
                        "budget": budget,
                        "metric": metric,
                        "optimizer": optimizer,
                        "average_rank": rank,
                        "friedman_p": result.pvalue,
                        "friedman_chi2": result.statistic,
                        "friedman_blocks": result.n_blocks,
                    }
                )
    return pd.DataFrame(rows)


def _ranked_and_tied(here: pd.DataFrame, metrics: list[str]) -> tuple[list[str], list[str]]:
    """The metrics of ``metrics`` on which the optimisers' ranks in ``here`` (one setting of
    :func:`overall_ranking`) differ, and those on which they are all the same."""
    ranked, tied = [], []
    for metric in metrics:
        ranks = here.loc[here["metric"] == metric, "average_rank"].dropna()
        if ranks.empty:
            continue
        (tied if ranks.round(9).nunique() == 1 else ranked).append(metric)
    return ranked, tied


def _ranking_rows(here: pd.DataFrame, ranked: list[str]) -> list[list[str]]:
    """Each optimiser's ranks on ``ranked`` in ``here``, then Friedman's p (blocks)."""
    by_metric = {m: here[here["metric"] == m].set_index("optimizer") for m in ranked}
    rows = []
    for optimizer in dict.fromkeys(here["optimizer"]):
        cells = []
        for metric in ranked:
            rank = by_metric[metric]["average_rank"].get(optimizer, math.nan)
            cells.append("–" if pd.isna(rank) else f"{rank:.2f}")
        rows.append([optimizer, *cells])
    cells = []
    for metric in ranked:
        first = by_metric[metric].iloc[0]
        cells.append(f"{p_cell(first['friedman_p'])} ({int(first['friedman_blocks'])})")
    rows.append(["Friedman p (blocks)", *cells])
    return rows


def _ranking_lines(
    ranking: pd.DataFrame, runs: pd.DataFrame, metrics: tuple[str, ...], varying: list[str]
) -> list[str]:
    """The section's ranking table per setting: optimisers as rows, metrics as columns, the
    Friedman p and number of blocks in the last row; tied metrics on one line."""
    lines = []
    for setting in _settings(ranking) if not ranking.empty else []:
        trigger, budget = setting
        here = ranking[(ranking["trigger"] == trigger) & (ranking["budget"] == budget)]
        setting_runs = runs[(runs["trigger"] == trigger) & (runs["budget"] == budget)]
        present = [m for m in metrics if m in setting_runs and not absent(setting_runs, m)]
        constant = constant_metrics(setting_runs, present)
        ranked, tied = _ranked_and_tied(here, [m for m in present if m not in constant])
        title = f"### Ranking across all cells{_setting_text(setting, varying)}"
        if not ranked:
            lines += [
                title,
                "",
                "Every optimiser has the same average rank on every metric: no ranking table.",
                "",
            ]
            continue
        columns = [metric_column(m, setting_runs[m]) for m in ranked]
        lines += [
            title,
            "",
            "Each optimiser's average Friedman rank on " + RANKED + ", over the blocks (N, "
            "graph, seed) that every optimiser ran, 1 = the lowest value"
            f"{_worst_note(ranked)}; last row: Friedman's p (blocks).",
            "",
        ]
        rows = _ranking_rows(here, ranked)
        lines += [*_split(["optimizer", *(c.header for c in columns)], rows, 1), ""]
        if tied:
            names = ", ".join(metric_column(m).name for m in tied)
            lines += [f"Every optimiser has the same average rank on: {names}.", ""]
        if constant:
            lines += [constant_line(constant).replace("of this block", "of these cells"), ""]
    return lines


# --- the sections ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Section:
    """One suite section: its long table, Markdown and figure-ready runs."""

    name: str
    metrics: tuple[str, ...]
    runs: pd.DataFrame
    """The runs with :func:`scenario_columns` and the factors as the report prints them."""
    table: pd.DataFrame
    """:func:`section_table`, sorted by condition."""
    intro: str
    """The heading and what the tables show (with :func:`power_note`)."""
    blocks: dict[str, str]
    """Per block (by its heading), its tables (Markdown): the optimisers as rows, the metrics
    that vary over the block's runs as columns, the others on one line."""
    block_columns: dict[str, tuple[str, ...]]
    """Per block, the metrics its tables have a column for."""
    ranking: pd.DataFrame = field(default_factory=pd.DataFrame)
    """:func:`overall_ranking` of the swarm section; empty in the others (they rank per
    block)."""
    ranking_text: str = ""

    @property
    def body(self) -> str:
        """Every block's tables, then the section's ranking."""
        return "\n".join([*self.blocks.values(), self.ranking_text]).rstrip() + "\n"

    @property
    def markdown(self) -> str:
        return "\n".join([self.intro, self.body]).rstrip() + "\n"


def _baseline_optimizer(table: pd.DataFrame) -> str:
    names = table["optimizer_baseline"].dropna() if "optimizer_baseline" in table else []
    return str(names.iloc[0]) if len(names) else "the first optimiser"


def _finish(table: pd.DataFrame, order: list[str]) -> pd.DataFrame:
    for column in ("average_rank", "optimizer_a12", "condition_a12", "friedman_p"):
        if column not in table:
            table[column] = np.nan
    table["is_optimizer_baseline"] = table["optimizer"] == _baseline_optimizer(table)
    table["seeds"] = table.groupby(["scenario", "trigger", "budget", "optimizer"])["n"].transform(
        "max"
    )
    baseline = _baseline_optimizer(table)

    def key(column: pd.Series) -> pd.Series:
        # the trigger on (the paper's configuration) first, the baseline optimiser first
        if column.name == "trigger":
            return column.map({"on": 0, "off": 1})
        if column.name == "optimizer":
            return column.map(lambda o: (o != baseline, o))
        return column

    return table.sort_values(
        ["trigger", "budget", *order], key=key, kind="stable", ignore_index=True
    )


def _intro(heading: str, text: str, table: pd.DataFrame) -> str:
    note = power_note(table)
    return "\n".join([heading, "", text, "", *([note, ""] if note else [])])


def _rank_legend(metrics: tuple[str, ...], baseline: str, within: str) -> str:
    return (
        f"Under a block's values, the optimisers' ranks within {within}: each optimiser's "
        f"average Friedman rank on {RANKED}, over the seeds all of them ran, 1 = the lowest "
        f"value{_worst_note(metrics)}; in brackets A12 = P(optimiser > {baseline}), * "
        f"Holm-adjusted Wilcoxon p < {SIGNIFICANCE:g} against {baseline}, paired by seed; last "
        "row: Friedman's p (seeds). A metric on which every optimiser has the same rank is "
        "named on a line instead."
    )


def _assemble(
    tables: _Tables, blocks: list[tuple[Block, str]]
) -> tuple[dict[str, str], dict[str, tuple[str, ...]]]:
    texts, columns = {}, {}
    for block, what in blocks:
        texts[block.heading], shown = tables.block(block, what)
        columns[block.heading] = tuple(shown)
    return texts, columns


def swarm_section(runs: pd.DataFrame) -> Section:
    """Per (N, graph) cell, the optimisers' metrics, off the complete graph against the
    complete graph at the same N; the optimisers ranked across all cells."""
    frame = prepare(runs)
    # two scenarios of one N on one graph (e.g. two 5-UAV formations) keep their own cells
    labels = frame.groupby(["n_uav", "graph"])["scenario"].transform("nunique")
    shared = labels > 1
    frame.loc[shared, "graph"] = frame["graph"] + " (" + frame["scenario"] + ")"
    conditions = condition_tests(
        frame, SWARM_METRICS, ["n_uav"], frame["graph"].str.startswith(COMPLETE)
    )
    table = section_table(frame, SWARM_METRICS, conditions)
    graph_order = {g: (not g.startswith(COMPLETE), g) for g in table["graph"].unique()}
    table["graph_order"] = table["graph"].map(graph_order)
    table = _finish(table, ["graph_order", "optimizer", "n_uav"])
    varying = _varying(table)
    tables = _Tables(frame, table, SWARM_METRICS)
    cells = table.drop_duplicates(["trigger", "budget", "scenario"]).sort_values(
        ["n_uav", "graph_order"], kind="stable"
    )
    blocks = []
    for setting in _settings(table):
        here = cells[(cells["trigger"] == setting[0]) & (cells["budget"] == setting[1])]
        for _, cell in here.iterrows():
            versus = pd.notna(cell.get("condition_baseline"))
            heading = (
                f"### N = {cell['n_uav']}, {cell['graph']} graph"
                + (" against the complete graph" if versus else "")
                + _setting_text(setting, varying)
            )
            blocks.append((Block(heading, setting, (cell["scenario"],)), ""))
    texts, columns = _assemble(tables, blocks)
    ranking = overall_ranking(frame, SWARM_METRICS, tables.optimizers)
    intro = _intro(
        "## Swarm: metrics against the number of UAVs",
        "One table per (N, graph) cell: the optimisers as rows, the metrics as columns, each "
        "cell the median over the seeds. Off the complete graph, `median vs the complete "
        "graph's median` at the same N, same optimiser, and A12 = P(graph > complete graph), "
        f"paired by seed; * Holm-adjusted Wilcoxon p < {SIGNIFICANCE:g} (adjusted over the "
        "graphs compared at that N). The bootstrap 95 % CIs of the medians are in swarm.csv. "
        "After the cells, the optimisers ranked across all of them.",
        table,
    )
    ranking_text = "\n".join(_ranking_lines(ranking, frame, SWARM_METRICS, varying))
    return Section(
        name="swarm",
        metrics=SWARM_METRICS,
        runs=frame,
        table=table,
        intro=intro,
        blocks=texts,
        block_columns=columns,
        ranking=ranking,
        ranking_text=ranking_text,
    )


def robustness_section(runs: pd.DataFrame) -> Section:
    """Per setting, the optimisers' metrics in the nominal scenario, then under each
    disturbance or fault against the nominal runs; the optimisers' ranks per block."""
    frame = prepare(runs)
    group = ["scenario_name", "n_uav", "graph"]
    conditions = condition_tests(frame, ROBUSTNESS_METRICS, group, frame["family"] == NOMINAL)
    table = _finish(
        section_table(frame, ROBUSTNESS_METRICS, conditions),
        ["level_order", "optimizer"],
    )
    varying = _varying(table)
    tables = _Tables(frame, table, ROBUSTNESS_METRICS)
    several = table["scenario_name"].nunique() > 1
    levels = table.drop_duplicates(["trigger", "budget", "scenario"])
    blocks = []
    for setting in _settings(table):
        here = levels[(levels["trigger"] == setting[0]) & (levels["budget"] == setting[1])]
        for _, level in here.iterrows():
            base = f"{level['scenario_name']}: " if several else ""
            name = f"{level['family']} {level['scenario']}"
            if level["scenario"] == level["family"]:  # the nominal run labelled "nominal"
                name = level["scenario"]
            versus = " against nominal" if pd.notna(level.get("condition_baseline")) else ""
            suffix = _setting_text(setting, varying)
            heading = f"### {base}{name}{versus}{suffix}"
            block = Block(heading, setting, (level["scenario"],), (level["scenario"],))
            blocks.append((block, f"{level['scenario']}{suffix}"))
    texts, columns = _assemble(tables, blocks)
    intro = _intro(
        "## Robustness: metrics against the disturbance level",
        "One table per disturbance or fault level and trigger setting: the optimisers as rows, "
        "the metrics as columns, each cell the median over the seeds, `median vs the nominal "
        "median`, same optimiser and trigger, and A12 = P(level > nominal), paired by seed; * "
        f"Holm-adjusted Wilcoxon p < {SIGNIFICANCE:g} (adjusted over the levels compared with "
        "the nominal one). The bootstrap 95 % CIs of the medians are in robustness.csv. "
        + _rank_legend(ROBUSTNESS_METRICS, tables.baseline, "the level"),
        table,
    )
    return Section(
        name="robustness",
        metrics=ROBUSTNESS_METRICS,
        runs=frame,
        table=table,
        intro=intro,
        blocks=texts,
        block_columns=columns,
    )


def obstacles_section(runs: pd.DataFrame) -> Section:
    """Per scenario, the optimisers' intrusions, collisions, separation and tracking with the
    penalties on against off; the optimisers' ranks with each penalty setting."""
    frame = prepare(runs)
    conditions = condition_tests(
        frame, OBSTACLE_METRICS, ["scenario_name", "n_uav"], frame["penalties"] == PENALTIES_OFF
    )
    table = section_table(frame, OBSTACLE_METRICS, conditions)
    table["penalties_order"] = table["penalties"] == PENALTIES_OFF
    table = _finish(table, ["scenario_name", "penalties_order", "optimizer"])
    varying = _varying(table)
    penalties = table.drop_duplicates("scenario").set_index("scenario")["penalties"]
    tables = _Tables(frame, table, OBSTACLE_METRICS, ("penalties", lambda s: penalties[s]))
    blocks = []
    for setting in _settings(table):
        here = table[(table["trigger"] == setting[0]) & (table["budget"] == setting[1])]
        for (name, n_uav), scenario in here.groupby(["scenario_name", "n_uav"], sort=False):
            labels = list(dict.fromkeys(scenario["scenario"]))
            on = [s for s in labels if penalties[s] != PENALTIES_OFF] or labels
            off = [s for s in labels if s not in on]
            suffix = _setting_text(setting, varying)
            compared = " and ".join(penalties[s] for s in on)
            versus = " against off" if off else ""
            heading = f"### {name}, {n_uav} UAVs: penalties {compared}{versus}{suffix}"
            block = Block(heading, setting, tuple(on), tuple(labels))
            blocks.append((block, f"{name}, each penalty setting{suffix}"))
    texts, columns = _assemble(tables, blocks)
    intro = _intro(
        "## Obstacles: penalties on and off",
        "One table per scenario: the optimisers as rows, the metrics as columns, each cell the "
        "median over the seeds with the penalties on in the local cost, `median vs the median "
        "with the penalties off`, same scenario and optimiser, and A12 = P(on > off), paired "
        f"by seed; * Holm-adjusted Wilcoxon p < {SIGNIFICANCE:g}. The bootstrap 95 % CIs of "
        "the medians are in obstacles.csv. "
        + _rank_legend(OBSTACLE_METRICS, tables.baseline, "each penalty setting"),
        table,
    )
    return Section(
        name="obstacles",
        metrics=OBSTACLE_METRICS,
        runs=frame,
        table=table,
        intro=intro,
        blocks=texts,
        block_columns=columns,
    )


def _groups_with(frame: pd.DataFrame, group: list[str], mask: pd.Series) -> pd.DataFrame:
    """The rows of every ``group`` that has a row in ``mask``."""
    wanted = frame.loc[mask, group].drop_duplicates()
    return frame.merge(wanted, on=group, how="inner")


def sections(results: pd.DataFrame) -> list[Section]:
    """The sections that apply to ``results``, each on the runs it compares.

    - robustness: the scenarios (by registered name, N and graph) with a disturbed or faulty
      run, all of their runs;
    - obstacles: the scenarios (by registered name and N) with obstacles or a penalty, all of
      their runs;
    - swarm: the undisturbed runs without obstacles and penalties, when they differ in the
      number of UAVs or the graph.
    """
    frame = scenario_columns(results)
    if "n_uav" not in frame:
        return []
    frame = frame.dropna(subset=["n_uav"]).astype({"n_uav": int})
    found = []
    plain = (frame["family"] == NOMINAL) & (frame["penalties"] == PENALTIES_OFF)
    plain &= frame["obstacles"] == 0
    swarm = frame[plain]
    if swarm["n_uav"].nunique() > 1 or swarm["graph"].nunique() > 1:
        found.append(swarm_section(swarm))
    disturbed = frame["family"] != NOMINAL
    if disturbed.any():
        group = ["scenario_name", "n_uav", "graph"]
        found.append(robustness_section(_groups_with(frame, group, disturbed)))
    penalised = (frame["penalties"] != PENALTIES_OFF) | (frame["obstacles"] > 0)
    if penalised.any():
        group = ["scenario_name", "n_uav"]
        found.append(obstacles_section(_groups_with(frame, group, penalised)))
    return found


# --- files and figures ----------------------------------------------------------------------


def section_figures(section: Section) -> dict[str, object]:
    """The figures of a section by file stem (Matplotlib figures; the caller saves them)."""
    from formation_bench.analysis import figures

    runs = section.runs
    drawn = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # seaborn on newer matplotlib
        if section.name == "swarm":
            for metric in section.metrics:
                drawn[f"swarm_{metric}"] = figures.metric_vs_n_figure(runs, metric)
        elif section.name == "robustness":
            for metric in section.metrics:
                drawn[f"robustness_{metric}"] = figures.metric_vs_level_figure(runs, metric)
        else:
            drawn["obstacles_separation"] = figures.safety_metrics_figure(runs)
    return drawn


def write_sections(results: pd.DataFrame, folder: Path, *, figures: bool = True) -> str:
    """Write every applicable section's Markdown, CSV (and ``<section>_ranking.csv`` where it
    ranks across its blocks) and figures; returns their Markdown."""
    texts = []
    for section in sections(results):
        (folder / f"{section.name}.md").write_text(section.markdown + "\n")
        section.table.drop(columns=["is_optimizer_baseline", "seeds"]).to_csv(
            folder / f"{section.name}.csv", index=False
        )
        if not section.ranking.empty:
            section.ranking.to_csv(folder / f"{section.name}_ranking.csv", index=False)
        texts.append(section.markdown)
        if figures:
            from formation_bench.analysis.figures import save_report_figure

            (folder / "figures").mkdir(parents=True, exist_ok=True)
            for stem, figure in section_figures(section).items():
                save_report_figure(figure, folder / "figures" / f"{stem}.png")
    return "\n\n".join(texts)
