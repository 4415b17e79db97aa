"""The statistics of a results table: one factor compared within blocks of the others.

One *factor* is compared (by default the optimiser; the trigger when the results hold one
optimiser but both trigger settings, as the ``paper`` suite does); the other factors
(scenario, trigger, budget, optimiser) form *blocks*, each analysed on its own. Within a
block, for every metric:

- per level of the factor: n, median, quartiles, IQR, bootstrap 95 % CI of the median;
- against the baseline level (or each of several), paired by seed: Wilcoxon signed-rank
  p-value, Holm-adjusted over the block's comparisons with that baseline for that metric, and
  the Vargha-Delaney A12 (P(level > baseline); below 0.5 the level has lower values);
- across all levels (3 or more): Friedman's test over the seeds present for every
  level, the average ranks (1 = lowest value) and Nemenyi post-hoc p-values.

The report (:mod:`~formation_bench.analysis.report`), its suite sections
(:mod:`~formation_bench.analysis.suite_sections`) and the variant pairs
(:mod:`~formation_bench.analysis.variant_pairs`) build on this module; it imports none of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from formation_bench.analysis import stats
from formation_bench.mpc.metrics import headline_metrics
from formation_bench.pipeline.record import is_metric_column

FACTORS = ("optimizer", "trigger", "budget", "scenario")
"""Factors a report can compare, in the order the default choice tries them."""


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
    head = [c for c in headline_metrics() if c in numeric]
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


def check_compared(frame: pd.DataFrame, compare: str | None) -> None:
    """Refuse a factor asked for (``--compare``) that has a single level in the results: a
    comparison of one level with nothing would be reported as if it were one."""
    if compare is None or compare not in FACTORS:
        return  # the default choice, or an unknown name that choose_factor names
    frame = prepare(frame)
    levels = levels_of(frame, compare)
    if len(levels) > 1:
        return
    several = [f"{f} ({frame[f].nunique()} levels)" for f in FACTORS if frame[f].nunique() > 1]
    instead = f"compare {' or '.join(several)}" if several else "no factor has two levels"
    raise ReportError(
        f"--compare {compare}: these results hold one {compare} ({levels[0] if levels else '-'}),"
        f" so there is nothing to compare it with; {instead}"
    )


def levels_of(frame: pd.DataFrame, factor: str) -> list[str]:
    """Levels in a stable order (as the results are sorted, i.e. by suite order of names)."""
    return list(dict.fromkeys(frame[factor]))


def choose_baselines(
    frame: pd.DataFrame, factor: str, baselines: str | list[str] | tuple[str, ...] | None
) -> tuple[str, ...]:
    """The levels every other one is compared with: ``baselines`` (checked), else the
    preferred level of the factor (the modified BSO, the trigger off, the paper scenario)."""
    levels = levels_of(frame, factor)
    if isinstance(baselines, str):
        baselines = (baselines,)
    if baselines:
        for baseline in baselines:
            if baseline not in levels:
                raise ReportError(
                    f"--baseline: {baseline!r} is not a level of {factor} in these results; "
                    f"allowed: {', '.join(levels)}"
                )
        return tuple(dict.fromkeys(baselines))
    preferred = {"optimizer": "modified-bso", "trigger": "off", "scenario": "paper"}.get(factor)
    return (preferred if preferred in levels else levels[0],)


@dataclass
class Report:
    """Everything a report holds."""

    factor: str
    baselines: tuple[str, ...]
    """The levels compared with every other, the first the main one."""
    block_factors: list[str]
    metrics: list[str]
    summary: pd.DataFrame
    wilcoxon: pd.DataFrame
    friedman: pd.DataFrame
    ranks: pd.DataFrame
    nemenyi: pd.DataFrame
    notes: list[str] = field(default_factory=list)

    @property
    def baseline(self) -> str:
        """The main baseline (the first)."""
        return self.baselines[0]


def analyse(
    results: pd.DataFrame,
    *,
    baseline: str | list[str] | tuple[str, ...] | None = None,
    compare: str | None = None,
    metrics: list[str] | None = None,
) -> Report:
    """Statistics of a results table (as
    :func:`formation_bench.experiments.store.load_results` returns it), of every
    metric column or of ``metrics`` (those of them the table holds); ``baseline`` is one
    level or several, each compared with every other level."""
    frame = prepare(results)
    factor = choose_factor(frame, compare)
    bases = choose_baselines(frame, factor, baseline)
    block_factors = [f for f in FACTORS if f != factor]
    every = metric_columns(frame)
    metrics = every if metrics is None else [m for m in metrics if m in every]
    summary_rows, test_rows, friedman_rows, rank_rows, nemenyi_rows = [], [], [], [], []
    notes = []
    for block_values, block in frame.groupby(block_factors, sort=False):
        block_key = dict(zip(block_factors, block_values, strict=True))
        levels = levels_of(block, factor)
        for base in bases:
            if base not in levels and len(levels) > 1:
                notes.append(
                    f"{describe_block(block_key, frame)}: no {base!r} runs, no paired tests "
                    f"against it"
                )
        for metric in metrics:
            table = block.pivot_table(index="seed", columns=factor, values=metric, aggfunc="first")
            table = table.reindex(columns=levels)
            for k, level in enumerate(levels):
                s = stats.describe(table[level].to_numpy(), seed=k)
                summary_rows.append({**block_key, factor: level, "metric": metric, **vars(s)})
            for base in bases:
                compared = [level for level in levels if level != base]
                if base not in levels or not compared:
                    continue
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
                    row["significant"] = bool(p_holm < stats.SIGNIFICANCE)
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
        baselines=bases,
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
