"""No kernel compiled by two processes: numba's cache behind a lock (formation_bench.kernel_cache),
and a cold sweep whose workers compile different kernels at the same time."""

from __future__ import annotations

import importlib.util
import json
import multiprocessing
import os
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

from formation_bench.experiments.store import load_results
from formation_bench.optimizers import get_optimizer
from formation_bench.pipeline.compiles import (
    HARNESS_COMPILE_CPU_S,
    CompileGroup,
    PendingCompiles,
    compile_first,
)

ROOT = Path(__file__).resolve().parent.parent

# compiles for about half a second: two processes that start it together both miss the cache
KERNEL_MODULE = """
import numpy as np
from {module} import njit

@njit(cache=True)
def kernel(values):
    total = 0.0
    for i in range(values.shape[0]):
        total += np.sin(values[i]) * np.cos(values[i]) + np.sqrt(abs(values[i]))
    ordered = np.sort(values)
    return total + ordered[0] + np.linalg.norm(values) + np.cumsum(values)[-1]
"""


def _kernel_module(folder: str):  # type: ignore[no-untyped-def]
    spec = importlib.util.spec_from_file_location("slow_kernel", Path(folder) / "slow_kernel.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["slow_kernel"] = module  # numba imports it by name to load a cached kernel
    spec.loader.exec_module(module)
    return module


def _call_kernel(folder: str, barrier, queue) -> None:  # type: ignore[no-untyped-def]
    import numpy as np

    slow_kernel = _kernel_module(folder)
    barrier.wait(timeout=120)
    value = slow_kernel.kernel(np.linspace(0.0, 1.0, 7))
    queue.put((value, sum(slow_kernel.kernel.stats.cache_misses.values())))


def _two_processes_call(tmp_path: Path, module: str) -> list[tuple[float, int]]:
    folder = tmp_path / module.replace(".", "_")
    folder.mkdir()
    (folder / "slow_kernel.py").write_text(KERNEL_MODULE.format(module=module))
    context = multiprocessing.get_context("spawn")
    barrier, queue = context.Barrier(2), context.Queue()
    os.environ["NUMBA_CACHE_DIR"] = str(folder / "cache")  # read by the spawned children
    try:
        processes = [
            context.Process(target=_call_kernel, args=(str(folder), barrier, queue))
            for _ in range(2)
        ]
        for process in processes:
            process.start()
        results = [queue.get(timeout=120) for _ in processes]
        for process in processes:
            process.join(timeout=60)
            assert process.exitcode == 0
    finally:
        del os.environ["NUMBA_CACHE_DIR"]
    return results


@pytest.mark.slow
def test_two_processes_missing_the_cache_together_compile_a_kernel_once(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    locked = _two_processes_call(tmp_path, "formation_bench.kernel_cache")
    assert sorted(misses for _, misses in locked) == [0, 1]  # one compiled, one loaded
    assert locked[0][0] == locked[1][0]
    # numba's own njit, the same kernel started the same way: both compile
    plain = _two_processes_call(tmp_path, "numba")
    assert [misses for _, misses in plain] == [1, 1]


def _fail_then_wait(folder: str, failed, done) -> None:  # type: ignore[no-untyped-def]
    from numba.core.errors import TypingError

    slow_kernel = _kernel_module(folder)
    try:
        slow_kernel.kernel("not an array")
    except TypingError:
        failed.set()
    done.wait(timeout=120)  # alive, as a sweep's worker stays after a failed run


def _compile(folder: str, queue) -> None:  # type: ignore[no-untyped-def]
    import numpy as np

    slow_kernel = _kernel_module(folder)
    queue.put(float(slow_kernel.kernel(np.ones(3))))


def test_a_failed_compilation_lets_other_processes_compile(tmp_path, monkeypatch):
    (tmp_path / "slow_kernel.py").write_text(
        KERNEL_MODULE.format(module="formation_bench.kernel_cache")
    )
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    context = multiprocessing.get_context("spawn")
    failed, done, queue = context.Event(), context.Event(), context.Queue()
    failing = context.Process(target=_fail_then_wait, args=(str(tmp_path), failed, done))
    failing.start()
    try:
        assert failed.wait(timeout=120)
        other = context.Process(target=_compile, args=(str(tmp_path), queue))
        other.start()
        assert queue.get(timeout=120) > 0  # it did not wait for the failed process to exit
        other.join(timeout=60)
    finally:
        done.set()
        failing.join(timeout=60)


def test_the_compile_notice_names_each_group_once_with_its_time():
    random_search = get_optimizer("random-search")
    group = CompileGroup(random_search.compiled_kernels(), ("random-search", "rs-2"), 3.0)
    unknown = CompileGroup(("k",), ("plugin-method",), None)
    notice = PendingCompiles(True, (group, unknown)).notice(2)
    assert notice is not None and "\n" not in notice
    assert "the harness ~2 s" in notice and "random-search (+1 configuration) ~3 s" in notice
    assert "plugin-method (time not measured)" in notice and "plus 1 not measured" in notice
    assert PendingCompiles(False, ()).notice(2) is None
    # on two workers: the harness in each, then the longest group first
    pending = PendingCompiles(
        True, tuple(CompileGroup((i,), (str(i),), s) for i, s in enumerate((30, 20, 10)))
    )
    assert pending.wall_s(2) == HARNESS_COMPILE_CPU_S + 30
    assert pending.wall_s(1) == HARNESS_COMPILE_CPU_S + 60


def test_a_sweep_starts_the_first_run_of_each_uncompiled_group_longest_first(monkeypatch):
    import formation_bench.pipeline.runner as runner

    monkeypatch.setattr(runner, "optimizer_kernels_cached", lambda optimizer: False)
    names = ["random-search", "random-search", "cma-es", "pso", "cma-es-ipop", "pso", "pycma"]
    order = compile_first(list(enumerate(names)), lambda spec: get_optimizer(spec[1]))
    assert [n for _, n in order[:3]] == ["cma-es", "pso", "random-search"]
    assert sorted(order) == sorted(enumerate(names))  # every run, once
    assert [i for i, _ in order[3:]] == [1, 4, 5, 6]  # the others in their order
    monkeypatch.setattr(runner, "optimizer_kernels_cached", lambda optimizer: True)
    assert compile_first(names, get_optimizer) == names


# a plugin each process of the sweep loads: it notes every kernel numba compiles in it
COUNTER_PLUGIN = """
import os
from numba.core import event

class Noted(event.Listener):
    def on_start(self, ev):
        pass
    def on_end(self, ev):
        func = getattr(ev.data["dispatcher"], "py_func", None)
        cached = type(getattr(ev.data["dispatcher"], "_cache", None)).__name__ != "NullCache"
        if func is not None and cached:
            with open(os.environ["COMPILES_NOTED"], "a") as notes:
                notes.write(f"{os.getpid()} {func.__module__}.{func.__qualname__} "
                            f"{ev.data['args']}\\n")

event.register("numba:compile", Noted())
"""

SUITE = """\
name = "cold-pair"
seeds = 2
triggers = [false]

[[optimizers]]
name = "random-search"

[[optimizers]]
name = "predictive-sampling"

[[optimizers]]
name = "predictive-sampling"
label = "predictive-sampling-large"
overrides = { population_size = 40 }

[[scenarios]]
name = "paper"
overrides = { n_steps = 10, settle_time_s = 1.0 }
"""


@pytest.mark.slow
def test_a_cold_sweep_compiles_each_kernel_in_one_process_only(tmp_path):
    (tmp_path / "noting.py").write_text(COUNTER_PLUGIN)
    (tmp_path / "pair.toml").write_text(SUITE)
    notes = tmp_path / "compiles.txt"
    env = dict(
        os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"), COMPILES_NOTED=str(notes)
    )
    done = subprocess.run(
        [sys.executable, "-m", "formation_bench.cli", f"--plugin={tmp_path / 'noting.py'}",
         "sweep", str(tmp_path / "pair.toml"), "--out", str(tmp_path / "out"), "--jobs", "2",
         "--no-progress"],
        capture_output=True, text=True, timeout=900, env=env, cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert len(load_results(tmp_path / "out", strict=True)) == 6
    assert done.stderr.count("compiling numba kernels once") == 1
    compiled = [line.split(" ", 1) for line in notes.read_text().splitlines()]
    by_kernel = Counter(kernel for _, kernel in compiled)
    assert len(by_kernel) > 10
    twice = {kernel: n for kernel, n in by_kernel.items() if n > 1}
    assert not twice, json.dumps(twice, indent=1)
    # both workers compiled, each its own optimiser's kernels
    assert len({pid for pid, _ in compiled}) == 2


def test_every_cached_kernel_of_the_package_takes_the_lock():
    import importlib
    import pkgutil

    from numba.core.caching import FunctionCache
    from numba.core.dispatcher import Dispatcher

    import formation_bench
    from formation_bench.kernel_cache import LockedCache

    found, plain = 0, []
    for info in pkgutil.walk_packages(formation_bench.__path__, "formation_bench."):
        if info.name.endswith("__main__"):  # runs the command line
            continue
        try:
            module = importlib.import_module(info.name)
        except ImportError:  # an optional extra not installed
            continue
        for name, value in vars(module).items():
            if isinstance(value, Dispatcher) and value.py_func.__module__ == info.name:
                if isinstance(value._cache, FunctionCache):
                    found += 1
                    if not isinstance(value._cache, LockedCache):
                        plain.append(f"{info.name}.{name}")
    assert found > 100 and not plain, plain


def test_every_shipped_optimizer_that_compiles_declares_its_compile_time():
    from formation_bench.optimizers import optimizer_names

    for name in optimizer_names():
        optimizer = get_optimizer(name)
        if optimizer.compiled_kernels():
            assert optimizer.compile_cpu_s is not None and optimizer.compile_cpu_s > 0, name
