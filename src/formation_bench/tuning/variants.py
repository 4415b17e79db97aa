"""The tuned-variant file a tuning writes, ``<out>/<NAME>.json``.

Its keys (``format`` 1): ``name`` and ``base``; ``values``, the tuned settings as ``--set``
writes them plus the budget setting that makes the variant's own budget the tuning's as
nearly as its batches allow; ``objective`` (kind, budget, metric, statistic, split, library,
suite, seeds, problems); ``tuner`` (library, version, sampler, trials, batch, seed);
``provenance`` (date, commit, version, command, wall time, machine); ``default_value`` (trial
0, the base configuration), ``best_value`` and ``history`` (every trial's value in trial
order). :mod:`formation_bench.optimizers.tuned` registers such a file.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

from formation_bench.optimizers import Budget, Optimizer, get_optimizer
from formation_bench.optimizers.base import BUDGET_MINIMUM, PopulationOptimizer
from formation_bench.optimizers.tuned import TUNED_FORMAT
from formation_bench.pipeline.outputs import atomic_write_bytes
from formation_bench.tuning.settings import TUNING_SPLIT, Objective, TuningSettings

SOLVE_METRIC = "median normalised gap"
"""What the per-solve objective measures, as the file names it."""


def budget_values(optimizer: Optimizer, max_evaluations: int) -> dict[str, Any]:
    """The budget setting that makes ``optimizer``'s own budget ``max_evaluations``
    evaluations, or as near below as whole iterations allow; empty for an optimiser whose
    own budget is not counted in either."""
    fields = {f.name for f in dataclasses.fields(optimizer)}  # type: ignore[arg-type]
    own = optimizer.default_budget
    if own.max_evaluations is not None and "max_evaluations" in fields:
        return {"max_evaluations": max_evaluations}
    if "max_iterations" in fields and isinstance(optimizer, PopulationOptimizer):
        planned = optimizer.planned_iterations(Budget(max_evaluations=max_evaluations))
        return {"max_iterations": max(BUDGET_MINIMUM, planned)}
    return {}


def objective_description(settings: TuningSettings) -> dict[str, Any]:
    """The file's ``objective``."""
    solve = settings.objective is Objective.SOLVE
    return {
        "kind": settings.objective.value,
        "budget": settings.max_evaluations,
        "metric": SOLVE_METRIC if solve else settings.metric,
        "statistic": "median",
        "split": TUNING_SPLIT if solve else None,
        "library": settings.library if solve else None,
        "suite": None if solve else settings.suite,
        "seeds": None if solve else list(settings.seeds),
        "problems": settings.problems if solve else None,
    }


def variant_file(
    settings: TuningSettings,
    best_values: dict[str, Any],
    history: list[float],
    best_value: float,
    provenance: dict[str, Any],
) -> dict[str, Any]:
    """The contents of the tuned-variant file."""
    import optuna

    tuned = get_optimizer(settings.optimizer, **best_values)
    return {
        "format": TUNED_FORMAT,
        "name": settings.variant_name,
        "base": settings.optimizer,
        "values": best_values | budget_values(tuned, settings.max_evaluations),
        "objective": objective_description(settings),
        "tuner": {
            "library": "optuna",
            "version": optuna.__version__,
            "sampler": "TPESampler",
            "trials": settings.trials,
            "batch": settings.batch,
            "seed": settings.seed,
        },
        "provenance": provenance,
        "default_value": history[0],
        "best_value": best_value,
        "history": history,
    }


def machine() -> str:
    """The processor model and core count, as the file records the machine."""
    from formation_bench.pipeline.provenance import cpu_model

    return f"{cpu_model() or 'unknown processor'}, {os.cpu_count()} cores"


def write_variant(path: Path, data: dict[str, Any]) -> None:
    """Write the file whole or not at all."""
    atomic_write_bytes(path, (json.dumps(data, indent=2) + "\n").encode())


def read_variant(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())
