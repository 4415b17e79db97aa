"""Running a suite: every run independent, seeded by its identity, stored as it finishes.

Runs go to local worker processes (joblib's loky backend, ``jobs`` workers,
native thread pools limited to one thread per worker) or, given a scheduler
address, to a Dask distributed cluster
(:mod:`~formation_bench.experiments.executors`). Workers only
compute: each returns its run's metrics row (and trace) to this process, which
alone writes the results folder. So a cluster needs no shared file system, and
the folder's lock keeps two sweeps from writing into it at once.

A run's random streams come from ``SeedSequence(entropy)`` with ``entropy``
derived from the run's identity
(:meth:`formation_bench.pipeline.spec.RunSpec.identity_entropy`), so
results do not depend on queue order, worker count or which worker ran what.
"""

from __future__ import annotations

import signal
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from formation_bench.experiments.errors import SweepError, SweepStopped
from formation_bench.experiments.executors import (
    DEFAULT_WORKER_TIMEOUT_S,
    RunResult,
    close_client,
    connect_scheduler,
    run_locally,
    run_on_dask,
)
from formation_bench.experiments.guard import FolderGuard
from formation_bench.experiments.suite import Suite
from formation_bench.pipeline.compiles import compile_first
from formation_bench.pipeline.interrupts import (
    interrupts_deferred,
    is_interrupt,
    raise_interrupt,
)
from formation_bench.pipeline.provenance import now
from formation_bench.pipeline.spec import RunSpec
from formation_bench.pipeline.staging import storage_advice, storage_problem

if TYPE_CHECKING:
    from dask.distributed import Client

    from formation_bench.experiments.store import ResultStore
    from formation_bench.optimizers import Optimizer

DEFAULT_JOBS = 2


@dataclass
class SweepSummary:
    """How a sweep went."""

    total: int
    """Runs in the suite."""
    already: int = 0
    """Runs found finished and skipped."""
    redo: dict[str, int] = field(default_factory=dict)
    """Runs found but redone, by reason (corrupt, stale, no-trace)."""
    stored: int = 0
    """Runs finished and stored by this sweep."""
    failed: list[dict[str, str]] = field(default_factory=list)
    """Runs that raised: run, key and error."""
    interrupted: bool = False
    wall_s: float = 0.0

    @property
    def pending(self) -> int:
        return self.total - self.already

    @property
    def exit_code(self) -> int:
        if self.interrupted:
            return 130
        return 1 if self.failed else 0


def plan(suite: Suite, store: ResultStore) -> tuple[list[RunSpec], SweepSummary]:
    """The runs still to do, and the summary so far; stops (:class:`ManifestError`) at a
    damaged manifest, which a sweep would otherwise rewrite."""
    # the manifest module reads Parquet with pandas: imported by the command that uses it
    from formation_bench.experiments.manifest import read_manifest

    read_manifest(store, suite)
    runs = suite.runs()
    summary = SweepSummary(total=len(runs))
    pending = []
    redo: Counter[str] = Counter()
    for spec in runs:
        status = store.status(spec.key, spec.config_hash, spec.trace)
        if status.state == "done":
            summary.already += 1
            continue
        if status.state != "missing":
            redo[status.state] += 1
        pending.append(spec)
    summary.redo = dict(redo)
    return pending, summary


def run_sweep(
    suite: Suite,
    out: Path | str,
    *,
    jobs: int = DEFAULT_JOBS,
    scheduler: str | None = None,
    worker_timeout_s: float = DEFAULT_WORKER_TIMEOUT_S,
    progress: bool | None = None,
    allow_suite_change: bool = False,
    log: Callable[[str], None] | None = None,
) -> SweepSummary:
    """Run every unfinished run of ``suite`` into ``out`` and return the summary.

    ``progress`` None shows the bar only on a terminal. Ctrl-C (or SIGTERM) stops
    cleanly: finished runs are stored, the rest are left for the next call. A sweep that
    cannot go on (its folder or lock deleted or moved, the disk full or read-only, no live
    Dask worker for ``worker_timeout_s``) stops with a :class:`SweepError` that says how
    many runs the folder holds.
    """
    say = log or (lambda text: print(text, file=sys.stderr, flush=True))
    if jobs < 1:
        raise SweepError(f"--jobs must be an integer >= 1, got {jobs}")
    if not worker_timeout_s > 0:
        raise SweepError(
            f"--worker-timeout must be a number of seconds > 0, got {worker_timeout_s}"
        )
    # the store reads and writes Parquet with pandas: imported by the command that uses it
    from formation_bench.experiments.store import ResultStore, StoreBusy

    start = time.perf_counter()
    client = connect_scheduler(scheduler) if scheduler else None
    store = ResultStore(out)
    keys = {spec.key for spec in suite.runs()}
    try:
        with store.lock():
            guard = FolderGuard(store.root)
            try:
                summary = _sweep_locked(
                    suite, store, guard, jobs, client, worker_timeout_s, progress,
                    allow_suite_change, say,
                )  # fmt: skip
            finally:
                guard.close()
    except StoreBusy as err:
        raise SweepError(f"--out: {err}") from None
    except SweepStopped as stop:
        raise SweepError(
            f"{stop.option}: {stop.reason}; stopped: {_stored(store, keys)} of {len(keys)} runs in "
            f"{store.root}; {stop.advice}"
        ) from None
    except OSError as err:
        problem = storage_problem(err, where=store.root)
        if problem is None:
            raise
        raise SweepError(
            f"--out: {problem}; {_stored(store, keys)} of {len(keys)} runs stored in "
            f"{store.root} and intact; {storage_advice(err)}"
        ) from None
    finally:
        if client is not None:
            close_client(client)
    summary.wall_s = time.perf_counter() - start
    for failure in summary.failed:
        last = failure["error"].strip().splitlines()[-1]
        say(f"failed: {failure['run']}: {last}")
    done = _stored(store, keys)  # what the folder holds, whatever this process believes
    if summary.interrupted:
        say(
            f"interrupted: {done} of {summary.total} runs stored in {store.root}; "
            "run the same command again to finish"
        )
    else:
        say(
            f"stored {summary.stored} runs in {summary.wall_s:.1f} s; {done} of {summary.total} "
            f"runs in {store.root}"
            + (
                f"; {len(summary.failed)} failed (see {store.manifest_path})"
                if summary.failed
                else ""
            )
        )
    return summary


def _stored(store: ResultStore, keys: set[str]) -> int:
    """How many of the runs ``keys`` have a run file in the folder (0 if it is gone)."""
    return len(keys.intersection(store.keys()))


def _sweep_locked(
    suite: Suite,
    store: ResultStore,
    guard: FolderGuard,
    jobs: int,
    client: Client | None,
    worker_timeout_s: float,
    progress: bool | None,
    allow_suite_change: bool,
    say: Callable[[str], None],
) -> SweepSummary:
    from formation_bench.experiments.manifest import (
        check_suite_matches,
        mixed_commits,
        read_manifest,
        session_entry,
        updated_manifest,
        write_manifest,
    )

    start = time.perf_counter()
    scheduler = client.scheduler.address if client is not None else None
    manifest = read_manifest(store, suite)
    check_suite_matches(manifest, suite, store.root, allow_suite_change)
    if manifest is not None:
        # this sweep holds the folder's lock, so a session still marked running was killed
        for stale in manifest.get("sessions", []):
            if stale.get("state") == "running":
                stale["state"] = "killed"
    guard.check()
    store.create()
    store.remove_temporaries()
    pending, summary = plan(suite, store)
    for note in suite.notes:
        say(f"note: {note}")
    redone = ", ".join(f"{n} {state}" for state, n in sorted(summary.redo.items()))
    where = f"Dask scheduler {scheduler}" if scheduler else f"{jobs} local worker(s)"
    say(
        f"suite {suite.name}: {summary.total} runs, {summary.already} already stored"
        + (f", redoing {redone}" if redone else "")
        + f"; {len(pending)} to run on {where}"
    )
    session = session_entry(jobs, scheduler)
    session.update(total=summary.total, already=summary.already, redo=summary.redo)
    mixed = mixed_commits(manifest, session, summary.already)
    if mixed:
        say(mixed)
    manifest = updated_manifest(manifest, suite, summary.total, session)
    guard.check()
    try:
        write_manifest(store, manifest)
    except OSError:
        guard.check()
        raise
    state = "error"  # whatever ends the sweep, the manifest never says it is still running
    refused: OSError | None = None
    try:
        with _sigterm_as_interrupt():
            _execute(
                pending, store, guard, summary, jobs, client, worker_timeout_s, progress,
                suite.name, say,
            )  # fmt: skip
        state = "failed" if summary.failed else "done"
    except SweepStopped:
        state = "stopped"
        raise
    except OSError as err:
        if storage_problem(err) is not None:
            state, refused = "stopped", err
        raise
    except BaseException as err:  # C code wraps an interrupt in its own error, of any class
        if not is_interrupt(err):
            raise
        summary.interrupted = True
        state = "interrupted"
    finally:
        # a second Ctrl-C must not cut this short: the manifest would say "running"
        with interrupts_deferred():
            session.update(
                finished=now(),
                state=state,
                stored=summary.stored,
                failed=summary.failed,
                wall_s=round(time.perf_counter() - start, 3),
            )
            manifest["updated"] = session["finished"]
            if guard.problem() is None:  # never recreate a folder that was taken away
                try:
                    write_manifest(store, manifest)
                except OSError as err:
                    # the write that failed first is the one to report
                    if guard.problem() is None and (
                        refused is None or storage_problem(err) is None
                    ):
                        raise
    return summary


def _execute(
    pending: list[RunSpec],
    store: ResultStore,
    guard: FolderGuard,
    summary: SweepSummary,
    jobs: int,
    client: Client | None,
    worker_timeout_s: float,
    progress: bool | None,
    name: str,
    say: Callable[[str], None],
) -> None:
    from tqdm import tqdm

    if not pending:
        return
    by_key = {spec.key: spec for spec in pending}
    # the workers start by compiling different kernels (the results do not depend on order)
    built: dict[tuple[str, str], Optimizer | None] = {}

    def optimizer_of(spec: RunSpec) -> Optimizer | None:
        key = (spec.optimizer_name, spec.optimizer_overrides)
        if key not in built:
            built[key] = _optimizer_of(spec)
        return built[key]

    pending = compile_first(pending, optimizer_of)
    results = (
        run_on_dask(pending, client, worker_timeout_s, notice=say)
        if client is not None
        else run_locally(pending, jobs)
    )
    try:
        with tqdm(
            total=len(pending),
            desc=name,
            unit="run",
            disable=None if progress is None else not progress,
            file=sys.stderr,
        ) as bar:
            for result in results:
                spec = by_key[result.key]
                if result.failed:
                    summary.failed.append(
                        {"run": spec.describe(), "key": spec.key, "error": result.error or ""}
                    )
                else:
                    guard.check()
                    try:
                        _write_run(store, result)
                    except OSError:
                        guard.check()  # the write failed because the folder went: say that
                        raise
                    summary.stored += 1
                bar.update(1)
    finally:
        # stop the workers now, not whenever the generator is garbage-collected (which may
        # be after the command has printed its last line), and let no Ctrl-C cut it short
        with interrupts_deferred():
            results.close()


def _optimizer_of(spec: RunSpec) -> Optimizer | None:
    """The run's optimiser; None if it cannot be built here (the run itself says why)."""
    from formation_bench.plugins import load_plugins

    try:
        load_plugins(spec.plugins)
        return spec.optimizer()
    except Exception:
        return None


def _write_run(store: ResultStore, result: RunResult) -> None:
    """Store one run; if the file system refuses, leave no trace without its run row. A
    Ctrl-C meanwhile is raised once the run is stored, not halfway through its file."""
    try:
        with interrupts_deferred():
            store.write_run(result.key, result.row or {}, result.trace)
    except OSError as err:
        if not store.run_path(result.key).exists():
            with interrupts_deferred():
                store.inside(store.trace_path(result.key)).unlink(missing_ok=True)
        if err.filename is None:  # a failed write names no file: name the run not stored
            err.filename = str(store.run_path(result.key))
        raise


class _sigterm_as_interrupt:
    """Turn SIGTERM into KeyboardInterrupt (main thread only), so batch systems stop cleanly."""

    def __enter__(self) -> None:
        self.previous = None
        try:
            self.previous = signal.signal(signal.SIGTERM, raise_interrupt)
        except ValueError:  # not the main thread
            self.previous = None

    def __exit__(self, *exc: object) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGTERM, self.previous)
