"""The report of a results folder: statistics tables (Markdown, CSV) and figures.

One *factor* is compared (by default the optimiser; the trigger when the
folder holds one optimiser but both trigger settings, as the ``paper`` suite
does); the other factors (scenario, trigger, budget, optimiser) form *blocks*,
each reported on its own. Within a block, for every metric:

- per level of the factor: n, median, quartiles, IQR, bootstrap 95 % CI of the median;
- against the baseline level, paired by seed: Wilcoxon signed-rank p-value, Holm-adjusted
  over the block's comparisons for that metric, and the Vargha-Delaney A12
  (P(level > baseline); below 0.5 the level has lower values, better for errors, costs, times);
- across all levels (3 or more): Friedman's test over the seeds present for every
  level, the average ranks (1 = lowest value) and Nemenyi post-hoc p-values.

Files written to the report folder: ``report.md``, ``summary.csv``,
``wilcoxon.csv``, ``friedman.csv``, ``ranks.csv``, ``nemenyi.csv`` and
``figures/*.png`` (metric distributions, solve-time ECDFs, trigger counts). Results that
vary the number of UAVs or the graph, disturb the runs or set obstacles and penalties get the
sections of :mod:`~formation_bench.analysis.suite_sections` too (``swarm.md``,
``robustness.md``, ``obstacles.md``, their CSV files and figures). Results holding a variant
and the configuration it varies (``pso-warm`` and ``pso``) get ``variant_pairs.md`` and
``variant_pairs.csv`` (:mod:`~formation_bench.analysis.variant_pairs`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from formation_bench.analysis import paper_budget, stats
from formation_bench.experiments.store import load_results
from formation_bench.pipeline.record import is_metric_column

FACTORS = ("optimizer", "trigger", "budget", "scenario")
"""Factors a report can compare, in the order the default choice tries them."""

HEADLINE_METRICS = (
    "steady_state_cost",
    "tracking_error_max_m",
    "tracking_error_rms_m",
    "distance_error_max_m_max",
    "transient_cost",
    "settling_time_s",
    "min_separation_m",
    "solves_total",
    "solve_time_median_s",
    "nfev_total",
)
"""Metrics printed on the terminal and plotted; the files hold every metric."""

SIGNIFICANCE = stats.SIGNIFICANCE

NOT_APPLICABLE: dict[str, str] = {
    "summary": "no results: the results folder holds no metric values",
    "wilcoxon": "not applicable: no block holds the baseline and another level to pair with "
    "it by seed",
    "friedman": "not applicable: Friedman's test needs 3 or more levels of the compared factor",
    "ranks": "not applicable: average ranks come with Friedman's test, which needs 3 or more "
    "levels of the compared factor",
    "nemenyi": "not applicable: the Nemenyi post-hoc test needs 3 or more levels of the "
    "compared factor and seeds complete for every level",
}
"""The report's tables, each with the note its CSV file holds when no row applies."""


class ReportError(ValueError):
    """A report that cannot be made as asked (one line, exit 2)."""


def metric_columns(frame: pd.DataFrame) -> list[str]:
    """The declared metrics with one number per run: the headline ones first, then the rest
    in stored order."""
    numeric = [
        c
        for c in frame.columns
        if is_metric_column(c)
        and pd.api.types.is_numeric_dtype(frame[c])
        and not pd.api.types.is_bool_dtype(frame[c])
    ]
    head = [c for c in HEADLINE_METRICS if c in numeric]
    return head + [c for c in numeric if c not in head]


def prepare(frame: pd.DataFrame) -> pd.DataFrame:
    """Results with the factors as strings (trigger as ``on``/``off``); prepared results are
    returned as they are."""
    frame = frame.copy()
    if not frame["trigger"].isin(["on", "off"]).all():
        frame["trigger"] = np.where(frame["trigger"].astype(bool), "on", "off")
    for factor in FACTORS:
        frame[factor] = frame[factor].astype(str)
    return frame


def choose_factor(frame: pd.DataFrame, compare: str | None) -> str:
    if compare is not None:
        if compare not in FACTORS:
            raise ReportError(
                f"--compare: unknown factor {compare!r}; allowed: {', '.join(FACTORS)}"
            )
        return compare
    for factor in FACTORS:
        if frame[factor].nunique() > 1:
            return factor
    return "optimizer"


def levels_of(frame: pd.DataFrame, factor: str) -> list[str]:
    """Levels in a stable order (as the results are sorted, i.e. by suite order of names)."""
    return list(dict.fromkeys(frame[factor]))


def choose_baseline(frame: pd.DataFrame, factor: str, baseline: str | None) -> str:
    levels = levels_of(frame, factor)
    if baseline is not None:
        if baseline not in levels:
            raise ReportError(
                f"--baseline: {baseline!r} is not a {factor} in these results; "
                f"allowed: {', '.join(levels)}"
            )
        return baseline
    preferred = {"optimizer": "modified-bso", "trigger": "off", "scenario": "paper"}.get(factor)
    return preferred if preferred in levels else levels[0]


@dataclass
class Report:
    """Everything a report holds."""

    factor: str
    baseline: str
    block_factors: list[str]
    metrics: list[str]
    summary: pd.DataFrame
    wilcoxon: pd.DataFrame
    friedman: pd.DataFrame
    ranks: pd.DataFrame
    nemenyi: pd.DataFrame
    notes: list[str] = field(default_factory=list)


def analyse(
    results: pd.DataFrame,
    *,
    baseline: str | None = None,
    compare: str | None = None,
    metrics: list[str] | None = None,
) -> Report:
    """Statistics of a results table (as
    :func:`formation_bench.experiments.store.load_results` returns it), of every
    metric column or of ``metrics`` (those of them the table holds)."""
    frame = prepare(results)
    factor = choose_factor(frame, compare)
    base = choose_baseline(frame, factor, baseline)
    block_factors = [f for f in FACTORS if f != factor]
    every = metric_columns(frame)
    metrics = every if metrics is None else [m for m in metrics if m in every]
    summary_rows, test_rows, friedman_rows, rank_rows, nemenyi_rows = [], [], [], [], []
    notes = []
    for block_values, block in frame.groupby(block_factors, sort=False):
        block_key = dict(zip(block_factors, block_values, strict=True))
        levels = levels_of(block, factor)
        compared = [level for level in levels if level != base]
        if base not in levels and len(levels) > 1:
            notes.append(f"{describe_block(block_key, frame)}: no {base!r} runs, no paired tests")
        for metric in metrics:
            table = block.pivot_table(index="seed", columns=factor, values=metric, aggfunc="first")
            table = table.reindex(columns=levels)
            for k, level in enumerate(levels):
                s = stats.describe(table[level].to_numpy(), seed=k)
                summary_rows.append({**block_key, factor: level, "metric": metric, **vars(s)})
            if base in levels and compared:
                rows = []
                for level in compared:
                    pair = table[[level, base]].dropna()
                    statistic, p = stats.wilcoxon_paired(
                        pair[level].to_numpy(), pair[base].to_numpy()
                    )
                    rows.append(
                        {
                            **block_key,
                            factor: level,
                            "baseline": base,
                            "metric": metric,
                            "n_pairs": len(pair),
                            "median_difference": float(np.median(pair[level] - pair[base]))
                            if len(pair)
                            else math.nan,
                            "wilcoxon_statistic": statistic,
                            "p": p,
                            "a12": stats.a12(table[level].dropna(), table[base].dropna()),
                        }
                    )
                adjusted = stats.holm([r["p"] for r in rows])
                for row, p_holm in zip(rows, adjusted, strict=True):
                    row["p_holm"] = p_holm
                    row["significant"] = bool(p_holm < SIGNIFICANCE)
                test_rows.extend(rows)
            if len(levels) >= 3:
                result = stats.friedman(table)
                friedman_rows.append(
                    {
                        **block_key,
                        "metric": metric,
                        "n_seeds": result.n_blocks,
                        "k": len(levels),
                        "statistic": result.statistic,
                        "p": result.pvalue,
                    }
                )
                for level, rank in result.average_ranks.items():
                    rank_rows.append(
                        {**block_key, factor: level, "metric": metric, "average_rank": rank}
                    )
                if result.nemenyi is not None:
                    for a in levels:
                        for b in levels:
                            if a < b:
                                nemenyi_rows.append(
                                    {
                                        **block_key,
                                        "metric": metric,
                                        f"{factor}_a": a,
                                        f"{factor}_b": b,
                                        "p": float(result.nemenyi.loc[a, b]),
                                    }
                                )
    return Report(
        factor=factor,
        baseline=base,
        block_factors=block_factors,
        metrics=metrics,
        summary=pd.DataFrame(summary_rows),
        wilcoxon=pd.DataFrame(test_rows),
        friedman=pd.DataFrame(friedman_rows),
        ranks=pd.DataFrame(rank_rows),
        nemenyi=pd.DataFrame(nemenyi_rows),
        notes=notes,
    )


def describe_block(block_key: dict[str, str], frame: pd.DataFrame) -> str:
    """The factors that vary in the results, e.g. ``scenario paper, trigger on``."""
    varying = [f for f in block_key if frame[f].nunique() > 1]
    parts = [f"{f} {block_key[f]}" for f in varying]
    if not parts:
        parts = [f"{f} {block_key[f]}" for f in ("scenario", "trigger") if f in block_key]
    return ", ".join(parts)


# --- Markdown -------------------------------------------------------------------------------


def _num(value: float) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if abs(value) >= 1000 or float(value).is_integer():
        return f"{value:.0f}"
    return f"{value:.4g}"


def _p(value: float) -> str:
    if value is None or not math.isfinite(value):
        return "–"
    return f"{value:.2e}" if value < 1e-3 else f"{value:.3f}"


def to_markdown(
    report: Report, results: pd.DataFrame, *, metrics: list[str] | None = None, title: str = ""
) -> str:
    """The report as Markdown: one section per block, one table per metric."""
    frame = prepare(results)
    factor, base = report.factor, report.baseline
    chosen = [m for m in (metrics or report.metrics) if m in report.metrics]
    lines = [f"# {title or 'Sweep report'}", ""]
    lines.append(
        f"{len(frame)} runs; compared: {factor} (baseline {base!r}); levels: "
        f"{', '.join(levels_of(frame, factor))}. Paired by seed; Wilcoxon signed-rank "
        f"(two-sided), Holm-adjusted per block and metric; A12 = P({factor} > baseline) "
        "(< 0.5: lower values than the baseline). CI: bootstrap 95 % CI of the median. "
        "Rank: Friedman average rank, 1 = lowest."
    )
    lines.append("")
    for note in report.notes:
        lines += [f"Note: {note}", ""]
    tables = _Tables(report)
    for block_values, _ in frame.groupby(report.block_factors, sort=False):
        block_key = dict(zip(report.block_factors, block_values, strict=True))
        lines += [f"## {describe_block(block_key, frame) or 'all runs'}", ""]
        for metric in chosen:
            lines += _metric_table(report, block_key, metric, tables)
    return "\n".join(lines).rstrip() + "\n"


def repeat_section(results: pd.DataFrame) -> str:
    """How to repeat any run of the report on its own, with the first run's command."""
    if "command" not in results or results.empty:
        return ""
    first = results.iloc[0]
    return (
        "\n## Repeating a run\n\n"
        "Every run's row (`runs/<run_key>.parquet`, column `command`) holds the "
        "`formation-bench run` command that repeats it exactly: the same configuration, "
        "budget and random streams (its `--seed` is the run's SeedSequence entropy). "
        f"The first run here ({first['optimizer']}, {first['scenario']}, trigger "
        f"{'on' if first['trigger'] else 'off'}, seed {first['seed']}):\n\n"
        f"```\n{first['command']}\n```\n"
    )


class _Tables:
    """The report's tables split by block and metric once: filtering them for every block and
    metric took 6.4 s per Markdown pass on the swarm suite's 14 blocks and 76 metrics, the
    split 2.5-3 s (same text)."""

    NAMES = ("summary", "wilcoxon", "ranks", "friedman")

    def __init__(self, report: Report) -> None:
        self.block_factors = report.block_factors
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
        key = (*(block_key[f] for f in self.block_factors), metric)
        return self.groups[name].get(key, table.iloc[0:0])


def _metric_table(
    report: Report, block_key: dict[str, str], metric: str, tables: _Tables
) -> list[str]:
    factor = report.factor
    summary = tables.select("summary", block_key, metric).set_index(factor)
    tests = tables.select("wilcoxon", block_key, metric)
    tests = tests.set_index(factor) if not tests.empty else tests
    ranks = tables.select("ranks", block_key, metric)
    ranks = ranks.set_index(factor) if not ranks.empty else ranks
    friedman = tables.select("friedman", block_key, metric)
    header = f"| {factor} | n | median | IQR | 95 % CI | p (Holm) | A12 |"
    rule = "|---|---:|---:|---:|---|---:|---:|"
    if not ranks.empty:
        header += " rank |"
        rule += "---:|"
    lines = [f"**{metric}**", "", header, rule]
    for level, row in summary.iterrows():
        if level in getattr(tests, "index", []):
            test = tests.loc[level]
            mark = " *" if test["significant"] else ""
            p_cell, a_cell = _p(test["p_holm"]) + mark, f"{test['a12']:.2f}"
        else:
            p_cell = "baseline" if level == report.baseline else "–"
            a_cell = "–"
        cells = [
            str(level),
            str(row["n"]),
            _num(row["median"]),
            _num(row["iqr"]),
            f"{_num(row['ci_low'])} – {_num(row['ci_high'])}",
            p_cell,
            a_cell,
        ]
        if not ranks.empty:
            cells.append(f"{ranks.loc[level, 'average_rank']:.2f}" if level in ranks.index else "–")
        lines.append("| " + " | ".join(cells) + " |")
    if not friedman.empty:
        f = friedman.iloc[0]
        lines.append("")
        lines.append(
            f"Friedman: chi2 = {_num(f['statistic'])}, p = {_p(f['p'])}, "
            f"{int(f['n_seeds'])} seeds x {int(f['k'])} levels."
        )
    lines.append("")
    return lines


# --- figures -------------------------------------------------------------------------------


def write_figures(report: Report, results: pd.DataFrame, folder: Path) -> list[Path]:
    """Seaborn figures: headline-metric distributions, solve-time ECDFs, trigger counts."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # seaborn on newer matplotlib
        return _write_figures(report, results, folder)


def _write_figures(report: Report, results: pd.DataFrame, folder: Path) -> list[Path]:
    import matplotlib.pyplot as plt

    from formation_bench.analysis.figures import (
        deadline_figure,
        distribution_figure,
        solve_time_ecdf_figure,
        trigger_conditions_figure,
    )

    folder.mkdir(parents=True, exist_ok=True)
    frame = prepare(results)
    factor = report.factor
    frame["block"] = [
        describe_block(dict(zip(report.block_factors, values, strict=True)), frame) or "all runs"
        for values in frame[report.block_factors].itertuples(index=False)
    ]
    block = "block" if frame["block"].nunique() > 1 else None
    written = []
    for metric in [m for m in HEADLINE_METRICS if m in report.metrics]:
        figure = distribution_figure(frame, metric, factor, block=block)
        written.append(_save(figure, folder / f"distribution_{metric}.png", plt))
    if "solve_times_s" in frame.columns:
        figure = solve_time_ecdf_figure(frame, factor, block=block)
        written.append(_save(figure, folder / "solve_time_ecdf.png", plt))
    if "budget_deadline_ms" in frame and frame["budget_deadline_ms"].nunique() > 1:
        figure = deadline_figure(frame, factor="optimizer" if factor == "budget" else factor)
        written.append(_save(figure, folder / "deadline_quality.png", plt))
    reasons = [c for c in frame.columns if c.startswith("trigger_") and c != "trigger"]
    if reasons and (frame["trigger"] == "on").any():
        figure = trigger_conditions_figure(frame, factor)
        written.append(_save(figure, folder / "trigger_counts.png", plt))
    return written


def _save(figure, path: Path, plt) -> Path:
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path


# --- the command --------------------------------------------------------------------------


def write_paper_budget(results: pd.DataFrame, folder: Path) -> str:
    """Write the budget-the-paper-needs tables; returns the report section."""
    runs = paper_budget.runs_table(results)
    table = paper_budget.budget_table(runs)
    smallest = paper_budget.smallest_budgets(table)
    figures = paper_budget.figure_table(runs)
    section = paper_budget.to_markdown(table, smallest, figures)
    (folder / "paper_budget.md").write_text(section)
    table.to_csv(folder / "paper_budget.csv", index=False)
    figures.to_csv(folder / "paper_budget_figures.csv", index=False)
    # the form shipped with the package, from which reproduce names the budget
    runs.to_csv(folder / "paper_budget_runs.csv", index=False)
    return section


def make_report(
    results_dir: Path | str,
    out: Path | str | None = None,
    *,
    baseline: str | None = None,
    compare: str | None = None,
    figures: bool = True,
) -> tuple[Report, str, Path]:
    """Analyse ``results_dir``, write every file; returns the report, its headline Markdown
    and the report folder (``results_dir/report`` unless ``out`` is given)."""
    results = load_results(results_dir)
    report = analyse(results, baseline=baseline, compare=compare)
    folder = Path(out) if out is not None else Path(results_dir) / "report"
    folder.mkdir(parents=True, exist_ok=True)
    suite = ", ".join(sorted(results["suite"].unique())) if "suite" in results else ""
    title = f"Sweep report: {suite}" if suite else "Sweep report"
    markdown = to_markdown(report, results, title=title)
    if paper_budget.applies(results):
        markdown += "\n" + write_paper_budget(results, folder)
    # imported here: the sections module builds on this one
    from formation_bench.analysis.suite_sections import write_sections

    suite_sections = write_sections(results, folder, figures=figures)
    if suite_sections:
        markdown += "\n" + suite_sections + "\n"
    from formation_bench.analysis import variant_pairs

    pairs = variant_pairs.pair_table(results)
    if not pairs.empty:
        pairs_markdown = variant_pairs.to_markdown(pairs)
        (folder / "variant_pairs.md").write_text(pairs_markdown)
        pairs.to_csv(folder / "variant_pairs.csv", index=False)
        markdown += "\n" + pairs_markdown
    markdown += repeat_section(results)
    (folder / "report.md").write_text(markdown)
    for name, reason in NOT_APPLICABLE.items():
        table = getattr(report, name)
        # an empty CSV reads as a failure: a table that does not apply says why instead
        written = table if len(table) else pd.DataFrame({"note": [reason]})
        written.to_csv(folder / f"{name}.csv", index=False)
    if figures:
        write_figures(report, results, folder / "figures")
    headline = to_markdown(report, results, metrics=list(HEADLINE_METRICS), title=title)
    return report, headline, folder
