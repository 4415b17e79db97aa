"""What the analysis notebook computes, as tested functions.

The notebook (``notebooks/analysis.ipynb``) only calls these and draws; every
sentence under a figure comes from a function here that reads the data, so
the words change when the results do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from formation_bench.analysis.cells import share_cell
from formation_bench.analysis.paper import PAPER_FIGURES
from formation_bench.analysis.suite_sections import Section, sections
from formation_bench.experiments.store import load_results, load_traces
from formation_bench.instances.instants import record_instants
from formation_bench.mpc.families import NOMINAL
from formation_bench.mpc.metrics import column_label
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import Budget, get_optimizer
from formation_bench.pipeline.record import stored_scenarios

COMPARED_METRICS = (
    "steady_state_cost",
    "tracking_error_max_m",
    "distance_error_max_m_max",
    "transient_cost",
)
"""The metrics the notebook compares the optimisers and the ablation variants on: the steady
state and the errors after the settle time first, the start-up apart."""


def convergence_seed_count(value: str | int) -> int:
    """The notebook's ``CONVERGENCE_SEEDS`` (set by ``FORMATION_BENCH_CONVERGENCE_SEEDS`` or
    a parameter), checked before any section runs: a whole number of at least 1."""
    try:
        count = int(str(value).strip())
    except ValueError:
        count = 0
    if count < 1:
        raise ValueError(
            "FORMATION_BENCH_CONVERGENCE_SEEDS (CONVERGENCE_SEEDS) must be a whole number "
            f">= 1, got {value!r}"
        )
    return count


def find_stores(results_dir: Path | str) -> dict[str, Path]:
    """Every results store below ``results_dir`` (itself included), by folder name."""
    root = Path(results_dir)
    candidates = [root, *sorted(p for p in root.iterdir() if p.is_dir())] if root.is_dir() else []
    return {p.name: p for p in candidates if (p / "runs").is_dir()}


def load_all(results_dir: Path | str) -> pd.DataFrame:
    """The runs of every store below ``results_dir`` as one table, with a ``store`` column."""
    stores = find_stores(results_dir)
    if not stores:
        raise FileNotFoundError(
            f"no results store (a folder with runs/) in {results_dir}; "
            "run `formation-bench sweep SUITE --out DIR` first"
        )
    frames = [load_results(path).assign(store=name) for name, path in stores.items()]
    return pd.concat(frames, ignore_index=True)


def suite_runs(results: pd.DataFrame, suite: str) -> pd.DataFrame:
    """The runs of one suite (empty if the folder holds none)."""
    return results[results["suite"] == suite].reset_index(drop=True)


def scenario_key(runs: pd.DataFrame) -> pd.Series:
    """Per run, the scenario it ran: its stored resolved scenario (``scenario_config``), or its
    registered name and overrides where a record holds no resolved one."""
    named = runs["scenario_name"].astype(str) + " " + runs["scenario_overrides"].astype(str)
    if "scenario_config" not in runs:
        return named
    return runs["scenario_config"].where(runs["scenario_config"].notna(), named).astype(str)


def on_one_scenario(suites: dict[str, pd.DataFrame]) -> tuple[pd.DataFrame, str]:
    """The runs of ``suites`` (by name, the first the one a section is about) pooled only
    where they ran the same scenario, and a sentence saying which were pooled.

    Runs of different scenarios (a different length, say) must not share a box: the pooled
    runs are those of the first suite's scenario (its most frequent one), and a suite with
    none of them is left out by name."""
    present = {name: runs for name, runs in suites.items() if not runs.empty}
    if not present:
        return pd.DataFrame(), "No runs to pool."
    first, *_ = present
    keys = {name: scenario_key(runs) for name, runs in present.items()}
    kept_key = keys[first].value_counts().index[0]
    kept = {name: runs[keys[name] == kept_key] for name, runs in present.items()}
    pooled = [name for name, runs in kept.items() if not runs.empty]
    left = [name for name in present if name not in pooled or len(kept[name]) < len(present[name])]
    frame = pd.concat([kept[name] for name in pooled], ignore_index=True)
    names = " and ".join(f"`{name}`" for name in pooled)
    text = f"Runs of the {names} suite{'s' if len(pooled) > 1 else ''} on one scenario"
    if left:
        dropped = sum(len(present[n]) - len(kept[n]) for n in left)
        text += (
            f"; {dropped} runs of the "
            + " and ".join(f"`{name}`" for name in left)
            + f" suite{'s' if len(left) > 1 else ''} ran another scenario than "
            f"`{first}`'s and are left out, so that no box pools runs of different scenarios"
        )
    return frame, text + "."


def paper_figures_table(runs: pd.DataFrame) -> pd.DataFrame:
    """Every figure the paper reports beside its median and worst value over the seeds."""
    rows = []
    for figure in PAPER_FIGURES:
        subset = runs[runs["trigger"] == figure.trigger]
        if subset.empty:
            continue
        values = np.array([figure.measured(r) for _, r in subset.iterrows()])
        rows.append(
            {
                "run": "with trigger" if figure.trigger else "without trigger",
                "figure": figure.label,
                "paper": f"<= {figure.limit:g} {figure.unit}",
                "median": float(np.median(values)),
                "worst": float(values.max()),
                "holds on": f"{int(np.sum(values <= figure.limit))}/{values.size} seeds",
            }
        )
    return pd.DataFrame(rows)


def paper_sentence(table: pd.DataFrame) -> str:
    """What :func:`paper_figures_table` shows, in one sentence."""
    held = table[table["holds on"].map(lambda s: s.split("/")[0] == s.split("/")[1].split()[0])]
    missed = table.drop(held.index)
    text = f"{len(held)} of {len(table)} reported figures hold on every seed"
    if len(missed):
        worst = missed.iloc[0]
        text += (
            f"; the others do not, e.g. {worst['run']} {worst['figure']}: median "
            f"{worst['median']:.3g}, worst {worst['worst']:.3g} "
            f"against the paper's {worst['paper']}"
        )
    return text + "."


def representative_run(
    results_dir: Path | str, runs: pd.DataFrame, trigger: bool
) -> tuple[pd.Series, pd.DataFrame]:
    """The run (row and stored trace) whose tracking error is the median over the seeds."""
    subset = runs[runs["trigger"] == trigger].sort_values("tracking_error_max_m")
    if subset.empty:
        raise ValueError(f"no runs with trigger={trigger}")
    row = subset.iloc[(len(subset) - 1) // 2]
    store = find_stores(results_dir)[row["store"]]
    return row, load_traces(store, [row["run_key"]])


def distribution_sentence(results: pd.DataFrame, metric: str, by: str = "optimizer") -> str:
    """Which level has the lowest and highest median of ``metric``, and by how much."""
    medians = results.groupby(by)[metric].median().sort_values()
    low, high = medians.index[0], medians.index[-1]
    return (
        f"Lowest median {column_label(metric)}: {low} ({medians.iloc[0]:.3g}); "
        f"highest: {high} ({medians.iloc[-1]:.3g}), over {results.groupby(by).size().min()}"
        f"-{results.groupby(by).size().max()} runs each."
    )


def solve_time_sentence(results: pd.DataFrame, by: str = "optimizer") -> str:
    """Median and 95th percentile of single solve times per level, fastest and slowest."""
    solves = results[[by, "solve_times_s"]].explode("solve_times_s").dropna()
    solves["solve_times_s"] = solves["solve_times_s"].astype(float)
    summary = solves.groupby(by)["solve_times_s"].quantile([0.5, 0.95]).unstack()
    summary = summary.sort_values(0.5)
    fast, slow = summary.iloc[0], summary.iloc[-1]
    return (
        f"Fastest median solve: {summary.index[0]} ({1e3 * fast[0.5]:.2f} ms, p95 "
        f"{1e3 * fast[0.95]:.2f} ms); slowest: {summary.index[-1]} ({1e3 * slow[0.5]:.2f} ms, "
        f"p95 {1e3 * slow[0.95]:.2f} ms)."
    )


@dataclass(frozen=True)
class AblationEffect:
    """One ablation variant against the full modified BSO, on one metric and trigger setting."""

    variant: str
    trigger: str
    metric: str
    a12: float
    p_holm: float


def ablation_effects(wilcoxon: pd.DataFrame, metric: str) -> list[AblationEffect]:
    """Effect sizes and Holm-adjusted p-values of the report's paired tests for ``metric``."""
    rows = wilcoxon[wilcoxon["metric"] == metric]
    level = "optimizer" if "optimizer" in rows.columns else rows.columns[0]
    return [
        AblationEffect(
            r[level], str(r.get("trigger", "")), metric, float(r["a12"]), float(r["p_holm"])
        )
        for _, r in rows.iterrows()
    ]


def ablation_sentence(effects: list[AblationEffect], alpha: float = 0.05) -> str:
    """Which switches change the metric significantly (Holm-adjusted), and in which direction."""
    if not effects:
        return "No paired comparisons are available for this metric."
    parts = []
    for e in effects:
        if e.p_holm < alpha:
            direction = "higher" if e.a12 > 0.5 else "lower"
            parts.append(
                f"{e.variant} (trigger {e.trigger}) is {direction} (A12 = {e.a12:.2f}, "
                f"p = {e.p_holm:.3g})"
            )
    metric = column_label(effects[0].metric)
    if not parts:
        return (
            f"No variant differs from the full modified BSO in {metric} at a Holm-adjusted "
            f"{alpha:g} level (smallest p = {min(e.p_holm for e in effects):.3g})."
        )
    return f"Against the full modified BSO, in {metric}: " + "; ".join(parts) + "."


def convergence_curves(
    optimizer_names: list[str],
    *,
    steps: tuple[int, ...] = (5, 60, 150),
    seeds: int = 5,
    max_evaluations: int = 1200,
    n_steps_scenario: int | None = None,
) -> pd.DataFrame:
    """Best cost against evaluations of each optimiser on fixed recorded paper instants.

    The instants are recorded once (a modified-BSO run of the paper scenario
    without trigger); every optimiser then solves each of them from the same
    warm start with ``seeds`` different Generators. The cost is divided by the
    warm start's cost, so instants of different scale share one axis.
    """
    scenario = get_scenario("paper")
    if n_steps_scenario is not None:
        scenario = scenario.with_overrides(n_steps=n_steps_scenario, settle_time_s=0.0)
    steps = tuple(s for s in steps if s < scenario.timing.n_steps)
    instants = record_instants(scenario, get_optimizer("modified-bso"), list(steps), seed=0)
    budget = Budget(max_evaluations=max_evaluations)
    rows = []
    for name in optimizer_names:
        optimizer = get_optimizer(name)
        for inst in instants:
            start_cost = float(inst.problem(inst.warm_start[None])[0])
            for seed in range(seeds):
                rng = np.random.default_rng([inst.step, inst.uav, seed])
                result = optimizer.minimize(
                    inst.problem, inst.problem.bounds, rng, budget, inst.warm_start
                )
                rows.extend(
                    {
                        "optimizer": name,
                        "instant": f"c={inst.step}, UAV {inst.uav + 1}",
                        "seed": seed,
                        "evaluations": int(n),
                        "relative_cost": float(f) / start_cost,
                    }
                    for n, f in zip(result.history_nfev, result.history_fun, strict=True)
                )
    return pd.DataFrame(rows)


def convergence_sentence(curves: pd.DataFrame) -> str:
    """Which optimiser ends lowest, and how far below the warm start."""
    final = curves.sort_values("evaluations").groupby(["optimizer", "instant", "seed"]).last()
    medians = final.groupby("optimizer")["relative_cost"].median().sort_values()
    return (
        f"After the full budget, {medians.index[0]} reaches a median of "
        f"{medians.iloc[0]:.3g} times the warm start's cost and "
        f"{medians.index[-1]} {medians.iloc[-1]:.3g}."
    )


def uav_counts(runs: pd.DataFrame) -> pd.Series:
    """Each run's own number of UAVs: its filled per-UAV solve columns.

    A frame that combines suites has the per-UAV columns of its largest swarm, empty on the
    rows of smaller ones, so the columns alone do not give a run's size.
    """
    return runs.filter(regex=r"^solves_uav\d+$").notna().sum(axis=1)


def trigger_tradeoff(runs: pd.DataFrame) -> pd.DataFrame:
    """Per trigger threshold (the stored scenario's ``eps_p``): solves saved and errors, per
    seed."""
    thresholds = [
        math.nan if scenario is None else scenario.trigger.eps_p
        for scenario in stored_scenarios(runs)
    ]
    frame = runs.assign(
        threshold_m=thresholds,
        solves_saved=1.0 - runs["solves_total"] / (runs["steps"] * uav_counts(runs)),
    )
    frame.loc[~frame["trigger"].astype(bool), "threshold_m"] = 0.0
    return frame


def trigger_sentence(frame: pd.DataFrame) -> str:
    """How much each threshold saves and what it costs in accuracy (medians over seeds)."""
    med = frame.groupby("threshold_m")[
        ["solves_saved", "tracking_error_max_m", "distance_error_max_m_max"]
    ].median()
    parts = [
        f"eps = {t:g} m saves {share_cell(r.solves_saved)} % of solves with tracking "
        f"{r.tracking_error_max_m:.2f} m and formation {r.distance_error_max_m_max:.2f} m"
        for t, r in med.iterrows()
        if t > 0
    ]
    base = med.loc[0.0] if 0.0 in med.index else None
    text = "; ".join(parts)
    if base is not None:
        text += (
            f" (no trigger: tracking {base.tracking_error_max_m:.2f} m, formation "
            f"{base.distance_error_max_m_max:.2f} m)"
        )
    return text + "."


def solves_sentence(results: pd.DataFrame) -> str:
    """Median solves per run with and without the trigger, per optimiser."""
    med = results.groupby(["optimizer", "trigger"])["solves_total"].median().unstack()
    parts = []
    for optimizer, row in med.iterrows():
        on = row.get(True, np.nan)
        off = row.get(False, np.nan)
        text = f"{optimizer}: {on:.0f} with trigger" if np.isfinite(on) else f"{optimizer}:"
        if np.isfinite(off):
            text += f"{',' if np.isfinite(on) else ''} {off:.0f} without"
        parts.append(text)
    return "Median solves per run (all UAVs): " + "; ".join(parts) + "."


# --- the suites beyond the paper's scenario --------------------------------------------------


def scenario_section(runs: pd.DataFrame, name: str) -> Section | None:
    """The report section ``name`` (``swarm``, ``robustness`` or ``obstacles``) of ``runs``,
    or None when it does not apply to them (or there are none)."""
    if runs.empty:
        return None
    return next((s for s in sections(runs) if s.name == name), None)


def _medians(section: Section, metric: str, *, one_setting: bool) -> pd.DataFrame:
    """The rows of ``metric`` with a median; with ``one_setting``, of the first trigger setting
    and budget only (the trigger on when there is one)."""
    rows = section.table[section.table["metric"] == metric].dropna(subset=["median"])
    return _first_setting(rows) if one_setting else rows


def _first_setting(rows: pd.DataFrame) -> pd.DataFrame:
    """The rows of the first row's trigger setting and budget."""
    if not len(rows):
        return rows
    first = rows.iloc[0]
    return rows[(rows["trigger"] == first["trigger"]) & (rows["budget"] == first["budget"])]


def swarm_sentence(section: Section, metric: str = "tracking_error_max_m") -> str:
    """How the median of ``metric`` changes from the fewest to the most UAVs on the complete
    graph, per optimiser, and which graph and optimiser have the lowest at the most UAVs (of
    the first trigger setting and budget)."""
    rows = _medians(section, metric, one_setting=True)
    name = column_label(metric)
    if not len(rows):
        return f"No run has a median {name}."
    smallest, largest = int(rows["n_uav"].min()), int(rows["n_uav"].max())
    parts = []
    for optimizer, runs in rows[rows["graph"] == "complete"].groupby("optimizer", sort=False):
        ends = runs.set_index("n_uav")["median"]
        if smallest in ends and largest in ends:
            parts.append(f"{optimizer} {ends[smallest]:.3g} to {ends[largest]:.3g}")
    text = (
        f"On the complete graph, the median {name} goes from N = {smallest} to N = {largest}: "
        + "; ".join(parts)
        + ". "
        if parts
        else ""
    )
    best = rows[rows["n_uav"] == largest].sort_values("median").iloc[0]
    return (
        f"{text}At N = {largest} the lowest median {name} is {best['optimizer']}'s on the "
        f"{best['graph']} graph ({best['median']:.3g})."
    )


def robustness_sentence(section: Section, metric: str = "tracking_error_max_m") -> str:
    """The level that raises the median of ``metric`` most above the nominal one, and how many
    (level, optimiser, trigger) cells are above the nominal in nearly every pairing."""
    rows = _medians(section, metric, one_setting=False)
    name = column_label(metric)
    # each level against its own nominal run: same base scenario, optimiser, trigger and budget
    keys = ["optimizer", "trigger", "budget"]
    nominal = rows[rows["family"] == NOMINAL].set_index(["scenario", *keys])["median"]
    levels = rows[rows["family"] != NOMINAL].copy()
    if "condition_baseline" not in levels or not len(levels):
        return f"No disturbed or faulty run has a median {name} to compare with a nominal one."
    paired = pd.MultiIndex.from_frame(levels[["condition_baseline", *keys]])
    levels["nominal"] = nominal.reindex(paired).to_numpy()
    levels["rise"] = levels["median"] - levels["nominal"]
    if levels["rise"].isna().all():
        return f"No disturbed or faulty run has a nominal run of the same setting ({name})."
    worst = levels.sort_values("rise", ascending=False).iloc[0]
    clear = levels[levels["condition_a12"] >= 0.9]
    return (
        f"The largest rise of the median {name} over the nominal run: {worst['scenario']} "
        f"({worst['family']}) with {worst['optimizer']}, trigger {worst['trigger']}: "
        f"{worst['median']:.3g} against {worst['nominal']:.3g} (A12 {worst['condition_a12']:.2f})."
        f" {len(clear)} of {len(levels)} (level, optimiser, trigger) cells have A12 >= 0.9 "
        "against the nominal run (higher in nearly every pairing of seeds)."
    )


def obstacles_sentence(section: Section) -> str:
    """Median intrusions, collisions and smallest separation with each penalty setting (of the
    first trigger setting and budget)."""
    parts = []
    for (scenario, penalties, optimizer), group in _first_setting(section.table).groupby(
        ["scenario_name", "penalties", "optimizer"], sort=False
    ):
        values = group.set_index("metric")["median"]
        parts.append(
            f"{scenario} with penalties {penalties}, {optimizer}: "
            f"{values.get('obstacle_intrusions', np.nan):.3g} intrusions, "
            f"{values.get('collisions', np.nan):.3g} collisions, smallest separation "
            f"{values.get('min_separation_m', np.nan):.3g} m"
        )
    return "Medians per run: " + "; ".join(parts) + "."
