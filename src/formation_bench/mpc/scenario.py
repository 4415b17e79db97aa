"""Scenarios: everything the DMPC harness needs, as one validated dataclass, and their registry.

A :class:`Scenario` holds the formation (initial states, offsets, reference path) and its
settings in named groups (:mod:`formation_bench.mpc.scenario_groups`): ``timing``,
``limits``, ``weights``, ``trigger``, ``evaluation``, ``communication``, ``disturbances`` and
``safety``. A setting's name is unique across the groups, so ``with_overrides`` and
``get_scenario`` take it flat (``n_steps=3``) or with its group (``timing.n_steps``).

The default is the paper's Section 3 scenario; the choices the paper leaves
open (reference path, formation frame, estimate extension, decision blocking,
weights) are fields with documented defaults, so a sweep can vary them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.fields import setting, validate_fields
from formation_bench.mpc.formations import (
    FormationShape,
    formation_offsets,
    scattered_initial_states,
)
from formation_bench.mpc.reference import REFERENCE_PATHS, ReferencePath
from formation_bench.mpc.scenario_groups import (
    MAX_ACCEL_M_S2,
    CommunicationGraph,
    CommunicationSettings,
    ControlLimits,
    CostWeights,
    DisturbanceSettings,
    EstimateExtension,
    EvaluationSettings,
    FormationFrame,
    SafetySettings,
    SettingGroup,
    TimingSettings,
    TriggerSettings,
    check_settings,
    check_within,
    is_number,
    number_array,
)
from formation_bench.plugins import SCENARIO_GROUP, Registry

__all__ = [
    "GROUPS",
    "GROUP_OF",
    "MAX_ACCEL_M_S2",
    "PAPER",
    "SCENARIOS",
    "SWARM_SIZES",
    "TOP_LEVEL",
    "CommunicationGraph",
    "CommunicationSettings",
    "ControlLimits",
    "CostWeights",
    "DisturbanceSettings",
    "EstimateExtension",
    "EvaluationSettings",
    "FormationFrame",
    "SafetySettings",
    "Scenario",
    "TimingSettings",
    "TriggerSettings",
    "get_scenario",
    "register_scenario",
    "swarm_scenario",
]


_GROUP_VALUES = "the group (see its class), or a table of some of its fields"
"""What a group field takes, in words."""


def _as_group(owner: str, name: str, value: object) -> SettingGroup:
    """The group field ``name``'s value: a group, or a table of some of its fields (the others
    keep their defaults)."""
    group_class = GROUPS[name]
    if isinstance(value, group_class):
        return value
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - set(_field_names(group_class)))
        if unknown:
            raise ValueError(
                f"unknown field(s) {', '.join(map(str, unknown))} of scenario group {name}; "
                f"its fields: {', '.join(_field_names(group_class))}"
            )
        return group_class(**value)
    raise ValueError(
        f"{owner}.{name} must be a {group_class.__name__} or a table of its fields, got {value!r}"
    )


@dataclass(frozen=True)
class Scenario:
    """A formation-control scenario and the DMPC settings that go with it."""

    name: str = setting("paper", allowed="any string", doc="Name used in results")
    initial_states: tuple[tuple[float, float, float, float], ...] = setting(
        (
            (-7.08, -17.96, math.radians(68.02), 13.12),
            (-18.48, -5.25, math.radians(14.74), 15.43),
            (-15.46, 11.29, math.radians(-35.97), 16.83),
        ),
        allowed="at least 2 finite (x, y, heading, speed) tuples",
        doc="Initial (x m, y m, heading rad, speed m/s) of every UAV (Table 1)",
    )
    formation_offsets: tuple[tuple[float, float], ...] = setting(
        ((10.0 / 3.0, -10.0), (-20.0 / 3.0, 0.0), (10.0 / 3.0, 10.0)),
        allowed="one (x, y) per UAV, zero mean",
        doc="Desired position of every UAV relative to the formation centre, m, in formation_frame",
    )
    """Their mean must be zero (the centre is the UAVs' mean). The default is the paper's
    isosceles right triangle: hypotenuse 20 m between UAV 1 and UAV 3 across the path, UAV 2 at
    the right angle trailing."""
    formation_frame: FormationFrame = setting(
        FormationFrame.PATH,
        doc="Frame of the offsets: turning with the reference heading, or fixed in the world",
    )
    reference: str = setting(
        "turn",
        choices=lambda: sorted(REFERENCE_PATHS),
        doc="Reference path of the formation centre: one of REFERENCE_PATHS",
    )
    reference_start: tuple[float, float] | None = setting(
        None,
        optional=True,
        allowed="two finite numbers",
        doc="Where the reference path starts at t = 0, m; None = the UAVs' initial centre",
    )
    """None means the UAVs' mean initial position."""
    timing: TimingSettings = setting(
        TimingSettings(), check=_as_group, allowed=_GROUP_VALUES,
        doc="Control period, horizon and its blocks, RK4 sub-steps, run length",
    )  # fmt: skip
    limits: ControlLimits = setting(
        ControlLimits(), check=_as_group, allowed=_GROUP_VALUES,
        doc="Bounds on the controls, common or per UAV",
    )  # fmt: skip
    weights: CostWeights = setting(
        CostWeights(), check=_as_group, allowed=_GROUP_VALUES,
        doc="Weights of the local cost's terms, eq. (14)",
    )  # fmt: skip
    trigger: TriggerSettings = setting(
        TriggerSettings(), check=_as_group, allowed=_GROUP_VALUES,
        doc="The event trigger, eqs. (15)-(17)",
    )  # fmt: skip
    evaluation: EvaluationSettings = setting(
        EvaluationSettings(), check=_as_group, allowed=_GROUP_VALUES,
        doc="Settle time and settling bands of the metrics",
    )  # fmt: skip
    communication: CommunicationSettings = setting(
        CommunicationSettings(), check=_as_group, allowed=_GROUP_VALUES,
        doc="Communication graph, lost and late plans, extension of neighbour estimates",
    )  # fmt: skip
    disturbances: DisturbanceSettings = setting(
        DisturbanceSettings(), check=_as_group, allowed=_GROUP_VALUES,
        doc="Wind, measurement noise and model mismatch (off by default)",
    )  # fmt: skip
    safety: SafetySettings = setting(
        SafetySettings(), check=_as_group, allowed=_GROUP_VALUES,
        doc="Obstacles, safety radius and their penalties (off by default)",
    )  # fmt: skip

    def __post_init__(self) -> None:
        validate_fields(self)
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Scenario.name must be a non-empty string, got {self.name!r}")
        # the structured fields are checked together, after the declared ranges
        states = number_array("initial_states", self.initial_states)
        offsets = number_array("formation_offsets", self.formation_offsets)
        if states.ndim != 2 or states.shape[1] != 4 or states.shape[0] < 2:
            raise ValueError(
                "Scenario.initial_states must be a list of at least 2 (x, y, heading, speed) "
                f"tuples, got shape {states.shape}"
            )
        if not np.all(np.isfinite(states)):
            raise ValueError("Scenario.initial_states must be finite")
        if offsets.shape != (states.shape[0], 2):
            raise ValueError(
                f"Scenario.formation_offsets must hold one (x, y) per UAV "
                f"({states.shape[0]}), got shape {offsets.shape}"
            )
        if not np.allclose(offsets.mean(axis=0), 0.0, atol=1e-9):
            raise ValueError(
                "Scenario.formation_offsets must have zero mean (offsets are relative to the "
                f"formation centre), got mean {offsets.mean(axis=0).tolist()}"
            )
        if self.reference_start is not None and (
            not isinstance(self.reference_start, tuple | list)
            or len(self.reference_start) != 2
            or not all(is_number(c) for c in self.reference_start)
            or not all(math.isfinite(c) for c in self.reference_start)
        ):
            raise ValueError(
                f"Scenario.reference_start must be None or two finite numbers, "
                f"got {self.reference_start!r}"
            )
        self._check_across_groups()

    def _check_across_groups(self) -> None:
        """The checks that read several groups or the number of UAVs."""
        values = self.setting_values()
        for group_name in GROUPS:
            # a range end naming a setting of another group (trigger_lookahead_steps)
            check_settings(getattr(self, group_name), values)
        limits, timing, communication = self.limits, self.timing, self.communication
        limits.per_uav_rows(self.n_uav)
        if (
            communication.graph == CommunicationGraph.K_NEAREST
            and communication.graph_neighbours >= self.n_uav
        ):
            raise ValueError(
                f"Scenario.graph_neighbours must be below the number of UAVs ({self.n_uav}) "
                f"on the k-nearest graph, got {communication.graph_neighbours}"
            )
        turn_limit = math.pi / timing.period_s
        for name in ("turn_rate_bounds", "uav_turn_rate_bounds"):
            check_within(
                name, getattr(limits, name), turn_limit, "half a turn per period: pi / period_s"
            )
        if communication.delay_steps > 0 and communication.delay_steps + 1 >= timing.n_steps:
            raise ValueError(
                f"Scenario.delay_steps must be below n_steps - 1 = {timing.n_steps - 1} (a plan "
                "arrives delay_steps + 1 instants after it is sent, so no plan would reach a "
                f"neighbour before the run ends), got {communication.delay_steps}"
            )

    def __hash__(self) -> int:
        # every solve looks its problem's decision space and penalties up by scenario: hashing
        # every field each time cost more than the lookup saves
        cached = self.__dict__.get("_hash")
        if cached is None:
            cached = hash(tuple(getattr(self, f.name) for f in dataclasses.fields(self)))
            object.__setattr__(self, "_hash", cached)
        return cached

    def __getstate__(self) -> dict[str, Any]:
        # a string's hash differs between processes, so the cached one does not travel
        state = dict(self.__dict__)
        state.pop("_hash", None)
        return state

    # --- the flat view: every setting by its name ---------------------------------------------

    @classmethod
    def setting_fields(cls) -> tuple[dataclasses.Field, ...]:
        """Every setting, the groups' by their own names: the top-level fields, then each
        group's fields, in declaration order."""
        flat: list[dataclasses.Field] = []
        for field in dataclasses.fields(cls):
            if field.name in GROUPS:
                flat.extend(dataclasses.fields(GROUPS[field.name]))
            else:
                flat.append(field)
        return tuple(flat)

    def setting_values(self) -> dict[str, Any]:
        """The value of every setting of :meth:`setting_fields`, by name."""
        values: dict[str, Any] = {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if field.name in GROUPS:
                values.update((f.name, getattr(value, f.name)) for f in dataclasses.fields(value))
            else:
                values[field.name] = value
        return values

    def with_overrides(self, **overrides: Any) -> Scenario:
        """A copy with settings replaced (validated): by name (``n_steps=3``), by group and
        name (``**{"timing.n_steps": 3}``), or a whole group (``timing=TimingSettings(...)``,
        or a table of some of its fields); unknown names are named in the error."""
        top: dict[str, Any] = {}
        in_group: dict[str, dict[str, Any]] = {}
        unknown = []
        for key, value in overrides.items():
            group_name, _, name = key.rpartition(".")
            home = GROUP_OF.get(name)
            if group_name and group_name != home:
                unknown.append(key)
            elif home is not None:
                in_group.setdefault(home, {})[name] = value
            elif name in GROUPS and isinstance(value, Mapping):
                in_group.setdefault(name, {}).update(value)
            elif name in TOP_LEVEL or name in GROUPS:
                top[name] = value
            else:
                unknown.append(key)
        if unknown:
            raise ValueError(
                f"unknown scenario field(s) {', '.join(sorted(unknown))}; "
                f"fields: {', '.join(sorted(GROUP_OF.keys() | TOP_LEVEL))} "
                f"(or GROUP.FIELD, groups: {', '.join(GROUPS)})"
            )
        for group_name, changes in in_group.items():
            group = top.get(group_name, getattr(self, group_name))
            if isinstance(group, GROUPS[group_name]):
                # a table of some fields is checked (and completed) as the group field's value
                group = dataclasses.asdict(group) | changes
            top[group_name] = group  # a value of another kind is named in the scenario's error
        return dataclasses.replace(self, **top)

    # --- derived values ----------------------------------------------------------------------

    @property
    def n_uav(self) -> int:
        """Number of UAVs."""
        return len(self.initial_states)

    @property
    def horizon_s(self) -> float:
        """Prediction horizon Tp in seconds."""
        return self.timing.horizon_s

    @property
    def trigger_lookahead(self) -> int:
        """Predicted periods after t_c at which conditions (15)-(16) are checked."""
        if self.trigger.trigger_lookahead_steps is None:
            return self.timing.horizon_steps
        return self.trigger.trigger_lookahead_steps

    @property
    def reference_path(self) -> ReferencePath:
        """The :class:`ReferencePath` named by ``reference``."""
        return REFERENCE_PATHS[self.reference]

    @property
    def control_lower(self) -> np.ndarray:
        """``[a_min, omega_min]``."""
        return self.limits.lower

    @property
    def control_upper(self) -> np.ndarray:
        """``[a_max, omega_max]``."""
        return self.limits.upper

    def control_bounds_of(self, uav: int) -> tuple[np.ndarray, np.ndarray]:
        """``([a_min, omega_min], [a_max, omega_max])`` of UAV ``uav`` (0-based)."""
        return self.limits.of_uav(uav)

    @property
    def communication_faults(self) -> bool:
        """Whether plans can be lost or late."""
        return self.communication.faults

    def initial_state_array(self) -> np.ndarray:
        """Initial states as an ``(N, 4)`` array."""
        return np.asarray(self.initial_states, dtype=np.float64)

    def reference_at(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference centre positions ``(T, 2)`` and headings ``(T,)`` at ``times``."""
        start = self.reference_start
        if start is None:
            start = tuple(self.initial_state_array()[:, :2].mean(axis=0))
        return self.reference_path.evaluate(times, start)

    def desired_offsets(self, headings: np.ndarray) -> np.ndarray:
        """World-frame offsets of every UAV from the centre: ``(T, N, 2)``."""
        offsets = np.asarray(self.formation_offsets, dtype=np.float64)
        headings = np.atleast_1d(headings)
        if self.formation_frame == FormationFrame.WORLD:
            return np.broadcast_to(offsets, (headings.size, *offsets.shape)).copy()
        cos, sin = np.cos(headings)[:, None], np.sin(headings)[:, None]
        return np.stack(
            (cos * offsets[:, 0] - sin * offsets[:, 1], sin * offsets[:, 0] + cos * offsets[:, 1]),
            axis=-1,
        )

    def desired_distances(self) -> np.ndarray:
        """Desired distance between every pair of UAVs: ``(N, N)``."""
        offsets = np.asarray(self.formation_offsets, dtype=np.float64)
        return np.linalg.norm(offsets[:, None, :] - offsets[None, :, :], axis=-1)


def _field_names(cls: type) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(cls))


GROUPS: dict[str, type[SettingGroup]] = {
    f.name: type(f.default)
    for f in dataclasses.fields(Scenario)
    if isinstance(f.default, SettingGroup)
}
"""The scenario's setting groups: field name -> group class, in declaration order."""
TOP_LEVEL = frozenset(_field_names(Scenario)) - GROUPS.keys()
"""The settings a scenario holds outside its groups."""
GROUP_OF: dict[str, str] = {
    name: group for group, cls in GROUPS.items() for name in _field_names(cls)
}
"""The group of every grouped setting, by the setting's name."""
if len(GROUP_OF) + len(TOP_LEVEL) != len(Scenario.setting_fields()) or GROUP_OF.keys() & (
    TOP_LEVEL | GROUPS.keys()
):
    raise TypeError("a scenario setting's name must be unique across its groups and the scenario")

PAPER = Scenario()


def swarm_scenario(
    name: str,
    n_uav: int,
    *,
    shape: FormationShape | str = FormationShape.WEDGE,
    spacing_m: float = 10.0,
    layout_seed: int = 2022,
    **settings: Any,
) -> Scenario:
    """A scenario of ``n_uav`` UAVs in ``shape``, starting scattered around the reference start.

    The initial states come from :func:`~formation_bench.mpc.formations.scattered_initial_states`
    with a Generator seeded by ``layout_seed`` and are stored in the scenario as data;
    ``settings`` sets any other scenario setting (``graph``, disturbances, ...), by name as in
    :meth:`Scenario.with_overrides`.
    """
    offsets = formation_offsets(shape, n_uav, spacing_m)
    states = scattered_initial_states(offsets, np.random.default_rng(layout_seed))
    return Scenario().with_overrides(
        name=name,
        initial_states=tuple(tuple(float(v) for v in row) for row in states),
        formation_offsets=tuple(tuple(float(v) for v in row) for row in offsets),
        reference_start=(0.0, 0.0),
        **settings,
    )


SWARM_SIZES = {5: FormationShape.WEDGE, 10: FormationShape.GRID, 20: FormationShape.GRID,
               25: FormationShape.GRID}  # fmt: skip
"""The registered swarms ``swarm-N``: number of UAVs and formation."""


def _check_scenario(name: str, scenario: Scenario) -> None:
    if not isinstance(scenario, Scenario):
        raise TypeError(f"{name!r}: registered scenarios must be Scenario instances")
    if scenario.name != name:
        raise ValueError(
            f"scenario registered as {name!r} must have name={name!r}, got {scenario.name!r}"
        )


SCENARIOS: Registry[Scenario] = Registry("scenario", SCENARIO_GROUP, _check_scenario)
"""Every registered scenario by name; plugins of the ``formation_bench.scenarios``
entry-point group are loaded on first lookup."""


def register_scenario(scenario: Scenario) -> Scenario:
    """Register ``scenario`` under its ``name``; refuses a name already taken."""
    return SCENARIOS.add(scenario.name, scenario)


register_scenario(PAPER)
register_scenario(PAPER.with_overrides(name="paper-straight", reference="straight"))
register_scenario(PAPER.with_overrides(name="paper-s-curve", reference="s-curve"))
register_scenario(
    PAPER.with_overrides(
        name="paper-obstacles",
        obstacles=((136.0, -4.0, 5.0), (392.0, 112.0, 5.0)),
        w_obstacle=100.0,
        w_collision=100.0,
    )
)
"""The paper's scenario with two no-fly zones: one on the straight leg, on the reference
centre's line (the trailing UAV's slot), one beside the turn; both penalties on."""
for _n, _shape in SWARM_SIZES.items():
    register_scenario(swarm_scenario(f"swarm-{_n}", _n, shape=_shape))


def get_scenario(name: str, /, **overrides: Any) -> Scenario:
    """The scenario registered as ``name``, with settings replaced by ``overrides`` (as in
    :meth:`Scenario.with_overrides`)."""
    if name not in SCENARIOS:
        raise SCENARIOS.unknown(name)
    scenario = SCENARIOS[name]
    return scenario.with_overrides(**overrides) if overrides else scenario
