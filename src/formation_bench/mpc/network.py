"""Communication between the UAVs: who listens to whom, and which plans arrive when.

A UAV sends its plan when it makes one (at an instant where it solved); the plan reaches
every UAV that listens to it at that instant over its own link, normally one period later
(at the next instant, as in the paper's Jacobi scheme). A link can lose the plan (with
probability ``packet_loss``, in bursts when ``loss_correlation`` > 0) or deliver it
``delay_steps`` (+ a uniform jitter of up to ``delay_jitter_steps``) periods late. Each UAV
keeps the newest plan it has received from every other UAV and builds its estimates from
it, aged by the instants since that plan was made (a plan that arrives after a newer one
from the same sender is dropped). At t0 every UAV knows every other's initial state (the
paper's assumption) and holds its coasting plan.

The links draw their random numbers at every instant from their own Generator, whether or
not a plan is sent, so the losses and delays of a seed are the same for every optimiser.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from formation_bench.mpc.problem import Plan
from formation_bench.mpc.scenario import CommunicationGraph, Scenario


def listening(scenario: Scenario, positions: np.ndarray) -> np.ndarray:
    """``(N, N)`` bool: ``[i, j]`` when UAV i listens to UAV j at positions ``(N, 2)``."""
    n_uav = positions.shape[0]
    communication = scenario.communication
    graph = communication.graph
    if graph == CommunicationGraph.COMPLETE:
        return ~np.eye(n_uav, dtype=bool)
    if graph == CommunicationGraph.RING:
        adjacency = np.zeros((n_uav, n_uav), dtype=bool)
        index = np.arange(n_uav)
        adjacency[index, (index + 1) % n_uav] = True
        adjacency[index, (index - 1) % n_uav] = True
        return adjacency
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
    np.fill_diagonal(distance, np.inf)
    if graph == CommunicationGraph.RANGE:
        return distance <= communication.graph_range_m
    nearest = np.argsort(distance, axis=1, kind="stable")[:, : communication.graph_neighbours]
    adjacency = np.zeros((n_uav, n_uav), dtype=bool)
    np.put_along_axis(adjacency, nearest, True, axis=1)
    return adjacency


def fixed_listening(scenario: Scenario) -> np.ndarray | None:
    """The :func:`listening` matrix of a graph that does not depend on the UAVs' positions
    (complete, ring); None for one that does (range, k-nearest)."""
    if scenario.communication.graph in (CommunicationGraph.COMPLETE, CommunicationGraph.RING):
        return listening(scenario, scenario.initial_state_array()[:, :2])
    return None


def heard_lists(listens: np.ndarray) -> list[list[int]]:
    """Row ``i``: the UAVs that UAV ``i`` listens to, in order, from a :func:`listening`
    matrix."""
    return [np.flatnonzero(row).tolist() for row in listens]


class Packet(NamedTuple):
    """A plan on its way from ``sender`` to ``receiver`` (a tuple: one is made per receiver of
    every plan)."""

    arrival_step: int
    sender: int
    receiver: int
    plan: Plan
    late: bool
    """Whether it arrives after the next instant (it was delayed)."""


class Network:
    """The plans every UAV holds of the others, and the plans in flight."""

    def __init__(self, scenario: Scenario, initial_plans: list[Plan], rng: np.random.Generator):
        self.scenario = scenario
        n_uav = scenario.n_uav
        self.n_uav = n_uav
        self.rng = rng
        self.held: list[list[Plan]] = [list(initial_plans) for _ in range(n_uav)]
        """``held[i][j]``: the newest plan UAV i has of UAV j (``held[i][i]`` is unused)."""
        self.in_flight: list[Packet] = []
        self.lost_state = np.zeros((n_uav, n_uav), dtype=bool)
        """Per link ``[receiver, sender]``: whether a plan sent over it this instant is lost."""
        self.extra_delay = np.zeros((n_uav, n_uav), dtype=np.int64)
        self._started = False

    def advance_links(self) -> None:
        """Draw every link's loss state and delay jitter for this instant."""
        scenario, n_uav = self.scenario, self.n_uav
        if scenario.communication.packet_loss > 0:
            draw = self.rng.random((n_uav, n_uav))
            loss, rho = scenario.communication.packet_loss, scenario.communication.loss_correlation
            if not self._started:
                chance = np.full((n_uav, n_uav), loss)  # the chain's stationary share
            else:
                chance = np.where(self.lost_state, loss + rho * (1.0 - loss), loss * (1.0 - rho))
            self.lost_state = draw < chance
        if scenario.communication.delay_jitter_steps > 0:
            self.extra_delay = self.rng.integers(
                0, scenario.communication.delay_jitter_steps + 1, size=(n_uav, n_uav)
            )
        self._started = True

    def deliver(self, step: int) -> np.ndarray:
        """Hand over the plans due by ``step``; returns ``(N,)`` late plans received by each."""
        late = np.zeros(self.n_uav, dtype=np.int64)
        waiting = []
        for packet in self.in_flight:
            if packet.arrival_step > step:
                waiting.append(packet)
                continue
            held = self.held[packet.receiver]
            if packet.plan.start_step >= held[packet.sender].start_step:
                held[packet.sender] = packet.plan
            late[packet.receiver] += packet.late
        self.in_flight = waiting
        return late

    def send(self, step: int, sender: int, plan: Plan, listeners: np.ndarray) -> np.ndarray:
        """Send ``sender``'s plan made at ``step`` to the UAVs in the bool mask ``listeners``;
        returns the bool mask of receivers whose copy was lost."""
        lost = listeners & self.lost_state[:, sender]
        nominal = step + 1 + self.scenario.communication.delay_steps
        delays = self.extra_delay[:, sender].tolist()
        for receiver in np.flatnonzero(listeners & ~lost).tolist():
            arrival = nominal + delays[receiver]
            self.in_flight.append(Packet(arrival, sender, receiver, plan, arrival > step + 1))
        return lost
