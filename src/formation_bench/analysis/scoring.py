"""Statistics of solves against best-known optima: the measures optimisation benchmarks use.

A *trial* is one optimiser's solve of one instance with one seed. Its gaps to the instance's
best-known cost ``J*`` (:func:`relative_gap`, :func:`normalised_gap`), the targets of the
normalised gap (:data:`TARGETS`) and its evaluations to each target
(:func:`evaluations_to_target`) are what a score run records: they are defined in
:mod:`formation_bench.experiments.gaps`, where the runs are made, and read here.

The fixed-target measures, at the targets :data:`TARGETS` of the normalised gap (target
1e-3: 99.9 % of the possible improvement made):

- :func:`success_rate`: the share of trials whose final gap is at most a target;
- :func:`expected_running_time`: COCO's ERT, the evaluations spent over all trials (a
  successful trial counts its evaluations to the target, an unsuccessful one all it used)
  divided by the number of successes (Hansen et al., COCO: performance assessment, 2021);
- :func:`runtime_ecdf`: the share of (trial, target) pairs reached within each number of
  evaluations, as COCO and IOHprofiler draw it.

And, for solve times:

- :func:`performance_profile`: Dolan and More's (2002) profile of a cost such as solve
  time: per solver, the share of problems it solves within a factor tau of the best solver
  on that problem (a failure never counts);
- :func:`shifted_geometric_mean`: exp(mean(log(t + shift))) - shift, with failures charged
  at a given value (as qpbenchmark charges them at the time limit).

The trial statistics take optional weights, so that a problem solved by several trials
counts once (each trial weighted by one over its problem's trials).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

# defined where the score runs are made; the analysis reads them from there
from formation_bench.experiments.gaps import TARGET_GAP as TARGET_GAP
from formation_bench.experiments.gaps import TARGETS as TARGETS
from formation_bench.experiments.gaps import evaluations_to_target as evaluations_to_target
from formation_bench.experiments.gaps import normalised_gap as normalised_gap
from formation_bench.experiments.gaps import relative_gap as relative_gap

SUCCESS_TARGETS = (1e-2, 1e-3, 1e-4)
"""Targets of the normalised gap at which success rates are reported."""


def _weights(weights: np.ndarray | None, size: int) -> np.ndarray:
    if weights is None:
        return np.ones(size)
    weights = np.asarray(weights, dtype=np.float64)
    if weights.shape != (size,):
        raise ValueError(f"{size} trials but weights of shape {weights.shape}")
    return weights


def success_rate(gaps: np.ndarray, target: float, weights: np.ndarray | None = None) -> float:
    """(Weighted) share of trials whose final gap is at most ``target`` (a NaN gap fails);
    NaN without trials."""
    gaps = np.asarray(gaps, dtype=np.float64)
    if gaps.size == 0:
        return math.nan
    return float(np.average(gaps <= target, weights=_weights(weights, gaps.size)))


def expected_running_time(
    hits: np.ndarray, used: np.ndarray, weights: np.ndarray | None = None
) -> float:
    """COCO's ERT over trials: ``hits`` are the evaluations to the target (NaN: not reached),
    ``used`` the evaluations each trial spent in all; inf if no trial reached the target.
    With ``weights``, the evaluations spent and the successes are both weighted sums."""
    hits = np.asarray(hits, dtype=np.float64)
    used = np.asarray(used, dtype=np.float64)
    w = _weights(weights, hits.size)
    success = np.isfinite(hits)
    if not (success & (w > 0)).any():
        return math.inf
    spent = (w * np.where(success, hits, used)).sum()
    return float(spent / w[success].sum())


def runtime_ecdf(
    hits: np.ndarray, budgets: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """Share of (trial, target) pairs reached within each of ``budgets`` evaluations.

    ``hits`` is ``(trials, targets)`` evaluations to each target (NaN: not reached);
    ``weights`` one per trial."""
    hits = np.asarray(hits, dtype=np.float64)
    hits = hits.reshape(hits.shape[0], -1) if hits.ndim else hits.reshape(1, 1)
    w = np.repeat(_weights(weights, hits.shape[0]), hits.shape[1])
    reached = np.where(np.isfinite(hits), hits, np.inf).reshape(-1)
    if reached.size == 0:
        return np.full(np.shape(budgets), np.nan)
    return np.array(
        [np.average(reached <= b, weights=w) for b in np.asarray(budgets, dtype=np.float64)]
    )


def performance_profile(costs: pd.DataFrame, taus: np.ndarray) -> pd.DataFrame:
    """Dolan-More profile: ``costs`` has one row per problem and one column per solver (NaN
    or inf: a failure). Returns, per tau, the share of problems each solver solves within tau
    times the best solver's cost on that problem."""
    values = costs.to_numpy(dtype=np.float64)
    values = np.where(np.isfinite(values), values, np.inf)
    best = values.min(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratios = np.where(np.isfinite(values), values / best, np.inf)
    profile = {
        solver: [float(np.mean(ratios[:, k] <= tau)) for tau in taus]
        for k, solver in enumerate(costs.columns)
    }
    return pd.DataFrame(profile, index=pd.Index(taus, name="tau"))


def shifted_geometric_mean(
    values: np.ndarray,
    shift: float,
    failed: np.ndarray | None = None,
    charge: float = math.nan,
    weights: np.ndarray | None = None,
) -> float:
    """``exp(mean(log(v + shift))) - shift``, with every failed value replaced by ``charge``
    (the mean weighted by ``weights``); NaN without values."""
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        return math.nan
    if failed is not None:
        values = np.where(np.asarray(failed, dtype=bool), charge, values)
    mean = np.average(np.log(values + shift), weights=_weights(weights, values.size))
    return float(np.exp(mean) - shift)
