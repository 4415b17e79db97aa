"""How the instance library is drawn and how its best-known optima are found.

Drawing (:class:`DrawPlan`): for every shipped scenario, trigger setting, drawing optimiser
and seed, one closed loop is flown and every solve it makes is recorded; ``per_loop``
solves, evenly spaced over the loop's solves in order (so the start-up and the steady
state are both in), become instances.

Best-known optimum (:class:`SearchPlan`), per instance, from seeded random numbers:

1. IPOPT (exact gradients and Hessian through CasADi, no dual warm start) from the warm
   start and from ``random_starts`` points drawn uniformly in the bounds;
2. every population optimiser registered when the library is built, at ``population_factor``
   times its own default evaluation budget, from the warm start;
3. IPOPT once more from the best point found, to polish it.

``J*`` is the smallest cost of all of these (and of the warm start itself) by the compiled
objective, ``x*`` its point. The manifest records the plans, the registered optimisers and
which method found each ``J*``. Regenerate with::

    python -m formation_bench.benchmarks.instances.build --out DIR [--jobs N]
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.benchmarks.instances.library import (
    ARRAYS,
    DATA_DIR,
    SHIPPED_VERSION,
    Library,
)
from formation_bench.benchmarks.instants import ObservedOptimizer
from formation_bench.benchmarks.provenance import git_info
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.problem import LocalProblem
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import OPTIMIZERS, Budget, Optimizer, get_optimizer

TIE_TOLERANCE = 1e-12
"""A later method takes J* over only if it improves on it by more than this, relatively."""
GRADIENT_SOLVERS = ("ipopt", "ltv-osqp")
"""Registered optimisers that solve only the MPC problem (searched apart, as IPOPT)."""


@dataclass(frozen=True)
class DrawPlan:
    """Which closed loops the instances come from."""

    scenarios: tuple[str, ...] = ("paper", "paper-s-curve", "paper-straight")
    """Registered scenarios flown (every shipped one)."""
    triggers: tuple[bool, ...] = (False, True)
    """Trigger settings flown."""
    optimizers: tuple[str, ...] = ("modified-bso", "pso", "ltv-osqp")
    """Optimisers flying the loops (so the states seen are those of different methods)."""
    seeds: tuple[int, ...] = (0, 1)
    """Seeds of the loops."""
    per_loop: int = 14
    """Instances taken from each loop, evenly spaced over its solves."""

    @property
    def size(self) -> int:
        loops = len(self.scenarios) * len(self.triggers) * len(self.optimizers) * len(self.seeds)
        return loops * self.per_loop


@dataclass(frozen=True)
class SearchPlan:
    """How the best-known optimum of each instance is searched for."""

    random_starts: int = 10
    """IPOPT starts drawn uniformly in the bounds, besides the warm start."""
    ipopt_iterations: int = 500
    """IPOPT's iteration limit per start."""
    population_factor: int = 10
    """Each population optimiser runs at this many times its default evaluation budget."""
    entropy: int = 20261123
    """Entropy of the SeedSequence every instance's random numbers are spawned from."""


def draw(plan: DrawPlan) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The drawn instances (as dicts of their arrays and origin) and the scenarios list."""
    scenarios = [{"name": name, "overrides": {}} for name in plan.scenarios]
    instances: list[dict[str, Any]] = []
    for s, name in enumerate(plan.scenarios):
        scenario = get_scenario(name)
        for trigger in plan.triggers:
            for drawer in plan.optimizers:
                for seed in plan.seeds:
                    observed = ObservedOptimizer(get_optimizer(drawer))
                    trace = simulate(scenario, observed, trigger=trigger, seed=seed)
                    where = np.argwhere(trace.solved)  # (c, uav) in solve order
                    chosen = np.unique(
                        np.linspace(0, len(observed.solves) - 1, plan.per_loop).round().astype(int)
                    )
                    for k in chosen:
                        solve = observed.solves[k]
                        problem = solve.objective
                        assert isinstance(problem, LocalProblem)
                        instances.append(
                            {
                                "uav": problem.uav,
                                "state": problem.state,
                                "neighbour_positions": problem.neighbour_positions,
                                "desired_relative": problem.desired_relative,
                                "reference": problem.reference,
                                "warm_start": solve.warm_start,
                                "scenario_index": s,
                                "trigger": trigger,
                                "drawn_by_index": plan.optimizers.index(drawer),
                                "seed": seed,
                                "step": int(where[k, 0]),
                            }
                        )
    return instances, scenarios


def population_optimizers() -> list[str]:
    """Every registered optimiser that works on any batch objective."""
    return sorted(name for name in OPTIMIZERS if name not in GRADIENT_SOLVERS)


def best_known(
    problem: LocalProblem,
    warm_start: np.ndarray,
    rng: np.random.Generator,
    plan: SearchPlan,
    ipopt: Optimizer,
    populations: dict[str, Optimizer],
) -> tuple[float, np.ndarray, str]:
    """``(J*, x*, method)`` of one problem by the procedure of this module."""
    bounds = problem.bounds
    best = (float(problem(warm_start[None])[0]), warm_start.copy(), "warm start")

    def consider(x: np.ndarray, method: str) -> None:
        nonlocal best
        x = bounds.clip(x)
        cost = float(problem(x[None])[0])
        # a point as good up to rounding leaves J* to the method that reached it first
        if cost < best[0] - TIE_TOLERANCE * abs(best[0]):
            best = (cost, x.copy(), method)

    ipopt_budget = Budget(max_iterations=plan.ipopt_iterations)
    consider(ipopt.minimize(problem, bounds, rng, ipopt_budget, warm_start).x, "ipopt")
    starts = rng.uniform(bounds.lower, bounds.upper, size=(plan.random_starts, bounds.dim))
    for start in starts:
        consider(ipopt.minimize(problem, bounds, rng, ipopt_budget, start).x, "ipopt random start")
    for name, optimizer in populations.items():
        default = optimizer.default_budget
        evaluations = (default.max_evaluations or 0) or None
        budget = (
            Budget(max_evaluations=plan.population_factor * evaluations)
            if evaluations is not None
            else Budget(max_iterations=plan.population_factor * (default.max_iterations or 1))
        )
        consider(optimizer.minimize(problem, bounds, rng, budget, warm_start).x, name)
    polished = ipopt.minimize(problem, bounds, rng, ipopt_budget, best[1]).x
    consider(polished, f"{best[2]} + ipopt polish")
    return best


@functools.cache
def _searchers() -> tuple[Optimizer, dict[str, Optimizer]]:
    """The optimisers of the search, built once per process: IPOPT's solver is built on its
    first solve and reused for every instance of the same shape."""
    ipopt = get_optimizer("ipopt", warm_start_duals=False)
    return ipopt, {name: get_optimizer(name) for name in population_optimizers()}


def _search_one(
    k: int, instance: dict[str, Any], scenario_name: str, plan: SearchPlan
) -> tuple[int, float, np.ndarray, str]:
    problem = LocalProblem(
        get_scenario(scenario_name),
        instance["uav"],
        instance["state"],
        instance["neighbour_positions"],
        instance["desired_relative"],
        instance["reference"],
    )
    rng = np.random.default_rng(np.random.SeedSequence([plan.entropy, k]))
    ipopt, populations = _searchers()
    j_star, x_star, method = best_known(
        problem, np.asarray(instance["warm_start"]), rng, plan, ipopt, populations
    )
    return k, j_star, x_star, method


def build(
    draw_plan: DrawPlan | None = None,
    search_plan: SearchPlan | None = None,
    *,
    version: str = SHIPPED_VERSION,
    jobs: int = 1,
    log: Any = print,
) -> Library:
    """Draw the instances and find their best-known optima."""
    draw_plan = DrawPlan() if draw_plan is None else draw_plan
    search_plan = SearchPlan() if search_plan is None else search_plan
    start = time.perf_counter()
    instances, scenarios = draw(draw_plan)
    log(f"drew {len(instances)} instances in {time.perf_counter() - start:.0f} s")
    names = [scenarios[i["scenario_index"]]["name"] for i in instances]
    tasks = [(k, inst, names[k], search_plan) for k, inst in enumerate(instances)]
    results = _run(tasks, jobs)
    methods: Counter[str] = Counter()
    for k, j_star, x_star, method in results:
        instances[k]["j_star"] = j_star
        instances[k]["x_star"] = x_star
        methods[method] += 1
    arrays = {name: np.stack([np.asarray(inst[name]) for inst in instances]) for name in ARRAYS}
    info = git_info()
    manifest = {
        "version": version,
        "instances": len(instances),
        "scenarios": scenarios,
        "drawn_by": list(draw_plan.optimizers),
        "draw_plan": dataclasses.asdict(draw_plan),
        "search_plan": dataclasses.asdict(search_plan),
        "population_optimizers": population_optimizers(),
        "found_by": dict(methods.most_common()),
        "built_with": {"version": info["version"], "commit": info["commit"]},
    }
    log(f"searched {len(instances)} instances in {time.perf_counter() - start:.0f} s")
    return Library(version, manifest, arrays)


def _run(tasks: list[tuple], jobs: int) -> Iterable[tuple[int, float, np.ndarray, str]]:
    if jobs == 1:
        return [_search_one(*task) for task in tasks]
    from joblib import Parallel, delayed

    return Parallel(n_jobs=jobs, batch_size=4)(delayed(_search_one)(*task) for task in tasks)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m formation_bench.benchmarks.instances.build",
        description="Draw the instance library and find its best-known optima.",
    )
    parser.add_argument("--out", type=Path, default=DATA_DIR, help="folder to write into")
    parser.add_argument("--version", default=SHIPPED_VERSION, help="library version name")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument(
        "--per-loop", type=int, default=DrawPlan.per_loop, help="instances per closed loop"
    )
    args = parser.parse_args(argv)
    library = build(
        DrawPlan(per_loop=args.per_loop),
        version=args.version,
        jobs=args.jobs,
        log=lambda text: print(text, file=sys.stderr, flush=True),
    )
    for path in library.save(args.out):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
