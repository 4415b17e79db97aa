"""The disturbance and fault families of a scenario: wind, noise, packet loss, delay, mismatch.

A family claims the disturbance or fault settings it is made of and says when a scenario has
it and how strongly (:class:`ScenarioFamily`). The disturbance and fault settings are every
setting of the ``disturbances`` group and every setting of the ``communication`` group but
those of :data:`NOT_DISTURBANCES` (the graph, the swarm section's business, and how estimates
are extended, a choice of the controller). Each is claimed by one family:
:func:`register_family` refuses a setting another family claims, and
:func:`scenario_families` refuses (:class:`UnclaimedDisturbanceError`) a scenario that departs
from the nominal value of a setting no family claims, so a disturbance added to the harness
without a family is never counted among the nominal runs.

The registry :data:`FAMILIES` is in the order the robustness section lists the families; a
user or a test adds one with :func:`register_family` (and takes it out again with
:func:`unregister_family`), without editing the package.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from formation_bench.mpc.scenario import GROUPS, Scenario
from formation_bench.plugins import DuplicateNameError

NOMINAL = "nominal"
"""The family of a scenario that has none: the runs every disturbed level is compared with."""
JOINED = " + "
"""Joins the names of the families of a scenario that has several (``wind + packet loss``)."""
DISTURBANCE_GROUPS = ("disturbances", "communication")
"""The scenario's setting groups that hold the disturbance and fault settings."""
NOT_DISTURBANCES: dict[str, str] = {
    "estimate_extension": "how a UAV extends a neighbour's plan: a choice of the controller",
    "graph": "who listens to whom: the swarm section compares graphs",
    "graph_neighbours": "a parameter of the graph: the swarm section's",
    "graph_range_m": "a parameter of the graph: the swarm section's",
}
"""The settings of :data:`DISTURBANCE_GROUPS` that are no disturbance or fault, and why."""


@dataclass(frozen=True)
class ScenarioFamily:
    """A kind of disturbance or fault: the settings it is made of, when a scenario has it,
    and how strongly."""

    name: str
    """How the report names the family (and its levels' headings)."""
    settings: tuple[str, ...]
    """The disturbance or fault settings the family claims, by their scenario names."""
    active: Callable[[Scenario], bool]
    """Whether a scenario has the family. A claimed setting may depart from its nominal value
    without it (a gust time constant without gusts changes nothing)."""
    severity: Callable[[Scenario], tuple[float, ...]]
    """Sorts the levels of the family, mildest first."""


class UnclaimedDisturbanceError(ValueError):
    """A scenario departs from the nominal value of a disturbance or fault setting that no
    registered family claims; the message names the setting."""


FAMILIES: list[ScenarioFamily] = []
"""The registered families, in the order the robustness section lists them; add one with
:func:`register_family`."""


def disturbance_settings() -> tuple[str, ...]:
    """Every disturbance and fault setting of the scenario's groups, by name."""
    return tuple(
        field.name
        for group_name in DISTURBANCE_GROUPS
        for field in dataclasses.fields(GROUPS[group_name])
        if field.name not in NOT_DISTURBANCES
    )


def claimed_by(setting_name: str) -> ScenarioFamily | None:
    """The registered family that claims ``setting_name``, or None."""
    return next((f for f in FAMILIES if setting_name in f.settings), None)


def unclaimed_settings() -> tuple[str, ...]:
    """The disturbance and fault settings no registered family claims."""
    return tuple(name for name in disturbance_settings() if claimed_by(name) is None)


def _check_family(family: ScenarioFamily) -> None:
    if not isinstance(family, ScenarioFamily):
        raise TypeError(f"a scenario family must be a ScenarioFamily, got {family!r}")
    if not family.name or family.name == NOMINAL or JOINED.strip() in family.name:
        raise ValueError(
            f"a scenario family's name must be non-empty, not {NOMINAL!r} and without "
            f"{JOINED.strip()!r} (it joins the names of several families), got {family.name!r}"
        )
    if any(f.name == family.name for f in FAMILIES):
        raise DuplicateNameError(f"scenario family {family.name!r} is already registered")
    if not family.settings:
        raise ValueError(f"scenario family {family.name!r} must claim at least one setting")
    known = disturbance_settings()
    for name in family.settings:
        if name not in known:
            why = NOT_DISTURBANCES.get(name, "not a setting of the groups")
            raise ValueError(
                f"scenario family {family.name!r} claims {name!r}, which is no disturbance or "
                f"fault setting ({why}); those are: {', '.join(known)}"
            )
        owner = claimed_by(name)
        if owner is not None:
            raise ValueError(
                f"scenario family {family.name!r} claims Scenario.{name}, already claimed by "
                f"family {owner.name!r}: a setting belongs to one family (unregister "
                f"{owner.name!r} first to split it)"
            )


def register_family(family: ScenarioFamily) -> ScenarioFamily:
    """Add ``family`` after the registered ones; refuses a name already taken and a setting
    another family claims or that is no disturbance or fault setting."""
    _check_family(family)
    FAMILIES.append(family)
    return family


def unregister_family(name: str) -> ScenarioFamily:
    """Take the family ``name`` out of the registry (its settings are then unclaimed until a
    family claims them) and return it."""
    for index, family in enumerate(FAMILIES):
        if family.name == name:
            return FAMILIES.pop(index)
    raise ValueError(
        f"no scenario family {name!r}; registered: {', '.join(f.name for f in FAMILIES)}"
    )


def _departures(scenario: Scenario) -> Iterator[tuple[str, Any]]:
    """The disturbance and fault settings of ``scenario`` off their nominal (default) values."""
    for group_name in DISTURBANCE_GROUPS:
        group = getattr(scenario, group_name)
        for field in dataclasses.fields(group):
            value = getattr(group, field.name)
            if field.name not in NOT_DISTURBANCES and value != _nominal(field):
                yield field.name, value


def _nominal(field: dataclasses.Field) -> Any:
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return field.default


def scenario_families(scenario: Scenario) -> tuple[ScenarioFamily, ...]:
    """The registered families ``scenario`` has, in registry order (none: it is nominal).

    Raises :class:`UnclaimedDisturbanceError` if it departs from the nominal value of a
    disturbance or fault setting that no family claims: such a scenario is disturbed in a way
    no family describes, and counting it as nominal would mix it into the baseline runs."""
    for name, value in _departures(scenario):
        if claimed_by(name) is None:
            raise UnclaimedDisturbanceError(
                f"Scenario.{name} = {value!r} (scenario {scenario.name!r}) is a disturbance or "
                "fault setting that no scenario family claims, so its runs are neither nominal "
                "nor of a family; register a family that claims it "
                "(formation_bench.mpc.families.register_family); families: "
                + ", ".join(f"{f.name} ({', '.join(f.settings)})" for f in FAMILIES)
            )
    return tuple(family for family in FAMILIES if family.active(scenario))


# --- the package's families ------------------------------------------------------------------


def _wind(scenario: Scenario) -> bool:
    disturbances = scenario.disturbances
    return disturbances.gust_std_m_s > 0 or any(w != 0 for w in disturbances.wind_mean_m_s)


def _noise_levels(scenario: Scenario) -> tuple[float, float, float]:
    disturbances = scenario.disturbances
    return (
        disturbances.position_noise_std_m,
        disturbances.heading_noise_std_rad,
        disturbances.speed_noise_std_m_s,
    )


def _mismatch(scenario: Scenario) -> tuple[float, float]:
    disturbances = scenario.disturbances
    return abs(1.0 - disturbances.plant_accel_gain), abs(1.0 - disturbances.plant_turn_rate_gain)


register_family(
    ScenarioFamily(
        "wind",
        ("wind_mean_m_s", "gust_std_m_s", "gust_time_constant_s"),
        _wind,
        lambda s: (math.hypot(*s.disturbances.wind_mean_m_s), s.disturbances.gust_std_m_s),
    )
)
register_family(
    ScenarioFamily(
        "noise",
        ("position_noise_std_m", "heading_noise_std_rad", "speed_noise_std_m_s"),
        lambda s: max(_noise_levels(s)) > 0,
        _noise_levels,
    )
)
register_family(
    ScenarioFamily(
        "packet loss",
        ("packet_loss", "loss_correlation"),
        lambda s: s.communication.packet_loss > 0,
        lambda s: (s.communication.packet_loss, s.communication.loss_correlation),
    )
)
register_family(
    ScenarioFamily(
        "delay",
        ("delay_steps", "delay_jitter_steps"),
        lambda s: s.communication.delay_steps > 0 or s.communication.delay_jitter_steps > 0,
        lambda s: (s.communication.delay_steps, s.communication.delay_jitter_steps),
    )
)
register_family(
    ScenarioFamily(
        "mismatch",
        ("plant_accel_gain", "plant_turn_rate_gain"),
        lambda s: max(_mismatch(s)) > 0,
        _mismatch,
    )
)
