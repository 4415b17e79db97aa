"""Pin the timing suite to two cores and one thread per native pool, before anything runs.

``pytest perf/timing`` is not part of the default test run (``testpaths``
is ``tests``). The command and how to compare two saved runs are in
``docs/explanation/benchmarks.md``.
"""

from __future__ import annotations

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

PINNED_CPUS: list[int] = []
if hasattr(os, "sched_setaffinity"):
    PINNED_CPUS = sorted(os.sched_getaffinity(0))[:2]
    os.sched_setaffinity(0, PINNED_CPUS)

from threadpoolctl import threadpool_limits  # noqa: E402

_LIMITS = threadpool_limits(limits=1)  # held for the whole session


def pytest_benchmark_update_machine_info(config, machine_info):
    """Record the pinning with every saved run, so comparisons can check it."""
    machine_info["cpu_affinity"] = PINNED_CPUS
    machine_info["thread_limits"] = "1 per native pool (threadpoolctl, OMP/BLAS/numba env)"
