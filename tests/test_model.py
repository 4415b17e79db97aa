"""The discretised model against closed-form motion."""

import math

import numpy as np
import pytest

from formation_bench.mpc.model import (
    REDUCTION_LIMIT,
    coast,
    cos_sin,
    rk4_substep,
    rollout,
    rollout_batch,
    rotated_substep,
    step_plant,
    turn_rotation,
)


def test_straight_line_with_constant_acceleration_is_exact():
    state = np.array([1.0, -2.0, 0.3, 10.0])
    a, period, steps = 1.5, 0.2, 50
    states = rollout(state, np.tile([a, 0.0], (steps, 1)), period, 1)
    t = np.arange(steps + 1) * period
    travelled = 10.0 * t + 0.5 * a * t**2
    np.testing.assert_allclose(states[:, 0], 1.0 + travelled * math.cos(0.3), atol=1e-9)
    np.testing.assert_allclose(states[:, 1], -2.0 + travelled * math.sin(0.3), atol=1e-9)
    np.testing.assert_allclose(states[:, 3], 10.0 + a * t, atol=1e-12)
    np.testing.assert_allclose(states[:, 2], 0.3, atol=1e-15)


@pytest.mark.parametrize("substeps", [1, 4])
def test_constant_turn_follows_the_circle(substeps):
    v, omega, theta0, period, steps = 15.0, 0.25, -0.4, 0.2, 240
    state = np.array([0.0, 0.0, theta0, v])
    states = rollout(state, np.tile([0.0, omega], (steps, 1)), period, substeps)
    t = np.arange(steps + 1) * period
    x = v / omega * (np.sin(theta0 + omega * t) - math.sin(theta0))
    y = -v / omega * (np.cos(theta0 + omega * t) - math.cos(theta0))
    tolerance = 1e-5 / substeps**4
    np.testing.assert_allclose(states[:, 0], x, atol=tolerance)
    np.testing.assert_allclose(states[:, 1], y, atol=tolerance)
    np.testing.assert_allclose(states[:, 2], theta0 + omega * t, atol=1e-12)
    # the radius is the constant v / omega around the turn's centre
    centre = np.array([-v / omega * math.sin(theta0), v / omega * math.cos(theta0)])
    np.testing.assert_allclose(np.hypot(*(states[:, :2] - centre).T), v / omega, atol=tolerance)


def test_batch_rollout_and_plant_agree_with_single_rollout():
    rng = np.random.default_rng(3)
    state = np.array([5.0, 1.0, 0.2, 12.0])
    controls = rng.uniform([-7, -0.25], [7, 0.25], size=(6, 20, 2))
    batch = rollout_batch(state, controls, 0.2, 1)
    for i in range(6):
        np.testing.assert_array_equal(batch[i], rollout(state, controls[i], 0.2, 1))
    plant = step_plant(np.stack([state, state]), controls[:2, 0], 0.2, 1)
    np.testing.assert_array_equal(plant[0], batch[0, 1])
    np.testing.assert_array_equal(plant[1], batch[1, 1])


def test_coast_is_zero_control_rollout():
    state = np.array([3.0, 4.0, 1.1, 14.0])
    positions = coast(state, np.arange(1, 11) * 0.2)
    states = rollout(state, np.zeros((10, 2)), 0.2, 1)
    np.testing.assert_allclose(positions, states[1:, :2], atol=1e-12)


def test_cos_sin_is_within_a_rounding_of_math():
    rng = np.random.default_rng(8)
    near_quadrants = np.arange(-4000, 4000) * (math.pi / 2)
    angles = np.concatenate(
        [
            rng.uniform(-4.0, 4.0, 20_000),
            rng.uniform(-1e3, 1e3, 20_000),
            rng.uniform(-REDUCTION_LIMIT, REDUCTION_LIMIT, 20_000),
            near_quadrants,
            near_quadrants + rng.normal(0, 1e-9, near_quadrants.size),
            [0.0, -0.0, math.pi / 4, -math.pi / 4, 1e-300],
        ]
    )
    for angle in angles:
        cos, sin = cos_sin(angle)
        assert abs(cos - math.cos(angle)) <= 2.3e-16
        assert abs(sin - math.sin(angle)) <= 2.3e-16
    # past the reduction's range, and for NaN and infinities, math's own values
    for angle in (REDUCTION_LIMIT, -REDUCTION_LIMIT * 3.7, 1e300):
        assert cos_sin(angle) == (math.cos(angle), math.sin(angle))
    for angle in (math.nan, math.inf, -math.inf):
        assert all(math.isnan(value) for value in cos_sin(angle))


def test_rotated_substep_is_the_plain_rk4_substep():
    rng = np.random.default_rng(9)
    for _ in range(2000):
        x, y, v = rng.normal(0, 100), rng.normal(0, 100), rng.uniform(0, 30)
        theta, a, omega = rng.uniform(-10, 10), rng.uniform(-7, 7), rng.uniform(-3, 3)
        h = rng.uniform(0.001, 0.5)
        plain = rk4_substep(x, y, theta, v, a, omega, h)
        cos_half, sin_half, cos_full, sin_full = turn_rotation(omega, h)
        assert cos_half**2 + sin_half**2 == pytest.approx(1.0, abs=4e-16)
        assert cos_full**2 + sin_full**2 == pytest.approx(1.0, abs=8e-16)
        x1, y1, cos_end, sin_end, v_end = rotated_substep(
            x, y, math.cos(theta), math.sin(theta), v, a, h, *turn_rotation(omega, h)
        )
        scale = abs(x) + abs(y) + v * h
        assert x1 == pytest.approx(plain[0], abs=4e-16 * scale)
        assert y1 == pytest.approx(plain[1], abs=4e-16 * scale)
        assert cos_end == pytest.approx(math.cos(plain[2]), abs=2e-15)
        assert sin_end == pytest.approx(math.sin(plain[2]), abs=2e-15)
        assert v_end == plain[3]


@pytest.mark.parametrize("substeps", [1, 2, 16, 17, 40])
def test_plant_steps_reproduce_the_plan_to_the_bit(substeps):
    """Stepped one period at a time, the plant is exactly where a plan's rollout predicts."""
    rng = np.random.default_rng(substeps)
    state = np.array([-3.0, 8.0, 2.2, 11.0])
    # a blocked plan: controls held over runs of periods, as the decision blocks hold them
    controls = np.repeat(rng.uniform([-7, -0.25], [7, 0.25], size=(5, 2)), 4, axis=0)
    plan = rollout(state, controls, 0.2, substeps)
    plant = [state]
    for k in range(len(controls)):
        plant.append(step_plant(plant[-1][None], controls[k : k + 1], 0.2, substeps)[0])
    np.testing.assert_array_equal(np.array(plant), plan)


def test_compiled_plant_step_is_each_uav_s_rollout():
    rng = np.random.default_rng(11)
    states = np.column_stack(
        (rng.uniform(-50, 50, (7, 2)), rng.uniform(-3, 3, 7), rng.uniform(5, 20, 7))
    )
    controls = rng.uniform([-7, -0.25], [7, 0.25], size=(7, 2))
    plant = step_plant(states, controls, 0.2, 4)
    for i in range(7):
        np.testing.assert_array_equal(plant[i], rollout(states[i], controls[i : i + 1], 0.2, 4)[1])
