"""Speed of one solve and of a whole closed-loop run as the swarm grows from 3 to 25 UAVs.

Run ``python -m perf.swarm_speed [--json FILE] [--repeats R]``.
The scenarios are the paper's (N = 3) and ``swarm-5``, ``swarm-10``, ``swarm-20`` and
``swarm-25``, each on the complete graph (every UAV listens to the J = N - 1 others) and on
the ring (J = 2). It measures, in one process:

1. **per solve**: the problems of a few UAVs (spread over the indices) at a few instants of
   a short closed loop without trigger
   (:func:`formation_bench.instances.instants.record_instants`), solved at the
   default budget by ``modified-bso``, ``pso`` and ``ltv-osqp`` from the loop's warm start,
   and the objective alone (the compiled cost on a population of 30 in bounds). Times are
   this thread's CPU time; the same solve (same seed) is repeated ``--repeats`` times, the
   configurations interleaved within a repeat, so a slow spell of the shared machine hits
   them all; per problem the median over the repeats, then the median over the problems.
   The time against J is fitted by a least-squares line, and the growth called at most
   linear when the time at the largest J over the time at the smallest is at most the
   ratio of the J and every point lies within :data:`RESIDUAL_TOLERANCE` of the line.
   ``ltv-osqp`` sets up its QP afresh at every call here (the recorded warm starts are not
   its own plans).
2. **per run**: a whole ``formation-bench run --no-figures`` equivalent (the runner's
   :func:`~formation_bench.pipeline.runner.execute`: build, closed loop, metrics, trace
   table), ``modified-bso``, trigger on, seed 0, wall-clock (and the process's CPU) time of
   the fastest of ``--run-repeats`` by loop time, split by the trace into
   the solves (``solve_time_s``: building the problem, ``minimize``, the plan), the rest of
   the loop, and the rest of the run.
3. **where the loop's time goes**: when the loop outside the solves takes more than
   :data:`OVERHEAD_SHARE_LIMIT` of the closed loop at the largest N (or, with ``--profile``,
   always), that run again under cProfile: the harness's main steps and the functions with
   the most own time.

The load average is recorded before and after; pin the process (``taskset -c 0,1``) and
keep the machine quiet for reference figures.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import json
import os
import platform
import pstats
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from formation_bench.fields import Validated, setting
from formation_bench.instances.instants import RecordedInstant, record_instants
from formation_bench.mpc.scenario import CommunicationGraph, Scenario, get_scenario
from formation_bench.optimizers import PopulationOptimizer, get_optimizer
from formation_bench.pipeline.provenance import machine_info
from formation_bench.pipeline.runner import execute, warm_up_kernels
from formation_bench.pipeline.spec import RunSpec
from perf.replay import replayed_objective_seconds

SWARM_SIZES = (3, 5, 10, 20, 25)
"""N of the measured scenarios: the paper's 3 UAVs, then the registered swarms."""
GRAPHS = (CommunicationGraph.COMPLETE, CommunicationGraph.RING)
SOLVE_OPTIMIZERS = ("modified-bso", "pso", "ltv-osqp")
RUN_OPTIMIZER = "modified-bso"
OBJECTIVE_POPULATION = 30
"""Candidates per batch of the objective-alone timing (the BSO's and PSO's population)."""
OVERHEAD_SHARE_LIMIT = 0.30
"""The loop's time outside the solves, as a share of the closed loop, above which the run
at the largest N is profiled."""
RESIDUAL_TOLERANCE = 0.10
"""Largest distance of a point from the fitted line, relative to the point, at which the time
still counts as a linear function of J (timing noise on a shared machine)."""


def _check_sizes(owner: str, name: str, value: Any) -> tuple[int, ...]:
    if not (isinstance(value, tuple | list) and value):
        raise ValueError(f"{owner}.{name} must be a non-empty tuple of UAV counts, got {value!r}")
    allowed = set(SWARM_SIZES)
    if any(not isinstance(n, int) or isinstance(n, bool) or n not in allowed for n in value):
        raise ValueError(
            f"{owner}.{name} must hold UAV counts among {sorted(allowed)}, got {value!r}"
        )
    return tuple(sorted(set(value)))


def _check_optimizers(owner: str, name: str, value: Any) -> tuple[str, ...]:
    if not (isinstance(value, tuple | list) and value):
        raise ValueError(f"{owner}.{name} must be a non-empty tuple of names, got {value!r}")
    for optimizer in value:
        if not isinstance(optimizer, str):
            raise ValueError(f"{owner}.{name} must hold optimiser names, got {value!r}")
        get_optimizer(optimizer)  # an unknown name raises, listing the registered ones
    return tuple(value)


def _check_steps(owner: str, name: str, value: Any) -> tuple[int, ...]:
    ok = isinstance(value, tuple | list) and value
    if not ok or any(not isinstance(s, int) or isinstance(s, bool) or s < 0 for s in value):
        raise ValueError(
            f"{owner}.{name} must be a non-empty tuple of instants >= 0, got {value!r}"
        )
    return tuple(sorted(set(value)))


@dataclasses.dataclass(frozen=True)
class SwarmSpeedSettings(Validated):
    """What :func:`measure` measures and how often."""

    sizes: tuple[int, ...] = setting(
        SWARM_SIZES, check=_check_sizes, allowed=f"UAV counts among {list(SWARM_SIZES)}",
        doc="Numbers of UAVs: 3 is the paper's scenario, the others swarm-N",
    )  # fmt: skip
    optimizers: tuple[str, ...] = setting(
        SOLVE_OPTIMIZERS, check=_check_optimizers, allowed="registered optimiser names",
        doc="Optimisers whose single solve is timed, at their default budgets",
    )  # fmt: skip
    instants: tuple[int, ...] = setting(
        (4, 12), check=_check_steps, allowed="instants >= 0",
        doc="Instants of the recording loop (no trigger) whose problems are timed",
    )  # fmt: skip
    uavs_per_instant: int = setting(
        4, low=1, doc="UAVs per instant whose problems are timed, spread over the indices"
    )
    repeats: int = setting(15, low=1, doc="Identical solves of every problem (interleaved)")
    objective_calls: int = setting(
        200, low=1, doc="Batch-cost calls per problem and repeat in the objective-alone timing"
    )
    run_repeats: int = setting(
        2, low=1, doc="Whole closed-loop runs per configuration (interleaved)"
    )
    run_steps: int | None = setting(
        None, kind=int, optional=True, low=1,
        doc="Instants of each whole run; None = the scenario's own (240)",
    )  # fmt: skip
    profile: bool = setting(
        False, doc="Profile the largest run even when its loop overhead is within the limit"
    )


def scenario_for(n_uav: int, graph: CommunicationGraph) -> tuple[str, Scenario]:
    """The registered scenario of ``n_uav`` UAVs (the paper's for 3) on ``graph``."""
    name = "paper" if n_uav == 3 else f"swarm-{n_uav}"
    scenario = get_scenario(name)
    if scenario.n_uav != n_uav:
        raise ValueError(f"scenario {name!r} has {scenario.n_uav} UAVs, not {n_uav}")
    return name, (
        scenario if graph == scenario.communication.graph else scenario.with_overrides(graph=graph)
    )


@dataclasses.dataclass(frozen=True)
class SwarmProblems:
    """Recorded problems of one scenario on one graph."""

    n_uav: int
    graph: CommunicationGraph
    neighbours: int
    """J, the neighbours every problem has."""
    instants: list[RecordedInstant]

    @property
    def label(self) -> str:
        return f"N={self.n_uav} {self.graph.value}"


def record_problems(
    n_uav: int, graph: CommunicationGraph, steps: Sequence[int], uavs_per_instant: int
) -> SwarmProblems:
    """The problems of ``uavs_per_instant`` UAVs (spread over the indices) at ``steps``."""
    _, scenario = scenario_for(n_uav, graph)
    instants = record_instants(scenario, get_optimizer("modified-bso"), list(steps), seed=1)
    picked = set(np.linspace(0, n_uav - 1, min(uavs_per_instant, n_uav)).round().astype(int))
    chosen = [inst for inst in instants if inst.uav in picked]
    counts = {inst.problem.neighbour_positions.shape[0] for inst in chosen}
    if len(counts) != 1:
        raise ValueError(f"N={n_uav} {graph.value}: problems with {sorted(counts)} neighbours")
    return SwarmProblems(n_uav, graph, counts.pop(), chosen)


def _cpu_seconds(func: Callable[[], Any]) -> tuple[float, Any]:
    start = time.thread_time()
    result = func()
    return time.thread_time() - start, result


def _fit(neighbours: np.ndarray, seconds: np.ndarray) -> dict[str, Any]:
    """Least-squares line of the time against J, and the checks of linear growth.

    The configurations with equal J (the ring's J = 2 at every N) are one point, their
    median, so that the many J = 2 do not outweigh the rest. The growth counts as at most
    linear when ``t(J max) / t(J min) <= J max / J min`` and no point is further than
    :data:`RESIDUAL_TOLERANCE` from the line. Reported besides: the share of ``t(J max)``
    that a least-squares parabola puts in its quadratic term (positive when the time per
    neighbour rises with J).
    """
    j = np.unique(neighbours).astype(np.float64)
    t = np.array([np.median(seconds[neighbours == value]) for value in j])
    result: dict[str, Any] = {
        "neighbours": j.tolist(),
        "seconds": t.tolist(),
        "time_ratio": float(t[-1] / t[0]),
        "neighbour_ratio": float(j[-1] / j[0]) if j[0] > 0 else None,
    }
    if j.size < 2:
        return result
    line = stats.linregress(j, t)
    residual = t - (line.intercept + line.slope * j)
    result.update(
        slope_s_per_neighbour=float(line.slope),
        intercept_s=float(line.intercept),
        r_squared=float(line.rvalue**2),
        max_relative_residual=float(np.max(np.abs(residual) / t)),
    )
    if j.size >= 3:
        quadratic = np.polynomial.Polynomial.fit(j, t, 2).convert().coef[2]
        result["quadratic_share"] = float(quadratic * j[-1] ** 2 / t[-1])
    ratio_ok = result["neighbour_ratio"] is None or t[-1] / t[0] <= j[-1] / j[0]
    result["at_most_linear"] = bool(
        ratio_ok and result["max_relative_residual"] <= RESIDUAL_TOLERANCE
    )
    return result


def time_solves(
    groups: list[SwarmProblems], optimizers: Sequence[str], repeats: int, objective_calls: int
) -> dict[str, Any]:
    """Part 1: CPU time per solve and of the objective alone, per configuration."""
    built = {name: get_optimizer(name) for name in optimizers}

    def solve(name: str, inst: RecordedInstant, seed: int) -> Any:
        problem = inst.problem
        return built[name].minimize(
            problem, problem.bounds, np.random.default_rng(seed), None, inst.warm_start
        )

    populations = {
        id(inst): inst.problem.bounds.sample(np.random.default_rng(k), OBJECTIVE_POPULATION)
        for group in groups
        for k, inst in enumerate(group.instants)
    }
    # first calls build CasADi functions, OSQP and compiled loops: not timed
    for group in groups:
        first = group.instants[0]
        replayed_objective_seconds(first.problem.compiled, [populations[id(first)]], 1)
        for name in optimizers:
            solve(name, first, 0)

    # [group][optimizer][problem][repeat]; "objective" is the batch cost alone
    keys = ("objective", *optimizers)
    cpu = {g.label: {k: np.full((len(g.instants), repeats), np.nan) for k in keys} for g in groups}
    nfev = {g.label: {k: np.zeros(len(g.instants), dtype=np.int64) for k in keys} for g in groups}
    load_before = os.getloadavg()
    for r in range(repeats):
        for group in groups:
            table = cpu[group.label]
            for k, inst in enumerate(group.instants):
                batches = [populations[id(inst)]] * objective_calls
                table["objective"][k, r] = replayed_objective_seconds(
                    inst.problem.compiled, batches, 1
                ) / len(batches)
                nfev[group.label]["objective"][k] = OBJECTIVE_POPULATION
                for name in optimizers:
                    seconds, result = _cpu_seconds(lambda n=name, i=inst, s=k: solve(n, i, s))
                    table[name][k, r] = seconds
                    nfev[group.label][name][k] = result.nfev
    load_after = os.getloadavg()

    rows = []
    for group in groups:
        for key in keys:
            times = cpu[group.label][key]
            per_problem = np.median(times, axis=1)
            evaluations = nfev[group.label][key]
            rows.append(
                {
                    "n_uav": group.n_uav,
                    "graph": group.graph.value,
                    "neighbours": group.neighbours,
                    "what": key,
                    "problems": len(group.instants),
                    "nfev_median": float(np.median(evaluations)),
                    "median_s": float(np.median(per_problem)),
                    # a derivative-based solve's evaluations are of another kind
                    "per_evaluation_s": float(np.median(per_problem / evaluations))
                    if key == "objective" or isinstance(built[key], PopulationOptimizer)
                    else None,
                    # per repeat, this configuration's median over its problems: the ratios
                    # below are formed within a repeat
                    "repeat_medians_s": np.median(times, axis=0).tolist(),
                }
            )
    fits: dict[str, Any] = {}
    for key in keys:
        mine = [row for row in rows if row["what"] == key]
        if not mine:
            continue
        fits[key] = _fit(
            np.array([row["neighbours"] for row in mine]),
            np.array([row["median_s"] for row in mine]),
        )
        fits[key].update(_per_repeat(mine))
    return {
        "repeats": repeats,
        "objective_calls": objective_calls,
        "objective_population": OBJECTIVE_POPULATION,
        "load_average_before": list(load_before),
        "load_average_after": list(load_after),
        "rows": rows,
        "fits": fits,
    }


def _quartiles(values: np.ndarray) -> dict[str, float]:
    q1, q3 = np.quantile(values, [0.25, 0.75])
    return {"median": float(np.median(values)), "q1": float(q1), "q3": float(q3)}


def _per_repeat(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The figures of :func:`_fit` formed within each repeat (median and quartiles): the time
    ratio, the largest residual and the quadratic share."""
    j = np.array([row["neighbours"] for row in rows])
    if j.min() == j.max():
        return {}
    per_repeat = np.array([row["repeat_medians_s"] for row in rows])  # (configs, repeats)
    ratios = np.median(per_repeat[j == j.max()], axis=0) / np.median(
        per_repeat[j == j.min()], axis=0
    )
    result = {"time_ratio_per_repeat": _quartiles(ratios)}
    fits = [_fit(j, seconds) for seconds in per_repeat.T]
    result["max_relative_residual_per_repeat"] = _quartiles(
        np.array([fit["max_relative_residual"] for fit in fits])
    )
    if "quadratic_share" in fits[0]:
        result["quadratic_share_per_repeat"] = _quartiles(
            np.array([fit["quadratic_share"] for fit in fits])
        )
    return result


def time_runs(
    sizes: Sequence[int], repeats: int, steps: int | None, optimizer_name: str = RUN_OPTIMIZER
) -> dict[str, Any]:
    """Part 2: whole closed-loop runs through the runner, trigger on, split by the trace."""
    optimizer = get_optimizer(optimizer_name)
    configs = [(n, graph) for n in sizes for graph in GRAPHS]
    measured: dict[tuple[int, str], list[dict[str, float]]] = {}
    load_before = os.getloadavg()
    for _ in range(repeats):
        for n_uav, graph in configs:
            spec = run_spec(n_uav, graph, steps, optimizer_name)
            start, cpu_start = time.perf_counter(), time.process_time()
            outcome = execute(spec)
            run_s, run_cpu_s = time.perf_counter() - start, time.process_time() - cpu_start
            trace = outcome.trace
            solves_s = float(np.nansum(trace.solve_time_s))
            measured.setdefault((n_uav, graph.value), []).append(
                {
                    "run_s": run_s,
                    "run_cpu_s": run_cpu_s,
                    "loop_s": trace.wall_time_s,
                    "solves_s": solves_s,
                    "solves": int(trace.solved.sum()),
                    "instants": int(trace.solved.shape[0]),
                }
            )
    load_after = os.getloadavg()
    rows = []
    for (n_uav, graph), runs in measured.items():
        # the repeat with the shortest loop: the one least slowed by other work
        best = min(runs, key=lambda run: run["loop_s"])
        loop_rest = best["loop_s"] - best["solves_s"]
        rows.append(
            {
                "n_uav": n_uav,
                "graph": graph,
                **best,
                "run_all_s": [run["run_s"] for run in runs],
                "run_cpu_all_s": [run["run_cpu_s"] for run in runs],
                "solve_share_of_loop": best["solves_s"] / best["loop_s"],
                "loop_rest_s": loop_rest,
                "loop_rest_share": loop_rest / best["loop_s"],
                "outside_loop_s": best["run_s"] - best["loop_s"],
                "per_solve_s": best["solves_s"] / best["solves"],
                "loop_rest_per_instant_s": loop_rest / best["instants"],
            }
        )
    return {
        "optimizer": optimizer_name,
        "optimizer_default_budget": repr(optimizer.default_budget),
        "trigger": True,
        "seed": 0,
        "repeats": repeats,
        "load_average_before": list(load_before),
        "load_average_after": list(load_after),
        "rows": rows,
    }


def run_spec(
    n_uav: int, graph: CommunicationGraph, steps: int | None, optimizer_name: str = RUN_OPTIMIZER
) -> RunSpec:
    """The run of part 2: ``optimizer_name`` at its default, trigger on, seed 0."""
    name, scenario = scenario_for(n_uav, graph)
    if steps is not None:
        scenario = scenario.with_overrides(
            n_steps=steps,
            settle_time_s=round(
                min(scenario.evaluation.settle_time_s, 0.5 * steps * scenario.timing.period_s), 6
            ),
        )
    return RunSpec.of(
        optimizer_name, get_optimizer(optimizer_name), name, scenario, trigger=True, seed=0
    )


HARNESS_STEPS = {
    "minimize (the optimiser)": ("", "minimize"),
    "LocalProblem built": ("mpc/problem.py", "__init__"),
    "problem packed for the kernel": ("mpc/problem.py", "packed"),
    "warm start (decision_from_controls)": ("mpc/problem.py", "decision_from_controls"),
    "plan of the decision (rollout)": ("mpc/problem.py", "plan"),
    "neighbour estimates (estimate_positions)": ("mpc/problem.py", "estimate_positions"),
    "trigger: distance condition": ("mpc/trigger.py", "distance_condition"),
    "trigger: tracking condition": ("mpc/trigger.py", "tracking_condition"),
    "trigger: control condition": ("mpc/trigger.py", "control_condition"),
    "plans sent (Network.send)": ("mpc/network.py", "send"),
    "plans delivered (Network.deliver)": ("mpc/network.py", "deliver"),
    "plant step (Disturbances.step)": ("mpc/disturbance.py", "step"),
    "at_bound": ("mpc/loop.py", "at_bound"),
    "closed loop (simulate)": ("mpc/loop.py", "simulate"),
    "metrics (compute_metrics)": ("mpc/metrics.py", "compute_metrics"),
    "trace table (trace_table)": ("pipeline/runner.py", "trace_table"),
}
"""Named steps of a run, found in the profile by file suffix and function name (an empty
suffix: every function of that name, e.g. each optimiser's ``minimize``; the largest
cumulative time among them is taken, which is the outermost call)."""


def profile_run(spec: RunSpec, top: int = 20) -> dict[str, Any]:
    """Part 3: one run under cProfile; the named steps' and the busiest functions' times."""
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    outcome = execute(spec)
    profiler.disable()
    wall = time.perf_counter() - start
    table = pstats.Stats(profiler).stats  # {(file, line, name): (cc, ncalls, tt, ct, callers)}
    steps: dict[str, dict[str, float]] = {}
    for label, (suffix, name) in HARNESS_STEPS.items():
        hits = [
            (calls, own, cumulative)
            for (path, _, func), (_, calls, own, cumulative, _) in table.items()
            if func == name and Path(path).as_posix().endswith(suffix)
        ]
        if hits:
            calls, _, cumulative = max(hits, key=lambda hit: hit[2])
            steps[label] = {"calls": int(calls), "cumulative_s": float(cumulative)}
    busiest = sorted(table.items(), key=lambda item: item[1][2], reverse=True)[:top]
    return {
        "scenario": spec.scenario_label,
        "wall_under_profile_s": wall,
        "loop_under_profile_s": outcome.trace.wall_time_s,
        "solves_under_profile_s": float(np.nansum(outcome.trace.solve_time_s)),
        "steps": steps,
        "own_time": [
            {
                "function": f"{_short(path)}:{line} {func}",
                "calls": int(calls),
                "own_s": float(own),
                "cumulative_s": float(cumulative),
            }
            for (path, line, func), (_, calls, own, cumulative, _) in busiest
        ],
    }


def _short(path: str) -> str:
    parts = Path(path).parts
    for anchor in ("formation_bench", "site-packages"):
        if anchor in parts:
            return "/".join(parts[parts.index(anchor) + 1 :])
    for anchor in ("mpc", "optimizers", "pipeline"):
        if anchor in parts:
            return "/".join(parts[parts.index(anchor) :])
    return path


def measure(settings: SwarmSpeedSettings | None = None) -> dict[str, Any]:
    """Parts 1-3 of the module docstring."""
    settings = settings or SwarmSpeedSettings()
    warm_up_kernels()
    groups = [
        record_problems(n, graph, settings.instants, settings.uavs_per_instant)
        for n in settings.sizes
        for graph in GRAPHS
    ]
    results: dict[str, Any] = {
        "machine": machine_info(),
        "python": platform.python_version(),
        "settings": {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)},
        "solves": time_solves(
            groups, settings.optimizers, settings.repeats, settings.objective_calls
        ),
    }
    # one untimed run first: the runner's first call in a process loads what later ones reuse
    execute(run_spec(min(settings.sizes), GRAPHS[0], 2))
    runs = time_runs(settings.sizes, settings.run_repeats, settings.run_steps)
    results["runs"] = runs
    largest = [row for row in runs["rows"] if row["n_uav"] == max(settings.sizes)]
    results["profiles"] = [
        profile_run(run_spec(row["n_uav"], CommunicationGraph(row["graph"]), settings.run_steps))
        for row in largest
        if settings.profile or row["loop_rest_share"] > OVERHEAD_SHARE_LIMIT
    ]
    return results


def format_results(results: dict[str, Any]) -> str:
    """Markdown tables of :func:`measure`'s figures."""
    solves, runs = results["solves"], results["runs"]
    lines = [
        f"Per solve: CPU time, median over {solves['repeats']} identical repeats per problem, "
        "then over the problems; load average "
        f"{_load(solves['load_average_before'])} before, "
        f"{_load(solves['load_average_after'])} after.",
        "",
        "| N | graph | J | what | problems | evaluations | median per solve (ms) "
        "| per evaluation (ns) |",
        "|---:|---|---:|---|---:|---:|---:|---:|",
    ]
    for row in sorted(solves["rows"], key=lambda r: (r["what"], r["graph"], r["n_uav"])):
        what = row["what"]
        if what == "objective":
            what = f"objective alone (batch of {solves['objective_population']})"
        per_evaluation = row["per_evaluation_s"]
        per_eval = "-" if per_evaluation is None else f"{1e9 * per_evaluation:.0f}"
        lines.append(
            f"| {row['n_uav']} | {row['graph']} | {row['neighbours']} | {what} "
            f"| {row['problems']} | {row['nfev_median']:g} | {1e3 * row['median_s']:.3f} "
            f"| {per_eval} |"
        )
    lines += [
        "",
        "Time against J (one point per J: the median over the configurations with that J; "
        "least-squares line; in brackets the same formed within each repeat: median, "
        "quartiles):",
        "",
        "| what | slope (µs per neighbour) | intercept (µs) | R² | largest residual "
        "| t(J max) / t(J min) | J max / J min | quadratic term's share of t(J max) "
        "| at most linear |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for what, fit in solves["fits"].items():
        if "slope_s_per_neighbour" not in fit:
            continue
        residual = _spread(
            fit["max_relative_residual"], fit.get("max_relative_residual_per_repeat")
        )
        ratio = _spread(fit["time_ratio"], fit.get("time_ratio_per_repeat"), percent=False)
        quadratic = "-"
        if "quadratic_share" in fit:
            quadratic = _spread(fit["quadratic_share"], fit.get("quadratic_share_per_repeat"))
        lines.append(
            f"| {what} | {1e6 * fit['slope_s_per_neighbour']:.3f} "
            f"| {1e6 * fit['intercept_s']:.2f} | {fit['r_squared']:.4f} | {residual} | {ratio} "
            f"| {fit['neighbour_ratio']:g} | {quadratic} "
            f"| {'yes' if fit['at_most_linear'] else 'NO'} |"
        )
    lines += [
        "",
        f"Whole runs ({runs['optimizer']}, trigger on, seed {runs['seed']}; fastest of "
        f"{runs['repeats']} by loop time, wall clock); load average "
        f"{_load(runs['load_average_before'])} before, {_load(runs['load_average_after'])} "
        "after.",
        "",
        "| N | graph | run (s) | run, CPU (s) | closed loop (s) | solves | in solves (s) "
        "| share | loop rest (s) | share | per instant (ms) | outside the loop (s) "
        "| ms per solve |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in sorted(runs["rows"], key=lambda r: (r["graph"], r["n_uav"])):
        lines.append(
            f"| {row['n_uav']} | {row['graph']} | {row['run_s']:.2f} | {row['run_cpu_s']:.2f} "
            f"| {row['loop_s']:.2f} "
            f"| {row['solves']} | {row['solves_s']:.2f} | {100 * row['solve_share_of_loop']:.0f} % "
            f"| {row['loop_rest_s']:.2f} | {100 * row['loop_rest_share']:.0f} % "
            f"| {1e3 * row['loop_rest_per_instant_s']:.2f} | {row['outside_loop_s']:.2f} "
            f"| {1e3 * row['per_solve_s']:.2f} |"
        )
    for prof in results["profiles"]:
        lines += [
            "",
            f"Profile of {prof['scenario']} (cProfile slows Python code more than compiled "
            f"code): run {prof['wall_under_profile_s']:.1f} s, closed loop "
            f"{prof['loop_under_profile_s']:.1f} s, solves {prof['solves_under_profile_s']:.1f} s.",
            "",
            "| step | calls | cumulative (s) |",
            "|---|---:|---:|",
        ]
        lines += [
            f"| {label} | {step['calls']} | {step['cumulative_s']:.2f} |"
            for label, step in prof["steps"].items()
        ]
        lines += ["", "| function | calls | own (s) | cumulative (s) |", "|---|---:|---:|---:|"]
        lines += [
            f"| {f['function']} | {f['calls']} | {f['own_s']:.2f} | {f['cumulative_s']:.2f} |"
            for f in prof["own_time"]
        ]
    return "\n".join(lines)


def _spread(value: float, per_repeat: dict[str, float] | None, percent: bool = True) -> str:
    """``value`` and, if given, `` (median per repeat; quartiles)``, as percentages or ratios."""

    def text(v: float) -> str:
        return f"{100 * v:.1f} %" if percent else f"{v:.2f}"

    if not per_repeat:
        return text(value)
    return (
        f"{text(value)} ({text(per_repeat['median'])}; "
        f"{text(per_repeat['q1'])} to {text(per_repeat['q3'])})"
    )


def _load(load: Sequence[float]) -> str:
    return ", ".join(f"{value:.2f}" for value in load)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.swarm_speed",
        description=__doc__.splitlines()[0],
    )
    defaults = SwarmSpeedSettings()
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    parser.add_argument(
        "--repeats", type=int, default=defaults.repeats,
        help=f"identical solves of every problem ({defaults.repeats})",
    )  # fmt: skip
    parser.add_argument(
        "--run-repeats", type=int, default=defaults.run_repeats,
        help=f"whole runs per configuration ({defaults.run_repeats})",
    )  # fmt: skip
    parser.add_argument(
        "--sizes", type=int, nargs="+", default=list(defaults.sizes),
        help=f"numbers of UAVs among {' '.join(map(str, SWARM_SIZES))} (all)",
    )  # fmt: skip
    parser.add_argument(
        "--run-steps", type=int, help="instants of each whole run (the scenario's 240)"
    )
    parser.add_argument(
        "--profile", action="store_true", help="profile the largest run whatever its overhead"
    )
    parser.add_argument(
        "--tiny", action="store_true",
        help="a smoke test: N = 3 and 5, one instant, 2 repeats, 6-instant runs, profiled",
    )  # fmt: skip
    args = parser.parse_args(argv)
    fields: dict[str, Any] = {
        "sizes": tuple(args.sizes),
        "repeats": args.repeats,
        "run_repeats": args.run_repeats,
        "run_steps": args.run_steps,
        "profile": args.profile,
    }
    if args.tiny:
        fields.update(
            sizes=(3, 5), instants=(2,), uavs_per_instant=2, repeats=2, objective_calls=5,
            run_repeats=1, run_steps=6, profile=True,
        )  # fmt: skip
    try:
        settings = SwarmSpeedSettings(**fields)
    except ValueError as error:
        parser.error(str(error))
    results = measure(settings)
    print(format_results(results))
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
