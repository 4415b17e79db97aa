"""Reference paths in closed form, and scenario validation."""

import math

import numpy as np
import pytest

from formation_bench.mpc.reference import REFERENCE_PATHS, ReferencePath
from formation_bench.mpc.scenario import PAPER, SCENARIOS, FormationFrame, Scenario, get_scenario


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
    assert PAPER.n_uav == 3 and PAPER.n_steps == 240
    assert PAPER.horizon_s == pytest.approx(4.0)
    d = PAPER.desired_distances()
    assert d[0, 2] == pytest.approx(20.0)
    assert d[0, 1] == pytest.approx(math.sqrt(200.0))
    assert d[1, 2] == pytest.approx(math.sqrt(200.0))
    np.testing.assert_allclose(PAPER.initial_states[0][2], math.radians(68.02))
    assert PAPER.accel_bounds == (-7.0, 7.0) and PAPER.turn_rate_bounds == (-0.25, 0.25)


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
    scenario = Scenario(estimate_extension="hold", formation_frame="world")
    assert scenario.formation_frame is FormationFrame.WORLD
    assert set(SCENARIOS) >= {"paper", "paper-straight", "paper-s-curve"}
