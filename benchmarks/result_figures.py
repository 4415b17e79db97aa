"""Seaborn figures of a results table (one row per run), shared by the report and the notebook.

Each function takes the table as :func:`benchmarks.store.load_results` returns
it and returns a Matplotlib figure; the caller saves or shows it.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import pandas as pd
import seaborn as sns

METRIC_LABELS = {
    "tracking_error_max_m": "tracking error max after settling (m)",
    "tracking_error_rms_m": "tracking error RMS after settling (m)",
    "distance_error_max_m_max": "largest distance error after settling (m)",
    "closed_loop_cost": "closed-loop cost, eq. (11) summed (m² s)",
    "solves_total": "solves per run, all UAVs",
    "solve_time_median_s": "median solve time (s)",
    "nfev_total": "objective evaluations per run",
}
"""Axis labels, with units, of the headline metrics."""

LOG_SCALE = frozenset({"closed_loop_cost", "solve_time_median_s", "nfev_total"})
"""Metrics that may spread over orders of magnitude: a log axis when they do (> 20x)."""


def label(metric: str) -> str:
    """Axis label of a metric (its name when no label is known)."""
    return METRIC_LABELS.get(metric, metric)


def _order(frame: pd.DataFrame, factor: str, by: str | None = None) -> list:
    if by is not None and by in frame.columns:
        return list(frame.groupby(factor)[by].median().sort_values().index)
    return sorted(frame[factor].unique(), key=str)


def distribution_figure(
    frame: pd.DataFrame, metric: str, factor: str = "optimizer", block: str | None = None
) -> plt.Figure:
    """Box plot with every run as a point, one box per level of ``factor``, best median first.

    With ``block`` (a column), one panel per value of it.
    """
    sns.set_theme(style="whitegrid")
    order = _order(frame, factor, metric)
    panels = sorted(frame[block].unique(), key=str) if block else [None]
    width = max(6.5, 0.6 * len(order) + 3.5)
    fig, axes = plt.subplots(
        1, len(panels), figsize=(width * len(panels), 5.4), squeeze=False, constrained_layout=True
    )
    for ax, panel in zip(axes[0], panels, strict=True):
        data = frame if panel is None else frame[frame[block] == panel]
        sns.boxplot(
            data=data, x=factor, y=metric, order=order, ax=ax, showfliers=False, color="#b7cde3"
        )
        sns.stripplot(
            data=data, x=factor, y=metric, order=order, ax=ax, color="#1f3b5a", size=3, alpha=0.6
        )
        values = data[metric][data[metric] > 0]
        if metric in LOG_SCALE and len(values) and values.max() > 20 * values.min():
            ax.set_yscale("log")
        ax.set_xlabel(factor)
        ax.set_ylabel(label(metric) if ax is axes[0][0] else "")
        ax.tick_params(axis="x", rotation=35)
        for tick in ax.get_xticklabels():
            tick.set_horizontalalignment("right")
        if panel is not None:
            ax.set_title(f"{block} = {panel}", fontsize=10)
    fig.suptitle(f"per {factor}, one point per run", fontsize=10)
    return fig


def solve_time_ecdf_figure(
    frame: pd.DataFrame, factor: str = "optimizer", block: str | None = None
) -> plt.Figure:
    """ECDF of every single solve time of every run, one curve per level of ``factor``.

    With ``block`` (a column), one panel per value of it.
    """
    sns.set_theme(style="whitegrid")
    columns = [factor, "solve_times_s", *([block] if block else [])]
    solves = frame[columns].explode("solve_times_s").dropna()
    solves["solve_times_s"] = solves["solve_times_s"].astype(float)
    solves = solves[solves["solve_times_s"] > 0]
    order = _order(solves, factor, "solve_times_s")
    # distinct colours for every curve: tab20 repeats past 20 levels
    if len(order) <= 10:
        palette = sns.color_palette("tab10", len(order))
    elif len(order) <= 20:
        palette = sns.color_palette("tab20", len(order))
    else:
        palette = sns.color_palette("husl", len(order))
    panels = sorted(solves[block].unique(), key=str) if block else [None]
    fig, axes = plt.subplots(1, len(panels), figsize=(8.5 * len(panels), 4.8), squeeze=False,
                             sharey=True, constrained_layout=True)  # fmt: skip
    for ax, panel in zip(axes[0], panels, strict=True):
        data = solves if panel is None else solves[solves[block] == panel]
        sns.ecdfplot(data=data, x="solve_times_s", hue=factor, hue_order=order, ax=ax,
                     log_scale=True, palette=palette, legend=ax is axes[0][-1])  # fmt: skip
        ax.set_xlabel("solve time (s), log scale")
        ax.set_ylabel("fraction of solves")
        if panel is not None:
            ax.set_title(f"{block} = {panel}", fontsize=10)
    legend = axes[0][-1].get_legend()
    if legend is not None:
        legend.set_title(factor)
        sns.move_legend(axes[0][-1], "upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    fig.suptitle("Solve-time ECDF (every solve of every run)", fontsize=11)
    return fig


def solves_figure(frame: pd.DataFrame, factor: str = "optimizer") -> plt.Figure:
    """Solves per run (all UAVs) per level of ``factor``, with and without the trigger."""
    sns.set_theme(style="whitegrid")
    data = frame.assign(
        trigger=frame["trigger"].map(lambda t: "on" if t in (True, "on") else "off")
    )
    order = _order(data, factor, "solves_total")
    fig, ax = plt.subplots(figsize=(max(6.0, 0.55 * len(order) + 3), 4.4), constrained_layout=True)
    sns.boxplot(
        data=data,
        x=factor,
        y="solves_total",
        hue="trigger",
        hue_order=["off", "on"],
        order=order,
        ax=ax,
        showfliers=False,
    )
    ax.set_xlabel(factor)
    ax.set_ylabel(label("solves_total"))
    ax.tick_params(axis="x", rotation=35)
    for tick in ax.get_xticklabels():
        tick.set_horizontalalignment("right")
    ax.legend(title="trigger", fontsize=8)
    ax.set_title("Solves per run with and without the event trigger", fontsize=11)
    return fig


def trigger_conditions_figure(frame: pd.DataFrame, factor: str = "optimizer") -> plt.Figure:
    """Mean solves per run at which each trigger condition held, runs with the trigger only."""
    sns.set_theme(style="whitegrid")
    reasons = [c for c in frame.columns if c.startswith("trigger_") and c != "trigger"]
    triggered = frame[frame["trigger"].map(lambda t: t in (True, "on"))]
    order = _order(triggered, factor, "solves_total")
    counts = triggered.groupby(factor)[reasons].mean().reindex(order)
    counts.columns = [c.removeprefix("trigger_") for c in counts.columns]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.55 * len(order) + 3), 4.4), constrained_layout=True)
    counts.plot.bar(ax=ax, rot=35)
    ax.set_xlabel(factor)
    ax.set_ylabel("solves per run at which the condition held")
    ax.legend(
        title="condition (eqs. 15-18)", fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0)
    )
    ax.set_title("Why the UAVs re-solved (trigger on)", fontsize=11)
    return fig
