"""The closed-loop tuning objective's noise, and whether a tuning's late gains hold on new seeds.

Run ``python -m perf.tuning_noise`` from a checkout (``--old DIR`` adds a comparison). For each
shipped ``NAME-tuned-loop`` variant (``--families`` chooses), the tuning's metric on the
tuning's suite at 50 seeds that neither the tuning (1000-1009) nor any results page (0-29)
uses, 1010-1059:

- **noise**: the standard deviation of the objective (the median over ten seeds) across the
  five disjoint sets of ten, what a trial's value would scatter by were its seeds others;
- with ``--old DIR`` (a folder of the same variants' files, e.g. from an earlier, shorter
  tuning): the old and the new configuration on the same 50 seeds, paired (the new one lower
  on how many, Wilcoxon signed-rank p), so that a gain the tuner saw on its ten seeds is
  checked on others.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

SEEDS = tuple(range(1010, 1060))
"""Fresh seeds: above the tuning's 1000-1009, far from the results pages' 0-29."""
SET_SIZE = 10
"""Seeds per objective value, as in the tuning."""


def loop_costs(name: str, values: dict) -> list[float]:
    """``name``'s metric at :data:`SEEDS` with the settings ``values`` (the tuning's suite,
    scenario, trigger and budget)."""
    from threadpoolctl import threadpool_limits

    from formation_bench.optimizers import get_optimizer
    from formation_bench.optimizers.base import Budget
    from formation_bench.pipeline.runner import execute
    from formation_bench.tuning.objectives import loop_runs
    from formation_bench.tuning.settings import Objective, TuningSettings

    settings = TuningSettings(optimizer=name, objective=Objective.LOOP, seeds=SEEDS)
    optimizer = get_optimizer(name, **values)
    budget = Budget(max_evaluations=settings.max_evaluations)
    with threadpool_limits(limits=1):
        return [
            float(execute(spec).record.to_json()[settings.metric])
            for spec in loop_runs(settings, optimizer, budget)
        ]


def noise(costs: list[float]) -> float:
    """Standard deviation of the median of :data:`SET_SIZE` over the disjoint sets."""
    sets = np.asarray(costs).reshape(-1, SET_SIZE)
    return float(np.std(np.median(sets, axis=1), ddof=1))


def main(argv: list[str] | None = None) -> int:
    from joblib import Parallel, delayed
    from scipy.stats import wilcoxon

    from formation_bench.optimizers.tuned import tuned_data

    parser = argparse.ArgumentParser(prog="python -m perf.tuning_noise", description=__doc__)
    parser.add_argument("--families", nargs="*", help="base names (default: every -tuned-loop)")
    parser.add_argument("--old", type=Path, help="a folder of earlier NAME-tuned-loop.json files")
    parser.add_argument("--jobs", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--json", type=Path, help="also write every cost as JSON")
    args = parser.parse_args(argv)
    from formation_bench.optimizers import optimizer_names

    tuned = [n for n in optimizer_names() if n.endswith("-tuned-loop")]
    families = args.families or [n.removesuffix("-tuned-loop") for n in tuned]
    missing = [f for f in families if f"{f}-tuned-loop" not in tuned]
    if missing:
        parser.error(f"--families: no tuned-loop variant of {', '.join(missing)}")
    jobs = [(f, "new", tuned_data(f"{f}-tuned-loop")["values"]) for f in families]
    if args.old is not None:
        for family in families:
            path = args.old / f"{family}-tuned-loop.json"
            if not path.is_file():
                parser.error(f"--old: {path} is missing")
            jobs.append((family, "old", json.loads(path.read_text())["values"]))
    costs = Parallel(n_jobs=args.jobs)(delayed(loop_costs)(f, values) for f, _, values in jobs)
    by = {(f, which): c for (f, which, _), c in zip(jobs, costs, strict=True)}
    print(f"steady-state cost at seeds {SEEDS[0]}-{SEEDS[-1]}; noise: SD of the median of "
          f"{SET_SIZE} over {len(SEEDS) // SET_SIZE} disjoint sets")  # fmt: skip
    header = "| family | median (new) | noise (new) |"
    if args.old is not None:
        header += " median (old) | new lower on | Wilcoxon p |"
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    for family in families:
        new = by[(family, "new")]
        row = f"| {family} | {np.median(new):.2f} | {noise(new):.2f} |"
        if args.old is not None:
            old = by[(family, "old")]
            lower = int(np.sum(np.asarray(new) < np.asarray(old)))
            same = np.array_equal(new, old)
            p = 1.0 if same else float(wilcoxon(new, old).pvalue)
            row += f" {np.median(old):.2f} | {lower} of {len(new)} | {p:.3g} |"
        print(row)
    if args.json is not None:
        args.json.write_text(json.dumps({f"{f}/{w}": c for (f, w), c in by.items()}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
