"""One closed-loop run end to end: :func:`execute` turns a :class:`RunSpec` into a
:class:`RunRecord` and a trace; the figures of one run are drawn here too."""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from formation_bench.mpc.cost import Penalties, compiled_cost, pack_problem, packed_batch_cost
from formation_bench.mpc.loop import ProgressCallback, Trace, simulate
from formation_bench.mpc.metrics import compute_metrics, pair_names
from formation_bench.mpc.model import rollout
from formation_bench.pipeline.outputs import seed_column, text_column, trace_frame
from formation_bench.pipeline.record import Provenance, RunDescription, RunRecord
from formation_bench.pipeline.spec import RunSpec
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
        sweep's store need it, a run without figures does not import pandas)."""
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
    compiled_cost()


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
        RunDescription.of(spec, scenario.n_steps, scenario.settle_time_s),
        metrics,
        Provenance.here(time.perf_counter() - start),
    )
    return RunOutcome(record, trace, table)


def trace_table(trace: Trace, spec: RunSpec) -> pa.Table:
    """The trace as a long table, labelled as the run's record is (seed, budget)."""
    table = trace_frame(trace)
    n_rows = table.num_rows
    table = table.set_column(
        table.schema.get_field_index("seed"), "seed", seed_column(spec.seed, n_rows)
    )
    return table.add_column(
        table.schema.get_field_index("trigger") + 1,
        "budget",
        text_column(spec.budget_label, n_rows),
    )


def write_figures(
    outcome: RunOutcome, out_dir: Path, suffix: str, fig_numbers: tuple[int, int]
) -> list[Path]:
    """Trajectory, states and separation figures of one run; returns the paths written.

    The first two are numbered as the paper's (``fig3_trajectory_no_trigger.png``, ...); the
    separation figure, which the paper has not, is ``separation_<suffix>.png``.
    """
    from formation_bench.analysis import run_figures as figures  # when drawing

    scenario = outcome.trace.scenario
    desired = scenario.desired_distances()
    desired_by_name = {name: float(desired[i, j]) for name, i, j in pair_names(scenario.n_uav)}
    trajectory = out_dir / f"fig{fig_numbers[0]}_trajectory_{suffix}.png"
    states = out_dir / f"fig{fig_numbers[1]}_states_{suffix}.png"
    separation = out_dir / f"separation_{suffix}.png"
    frame = outcome.frame
    figures.save(figures.trajectory_figure(frame, scenario), trajectory)
    figures.save(
        figures.states_figure(frame, desired_by_name, scenario.settle_time_s, scenario), states
    )
    figures.save(figures.separation_figure(frame, scenario), separation)
    return [trajectory, states, separation]


def write_trigger_figure(outcome: RunOutcome, out_dir: Path, name: str) -> Path:
    """Fig. 7 for one run."""
    from formation_bench.analysis import run_figures as figures

    path = out_dir / name
    figures.save(figures.trigger_figure(outcome.frame), path)
    return path
