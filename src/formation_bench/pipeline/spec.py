"""What a closed-loop run is, as plain data: :class:`RunSpec`.

``run``, ``reproduce`` and every run of a ``sweep`` are described by a :class:`RunSpec`
(optimiser and its overrides, scenario and its overrides, trigger, seed, budget) and carried
out by :func:`formation_bench.pipeline.runner.execute`. The canonical JSON helpers here
make equal configurations give equal text, so a run's identity, result file name and random
streams never depend on how the configuration was written. :class:`Identified` derives a
run's key and random numbers from its identity; a score run
(:class:`~formation_bench.experiments.score.ScoreRun`) uses it too.

A per-solve budget is an optimiser :class:`~formation_bench.optimizers.Budget`, deadline in
seconds, or None for the optimiser's own budget. Only the user-facing text names a deadline
in milliseconds (``--deadline-ms``, a suite's ``deadline_ms``, the budget label, the run's
identity): :func:`deadline_s_of_ms` reads it, :func:`deadline_ms_of_s` writes it.
"""

from __future__ import annotations

import abc
import dataclasses
import enum
import functools
import hashlib
import json
import re
import shlex
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import numpy as np

from formation_bench.mpc.scenario import Scenario, get_scenario
from formation_bench.optimizers import Budget, Optimizer, get_optimizer

IDENTITY_VERSION = 1
"""Bumped if the identity's layout ever changes (it would re-key every run)."""

ConfigT = TypeVar("ConfigT")


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
    if _is_config(value):
        return config_of(value)
    return re.sub(r" at 0x[0-9a-fA-F]+", "", repr(value))  # no memory addresses: hashes repeat


def canonical_json(data: Any) -> str:
    """Compact JSON with sorted keys: equal data gives equal text."""
    return json.dumps(jsonable(data), sort_keys=True, separators=(",", ":"), allow_nan=True)


def sha256_hex(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _is_config(value: Any) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def config_of(obj: Any) -> dict[str, Any]:
    """Every field of a config dataclass as JSON data, with its class name; a field holding a
    config dataclass (a group of settings) is nested the same way."""
    fields = {f.name: jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    return {"class": type(obj).__qualname__, **fields}


def flat_fields(obj: Any) -> dict[str, Any]:
    """Every setting of a config dataclass as JSON data, by name, with the settings of a group
    (a field holding a config dataclass) in place of the group: the result does not depend on
    how the class groups its settings. A name two groups share is kept as ``group.name``."""
    values: dict[str, Any] = {}
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if not _is_config(value):
            values[f.name] = jsonable(value)
            continue
        for name, leaf in flat_fields(value).items():
            values[f"{f.name}.{name}" if name in values else name] = leaf
    return values


def flat_config(obj: Any) -> dict[str, Any]:
    """:func:`config_of` with the groups of settings flattened (:func:`flat_fields`): what a
    configuration's hash is taken of."""
    return {"class": type(obj).__qualname__, **flat_fields(obj)}


def effective_overrides(default: Any, configured: Any) -> dict[str, Any]:
    """The settings of ``configured`` that differ from ``default`` (as JSON data, by name, a
    group's settings flattened as :func:`flat_fields` does).

    So ``population_size = 30`` on a registered optimiser whose population is
    already 30 is no override at all, and ``3`` equals ``3.0``.
    """
    old = flat_fields(default)
    return {name: new for name, new in flat_fields(configured).items() if new != old.get(name)}


def from_json_value(value: Any) -> Any:
    """JSON/TOML data back to a field value: lists become tuples (dataclass fields are tuples)."""
    if isinstance(value, list):
        return tuple(from_json_value(v) for v in value)
    if isinstance(value, dict):
        return {k: from_json_value(v) for k, v in value.items()}
    return value


def from_config(cls: type[ConfigT], data: Mapping[str, Any]) -> ConfigT:
    """An instance of the config dataclass ``cls`` from its JSON data, as :func:`config_of`
    (groups nested) or :func:`flat_fields` (groups flattened) wrote it.

    A group of settings (a field whose class is a config dataclass) is built from its own
    object when ``data`` nests it, else from the settings of the same names at any level of
    ``data``; so a record written before the class grouped its settings, or after, rebuilds
    with the class of today. A setting ``data`` lacks (one added since) keeps ``cls``'s
    default; the ``class`` entries are not checked. Values are validated as ``cls`` validates
    them (enum names are coerced by the settings)."""
    return _built(cls, data, _leaves(data))


def _leaves(data: Mapping[str, Any]) -> dict[str, Any]:
    """Every setting of ``data`` and of the config objects nested in it, by name (an outer
    setting first)."""
    leaves: dict[str, Any] = {}
    nested = []
    for name, value in data.items():
        if isinstance(value, Mapping) and "class" in value:
            nested.append(value)
        elif name != "class":
            leaves[name] = value
    for value in nested:
        for name, leaf in _leaves(value).items():
            leaves.setdefault(name, leaf)
    return leaves


def _built(cls: type[ConfigT], data: Mapping[str, Any], leaves: dict[str, Any]) -> ConfigT:
    kwargs = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if not f.init:
            continue
        group = _group_class(cls, f)
        if group is not None:
            own = data.get(f.name)
            kwargs[f.name] = _built(group, own if isinstance(own, Mapping) else {}, leaves)
        elif f.name in data:
            kwargs[f.name] = from_json_value(data[f.name])
        elif f.name in leaves:
            kwargs[f.name] = from_json_value(leaves[f.name])
    return cls(**kwargs)


def _group_class(cls: type, f: dataclasses.Field) -> type | None:
    """The config dataclass a field of ``cls`` holds (a group of settings), or None."""
    default = f.default
    if default is dataclasses.MISSING and f.default_factory is not dataclasses.MISSING:
        default = f.default_factory()
    if _is_config(default):
        return type(default)
    if default is not None and default is not dataclasses.MISSING:
        return None  # a plain value: a setting, not a group
    hint = _type_hints(cls).get(f.name)
    kinds = typing.get_args(hint) if isinstance(hint, types.UnionType) else (hint,)
    return next((k for k in kinds if isinstance(k, type) and dataclasses.is_dataclass(k)), None)


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except (NameError, TypeError):  # an annotation of a plugin's class that does not resolve
        return {}


# --- budgets ----------------------------------------------------------------------------------


def deadline_s_of_ms(deadline_ms: float) -> float:
    """A deadline given in milliseconds (``--deadline-ms``, a suite's ``deadline_ms``) in the
    seconds of :attr:`Budget.deadline_s`: the one conversion of user input."""
    return float(deadline_ms) / 1000.0


def deadline_ms_of_s(deadline_s: float) -> float:
    """A deadline in the milliseconds its user-facing text names: the shortest decimal whose
    :func:`deadline_s_of_ms` is ``deadline_s`` (so ``0.002`` s is ``2.0`` ms, as given)."""
    for digits in range(1, 18):
        deadline_ms = float(f"{deadline_s * 1000.0:.{digits}g}")
        if deadline_s_of_ms(deadline_ms) == deadline_s:
            return deadline_ms
    return deadline_s * 1000.0


def solve_budget(budget: Budget | None, optimizer: Optimizer) -> Budget | None:
    """The budget each solve of ``optimizer`` gets: ``budget`` completed with the optimiser's
    own limits if it sets only a deadline; None: the optimiser's own budget."""
    return None if budget is None else budget.within(optimizer.default_budget)


def budget_label(budget: Budget | None) -> str:
    """``default`` or e.g. ``max_evaluations=1200`` or ``deadline_ms=2`` (as results name it)."""
    if budget is None:
        return "default"
    parts = [
        f"{name}={value}"
        for name, value in (
            ("max_evaluations", budget.max_evaluations),
            ("max_iterations", budget.max_iterations),
            ("deadline_ms", _deadline_text(budget)),
        )
        if value is not None
    ]
    return ",".join(parts)


def _deadline_text(budget: Budget) -> str | None:
    return None if budget.deadline_s is None else f"{deadline_ms_of_s(budget.deadline_s):g}"


def budget_deadline_ms(budget: Budget | None) -> float | None:
    """The per-solve deadline of ``budget`` in milliseconds, as records and identities name it."""
    if budget is None or budget.deadline_s is None:
        return None
    return deadline_ms_of_s(budget.deadline_s)


def budget_limits(budget: Budget | None) -> tuple[int | None, int | None]:
    """``(max_evaluations, max_iterations)`` of ``budget``; both None: the optimiser's own."""
    return (None, None) if budget is None else (budget.max_evaluations, budget.max_iterations)


def budget_arguments(budget: Budget | None) -> list[str]:
    """The command-line options that ask for ``budget`` (``run`` and ``score`` take them)."""
    max_evaluations, max_iterations = budget_limits(budget)
    deadline_ms = budget_deadline_ms(budget)
    args = []
    if max_evaluations is not None:
        args += ["--max-evaluations", str(max_evaluations)]
    if max_iterations is not None:
        args += ["--max-iterations", str(max_iterations)]
    if deadline_ms is not None:
        args += ["--deadline-ms", repr(deadline_ms)]
    return args


def resolved_config_hash(
    scenario: Scenario | None, optimizer: Optimizer, budget: Budget | None
) -> str:
    """SHA-256 of everything that configures a run (see :attr:`RunSpec.config_hash`; a score
    run has no scenario); the groups of settings are flattened (:func:`flat_config`), so
    regrouping them changes no hash."""
    effective = budget if budget is not None else optimizer.default_budget
    parts = {"optimizer": flat_config(optimizer), "budget": effective}
    if scenario is not None:
        parts["scenario"] = flat_config(scenario)
    return sha256_hex(canonical_json(parts))


# --- identities -------------------------------------------------------------------------------


class Identified(abc.ABC):
    """A run whose result file name (:attr:`key`) and random numbers
    (:meth:`identity_entropy`) derive from what it is (:meth:`identity`), never from where it
    sits in a queue or which worker runs it."""

    ENTROPY_DOMAIN: ClassVar[bytes]
    """Prefix of the identity in the digest the entropy is taken from: runs of two kinds with
    equal identities draw different random numbers."""

    @abc.abstractmethod
    def identity(self) -> dict[str, Any]:
        """What the run is: the fields its key and random numbers derive from."""

    @property
    def identity_json(self) -> str:
        return canonical_json(self.identity())

    @property
    def key(self) -> str:
        """24 hex digits of the identity's SHA-256: the result file's name."""
        return sha256_hex(self.identity_json)[:24]

    def identity_entropy(self) -> int:
        """128-bit entropy from the identity's SHA-256."""
        digest = hashlib.sha256(self.ENTROPY_DOMAIN + self.identity_json.encode())
        return int.from_bytes(digest.digest()[:16], "big")


# --- runs ---------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunSpec(Identified):
    """One closed-loop run: everything needed to carry it out, as plain data."""

    ENTROPY_DOMAIN: ClassVar[bytes] = b"formation-bench run seed\0"

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
    budget: Budget | None
    """Per-solve budget as asked for; None: the optimiser's own. One that sets only a
    deadline caps the optimiser's own limits (:func:`solve_budget`). A run under a deadline
    depends on the machine's speed."""
    config_hash: str
    """SHA-256 of the fully resolved optimiser, scenario and budget: a stored result whose
    hash differs was produced by a different configuration (changed code defaults) and is
    redone."""
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
            budget=budget,
            config_hash=resolved_config_hash(scenario, optimizer, solve_budget(budget, optimizer)),
            plugins=plugins,
        )

    def budget_for(self, optimizer: Optimizer) -> Budget | None:
        """The per-solve budget of this run's ``optimizer``; None: the optimiser's own."""
        return solve_budget(self.budget, optimizer)

    @property
    def budget_label(self) -> str:
        return budget_label(self.budget)

    def identity(self) -> dict[str, Any]:
        """What the run *is*: its result file name and a suite run's streams derive from it."""
        max_evaluations, max_iterations = budget_limits(self.budget)
        deadline_ms = budget_deadline_ms(self.budget)
        return {
            "v": IDENTITY_VERSION,
            "optimizer": self.optimizer_name,
            "optimizer_overrides": json.loads(self.optimizer_overrides),
            "scenario": self.scenario_name,
            "scenario_overrides": json.loads(self.scenario_overrides),
            "trigger": self.trigger,
            # a deadline joins the identity only when set, so no other run changes its key
            "budget": {"max_evaluations": max_evaluations, "max_iterations": max_iterations}
            | ({} if deadline_ms is None else {"deadline_ms": deadline_ms}),
            "seed": self.seed,
        }

    @property
    def entropy(self) -> int:
        """Entropy of the run's SeedSequence: the UAVs' streams are spawned from it."""
        return self.seed if self.seed_entropy is None else self.seed_entropy

    def configured(self) -> tuple[Scenario, Optimizer]:
        """The scenario (under its registered name) and optimiser objects of this run: the
        configuration :attr:`config_hash` is taken of."""
        scenario_overrides = from_json_value(json.loads(self.scenario_overrides))
        return get_scenario(self.scenario_name, **scenario_overrides), self.optimizer()

    def optimizer(self) -> Optimizer:
        """The optimiser object of this run (as :meth:`configured` builds it)."""
        return get_optimizer(
            self.optimizer_name, **from_json_value(json.loads(self.optimizer_overrides))
        )

    def build(self) -> tuple[Scenario, Optimizer]:
        """The scenario (named by its label) and optimiser objects of this run."""
        scenario, optimizer = self.configured()
        return scenario.with_overrides(name=self.scenario_label), optimizer

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
        return args + budget_arguments(self.budget)

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
