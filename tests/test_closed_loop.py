"""The closed loop and its metrics, on short runs."""

import numpy as np
import pytest

from formation_bench.instances.instants import ObservedOptimizer
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.metrics import (
    closed_loop_cost,
    compute_metrics,
    distance_errors,
    pair_names,
    tracking_error,
)
from formation_bench.mpc.model import rollout
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import get_optimizer

SHORT = get_scenario("paper", n_steps=30, settle_time_s=0.0)
FAST_BSO = get_optimizer("modified-bso", max_iterations=10)


@pytest.fixture(scope="module")
def runs():
    return {
        trigger: simulate(SHORT, FAST_BSO, trigger=trigger, seed=7, optimizer_name="fast")
        for trigger in (False, True)
    }


def test_without_trigger_every_uav_solves_every_instant(runs):
    trace = runs[False]
    assert trace.solved.all()
    assert (trace.nfev > 0).all()
    assert np.isfinite(trace.solve_time_s).all()


def test_with_trigger_solves_are_explained_by_conditions(runs):
    trace = runs[True]
    assert trace.solved[0].all()  # no plan yet at t0
    assert np.array_equal(trace.solved, trace.reasons.any(axis=2))
    assert (trace.nfev[~trace.solved] == 0).all()
    assert np.isnan(trace.solve_time_s[~trace.solved]).all()


def test_applied_controls_respect_bounds_and_the_plant_follows_them(runs):
    for trace in runs.values():
        lower, upper = SHORT.control_lower, SHORT.control_upper
        assert (trace.controls >= lower).all() and (trace.controls <= upper).all()
        for i in range(SHORT.n_uav):
            flown = rollout(trace.states[0, i], trace.controls[:, i], SHORT.timing.period_s, 1)
            np.testing.assert_allclose(flown, trace.states[:, i], atol=1e-9)


def test_same_seed_same_run_other_seed_other_run(runs):
    again = simulate(SHORT, FAST_BSO, trigger=True, seed=7, optimizer_name="fast")
    np.testing.assert_array_equal(again.states, runs[True].states)
    np.testing.assert_array_equal(again.solved, runs[True].solved)
    other = simulate(SHORT, FAST_BSO, trigger=True, seed=8, optimizer_name="fast")
    assert not np.array_equal(other.states, runs[True].states)


def test_kept_plan_is_applied_between_solves():
    """A UAV that skips a solve applies what its last solve planned for this instant."""
    offsets = np.asarray(SHORT.formation_offsets)
    in_formation = SHORT.with_overrides(
        initial_states=tuple((x, y, 0.0, 15.0) for x, y in offsets),
        reference="straight",
        n_steps=40,
    )
    recording = ObservedOptimizer(FAST_BSO)
    trace = simulate(in_formation, recording, trigger=True, seed=2)
    skipped = np.argwhere(~trace.solved)
    assert len(skipped) > 20, "a formation flying in place should skip most solves"
    for i in range(in_formation.n_uav):
        plans = iter(
            [s.objective.controls(s.result.x) for s in recording.solves if s.objective.uav == i]
        )
        plan, start = None, 0
        for c in range(in_formation.timing.n_steps):
            if trace.solved[c, i]:
                plan, start = next(plans), c
            np.testing.assert_array_equal(trace.controls[c, i], plan[c - start])


def test_hold_extension_changes_the_run():
    hold = SHORT.with_overrides(estimate_extension="hold")
    a = simulate(SHORT, FAST_BSO, trigger=False, seed=1)
    b = simulate(hold, FAST_BSO, trigger=False, seed=1)
    assert not np.allclose(a.states, b.states)


def test_huge_thresholds_leave_only_expiry_and_saturation():
    scenario = SHORT.with_overrides(eps_p=1e9, eps_o=1e9, n_steps=45)
    trace = simulate(scenario, FAST_BSO, trigger=True, seed=3)
    assert not trace.reasons[1:, :, 0].any() and not trace.reasons[1:, :, 1].any()
    for i in range(scenario.n_uav):
        solves = np.flatnonzero(trace.solved[:, i])
        gaps = np.diff(solves)
        assert gaps.max() <= scenario.timing.horizon_steps


def test_metrics_keys_and_values(runs):
    trace = runs[False]
    metrics = compute_metrics(trace)
    columns = metrics.columns()
    assert [c for c in columns if c.startswith("distance_error_max_m_d")] == [
        "distance_error_max_m_d12",
        "distance_error_max_m_d23",
        "distance_error_max_m_d31",
    ]
    assert columns["distance_error_max_m_max"] == max(metrics.distance_error_max_m.values())
    assert [columns[f"solves_uav{k}"] for k in (1, 2, 3)] == [30, 30, 30]
    assert columns["solves_total"] == 90
    # no trigger: every solve is counted under the conditions that held, the first as expiry
    assert columns["trigger_expiry"] >= 3
    assert len(columns["solve_times_s"]) == 90
    assert metrics.nfev_total == int(trace.nfev.sum())
    assert metrics.tracking_error_max_m == pytest.approx(tracking_error(trace).max())
    centre = trace.states[5, :, :2].mean(axis=0)
    assert tracking_error(trace)[5] == pytest.approx(np.linalg.norm(centre - trace.reference[5]))
    d31 = np.linalg.norm(trace.states[:, 2, :2] - trace.states[:, 0, :2], axis=1)
    np.testing.assert_allclose(distance_errors(trace)["d31"], np.abs(d31 - 20.0))


def test_closed_loop_cost_is_eq11_summed(runs):
    trace = runs[True]
    s = trace.scenario
    total = 0.0
    for c in range(1, trace.times.size):
        p = trace.states[c, :, :2]
        centre_error = p.mean(axis=0) - trace.reference[c]
        for i in range(s.n_uav):
            formation = sum(
                np.sum(
                    (p[i] - p[j] - (trace.desired_offsets[c, i] - trace.desired_offsets[c, j])) ** 2
                )
                for j in range(s.n_uav)
                if j != i
            )
            rate = s.weights.w_dst * formation + s.weights.w_trj * np.sum(centre_error**2)
            total += s.timing.period_s * rate
    assert closed_loop_cost(trace) == pytest.approx(total, rel=1e-12)


def test_pair_names():
    assert [n for n, _, _ in pair_names(3)] == ["d12", "d23", "d31"]
    assert [n for n, _, _ in pair_names(4)] == ["d12", "d23", "d34", "d41", "d13", "d24"]
    assert [n for n, _, _ in pair_names(2)] == ["d12"]


def test_settle_time_after_the_run_is_an_error():
    trace = simulate(
        SHORT.with_overrides(n_steps=3, settle_time_s=10.0), FAST_BSO, trigger=False, seed=0
    )
    with pytest.raises(ValueError, match="settle_time_s"):
        compute_metrics(trace)
