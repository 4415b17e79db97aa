"""The common optimiser interface.

Every optimiser in formation-bench minimises a *batch* objective
``f: (n, d) -> (n,)`` over a box ``[lower, upper]`` under a :class:`Budget`,
with all randomness drawn from a passed :class:`numpy.random.Generator`, and
returns an :class:`OptimizeResult` (the fields follow ``scipy.optimize``).

The population methods of formation-bench are
:class:`~formation_bench.optimizers.ask_tell.AskTellOptimizer`: compiled ask/tell kernels over
a named state, driven by loops that own the evaluation counting and the budget. The adapters
of other libraries subclass :class:`PopulationOptimizer` and implement a pure
``init``/``step`` pair over an immutable state; its loop likewise owns the counting and the
budget, so that no optimiser can exceed its evaluation budget or forget to count an
evaluation.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field
from time import perf_counter
from typing import Any, ClassVar, Generic, Protocol, TypeVar

import numpy as np

# The config-field checks live in the neutral formation_bench.fields; re-exported here so that
# existing imports keep working.
from formation_bench.fields import (  # noqa: F401
    check_bool,
    check_int,
    check_real,
    coerce_enum,
    setting,
)
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.compiled import UNLIMITED


class BatchObjective(Protocol):
    """A cost evaluated for a whole population in one call: ``(n, d) -> (n,)``.

    An objective may also carry a ``compiled`` attribute, a
    :class:`~formation_bench.optimizers.compiled.CompiledObjective` computing the same costs;
    optimisers that run their iterations in compiled code call that instead, without Python
    in between.
    """

    def __call__(self, x: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class Bounds:
    """Box constraints ``lower <= x <= upper`` of the decision vector."""

    lower: np.ndarray
    """Lower bound of every coordinate, shape ``(d,)``, finite."""
    upper: np.ndarray
    """Upper bound of every coordinate, shape ``(d,)``, finite and > ``lower``."""

    def __post_init__(self) -> None:
        lower = np.asarray(self.lower, dtype=np.float64).reshape(-1)
        upper = np.asarray(self.upper, dtype=np.float64).reshape(-1)
        if lower.shape != upper.shape or lower.size == 0:
            raise ValueError(
                f"Bounds: lower and upper must be non-empty and of equal length, "
                f"got {lower.size} and {upper.size}"
            )
        if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper))):
            raise ValueError("Bounds: lower and upper must be finite")
        if np.any(upper <= lower):
            bad = int(np.argmax(upper <= lower))
            raise ValueError(
                f"Bounds: upper must exceed lower in every coordinate; coordinate {bad} has "
                f"lower={lower[bad]} upper={upper[bad]}"
            )
        lower.setflags(write=False)
        upper.setflags(write=False)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @property
    def dim(self) -> int:
        """Dimension ``d`` of the decision vector."""
        return int(self.lower.size)

    @property
    def width(self) -> np.ndarray:
        """``upper - lower`` per coordinate."""
        return self.upper - self.lower

    def contains(self, x: np.ndarray) -> bool:
        """True when every row of ``x`` lies inside the box."""
        x = np.atleast_2d(x)
        return bool(np.all(x >= self.lower) and np.all(x <= self.upper))

    def clip(self, x: np.ndarray) -> np.ndarray:
        """Project ``x`` onto the box (``np.clip``'s values; two ufuncs are faster than its
        dispatch on the small arrays of a solve)."""
        return np.minimum(np.maximum(x, self.lower), self.upper)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` points drawn uniformly in the box: ``lower + u (upper - lower)``."""
        points = rng.random((n, self.lower.size))
        _scale_into_box(points, self.lower, self.upper)
        return points

    def cache_key(self) -> tuple[bytes, bytes]:
        """The box by value, for caching what depends on it alone (the arrays are read-only
        here, but may be views of an array the caller still changes, so it is read each
        time)."""
        return self.lower.tobytes(), self.upper.tobytes()


@njit(cache=True)
def _scale_into_box(points: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
    """``points = lower + points (upper - lower)`` in place: numpy's values of the expression
    (numba fuses no multiply-add without fastmath), in a fifth of the time of its three
    broadcast operations on a population."""
    n, d = points.shape
    for i in range(n):
        for c in range(d):
            points[i, c] = lower[c] + points[i, c] * (upper[c] - lower[c])


BUDGET_MINIMUM = 1
"""The least every limit of a budget may be, evaluations and iterations alike, whoever sets
it (a command's option, a suite's budget table, an optimiser's own setting): a solve allowed
no iteration returns its warm start, or its first samples, as if it had optimised."""


def budget_setting(default: int, *, doc: str) -> Any:
    """An optimiser's own budget limit (the iterations or evaluations of its
    ``default_budget``), declared with :func:`~formation_bench.fields.setting` under the rule
    :class:`Budget` applies to every limit: an integer >= :data:`BUDGET_MINIMUM`."""
    return setting(default, low=BUDGET_MINIMUM, doc=doc)


@dataclass(frozen=True)
class Budget:
    """How much an optimiser may spend on one solve.

    The solve stops at whichever limit is reached first, and the evaluation count
    never exceeds ``max_evaluations``. A ``deadline_s`` also stops it once that much
    wall time has passed since the solve began, with the best point so far: a
    population method checks it between iterations (its initial population is
    always evaluated), so one iteration may run past it.

    A budget with a deadline but neither limit keeps the optimiser's own limits
    (:attr:`keeps_own_limits`); :meth:`within` completes it with them, and a solve
    is given the completed budget. Deadlines are in seconds everywhere in the code;
    a user-facing option in milliseconds (``--deadline-ms``, a suite's
    ``deadline_ms``) is converted where it is read.
    """

    max_evaluations: int | None = None
    """Largest number of objective evaluations (rows evaluated), >= :data:`BUDGET_MINIMUM`."""
    max_iterations: int | None = None
    """Largest number of iterations (generations) after initialisation, >=
    :data:`BUDGET_MINIMUM`."""
    deadline_s: float | None = None
    """Wall-clock time per solve, seconds, > 0; None: no deadline. A solve under a deadline
    depends on the machine's speed, so its result is not repeatable bit for bit."""

    def __post_init__(self) -> None:
        if self.keeps_own_limits and self.deadline_s is None:
            raise ValueError(
                "Budget: set max_evaluations, max_iterations, or both (a deadline_s alone keeps "
                "the optimiser's own limits)"
            )
        for name in ("max_evaluations", "max_iterations"):
            if getattr(self, name) is not None:
                check_int("Budget", name, getattr(self, name), BUDGET_MINIMUM)
        if self.deadline_s is not None and not (
            isinstance(self.deadline_s, int | float | np.integer | np.floating)
            and not isinstance(self.deadline_s, bool)
            and math.isfinite(self.deadline_s)
            and self.deadline_s > 0
        ):
            raise ValueError(f"Budget.deadline_s must be a number > 0, got {self.deadline_s!r}")

    @property
    def keeps_own_limits(self) -> bool:
        """Whether it sets neither limit (only a deadline): the optimiser's own limits apply."""
        return self.max_evaluations is None and self.max_iterations is None

    def within(self, own: Budget) -> Budget:
        """The budget a solve runs under: this one, or, when it sets neither limit, the
        optimiser's own budget ``own`` with this one's deadline."""
        if not self.keeps_own_limits:
            return self
        return Budget(own.max_evaluations, own.max_iterations, self.deadline_s)


@dataclass(frozen=True)
class OptimizeResult:
    """Outcome of one solve (field names as in ``scipy.optimize.OptimizeResult``)."""

    x: np.ndarray
    """Best point found, shape ``(d,)``."""
    fun: float
    """Its cost."""
    nfev: int
    """Objective evaluations used (rows evaluated)."""
    nit: int
    """Iterations completed after initialisation."""
    success: bool
    """True when the solve ended normally (budget reached or converged)."""
    message: str
    """Why the solve ended."""
    history_nfev: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """Evaluations used at the end of initialisation and of every iteration."""
    history_fun: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """Best cost so far at the same moments as ``history_nfev``."""
    info: dict[str, Any] = field(default_factory=dict)
    """Optimiser-specific extras (e.g. time spent clustering)."""


_FLOAT64 = np.dtype(np.float64)


class BudgetExhausted(RuntimeError):
    """Raised when an objective call would exceed the evaluation budget."""


class EvaluationCounter:
    """Wraps a batch objective: counts rows, enforces the budget, keeps the best.

    Non-finite costs (NaN, +-inf) are mapped to ``+inf`` so that they rank
    below every finite cost in every comparison.
    """

    def __init__(self, objective: BatchObjective, dim: int, max_evaluations: int | None) -> None:
        self._objective = objective
        self._dim = dim
        self.max_evaluations = max_evaluations
        self.nfev = 0
        self.objective_time_s = 0.0
        self.best_x: np.ndarray | None = None
        self.best_f = math.inf

    @property
    def remaining(self) -> int:
        """Evaluations left (a large number when there is no evaluation limit)."""
        if self.max_evaluations is None:
            return UNLIMITED
        return self.max_evaluations - self.nfev

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=np.float64)
        shape = x.shape
        if len(shape) != 2 or shape[1] != self._dim:
            raise ValueError(f"objective input must have shape (n, {self._dim}), got {shape}")
        n = shape[0]
        if n == 0:
            return np.zeros(0)
        if self.max_evaluations is not None and n > self.max_evaluations - self.nfev:
            raise BudgetExhausted(f"{n} evaluations requested, {self.remaining} left")
        start = perf_counter()
        raw = self._objective(x)
        self.objective_time_s += perf_counter() - start
        # a copy, so the caller never aliases a buffer the objective may reuse; an array of
        # float64 costs (the usual answer) is copied directly, which is cheaper than np.array
        if type(raw) is np.ndarray and raw.dtype == _FLOAT64 and raw.ndim == 1:
            f = raw.copy()
        else:
            f = np.array(raw, dtype=np.float64).reshape(-1)
        if f.shape[0] != n:
            raise ValueError(f"objective returned {f.shape[0]} costs for {n} points")
        # argmin returns the first NaN if there is one, and -inf if there is one, so a
        # finite minimum proves the only non-finite values are +inf (already the mapped
        # value): the common all-finite case costs one reduction instead of three.
        i = f.argmin()
        best = f.item(i)
        if not math.isfinite(best):
            f[~np.isfinite(f)] = np.inf
            i = f.argmin()
            best = f.item(i)
        self.nfev += n
        if best < self.best_f or self.best_x is None:
            self.best_f = best
            self.best_x = x[i].copy()
        return f


def counted_result(
    counter: EvaluationCounter,
    nit: int,
    message: str,
    history: tuple[list[int], list[float]],
    info: dict[str, Any],
) -> OptimizeResult:
    """The result of a solve whose evaluations ``counter`` counted: its best point and cost,
    counts, ``history`` (evaluations and best cost after the start and each iteration) and
    ``info`` after the objective's time."""
    assert counter.best_x is not None
    return OptimizeResult(
        x=counter.best_x,
        fun=counter.best_f,
        nfev=counter.nfev,
        nit=nit,
        success=True,
        message=message,
        history_nfev=np.asarray(history[0], dtype=np.int64),
        history_fun=np.asarray(history[1]),
        info={"objective_time_s": counter.objective_time_s, **info},
    )


def check_rng(rng: object) -> np.random.Generator:
    """Return ``rng`` if it is a Generator; refuse global-state or integer seeds."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(
            f"rng must be a numpy.random.Generator (e.g. np.random.default_rng(seed)), "
            f"got {type(rng).__name__}"
        )
    return rng


def check_x0(x0: np.ndarray | None, bounds: Bounds) -> np.ndarray | None:
    """Validate a warm start and project it onto the bounds."""
    if x0 is None:
        return None
    x0 = np.asarray(x0, dtype=np.float64).reshape(-1)
    if x0.size != bounds.lower.size:
        raise ValueError(f"x0 must have {bounds.dim} entries, got {x0.size}")
    # the few entries of a warm start checked in Python: np.isfinite(x0).all() takes a
    # microsecond of every solve
    if not all(map(math.isfinite, x0.tolist())):
        raise ValueError("x0 must be finite")
    return bounds.clip(x0)


StateT = TypeVar("StateT")


class Optimizer(abc.ABC):
    """What the DMPC harness (and every benchmark) needs from an optimiser."""

    compile_cpu_s: ClassVar[float | None] = None
    """CPU seconds numba takes to compile :meth:`compiled_kernels` (and what they call) on an
    empty cache, as ``python -m perf.cold_warm`` measured them on the development machine,
    without the harness's share; None: not measured (a plugin's). For the notice of a command
    that compiles and the order in which a sweep starts its first runs."""

    def compiled_kernels(self) -> tuple[Any, ...]:
        """The outermost numba kernels (cached ``njit`` functions) of a solve: once they are in
        numba's cache, a solve compiles nothing. Empty for an optimiser without any; the
        optimisers that share them compile the same code."""
        return ()

    @property
    @abc.abstractmethod
    def default_budget(self) -> Budget:
        """The budget used when the caller gives none (the optimiser's own setting)."""

    def solve_budget(self, budget: Budget | None) -> Budget:
        """The budget a solve runs under: :attr:`default_budget` when ``budget`` is None, its
        limits with ``budget``'s deadline when ``budget`` sets a deadline alone, else
        ``budget``."""
        if budget is not None and not budget.keeps_own_limits:
            return budget  # the usual call: the default budget is not built
        return self.default_budget if budget is None else budget.within(self.default_budget)

    def forget_solves(self) -> None:
        """Drop what earlier solves left for the next one (an exact solver's workspace warm
        started from the previous plan), so that the next solve runs as a first one would.
        A warm-up solve before timed ones calls it; there is nothing to drop by default."""
        return None

    @abc.abstractmethod
    def minimize(
        self,
        objective: BatchObjective,
        bounds: Bounds,
        rng: np.random.Generator,
        budget: Budget | None = None,
        x0: np.ndarray | None = None,
    ) -> OptimizeResult:
        """Minimise ``objective`` over ``bounds``.

        ``x0`` is a warm start (e.g. the shifted previous plan); an optimiser
        that uses it must evaluate it, so the result is never worse than it.
        """


class PopulationOptimizer(Optimizer, Generic[StateT]):
    """Base for population methods: a pure ``init``/``step`` over immutable state.

    ``init`` and ``step`` evaluate only through the passed
    :class:`EvaluationCounter` and must not ask it for more rows than
    ``counter.remaining``; ``step`` returns a new state.
    """

    @abc.abstractmethod
    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> StateT:
        """Initial state; ``max_iterations`` is the planned number of steps."""

    @abc.abstractmethod
    def step(
        self,
        state: StateT,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> StateT:
        """One iteration; ``iteration`` counts from 1."""

    @abc.abstractmethod
    def evaluations_per_step(self) -> int:
        """Rows one ``step`` evaluates in the usual case (used to plan iterations)."""

    def planned_iterations(self, budget: Budget) -> int:
        """Iterations the budget allows; schedules (e.g. BSO's logsig) use it as T_max."""
        limits = [] if budget.max_iterations is None else [budget.max_iterations]
        if budget.max_evaluations is not None:
            initial = self.initial_evaluations()
            limits.append(max(0, (budget.max_evaluations - initial) // self.evaluations_per_step()))
        return int(min(limits))

    def initial_evaluations(self) -> int:
        """Rows evaluated by ``init``; population size for most methods."""
        return self.evaluations_per_step()

    def minimize(
        self,
        objective: BatchObjective,
        bounds: Bounds,
        rng: np.random.Generator,
        budget: Budget | None = None,
        x0: np.ndarray | None = None,
    ) -> OptimizeResult:
        rng = check_rng(rng)
        budget = self.solve_budget(budget)
        started = perf_counter()
        x0 = check_x0(x0, bounds)
        counter = EvaluationCounter(objective, bounds.dim, budget.max_evaluations)
        max_iterations = self.planned_iterations(budget)
        state = self.init(counter, bounds, rng, x0, max_iterations)
        history_nfev = [counter.nfev]
        history_fun = [counter.best_f]
        nit = 0
        message = "iteration budget reached"
        iteration_limit = budget.max_iterations if budget.max_iterations is not None else math.inf
        # read once: this loop runs once per generation, up to a few hundred times per solve
        max_evaluations = budget.max_evaluations
        evaluation_limit = math.inf if max_evaluations is None else max_evaluations
        deadline_s = budget.deadline_s
        step = self.step
        while nit < iteration_limit:
            if counter.nfev >= evaluation_limit:
                message = "evaluation budget reached"
                break
            if deadline_s is not None and perf_counter() - started >= deadline_s:
                message = "deadline reached"
                break
            nit += 1
            state = step(state, counter, bounds, rng, nit)
            history_nfev.append(counter.nfev)
            history_fun.append(counter.best_f)
        else:
            if counter.remaining <= 0:
                message = "evaluation budget reached"
        return counted_result(
            counter, nit, message, (history_nfev, history_fun), self.result_info(state)
        )

    def result_info(self, state: StateT) -> dict[str, Any]:
        """Optimiser-specific extras copied into :attr:`OptimizeResult.info`."""
        return {}

    def has_compiled_loop(self) -> bool:
        """True when a compiled objective's iterations run in compiled code (see
        :class:`~formation_bench.optimizers.ask_tell.AskTellOptimizer`)."""
        return False
