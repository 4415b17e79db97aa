"""How the instance library is drawn and how its best-known optima are found.

Drawing (:class:`DrawPlan`), a stratified, seeded draw of distinct problems:

1. *Families.* A family is a registered scenario with overrides, under a label
   (:data:`FAMILIES`): the paper's scenario on its three references (``paper``,
   ``paper-s-curve``, ``paper-straight``), the swarms (``swarm-5`` on the complete graph and
   on the ring, ``swarm-10`` on its k-nearest graph and on the range graph), faults (packet
   loss 0.3; plans two periods late), wind (gusts of 1 m/s; a steady 3 m/s cross wind) and
   the obstacles (``paper-obstacles``).
2. *Loops.* For every family, trigger off and on, loop optimiser (``modified-bso``, ``pso``,
   ``ltv-osqp``) and seed (0, 1), in that nesting order, one closed loop is flown and every
   solve it makes is recorded. The loops are numbered 0, 1, ... in that order.
3. *Phases.* Each solve falls in a phase by its instant's time ``t = step * period_s``:
   ``start-up`` (step 0), ``transient`` (``0 < t < settle_time_s``), ``steady``
   (``t >= settle_time_s``).
4. *Draw.* From loop ``n``, with a Generator from ``SeedSequence([entropy, n])``, phase by
   phase in that order, ``per_phase`` solves are drawn uniformly without replacement among
   the loop's solves of the phase whose content hash
   (:func:`~formation_bench.instances.library.content_hash`) is not yet in the
   library (each problem counted once, at its first solve in the loop); fewer if fewer
   remain. So no problem is taken twice, and the start-up stratum stays small: without
   measurement noise every loop of a family poses the same start-up problems, one per UAV.

Best-known optimum (:class:`SearchPlan`), per instance, from seeded random numbers:

1. IPOPT (exact gradients and Hessian through CasADi, no dual warm start) from the warm
   start and from ``random_starts`` points drawn uniformly in the bounds;
2. the population optimisers of :data:`SEARCH_OPTIMIZERS`, in that order, each at
   ``population_factor`` times its own default evaluation budget, from the warm start;
3. IPOPT once more from the best point found, to polish it.

``J*`` is the smallest cost of all of these (and of the warm start itself) by the compiled
objective, ``x*`` its point. Then each instance is flagged degenerate or not
(:data:`~formation_bench.instances.library.DEGENERATE_J_STAR`,
:data:`~formation_bench.instances.library.WARM_START_OPTIMAL`) and split
(:data:`~formation_bench.instances.library.SPLIT_RULE`). The manifest records the
plans, the optimisers searched, the split rule, the degenerate thresholds and the counts per
stratum and per method that found ``J*``; the array ``found_by_index`` says which method found
each instance's ``J*`` (an index into the manifest's ``found_by_methods``). Regenerate with::

    python -m formation_bench.instances.build --out DIR --version v2 [--jobs N]

``J*`` and the warm start's cost are the shipped cost kernel's values (a test checks them to
the bit). A change to the kernel that rounds differently recomputes them, at the stored
points and nothing else, with::

    python -m formation_bench.instances.build --recompute-costs --version v2

(``v1`` was drawn by an earlier procedure, 14 evenly spaced solves per loop of the three
paper scenarios; its manifest records it.)
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys
import time
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from formation_bench.instances.instants import ObservedOptimizer
from formation_bench.instances.library import (
    ARRAYS,
    DATA_DIR,
    DEGENERATE_J_STAR,
    FORMAT_VERSION,
    J_STAR_ATOL,
    J_STAR_RTOL,
    PHASES,
    SPLIT_RULE,
    SPLITS,
    WARM_START_OPTIMAL,
    Library,
    LibraryError,
    is_degenerate,
    load,
    phase_of,
    problem_hash,
    split_indices,
)
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.problem import LocalProblem
from formation_bench.mpc.scenario import Scenario, get_scenario
from formation_bench.optimizers import OPTIMIZERS, Budget, Optimizer, get_optimizer
from formation_bench.optimizers.adapters import ADAPTERS
from formation_bench.pipeline.provenance import git_info
from formation_bench.pipeline.spec import jsonable

TIE_TOLERANCE = 1e-12
"""A later method takes J* over only if it improves on it by more than this, relatively."""
SEARCH_OPTIMIZERS = (
    "chaotic-pso",
    "chaotic-pso-coefficients",
    "chaotic-pso-inertia",
    "cls-bso",
    "cma-es",
    "cma-es-bipop",
    "cma-es-ipop",
    "cma-es-warm",
    "de",
    "de-current-to-best",
    "de-immediate",
    "de-immediate-warm",
    "modified-bso",
    "modified-bso-chebyshev",
    "modified-bso-circle",
    "modified-bso-gauss",
    "modified-bso-iterative",
    "modified-bso-no-all-centre",
    "modified-bso-no-chaos-replacement",
    "modified-bso-no-modifications",
    "modified-bso-piecewise",
    "modified-bso-raw-weights",
    "modified-bso-sine",
    "modified-bso-singer",
    "modified-bso-sinusoidal",
    "modified-bso-tent",
    "modified-bso-warm",
    "original-bso",
    "original-bso-range-step",
    "original-bso-warm",
    "pso",
    "pso-constriction",
    "pso-warm",
    "random-search",
)
"""The population optimisers the search for ``J*`` runs, in this order: v2's. Each draws
from the instance's Generator after the one before, so the list and its order are part of
the search; named here rather than taken from the registry, so that an optimiser registered
later (the sampling methods, iLQR) enters the search only when added here and the library
rebuilt. The adapters of other libraries stay out (their Python overhead makes a solve take
seconds)."""
GRADIENT_SOLVERS = ("ipopt", "ltv-osqp")
"""Registered optimisers that solve only the MPC problem (IPOPT is searched apart)."""
DRAW_ENTROPY = 20261125
"""Entropy of the SeedSequence each loop's draw is spawned from (with the loop's number)."""
PHASE_RULE = (
    "t = step * period_s; 'start-up': step 0; 'transient': 0 < t < settle_time_s; "
    "'steady': t >= settle_time_s"
)
"""The phase rule, as the manifest states it."""


@dataclass(frozen=True)
class Family:
    """A registered scenario with overrides, under a label."""

    label: str
    scenario: str
    """Registered scenario name."""
    overrides: tuple[tuple[str, Any], ...] = ()
    """``(field, value)`` pairs changed from the registered scenario."""

    def build(self) -> Scenario:
        return get_scenario(self.scenario, **dict(self.overrides))

    def as_json(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "scenario": self.scenario,
            "overrides": jsonable(dict(self.overrides)),
        }


FAMILIES = (
    Family("paper", "paper"),
    Family("paper-s-curve", "paper-s-curve"),
    Family("paper-straight", "paper-straight"),
    Family("swarm-5-complete", "swarm-5", (("graph", "complete"),)),
    Family("swarm-5-ring", "swarm-5", (("graph", "ring"),)),
    Family("swarm-10-k-nearest", "swarm-10", (("graph", "k-nearest"),)),
    Family("swarm-10-range", "swarm-10", (("graph", "range"),)),
    Family("paper-packet-loss", "paper", (("packet_loss", 0.3),)),
    Family("paper-delay", "paper", (("delay_steps", 2),)),
    Family("paper-gusts", "paper", (("gust_std_m_s", 1.0),)),
    Family("paper-cross-wind", "paper", (("wind_mean_m_s", (0.0, 3.0)),)),
    Family("paper-obstacles", "paper-obstacles"),
)
"""The families of v2."""


@dataclass(frozen=True)
class DrawPlan:
    """Which closed loops the instances come from and how many are drawn from each."""

    families: tuple[Family, ...] = FAMILIES
    """Scenario families flown."""
    triggers: tuple[bool, ...] = (False, True)
    """Trigger settings flown."""
    optimizers: tuple[str, ...] = ("modified-bso", "pso", "ltv-osqp")
    """Optimisers flying the loops (so the states seen are those of different methods)."""
    seeds: tuple[int, ...] = (0, 1)
    """Seeds of the loops."""
    per_phase: tuple[int, int, int] = (1, 3, 3)
    """Solves drawn from each loop per phase, in the order of :data:`PHASES`."""
    entropy: int = DRAW_ENTROPY
    """Entropy of the draw: loop n draws from ``SeedSequence([entropy, n])``."""

    def loops(self) -> Iterator[tuple[int, int, bool, str, int]]:
        """``(loop number, family index, trigger, optimiser, seed)`` in the drawing order."""
        n = 0
        for f in range(len(self.families)):
            for trigger in self.triggers:
                for drawer in self.optimizers:
                    for seed in self.seeds:
                        yield n, f, trigger, drawer, seed
                        n += 1

    def as_json(self) -> dict[str, Any]:
        return {
            "families": [family.as_json() for family in self.families],
            "triggers": list(self.triggers),
            "optimizers": list(self.optimizers),
            "seeds": list(self.seeds),
            "phases": list(PHASES),
            "phase_rule": PHASE_RULE,
            "per_phase": dict(zip(PHASES, self.per_phase, strict=True)),
            "entropy": self.entropy,
        }


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


def draw(plan: DrawPlan, log: Any = None) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The drawn instances (dicts of their arrays and origin; the neighbour arrays unpadded,
    ``centre_offset_sum`` None on the complete graph) and the scenarios list (one per
    family)."""
    scenarios = [
        {"name": f.scenario, "overrides": jsonable(dict(f.overrides)), "family": f.label}
        for f in plan.families
    ]
    built = [family.build() for family in plan.families]
    taken: set[str] = set()
    instances: list[dict[str, Any]] = []
    for n, f, trigger, drawer, seed in plan.loops():
        scenario = built[f]
        observed = ObservedOptimizer(get_optimizer(drawer))
        trace = simulate(scenario, observed, trigger=trigger, seed=seed)
        where = np.argwhere(trace.solved)  # (c, uav) in solve order
        candidates: dict[str, dict[str, int]] = {phase: {} for phase in PHASES}
        for k, solve in enumerate(observed.solves):
            problem = solve.objective
            assert isinstance(problem, LocalProblem) and solve.warm_start is not None
            key = problem_hash(problem, solve.warm_start)
            phase = phase_of(int(where[k, 0]), scenario)
            if key not in taken:
                candidates[phase].setdefault(key, k)  # a problem counts at its first solve
        rng = np.random.default_rng(np.random.SeedSequence([plan.entropy, n]))
        drawn = 0
        for phase, count in zip(PHASES, plan.per_phase, strict=True):
            pool = sorted(candidates[phase].items(), key=lambda item: item[1])
            chosen = rng.choice(len(pool), size=min(count, len(pool)), replace=False)
            for key, k in sorted((pool[c] for c in chosen), key=lambda item: item[1]):
                solve = observed.solves[k]
                problem = solve.objective
                assert isinstance(problem, LocalProblem) and solve.warm_start is not None
                taken.add(key)
                drawn += 1
                instances.append(
                    {
                        "uav": problem.uav,
                        "state": problem.state,
                        "neighbour_positions": problem.neighbour_positions,
                        "desired_relative": problem.desired_relative,
                        "reference": problem.reference,
                        "centre_offset_sum": problem.centre_offset_sum,
                        "warm_start": solve.warm_start,
                        "scenario_index": f,
                        "trigger": trigger,
                        "drawn_by_index": plan.optimizers.index(drawer),
                        "seed": seed,
                        "step": int(where[k, 0]),
                        "content_hash": key,
                        "phase_index": PHASES.index(phase),
                        "warm_cost": float(problem(solve.warm_start[None])[0]),
                    }
                )
        if log is not None:
            log(
                f"loop {n}: {plan.families[f].label} trigger={trigger} {drawer} seed={seed}: "
                f"{len(observed.solves)} solves, drew {drawn}"
            )
    return instances, scenarios


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
    return ipopt, {name: get_optimizer(name) for name in SEARCH_OPTIMIZERS}


def _search_one(
    k: int, instance: dict[str, Any], scenario: Scenario, plan: SearchPlan
) -> tuple[int, float, np.ndarray, str]:
    problem = LocalProblem(
        scenario,
        instance["uav"],
        instance["state"],
        instance["neighbour_positions"],
        instance["desired_relative"],
        instance["reference"],
        instance["centre_offset_sum"],
    )
    rng = np.random.default_rng(np.random.SeedSequence([plan.entropy, k]))
    ipopt, populations = _searchers()
    j_star, x_star, method = best_known(
        problem, np.asarray(instance["warm_start"]), rng, plan, ipopt, populations
    )
    return k, j_star, x_star, method


def _stack(instances: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """The arrays of :data:`ARRAYS`: neighbour arrays NaN-padded to the largest count, the centre's
    offset sum NaN where there is none."""
    n = len(instances)
    counts = np.array([len(i["neighbour_positions"]) for i in instances], dtype=np.int16)
    horizon = instances[0]["reference"].shape
    padded = {}
    for name in ("neighbour_positions", "desired_relative"):
        padded[name] = np.full((n, int(counts.max()), *horizon), np.nan)
        for k, inst in enumerate(instances):
            padded[name][k, : counts[k]] = inst[name]
    has_sum = np.array([i["centre_offset_sum"] is not None for i in instances])
    sums = np.full((n, *horizon), np.nan)
    for k, inst in enumerate(instances):
        if has_sum[k]:
            sums[k] = inst["centre_offset_sum"]
    special = {
        **padded,
        "neighbour_count": counts,
        "centre_offset_sum": sums,
        "has_centre_offset_sum": has_sum,
        "content_hash": np.array([i["content_hash"] for i in instances], dtype="<U64"),
        "trigger": np.array([i["trigger"] for i in instances], dtype=bool),
        "degenerate": np.array([i["degenerate"] for i in instances], dtype=bool),
        "phase_index": np.array([i["phase_index"] for i in instances], dtype=np.int8),
        "split_index": np.array([i["split_index"] for i in instances], dtype=np.int8),
        "found_by_index": np.array([i["found_by_index"] for i in instances], dtype=np.int8),
    }
    return {
        name: special[name]
        if name in special
        else np.stack([np.asarray(i[name]) for i in instances])
        for name in ARRAYS
    }


def strata(instances: list[dict[str, Any]], plan: DrawPlan) -> list[dict[str, Any]]:
    """Counts per stratum cell (family, phase, trigger) in the plan's order."""
    cells: dict[tuple[int, int, bool], list[dict[str, Any]]] = {}
    for inst in instances:
        key = (inst["scenario_index"], inst["phase_index"], bool(inst["trigger"]))
        cells.setdefault(key, []).append(inst)
    rows = []
    for f, family in enumerate(plan.families):
        for p, phase in enumerate(PHASES):
            for trigger in plan.triggers:
                cell = cells.get((f, p, trigger), [])
                splits = Counter(SPLITS[i["split_index"]] for i in cell)
                rows.append(
                    {
                        "family": family.label,
                        "phase": phase,
                        "trigger": trigger,
                        "instances": len(cell),
                        "degenerate": sum(bool(i["degenerate"]) for i in cell),
                        **{split: splits[split] for split in SPLITS},
                    }
                )
    return rows


def build(
    draw_plan: DrawPlan | None = None,
    search_plan: SearchPlan | None = None,
    *,
    version: str = "v2",
    jobs: int = 1,
    log: Any = print,
) -> Library:
    """Draw the instances, find their best-known optima, flag and split them (``log``: a
    function of one line of progress, or None)."""
    log = (lambda text: None) if log is None else log
    draw_plan = DrawPlan() if draw_plan is None else draw_plan
    search_plan = SearchPlan() if search_plan is None else search_plan
    start = time.perf_counter()
    instances, scenarios = draw(draw_plan, log=log)
    log(f"drew {len(instances)} instances in {time.perf_counter() - start:.0f} s")
    built = [family.build() for family in draw_plan.families]
    tasks = [
        (k, inst, built[inst["scenario_index"]], search_plan) for k, inst in enumerate(instances)
    ]
    searched = _run(tasks, jobs)
    for k, j_star, x_star, method in searched:
        inst = instances[k]
        inst["j_star"], inst["x_star"], inst["found_by"] = j_star, x_star, method
        inst["degenerate"] = is_degenerate(j_star, inst["warm_cost"])
    methods = Counter(inst["found_by"] for inst in instances)
    found_by_methods = [method for method, _ in methods.most_common()]
    for inst in instances:
        inst["found_by_index"] = found_by_methods.index(inst["found_by"])
    cells = [(i["scenario_index"], i["phase_index"], i["trigger"]) for i in instances]
    splits = split_indices(cells, [i["content_hash"] for i in instances])
    for inst, split in zip(instances, splits, strict=True):
        inst["split_index"] = int(split)
    arrays = _stack(instances)
    seconds = time.perf_counter() - start
    info = git_info()
    manifest = {
        "version": version,
        "format_version": FORMAT_VERSION,
        "instances": len(instances),
        "distinct": len({i["content_hash"] for i in instances}),
        "scenarios": scenarios,
        "drawn_by": list(draw_plan.optimizers),
        "draw_plan": draw_plan.as_json(),
        "search_plan": dataclasses.asdict(search_plan),
        "population_optimizers": list(SEARCH_OPTIMIZERS),
        "gradient_solvers": list(GRADIENT_SOLVERS),
        "adapters_not_searched": sorted(name for name in ADAPTERS if name in OPTIMIZERS),
        "found_by": dict(methods.most_common()),
        "found_by_methods": found_by_methods,
        "j_star_tolerance": {"rtol": J_STAR_RTOL, "atol": J_STAR_ATOL},
        "degenerate": {
            "j_star_below": DEGENERATE_J_STAR,
            "warm_start_optimal_rtol": WARM_START_OPTIMAL,
            "count": int(arrays["degenerate"].sum()),
        },
        "split_rule": SPLIT_RULE,
        "splits": {s: int((splits == j).sum()) for j, s in enumerate(SPLITS)},
        "strata": strata(instances, draw_plan),
        "build_seconds": round(seconds),
        "built_with": {"version": info["version"], "commit": info["commit"]},
    }
    log(f"searched {len(instances)} instances in {seconds:.0f} s")
    return Library(version, manifest, arrays)


def with_shipped_costs(library: Library) -> Library:
    """``library`` with ``J*`` and the warm starts' costs recomputed by the installed cost
    kernel at the stored ``x*`` and warm starts, and nothing else changed (a format-1 library
    stores no warm cost: it is computed on loading). Raises
    :class:`~formation_bench.instances.library.LibraryError` where that would change a
    degenerate flag or put a warm start below ``J*``: the library must then be rebuilt."""
    instances = list(library)
    j_star = np.array([float(i.problem(i.x_star[None])[0]) for i in instances])
    warm_cost = np.array([float(i.problem(i.warm_start[None])[0]) for i in instances])
    flagged = np.array([i.degenerate for i in instances])
    moved = np.flatnonzero(is_degenerate(j_star, warm_cost) != flagged)
    below = np.flatnonzero(warm_cost < j_star)
    refusals = (
        (moved, "changes the degenerate flag"),
        (below, "puts the warm start below J*"),
    )
    for found, what in refusals:
        if found.size:
            raise LibraryError(
                f"library {library.version}: the installed cost kernel {what} of instances "
                f"{found.tolist()}; rebuild the library"
            )
    arrays = {**library.arrays, "j_star": j_star}
    if "warm_cost" in arrays:
        arrays["warm_cost"] = warm_cost
    info = git_info()
    manifest = {
        **library.manifest,
        "costs_computed_with": {"version": info["version"], "commit": info["commit"]},
    }
    return Library(library.version, manifest, arrays)


def _run(tasks: list[tuple], jobs: int) -> Iterable[tuple[int, float, np.ndarray, str]]:
    if jobs == 1:
        return [_search_one(*task) for task in tasks]
    from joblib import Parallel, delayed

    # by the importable module's function: run as ``python -m``, this module is __main__,
    # whose functions the workers cannot look up
    from formation_bench.instances import build as module

    search = delayed(module._search_one)
    return Parallel(n_jobs=jobs, batch_size=4)(search(*task) for task in tasks)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m formation_bench.instances.build",
        description="Draw the instance library and find its best-known optima.",
    )
    parser.add_argument("--out", type=Path, default=DATA_DIR, help="folder to write into")
    parser.add_argument("--version", default="v2", help="library version name (default v2)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (default 2)")
    parser.add_argument(
        "--recompute-costs",
        action="store_true",
        help="recompute J* and the warm starts' costs of the library VERSION in --out with the "
        "installed cost kernel, change nothing else, and write it back (no draw, no search)",
    )
    parser.add_argument(
        "--per-phase",
        type=int,
        nargs=3,
        default=DrawPlan.per_phase,
        metavar=("START_UP", "TRANSIENT", "STEADY"),
        help="solves drawn per loop and phase (default %(default)s)",
    )
    args = parser.parse_args(argv)
    if args.recompute_costs:
        try:
            library = with_shipped_costs(load(args.out, args.version))
        except LibraryError as err:
            print(f"{parser.prog}: error: {err}", file=sys.stderr)
            return 2
        for path in library.save(args.out):
            print(f"wrote {path}")
        return 0
    library = build(
        DrawPlan(per_phase=tuple(args.per_phase)),
        version=args.version,
        jobs=args.jobs,
        log=lambda text: print(text, file=sys.stderr, flush=True),
    )
    for path in library.save(args.out):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
