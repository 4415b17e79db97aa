"""The columns of a run's trace table (``trace.parquet``), declared once.

The trace is stored long: one row per instant (0 to ``n_steps``) and UAV. Each
:class:`TraceColumn` says what a column holds (its name, type, unit and meaning), which rows
it fills (:class:`Span`) and where its values come from (the run's labels or its
:class:`~formation_bench.mpc.loop.Trace`). The table is written from :data:`TRACE_COLUMNS`
(:func:`formation_bench.pipeline.outputs.trace_table`), checked against it when read
(:func:`check_schema`), and documented from it (:func:`columns_table`, shown verbatim in
``docs/explanation/benchmarks.md``).
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from formation_bench.mpc.loop import Trace
from formation_bench.mpc.trigger import TRIGGER_CONDITIONS

if TYPE_CHECKING:
    import pyarrow as pa


class Kind(enum.Enum):
    """The type of a column's values, as Parquet stores it (and pandas writes it)."""

    TEXT = "large_string"
    BOOL = "bool"
    INT = "int64"
    FLOAT = "double"
    SEED = "seed"
    """int64, or the decimal text of a seed of 2^63 or more (a 128-bit sweep entropy)."""

    @property
    def stored_as(self) -> tuple[str, ...]:
        """The Arrow types a column of this kind may have."""
        return (Kind.INT.value, Kind.TEXT.value) if self is Kind.SEED else (self.value,)

    @property
    def dtype(self) -> np.dtype:
        """The NumPy type of a column of numbers or flags."""
        return np.dtype({Kind.BOOL: np.bool_, Kind.INT: np.int64, Kind.FLOAT: np.float64}[self])


class Span(enum.Enum):
    """Which rows of the long table a column's source fills."""

    RUN = "run"
    """One value of the run, on every row."""
    INSTANT = "instant"
    """A value per instant 0 .. T (``(T + 1, N)``, or broadcast to it)."""
    PERIOD = "period"
    """A value per period 0 .. T - 1 (``(T, N)``): the last instant, which holds the final
    state only, gets :attr:`TraceColumn.fill`."""


@dataclass(frozen=True)
class RunLabels:
    """What the run-level columns say: the run as its record labels it."""

    optimizer: str
    """The optimiser configuration's label."""
    scenario: str
    """The scenario configuration's label."""
    trigger: bool
    budget: str
    """``default`` or the per-solve budget, e.g. ``max_evaluations=1200``."""
    seed: int
    """The run's seed as the user gave it."""


Source = Callable[[Trace, RunLabels], Any]


@dataclass(frozen=True)
class TraceColumn:
    """One column of the trace table."""

    name: str
    kind: Kind
    unit: str
    doc: str
    """Its meaning (Markdown: the documentation shows it verbatim)."""
    span: Span
    source: Source
    """Its values: a scalar for :attr:`Span.RUN`, else an array (see :class:`Span`)."""

    @property
    def fill(self) -> Any:
        """The value at the last instant of a :attr:`Span.PERIOD` column: none to show."""
        return {Kind.FLOAT: np.nan, Kind.INT: 0, Kind.BOOL: False}[self.kind]

    def values(self, trace: Trace, labels: RunLabels) -> Any:
        """The run's value (:attr:`Span.RUN`) or ``(T + 1) * N`` values, instant-major."""
        value = self.source(trace, labels)
        if self.span is Span.RUN:
            return value
        n_instants, n_uav = trace.states.shape[:2]
        value = np.asarray(value, dtype=self.kind.dtype)
        if self.span is Span.PERIOD:
            last = np.full((1, *value.shape[1:]), self.fill, dtype=value.dtype)
            value = np.concatenate([value, last])
        return np.broadcast_to(value, (n_instants, n_uav)).reshape(-1)


def _state(k: int) -> Source:
    return lambda trace, _: trace.states[:, :, k]


def _control(k: int) -> Source:
    return lambda trace, _: trace.controls[:, :, k]


def _reason(k: int) -> Source:
    return lambda trace, _: trace.reasons[:, :, k]


def _desired(k: int) -> Source:
    return lambda trace, _: trace.reference[:, None, k] + trace.desired_offsets[:, :, k]


def _wind(k: int) -> Source:
    return lambda trace, _: trace.wind[:, :, k]


TRIGGER_DOCS = {
    "distance": (
        "condition of eq. (15) held: a neighbour's relative-position error reached `eps_p`"
    ),
    "tracking": (
        "condition of eq. (16) held: the estimated formation centre was `eps_o` or more from "
        "the reference"
    ),
    "control": (
        "condition of eq. (17) held: a planned control component reached `eta` times its bound"
    ),
    "expiry": (
        "condition of eq. (18) held: the published plan ran out (at instant 0 every UAV, "
        "having no plan)"
    ),
}
"""What each trigger condition's column says, by condition (``TRIGGER_CONDITIONS``)."""

_POSITION = "position at the instant"
_REFERENCE = "reference position of the formation centre"
_DESIRED = "desired position of the UAV: reference plus its formation offset"
_WIND = "wind that moved the UAV from this instant to the next, NaN at the last instant"

TRACE_COLUMNS: tuple[TraceColumn, ...] = (
    TraceColumn(
        "optimizer", Kind.TEXT, "",
        "optimiser label (the name, with `[field=value,...]` for overrides)",
        Span.RUN, lambda _, run: run.optimizer,
    ),
    TraceColumn(
        "scenario", Kind.TEXT, "",
        "scenario label (the name, with `[field=value,...]` for overrides)",
        Span.RUN, lambda _, run: run.scenario,
    ),
    TraceColumn(
        "trigger", Kind.BOOL, "", "whether the event trigger was on",
        Span.RUN, lambda _, run: run.trigger,
    ),
    TraceColumn(
        "budget", Kind.TEXT, "",
        "`default` or the per-solve budget, e.g. `max_evaluations=1200`",
        Span.RUN, lambda _, run: run.budget,
    ),
    TraceColumn(
        "seed", Kind.SEED, "",
        "run seed; a seed of 2^63 or more is stored as its decimal string",
        Span.RUN, lambda _, run: run.seed,
    ),
    TraceColumn(
        "step", Kind.INT, "", "instant index c, 0 to `n_steps`",
        Span.INSTANT, lambda trace, _: np.arange(trace.states.shape[0])[:, None],
    ),
    TraceColumn(
        "time_s", Kind.FLOAT, "s", "time of the instant, c T",
        Span.INSTANT, lambda trace, _: trace.times[:, None],
    ),
    TraceColumn(
        "uav", Kind.INT, "", "UAV number, from 1",
        Span.INSTANT, lambda trace, _: np.arange(1, trace.states.shape[1] + 1),
    ),
    TraceColumn("x_m", Kind.FLOAT, "m", _POSITION, Span.INSTANT, _state(0)),
    TraceColumn("y_m", Kind.FLOAT, "m", _POSITION, Span.INSTANT, _state(1)),
    TraceColumn(
        "heading_rad", Kind.FLOAT, "rad", "heading at the instant", Span.INSTANT, _state(2)
    ),
    TraceColumn("speed_m_s", Kind.FLOAT, "m/s", "speed at the instant", Span.INSTANT, _state(3)),
    TraceColumn(
        "accel_m_s2", Kind.FLOAT, "m/s^2", "acceleration applied from this instant to the next",
        Span.PERIOD, _control(0),
    ),
    TraceColumn(
        "turn_rate_rad_s", Kind.FLOAT, "rad/s", "turn rate applied from this instant to the next",
        Span.PERIOD, _control(1),
    ),
    TraceColumn(
        "solved", Kind.BOOL, "", "whether the UAV solved its MPC problem at this instant",
        Span.PERIOD, lambda trace, _: trace.solved,
    ),
    *(
        TraceColumn(f"trigger_{name}", Kind.BOOL, "", TRIGGER_DOCS[name], Span.PERIOD, _reason(k))
        for k, name in enumerate(TRIGGER_CONDITIONS)
    ),
    TraceColumn(
        "solve_time_s", Kind.FLOAT, "s",
        "wall time of the solve (problem build and optimiser), NaN without a solve",
        Span.PERIOD, lambda trace, _: trace.solve_time_s,
    ),
    TraceColumn(
        "nfev", Kind.INT, "evaluations", "cost evaluations of the solve, 0 without a solve",
        Span.PERIOD, lambda trace, _: trace.nfev,
    ),
    TraceColumn(
        "solve_cost", Kind.FLOAT, "",
        "cost J_i of eq. (14) at the solution found, NaN without a solve",
        Span.PERIOD, lambda trace, _: trace.solve_cost,
    ),
    TraceColumn(
        "solve_failed", Kind.BOOL, "",
        "the optimiser reported failure; the UAV then applied its shifted previous plan",
        Span.PERIOD, lambda trace, _: trace.solve_failed,
    ),
    TraceColumn(
        "plan_at_bound", Kind.BOOL, "",
        "the plan the solve published has a control within 10^-6 of its bounds' range from a "
        "bound",
        Span.PERIOD, lambda trace, _: trace.plan_at_bound,
    ),
    TraceColumn(
        "ref_x_m", Kind.FLOAT, "m", _REFERENCE,
        Span.INSTANT, lambda trace, _: trace.reference[:, None, 0],
    ),
    TraceColumn(
        "ref_y_m", Kind.FLOAT, "m", _REFERENCE,
        Span.INSTANT, lambda trace, _: trace.reference[:, None, 1],
    ),
    TraceColumn(
        "ref_heading_rad", Kind.FLOAT, "rad", "reference heading",
        Span.INSTANT, lambda trace, _: trace.reference_heading[:, None],
    ),
    TraceColumn("desired_x_m", Kind.FLOAT, "m", _DESIRED, Span.INSTANT, _desired(0)),
    TraceColumn("desired_y_m", Kind.FLOAT, "m", _DESIRED, Span.INSTANT, _desired(1)),
    TraceColumn(
        "neighbours", Kind.INT, "UAVs",
        "UAVs this UAV listened to at the instant (its communication graph's neighbours), 0 at "
        "the last instant",
        Span.PERIOD, lambda trace, _: trace.neighbours.sum(axis=2),
    ),
    TraceColumn(
        "plans_lost", Kind.INT, "plans",
        "plans sent to this UAV at the instant that its links lost",
        Span.PERIOD, lambda trace, _: trace.plans_lost,
    ),
    TraceColumn(
        "plans_late", Kind.INT, "plans",
        "plans this UAV received at the instant later than the instant after they were sent",
        Span.PERIOD, lambda trace, _: trace.plans_late,
    ),
    TraceColumn("wind_x_m_s", Kind.FLOAT, "m/s", _WIND, Span.PERIOD, _wind(0)),
    TraceColumn("wind_y_m_s", Kind.FLOAT, "m/s", _WIND, Span.PERIOD, _wind(1)),
)  # fmt: skip
"""Every column of the trace table, in the order it is written."""

TRACE_COLUMN_NAMES = tuple(column.name for column in TRACE_COLUMNS)


class TraceFormatError(ValueError):
    """A trace table whose columns are not the declared ones."""


def check_schema(schema: pa.Schema) -> None:
    """Raise :class:`TraceFormatError` unless ``schema`` has the declared columns, in their
    order and of their types (a seed of either of its two types)."""
    names = list(schema.names)
    if names != list(TRACE_COLUMN_NAMES):
        missing = [n for n in TRACE_COLUMN_NAMES if n not in names]
        extra = [n for n in names if n not in TRACE_COLUMN_NAMES]
        raise TraceFormatError(
            "not a trace table of this version: "
            + "; ".join(
                part
                for part in (
                    f"missing {', '.join(missing)}" if missing else "",
                    f"unexpected {', '.join(extra)}" if extra else "",
                    "columns out of order" if not (missing or extra) else "",
                )
                if part
            )
        )
    for column in TRACE_COLUMNS:
        stored = str(schema.field(column.name).type)
        if stored not in column.kind.stored_as:
            raise TraceFormatError(
                f"trace column {column.name!r} holds {stored}, declared "
                + " or ".join(column.kind.stored_as)
            )


def columns_table() -> str:
    """The columns as a Markdown table (the documentation shows it verbatim); neighbouring
    columns of one unit and meaning (``x_m``, ``y_m``) share a line."""
    lines = ["| column | unit | meaning |", "|---|---|---|"]
    shared: list[list[TraceColumn]] = []
    for column in TRACE_COLUMNS:
        previous = shared[-1][-1] if shared else None
        if previous is not None and (previous.unit, previous.doc) == (column.unit, column.doc):
            shared[-1].append(column)
        else:
            shared.append([column])
    for group in shared:
        names = ", ".join(f"`{c.name}`" for c in group)
        unit = f" {group[0].unit}" if group[0].unit else ""
        lines.append(f"| {names} |{unit} | {group[0].doc} |")
    return "\n".join(lines)
