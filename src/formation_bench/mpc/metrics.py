"""Metrics of one closed-loop run, computed from its :class:`~formation_bench.mpc.loop.Trace`.


:class:`Metrics` declares every metric once: its meaning, unit, whether it is a timing (and
so differs between two runs of the same thing), and whether it is one value per run or one per
UAV pair, UAV or trigger condition; and how it is shown: its axis label, which values are
better, whether its axis may be logarithmic, and whether (and where) it is a headline metric.
:meth:`Metrics.columns` names every value as a column (``distance_error_max_m_d12``,
``solves_uav1``, ...); ``metrics.json``, the results store, the report, the figures and the
notebook all read those columns and :func:`metric_infos`.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.mpc.loop import Trace
from formation_bench.mpc.trigger import TRIGGER_CONDITIONS

PAIR_COLUMNS_MAX_UAVS = 4
"""Runs of up to this many UAVs have a column per UAV pair (d12, d23, d31 for the paper);
larger swarms are summarised over the pairs of their communication graph."""


def pair_names(n_uav: int) -> list[tuple[str, int, int]]:
    """Named UAV pairs: the ring (d12, d23, ..., dN1) first, then any other pair.

    For the paper's three UAVs this is d12, d23, d31, as in the paper. Empty above
    :data:`PAIR_COLUMNS_MAX_UAVS` UAVs, where the names would be ambiguous (d112) and too many.
    """
    if n_uav > PAIR_COLUMNS_MAX_UAVS:
        return []
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


def pair_gaps(positions: np.ndarray) -> np.ndarray:
    """``(T + 1, N, N)`` distance between every two UAVs at every instant of ``positions``
    ``(T + 1, N, 2)``."""
    return np.linalg.norm(positions[:, :, None] - positions[:, None, :], axis=-1)


def pair_distance_errors(trace: Trace) -> np.ndarray:
    """``(T + 1, N, N)`` |actual - desired| distance of every pair at every instant."""
    return np.abs(pair_gaps(trace.states[:, :, :2]) - trace.scenario.desired_distances())


def listened(trace: Trace) -> np.ndarray:
    """``(T, N, N)`` the trace's neighbour sets; every other UAV when it has none logged."""
    n_steps, n_uav = trace.controls.shape[:2]
    if trace.neighbours.shape == (n_steps, n_uav, n_uav):
        return trace.neighbours
    return np.broadcast_to(~np.eye(n_uav, dtype=bool), (n_steps, n_uav, n_uav))


def pairs_of_graph(neighbours: np.ndarray) -> np.ndarray:
    """``(T + 1, N, N)`` from the neighbour sets ``(T, N, N)``: the pairs of the communication
    graph at every instant, i < j with i listening to j or j to i (the last instant keeps the
    graph of the one before)."""
    links = neighbours | np.transpose(neighbours, (0, 2, 1))
    links = np.concatenate((links, links[-1:]))
    return np.triu(links, k=1)


def graph_pairs(trace: Trace) -> np.ndarray:
    """:func:`pairs_of_graph` of the trace's neighbour sets."""
    return pairs_of_graph(listened(trace))


def distance_errors(trace: Trace) -> dict[str, np.ndarray]:
    """|actual - desired| distance of every named pair, per instant."""
    return named_pair_series(pair_distance_errors(trace))


def named_pair_series(pair_values: np.ndarray) -> dict[str, np.ndarray]:
    """The series of every named pair (:func:`pair_names`) in a ``(T + 1, N, N)`` array."""
    return {name: pair_values[:, i, j] for name, i, j in pair_names(pair_values.shape[1])}


def closed_loop_cost(trace: Trace, instants: slice | np.ndarray = slice(None)) -> float:
    """Eq. (11) summed over the UAVs and integrated along the flown trajectory.

    Uses the actual positions of all UAVs (not estimates) at t_1 .. t_T, with
    the same rectangle rule as the predictive cost; ``instants`` selects some of
    t_1 .. t_T (a mask or slice over them).
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
    rate = scenario.weights.w_dst * formation + scenario.weights.w_trj * tracking
    return float(scenario.timing.period_s * np.sum(rate[instants]))


def settling_index(trace: Trace, tracking: np.ndarray, errors: np.ndarray) -> int | None:
    """Index of the first instant from which every graph pair's distance error stays within
    ``settling_distance_band`` of its desired distance and the tracking error within
    ``settling_tracking_band_m`` to the end of the run; None if the last instant is outside.
    ``tracking`` and ``errors`` are :func:`tracking_error` and :func:`pair_distance_errors`
    of the trace, at every instant; the pairs are :func:`graph_pairs`."""
    scenario = trace.scenario
    desired = scenario.desired_distances()
    inside = tracking <= scenario.evaluation.settling_tracking_band_m
    outside_band = (errors > scenario.evaluation.settling_distance_band * desired) & graph_pairs(
        trace
    )
    inside &= ~outside_band.any(axis=(1, 2))
    outside = np.flatnonzero(~inside)
    if outside.size == 0:
        return 0
    if outside[-1] == inside.size - 1:
        return None
    return int(outside[-1] + 1)


def min_separation(trace: Trace) -> float:
    """The smallest distance between any two UAVs at any instant, m."""
    return float(separation_over_time(trace).min())


def control_effort(trace: Trace) -> np.ndarray:
    """Per UAV, the integral over the run of (a / a_max)^2 + (omega / omega_max)^2, where
    a_max and omega_max are each control's largest bound magnitude for that UAV: seconds at
    full effort."""
    scenario = trace.scenario
    bounds = [scenario.control_bounds_of(i) for i in range(scenario.n_uav)]
    scale = np.array([np.maximum(np.abs(lower), np.abs(upper)) for lower, upper in bounds])
    return scenario.timing.period_s * np.sum((trace.controls / scale) ** 2, axis=(0, 2))


def segment_min_distance(start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Smallest norm along each straight segment from ``start`` to ``end`` (``(..., 2)``)."""
    step = end - start
    length2 = np.sum(step * step, axis=-1)
    moving = length2 > 0
    along = np.where(moving, -np.sum(start * step, axis=-1) / np.where(moving, length2, 1.0), 0.0)
    along = np.clip(along, 0.0, 1.0)
    return np.linalg.norm(start + along[..., None] * step, axis=-1)


def _events(inside: np.ndarray) -> int:
    """Times a bool series (over axis 0) turns True, counting a True start once."""
    before = np.concatenate((np.zeros_like(inside[:1]), inside[:-1]))
    return int(np.sum(inside & ~before))


def closest_approach(relative: np.ndarray) -> np.ndarray:
    """``(T, ...)`` for relative positions ``(T + 1, ..., 2)`` at the instants: the smallest
    distance within each period, moving in straight lines between the instants."""
    return segment_min_distance(relative[:-1], relative[1:])


def collision_periods_at(positions: np.ndarray, safety_radius: float) -> np.ndarray:
    """``(T, N, N)`` upper-triangular, for positions ``(T + 1, N, 2)``: pairs that came
    closer than ``safety_radius`` during each period (straight lines between the instants)."""
    relative = positions[:, :, None] - positions[:, None, :]  # (T + 1, N, N, 2)
    return np.triu(closest_approach(relative) < safety_radius, k=1)


def obstacle_periods_at(positions: np.ndarray, obstacles: np.ndarray) -> np.ndarray:
    """``(T, N, K)``, for positions ``(T + 1, N, 2)`` and obstacle rows ``(x, y, r)``: UAVs
    inside obstacle k's radius during each period (straight lines between the instants)."""
    obstacles = np.asarray(obstacles, dtype=np.float64).reshape(-1, 3)
    relative = positions[:, :, None] - obstacles[None, None, :, :2]  # (T + 1, N, K, 2)
    return closest_approach(relative) < obstacles[:, 2]


def separation_at(positions: np.ndarray) -> np.ndarray:
    """``(T + 1,)`` the smallest distance between two UAVs at each instant of ``positions``."""
    gaps = pair_gaps(positions)
    return gaps[:, *np.triu_indices(positions.shape[1], k=1)].min(axis=1)


def collision_periods(trace: Trace) -> np.ndarray:
    """:func:`collision_periods_at` of the trace, against ``safety_radius_m``."""
    return collision_periods_at(trace.states[:, :, :2], trace.scenario.safety.safety_radius_m)


def obstacle_periods(trace: Trace) -> np.ndarray:
    """:func:`obstacle_periods_at` of the trace and its scenario's obstacles."""
    return obstacle_periods_at(trace.states[:, :, :2], trace.scenario.safety.obstacles)


def separation_over_time(trace: Trace) -> np.ndarray:
    """``(T + 1,)`` the smallest distance between two UAVs at each instant, m."""
    return separation_at(trace.states[:, :, :2])


def plans_sent_at(solved: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """``(T,)`` plans sent at each instant: one per listener of each new plan."""
    return np.sum(solved[:, None, :] & neighbours, axis=(1, 2))


class Per(enum.Enum):
    """What one declared metric has a value for."""

    RUN = "run"
    """One value: the column is the field's name."""
    PAIR = "pair"
    """One value per named UAV pair (:func:`pair_names`): ``FIELD_d12``, ``FIELD_d23``, ..."""
    UAV = "uav"
    """One value per UAV: ``FIELD_uav1``, ``FIELD_uav2``, ..."""
    CONDITION = "condition"
    """One value per trigger condition: ``FIELD_distance``, ``FIELD_tracking``, ..."""
    SOLVE = "solve"
    """A list with one value per solve, in one column named as the field."""


class Better(enum.Enum):
    """Which values of a metric are the better ones."""

    LOWER = "lower"
    """Errors, costs, times, counts of solves and faults: the lowest value is the best."""
    HIGHER = "higher"
    """The lowest value is the worst (the smallest separation of two UAVs)."""
    NEITHER = "neither"
    """A description of the run that ranks nothing (which trigger condition held)."""


def metric(
    doc: str,
    unit: str,
    *,
    per: Per = Per.RUN,
    timing: bool = False,
    label: str | None = None,
    better: Better = Better.LOWER,
    log_scale: bool = False,
    headline: int | None = None,
) -> Any:
    """Declare a field of :class:`Metrics`.

    ``doc``: what it measures; ``unit``: its unit; ``per``: its layout (:class:`Per`);
    ``timing``: a wall-clock time (differs between two runs of the same thing).
    How it is shown: ``label`` is its axis label, unit included (without one, the column's
    name and ``unit``); ``better``: which values are better (:class:`Better`);
    ``log_scale``: its values may spread over orders of magnitude, so a figure draws a log
    axis when they do; ``headline``: its place (1 first) among the headline metrics, which
    the report shows on the terminal and plots, None when it is not one.
    """
    return dataclasses.field(
        metadata={
            "doc": doc,
            "unit": unit,
            "per": per,
            "timing": timing,
            "label": label,
            "better": better,
            "log_scale": log_scale,
            "headline": headline,
        }
    )


@dataclass(frozen=True)
class Metrics:
    """The metrics of one closed-loop run. Errors are taken after the settle time."""

    tracking_error_max_m: float = metric(
        "largest distance of the formation centre from the reference after the settle time",
        "m",
        label="tracking error max after the settle time (m)",
        headline=2,
    )
    tracking_error_rms_m: float = metric(
        "root mean square of that distance after the settle time",
        "m",
        label="tracking error RMS after the settle time (m)",
        headline=3,
    )
    distance_error_max_m: dict[str, float] = metric(
        "largest difference between a UAV pair's actual and desired distance after the settle time",
        "m",
        per=Per.PAIR,
    )
    distance_error_max_m_max: float = metric(
        "the largest distance error of the communication graph's pairs after the settle time "
        "(every pair on the complete graph, so on a partial graph it may be below a named "
        "pair's distance_error_max_m)",
        "m",
        label="largest distance error after the settle time (m)",
        headline=4,
    )
    solves: tuple[int, ...] = metric(
        "solves of a UAV over the run (one per instant without the trigger)", "solves", per=Per.UAV
    )
    solves_total: int = metric(
        "solves of all UAVs over the run",
        "solves",
        label="solves per run, all UAVs",
        headline=8,
    )
    trigger: dict[str, int] = metric(
        "solves at which a trigger condition held (several may hold at one solve; the first "
        "solve of every UAV counts as expiry)",
        "solves",
        per=Per.CONDITION,
        better=Better.NEITHER,
    )
    closed_loop_cost: float = metric(
        "eq. (11) summed over the UAVs and integrated along the flown trajectory from t = 0",
        "cost",
        label="closed-loop cost from t = 0, eq. (11) summed (m² s)",
        log_scale=True,
    )
    transient_cost: float = metric(
        "the part of closed_loop_cost before the settle time (the start-up)",
        "cost",
        label="transient cost, eq. (11) before the settle time (m² s)",
        log_scale=True,
        headline=5,
    )
    steady_state_cost: float = metric(
        "the part of closed_loop_cost from the settle time on (the steady state)",
        "cost",
        label="steady-state cost, eq. (11) after the settle time (m² s)",
        log_scale=True,
        headline=1,
    )
    settling_time_s: float = metric(
        "first time from which every pair's distance error stays within "
        "settling_distance_band of its desired distance and the tracking error within "
        "settling_tracking_band_m to the end; NaN if the end is outside",
        "s",
        label="settling time (s)",
        headline=6,
    )
    tracking_error_max_settled_m: float = metric(
        "largest distance of the formation centre from the reference from the run's own "
        "settling time on (settling_time_s, not the settle time); NaN if it does not settle",
        "m",
    )
    distance_error_max_settled_m: dict[str, float] = metric(
        "largest difference between a UAV pair's actual and desired distance from the run's own "
        "settling time on; NaN if it does not settle",
        "m",
        per=Per.PAIR,
    )
    distance_error_rms_m: float = metric(
        "root mean square of the distance errors of the communication graph's pairs after the "
        "settle time (every pair on the complete graph)",
        "m",
        label="distance error RMS, graph pairs (m)",
    )
    min_separation_m: float = metric(
        "smallest distance between two UAVs at the update instants",
        "m",
        label="smallest separation of two UAVs (m)",
        better=Better.HIGHER,
        headline=7,
    )
    collisions: int = metric(
        "times a UAV pair came closer than safety_radius_m (straight lines between instants; "
        "a stay of several periods counts once)",
        "events",
        label="collisions per run (pairs within the safety radius)",
    )
    collision_time_s: float = metric(
        "time UAV pairs spent closer than safety_radius_m, summed over the pairs (whole periods)",
        "s",
        label="time pairs spent within the safety radius (s)",
    )
    obstacle_intrusions: int = metric(
        "times a UAV entered an obstacle's radius (straight lines between instants)",
        "events",
        label="obstacle intrusions per run",
    )
    obstacle_time_s: float = metric(
        "time UAVs spent inside obstacles, summed over the UAVs (whole periods)",
        "s",
        label="time UAVs spent inside obstacles (s)",
    )
    plans_sent: int = metric("plans sent over the links (one per listener of a new plan)", "plans")
    plans_lost: int = metric("plans the links lost", "plans")
    plans_late: int = metric(
        "plans that arrived later than the instant after they were made", "plans"
    )
    control_effort: tuple[float, ...] = metric(
        "integral of (a / a_max)^2 + (omega / omega_max)^2 over the run, bounds' largest "
        "magnitudes as the scales",
        "s",
        per=Per.UAV,
    )
    solves_at_bound_share: float = metric(
        "share of solves whose published plan has a control at one of its bounds", "fraction"
    )
    nfev_total: int = metric(
        "cost evaluations of all solves",
        "evaluations",
        label="objective evaluations per run",
        log_scale=True,
        headline=10,
    )
    solve_failures: int = metric(
        "solves whose optimiser reported failure (the UAV kept its shifted plan)", "solves"
    )
    deadline_misses: int = metric(
        "solves whose wall time (problem build and optimiser) passed the budget's deadline; "
        "0 without a deadline",
        "solves",
        timing=True,
    )
    solve_time_median_s: float = metric(
        "median wall time of a solve",
        "s",
        timing=True,
        label="median solve time (s)",
        log_scale=True,
        headline=9,
    )
    solve_time_p95_s: float = metric("95th percentile of a solve's wall time", "s", timing=True)
    solve_time_max_s: float = metric("longest solve", "s", timing=True)
    solve_times_s: tuple[float, ...] = metric(
        "wall time of every solve, in solve order", "s", per=Per.SOLVE, timing=True
    )
    wall_time_s: float = metric("wall time of the closed loop", "s", timing=True)

    def columns(self) -> dict[str, Any]:
        """Every value under its column name, in declaration order."""
        out: dict[str, Any] = {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            per = field.metadata["per"]
            if per in (Per.PAIR, Per.CONDITION):
                out.update({f"{field.name}_{item}": v for item, v in value.items()})
            elif per is Per.UAV:
                out.update({f"{field.name}_uav{k}": v for k, v in enumerate(value, start=1)})
            else:
                out[field.name] = list(value) if per is Per.SOLVE else value
        return out


@dataclass(frozen=True)
class MetricInfo:
    """One declared metric, for documentation and for telling metric columns apart."""

    name: str
    doc: str
    unit: str
    per: Per
    timing: bool
    label: str | None
    better: Better
    log_scale: bool
    headline: int | None

    def label_of(self, column: str) -> str:
        """Axis label of one of its columns: the declared label of the metric's own column,
        else the column's name and the unit (``distance_error_max_m_d12 (m)``)."""
        if column == self.name and self.label is not None:
            return self.label
        return f"{column} ({self.unit})"

    def owns(self, column: str) -> bool:
        """Whether ``column`` holds a value of this metric."""
        if self.per in (Per.RUN, Per.SOLVE):
            return column == self.name
        stem = f"{self.name}_uav" if self.per is Per.UAV else f"{self.name}_"
        return column.startswith(stem) and column != self.name and not _declared(column)


def metric_infos() -> Iterator[MetricInfo]:
    """Every declared metric, in declaration order."""
    for field in dataclasses.fields(Metrics):
        yield MetricInfo(field.name, **field.metadata)


def _declared(column: str) -> bool:
    return column in {f.name for f in dataclasses.fields(Metrics)}


def metric_of(column: str) -> MetricInfo | None:
    """The declared metric a column holds a value of, or None if it holds none."""
    for info in metric_infos():
        if info.owns(column):
            return info
    return None


def column_label(column: str) -> str:
    """Axis label of a column: :meth:`MetricInfo.label_of` for a metric's column, else the
    column's name."""
    info = metric_of(column)
    return info.label_of(column) if info is not None else column


def log_scale(column: str) -> bool:
    """Whether a column holds a metric declared with ``log_scale``."""
    info = metric_of(column)
    return info is not None and info.log_scale


def headline_metrics() -> tuple[str, ...]:
    """The headline metrics, in their declared places: printed on the terminal and plotted
    by the report, which holds every metric in its files."""
    ranked = sorted((i.headline, i.name) for i in metric_infos() if i.headline is not None)
    return tuple(name for _, name in ranked)


def compute_metrics(trace: Trace) -> Metrics:
    """The metrics of a run."""
    scenario = trace.scenario
    settled = trace.times >= scenario.evaluation.settle_time_s - 1e-9
    if not np.any(settled):
        raise ValueError(
            f"settle_time_s={scenario.evaluation.settle_time_s} is after the end of the run "
            f"({trace.times[-1]:.2f} s)"
        )
    tracking_all, pair_errors = tracking_error(trace), pair_distance_errors(trace)
    errors, pairs = named_pair_series(pair_errors), graph_pairs(trace)
    settled_pair_errors = pair_errors[settled][pairs[settled]]
    tracking = tracking_all[settled]
    collisions, intrusions = collision_periods(trace), obstacle_periods(trace)
    solve_times = trace.solve_time_s[trace.solved]
    distances = {name: float(err[settled].max()) for name, err in errors.items()}
    solves = tuple(int(n) for n in trace.solved.sum(axis=0))
    by_condition = trace.reasons[trace.solved].sum(axis=0)
    steady = trace.times[1:] >= scenario.evaluation.settle_time_s - 1e-9
    settled_from = settling_index(trace, tracking_all, pair_errors)

    return Metrics(
        tracking_error_max_m=float(tracking.max()),
        tracking_error_rms_m=float(np.sqrt(np.mean(tracking**2))),
        distance_error_max_m=distances,
        distance_error_max_m_max=float(settled_pair_errors.max())
        if settled_pair_errors.size
        else math.nan,
        solves=solves,
        solves_total=int(sum(solves)),
        trigger={name: int(by_condition[k]) for k, name in enumerate(TRIGGER_CONDITIONS)},
        closed_loop_cost=closed_loop_cost(trace),
        transient_cost=closed_loop_cost(trace, ~steady),
        steady_state_cost=closed_loop_cost(trace, steady),
        settling_time_s=math.nan if settled_from is None else float(trace.times[settled_from]),
        tracking_error_max_settled_m=math.nan
        if settled_from is None
        else float(tracking_all[settled_from:].max()),
        distance_error_max_settled_m={
            name: math.nan if settled_from is None else float(err[settled_from:].max())
            for name, err in errors.items()
        },
        distance_error_rms_m=float(np.sqrt(np.mean(settled_pair_errors**2)))
        if settled_pair_errors.size
        else math.nan,
        min_separation_m=min_separation(trace),
        collisions=_events(collisions),
        collision_time_s=float(collisions.sum() * scenario.timing.period_s),
        obstacle_intrusions=_events(intrusions),
        obstacle_time_s=float(intrusions.sum() * scenario.timing.period_s),
        plans_sent=int(plans_sent_at(trace.solved, listened(trace)).sum()),
        plans_lost=int(trace.plans_lost.sum()),
        plans_late=int(trace.plans_late.sum()),
        control_effort=tuple(float(e) for e in control_effort(trace)),
        solves_at_bound_share=float(trace.plan_at_bound[trace.solved].mean()),
        nfev_total=int(trace.nfev.sum()),
        solve_failures=int(trace.solve_failed.sum()),
        deadline_misses=0
        if trace.deadline_s is None
        else int(np.sum(solve_times > trace.deadline_s)),
        solve_time_median_s=float(np.median(solve_times)),
        solve_time_p95_s=float(np.percentile(solve_times, 95)),
        solve_time_max_s=float(solve_times.max()),
        solve_times_s=tuple(float(t) for t in solve_times),
        wall_time_s=float(trace.wall_time_s),
    )
