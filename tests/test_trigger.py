"""Each trigger condition of eqs. (15)-(19) on hand-built cases."""

import numpy as np

from formation_bench.mpc.trigger import (
    TriggerDecision,
    control_condition,
    distance_condition,
    expiry_condition,
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
