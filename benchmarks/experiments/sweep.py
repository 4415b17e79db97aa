"""Running a suite: every run independent, seeded by its identity, stored as it finishes.

Runs go to local worker processes (joblib's loky backend, ``jobs`` workers,
native thread pools limited to one thread per worker) or, given a scheduler
address, to a Dask distributed cluster. Workers only compute: each returns its
run's metrics row (and trace) to this process, which alone writes the results
folder. So a cluster needs no shared file system, and the folder's lock keeps
two sweeps from writing into it at once.

A run's random streams come from ``SeedSequence(entropy)`` with ``entropy``
derived from the run's identity
(:meth:`formation_bench.benchmarks.spec.RunSpec.identity_entropy`), so
results do not depend on queue order, worker count or which worker ran what.
"""

from __future__ import annotations

import os
import signal
import sys
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from formation_bench.benchmarks.experiments.suite import Suite
from formation_bench.benchmarks.interrupts import is_interrupt
from formation_bench.benchmarks.provenance import git_info, machine_info, now, package_versions
from formation_bench.benchmarks.runner import execute
from formation_bench.benchmarks.spec import RunSpec

if TYPE_CHECKING:
    import pandas as pd

    from formation_bench.benchmarks.experiments.store import ResultStore

DEFAULT_JOBS = 2
SCHEDULER_TIMEOUT_S = 20
"""How long to try to reach a Dask scheduler before giving up."""
MANIFEST_FORMAT = 1


class SweepError(RuntimeError):
    """A sweep that cannot start as asked (reported in one line, exit 2)."""


# --- one run, in a worker ---------------------------------------------------------------------


@dataclass
class RunResult:
    """What a worker sends back: the row to store, or the error of a failed run."""

    key: str
    row: dict[str, Any] | None
    trace: pd.DataFrame | None = None
    error: str | None = None


def execute_run(spec: RunSpec) -> RunResult:
    """Carry out one run in a worker and return its row; errors are returned, not raised.

    An interrupt is raised, also when numba reports it as a ``SystemError`` (in-process runs
    with one job): it stops the sweep rather than being stored as a failed run.
    """
    from threadpoolctl import threadpool_limits

    try:
        with threadpool_limits(limits=1):
            outcome = execute(spec)
        return RunResult(spec.key, outcome.record.row(), outcome.frame if spec.trace else None)
    except Exception as err:
        if is_interrupt(err):
            raise
        return RunResult(spec.key, None, error=traceback.format_exc())


# --- executors ---------------------------------------------------------------------------------


def run_locally(specs: list[RunSpec], jobs: int) -> Iterator[RunResult]:
    """Results in completion order from ``jobs`` loky worker processes (in-process if 1)."""
    if jobs == 1:
        for spec in specs:
            yield execute_run(spec)
        return
    from joblib import Parallel, delayed, parallel_config

    with parallel_config(backend="loky", inner_max_num_threads=1):
        parallel = Parallel(
            n_jobs=jobs, return_as="generator_unordered", batch_size=1, pre_dispatch="2*n_jobs"
        )
        yield from parallel(delayed(_local_worker_run)(spec) for spec in specs)


_PDEATHSIG_SET = False


def _local_worker_run(spec: RunSpec) -> RunResult:
    """:func:`execute_run` in a local worker that dies with the sweep process.

    On Linux the worker asks the kernel for SIGKILL when its parent dies, so a
    sweep killed with SIGKILL leaves no worker computing or idling behind.
    """
    global _PDEATHSIG_SET
    if not _PDEATHSIG_SET:
        # Ctrl-C reaches the whole process group: the sweep process stops cleanly and
        # takes its workers down, so a worker must not die on SIGINT with a traceback.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    if not _PDEATHSIG_SET and sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
            if os.getppid() == 1:  # the parent died before prctl: do not run orphaned
                os._exit(1)
        except (OSError, AttributeError):
            pass
        _PDEATHSIG_SET = True
    return execute_run(spec)


def run_on_dask(specs: list[RunSpec], address: str) -> Iterator[RunResult]:
    """Results in completion order from the Dask cluster whose scheduler is at ``address``."""
    from dask.distributed import Client, as_completed

    try:
        client = Client(address, timeout=f"{SCHEDULER_TIMEOUT_S}s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as err:
        reason = " ".join(str(err).split())
        raise SweepError(
            f"--scheduler: cannot reach a Dask scheduler at {address!r}: {reason}"
        ) from None
    futures = []
    try:
        futures = client.map(
            execute_run, specs, key=[f"formation-bench-run-{s.key}" for s in specs], pure=False
        )
        spec_of = {f.key: s for f, s in zip(futures, specs, strict=True)}
        # the client is not the default one, so as_completed must be given its loop
        for future in as_completed(futures, loop=client.loop):
            try:
                result = future.result()
            except Exception:  # the worker died (KilledWorker) or the task was lost
                result = RunResult(spec_of[future.key].key, None, error=traceback.format_exc())
            future.release()
            yield result
    finally:
        if futures:
            client.cancel(futures)
        client.close()


# --- the sweep ------------------------------------------------------------------------------


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
    """The runs still to do, and the summary so far."""
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


def _check_suite_matches(
    manifest: dict[str, Any] | None, suite: Suite, root: Path, allow_change: bool
) -> None:
    if manifest is None or allow_change:
        return
    stored = manifest.get("suite", {})
    if stored.get("sha256") != suite.sha256:
        raise SweepError(
            f"--out: {root} holds results of suite {stored.get('name')!r} from a different suite "
            f"file (sha256 {str(stored.get('sha256'))[:12]}, now {suite.sha256[:12]}); "
            "choose another --out, or add --allow-suite-change to add to it"
        )


def _session(jobs: int, scheduler: str | None) -> dict[str, Any]:
    return {
        "started": now(),
        "finished": None,
        "state": "running",
        "executor": f"dask {scheduler}" if scheduler else f"joblib loky, {jobs} workers",
        "command": " ".join(sys.argv),
        "versions": package_versions(),
        "git": git_info(),
        "machine": machine_info(),
    }


def run_sweep(
    suite: Suite,
    out: Path | str,
    *,
    jobs: int = DEFAULT_JOBS,
    scheduler: str | None = None,
    progress: bool | None = None,
    allow_suite_change: bool = False,
    log: Callable[[str], None] | None = None,
) -> SweepSummary:
    """Run every unfinished run of ``suite`` into ``out`` and return the summary.

    ``progress`` None shows the bar only on a terminal. Ctrl-C (or SIGTERM) stops
    cleanly: finished runs are stored, the rest are left for the next call.
    """
    say = log or (lambda text: print(text, file=sys.stderr, flush=True))
    if jobs < 1:
        raise SweepError(f"--jobs must be an integer >= 1, got {jobs}")
    # the store reads and writes Parquet with pandas: imported by the command that uses it
    from formation_bench.benchmarks.experiments.store import ResultStore, StoreBusy

    start = time.perf_counter()
    store = ResultStore(out)
    try:
        with store.lock():
            summary = _sweep_locked(
                suite, store, jobs, scheduler, progress, allow_suite_change, say
            )
    except StoreBusy as err:
        raise SweepError(f"--out: {err}") from None
    summary.wall_s = time.perf_counter() - start
    for failure in summary.failed:
        last = failure["error"].strip().splitlines()[-1]
        say(f"failed: {failure['run']}: {last}")
    done = summary.already + summary.stored
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


def _sweep_locked(
    suite: Suite,
    store: ResultStore,
    jobs: int,
    scheduler: str | None,
    progress: bool | None,
    allow_suite_change: bool,
    say: Callable[[str], None],
) -> SweepSummary:
    start = time.perf_counter()
    manifest = store.read_manifest()
    _check_suite_matches(manifest, suite, store.root, allow_suite_change)
    if manifest is not None:
        # this sweep holds the folder's lock, so a session still marked running was killed
        for stale in manifest.get("sessions", []):
            if stale.get("state") == "running":
                stale["state"] = "killed"
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
    session = _session(jobs, scheduler)
    session.update(total=summary.total, already=summary.already, redo=summary.redo)
    manifest = _updated_manifest(manifest, suite, summary.total, session)
    store.write_manifest(manifest)
    state = "error"  # whatever ends the sweep, the manifest never says it is still running
    try:
        with _sigterm_as_interrupt():
            _execute(pending, store, summary, jobs, scheduler, progress, suite.name)
        state = "failed" if summary.failed else "done"
    except (KeyboardInterrupt, SystemError) as err:
        if not is_interrupt(err):
            raise
        summary.interrupted = True
        state = "interrupted"
    finally:
        session.update(
            finished=now(),
            state=state,
            stored=summary.stored,
            failed=summary.failed,
            wall_s=round(time.perf_counter() - start, 3),
        )
        manifest["updated"] = session["finished"]
        store.write_manifest(manifest)
    return summary


def _execute(
    pending: list[RunSpec],
    store: ResultStore,
    summary: SweepSummary,
    jobs: int,
    scheduler: str | None,
    progress: bool | None,
    name: str,
) -> None:
    from tqdm import tqdm

    if not pending:
        return
    by_key = {spec.key: spec for spec in pending}
    results: Iterable[RunResult] = (
        run_on_dask(pending, scheduler) if scheduler else run_locally(pending, jobs)
    )
    with tqdm(
        total=len(pending),
        desc=name,
        unit="run",
        disable=None if progress is None else not progress,
        file=sys.stderr,
    ) as bar:
        for result in results:
            spec = by_key[result.key]
            if result.row is None:
                summary.failed.append(
                    {"run": spec.describe(), "key": spec.key, "error": result.error or ""}
                )
            else:
                store.write_run(result.key, result.row, result.trace)
                summary.stored += 1
            bar.update(1)


class _sigterm_as_interrupt:
    """Turn SIGTERM into KeyboardInterrupt (main thread only), so batch systems stop cleanly."""

    def __enter__(self) -> None:
        self.previous = None
        try:
            self.previous = signal.signal(signal.SIGTERM, self._raise)
        except ValueError:  # not the main thread
            self.previous = None

    def __exit__(self, *exc: object) -> None:
        if self.previous is not None:
            signal.signal(signal.SIGTERM, self.previous)

    @staticmethod
    def _raise(signum: int, frame: object) -> None:
        raise KeyboardInterrupt


def _updated_manifest(
    manifest: dict[str, Any] | None, suite: Suite, total: int, session: dict[str, Any]
) -> dict[str, Any]:
    suite_info = {
        "name": suite.name,
        "file": str(suite.path),
        "sha256": suite.sha256,
        "text": suite.text,
        "runs": total,
        "notes": list(suite.notes),
    }
    if manifest is None:
        manifest = {"format": MANIFEST_FORMAT, "created": session["started"], "sessions": []}
    previous = manifest.get("suite")
    if previous and previous.get("sha256") != suite.sha256:
        manifest.setdefault("previous_suites", []).append(previous)
    manifest["suite"] = suite_info
    manifest["updated"] = session["started"]
    for key in ("versions", "git", "machine"):
        manifest[key] = session[key]
    manifest.setdefault("sessions", []).append(session)
    return manifest
