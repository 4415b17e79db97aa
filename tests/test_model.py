"""The discretised model against closed-form motion."""

import math

import numpy as np
import pytest

from formation_bench.mpc.model import coast, rollout, rollout_batch, step_plant


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
