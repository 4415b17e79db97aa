"""The scenario families beyond the paper: formations, graphs, faults, disturbances, obstacles,
mixed vehicles, and the metrics at scale."""

from __future__ import annotations

import numpy as np
import pytest

from formation_bench.mpc.cost import reference_cost
from formation_bench.mpc.disturbance import Disturbances
from formation_bench.mpc.formations import (
    FormationShape,
    formation_offsets,
    scattered_initial_states,
)
from formation_bench.mpc.loop import Trace, simulate
from formation_bench.mpc.metrics import compute_metrics, graph_pairs, segment_min_distance
from formation_bench.mpc.model import step_plant
from formation_bench.mpc.network import Network, listening
from formation_bench.mpc.problem import LocalProblem, Plan, coasting_plan, estimate_positions
from formation_bench.mpc.scenario import PAPER, CommunicationGraph, get_scenario, swarm_scenario
from formation_bench.mpc.trigger import tracking_condition
from formation_bench.optimizers import get_optimizer

SHORT = {"n_steps": 40, "settle_time_s": 4.0}


def random_problem_inputs(rng: np.random.Generator, scenario, n_neighbours: int):
    horizon = scenario.timing.horizon_steps
    state = np.array([0.0, 0.0, 0.3, 15.0]) + rng.normal(0, 1, 4)
    neighbours = rng.normal(0, 20, (n_neighbours, horizon, 2))
    desired = rng.normal(0, 10, (n_neighbours, horizon, 2))
    reference = rng.normal(0, 20, (horizon, 2))
    return state, neighbours, desired, reference


# --- the generalised formation centre ----------------------------------------------------------


@pytest.mark.parametrize("seed", range(5))
def test_group_centre_equals_the_papers_centre_on_the_complete_graph(seed):
    """With every UAV in the group the offsets sum to zero, so the estimated centre, and with
    it the cost, is eq. (14)'s."""
    rng = np.random.default_rng(seed)
    n_uav = 3 + seed
    offsets = formation_offsets("circle", n_uav, 10.0)
    scenario = PAPER.with_overrides(
        initial_states=tuple((0.0, 0.0, 0.0, 15.0) for _ in range(n_uav)),
        formation_offsets=tuple(map(tuple, offsets)),
    )
    state, neighbours, desired, reference = random_problem_inputs(rng, scenario, n_uav - 1)
    offset_sum = np.broadcast_to(offsets.sum(axis=0), (scenario.timing.horizon_steps, 2)).copy()
    paper = LocalProblem(scenario, 0, state, neighbours, desired, reference)
    group = LocalProblem(scenario, 0, state, neighbours, desired, reference, offset_sum)
    assert group.centre_group == paper.centre_group == n_uav
    decisions = paper.bounds.sample(rng, 50)
    expected = paper(decisions)
    np.testing.assert_allclose(group(decisions), expected, rtol=1e-12)
    plain = [group.reference_cost(d) for d in decisions[:5]]
    np.testing.assert_allclose(plain, expected[:5], rtol=1e-12)


def test_group_centre_is_the_true_centre_when_the_group_holds_its_slots():
    """Off the complete graph the estimate uses the UAV and its neighbours only; it is exact
    when they are in formation, whoever the neighbours are."""
    rng = np.random.default_rng(4)
    offsets = formation_offsets("grid", 9, 10.0)
    centre = np.array([50.0, -20.0])
    positions = centre + offsets
    for group in ([0, 1, 3], [4], [8, 7, 6, 5]):
        own, heard = positions[group[0]][None], positions[group[1:]][:, None]
        assert not tracking_condition(
            own, heard, centre[None], len(group), 1e-9, offsets[group].sum(axis=0)[None]
        )
        moved = centre + rng.normal(0, 5, 2)
        assert tracking_condition(
            own, heard, moved[None], len(group), 1e-3, offsets[group].sum(axis=0)[None]
        )


def test_centre_weight_and_target_follow_the_group():
    rng = np.random.default_rng(1)
    scenario = get_scenario("swarm-5", graph="ring")
    state, neighbours, desired, reference = random_problem_inputs(rng, scenario, 2)
    offset_sum = rng.normal(0, 5, (scenario.timing.horizon_steps, 2))
    problem = LocalProblem(scenario, 2, state, neighbours, desired, reference, offset_sum)
    assert problem.centre_group == 3
    np.testing.assert_array_equal(problem.centre_neighbour_sum, neighbours.sum(axis=0) - offset_sum)
    decisions = problem.bounds.sample(rng, 8)
    plain = [
        reference_cost(
            d,
            state,
            problem.block_of_step,
            scenario.timing.period_s,
            scenario.timing.rk4_substeps,
            neighbours,
            desired,
            reference,
            scenario.weights.w_dst,
            scenario.weights.w_trj,
            scenario.n_uav,
            offset_sum,
        )
        for d in decisions
    ]
    np.testing.assert_allclose(problem(decisions), plain, rtol=1e-12)


# --- communication graphs --------------------------------------------------------------------


def test_ring_and_k_nearest_neighbour_sets():
    positions = np.array([[0.0, 0.0], [10.0, 0.0], [25.0, 0.0], [100.0, 0.0], [101.0, 0.0]])
    scenario = get_scenario("swarm-5", graph="ring")
    ring = listening(scenario, positions)
    assert ring.sum(axis=1).tolist() == [2] * 5
    assert ring[0, 1] and ring[0, 4] and not ring[0, 2]
    knn = listening(scenario.with_overrides(graph="k-nearest", graph_neighbours=2), positions)
    assert knn.sum(axis=1).tolist() == [2] * 5
    assert knn[0].nonzero()[0].tolist() == [1, 2]
    assert knn[3].nonzero()[0].tolist() == [2, 4]
    assert not knn.diagonal().any()


def test_range_limited_neighbour_sets_change_as_the_uavs_move():
    scenario = get_scenario("swarm-5", graph="range", graph_range_m=15.0)
    near = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0], [40.0, 0.0]])
    spread = near * 2.0
    assert listening(scenario, near).sum() == 8  # a chain: 4 links, both ways
    assert listening(scenario, spread).sum() == 0
    # in a closed loop the scattered start and the formation differ: the sets change
    trace = simulate(
        get_scenario("swarm-10", graph="range", graph_range_m=12.0, **SHORT),
        get_optimizer("pso"), trigger=True, seed=0,
    )  # fmt: skip
    changes = np.any(trace.neighbours[1:] != trace.neighbours[:-1], axis=(1, 2))
    assert changes.any()
    assert (trace.neighbours == np.transpose(trace.neighbours, (0, 2, 1))).all()


def test_each_uav_uses_only_what_it_receives():
    """On the ring, UAV 1's problem holds its two neighbours' estimates only."""
    seen = []

    class Recording:
        default_budget = get_optimizer("pso").default_budget

        def minimize(self, problem, bounds, rng, budget, x0):
            seen.append((problem.uav, problem.neighbour_positions.shape[0], problem.centre_group))
            return get_optimizer("pso").minimize(problem, bounds, rng, budget, x0)

    simulate(get_scenario("swarm-5", graph="ring", n_steps=2, settle_time_s=0.2),
             Recording(), trigger=False, seed=0)  # fmt: skip
    assert {(j, m) for _, j, m in seen} == {(2, 3)}


# --- lost and late plans ---------------------------------------------------------------------


def plan_at(step: int, scenario, state=(0.0, 0.0, 0.0, 15.0)) -> Plan:
    return coasting_plan(np.array(state), step, scenario)


def test_a_lost_plan_leaves_the_older_one_aged_by_the_periods_since_it_was_made():
    scenario = get_scenario("paper", packet_loss=0.5)
    initial = [plan_at(0, scenario, (10.0 * k, 0.0, 0.0, 15.0)) for k in range(3)]
    network = Network(scenario, initial, np.random.default_rng(0))
    everyone = np.array([True, False, True])  # UAVs 1 and 3 listen to UAV 2
    older = plan_at(3, scenario, (0.0, 5.0, 0.5, 14.0))
    network.lost_state[:] = False
    assert not network.send(3, 1, older, everyone).any()
    network.deliver(4)
    assert network.held[0][1] is older
    newer = plan_at(6, scenario, (0.0, 50.0, -0.5, 16.0))
    network.lost_state[:] = True
    assert network.send(6, 1, newer, everyone).tolist() == [True, False, True]
    network.deliver(7)
    assert network.held[0][1] is older
    estimate = estimate_positions(network.held[0][1], 7, 5, scenario.timing.period_s, "coast")
    np.testing.assert_array_equal(estimate, older.states[4:9, :2])  # 7 - 3 periods on


def test_a_delayed_plan_arrives_shifted_by_the_delay():
    scenario = get_scenario("paper", delay_steps=2)
    initial = [plan_at(0, scenario) for _ in range(3)]
    network = Network(scenario, initial, np.random.default_rng(0))
    plan = plan_at(4, scenario, (1.0, 2.0, 0.1, 15.0))
    network.send(4, 2, plan, np.array([True, True, False]))
    for step in (5, 6):
        assert network.deliver(step).sum() == 0
        assert network.held[0][2] is initial[2]
    late = network.deliver(7)  # made at 4, due at 5, two periods late
    assert late.tolist() == [1, 1, 0]
    assert network.held[0][2] is plan and network.held[1][2] is plan


def test_a_plan_older_than_the_one_held_is_dropped():
    scenario = get_scenario("paper", delay_steps=3, delay_jitter_steps=2)
    initial = [plan_at(0, scenario) for _ in range(3)]
    network = Network(scenario, initial, np.random.default_rng(0))
    slow, fast = plan_at(2, scenario), plan_at(3, scenario)
    network.extra_delay[:] = 2
    network.send(2, 1, slow, np.array([True, False, False]))  # arrives at 8
    network.extra_delay[:] = 0
    network.send(3, 1, fast, np.array([True, False, False]))  # arrives at 7
    network.deliver(7)
    network.deliver(8)
    assert network.held[0][1] is fast


def test_copies_of_one_plan_arrive_at_each_receivers_own_delay():
    scenario = get_scenario("paper", delay_jitter_steps=3)
    initial = [plan_at(0, scenario) for _ in range(3)]
    network = Network(scenario, initial, np.random.default_rng(0))
    plan = plan_at(4, scenario, (1.0, 2.0, 0.1, 15.0))
    network.extra_delay[:] = np.array([[0, 0, 0], [0, 0, 0], [0, 2, 0]])  # [receiver, sender]
    network.send(4, 1, plan, np.array([True, False, True]))
    assert network.deliver(5).tolist() == [0, 0, 0]  # UAV 1's copy, on time
    assert network.held[0][1] is plan and network.held[2][1] is initial[1]
    assert network.deliver(6).tolist() == [0, 0, 0]
    assert network.deliver(7).tolist() == [0, 0, 1]  # UAV 3's copy, two periods late
    assert network.held[2][1] is plan and network.in_flight == []


def test_the_network_hands_over_what_one_copy_at_a_time_would():
    """Random sends under loss and jitter against a plain per-copy model of the links."""
    scenario = get_scenario("paper", packet_loss=0.3, loss_correlation=0.4,
                            delay_steps=1, delay_jitter_steps=3)  # fmt: skip
    rng = np.random.default_rng(5)
    initial = [plan_at(0, scenario) for _ in range(3)]
    network = Network(scenario, initial, np.random.default_rng(1))
    held = [list(initial) for _ in range(3)]
    copies: list[tuple[int, int, int, Plan, bool]] = []  # arrival, sender, receiver, plan, late
    for step in range(1, 60):
        network.advance_links()
        late = np.zeros(3, dtype=np.int64)
        waiting = []
        for arrival, sender, receiver, plan, is_late in copies:
            if arrival > step:
                waiting.append((arrival, sender, receiver, plan, is_late))
                continue
            if plan.start_step >= held[receiver][sender].start_step:
                held[receiver][sender] = plan
            late[receiver] += is_late
        copies = waiting
        np.testing.assert_array_equal(network.deliver(step), late)
        assert all(network.held[i][j] is held[i][j] for i in range(3) for j in range(3))
        for sender in np.flatnonzero(rng.random(3) < 0.6):
            listeners = rng.random(3) < 0.8
            listeners[sender] = False
            plan = plan_at(step, scenario)
            lost = network.send(step, int(sender), plan, listeners)
            np.testing.assert_array_equal(lost, listeners & network.lost_state[:, sender])
            for receiver in np.flatnonzero(listeners & ~lost):
                delay = scenario.communication.delay_steps + network.extra_delay[receiver, sender]
                arrival = step + 1 + delay
                copies.append((arrival, int(sender), int(receiver), plan, arrival > step + 1))


def test_bursty_losses_have_the_stated_share_and_burst_length():
    loss, rho = 0.3, 0.6
    scenario = get_scenario("paper", packet_loss=loss, loss_correlation=rho)
    network = Network(scenario, [plan_at(0, scenario)] * 3, np.random.default_rng(7))
    states = []
    for _ in range(20_000):
        network.advance_links()
        states.append(network.lost_state[0, 1])
    states = np.array(states)
    assert abs(states.mean() - loss) < 0.02
    starts = np.flatnonzero(states[1:] & ~states[:-1])
    bursts = states.sum() / max(len(starts), 1)
    assert abs(bursts - 1.0 / ((1 - loss) * (1 - rho))) < 0.35


def test_losses_and_delays_are_logged_and_counted():
    scenario = get_scenario("paper", packet_loss=0.3, delay_steps=1, **SHORT)
    trace = simulate(scenario, get_optimizer("pso"), trigger=False, seed=3)
    metrics = compute_metrics(trace)
    assert metrics.plans_sent == 3 * 2 * scenario.timing.n_steps
    assert 0.15 < metrics.plans_lost / metrics.plans_sent < 0.45
    assert metrics.plans_late > 0
    assert metrics.plans_late + metrics.plans_lost <= metrics.plans_sent
    again = simulate(scenario, get_optimizer("pso"), trigger=False, seed=3)
    np.testing.assert_array_equal(again.plans_lost, trace.plans_lost)
    np.testing.assert_array_equal(again.states, trace.states)


def test_link_draws_do_not_depend_on_the_optimiser():
    scenario = get_scenario("paper", packet_loss=0.4, **SHORT)
    a = simulate(scenario, get_optimizer("pso"), trigger=False, seed=5)
    b = simulate(scenario, get_optimizer("random-search"), trigger=False, seed=5)
    # with the trigger off every UAV sends at every instant: the same links lose the same plans
    np.testing.assert_array_equal(a.plans_lost, b.plans_lost)


# --- disturbances ----------------------------------------------------------------------------


def test_zero_wind_and_zero_noise_change_nothing():
    quiet = PAPER.with_overrides(
        wind_mean_m_s=(0.0, 0.0), gust_std_m_s=0.0, gust_time_constant_s=7.0,
        position_noise_std_m=0.0, heading_noise_std_rad=0.0, speed_noise_std_m_s=0.0,
        **SHORT,
    )  # fmt: skip
    base = PAPER.with_overrides(**SHORT)
    a = simulate(base, get_optimizer("modified-bso"), trigger=True, seed=2)
    b = simulate(quiet, get_optimizer("modified-bso"), trigger=True, seed=2)
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.solve_cost, b.solve_cost)
    assert not b.wind.any()
    disturbances = Disturbances(quiet, np.random.default_rng(0), np.random.default_rng(1))
    states = quiet.initial_state_array()
    assert disturbances.measure(states) is states
    controls = np.full((3, 2), 0.1)
    following, _ = disturbances.step(states, controls)
    np.testing.assert_array_equal(following, step_plant(states, controls, 0.2, 1))


def test_wind_moves_the_plant_by_wind_times_period():
    scenario = get_scenario("paper", wind_mean_m_s=(2.0, -1.0))
    disturbances = Disturbances(scenario, np.random.default_rng(0), np.random.default_rng(1))
    states, controls = scenario.initial_state_array(), np.zeros((3, 2))
    following, wind = disturbances.step(states, controls)
    still = step_plant(states, controls, 0.2, 1)
    np.testing.assert_allclose(following[:, :2] - still[:, :2], [[0.4, -0.2]] * 3, atol=1e-12)
    np.testing.assert_array_equal(following[:, 2:], still[:, 2:])
    assert wind.tolist() == [[2.0, -1.0]] * 3


def test_gusts_are_an_ornstein_uhlenbeck_process_with_the_stated_spread_and_memory():
    scenario = get_scenario("paper", gust_std_m_s=1.5, gust_time_constant_s=2.0)
    disturbances = Disturbances(scenario, np.random.default_rng(3), np.random.default_rng(4))
    states, controls = scenario.initial_state_array(), np.zeros((3, 2))
    samples = []
    for _ in range(6000):
        samples.append(disturbances.wind[:, 0].copy())
        disturbances.step(states, controls)
    series = np.array(samples)
    assert abs(series.std() - 1.5) < 0.15
    lag = np.corrcoef(series[1:, 0], series[:-1, 0])[0, 1]
    assert abs(lag - np.exp(-0.2 / 2.0)) < 0.05


def test_noise_and_mismatch_act_and_keep_the_prediction_model():
    scenario = get_scenario("paper", position_noise_std_m=0.5, plant_accel_gain=0.5, **SHORT)
    seen = []

    class Recording:
        default_budget = get_optimizer("pso").default_budget

        def minimize(self, problem, bounds, rng, budget, x0):
            seen.append(problem.state.copy())
            return get_optimizer("pso").minimize(problem, bounds, rng, budget, x0)

    trace = simulate(scenario, Recording(), trigger=False, seed=0)
    measured = np.array(seen[:3])
    true = trace.states[0]
    assert np.all(np.abs(measured[:, :2] - true[:, :2]) > 0)
    np.testing.assert_array_equal(measured[:, 2:], true[:, 2:])  # heading/speed noise off
    # the plant's speed follows half the commanded acceleration
    np.testing.assert_allclose(
        trace.states[1:, :, 3] - trace.states[:-1, :, 3],
        0.5 * trace.controls[:, :, 0] * scenario.timing.period_s,
        atol=1e-12,
    )


# --- obstacles, collisions and the metrics at scale --------------------------------------------


def hand_trace(positions: np.ndarray, scenario) -> Trace:
    """A trace with the given positions ``(T + 1, N, 2)`` and nothing else of interest."""
    n_instants, n_uav = positions.shape[:2]
    states = np.zeros((n_instants, n_uav, 4))
    states[:, :, :2] = positions
    n_steps = n_instants - 1
    times = np.arange(n_instants) * scenario.timing.period_s
    return Trace(
        scenario=scenario, optimizer="hand", trigger=False, seed=0, times=times, states=states,
        controls=np.zeros((n_steps, n_uav, 2)), solved=np.ones((n_steps, n_uav), bool),
        reasons=np.zeros((n_steps, n_uav, 4), bool), solve_time_s=np.full((n_steps, n_uav), 1e-3),
        nfev=np.ones((n_steps, n_uav), np.int64), solve_cost=np.zeros((n_steps, n_uav)),
        reference=positions.mean(axis=1), reference_heading=np.zeros(n_instants),
        desired_offsets=np.broadcast_to(
            np.asarray(scenario.formation_offsets), (n_instants, n_uav, 2)
        ),
        wall_time_s=1.0, solve_failed=np.zeros((n_steps, n_uav), bool),
        plan_at_bound=np.zeros((n_steps, n_uav), bool),
    )  # fmt: skip


def test_a_collision_is_counted_when_two_uavs_pass_within_the_safety_radius():
    scenario = get_scenario("paper", safety_radius_m=3.0, n_steps=4, settle_time_s=0.0)
    # UAVs 1 and 2 cross between instants 1 and 2 (at the instants they are 10 m apart);
    # UAV 3 stays far away
    uav1 = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0], [40.0, 0.0]])
    uav2 = np.array([[30.0, -1.0], [20.0, -1.0], [10.0, -1.0], [0.0, -1.0], [-10.0, -1.0]])
    uav3 = np.array([[0.0, 100.0]] * 5)
    trace = hand_trace(np.stack((uav1, uav2, uav3), axis=1), scenario)
    metrics = compute_metrics(trace)
    assert metrics.min_separation_m == pytest.approx(np.hypot(10.0, 1.0))
    assert metrics.collisions == 1
    assert metrics.collision_time_s == pytest.approx(0.2)
    wider = compute_metrics(hand_trace(trace.states[:, :, :2], scenario.with_overrides(
        safety_radius_m=0.5)))  # fmt: skip
    assert wider.collisions == 0


def test_obstacle_intrusions_are_counted_once_per_entry():
    scenario = get_scenario("paper", obstacles=((15.0, 0.0, 2.0),), n_steps=4, settle_time_s=0.0)
    uav1 = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0], [40.0, 0.0]])
    far = np.array([[0.0, 100.0]] * 5)
    trace = hand_trace(np.stack((uav1, far, far + np.array([0.0, 50.0])), axis=1), scenario)
    metrics = compute_metrics(trace)
    assert metrics.obstacle_intrusions == 1
    assert metrics.obstacle_time_s == pytest.approx(0.2)


def test_segment_min_distance_is_the_closest_approach():
    start = np.array([[-5.0, 2.0], [1.0, 1.0], [3.0, 4.0]])
    end = np.array([[5.0, 2.0], [2.0, 2.0], [3.0, 4.0]])
    np.testing.assert_allclose(segment_min_distance(start, end), [2.0, np.sqrt(2.0), 5.0])


def test_collision_penalty_pushes_the_plan_away_from_a_neighbour():
    scenario = get_scenario("paper", w_collision=100.0, safety_radius_m=5.0)
    rng = np.random.default_rng(0)
    state = np.array([0.0, 0.0, 0.0, 15.0])
    horizon = scenario.timing.horizon_steps
    ahead = np.column_stack((15.0 * 0.2 * np.arange(1, horizon + 1), np.zeros(horizon)))
    neighbours = np.stack((ahead, ahead + 100.0))
    desired = np.zeros_like(neighbours)
    penalised = LocalProblem(scenario, 0, state, neighbours, desired, ahead)
    free = LocalProblem(scenario.with_overrides(w_collision=0.0), 0, state, neighbours, desired,
                        ahead)  # fmt: skip
    decisions = penalised.bounds.sample(rng, 20)
    assert np.all(penalised(decisions) >= free(decisions))
    straight = np.zeros((1, penalised.dim))
    assert penalised(straight)[0] > free(straight)[0]  # flying into the neighbour's estimate
    plain = penalised.reference_cost(straight[0])
    assert penalised(straight)[0] == pytest.approx(plain, rel=1e-12)


def test_obstacle_penalty_agrees_with_the_plain_cost():
    scenario = get_scenario("paper-obstacles", obstacles=((20.0, 1.0, 4.0),))
    rng = np.random.default_rng(2)
    state, neighbours, desired, reference = random_problem_inputs(rng, scenario, 2)
    state[:2] = 0.0
    problem = LocalProblem(scenario, 0, state, neighbours, desired, reference)
    decisions = problem.bounds.sample(rng, 20)
    plain = [problem.reference_cost(d) for d in decisions]
    np.testing.assert_allclose(problem(decisions), plain, rtol=1e-12)
    free = LocalProblem(scenario.with_overrides(w_obstacle=0.0, w_collision=0.0), 0, state,
                        neighbours, desired, reference)  # fmt: skip
    assert np.any(problem(decisions) > free(decisions))


def test_swarm_metrics_summarise_the_graph_pairs():
    scenario = get_scenario("swarm-10", graph="ring", **SHORT)
    trace = simulate(scenario, get_optimizer("pso"), trigger=True, seed=0)
    columns = compute_metrics(trace).columns()
    assert not any(name.startswith("distance_error_max_m_d") for name in columns)
    pairs = graph_pairs(trace)
    assert pairs[0].sum() == 10  # the ring's pairs
    assert np.isfinite(columns["distance_error_rms_m"])
    assert columns["distance_error_rms_m"] <= columns["distance_error_max_m_max"]
    paper = compute_metrics(simulate(PAPER.with_overrides(**SHORT), get_optimizer("pso"),
                                     trigger=True, seed=0)).columns()  # fmt: skip
    assert {"distance_error_max_m_d12", "distance_error_max_m_d23",
            "distance_error_max_m_d31"} <= set(paper)  # fmt: skip


def test_named_pairs_cover_every_pair_and_the_max_covers_the_graph_pairs():
    scenario = swarm_scenario("ring-4", 4, graph="ring", **SHORT)
    trace = simulate(scenario, get_optimizer("pso"), trigger=True, seed=0)
    measured = compute_metrics(trace)
    named = measured.distance_error_max_m
    assert list(named) == ["d12", "d23", "d34", "d41", "d13", "d24"]  # ring first, then chords
    pairs = graph_pairs(trace)
    assert np.all(pairs.sum(axis=(1, 2)) == 4)  # the chords d13, d24 are not links
    ring = [named[name] for name in ("d12", "d23", "d34", "d41")]
    assert measured.distance_error_max_m_max == max(ring)


# --- mixed vehicles and the formation library ------------------------------------------------


def test_per_uav_bounds_reach_the_problem_and_the_plan():
    bounds = ((-2.0, 2.0), (-7.0, 7.0), (-4.0, 1.0))
    scenario = get_scenario("paper", uav_accel_bounds=bounds, **SHORT)
    trace = simulate(scenario, get_optimizer("pso"), trigger=False, seed=1)
    for uav, (low, high) in enumerate(bounds):
        assert trace.controls[:, uav, 0].min() >= low - 1e-12
        assert trace.controls[:, uav, 0].max() <= high + 1e-12
    problem_bounds = LocalProblem(scenario, 2, *random_problem_inputs(
        np.random.default_rng(0), scenario, 2)).bounds  # fmt: skip
    assert problem_bounds.lower[0] == -4.0 and problem_bounds.upper[0] == 1.0
    assert problem_bounds.lower[1] == -0.25


@pytest.mark.parametrize("shape", list(FormationShape))
@pytest.mark.parametrize("n_uav", [3, 4, 7, 25])
def test_formations_are_centred_with_the_stated_spacing(shape, n_uav):
    if shape == FormationShape.TRIANGLE and n_uav != 3:
        with pytest.raises(ValueError, match="triangle"):
            formation_offsets(shape, n_uav, 10.0)
        return
    offsets = formation_offsets(shape, n_uav, 8.0)
    assert offsets.shape == (n_uav, 2)
    np.testing.assert_allclose(offsets.mean(axis=0), 0.0, atol=1e-12)
    gaps = np.linalg.norm(offsets[:, None] - offsets[None], axis=-1)[np.triu_indices(n_uav, 1)]
    assert gaps.min() == pytest.approx(8.0 if shape != FormationShape.TRIANGLE else 8.0 * 2**0.5)


def test_the_triangle_is_the_papers():
    np.testing.assert_allclose(
        formation_offsets("triangle", 3, 10.0), np.asarray(PAPER.formation_offsets), atol=1e-12
    )


def test_scattered_initial_states_are_seeded_and_apart():
    offsets = formation_offsets("grid", 20, 10.0)
    a = scattered_initial_states(offsets, np.random.default_rng(5))
    b = scattered_initial_states(offsets, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    gaps = np.linalg.norm(a[:, None, :2] - a[None, :, :2], axis=-1)[np.triu_indices(20, 1)]
    assert gaps.min() >= 5.0
    assert np.all((a[:, 3] >= 13.0) & (a[:, 3] <= 17.0))
    scenario = swarm_scenario("mine", 20, shape="grid", layout_seed=5)
    np.testing.assert_array_equal(scenario.initial_state_array(), a)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"graph": "star"}, "Scenario.graph must be one of"),
        ({"graph": "k-nearest", "graph_neighbours": 3}, "graph_neighbours must be below"),
        ({"packet_loss": 1.0}, "Scenario.packet_loss"),
        ({"delay_steps": -1}, "Scenario.delay_steps"),
        ({"wind_mean_m_s": (1.0,)}, "Scenario.wind_mean_m_s must be two finite numbers"),
        ({"obstacles": ((1.0, 2.0),)}, "Scenario.obstacles must hold"),
        ({"obstacles": ((1.0, 2.0, 0.0),)}, "radii must be > 0"),
        ({"uav_accel_bounds": ((-1.0, 1.0),)}, "Scenario.uav_accel_bounds must hold 3"),
        ({"uav_turn_rate_bounds": ((1.0, -1.0),) * 3}, "lower < upper"),
        ({"plant_accel_gain": 0.0}, "Scenario.plant_accel_gain"),
        ({"safety_radius_m": 0.0}, "Scenario.safety_radius_m"),
    ],
)
def test_bad_scenario_fields_are_named(overrides, message):
    with pytest.raises(ValueError, match=message):
        get_scenario("paper", **overrides)


def test_registered_swarms():
    for n_uav in (5, 10, 20, 25):
        scenario = get_scenario(f"swarm-{n_uav}")
        assert scenario.n_uav == n_uav
        assert scenario.communication.graph == CommunicationGraph.COMPLETE
