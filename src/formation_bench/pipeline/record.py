"""What a finished run leaves: its :class:`RunRecord`.

A record is the run's specification, its :class:`~formation_bench.mpc.metrics.Metrics`, the
scenario's length, the version and commit of the code that ran it, and where and how long it
ran. Every command writes records in the same shape: ``run`` and ``reproduce`` as a JSON list
in ``metrics.json`` (:meth:`RunRecord.to_json`), a sweep as one Parquet row per run
(:meth:`RunRecord.row`). The columns are declared here and in
:class:`~formation_bench.mpc.metrics.Metrics`, once: :func:`is_metric_column` and
:func:`is_timing_column` read those declarations, so no other module keeps a list of them.

A record describes itself: besides the registered names and overrides it holds every setting
of the resolved scenario and optimiser (``scenario_config``, ``optimizer_config``), so
:func:`stored_scenario` and :func:`stored_optimizer` rebuild what ran without today's
registry or defaults. A row stored before those columns existed is rebuilt from today's
registry only when that reproduces its ``config_hash`` exactly.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import socket
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from types import NoneType
from typing import TYPE_CHECKING, Any

from formation_bench.mpc.metrics import MetricInfo, Metrics, Per, metric_infos, metric_of
from formation_bench.mpc.scenario import Scenario, get_scenario
from formation_bench.optimizers import Budget, Optimizer, get_optimizer
from formation_bench.pipeline.spec import (
    RunSpec,
    budget_deadline_ms,
    budget_limits,
    canonical_json,
    config_of,
    deadline_s_of_ms,
    from_config,
    from_json_value,
    resolved_config_hash,
    solve_budget,
)

if TYPE_CHECKING:  # the run pipeline itself writes no data frames
    import pandas as pd

RECORD_FORMAT = 4
"""What the record's columns mean, as a number. Bumped only when a column changes meaning: a
stored run of another meaning is redone. A column added without changing the meaning of the
others does not bump it: a row stored before the column existed reads it as empty (missing).
4 added columns only (the CPU model; the casadi, osqp, cvxpy and ioh versions) to 3, whose
errors are taken from each run's own settling time."""
SAME_MEANING_FORMATS = frozenset({3, RECORD_FORMAT})
"""Record formats whose columns mean what those of :data:`RECORD_FORMAT` mean (a row of one
lacks only columns added since): a stored run of one of them is kept, not redone."""
JSON_COLUMNS = ("optimizer_overrides", "scenario_overrides", "scenario_config", "optimizer_config")
"""Columns holding canonical JSON text (objects in a ``metrics.json`` record)."""


def column(doc: str, *, timing: bool = False) -> Any:
    """Declare a record column that is not a metric."""
    return dataclasses.field(metadata={"doc": doc, "timing": timing})


@dataclass(frozen=True)
class RunDescription:
    """The columns that say which run a record is (from its :class:`RunSpec`)."""

    record_format: int = column(
        "what the record's columns mean, as a number (changes only when a column changes "
        "meaning, not when one is added)"
    )
    run_key: str = column("24 hex digits of the SHA-256 of the run's identity")
    suite: str | None = column("suite the run came from; empty for a run of its own")
    optimizer: str = column("the optimiser configuration's label")
    optimizer_name: str = column("registered optimiser name")
    optimizer_overrides: str = column("fields changed from the registered optimiser (JSON)")
    scenario: str = column("the scenario configuration's label")
    scenario_name: str = column("registered scenario name")
    scenario_overrides: str = column("fields changed from the registered scenario (JSON)")
    trigger: bool = column("event trigger on, or a solve at every instant")
    budget: str = column("per-solve budget: 'default' or e.g. 'max_evaluations=1200'")
    budget_max_evaluations: int | None = column("per-solve evaluation limit, if set")
    budget_max_iterations: int | None = column("per-solve iteration limit, if set")
    budget_deadline_ms: float | None = column(
        "per-solve wall-clock deadline, ms, if set (the run then depends on the machine's speed)"
    )
    seed: int = column("the run's seed as the user gave it (0, 1, ... in a suite)")
    seed_entropy: str = column("entropy of the run's SeedSequence (decimal; up to 128 bits)")
    config_hash: str = column("SHA-256 of the fully resolved optimiser, scenario and budget")
    scenario_config: str | None = column(
        "every setting of the resolved scenario, under its registered name (canonical JSON, "
        "groups of settings nested); empty in a row stored before it was recorded"
    )
    optimizer_config: str | None = column(
        "every setting of the resolved optimiser (canonical JSON); empty in a row stored "
        "before it was recorded"
    )
    command: str = column("the formation-bench run command that repeats the run exactly")
    steps: int = column("update instants simulated (n_steps)")
    settle_time_s: float = column("errors are taken from this time on, s")

    @classmethod
    def of(cls, spec: RunSpec, steps: int, settle_time_s: float) -> RunDescription:
        scenario, optimizer = spec.configured()
        max_evaluations, max_iterations = budget_limits(spec.budget)
        return cls(
            record_format=RECORD_FORMAT,
            run_key=spec.key,
            suite=spec.suite,
            optimizer=spec.optimizer_label,
            optimizer_name=spec.optimizer_name,
            optimizer_overrides=spec.optimizer_overrides,
            scenario=spec.scenario_label,
            scenario_name=spec.scenario_name,
            scenario_overrides=spec.scenario_overrides,
            trigger=spec.trigger,
            budget=spec.budget_label,
            budget_max_evaluations=max_evaluations,
            budget_max_iterations=max_iterations,
            budget_deadline_ms=budget_deadline_ms(spec.budget),
            seed=spec.seed,
            seed_entropy=str(spec.entropy),
            config_hash=spec.config_hash,
            scenario_config=canonical_json(config_of(scenario)),
            optimizer_config=canonical_json(config_of(optimizer)),
            command=spec.run_command(out=f"repeat-{spec.key}"),
            steps=steps,
            settle_time_s=settle_time_s,
        )


@dataclass(frozen=True)
class Provenance:
    """The columns that say what code ran the run, where and for how long."""

    version: str = column("formation-bench version that ran it")
    commit: str | None = column("git commit of the installed code (None if unknown)")
    run_time_s: float = column(
        "wall time of the whole run: build, kernels, closed loop, metrics", timing=True
    )
    finished_at: str = column("UTC time the run finished (ISO 8601)", timing=True)
    worker_host: str = column("host that ran it", timing=True)
    worker_pid: int = column("process that ran it", timing=True)
    cpu_model: str | None = column("processor model of the host (None if unknown)", timing=True)
    casadi_version: str | None = column("casadi version, with the IPOPT it ships", timing=True)
    osqp_version: str | None = column("osqp version", timing=True)
    cvxpy_version: str | None = column("cvxpy version (None: not installed)", timing=True)
    ioh_version: str | None = column("ioh version (None: not installed)", timing=True)
    cost_kernel: str | None = column(
        "cost kernel the compiled solve loops called, c or numba (the same numbers, not the "
        "same speed; None: stored before it was recorded)",
        timing=True,
    )

    @classmethod
    def here(cls, run_time_s: float) -> Provenance:
        from formation_bench.mpc.native_cost import cost_function
        from formation_bench.pipeline.provenance import cpu_model, git_info, now, package_versions

        info = git_info()
        versions = package_versions()
        return cls(
            version=info["version"],
            commit=info["commit"],
            run_time_s=run_time_s,
            finished_at=now(),
            worker_host=socket.gethostname(),
            worker_pid=os.getpid(),
            cpu_model=cpu_model(),
            casadi_version=versions["casadi"],
            osqp_version=versions["osqp"],
            cvxpy_version=versions["cvxpy"],
            ioh_version=versions["ioh"],
            cost_kernel=cost_function().kernel.value,
        )


@dataclass(frozen=True)
class RunRecord:
    """A finished run: which run it was, what it measured, what ran it."""

    description: RunDescription
    metrics: Metrics
    provenance: Provenance

    def row(self) -> dict[str, Any]:
        """Every column, as one row of the results store."""
        return {
            **dataclasses.asdict(self.description),
            **self.metrics.columns(),
            **dataclasses.asdict(self.provenance),
        }

    def to_json(self) -> dict[str, Any]:
        """The row as JSON data: the overrides and configurations as objects rather than JSON
        text."""
        row = self.row()
        for name in JSON_COLUMNS:
            row[name] = json.loads(row[name])
        return row


def record_columns() -> Iterator[tuple[str, str, bool]]:
    """``(name, doc, timing)`` of every column that is not a metric, in row order."""
    for part in (RunDescription, Provenance):
        for field in dataclasses.fields(part):
            yield field.name, field.metadata["doc"], field.metadata["timing"]


_TIMING = frozenset(name for name, _, timing in record_columns() if timing)


def columns_table() -> str:
    """Every column of a record as a Markdown table (the documentation shows it verbatim)."""
    lines = ["| column | unit | timing | meaning |", "|---|---|---|---|"]
    for name, doc, timing in record_columns():
        if name == "version":  # the metrics come between the description and the provenance
            lines += [_metric_line(info) for info in metric_infos()]
        lines.append(f"| `{name}` | | {'yes' if timing else ''} | {doc} |")
    return "\n".join(lines)


_PATTERNS = {
    Per.RUN: "`{}`",
    Per.SOLVE: "`{}` (list)",
    Per.PAIR: "`{}_d12`, `{}_d23`, ... (per UAV pair)",
    Per.UAV: "`{}_uav1`, `{}_uav2`, ... (per UAV)",
    Per.CONDITION: "`{}_distance`, `_tracking`, `_control`, `_expiry`",
}


def _metric_line(info: MetricInfo) -> str:
    pattern = _PATTERNS[info.per].replace("{}", info.name)
    return f"| {pattern} | {info.unit} | {'yes' if info.timing else ''} | {info.doc} |"


def value_type(name: str) -> type:
    """The Python type of a column's values (``float`` for every metric but counts)."""
    return _value_types().get(name, float)


@functools.cache
def _value_types() -> dict[str, type]:
    # resolving the type hints takes longer than storing a run row: once per process
    types: dict[str, type] = {}
    for part in (RunDescription, Provenance):
        for column_name, hint in typing.get_type_hints(part).items():
            kinds = [t for t in typing.get_args(hint) or (hint,) if t is not NoneType]
            types.setdefault(column_name, kinds[0])
    return types


def is_metric_column(name: str) -> bool:
    """Whether a record column holds a declared metric."""
    return metric_of(name) is not None


@functools.cache
def duration_columns() -> tuple[str, ...]:
    """Columns that hold durations (seconds from a monotonic clock, so never below zero):
    the run's wall time and every timing metric in seconds, one value per run or per solve."""
    metrics = tuple(
        info.name
        for info in metric_infos()
        if info.timing and info.unit == "s" and info.per in (Per.RUN, Per.SOLVE)
    )
    return ("run_time_s", *metrics)


def is_timing_column(name: str) -> bool:
    """Whether a column measures time or place, and so differs between two runs of the same
    thing (declared ``timing`` in the record or in :class:`Metrics`)."""
    if name in _TIMING:
        return True
    info = metric_of(name)
    return info is not None and info.timing


# --- what a stored row ran ---------------------------------------------------------------------


def stored_budget(row: Mapping[str, Any]) -> Budget | None:
    """The per-solve budget a stored row asked for; None: the optimiser's own."""
    max_evaluations = _count(row.get("budget_max_evaluations"))
    max_iterations = _count(row.get("budget_max_iterations"))
    deadline_ms = row.get("budget_deadline_ms")
    deadline_s = None if _missing(deadline_ms) else deadline_s_of_ms(deadline_ms)
    if max_evaluations is None and max_iterations is None and deadline_s is None:
        return None
    return Budget(max_evaluations, max_iterations, deadline_s)


STORED_CONFIGURATION_COLUMNS = (
    "scenario_config",
    "optimizer_config",
    "scenario_name",
    "scenario_overrides",
    "optimizer_name",
    "optimizer_overrides",
    "config_hash",
    "budget_max_evaluations",
    "budget_max_iterations",
    "budget_deadline_ms",
)
"""The columns of a stored row that :func:`stored_configuration` reads."""


def stored_scenarios(rows: pd.DataFrame) -> list[Scenario | None]:
    """:func:`stored_scenario` of every row of ``rows`` (stored runs), each distinct stored
    configuration rebuilt once."""
    columns = [c for c in STORED_CONFIGURATION_COLUMNS if c in rows]
    # keys as text: a missing value (NaN) is then equal to itself
    keys = list(rows[columns].astype(str).itertuples(index=False, name=None))
    rebuilt: dict[tuple, Scenario | None] = {}
    for key, row in zip(keys, rows[columns].to_dict("records"), strict=True):
        if key not in rebuilt:
            rebuilt[key] = stored_scenario(row)
    return [rebuilt[key] for key in keys]


def stored_scenario(row: Mapping[str, Any]) -> Scenario | None:
    """The scenario a stored row ran (under its registered name), rebuilt from its
    ``scenario_config``; None if it cannot be rebuilt here (see :func:`stored_configuration`)."""
    config = _json(row.get("scenario_config"))
    if config is not None:
        return _rebuilt(Scenario, config)
    return stored_configuration(row)[0]


def stored_optimizer(row: Mapping[str, Any]) -> Optimizer | None:
    """The optimiser a stored row ran, rebuilt from its ``optimizer_config``; None if it
    cannot be rebuilt here (see :func:`stored_configuration`)."""
    return stored_configuration(row)[1]


def stored_configuration(row: Mapping[str, Any]) -> tuple[Scenario | None, Optimizer | None]:
    """The scenario and optimiser a stored row ran, each None where it cannot be rebuilt.

    A row holding its configuration is rebuilt from it alone (:func:`from_config`): no
    registry and no default of today enters, but for a setting added since (which keeps its
    default). The optimiser's class must be imported (a plugin's, by loading the plugin). A row
    stored before configurations were recorded is rebuilt from today's registry, by name and
    overrides, only when that gives exactly the configuration it ran: its ``config_hash``.
    """
    scenario_config = _json(row.get("scenario_config"))
    optimizer_config = _json(row.get("optimizer_config"))
    if scenario_config is None or optimizer_config is None:
        return _registry_configuration(row)
    scenario = _rebuilt(Scenario, scenario_config)
    optimizer_class = _optimizer_class(str(optimizer_config.get("class", "")))
    optimizer = None if optimizer_class is None else _rebuilt(optimizer_class, optimizer_config)
    return scenario, optimizer  # type: ignore[return-value]


def _registry_configuration(row: Mapping[str, Any]) -> tuple[Scenario | None, Optimizer | None]:
    try:
        scenario = get_scenario(
            str(row["scenario_name"]), **from_json_value(json.loads(row["scenario_overrides"]))
        )
        optimizer = get_optimizer(
            str(row["optimizer_name"]), **from_json_value(json.loads(row["optimizer_overrides"]))
        )
        budget = solve_budget(stored_budget(row), optimizer)
    except (KeyError, ValueError, TypeError):  # not registered here, or no longer valid
        return None, None
    if resolved_config_hash(scenario, optimizer, budget) != row.get("config_hash"):
        return None, None  # today's registry would read it with other settings than it ran
    return scenario, optimizer


def _rebuilt(cls: type, config: dict[str, Any]) -> Any:
    try:
        return from_config(cls, config)
    except (ValueError, TypeError, KeyError):  # a stored setting today's checks refuse
        return None


def _optimizer_class(qualname: str) -> type | None:
    """The one imported optimiser class of that name (None if none or several)."""
    found, pending = set(), [Optimizer]
    while pending:
        cls = pending.pop()
        pending.extend(cls.__subclasses__())
        if cls.__qualname__ == qualname and dataclasses.is_dataclass(cls):
            found.add(cls)
    return found.pop() if len(found) == 1 else None


def _missing(value: Any) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


def _count(value: Any) -> int | None:
    return None if _missing(value) else int(value)


def _json(value: Any) -> dict[str, Any] | None:
    if isinstance(value, str) and value:
        return json.loads(value)
    return value if isinstance(value, dict) else None
