"""Smoke tests of the scaling benchmark, the kernel comparison and the pytest-benchmark suite."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from perf import population_speed, scaling, speed

ROOT = Path(__file__).resolve().parent.parent


def test_scaling_script_reports_speedup_and_overhead(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(scaling, "WARM", scaling.WARM.replace("n_steps = 40", "n_steps = 5"))
    out = tmp_path / "scaling.json"
    assert scaling.main(["--runs", "2", "--steps", "10", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "speed-up, 2 workers over 1" in printed and "machinery overhead per run" in printed
    figures = json.loads(out.read_text())
    assert figures["speedup"] > 0
    assert figures["jobs1"]["workers_used"] == 1 and figures["jobs2"]["workers_used"] >= 1
    assert figures["jobs2"]["workers_started"] == 2
    assert 0 < figures["jobs1"]["simulate_total_s"] < 2 * figures["jobs1"]["sweep_wall_s"]


@pytest.mark.slow
def test_timing_suite_collects_every_optimizer_and_runs(tmp_path):
    listing = subprocess.run(
        [sys.executable, "-m", "pytest", "perf/timing", "--collect-only", "-q"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert listing.returncode == 0, listing.stdout + listing.stderr
    from formation_bench.optimizers import OPTIMIZERS

    for name in OPTIMIZERS:
        assert f"test_solve_time[{name}-default]" in listing.stdout
    saved = tmp_path / "timing.json"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "perf/timing/test_solve_timing.py::test_solve_time[modified-bso-default]",
            "perf/timing/test_solve_timing.py::test_solve_time[pso-equal-1200]",
            f"--benchmark-json={saved}",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    data = json.loads(saved.read_text())
    names = {b["name"] for b in data["benchmarks"]}
    assert names == {"test_solve_time[modified-bso-default]", "test_solve_time[pso-equal-1200]"}
    assert data["machine_info"]["cpu_affinity"]
    assert all(b["stats"]["rounds"] == 27 for b in data["benchmarks"])


@pytest.mark.slow
def test_kernel_comparison_times_both_kernels_on_paper_problems():
    instants = population_speed.paper_instants((5,))
    figures = speed.kernel_comparison(instants, speed.default_population_size(), 3, number=5)
    assert figures["kernel_population"] == 30 and figures["kernel_problems"] == 3
    assert figures["kernel_reference_per_eval_s"] > 0 and figures["kernel_rotation_per_eval_s"] > 0
    low, high = figures["kernel_ratio_quartiles"]
    assert 0 < low <= figures["kernel_ratio_median"] <= high
    assert figures["kernel_max_relative_difference"] < 1e-12
    table = speed.format_kernel_comparison(figures)
    assert "ns per evaluation" in table and "ratio now / before, per repeat (3 repeats)" in table


@pytest.mark.slow
def test_startup_script_measures_overhead_and_compile(tmp_path, monkeypatch):
    from perf import startup

    short = ["--set", "n_steps=8", "--set", "settle_time_s=0.5", "--set", "max_iterations=3"]
    monkeypatch.setattr(startup, "RUN", [*startup.RUN, *short])
    assert "pandas" not in startup.modules_loaded([*startup.RUN, "--out", str(tmp_path / "m")])
    warm = startup.warm_overhead(1, tmp_path)
    assert warm["ratio"]["median"] > 1  # a command takes longer than its solves
    assert 0 < warm["solve_sum_s"]["median"] < warm["wall_s"]["median"]
    cold = startup.cold_start(1, tmp_path)
    kernels = cold["kernels_cpu_s"]
    # the run solves through the compiled loop, which holds the iteration and the cost kernel
    assert "formation_bench.optimizers.modified_bso_kernels.modified_bso_iterate" in kernels
    assert "formation_bench.mpc.cost.packed_batch_cost" in kernels
    assert cold["compile_cpu_s"] == pytest.approx(sum(kernels.values()))
    assert cold["wall_s"]["median"] > warm["wall_s"]["median"]
