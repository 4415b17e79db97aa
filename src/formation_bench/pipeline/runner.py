"""One closed-loop run end to end: :func:`execute` turns a :class:`RunSpec` into a
:class:`RunRecord` and a trace. It returns them and draws nothing: the figures of a run are
:mod:`formation_bench.analysis.run_figures`'s."""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from formation_bench.mpc.cost import Penalties, pack_problem, packed_batch_cost
from formation_bench.mpc.loop import ProgressCallback, Trace, simulate
from formation_bench.mpc.metrics import compute_metrics
from formation_bench.mpc.model import rollout
from formation_bench.mpc.native_cost import cost_function
from formation_bench.pipeline import outputs
from formation_bench.pipeline.record import Provenance, RunDescription, RunRecord
from formation_bench.pipeline.spec import RunSpec
from formation_bench.pipeline.trace_columns import RunLabels
from formation_bench.plugins import load_plugins

if TYPE_CHECKING:
    import pandas as pd
    import pyarrow as pa


@dataclass(frozen=True)
class RunOutcome:
    """A finished run: its record, its trace, and the trace as a table."""

    record: RunRecord
    trace: Trace
    table: pa.Table
    """The trace table (:func:`trace_table`), as it is written to ``trace.parquet``."""

    @functools.cached_property
    def frame(self) -> pd.DataFrame:
        """The trace table as a pandas DataFrame (converted on first use: the figures and a
        sweep's store need it, a run without either does not import pandas)."""
        return self.table.to_pandas()


def kernels_cached() -> bool:
    """Whether numba's on-disk cache holds the harness's and the modified BSO's kernels.

    A cold cache means a first run that compiles for several seconds; the
    command line says so before it starts.
    """
    from formation_bench.mpc import cost
    from formation_bench.optimizers import modified_bso_kernels

    for module in (cost, modified_bso_kernels):
        path = Path(module.__file__)
        if not any((path.parent / "__pycache__").glob(f"{path.stem}.*.nbi")):
            return False
    return True


def warm_up_kernels() -> None:
    """Compile (or load from cache) the numba kernels before anything is timed."""
    state = np.zeros(4)
    rollout(state, np.zeros((2, 2)), 0.1, 1)
    packed = pack_problem(
        state, np.zeros(2, dtype=np.int64), 0.1, 1, np.zeros((1, 2, 2)), np.zeros((2, 2)),
        1.0, 1.0, np.zeros((1, 2, 2)), Penalties(),
    )  # fmt: skip
    packed_batch_cost(np.zeros((2, 2)), packed)
    cost_function()


def execute(spec: RunSpec, *, progress: ProgressCallback | None = None) -> RunOutcome:
    """Carry out one run: the one path of ``run``, ``reproduce`` and every run of a sweep."""
    start = time.perf_counter()
    # a fresh sweep worker knows only the built-in and entry-point optimisers
    load_plugins(spec.plugins)
    scenario, optimizer = spec.build()
    warm_up_kernels()
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
    table = trace_table(trace, spec)
    record = RunRecord(
        RunDescription.of(spec, scenario.timing.n_steps, scenario.evaluation.settle_time_s),
        metrics,
        Provenance.here(time.perf_counter() - start),
    )
    return RunOutcome(record, trace, table)


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
