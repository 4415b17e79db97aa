# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.6
#   kernelspec:
#     display_name: Python 3 (ipykernel)
#     language: python
#     name: python3
# ---

# %% [markdown]
# # formation-bench: analysis of stored results
#
# This notebook reads the results of `formation-bench sweep` runs and draws the
# paper's figures, the optimiser comparison, the ablation of the modified BSO, the
# trigger trade-off, and the scenarios beyond the paper: swarms on communication
# graphs, disturbances and faults, obstacles. It computes no metric itself: the
# metrics come from the results store, and the statistics from
# `formation_bench.analysis.report` (and its suite sections). The sentence
# under each figure is computed from the data.
#
# Produce the results (each suite's results page in the documentation says how long it
# took, when and on which machine):
#
# ```bash
# for suite in paper ablation comparison trigger swarm robustness obstacles; do
#     formation-bench sweep $suite --out results/$suite
# done
# ```
#
# A section whose suite is missing says so and is skipped.

# %% tags=["parameters"]
import os

# The folder that holds the results stores (one subfolder per suite).
RESULTS_DIR = os.environ.get("FORMATION_BENCH_RESULTS", "../results")
# Seeds per recorded instant for the convergence curves (section 3).
CONVERGENCE_SEEDS = os.environ.get("FORMATION_BENCH_CONVERGENCE_SEEDS", "5")

# %%
# %matplotlib inline
import matplotlib.pyplot as plt
import pandas as pd
from IPython.display import Markdown, display

from formation_bench.analysis import figures, run_figures
from formation_bench.analysis import notebook as analysis
from formation_bench.analysis.figures import (
    distribution_figure,
    metric_vs_level_figure,
    metric_vs_n_figure,
    safety_metrics_figure,
    solve_time_ecdf_figure,
    solves_figure,
)
from formation_bench.analysis.report import analyse
from formation_bench.mpc.scenario import get_scenario

pd.set_option("display.precision", 3)
CONVERGENCE_SEEDS = analysis.convergence_seed_count(CONVERGENCE_SEEDS)
results = analysis.load_all(RESULTS_DIR)
display(
    Markdown(
        f"Loaded {len(results)} runs from {RESULTS_DIR}: "
        + ", ".join(f"{s} ({n})" for s, n in results.groupby("suite").size().items())
    )
)


def say(text: str) -> None:
    display(Markdown(text))


def show(fig: plt.Figure) -> None:
    """Embed the figure (works with any backend, also headless Agg) and free it."""
    display(fig)
    plt.close(fig)


# %% [markdown]
# ## 1. The paper reproduced
#
# The `paper` suite: the paper scenario with the modified BSO, without and with
# the trigger. The figures show the run whose tracking error is the median over
# the seeds.

# %%
paper = analysis.suite_runs(results, "paper")
if paper.empty:
    say("No `paper` suite in this folder: section 1 skipped.")
else:
    table = analysis.paper_figures_table(paper)
    display(table)
    say(analysis.paper_sentence(table))

# %%
if not paper.empty:
    desired_by_name = run_figures.named_desired_distances(get_scenario("paper"))
    for trigger, numbers in ((False, (3, 4)), (True, (5, 6))):
        if not (paper["trigger"] == trigger).any():
            continue
        row, trace = analysis.representative_run(RESULTS_DIR, paper, trigger)
        settle = float(row["settle_time_s"])
        show(figures.trajectory_figure(trace))
        say(
            f"Fig. {numbers[0]} ({'with' if trigger else 'without'} trigger, seed {row['seed']}): "
            + figures.trajectory_sentence(trace, settle)
        )
        show(figures.states_figure(trace, desired_by_name, settle))
        say(f"Fig. {numbers[1]}: " + figures.states_sentence(trace, desired_by_name, settle))
        if trigger:
            show(figures.trigger_figure(trace))
            say("Fig. 7: " + figures.trigger_sentence(trace))

# %% [markdown]
# ## 2. Optimiser comparison
#
# The `comparison` suite: every registered optimiser at one evaluation budget per
# solve, on the paper scenario with the trigger. Ranked by the steady state (eq. 11 from
# the settle time on, and the errors after it); the closed-loop cost from t = 0 is
# almost all start-up, so the transient cost is shown apart.

# %%
comparison = analysis.suite_runs(results, "comparison")
if comparison.empty:
    say("No `comparison` suite in this folder: section 2 skipped.")
else:
    for metric in analysis.COMPARED_METRICS:
        show(distribution_figure(comparison, metric, "optimizer"))
        say(analysis.distribution_sentence(comparison, metric))

# %%
if not comparison.empty:
    show(solve_time_ecdf_figure(comparison, "optimizer"))
    say(analysis.solve_time_sentence(comparison))

# %%
# the paper suite adds the runs without the trigger, where it ran the comparison's scenario
with_and_without, pooled = analysis.on_one_scenario({"comparison": comparison, "paper": paper})
if not with_and_without.empty:
    say(pooled)
    show(solves_figure(with_and_without))
    say(analysis.solves_sentence(with_and_without))

# %%
if not comparison.empty:
    # the paper's method, and the strongest black-box method of the earlier comparison
    present = set(comparison["optimizer"])
    baselines = [b for b in ("modified-bso", "cma-es") if b in present] or None
    report = analyse(comparison, baseline=baselines)
    say(
        "Statistics against " + " and ".join(f"`{b}`" for b in report.baselines)
        + " (paired by seed, Wilcoxon signed-rank, Holm-adjusted per baseline; A12 < 0.5: "
        "lower than the baseline):"
    )
    display(report.wilcoxon[report.wilcoxon["metric"].isin(analysis.COMPARED_METRICS)])
    display(report.friedman)

# %% [markdown]
# ## 3. Ablation of the modified BSO
#
# The `ablation` suite: the modified BSO with each modification switched off,
# both off, and the raw (unnormalised) weights of eq. (9), at one evaluation
# budget, paired by seed against the full modified BSO.

# %%
ablation = analysis.suite_runs(results, "ablation")
if ablation.empty:
    say("No `ablation` suite in this folder: section 3 skipped.")
else:
    ablation_report = analyse(ablation, baseline="modified-bso")
    for metric in analysis.COMPARED_METRICS:
        effects = analysis.ablation_effects(ablation_report.wilcoxon, metric)
        display(pd.DataFrame([vars(e) for e in effects]))
        say(analysis.ablation_sentence(effects))

# %%
if not ablation.empty:
    show(distribution_figure(ablation, "distance_error_max_m_max", "optimizer"))
    say(analysis.distribution_sentence(ablation, "distance_error_max_m_max"))

# %%
if not ablation.empty:
    variants = sorted(ablation["optimizer"].unique())
    curves = analysis.convergence_curves(variants, seeds=CONVERGENCE_SEEDS)
    show(figures.convergence_figure(curves))
    say(analysis.convergence_sentence(curves))

# %% [markdown]
# ## 4. Trigger trade-off
#
# The `trigger` suite sweeps the thresholds eps_p = eps_O; the runs without the
# trigger come from the `paper` suite.

# %%
trigger_runs = analysis.suite_runs(results, "trigger")
if trigger_runs.empty:
    say("No `trigger` suite in this folder: section 4 skipped.")
else:
    baseline = paper[~paper["trigger"].astype(bool)] if not paper.empty else paper
    tradeoff = analysis.trigger_tradeoff(pd.concat([trigger_runs, baseline], ignore_index=True))
    show(figures.trigger_tradeoff_figure(tradeoff))
    say(analysis.trigger_sentence(tradeoff))


# %% [markdown]
# ## 5. Swarms and communication graphs
#
# The `swarm` suite: 3 (the paper), 5, 10 and 20 UAVs on the complete graph, a ring,
# the 3 nearest UAVs and a 35 m radio range. Median and quartiles over the seeds against
# the number of UAVs; the tables give the bootstrap CI of the median, the A12 of each
# graph against the complete graph at the same N, and the optimisers' Friedman ranks.

# %%
swarm = analysis.scenario_section(analysis.suite_runs(results, "swarm"), "swarm")
if swarm is None:
    say("No `swarm` suite in this folder: section 5 skipped.")
else:
    for metric in ("tracking_error_max_m", "distance_error_rms_m"):
        show(metric_vs_n_figure(swarm.runs, metric))
        say(analysis.swarm_sentence(swarm, metric))
    say(swarm.markdown)

# %% [markdown]
# ## 6. Robustness: wind, noise, lost and late plans, model mismatch
#
# The `robustness` suite: the paper scenario with one disturbance or fault at a time,
# each level against the nominal run (same optimiser and trigger, paired by seed).

# %%
robustness = analysis.scenario_section(analysis.suite_runs(results, "robustness"), "robustness")
if robustness is None:
    say("No `robustness` suite in this folder: section 6 skipped.")
else:
    show(metric_vs_level_figure(robustness.runs, "tracking_error_max_m"))
    say(analysis.robustness_sentence(robustness, "tracking_error_max_m"))
    say(robustness.markdown)

# %% [markdown]
# ## 7. Obstacles and collisions
#
# The `obstacles` suite: `paper-obstacles` with its obstacle and collision penalties on
# and off, and `swarm-10` with the collision penalty on and off.

# %%
obstacles = analysis.scenario_section(analysis.suite_runs(results, "obstacles"), "obstacles")
if obstacles is None:
    say("No `obstacles` suite in this folder: section 7 skipped.")
else:
    show(safety_metrics_figure(obstacles.runs))
    say(analysis.obstacles_sentence(obstacles))
    say(obstacles.markdown)
