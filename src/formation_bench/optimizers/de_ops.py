"""Differential evolution: settings declared once, and the generation as pure, compiled functions.

Storn, R. & Price, K. (1997). *Differential Evolution - A Simple and
Efficient Heuristic for Global Optimization over Continuous Spaces*. Journal
of Global Optimization 11, 341-359.

Like the other ``*_ops`` modules, every random number comes in as an array
(one row of :func:`uniforms_per_generation` values per generation), inputs are
never modified (but by the ``*_inplace`` functions), and one call of
:func:`de_generation` does a whole deferred generation's own work besides the
objective: the selection of the last generation's trials, then the next
trials. At N = 30 a Python-level call into a kernel costs about as much as its
arithmetic, so the two are fused. An immediate generation
(:attr:`DEUpdating.IMMEDIATE`) is a sequence of :func:`immediate_trial` and
:func:`select_trial_inplace`, one evaluation between them.

Layout of a generation's uniforms: for member ``i`` (``i = 0 .. N-1``), the
block ``u[i * (4 + D) : (i + 1) * (4 + D)]`` holds three values that pick the
distinct partner indices (:func:`distinct_partners`), one that picks the
coordinate ``j_rand`` always taken from the mutant, and ``D`` crossover draws;
with RESAMPLE bound handling ``N * D`` values for re-drawn coordinates follow
(member ``i``'s ``D`` values at ``N * (4 + D) + i * D``). Both updating modes
read the same layout, so a solve draws the same numbers in either.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

import numpy as np
from numba import njit

from formation_bench.fields import Validated, kernel_settings_class, pack_settings, setting
from formation_bench.optimizers.base import Bounds
from formation_bench.optimizers.bound_handling import BoundHandling, apply_bounds_inplace
from formation_bench.optimizers.compiled import NFEV, evaluate, remaining

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
    """All N trials are made from the population at the start of the generation, evaluated in
    one batch, then selected (Storn & Price; scipy's ``updating='deferred'``)."""
    IMMEDIATE = 1
    """Trial ``i`` is made from the population as trials ``0 .. i-1`` left it, evaluated alone
    and selected at once, and the best member follows at once (scipy's default)."""


PER_SOLVE = ("lower", "upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


@dataclass(frozen=True)
class DEConfig(Validated):
    """The settings of differential evolution, declared once.

    The fields marked ``kernel=True`` make :class:`DESettings`, which
    :func:`de_generation` rebuilds and reads by name.
    """

    population_size: int = setting(
        30, low=4, doc="N, members (rand/1 needs three partners besides the member)"
    )
    max_iterations: int = setting(
        40, low=0,
        doc="Generations when the caller gives no budget; the default budget is N (T + 1)",
    )  # fmt: skip
    strategy: DEStrategy = setting(
        DEStrategy.RAND_1_BIN, kernel=True,
        doc="Mutant: x_r1 + F (x_r2 - x_r3), or x_i + F (x_best - x_i + x_r1 - x_r2)",
    )  # fmt: skip
    differential_weight: float = setting(
        0.5, low=0.0, high=2.0, low_open=True, kernel=True,
        doc="F, the scale of the difference vectors",
    )  # fmt: skip
    crossover_rate: float = setting(
        0.9, low=0.0, high=1.0, kernel=True,
        doc="CR, probability that a coordinate (besides j_rand) comes from the mutant",
    )  # fmt: skip
    bound_handling: BoundHandling = setting(
        BoundHandling.RESAMPLE, kernel=True,
        doc="How trial coordinates outside the box are brought back: clip, reflect or resample",
    )  # fmt: skip
    updating: DEUpdating = setting(
        DEUpdating.DEFERRED, kernel=True,
        doc="deferred: a generation's trials are evaluated in one batch, then selected; "
        "immediate: each trial is selected before the next is made (scipy's default)",
    )  # fmt: skip

    def de_settings(self, bounds: Bounds) -> tuple:
        """The packed :class:`DESettings` of a solve over ``bounds``."""
        return pack_settings(
            DESettings, self, lower=np.array(bounds.lower), upper=np.array(bounds.upper)
        )

    def uniforms_per_step(self, n: int, d: int) -> int:
        """Length of one generation's uniforms (layout: module docstring)."""
        return uniforms_per_generation(n, d, self.bound_handling is BoundHandling.RESAMPLE)


DESettings = kernel_settings_class(
    "DESettings",
    __name__,
    DEConfig,
    PER_SOLVE,
    """What :func:`de_generation` reads, fixed during a solve: the kernel fields of
    :class:`DEConfig` (enums as integers), then the bounds (private writable copies: numba
    compiles read-only arrays separately).""",
)


def uniforms_per_generation(n: int, d: int, resample: bool) -> int:
    """Uniforms one generation of ``n`` members in ``d`` dimensions reads."""
    return n * (PARTNER_UNIFORMS + 1 + d) + (n * d if resample else 0)


@njit(cache=True)
def distinct_partners(i: int, n: int, u: np.ndarray, out: np.ndarray) -> None:
    """Fill ``out`` with ``len(out)`` indices in ``[0, n)``, distinct and none equal to ``i``.

    The k-th index is ``floor(u[k] (n - 1 - k))`` counted among the indices not
    yet taken (``i`` and the earlier partners): each ordered choice is equally
    likely, and the values depend only on ``u``. Needs ``n > len(out)``.
    """
    partners_into(i, n, u, out, np.empty(out.shape[0] + 1, dtype=np.int64))


# inline: mutant_into calls it once per member with its own scratch, so that a generation
# allocates nothing per member
@njit(cache=True, inline="always")
def partners_into(i: int, n: int, u: np.ndarray, out: np.ndarray, taken: np.ndarray) -> None:
    """:func:`distinct_partners` with ``taken`` (at least ``len(out) + 1`` entries) as scratch."""
    taken[0] = i
    count = 1
    for k in range(out.shape[0]):
        r = min(int(u[k] * (n - count)), n - count - 1)
        # the r-th free index: walk the taken ones in increasing order, skipping each
        for a in range(count):
            for b in range(a + 1, count):
                if taken[b] < taken[a]:
                    taken[a], taken[b] = taken[b], taken[a]
        for a in range(count):
            if r >= taken[a]:
                r += 1
        out[k] = r
        taken[count] = r
        count += 1


# inline: make_trials and make_trial call it once per member with their own scratch
@njit(cache=True, inline="always")
def mutant_into(
    x: np.ndarray,
    i: int,
    best: int,
    strategy: int,
    differential_weight: float,
    crossover_rate: float,
    u: np.ndarray,
    partners: np.ndarray,
    taken: np.ndarray,
    out: np.ndarray,
) -> None:
    """Member ``i``'s trial before bound handling (mutation, binomial crossover) into ``out``.

    ``u`` is the member's block of uniforms; ``partners`` and ``taken`` are
    scratch of :data:`PARTNER_UNIFORMS` and one more entries.
    """
    d = x.shape[1]
    if strategy == DEStrategy.RAND_1_BIN:
        partners_into(i, x.shape[0], u[:3], partners, taken)
    else:
        partners_into(i, x.shape[0], u[:2], partners[:2], taken)
    j_rand = min(int(u[PARTNER_UNIFORMS] * d), d - 1)
    for j in range(d):
        if j != j_rand and not u[PARTNER_UNIFORMS + 1 + j] < crossover_rate:
            out[j] = x[i, j]
        elif strategy == DEStrategy.RAND_1_BIN:
            a, b, c = partners[0], partners[1], partners[2]
            out[j] = x[a, j] + differential_weight * (x[b, j] - x[c, j])
        else:
            a, b = partners[0], partners[1]
            out[j] = x[i, j] + differential_weight * (x[best, j] - x[i, j] + x[a, j] - x[b, j])


@njit(cache=True)
def make_trials(
    x: np.ndarray,
    best: int,
    strategy: int,
    differential_weight: float,
    crossover_rate: float,
    bound_handling: int,
    lower: np.ndarray,
    upper: np.ndarray,
    uniforms: np.ndarray,
) -> np.ndarray:
    """One trial per member of ``x``: mutation, binomial crossover, bound handling.

    ``best`` is the index of the best member (read by current-to-best/1).
    Only mutant coordinates can leave the box; they are brought back by
    ``bound_handling`` (a :class:`BoundHandling` value), RESAMPLE reading the
    ``N * D`` uniforms after the members' blocks. Returns new ``(N, D)`` trials.
    """
    n, d = x.shape
    block = PARTNER_UNIFORMS + 1 + d
    trials = np.empty((n, d))
    partners = np.empty(PARTNER_UNIFORMS, dtype=np.int64)
    taken = np.empty(PARTNER_UNIFORMS + 1, dtype=np.int64)
    for i in range(n):
        mutant_into(
            x, i, best, strategy, differential_weight, crossover_rate,
            uniforms[i * block : (i + 1) * block], partners, taken, trials[i],
        )  # fmt: skip
    if bound_handling == BoundHandling.RESAMPLE:
        redraws = np.ascontiguousarray(uniforms[n * block : n * block + n * d]).reshape(n, d)
        apply_bounds_inplace(trials, lower, upper, bound_handling, redraws)
    else:
        apply_bounds_inplace(trials, lower, upper, bound_handling, trials)
    return trials


@njit(cache=True)
def make_trial(
    x: np.ndarray,
    i: int,
    best: int,
    strategy: int,
    differential_weight: float,
    crossover_rate: float,
    bound_handling: int,
    lower: np.ndarray,
    upper: np.ndarray,
    uniforms: np.ndarray,
) -> np.ndarray:
    """Member ``i``'s trial alone, as row ``i`` of :func:`make_trials` would be: shape ``(1, D)``.

    It reads member ``i``'s uniforms of the generation's row (its block, and
    its ``D`` re-draws with RESAMPLE), so an immediate generation draws what
    a deferred one draws.
    """
    n, d = x.shape
    block = PARTNER_UNIFORMS + 1 + d
    trial = np.empty((1, d))
    partners = np.empty(PARTNER_UNIFORMS, dtype=np.int64)
    taken = np.empty(PARTNER_UNIFORMS + 1, dtype=np.int64)
    mutant_into(
        x, i, best, strategy, differential_weight, crossover_rate,
        uniforms[i * block : (i + 1) * block], partners, taken, trial[0],
    )  # fmt: skip
    if bound_handling == BoundHandling.RESAMPLE:
        first = n * block + i * d
        redraws = np.ascontiguousarray(uniforms[first : first + d]).reshape(1, d)
        apply_bounds_inplace(trial, lower, upper, bound_handling, redraws)
    else:
        apply_bounds_inplace(trial, lower, upper, bound_handling, trial)
    return trial


@njit(cache=True)
def select_trials(
    x: np.ndarray, f: np.ndarray, trials: np.ndarray, trial_costs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Storn & Price's selection: trial ``i`` replaces member ``i`` when its cost is no higher.

    ``trials`` may have fewer rows than ``x`` (a generation the budget cut
    short: only the evaluated trials compete). Ties go to the trial, so the
    population can move across plateaus; NaN costs never win (the evaluation
    counter maps them to ``+inf``). Returns new arrays.
    """
    new_x = x.copy()
    new_f = f.copy()
    # element loops, not a row assignment: see population.greedy_select
    for i in range(trials.shape[0]):
        if trial_costs[i] <= f[i]:
            for c in range(x.shape[1]):
                new_x[i, c] = trials[i, c]
            new_f[i] = trial_costs[i]
    return new_x, new_f


@njit(cache=True)
def best_member(f: np.ndarray) -> int:
    """Index of the lowest cost, the first of a tie."""
    best = 0
    for i in range(f.shape[0]):
        if f[i] < f[best]:
            best = i
    return best


@njit(cache=True)
def select_trial_inplace(
    x: np.ndarray, f: np.ndarray, i: int, best: int, trial: np.ndarray, cost: float
) -> int:
    """Immediate selection of member ``i``'s ``(1, D)`` trial, written into ``x`` and ``f``.

    The rule of :func:`select_trials` (ties to the trial). Returns the index of
    the best member afterwards: ``i`` when the trial is strictly below the best
    cost, else ``best`` unchanged (scipy's ``updating='immediate'`` keeps its
    best on a tie as well).
    """
    if cost <= f[i]:
        for c in range(x.shape[1]):
            x[i, c] = trial[0, c]
        f[i] = cost
        if cost < f[best]:
            return i
    return best


@njit(cache=True)
def immediate_trial(
    x: np.ndarray, i: int, best: int, uniforms: np.ndarray, packed: tuple
) -> np.ndarray:
    """Member ``i``'s trial of an immediate generation, from the population as it now is.

    ``packed`` is a plain tuple in :class:`DESettings` order; ``best`` is the
    best member now (read by current-to-best/1). Returns a new ``(1, D)`` array.
    """
    s = DESettings(*packed)
    return make_trial(
        x,
        i,
        best,
        strategy=s.strategy,
        differential_weight=s.differential_weight,
        crossover_rate=s.crossover_rate,
        bound_handling=s.bound_handling,
        lower=s.lower,
        upper=s.upper,
        uniforms=uniforms,
    )


@njit(cache=True)
def de_generation(
    x: np.ndarray,
    f: np.ndarray,
    trials: np.ndarray,
    trial_costs: np.ndarray,
    uniforms: np.ndarray,
    packed: tuple,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One deferred generation's own work: select the last trials (none at first), make the next.

    ``packed`` is a plain tuple in :class:`DESettings` order. Returns the
    population after the selection, its costs, and the new trials.
    """
    s = DESettings(*packed)
    x, f = select_trials(x, f, trials, trial_costs)
    new_trials = make_trials(
        x,
        best_member(f),
        strategy=s.strategy,
        differential_weight=s.differential_weight,
        crossover_rate=s.crossover_rate,
        bound_handling=s.bound_handling,
        lower=s.lower,
        upper=s.upper,
        uniforms=uniforms,
    )
    return x, f, new_trials


@njit(cache=True)
def immediate_generation(
    address: int,
    data: np.ndarray,
    counts: np.ndarray,
    best: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    uniforms: np.ndarray,
    packed: tuple,
) -> tuple[np.ndarray, np.ndarray]:
    """An immediate generation of a compiled solve: ``DifferentialEvolution.step``'s loop.

    Trial ``i`` is made (:func:`immediate_trial`), evaluated alone through
    ``address``/``data`` and selected (:func:`select_trial_inplace`) before trial
    ``i + 1`` is made; the trials the budget leaves no evaluation for are not
    made. Returns the new population and costs (the inputs are not modified).
    """
    x = x.copy()
    f = f.copy()
    current = best_member(f)
    for i in range(min(x.shape[0], remaining(counts))):
        trial = immediate_trial(x, i, current, uniforms, packed)
        cost = evaluate(address, data, trial, 1, counts, best)[0]
        current = select_trial_inplace(x, f, i, current, trial, cost)
    return x, f


@njit(cache=True)
def de_block(
    address: int,
    data: np.ndarray,
    counts: np.ndarray,
    best: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    trials: np.ndarray,
    trial_costs: np.ndarray,
    uniforms: np.ndarray,
    nit: int,
    first_iteration: int,
    iteration_limit: int,
    settings: tuple,
    history_nfev: np.ndarray,
    history_fun: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Generations ``nit + 1``, ... of a compiled solve, one per row of ``uniforms``.

    Each is :meth:`DifferentialEvolution.step` with the objective called through
    ``address``/``data`` (see :mod:`~formation_bench.optimizers.compiled`); the block stops
    early at the iteration limit or when no evaluation is left. Returns ``(x, f, trials,
    trial_costs, generations done)``, the trials those whose selection is pending (none with
    immediate updating); the history arrays get one entry per generation done.
    """
    s = DESettings(*settings)
    done = 0
    row = nit + 1 - first_iteration
    while nit < iteration_limit and row < uniforms.shape[0] and remaining(counts) > 0:
        nit += 1
        if s.updating == DEUpdating.IMMEDIATE:
            x, f = immediate_generation(address, data, counts, best, x, f, uniforms[row], settings)
        else:
            x, f, trials = de_generation(x, f, trials, trial_costs, uniforms[row], settings)
            # a generation the budget cuts short evaluates its first trials; only those compete
            allowed = min(trials.shape[0], remaining(counts))
            if allowed < trials.shape[0]:
                trials = trials[:allowed].copy()
            trial_costs = evaluate(address, data, trials, allowed, counts, best)
        history_nfev[done] = counts[NFEV]
        history_fun[done] = best[0]
        done += 1
        row += 1
    return x, f, trials, trial_costs, done
