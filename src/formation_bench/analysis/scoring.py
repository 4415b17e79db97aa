"""Statistics of solves against best-known optima: the measures optimisation benchmarks use.

A *trial* is one optimiser's solve of one instance with one seed. Two gaps measure how far
its cost ``f`` ends from the instance's best-known cost ``J*``:

- :func:`relative_gap`: ``(f - J*) / |J*|``, the share of ``J*`` left. Reported, but noise
  where ``J*`` is near zero, and no target of it means the same on every problem;
- :func:`normalised_gap`: ``(f - J*) / (f_warm - J*)``, the share of the possible
  improvement (from the warm start's cost ``f_warm`` to ``J*``) left: 1 at the warm start,
  0 at ``J*``. Defined wherever the warm start leaves something to gain, that is on every
  non-degenerate instance of the library; the fixed-target measures use it.

The fixed-target measures, at the targets :data:`TARGETS` of the normalised gap (target
1e-3: 99.9 % of the possible improvement made):

- :func:`evaluations_to_target`: from a solve's history, the evaluations after which its
  best cost so far first reached a target;
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

TARGETS = (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
"""Targets of the normalised gap for the runtime statistics (evaluations to each target,
ERT, ECDFs); target t: a share ``1 - t`` of the possible improvement made."""
SUCCESS_TARGETS = (1e-2, 1e-3, 1e-4)
"""Targets of the normalised gap at which success rates are reported."""
TARGET_GAP = "normalised gap (f - J*) / (f_warm - J*)"
"""The gap every target refers to, as the outputs name it."""


def relative_gap(cost: np.ndarray | float, j_star: np.ndarray | float) -> np.ndarray:
    """``(cost - J*) / |J*|``: 0 at the best-known cost, negative below it."""
    j_star = np.asarray(j_star, dtype=np.float64)
    return (np.asarray(cost, dtype=np.float64) - j_star) / np.abs(j_star)


def normalised_gap(
    cost: np.ndarray | float, j_star: np.ndarray | float, warm_cost: np.ndarray | float
) -> np.ndarray:
    """``(cost - J*) / (warm_cost - J*)``: 1 at the warm start's cost, 0 at ``J*``, negative
    below it; NaN where the warm start is not above ``J*`` (nothing to improve). The
    library's :meth:`Instance.normalised_gap` is the same, and NaN on every degenerate
    instance."""
    j_star = np.asarray(j_star, dtype=np.float64)
    span = np.asarray(warm_cost, dtype=np.float64) - j_star
    cost = np.asarray(cost, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(span > 0, (cost - j_star) / np.where(span > 0, span, 1.0), np.nan)


def evaluations_to_target(
    history_nfev: np.ndarray,
    history_fun: np.ndarray,
    j_star: float,
    warm_cost: float,
    target: float,
) -> float:
    """Evaluations after which the best cost so far first had a normalised gap <= ``target``;
    NaN if the solve never reached it, or the gap is not defined (warm start not above
    ``J*``). ``history_*`` are the solve's best-so-far trace."""
    reached = np.flatnonzero(normalised_gap(history_fun, j_star, warm_cost) <= target)
    return float(np.asarray(history_nfev)[reached[0]]) if reached.size else math.nan


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
