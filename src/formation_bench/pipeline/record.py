"""What a finished run leaves: its :class:`RunRecord`.

A record is the run's specification, its :class:`~formation_bench.mpc.metrics.Metrics`, the
scenario's length, the version and commit of the code that ran it, and where and how long it
ran. Every command writes records in the same shape: ``run`` and ``reproduce`` as a JSON list
in ``metrics.json`` (:meth:`RunRecord.to_json`), a sweep as one Parquet row per run
(:meth:`RunRecord.row`). The columns are declared here and in
:class:`~formation_bench.mpc.metrics.Metrics`, once: :func:`is_metric_column` and
:func:`is_timing_column` read those declarations, so no other module keeps a list of them.
"""

from __future__ import annotations

import dataclasses
import json
import os
import socket
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from types import NoneType
from typing import Any

from formation_bench.mpc.metrics import MetricInfo, Metrics, Per, metric_infos, metric_of
from formation_bench.pipeline.spec import RunSpec

RECORD_FORMAT = 4
"""Bumped when the columns change; a stored run of another format is redone. 4: the CPU model
and the casadi, osqp, cvxpy and ioh versions."""


def column(doc: str, *, timing: bool = False) -> Any:
    """Declare a record column that is not a metric."""
    return dataclasses.field(metadata={"doc": doc, "timing": timing})


@dataclass(frozen=True)
class RunDescription:
    """The columns that say which run a record is (from its :class:`RunSpec`)."""

    record_format: int = column("layout version of the record's columns")
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
    command: str = column("the formation-bench run command that repeats the run exactly")
    steps: int = column("update instants simulated (n_steps)")
    settle_time_s: float = column("errors are taken from this time on, s")

    @classmethod
    def of(cls, spec: RunSpec, steps: int, settle_time_s: float) -> RunDescription:
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
            budget_max_evaluations=spec.budget_max_evaluations,
            budget_max_iterations=spec.budget_max_iterations,
            budget_deadline_ms=spec.budget_deadline_ms,
            seed=spec.seed,
            seed_entropy=str(spec.entropy),
            config_hash=spec.config_hash,
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

    @classmethod
    def here(cls, run_time_s: float) -> Provenance:
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
        """The row as JSON data: the overrides as objects rather than JSON text."""
        row = self.row()
        for name in ("optimizer_overrides", "scenario_overrides"):
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
    for part in (RunDescription, Provenance):
        hints = typing.get_type_hints(part)
        if name in hints:
            kinds = [t for t in typing.get_args(hints[name]) or (hints[name],) if t is not NoneType]
            return kinds[0]
    return float


def is_metric_column(name: str) -> bool:
    """Whether a record column holds a declared metric."""
    return metric_of(name) is not None


def is_timing_column(name: str) -> bool:
    """Whether a column measures time or place, and so differs between two runs of the same
    thing (declared ``timing`` in the record or in :class:`Metrics`)."""
    if name in _TIMING:
        return True
    info = metric_of(name)
    return info is not None and info.timing
