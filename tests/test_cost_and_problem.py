"""The compiled cost against eq. (14) as printed and the plant; plans, estimates and warm starts."""

import math

import numpy as np
import pytest

from formation_bench.mpc.cost import NO_PENALTIES, batch_cost, batch_cost_reference, block_map
from formation_bench.mpc.model import REDUCTION_LIMIT, step_plant
from formation_bench.mpc.problem import (
    LocalProblem,
    Plan,
    coasting_plan,
    estimate_positions,
    shifted_controls,
)
from formation_bench.mpc.scenario import PAPER, EstimateExtension


def random_problem(rng, scenario):
    horizon = scenario.timing.horizon_steps
    state = np.array(
        [rng.normal(0, 20), rng.normal(0, 20), rng.uniform(-math.pi, math.pi), rng.uniform(5, 20)]
    )
    neighbours = rng.normal(0, 30, size=(scenario.n_uav - 1, horizon, 2))
    desired = rng.normal(0, 10, size=(scenario.n_uav - 1, horizon, 2))
    reference = rng.normal(0, 30, size=(horizon, 2))
    return LocalProblem(scenario, 0, state, neighbours, desired, reference)


@pytest.mark.parametrize(
    ("n_blocks", "substeps", "w_dst", "w_trj"),
    [(4, 1, 1.0, 1.0), (20, 1, 0.3, 2.5), (3, 3, 1.7, 0.0), (1, 2, 0.0, 1.0)],
)
def test_compiled_cost_matches_plain_eq14(n_blocks, substeps, w_dst, w_trj):
    rng = np.random.default_rng(n_blocks + 10 * substeps)
    scenario = PAPER.with_overrides(
        n_blocks=n_blocks, rk4_substeps=substeps, w_dst=w_dst, w_trj=w_trj
    )
    for _ in range(5):
        problem = random_problem(rng, scenario)
        decisions = problem.bounds.sample(rng, 30)
        compiled = problem(decisions)
        plain = np.array([problem.reference_cost(d) for d in decisions])
        np.testing.assert_allclose(compiled, plain, rtol=1e-9)


def random_kernel_inputs(rng, horizon, n_blocks, n_neighbours, n):
    """State, targets and decisions for the kernels, decisions inside the paper's bounds."""
    state = np.array(
        [rng.normal(0, 20), rng.normal(0, 20), rng.uniform(-math.pi, math.pi), rng.uniform(5, 20)]
    )
    distance_targets = rng.normal(0, 30, size=(n_neighbours, horizon, 2))
    centre_target = rng.normal(0, 30, size=(horizon, 2))
    decisions = rng.uniform([-7.0, -0.25] * n_blocks, [7.0, 0.25] * n_blocks, (n, 2 * n_blocks))
    return state, distance_targets, centre_target, decisions


# (horizon, n_blocks, substeps): one block, several, one per period, uneven blocks, sub-steps
# across the heading reset, and the longest horizon the scenarios allow with long periods
KERNEL_LAYOUTS = [
    (1, 1, 1),
    (20, 5, 1),
    (20, 20, 1),
    (20, 1, 3),
    (7, 3, 16),
    (13, 4, 17),
    (40, 6, 50),
    (500, 1, 1),
    (500, 37, 2),
    (500, 1, 1000),
]
# (w_dst, w_centre): both terms, each alone, and large weights
KERNEL_WEIGHTS = [(1.0, 1.0 / 3.0), (0.0, 1.0), (2.5, 0.0), (40.0, 7.0)]


@pytest.mark.parametrize("weights", KERNEL_WEIGHTS)
@pytest.mark.parametrize(("horizon", "n_blocks", "substeps"), KERNEL_LAYOUTS)
def test_rotation_kernel_matches_reference_kernel(horizon, n_blocks, substeps, weights):
    seed = [horizon, n_blocks, substeps, KERNEL_WEIGHTS.index(weights)]
    rng = np.random.default_rng(seed)
    n = 4 if horizon * substeps > 10_000 else 40
    for n_neighbours in (1, 2, 4):
        state, distance_targets, centre_target, decisions = random_kernel_inputs(
            rng, horizon, n_blocks, n_neighbours, n
        )
        args = (state, block_map(horizon, n_blocks), 0.2, substeps, distance_targets,
                centre_target, *weights)  # fmt: skip
        rotated = batch_cost(decisions, *args, *NO_PENALTIES)
        plain = batch_cost_reference(decisions, *args)
        assert np.all(plain > 0)
        np.testing.assert_allclose(rotated, plain, rtol=1e-12, atol=0)


@pytest.mark.parametrize("theta", [1e3, 1e5, REDUCTION_LIMIT + 0.1, -3e6, 1e9])
def test_rotation_kernel_matches_reference_at_large_headings(theta):
    """Large headings, up to and past the polynomial reduction's range (math.cos/sin there).

    The reference rounds its middle-stage heading ``theta + h omega / 2`` to the
    spacing of the floats near ``theta``, where the rotation turns by the exact
    half turn, and both round the advanced heading to that spacing at every sub-step
    (the kernel once, in a fused multiply-add; the reference twice): the two then agree
    to a few times that spacing, relative, not better.
    """
    rng = np.random.default_rng(11)
    state, distance_targets, centre_target, decisions = random_kernel_inputs(rng, 20, 4, 2, 30)
    state[2] = theta
    args = (state, block_map(20, 4), 0.2, 2, distance_targets, centre_target, 1.0, 0.5)
    np.testing.assert_allclose(
        batch_cost(decisions, *args, *NO_PENALTIES),
        batch_cost_reference(decisions, *args),
        rtol=max(1e-12, 4 * float(np.spacing(abs(theta)))),
    )


def plant_path(state, decision, block_of_step, period, substeps):
    """Positions the plant reaches, one period at a time, under a decision's block controls."""
    controls = decision.reshape(-1, 2)[block_of_step]
    states = [state]
    for k in range(len(block_of_step)):
        states.append(step_plant(states[-1][None], controls[k : k + 1], period, substeps)[0])
    return np.array(states)[1:, :2]


@pytest.mark.parametrize(
    ("horizon", "n_blocks", "substeps", "theta"),
    [(20, 5, 1, 0.4), (20, 20, 1, -2.9), (9, 2, 3, 1.0), (11, 3, 37, 5.5), (6, 2, 2, -4e6)],
)
def test_kernel_prediction_is_the_plant_to_rounding(horizon, n_blocks, substeps, theta):
    """The kernel's predicted positions are those the plant reaches, to rounding.

    With the plant's own positions as every target, the cost is
    ``period * (2 w_dst + w_centre) * sum_k |d_k|^2`` for the kernel's position errors
    d_k, which bounds the largest of them. The kernel rounds differently (fused
    multiply-adds, the heading's pair rotated across periods): its positions stay within
    1e-14 of the path's size, or a few float spacings of the heading where that is
    larger (far past the polynomial's range the heading itself rounds to about 1e-9).
    """
    rng = np.random.default_rng([horizon, substeps])
    block_of_step = block_map(horizon, n_blocks)
    state = np.array([12.0, -30.0, theta, 14.0])
    decisions = rng.uniform([-7.0, -0.25] * n_blocks, [7.0, 0.25] * n_blocks, (9, 2 * n_blocks))
    for row, decision in enumerate(decisions):
        path = plant_path(state, decision, block_of_step, 0.2, substeps)
        targets = (np.ascontiguousarray(np.stack([path, path])), path)
        costs = batch_cost(
            decisions, state, block_of_step, 0.2, substeps, *targets, 1.0, 0.3, *NO_PENALTIES
        )
        largest_error = np.sqrt(costs[row] / (0.2 * (2 * 1.0 + 0.3)))
        bound = max(1e-14, 8 * float(np.spacing(abs(theta)))) * np.abs(path).max()
        assert largest_error <= bound
        others = np.delete(costs, row)
        assert np.all(others > 0)


def test_cost_is_zero_on_a_perfect_plan_and_positive_off_it():
    scenario = PAPER.with_overrides(n_blocks=2)
    state = np.array([0.0, 0.0, 0.0, 15.0])
    decision = np.array([1.0, 0.0, -0.5, 0.1])
    problem0 = LocalProblem(
        scenario, 0, state, np.zeros((2, 20, 2)), np.zeros((2, 20, 2)), np.zeros((20, 2))
    )
    path = problem0.plan(decision, 0).states[1:, :2]
    offsets = np.array([[5.0, 1.0], [-3.0, 4.0]])
    neighbours = path[None] - offsets[:, None, :]
    desired = np.broadcast_to(offsets[:, None, :], neighbours.shape).copy()
    reference = (path + neighbours.sum(axis=0)) / 3
    problem = LocalProblem(scenario, 0, state, neighbours, desired, reference)
    costs = problem(np.stack([decision, decision + np.array([0.5, 0.0, 0.0, 0.0])]))
    assert costs[0] == pytest.approx(0.0, abs=1e-20)
    assert costs[1] > 1.0


def test_block_map_and_decision_round_trip():
    np.testing.assert_array_equal(block_map(20, 4), np.repeat(np.arange(4), 5))
    np.testing.assert_array_equal(block_map(5, 2), [0, 0, 0, 1, 1])
    problem = random_problem(np.random.default_rng(0), PAPER.with_overrides(n_blocks=4))
    decision = np.array([1.0, 0.1, -2.0, 0.2, 3.0, -0.1, 0.0, 0.05])
    controls = problem.controls(decision)
    assert controls.shape == (20, 2)
    np.testing.assert_array_equal(controls[5], [-2.0, 0.2])
    np.testing.assert_allclose(problem.decision_from_controls(controls), decision)


def test_batch_cost_input_shape_is_checked():
    problem = random_problem(np.random.default_rng(0), PAPER)
    with pytest.raises(ValueError, match="shape"):
        problem(np.zeros((3, problem.dim + 1)))


def make_plan(start_step=4):
    controls = np.tile([0.5, 0.1], (20, 1))
    state = np.array([0.0, 0.0, 0.3, 12.0])
    from formation_bench.mpc.model import rollout

    return Plan(start_step, controls, rollout(state, controls, 0.2, 1))


def test_estimate_inside_plan_is_the_plan():
    plan = make_plan(start_step=4)
    estimate = estimate_positions(plan, 10, 15, 0.2, EstimateExtension.COAST)
    np.testing.assert_array_equal(estimate, plan.states[6:21, :2])


@pytest.mark.parametrize("rule", list(EstimateExtension))
def test_estimate_extension_past_the_plan(rule):
    plan = make_plan(start_step=4)
    estimate = estimate_positions(plan, 10, 21, 0.2, rule)  # instants 10..30, plan ends at 24
    np.testing.assert_array_equal(estimate[:15], plan.states[6:21, :2])
    x, y, theta, v = plan.states[20]
    beyond = np.arange(1, 7) * 0.2
    if rule == EstimateExtension.HOLD:
        expected = np.tile([x, y], (6, 1))
    else:
        expected = np.column_stack((x + v * np.cos(theta) * beyond, y + v * np.sin(theta) * beyond))
    np.testing.assert_allclose(estimate[15:], expected, atol=1e-12)
    with pytest.raises(ValueError, match="after"):
        estimate_positions(plan, 3, 5, 0.2, rule)


def test_shifted_controls_pad_with_the_last_control():
    plan = make_plan(start_step=0)
    controls = plan.controls.copy()
    controls[-1] = [2.0, -0.2]
    plan = Plan(0, controls, plan.states)
    shifted = shifted_controls(plan, 3)
    np.testing.assert_array_equal(shifted[:16], controls[3:19])
    np.testing.assert_array_equal(shifted[16:], np.tile([2.0, -0.2], (4, 1)))


def test_coasting_plan_keeps_speed_and_heading():
    state = np.array([1.0, 2.0, 0.7, 13.0])
    plan = coasting_plan(state, 0, PAPER)
    np.testing.assert_allclose(plan.states[:, 2:], np.tile(state[2:], (21, 1)))
    np.testing.assert_allclose(
        plan.states[-1, :2], state[:2] + 13.0 * 4.0 * np.array([math.cos(0.7), math.sin(0.7)])
    )


def test_batch_cost_kernel_directly_against_single_rows():
    problem = random_problem(np.random.default_rng(5), PAPER)
    decisions = problem.bounds.sample(np.random.default_rng(6), 7)
    together = problem(decisions)
    one_by_one = np.concatenate([problem(decisions[i : i + 1]) for i in range(7)])
    np.testing.assert_array_equal(together, one_by_one)
    assert batch_cost is not None


@pytest.mark.parametrize("rule", list(EstimateExtension))
def test_compiled_estimate_is_the_numpy_formula_to_the_bit(rule):
    rng = np.random.default_rng(21)
    for start, step, n_points in [(4, 4, 21), (4, 10, 42), (0, 30, 5), (7, 7, 1)]:
        controls = rng.uniform([-7, -0.25], [7, 0.25], size=(20, 2))
        state = np.array([*rng.uniform(-50, 50, 2), rng.uniform(-3, 3), rng.uniform(5, 20)])
        from formation_bench.mpc.model import coast, rollout

        plan = Plan(start, controls, rollout(state, controls, 0.2, 3))
        index = step - start + np.arange(n_points)
        expected = plan.states[np.minimum(index, 20), :2].copy()
        beyond = index > 20
        if rule == EstimateExtension.COAST and beyond.any():
            expected[beyond] = coast(plan.states[20], (index[beyond] - 20) * 0.2)
        np.testing.assert_array_equal(estimate_positions(plan, step, n_points, 0.2, rule), expected)


def test_block_means_sum_in_the_order_of_add_at():
    from formation_bench.mpc.cost import block_map
    from formation_bench.mpc.problem import block_means

    rng = np.random.default_rng(5)
    for horizon, n_blocks in [(20, 5), (20, 20), (17, 4), (20, 1)]:
        blocks = block_map(horizon, n_blocks)
        controls = rng.uniform(-7, 7, size=(horizon, 2)) * 10.0 ** rng.integers(-8, 8, (horizon, 1))
        sums = np.zeros((n_blocks, 2))
        np.add.at(sums, blocks, controls)
        counts = np.bincount(blocks, minlength=n_blocks)[:, None]
        np.testing.assert_array_equal(
            block_means(controls, blocks, n_blocks), (sums / counts).reshape(-1)
        )
