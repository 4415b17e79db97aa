"""Limits checked before a closed loop starts, so that a run never fails or exhausts the
machine after the work has been done."""

from __future__ import annotations

import re
from typing import Any

from formation_bench.mpc.scenario import Scenario
from formation_bench.optimizers import Budget, Optimizer

MAX_UAV_INSTANTS = 1_000_000
"""Instants times UAVs: each is a solve; a million of them takes hours on a laptop."""
MAX_HORIZON_STEPS = 500
"""Prediction periods: every cost evaluation integrates the whole horizon."""
MAX_UAVS = 100
"""UAVs: every UAV's cost sums over all the others, so the work grows with the square."""
MAX_POPULATION = 100_000
"""Points per population: each iteration holds several (population x dimension) arrays."""
MAX_EVALUATIONS = 10_000_000
"""Cost evaluations per solve: about a minute per solve at 5 µs each."""
MAX_ITERATIONS = 1_000_000
"""Iterations per solve."""
MAX_DEADLINE_S = 60.0
"""Per-solve deadline: a closed loop makes hundreds of solves, so a minute each is hours."""
MAX_SEED = 2**128 - 1
"""Largest seed: a sweep run's SeedSequence entropy is 128 bits, and ``run --seed`` repeats it."""
MAX_SEEDS = 10_000
"""Seeds per command or suite: each seed is at least one closed loop of seconds, so 10,000 of
them are most of a day on a laptop (and a suite of a billion seeds would not fit in memory)."""
DASK_SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")
"""Dask communication protocols that reach a scheduler in another process."""
_HOST_PORT = re.compile(
    r"(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9._-]*)(?::(?P<port>\d+))?"
)


class LimitError(ValueError):
    """A run that would exhaust memory or not finish in reasonable time (one line)."""


def check_run(scenario: Scenario, optimizer: Optimizer, budget: Budget | None) -> None:
    """Refuse a run that cannot produce its metrics or would not finish; the message says why."""
    end = scenario.n_steps * scenario.period_s
    if scenario.settle_time_s > end + 1e-9:
        raise LimitError(
            f"settle_time_s={scenario.settle_time_s:g} is after the end of the run "
            f"({end:g} s = n_steps * period_s): no instant would be measured; lower "
            "settle_time_s or raise n_steps"
        )
    if scenario.n_uav > MAX_UAVS:
        raise LimitError(
            f"initial_states: {scenario.n_uav} UAVs is more than {MAX_UAVS} (each UAV's cost "
            "sums over all others, so the work grows with the square)"
        )
    if scenario.n_steps * scenario.n_uav > MAX_UAV_INSTANTS:
        raise LimitError(
            f"n_steps={scenario.n_steps} with {scenario.n_uav} UAVs is more than "
            f"{MAX_UAV_INSTANTS:,} solves (hours of computing); split the run"
        )
    if scenario.horizon_steps > MAX_HORIZON_STEPS:
        raise LimitError(
            f"horizon_steps={scenario.horizon_steps} is more than {MAX_HORIZON_STEPS} (every "
            "cost evaluation integrates the whole horizon)"
        )
    population = getattr(optimizer, "population_size", None)
    if isinstance(population, int) and population > MAX_POPULATION:
        raise LimitError(
            f"population_size={population} is more than {MAX_POPULATION:,} (memory per "
            "iteration grows with population x dimension)"
        )
    _check_budget("budget", budget)
    _check_budget(f"{type(optimizer).__name__}'s default budget", optimizer.default_budget)


def _check_budget(what: str, budget: Budget | None) -> None:
    if budget is None:
        return
    limits: tuple[tuple[str, Any, int], ...] = (
        ("max_evaluations", budget.max_evaluations, MAX_EVALUATIONS),
        ("max_iterations", budget.max_iterations, MAX_ITERATIONS),
    )
    for name, value, limit in limits:
        if value is not None and value > limit:
            raise LimitError(
                f"{what}: {name}={value} is more than {limit:,} per solve (a closed loop "
                "makes hundreds of solves)"
            )
    if budget.deadline_s is not None and budget.deadline_s > MAX_DEADLINE_S:
        raise LimitError(
            f"{what}: deadline_ms={1000 * budget.deadline_s:g} is more than "
            f"{1000 * MAX_DEADLINE_S:,.0f} per solve (a closed loop makes hundreds of solves)"
        )


def check_seed_count(count: int, what: str = "--seeds") -> None:
    """Refuse more seeds than a command can run in a day."""
    if count > MAX_SEEDS:
        raise LimitError(
            f"{what}: {count:,} seeds is more than {MAX_SEEDS:,} (each seed is at least one "
            "closed loop of seconds: that many would run for days)"
        )


def check_scheduler_address(address: str) -> str:
    """A Dask scheduler address, ``[PROTOCOL://]HOST[:PORT]``; returned unchanged."""
    expected = f"expected [PROTOCOL://]HOST[:PORT] with PROTOCOL one of {', '.join(DASK_SCHEMES)}"
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    match = _HOST_PORT.fullmatch(rest)
    if scheme not in DASK_SCHEMES or match is None:
        raise LimitError(f"{expected} (e.g. tcp://host:8786), got {address!r}")
    port = match["port"]
    if port is not None and not 1 <= int(port) <= 65535:
        raise LimitError(f"port must be in 1..65535, got {port} in {address!r}")
    return address
