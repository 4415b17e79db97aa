"""One closed-loop run end to end: :func:`execute` turns a :class:`RunSpec` into a
:class:`RunRecord` and a trace. It returns them and draws nothing: the figures of a run are
:mod:`formation_bench.analysis.run_figures`'s."""

from __future__ import annotations

import contextlib
import functools
import gc
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from formation_bench.mpc.cost import Penalties, pack_problem
from formation_bench.mpc.loop import ClosedLoop, ProgressCallback, Trace, simulate
from formation_bench.mpc.metrics import compute_metrics
from formation_bench.mpc.model import rollout
from formation_bench.mpc.native_cost import CostKernel, cost_function, packed_costs
from formation_bench.pipeline import outputs
from formation_bench.pipeline.interrupts import interrupts_where_safe
from formation_bench.pipeline.record import Provenance, RunDescription, RunRecord
from formation_bench.pipeline.spec import RunSpec
from formation_bench.pipeline.trace_columns import RunLabels
from formation_bench.plugins import load_plugins

if TYPE_CHECKING:
    import pandas as pd
    import pyarrow as pa

    from formation_bench.mpc.scenario import Scenario
    from formation_bench.optimizers import BatchObjective, Bounds, Budget, Optimizer


@dataclass(frozen=True)
class RunOutcome:
    """A finished run: its record, its trace, and the trace as a table."""

    record: RunRecord
    trace: Trace
    spec: RunSpec
    """What was run (labels the trace table)."""

    @functools.cached_property
    def table(self) -> pa.Table:
        """The trace table (:func:`trace_table`), as it is written to ``trace.parquet``; built
        on first use (a sweep that stores no trace never needs it)."""
        return trace_table(self.trace, self.spec)

    @functools.cached_property
    def frame(self) -> pd.DataFrame:
        """The trace table as a pandas DataFrame (converted on first use: the figures and a
        sweep's store need it, a run without either does not import pandas)."""
        return self.table.to_pandas(use_threads=outputs.ARROW_THREADS)


def kernels_cached() -> bool:
    """Whether numba's on-disk cache holds the harness's kernels (the model, the cost and the
    trigger's conditions, which every run uses), fresh for their source.

    A cold cache means a first run that compiles for several seconds; the command line says so
    before it starts (:func:`optimizer_kernels_cached` for the optimiser's own kernels).
    """
    from formation_bench.mpc import cost, model, trigger

    harness = (
        model.rollout,
        trigger.distance_condition,
        trigger.tracking_condition,
        trigger.control_condition,
    )
    if cost_function().kernel is CostKernel.NUMBA:  # compiled only when it serves
        harness += (cost.packed_batch_cost,)
    return all(kernel_cached(kernel) for kernel in harness)


def optimizer_kernels_cached(optimizer: Optimizer) -> bool:
    """Whether numba's cache holds ``optimizer``'s :meth:`~formation_bench.optimizers.
    Optimizer.compiled_kernels` (True for an optimiser without any)."""
    return all(kernel_cached(kernel) for kernel in optimizer.compiled_kernels())


def kernel_cached(kernel: object) -> bool:
    """Whether numba's on-disk cache (``NUMBA_CACHE_DIR`` or beside the source) holds a
    compilation of the ``@njit(cache=True)`` function ``kernel`` made from its current source;
    True for anything numba does not cache, which has nothing to find."""
    cache_file = getattr(getattr(kernel, "_cache", None), "_cache_file", None)
    if cache_file is None:
        return True
    try:
        # the index numba itself reads: empty when missing, from another numba version or
        # from an older version of the source
        return bool(cache_file._load_index())
    except Exception:  # numba's private layout changed: whether the index exists at all
        return Path(cache_file._index_path).exists()


def warm_up_kernels() -> None:
    """Compile (or load from cache) the numba kernels before anything is timed."""
    state = np.zeros(4)
    rollout(state, np.zeros((2, 2)), 0.1, 1)
    packed = pack_problem(
        state, np.zeros(2, dtype=np.int64), 0.1, 1, np.zeros((1, 2, 2)), np.zeros((2, 2)),
        1.0, 1.0, np.zeros((1, 2, 2)), Penalties(),
    )  # fmt: skip
    packed_costs(np.zeros((2, 2)), packed)


@contextlib.contextmanager
def compile_garbage_collected() -> Iterator[None]:
    """Collect Python's garbage at the end of the block if numba loaded or compiled kernels in
    it: what that leaves made the next full collection (0.1-0.2 s) land in a timed solve (a
    score run's first solve 3-5 ms against 0.7). A block that compiled nothing, as in a warm
    process, collects nothing, since a full collection costs that much every time."""
    from numba.core import event  # numba's event API: the compiler lock is taken to load or compile

    with event.install_recorder("numba:compiler_lock") as compiled:
        yield
    if compiled.buffer:
        gc.collect()


WARM_UP_SEED = 0
"""Seed of the generators of a warm-up (:func:`warm_up_solve`, :func:`warm_up_loop`): their
own, so the timed solves' random numbers are those they would be without it."""


def warm_up_solve(
    optimizer: Optimizer,
    objective: BatchObjective,
    bounds: Bounds,
    budget: Budget | None,
    x0: np.ndarray | None,
) -> None:
    """One untimed solve before timed ones, so that no timed solve holds numba's compilation
    (or loading) of ``optimizer``'s kernels, nor an exact solver's building of its functions;
    then :meth:`~formation_bench.optimizers.Optimizer.forget_solves`, so that the first timed
    solve is the same as without it."""
    with compile_garbage_collected():
        optimizer.minimize(objective, bounds, np.random.default_rng(WARM_UP_SEED), budget, x0)
    optimizer.forget_solves()


WARM_UP_PERIODS = 2
"""Control periods of a warm-up loop: the first solves from no plan and checks no trigger
condition; the second checks them all and solves warm-started, so that a timed run compiles
nothing the warm-up did not (the trigger's kernels once cost a sweep's first run 0.4-1 s)."""


def warm_up_loop(scenario: Scenario, optimizer: Optimizer, budget: Budget | None) -> None:
    """Untimed first instants of the closed loop of ``scenario`` (:data:`WARM_UP_PERIODS`, every
    UAV solving at each): the harness's kernels and ``optimizer``'s compiled or built on the
    problems the run solves."""
    with compile_garbage_collected():
        warm_up_kernels()
        loop = ClosedLoop(scenario, optimizer, trigger=False, seed=WARM_UP_SEED, budget=budget)
        for c in range(min(WARM_UP_PERIODS, scenario.timing.n_steps)):
            loop.control_period(c)
    optimizer.forget_solves()


def execute(spec: RunSpec, *, progress: ProgressCallback | None = None) -> RunOutcome:
    """Carry out one run: the one path of ``run``, ``reproduce`` and every run of a sweep.

    Its times (``run_time_s``, every solve's) start after a warm-up (:func:`warm_up_loop`),
    so the first run of a process measures what the others do."""
    # a fresh sweep worker knows only the built-in and entry-point optimisers
    load_plugins(spec.plugins)
    scenario, optimizer = spec.build()
    with interrupts_where_safe():
        warm_up_loop(scenario, optimizer, spec.budget_for(optimizer))
        start = time.perf_counter()
        trace = simulate(
            scenario,
            optimizer,
            trigger=spec.trigger,
            seed=spec.entropy,
            optimizer_name=spec.optimizer_label,
            budget=spec.budget_for(optimizer),
            progress=progress,
        )
    metrics = compute_metrics(trace)
    record = RunRecord(
        RunDescription.of(spec, scenario.timing.n_steps, scenario.evaluation.settle_time_s),
        metrics,
        Provenance.here(time.perf_counter() - start),
    )
    return RunOutcome(record, trace, spec)


def trace_table(trace: Trace, spec: RunSpec) -> pa.Table:
    """The trace as a long table (:func:`~formation_bench.pipeline.outputs.trace_table`),
    labelled as the run's record is (its seed as given, its budget)."""
    labels = RunLabels(
        optimizer=trace.optimizer,
        scenario=trace.scenario.name,
        trigger=trace.trigger,
        budget=spec.budget_label,
        seed=spec.seed,
    )
    return outputs.trace_table(trace, labels)
