"""Uniform random search: the floor every optimiser must beat.

Each iteration draws ``population_size`` points uniformly in the box and evaluates them in one
batch; the initial batch holds the warm start ``x0`` (when given) in its first row, so the
result is never worse than the warm start. Nothing is learned from the costs: the evaluation
tally keeps the best point seen, which is the result. With the defaults (30 points, 40
iterations after the first batch) it spends the ~1230 evaluations of the other population
optimisers' default budget, so its result is the budget's worth of blind sampling any method
has to improve on.

The iteration is the kernel :func:`random_search_ask` (its ``tell`` keeps nothing), which both
solve loops of :mod:`~formation_bench.optimizers.ask_tell` drive. An iteration draws the
uniforms of its batch alone, as many as the budget lets it evaluate.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from formation_bench.fields import Validated, kernel_settings_class, pack_settings, setting
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.ask_tell import (
    AskTellOptimizer,
    DrawPlan,
    Kernels,
    iterate,
    register_kernels,
)
from formation_bench.optimizers.base import Bounds, budget_setting
from formation_bench.optimizers.registry import register

PER_SOLVE = ("lower", "width")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


@dataclass(frozen=True)
class RandomSearchConfig(Validated):
    """The settings of :class:`RandomSearch`, declared once."""

    population_size: int = setting(
        30, low=1, kernel=True, doc="Points drawn and evaluated per batch"
    )
    max_iterations: int = budget_setting(
        40,
        doc="Batches after the first when the caller gives no budget; default budget N (T + 1)",
    )  # fmt: skip


RandomSearchSettings = kernel_settings_class(
    "RandomSearchSettings",
    __name__,
    RandomSearchConfig,
    PER_SOLVE,
    """What the kernel reads: the batch size, then the box's lower corner and widths.""",
)


class RandomSearchState(NamedTuple):
    """Nothing: random search learns nothing from the costs."""


@njit(cache=True, inline="always")
def random_search_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """A batch of ``m = min(population_size, remaining)`` points ``lower + u width`` on the
    iteration's ``m D`` uniforms, row by row (as :meth:`Bounds.sample
    <formation_bench.optimizers.base.Bounds.sample>` uses its draw)."""
    s = RandomSearchSettings(*params)
    d = s.lower.shape[0]
    m = min(s.population_size, remaining)
    points = np.empty((m, d))
    for i in range(m):
        for c in range(d):
            points[i, c] = s.lower[c] + uniforms[i * d + c] * s.width[c]
    return state, points, True


@njit(cache=True, inline="always")
def random_search_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """Nothing to keep: the tally holds the best point."""
    return state


register_kernels(RandomSearchState, random_search_ask, random_search_tell)


@njit(cache=True)
def random_search_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the random search kernels."""
    return iterate(state, params, block, nit, rows)


@dataclass(frozen=True)
class RandomSearch(RandomSearchConfig, AskTellOptimizer):
    """Uniform samples in the box, batch-evaluated; see the module docstring."""

    compile_cpu_s = 3.0
    kernels = Kernels(random_search_ask, random_search_tell, random_search_iterate)

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return pack_settings(
            RandomSearchSettings, self, lower=np.array(bounds.lower), width=bounds.width
        )

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> RandomSearchState:
        return RandomSearchState()

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        # one draw of the points evaluated: Bounds.sample's, the Python loop's before
        return DrawPlan(n * d, per_batch=lambda evaluated: evaluated * d, batch=n)


register(
    "random-search",
    RandomSearch(),
    "Uniform random search, 30 points per batch (the floor every optimiser must beat)",
)
