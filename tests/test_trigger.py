"""Each trigger condition of eqs. (15)-(19) on hand-built cases."""

import numpy as np
import pytest

from formation_bench.mpc.trigger import (
    TriggerDecision,
    control_condition,
    distance_condition,
    expiry_condition,
    numpy_control_condition,
    numpy_distance_condition,
    numpy_tracking_condition,
    tracking_condition,
)


def test_distance_condition_fires_at_the_threshold():
    own = np.array([[10.0, 0.0]])
    desired = np.array([[[10.0, 0.0]], [[0.0, 10.0]]])  # desired p_i - p_j
    neighbours = np.array([[[0.0, 0.0]], [[10.0, -10.0]]])  # both exactly in place
    assert not distance_condition(own, neighbours, desired, 2.0)
    off = neighbours.copy()
    off[1, 0] += [0.0, 1.99]
    assert not distance_condition(own, off, desired, 2.0)
    off[1, 0] += [0.0, 0.01]  # now exactly 2.0 m off: eq. (15) uses >= 0
    assert distance_condition(own, off, desired, 2.0)


def test_distance_condition_over_lookahead_window():
    own = np.zeros((3, 2))
    desired = np.zeros((1, 3, 2))
    neighbours = np.zeros((1, 3, 2))
    neighbours[0, 2] = [3.0, 0.0]
    assert distance_condition(own, neighbours, desired, 2.0)
    assert not distance_condition(own[:2], neighbours[:, :2], desired[:, :2], 2.0)


def test_tracking_condition_uses_the_mean_of_n_uav():
    own = np.array([[3.0, 0.0]])
    neighbours = np.array([[[0.0, 0.0]], [[0.0, 0.0]]])
    reference = np.array([[0.0, 0.0]])
    # centre = (3 + 0 + 0) / 3 = 1 m from the reference
    assert not tracking_condition(own, neighbours, reference, 3, 1.01)
    assert tracking_condition(own, neighbours, reference, 3, 1.0)


def test_control_condition_uses_a_max_and_omega_max():
    lower, upper = np.array([-7.0, -0.25]), np.array([7.0, 0.25])
    assert not control_condition(np.array([6.9, 0.24]), lower, upper, 1.0)
    assert control_condition(np.array([7.0, 0.0]), lower, upper, 1.0)
    assert control_condition(np.array([0.0, -0.25]), lower, upper, 1.0)
    # eq. (17) as printed would compare omega with a_max: 0.2 rad/s would never fire
    assert control_condition(np.array([0.0, 0.2]), lower, upper, 0.8)
    assert not control_condition(np.array([5.5, 0.19]), lower, upper, 0.8)


def test_expiry_condition():
    assert not expiry_condition(19, 20)
    assert expiry_condition(20, 20)


def test_decision_fires_on_any_condition():
    assert not TriggerDecision(False, False, False, False).fire
    for k in range(4):
        flags = [False] * 4
        flags[k] = True
        assert TriggerDecision(*flags).fire


@pytest.mark.parametrize("n_neighbours", [0, 1, 2, 5, 9, 24])
@pytest.mark.parametrize("window", [1, 3])
def test_compiled_conditions_are_numpy_conditions(n_neighbours, window):
    """The compiled conditions decide as the numpy forms do, thresholds at the very errors
    included, on views laid out as the closed loop passes them."""
    rng = np.random.default_rng([n_neighbours, window])
    for _ in range(40):
        own = rng.normal(0.0, 30.0, (window + 2, 2))[:window]
        stacked = rng.normal(0.0, 30.0, (n_neighbours, window + 2, 2))
        neighbours = stacked[:, :window]
        desired = np.transpose(rng.normal(0.0, 10.0, (window, n_neighbours, 2)), (1, 0, 2))
        reference = rng.normal(0.0, 30.0, (window, 2))
        offsets = rng.normal(0.0, 10.0, (window, 2))
        errors = np.linalg.norm(own[None] - neighbours - desired, axis=-1).ravel()
        for eps in (*errors[:3], 1e-9, 1e9):
            assert distance_condition(own, neighbours, desired, eps) == numpy_distance_condition(
                own, neighbours, desired, eps
            )
        for offset_sum in (None, offsets):
            centre = own + neighbours.sum(axis=0) - (0.0 if offset_sum is None else offset_sum)
            group = n_neighbours + 1
            gaps = np.linalg.norm(centre / group - reference, axis=-1)
            for eps in (*gaps, 1e-9, 1e9):
                args = (own, neighbours, reference, group, eps, offset_sum)
                assert tracking_condition(*args) == numpy_tracking_condition(*args)
        control = rng.uniform(-8.0, 8.0, 2)
        lower, upper = np.array([-7.0, -0.25]), np.array([7.0, 0.25])
        for eta in (0.5, 0.9, 1.0, abs(control[0]) / 7.0):
            assert control_condition(control, lower, upper, eta) == numpy_control_condition(
                control, lower, upper, eta
            )
