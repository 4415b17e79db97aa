"""Declared config fields: every setting has a doc and a range; out-of-range values fail."""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from formation_bench import fields
from formation_bench.fields import declared, describe_fields, setting, validate_fields
from formation_bench.mpc.scenario import Scenario
from formation_bench.optimizers import OPTIMIZERS, ModifiedBSO, base, get_optimizer
from formation_bench.optimizers.chaos import ChaoticMap

NAMES = sorted(OPTIMIZERS)


def config_fields(obj: object) -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(obj) if f.init and not f.name.startswith("_")]


@pytest.mark.parametrize("name", NAMES)
def test_every_field_of_every_registered_optimizer_is_declared_with_doc_and_range(name: str):
    optimizer = get_optimizer(name)
    infos = {info.name: info for info in describe_fields(optimizer)}
    for field in config_fields(optimizer):
        assert field.name in infos, f"{name}: {field.name} is not declared with setting()"
        info = infos[field.name]
        assert info.doc and "\n" not in info.doc, f"{name}: {field.name} has no one-line doc"
        assert info.allowed, f"{name}: {field.name} has no allowed range"
        assert info.value == getattr(optimizer, field.name)


def test_every_scenario_field_is_declared_with_doc_and_range():
    infos = describe_fields(Scenario)
    assert [i.name for i in infos] == [f.name for f in dataclasses.fields(Scenario)]
    assert all(i.doc and i.allowed for i in infos)


def out_of_range(obj: object, spec: fields.Setting) -> list[object]:
    """Values the declaration must refuse (read against ``obj`` for limits naming a field)."""
    limit = fields._limit
    none = [] if spec.optional else [None]
    if spec.kind == "bool":
        return ["yes", 1, *none]
    if spec.kind == "enum":
        return ["no-such-member", True, *none]
    if spec.kind == "choice":
        return ["no-such-choice", *none]
    if spec.kind == "int":
        bad: list[object] = [limit(obj, spec.low) - 1, 2.5, True, "3", *none]
        if spec.high is not None:
            bad.append(limit(obj, spec.high) + 1)
        return bad
    if spec.kind == "real":
        low, high = limit(obj, spec.low), limit(obj, spec.high)
        bad = [math.nan, math.inf, "0.5", False, *none]
        if low is not None:
            bad.append(low if spec.low_open else low - 1.0)
        if high is not None:
            bad.append(high if spec.high_open else high + 1.0)
        return bad
    return [object()] if spec.check is not None else []


@pytest.mark.parametrize("name", NAMES)
def test_validate_fields_rejects_each_out_of_range_value_naming_the_field(name: str):
    optimizer = get_optimizer(name)
    owner = type(optimizer).__name__
    checked = 0
    for field in config_fields(optimizer):
        spec = declared(field)
        assert spec is not None
        for value in out_of_range(optimizer, spec):
            with pytest.raises(ValueError, match=rf"^{owner}\.{field.name} must"):
                dataclasses.replace(optimizer, **{field.name: value})
            checked += 1
    assert checked >= len(config_fields(optimizer))


@pytest.mark.parametrize("name", NAMES)
def test_declared_defaults_and_registered_values_pass_their_own_checks(name: str):
    optimizer = get_optimizer(name)
    again = dataclasses.replace(optimizer)
    assert again == optimizer


def test_messages_keep_their_wording():
    with pytest.raises(ValueError) as info:
        ModifiedBSO(n_clusters=40)
    assert str(info.value) == "ModifiedBSO.n_clusters must be an integer in [1, 30], got 40"
    with pytest.raises(ValueError) as info:
        ModifiedBSO(weight_map="x")
    allowed = ", ".join(m.name.lower() for m in ChaoticMap)
    assert str(info.value) == f"ModifiedBSO.weight_map must be one of {allowed}, got 'x'"
    with pytest.raises(ValueError) as info:
        ModifiedBSO(slope=0.0)
    assert str(info.value) == "ModifiedBSO.slope must be a finite number in (0.0, inf), got 0.0"
    with pytest.raises(ValueError) as info:
        ModifiedBSO(population_size=1)
    assert str(info.value) == "ModifiedBSO.population_size must be an integer >= 2, got 1"


def test_values_are_normalised():
    optimizer = ModifiedBSO(
        population_size=np.int64(20),
        slope=np.float32(4),
        weight_map="Tent",
        normalise_weights=np.True_,
    )
    assert type(optimizer.population_size) is int and optimizer.population_size == 20
    assert type(optimizer.slope) is float and optimizer.slope == 4.0
    assert optimizer.weight_map is ChaoticMap.TENT
    assert optimizer.normalise_weights is True


def test_a_cross_field_limit_reads_the_other_field():
    assert ModifiedBSO(population_size=8, n_clusters=8).n_clusters == 8
    with pytest.raises(ValueError, match=r"n_clusters must be an integer in \[1, 8\], got 9"):
        ModifiedBSO(population_size=8, n_clusters=9)


@dataclasses.dataclass(frozen=True)
class Example:
    count: int = setting(3, low=1, high=lambda obj: int(2 * obj.size), doc="A count")
    size: float = setting(1.5, low=0.0, high=2.0, high_open=True, doc="A size")
    limit: int | None = setting(None, kind=int, optional=True, low=0, doc="An optional limit")
    mode: str = setting("a", choices=("a", "b"), doc="A mode")
    pair: tuple[int, int] = setting((1, 2), allowed="two integers", doc="A pair")

    def __post_init__(self) -> None:
        validate_fields(self)


def test_open_ends_optional_values_callables_and_choices():
    assert Example(size=1.99).size == 1.99
    with pytest.raises(ValueError, match=r"Example\.size must be a finite number in \[0.0, 2.0\)"):
        Example(size=2.0)
    assert Example(limit=None).limit is None and Example(limit=4).limit == 4
    with pytest.raises(ValueError, match=r"Example\.limit must be an integer >= 0, got -1"):
        Example(limit=-1)
    with pytest.raises(ValueError, match=r"Example\.count must be an integer in \[1, 3\]"):
        Example(count=4)  # count is checked before size: the limit reads the given size
    with pytest.raises(ValueError, match=r"Example\.mode must be one of a, b, got 'c'"):
        Example(mode="c")
    infos = {i.name: i for i in describe_fields(Example)}
    assert infos["size"].allowed == "finite number in [0.0, 2.0)"
    assert infos["limit"].allowed == "integer >= 0, or None"
    assert infos["mode"].allowed == "one of a, b"
    assert infos["pair"].allowed == "two integers"
    assert infos["count"].type == "int" and infos["count"].default == 3


def test_describe_fields_of_a_registered_configuration():
    infos = {i.name: i for i in describe_fields(get_optimizer("modified-bso-tent"))}
    assert infos["n_clusters"].allowed == "integer in [1, population_size]"
    assert infos["weight_map"].default is ChaoticMap.LOGISTIC
    assert infos["weight_map"].value is ChaoticMap.TENT
    assert infos["weight_map"].type == "ChaoticMap"


def test_a_setting_needs_a_one_line_doc_and_a_known_kind():
    with pytest.raises(ValueError, match="one-line doc"):
        setting(1, low=0, doc="")
    with pytest.raises(TypeError, match="kind"):
        setting([1], doc="a list")
    with pytest.raises(ValueError, match="needs low"):
        setting(1, doc="no low")


def test_the_old_helpers_are_still_importable_from_base():
    for name in ("check_int", "check_real", "check_bool", "coerce_enum"):
        assert getattr(base, name) is getattr(fields, name)


# --- the registry keeper: every name maps to the configuration recorded for it ----------------
# tests/data/registry.json records, for every registered name, the class, the description and
# the fields that differ from the class's defaults, and every class's defaults (enum members by
# lower-case name), so that a default or a variant changed by accident shows up here. A name
# registered since is recorded by the keeper itself (the test fails once, saying so); a change
# to a recorded name fails until it is accepted with FORMATION_BENCH_ACCEPT_REGISTRY=1.

REGISTRY_FILE = Path(__file__).parent / "data" / "registry.json"
ACCEPT = "FORMATION_BENCH_ACCEPT_REGISTRY"


def plain(value: object) -> object:
    value = value.name.lower() if isinstance(value, enum.Enum) else value
    return json.loads(json.dumps(value))  # tuples as lists, as the file holds them


def field_values(obj: object) -> dict[str, object]:
    return {f.name: plain(getattr(obj, f.name)) for f in config_fields(obj)}


def registry_now() -> dict[str, dict]:
    """The registry as the file records it (adapters whose library is missing left out)."""
    optimizers: dict[str, dict] = {}
    defaults: dict[str, dict] = {}
    for name in sorted(OPTIMIZERS):
        entry = OPTIMIZERS[name]
        class_name = type(entry.optimizer).__name__
        defaults[class_name] = field_values(type(entry.optimizer)())
        values = field_values(entry.optimizer)
        optimizers[name] = {
            "class": class_name,
            "description": entry.description,
            "overrides": {k: v for k, v in values.items() if v != defaults[class_name].get(k)},
        }
    return {"optimizers": optimizers, "class_defaults": dict(sorted(defaults.items()))}


def registry_changes(recorded: dict, now: dict, missing: set[str]) -> tuple[list[str], list[str]]:
    """``(added, changed)``: names (and classes) new since the record, and every difference
    from it, each as a line saying what differs. Names in ``missing`` (adapters whose library
    is not installed) and classes only they use are not expected."""
    expected_classes = {v["class"] for k, v in recorded["optimizers"].items() if k not in missing}
    added, changed = [], []
    for section in ("optimizers", "class_defaults"):
        old, new = recorded[section], now[section]
        expected = (set(old) - missing) if section == "optimizers" else expected_classes
        for key in sorted(set(old) | set(new)):
            if key not in new:
                if key in expected:
                    changed.append(f"{section}: {key} is recorded but no longer registered")
            elif key not in old:
                added.append(f"{section}: {key}")
            elif old[key] != new[key]:
                changed.append(f"{section}: {key} was {old[key]}, is now {new[key]}")
    return added, changed


def test_the_registry_is_the_recorded_one():
    recorded = json.loads(REGISTRY_FILE.read_text())
    now = registry_now()
    missing = set(OPTIMIZERS.missing())
    added, changed = registry_changes(recorded, now, missing)
    accept = os.environ.get(ACCEPT) == "1"
    if added or (changed and accept):
        merged = {
            section: now[section] if accept else {**recorded[section], **now[section]}
            for section in ("optimizers", "class_defaults")
        }
        REGISTRY_FILE.write_text(json.dumps(merged, indent=1, sort_keys=True) + "\n")
    if added and not accept:
        pytest.fail(
            f"recorded {len(added)} new registry entries in {REGISTRY_FILE.name}: "
            + "; ".join(added)
            + ". Check the recorded configuration, commit the file and run the tests again."
        )
    assert accept or not changed, (
        "the registry differs from tests/data/registry.json:\n  "
        + "\n  ".join(changed)
        + f"\nIf the change is meant, run the tests once with {ACCEPT}=1 and commit the file."
    )


def test_the_keeper_tells_new_names_from_changed_ones():
    recorded = {
        "optimizers": {"a": {"class": "A", "description": "x", "overrides": {}}},
        "class_defaults": {"A": {"n": 1}},
    }
    now = {
        "optimizers": {
            "a": {"class": "A", "description": "y", "overrides": {}},
            "b": {"class": "A", "description": "z", "overrides": {"n": 2}},
        },
        "class_defaults": {"A": {"n": 1}},
    }
    added, changed = registry_changes(recorded, now, set())
    assert added == ["optimizers: b"]
    assert len(changed) == 1 and "a was" in changed[0] and "'y'" in changed[0]
    gone, changed = registry_changes(now, recorded, set())
    assert gone == [] and any("b is recorded but no longer registered" in c for c in changed)
    assert not any("b is recorded" in c for c in registry_changes(now, recorded, {"b"})[1])


@dataclasses.dataclass(frozen=True)
class _DeclaredOnly(base.Optimizer):
    """Declares its setting but never validates it itself (no ``Validated``)."""

    population_size: int = setting(4, low=1, doc="Points per iteration")

    @property
    def default_budget(self) -> base.Budget:
        return base.Budget(max_iterations=1)

    def minimize(self, objective, bounds, rng, budget=None, x0=None):  # pragma: no cover
        raise AssertionError("only registered and configured here, never asked to solve")


@dataclasses.dataclass(frozen=True)
class _Undeclared(_DeclaredOnly):
    max_iterations: int = 3


def test_the_registry_checks_declared_settings_and_refuses_undeclared_ones():
    from formation_bench.optimizers import register

    try:
        register("declared-only", _DeclaredOnly(), "settings checked by the registry")
        assert get_optimizer("declared-only", population_size=2).population_size == 2
        with pytest.raises(ValueError, match=r"_DeclaredOnly\.population_size must be an integer"):
            get_optimizer("declared-only", population_size=0)
        with pytest.raises(ValueError, match=r"_DeclaredOnly\.population_size must be"):
            register("declared-bad-default", _DeclaredOnly(population_size=0), "a bad default")
        with pytest.raises(TypeError, match=r"declare max_iterations of _Undeclared with"):
            register("undeclared", _Undeclared(), "a field without setting()")
        assert "declared-bad-default" not in OPTIMIZERS and "undeclared" not in OPTIMIZERS
    finally:
        OPTIMIZERS.pop("declared-only", None)


# --- what a tuner searches ---------------------------------------------------------------------


def test_a_search_is_checked_against_the_kind_of_its_setting():
    with pytest.raises(ValueError, match="the search of an int setting needs low and high only"):
        setting(3, low=1, doc="A count", search=fields.Search(choices=(1, 2)))
    with pytest.raises(ValueError, match="needs low and high only"):
        setting(0.5, doc="A share", search=fields.Search(0.1))
    with pytest.raises(ValueError, match="the search of a bool setting takes choices only"):
        setting(True, doc="A switch", search=fields.Search(0, 1))
    with pytest.raises(ValueError, match="the search of a enum setting takes choices only"):
        setting(ChaoticMap.TENT, doc="A map", search=fields.Search(log=True))
    with pytest.raises(ValueError, match="a custom setting cannot be searched"):
        setting((1, 2), allowed="two integers", doc="A pair", search=fields.Search(0, 1))
    with pytest.raises(TypeError, match=r"search must be a formation_bench\.fields\.Search"):
        setting(3, low=1, doc="A count", search=(1, 5))  # type: ignore[arg-type]


def test_a_search_needs_low_below_high_and_a_positive_low_on_a_log_scale():
    with pytest.raises(ValueError, match="search low must be below high, got 5, 5"):
        setting(5, low=1, doc="A count", search=fields.Search(5, 5))
    with pytest.raises(ValueError, match=r"search low must be below high, got 0\.9, 0\.1"):
        setting(0.5, doc="A share", search=fields.Search(0.9, 0.1))
    with pytest.raises(ValueError, match=r"a log-scale search needs low > 0, got 0\.0"):
        setting(0.5, doc="A share", search=fields.Search(0.0, 1.0, log=True))
    # limits naming a field or computed from one are checked when the space is resolved
    assert setting(2, low=1, doc="A count", search=fields.Search(1, "size")) is not None


@dataclasses.dataclass(frozen=True)
class Searched:
    size: int = setting(8, low=2, doc="A size", search=fields.Search(4, 100, log=True))
    count: int = setting(
        3, low=1, high="size", doc="A count", search=fields.Search(2, lambda o: o.size // 2)
    )
    rate: float = setting(0.5, low=0.0, high=1.0, doc="A rate", search=fields.Search(0.0, 1.0))
    map: ChaoticMap = setting(ChaoticMap.TENT, doc="A map", search=fields.Search())
    some: ChaoticMap = setting(
        ChaoticMap.TENT, doc="Some maps", search=fields.Search(choices=("tent", "sine"))
    )
    switch: bool = setting(False, doc="A switch", search=fields.Search())
    fixed: float = setting(1.0, doc="Not searched")

    def __post_init__(self) -> None:
        validate_fields(self)


def test_search_text_and_resolved_ranges():
    infos = {i.name: i for i in describe_fields(Searched)}
    assert infos["size"].search == "searched: [4, 100] log"
    assert infos["rate"].search == "searched: [0.0, 1.0]"
    assert infos["map"].search == "searched: " + ", ".join(m.name.lower() for m in ChaoticMap)
    assert infos["some"].search == "searched: tent, sine"
    assert infos["switch"].search == "searched: False, True"
    assert infos["fixed"].search == "not tuned"
    spec = {f.name: declared(f) for f in dataclasses.fields(Searched)}
    assert fields.search_bounds(Searched(size=40), spec["count"]) == (2, 20)
    assert fields.search_bounds(Searched(), spec["size"]) == (4, 100)
    assert fields.searched_values(spec["some"]) == ("tent", "sine")
