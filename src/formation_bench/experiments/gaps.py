"""How far a solve ends from an instance's best-known cost: the gaps and the evaluations to a
target that a score run (:mod:`~formation_bench.experiments.score`) records for every solve.

Two gaps measure how far a cost ``f`` ends from the best-known cost ``J*``:

- :func:`relative_gap`: ``(f - J*) / |J*|``, the share of ``J*`` left. Reported, but noise
  where ``J*`` is near zero, and no target of it means the same on every problem;
- :func:`normalised_gap`: ``(f - J*) / (f_warm - J*)``, the share of the possible
  improvement (from the warm start's cost ``f_warm`` to ``J*``) left: 1 at the warm start,
  0 at ``J*``. Defined wherever the warm start leaves something to gain, that is on every
  non-degenerate instance of the library; the fixed-target measures use it.

:func:`evaluations_to_target` reads, from a solve's history, when its best cost so far first
reached each of the :data:`TARGETS`. The statistics over many solves (success rates, ERT,
ECDFs, profiles) are in :mod:`formation_bench.analysis.scoring`, which reads what is stored.
"""

from __future__ import annotations

import math

import numpy as np

TARGETS = (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
"""Targets of the normalised gap for the runtime statistics (evaluations to each target,
ERT, ECDFs); target t: a share ``1 - t`` of the possible improvement made."""
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


def target_column(target: float) -> str:
    """Column of the evaluations to reach a normalised gap of ``target`` (e.g.
    ``evals_to_norm_1e-03``)."""
    return f"evals_to_norm_{target:.0e}"
