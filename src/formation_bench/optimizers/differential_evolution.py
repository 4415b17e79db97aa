"""Differential evolution: DE/rand/1/bin and DE/current-to-best/1/bin, configurations of one class.

After Storn & Price, "Differential Evolution - A Simple and Efficient Heuristic for Global
Optimization over Continuous Spaces", J. Global Optimization 11, 1997. For each member ``x_i``:
a mutant ``v = x_r1 + F (x_r2 - x_r3)`` (rand/1, ``de``) or ``x_i + F (x_best - x_i) +
F (x_r1 - x_r2)`` (current-to-best/1, one F for both terms as in scipy), partners distinct and
not ``i``; binomial crossover (coordinate ``j`` from ``v`` when a uniform is below CR or ``j =
j_rand``, so every trial differs from its target); coordinates outside the box re-drawn
uniformly (scipy's rule, the default; or clipped or reflected); the trial replaces ``x_i`` when
its cost is *no higher* (ties let the population cross plateaus). Deferred updating (the
default) makes the N trials from the population at the start of the generation, evaluates them
in one batch, then selects; immediate updating (scipy's default, ``de-immediate``) makes trial
``i`` from the population trials ``0 .. i-1`` left, evaluates and selects it at once, and moves
``x_best`` as soon as a trial beats it. F = 0.5, CR = 0.9 are Storn & Price's suggested start;
N = 30 and 40 generations give the other population optimisers' ~1230 evaluations. The warm
start is member 0 (:class:`~formation_bench.optimizers.population.WarmStartInit` for a share
drawn around it, ``de-immediate-warm``).

A generation is written once, as the kernels :func:`de_ask` and :func:`de_tell`: one round when
deferred, one round per trial when immediate. Its uniforms, drawn ahead, hold per member ``i``
the block ``u[i (4 + D) : (i + 1) (4 + D)]``: three picking the partners (:func:`partners_of`),
one ``j_rand``, ``D`` crossover draws; with ``resample``, ``N D`` re-draws follow (member ``i``'s
at ``N (4 + D) + i D``). Both updating modes read this layout, so they draw the same numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from formation_bench.fields import (
    Search,
    Validated,
    kernel_settings_class,
    pack_settings,
    setting,
)
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.ask_tell import (
    AskTellOptimizer,
    DrawPlan,
    Kernels,
    iterate,
    register_kernels,
)
from formation_bench.optimizers.base import Bounds, budget_setting
from formation_bench.optimizers.bound_handling import BoundHandling, apply_bounds_inplace
from formation_bench.optimizers.population import POPULATION_SEARCH, WarmStartInit
from formation_bench.optimizers.registry import register

PARTNER_UNIFORMS = 3
"""Uniforms per member that pick its partners (rand/1 needs three, current-to-best/1 two)."""


class DEStrategy(IntEnum):
    """How the mutant of member ``i`` is built (``r1, r2, r3`` distinct and not ``i``)."""

    RAND_1_BIN = 0
    """``v = x_r1 + F (x_r2 - x_r3)``, binomial crossover (Storn & Price's DE1)."""
    CURRENT_TO_BEST_1_BIN = 1
    """``v = x_i + F (x_best - x_i) + F (x_r1 - x_r2)``, binomial crossover."""


class DEUpdating(IntEnum):
    """When the trials of a generation replace their targets."""

    DEFERRED = 0
    """A generation's trials evaluated in one batch, then selected (Storn & Price)."""
    IMMEDIATE = 1
    """Each trial evaluated and selected before the next is made (scipy's default)."""


PER_SOLVE = ("lower", "upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


@dataclass(frozen=True)
class DEConfig(Validated):
    """The settings of differential evolution, declared once: the fields marked ``kernel=True``
    make :class:`DESettings`, which the kernels rebuild and read by name."""

    population_size: int = setting(
        30, low=4, search=POPULATION_SEARCH,
        doc="N, members (rand/1 needs three partners besides the member)",
    )  # fmt: skip
    max_iterations: int = budget_setting(
        40,
        doc="Generations when the caller gives no budget; the default budget is N (T + 1)",
    )  # fmt: skip
    strategy: DEStrategy = setting(
        DEStrategy.RAND_1_BIN, kernel=True,
        doc="Mutant: x_r1 + F (x_r2 - x_r3), or x_i + F (x_best - x_i + x_r1 - x_r2)",
    )  # fmt: skip
    differential_weight: float = setting(
        0.5, low=0.0, high=2.0, low_open=True, kernel=True, search=Search(0.1, 1.5),
        doc="F, the scale of the difference vectors",
    )  # fmt: skip
    crossover_rate: float = setting(
        0.9, low=0.0, high=1.0, kernel=True, search=Search(0.0, 1.0),
        doc="CR, probability that a coordinate (besides j_rand) comes from the mutant",
    )  # fmt: skip
    bound_handling: BoundHandling = setting(
        BoundHandling.RESAMPLE, kernel=True, search=Search(),
        doc="How trial coordinates outside the box are brought back: clip, reflect or resample",
    )  # fmt: skip
    updating: DEUpdating = setting(
        DEUpdating.DEFERRED, kernel=True,
        doc="deferred: a generation's trials are evaluated in one batch, then selected; "
        "immediate: each trial is selected before the next is made (scipy's default)",
    )  # fmt: skip

    def uniforms_per_step(self, n: int, d: int) -> int:
        """Uniforms one generation of ``n`` members in ``d`` dimensions reads (module docstring)."""
        resample = self.bound_handling is BoundHandling.RESAMPLE
        return n * (PARTNER_UNIFORMS + 1 + d) + (n * d if resample else 0)


DESettings = kernel_settings_class(
    "DESettings", __name__, DEConfig, PER_SOLVE,
    """What the kernels read, fixed during a solve: the kernel fields of :class:`DEConfig` (enums
    as integers), then the bounds (private writable copies: numba compiles read-only arrays
    separately).""",
)  # fmt: skip


class DEState(NamedTuple):
    """The population between rounds. Kernels return a new state; they modify no state but
    those of an immediate generation's rounds, whose arrays the generation copied for itself."""

    x: np.ndarray
    """Members, shape (N, D)."""
    f: np.ndarray
    """Their costs (+inf for members not evaluated for lack of budget)."""
    generation: int
    """Immediate updating: the generation whose trials are being made (0 before the first)."""
    member: int
    """Immediate updating: the member whose trial was asked last."""
    best: int
    """Immediate updating: the best member as the generation's trials so far left it."""


# inline, and in scalars: called once per trial, so that a trial allocates nothing but itself
@njit(cache=True, inline="always")
def partners_of(i: int, n: int, u: np.ndarray, used: int) -> tuple[int, int, int]:
    """``used`` (at most 3) indices in ``[0, n)``, distinct and none equal to ``i``; the
    unused ones are -1.

    The k-th is ``floor(u[k] (n - 1 - k))`` counted among the indices not yet taken (``i`` and
    the earlier partners): each ordered choice is equally likely, and the values depend only on
    ``u``. Needs ``n > used``.
    """
    # the taken indices in increasing order, n where none is taken yet (no r reaches n)
    low, mid, high = i, n, n
    first = second = third = -1
    for k in range(used):
        count = k + 1
        r = min(int(u[k] * (n - count)), n - count - 1)
        # the r-th free index: skip the taken ones, in increasing order
        if r >= low:
            r += 1
        if r >= mid:
            r += 1
        if r >= high:
            r += 1
        if r < low:
            low, mid, high = r, low, mid
        elif r < mid:
            mid, high = r, mid
        else:
            high = r
        if k == 0:
            first = r
        elif k == 1:
            second = r
        else:
            third = r
    return first, second, third


# inline: called once per member, so that a generation's trials stay one loop
@njit(cache=True, inline="always")
def mutant_into(out, x, i, best, s, uniforms):  # type: ignore[no-untyped-def]
    """Member ``i``'s trial before bound handling into the row ``out``: mutation (around the
    member ``best`` for current-to-best/1), binomial crossover; ``s`` the :class:`DESettings`,
    ``uniforms`` the generation's."""
    n, d = x.shape
    block = PARTNER_UNIFORMS + 1 + d
    u = uniforms[i * block : (i + 1) * block]
    used = PARTNER_UNIFORMS if s.strategy == DEStrategy.RAND_1_BIN else PARTNER_UNIFORMS - 1
    a, b, c = partners_of(i, n, u, used)
    j_rand = min(int(u[PARTNER_UNIFORMS] * d), d - 1)
    for j in range(d):
        if j != j_rand and not u[PARTNER_UNIFORMS + 1 + j] < s.crossover_rate:
            out[j] = x[i, j]
        elif s.strategy == DEStrategy.RAND_1_BIN:
            out[j] = x[a, j] + s.differential_weight * (x[b, j] - x[c, j])
        else:
            out[j] = x[i, j] + s.differential_weight * (x[best, j] - x[i, j] + x[a, j] - x[b, j])


@njit(cache=True, inline="always")
def redraws_of(s, uniforms, n, d, member, rows):  # type: ignore[no-untyped-def]
    """The re-draws of members ``member .. member + rows - 1``, shape ``(rows, D)``: the
    values ``resample`` puts in place of their coordinates outside the box (else empty)."""
    if s.bound_handling != BoundHandling.RESAMPLE:
        return np.empty((0, d))
    first = n * (PARTNER_UNIFORMS + 1 + d) + member * d
    return np.ascontiguousarray(uniforms[first : first + rows * d]).reshape(rows, d)


@njit(cache=True, inline="always")
def de_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """The generation's N trials (deferred), or the next member's trial alone (immediate: the
    generation's last round is its last member's, or the last evaluation's). Only mutant
    coordinates can leave the box."""
    s = DESettings(*params)
    n, d = state.x.shape
    # one return: each exit would count references to the state's arrays again; and one call
    # of each inlined helper, which numba types again at every call site
    deferred = s.updating == DEUpdating.DEFERRED
    if deferred:
        x, f, member, best, rows = state.x, state.f, 0, np.argmin(state.f), n
    elif iteration != state.generation:
        # the generation's own copies, into which its rounds' selections are written
        x, f = state.x.copy(), state.f.copy()
        member, best, rows = 0, np.argmin(f), 1
    else:
        x, f, member, best, rows = state.x, state.f, state.member + 1, state.best, 1
    trials = np.empty((rows, d))
    for k in range(rows):
        mutant_into(trials[k], x, member + k, best, s, uniforms)
    redraws = redraws_of(s, uniforms, n, d, member, rows)
    apply_bounds_inplace(trials, s.lower, s.upper, s.bound_handling, redraws)
    last = deferred or member == n - 1 or remaining <= 1
    if not deferred:
        state = DEState(x, f, iteration, member, best)
    return state, trials, last


@njit(cache=True, inline="always")
def de_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """Storn & Price's selection of the evaluated trials: a trial replaces its target when its
    cost is no higher (NaN never: the loops map it to +inf). With immediate updating, a trial
    strictly below the best member's cost becomes the best (scipy too keeps its best on a tie)."""
    s = DESettings(*params)
    x, f, best, first = state.x, state.f, state.best, state.member
    if s.updating == DEUpdating.DEFERRED:
        x, f, first = x.copy(), f.copy(), 0
    # immediate: x and f are the generation's copies (de_ask), written trial by trial
    for k in range(costs.shape[0]):
        i = first + k
        if costs[k] <= f[i]:
            # element loops, not a row assignment: see population.greedy_select
            for c in range(x.shape[1]):
                x[i, c] = candidates[k, c]
            f[i] = costs[k]
            if f[i] < f[best]:
                best = i
    return DEState(x, f, state.generation, state.member, best)


register_kernels(DEState, de_ask, de_tell)


@njit(cache=True)
def de_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the DE kernels."""
    return iterate(state, params, block, nit, rows)


# WarmStartInit before DEConfig: a dataclass lists the fields of its bases from the last in
# the MRO, so the DE settings come first and the initialisation's after them
@dataclass(frozen=True)
class DifferentialEvolution(WarmStartInit, DEConfig, AskTellOptimizer):
    """Storn & Price's DE; the settings are those of :class:`DEConfig` and the initial
    population's of :class:`~formation_bench.optimizers.population.WarmStartInit`."""

    compile_cpu_s = 9.0
    kernels = Kernels(de_ask, de_tell, de_iterate)

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return pack_settings(
            DESettings, self, lower=np.array(bounds.lower), upper=np.array(bounds.upper)
        )

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> DEState:
        return DEState(points, costs, 0, 0, 0)

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        return DrawPlan(self.uniforms_per_step(n, d))


register(
    "de",
    DifferentialEvolution(),
    "Differential evolution DE/rand/1/bin (Storn & Price 1997), N = 30, F = 0.5, CR = 0.9",
)
register(
    "de-current-to-best",
    DifferentialEvolution(strategy=DEStrategy.CURRENT_TO_BEST_1_BIN),
    "Differential evolution DE/current-to-best/1/bin, N = 30, F = 0.5, CR = 0.9",
)
register(
    "de-immediate",
    DifferentialEvolution(updating=DEUpdating.IMMEDIATE),
    "Differential evolution DE/rand/1/bin, N = 30, F = 0.5, CR = 0.9, immediate updating "
    "(each trial selected before the next is made: scipy's default)",
)
WARM_START_SHARE = 0.9
"""``warm_start_share`` of ``de-immediate-warm``: chosen with the spread on the instance
library's validation split (docs/explanation/optimizers.md, "Initial population around the
warm start")."""
WARM_START_SPREAD = 0.02
"""``warm_start_spread`` of ``de-immediate-warm``, chosen with the share."""

register(
    "de-immediate-warm",
    DifferentialEvolution(
        updating=DEUpdating.IMMEDIATE,
        warm_start_share=WARM_START_SHARE,
        warm_start_spread=WARM_START_SPREAD,
    ),
    f"de-immediate with {WARM_START_SHARE:.0%} of the initial population drawn around the warm "
    f"start (std {WARM_START_SPREAD:g} x range), the rest uniform",
)
