"""Helpers shared by the population optimisers: the initial population and budget-truncated batches.

Every population method starts the same way (``N`` uniform points, the warm
start in row 0, optionally a share of the members drawn around the warm start
(:class:`WarmStartInit`), one batch evaluation within the budget), and every
one of them evaluates a batch of new points that the budget may cut short.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from time import perf_counter
from typing import NamedTuple

import numpy as np

from formation_bench.fields import Search, setting
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.base import Bounds, EvaluationCounter, OptimizeResult
from formation_bench.optimizers.bound_handling import BoundHandling, apply_bounds_inplace
from formation_bench.optimizers.compiled import (
    HAS_BEST,
    NFEV,
    CompiledObjective,
    new_tally,
)
from formation_bench.optimizers.compiled import evaluate_prefix as compiled_evaluate_prefix

POPULATION_SEARCH = Search(4, 100, log=True)
"""What a tuner searches of a population size: at the evaluation budget a tuning gives a solve
(about 1200) 100 members still leave some ten iterations; 4 is the least every method takes."""


@dataclass(frozen=True)
class WarmStartInit:
    """How much of the initial population starts around the warm start.

    In a receding horizon the warm start (the shifted previous plan) is nearly
    right, and a population drawn uniformly in the box spends its first
    generations far from it. With ``warm_start_share`` > 0, that share of the
    members after row 0 is drawn from a Gaussian cloud around the warm start
    (standard deviation ``warm_start_spread`` of each coordinate's range),
    mirrored back into the box at its faces; the rest stay uniform, so the
    search can still leave a wrong start. Without a warm start, or at share 0
    (the published methods), the population is uniform with the warm start as
    row 0, drawing exactly the random numbers it drew before.
    """

    warm_start_share: float = setting(
        0.0,
        low=0.0,
        high=1.0,
        search=Search(0.0, 1.0),
        doc="Share of the initial population drawn around the warm start (rows after "
        "row 0, which is the warm start itself); 0: uniform in the box (the published methods)",
    )
    warm_start_spread: float = setting(
        0.05,
        low=0.0,
        low_open=True,
        high=1.0,
        search=Search(0.001, 0.5, log=True),
        doc="Standard deviation of the cloud around the warm start, per coordinate, "
        "as a share of the coordinate's range",
    )

    def warm_members(self, size: int) -> int:
        """How many rows after row 0 are drawn around the warm start, of ``size`` members."""
        return min(size - 1, round(self.warm_start_share * size)) if size > 1 else 0


UNIFORM_START = WarmStartInit()
"""The published initialisation: uniform in the box, the warm start as row 0."""


def starting_points(
    bounds: Bounds,
    rng: np.random.Generator,
    size: int,
    x0: np.ndarray | None,
    init: WarmStartInit = UNIFORM_START,
) -> np.ndarray:
    """The ``size`` initial members (see :class:`WarmStartInit`), not yet evaluated.

    The uniform points are drawn first, so at share 0 the numbers drawn are
    those of the uniform start; the cloud's normals are drawn after them.
    """
    points = bounds.sample(rng, size)
    if x0 is None:
        return points
    points[0] = x0
    warm = init.warm_members(size)
    if warm > 0:
        spread = init.warm_start_spread * bounds.width
        cloud = x0 + rng.standard_normal((warm, bounds.dim)) * spread
        apply_bounds_inplace(
            cloud, bounds.lower, bounds.upper, BoundHandling.REFLECT, np.empty((0, 0))
        )
        points[1 : warm + 1] = cloud
    return points


def initial_population(
    counter: EvaluationCounter,
    bounds: Bounds,
    rng: np.random.Generator,
    size: int,
    x0: np.ndarray | None,
    init: WarmStartInit = UNIFORM_START,
) -> tuple[np.ndarray, np.ndarray]:
    """The initial members (:func:`starting_points`) and their costs.

    Rows beyond the remaining evaluation budget are left unevaluated with
    cost ``+inf``, so they lose every comparison.
    """
    points = starting_points(bounds, rng, size, x0, init)
    costs = evaluate_prefix(counter, points)
    return points, costs


def evaluate_prefix(counter: EvaluationCounter, points: np.ndarray) -> np.ndarray:
    """Costs of ``points``: the first ``counter.remaining`` rows evaluated, the rest ``+inf``."""
    n = points.shape[0]
    if counter.remaining >= n:  # the usual case: no copy, no padding
        return counter(points)
    costs = np.full(n, math.inf)
    allowed = counter.remaining
    if allowed > 0:
        costs[:allowed] = counter(points[:allowed])
    return costs


@njit(cache=True)
def greedy_select(
    old_x: np.ndarray, old_f: np.ndarray, new_x: np.ndarray, new_f: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """Slot-wise selection: ``new_x[i]`` replaces ``old_x[i]`` only if strictly better.

    ``new_x`` may have fewer rows than ``old_x`` (a batch truncated by the
    budget); the remaining slots keep their old members. Returns
    ``(x, f, number of replaced slots)``. NaN costs never win a comparison;
    the evaluation counter already maps them to ``+inf``.
    """
    x = old_x.copy()
    f = old_f.copy()
    improved = 0
    # element loops rather than row assignments: a row assignment makes numba compile a
    # shape-mismatch error path (with its message formatting), a second of a cold start
    for i in range(new_x.shape[0]):
        if new_f[i] < old_f[i]:
            for c in range(x.shape[1]):
                x[i, c] = new_x[i, c]
            f[i] = new_f[i]
            improved += 1
    return x, f, improved


COMPILED_NORMALS_FROM = 1000
"""Draws of at least this many standard normals are made by :func:`_fill_standard_normals`."""


@njit(cache=True)
def _fill_standard_normals(rng: np.random.Generator, out: np.ndarray) -> None:
    for i in range(out.shape[0]):
        out[i] = rng.standard_normal()


def standard_normals(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """``rng.standard_normal(shape)``: the same numbers, and ``rng`` left in the same state.

    numba's Generator runs numpy's own ziggurat on the same bit generator, one number after
    the other as numpy fills an array, in about a third of numpy's time (2.8 against 8.5 ns
    per number on the development machine); handing it the Generator costs about 5 µs (numba
    unboxes it through three ``ctypes.cast`` calls), so only draws of
    :data:`COMPILED_NORMALS_FROM` numbers or more go to it (both take about 8 µs for 900). A
    test checks both paths against ``rng.standard_normal``.
    """
    size = math.prod(shape)
    if size < COMPILED_NORMALS_FROM:
        return rng.standard_normal(shape)
    out = np.empty(size)
    _fill_standard_normals(rng, out)
    return out.reshape(shape)


ROWS_AHEAD = 64
"""Most iterations whose random numbers one Generator call draws."""


class RandomAhead(NamedTuple):
    """Uniforms and standard normals drawn ahead for the next iterations of a solve.

    A Generator call costs about a microsecond besides its numbers, and the
    numbers themselves come about three times cheaper per value in one large
    call: together about 3 µs of a BSO iteration's 30 µs of own work at
    N = 30. So :func:`iteration_randoms` draws each kind for up to
    :data:`ROWS_AHEAD` iterations at once, one row per iteration. Which
    numbers an iteration gets depends only on the seed, the planned
    iterations and the row layout.
    """

    first_iteration: int
    """Iteration whose numbers are row 0."""
    uniforms: np.ndarray
    """Uniforms in [0, 1), one row per iteration."""
    normals: np.ndarray
    """Standard normals, one block per iteration (shape ``(rows, *normal_shape)``)."""


@functools.lru_cache(maxsize=64)
def no_randoms(n_uniforms: int, normal_shape: tuple[int, ...]) -> RandomAhead:
    """An empty block: the first :func:`iteration_randoms` call draws. Shared by the solves
    (it holds no number to modify)."""
    return RandomAhead(1, np.empty((0, n_uniforms)), np.empty((0, *normal_shape)))


def iteration_randoms(
    block: RandomAhead, rng: np.random.Generator, iteration: int, t_max: int
) -> tuple[RandomAhead, np.ndarray, np.ndarray]:
    """``(block, uniforms, normals)`` of ``iteration``, drawing a new block when needed.

    A new block covers the planned iterations left (``t_max - iteration + 1``),
    at least one and at most :data:`ROWS_AHEAD`, in two calls: all its
    uniforms, then all its normals. The returned rows are views; the block's
    arrays are never modified.
    """
    row = iteration - block.first_iteration
    if not 0 <= row < block.uniforms.shape[0]:
        rows = min(max(t_max - iteration + 1, 1), ROWS_AHEAD)
        width = block.uniforms.shape[1]
        # a draw of no numbers leaves the Generator as it is, and is not made
        uniforms = rng.random((rows, width)) if width else np.empty((rows, 0))
        normals = standard_normals(rng, (rows, *block.normals.shape[1:]))
        block, row = RandomAhead(iteration, uniforms, normals), 0
    return block, block.uniforms[row], block.normals[row]


def step_scale(bounds: Bounds, scale: float, relative_to_range: bool) -> np.ndarray:
    """Per-coordinate step multiplier: ``scale``, times the range when ``relative_to_range``."""
    factor = bounds.width if relative_to_range else np.ones(bounds.dim)
    return np.ascontiguousarray(scale * factor, dtype=np.float64)


@njit(cache=True)
def progress(iteration: int, t_max: int) -> float:
    """``(iteration - 1) / (t_max - 1)`` clipped to [0, 1]: 0 at the first iteration, 1 at the last.

    0 throughout when ``t_max <= 1``. Schedules (inertia, search radius) use it.
    """
    if t_max <= 1:
        return 0.0
    return min(max((iteration - 1) / (t_max - 1), 0.0), 1.0)


class CompiledStart(NamedTuple):
    """A compiled solve after its initial population: its tally and when it began."""

    counts: np.ndarray
    """The tally's counts (see :func:`~formation_bench.optimizers.compiled.new_tally`)."""
    best: np.ndarray
    """The tally's best cost and point."""
    started: float
    """``time.perf_counter()`` when the solve began, for a budget's deadline."""


def compiled_initial_population(
    objective: CompiledObjective,
    bounds: Bounds,
    rng: np.random.Generator,
    size: int,
    x0: np.ndarray | None,
    max_evaluations: int | None,
    init: WarmStartInit = UNIFORM_START,
) -> tuple[np.ndarray, np.ndarray, CompiledStart]:
    """:func:`initial_population` for a compiled solve: the same points, costs and draws."""
    start = CompiledStart(*new_tally(bounds.dim, max_evaluations), perf_counter())
    points = starting_points(bounds, rng, size, x0, init)
    costs = compiled_evaluate_prefix(
        objective.address, objective.data, points, start.counts, start.best
    )
    return points, costs, start


def compiled_result(
    tally: CompiledStart,
    nit: int,
    message: str,
    history_nfev: list[int],
    history_fun: list[float],
    info: dict,
) -> OptimizeResult:
    """The :class:`OptimizeResult` of a compiled solve, from its tally and history.

    ``info["objective_time_s"]`` is NaN: compiled code has no clock around its objective calls.
    """
    counts, best = tally.counts, tally.best
    assert counts[HAS_BEST] == 1
    return OptimizeResult(
        x=best[1:].copy(),
        fun=float(best[0]),
        nfev=int(counts[NFEV]),
        nit=nit,
        success=True,
        message=message,
        history_nfev=np.asarray(history_nfev, dtype=np.int64),
        history_fun=np.asarray(history_fun),
        info={"objective_time_s": math.nan, **info},
    )
