"""Limits checked before a closed loop starts, so that a run never fails or exhausts the
machine after the work has been done."""

from __future__ import annotations

import os
import re
from pathlib import PurePath
from typing import Any

from formation_bench.mpc.scenario import Scenario
from formation_bench.optimizers import Budget, Optimizer
from formation_bench.pipeline.spec import deadline_ms_of_s

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
MAX_LABEL_CHARS = 48
"""Characters of a name a suite gives its configurations (or derives from their overrides)
and itself: every table row, legend and axis of a report prints it in full, and a figure with
longer ones is unreadable (the longest registered name, 33 characters, fits)."""
JOBS_PER_CPU = 2
"""Local worker processes per CPU this process may use: each runs one closed loop at a time on
one thread, so more only add memory, start-up time and processes to stop on Ctrl-C."""
NAME_MAX_FALLBACK = 255
"""Bytes per file name where the file system cannot be asked (``_XOPEN_NAME_MAX``)."""
PATH_MAX_FALLBACK = 1024
"""Bytes per path where the file system cannot be asked (``_XOPEN_PATH_MAX``)."""
OUT_NAME_RESERVE = 32
"""Bytes an output folder's name leaves free: a command writes beside it, into a temporary
folder named from it (``.NAME.<random>.partial``), and renames that into place at the end."""
OUT_PATH_RESERVE = 128
"""Bytes an output folder's path leaves free for the files written inside it (the longest, a
sweep's ``traces/<sha256>.parquet``, is under 100)."""
DASK_SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")
"""Dask communication protocols that reach a scheduler in another process."""
_HOST_PORT = re.compile(
    r"(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9._-]*)(?::(?P<port>\d+))?"
)


class LimitError(ValueError):
    """A run that would exhaust memory or not finish in reasonable time (one line)."""


def check_run(scenario: Scenario, optimizer: Optimizer, budget: Budget | None) -> None:
    """Refuse a run that cannot produce its metrics or would not finish; the message says why."""
    end = scenario.timing.n_steps * scenario.timing.period_s
    if scenario.evaluation.settle_time_s > end + 1e-9:
        raise LimitError(
            f"settle_time_s={scenario.evaluation.settle_time_s:g} is after the end of the run "
            f"({end:g} s = n_steps * period_s): no instant would be measured; lower "
            "settle_time_s or raise n_steps"
        )
    if scenario.n_uav > MAX_UAVS:
        raise LimitError(
            f"initial_states: {scenario.n_uav} UAVs is more than {MAX_UAVS} (each UAV's cost "
            "sums over all others, so the work grows with the square)"
        )
    if scenario.timing.n_steps * scenario.n_uav > MAX_UAV_INSTANTS:
        raise LimitError(
            f"n_steps={scenario.timing.n_steps} with {scenario.n_uav} UAVs is more than "
            f"{MAX_UAV_INSTANTS:,} solves (hours of computing); split the run"
        )
    if scenario.timing.horizon_steps > MAX_HORIZON_STEPS:
        raise LimitError(
            f"horizon_steps={scenario.timing.horizon_steps} is more than {MAX_HORIZON_STEPS} "
            "(every cost evaluation integrates the whole horizon)"
        )
    check_optimizer(optimizer, budget)


def check_optimizer(optimizer: Optimizer, budget: Budget | None) -> None:
    """Refuse an optimiser configuration or per-solve budget that would exhaust memory or
    not finish (``run``, ``sweep`` and ``score`` alike)."""
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
            f"{what}: deadline_ms={deadline_ms_of_s(budget.deadline_s):g} is more than "
            f"{deadline_ms_of_s(MAX_DEADLINE_S):,.0f} per solve (a closed loop makes hundreds "
            "of solves)"
        )


def check_seed_count(count: int, what: str = "--seeds") -> None:
    """Refuse more seeds than a command can run in a day."""
    if count > MAX_SEEDS:
        raise LimitError(
            f"{what}: {count:,} seeds is more than {MAX_SEEDS:,} (each seed is at least one "
            "closed loop of seconds: that many would run for days)"
        )


def check_label(label: str) -> None:
    """Refuse a label a report could not print: longer than :data:`MAX_LABEL_CHARS`, or not
    one line of printable characters."""
    if len(label) > MAX_LABEL_CHARS:
        raise LimitError(
            f"{_shortened(label, 16)!r} is {len(label):,} characters, more than "
            f"{MAX_LABEL_CHARS} (reports print it in every table row, legend and axis); "
            "give a shorter one"
        )
    if not label.isprintable():
        raise LimitError(f"{label!r} is not one line of printable characters")


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity where the system tells, else all)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def max_jobs() -> int:
    """The most local worker processes a command starts here."""
    return JOBS_PER_CPU * usable_cpus()


def check_jobs(jobs: int, option: str = "--jobs") -> None:
    """Refuse more local worker processes than the CPUs can run."""
    cpus = usable_cpus()
    if jobs > max_jobs():
        raise LimitError(
            f"{option}: {jobs} is more than {max_jobs()} ({JOBS_PER_CPU} per CPU, {cpus} CPU"
            f"{'s' if cpus != 1 else ''} here): each worker runs one closed loop on one thread, "
            "so more only add memory and processes to stop"
        )


def check_out_path(text: str, option: str = "--out", *, staged: bool = True) -> None:
    """Refuse an output path that is empty or longer than the file system takes and, for a
    ``staged`` folder (written whole, then renamed into place), one that names no folder of
    its own (``.``, ``..``, ``/``); all before any work starts."""
    if not text.strip():
        raise LimitError(f"{option}: empty path; give a folder, e.g. {option} results/mine")
    if staged and PurePath(text).name in ("", ".."):
        raise LimitError(
            f"{option} {text}: names no folder of its own (the command writes a new folder "
            "beside it and renames it into place); give a subfolder, e.g. ./out"
        )
    path = os.path.abspath(text)
    ancestor = _nearest_existing(path)
    name_max = _pathconf(ancestor, "PC_NAME_MAX", NAME_MAX_FALLBACK)
    path_max = _pathconf(ancestor, "PC_PATH_MAX", PATH_MAX_FALLBACK)
    for name in text.split(os.sep):
        size = len(os.fsencode(name))
        if size > name_max - OUT_NAME_RESERVE:
            raise LimitError(
                f"{option}: the name {_shortened(name)} is {size} bytes, more than "
                f"{name_max - OUT_NAME_RESERVE} (the file system takes {name_max} per name, and "
                f"{OUT_NAME_RESERVE} are kept for the temporary folder written beside it)"
            )
    size = len(os.fsencode(path))
    if size > path_max - OUT_PATH_RESERVE:
        raise LimitError(
            f"{option}: the path {_shortened(path)} is {size} bytes, more than "
            f"{path_max - OUT_PATH_RESERVE} (the file system takes {path_max} per path, and "
            f"{OUT_PATH_RESERVE} are kept for the files written inside it)"
        )


def _nearest_existing(path: str) -> str:
    """``path`` or its nearest ancestor that exists (``os.path.exists`` is False, not an
    error, for a path too long to look up)."""
    while not os.path.exists(path):
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return path


def _pathconf(path: str, name: str, fallback: int) -> int:
    try:
        value = os.pathconf(path, name)
    except (OSError, ValueError, AttributeError):
        return fallback
    return value if value > 0 else fallback


def _shortened(text: str, keep: int = 24) -> str:
    """A long name or path as its two ends, so that the message stays one readable line."""
    return text if len(text) <= 2 * keep + 3 else f"{text[:keep]}...{text[-keep:]}"


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
