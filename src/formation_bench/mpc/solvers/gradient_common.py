"""What the derivative-based baselines (``ipopt``, ``ltv-osqp``, ``ilqr``) share.

They differ from the population optimisers in three ways that this module
handles once:

- they need the problem's parameters, not only a batch objective, so they
  accept only a :class:`~formation_bench.mpc.problem.LocalProblem` (:func:`require_local_problem`);
- they build a solver once per problem shape (and UAV) and keep it between
  calls in a private cache that is dropped when the optimiser is pickled
  (:class:`SolverCacheMixin`), so the sweep machinery can send them to worker
  processes;
- a solve that fails falls back to the warm start (the shifted previous plan)
  and says so with ``success=False`` (:func:`fallback_result`); the closed loop
  counts it in ``Trace.solve_failed``.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from formation_bench.optimizers.base import BatchObjective, Bounds, OptimizeResult, check_x0

if TYPE_CHECKING:  # mpc.problem imports optimizers.base: imported when first needed
    from formation_bench.mpc.problem import LocalProblem


def require_local_problem(owner: str, objective: BatchObjective) -> LocalProblem:
    """``objective`` if it is a :class:`LocalProblem`, else a TypeError saying why."""
    from formation_bench.mpc.problem import LocalProblem

    if not isinstance(objective, LocalProblem):
        raise TypeError(
            f"{owner} solves the DMPC problem of eq. (14) from its parameters and needs an "
            f"mpc.problem.LocalProblem as the objective, got {type(objective).__name__}"
        )
    return objective


def warm_start_of(problem: LocalProblem, bounds: Bounds, x0: np.ndarray | None) -> np.ndarray:
    """The validated warm start projected onto the bounds; zero controls when none is given."""
    x0 = check_x0(x0, bounds)
    if x0 is None:
        return bounds.clip(np.zeros(bounds.dim))
    return x0


SOLVER_CACHE_ENTRIES = 256
"""Most entries an optimiser's solver cache keeps (built functions, solvers, per-UAV state).

The paper needs a handful; a swarm on a range graph keys one per UAV and neighbour count. The
least recently used entry goes first: an entry of the current run is dropped only after this
many others were used since its own last use, so what a run keeps depends on that run alone.
"""


class LruCache(OrderedDict[Any, Any]):
    """A dict that keeps at most ``capacity`` entries, dropping the least recently used."""

    def __init__(self, capacity: int = SOLVER_CACHE_ENTRIES) -> None:
        super().__init__()
        self.capacity = capacity

    def get(self, key: Any, default: Any = None) -> Any:
        if key not in self:
            return default
        self.move_to_end(key)
        return self[key]

    def __setitem__(self, key: Any, value: Any) -> None:
        super().__setitem__(key, value)
        self.move_to_end(key)
        while len(self) > self.capacity:
            self.popitem(last=False)


class SolverCacheMixin:
    """Solvers kept between calls in a private bounded cache that is no dataclass field.

    The built solvers live in the instance's ``__dict__`` but outside
    :func:`dataclasses.fields`, so they never enter the configuration
    (equality, hashing, ``repr``, the sweep's config hash); pickling (e.g. to a
    sweep worker) and :func:`copy.deepcopy` drop them, and the copy rebuilds
    its solvers on first use. The cache is an :class:`LruCache` of
    :data:`SOLVER_CACHE_ENTRIES` entries, so a long sweep over many problem shapes does not
    grow it without bound.
    """

    CARRIED: ClassVar[frozenset[str]] = frozenset()
    """The first element of the cache keys whose entries a solve leaves for the next one (a
    warm-started workspace, the previous plan's multipliers), as opposed to built solvers."""

    def forget_solves(self) -> None:
        """Drop the entries of :attr:`CARRIED`, keep the built solvers."""
        cache = self._solver_cache
        for key in [k for k in cache if isinstance(k, tuple) and k and k[0] in self.CARRIED]:
            del cache[key]

    @property
    def _solver_cache(self) -> LruCache:
        cache = self.__dict__.get("_solver_cache_dict")
        if cache is None:
            cache = LruCache()
            object.__setattr__(self, "_solver_cache_dict", cache)
        return cache

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("_solver_cache_dict", None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)


def fallback_result(
    x0: np.ndarray,
    fun: float,
    nfev: int,
    nit: int,
    message: str,
    info: dict[str, Any],
) -> OptimizeResult:
    """A failed solve: the warm start, flagged ``success=False`` (the loop counts it)."""
    return OptimizeResult(
        x=x0.copy(),
        fun=float(fun),
        nfev=int(nfev),
        nit=int(nit),
        success=False,
        message=message,
        history_nfev=np.asarray([nfev], dtype=np.int64),
        history_fun=np.asarray([fun]),
        info={**info, "fallback": True},
    )


def shift_of(
    problem: LocalProblem,
    previous_decision: np.ndarray,
    previous_states: np.ndarray,
    x0: np.ndarray,
) -> int | None:
    """How many periods ago ``previous_decision`` was the plan that ``x0`` shifts, or None.

    The closed loop warm-starts from the previous plan shifted by the periods
    elapsed since it was computed (:func:`formation_bench.mpc.problem.shifted_controls`). When
    the current state lies on that plan's predicted trajectory ``s`` periods
    in, and shifting the plan by ``s`` gives ``x0``, the plan is this UAV's
    previous solve in the same run, and quantities kept from that solve (dual
    variables) belong to this one. Anything else (a new run, another UAV, a
    failed solve in between) returns None, so a result never depends on what
    the optimiser solved before unless that solve is the one being continued.
    """
    state = problem.state
    horizon = previous_states.shape[0] - 1
    tolerance = 1e-9 * (1.0 + float(np.abs(state).max()))
    gaps = np.abs(previous_states[1:] - state).max(axis=1)
    for s in np.flatnonzero(gaps <= tolerance) + 1:
        controls = problem.controls(previous_decision)
        index = np.minimum(s + np.arange(horizon), horizon - 1)
        if np.abs(problem.decision_from_controls(controls[index]) - x0).max() <= 1e-12:
            return int(s)
    return None


class BufferedFunction:
    """A CasADi ``Function`` evaluated in place on preallocated arrays (its buffer interface).

    An ordinary call converts every argument and result to and from ``DM``: about 40 µs of a
    50 µs linearisation, 0.1 ms of an ``nlpsol`` call. Here the arguments are written into
    :attr:`inputs`, :meth:`__call__` evaluates, and the results are read from :attr:`outputs`
    (both by the function's own names, in its order; the results are overwritten by the next
    call). The buffer's memory adds CasADi's counters and timers up over its calls:
    :meth:`stats` returns this call's, as differences.
    """

    def __init__(self, function: Any) -> None:
        self.inputs = {n: np.zeros(function.nnz_in(i)) for i, n in enumerate(function.name_in())}
        self.outputs = {n: np.zeros(function.nnz_out(i)) for i, n in enumerate(function.name_out())}
        self._buffer, self._evaluate = function.buffer()
        for index, array in enumerate(self.inputs.values()):
            self._buffer.set_arg(index, memoryview(array))
        for index, array in enumerate(self.outputs.values()):
            self._buffer.set_res(index, memoryview(array))
        self._totals: dict[str, float] = {}

    def __call__(self) -> None:
        self._evaluate()

    def stats(self) -> dict[str, Any]:
        """CasADi's statistics of the last call (its counters and timers for that call alone)."""
        stats = dict(self._buffer.stats())
        for name, value in stats.items():
            if name.startswith(("n_call_", "t_wall_", "t_proc_")):
                stats[name] = value - self._totals.get(name, 0)
                self._totals[name] = value
        return stats
