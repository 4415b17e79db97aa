"""Every figure formation-bench draws, in one place.

Two kinds of input:

- the long trace of ONE run (see :func:`formation_bench.pipeline.outputs.trace_table`):
  figures like the paper's Figs. 3-7 (:func:`trajectory_figure`, :func:`states_figure`,
  :func:`trigger_figure`);
- a results table, one row per run (as
  :func:`~formation_bench.experiments.store.load_results` returns it):
  distributions, solve-time ECDFs, solve counts, trigger conditions, convergence
  curves and the trigger trade-off.

Each function returns a Matplotlib figure; the caller saves or shows it. The run figures
live in :mod:`~formation_bench.analysis.run_figures` (no seaborn import) and are
re-exported here.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import seaborn as sns
from matplotlib.ticker import LogFormatter

# the figures of one run are drawn without seaborn; re-exported so that every figure is here
from formation_bench.analysis.cells import share_cell
from formation_bench.analysis.run_figures import (  # noqa: F401
    save,
    states_figure,
    trajectory_figure,
    trigger_figure,
)
from formation_bench.analysis.run_figures import wide as _wide
from formation_bench.mpc.families import NOMINAL
from formation_bench.mpc.metrics import column_label, log_scale, pair_names


def _settled(frame: pd.DataFrame, settle_time_s: float) -> pd.DataFrame:
    return frame[frame["time_s"] >= settle_time_s - 1e-9]


def trajectory_sentence(frame: pd.DataFrame, settle_time_s: float = 10.0) -> str:
    """How far the formation centre strays from the reference, before and after settling."""
    x, y = _wide(frame, "x_m"), _wide(frame, "y_m")
    reference = frame[frame["uav"] == frame["uav"].min()].set_index("time_s")
    error = np.hypot(x.mean(axis=1) - reference["ref_x_m"], y.mean(axis=1) - reference["ref_y_m"])
    settled = error[error.index >= settle_time_s - 1e-9]
    return (
        f"the formation centre starts {error.iloc[0]:.1f} m from the reference, strays up to "
        f"{error.max():.1f} m while the formation forms, and stays within {settled.max():.2f} m "
        f"of it after {settle_time_s:g} s."
    )


def states_sentence(
    frame: pd.DataFrame, desired_distances: dict[str, float], settle_time_s: float
) -> str:
    """The largest distance error of each pair after settling, and the speed spread at the end."""
    x, y = _wide(frame, "x_m"), _wide(frame, "y_m")
    keep = x.index >= settle_time_s - 1e-9
    errors = []
    for name, i, j in pair_names(x.shape[1]):
        distance = np.hypot(x.iloc[:, i] - x.iloc[:, j], y.iloc[:, i] - y.iloc[:, j])
        errors.append(f"{name} {np.abs(distance[keep] - desired_distances[name]).max():.2f} m")
    speed = _wide(frame, "speed_m_s").iloc[-1]
    return (
        f"after {settle_time_s:g} s the largest distance errors are "
        + ", ".join(errors)
        + f"; at the end the speeds differ by {speed.max() - speed.min():.2f} m/s."
    )


def trigger_sentence(frame: pd.DataFrame) -> str:
    """Solves per UAV and how they thin out after the start-up."""
    solved = frame[frame["solved"]]
    steps = int(frame["step"].max())
    counts = solved.groupby("uav").size().reindex(sorted(frame["uav"].unique()), fill_value=0)
    half = frame["time_s"].max() / 2
    early = solved[solved["time_s"] < half].shape[0]
    late = solved[solved["time_s"] >= half].shape[0]
    return (
        "the UAVs solve " + ", ".join(f"{n}" for n in counts) + f" times of {steps} "
        f"({share_cell(1 - counts.mean() / steps)} % saved on average); "
        f"{early} solves fall in the first half of the run and {late} in the second."
    )


# --- figures of a results table (one row per run) ----------------------------------------


def save_report_figure(figure: plt.Figure, path: Path) -> Path:
    """Save a figure of the report as PNG, cropped to what it draws, and free it."""
    figure.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path


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
    missing = int(frame[metric].isna().sum())
    for ax, panel in zip(axes[0], panels, strict=True):
        data = frame if panel is None else frame[frame[block] == panel]
        # a run without a value (e.g. one that never settled) has no point to draw
        data = data.dropna(subset=[metric])
        shown = [level for level in order if level in set(data[factor])]
        if not shown:
            ax.text(0.5, 0.5, "no values", ha="center", va="center", transform=ax.transAxes)
            continue
        sns.boxplot(
            data=data, x=factor, y=metric, order=shown, ax=ax, showfliers=False, color="#b7cde3"
        )
        sns.stripplot(
            data=data, x=factor, y=metric, order=shown, ax=ax, color="#1f3b5a", size=3, alpha=0.6
        )
        values = data[metric][data[metric] > 0]
        if log_scale(metric) and len(values) and values.max() > 20 * values.min():
            ax.set_yscale("log")
        ax.set_xlabel(factor)
        ax.set_ylabel(column_label(metric) if ax is axes[0][0] else "")
        ax.tick_params(axis="x", rotation=35)
        for tick in ax.get_xticklabels():
            tick.set_horizontalalignment("right")
        if panel is not None:
            ax.set_title(f"{block} = {panel}", fontsize=10)
    left_out = f"; {missing} runs without a value left out" if missing else ""
    fig.suptitle(f"per {factor}, one point per run{left_out}", fontsize=10)
    return fig


def deadline_figure(
    frame: pd.DataFrame,
    metrics: tuple[str, ...] = ("steady_state_cost", "tracking_error_max_m", "deadline_misses"),
    factor: str = "optimizer",
) -> plt.Figure:
    """Each level's median (and quartiles) of ``metrics`` against the per-solve deadline.

    Only runs with a deadline are drawn; the deadline axis is logarithmic.
    """
    sns.set_theme(style="whitegrid")
    data = frame.dropna(subset=["budget_deadline_ms"])
    shown = [m for m in metrics if m in data.columns]
    fig, axes = plt.subplots(
        1, len(shown), figsize=(5.2 * len(shown), 4.4), squeeze=False, constrained_layout=True
    )
    for ax, metric in zip(axes[0], shown, strict=True):
        for level, runs in data.groupby(factor, sort=True):
            quartiles = runs.groupby("budget_deadline_ms")[metric].quantile([0.25, 0.5, 0.75])
            table = quartiles.unstack()
            line = ax.plot(table.index, table[0.5], marker="o", label=str(level))[0]
            ax.fill_between(
                table.index, table[0.25], table[0.75], color=line.get_color(), alpha=0.15
            )
        ax.set_xscale("log")
        deadlines = sorted(data["budget_deadline_ms"].unique())
        ax.set_xticks(deadlines, [f"{d:g}" for d in deadlines])
        ax.minorticks_off()
        ax.set_xlabel("per-solve deadline (ms)")
        ax.set_ylabel(column_label(metric))
    axes[0][0].legend(fontsize=8)
    fig.suptitle(f"median and quartiles per {factor} over the seeds", fontsize=10)
    return fig


def score_ecdf_figure(curves: pd.DataFrame) -> plt.Figure:
    """Share of (trial, target) pairs reached against evaluations, one panel per budget, as
    COCO and IOHprofiler draw runtime distributions."""
    fig = _step_panels_per_budget(
        curves, "evaluations", "evaluations", "share of (trial, target gap) pairs reached"
    )
    fig.suptitle("targets 1e-1 .. 1e-6 relative gap to J*", fontsize=10)
    return fig


def score_profile_figure(profile: pd.DataFrame) -> plt.Figure:
    """Dolan-More performance profiles of solve time, one panel per budget."""
    return _step_panels_per_budget(
        profile,
        "tau",
        "tau (solve time / best solver's on the instance)",
        "share of instances solved to 1e-3 within tau",
    )


def _step_panels_per_budget(frame: pd.DataFrame, x: str, xlabel: str, ylabel: str) -> plt.Figure:
    """One panel per budget, one step curve of ``share`` against ``x`` per optimiser."""
    sns.set_theme(style="whitegrid")
    budgets = list(dict.fromkeys(frame["budget"]))
    fig, axes = plt.subplots(
        1, len(budgets), figsize=(6 * len(budgets), 4.6), squeeze=False, constrained_layout=True
    )
    for ax, budget in zip(axes[0], budgets, strict=True):
        for optimizer, curve in frame[frame["budget"] == budget].groupby("optimizer"):
            ax.step(curve[x], curve["share"], where="post", label=str(optimizer))
        ax.set_xscale("log")
        ax.set_ylim(0, 1)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_title(f"budget {budget}", fontsize=10)
    axes[0][-1].legend(fontsize=7, loc="lower right")
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
    ax.set_ylabel(column_label("solves_total"))
    ax.tick_params(axis="x", rotation=35)
    for tick in ax.get_xticklabels():
        tick.set_horizontalalignment("right")
    ax.legend(title="trigger", fontsize=8)
    ax.set_title("Solves per run with and without the event trigger", fontsize=11)
    return fig


def trigger_conditions_figure(frame: pd.DataFrame, factor: str = "optimizer") -> plt.Figure:
    """Runs with the trigger on: the solves per run (all UAVs; left panel, one point per run,
    the median as a bar) and the mean solves per run at which each trigger condition held
    (right panel; several conditions may hold at one solve)."""
    sns.set_theme(style="whitegrid")
    reasons = [c for c in frame.columns if c.startswith("trigger_") and c != "trigger"]
    triggered = frame[frame["trigger"].map(lambda t: t in (True, "on"))]
    order = _order(triggered, factor, "solves_total")
    counts = triggered.groupby(factor)[reasons].mean().reindex(order)
    counts.columns = [c.removeprefix("trigger_") for c in counts.columns]
    width = max(6.0, 0.55 * len(order) + 3)
    fig, (solves_ax, ax) = plt.subplots(
        1, 2, figsize=(2 * width, 4.4), constrained_layout=True, sharey=False
    )
    medians = triggered.groupby(factor)["solves_total"].median().reindex(order)
    solves_ax.bar(range(len(order)), medians.to_numpy(), color="0.85", label="median")
    positions = {level: k for k, level in enumerate(order)}
    solves_ax.scatter(
        triggered[factor].map(positions), triggered["solves_total"], s=10, color="C0", label="run"
    )
    solves_ax.set_xticks(range(len(order)), order, rotation=35, ha="right")
    solves_ax.set_xlabel(factor)
    solves_ax.set_ylabel(column_label("solves_total"))
    solves_ax.legend(fontsize=8)
    solves_ax.set_title("Solves per run (trigger on)", fontsize=11)
    counts.plot.bar(ax=ax, rot=35)
    ax.set_xlabel(factor)
    ax.set_ylabel("solves per run at which the condition held")
    ax.legend(
        title="condition (eqs. 15-18)", fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0)
    )
    ax.set_title("Why the UAVs re-solved (trigger on)", fontsize=11)
    return fig


def convergence_figure(curves: pd.DataFrame) -> plt.Figure:
    """Median (over instants and seeds) best cost relative to the warm start, per optimiser."""
    sns.set_theme(style="whitegrid")
    # Each run's best-so-far is a step function of the evaluations: read it on one grid,
    # so that the medians across runs are taken at equal evaluation counts.
    points = np.arange(0, curves["evaluations"].max() + 1, 25)
    pieces = []
    for (optimizer, _, _), run in curves.groupby(["optimizer", "instant", "seed"]):
        index = np.searchsorted(run["evaluations"].to_numpy(), points, side="right") - 1
        known = index >= 0
        pieces.append(
            pd.DataFrame(
                {
                    "optimizer": optimizer,
                    "evaluations": points[known],
                    "relative_cost": run["relative_cost"].to_numpy()[index[known]],
                }
            )
        )
    grid = pd.concat(pieces, ignore_index=True)
    fig, ax = plt.subplots(figsize=(8, 4.5), constrained_layout=True)
    sns.lineplot(
        data=grid,
        x="evaluations",
        y="relative_cost",
        hue="optimizer",
        estimator="median",
        errorbar=("pi", 50),
        ax=ax,
    )
    ax.set_yscale("log")
    ax.set_xlabel("objective evaluations")
    ax.set_ylabel("best cost / warm-start cost")
    ax.set_title("Convergence on recorded paper instants (median, band: 25-75 %)", fontsize=10)
    return fig


def tuning_figure(curves: pd.DataFrame) -> plt.Figure:
    """The best value a tuning found so far, divided by its default value, against the trial
    count: one curve per tuned variant, one panel per objective kind."""
    sns.set_theme(style="whitegrid")
    kinds = list(dict.fromkeys(curves["objective"]))
    fig, axes = plt.subplots(
        1, len(kinds), figsize=(6.5 * len(kinds), 6.4), squeeze=False, constrained_layout=True
    )
    for ax, kind in zip(axes[0], kinds, strict=True):
        groups = list(curves[curves["objective"] == kind].groupby("variant", sort=False))
        # a colour and a dash per variant: the ten default colours would repeat for the twelve
        # families, two curves alike
        colours = sns.color_palette("tab20", len(groups))
        for k, (variant, curve) in enumerate(groups):
            (line,) = ax.step(
                curve["trials"], curve["best_so_far_relative"], where="post", label=variant,
                color=colours[k], linestyle=("-", "--", ":")[k % 3],
            )  # fmt: skip
            flat = curve[curve["flattening_point"]]
            ax.plot(flat["trials"], flat["best_so_far_relative"], "o", color=line.get_color())
        ax.set_xlabel("trials (dot: flattening point)")
        ax.set_ylabel("best value found so far / default value")
        ax.set_title(f"objective: {kind}", fontsize=10)
        # below the panel: above it, the legend hides the first trials' curves
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    return fig


def trigger_tradeoff_figure(frame: pd.DataFrame) -> plt.Figure:
    """Solves saved against tracking and formation error as the thresholds vary."""
    sns.set_theme(style="whitegrid")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharex=True, constrained_layout=True)
    for ax, metric in zip(axes, ("tracking_error_max_m", "distance_error_max_m_max"), strict=True):
        sns.scatterplot(
            data=frame,
            x="solves_saved",
            y=metric,
            hue="threshold_m",
            palette="viridis",
            ax=ax,
            s=30,
            alpha=0.8,
        )
        means = frame.groupby("threshold_m")[["solves_saved", metric]].median()
        ax.plot(means["solves_saved"], means[metric], "k--", lw=1, label="medians")
        ax.set_xlabel("fraction of solves saved by the trigger")
        ax.set_ylabel(column_label(metric))
        ax.legend(title="eps_p = eps_O (m); 0 = no trigger", fontsize=8, title_fontsize=8)
    fig.suptitle("Trigger trade-off: solves saved against accuracy", fontsize=11)
    return fig


# --- figures of the suites beyond the paper's scenario --------------------------------------
# Their frames carry what each run's scenario is (n_uav, graph, family, penalties, ...), as
# formation_bench.analysis.suite_sections.scenario_columns adds it.


def _log_if_spread(ax: plt.Axes, values: pd.Series) -> None:
    """A log axis when every value is positive and they spread over more than 20x."""
    values = values.dropna()
    if len(values) and values.min() > 0 and values.max() > 20 * values.min():
        ax.set_yscale("log")
        # 0.2, 1, 50 rather than 2 x 10^-1; minor ticks labelled only over few decades
        ax.yaxis.set_major_formatter(LogFormatter())
        ax.yaxis.set_minor_formatter(LogFormatter(labelOnlyBase=False))


def metric_vs_n_figure(
    frame: pd.DataFrame, metric: str, hue: str = "optimizer", panel: str = "graph"
) -> plt.Figure:
    """Median (line) and quartiles (band) of ``metric`` over the seeds against the number of
    UAVs, one line per level of ``hue``, one panel per ``panel`` (the complete graph first)."""
    sns.set_theme(style="whitegrid")
    data = frame.dropna(subset=[metric])
    panels = sorted(data[panel].unique(), key=lambda g: (g != "complete", str(g)))
    order = sorted(data[hue].unique(), key=str)
    fig, axes = plt.subplots(
        1,
        len(panels),
        figsize=(4.4 * len(panels), 4.2),
        squeeze=False,
        sharey=True,
        constrained_layout=True,
    )
    for ax, value in zip(axes[0], panels, strict=True):
        sns.lineplot(
            data=data[data[panel] == value],
            x="n_uav",
            y=metric,
            hue=hue,
            hue_order=order,
            estimator="median",
            errorbar=("pi", 50),
            marker="o",
            ax=ax,
            legend=ax is axes[0][-1],
        )
        ax.set_xticks(sorted(data["n_uav"].unique()))
        ax.set_xlabel("UAVs (N)")
        ax.set_ylabel(column_label(metric))
        ax.set_title(f"{panel}: {value}", fontsize=10)
    _log_if_spread(axes[0][0], data[metric])
    if axes[0][-1].get_legend() is not None:
        sns.move_legend(axes[0][-1], "upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    fig.suptitle("median over the seeds, band: quartiles", fontsize=10)
    return fig


def metric_vs_level_figure(frame: pd.DataFrame, metric: str, hue: str = "optimizer") -> plt.Figure:
    """Median and quartiles of ``metric`` over the seeds at every disturbance level, one panel
    per family (the nominal level first in each) and trigger setting, one colour per ``hue``."""
    sns.set_theme(style="whitegrid")
    data = frame.dropna(subset=[metric])
    nominal = list(dict.fromkeys(data.loc[data["family"] == NOMINAL, "scenario"]))
    levels = data[data["family"] != NOMINAL].sort_values("level_order", kind="stable")
    families = list(dict.fromkeys(levels["family"]))
    triggers = sorted(data["trigger"].unique(), key=str, reverse=True)  # "on" first
    order = sorted(data[hue].unique(), key=str)
    widths = [
        len(nominal) + levels.loc[levels["family"] == f, "scenario"].nunique() for f in families
    ]
    fig, axes = plt.subplots(
        len(triggers),
        len(families),
        figsize=(1.1 * sum(widths) + 3, 3.8 * len(triggers)),
        squeeze=False,
        sharey="row",
        gridspec_kw={"width_ratios": widths},
        constrained_layout=True,
    )
    for row, trigger in enumerate(triggers):
        for col, family in enumerate(families):
            ax = axes[row][col]
            shown = nominal + list(
                dict.fromkeys(levels.loc[levels["family"] == family, "scenario"])
            )
            part = data[(data["trigger"] == trigger) & data["scenario"].isin(shown)]
            sns.pointplot(
                data=part,
                x="scenario",
                y=metric,
                hue=hue,
                order=shown,
                hue_order=order,
                estimator="median",
                errorbar=("pi", 50),
                dodge=0.4,
                markersize=4,
                linewidth=1.2,
                ax=ax,
                legend=row == 0 and col == len(families) - 1,
            )
            ax.set_title(f"{family}, trigger {trigger}", fontsize=10)
            ax.set_xlabel("")
            ax.set_ylabel(column_label(metric) if col == 0 else "")
            ax.tick_params(axis="x", rotation=35)
            for tick in ax.get_xticklabels():
                tick.set_horizontalalignment("right")
        # one scale for every row, so that the trigger settings compare at a glance
        _log_if_spread(axes[row][0], data[metric])
    if axes[0][-1].get_legend() is not None:
        sns.move_legend(axes[0][-1], "upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    fig.suptitle("median over the seeds, bars: quartiles", fontsize=10)
    return fig


def safety_metrics_figure(
    frame: pd.DataFrame,
    metrics: tuple[str, ...] = ("min_separation_m", "collisions", "obstacle_intrusions"),
    hue: str = "optimizer",
) -> plt.Figure:
    """Box and strip plots of ``metrics`` per scenario and penalty setting, one colour per
    ``hue``; the smallest-separation panel marks the safety radius."""
    sns.set_theme(style="whitegrid")
    penalties = frame["penalties"].where(frame["penalties"] != "off", "no penalty")
    data = frame.assign(condition=frame["scenario_name"].astype(str) + "\n" + penalties)
    data = data.sort_values(
        ["scenario_name", "penalties"],
        key=lambda c: c.eq("off") if c.name == "penalties" else c,
        kind="stable",
    )
    shown = [m for m in metrics if m in data.columns]
    conditions = list(dict.fromkeys(data["condition"]))
    order = sorted(data[hue].unique(), key=str)
    fig, axes = plt.subplots(
        1,
        len(shown),
        figsize=(max(4.5, 1.5 * len(conditions)) * len(shown), 4.6),
        squeeze=False,
        constrained_layout=True,
    )
    for ax, metric in zip(axes[0], shown, strict=True):
        sns.boxplot(
            data=data,
            x="condition",
            y=metric,
            hue=hue,
            order=conditions,
            hue_order=order,
            showfliers=False,
            saturation=1.0,
            ax=ax,
            legend=ax is axes[0][-1],
        )
        sns.stripplot(
            data=data,
            x="condition",
            y=metric,
            hue=hue,
            order=conditions,
            hue_order=order,
            dodge=True,
            size=3.5,
            edgecolor="#1f3b5a",
            linewidth=0.5,
            ax=ax,
            legend=False,
        )
        if metric == "min_separation_m" and "safety_radius_m" in data:
            for radius in sorted(data["safety_radius_m"].dropna().unique()):
                ax.axhline(radius, color="#b03a2e", lw=1, ls="--")
                ax.annotate(
                    f"safety radius {radius:g} m",
                    (0.01, radius),
                    xycoords=("axes fraction", "data"),
                    fontsize=8,
                    color="#b03a2e",
                    va="bottom",
                )
        ax.set_xlabel("")
        ax.set_ylabel(column_label(metric))
        ax.tick_params(axis="x", labelsize=8)
    if axes[0][-1].get_legend() is not None:
        sns.move_legend(axes[0][-1], "upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    fig.suptitle("one point per run; boxes: quartiles and median", fontsize=10)
    return fig
