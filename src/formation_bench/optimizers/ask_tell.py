"""Population optimisers written once, as compiled ask/tell kernels over a named state.

An optimiser of this kind (:class:`AskTellOptimizer`) supplies

* its **state**, a :class:`typing.NamedTuple` of arrays and numbers (numba compiles a
  NamedTuple into a struct, and a kernel returns the next one; it may write into arrays that
  the block owns, as CMA-ES does after copying its run once per block);
* its **params**, the tuple of settings its kernels read, built from its declared fields
  and a solve's box (:meth:`AskTellOptimizer.params`) and kept for the next solves over the
  same box (:meth:`AskTellOptimizer.solve_params`): the kernels never write into them;
* two compiled **kernels** (``@njit(cache=True)``):

  .. code-block:: python

      ask(state, params, uniforms, normals, iteration, remaining) -> (state, candidates, last)
      tell(state, params, candidates, costs, iteration) -> state

  ``uniforms`` and ``normals`` are the iteration's random numbers (one row of the block drawn
  ahead, see :class:`DrawPlan`); ``remaining`` is the number of evaluations left;
  ``candidates`` is a C-contiguous ``(m, d)`` array (``m`` may be 0). The loop evaluates its
  first ``min(m, remaining)`` rows and gives ``tell`` their costs (``+inf`` for a non-finite
  cost), so ``costs`` may be shorter than ``candidates``. An iteration is one or more
  ask/tell rounds: it ends after the round whose ``ask`` says ``last`` (a method whose
  iteration evaluates in two stages, or one point at a time, asks again);
* the registration of its kernels for its state's class (:func:`register_kernels`) and a
  cached three-line wrapper of :func:`iterate` in its own module.

Every solve drives those same kernels in compiled code (:func:`iterate`): the objective is
called through its compiled handle when it has one (the harness's), and otherwise through a C
callback into the Python objective (:mod:`~formation_bench.optimizers.tallies`). Only a
configuration whose ``ask`` is Python itself runs the same rounds from Python. The random
numbers are drawn by one outer loop (:func:`run_blocks`), so every path gives the same result
to the bit: there is one implementation of each update rule, and no second one to keep in
step.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass
from time import perf_counter
from typing import Any, NamedTuple

import numpy as np
from numba import types
from numba.extending import overload

from formation_bench.kernel_cache import njit
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    OptimizeResult,
    PopulationOptimizer,
    check_rng,
    check_x0,
)
from formation_bench.optimizers.clock import NEVER, Deadline, read_clock, solve_deadline
from formation_bench.optimizers.compiled import NFEV, UNLIMITED, evaluate, remaining
from formation_bench.optimizers.population import (
    ROWS_AHEAD,
    UNIFORM_START,
    WarmStartInit,
    evaluate_prefix,
    iteration_randoms,
    no_randoms,
    starting_points,
)
from formation_bench.optimizers.tallies import Draws, History, Tally, open_tally, plain


@dataclass(frozen=True)
class DrawPlan:
    """The random numbers one iteration reads.

    ``uniforms`` uniforms and a block of standard normals of shape ``normal_shape``, drawn
    ahead for up to 64 iterations in two Generator calls
    (:func:`~formation_bench.optimizers.population.iteration_randoms`). With ``per_batch``,
    the iteration draws no normals and its uniforms are ``per_batch(m)`` for the ``m``
    candidates the budget lets it evaluate (``m = min(batch, left)``): the numbers of one
    ``rng.random`` call per iteration, drawn together (:func:`per_batch_draws`).
    """

    uniforms: int
    """Uniforms per iteration (per full batch with ``per_batch``)."""
    normal_shape: tuple[int, ...] = (0,)
    """Shape of one iteration's block of standard normals."""
    per_batch: Callable[[int], int] | None = None
    """``m -> uniforms`` of an iteration evaluating ``m`` rows; None: draws ahead."""
    batch: int = 0
    """Rows one iteration evaluates when the budget allows (with ``per_batch``)."""


def ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """The ``ask`` kernel registered for ``state``'s class (:func:`register_kernels`)."""
    raise TypeError("ask() is resolved in compiled code by the class of its state")


def tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """The ``tell`` kernel registered for ``state``'s class (:func:`register_kernels`)."""
    raise TypeError("tell() is resolved in compiled code by the class of its state")


def register_kernels(state_class: type, ask_kernel: Any, tell_kernel: Any) -> None:
    """Make :func:`ask` and :func:`tell` in compiled code call ``ask_kernel`` and
    ``tell_kernel`` for a state of ``state_class``.

    The kernels are chosen while compiling, by the state's type: a compiled function given
    another one as an argument would be a dynamic global, which numba cannot cache. The
    overloads are not cached themselves (their cache would be checked against this file
    only, and keep a kernel's old code after an edit of its module): they are compiled into,
    and cached with, each optimiser's ``*_iterate`` wrapper. They are inlined, so that the
    state's arrays are not passed through a call and its reference counts every round.
    """

    def matches(state: Any) -> bool:
        return isinstance(state, types.BaseNamedTuple) and state.instance_class is state_class

    @overload(ask, inline="always")
    def _ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
        if matches(state):
            return lambda state, params, uniforms, normals, iteration, remaining: ask_kernel(
                state, params, uniforms, normals, iteration, remaining
            )
        return None

    @overload(tell, inline="always")
    def _tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
        if matches(state):
            return lambda state, params, candidates, costs, iteration: tell_kernel(
                state, params, candidates, costs, iteration
            )
        return None


# Not cached itself: each optimiser caches it inside a three-line wrapper in its own module
# (see the module docstring), so that editing the optimiser's kernels invalidates the cache
# (numba checks only the source file of the cached function).
@njit
def iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """Iterations ``nit + 1``, ... ``nit + rows`` of a compiled solve, while evaluations are
    left and the block's deadline has not passed, with the kernels registered for ``state``'s
    class. Returns ``(state, iterations done)``, the state as a plain tuple (:func:`plain`;
    :func:`dressed` restores it)."""
    done = 0
    for row in range(rows):
        if remaining(block.counts) <= 0:
            break
        # the clock is read here, not between blocks, so that a deadline costs a method of
        # short iterations no more than one of long ones (a read is about 22 ns)
        if (
            block.deadline_ns != NEVER
            and read_clock(block.clock, block.clock_id) >= block.deadline_ns
        ):
            break
        nit += 1
        uniforms = block.uniforms[row]
        normals = block.normals[row]
        last = False
        while not last:
            state, candidates, last = ask(
                state, params, uniforms, normals, nit, remaining(block.counts)
            )
            allowed = min(candidates.shape[0], remaining(block.counts))
            costs = evaluate(block.address, block.data, candidates, allowed, block.counts,
                             block.best)  # fmt: skip
            state = tell(state, params, candidates, costs, nit)
        block.history_nfev[done] = block.counts[NFEV]
        block.history_fun[done] = block.best[0]
        done += 1
    return plain(state), done


class Kernels(NamedTuple):
    """An optimiser's compiled kernels (see the module docstring)."""

    ask: Any
    """``(state, params, uniforms, normals, iteration, remaining) -> (state, candidates,
    last)``."""
    tell: Any
    """``(state, params, candidates, costs, iteration) -> state``."""
    iterate: Any
    """``(state, params, block, nit, rows) -> (state, done)``: the optimiser's cached wrapper
    of :func:`iterate`."""


SOLVE_CONSTANTS_KEPT = 64
"""Most entries an optimiser keeps of what its solves would otherwise rebuild from its settings
and their box alone (:meth:`AskTellOptimizer.solve_constant`); a full cache is emptied. A run's
solves share a box per UAV."""

_SOLVE_CONSTANTS = "_solve_constants"
"""Where an optimiser keeps them: in its ``__dict__``, outside its dataclass fields (so outside
its equality, ``repr`` and configuration hash), and not pickled."""


class AskTellOptimizer(PopulationOptimizer[Any]):
    """A population optimiser given by its kernels; the base class runs both solve loops.

    Subclasses (frozen dataclasses with their declared settings) define :attr:`kernels`,
    :meth:`params`, :meth:`start` and :meth:`draw_plan`; the defaults of
    :attr:`default_budget` and :meth:`evaluations_per_step` read the settings
    ``max_iterations`` and ``population_size``. :meth:`result_info`, :meth:`initialisation`,
    :meth:`initial_points` and :meth:`block_source` may be redefined.
    """

    kernels: Kernels
    """The compiled kernels (a class attribute)."""

    @abc.abstractmethod
    def params(self, bounds: Bounds, t_max: int) -> tuple:
        """The settings the kernels read, for a solve over ``bounds`` planning ``t_max``."""

    @abc.abstractmethod
    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> Any:
        """The state after the initial population ``points`` (their ``costs``, ``+inf`` where
        the budget left a row unevaluated); may draw further numbers from ``rng``."""

    @abc.abstractmethod
    def draw_plan(self, n: int, d: int) -> DrawPlan:
        """The random numbers of one iteration, for ``n`` members in ``d`` dimensions."""

    @property
    def default_budget(self) -> Budget:
        """``max_iterations`` iterations, the declared setting of a population method."""
        return Budget(max_iterations=self.max_iterations)  # type: ignore[attr-defined]

    def evaluations_per_step(self) -> int:
        """``population_size``: the batch one iteration evaluates."""
        return int(self.population_size)  # type: ignore[attr-defined]

    def initial_points(
        self, bounds: Bounds, rng: np.random.Generator, x0: np.ndarray | None
    ) -> np.ndarray:
        """The initial population, not yet evaluated (:func:`~formation_bench.optimizers.
        population.starting_points` of :meth:`population` members)."""
        return starting_points(bounds, rng, self.population(), x0, self.initialisation())

    def block_source(self, bounds: Bounds, shape: tuple[int, ...], t_max: int) -> BlockSource:
        """Where the solve's blocks of random numbers come from: :meth:`draw_plan`'s, for an
        initial population of ``shape``."""
        plan = self.solve_constant(("draw_plan", shape), lambda: self.draw_plan(*shape))
        return PlannedDraws(plan, t_max)

    def solve_params(self, bounds: Bounds, t_max: int) -> tuple:
        """:meth:`params`, built once for a box and ``t_max`` and shared by the solves over
        them (rebuilding them took a few microseconds of every solve). The kernels and
        :meth:`start` only read them."""
        key = ("params", bounds.cache_key(), t_max)
        return self.solve_constant(key, lambda: self.params(bounds, t_max))

    def solve_constant(self, key: tuple, build: Callable[[], Any]) -> Any:
        """``build()``, kept under ``key`` for the next solves: for what depends on the
        (frozen) settings and on ``key`` alone, and is never modified."""
        cache = self.__dict__.get(_SOLVE_CONSTANTS)
        if cache is None:
            cache = self.__dict__[_SOLVE_CONSTANTS] = {}
        value = cache.get(key)
        if value is None:
            if len(cache) >= SOLVE_CONSTANTS_KEPT:
                cache.clear()
            value = cache[key] = build()
        return value

    def __getstate__(self) -> dict[str, Any]:
        # a copy or a sweep worker's optimiser rebuilds its solve constants on first use
        state = dict(self.__dict__)
        state.pop(_SOLVE_CONSTANTS, None)
        return state

    def initialisation(self) -> WarmStartInit:
        """How the initial population is drawn (uniform with the warm start in row 0)."""
        return self if isinstance(self, WarmStartInit) else UNIFORM_START

    def population(self) -> int:
        """Size of the initial population."""
        return int(self.population_size)  # type: ignore[attr-defined]

    def result_info(self, state: Any) -> dict[str, Any]:
        return {}

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> Any:
        """The state after the initial population, evaluated through ``counter`` (as a solve
        starts; for inspecting a start)."""
        points = self.initial_points(bounds, rng, x0)
        costs = evaluate_prefix(counter, points)
        return self.start(points, costs, rng, self.solve_params(bounds, max_iterations))

    def step(
        self,
        state: Any,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> Any:
        raise TypeError(f"{type(self).__name__} runs its iterations in blocks, not by step()")

    def compiled_kernels(self) -> tuple[Any, ...]:
        """The optimiser's cached wrapper of :func:`iterate` (its ask and tell compile with
        it)."""
        kernels = self.kernels
        if kernels.iterate is not None:
            return (kernels.iterate,)
        return tuple(k for k in (kernels.ask, kernels.tell) if hasattr(k, "py_func"))

    def has_compiled_loop(self) -> bool:
        """Whether a compiled objective's iterations run in compiled code (False when a
        configuration's ``ask`` or ``tell`` is Python: the objective is then called from
        Python too)."""
        return True

    def minimize(
        self,
        objective: Any,
        bounds: Bounds,
        rng: np.random.Generator,
        budget: Budget | None = None,
        x0: np.ndarray | None = None,
    ) -> OptimizeResult:
        budget = self.solve_budget(budget)
        started = perf_counter()
        deadline = solve_deadline(budget.deadline_s)
        rng = check_rng(rng)
        x0 = check_x0(x0, bounds)
        t_max = self.planned_iterations(budget)
        params = self.solve_params(bounds, t_max)
        tally = open_tally(objective, bounds.dim, budget, started, self.has_compiled_loop())
        points = self.initial_points(bounds, rng, x0)
        costs = tally.evaluate_prefix(points)
        state = self.start(points, costs, rng, params)
        source = self.block_source(bounds, points.shape, t_max)
        state, nit, message, history = run_blocks(
            self.kernels, state, params, tally, rng, budget, source, deadline
        )
        return tally.result(nit, message, history, self.result_info(state))


class BlockSource(abc.ABC):
    """Where the random numbers of a solve's next block of iterations come from, and what
    happens between blocks (a restart, say)."""

    @abc.abstractmethod
    def next_block(
        self, state: Any, rng: np.random.Generator, iteration: int, rows: int, left: int
    ) -> tuple[Any, np.ndarray, np.ndarray]:
        """``(state, uniforms, normals)`` of at most ``rows`` iterations from ``iteration`` on,
        one row each, with ``left`` evaluations left."""

    def iterations_done(self, state: Any, nit: int, done: int) -> int:
        """Of the ``done`` iterations a block ran after iteration ``nit``, those that count."""
        return done


class PlannedDraws(BlockSource):
    """The numbers of a :class:`DrawPlan`: drawn ahead (up to 64 iterations, bounded by the
    ``t_max`` planned) or per batch (:func:`per_batch_draws`)."""

    def __init__(self, plan: DrawPlan, t_max: int) -> None:
        self.plan, self.t_max = plan, t_max
        self.randoms = no_randoms(plan.uniforms, plan.normal_shape)

    def next_block(
        self, state: Any, rng: np.random.Generator, iteration: int, rows: int, left: int
    ) -> tuple[Any, np.ndarray, np.ndarray]:
        if self.plan.per_batch is not None:
            return state, *per_batch_draws(rng, self.plan, left, iteration, rows, self.t_max)
        self.randoms, _, _ = iteration_randoms(self.randoms, rng, iteration, self.t_max)
        offset = iteration - self.randoms.first_iteration
        rows = min(self.randoms.uniforms.shape[0] - offset, rows)
        uniforms = self.randoms.uniforms[offset : offset + rows]
        return state, uniforms, self.randoms.normals[offset : offset + rows]


def run_blocks(
    kernels: Kernels,
    state: Any,
    params: tuple,
    tally: Tally,
    rng: np.random.Generator,
    budget: Budget,
    source: BlockSource,
    deadline: Deadline | None = None,
) -> tuple[Any, int, str, History]:
    """The iterations of a solve, block by block: ``(state, nit, message, history)``.

    Each block's numbers come from ``source`` before it runs; the evaluation budget and the
    ``deadline`` (by default :func:`~formation_bench.optimizers.clock.solve_deadline` of
    ``budget``'s, from now) are checked before every block and, inside it, before every
    iteration: on the same clock, so a block that stopped at the deadline ends the solve.
    """
    if deadline is None:
        deadline = solve_deadline(budget.deadline_s)
    history = HistoryRows(*tally.progress())
    iteration_limit = budget.max_iterations if budget.max_iterations is not None else UNLIMITED
    message = "iteration budget reached"
    nit = 0
    while nit < iteration_limit:
        if tally.remaining() <= 0:
            message = "evaluation budget reached"
            break
        if deadline.passed():
            message = "deadline reached"
            break
        rows = iteration_limit - nit
        state, uniforms, normals = source.next_block(state, rng, nit + 1, rows, tally.remaining())
        draws = Draws(uniforms, normals, *history.next_rows(uniforms.shape[0]))
        state, done = tally.run(kernels, state, params, draws, nit, deadline)
        done = source.iterations_done(state, nit, done)
        history.keep(done)
        nit += done
    else:
        if tally.remaining() <= 0:
            message = "evaluation budget reached"
    return state, nit, message, history.arrays()


class HistoryRows:
    """A solve's history in two arrays, whose next rows each block fills in place (no lists
    to convert at the end)."""

    def __init__(self, nfev: int, best_f: float) -> None:
        # room for the start and a block of ROWS_AHEAD iterations: most solves' whole history
        self.nfev = np.empty(1 + ROWS_AHEAD, dtype=np.int64)
        self.fun = np.empty(1 + ROWS_AHEAD)
        self.nfev[0], self.fun[0] = nfev, best_f
        self.size = 1

    def next_rows(self, rows: int) -> tuple[np.ndarray, np.ndarray]:
        """Views of the ``rows`` rows after those kept, for a block to fill."""
        end = self.size + rows
        if end > self.nfev.shape[0]:
            capacity = max(end, 2 * self.nfev.shape[0])
            self.nfev = _grown(self.nfev, self.size, capacity)
            self.fun = _grown(self.fun, self.size, capacity)
        return self.nfev[self.size : end], self.fun[self.size : end]

    def keep(self, done: int) -> None:
        """Keep the first ``done`` rows the block filled."""
        self.size += done

    def arrays(self) -> History:
        """Evaluations and best cost after the start and after each iteration kept."""
        return self.nfev[: self.size], self.fun[: self.size]


def _grown(values: np.ndarray, kept: int, capacity: int) -> np.ndarray:
    grown = np.empty(capacity, dtype=values.dtype)
    grown[:kept] = values[:kept]
    return grown


def per_batch_draws(
    rng: np.random.Generator, plan: DrawPlan, left: int, iteration: int, most: int, t_max: int
) -> tuple[np.ndarray, np.ndarray]:
    """The uniforms of the next iterations of a per-batch plan, one row each.

    The iterations such a loop runs are known before they start (each takes ``min(batch,
    left)`` of the ``left`` evaluations), and so are the sizes of their draws. A Generator
    fills an array one number after the other from one stream, so one ``rng.random`` call of
    their total gives the numbers of the separate calls, in order, and leaves ``rng`` where
    they leave it. The block covers the iterations :func:`iteration_randoms` would cover, at
    most ``most`` and as many as the evaluations left allow; row ``j`` holds iteration
    ``j``'s numbers (the last row padded with zeros, never read, when its batch is cut
    short).
    """
    assert plan.per_batch is not None
    batch = plan.batch
    rows = min(max(t_max - iteration + 1, 1), ROWS_AHEAD, most, -(-left // batch))
    full = plan.per_batch(batch)
    # every iteration but the last takes a full batch; the last may take what is left
    last = plan.per_batch(min(batch, left - (rows - 1) * batch))
    flat = rng.random(full * (rows - 1) + last)
    if last == full:
        return flat.reshape(rows, full), np.zeros((rows, 0))
    uniforms = np.zeros((rows, full))
    uniforms[: rows - 1] = flat[: full * (rows - 1)].reshape(rows - 1, full)
    uniforms[rows - 1, :last] = flat[full * (rows - 1) :]
    return uniforms, np.zeros((rows, 0))
