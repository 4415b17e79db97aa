"""The phase metrics on a two-UAV trace whose values are worked out by hand.

Two UAVs 10 m apart on the x axis (world-frame formation), the reference at the origin.
At instant k UAV 1 is displaced by a_k and UAV 2 by b_k along x, so the centre is
((a_k + b_k) / 2, 0), the tracking error |a_k + b_k| / 2 and the distance error |b_k - a_k|.
"""

import math

import numpy as np
import pytest

from formation_bench.mpc.loop import AT_BOUND_TOLERANCE, Trace, at_bound
from formation_bench.mpc.metrics import compute_metrics
from formation_bench.mpc.scenario import FormationFrame, get_scenario

#             k:   0    1    2    3     4     5
A = np.array([0.0, 0.1, 0.0, 0.9, -0.05, 0.0])
B = np.array([3.0, 0.1, 0.5, 0.9, 0.05, 0.0])
# tracking |a + b| / 2:  1.5   0.1  0.25  0.9   0     0    (band 1 m: out at k = 0)
# distance |b - a|:      3     0    0.5   0     0.1   0    (band 2 % of 10 m = 0.2: out at 0, 2)


def scenario(**overrides):
    return get_scenario("paper").with_overrides(
        initial_states=((-5.0, 0.0, 0.0, 10.0), (5.0, 0.0, 0.0, 10.0)),
        formation_offsets=((-5.0, 0.0), (5.0, 0.0)),
        formation_frame=FormationFrame.WORLD,
        n_steps=5,
        settle_time_s=0.4,
        **overrides,
    )


def trace(a=A, b=B, **overrides) -> Trace:
    sc = scenario(**overrides)
    times = np.arange(6) * 0.2
    states = np.zeros((6, 2, 4))
    states[:, 0, 0] = -5.0 + a
    states[:, 1, 0] = 5.0 + b
    controls = np.zeros((5, 2, 2))
    controls[0, 0] = (3.5, 0.125)  # half of each bound: 0.25 + 0.25 per second
    controls[:, 1, 0] = 7.0  # full acceleration throughout: 1 per second
    solved = np.zeros((5, 2), dtype=bool)
    solved[0] = True
    solved[2, 0] = True
    plan_at_bound = np.zeros((5, 2), dtype=bool)
    plan_at_bound[0, 1] = True
    return Trace(
        scenario=sc,
        optimizer="hand",
        trigger=True,
        seed=0,
        times=times,
        states=states,
        controls=controls,
        solved=solved,
        reasons=np.zeros((5, 2, 4), dtype=bool),
        solve_time_s=np.where(solved, 1e-3, np.nan),
        nfev=solved.astype(np.int64),
        solve_cost=np.where(solved, 0.0, np.nan),
        reference=np.zeros((6, 2)),
        reference_heading=np.zeros(6),
        desired_offsets=np.broadcast_to(np.array([[-5.0, 0.0], [5.0, 0.0]]), (6, 2, 2)).copy(),
        wall_time_s=0.0,
        solve_failed=np.zeros((5, 2), dtype=bool),
        plan_at_bound=plan_at_bound,
    )


def test_settling_time_is_the_first_instant_inside_both_bands_to_the_end():
    # outside at k = 0 (both) and k = 2 (distance 0.5 > 0.2): settled from k = 3, t = 0.6 s
    assert compute_metrics(trace()).settling_time_s == pytest.approx(0.6)
    # wider bands: only k = 0 is outside
    wide = compute_metrics(trace(settling_distance_band=0.06))
    assert wide.settling_time_s == pytest.approx(0.2)
    # a tracking band below 0.9 m puts k = 3 outside: settled from k = 4
    narrow = compute_metrics(trace(settling_tracking_band_m=0.5))
    assert narrow.settling_time_s == pytest.approx(0.8)


def test_settling_time_is_nan_when_the_end_is_outside_and_zero_when_never_outside():
    late = B.copy()
    late[-1] = 1.0  # distance error 1 m at the last instant
    assert math.isnan(compute_metrics(trace(b=late)).settling_time_s)
    calm = np.zeros(6)
    assert compute_metrics(trace(a=calm, b=calm)).settling_time_s == 0.0


def test_errors_from_the_settling_time_count_from_the_run_own_settling_instant():
    # settled from k = 3: tracking 0.9, 0, 0 and distance 0, 0.1, 0 from there on
    metrics = compute_metrics(trace())
    assert metrics.tracking_error_max_settled_m == pytest.approx(0.9)
    assert metrics.distance_error_max_settled_m == {"d12": pytest.approx(0.1)}
    # from the settle time (0.4 s, k = 2) the distance error of k = 2 counts as well
    assert metrics.distance_error_max_m == {"d12": pytest.approx(0.5)}
    # wider bands settle from k = 1: k = 2's distance error 0.5 counts
    wide = compute_metrics(trace(settling_distance_band=0.06))
    assert wide.distance_error_max_settled_m == {"d12": pytest.approx(0.5)}
    late = B.copy()
    late[-1] = 1.0
    unsettled = compute_metrics(trace(b=late))
    assert math.isnan(unsettled.tracking_error_max_settled_m)
    assert math.isnan(unsettled.distance_error_max_settled_m["d12"])


def test_the_cost_splits_at_the_settle_time():
    # eq. (11) rate at k: w_dst * 2 (b - a)^2 + w_trj * 2 ((a + b) / 2)^2 = 2 (b-a)^2 + 1.5 (a+b)^2
    # k = 1..5: 0.06, 0.875, 4.86, 0.02, 0; times 0.2..1.0, settle 0.4 -> k = 1 is transient
    metrics = compute_metrics(trace())
    assert metrics.transient_cost == pytest.approx(0.2 * 0.06)
    assert metrics.steady_state_cost == pytest.approx(0.2 * (0.875 + 4.86 + 0.02))
    assert metrics.closed_loop_cost == pytest.approx(0.2 * (0.06 + 0.875 + 4.86 + 0.02))
    assert metrics.transient_cost + metrics.steady_state_cost == pytest.approx(
        metrics.closed_loop_cost, rel=1e-15
    )


def test_separation_effort_and_bound_share():
    metrics = compute_metrics(trace())
    assert metrics.min_separation_m == pytest.approx(10.0)  # 10 + b - a, smallest at k = 1, 3, 5
    # UAV 1: (0.5^2 + 0.5^2) for one period; UAV 2: 1 for five periods of 0.2 s
    assert metrics.control_effort == pytest.approx((0.2 * 0.5, 1.0))
    assert metrics.solves_at_bound_share == pytest.approx(1 / 3)  # 1 of the 3 solves
    columns = metrics.columns()
    assert columns["control_effort_uav2"] == pytest.approx(1.0)


def test_a_control_at_a_bound_is_found_within_the_tolerance():
    lower, upper = np.array([-7.0, -0.25]), np.array([7.0, 0.25])
    assert not at_bound(np.array([0.0, 0.0]), lower, upper)
    assert at_bound(np.array([7.0, 0.0]), lower, upper)
    inside = -0.25 + 0.5 * AT_BOUND_TOLERANCE * 0.5
    assert at_bound(np.array([0.0, inside]), lower, upper)
    assert not at_bound(np.array([0.0, -0.25 + 2 * AT_BOUND_TOLERANCE * 0.5]), lower, upper)


def test_compiled_at_bound_agrees_with_the_numpy_form():
    rng = np.random.default_rng(2)
    lower, upper = np.tile([-7.0, -0.25], 5), np.tile([7.0, 0.25], 5)
    margin = AT_BOUND_TOLERANCE * (upper - lower)
    for _ in range(500):
        decision = rng.uniform(lower, upper)
        # put some components within a few margins of a bound, on either side of it
        near = rng.random(10) < 0.1
        side = np.where(rng.random(10) < 0.5, lower + margin, upper - margin)
        decision[near] = side[near] + rng.uniform(-2, 2, near.sum()) * margin[near]
        expected = bool(np.any((decision <= lower + margin) | (decision >= upper - margin)))
        assert at_bound(decision, lower, upper) is expected
