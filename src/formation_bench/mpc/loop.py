"""The closed loop: the fixed DMPC harness every optimiser is plugged into.

At every update instant t_c (c = 0, 1, ...), every UAV, in parallel (Jacobi):

1. builds estimates of its neighbours from their last published plans;
2. decides with the trigger whether to re-solve (always at c = 0, when it has
   no plan of its own, and at every instant when the trigger is off);
3. if so, solves its problem of eq. (14) warm-started from its shifted
   previous plan, and publishes the new plan;
4. applies the control of its current plan for this period.

The plant is the same model as the prediction (eq. 1, RK4, zero-order hold).
Each UAV draws its random numbers from its own Generator, spawned from the
run's seed, so a run's numbers do not depend on the order of the UAVs' solves.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from formation_bench.mpc.disturbance import Disturbances
from formation_bench.mpc.network import Network, listening
from formation_bench.mpc.problem import (
    LocalProblem,
    Plan,
    centre_group_size,
    coasting_plan,
    estimate_positions,
    shifted_controls,
)
from formation_bench.mpc.scenario import CommunicationGraph, Scenario
from formation_bench.mpc.trigger import (
    TriggerDecision,
    control_condition,
    distance_condition,
    expiry_condition,
    tracking_condition,
)
from formation_bench.optimizers.base import Budget, Optimizer


@dataclass(frozen=True)
class Trace:
    """Everything logged by one closed-loop run (T = n_steps instants, N UAVs)."""

    scenario: Scenario
    optimizer: str
    trigger: bool
    seed: int
    times: np.ndarray
    """``(T + 1,)`` instants t_c, seconds; the last is the end of the run."""
    states: np.ndarray
    """``(T + 1, N, 4)`` states at every instant."""
    controls: np.ndarray
    """``(T, N, 2)`` controls applied over ``[t_c, t_c + delta_T)``."""
    solved: np.ndarray
    """``(T, N)`` whether each UAV re-solved at t_c."""
    reasons: np.ndarray
    """``(T, N, 4)`` which trigger conditions held (see ``TRIGGER_CONDITIONS``); at c = 0
    every UAV has no plan yet, logged as expiry."""
    solve_time_s: np.ndarray
    """``(T, N)`` wall time of each solve (problem build + optimiser), NaN if none."""
    nfev: np.ndarray
    """``(T, N)`` objective evaluations of each solve, 0 if none."""
    solve_cost: np.ndarray
    """``(T, N)`` optimal cost J_i found, NaN if none."""
    reference: np.ndarray
    """``(T + 1, 2)`` reference formation-centre position at every instant."""
    reference_heading: np.ndarray
    """``(T + 1,)`` reference heading, rad."""
    desired_offsets: np.ndarray
    """``(T + 1, N, 2)`` desired world-frame offsets of every UAV from the centre."""
    wall_time_s: float
    """Wall time of the whole run, seconds."""
    solve_failed: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    """``(T, N)`` whether a solve failed (``result.success`` False): the UAV then applied its
    shifted previous plan (the warm start) instead of the result."""
    deadline_s: float | None = None
    """Per-solve wall-clock deadline of the run's budget, seconds; None: none."""
    plan_at_bound: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=bool))
    """``(T, N)`` whether the plan a solve published has a control at one of its bounds
    (within :data:`AT_BOUND_TOLERANCE` of the bound's range), False without a solve."""
    neighbours: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 0), dtype=bool))
    """``(T, N, N)`` whether UAV i listened to UAV j at t_c (``[c, i, j]``)."""
    plans_lost: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64))
    """``(T, N)`` plans sent to each UAV at t_c that its links lost."""
    plans_late: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), dtype=np.int64))
    """``(T, N)`` plans each UAV received at t_c later than the next instant after sending."""
    wind: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 2)))
    """``(T, N, 2)`` wind velocity that moved each UAV over ``[t_c, t_c + delta_T)``, m/s."""


ProgressCallback = Callable[[int, int], None]

AT_BOUND_TOLERANCE = 1e-6
"""A planned control this fraction of its bounds' range from a bound counts as at it (an
interior-point solver stops a little inside an active bound)."""


def at_bound(decision: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> bool:
    """Whether any component of ``decision`` lies at its lower or upper bound."""
    margin = AT_BOUND_TOLERANCE * (upper - lower)
    return bool(np.any((decision <= lower + margin) | (decision >= upper - margin)))


def simulate(
    scenario: Scenario,
    optimizer: Optimizer,
    *,
    trigger: bool,
    seed: int,
    optimizer_name: str = "",
    budget: Budget | None = None,
    progress: ProgressCallback | None = None,
) -> Trace:
    """Run the closed loop for ``scenario.n_steps`` instants and log it."""
    start_time = time.perf_counter()
    n_uav, horizon, period = scenario.n_uav, scenario.horizon_steps, scenario.period_s
    n_steps = scenario.n_steps
    # the UAVs' streams come first, so adding the environment's changed none of them
    streams = np.random.SeedSequence(seed).spawn(n_uav + 3)
    rngs = [np.random.default_rng(s) for s in streams[:n_uav]]
    network_rng, wind_rng, noise_rng = (np.random.default_rng(s) for s in streams[n_uav:])

    times = np.arange(n_steps + horizon + 1) * period
    reference, heading = scenario.reference_at(times)
    offsets = scenario.desired_offsets(heading)  # (n_steps + H + 1, N, 2)
    lookahead = scenario.trigger_lookahead
    bounds = [scenario.control_bounds_of(i) for i in range(n_uav)]
    # off the complete graph the centre is estimated from the UAV and its neighbours alone
    group_centre = scenario.graph != CommunicationGraph.COMPLETE

    states = np.empty((n_steps + 1, n_uav, 4))
    states[0] = scenario.initial_state_array()
    controls = np.zeros((n_steps, n_uav, 2))
    solved = np.zeros((n_steps, n_uav), dtype=bool)
    reasons = np.zeros((n_steps, n_uav, 4), dtype=bool)
    solve_time = np.full((n_steps, n_uav), np.nan)
    nfev = np.zeros((n_steps, n_uav), dtype=np.int64)
    solve_cost = np.full((n_steps, n_uav), np.nan)
    solve_failed = np.zeros((n_steps, n_uav), dtype=bool)
    plan_at_bound = np.zeros((n_steps, n_uav), dtype=bool)
    neighbours = np.zeros((n_steps, n_uav, n_uav), dtype=bool)
    plans_lost = np.zeros((n_steps, n_uav), dtype=np.int64)
    plans_late = np.zeros((n_steps, n_uav), dtype=np.int64)
    wind = np.zeros((n_steps, n_uav, 2))

    plans: list[Plan] = [coasting_plan(states[0, i], 0, scenario) for i in range(n_uav)]
    network = Network(scenario, plans, network_rng)
    disturbances = Disturbances(scenario, wind_rng, noise_rng)
    for c in range(n_steps):
        network.advance_links()
        plans_late[c] = network.deliver(c)
        listens = listening(scenario, states[c, :, :2])
        neighbours[c] = listens
        measured = disturbances.measure(states[c])
        estimated: dict[int, np.ndarray] = {}  # positions at c .. c + H, once per plan
        published = list(plans)
        for i in range(n_uav):
            heard = [int(j) for j in np.flatnonzero(listens[i])]
            for plan in (plans[i], *(network.held[i][j] for j in heard)):
                if id(plan) not in estimated:
                    estimated[id(plan)] = estimate_positions(
                        plan, c, horizon + 1, period, scenario.estimate_extension
                    )
            own = estimated[id(plans[i])]
            others = (
                np.stack([estimated[id(network.held[i][j])] for j in heard])
                if heard
                else np.zeros((0, horizon + 1, 2))
            )  # (J, H + 1, 2)
            desired_relative = np.transpose(
                offsets[c : c + horizon + 1, i][:, None] - offsets[c : c + horizon + 1, heard],
                (1, 0, 2),
            )  # (J, H + 1, 2)
            group_offsets = (
                offsets[c : c + horizon + 1, [i, *heard]].sum(axis=1) if group_centre else None
            )
            lower, upper = bounds[i]
            if c == 0:
                decision = TriggerDecision(False, False, False, True)
            else:
                window = slice(0, lookahead + 1)
                own_plan = plans[i]
                decision = TriggerDecision(
                    distance=distance_condition(
                        own[window], others[:, window], desired_relative[:, window], scenario.eps_p
                    ),
                    tracking=tracking_condition(
                        own[window],
                        others[:, window],
                        reference[c : c + lookahead + 1],
                        centre_group_size(n_uav, len(heard), group_centre),
                        scenario.eps_o,
                        None if group_offsets is None else group_offsets[window],
                    ),
                    control=c - own_plan.start_step < horizon
                    and control_condition(
                        own_plan.controls[c - own_plan.start_step], lower, upper, scenario.eta
                    ),
                    expiry=expiry_condition(c - own_plan.start_step, horizon),
                )
            reasons[c, i] = decision.as_tuple()
            if trigger and not decision.fire:
                continue
            solve_start = time.perf_counter()
            problem = LocalProblem(
                scenario,
                i,
                measured[i],
                np.ascontiguousarray(others[:, 1:]),
                desired_relative[:, 1:],
                reference[c + 1 : c + horizon + 1],
                None if group_offsets is None else group_offsets[1:],
            )
            warm_start = problem.decision_from_controls(shifted_controls(plans[i], c))
            result = optimizer.minimize(problem, problem.bounds, rngs[i], budget, warm_start)
            decision = result.x
            if not result.success:  # a failed solve falls back to the shifted previous plan
                decision = warm_start
                solve_failed[c, i] = True
            published[i] = problem.plan(decision, c)
            solve_time[c, i] = time.perf_counter() - solve_start
            solved[c, i] = True
            nfev[c, i] = result.nfev
            solve_cost[c, i] = result.fun
            plan_at_bound[c, i] = at_bound(decision, problem.bounds.lower, problem.bounds.upper)
            plans_lost[c] += network.send(c, i, published[i], listens[:, i])
        plans = published
        for i in range(n_uav):
            controls[c, i] = plans[i].controls[c - plans[i].start_step]
        states[c + 1], wind[c] = disturbances.step(states[c], controls[c])
        if progress is not None:
            progress(c + 1, n_steps)

    return Trace(
        scenario=scenario,
        optimizer=optimizer_name or type(optimizer).__name__,
        trigger=trigger,
        seed=seed,
        times=times[: n_steps + 1],
        states=states,
        controls=controls,
        solved=solved,
        reasons=reasons,
        solve_time_s=solve_time,
        nfev=nfev,
        solve_cost=solve_cost,
        reference=reference[: n_steps + 1],
        reference_heading=heading[: n_steps + 1],
        desired_offsets=offsets[: n_steps + 1],
        wall_time_s=time.perf_counter() - start_time,
        solve_failed=solve_failed,
        plan_at_bound=plan_at_bound,
        deadline_s=None if budget is None else budget.deadline_s,
        neighbours=neighbours,
        plans_lost=plans_lost,
        plans_late=plans_late,
        wind=wind,
    )
