"""One closed-loop run end to end: simulate, measure, write outputs and figures."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formation_bench.benchmarks.outputs import trace_frame
from formation_bench.mpc.cost import batch_cost
from formation_bench.mpc.loop import ProgressCallback, Trace, simulate
from formation_bench.mpc.metrics import compute_metrics, pair_names
from formation_bench.mpc.model import rollout
from formation_bench.mpc.scenario import Scenario
from formation_bench.optimizers.base import Budget, Optimizer


@dataclass(frozen=True)
class RunOutcome:
    """A finished run: its trace, metrics, and trace table."""

    trace: Trace
    metrics: dict[str, Any]
    frame: pd.DataFrame


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
    batch_cost(
        np.zeros((2, 2)),
        state,
        np.zeros(2, dtype=np.int64),
        0.1,
        1,
        np.zeros((1, 2, 2)),
        np.zeros((2, 2)),
        1.0,
        1.0,
    )


def run_closed_loop(
    scenario: Scenario,
    optimizer_name: str,
    optimizer: Optimizer,
    *,
    trigger: bool,
    seed: int,
    budget: Budget | None = None,
    progress: ProgressCallback | None = None,
) -> RunOutcome:
    """Simulate one run and compute its metrics (``budget`` None: the optimiser's own)."""
    warm_up_kernels()
    trace = simulate(
        scenario,
        optimizer,
        trigger=trigger,
        seed=seed,
        optimizer_name=optimizer_name,
        budget=budget,
        progress=progress,
    )
    return RunOutcome(trace, compute_metrics(trace), trace_frame(trace))


def write_figures(
    outcome: RunOutcome, out_dir: Path, suffix: str, fig_numbers: tuple[int, int]
) -> list[Path]:
    """Trajectory and states figures of one run; returns the paths written."""
    from formation_bench.benchmarks.analysis import figures  # matplotlib only when drawing

    scenario = outcome.trace.scenario
    desired = scenario.desired_distances()
    desired_by_name = {name: float(desired[i, j]) for name, i, j in pair_names(scenario.n_uav)}
    trajectory = out_dir / f"fig{fig_numbers[0]}_trajectory_{suffix}.png"
    states = out_dir / f"fig{fig_numbers[1]}_states_{suffix}.png"
    figures.save(figures.trajectory_figure(outcome.frame), trajectory)
    figures.save(
        figures.states_figure(outcome.frame, desired_by_name, scenario.settle_time_s), states
    )
    return [trajectory, states]


def write_trigger_figure(outcome: RunOutcome, out_dir: Path, name: str) -> Path:
    """Fig. 7 for one run."""
    from formation_bench.benchmarks.analysis import figures

    path = out_dir / name
    figures.save(figures.trigger_figure(outcome.frame), path)
    return path
