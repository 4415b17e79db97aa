"""The rules of :mod:`.cem` as pure functions a test drives with fixed numbers: the batch sizes
(iCEM's decay and the mean in the last iteration), the normals of the samples, and the refit
of the Gaussian to its elites with momentum."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from formation_bench.kernel_cache import njit
from formation_bench.optimizers.ask_tell import BlockSource
from formation_bench.optimizers.population import ROWS_AHEAD, standard_normals

UNPLANNED = 2**62
"""A ``t_max`` no iteration reaches: only the evaluations left end the iterations."""


class Schedule(NamedTuple):
    """What the batch sizes depend on: the fields of these names of a configuration and its
    ``t_max`` (compiled code passes the kernel settings, which have them too)."""

    population_size: int
    elite_count: int
    sample_decay: float
    sample_mean_last: bool
    t_max: int

    @classmethod
    def of(cls, config: Any, t_max: int) -> Schedule:
        return cls(config.population_size, config.elite_count, config.sample_decay,
                   config.sample_mean_last, t_max)  # fmt: skip


@njit(cache=True)
def sample_count(population_size: int, elite_count: int, sample_decay: float, i: int) -> int:
    """``N_i = min(N, max(floor(N gamma^-i), 2K))``, iteration ``i`` counted from 0."""
    decayed = math.floor(population_size / sample_decay**i)
    return min(population_size, max(decayed, 2 * elite_count))


@njit(cache=True)
def batch_size(s, iteration, remaining):  # type: ignore[no-untyped-def]
    """``(samples, mean)`` of ``iteration`` (from 1) with ``remaining`` evaluations left, for
    a :class:`Schedule` ``s``: ``N_i`` samples, fewer if the evaluations end, and ``mean = 1``
    in the last iteration with ``sample_mean_last`` (the planned last, ``t_max``, or the one
    the evaluations end). Python runs the same code (``batch_size.py_func``)."""
    drawn = sample_count(population_size=s.population_size, elite_count=s.elite_count,
                         sample_decay=s.sample_decay, i=iteration - 1)  # fmt: skip
    last = iteration >= s.t_max or remaining <= drawn + 1
    mean = 1 if s.sample_mean_last and last else 0
    return min(drawn, remaining - mean), mean


def iterations_within(config: Any, left: int) -> int:
    """Iterations that ``left`` evaluations allow ``config``, the last taking what is left;
    the sizes stop changing at ``min(N, 2K)`` (at once without decay), and the rest is
    counted, not run."""
    s = Schedule.of(config, UNPLANNED)
    floor_size = min(s.population_size, 2 * s.elite_count)
    done = 0
    while left > 0:
        full = sample_count(population_size=s.population_size, elite_count=s.elite_count,
                            sample_decay=s.sample_decay, i=done)  # fmt: skip
        if full == floor_size or s.sample_decay == 1.0:
            return done + max(1, -(-(left - int(s.sample_mean_last)) // full))
        drawn, mean = batch_size.py_func(s, done + 1, left)
        left -= drawn + mean
        done += 1
    return done


class SampleNormals(BlockSource):
    """The standard normals of the samples, and no more: the next iterations' batch sizes are
    known before they run, so one ``standard_normal`` call draws theirs, in order, into rows
    of ``(N, D)`` (a decayed batch fills the first rows; the rest is zero, never read). A
    Generator gives the numbers of separate calls in one, so the numbers an iteration gets do
    not depend on how the iterations are blocked."""

    def __init__(self, schedule: Schedule, dim: int) -> None:
        self.schedule, self.dim = schedule, dim

    def next_block(
        self, state: Any, rng: np.random.Generator, iteration: int, rows: int, left: int
    ) -> tuple[Any, np.ndarray, np.ndarray]:
        s, d = self.schedule, self.dim
        rows = min(max(s.t_max - iteration + 1, 1), ROWS_AHEAD, rows)
        sizes = []
        while len(sizes) < rows and left > 0:
            drawn, mean = batch_size.py_func(s, iteration + len(sizes), left)
            sizes.append(drawn)
            left -= drawn + mean
        flat = standard_normals(rng, (sum(sizes) * d,))
        normals = np.zeros((len(sizes), s.population_size, d))
        start = 0
        for row, drawn in enumerate(sizes):
            normals[row, :drawn] = flat[start : start + drawn * d].reshape(drawn, d)
            start += drawn * d
        return state, np.zeros((len(sizes), 0)), normals


@njit(cache=True)
def elite_refit(state, points, costs, elite_count, momentum, kept_count):  # type: ignore[no-untyped-def]
    """``(mean, std, kept, kept_costs)`` after a selection among ``points`` (with ``costs``)
    and ``state``'s kept elites: the ``K`` best (ties: the earlier, samples before kept
    ones), their mean and maximum-likelihood std (divisor K) mixed into ``state``'s with
    ``momentum``, and the best ``kept_count`` of them, best first, kept."""
    m, d = points.shape
    pool = np.empty((m + state.kept.shape[0], d))
    # element by element: a slice assignment makes numba compile its shape-mismatch error,
    # and with it string formatting (about 1.5 s of a first run's compile)
    for i in range(m):
        for j in range(d):
            pool[i, j] = points[i, j]
    for i in range(state.kept.shape[0]):
        for j in range(d):
            pool[m + i, j] = state.kept[i, j]
    pool_costs = np.concatenate((costs, state.kept_costs))
    order = np.argsort(pool_costs, kind="mergesort")
    k = min(elite_count, pool.shape[0])
    if k == 0:
        return state.mean, state.std, state.kept, state.kept_costs
    elite_mean = np.zeros(d)
    for r in range(k):
        elite_mean += pool[order[r]]
    elite_mean /= k
    elite_var = np.zeros(d)
    for r in range(k):
        elite_var += (pool[order[r]] - elite_mean) ** 2
    elite_std = np.sqrt(elite_var / k)
    keep = min(kept_count, k)
    kept = np.empty((keep, d))
    for r in range(keep):
        for j in range(d):
            kept[r, j] = pool[order[r], j]
    mean = momentum * state.mean + (1.0 - momentum) * elite_mean
    std = momentum * state.std + (1.0 - momentum) * elite_std
    return mean, std, kept, pool_costs[order[:keep]]
