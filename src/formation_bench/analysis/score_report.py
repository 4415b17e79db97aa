"""The report of score runs: the leaderboard on the instance library and its statistics.

Two gaps measure a solve's final cost ``f`` against the instance's best-known cost ``J*``
(:mod:`~formation_bench.analysis.scoring`): the relative gap ``(f - J*) / J*`` and
the normalised gap ``(f - J*) / (f_warm - J*)``, the share of the possible improvement (from
the warm start's cost to ``J*``) left. Every target (success rates, ERT, ECDFs, the failure
threshold of the time statistics) is a target of the normalised gap.

The headline is over the non-degenerate instances (a degenerate one has ``J*`` near zero or
a warm start already optimal, so neither gap says anything about the optimiser), each
distinct problem (content hash) counted once: per optimiser and budget, each problem's gaps,
evaluations and solve time are first averaged over its trials (its seeds, and repeats of the
problem in other runs of the same optimiser and budget), and the trial statistics weight each
trial by one over its problem's trials. The leaderboard ranks by the median over problems of
the normalised gap, and shows the median relative gap with its bootstrap 95 % CI, success
rates at :data:`~formation_bench.analysis.scoring.SUCCESS_TARGETS`, median
evaluations and solve time (median, and shifted geometric mean with failures, normalised gap
above :data:`FAILURE_GAP`, charged at the slowest solve at the same budget). Beside it:

- the degenerate stratum: per optimiser, its problems, the share of them on which it returns
  the warm start's cost or better, and the median ``|f - J*|``;
- per phase of the loop (start-up, transient, steady): the median normalised gap;
- paired comparisons, by problem, of the normalised gap: every optimiser against
  :data:`BASELINE`, against the leader (the optimiser with the smallest median normalised
  gap at that budget) and every variant against the configuration it varies (``X-warm``,
  ``X-tuned``, ``X-tuned-loop`` against ``X``; Wilcoxon signed-rank, two-sided,
  Holm-adjusted within each budget and kind of comparison; Vargha-Delaney A12);
- the rank change of each family with a tuned variant ``X-tuned``
  (:func:`rank_change_table`): at the evaluation budget it was tuned at (as its registered
  tuned-variant file records it), its rank with every
  family at its default configuration against its tuned variant's rank with every family
  tuned, and the tuned variant against the family paired by problem (a note names a family
  left out because it or its tuned variant has no score runs at that budget, nor at its own);
- COCO's expected running time to each target, the Dolan-More performance profile of solve
  time and, with figures, the runtime ECDF.

Every table of ``score.md`` fits the documentation's content column, where the leaderboard
page is read (:data:`~formation_bench.analysis.cells.TABLE_WIDTH`): a wider one is split into
tables of the same rows, each repeating the columns that name the row (:func:`fitted_table`).

Files: ``score.md``, ``score_summary.csv``, ``score_degenerate.csv``, ``score_phases.csv``,
``score_paired.csv``, ``score_ert.csv``, ``score_profile.csv``, ``score_rank_change.csv``
and, with figures, ``figures/score_ecdf.png`` and ``figures/score_profile.png``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from formation_bench.analysis import stats
from formation_bench.analysis.cells import TABLE_WIDTH, column_width, share_cell, split_columns
from formation_bench.analysis.scoring import (
    SUCCESS_TARGETS,
    TARGET_GAP,
    TARGETS,
    expected_running_time,
    performance_profile,
    runtime_ecdf,
    shifted_geometric_mean,
    success_rate,
)
from formation_bench.analysis.variant_pairs import VARIANT_KINDS, kind_of, variant_pairs
from formation_bench.experiments.score import check_score_format, target_column
from formation_bench.instances.library import PHASES
from formation_bench.optimizers import Budget
from formation_bench.pipeline.spec import budget_label

FAILURE_GAP = 1e-3
"""A trial whose final normalised gap is above this failed (for the time statistics)."""
TIME_SHIFT_S = 1e-3
"""Shift of the geometric mean of solve times, s (about a tenth of a typical solve)."""
PROFILE_TAUS = np.array([1, 1.5, 2, 3, 5, 10, 20, 50, 100], dtype=float)
"""Factors of the performance profile."""
BASELINE = "modified-bso"
"""The optimiser every other one is compared with, when the scores hold it."""
TUNED_BASELINE = f"{BASELINE}-tuned"
"""The baseline tuned: every other per-solve tuned variant is compared with it too, so that a
question asked of the defaults (do the modifications help?) is asked again at the best
settings of each."""
WARM_TOLERANCE = 1e-9
"""Relative: a final cost within this of the warm start's cost counts as returning it."""

GROUP = ["optimizer", "budget"]
PROBLEM = [*GROUP, "content_hash"]


def success_column(target: float) -> str:
    """Column of the success rate at a normalised gap of ``target`` (``success_norm_1e-03``)."""
    return f"success_norm_{target:.0e}"


# --- the trials -------------------------------------------------------------------------------


def headline_trials(scores: pd.DataFrame) -> pd.DataFrame:
    """The trials on non-degenerate instances, each with ``weight`` one over the trials of its
    problem (content hash) for the same optimiser and budget, so every problem counts once."""
    trials = scores[~scores["degenerate"].astype(bool)]
    count = trials.groupby(PROBLEM, sort=False)["fun"].transform("size")
    return trials.assign(weight=1.0 / count)


def per_problem(trials: pd.DataFrame) -> pd.DataFrame:
    """One row per optimiser, budget and problem: its trials' gaps, evaluations and solve time
    averaged (seeds first, and repeats of the problem), with its phase and trial count."""
    return (
        trials.groupby(PROBLEM, sort=False)
        .agg(
            normalised_gap=("normalised_gap", "mean"),
            gap=("gap", "mean"),
            abs_error=("abs_error", "mean"),
            warm_or_better=("warm_or_better", "mean"),
            nfev=("nfev", "mean"),
            seconds=("seconds", "mean"),
            phase=("phase", "first"),
            trials=("fun", "size"),
        )
        .reset_index()
    )


def _with_measures(scores: pd.DataFrame) -> pd.DataFrame:
    """``scores`` with ``abs_error`` ``|f - J*|`` and ``warm_or_better``."""
    warm = scores["warm_cost"].to_numpy(dtype=float)
    return scores.assign(
        abs_error=(scores["fun"] - scores["j_star"]).abs(),
        warm_or_better=scores["fun"].to_numpy(dtype=float) <= warm + WARM_TOLERANCE * np.abs(warm),
    )


def repeated_problems(scores: pd.DataFrame) -> tuple[int, int]:
    """``(within runs, across runs)``: content hashes repeated within one score run (the
    library promises there are none), and (optimiser, budget, seed, problem) solved by more
    than one run (runs over overlapping splits or libraries)."""
    within = int(scores.duplicated(["run_key", "content_hash"]).sum())
    across = scores.groupby([*GROUP, "seed", "content_hash"], sort=False)["run_key"].nunique()
    return within, int((across > 1).sum())


# --- the tables -------------------------------------------------------------------------------


def summary_table(scores: pd.DataFrame) -> pd.DataFrame:
    """The headline: one row per optimiser and budget over its non-degenerate problems, ranked
    within each budget by the median normalised gap (rank 1: the lowest)."""
    scores = _with_measures(scores)
    trials = headline_trials(scores)
    problems = per_problem(trials)
    # a failure is charged at the slowest solve of any optimiser at the same budget
    slowest = trials.groupby("budget")["seconds"].max()
    rows = []
    for (optimizer, budget), mine in problems.groupby(GROUP, sort=False):
        solves = trials[(trials["optimizer"] == optimizer) & (trials["budget"] == budget)]
        weights = solves["weight"].to_numpy()
        normalised = stats.describe(mine["normalised_gap"].to_numpy())
        relative = stats.describe(mine["gap"].to_numpy())
        final = solves["normalised_gap"].to_numpy(dtype=float)
        rows.append(
            {
                "optimizer": optimizer,
                "budget": budget,
                "instances": len(mine),
                "trials": len(solves),
                "norm_gap_median": normalised.median,
                "norm_gap_q1": normalised.q1,
                "norm_gap_q3": normalised.q3,
                "norm_gap_ci_low": normalised.ci_low,
                "norm_gap_ci_high": normalised.ci_high,
                "gap_median": relative.median,
                "gap_q1": relative.q1,
                "gap_q3": relative.q3,
                "gap_ci_low": relative.ci_low,
                "gap_ci_high": relative.ci_high,
                **{success_column(t): success_rate(final, t, weights) for t in SUCCESS_TARGETS},
                "nfev_median": float(mine["nfev"].median()),
                "solve_time_median_s": float(mine["seconds"].median()),
                "solve_time_sgm_s": shifted_geometric_mean(
                    solves["seconds"].to_numpy(),
                    TIME_SHIFT_S,
                    ~(final <= FAILURE_GAP),
                    charge=slowest[budget],
                    weights=weights,
                ),
            }
        )
    columns = ["optimizer", "budget", "rank", "instances", "trials", "norm_gap_median"]
    if not rows:
        return pd.DataFrame(columns=columns)
    summary = pd.DataFrame(rows).sort_values(["budget", "norm_gap_median"], ignore_index=True)
    rank = summary.groupby("budget", sort=False)["norm_gap_median"].rank(method="min")
    summary.insert(2, "rank", rank.astype("Int64"))
    return summary


def degenerate_table(scores: pd.DataFrame) -> pd.DataFrame:
    """The degenerate stratum, left out of the headline: per optimiser and budget, its
    problems and trials, the share of problems on which it returns the warm start's cost or
    better (averaged over each problem's trials) and the median ``|f - J*|``."""
    scores = _with_measures(scores)
    degenerate = scores[scores["degenerate"].astype(bool)]
    columns = [
        "optimizer",
        "budget",
        "instances",
        "trials",
        "warm_or_better_share",
        "abs_error_median",
    ]
    if degenerate.empty:
        return pd.DataFrame(columns=columns)
    rows = []
    for (optimizer, budget), mine in per_problem(degenerate).groupby(GROUP, sort=False):
        rows.append(
            {
                "optimizer": optimizer,
                "budget": budget,
                "instances": len(mine),
                "trials": int(mine["trials"].sum()),
                "warm_or_better_share": float(mine["warm_or_better"].mean()),
                "abs_error_median": float(mine["abs_error"].median()),
            }
        )
    return pd.DataFrame(rows, columns=columns).sort_values(
        ["budget", "optimizer"], ignore_index=True
    )


def phase_table(scores: pd.DataFrame) -> pd.DataFrame:
    """Median normalised gap per optimiser, budget and phase of the loop, over the
    non-degenerate problems (each averaged over its trials first)."""
    problems = per_problem(headline_trials(_with_measures(scores)))
    rows = []
    for (optimizer, budget), mine in problems.groupby(GROUP, sort=False):
        for phase in PHASES:
            gaps = mine.loc[mine["phase"] == phase, "normalised_gap"]
            rows.append(
                {
                    "optimizer": optimizer,
                    "budget": budget,
                    "phase": phase,
                    "instances": len(gaps),
                    "norm_gap_median": float(gaps.median()) if len(gaps) else math.nan,
                }
            )
    return pd.DataFrame(
        rows, columns=["optimizer", "budget", "phase", "instances", "norm_gap_median"]
    )


def comparisons(optimizers: list[str], leader: str | None = None) -> list[tuple[str, str, str]]:
    """``(kind, x, y)`` of the paired comparisons among ``optimizers``: each against
    :data:`BASELINE` when it is there, each per-solve tuned variant against
    :data:`TUNED_BASELINE` when it is there, each against ``leader`` (the best at the budget,
    when given and not the baseline), each variant (``X-warm``, ``X-tuned``, ``X-tuned-loop``)
    against ``X``, one kind of comparison per kind of variant."""
    present = set(optimizers)
    found = []
    if BASELINE in present:
        found += [(f"against {BASELINE}", x, BASELINE) for x in optimizers if x != BASELINE]
    if TUNED_BASELINE in present:
        found += [
            (f"tuned, against {TUNED_BASELINE}", x, TUNED_BASELINE)
            for x in optimizers
            if x != TUNED_BASELINE and x.endswith("-tuned")
        ]
    if leader is not None and leader != BASELINE and leader in present:
        kind = f"against the leader, {leader}"
        found += [(kind, x, leader) for x in optimizers if x != leader]
    pairs = variant_pairs(optimizers)
    for kind in VARIANT_KINDS:  # each kind of variant its own family of tests
        found += [(kind.comparison, x, y) for x, y in pairs if kind_of(x) == kind]
    return found


def a12_reading(x: str, y: str, a12: float) -> str:
    """A sentence saying which way A12 = P(x > y) + P(x = y) / 2 of the normalised gap points."""
    if not math.isfinite(a12):
        return "no pairs"
    if a12 == 0.5:
        return f"no difference: {x} and {y} equally likely to leave the smaller gap"
    better, worse, p = (x, y, 1 - a12) if a12 < 0.5 else (y, x, a12)
    return (
        f"favours {better}: a {better} solve leaves the smaller normalised gap than a {worse} "
        f"solve with probability {p:.2f} (ties half)"
    )


def paired_table(scores: pd.DataFrame) -> pd.DataFrame:
    """Paired comparisons of the normalised gap, one row per budget and comparison
    (:func:`comparisons`), paired by problem (each averaged over its trials first): the
    medians, the median of the differences x - y, wins/losses/ties of x, Wilcoxon's two-sided
    p, Holm-adjusted within the budget and kind of comparison, and A12 with its reading."""
    problems = per_problem(headline_trials(_with_measures(scores)))
    rows = []
    for budget, at_budget in problems.groupby("budget", sort=False):
        table = at_budget.pivot_table(
            index="content_hash", columns="optimizer", values="normalised_gap", aggfunc="first"
        )
        medians = table.median().sort_index()
        leader = str(medians.idxmin()) if medians.notna().any() else None
        found = []
        for kind, x_name, y_name in comparisons(sorted(table.columns), leader):
            pair = table[[x_name, y_name]].dropna()
            compared = stats.paired_comparison(pair[x_name], pair[y_name])
            found.append(
                {
                    "budget": budget,
                    "comparison": kind,
                    "x": x_name,
                    "y": y_name,
                    "x_norm_gap_median": compared.pop("x_median"),
                    "y_norm_gap_median": compared.pop("y_median"),
                    **compared,
                    "reading": a12_reading(x_name, y_name, compared["a12"]),
                }
            )
        for kind in dict.fromkeys(r["comparison"] for r in found):
            stats.holm_family([r for r in found if r["comparison"] == kind])
        rows += found
    columns = [
        "budget", "comparison", "x", "y", "pairs", "x_norm_gap_median", "y_norm_gap_median",
        "median_difference", "x_lower", "x_higher", "ties", "p", "p_holm", "significant",
        "a12", "reading",
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=columns)


DEFAULT_BUDGET = budget_label(None)
"""The label of the optimisers' own budgets in the scores."""
TUNED = next(kind for kind in VARIANT_KINDS if kind.suffix == "-tuned")
"""The variants whose rank change the leaderboard states: those tuned per solve."""
TUNED_KINDS = tuple(k for k in VARIANT_KINDS if k.suffix.startswith("-tuned"))
"""Every kind of tuned variant: none of them ranks with the defaults."""


def _is_tuned(optimizer: str) -> bool:
    return any(optimizer.endswith(kind.suffix) for kind in TUNED_KINDS)


def tuned_families(optimizers: list[str]) -> list[tuple[str, str]]:
    """``(tuned variant, family)`` of every ``X-tuned`` among ``optimizers`` whose ``X`` is
    there too."""
    return [(x, y) for x, y in variant_pairs(optimizers) if kind_of(x) == TUNED]


def _ranking_rows(summary: pd.DataFrame, budget: str) -> pd.DataFrame:
    """Each optimiser's leaderboard row at ``budget``, or at its own budget when it has no
    score runs at ``budget`` (the derivative-based ones, pycma), indexed by optimiser."""
    at = summary[summary["budget"] == budget].set_index("optimizer")
    own = summary[summary["budget"] == DEFAULT_BUDGET].set_index("optimizer")
    return pd.concat([at, own[~own.index.isin(at.index)]])


def _ranks(medians: pd.Series) -> pd.Series:
    return medians.rank(method="min").astype("Int64")


def rank_change_table(
    scores: pd.DataFrame, summary: pd.DataFrame, tuning_budgets: dict[str, int]
) -> pd.DataFrame:
    """Per family with a tuned variant (:func:`tuned_families`) whose tuning budget
    ``tuning_budgets`` knows, at that budget (``max_evaluations=B``): its rank by the median
    normalised gap among every optimiser at its default configuration (the tuned variants
    left out), and its tuned variant's rank with every such family replaced by its tuned
    variant (the others unchanged); an optimiser without score runs at that budget ranks with
    its runs at its own budget. With the two medians and CIs, and the tuned variant against
    the family paired by problem: Wilcoxon's two-sided p, Holm-adjusted over the families at
    the budget, and A12 = P(tuned > default)."""
    problems = per_problem(headline_trials(_with_measures(scores)))
    families = _known_families(summary, tuning_budgets)
    rows = []
    for tuning_budget in sorted({b for _, _, b in families}):
        budget = budget_label(Budget(max_evaluations=tuning_budget))
        ranked = _ranking_rows(summary, budget)
        here = [
            (t, f) for t, f, b in families if b == tuning_budget and not _unranked(ranked, t, f)
        ]
        if here:  # else nothing to compare at this budget: rank_change_notes says why
            rows += _rank_changes_at(problems, ranked, budget, here)
    columns = [
        "budget", "family", "tuned", "optimizers", "default_rank", "tuned_rank", "rank_change",
        *(f"default_{k}" for k in _MEDIAN), *(f"tuned_{k}" for k in _MEDIAN), "pairs", "p",
        "p_holm", "significant", "a12",
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=columns)


_MEDIAN = ("median", "ci_low", "ci_high")


def _rank_changes_at(
    problems: pd.DataFrame, ranked: pd.DataFrame, budget: str, here: list[tuple[str, str]]
) -> list[dict]:
    """The rows of :func:`rank_change_table` at ``budget`` of the ``(tuned variant, family)``
    pairs ``here``, both of each ranked in ``ranked`` (a :func:`_ranking_rows`); ``problems``
    is a :func:`per_problem` table."""
    defaults = ranked[[not _is_tuned(name) for name in ranked.index]]["norm_gap_median"]
    tuned_medians = defaults.rename(index={f: t for t, f in here})
    for tuned, _ in here:
        tuned_medians[tuned] = ranked.loc[tuned, "norm_gap_median"]
    default_rank, tuned_rank = _ranks(defaults), _ranks(tuned_medians)
    found = []
    for tuned, family in here:
        x, y = (_problem_gaps(problems, name, ranked.loc[name, "budget"])
                for name in (tuned, family))  # fmt: skip
        paired = pd.concat([x, y], axis=1, join="inner").dropna()
        compared = stats.paired_comparison(paired.iloc[:, 0], paired.iloc[:, 1])
        found.append(
            {
                "budget": budget,
                "family": family,
                "tuned": tuned,
                "optimizers": len(defaults),
                "default_rank": default_rank[family],
                "tuned_rank": tuned_rank[tuned],
                "rank_change": int(default_rank[family] - tuned_rank[tuned]),
                **{f"default_{k}": ranked.loc[family, f"norm_gap_{k}"] for k in _MEDIAN},
                **{f"tuned_{k}": ranked.loc[tuned, f"norm_gap_{k}"] for k in _MEDIAN},
                "pairs": compared["pairs"],
                "p": compared["p"],
                "a12": compared["a12"],
            }
        )
    stats.holm_family(found)
    return found


def _known_families(
    summary: pd.DataFrame, tuning_budgets: dict[str, int]
) -> list[tuple[str, str, int]]:
    """``(tuned variant, family, tuning budget)`` of every family of ``summary`` with a tuned
    variant whose tuning budget ``tuning_budgets`` knows."""
    return [
        (tuned, family, tuning_budgets[tuned])
        for tuned, family in tuned_families(sorted(summary["optimizer"].unique()))
        if tuned in tuning_budgets
    ]


def _unranked(ranked: pd.DataFrame, tuned: str, family: str) -> list[str]:
    """Those of ``tuned`` and ``family`` that have no leaderboard row in ``ranked`` (a
    :func:`_ranking_rows`), so no rank there."""
    return [name for name in (tuned, family) if name not in ranked.index]


def rank_change_notes(summary: pd.DataFrame, tuning_budgets: dict[str, int]) -> list[str]:
    """A line per family with a tuned variant whose tuning budget ``tuning_budgets`` knows
    but which :func:`rank_change_table` leaves out: the variant or the family has no score
    runs at that budget, nor at its own."""
    notes = []
    for tuned, family, tuning_budget in _known_families(summary, tuning_budgets):
        budget = budget_label(Budget(max_evaluations=tuning_budget))
        unranked = _unranked(_ranking_rows(summary, budget), tuned, family)
        if unranked:
            notes.append(
                f"no rank change of {family} with {tuned}, tuned at {budget}: "
                f"{' and '.join(unranked)} {'has' if len(unranked) == 1 else 'have'} no score "
                f"runs at that budget (nor at {DEFAULT_BUDGET}), so there is nothing to compare."
            )
    return notes


def _problem_gaps(problems: pd.DataFrame, optimizer: str, budget: str) -> pd.Series:
    """The normalised gap of each problem ``optimizer`` solved at ``budget``."""
    mine = problems[(problems["optimizer"] == optimizer) & (problems["budget"] == budget)]
    return mine.set_index("content_hash")["normalised_gap"].rename(optimizer)


def ert_table(scores: pd.DataFrame) -> pd.DataFrame:
    """COCO's expected running time (evaluations) per optimiser, budget and target of the
    normalised gap, over the non-degenerate trials weighted so each problem counts once;
    ``successes`` is the number of trials that reached the target."""
    rows = []
    for (optimizer, budget), trials in headline_trials(scores).groupby(GROUP, sort=False):
        used = trials["nfev"].to_numpy(dtype=float)
        weights = trials["weight"].to_numpy()
        for target in TARGETS:
            hits = trials[target_column(target)].to_numpy(dtype=float)
            rows.append(
                {
                    "optimizer": optimizer,
                    "budget": budget,
                    "target_norm_gap": target,
                    "successes": int(np.isfinite(hits).sum()),
                    "trials": len(trials),
                    "ert_evaluations": expected_running_time(hits, used, weights),
                }
            )
    return pd.DataFrame(rows)


def profile_table(scores: pd.DataFrame) -> pd.DataFrame:
    """Performance profile of solve time per budget over the non-degenerate problems (mean
    over each problem's trials; a trial with a normalised gap above :data:`FAILURE_GAP`
    fails, and so does the problem's time)."""
    frames = []
    for budget, trials in headline_trials(scores).groupby("budget", sort=False):
        solved = trials["normalised_gap"].to_numpy(dtype=float) <= FAILURE_GAP
        timed = trials.assign(time=np.where(solved, trials["seconds"], np.inf))
        per_problem_time = timed.groupby(["content_hash", "optimizer"])["time"].mean().unstack()
        profile = performance_profile(per_problem_time, PROFILE_TAUS)
        frames.append(profile.reset_index().melt("tau", var_name="optimizer", value_name="share"))
        frames[-1].insert(0, "budget", budget)
    if not frames:
        return pd.DataFrame(columns=["budget", "tau", "optimizer", "share"])
    return pd.concat(frames, ignore_index=True)


def ecdf_curves(scores: pd.DataFrame, points: int = 40) -> pd.DataFrame:
    """Share of (trial, target of the normalised gap) pairs reached against evaluations, per
    optimiser and budget, over the non-degenerate trials weighted so each problem counts once."""
    trials_all = headline_trials(scores)
    top = max(float(trials_all["nfev"].max()) if len(trials_all) else 0.0, 10.0)
    budgets = np.unique(np.geomspace(1, top, points).round())
    columns = [target_column(t) for t in TARGETS]
    rows = []
    for (optimizer, budget), trials in trials_all.groupby(GROUP, sort=False):
        shares = runtime_ecdf(
            trials[columns].to_numpy(dtype=float), budgets, trials["weight"].to_numpy()
        )
        rows += [
            {"optimizer": optimizer, "budget": budget, "evaluations": b, "share": s}
            for b, s in zip(budgets, shares, strict=True)
        ]
    return pd.DataFrame(rows, columns=["optimizer", "budget", "evaluations", "share"])


# --- fitting a table into the documentation's content column ------------------------------


@dataclass(frozen=True)
class Column:
    """A column of a Markdown table before it is printed: its header, its cells (one per row)
    and whether it holds text (left-aligned) rather than numbers (right-aligned)."""

    header: str
    cells: list[str]
    text: bool = False

    @property
    def width(self) -> int:
        """The narrowest the column can be, in characters (:func:`column_width`)."""
        return column_width([self.header, *self.cells])


Section = list[Column]
"""Value columns that read together (a median and its CI, the success rates at each target):
a split table keeps them in one part when they fit one."""


def fitted_table(lead: list[Column], sections: list[Section], room: int = TABLE_WIDTH) -> list[str]:
    """The Markdown of a table of the ``lead`` columns (which name the row) and the value
    columns of ``sections``, in as many tables of the same rows as it takes for each to fit
    ``room`` characters (:func:`split_columns`): the lead columns in every one, the sections
    in order and whole where they fit beside the lead (else column by column). Each table is
    followed by a blank line."""
    free = room - sum(column.width for column in lead)
    units: list[Section] = []
    for section in sections:
        fits = sum(column.width for column in section) <= free
        units += [section] if fits else [[column] for column in section]
    groups = split_columns([sum(column.width for column in unit) for unit in units], free)
    lines: list[str] = []
    for group in groups or [[]]:
        lines += [*_table_lines([*lead, *(c for k in group for c in units[k])]), ""]
    return lines


def _table_lines(columns: list[Column]) -> list[str]:
    rule = "|" + "".join("---|" if column.text else "---:|" for column in columns)
    rows = zip(*(column.cells for column in columns), strict=True)
    return [_row([column.header for column in columns]), rule, *(_row(list(r)) for r in rows)]


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _column(
    rows: pd.DataFrame, header: str, cell: Callable[[pd.Series], str], *, text: bool = False
) -> Column:
    """The column headed ``header`` of one cell per row of ``rows``, ``cell(row)``."""
    return Column(header, [cell(row) for _, row in rows.iterrows()], text)


# --- the leaderboard --------------------------------------------------------------------------


def _g(value: float, spec: str = ".3g") -> str:
    return "-" if value is None or not math.isfinite(float(value)) else format(value, spec)


def _share(value: float, problems: int) -> str:
    """A share of ``problems`` (each problem weighted once): ``92%``, or ``587/588`` where the
    percentage would round to 0 or 100; ``-`` when there is none."""
    return "-" if not math.isfinite(float(value)) else share_cell(value, problems)


def _p(value: float) -> str:
    return "-" if not math.isfinite(float(value)) else f"{value:.2g}"


def to_markdown(
    summary: pd.DataFrame,
    degenerate: pd.DataFrame,
    phases: pd.DataFrame,
    paired: pd.DataFrame,
    *,
    library: str,
    notes: list[str] = (),
    rank_change: pd.DataFrame | None = None,
) -> str:
    """The rank change of the families with a tuned variant (when ``rank_change`` has rows),
    then the leaderboard per budget, the degenerate stratum, the phases and the paired
    comparisons at that budget."""
    lines = [
        f"# Score on the instance library {library}",
        "",
        "Relative gap: (f - J*) / J*. Normalised gap: (f - J*) / (f_warm - J*), the share of "
        "the possible improvement (from the warm start's cost f_warm to the best-known J*) "
        "left; 1 at the warm start, 0 at J*.",
        "",
        "Headline: the non-degenerate instances, each distinct problem (content hash) counted "
        "once; per optimiser, each problem's gaps, evaluations and times are averaged over its "
        "trials (seeds) first. **Ranked by the median normalised gap** over the problems "
        f"(rank 1: the lowest). Every target is a target of the {TARGET_GAP}: success at t "
        "= final normalised gap <= t (1e-3: 99.9 % of the possible improvement made), the "
        "share of trials, each problem weighted once. Solve time: median over problems, and "
        f"shifted geometric mean (shift {TIME_SHIFT_S * 1e3:g} ms) with trials whose "
        f"normalised gap is above {FAILURE_GAP:g} charged at the slowest solve at the same "
        "budget. CI: percentile bootstrap 95 % of the median.",
        "",
        "Degenerate instances (J* near zero, or a warm start already optimal: neither gap "
        "means anything there) are left out of the headline and reported on their own.",
        "",
        *[f"Note: {note}" for note in notes],
        *([""] if notes else []),
    ]
    if rank_change is not None and len(rank_change):
        lines += _rank_change_section(rank_change)
    for budget in dict.fromkeys(
        [*summary["budget"], *degenerate["budget"], *phases["budget"], *paired["budget"]]
    ):
        lines += [f"## budget {budget}", ""]
        lines += _summary_section(summary[summary["budget"] == budget])
        lines += _degenerate_section(degenerate[degenerate["budget"] == budget])
        lines += _phase_section(phases[phases["budget"] == budget])
        lines += _paired_section(paired[paired["budget"] == budget])
    return "\n".join(lines)


def _with_ci(row: pd.Series, prefix: str) -> str:
    """``median [ci_low, ci_high]`` of the ``prefix`` columns of ``row``."""
    return (
        f"{_g(row[f'{prefix}_median'])} [{_g(row[f'{prefix}_ci_low'])}, "
        f"{_g(row[f'{prefix}_ci_high'])}]"
    )


def _p_holm(row: pd.Series) -> str:
    """The Holm-adjusted p of ``row``, starred when significant."""
    return f"{_p(row['p_holm'])}{' *' if row['significant'] else ''}"


def _summary_section(rows: pd.DataFrame) -> list[str]:
    """The leaderboard at one budget: ranks, counts and gaps, then (where the table does not
    fit the page in one) the success rates and solve times beside the same rank and name."""
    if rows.empty:
        return ["No non-degenerate instance was solved at this budget.", ""]

    def success(target: float) -> Column:
        # the target alone heads it: the text above defines success at t
        column = success_column(target)
        return _column(rows, f"success {target:.0e}", lambda r: _share(r[column], r["instances"]))

    lead = [
        _column(rows, "rank", lambda r: f"{r['rank']}"),
        _column(rows, "optimizer", lambda r: f"{r['optimizer']}", text=True),
    ]
    sections = [
        [
            _column(rows, "instances", lambda r: f"{r['instances']}"),
            _column(rows, "trials", lambda r: f"{r['trials']}"),
        ],
        [
            _column(rows, "median normalised gap [95 % CI]", lambda r: _with_ci(r, "norm_gap")),
            _column(rows, "median relative gap [95 % CI]", lambda r: _with_ci(r, "gap")),
        ],
        [_column(rows, "median evaluations", lambda r: _g(r["nfev_median"], ".0f"))],
        [success(target) for target in SUCCESS_TARGETS],
        [
            _column(rows, "solve time median (ms)",
                    lambda r: _g(1e3 * r["solve_time_median_s"], ".2f")),
            _column(rows, "sgm, failures charged (ms)",
                    lambda r: _g(1e3 * r["solve_time_sgm_s"], ".1f")),
        ],
    ]  # fmt: skip
    return fitted_table(lead, sections)


def _rank_change_section(rows: pd.DataFrame) -> list[str]:
    lines = []
    for budget, at in rows.groupby("budget", sort=False):
        lines += [
            f"## Rank change with the tuned variants, budget {budget}",
            "",
            f"At {budget}, the evaluation budget per solve the tuned variants were tuned at, "
            "every optimiser is ranked by its median normalised gap (rank 1: the lowest; one "
            "without score runs at this budget, such as the derivative-based ones, ranks with "
            "its runs at its own budget) twice: once with every family at its default "
            "configuration (no tuned variant), once with each family below replaced by its "
            "tuned variant `<family>-tuned` and every other optimiser unchanged; rank change = "
            "default rank - tuned rank (positive: tuning moved the family up). Tuned against "
            "default paired by problem: Wilcoxon signed-rank, two-sided, Holm-adjusted over "
            "the families; A12 = P(tuned > default) of the normalised gap (below 0.5: the "
            f"tuned variant leaves less). {at['optimizers'].iloc[0]} optimisers ranked.",
            "",
        ]
        sections = [
            [
                _column(at, "default rank", lambda r: f"{r['default_rank']}"),
                _column(at, "tuned rank", lambda r: f"{r['tuned_rank']}"),
                _column(at, "rank change", lambda r: f"{r['rank_change']:+d}"),
            ],
            [
                _column(at, "default median normalised gap [95 % CI]",
                        lambda r: _with_ci(r, "default")),
                _column(at, "tuned median normalised gap [95 % CI]",
                        lambda r: _with_ci(r, "tuned")),
            ],
            [
                _column(at, "pairs", lambda r: f"{r['pairs']}"),
                _column(at, "p Holm", _p_holm),
                _column(at, "A12 tuned vs default", lambda r: _g(r["a12"], ".2f")),
            ],
        ]  # fmt: skip
        lines += fitted_table([_column(at, "family", lambda r: f"{r['family']}", text=True)],
                              sections)  # fmt: skip
    return lines


def _degenerate_section(rows: pd.DataFrame) -> list[str]:
    lines = ["### Degenerate instances (left out of the headline)", ""]
    if rows.empty:
        return [*lines, "None solved.", ""]
    lines += [
        "Per optimiser: its degenerate problems, the share of them on which it returns the warm "
        f"start's cost or better (to {WARM_TOLERANCE:g} relative), and the median |f - J*| "
        "(absolute, in cost units).",
        "",
    ]
    sections = [
        [
            _column(rows, "instances", lambda r: f"{r['instances']}"),
            _column(rows, "trials", lambda r: f"{r['trials']}"),
        ],
        [
            _column(rows, "warm-start cost or better",
                    lambda r: _share(r["warm_or_better_share"], r["instances"])),
            _column(rows, "median abs(f - J*)", lambda r: _g(r["abs_error_median"])),
        ],
    ]  # fmt: skip
    lead = [_column(rows, "optimizer", lambda r: f"{r['optimizer']}", text=True)]
    return [*lines, *fitted_table(lead, sections)]


def _phase_section(rows: pd.DataFrame) -> list[str]:
    if rows.empty:
        return []
    optimizers = list(dict.fromkeys(rows["optimizer"]))
    by_phase = rows.set_index(["optimizer", "phase"])

    def phase_cell(optimizer: str, phase: str) -> str:
        row = by_phase.loc[(optimizer, phase)]
        return f"{_g(row['norm_gap_median'])} ({row['instances']})"

    lead = [Column("optimizer", optimizers, text=True)]
    phases = [Column(phase, [phase_cell(o, phase) for o in optimizers]) for phase in PHASES]
    return [
        "### Median normalised gap per phase of the loop",
        "",
        "Non-degenerate problems of each phase (their number in brackets).",
        "",
        *fitted_table(lead, [phases]),
    ]


def _paired_section(rows: pd.DataFrame) -> list[str]:
    if rows.empty:
        return []
    lead = [
        _column(rows, "comparison", lambda r: f"{r['comparison']}", text=True),
        _column(rows, "x", lambda r: f"{r['x']}", text=True),
        _column(rows, "y", lambda r: f"{r['y']}", text=True),
    ]
    sections = [
        [
            _column(rows, "pairs", lambda r: f"{r['pairs']}"),
            _column(rows, "median x", lambda r: _g(r["x_norm_gap_median"])),
            _column(rows, "median y", lambda r: _g(r["y_norm_gap_median"])),
        ],
        [
            _column(rows, "x lower / higher / tied",
                    lambda r: f"{r['x_lower']} / {r['x_higher']} / {r['ties']}"),
        ],
        [
            _column(rows, "p", lambda r: _p(r["p"])),
            _column(rows, "p Holm", _p_holm),
            _column(rows, "A12", lambda r: _g(r["a12"], ".2f")),
        ],
        [_column(rows, "reading", lambda r: f"{r['reading']}", text=True)],
    ]  # fmt: skip
    return [
        "### Paired comparisons of the normalised gap",
        "",
        "Paired by problem (each averaged over its trials). Wilcoxon signed-rank, two-sided, "
        "Holm-adjusted within each kind of comparison at this budget; A12 = P(x > y) + "
        "P(x = y) / 2 of the normalised gap (below 0.5: x leaves less).",
        "",
        *fitted_table(lead, sections),
    ]


def _notes(scores: pd.DataFrame) -> list[str]:
    within, across = repeated_problems(scores)
    notes = []
    if within:
        notes.append(
            f"{within} score rows repeat the problem (content hash) of another row of their run "
            "(a problem drawn twice into the library: v1 has such repeats, v2 has none); each "
            "problem is counted once, its repeats averaged."
        )
    if across:
        notes.append(
            f"{across} (optimizer, budget, seed, problem) were solved by more than one run "
            "(runs over overlapping splits or libraries); each problem is counted once, its "
            "solves averaged."
        )
    return notes


def _library_label(scores: pd.DataFrame, split: str = "") -> str:
    """The libraries and the splits their runs were over; with ``split``, named as the
    report of that split's instances only."""
    parts = []
    for library, rows in scores.groupby("library", sort=True):
        splits = ", ".join(sorted(rows["run_split"].astype(str).unique()))
        parts.append(
            f"{library}, {split} instances (runs over split {splits})"
            if split
            else f"{library} (split {splits})"
        )
    return "; ".join(parts)


def instance_splits(scores: pd.DataFrame) -> list[str]:
    """The library splits of the instances ``scores`` solved (``""`` for a library without
    splits), in sorted order."""
    return sorted(scores["split"].astype(str).unique())


def write_score_report(
    scores: pd.DataFrame,
    folder: Path,
    *,
    figures: bool = True,
    tuning_budgets: dict[str, int] | None = None,
) -> str:
    """Write every score file into ``folder``; returns the Markdown leaderboard. Raises
    :class:`~formation_bench.experiments.errors.StoreError` when runs were stored
    in an older score format.

    Instances of different splits are never pooled: with several (test and validation, e.g.
    from a run over split ``all`` beside a run over ``test``), each split has its own
    leaderboard and statistics, every table a ``split`` column, and every figure one file per
    split (``score_ecdf_test.png``, ...); a run over ``all`` counts in each split with the
    instances of that split.

    ``tuning_budgets`` (tuned variant -> the evaluation budget it was tuned at) places the
    rank change of each family with a tuned variant (:func:`rank_change_table`); by default
    the budgets the registered tuned variants record."""
    check_score_format(scores, "a report")
    folder.mkdir(parents=True, exist_ok=True)
    tuning_notes: list[str] = []
    if tuning_budgets is None:
        tuning_budgets, tuning_notes = _tuning_budgets(scores)
    splits = instance_splits(scores)
    if len(splits) == 1:
        tables = _score_tables(scores, tuning_budgets)
        markdown = _markdown(scores, tables, [*_notes(scores), *tuning_notes], tuning_budgets)
        figure_sets = {"": (scores, tables["profile"])}
    else:
        shown = ", ".join(split or "none (a library without splits)" for split in splits)
        note = (
            f"these score runs solved instances of {len(splits)} splits ({shown}); each split "
            "has its own leaderboard and statistics below, and no row pools them (a run over "
            "split all counts in each, with the instances of that split)."
        )
        parts = {split: scores[scores["split"].astype(str) == split] for split in splits}
        per_split = {split: _score_tables(part, tuning_budgets) for split, part in parts.items()}
        tables = {
            name: pd.concat(
                [t[name].assign(split=split)[["split", *t[name].columns]]
                 for split, t in per_split.items()],
                ignore_index=True,
            )
            for name in SCORE_TABLES
        }  # fmt: skip
        markdown = "\n\n".join(
            _markdown(part, per_split[split], [note, *_notes(part), *tuning_notes],
                      tuning_budgets, split)
            for split, part in parts.items()
        )  # fmt: skip
        figure_sets = {split: (part, per_split[split]["profile"]) for split, part in parts.items()}
    for name, table in tables.items():
        table.to_csv(folder / f"score_{name}.csv", index=False)
    (folder / "score.md").write_text(markdown)
    if figures:
        for split, (part, profile) in figure_sets.items():
            _figures(part, profile, folder / "figures", split)
    return markdown


SCORE_TABLES = ("summary", "degenerate", "phases", "paired", "ert", "profile", "rank_change")
"""The tables of a score report, each written to ``score_NAME.csv``."""


def _score_tables(scores: pd.DataFrame, tuning_budgets: dict[str, int]) -> dict[str, pd.DataFrame]:
    tables = (
        summary_table, degenerate_table, phase_table, paired_table, ert_table, profile_table
    )  # fmt: skip
    made = {name: make(scores) for name, make in zip(SCORE_TABLES, tables, strict=False)}
    made["rank_change"] = rank_change_table(scores, made["summary"], tuning_budgets)
    return made


def _markdown(
    scores: pd.DataFrame,
    tables: dict[str, pd.DataFrame],
    notes: list[str],
    tuning_budgets: dict[str, int],
    split: str = "",
) -> str:
    return to_markdown(
        tables["summary"],
        tables["degenerate"],
        tables["phases"],
        tables["paired"],
        library=_library_label(scores, split),
        notes=[*notes, *rank_change_notes(tables["summary"], tuning_budgets)],
        rank_change=tables["rank_change"],
    )


def _tuning_budgets(scores: pd.DataFrame) -> tuple[dict[str, int], list[str]]:
    """The budget every registered tuned variant in ``scores`` was tuned at, and a note
    naming the variants ending in ``-tuned`` that are not registered tuned variants (left
    out of the rank change)."""
    from formation_bench.optimizers.tuned import tuned_data

    tuned = [t for t, _ in tuned_families(sorted(scores["optimizer"].unique()))]
    known = {t: int(data["objective"]["budget"]) for t in tuned if (data := tuned_data(t))}
    unknown = [t for t in tuned if t not in known]
    if not unknown:
        return known, []
    return known, [
        f"{', '.join(unknown)}: not registered here as a tuned variant (no tuned-variant file), "
        "so the budget it was tuned at is unknown and it has no rank change"
    ]


def _figures(scores: pd.DataFrame, profile: pd.DataFrame, folder: Path, split: str) -> None:
    """The ECDF and profile figures; those of one split of several named after it."""
    import matplotlib.pyplot as plt

    from formation_bench.analysis.figures import score_ecdf_figure, score_profile_figure

    folder.mkdir(parents=True, exist_ok=True)
    ecdf = score_ecdf_figure(ecdf_curves(scores))
    ecdf.suptitle(
        f"targets {TARGETS[0]:.0e} .. {TARGETS[-1]:.0e} of the normalised gap\n"
        f"(f - J*) / (f_warm - J*), non-degenerate {split + ' ' if split else ''}instances",
        fontsize=9,
    )
    profile_figure = score_profile_figure(profile)
    for axes in profile_figure.axes:
        axes.set_ylabel(f"share within tau (normalised gap <= {FAILURE_GAP:g})")
    for name, figure in (("score_ecdf", ecdf), ("score_profile", profile_figure)):
        name = f"{name}_{split}.png" if split else f"{name}.png"
        figure.savefig(folder / name, dpi=120)
        plt.close(figure)
