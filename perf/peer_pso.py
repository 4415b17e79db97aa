"""Solve quality of the package's PSOs against evosax's and mealpy's PSO, paired by problem.

Run ``python -m perf.peer_pso --optimizers pso pso-tuned`` in an environment that also has
``evosax`` (and JAX) installed; mealpy's PSO runs when ``mealpy`` (the ``peers`` extra) is
there. Neither library is a dependency of the package: this script only measures.

Every method solves the same non-degenerate problems of the instance library's test split
at the same evaluation budget (``--budget``, default 1200), starting from the same kind of
population: the package's optimisers as registered (uniform in the box, the loop's warm start
as member 0; their ``-warm`` variants otherwise), evosax's ``PSO`` (its default inertia 0.75,
c1 1.5, c2 2.0, 30 particles) from a population drawn uniformly in the box with the warm start
as member 0, and mealpy's ``OriginalPSO`` (30 particles, its defaults) from its own uniform
start with the warm start put in as member 0 (mealpy's ``starting_solutions``). Points outside
the box are clipped before they are evaluated for the two libraries (neither keeps to a box
itself). The measure is the normalised gap (f - J*) / (f_warm - J*) of the best point found;
the table gives its median with a bootstrap 95 % CI, and each package optimiser against each
library paired by problem (Wilcoxon signed-rank, A12 = P(package's gap > library's gap)).
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from collections.abc import Callable

import numpy as np

from formation_bench.analysis import stats
from formation_bench.experiments.gaps import normalised_gap
from formation_bench.instances.library import Instance, load_shipped
from formation_bench.optimizers import Budget, get_optimizer

POPULATION = 30
"""Particles of the two libraries' PSOs (the package's PSO's default too)."""


def _start(instance: Instance, rng: np.random.Generator) -> np.ndarray:
    bounds = instance.problem.bounds
    lower, upper = np.asarray(bounds.lower), np.asarray(bounds.upper)
    points = lower + (upper - lower) * rng.random((POPULATION, lower.size))
    points[0] = np.clip(instance.warm_start, lower, upper)
    return points


def solve_package(name: str, budget: int) -> Callable[[Instance, int], float]:
    optimizer = get_optimizer(name)

    def solve(instance: Instance, seed: int) -> float:
        problem = instance.problem
        rng = np.random.default_rng(np.random.SeedSequence([seed, instance.index]))
        result = optimizer.minimize(
            problem, problem.bounds, rng, Budget(max_evaluations=budget), instance.warm_start
        )
        return float(result.fun)

    return solve


def solve_evosax(budget: int) -> Callable[[Instance, int], float]:
    import functools

    import jax
    from evosax.algorithms import PSO

    # one strategy per dimension: its jitted ask and tell are traced once, not per problem
    strategy_of = functools.cache(
        lambda dim: PSO(population_size=POPULATION, solution=np.zeros(dim))
    )

    def solve(instance: Instance, seed: int) -> float:
        problem = instance.problem
        lower, upper = np.asarray(problem.bounds.lower), np.asarray(problem.bounds.upper)
        rng = np.random.default_rng(np.random.SeedSequence([seed, instance.index]))
        population = _start(instance, rng)
        fitness = problem(population)
        best, used = float(fitness.min()), POPULATION
        strategy = strategy_of(lower.size)
        params = strategy.default_params
        key = jax.random.key(seed * 100003 + instance.index)
        key, init_key = jax.random.split(key)
        state = strategy.init(init_key, population, fitness, params)
        while used + POPULATION <= budget:
            key, ask_key, tell_key = jax.random.split(key, 3)
            asked, state = strategy.ask(ask_key, state, params)
            points = np.clip(np.asarray(asked, dtype=np.float64), lower, upper)
            fitness = problem(points)
            used += POPULATION
            best = min(best, float(fitness.min()))
            state, _ = strategy.tell(tell_key, points, fitness, state, params)
        return best

    return solve


def solve_mealpy(budget: int) -> Callable[[Instance, int], float]:
    from mealpy import FloatVar
    from mealpy.swarm_based.PSO import OriginalPSO

    def solve(instance: Instance, seed: int) -> float:
        problem = instance.problem
        lower, upper = np.asarray(problem.bounds.lower), np.asarray(problem.bounds.upper)
        rng = np.random.default_rng(np.random.SeedSequence([seed, instance.index]))
        start = _start(instance, rng)
        model = OriginalPSO(epoch=budget // POPULATION - 1, pop_size=POPULATION)
        spec = {
            "obj_func": lambda x: float(problem(np.clip(x, lower, upper)[None, :])[0]),
            "bounds": FloatVar(lb=lower, ub=upper),
            "minmax": "min",
            "log_to": None,
        }
        agent = model.solve(spec, starting_solutions=list(start), seed=seed)
        return float(agent.target.fitness)

    return solve


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--optimizers", nargs="+", default=["pso"], help="registered names")
    parser.add_argument("--budget", type=int, default=1200, help="evaluations per solve")
    parser.add_argument("--problems", type=int, default=0, help="first N problems (0: all)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    library = load_shipped("v2")
    instances = [i for i in library.instances("test") if not i.degenerate]
    if args.problems:
        instances = instances[: args.problems]
    methods = {name: solve_package(name, args.budget) for name in args.optimizers}
    if importlib.util.find_spec("evosax"):
        methods["evosax PSO"] = solve_evosax(args.budget)
    if importlib.util.find_spec("mealpy"):
        methods["mealpy OriginalPSO"] = solve_mealpy(args.budget)
    gaps: dict[str, np.ndarray] = {}
    for label, solve in methods.items():
        solve(instances[0], args.seed)  # compiled (numba, jax) before the clock starts
        start = time.perf_counter()
        costs = [solve(instance, args.seed) for instance in instances]
        seconds = time.perf_counter() - start
        gaps[label] = np.array(
            [
                normalised_gap(c, i.j_star, i.warm_cost)
                for c, i in zip(costs, instances, strict=True)
            ]
        )
        summary = stats.describe(gaps[label])
        print(
            f"{label:24s} median normalised gap {summary.median:.4g} "
            f"[{summary.ci_low:.4g}, {summary.ci_high:.4g}]  "
            f"{1e3 * seconds / len(instances):.2f} ms per solve (wall, warm)"
        )
    print(f"{len(instances)} test problems, {args.budget} evaluations, seed {args.seed}")
    for name in args.optimizers:
        for label in gaps:
            if label in args.optimizers:
                continue
            c = stats.paired_comparison(gaps[name], gaps[label])
            print(
                f"{name} vs {label}: lower on {c['x_lower']} of {c['pairs']}, "
                f"Wilcoxon p = {c['p']:.2g}, A12 = {c['a12']:.2f}"
            )


if __name__ == "__main__":
    main()
