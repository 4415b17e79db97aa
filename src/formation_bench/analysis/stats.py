"""Statistics of sweep results: descriptive summaries and paired comparisons.

Every test is a library call (scipy.stats, scikit-posthocs, statsmodels); this
module only arranges the data and names the outputs:

- :func:`describe`: median, quartiles, IQR and a percentile-bootstrap 95 % CI of
  the median (:func:`scipy.stats.bootstrap`, fixed generator so reports repeat);
- :func:`wilcoxon_paired`: Wilcoxon signed-rank test on pairs matched by seed
  (:func:`scipy.stats.wilcoxon`, two-sided, zero differences dropped);
- :func:`holm`: Holm's step-down adjustment, the formula of
  ``statsmodels.stats.multitest.multipletests(method="holm")`` (checked against it in
  the tests; that function calls ``gc.collect()`` on every call, ~0.1 s in a report's
  process, so the two lines are written out here);
- :func:`a12`: the Vargha-Delaney effect size A12 = P(X > Y) + P(X = Y) / 2, from
  the Mann-Whitney U of :func:`scipy.stats.mannwhitneyu` (A12 = U / (m n));
- :func:`friedman`: Friedman's test over seeds (:func:`scipy.stats.friedmanchisquare`)
  with the average ranks (rank 1 = smallest value), and the Nemenyi post-hoc
  p-values (:func:`scikit_posthocs.posthoc_nemenyi_friedman`).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

SIGNIFICANCE = 0.05
"""Level of every test the reports mark (after Holm's adjustment)."""
BOOTSTRAP_RESAMPLES = 2000
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Summary:
    """Descriptive statistics of one sample."""

    n: int
    median: float
    q1: float
    q3: float
    iqr: float
    ci_low: float
    ci_high: float


def describe(values: np.ndarray, *, seed: int = 0) -> Summary:
    """Median, quartiles (linear interpolation), IQR and bootstrap CI of the median."""
    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        nan = math.nan
        return Summary(0, nan, nan, nan, nan, nan, nan)
    q1, median, q3 = np.percentile(x, [25, 50, 75])
    if x.size < 2 or np.all(x == x[0]):
        low = high = float(median)
    else:
        result = stats.bootstrap(
            (x,),
            np.median,
            confidence_level=CONFIDENCE,
            n_resamples=BOOTSTRAP_RESAMPLES,
            method="percentile",
            rng=np.random.default_rng(seed),
        )
        low, high = float(result.confidence_interval.low), float(result.confidence_interval.high)
    return Summary(int(x.size), float(median), float(q1), float(q3), float(q3 - q1), low, high)


def a12(x: np.ndarray, y: np.ndarray) -> float:
    """Vargha-Delaney A12: probability that a value of ``x`` exceeds one of ``y`` (ties half).

    0.5 = no difference; for error metrics (lower is better) A12 < 0.5 favours ``x``.
    """
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.size == 0 or y.size == 0:
        return math.nan
    u = stats.mannwhitneyu(x, y, alternative="two-sided").statistic
    return float(u / (x.size * y.size))


def wilcoxon_paired(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Two-sided Wilcoxon signed-rank test of paired samples: ``(statistic, p)``.

    Pairs with zero difference are dropped (``zero_method="wilcox"``); when every
    difference is zero there is no evidence of a difference: ``(nan, 1.0)``.
    """
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.size != y.size:
        raise ValueError(f"paired samples must have equal length, got {x.size} and {y.size}")
    if x.size == 0:
        return math.nan, math.nan
    if np.all(x == y):
        return math.nan, 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "sample size too small" for exact p
        result = stats.wilcoxon(x, y, zero_method="wilcox", alternative="two-sided")
    return float(result.statistic), float(result.pvalue)


def paired_comparison(x: np.ndarray, y: np.ndarray) -> dict[str, float | int]:
    """Two paired samples side by side: their number, medians, the median of ``x - y``, how
    often ``x`` is lower, higher or tied, the two-sided Wilcoxon p (:func:`wilcoxon_paired`)
    and A12 = P(x > y) (:func:`a12`)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    _, p = wilcoxon_paired(x, y)
    some = x.size > 0
    return {
        "pairs": int(x.size),
        "x_median": float(np.median(x)) if some else math.nan,
        "y_median": float(np.median(y)) if some else math.nan,
        "median_difference": float(np.median(x - y)) if some else math.nan,
        "x_lower": int((x < y).sum()),
        "x_higher": int((x > y).sum()),
        "ties": int((x == y).sum()),
        "p": p,
        "a12": a12(x, y),
    }


def holm_family(rows: list[dict]) -> None:
    """Add ``p_holm`` (Holm over the rows' ``p``) and ``significant`` (``p_holm`` below
    :data:`SIGNIFICANCE`) to each row of one family of tests."""
    for row, p_holm in zip(rows, holm([r["p"] for r in rows]), strict=True):
        row["p_holm"] = float(p_holm)
        row["significant"] = bool(p_holm < SIGNIFICANCE)


def holm(pvalues: list[float] | np.ndarray) -> np.ndarray:
    """Holm-adjusted p-values (NaN entries stay NaN and do not count in the family)."""
    p = np.asarray(pvalues, dtype=np.float64)
    adjusted = np.full(p.shape, np.nan)
    finite = np.flatnonzero(np.isfinite(p))
    if finite.size:
        order = finite[np.argsort(p[finite], kind="stable")]
        m = order.size
        stepped = np.maximum.accumulate(p[order] * np.arange(m, 0, -1))
        adjusted[order] = np.minimum(stepped, 1.0)
    return adjusted


@dataclass(frozen=True)
class FriedmanResult:
    """Friedman's test over blocks (seeds) and treatments (columns)."""

    n_blocks: int
    statistic: float
    pvalue: float
    average_ranks: pd.Series
    """Mean rank of each treatment over the blocks; rank 1 = smallest value."""
    nemenyi: pd.DataFrame | None
    """Pairwise Nemenyi p-values, or None with fewer than 3 treatments."""


def friedman(table: pd.DataFrame) -> FriedmanResult:
    """Friedman's test of a blocks x treatments table (rows with a NaN are dropped)."""
    complete = table.dropna()
    ranks = pd.DataFrame(
        stats.rankdata(complete.to_numpy(), axis=1), index=complete.index, columns=complete.columns
    )
    average = ranks.mean(axis=0) if len(complete) else pd.Series(np.nan, index=table.columns)
    if complete.shape[1] < 3 or len(complete) < 2:
        return FriedmanResult(len(complete), math.nan, math.nan, average, None)
    values = complete.to_numpy()
    if np.all(values == values[:, :1]):  # every treatment equal in every block
        return FriedmanResult(len(complete), 0.0, 1.0, average, None)
    result = stats.friedmanchisquare(*(values[:, k] for k in range(values.shape[1])))
    nemenyi = _nemenyi(complete)
    return FriedmanResult(
        len(complete), float(result.statistic), float(result.pvalue), average, nemenyi
    )


def _nemenyi(complete: pd.DataFrame) -> pd.DataFrame:
    import scikit_posthocs as sp

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return (
            sp.posthoc_nemenyi_friedman(complete.to_numpy())
            .set_axis(complete.columns, axis=0)
            .set_axis(complete.columns, axis=1)
        )
