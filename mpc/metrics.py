"""Metrics of one closed-loop run, computed from its :class:`~formation_bench.mpc.loop.Trace`."""

from __future__ import annotations

from typing import Any

import numpy as np

from formation_bench.mpc.loop import Trace


def pair_names(n_uav: int) -> list[tuple[str, int, int]]:
    """Named UAV pairs: the ring (d12, d23, ..., dN1) first, then any other pair.

    For the paper's three UAVs this is d12, d23, d31, as in the paper.
    """
    ring = [(i, (i + 1) % n_uav) for i in range(n_uav)] if n_uav > 2 else [(0, 1)]
    seen = {frozenset(p) for p in ring}
    chords = [
        (i, j) for i in range(n_uav) for j in range(i + 1, n_uav) if frozenset((i, j)) not in seen
    ]
    return [(f"d{i + 1}{j + 1}", i, j) for i, j in [*ring, *chords]]


def tracking_error(trace: Trace) -> np.ndarray:
    """Distance of the formation centre (mean position) from the reference, per instant."""
    centre = trace.states[:, :, :2].mean(axis=1)
    return np.linalg.norm(centre - trace.reference, axis=1)


def distance_errors(trace: Trace) -> dict[str, np.ndarray]:
    """|actual - desired| distance of every named pair, per instant."""
    desired = trace.scenario.desired_distances()
    positions = trace.states[:, :, :2]
    return {
        name: np.abs(np.linalg.norm(positions[:, i] - positions[:, j], axis=1) - desired[i, j])
        for name, i, j in pair_names(trace.scenario.n_uav)
    }


def closed_loop_cost(trace: Trace) -> float:
    """Eq. (11) summed over the UAVs and integrated along the flown trajectory.

    Uses the actual positions of all UAVs (not estimates) at t_1 .. t_T, with
    the same rectangle rule as the predictive cost.
    """
    scenario = trace.scenario
    positions = trace.states[1:, :, :2]
    offsets = trace.desired_offsets[1:]
    relative_error = (positions[:, :, None] - positions[:, None, :]) - (
        offsets[:, :, None] - offsets[:, None, :]
    )
    formation = np.sum(relative_error**2, axis=(1, 2, 3))  # i == j terms are zero
    centre_error = positions.mean(axis=1) - trace.reference[1:]
    tracking = scenario.n_uav * np.sum(centre_error**2, axis=1)
    return float(scenario.period_s * np.sum(scenario.w_dst * formation + scenario.w_trj * tracking))


def compute_metrics(trace: Trace) -> dict[str, Any]:
    """The metrics of a run, as written to ``metrics.json``."""
    scenario = trace.scenario
    settled = trace.times >= scenario.settle_time_s - 1e-9
    if not np.any(settled):
        raise ValueError(
            f"settle_time_s={scenario.settle_time_s} is after the end of the run "
            f"({trace.times[-1]:.2f} s)"
        )
    tracking = tracking_error(trace)[settled]
    solve_times = trace.solve_time_s[trace.solved]
    return {
        "optimizer": trace.optimizer,
        "scenario": scenario.name,
        "trigger": bool(trace.trigger),
        "seed": int(trace.seed),
        "steps": int(scenario.n_steps),
        "settle_time_s": float(scenario.settle_time_s),
        "tracking_error_max_m": float(tracking.max()),
        "tracking_error_rms_m": float(np.sqrt(np.mean(tracking**2))),
        "distance_error_max_m": {
            name: float(err[settled].max()) for name, err in distance_errors(trace).items()
        },
        "solves_per_uav": [int(n) for n in trace.solved.sum(axis=0)],
        "closed_loop_cost": closed_loop_cost(trace),
        "solve_time_median_s": float(np.median(solve_times)),
        "solve_time_p95_s": float(np.percentile(solve_times, 95)),
        "solve_time_max_s": float(solve_times.max()),
        "nfev_total": int(trace.nfev.sum()),
        "solve_failures": int(trace.solve_failed.sum()),
        "wall_time_s": float(trace.wall_time_s),
    }
