"""Scoring an optimiser on the instance library: every instance solved, stored per run.

A *score run* is one optimiser configuration at one budget with one seed, solving every
instance of one split of the library (``test``, ``validation`` or ``all``; a library without
splits, ``v1``, has ``all`` only) from its warm start, degenerate instances included. Its
rows (one per instance: where it comes from, its content hash, family, phase, split, whether
it is degenerate, ``J*`` and the warm start's cost; the final cost, the relative gap
``(f - J*) / J*`` and the normalised gap ``(f - J*) / (f_warm - J*)``, evaluations,
iterations, wall time, the evaluations to each target of the normalised gap, the
improvements of the best cost so far and the point returned) are stored as
``DIR/score/<key>.parquet``, written atomically when the run is complete and sealed like every
file of the store (page checksums and a SHA-256 of the whole file naming the run's key; see
:mod:`~formation_bench.experiments.store`), so an interrupted ``score`` resumes with
the runs still missing, stored in another :data:`SCORE_FORMAT`, damaged, or stored before
checksums were kept. :func:`load_scores` (what ``report`` and ``export-ioh`` read) leaves a
damaged file out and names it on stderr.
Runs go to local worker processes (joblib's loky backend). Instance ``k`` of a run draws its
random numbers from ``SeedSequence([run entropy, k])``, so results do not depend on the worker
count.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from formation_bench.analysis.scoring import (
    TARGETS,
    evaluations_to_target,
    normalised_gap,
)
from formation_bench.experiments.errors import IntegrityError, StoreError
from formation_bench.experiments.seal import (
    read_table,
    sealed_parquet,
)
from formation_bench.experiments.store import intact_frames, to_stderr
from formation_bench.instances.library import (
    Instance,
    Library,
    LibraryError,
    load_shipped,
    shipped,
)
from formation_bench.optimizers import Budget, Optimizer, get_optimizer
from formation_bench.pipeline.outputs import atomic_write_bytes
from formation_bench.pipeline.spec import (
    budget_label,
    canonical_json,
    from_json_value,
    labelled,
    resolved_budget,
)
from formation_bench.plugins import load_plugins

SCORE = "score"
"""Subfolder of a results folder that holds score runs."""
SCORE_FORMAT = 3
"""Layout version of the score rows (column ``score_format``); bumped when the columns
change, so a run stored in another layout is redone on resume. 2 added the improvement
history and the point returned; 3 the run's split (``run_split``), the instance's content
hash, family, phase, split, degeneracy and warm-start cost, the normalised gap, and the
evaluations to targets of the normalised gap (``evals_to_norm_*``, where 2 had targets of the
relative gap)."""
SPLITS = ("test", "validation", "all")
"""Splits a score run can solve: a split of the library, or ``all``, every instance."""
DEFAULT_SPLIT = "test"
"""The split scored when none is named, on a library with splits (``all`` on one without)."""


class ScoreError(ValueError):
    """A score run that cannot be made as asked (one line, naming the option)."""


def target_column(target: float) -> str:
    """Column of the evaluations to reach a normalised gap of ``target`` (e.g.
    ``evals_to_norm_1e-03``)."""
    return f"evals_to_norm_{target:.0e}"


def resolved_split(library: Library, split: str | None) -> str:
    """``split`` checked against ``library`` (None: :data:`DEFAULT_SPLIT`, or ``all`` on a
    library without splits); raises :class:`ScoreError` naming ``--split``."""
    allowed = SPLITS if library.has_splits else ("all",)
    if split is None:
        return DEFAULT_SPLIT if library.has_splits else "all"
    if split not in allowed:
        without = "" if library.has_splits else " (it has no splits)"
        raise ScoreError(
            f"--split: {split!r} is not a split of library {library.version}{without}; "
            f"allowed: {', '.join(allowed)}"
        )
    return split


def split_instances(library: Library, split: str) -> list[Instance]:
    """The instances a score run over ``split`` solves, degenerate ones included."""
    resolved_split(library, split)
    return library.instances(None if split == "all" else split, degenerate=None)


@dataclass(frozen=True)
class ScoreRun:
    """One optimiser configuration at one budget with one seed, over the whole library."""

    optimizer_label: str
    optimizer_name: str
    optimizer_overrides: str
    """Canonical JSON of the fields changed from the registered configuration."""
    max_evaluations: int | None
    """Per-solve evaluation budget; None with ``max_iterations`` None: the optimiser's own."""
    max_iterations: int | None
    deadline_ms: float | None
    seed: int
    library_version: str
    split: str = "all"
    """The split solved (:data:`SPLITS`); ``all``: every instance."""
    plugins: tuple[str, ...] = ()

    @property
    def budget_label(self) -> str:
        return budget_label(self.max_evaluations, self.max_iterations, self.deadline_ms)

    def identity(self) -> dict[str, Any]:
        """What the run's key and random numbers derive from. The split is part of it, but
        for ``all``, which leaves it out, so a run over a whole library keeps the key (and
        random numbers) it had before runs had splits, and is redone in place on resume."""
        identity = {
            "optimizer": self.optimizer_name,
            "optimizer_overrides": json.loads(self.optimizer_overrides),
            "max_evaluations": self.max_evaluations,
            "max_iterations": self.max_iterations,
            "deadline_ms": self.deadline_ms,
            "seed": self.seed,
            "library": self.library_version,
        }
        if self.split != "all":
            identity["split"] = self.split
        return identity

    @property
    def key(self) -> str:
        return hashlib.sha256(canonical_json(self.identity()).encode()).hexdigest()[:24]

    @property
    def entropy(self) -> int:
        digest = hashlib.sha256(
            b"formation-bench score\0" + canonical_json(self.identity()).encode()
        )
        return int.from_bytes(digest.digest()[:16], "big")

    def optimizer(self) -> Optimizer:
        return get_optimizer(
            self.optimizer_name, **from_json_value(json.loads(self.optimizer_overrides))
        )

    def budget(self, optimizer: Optimizer) -> Budget | None:
        return resolved_budget(
            self.max_evaluations, self.max_iterations, self.deadline_ms, optimizer
        )


def score_runs(
    optimizer_name: str,
    overrides: dict[str, Any],
    budgets: list[tuple[int | None, int | None]],
    seeds: list[int],
    *,
    deadline_ms: float | None = None,
    library: Library | None = None,
    split: str | None = None,
    plugins: tuple[str, ...] = (),
) -> list[ScoreRun]:
    """The score runs of one optimiser configuration at every budget and seed, over ``split``
    of ``library`` (by default the shipped library and :func:`resolved_split`'s default)."""
    library = shipped() if library is None else library
    split = resolved_split(library, split)
    configured = get_optimizer(optimizer_name, **overrides)
    label, changed = labelled(optimizer_name, get_optimizer(optimizer_name), configured)
    return [
        ScoreRun(
            optimizer_label=label,
            optimizer_name=optimizer_name,
            optimizer_overrides=canonical_json(changed),
            max_evaluations=max_evaluations,
            max_iterations=max_iterations,
            deadline_ms=deadline_ms,
            seed=seed,
            library_version=library.version,
            split=split,
            plugins=plugins,
        )
        for max_evaluations, max_iterations in budgets
        for seed in seeds
    ]


def run_library(run: ScoreRun, library: Library | None = None) -> Library:
    """The library ``run`` solves: ``library`` if given (it must be the run's version), else
    the shipped one of the run's version."""
    if library is None:
        try:
            return load_shipped(run.library_version)
        except LibraryError as err:
            raise ScoreError(f"--library: {err}") from None
    if library.version != run.library_version:
        raise ScoreError(
            f"a score run on library {run.library_version} given library {library.version}"
        )
    return library


def execute_score(run: ScoreRun, library: Library | None = None) -> pd.DataFrame:
    """Solve every instance of the run's split once; one row per instance."""
    from threadpoolctl import threadpool_limits

    load_plugins(run.plugins)
    library = run_library(run, library)
    optimizer = run.optimizer()
    budget = run.budget(optimizer)
    rows = []
    with threadpool_limits(limits=1):
        for instance in split_instances(library, run.split):
            problem = instance.problem
            rng = np.random.default_rng(np.random.SeedSequence([run.entropy, instance.index]))
            start = time.perf_counter()
            result = optimizer.minimize(problem, problem.bounds, rng, budget, instance.warm_start)
            seconds = time.perf_counter() - start
            history_nfev = result.history_nfev if result.history_nfev.size else [result.nfev]
            history_fun = result.history_fun if result.history_fun.size else [result.fun]
            improved_nfev, improved_fun = improvements(history_nfev, history_fun)
            rows.append(
                {
                    "instance": instance.index,
                    "content_hash": instance.content_hash,
                    "family": instance.family,
                    "phase": instance.phase,
                    "split": instance.split,
                    "degenerate": bool(instance.degenerate),
                    "scenario": instance.scenario_name,
                    "trigger": instance.trigger,
                    "step": instance.step,
                    "j_star": instance.j_star,
                    "warm_cost": float(instance.warm_cost),
                    "fun": float(result.fun),
                    "gap": float(instance.gap(result.fun)),
                    "normalised_gap": _normalised(instance, result.fun),
                    "nfev": int(result.nfev),
                    "nit": int(result.nit),
                    "seconds": seconds,
                    "success": bool(result.success),
                    **{
                        target_column(t): (
                            math.nan
                            if instance.degenerate
                            else evaluations_to_target(
                                np.asarray(history_nfev),
                                np.asarray(history_fun),
                                instance.j_star,
                                instance.warm_cost,
                                t,
                            )
                        )
                        for t in TARGETS
                    },
                    "improvement_nfev": improved_nfev,
                    "improvement_fun": improved_fun,
                    "x": np.asarray(result.x, dtype=np.float64).tolist(),
                    "score_format": SCORE_FORMAT,
                }
            )
    frame = pd.DataFrame(rows)
    if frame.empty:
        raise ScoreError(f"--split: library {run.library_version} has no {run.split} instances")
    frame.insert(0, "run_key", run.key)
    frame.insert(1, "optimizer", run.optimizer_label)
    frame.insert(2, "optimizer_name", run.optimizer_name)
    frame.insert(3, "optimizer_overrides", run.optimizer_overrides)
    frame.insert(4, "budget", run.budget_label)
    frame.insert(5, "budget_max_evaluations", pd.array([run.max_evaluations] * len(frame), "Int64"))
    frame.insert(6, "deadline_ms", float("nan") if run.deadline_ms is None else run.deadline_ms)
    frame.insert(7, "seed", run.seed)
    frame.insert(8, "library", run.library_version)
    frame.insert(9, "run_split", run.split)
    return frame


def _normalised(instance: Instance, cost: float) -> float:
    """The normalised gap of ``cost`` on ``instance``: NaN on a degenerate one."""
    if instance.degenerate:
        return math.nan
    return float(normalised_gap(cost, instance.j_star, instance.warm_cost))


def improvements(history_nfev: np.ndarray, history_fun: np.ndarray) -> tuple[list, list]:
    """The points of a best-so-far history where the best cost first fell to a new low."""
    fun = np.asarray(history_fun, dtype=np.float64)
    # a solve that starts at the warm start has no cost before its first record: it counts
    previous = np.concatenate(([np.inf], np.minimum.accumulate(fun)[:-1]))
    keep = fun < previous
    return np.asarray(history_nfev)[keep].tolist(), fun[keep].tolist()


def stored_keys(out: Path) -> set[str]:
    """Keys of the runs stored whole, sealed, in the current :data:`SCORE_FORMAT`."""
    folder = out / SCORE
    if not folder.is_dir():
        return set()
    return {p.stem for p in folder.glob("*.parquet") if _stored_whole(p)}


def _stored_whole(path: Path) -> bool:
    try:
        table, seal = read_table(path, "score", path.stem, ["run_key", "score_format"])
    except IntegrityError:  # damaged, or another run's file: redone
        return False
    # a file without a seal (stored before checksums were kept) is redone, and sealed
    return seal is not None and set(table.column("score_format").to_pylist()) == {SCORE_FORMAT}


def write_score(out: Path, run: ScoreRun, frame: pd.DataFrame) -> Path:
    path = out / SCORE / f"{run.key}.parquet"
    data, _ = sealed_parquet(pa.Table.from_pandas(frame, preserve_index=False), "score", run.key)
    atomic_write_bytes(path, data)
    return path


def run_scores(
    runs: list[ScoreRun], out: Path, *, jobs: int = 2, library: Library | None = None
) -> Iterator[ScoreRun]:
    """Carry out the runs not stored whole in ``out`` (on ``library``, by default the shipped
    one); yields each as it is stored."""
    todo = [run for run in runs if run.key not in stored_keys(out)]
    if jobs == 1 or len(todo) <= 1:
        for run in todo:
            write_score(out, run, execute_score(run, library))
            yield run
        return
    from joblib import Parallel, delayed, parallel_config

    with parallel_config(backend="loky", inner_max_num_threads=1):
        parallel = Parallel(n_jobs=jobs, return_as="generator_unordered", batch_size=1)
        for run, frame in parallel(delayed(_execute_pair)(run, library) for run in todo):
            write_score(out, run, frame)
            yield run


def _execute_pair(run: ScoreRun, library: Library | None) -> tuple[ScoreRun, pd.DataFrame]:
    return run, execute_score(run, library)


def check_score_format(scores: pd.DataFrame, doing: str) -> None:
    """Raise :class:`StoreError` naming the runs of ``scores`` stored in another
    :data:`SCORE_FORMAT` (which lack columns ``doing`` needs), with the fix."""
    stored = scores["score_format"] if "score_format" in scores else pd.Series(np.nan, scores.index)
    old = scores[stored.fillna(0).astype(int) != SCORE_FORMAT]
    if old.empty:
        return
    runs = old.drop_duplicates("run_key")
    named = ", ".join(f"{r.optimizer} / {r.budget} / seed {r.seed}" for r in runs.itertuples())
    raise StoreError(
        f"{len(runs)} score run(s) were stored in an older score format (before "
        f"{SCORE_FORMAT}: no normalised gap), which {doing} cannot use: {named}; run the same "
        "'formation-bench score' commands on the folder again to redo them"
    )


def load_scores(out: Path | str, *, notice: Callable[[str], None] = to_stderr) -> pd.DataFrame:
    """Every intact stored score row of ``out``, one row per (run, instance).

    A file that fails its checks is left out and named on stderr, one line each. How many
    files were used unverified (stored before checksums were kept) goes to ``notice``.
    """
    folder = Path(out) / SCORE
    paths = sorted(folder.glob("*.parquet")) if folder.is_dir() else []
    redo = f"'formation-bench score' with the run's options and --out {out}"

    def read(key: str) -> tuple[pd.DataFrame, bool]:
        table, seal = read_table(folder / f"{key}.parquet", "score", key)
        return table.to_pandas(), seal is not None

    frames = intact_frames(
        [(path, path.stem) for path in paths], read,
        redo=redo, redo_all=redo, folder=folder, notice=notice,
    )  # fmt: skip
    if not frames:
        raise StoreError(f"{out} holds no score runs (no intact {SCORE}/*.parquet)")
    frame = pd.concat(frames, ignore_index=True)
    return frame.sort_values(
        ["optimizer", "budget", "seed", "library", "instance"], ignore_index=True
    )
