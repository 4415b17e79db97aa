"""No timing holds numba's compilation: on a cold cache (a new ``NUMBA_CACHE_DIR``) the first
timed solve of a score run, and the first solve of each sweep run, take about what the others
take, because an untimed warm-up solve compiles first."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from formation_bench.experiments.store import load_results

ROOT = Path(__file__).resolve().parent.parent
OPTIMIZER = "random-search"
"""The optimiser of both tests: its kernels compile fastest, and what the warm-up does is the
same for every optimiser."""
AT_MOST = 3.0
"""The first solve's time may be at most this many times the median of the others."""


def cold_cache(tmp_path: Path) -> dict[str, str]:
    """The environment of a process whose numba cache is empty."""
    return dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba-cache"))


@pytest.mark.slow
def test_a_score_runs_first_solve_on_a_cold_cache_takes_what_the_others_take(tmp_path):
    script = textwrap.dedent(f"""
        import json
        from formation_bench.experiments import score

        every = score.split_instances
        score.split_instances = lambda library, split: every(library, split)[:15]
        (run,) = score.score_runs({OPTIMIZER!r}, {{}}, [None], [0])
        print(json.dumps(score.execute_score(run)["seconds"].tolist()))
    """)
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=900,
        env=cold_cache(tmp_path), cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert any((tmp_path / "numba-cache").rglob("*.nbi")), "the cache was not the one used"
    seconds = json.loads(done.stdout.splitlines()[-1])
    first, others = seconds[0], np.median(seconds[1:])
    assert first <= AT_MOST * others, (first, others)


SUITE = f"""\
name = "cold"
seeds = 3
triggers = [false]

[[optimizers]]
name = "{OPTIMIZER}"

[[scenarios]]
name = "paper"
overrides = {{ n_steps = 15, settle_time_s = 1.0 }}
"""


@pytest.mark.slow
def test_a_sweeps_first_runs_on_a_cold_cache_take_what_the_others_take(tmp_path):
    suite = tmp_path / "cold.toml"
    suite.write_text(SUITE)
    out = tmp_path / "out"
    done = subprocess.run(
        [sys.executable, "-m", "formation_bench.cli", "sweep", str(suite), "--out", str(out),
         "--jobs", "2", "--no-progress"],
        capture_output=True, text=True, timeout=900, env=cold_cache(tmp_path), cwd=ROOT,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    # the compilation announced once, whatever the output mode
    assert done.stderr.count("compiling numba kernels once") == 1
    assert "the harness ~2 s, random-search ~3 s" in done.stderr
    runs = load_results(out, strict=True)
    assert len(runs) == 3  # each worker's first run among them
    for times in runs["solve_times_s"]:
        times = np.asarray(times)
        assert times[0] <= AT_MOST * np.median(times[1:]), (times[0], np.median(times[1:]))
    run_time = runs["run_time_s"].to_numpy()
    assert run_time.max() <= AT_MOST * np.median(run_time), run_time


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ltv-osqp", "ipopt"])
def test_a_warm_up_leaves_the_built_solvers_and_nothing_a_solve_carries(name):
    from formation_bench.experiments.score import split_instances
    from formation_bench.instances.library import shipped
    from formation_bench.optimizers import get_optimizer
    from formation_bench.pipeline.runner import warm_up_solve

    optimizer = get_optimizer(name)
    instance = split_instances(shipped(), "test")[0]
    problem = instance.problem
    optimizer.minimize(problem, problem.bounds, np.random.default_rng(0), None, instance.warm_start)
    kinds = {key[0] for key in optimizer._solver_cache if isinstance(key, tuple)}
    assert optimizer.CARRIED <= kinds  # what a solve leaves for the next one is there
    warm_up_solve(optimizer, problem, problem.bounds, None, instance.warm_start)
    kept = {key[0] for key in optimizer._solver_cache if isinstance(key, tuple)}
    assert kept == kinds - optimizer.CARRIED and kept  # built solvers kept, the rest dropped
