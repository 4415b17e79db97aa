"""Reference paths in closed form, scenario validation, and the scenario's setting groups."""

import ast
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from formation_bench.fields import declared
from formation_bench.mpc import scenario as scenario_module
from formation_bench.mpc.reference import REFERENCE_PATHS, ReferencePath
from formation_bench.mpc.scenario import (
    GROUP_OF,
    GROUPS,
    PAPER,
    SCENARIOS,
    CommunicationGraph,
    EstimateExtension,
    FormationFrame,
    Scenario,
    TimingSettings,
    TriggerSettings,
    get_scenario,
)


def test_straight_reference():
    path = ReferencePath("s", heading=0.5, speed=10.0)
    positions, headings = path.evaluate(np.array([0.0, 3.0]), start=(1.0, 2.0))
    np.testing.assert_allclose(positions[1], [1 + 30 * math.cos(0.5), 2 + 30 * math.sin(0.5)])
    np.testing.assert_allclose(headings, 0.5)


def test_turn_reference_is_a_circular_arc_then_straight():
    rate, speed = math.pi / 40.0, 15.0
    path = REFERENCE_PATHS["turn"]
    t = np.linspace(15.0, 35.0, 41)
    positions, headings = path.evaluate(t)
    radius = speed / rate
    centre = np.array([15.0 * speed, radius])  # left turn from heading 0 at (225, 0)
    np.testing.assert_allclose(np.hypot(*(positions - centre).T), radius, rtol=1e-12)
    np.testing.assert_allclose(headings, rate * (t - 15.0), atol=1e-12)
    after, heading_after = path.evaluate(np.array([35.0, 40.0]))
    np.testing.assert_allclose(heading_after, math.pi / 2)
    np.testing.assert_allclose(after[1] - after[0], [0.0, 5 * speed], atol=1e-9)


@pytest.mark.parametrize("name", sorted(REFERENCE_PATHS))
def test_reference_speed_is_constant(name):
    t = np.linspace(0, 48, 4801)
    positions = REFERENCE_PATHS[name].position(t)
    speeds = np.hypot(*np.diff(positions, axis=0).T) / np.diff(t)
    np.testing.assert_allclose(speeds, REFERENCE_PATHS[name].speed, rtol=1e-6)


def test_paper_scenario_matches_section_3():
    assert PAPER.n_uav == 3 and PAPER.timing.n_steps == 240
    assert PAPER.horizon_s == pytest.approx(4.0)
    d = PAPER.desired_distances()
    assert d[0, 2] == pytest.approx(20.0)
    assert d[0, 1] == pytest.approx(math.sqrt(200.0))
    assert d[1, 2] == pytest.approx(math.sqrt(200.0))
    np.testing.assert_allclose(PAPER.initial_states[0][2], math.radians(68.02))
    assert PAPER.limits.accel_bounds == (-7.0, 7.0)
    assert PAPER.limits.turn_rate_bounds == (-0.25, 0.25)


def test_path_frame_offsets_rotate_with_heading():
    world = PAPER.with_overrides(formation_frame=FormationFrame.WORLD)
    headings = np.array([0.0, math.pi / 2])
    rotated = PAPER.desired_offsets(headings)
    fixed = world.desired_offsets(headings)
    np.testing.assert_allclose(rotated[0], fixed[0])
    np.testing.assert_allclose(rotated[1][:, 0], -fixed[1][:, 1], atol=1e-12)
    np.testing.assert_allclose(rotated[1][:, 1], fixed[1][:, 0], atol=1e-12)


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("n_blocks", 0, "n_blocks"),
        ("n_blocks", 21, "[1, 20]"),
        ("period_s", 0.0, "period_s"),
        ("eta", 1.5, "eta"),
        ("eps_p", -1.0, "eps_p"),
        ("reference", "loop", "straight"),
        ("estimate_extension", "freeze", "coast, hold"),
        ("accel_bounds", (7.0, -7.0), "accel_bounds"),
        ("formation_offsets", ((1.0, 0.0), (0.0, 0.0), (0.0, 0.0)), "zero mean"),
        ("trigger_lookahead_steps", 21, "trigger_lookahead_steps"),
    ],
)
def test_bad_scenario_fields_are_named(field, value, needle):
    with pytest.raises(ValueError, match=None) as info:
        PAPER.with_overrides(**{field: value})
    assert needle in str(info.value)
    assert field in str(info.value)


def test_unknown_scenario_field_and_name():
    with pytest.raises(ValueError, match="unknown scenario field"):
        PAPER.with_overrides(colour="red")
    with pytest.raises(KeyError, match="paper"):
        get_scenario("nope")


def test_enum_fields_accept_strings():
    scenario = Scenario(communication={"estimate_extension": "hold"}, formation_frame="world")
    assert scenario.formation_frame is FormationFrame.WORLD
    assert scenario.communication.estimate_extension is EstimateExtension.HOLD
    assert set(SCENARIOS) >= {"paper", "paper-straight", "paper-s-curve"}


# --- the setting groups ------------------------------------------------------------------------


def test_every_setting_is_declared_once_in_one_group_or_at_the_top():
    flat = Scenario.setting_fields()
    names = [f.name for f in flat]
    assert len(names) == len(set(names)) == 45
    assert all(declared(f) is not None and declared(f).doc for f in flat)
    grouped = [f.name for group in GROUPS.values() for f in dataclasses.fields(group)]
    assert sorted(grouped) == sorted(GROUP_OF)
    top = {"name", "initial_states", "formation_offsets", "formation_frame", "reference",
           "reference_start"}  # fmt: skip
    assert set(names) == set(grouped) | top
    values = PAPER.setting_values()
    assert list(values) == names
    assert values["eta"] == PAPER.trigger.eta and values["n_steps"] == PAPER.timing.n_steps


def test_overrides_by_name_by_group_and_name_and_by_group():
    flat = PAPER.with_overrides(n_steps=3, eta=0.5, graph="ring")
    dotted = PAPER.with_overrides(**{"timing.n_steps": 3, "trigger.eta": 0.5,
                                     "communication.graph": "ring"})  # fmt: skip
    tables = PAPER.with_overrides(timing={"n_steps": 3}, trigger={"eta": 0.5},
                                  communication={"graph": "ring"})  # fmt: skip
    assert flat == dotted == tables
    assert flat.timing.n_steps == 3 and flat.trigger.eta == 0.5
    assert flat.communication.graph is CommunicationGraph.RING
    assert flat.timing.horizon_steps == PAPER.timing.horizon_steps  # the rest of the group kept
    whole = PAPER.with_overrides(trigger=TriggerSettings(eps_p=1.0), eta=0.25)
    assert (whole.trigger.eps_p, whole.trigger.eta) == (1.0, 0.25)
    assert get_scenario("paper", **{"trigger.eta": 0.5}) == PAPER.with_overrides(eta=0.5)


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        ({"colour": 1}, "unknown scenario field(s) colour; fields: accel_bounds"),
        ({"trigger.n_steps": 3}, "unknown scenario field(s) trigger.n_steps"),
        ({"timing.name": "x"}, "unknown scenario field(s) timing.name"),
        ({"trigger": {"n_steps": 3}}, "unknown field(s) n_steps of scenario group trigger"),
        ({"trigger": 3}, "Scenario.trigger must be a TriggerSettings or a table of its fields"),
        ({"trigger.eta": 2.0}, "Scenario.eta must be a finite number in (0.0, 1.0]"),
    ],
)
def test_bad_overrides_name_the_field(overrides, needle):
    with pytest.raises(ValueError) as info:
        PAPER.with_overrides(**overrides)
    assert needle in str(info.value)


def test_a_group_checks_its_own_fields_and_the_scenario_those_across_groups():
    with pytest.raises(ValueError, match=r"Scenario.n_blocks must be an integer in \[1, 4\]"):
        TimingSettings(horizon_steps=4, n_blocks=5)
    # the lookahead's upper end is the horizon of another group: open in the group alone
    assert TriggerSettings(trigger_lookahead_steps=50).trigger_lookahead_steps == 50
    with pytest.raises(ValueError, match=r"lookahead_steps must be an integer in \[0, 20\]"):
        Scenario(trigger=TriggerSettings(trigger_lookahead_steps=50))
    longer = PAPER.with_overrides(horizon_steps=60, trigger_lookahead_steps=50)
    assert longer.trigger_lookahead == 50
    with pytest.raises(ValueError, match="delay_steps must be below n_steps - 1"):
        PAPER.with_overrides(n_steps=3, delay_steps=2)


def test_the_scenario_module_and_the_formation_library_import_one_way():
    formations = Path(scenario_module.__file__).with_name("formations.py")
    imported = {
        node.module
        for node in ast.walk(ast.parse(formations.read_text()))
        if isinstance(node, ast.ImportFrom)
    } | {
        alias.name
        for node in ast.walk(ast.parse(formations.read_text()))
        if isinstance(node, ast.Import)
        for alias in node.names
    }
    assert not any(name and name.startswith("formation_bench.mpc.scenario") for name in imported)
    assert "swarm-10" in SCENARIOS and SCENARIOS["swarm-10"].n_uav == 10


def test_a_scenario_hash_is_its_fields_and_does_not_travel_in_a_pickle():
    import pickle

    scenario = get_scenario("paper")
    equal = get_scenario("paper").with_overrides(n_steps=scenario.timing.n_steps)
    assert scenario == equal and hash(scenario) == hash(equal)
    fields = tuple(getattr(scenario, f.name) for f in dataclasses.fields(scenario))
    assert hash(scenario) == hash(fields)
    copy = pickle.loads(pickle.dumps(scenario))
    assert "_hash" not in copy.__dict__ and copy == scenario and hash(copy) == hash(scenario)
    assert hash(scenario.with_overrides(n_steps=10)) != hash(scenario)
