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

from formation_bench.kernel_cache import njit
from formation_bench.mpc.disturbance import Disturbances
from formation_bench.mpc.network import Network, fixed_listening, heard_lists, listening
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

TRACK_HORIZONS = 2
"""Horizons (of H + 1 instants) a plan's estimate is computed over at first: its own plan is
re-solved at the latest after one horizon, so two cover every instant it is used at unless
plans are lost or late (then the estimate is extended)."""

AT_BOUND_TOLERANCE = 1e-6
"""A planned control this fraction of its bounds' range from a bound counts as at it (an
interior-point solver stops a little inside an active bound)."""


@njit(cache=True)
def at_bound(decision: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> bool:
    """Whether any component of ``decision`` lies at its lower or upper bound (compiled:
    asked after every solve)."""
    for k in range(decision.shape[0]):
        margin = AT_BOUND_TOLERANCE * (upper[k] - lower[k])
        if decision[k] <= lower[k] + margin or decision[k] >= upper[k] - margin:
            return True
    return False


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
    """Run the closed loop for ``scenario.timing.n_steps`` instants and log it."""
    start_time = time.perf_counter()
    loop = ClosedLoop(scenario, optimizer, trigger=trigger, seed=seed, budget=budget)
    n_steps = scenario.timing.n_steps
    for c in range(n_steps):
        loop.control_period(c)
        if progress is not None:
            progress(c + 1, n_steps)
    return loop.trace(
        optimizer_name or type(optimizer).__name__, seed, time.perf_counter() - start_time
    )


@dataclass(frozen=True)
class RandomStreams:
    """A run's random numbers: one Generator per UAV (its solves), then the links', the
    wind's and the measurement noise's, all spawned from the run's seed."""

    uavs: list[np.random.Generator]
    network: np.random.Generator
    wind: np.random.Generator
    noise: np.random.Generator

    @classmethod
    def spawned(cls, seed: int, n_uav: int) -> RandomStreams:
        # the UAVs' streams come first, so adding the environment's changed none of them
        streams = np.random.SeedSequence(seed).spawn(n_uav + 3)
        uavs = [np.random.default_rng(s) for s in streams[:n_uav]]
        network, wind, noise = (np.random.default_rng(s) for s in streams[n_uav:])
        return cls(uavs, network, wind, noise)


@dataclass(frozen=True)
class TraceLog:
    """The per-instant arrays of a run as it fills them (T instants, N UAVs; see
    :class:`Trace` for each)."""

    states: np.ndarray
    controls: np.ndarray
    solved: np.ndarray
    reasons: np.ndarray
    solve_time_s: np.ndarray
    nfev: np.ndarray
    solve_cost: np.ndarray
    solve_failed: np.ndarray
    plan_at_bound: np.ndarray
    neighbours: np.ndarray
    plans_lost: np.ndarray
    plans_late: np.ndarray
    wind: np.ndarray

    @classmethod
    def empty(cls, n_steps: int, initial_states: np.ndarray) -> TraceLog:
        """Nothing logged yet: the initial states, no solve, no control."""
        n_uav = initial_states.shape[0]
        states = np.empty((n_steps + 1, n_uav, 4))
        states[0] = initial_states
        return cls(
            states=states,
            controls=np.zeros((n_steps, n_uav, 2)),
            solved=np.zeros((n_steps, n_uav), dtype=bool),
            reasons=np.zeros((n_steps, n_uav, 4), dtype=bool),
            solve_time_s=np.full((n_steps, n_uav), np.nan),
            nfev=np.zeros((n_steps, n_uav), dtype=np.int64),
            solve_cost=np.full((n_steps, n_uav), np.nan),
            solve_failed=np.zeros((n_steps, n_uav), dtype=bool),
            plan_at_bound=np.zeros((n_steps, n_uav), dtype=bool),
            neighbours=np.zeros((n_steps, n_uav, n_uav), dtype=bool),
            plans_lost=np.zeros((n_steps, n_uav), dtype=np.int64),
            plans_late=np.zeros((n_steps, n_uav), dtype=np.int64),
            wind=np.zeros((n_steps, n_uav, 2)),
        )


@dataclass(frozen=True)
class Neighbourhood:
    """What one UAV knows at an instant, over the predicted instants c .. c + H."""

    heard: list[int]
    """The neighbours it listens to."""
    own: np.ndarray
    """``(H + 1, 2)`` its own estimated positions (from its current plan)."""
    others: np.ndarray
    """``(J, H + 1, 2)`` its neighbours' estimated positions (from the plans it holds)."""
    desired_relative: np.ndarray
    """``(J, H + 1, 2)`` its desired position relative to each neighbour."""
    group_offsets: np.ndarray | None
    """``(H + 1, 2)`` the sum of its and its neighbours' desired offsets, when it estimates the
    formation centre from them alone (off the complete graph); None on the complete graph."""


class ClosedLoop:
    """One run of the closed loop: the swarm's plans, links and plant between instants, and the
    log of every instant."""

    def __init__(
        self,
        scenario: Scenario,
        optimizer: Optimizer,
        *,
        trigger: bool,
        seed: int,
        budget: Budget | None,
    ) -> None:
        self.scenario, self.optimizer, self.trigger_on, self.budget = (
            scenario, optimizer, trigger, budget
        )  # fmt: skip
        n_uav, timing = scenario.n_uav, scenario.timing
        self.n_uav, self.horizon, self.period = n_uav, timing.horizon_steps, timing.period_s
        n_steps = timing.n_steps
        self.streams = RandomStreams.spawned(seed, n_uav)

        self.times = np.arange(n_steps + self.horizon + 1) * self.period
        self.reference, self.heading = scenario.reference_at(self.times)
        self.offsets = scenario.desired_offsets(self.heading)  # (n_steps + H + 1, N, 2)
        # by UAV, so that a UAV's desired offsets from its neighbours are one subtraction
        self.offsets_by_uav = np.ascontiguousarray(self.offsets.transpose(1, 0, 2))
        self.lookahead = scenario.trigger_lookahead
        self.bounds = [scenario.control_bounds_of(i) for i in range(n_uav)]
        # off the complete graph the centre is estimated from the UAV and its neighbours alone
        self.group_centre = scenario.communication.graph != CommunicationGraph.COMPLETE

        self.log = TraceLog.empty(n_steps, scenario.initial_state_array())
        self.plans: list[Plan] = [
            coasting_plan(self.log.states[0, i], 0, scenario) for i in range(n_uav)
        ]
        self.network = Network(scenario, self.plans, self.streams.network)
        # the complete graph and the ring do not depend on where the UAVs are
        self.fixed_listens = fixed_listening(scenario)
        if self.fixed_listens is not None:
            self.fixed_listens.setflags(write=False)
        self.fixed_heard = None if self.fixed_listens is None else heard_lists(self.fixed_listens)
        self.disturbances = Disturbances(scenario, self.streams.wind, self.streams.noise)
        self.tracks: dict[int, tuple[Plan, np.ndarray]] = {}
        """By plan id: the plan and its estimated positions from its start over
        :data:`TRACK_HORIZONS` horizons, of which each instant's estimate is a slice."""

    def control_period(self, c: int) -> None:
        """The period from instant ``c``: plans arrive, every UAV decides whether to re-solve
        (and if so solves and sends its new plan), then every UAV applies its plan's control
        and the plant moves on to instant ``c + 1``."""
        log, network = self.log, self.network
        network.advance_links()
        log.plans_late[c] = network.deliver(c)
        if self.fixed_listens is None:
            listens = listening(self.scenario, log.states[c, :, :2])
            heard = heard_lists(listens)
        else:
            listens, heard = self.fixed_listens, self.fixed_heard
        log.neighbours[c] = listens
        measured = self.disturbances.measure(log.states[c])
        published = list(self.plans)
        for i in range(self.n_uav):
            known = self.neighbourhood(c, i, heard[i])
            decision = self.trigger_decision(c, i, known)
            log.reasons[c, i] = decision.as_tuple()
            if self.trigger_on and not decision.fire:
                continue
            published[i] = self.solve(c, i, known, measured[i])
            log.plans_lost[c] += network.send(c, i, published[i], listens[:, i])
        self.plans = published
        self.forget_old_tracks()
        self.apply_controls(c)

    def neighbourhood(self, c: int, i: int, heard: list[int]) -> Neighbourhood:
        """UAV ``i``'s view at instant ``c`` of the neighbours it hears (estimates from
        :meth:`estimate`)."""
        window = slice(c, c + self.horizon + 1)
        own = self.estimate(self.plans[i], c)
        if heard:
            held = self.network.held[i]
            others = np.array([self.estimate(held[j], c) for j in heard])  # (J, H + 1, 2)
            by_uav = self.offsets_by_uav
            desired_relative = by_uav[i, window] - by_uav[heard, window]  # (J, H + 1, 2)
        else:
            others, desired_relative = np.zeros((2, 0, self.horizon + 1, 2))
        group_offsets = self.offsets[window, [i, *heard]].sum(axis=1) if self.group_centre else None
        return Neighbourhood(heard, own, others, desired_relative, group_offsets)

    def estimate(self, plan: Plan, c: int) -> np.ndarray:
        """``plan``'s estimated positions at instants ``c .. c + H`` (read-only).

        A plan is estimated once, from its start over :data:`TRACK_HORIZONS` horizons (longer
        when plans are lost or late and it is held for longer), and each instant takes its
        slice; every position depends on its instant alone, so the slice is what
        :func:`estimate_positions` computes at ``c``, to the bit.
        """
        horizon, offset = self.horizon, c - plan.start_step
        if offset < 0:
            raise ValueError(f"plan starts at instant {plan.start_step}, after {c}")
        needed = offset + horizon + 1
        # the entry holds the plan, so no other object can take its id while it is there
        entry = self.tracks.get(id(plan))
        if entry is None or entry[1].shape[0] < needed:
            length = max(TRACK_HORIZONS * (horizon + 1), needed + horizon + 1)
            track = estimate_positions(
                plan, plan.start_step, length, self.period,
                self.scenario.communication.estimate_extension,
            )  # fmt: skip
            track.setflags(write=False)
            entry = self.tracks[id(plan)] = (plan, track)
        return entry[1][offset:needed]

    def forget_old_tracks(self) -> None:
        """Drop the tracks of plans that no UAV holds any more."""
        live = {id(plan) for plan in self.plans}
        live.update(id(plan) for row in self.network.held for plan in row)
        for key in [key for key in self.tracks if key not in live]:
            del self.tracks[key]

    def trigger_decision(self, c: int, i: int, known: Neighbourhood) -> TriggerDecision:
        """Which of the trigger's conditions hold for UAV ``i`` at instant ``c``; at c = 0 no UAV
        has a plan of its own yet (logged as expiry)."""
        if c == 0:
            return TriggerDecision(False, False, False, True)
        trigger, horizon, checked = self.scenario.trigger, self.horizon, self.lookahead + 1
        lower, upper = self.bounds[i]
        own, others = known.own[:checked], known.others[:, :checked]
        group_offsets = known.group_offsets
        age = c - self.plans[i].start_step
        return TriggerDecision(
            distance=distance_condition(
                own, others, known.desired_relative[:, :checked], trigger.eps_p
            ),
            tracking=tracking_condition(
                own,
                others,
                self.reference[c : c + checked],
                centre_group_size(self.n_uav, len(known.heard), self.group_centre),
                trigger.eps_o,
                None if group_offsets is None else group_offsets[:checked],
            ),
            control=age < horizon
            and control_condition(self.plans[i].controls[age], lower, upper, trigger.eta),
            expiry=expiry_condition(age, horizon),
        )

    def solve(self, c: int, i: int, known: Neighbourhood, measured: np.ndarray) -> Plan:
        """UAV ``i``'s new plan at instant ``c`` from its ``measured`` state, warm-started
        from its shifted previous plan (which it keeps if the solve fails); logs the solve."""
        log, horizon = self.log, self.horizon
        solve_start = time.perf_counter()
        problem = LocalProblem(
            self.scenario,
            i,
            measured,
            np.ascontiguousarray(known.others[:, 1:]),
            known.desired_relative[:, 1:],
            self.reference[c + 1 : c + horizon + 1],
            None if known.group_offsets is None else known.group_offsets[1:],
        )
        warm_start = problem.decision_from_controls(shifted_controls(self.plans[i], c))
        result = self.optimizer.minimize(
            problem, problem.bounds, self.streams.uavs[i], self.budget, warm_start
        )
        decision = result.x
        if not result.success:  # a failed solve falls back to the shifted previous plan
            decision = warm_start
            log.solve_failed[c, i] = True
        plan = problem.plan(decision, c)
        log.solve_time_s[c, i] = time.perf_counter() - solve_start
        log.solved[c, i] = True
        log.nfev[c, i] = result.nfev
        log.solve_cost[c, i] = result.fun
        log.plan_at_bound[c, i] = at_bound(decision, problem.bounds.lower, problem.bounds.upper)
        return plan

    def apply_controls(self, c: int) -> None:
        """Every UAV applies its plan's control over the period; the plant moves to ``c + 1``."""
        log = self.log
        for i in range(self.n_uav):
            log.controls[c, i] = self.plans[i].controls[c - self.plans[i].start_step]
        log.states[c + 1], log.wind[c] = self.disturbances.step(log.states[c], log.controls[c])

    def trace(self, optimizer_name: str, seed: int, wall_time_s: float) -> Trace:
        """The run's :class:`Trace`."""
        log, n_steps = self.log, self.scenario.timing.n_steps
        return Trace(
            scenario=self.scenario,
            optimizer=optimizer_name,
            trigger=self.trigger_on,
            seed=seed,
            times=self.times[: n_steps + 1],
            states=log.states,
            controls=log.controls,
            solved=log.solved,
            reasons=log.reasons,
            solve_time_s=log.solve_time_s,
            nfev=log.nfev,
            solve_cost=log.solve_cost,
            reference=self.reference[: n_steps + 1],
            reference_heading=self.heading[: n_steps + 1],
            desired_offsets=self.offsets[: n_steps + 1],
            wall_time_s=wall_time_s,
            solve_failed=log.solve_failed,
            plan_at_bound=log.plan_at_bound,
            deadline_s=None if self.budget is None else self.budget.deadline_s,
            neighbours=log.neighbours,
            plans_lost=log.plans_lost,
            plans_late=log.plans_late,
            wind=log.wind,
        )
