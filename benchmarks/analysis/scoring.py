"""Statistics of solves against best-known optima: the measures optimisation benchmarks use.

A *trial* is one optimiser's solve of one instance with one seed. Each trial gives its final
relative gap to the instance's best-known cost ``J*`` and, from the solve's history, the
evaluations it took to first reach each target gap. From those:

- :func:`success_rate`: the share of trials whose final gap is at most a target;
- :func:`expected_running_time`: COCO's ERT, the evaluations spent over all trials (a
  successful trial counts its evaluations to the target, an unsuccessful one all it used)
  divided by the number of successes (Hansen et al., COCO: performance assessment, 2021);
- :func:`runtime_ecdf`: the share of (trial, target) pairs reached within each number of
  evaluations, as COCO and IOHprofiler draw it;
- :func:`performance_profile`: Dolan and More's (2002) profile of a cost such as solve
  time: per solver, the share of problems it solves within a factor tau of the best solver
  on that problem (a failure never counts);
- :func:`shifted_geometric_mean`: exp(mean(log(t + shift))) - shift, with failures charged
  at a given value (as qpbenchmark charges them at the time limit).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

TARGETS = (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
"""Target relative gaps of the runtime statistics; success rates are reported at 1e-2,
1e-3 and 1e-4."""
SUCCESS_TARGETS = (1e-2, 1e-3, 1e-4)


def relative_gap(cost: np.ndarray | float, j_star: np.ndarray | float) -> np.ndarray:
    """``(cost - J*) / |J*|``: 0 at the best-known cost, negative below it."""
    j_star = np.asarray(j_star, dtype=np.float64)
    return (np.asarray(cost, dtype=np.float64) - j_star) / np.abs(j_star)


def evaluations_to_target(
    history_nfev: np.ndarray, history_fun: np.ndarray, j_star: float, target: float
) -> float:
    """Evaluations after which the best cost so far first had a gap <= ``target``; NaN if
    the solve never reached it. ``history_*`` are the solve's best-so-far trace."""
    reached = np.flatnonzero(relative_gap(history_fun, j_star) <= target)
    return float(history_nfev[reached[0]]) if reached.size else math.nan


def success_rate(gaps: np.ndarray, target: float) -> float:
    """Share of trials whose final gap is at most ``target``."""
    gaps = np.asarray(gaps, dtype=np.float64)
    return float(np.mean(gaps <= target))


def expected_running_time(hits: np.ndarray, used: np.ndarray) -> float:
    """COCO's ERT over trials: ``hits`` are the evaluations to the target (NaN: not reached),
    ``used`` the evaluations each trial spent in all; inf if no trial reached the target."""
    hits = np.asarray(hits, dtype=np.float64)
    used = np.asarray(used, dtype=np.float64)
    success = np.isfinite(hits)
    if not success.any():
        return math.inf
    spent = np.where(success, hits, used).sum()
    return float(spent / success.sum())


def runtime_ecdf(hits: np.ndarray, budgets: np.ndarray) -> np.ndarray:
    """Share of (trial, target) pairs reached within each of ``budgets`` evaluations.

    ``hits`` is ``(trials, targets)`` evaluations to each target (NaN: not reached)."""
    hits = np.asarray(hits, dtype=np.float64).reshape(-1)
    reached = np.where(np.isfinite(hits), hits, np.inf)
    return np.array([np.mean(reached <= b) for b in np.asarray(budgets, dtype=np.float64)])


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
    values: np.ndarray, shift: float, failed: np.ndarray | None = None, charge: float = math.nan
) -> float:
    """``exp(mean(log(v + shift))) - shift``, with every failed value replaced by ``charge``."""
    values = np.asarray(values, dtype=np.float64)
    if failed is not None:
        values = np.where(np.asarray(failed, dtype=bool), charge, values)
    return float(np.exp(np.mean(np.log(values + shift))) - shift)
