"""What a closed-loop run is, as plain data: :class:`RunSpec`.

``run``, ``reproduce`` and every run of a ``sweep`` are described by a :class:`RunSpec`
(optimiser and its overrides, scenario and its overrides, trigger, seed, budget) and carried
out by :func:`formation_bench.benchmarks.pipeline.execute`. The canonical JSON helpers here
make equal configurations give equal text, so a run's identity, result file name and random
streams never depend on how the configuration was written.
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import json
import re
import shlex
from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.mpc.scenario import Scenario, get_scenario
from formation_bench.optimizers import Budget, Optimizer, get_optimizer

IDENTITY_VERSION = 1
"""Bumped if the identity's layout ever changes (it would re-key every run)."""


# --- canonical JSON of configuration values --------------------------------------------------


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON data (enums by value or lower-case name, tuples as lists)."""
    if isinstance(value, enum.Enum):
        return value.value if isinstance(value.value, str) else value.name.lower()
    if isinstance(value, bool | str) or value is None:
        return value
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value)
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return config_of(value)
    return re.sub(r" at 0x[0-9a-fA-F]+", "", repr(value))  # no memory addresses: hashes repeat


def canonical_json(data: Any) -> str:
    """Compact JSON with sorted keys: equal data gives equal text."""
    return json.dumps(jsonable(data), sort_keys=True, separators=(",", ":"), allow_nan=True)


def sha256_hex(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def config_of(obj: Any) -> dict[str, Any]:
    """Every field of a config dataclass as JSON data, with its class name."""
    fields = {f.name: jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    return {"class": type(obj).__qualname__, **fields}


def effective_overrides(default: Any, configured: Any) -> dict[str, Any]:
    """The fields of ``configured`` that differ from ``default`` (as JSON data).

    So ``population_size = 30`` on a registered optimiser whose population is
    already 30 is no override at all, and ``3`` equals ``3.0``.
    """
    changed = {}
    for f in dataclasses.fields(configured):
        new, old = jsonable(getattr(configured, f.name)), jsonable(getattr(default, f.name))
        if new != old:
            changed[f.name] = new
    return changed


def from_json_value(value: Any) -> Any:
    """JSON/TOML data back to a field value: lists become tuples (dataclass fields are tuples)."""
    if isinstance(value, list):
        return tuple(from_json_value(v) for v in value)
    if isinstance(value, dict):
        return {k: from_json_value(v) for k, v in value.items()}
    return value


# --- runs ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunSpec:
    """One closed-loop run: everything needed to carry it out, as plain data."""

    optimizer_label: str
    """Name of the optimiser configuration in results."""
    optimizer_name: str
    """Registered optimiser name."""
    optimizer_overrides: str
    """Canonical JSON of the config fields changed from the registered configuration."""
    scenario_label: str
    """Name of the scenario configuration in results (the scenario is renamed to it, so the
    trace and the figures name it too)."""
    scenario_name: str
    """Registered scenario name."""
    scenario_overrides: str
    """Canonical JSON of the scenario fields changed from the registered scenario."""
    trigger: bool
    """Event trigger on, or a solve at every instant."""
    seed: int
    """The user-facing seed (``run --seed``; 0, 1, ... in a suite)."""
    budget_max_evaluations: int | None
    """Per-solve evaluation limit; both limits None = the optimiser's own default budget."""
    budget_max_iterations: int | None
    """Per-solve iteration limit."""
    config_hash: str
    """SHA-256 of the fully resolved optimiser, scenario and budget: a stored result whose
    hash differs was produced by a different configuration (changed code defaults) and is
    redone."""
    budget_deadline_ms: float | None = None
    """Per-solve wall-clock deadline, milliseconds; None: none. With no other limit it caps
    the optimiser's own budget. A run under a deadline depends on the machine's speed."""
    seed_entropy: int | None = None
    """Entropy of the run's :class:`numpy.random.SeedSequence`; None: the seed itself. A
    suite's runs take it from their identity (:meth:`identity_entropy`), so that seed 0 of
    two configurations does not share random numbers."""
    suite: str | None = None
    """Name of the suite it came from (recorded, not part of the identity); None for a run
    of its own."""
    trace: bool = True
    """Keep the per-instant trace (a sweep stores it only if its suite asks)."""
    plugins: tuple[str, ...] = ()
    """Plugin modules or files loaded before the run is built (those the command loaded with
    ``--plugin``; a sweep's workers need them); not part of the identity."""

    @classmethod
    def of(
        cls,
        optimizer_name: str,
        optimizer: Optimizer,
        scenario_name: str,
        scenario: Scenario,
        *,
        trigger: bool,
        seed: int,
        budget: Budget | None = None,
        deadline_ms: float | None = None,
        plugins: tuple[str, ...] = (),
    ) -> RunSpec:
        """The run of configured objects, labelled by their changes from the registered
        ``optimizer_name`` and ``scenario_name``."""
        optimizer_label, optimizer_changes = labelled(
            optimizer_name, get_optimizer(optimizer_name), optimizer
        )
        scenario_label, scenario_changes = labelled(
            scenario_name, get_scenario(scenario_name), scenario
        )
        return cls(
            optimizer_label=optimizer_label,
            optimizer_name=optimizer_name,
            optimizer_overrides=canonical_json(optimizer_changes),
            scenario_label=scenario_label,
            scenario_name=scenario_name,
            scenario_overrides=canonical_json(scenario_changes),
            trigger=trigger,
            seed=seed,
            budget_max_evaluations=None if budget is None else budget.max_evaluations,
            budget_max_iterations=None if budget is None else budget.max_iterations,
            config_hash=resolved_config_hash(
                scenario, optimizer, with_deadline(budget, deadline_ms, optimizer)
            ),
            budget_deadline_ms=deadline_ms,
            plugins=plugins,
        )

    def budget_for(self, optimizer: Optimizer) -> Budget | None:
        """The per-solve budget of this run's ``optimizer``; None: the optimiser's own."""
        return resolved_budget(
            self.budget_max_evaluations,
            self.budget_max_iterations,
            self.budget_deadline_ms,
            optimizer,
        )

    @property
    def budget(self) -> Budget | None:
        """The per-solve budget; None: the optimiser's own."""
        return self.budget_for(self.build()[1])

    @property
    def budget_label(self) -> str:
        return budget_label(
            self.budget_max_evaluations, self.budget_max_iterations, self.budget_deadline_ms
        )

    def identity(self) -> dict[str, Any]:
        """What the run *is*: its result file name and a suite run's streams derive from it."""
        return {
            "v": IDENTITY_VERSION,
            "optimizer": self.optimizer_name,
            "optimizer_overrides": json.loads(self.optimizer_overrides),
            "scenario": self.scenario_name,
            "scenario_overrides": json.loads(self.scenario_overrides),
            "trigger": self.trigger,
            # a deadline joins the identity only when set, so no other run changes its key
            "budget": {
                "max_evaluations": self.budget_max_evaluations,
                "max_iterations": self.budget_max_iterations,
            }
            | ({} if self.budget_deadline_ms is None else {"deadline_ms": self.budget_deadline_ms}),
            "seed": self.seed,
        }

    @property
    def identity_json(self) -> str:
        return canonical_json(self.identity())

    @property
    def key(self) -> str:
        """24 hex digits of the identity's SHA-256: the result file's name."""
        return sha256_hex(self.identity_json)[:24]

    def identity_entropy(self) -> int:
        """128-bit entropy from the identity's SHA-256 (what a suite's runs are seeded by)."""
        digest = hashlib.sha256(b"formation-bench run seed\0" + self.identity_json.encode())
        return int.from_bytes(digest.digest()[:16], "big")

    @property
    def entropy(self) -> int:
        """Entropy of the run's SeedSequence: the UAVs' streams are spawned from it."""
        return self.seed if self.seed_entropy is None else self.seed_entropy

    def build(self) -> tuple[Scenario, Optimizer]:
        """The scenario (named by its label) and optimiser objects of this run."""
        scenario_overrides = from_json_value(json.loads(self.scenario_overrides))
        optimizer_overrides = from_json_value(json.loads(self.optimizer_overrides))
        scenario = get_scenario(self.scenario_name, **scenario_overrides)
        return (
            scenario.with_overrides(name=self.scenario_label),
            get_optimizer(self.optimizer_name, **optimizer_overrides),
        )

    def describe(self) -> str:
        return (
            f"{self.optimizer_label} / {self.scenario_label} / "
            f"trigger {'on' if self.trigger else 'off'} / {self.budget_label} / seed {self.seed}"
        )

    def run_arguments(self) -> list[str]:
        """The ``formation-bench`` arguments of the ``run`` that repeats this run exactly
        (without ``--out``): same configuration, budget and random streams."""
        args = [f"--plugin={plugin}" for plugin in self.plugins]
        args += ["run", "--optimizer", self.optimizer_name, "--scenario", self.scenario_name]
        for kind, overrides in (
            ("scenario", self.scenario_overrides),
            ("optimizer", self.optimizer_overrides),
        ):
            for field, value in json.loads(overrides).items():
                args += ["--set", f"{kind}.{field}={set_value(value)}"]
        args += ["--trigger" if self.trigger else "--no-trigger", "--seed", str(self.entropy)]
        if self.budget_max_evaluations is not None:
            args += ["--max-evaluations", str(self.budget_max_evaluations)]
        if self.budget_max_iterations is not None:
            args += ["--max-iterations", str(self.budget_max_iterations)]
        if self.budget_deadline_ms is not None:
            args += ["--deadline-ms", repr(self.budget_deadline_ms)]
        return args

    def run_command(self, out: str = "DIR") -> str:
        """:meth:`run_arguments` as a shell command writing into ``out``."""
        return shlex.join(["formation-bench", *self.run_arguments(), "--out", out])


def set_value(value: Any) -> str:
    """A JSON field value as ``run --set`` reads it back (a Python literal)."""
    return repr(from_json_value(value))


def labelled(name: str, default: Any, configured: Any) -> tuple[str, dict[str, Any]]:
    """``name``, or ``name[field=value,...]`` when fields differ from the registered ones;
    and the changed fields."""
    changed = effective_overrides(default, configured)
    changed.pop("name", None)
    if not changed:
        return name, changed
    return name + "[" + ",".join(f"{k}={short_value(v)}" for k, v in changed.items()) + "]", changed


def short_value(value: Any) -> str:
    """A field value as it appears in a label: compact JSON without quotes."""
    return json.dumps(value, separators=(",", ":")).strip('"')


def with_deadline(
    budget: Budget | None, deadline_ms: float | None, optimizer: Optimizer | None
) -> Budget | None:
    """``budget`` (or, if None, ``optimizer``'s own) with a per-solve deadline in ms."""
    if deadline_ms is None:
        return budget
    if budget is None:
        assert optimizer is not None, "a deadline alone caps the optimiser's own budget"
        budget = optimizer.default_budget
    return dataclasses.replace(budget, deadline_s=deadline_ms / 1000.0)


def resolved_budget(
    max_evaluations: int | None,
    max_iterations: int | None,
    deadline_ms: float | None,
    optimizer: Optimizer,
) -> Budget | None:
    """The per-solve budget of these limits for ``optimizer`` (None: its own)."""
    limits = (
        None
        if max_evaluations is None and max_iterations is None
        else Budget(max_evaluations, max_iterations)
    )
    return with_deadline(limits, deadline_ms, optimizer)


def budget_label(
    max_evaluations: int | None, max_iterations: int | None, deadline_ms: float | None = None
) -> str:
    """``default`` or e.g. ``max_evaluations=1200``."""
    parts = [
        f"{name}={value}"
        for name, value in (
            ("max_evaluations", max_evaluations),
            ("max_iterations", max_iterations),
            ("deadline_ms", None if deadline_ms is None else f"{deadline_ms:g}"),
        )
        if value is not None
    ]
    return ",".join(parts) if parts else "default"


def resolved_config_hash(scenario: Scenario, optimizer: Optimizer, budget: Budget | None) -> str:
    """SHA-256 of everything that configures a run (see :attr:`RunSpec.config_hash`)."""
    effective = budget if budget is not None else optimizer.default_budget
    return sha256_hex(
        canonical_json(
            {
                "scenario": config_of(scenario),
                "optimizer": config_of(optimizer),
                "budget": effective,
            }
        )
    )
