"""What a tuner searches: the search declared on each optimiser's settings, checked for every
registered configuration (a plugin's the same way) against what is valid, the default, the
budget, the variants, and the solves themselves."""

from __future__ import annotations

import dataclasses
import math
import re
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import Recorder, budget_settings

from formation_bench.cli.main import shown_value
from formation_bench.fields import (
    Setting,
    check_value,
    declared,
    member_text,
    search_bounds,
    search_text,
    searched_values,
)
from formation_bench.optimizers import OPTIMIZERS, Bounds, Budget, Optimizer
from formation_bench.optimizers.tuned import is_tuned


def searched(optimizer: Any) -> list[tuple[str, Setting]]:
    """``(name, declaration)`` of each searched setting, in declaration order."""
    return [
        (f.name, spec)
        for f in dataclasses.fields(optimizer)
        if (spec := declared(f)) is not None and spec.search is not None
    ]


TUNED = sorted(name for name in OPTIMIZERS if searched(OPTIMIZERS[name].optimizer))
KNOBS = [name for name in TUNED if not is_tuned(name)]
"""The names whose settings are checked to be real knobs: a tuned variant is another
configuration of a class its base already covers, and at a tuned point a setting may move
nothing on the small test problem (one choice probability under another near 0 or 1)."""

FAMILIES = {
    "modified-bso": ("modified-bso", "modified-bso-no-chaos-replacement",
                     "modified-bso-no-all-centre", "modified-bso-no-modifications"),
    "original-bso": ("original-bso",),
    "pso": ("pso",),
    "de": ("de",),
    "cma-es": ("cma-es",),
    "mppi": ("mppi",),
    "cem": ("cem", "icem"),
    "predictive-sampling": ("predictive-sampling",),
}  # fmt: skip
"""The families every tuning covers, by the registered names tuned."""

VARIANT_SWITCHES = {
    "ModifiedBSO": ("chaos_replacement", "all_centre_weighting", "replacement_map", "weight_map",
                    "normalise_weights", "step_relative_to_range"),
    "OriginalBSO": ("step_relative_to_range",),
    "ChaoticLocalSearchBSO": ("step_relative_to_range", "local_map"),
    "PSO": ("chaotic_coefficients", "coefficient_map", "chaotic_inertia", "inertia_map"),
    "DifferentialEvolution": ("strategy", "updating"),
    "CMAES": ("restarts", "constants", "active"),
    "MPPI": ("smoothing_window", "temperature_scale"),
    "CEM": ("noise_exponent", "keep_elites", "sample_decay", "sample_mean_last"),
    "PredictiveSampling": ("plan_channels",),
}  # fmt: skip
"""Per class, the settings that make a registered variant (or the units of a searched one):
a tuned variant must stay the method it is named after, so none of them is searched."""


def as_written(value: Any) -> Any:
    return member_text(value) if hasattr(value, "name") and hasattr(value, "value") else value


def resolved_corner(optimizer: Any, end: int) -> dict[str, Any]:
    """Every numeric searched setting at one end of its search (0: low, 1: high), resolved in
    declaration order against the values chosen before it, as a tuner builds its space."""
    values: dict[str, Any] = {}
    for name, spec in searched(optimizer):
        if spec.kind in ("int", "real"):
            view = types.SimpleNamespace(**{**vars_of(optimizer), **values})
            values[name] = search_bounds(view, spec)[end]
    return values


def vars_of(optimizer: Any) -> dict[str, Any]:
    return {f.name: getattr(optimizer, f.name) for f in dataclasses.fields(optimizer)}


@pytest.mark.parametrize("name", TUNED)
def test_each_search_lies_inside_the_valid_range_and_holds_the_registered_value(name: str):
    optimizer = OPTIMIZERS[name].optimizer
    owner = type(optimizer).__name__
    for field, spec in searched(optimizer):
        value = getattr(optimizer, field)
        if spec.kind in ("int", "real"):
            low, high = search_bounds(optimizer, spec)
            assert low < high, f"{name}: {field} searches [{low}, {high}]"
            for end in (low, high):
                assert check_value(optimizer, owner, field, spec, end) == end, (name, field)
            if spec.kind == "int":
                assert type(low) is int and type(high) is int, (name, field)
            assert low <= value <= high, f"{name}: {field} = {value} outside [{low}, {high}]"
            assert not spec.search.log or low > 0
        else:
            choices = searched_values(spec)
            for choice in choices:
                check_value(optimizer, owner, field, spec, choice)
            assert as_written(value) in choices, f"{name}: {field} = {value} not in {choices}"


@pytest.mark.parametrize("name", TUNED)
def test_every_corner_of_the_search_is_a_valid_configuration(name: str):
    # the limits that read another setting must stay valid wherever that setting is searched
    optimizer = OPTIMIZERS[name].optimizer
    owner = type(optimizer).__name__
    for end in (0, 1):
        values = resolved_corner(optimizer, end)
        view = types.SimpleNamespace(**{**vars_of(optimizer), **values})
        for field, spec in searched(optimizer):
            if spec.kind in ("int", "real"):
                low, high = search_bounds(view, spec)
                assert low < high, f"{name}: {field} searches [{low}, {high}] at {values}"
                for limit in (low, high):
                    check_value(view, owner, field, spec, limit)
        dataclasses.replace(optimizer, **values)


@pytest.mark.parametrize("name", TUNED)
def test_no_budget_setting_is_searched(name: str):
    optimizer = OPTIMIZERS[name].optimizer
    budget = set(budget_settings(optimizer))
    assert budget, name
    assert not budget & {field for field, _ in searched(optimizer)}, name


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_every_family_searches_something(family: str):
    for name in FAMILIES[family]:
        assert searched(OPTIMIZERS[name].optimizer), f"{family}: {name} searches nothing"


@pytest.mark.parametrize("name", TUNED)
def test_the_settings_that_make_a_variant_are_not_searched(name: str):
    optimizer = OPTIMIZERS[name].optimizer
    cls = type(optimizer)
    if cls.__name__ not in VARIANT_SWITCHES:
        pytest.skip(f"{cls.__name__} is not one of this package's families (a plugin's)")
    switches = set(VARIANT_SWITCHES[cls.__name__])
    assert switches <= {f.name for f in dataclasses.fields(optimizer)}, cls.__name__
    assert not switches & {field for field, _ in searched(optimizer)}, name
    # and the list is complete: whatever else tells two registered names of the class apart
    # is searched, a budget, or an implementation choice that gives the same result
    same = {"clustering"}
    for other in OPTIMIZERS.values():
        if type(other.optimizer) is not cls:
            continue
        for field in vars_of(optimizer):
            if getattr(other.optimizer, field) != getattr(optimizer, field):
                known = switches | same | set(budget_settings(optimizer))
                assert field in known | {f for f, _ in searched(optimizer)}, (name, other.name)


# --- every searched setting is a knob: its ends change a small solve ---------------------------

DIM = 6
BOX = Bounds(np.full(DIM, -1.0), np.full(DIM, 1.0))
TARGET = np.array([0.95, -0.3, 1.3, 0.1, -0.8, 0.5])
"""The quadratic's minimum: off-centre, one coordinate outside the box, so that the bound
handling matters."""
WARM_START = np.array([0.9, -0.25, 0.97, 0.15, -0.75, 0.45])
"""Near the minimum, so that the moves around it cross the box's face."""
BUDGET = Budget(max_evaluations=300)


def quadratic(x: np.ndarray) -> np.ndarray:
    z = (x - TARGET) * np.arange(1.0, DIM + 1.0)
    return np.einsum("ij,ij->i", z, z)


def solve(optimizer: Optimizer) -> np.ndarray:
    """What a solve did: every point it evaluated, in order, then its result's point and cost
    (a probability changes what is tried before it changes what is found)."""
    recorder = Recorder(quadratic)
    result = optimizer.minimize(recorder, BOX, np.random.default_rng(7), BUDGET, WARM_START)
    return np.concatenate([recorder.points.ravel(), result.x, [result.fun]])


INERT = {
    "warm_start_spread": lambda o: o.warm_start_share == 0.0,
    "p_replace": lambda o: not getattr(o, "chaos_replacement", True),
    "n_replace": lambda o: not o.chaos_replacement,
    "p_one_cluster": lambda o: getattr(o, "all_centre_weighting", False),
    "p_one_centre": lambda o: getattr(o, "all_centre_weighting", False),
    "p_two_centres": lambda o: getattr(o, "all_centre_weighting", False),
}
"""Settings another, unsearched setting of the configuration switches off: changing them
must then change nothing (which is checked too)."""


def ends(optimizer: Any, field: str, spec: Setting) -> list[Any]:
    """The values of ``field`` to try besides the configuration's: its search's ends, or every
    other value searched."""
    value = getattr(optimizer, field)
    if spec.kind in ("int", "real"):
        candidates = list(search_bounds(optimizer, spec))
    else:
        candidates = list(searched_values(spec))
    return [v for v in candidates if v != as_written(value)]


def with_value(optimizer: Any, field: str, value: Any) -> Any:
    """``optimizer`` with ``field`` at ``value``; a later setting whose valid range this moves
    (clusters <= population) brought into its search range, as a tuner's space does."""
    owner = type(optimizer).__name__
    values = {field: value}
    names = [name for name, _ in searched(optimizer)]
    for later, spec in searched(optimizer)[names.index(field) + 1 :]:
        if spec.kind not in ("int", "real"):
            continue
        view = types.SimpleNamespace(**{**vars_of(optimizer), **values})
        try:
            check_value(view, owner, later, spec, getattr(optimizer, later))
        except ValueError:
            low, high = search_bounds(view, spec)
            values[later] = min(max(getattr(optimizer, later), low), high)
    return dataclasses.replace(optimizer, **values)


# slow: about 2.6 s for every registered name together (the kernels compiled)
@pytest.mark.slow
@pytest.mark.parametrize("name", KNOBS)
def test_each_searched_setting_changes_a_small_solve(name: str):
    optimizer = OPTIMIZERS[name].optimizer
    base = solve(optimizer)
    assert np.array_equal(base, solve(optimizer))  # the comparison is of settings alone
    for field, spec in searched(optimizer):
        inert = field in INERT and INERT[field](optimizer)
        for value in ends(optimizer, field, spec):
            changed = solve(with_value(optimizer, field, value))
            same = changed.shape == base.shape and np.array_equal(changed, base)
            assert same == inert, f"{name}: {field} = {value} {'changes' if inert else 'keeps'}"
        assert math.isfinite(base[-1])


# --- the explanation page's tables are the declarations ----------------------------------------

PAGE = Path(__file__).parents[1] / "docs" / "explanation" / "optimizers.md"


def page_tables() -> dict[str, list[tuple[str, str, str]]]:
    """``{registered name: [(setting, searched, default)]}`` of each table under "What a tuner
    searches", by the first name in its heading."""
    section = PAGE.read_text().split("## What a tuner searches\n", 1)[1].split("\n## ", 1)[0]
    tables = {}
    for part in section.split("\n### ")[1:]:
        heading, body = part.split("\n", 1)
        name = re.search(r"`([^`]+)`", heading).group(1)  # type: ignore[union-attr]
        rows = [line.strip("|").split("|") for line in body.splitlines() if line.startswith("| `")]
        tables[name] = [tuple(cell.strip().strip("`") for cell in row) for row in rows]
    return tables


def test_the_page_shows_every_family_s_search_as_declared():
    tables = page_tables()
    assert set(FAMILIES) <= set(tables)
    for name, rows in tables.items():
        optimizer = OPTIMIZERS[name].optimizer
        declared_rows = [
            (field, search_text(spec).removeprefix("searched: "),
             shown_value(getattr(optimizer, field)))
            for field, spec in searched(optimizer)
        ]  # fmt: skip
        assert rows == declared_rows, name
