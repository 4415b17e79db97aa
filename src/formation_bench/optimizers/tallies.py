"""A solve's evaluations, and how the iterations of a block reach the objective.

The outer loop of an ask/tell solve (:func:`~formation_bench.optimizers.ask_tell.run_blocks`)
reads the evaluations left and the best so far between blocks, and hands each block to its
:class:`Tally`:

* :class:`CompiledTally`: the objective has a compiled handle; the block runs in compiled
  code (the optimiser's ``*_iterate``), the objective called through its C address;
* :class:`ForwardedTally`: the objective is a Python callable; the block still runs in the
  same compiled code, and the objective is reached through a C callback that forwards a
  copy of each batch to it (the compiled side counts the evaluations and keeps the best). An
  exception in the objective (a KeyboardInterrupt too) ends the block at once and is raised
  again when it returns;
* :class:`CounterTally`: a configuration whose ``ask`` is Python (the modified BSO with
  scikit-learn's k-means): the same rounds, run from Python (:func:`iterate_python`).

:func:`open_tally` picks the tally of an objective.
"""

from __future__ import annotations

import abc
import ctypes
import math
from time import perf_counter
from typing import Any, NamedTuple

import numpy as np
from numba import types
from numba.extending import overload

from formation_bench.optimizers.base import (
    Budget,
    EvaluationCounter,
    OptimizeResult,
    counted_result,
)
from formation_bench.optimizers.clock import NEVER, Deadline
from formation_bench.optimizers.compiled import (
    LIMIT,
    NFEV,
    NO_LIMIT,
    UNLIMITED,
    CompiledObjective,
    compiled_of,
    evaluate_prefix,
    new_tally,
)
from formation_bench.optimizers.population import CompiledStart, compiled_result


def plain(value: Any) -> Any:
    """``value`` with every named tuple in it, nested ones too, made a plain tuple.

    A compiled function returns its state to Python through this. Numba boxes a named tuple
    by calling its class without checking the result; a plain tuple spares that call (its
    arrays are still boxed through a Python lookup of their type, which is why the command's
    Ctrl-C handler waits until a compiled call has returned: :mod:`formation_bench.pipeline.
    interrupts`), and :func:`dressed` gives the value its classes back in Python.
    """
    if isinstance(value, tuple):
        return tuple(plain(v) for v in value)
    return value


@overload(plain)
def _plain(value):  # type: ignore[no-untyped-def]
    if not isinstance(value, types.BaseNamedTuple):
        return lambda value: value
    fields = "".join(f"plain(value[{i}]), " for i in range(len(value.types)))
    namespace: dict[str, Any] = {"plain": plain}
    # a function of as many fields as the named tuple has, generated: numba needs constant indices
    exec(f"def impl(value):\n    return ({fields})\n", namespace)
    return namespace["impl"]


def dressed(plain_value: Any, like: Any) -> Any:
    """``plain_value`` (from :func:`plain`) with the named-tuple classes of ``like``, a value
    of the same structure (a state's fields keep their types, so the structure is that of
    ``like``'s class)."""
    dress = _DRESSERS.get(type(like))
    if dress is None:
        dress = _DRESSERS[type(like)] = _dresser(like)
    return dress(plain_value)


_DRESSERS: dict[type, Any] = {}
"""A generated :func:`dressed` per state class: walking a nested state field by field in
Python took about 10 µs per block call for CMA-ES, one generated expression about 2."""


def _dresser(like: Any) -> Any:
    classes: dict[str, type] = {}

    def expression(model: Any, path: str) -> str:
        if not (isinstance(model, tuple) and hasattr(type(model), "_fields")):
            return path
        name = f"C{len(classes)}"
        classes[name] = type(model)
        fields = "".join(f"{expression(m, f'{path}[{k}]')}, " for k, m in enumerate(model))
        return f"new({name}, ({fields}))"

    namespace: dict[str, Any] = {"new": tuple.__new__}
    body = expression(like, "p")
    namespace.update(classes)
    exec(f"def dress(p):\n    return {body}\n", namespace)
    return namespace["dress"]


class Block(NamedTuple):
    """What a compiled block of iterations needs besides the kernels, the state and params."""

    address: int
    """Address of the compiled cost (see :mod:`~formation_bench.optimizers.compiled`)."""
    data: np.ndarray
    """The problem the cost reads."""
    counts: np.ndarray
    """The solve's tally counts (evaluations, limit, whether a best is held)."""
    best: np.ndarray
    """The solve's best cost followed by its point."""
    uniforms: np.ndarray
    """The block's uniforms, one row per iteration."""
    normals: np.ndarray
    """The block's standard normals, one block per iteration."""
    history_nfev: np.ndarray
    """Evaluations after each iteration done."""
    history_fun: np.ndarray
    """Best cost after each iteration done."""
    clock: int = 0
    """Address of the clock the deadline is read from (a :class:`~formation_bench.optimizers.
    clock.Clock`'s)."""
    clock_id: int = 0
    """The clock's id."""
    deadline_ns: int = NEVER
    """The clock's time at the deadline, checked before each iteration; :data:`~formation_bench.
    optimizers.clock.NEVER`: none (the clock is not read)."""


class Draws(NamedTuple):
    """The random numbers of a block of iterations, one row each, and its history."""

    uniforms: np.ndarray
    """Uniforms, one row per iteration."""
    normals: np.ndarray
    """Standard normals, one block per iteration."""
    history_nfev: np.ndarray
    """Filled by the block: evaluations after each iteration done."""
    history_fun: np.ndarray
    """Filled by the block: best cost after each iteration done."""


History = tuple[np.ndarray, np.ndarray]
"""Evaluations (int64) and best cost after the start and after each iteration."""
Outcome = tuple[Any, int]
"""A block's new state and the iterations it did."""


class Tally(abc.ABC):
    """A solve's evaluations so far: what the outer loop reads between blocks."""

    started: float
    """``time.perf_counter()`` when the solve began."""

    @abc.abstractmethod
    def remaining(self) -> int:
        """Evaluations left (a large number without a limit)."""

    @abc.abstractmethod
    def progress(self) -> tuple[int, float]:
        """``(evaluations, best cost)`` so far."""

    @abc.abstractmethod
    def evaluate_prefix(self, points: np.ndarray) -> np.ndarray:
        """Costs of ``points``: the rows the budget allows evaluated, the rest ``+inf``."""

    @abc.abstractmethod
    def run(
        self, kernels: Any, state: Any, params: tuple, draws: Draws, nit: int, deadline: Deadline
    ) -> Outcome:
        """Iterations ``nit + 1``, ... on ``draws`` (one row each) with ``kernels`` (an
        :class:`~formation_bench.optimizers.ask_tell.Kernels`), while evaluations are left
        and ``deadline`` has not passed (checked before each iteration): ``(state, iterations
        done)``, with ``draws``' history filled."""

    @abc.abstractmethod
    def result(self, nit: int, message: str, history: History, info: dict) -> OptimizeResult:
        """The solve's result."""


class CompiledTally(Tally):
    """The tally of a solve whose iterations run in compiled code."""

    def __init__(self, objective: CompiledObjective, max_evaluations: int | None, dim: int,
                 started: float) -> None:  # fmt: skip
        self.objective, self.started = objective, started
        self.counts, self.best = new_tally(dim, max_evaluations)

    def remaining(self) -> int:
        # compiled.remaining's arithmetic, without a call into compiled code from Python (and
        # on Python ints: item() is cheaper than numpy scalars)
        limit = self.counts.item(LIMIT)
        return UNLIMITED if limit == NO_LIMIT else limit - self.counts.item(NFEV)

    def progress(self) -> tuple[int, float]:
        return self.counts.item(NFEV), self.best.item(0)

    def evaluate_prefix(self, points: np.ndarray) -> np.ndarray:
        objective = self.objective
        return evaluate_prefix(objective.address, objective.data, points, self.counts, self.best)

    def run(
        self, kernels: Any, state: Any, params: tuple, draws: Draws, nit: int, deadline: Deadline
    ) -> Outcome:
        clock = deadline.clock
        block = Block(self.objective.address, self.objective.data, self.counts, self.best,
                      *draws, clock.address, clock.clock_id, deadline.at_ns)  # fmt: skip
        # the state comes back as plain tuples (plain says why)
        returned, done = kernels.iterate(state, params, block, nit, draws.uniforms.shape[0])
        return dressed(returned, state), done

    def result(self, nit: int, message: str, history: History, info: dict) -> OptimizeResult:
        start = CompiledStart(self.counts, self.best, self.started)
        return compiled_result(start, nit, message, history[0], history[1], info)


_COST_CALLBACK = ctypes.CFUNCTYPE(
    None, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p
)
"""The C calling convention of a compiled cost, for a Python function."""


class ForwardedTally(CompiledTally):
    """The compiled loop with a Python objective, reached through a C callback.

    The compiled side already counts the evaluations, keeps the best point and maps
    non-finite costs to ``+inf`` (:func:`~formation_bench.optimizers.compiled.evaluate`), so a
    call only copies the batch, calls the objective, checks the costs' count and times it:
    an immediate DE generation calls it once per trial.
    """

    def __init__(self, objective: Any, dim: int, max_evaluations: int | None,
                 started: float) -> None:  # fmt: skip
        self.python_objective = objective
        self.objective_time_s = 0.0
        self.failure: BaseException | None = None
        callback = _COST_CALLBACK(self._forward)
        address = ctypes.cast(callback, ctypes.c_void_p).value
        assert address is not None
        super().__init__(CompiledObjective(address, np.zeros(1), callback), max_evaluations,
                         dim, started)  # fmt: skip

    def _forward(self, x_address: int, n: int, d: int, data: int, out_address: int) -> None:
        out = np.frombuffer((ctypes.c_double * n).from_address(out_address), dtype=np.float64)
        if self.failure is None:
            try:
                # a copy, so that an objective keeping the batch never holds memory the
                # compiled code frees
                batch = np.array((ctypes.c_double * (n * d)).from_address(x_address))
                start = perf_counter()
                raw = self.python_objective(batch.reshape(n, d))
                self.objective_time_s += perf_counter() - start
                costs = np.asarray(raw, dtype=np.float64).reshape(-1)
                if costs.shape[0] != n:
                    raise ValueError(f"objective returned {costs.shape[0]} costs for {n} points")
                out[:] = costs
                return
            except BaseException as exc:  # raised again by the caller, after the block
                self.failure = exc
                # no evaluation is left once this one is counted: the block ends
                self.counts[LIMIT] = self.counts[NFEV] + n
        out[:] = math.nan

    def _raise_failure(self) -> None:
        if self.failure is not None:
            raise self.failure

    def evaluate_prefix(self, points: np.ndarray) -> np.ndarray:
        costs = super().evaluate_prefix(points)
        self._raise_failure()
        return costs

    def run(
        self, kernels: Any, state: Any, params: tuple, draws: Draws, nit: int, deadline: Deadline
    ) -> Outcome:
        outcome = super().run(kernels, state, params, draws, nit, deadline)
        self._raise_failure()
        return outcome

    def result(self, nit: int, message: str, history: History, info: dict) -> OptimizeResult:
        result = super().result(nit, message, history, info)
        result.info["objective_time_s"] = self.objective_time_s
        return result


class CounterTally(Tally):
    """The tally of a solve whose rounds run from Python, through a counter."""

    def __init__(self, counter: EvaluationCounter, started: float) -> None:
        self.counter, self.started = counter, started

    def remaining(self) -> int:
        return self.counter.remaining

    def progress(self) -> tuple[int, float]:
        return self.counter.nfev, self.counter.best_f

    def evaluate_prefix(self, points: np.ndarray) -> np.ndarray:
        from formation_bench.optimizers.population import evaluate_prefix as counted_prefix

        return counted_prefix(self.counter, points)

    def run(
        self, kernels: Any, state: Any, params: tuple, draws: Draws, nit: int, deadline: Deadline
    ) -> Outcome:
        return iterate_python(kernels, state, params, self.counter, draws, nit, deadline)

    def result(self, nit: int, message: str, history: History, info: dict) -> OptimizeResult:
        return counted_result(self.counter, nit, message, history, info)


def iterate_python(
    kernels: Any,
    state: Any,
    params: tuple,
    counter: EvaluationCounter,
    draws: Draws,
    nit: int,
    deadline: Deadline | None = None,
) -> tuple[Any, int]:
    """The rounds of :func:`~formation_bench.optimizers.ask_tell.iterate`, run from Python
    (for an ``ask`` that is Python itself), evaluating through ``counter``, checking
    ``deadline`` (if any) before each iteration as the compiled block does."""
    ask, tell = kernels.ask, kernels.tell
    done = 0
    for row in range(draws.uniforms.shape[0]):
        if counter.remaining <= 0 or (deadline is not None and deadline.passed()):
            break
        nit += 1
        uniforms = draws.uniforms[row]
        normals = draws.normals[row]
        last = False
        while not last:
            state, candidates, last = ask(state, params, uniforms, normals, nit, counter.remaining)
            allowed = min(candidates.shape[0], counter.remaining)
            costs = counter(candidates[:allowed]) if allowed > 0 else np.empty(0)
            state = tell(state, params, candidates, costs, nit)
        draws.history_nfev[done] = counter.nfev
        draws.history_fun[done] = counter.best_f
        done += 1
    return state, done


def open_tally(
    objective: Any, dim: int, budget: Budget, started: float, compiled_loop: bool
) -> Tally:
    """The tally of a solve of ``objective`` in ``dim`` dimensions: compiled when the
    optimiser's configuration runs in compiled code (``compiled_loop``), through the objective's
    compiled handle if it has one, else forwarded to the Python objective."""
    if not compiled_loop:
        return CounterTally(EvaluationCounter(objective, dim, budget.max_evaluations), started)
    handle = compiled_of(objective)
    if handle is not None:
        return CompiledTally(handle, budget.max_evaluations, dim, started)
    return ForwardedTally(objective, dim, budget.max_evaluations, started)
