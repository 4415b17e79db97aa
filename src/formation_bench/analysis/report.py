"""The report of a results folder: statistics tables (Markdown, CSV) and figures.

The statistics are :func:`~formation_bench.analysis.comparison.analyse`'s: one factor
compared (by default the optimiser) within blocks of the others, per metric: the levels'
medians and bootstrap CIs, each level against the baseline paired by seed (Wilcoxon,
Holm-adjusted, A12), and with 3 or more levels Friedman's test, average ranks and Nemenyi
post-hoc p-values.

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

import warnings
from pathlib import Path

import pandas as pd

from formation_bench.analysis import paper_budget, variant_pairs
from formation_bench.analysis.block_table import BlockTables, block_lines
from formation_bench.analysis.comparison import (
    Report,
    analyse,
    check_compared,
    describe_block,
    levels_of,
    prepare,
)

# the command line takes the error of a report that cannot be made as asked from here
from formation_bench.analysis.comparison import ReportError as ReportError
from formation_bench.analysis.suite_sections import write_sections
from formation_bench.experiments.store import load_results
from formation_bench.mpc.metrics import headline_metrics

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


# --- Markdown -------------------------------------------------------------------------------


def to_markdown(
    report: Report, results: pd.DataFrame, *, metrics: list[str] | None = None, title: str = ""
) -> str:
    """The report as Markdown: one section per block, its configurations as rows and its
    metrics as columns, split into tables that fit the page (:mod:`~formation_bench.analysis.
    block_table`). Without ``metrics``,
    every metric: the headline ones first, then the others under "Further metrics"."""
    frame = prepare(results)
    factor = report.factor
    bases = " and ".join(repr(b) for b in report.baselines)
    chosen = [m for m in (metrics or report.metrics) if m in report.metrics]
    headline = [m for m in headline_metrics() if m in chosen] if metrics is None else chosen
    further = [m for m in chosen if m not in headline]
    lines = [f"# {title or 'Sweep report'}", ""]
    lines.append(
        f"{len(frame)} runs; compared: {factor} (baseline {bases}); levels: "
        f"{', '.join(levels_of(frame, factor))}. Each block below compares the levels at one "
        "setting of the other factors: one table of values with a column per metric (its unit "
        "in the header), then the Friedman ranks and the paired tests against each baseline "
        "with the same rows and columns; metrics that do not fit the page's width continue in "
        "further tables of the same rows. A metric with one value in every run of a block has "
        "no column; the line under the values names it."
    )
    lines.append("")
    for note in report.notes:
        lines += [f"Note: {note}", ""]
    tables = BlockTables(report)
    for block_values, block in frame.groupby(report.block_factors, sort=False):
        block_key = dict(zip(report.block_factors, block_values, strict=True))
        lines += [f"## {describe_block(block_key, frame) or 'all runs'}", ""]
        lines += block_lines(tables, block_key, block, headline)
        if further:
            lines += ["### Further metrics", ""]
            lines += block_lines(tables, block_key, block, further)
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


# --- figures -------------------------------------------------------------------------------


def write_figures(report: Report, results: pd.DataFrame, folder: Path) -> list[Path]:
    """Seaborn figures: headline-metric distributions, solve-time ECDFs, trigger counts."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # seaborn on newer matplotlib
        return _write_figures(report, results, folder)


def _write_figures(report: Report, results: pd.DataFrame, folder: Path) -> list[Path]:
    # seaborn and scipy.stats take seconds to import: only when drawing
    from formation_bench.analysis.figures import (
        deadline_figure,
        distribution_figure,
        save_report_figure,
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
    for metric in [m for m in headline_metrics() if m in report.metrics]:
        figure = distribution_figure(frame, metric, factor, block=block)
        written.append(save_report_figure(figure, folder / f"distribution_{metric}.png"))
    if "solve_times_s" in frame.columns:
        figure = solve_time_ecdf_figure(frame, factor, block=block)
        written.append(save_report_figure(figure, folder / "solve_time_ecdf.png"))
    if "budget_deadline_ms" in frame and frame["budget_deadline_ms"].nunique() > 1:
        figure = deadline_figure(frame, factor="optimizer" if factor == "budget" else factor)
        written.append(save_report_figure(figure, folder / "deadline_quality.png"))
    reasons = [c for c in frame.columns if c.startswith("trigger_") and c != "trigger"]
    if reasons and (frame["trigger"] == "on").any():
        figure = trigger_conditions_figure(frame, factor)
        written.append(save_report_figure(figure, folder / "trigger_counts.png"))
    return written


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
    baseline: str | list[str] | tuple[str, ...] | None = None,
    compare: str | None = None,
    figures: bool = True,
) -> tuple[Report, str, Path]:
    """Analyse ``results_dir``, write every file; returns the report, its headline Markdown
    and the report folder (``results_dir/report`` unless ``out`` is given)."""
    results = load_results(results_dir)
    check_compared(results, compare)
    report = analyse(results, baseline=baseline, compare=compare)
    folder = Path(out) if out is not None else Path(results_dir) / "report"
    folder.mkdir(parents=True, exist_ok=True)
    suite = ", ".join(sorted(results["suite"].unique())) if "suite" in results else ""
    title = f"Sweep report: {suite}" if suite else "Sweep report"
    markdown = to_markdown(report, results, title=title)
    if paper_budget.applies(results):
        markdown += "\n" + write_paper_budget(results, folder)
    suite_sections = write_sections(results, folder, figures=figures)
    if suite_sections:
        markdown += "\n" + suite_sections + "\n"
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
    headline = to_markdown(report, results, metrics=list(headline_metrics()), title=title)
    return report, headline, folder
