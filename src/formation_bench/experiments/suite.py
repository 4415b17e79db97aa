"""Sweep specifications: TOML suite files, validated on load, expanded into runs.

A suite names optimisers (with config overrides), scenarios (with overrides),
trigger settings, seeds and budgets; every combination is one closed-loop run.
Shipped suites live in ``src/formation_bench/experiments/suites/NAME.toml``; any other TOML file can
be given by path. The format is documented in ``docs/explanation/benchmarks.md``.

Every error names the file, the key path and the allowed values, e.g.::

    paper.toml: optimizers[0].name: unknown optimizer 'psoo'; allowed: ...

(a TOML syntax error keeps the line and column that :mod:`tomllib` reports).

Each run has an *identity*: the registered optimiser and scenario names, the
fields their overrides actually change, the trigger, the budget and the seed.
Its SHA-256 names the run's result file and is the entropy of the run's
:class:`numpy.random.SeedSequence`, so a run's random numbers depend on what
the run is and never on where it sits in the queue or which worker runs it.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import json
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from formation_bench.mpc.scenario import SCENARIOS, get_scenario
from formation_bench.optimizers import OPTIMIZERS, Budget, get_optimizer
from formation_bench.optimizers.base import BUDGET_MINIMUM
from formation_bench.pipeline.checks import (
    MAX_LABEL_CHARS,
    MAX_SEED,
    LimitError,
    check_label,
    check_run,
    check_seed_count,
)
from formation_bench.pipeline.spec import (
    RunSpec,
    canonical_json,
    deadline_s_of_ms,
    flat_fields,
    from_json_value,
    labelled,
    resolved_config_hash,
    sha256_hex,
    solve_budget,
)
from formation_bench.plugins import loaded_plugins

SUITES_DIR = Path(__file__).parent / "suites"
"""Where the shipped suites live."""

TOP_LEVEL_KEYS: dict[str, str] = {
    "name": f"the suite's name (a non-empty string of at most {MAX_LABEL_CHARS} characters; "
    "default: the file's stem)",
    "description": "one line saying what the suite compares (default: empty)",
    "seeds": "a count of seeds per configuration (seeds 0 .. count - 1), or a list of distinct "
    "seeds, integers from 0 to 2**128 - 1; required",
    "triggers": "true, false or [true, false]: the event trigger on, off or both (default: [true])",
    "budgets": 'a list of per-solve budgets, each "default" (the optimiser\'s own) or a budget '
    'table (default: ["default"])',
    "trace": "store every run's per-instant trace beside its record (default: false)",
    "optimizers": "one or more [[optimizers]] tables; required",
    "scenarios": "one or more [[scenarios]] tables (default: the paper scenario alone)",
}
"""The keys at the top level of a suite file, with what each holds."""
OPTIMIZER_KEYS: dict[str, str] = {
    "name": 'a registered optimiser, or "*" for every registered one; required',
    "label": "the name the results and the report give this configuration, at most "
    f"{MAX_LABEL_CHARS} characters on one line (default: the name with its overrides, which "
    "must then fit too)",
    "overrides": "a table of the optimiser's settings to change, checked before any run",
    "optional": "true: skip the entry, with a note, when the name is not registered here "
    "(an adapter whose library is not installed); default false",
    "exclude": 'with name = "*": names or shell patterns left out, e.g. ["ng-*", "pycma"]',
    "budgets": "this optimiser's own list of budgets, in place of the suite's",
}
"""The keys of an ``[[optimizers]]`` table."""
SCENARIO_KEYS: dict[str, str] = {
    "name": "a registered scenario; required",
    "label": "the name the results and the report give this configuration, at most "
    f"{MAX_LABEL_CHARS} characters on one line (default: the name with its overrides, which "
    "must then fit too)",
    "overrides": "a table of the scenario's settings to change, checked before any run",
}
"""The keys of a ``[[scenarios]]`` table."""
BUDGET_KEYS: dict[str, str] = {
    "max_evaluations": f"objective evaluations per solve, an integer >= {BUDGET_MINIMUM}",
    "max_iterations": f"optimiser iterations per solve, an integer >= {BUDGET_MINIMUM}",
    "deadline_ms": "wall-clock deadline per solve, in milliseconds (read into the seconds of "
    "Budget.deadline_s)",
}
"""The keys of a budget table; an empty table is the optimiser's own budget."""
TOP_LEVEL_FIELDS = tuple(k for k in TOP_LEVEL_KEYS if k not in ("optimizers", "scenarios"))
TABLE_FIELDS = ("optimizers", "scenarios")
OPTIMIZER_FIELDS = tuple(OPTIMIZER_KEYS)
SCENARIO_FIELDS = tuple(SCENARIO_KEYS)
BUDGET_FIELDS = tuple(BUDGET_KEYS)
ALL_OPTIMIZERS = "*"


class SuiteError(ValueError):
    """A suite file that cannot be used; the message names the file, line and allowed values."""


# --- the suite ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Entry:
    """One optimiser or scenario configuration of a suite."""

    label: str
    name: str
    overrides: str
    """Canonical JSON of the effective overrides."""
    budgets: tuple[Budget | None, ...] | None = None
    """An optimiser's own budgets, in place of the suite's (None: the suite's)."""

    def budgets_or(self, suite_budgets: tuple[Budget | None, ...]) -> tuple[Budget | None, ...]:
        """The budgets this entry runs at, given the suite's."""
        return suite_budgets if self.budgets is None else self.budgets


@dataclass(frozen=True)
class Suite:
    """A validated suite."""

    name: str
    path: Path
    text: str
    """The suite file's text (recorded in the results manifest)."""
    description: str
    seeds: tuple[int, ...]
    triggers: tuple[bool, ...]
    budgets: tuple[Budget | None, ...]
    """The per-solve budgets; None: the optimiser's own (``"default"``). An optimiser entry
    with budgets of its own runs those instead."""
    trace: bool
    optimizers: tuple[Entry, ...]
    scenarios: tuple[Entry, ...]
    notes: tuple[str, ...] = ()
    """What was skipped on load (optional optimisers that are not registered)."""

    @property
    def sha256(self) -> str:
        return sha256_hex(self.text)

    def budgets_of(self, entry: Entry) -> tuple[Budget | None, ...]:
        """The budgets an optimiser entry runs at."""
        return entry.budgets_or(self.budgets)

    def runs(self) -> list[RunSpec]:
        """Every run, in a fixed order (scenario, optimiser, budget, trigger, seed)."""
        runs = []
        for scenario_entry in self.scenarios:
            for optimizer_entry in self.optimizers:
                scenario = get_scenario(
                    scenario_entry.name, **from_json_value(json.loads(scenario_entry.overrides))
                )
                optimizer = get_optimizer(
                    optimizer_entry.name, **from_json_value(json.loads(optimizer_entry.overrides))
                )
                for budget in self.budgets_of(optimizer_entry):
                    config_hash = resolved_config_hash(
                        scenario, optimizer, solve_budget(budget, optimizer)
                    )
                    for trigger in self.triggers:
                        for seed in self.seeds:
                            spec = RunSpec(
                                suite=self.name,
                                optimizer_label=optimizer_entry.label,
                                optimizer_name=optimizer_entry.name,
                                optimizer_overrides=optimizer_entry.overrides,
                                scenario_label=scenario_entry.label,
                                scenario_name=scenario_entry.name,
                                scenario_overrides=scenario_entry.overrides,
                                trigger=trigger,
                                budget=budget,
                                seed=seed,
                                trace=self.trace,
                                config_hash=config_hash,
                                plugins=loaded_plugins(),
                            )
                            # seed 0 of two configurations must not share random numbers
                            runs.append(
                                dataclasses.replace(spec, seed_entropy=spec.identity_entropy())
                            )
        return runs


def shipped_suites() -> list[str]:
    """Names of the suites in ``src/formation_bench/experiments/suites/``."""
    return sorted(p.stem for p in SUITES_DIR.glob("*.toml"))


def resolve_suite_path(name_or_path: str) -> Path:
    """A shipped suite's file, or the given path if it is a file.

    A bare shipped name (``comparison``) is the shipped suite even where the working folder
    holds something of that name, such as the results folder of an earlier sweep."""
    candidate = Path(name_or_path)
    shipped = SUITES_DIR / f"{name_or_path}.toml"
    if name_or_path in shipped_suites() and candidate.name == name_or_path:
        return shipped
    if candidate.is_dir():
        raise SuiteError(f"suite {name_or_path}: is a folder; give a suite .toml file")
    if candidate.suffix == ".toml" or candidate.is_file():
        if not candidate.is_file():
            raise SuiteError(f"suite file {name_or_path} does not exist")
        return candidate
    raise SuiteError(
        f"unknown suite {name_or_path!r}; shipped: {', '.join(shipped_suites())} "
        "(or give the path of a .toml file)"
    )


def load_suite(name_or_path: str) -> Suite:
    """Read and validate a suite (shipped name or path); raises :class:`SuiteError`."""
    path = resolve_suite_path(name_or_path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise SuiteError(f"{path}: not UTF-8 text ({err.reason} at byte {err.start})") from None
    except OSError as err:
        raise SuiteError(f"{path}: cannot be read ({err.strerror})") from None
    return parse_suite(text, path)


def parse_suite(text: str, path: Path) -> Suite:
    """Validate the suite ``text`` read from ``path``."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SuiteError(f"{path}: not valid TOML: {err}") from None
    return _Validator(text, path, data).suite()


class _Validator:
    def __init__(self, text: str, path: Path, data: dict[str, Any]) -> None:
        self.path = path
        self.data = data
        self.text = text

    # errors ------------------------------------------------------------------------------------

    def fail(self, where: tuple[Any, ...], message: str) -> SuiteError:
        # tomllib gives positions for syntax errors only; a semantic error names its key path
        label = _dotted(where)
        return SuiteError(f"{self.path}: {label + ': ' if label else ''}{message}")

    # top level ---------------------------------------------------------------------------------

    def suite(self) -> Suite:
        data = self.data
        allowed = (*TOP_LEVEL_FIELDS, *TABLE_FIELDS)
        for key in data:
            if key not in allowed:
                raise self.fail((key,), f"unknown field; allowed: {', '.join(allowed)}")
        name = data.get("name", self.path.stem)
        if not isinstance(name, str) or not name:
            raise self.fail(("name",), f"must be a non-empty string, got {name!r}")
        self.check_label(("name",), name, None if "name" in data else "the file name")
        description = data.get("description", "")
        if not isinstance(description, str):
            raise self.fail(("description",), f"must be a string, got {description!r}")
        trace = data.get("trace", False)
        if not isinstance(trace, bool):
            raise self.fail(("trace",), f"must be true or false, got {trace!r}")
        optimizers, notes = self.optimizers()
        if not optimizers:
            why = "; ".join(notes) or f"its {ALL_OPTIMIZERS!r} entries exclude every one"
            raise self.fail(
                ("optimizers",),
                f"suite {name!r} matches no registered optimizer ({why}), so it has no runs "
                "and would store nothing; name an optimizer that is registered here (see "
                "'formation-bench list')",
            )
        scenarios = self.scenarios()
        for entry in scenarios:
            self.check_settle_time(entry)
        budgets = self.budgets()
        self.check_limits(optimizers, scenarios, budgets)
        return Suite(
            name=name,
            path=self.path,
            text=self.text,
            description=description,
            seeds=self.seeds(),
            triggers=self.triggers(),
            budgets=budgets,
            trace=trace,
            optimizers=optimizers,
            scenarios=scenarios,
            notes=tuple(notes),
        )

    def seeds(self) -> tuple[int, ...]:
        seeds = self.data.get("seeds")
        if seeds is None:
            raise self.fail((), "missing field 'seeds' (a count, e.g. 30, or a list of seeds)")
        if _is_int(seeds):
            if seeds < 1:
                raise self.fail(("seeds",), f"a count must be >= 1, got {seeds}")
            self.check_seed_count(seeds)
            return tuple(range(seeds))
        if isinstance(seeds, list) and seeds and all(_is_int(s) and s >= 0 for s in seeds):
            self.check_seed_count(len(seeds))
            if len(set(seeds)) != len(seeds):
                raise self.fail(("seeds",), "seeds must be distinct")
            too_large = [s for s in seeds if s > MAX_SEED]
            if too_large:
                raise self.fail(
                    ("seeds",),
                    f"{too_large[0]} is more than 2**128 - 1 (a run's seed is a 128-bit "
                    "SeedSequence entropy)",
                )
            return tuple(seeds)
        raise self.fail(
            ("seeds",),
            f"must be a count >= 1 or a non-empty list of integers >= 0, got {seeds!r}",
        )

    def check_seed_count(self, count: int) -> None:
        try:
            check_seed_count(count, "seeds")
        except LimitError as err:
            raise self.fail((), str(err)) from None

    def triggers(self) -> tuple[bool, ...]:
        triggers = self.data.get("triggers", [True])
        if isinstance(triggers, bool):
            triggers = [triggers]
        if (
            not isinstance(triggers, list)
            or not triggers
            or not all(isinstance(t, bool) for t in triggers)
            or len(set(triggers)) != len(triggers)
        ):
            raise self.fail(
                ("triggers",), f"must be true, false or [true, false], got {triggers!r}"
            )
        return tuple(triggers)

    def budgets(self) -> tuple[Budget | None, ...]:
        return self.budget_list(("budgets",), self.data.get("budgets", ["default"]))

    def budget_list(self, where_list: tuple[Any, ...], budgets: Any) -> tuple[Budget | None, ...]:
        if not isinstance(budgets, list) or not budgets:
            raise self.fail(
                where_list,
                'must be a non-empty list of "default" or tables '
                f"{{max_evaluations = N, max_iterations = M, deadline_ms = T}}, got {budgets!r}",
            )
        result: list[Budget | None] = []
        for k, budget in enumerate(budgets):
            where = (*where_list, k)
            if budget == "default":
                result.append(None)
                continue
            if not isinstance(budget, dict):
                raise self.fail(
                    where,
                    f'must be "default" or a table with {" and/or ".join(BUDGET_FIELDS)}, '
                    f"got {budget!r}",
                )
            for key in budget:
                if key not in BUDGET_FIELDS:
                    raise self.fail(
                        (*where, key), f"unknown budget field; allowed: {', '.join(BUDGET_FIELDS)}"
                    )
            limits = {k: v for k, v in budget.items() if k != "deadline_ms"}
            deadline_ms = budget.get("deadline_ms")
            if deadline_ms is not None and not (
                isinstance(deadline_ms, int | float)
                and not isinstance(deadline_ms, bool)
                and math.isfinite(deadline_ms)
                and deadline_ms > 0
            ):
                raise self.fail(
                    (*where, "deadline_ms"), f"must be a number of milliseconds > 0, got "
                    f"{deadline_ms!r}",
                )  # fmt: skip
            if not limits and deadline_ms is None:  # an empty table: the optimiser's own
                result.append(None)
                continue
            try:
                result.append(
                    Budget(
                        **limits,
                        deadline_s=None if deadline_ms is None else deadline_s_of_ms(deadline_ms),
                    )
                )
            except ValueError as err:
                raise self.fail(where, str(err)) from None
        if len(set(result)) != len(result):
            raise self.fail(where_list, "budgets must be distinct")
        return tuple(result)

    # optimisers and scenarios -----------------------------------------------------------------

    def entries(self, key: str) -> list[tuple[tuple[Any, ...], dict[str, Any]]]:
        raw = self.data.get(key)
        if not isinstance(raw, list) or not raw or not all(isinstance(e, dict) for e in raw):
            raise self.fail((key,), f"must be one or more [[{key}]] tables with at least a name")
        return [((key, k), entry) for k, entry in enumerate(raw)]

    def optimizers(self) -> tuple[tuple[Entry, ...], list[str]]:
        registered = sorted(OPTIMIZERS)
        entries: list[Entry] = []
        notes: list[str] = []
        for where, raw in self.entries("optimizers"):
            self.check_fields(where, raw, OPTIMIZER_FIELDS)
            name = self.name_field(where, raw)
            optional = raw.get("optional", False)
            if not isinstance(optional, bool):
                raise self.fail((*where, "optional"), f"must be true or false, got {optional!r}")
            exclude = raw.get("exclude", [])
            own_budgets = (
                self.budget_list((*where, "budgets"), raw["budgets"]) if "budgets" in raw else None
            )
            if name == ALL_OPTIMIZERS:
                if not isinstance(exclude, list) or not all(isinstance(e, str) for e in exclude):
                    raise self.fail(
                        (*where, "exclude"), f"must be a list of names or patterns, got {exclude!r}"
                    )
                for field_name in ("overrides", "label"):
                    if field_name in raw:
                        raise self.fail(
                            (*where, field_name),
                            f"not allowed with name = {ALL_OPTIMIZERS!r} (give each optimiser "
                            "its own [[optimizers]] table instead)",
                        )
                for each in registered:
                    if not any(fnmatch.fnmatchcase(each, pattern) for pattern in exclude):
                        entries.append(Entry(each, each, "{}", own_budgets))
                continue
            if "exclude" in raw:
                raise self.fail((*where, "exclude"), f"only allowed with name = {ALL_OPTIMIZERS!r}")
            if name not in OPTIMIZERS:
                if optional:
                    notes.append(f"optimizer {name!r} is not registered here: skipped")
                    continue
                raise self.fail(
                    (*where, "name"),
                    f"unknown optimizer {name!r}; allowed: {', '.join(registered)}, "
                    f"or {ALL_OPTIMIZERS!r} for all",
                )
            default = get_optimizer(name)
            overrides = self.overrides_field(where, raw, default, f"optimizer {name!r}")
            try:
                configured = get_optimizer(name, **overrides)
            except (ValueError, TypeError) as err:
                raise self.override_error(where, overrides, err) from None
            entry = self.entry(where, raw, name, default, configured)
            entries.append(dataclasses.replace(entry, budgets=own_budgets))
        self.check_unique(entries, "optimizers")
        return tuple(entries), notes

    def scenarios(self) -> tuple[Entry, ...]:
        if "scenarios" not in self.data:
            return (Entry("paper", "paper", "{}"),)
        entries = []
        for where, raw in self.entries("scenarios"):
            self.check_fields(where, raw, SCENARIO_FIELDS)
            name = self.name_field(where, raw)
            if name not in SCENARIOS:
                raise self.fail(
                    (*where, "name"),
                    f"unknown scenario {name!r}; allowed: {', '.join(sorted(SCENARIOS))}",
                )
            default = get_scenario(name)
            overrides = self.overrides_field(where, raw, default, f"scenario {name!r}")
            try:
                configured = get_scenario(name, **overrides)
            except (ValueError, TypeError) as err:
                raise self.override_error(where, overrides, err) from None
            entries.append(self.entry(where, raw, name, default, configured))
        self.check_unique(entries, "scenarios")
        return tuple(entries)

    def check_settle_time(self, entry: Entry) -> None:
        scenario = get_scenario(entry.name, **from_json_value(json.loads(entry.overrides)))
        end = scenario.timing.n_steps * scenario.timing.period_s
        if scenario.evaluation.settle_time_s > end + 1e-9:
            where = self.find_entry("scenarios", entry)
            raise self.fail(
                (*where, "overrides", "settle_time_s"),
                f"settle_time_s={scenario.evaluation.settle_time_s:g} is after the end of the run "
                f"({end:g} s = n_steps * period_s); lower settle_time_s",
            )

    def check_limits(
        self,
        optimizers: tuple[Entry, ...],
        scenarios: tuple[Entry, ...],
        budgets: tuple[Budget | None, ...],
    ) -> None:
        """Every combination must be a run that finishes (before any of them starts)."""
        for scenario_entry in scenarios:
            scenario = get_scenario(
                scenario_entry.name, **from_json_value(json.loads(scenario_entry.overrides))
            )
            for optimizer_entry in optimizers:
                optimizer = get_optimizer(
                    optimizer_entry.name, **from_json_value(json.loads(optimizer_entry.overrides))
                )
                for budget in optimizer_entry.budgets_or(budgets):
                    try:
                        check_run(scenario, optimizer, solve_budget(budget, optimizer))
                    except LimitError as err:
                        raise self.fail(
                            (), f"{scenario_entry.label} with {optimizer_entry.label}: {err}"
                        ) from None

    def find_entry(self, key: str, entry: Entry) -> tuple[Any, ...]:
        for k, raw in enumerate(self.data.get(key) or []):
            if isinstance(raw, dict) and raw.get("name") == entry.name:
                return (key, k)
        return (key,)

    def check_fields(self, where: tuple[Any, ...], raw: dict[str, Any], allowed: tuple) -> None:
        for key in raw:
            if key not in allowed:
                raise self.fail((*where, key), f"unknown field; allowed: {', '.join(allowed)}")

    def name_field(self, where: tuple[Any, ...], raw: dict[str, Any]) -> str:
        name = raw.get("name")
        if not isinstance(name, str) or not name:
            raise self.fail(where, f'needs name = "..." (a registered name), got {name!r}')
        return name

    def overrides_field(
        self, where: tuple[Any, ...], raw: dict[str, Any], default: Any, owner: str
    ) -> dict[str, Any]:
        overrides = raw.get("overrides", {})
        if not isinstance(overrides, dict):
            raise self.fail(
                (*where, "overrides"), f"must be a table of FIELD = VALUE, got {overrides!r}"
            )
        fields = sorted(flat_fields(default))
        for key in overrides:
            if key not in fields:
                raise self.fail(
                    (*where, "overrides", key),
                    f"unknown field of {owner}; fields: {', '.join(fields)}",
                )
        return {k: from_json_value(v) for k, v in overrides.items()}

    def override_error(
        self, where: tuple[Any, ...], overrides: dict[str, Any], err: BaseException
    ) -> SuiteError:
        message = str(err.args[0]) if err.args else str(err)
        culprit = next((k for k in overrides if re.search(rf"\b{re.escape(k)}\b", message)), None)
        path = (*where, "overrides", culprit) if culprit else (*where, "overrides")
        return self.fail(path, message)

    def entry(
        self, where: tuple[Any, ...], raw: dict[str, Any], name: str, default: Any, configured: Any
    ) -> Entry:
        derived, effective = labelled(name, default, configured)
        label = raw.get("label", derived)
        if not isinstance(label, str) or not label:
            raise self.fail((*where, "label"), f"must be a non-empty string, got {label!r}")
        self.check_label((*where, "label"), label, None if "label" in raw else "the overrides")
        return Entry(label, name, canonical_json(effective))

    def check_label(self, where: tuple[Any, ...], label: str, derived_from: str | None) -> None:
        """``label`` as written, or derived from ``derived_from`` when the file gives none."""
        try:
            check_label(label)
        except LimitError as err:
            if derived_from is None:
                raise self.fail(where, str(err)) from None
            raise self.fail(
                where, f"the name derived from {derived_from}: {err} (give this key a value)"
            ) from None

    def check_unique(self, entries: list[Entry], key: str) -> None:
        labels: dict[str, int] = {}
        configs: dict[tuple[str, str], int] = {}
        for k, entry in enumerate(entries):
            if entry.label in labels:
                raise self.fail(
                    (key, k, "label"),
                    f"label {entry.label!r} is used twice; give each [[{key}]] its own label",
                )
            labels[entry.label] = k
            if (entry.name, entry.overrides) in configs:
                raise self.fail(
                    (key, k),
                    f"{entry.label!r} is the same configuration as "
                    f"{entries[configs[entry.name, entry.overrides]].label!r}",
                )
            configs[entry.name, entry.overrides] = k


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _dotted(where: tuple[Any, ...]) -> str:
    text = ""
    for part in where:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else str(part))
    return text


def run_count(suite: Suite) -> int:
    """Number of runs of a suite, without building them."""
    budgets = sum(len(suite.budgets_of(entry)) for entry in suite.optimizers)
    return len(suite.scenarios) * budgets * len(suite.triggers) * len(suite.seeds)
