"""Score runs in the IOHprofiler format, the one IOHanalyzer reads.

The layout is the one ``ioh``'s ``Analyzer`` logger writes (its format version
:data:`IOH_FORMAT_VERSION`; ``tests/test_ioh_export.py`` checks the match against the
installed ``ioh``): one folder per algorithm, in it one JSON meta file per function and,
per dimension, one data file with every run, each run opening with the line
``evaluations raw_y``::

    OUT/<algorithm>/IOHprofiler_f<F>_<function>.json
    OUT/<algorithm>/data_f<F>_<function>/IOHprofiler_f<F>_DIM<D>.dat

The mapping:

- algorithm: the optimiser configuration's label and the budget, ``pso @ default``;
- function: the instance library, ``formation_library_v1`` with ``F`` = 1 (the number of
  its version); the library's instances are the function's instances (``instance`` = the
  library index), as IOHprofiler pools the instances of a function, so IOHanalyzer's
  statistics run over every (instance, seed) trial, as ``formation-bench report`` does;
- dimension: the length of the decision vector;
- run: one solve, one instance with one seed (run attributes ``j_star``, the instance's
  best-known cost, ``seed`` and ``warm_cost``, the cost of its warm start);
- raw_y: the normalised gap ``(cost - J*) / (warm_cost - J*)`` of the best cost so far, the
  share of the possible improvement left (the gap the report's targets use), so the optimum
  is 0 on every instance (``ioh`` likewise logs ``y - f_opt``) and a target means the same
  on every instance; a solve that beats ``J*`` gives a negative raw_y. Solves of degenerate
  instances, where the normalised gap is not defined, are left out.

A run's lines are the evaluations at which its best cost so far improved, then its last
evaluation (as the logger ends a run). Values are written in full precision, where the
logger writes ten decimals (which would turn gaps below 5e-11 into 0).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formation_bench.analysis.scoring import TARGET_GAP, normalised_gap
from formation_bench.experiments.errors import StoreError
from formation_bench.experiments.score import check_score_format

IOH_FORMAT_VERSION = "0.4.2"
"""Version of ``ioh`` whose logger layout is written, and written as the format version (the
logger writes its own version there; IOHanalyzer reads JSON meta files from version 0.3.3
on). The logger of 0.3.22 writes the same files but for that number. The lock installs this
``ioh``, and the layout test fails when the installed one writes another version."""
SUITE = "formation-bench"
HISTORY = ("improvement_nfev", "improvement_fun", "x")
"""Score columns of the improvement history the export needs (stored from score format 2 on;
the warm start's cost and the degeneracy from format 3 on)."""
RUN_ATTRIBUTES = ("j_star", "seed", "warm_cost")


class ExportError(ValueError):
    """Score rows that cannot be exported (one line, naming the runs and the fix)."""


def algorithm_name(optimizer: str, budget: str) -> str:
    return f"{optimizer} @ {budget}"


def function_of(library: str) -> tuple[int, str]:
    """IOHprofiler function id and name of a library version ``v<N>``."""
    match = re.fullmatch(r"v(\d+)", library)
    if match is None:
        raise ExportError(
            f"library version {library!r}: an export needs versions named v<N> (the function "
            "id is N)"
        )
    return int(match[1]), f"formation_library_{library}"


def run_lines(row: Any) -> list[tuple[int, float]]:
    """A solve's ``(evaluations, raw_y)`` lines: its improvements, then its last evaluation;
    raw_y the normalised gap of the best cost so far."""
    improved = np.asarray(row.improvement_fun, dtype=np.float64)
    lines = list(
        zip(
            (int(n) for n in row.improvement_nfev),
            normalised_gap(improved, row.j_star, row.warm_cost).tolist(),
            strict=True,
        )
    )
    if not lines or int(row.nfev) > lines[-1][0]:
        lines.append((int(row.nfev), float(row.normalised_gap)))
    return lines


def export_ioh(scores: pd.DataFrame, out: Path) -> dict[str, int]:
    """Write ``scores`` (:func:`~formation_bench.experiments.score.load_scores`)
    into the folder ``out``, but for the solves of degenerate instances (no normalised gap);
    returns the number of runs per algorithm."""
    _check_history(scores)
    scores = scores[~scores["degenerate"].astype(bool)]
    written: dict[str, int] = {}
    folders: set[str] = set()
    for (optimizer, budget), rows in scores.groupby(["optimizer", "budget"], sort=True):
        algorithm = algorithm_name(str(optimizer), str(budget))
        folder = _unique(re.sub(r"[^A-Za-z0-9._=,+@-]+", "_", algorithm.replace(" ", "")), folders)
        for library, in_library in rows.groupby("library", sort=True):
            _write_function(out / folder, algorithm, str(library), in_library)
        written[algorithm] = len(rows)
    return written


def _write_function(folder: Path, algorithm: str, library: str, rows: pd.DataFrame) -> None:
    fid, name = function_of(library)
    first = rows.iloc[0]
    dimensions = rows["x"].map(len)
    scenarios = []
    for dimension, runs in rows.assign(dim=dimensions).groupby("dim", sort=True):
        path = f"data_f{fid}_{name}/IOHprofiler_f{fid}_DIM{dimension}.dat"
        text, meta = [], []
        for row in runs.sort_values(["seed", "instance"]).itertuples(index=False):
            lines = run_lines(row)
            text.append("evaluations raw_y\n")
            text.extend(f"{n} {y!r}\n" for n, y in lines)
            final = float(row.normalised_gap)
            best_evals = next((n for n, y in lines if y <= final), int(row.nfev))
            best = {"evals": best_evals, "y": final, "x": [float(v) for v in row.x]}
            meta.append(
                {
                    "instance": int(row.instance),
                    "evals": int(row.nfev),
                    "best": best,
                    "j_star": float(row.j_star),
                    "seed": int(row.seed),
                    "warm_cost": float(row.warm_cost),
                }
            )
        (folder / path).parent.mkdir(parents=True, exist_ok=True)
        (folder / path).write_text("".join(text))
        scenarios.append({"dimension": int(dimension), "path": path, "runs": meta})
    info = {
        "version": IOH_FORMAT_VERSION,
        "suite": SUITE,
        "function_id": fid,
        "function_name": name,
        "maximization": False,
        "algorithm": {
            "name": algorithm,
            "info": f"{first.optimizer_name} {first.optimizer_overrides} budget {first.budget}",
        },
        "experiment_attributes": [
            {"budget": str(first.budget)},
            {"library": library},
            {"optimizer_name": str(first.optimizer_name)},
            {"raw_y": TARGET_GAP},
        ],
        "run_attributes": list(RUN_ATTRIBUTES),
        "attributes": ["evaluations", "raw_y"],
        "scenarios": scenarios,
    }
    try:
        text = _meta_text(info)
    except ValueError:
        raise ExportError(f"{algorithm}: a cost is not finite, which JSON cannot hold") from None
    (folder / f"IOHprofiler_f{fid}_{name}.json").write_text(text)


def _meta_text(info: dict[str, Any]) -> str:
    """The meta JSON laid out as the logger lays it out: a key a line, a run a line."""

    def dump(value: Any) -> str:
        return json.dumps(value, allow_nan=False)

    head = [f"\t{dump(k)}: {dump(v)}" for k, v in info.items() if k != "scenarios"]
    scenarios = [
        f'\t\t{{"dimension": {s["dimension"]}, "path": {dump(s["path"])}, "runs": [\n'
        + ",\n".join(f"\t\t\t{dump(run)}" for run in s["runs"])
        + "\n\t\t]}"
        for s in info["scenarios"]
    ]
    return (
        "{\n"
        + ",\n".join([*head, '\t"scenarios": [\n' + ",\n".join(scenarios) + "\n\t]"])
        + "\n}\n"
    )


def _check_history(scores: pd.DataFrame) -> None:
    try:
        check_score_format(scores, "an export")
    except StoreError as err:
        raise ExportError(str(err)) from None
    missing = [c for c in HISTORY if c not in scores.columns]
    lacking = scores if missing else scores[scores[list(HISTORY)].isna().any(axis=1)]
    if len(lacking):
        runs = lacking.drop_duplicates("run_key")
        named = ", ".join(f"{r.optimizer} / {r.budget} / seed {r.seed}" for r in runs.itertuples())
        raise ExportError(
            f"{len(runs)} score run(s) were stored without the improvement history (an older "
            f"score format): {named}; run the same 'formation-bench score' commands on the "
            "folder again to redo them"
        )


def _unique(name: str, taken: set[str]) -> str:
    candidate, k = name, 1
    while candidate in taken:
        k += 1
        candidate = f"{name}-{k}"
    taken.add(candidate)
    return candidate
