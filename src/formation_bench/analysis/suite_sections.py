"""Report sections of the suites beyond the paper's scenario: the number of UAVs and the
communication graph (``swarm``), disturbances and communication faults (``robustness``),
obstacle and collision penalties (``obstacles``).

What a run's scenario is (its UAVs, graph, disturbance family, penalties) is read from its
registered name and overrides (:func:`scenario_columns`), never from its label, so every
results folder that varies these gets the section, whatever the suite is called. A section
tabulates a few metrics against its *condition* (N and graph; the disturbance level; the
penalties) with the median and the bootstrap 95 % CI of the median over the seeds, and carries
the report's statistics (:func:`~formation_bench.analysis.comparison.analyse`):

- every condition against its baseline condition (the complete graph at the same N; the
  nominal scenario; the penalties off), same optimiser, trigger and budget, paired by seed:
  Wilcoxon signed-rank, Holm-adjusted over the conditions compared with that baseline, and
  A12 = P(condition > baseline);
- the optimisers within every condition: Friedman's average rank over the seeds that all of
  them ran (1 = lowest value) and its p-value, and every optimiser against the baseline
  optimiser (Wilcoxon, Holm-adjusted, A12).

:func:`write_sections` writes ``<section>.md`` and ``<section>.csv`` (one row per condition,
trigger, budget, optimiser and metric) and the figures, and returns the Markdown that
``report.md`` appends.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from formation_bench.analysis.cells import number_cell, p_cell
from formation_bench.analysis.comparison import analyse, prepare
from formation_bench.analysis.stats import SIGNIFICANCE
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
HEADINGS = {"n_uav": "N", "scenario": "level", "scenario_name": "scenario"}
"""Column headings of the Markdown tables, where the column's name is not one."""

NOMINAL = "nominal"
PENALTIES_OFF = "off"
COMPLETE = "complete"


# --- what each run's scenario is ----------------------------------------------------------------


@dataclass(frozen=True)
class Family:
    """A kind of disturbance or fault: when a scenario has it, and how strongly."""

    name: str
    active: Callable[[Scenario], bool]
    severity: Callable[[Scenario], tuple[float, ...]]
    """Sorts the levels of the family, mildest first."""


FAMILIES = (
    Family(
        "wind",
        lambda s: (
            s.disturbances.gust_std_m_s > 0 or any(w != 0 for w in s.disturbances.wind_mean_m_s)
        ),
        lambda s: (math.hypot(*s.disturbances.wind_mean_m_s), s.disturbances.gust_std_m_s),
    ),
    Family(
        "noise",
        lambda s: (
            max(
                s.disturbances.position_noise_std_m,
                s.disturbances.heading_noise_std_rad,
                s.disturbances.speed_noise_std_m_s,
            )
            > 0
        ),
        lambda s: (
            s.disturbances.position_noise_std_m,
            s.disturbances.heading_noise_std_rad,
            s.disturbances.speed_noise_std_m_s,
        ),
    ),
    Family(
        "packet loss",
        lambda s: s.communication.packet_loss > 0,
        lambda s: (s.communication.packet_loss, s.communication.loss_correlation),
    ),
    Family(
        "delay",
        lambda s: s.communication.delay_steps > 0 or s.communication.delay_jitter_steps > 0,
        lambda s: (s.communication.delay_steps, s.communication.delay_jitter_steps),
    ),
    Family(
        "mismatch",
        lambda s: (
            s.disturbances.plant_accel_gain != 1.0 or s.disturbances.plant_turn_rate_gain != 1.0
        ),
        lambda s: (
            abs(1.0 - s.disturbances.plant_accel_gain),
            abs(1.0 - s.disturbances.plant_turn_rate_gain),
        ),
    ),
)
"""The disturbance and fault families of the robustness section, in its order."""


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
    active = [k for k, family in enumerate(FAMILIES) if family.active(scenario)]
    if not active:
        family, family_index, severity = NOMINAL, -1, ()
    elif len(active) == 1:
        family_index = active[0]
        family = FAMILIES[family_index].name
        severity = FAMILIES[family_index].severity(scenario)
    else:  # several at once: after the single families
        family, family_index = " + ".join(FAMILIES[k].name for k in active), len(FAMILIES)
        severity = tuple(v for k in active for v in FAMILIES[k].severity(scenario))
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
    :data:`FAMILIES`, ``nominal`` or several joined by ``+``), ``penalties``, ``obstacles``,
    ``safety_radius_m``, and ``level_order`` (levels sorted by family, then severity).

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


def _is_true(value: object) -> bool:
    # a merged column of test outcomes holds booleans and NaN (no test)
    return isinstance(value, bool | np.bool_) and bool(value)


def _cell(row: pd.Series, *, versus: bool) -> str:
    if not row["n"]:
        return "–"
    text = (
        f"{number_cell(row['median'])} "
        f"[{number_cell(row['ci_low'])}, {number_cell(row['ci_high'])}]"
    )
    if row["n"] < row["seeds"]:  # some runs have no value (e.g. never settled)
        text += f" (n {row['n']})"
    if versus and pd.notna(row.get("condition_a12")):
        mark = "*" if _is_true(row.get("condition_significant")) else ""
        text += f" A12 {row['condition_a12']:.2f}{mark}"
    return text


def _rank_cell(row: pd.Series) -> str:
    rank = row.get("average_rank")
    text = f"{rank:.2f}" if pd.notna(rank) else ""
    if pd.notna(row.get("optimizer_a12")):
        mark = "*" if _is_true(row.get("optimizer_significant")) else ""
        text += f" (A12 {row['optimizer_a12']:.2f}{mark})"
    return text.strip() or ("baseline" if row.get("is_optimizer_baseline") else "–")


def _grid(
    table: pd.DataFrame,
    rows: list[str],
    column: str,
    cell: Callable[[pd.Series], str],
    heading: Callable[[object], str],
    extra: tuple[str, Callable[[pd.DataFrame], str]] | None = None,
) -> list[str]:
    """A Markdown table: one line per value of ``rows`` (in table order), one column per
    value of ``column`` (ascending if numbers, else in table order), ``cell`` of each row of
    ``table``; ``extra`` adds a last column computed from each line's rows."""
    columns = list(dict.fromkeys(table[column]))
    if pd.api.types.is_numeric_dtype(table[column]):
        columns = sorted(columns)
    names = [HEADINGS.get(r, r) for r in rows]
    header = [*names, *(heading(c) for c in columns), *([extra[0]] if extra else [])]
    lines = [
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(rows) + "---:|" * (len(header) - len(rows)),
    ]
    for key, group in table.groupby(rows, sort=False):
        key = key if isinstance(key, tuple) else (key,)
        cells = {r[column]: cell(r) for _, r in group.iterrows()}
        values = [str(k) for k in key] + [cells.get(c, "–") for c in columns]
        if extra:
            values.append(extra[1](group))
        lines.append("| " + " | ".join(values) + " |")
    return [*lines, ""]


def _friedman_cell(group: pd.DataFrame) -> str:
    if "friedman_p" not in group or group["friedman_p"].isna().all():
        return "–"
    return p_cell(float(group["friedman_p"].dropna().iloc[0]))


def _varying(table: pd.DataFrame, columns: tuple[str, ...] = ("trigger", "budget")) -> list[str]:
    return [c for c in columns if table[c].nunique() > 1]


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


def _rank_text(condition: str, metric: str, baseline: str) -> str:
    info = metric_of(metric)
    higher = info is not None and info.better is Better.HIGHER
    worst = " (the worst here: a higher separation is better)" if higher else ""
    return (
        f"Optimiser ranks on `{metric}`: within each {condition}, each optimiser's average "
        f"Friedman rank over the seeds all of them ran, 1 = lowest value{worst}; Friedman p: "
        f"do the optimisers differ; in brackets A12 = P(optimiser > {baseline}), * "
        f"Holm-adjusted Wilcoxon p < {SIGNIFICANCE:g} against {baseline}, paired by seed."
    )


# --- the sections ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Section:
    """One suite section: its long table, Markdown and figure-ready runs."""

    name: str
    title: str
    metrics: tuple[str, ...]
    runs: pd.DataFrame
    """The runs with :func:`scenario_columns` and the factors as the report prints them."""
    table: pd.DataFrame
    """:func:`section_table`, sorted by condition."""
    intro: str
    """The heading and what the tables show (with :func:`power_note`)."""
    parts: dict[str, str]
    """Per metric, its tables (Markdown)."""

    @property
    def markdown(self) -> str:
        return "\n".join([self.intro, *self.parts.values()]).rstrip() + "\n"


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


def _parts(
    table: pd.DataFrame, metrics: tuple[str, ...], tables: Callable[[pd.DataFrame, str], list[str]]
) -> dict[str, str]:
    parts = {}
    for metric in metrics:
        rows = table[table["metric"] == metric]
        if not rows.empty:
            parts[metric] = "\n".join(tables(rows, metric))
    return parts


def swarm_section(runs: pd.DataFrame) -> Section:
    """Metrics against the number of UAVs per graph and optimiser; graphs against the
    complete graph at the same N; optimiser ranks per N and graph."""
    frame = prepare(runs)
    # two scenarios of one N on one graph (e.g. two 5-UAV formations) keep their own lines
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
    baseline = _baseline_optimizer(table)

    def tables(rows: pd.DataFrame, metric: str) -> list[str]:
        ranked = rows.sort_values(["n_uav", "graph_order"], kind="stable")
        return [
            f"**{metric}** against N",
            "",
            *_grid(
                rows,
                [*varying, "graph", "optimizer"],
                "n_uav",
                lambda r: _cell(r, versus=True),
                lambda n: f"N = {n}",
            ),
            _rank_text("(N, graph)", metric, baseline),
            "",
            *_grid(
                ranked,
                [*varying, "n_uav", "graph"],
                "optimizer",
                _rank_cell,
                str,
                ("Friedman p", _friedman_cell),
            ),
        ]

    intro = _intro(
        "## Swarm: metrics against the number of UAVs",
        "Median [bootstrap 95 % CI of the median] over the seeds, per graph and optimiser. "
        "Off the complete graph, A12 = P(graph > complete graph) at the same N, same "
        f"optimiser, paired by seed; * Holm-adjusted Wilcoxon p < {SIGNIFICANCE:g} (adjusted "
        "over the graphs compared at that N).",
        table,
    )
    parts = _parts(table, SWARM_METRICS, tables)
    return Section("swarm", "Swarm", SWARM_METRICS, frame, table, intro, parts)


def robustness_section(runs: pd.DataFrame) -> Section:
    """Metrics per disturbance level against the nominal scenario; optimiser ranks per level."""
    frame = prepare(runs)
    group = ["scenario_name", "n_uav", "graph"]
    conditions = condition_tests(frame, ROBUSTNESS_METRICS, group, frame["family"] == NOMINAL)
    table = _finish(
        section_table(frame, ROBUSTNESS_METRICS, conditions),
        ["level_order", "optimizer"],
    )
    baseline = _baseline_optimizer(table)
    splits = _varying(table)

    def tables(rows: pd.DataFrame, metric: str) -> list[str]:
        lines = []
        for key, part in rows.groupby(splits, sort=False) if splits else [((), rows)]:
            key = key if isinstance(key, tuple) else (key,)
            where = ", ".join(f"{s} {v}" for s, v in zip(splits, key, strict=True))
            lines += [f"**{metric}** per level{', ' + where if where else ''}", ""]
            lines += _grid(
                part, ["family", "scenario"], "optimizer", lambda r: _cell(r, versus=True), str
            )
        return [
            *lines,
            _rank_text("level and trigger", metric, baseline),
            "",
            *_grid(
                rows,
                ["family", "scenario", *splits],
                "optimizer",
                _rank_cell,
                str,
                ("Friedman p", _friedman_cell),
            ),
        ]

    intro = _intro(
        "## Robustness: metrics against the disturbance level",
        "Median [bootstrap 95 % CI of the median] over the seeds. A12 = P(level > nominal), "
        "same optimiser and trigger, paired by seed; * Holm-adjusted Wilcoxon p < "
        f"{SIGNIFICANCE:g} (adjusted over the levels compared with the nominal one).",
        table,
    )
    parts = _parts(table, ROBUSTNESS_METRICS, tables)
    return Section("robustness", "Robustness", ROBUSTNESS_METRICS, frame, table, intro, parts)


def obstacles_section(runs: pd.DataFrame) -> Section:
    """Intrusions, collisions, separation and tracking with the penalties on and off."""
    frame = prepare(runs)
    conditions = condition_tests(
        frame, OBSTACLE_METRICS, ["scenario_name", "n_uav"], frame["penalties"] == PENALTIES_OFF
    )
    table = section_table(frame, OBSTACLE_METRICS, conditions)
    table["penalties_order"] = table["penalties"] == PENALTIES_OFF
    table = _finish(table, ["scenario_name", "penalties_order", "optimizer"])
    rows_by = [*_varying(table), "scenario_name", "penalties"]
    baseline = _baseline_optimizer(table)

    def tables(rows: pd.DataFrame, metric: str) -> list[str]:
        return [
            f"**{metric}**",
            "",
            *_grid(rows, rows_by, "optimizer", lambda r: _cell(r, versus=True), str),
            _rank_text("scenario and penalty setting", metric, baseline),
            "",
            *_grid(rows, rows_by, "optimizer", _rank_cell, str, ("Friedman p", _friedman_cell)),
        ]

    intro = _intro(
        "## Obstacles: penalties on and off",
        "Median [bootstrap 95 % CI of the median] over the seeds, per scenario, penalties in "
        "the local cost and optimiser. With a penalty on, A12 = P(on > off), same scenario and "
        f"optimiser, paired by seed; * Holm-adjusted Wilcoxon p < {SIGNIFICANCE:g}.",
        table,
    )
    parts = _parts(table, OBSTACLE_METRICS, tables)
    return Section("obstacles", "Obstacles", OBSTACLE_METRICS, frame, table, intro, parts)


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
    """Write every applicable section's Markdown, CSV and figures; returns their Markdown."""
    texts = []
    for section in sections(results):
        (folder / f"{section.name}.md").write_text(section.markdown + "\n")
        section.table.drop(columns=["is_optimizer_baseline", "seeds"]).to_csv(
            folder / f"{section.name}.csv", index=False
        )
        texts.append(section.markdown)
        if figures:
            from formation_bench.analysis.figures import save_report_figure

            (folder / "figures").mkdir(parents=True, exist_ok=True)
            for stem, figure in section_figures(section).items():
                save_report_figure(figure, folder / "figures" / f"{stem}.png")
    return "\n\n".join(texts)
