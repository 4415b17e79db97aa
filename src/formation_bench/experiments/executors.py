"""Where runs are computed: :func:`execute_run` carries out one closed-loop run of a sweep in a
worker, :func:`run_locally` and :func:`run_on_dask` yield the results of many in completion
order, from local loky worker processes or a Dask cluster. Workers only compute and send back
each run's row (and trace); the command's own process alone stores them
(:mod:`~formation_bench.experiments.sweep`, :mod:`~formation_bench.experiments.score`).

The executors take any run with a ``key`` and the module-level function that carries it out
(``work``, :func:`execute_run` by default): a score run goes through them with
:func:`~formation_bench.experiments.score.execute_score_run`. A work function wraps its
computation in :func:`computed`, so that every run's thread pools and errors are handled
alike.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import sys
import time
import traceback
import warnings
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from formation_bench.experiments.errors import SweepError, SweepStopped
from formation_bench.pipeline.interrupts import (
    interrupts_deferred,
    is_interrupt,
    started_deaf_to_interrupts,
)
from formation_bench.pipeline.runner import execute
from formation_bench.pipeline.spec import RunSpec

if TYPE_CHECKING:
    import pandas as pd
    from dask.distributed import Client

SCHEDULER_TIMEOUT_S = 20
"""How long to try to reach a Dask scheduler before giving up."""
DEFAULT_WORKER_TIMEOUT_S = 300.0
"""How long a Dask sweep waits with no live worker before it stops (finished runs stored):
long enough for a batch system to start workers, short enough not to wait unseen all night."""
WORKER_CHECK_S = 5.0
"""How often a Dask sweep asks the scheduler whether any worker is alive."""


# --- one run, in a worker ---------------------------------------------------------------------


@dataclass
class RunResult:
    """What a worker sends back: what to store, or the error of a failed run."""

    key: str
    row: dict[str, Any] | None
    """A closed-loop run's row (None for a failed run, or a score run: see :attr:`rows`)."""
    trace: pd.DataFrame | None = None
    """A closed-loop run's trace, when its suite keeps traces."""
    error: str | None = None
    """The traceback of a failed run; None: it finished."""
    rows: pd.DataFrame | None = None
    """A score run's rows, one per instance solved."""

    @property
    def failed(self) -> bool:
        return self.error is not None


class Keyed(Protocol):
    """A run an executor can carry out: named by its key (the store's file name)."""

    @property
    def key(self) -> str: ...


Work = Callable[[Any], RunResult]
"""A module-level function that carries out one run in a worker (it is sent to the worker by
name)."""


def computed(key: str, compute: Callable[[], RunResult]) -> RunResult:
    """``compute()`` with native thread pools at one thread (one run per worker process); an
    error is returned in the result of run ``key``, not raised.

    An interrupt is raised, also when numba reports it as a ``SystemError`` (in-process runs
    with one job): it stops the command rather than being stored as a failed run.
    """
    from threadpoolctl import threadpool_limits

    try:
        with threadpool_limits(limits=1):
            return compute()
    except Exception as err:
        if is_interrupt(err):
            raise
        return RunResult(key, None, error=traceback.format_exc())


def execute_run(spec: RunSpec) -> RunResult:
    """Carry out one closed-loop run in a worker and return its row (and trace)."""

    def closed_loop() -> RunResult:
        outcome = execute(spec)
        return RunResult(spec.key, outcome.record.row(), outcome.frame if spec.trace else None)

    return computed(spec.key, closed_loop)


# --- executors ---------------------------------------------------------------------------------


TRACKER_CLEAN_UP_WARNING = "ignore:resource_tracker:UserWarning"
"""``-W`` option of loky's resource tracker: its reports of what it cleans up."""
DROPPED_RESULTS_WARNING = r"\d+ tasks (?:have been successfully executed|which were still being)"
"""joblib's warning about the tasks it drops when a sweep stops early: finished but not handed
back, or still running and cancelled (a sweep stopped by a full disk or a folder taken away
while both workers compute)."""


def run_locally(
    specs: Sequence[Keyed], jobs: int, work: Work = execute_run
) -> Generator[RunResult, None, None]:
    """Results of ``work`` on every run of ``specs``, in completion order, from ``jobs`` loky
    worker processes (in-process if 1)."""
    if jobs == 1:
        for spec in specs:
            yield work(spec)
        return
    from joblib import Parallel, delayed, parallel_config

    # After a Ctrl-C or a stop, joblib warns that it drops the runs its workers finished but
    # had not handed back or were still computing (the next sweep redoes them), and loky's
    # resource tracker, a process of its own that outlives the command, reports the
    # semaphores of the killed workers it then removes: both would follow the command's one
    # line. The tracker takes its warning
    # options from this process's.
    if TRACKER_CLEAN_UP_WARNING not in sys.warnoptions:
        sys.warnoptions.append(TRACKER_CLEAN_UP_WARNING)
    with parallel_config(backend="loky", inner_max_num_threads=1), warnings.catch_warnings():
        warnings.filterwarnings("ignore", DROPPED_RESULTS_WARNING, UserWarning)
        parallel = Parallel(
            n_jobs=jobs, return_as="generator_unordered", batch_size=1, pre_dispatch="2*n_jobs"
        )
        with started_deaf_to_interrupts():  # the workers start here
            results = parallel(delayed(_local_worker_run)(work, spec) for spec in specs)
        yield from results


_PDEATHSIG_SET = False


def _local_worker_run(work: Work, spec: Keyed) -> RunResult:
    """``work(spec)`` in a local worker that dies with the command's process.

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
    return work(spec)


def connect_scheduler(address: str) -> Client:
    """A client of the Dask scheduler at ``address``; called before any folder is made, so a
    missing ``dask`` extra or an unreachable scheduler leaves nothing behind."""
    try:
        from dask.distributed import Client
    except ImportError as err:
        raise SweepError(
            f'--scheduler needs the dask extra: pip install ".[dask]" (import failed: {err})'
        ) from None
    _check_reachable(address)
    try:
        return Client(address, timeout=f"{SCHEDULER_TIMEOUT_S}s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as err:
        raise SweepError(_unreachable(address, err)) from None


def _unreachable(address: str, err: BaseException) -> str:
    reason = " ".join(str(err).split()) or type(err).__name__
    return f"--scheduler: cannot reach a Dask scheduler at {address!r}: {reason}"


def _check_reachable(address: str) -> None:
    """Refuse a TCP address nothing listens on at once: the client itself keeps retrying
    a refused connection until its timeout."""
    from urllib.parse import urlsplit

    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    if parts.scheme != "tcp" or not parts.hostname:
        return
    try:
        with socket.create_connection(
            (parts.hostname, parts.port or 8786), timeout=SCHEDULER_TIMEOUT_S
        ):
            pass
    except OSError as err:
        raise SweepError(_unreachable(address, err)) from None


def _live_workers(client: Client) -> int:
    return len(client.scheduler_info().get("workers", {}))


def _connected(client: Client) -> bool:
    """Whether the client is connected to its scheduler (not reconnecting, not given up)."""
    return client.status == "running"


def _scheduler_lost(client: Client) -> SweepStopped:
    return SweepStopped(
        f"lost the connection to the Dask scheduler at {client.scheduler.address}",
        "start the scheduler and its workers again and run the same command to finish",
        option="--scheduler",
    )


def close_client(client: Client) -> None:
    """Close ``client``, letting no Ctrl-C cut it short.

    A client that lost its scheduler is still trying to reconnect: closing it stops that,
    and the client logs the stop (an error line, or the traceback of its cancelled attempt)
    on stderr. The sweep has said in its one line that the scheduler was lost, so the
    client's log is silenced while it closes.
    """
    client_log = logging.getLogger("distributed.client")
    silenced = not _connected(client) and client.status != "closed"
    if silenced:
        client_log.disabled = True
    try:
        with interrupts_deferred():
            client.close()
    finally:
        if silenced:
            client_log.disabled = False


def _to_stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def run_on_dask(
    specs: Sequence[Keyed],
    client: Client,
    worker_timeout_s: float = DEFAULT_WORKER_TIMEOUT_S,
    work: Work = execute_run,
    notice: Callable[[str], None] = _to_stderr,
) -> Generator[RunResult, None, None]:
    """Results of ``work`` on every run of ``specs``, in completion order, from the Dask
    cluster of ``client``.

    Raises :class:`SweepStopped` when the scheduler has had no worker for
    ``worker_timeout_s`` (saying so through ``notice`` when it starts waiting), or when the
    connection to the scheduler is lost for good: the runs finished until then are all
    yielded first, and the runs still out are left for the next sweep, not reported failed.
    """
    from dask.distributed import as_completed

    futures = client.map(
        work, specs, key=[f"formation-bench-run-{s.key}" for s in specs], pure=False
    )
    spec_of = {f.key: s for f, s in zip(futures, specs, strict=True)}
    remaining = set(futures)
    check_s = min(WORKER_CHECK_S, worker_timeout_s / 4)
    worker_seen = time.monotonic()
    waiting = False
    try:
        while remaining:
            try:
                # the client is not the default one, so as_completed must be given its loop;
                # its timeout only wakes this loop up to look for live workers
                for future in as_completed(list(remaining), loop=client.loop, timeout=check_s):
                    remaining.discard(future)
                    worker_seen = time.monotonic()
                    try:
                        result = future.result()
                    except Exception:  # the worker died (KilledWorker) or the task was lost
                        if not _connected(client):  # ... or the scheduler is gone
                            raise _scheduler_lost(client) from None
                        error = traceback.format_exc()
                        result = RunResult(spec_of[future.key].key, None, error=error)
                    future.release()
                    yield result
            except TimeoutError:
                pass
            if not _connected(client):
                if client.status in ("closing", "closed"):
                    raise _scheduler_lost(client)
                continue  # reconnecting: the client gives up after its own timeout
            if _live_workers(client):
                worker_seen = time.monotonic()
                if waiting:
                    notice(f"note: a Dask worker is live again at {client.scheduler.address}")
                waiting = False
            elif time.monotonic() - worker_seen >= worker_timeout_s:
                raise SweepStopped(
                    f"no live Dask worker at {client.scheduler.address} for "
                    f"{worker_timeout_s:g} s (--worker-timeout)",
                    "start workers and run the same command again",
                    option="--scheduler",
                )
            elif not waiting:
                waiting = True
                notice(
                    f"note: no live Dask worker at {client.scheduler.address}; waiting up to "
                    f"{worker_timeout_s:g} s (--worker-timeout) for one, the finished runs "
                    "stored"
                )
    finally:
        if remaining and _connected(client):
            client.cancel(list(remaining))
